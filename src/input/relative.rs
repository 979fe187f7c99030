//! Motion relative to a moving reference node (`relative_to`): every other part is swept in
//! the reference's own frame (its mesh's coordinates).
//!
//! At a row time t the reference stands at R_t·W_ref and a part at P_t·W (W the nodes' world
//! transforms, R_t and P_t the rows' matrices). In the reference's frame the part stands at
//! (R_t·W_ref)⁻¹·P_t·W, so its row becomes W_ref⁻¹·R_t⁻¹·P_t (the part's W is applied after,
//! as for any row). A part no row moves stands at W, so it gets one row W_ref⁻¹·R_t⁻¹ per
//! reference row. The rewritten rows are ordinary rows: the motion between them (the screw,
//! where asked) is then the screw in the reference's frame. Every part row must share its time
//! with a reference row; the reference leaves the generator (it is the frame, and the natural
//! obstacle, `reference_obstacle`).

use std::collections::BTreeMap;
use std::path::Path;

use glam::DMat4;

use super::model::{Generator, Part, Pose, Trajectory};
use crate::error::{InputError, OptionError, OptionKey};

/// A row time as a map key: its bits, with -0 taken as 0.
fn time_key(t: f64) -> u64 {
    (t + 0.0).to_bits()
}

/// The generator less the reference part, the trajectory rewritten into the reference's
/// frame, and the reference part itself.
pub fn apply(
    generator: &Generator,
    trajectory: &Trajectory,
    csv_path: &Path,
    reference: &str,
) -> anyhow::Result<(Generator, Trajectory, Part)> {
    let named: Vec<usize> = (0..generator.parts.len())
        .filter(|&i| generator.parts[i].node_name.as_deref() == Some(reference))
        .collect();
    let r = match named.as_slice() {
        [r] => *r,
        [] => {
            let names: Vec<&str> = generator
                .parts
                .iter()
                .filter_map(|p| p.node_name.as_deref())
                .collect();
            return Err(OptionError::new(
                OptionKey::RelativeTo,
                format!(
                    "$relative_to {reference:?}: the generator has no node of that name (its nodes: {})",
                    names.join(", ")
                ),
            )
            .into());
        }
        _ => {
            return Err(OptionError::new(
                OptionKey::RelativeTo,
                format!(
                    "$relative_to {reference:?}: {} nodes have that name; rename all but one",
                    named.len()
                ),
            )
            .into())
        }
    };
    if !trajectory.has_node_column {
        return Err(InputError::new(
            csv_path,
            "relative motion needs a node column: which rows move the reference, which the parts",
            format!("add a node column and give the rows of {reference:?} and of each part"),
        )
        .into());
    }
    // The reference's rows by time.
    let mut at: BTreeMap<u64, (DMat4, u64)> = BTreeMap::new();
    for p in trajectory
        .poses
        .iter()
        .filter(|p| p.node.as_deref() == Some(reference))
    {
        let Some(t) = p.frame else {
            return Err(InputError::new(
                csv_path,
                "relative motion pairs rows by time, and this file has no frame or time column",
                "add a frame (or time) column: a part's row and the reference's row at one time share its value",
            )
            .at_line(p.line)
            .into());
        };
        if at.insert(time_key(t), (p.matrix, p.line)).is_some() {
            return Err(InputError::new(
                csv_path,
                format!("the reference {reference:?} has two rows at time {t}"),
                "give the reference one row per time",
            )
            .at_line(p.line)
            .into());
        }
    }
    if at.is_empty() {
        return Err(OptionError::new(
            OptionKey::RelativeTo,
            format!(
                "$relative_to {reference:?}: no row of {} moves that node",
                csv_path.display()
            ),
        )
        .into());
    }
    let w_inv = generator.parts[r].world.inverse();
    let mut poses = Vec::new();
    for p in trajectory
        .poses
        .iter()
        .filter(|p| p.node.as_deref() != Some(reference))
    {
        let found = p.frame.and_then(|t| at.get(&time_key(t)));
        let Some((rm, _)) = found else {
            return Err(InputError::new(
                csv_path,
                format!(
                    "node {:?} has a row at time {} where the reference {reference:?} has none",
                    p.node.as_deref().unwrap_or(""),
                    p.frame.map_or("(none)".into(), |t| t.to_string())
                ),
                format!(
                    "give {reference:?} a row at every time a part has one (or remove this row)"
                ),
            )
            .at_line(p.line)
            .into());
        };
        poses.push(Pose {
            matrix: w_inv * rm.inverse() * p.matrix,
            ..p.clone()
        });
    }
    // Parts no row moves stand still in the world: they move in the reference's frame.
    let moved = |name: &str| {
        trajectory
            .poses
            .iter()
            .any(|p| p.node.as_deref() == Some(name))
    };
    let mut parts = Vec::new();
    for (i, part) in generator.parts.iter().enumerate() {
        if i == r {
            continue;
        }
        let name = part.node_name.clone().unwrap_or_default();
        if !moved(&name) {
            if name.is_empty() {
                return Err(InputError::new(
                    csv_path,
                    format!(
                        "node {} has no name, so relative motion cannot give it rows",
                        part.node_index
                    ),
                    "name every node of the generator",
                )
                .into());
            }
            for (&t, (rm, line)) in &at {
                poses.push(Pose {
                    line: *line,
                    frame: Some(f64::from_bits(t)),
                    node: Some(name.clone()),
                    matrix: w_inv * rm.inverse(),
                });
            }
        }
        parts.push(part.clone());
    }
    if parts.is_empty() {
        return Err(OptionError::new(
            OptionKey::RelativeTo,
            format!("$relative_to {reference:?}: the generator has no other part to sweep"),
        )
        .into());
    }
    Ok((
        Generator {
            parts,
            nodes: Vec::new(), // the parts now stand in the reference's frame: no hierarchy
            warnings: generator.warnings.clone(),
        },
        Trajectory {
            poses,
            has_node_column: true,
            rows: crate::input::model::Rows::World,
        },
        generator.parts[r].clone(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DQuat, DVec3, Vec3};

    fn part(name: &str, world: DMat4) -> Part {
        Part {
            node_index: 0,
            node_name: Some(name.into()),
            world,
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            triangles: vec![[0, 1, 2]],
        }
    }

    fn row(line: u64, t: f64, node: &str, m: DMat4) -> Pose {
        Pose {
            line,
            frame: Some(t),
            node: Some(node.into()),
            matrix: m,
        }
    }

    /// A part and a reference moved by the same rows stand still relative to each other: every
    /// rewritten row places the part where it stands in the reference's frame at the start.
    #[test]
    fn parts_moving_with_the_reference_stand_still_in_its_frame() {
        let w_ref = DMat4::from_translation(DVec3::new(0.5, 0.0, 2.0));
        let w_part = DMat4::from_rotation_z(0.3);
        let g = Generator {
            nodes: Vec::new(),
            parts: vec![part("frame", w_ref), part("arm", w_part)],
            warnings: vec![],
        };
        let mut poses = Vec::new();
        for k in 0..6 {
            let m = DMat4::from_rotation_translation(
                DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), k as f64 * 0.4),
                DVec3::new(k as f64, -0.5 * k as f64, 0.2),
            );
            poses.push(row(2 + 2 * k, k as f64, "frame", m));
            poses.push(row(3 + 2 * k, k as f64, "arm", m));
        }
        let t = Trajectory {
            rows: Default::default(),
            poses,
            has_node_column: true,
        };
        let (g2, t2, reference) = apply(&g, &t, Path::new("t.csv"), "frame").unwrap();
        assert_eq!(reference.node_name.as_deref(), Some("frame"));
        assert_eq!(g2.parts.len(), 1);
        let want = w_ref.inverse();
        for p in &t2.poses {
            assert!(p.matrix.abs_diff_eq(want, 1e-12), "{:?}", p.matrix);
        }
    }

    #[test]
    fn missing_references_and_unpaired_times_are_refused_by_name() {
        let g = Generator {
            nodes: Vec::new(),
            parts: vec![part("frame", DMat4::IDENTITY), part("arm", DMat4::IDENTITY)],
            warnings: vec![],
        };
        let t = Trajectory {
            rows: Default::default(),
            poses: vec![
                row(2, 0.0, "frame", DMat4::IDENTITY),
                row(3, 0.0, "arm", DMat4::IDENTITY),
                row(4, 1.0, "arm", DMat4::IDENTITY),
            ],
            has_node_column: true,
        };
        let csv = Path::new("t.csv");
        let e = apply(&g, &t, csv, "base").unwrap_err().to_string();
        assert!(
            e.contains("no node of that name") && e.contains("frame, arm"),
            "{e}"
        );
        let e = apply(&g, &t, csv, "frame").unwrap_err();
        let e = e.downcast::<InputError>().unwrap();
        assert_eq!(e.line, Some(4), "{e}");
        let only_arm = Trajectory {
            rows: Default::default(),
            poses: vec![row(3, 0.0, "arm", DMat4::IDENTITY)],
            has_node_column: true,
        };
        let e = apply(&g, &only_arm, csv, "frame").unwrap_err().to_string();
        assert!(e.contains("no row"), "{e}");
    }
}
