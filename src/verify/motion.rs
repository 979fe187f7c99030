//! The continuous motion between rows, as the verifier sees it: its own polar split, its own
//! screw in the axis-point form and its own path bound, sharing nothing with
//! `input::motion` (the sweep's exponential map) but the motion model of docs/design.md.
//!
//! Each interval of a part's rows becomes m sub-intervals; each is represented by the pose at
//! its middle with a reach r = L/(2m): every instant of the sub-interval puts every point of
//! the part within r of where the middle pose puts it (L bounds every point's path over the
//! interval). Containment then certifies each middle pose with clearance widened by r
//! (`Cluster::spread`), which certifies every instant.

use glam::{DMat3, DMat4, DQuat, DVec3};
use serde::Serialize;

use super::poses::{Between, PartPose};
use crate::error::InputError;
use crate::input::model::Generator;

/// Turns this close to half a revolution are refused, as `run` does (179.9°).
const MAX_TURN: f64 = std::f64::consts::PI - 1.75e-3;
/// At most this many middle poses in all.
const MAX_POSES: u64 = 5_000_000;

/// What the verifier did with the motion.
#[derive(Clone, Debug, Default, Serialize)]
pub struct MotionCheck {
    /// "screw" or "discrete".
    pub model: &'static str,
    /// Intervals between consecutive rows of a part.
    pub intervals: u64,
    /// Poses certified (middle poses of the sub-intervals, or the rows for discrete motion).
    pub poses: u64,
    /// The largest reach of a middle pose (0 for discrete), and the largest path bound of an
    /// interval, world units.
    pub max_reach: f64,
    pub max_path: f64,
}

impl MotionCheck {
    /// Count an interval whose path bound is `path`: the m sub-intervals of reach at most
    /// `reach` it is cut into. Refused: more than MAX_POSES middle poses in all.
    pub(super) fn interval(
        &mut self,
        path: f64,
        reach: f64,
        csv_path: &std::path::Path,
    ) -> Result<u64, InputError> {
        let m = ((path / (2.0 * reach)).ceil() as u64).max(1);
        self.intervals += 1;
        self.max_path = self.max_path.max(path);
        self.max_reach = self.max_reach.max(path / (2.0 * m as f64));
        self.poses += m;
        if self.poses > MAX_POSES {
            return Err(InputError::new(
                csv_path,
                format!("the continuous motion needs more than {MAX_POSES} poses at covering radius {reach:e}"),
                "give a larger --spacing, add rows, or verify with --motion discrete",
            ));
        }
        Ok(m)
    }
}

/// Rigid part G = [R | t] and symmetric stretch S of a pose M = G·S, by the polar
/// decomposition A = R·S computed from the eigen-free iteration X ← (X + X⁻ᵀ)/2.
fn polar(m: &DMat4) -> Option<(DMat3, DVec3, DMat3)> {
    let a = DMat3::from_mat4(*m);
    let det = a.determinant();
    if !(det.is_finite() && det != 0.0) {
        return None;
    }
    let mut x = a;
    for _ in 0..100 {
        let y = (x + x.inverse().transpose()) * 0.5;
        let done = (y - x)
            .to_cols_array()
            .iter()
            .all(|d| d.abs() <= 4.0 * f64::EPSILON);
        x = y;
        if done {
            break;
        }
    }
    let r = if det < 0.0 { -x } else { x };
    let s = r.transpose() * a;
    Some((r, m.w_axis.truncate(), (s + s.transpose()) * 0.5))
}

/// One interval as a screw about an axis: the relative rigid motion turns by `theta` about the
/// unit axis `u` through `c` and slides `d` along it (all in the first pose's rigid frame).
pub(super) struct Screw {
    r0: DMat3,
    t0: DVec3,
    pub(super) s0: DMat3,
    pub(super) s1: DMat3,
    u: DVec3,
    pub(super) theta: f64,
    d: f64,
    /// For a turn: ω × c (stable as θ → 0); for a slide: the whole translation.
    omega_c: DVec3,
    c: DVec3,
}

