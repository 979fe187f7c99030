//! The verify report in words: what was checked, at which density, the results, and a final
//! PASS or FAIL line with the reasons; and the number and place formats its failure lines use.

use super::{containment, Report};

pub(super) fn fmt_len(x: f64) -> String {
    format!("{x:.6e}")
}

pub(super) fn fmt_point(p: [f64; 3]) -> String {
    format!("({:.6}, {:.6}, {:.6})", p[0], p[1], p[2])
}

pub(super) fn describe_pose(row: Option<u32>, line: Option<u64>) -> String {
    match (row, line) {
        (Some(r), Some(l)) => format!("pose row {r} (CSV line {l})"),
        _ => "its rest pose (no trajectory row moves it)".into(),
    }
}

pub(super) fn describe_outside(w: &containment::OutsidePoint) -> String {
    format!(
        "at {}: part {:?} (node {}) triangle {}, {}",
        fmt_point(w.point),
        w.node_name,
        w.node,
        w.triangle,
        match w.between {
            Some(b) => format!(
                "on the screw motion from pose row {} (CSV line {}) to row {} (line {}), at s = {:.4}",
                w.pose_row.unwrap_or(0),
                w.csv_line.unwrap_or(0),
                b.to_row,
                b.to_line,
                b.s
            ),
            None => describe_pose(w.pose_row, w.csv_line),
        }
    )
}

impl Report {
    /// The human-readable report: what was checked, at which density, the results, and a final
    /// PASS or FAIL line with the reasons.
    pub fn text(&self) -> String {
        let i = &self.inputs;
        let h = &self.health;
        let c = &self.containment;
        let d = &self.deviation;
        let yes = |b: bool| if b { "yes" } else { "no" };
        let mut s = String::new();
        s += &format!(
            "sweptvol verify {}\n  generator  {} ({} parts, {} triangles)\n  trajectory {} ({} rows; {} posed triangles)\n  mesh       {} ({} triangles)\n",
            self.sweptvol_version,
            i.generator.display(),
            i.generator_parts,
            i.generator_triangles,
            i.trajectory.display(),
            i.trajectory_rows,
            i.posed_triangles,
            i.mesh.display(),
            i.mesh_triangles
        );
        s += &format!(
            "mesh health: closed {}, watertight and manifold {}; {} open, {} misoriented, {} non-manifold edges; {} non-manifold vertices; {} components; {} self-intersecting triangle pairs; {} degenerate triangles; signed volume {:.6e}\n",
            yes(h.closed),
            yes(h.watertight_manifold),
            h.open_edges,
            h.misoriented_edges,
            h.non_manifold_edges,
            h.non_manifold_vertices,
            h.components,
            h.self_intersecting_pairs,
            h.degenerate_triangles,
            h.signed_volume
        );
        let m = &self.motion;
        s += &if m.model == "screw" {
            format!(
                "motion: screw between rows ({} intervals), certified through {} poses each standing for its part of the motion within {} (largest path of an interval {})\n",
                m.intervals,
                m.poses,
                fmt_len(m.max_reach),
                fmt_len(m.max_path)
            )
        } else {
            format!(
                "motion: discrete, the {} listed poses only (the motion between rows is not certified)\n",
                m.poses
            )
        };
        let r = &c.result;
        s += &format!(
            "containment (generalized winding number >= 1/2 with clearance >= covering radius; covering radius {}, down to {} near the surface): {} of {} posed triangles certified inside, {} with points outside, {} too close to certify ({} ball tests, {} winding numbers, {} outside samples, {} uncertain samples, {} pieces certified by a separating axis)\n",
            fmt_len(c.spacing),
            fmt_len(c.finest),
            r.certified,
            r.posed_triangles,
            r.outside,
            r.too_close,
            r.ball_tests,
            r.winding_evaluations,
            r.outside_samples,
            r.too_close_samples,
            r.separated_samples
        );
        if let Some(w) = &r.worst_outside {
            s += &format!(
                "  worst point outside: {} outside the mesh, {}\n",
                fmt_len(w.distance),
                describe_outside(w)
            );
        }
        let dr = &d.result;
        s += &format!(
            "deviation (one-sided Hausdorff distance from the mesh to the posed generator surfaces; sample covering radius {}, {} samples): at most {}, at least {}",
            fmt_len(dr.spacing),
            dr.samples,
            fmt_len(dr.bound),
            fmt_len(dr.lower)
        );
        if let Some(limit) = d.limit {
            s += &format!(" (--bound {})", fmt_len(limit));
        }
        s += "\n";
        if let Some(p) = &d.pockets {
            s += &format!(
                "  beyond the bound: {} pieces, {} hidden from all six axis directions (filled pockets), {} visible along an axis, {} undetermined ({} rays, {} steps)\n",
                p.pieces_beyond, p.hidden, p.visible, p.undetermined, p.rays, p.steps
            );
        }
        if let Some(p) = &dr.place {
            s += &format!(
                "  reached near {} on mesh triangle {}: {} from part {:?} (node {}) triangle {}, {}\n",
                fmt_point(p.point),
                p.mesh_triangle,
                fmt_len(p.distance),
                p.node_name,
                p.node,
                p.triangle,
                describe_pose(p.pose_row, p.csv_line)
            );
        }
        s += &format!(
            "time: {:.2} s ({} threads)\n",
            self.timings.total, self.threads
        );
        if self.passed {
            s += "PASS: every posed generator triangle is certified inside the closed mesh";
            if let Some(b) = d.limit {
                s += &match d.pockets {
                    Some(_) => format!(
                        " and the deviation is within {} wherever the mesh sees out along an axis",
                        fmt_len(b)
                    ),
                    None => format!(" and the deviation is within {}", fmt_len(b)),
                };
            }
            s += "\n";
        } else {
            s += "FAIL:\n";
            for f in &self.failures {
                s += &format!("  {f}\n");
            }
        }
        s
    }
}