impl Screw {
    pub(super) fn new(m0: &DMat4, m1: &DMat4) -> Result<Screw, &'static str> {
        let (Some((r0, t0, s0)), Some((r1, t1, s1))) = (polar(m0), polar(m1)) else {
            return Err("a pose is singular");
        };
        if s0.determinant().signum() != s1.determinant().signum() {
            return Err("the part is mirrored in one row and not the other");
        }
        let rr = r0.transpose() * r1;
        let tt = r0.transpose() * (t1 - t0);
        let mut q = DQuat::from_mat3(&rr).normalize();
        if q.w < 0.0 {
            q = -q;
        }
        let v = DVec3::new(q.x, q.y, q.z);
        let theta = 2.0 * v.length().atan2(q.w);
        if theta > MAX_TURN {
            return Err("a turn of 180° or more between two rows");
        }
        let (u, c, omega_c, d) = if theta < 1e-12 {
            let len = tt.length();
            let u = if len > 0.0 { tt / len } else { DVec3::X };
            (u, DVec3::ZERO, DVec3::ZERO, len)
        } else {
            let u = v / v.length();
            let d = u.dot(tt);
            let perp = tt - d * u;
            // Rotation about c takes 0 to perp: c = (perp + cot(θ/2)·u × perp)/2, and
            // ω × c = (θ/2)·u × perp - (θ/2)cot(θ/2)·perp.
            let half = theta / 2.0;
            let cot = half.cos() / half.sin();
            let c = (perp + cot * u.cross(perp)) / 2.0;
            let omega_c = half * u.cross(perp) - half * cot * perp;
            (u, c, omega_c, d)
        };
        Ok(Screw {
            r0,
            t0,
            s0,
            s1,
            u,
            theta,
            d,
            omega_c,
            c,
        })
    }

    /// The pose at s: G₀ · [c + R(sθ)(x - c) + s·d·u] · S(s).
    pub(super) fn at(&self, s: f64) -> DMat4 {
        let stretch = self.stretch(s);
        let (rot, shift) = if self.theta < 1e-12 {
            (DMat3::IDENTITY, self.u * (self.d * s))
        } else {
            let rot = DMat3::from_axis_angle(self.u, s * self.theta);
            (rot, self.c - rot * self.c + self.u * (self.d * s))
        };
        let a = self.r0 * rot * stretch;
        let t = self.t0 + self.r0 * shift;
        DMat4::from_cols(
            a.x_axis.extend(0.0),
            a.y_axis.extend(0.0),
            a.z_axis.extend(0.0),
            t.extend(1.0),
        )
    }

    /// Speed of the rigid screw at a point x of G₀'s frame: θ·u × x - ω × c + d·u (the
    /// helix's speed, the same at every instant for the same distance from the axis).
    pub(super) fn rigid_speed(&self, x: DVec3) -> f64 {
        if self.theta < 1e-12 {
            return self.d;
        }
        (self.theta * self.u.cross(x) - self.omega_c + self.d * self.u).length()
    }

    /// The stretch at s: (1 - s)S₀ + sS₁.
    pub(super) fn stretch(&self, s: f64) -> DMat3 {
        self.s0 * (1.0 - s) + self.s1 * s
    }

    /// Bound on the path length of local point p over the interval: the rigid speed at S₀p or
    /// S₁p (it is convex along the stretch's straight line) plus the stretch's own motion.
    fn path(&self, p: DVec3) -> f64 {
        self.rigid_speed(self.s0 * p)
            .max(self.rigid_speed(self.s1 * p))
            + ((self.s1 - self.s0) * p).length()
    }
}

/// Replace each part's consecutive rows by the middle poses of sub-intervals whose reach is at
/// most `reach`. A part with one pose keeps it. Errors name the later row's CSV line.
pub fn continuous(
    generator: &Generator,
    assigned: Vec<Vec<PartPose>>,
    reach: f64,
    csv_path: &std::path::Path,
) -> Result<(Vec<Vec<PartPose>>, MotionCheck), InputError> {
    let mut check = MotionCheck {
        model: "screw",
        ..Default::default()
    };
    let mut out = Vec::with_capacity(assigned.len());
    for (part, poses) in generator.parts.iter().zip(assigned) {
        if poses.len() < 2 {
            check.poses += poses.len() as u64;
            out.push(poses);
            continue;
        }
        let mut expanded = Vec::new();
        for pair in poses.windows(2) {
            let (a, b) = (&pair[0], &pair[1]);
            let screw = Screw::new(&a.matrix, &b.matrix).map_err(|why| {
                InputError::new(
                    csv_path,
                    format!(
                        "the motion between lines {} and {} cannot be followed: {why}",
                        a.line.unwrap_or(0),
                        b.line.unwrap_or(0)
                    ),
                    "add a row between them, or verify with --motion discrete",
                )
                .at_line(b.line.unwrap_or(0))
            })?;
            let path = part
                .positions
                .iter()
                .map(|p| screw.path(p.as_dvec3()))
                .fold(0.0, f64::max);
            // The f64 evaluation's error, as a distance (generous: 2¹⁰ ulps of the largest
            // coordinate the interval reaches).
            let far = a
                .matrix
                .w_axis
                .truncate()
                .abs()
                .max(b.matrix.w_axis.truncate().abs())
                .max_element()
                + path
                + part
                    .positions
                    .iter()
                    .map(|p| p.as_dvec3().length())
                    .fold(0.0, f64::max)
                    * a.sigma_max.max(b.sigma_max);
            let path = path + 1024.0 * f64::EPSILON * far;
            let m = check.interval(path, reach, csv_path)?;
            for j in 0..m {
                let s = (j as f64 + 0.5) / m as f64;
                let mut pose = PartPose::new(screw.at(s), a.row, a.line);
                pose.reach = path / (2.0 * m as f64);
                pose.between = Some(Between {
                    to_row: b.row.unwrap_or(0),
                    to_line: b.line.unwrap_or(0),
                    s,
                });
                expanded.push(pose);
            }
        }
        out.push(expanded);
    }
    Ok((out, check))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The axis-point screw meets both rows and bounds the paths it makes.
    #[test]
    fn the_screw_meets_both_rows_and_bounds_every_path() {
        let mut rng = fastrand::Rng::with_seed(23);
        let mut r = || rng.f64() * 2.0 - 1.0;
        for _ in 0..200 {
            let m0 = DMat4::from_rotation_translation(
                DQuat::from_axis_angle(DVec3::new(r(), r(), r() + 2.0).normalize(), r() * 3.0),
                DVec3::new(r(), r(), r()) * 50.0,
            ) * DMat4::from_scale(DVec3::new(1.0 + 0.3 * r(), 1.0, 1.0));
            let m1 = DMat4::from_rotation_translation(
                DQuat::from_axis_angle(DVec3::new(r() + 2.0, r(), r()).normalize(), r() * 3.0),
                DVec3::new(r(), r(), r()) * 50.0,
            ) * DMat4::from_scale(DVec3::new(1.0, 1.0 + 0.3 * r(), 1.0));
            let Ok(screw) = Screw::new(&m0, &m1) else {
                continue;
            };
            let close = |a: DMat4, b: DMat4| {
                a.to_cols_array()
                    .iter()
                    .zip(b.to_cols_array())
                    .all(|(x, y)| (x - y).abs() < 1e-9)
            };
            assert!(close(screw.at(0.0), m0) && close(screw.at(1.0), m1));
            let p = DVec3::new(r(), r(), r()) * 4.0;
            let (mut len, mut prev) = (0.0, m0.transform_point3(p));
            for j in 1..=1000 {
                let q = screw.at(j as f64 / 1000.0).transform_point3(p);
                len += (q - prev).length();
                prev = q;
            }
            assert!(
                len <= screw.path(p) * (1.0 + 1e-9),
                "{len} > {}",
                screw.path(p)
            );
        }
    }
}
