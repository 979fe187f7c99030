//! Continuous motion between trajectory rows (docs/design.md, "Continuous motion").
//!
//! Between two consecutive rows of one part the part moves by the constant-velocity screw
//! motion from the one pose to the next: with each pose split as M = G·S (G rigid, S the
//! symmetric stretch of its polar decomposition), M(s) = G₀·exp(s·log(G₀⁻¹G₁))·((1-s)S₀ + sS₁)
//! for s in [0, 1]. A bound L on how far any point of the part travels along an interval
//! (derived below, never sampled) sets the sub-poses the sweep renders: k equal steps of s
//! leave every point of the motion within L/(2k) ≤ μ of a rendered sub-pose, and the sweep
//! renders δ + μ around each, so the δ-offset of the continuous motion is covered.
//!
//! Units: world units and radians; matrices map a part's local frame to the world.

use std::collections::HashMap;
use std::path::Path;

use glam::{DMat3, DMat4, DQuat, DVec3};
use serde::{Deserialize, Serialize};

use crate::error::{num, InputError, OptionError, OptionKey};
use crate::input::model::PartPoses;
use crate::input::model::{Generator, Trajectory};

/// What moves the part between the rows of its trajectory.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Motion {
    /// The screw motion from each row to the next (the default): the whole motion is covered.
    #[default]
    Screw,
    /// Only the listed poses (the paper's method): the motion between rows is not covered.
    Discrete,
}

impl Motion {
    pub fn name(self) -> &'static str {
        match self {
            Motion::Screw => "screw",
            Motion::Discrete => "discrete",
        }
    }
}

/// The budget μ of the sub-pose spacing, voxels: the stated bound grows by this much.
pub const MU_VOXELS: f64 = 0.25;
/// A relative rotation this close to a half turn (radians) between two rows is refused: which
/// way the part turned is not determined by the two poses.
const MAX_TURN: f64 = std::f64::consts::PI - 1.75e-3; // 179.9°
/// Poses (rows and sub-poses) in all at most. Not a memory limit: the sweep makes sub-poses on
/// the fly, a batch at a time (`input::poses`). It is the range of the sweep's pose indices (u32
/// in `PartRange` and the GPU's parameters); long before it the sweep's time is the limit (each
/// pose renders every triangle of its part), which the reported posed-triangle count states.
const MAX_POSES: u64 = u32::MAX as u64;
/// Relative accuracy of the f64 screw evaluation: a generous multiple of f64's unit roundoff
/// times the few dozen operations of `Interval::at` (exp map, two products). The path bound
/// budgets this error times the largest coordinate, so sub-poses stay within μ.
const F64_EVAL_REL: f64 = 1024.0 * f64::EPSILON;

/// A pose split as M = G·S: G = [R | t] rigid (det R = +1), S symmetric (det S < 0 for a
/// mirrored part).
#[derive(Clone, Copy, Debug)]
struct Split {
    r: DMat3,
    t: DVec3,
    s: DMat3,
}

/// Polar decomposition of the linear part of `m` (Higham's iteration X ← (X + X⁻ᵀ)/2, which
/// converges quadratically to the orthogonal factor). None for a singular matrix.
fn split(m: &DMat4) -> Option<Split> {
    let a = DMat3::from_mat4(*m);
    let det = a.determinant();
    if !(det.is_finite() && det != 0.0) {
        return None;
    }
    let mut x = a;
    for _ in 0..100 {
        let next = (x + x.inverse().transpose()) * 0.5;
        let change = (next - x)
            .to_cols_array()
            .iter()
            .map(|v| v.abs())
            .fold(0.0, f64::max);
        x = next;
        if change <= 4.0 * f64::EPSILON {
            break;
        }
    }
    // x is orthogonal with det ±1; a mirror moves into the stretch so that r is a rotation.
    let (r, s) = if det < 0.0 {
        (-x, -(x.transpose() * a))
    } else {
        (x, x.transpose() * a)
    };
    // Symmetric up to rounding: keep it exactly symmetric.
    let s = (s + s.transpose()) * 0.5;
    Some(Split {
        r,
        t: m.w_axis.truncate(),
        s,
    })
}

fn cross_matrix(w: DVec3) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(0.0, w.z, -w.y),
        DVec3::new(-w.z, 0.0, w.x),
        DVec3::new(w.y, -w.x, 0.0),
    )
}

/// V(ω) = I + (1-cos θ)/θ²·[ω]× + (θ-sin θ)/θ³·[ω]×² (θ = |ω|), the map from a twist's v to
/// the translation of its exponential; series near θ = 0.
fn v_matrix(w: DVec3) -> DMat3 {
    let th2 = w.length_squared();
    let th = th2.sqrt();
    let (b, c) = if th < 1e-4 {
        (0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0)
    } else {
        ((1.0 - th.cos()) / th2, (th - th.sin()) / (th2 * th))
    };
    let k = cross_matrix(w);
    DMat3::IDENTITY + k * b + k * k * c
}

/// V(ω)⁻¹ = I - ½[ω]× + (1 - θ sin θ/(2(1-cos θ)))/θ²·[ω]×².
fn v_inverse(w: DVec3) -> DMat3 {
    let th2 = w.length_squared();
    let th = th2.sqrt();
    let e = if th < 1e-4 {
        1.0 / 12.0 + th2 / 720.0
    } else {
        (1.0 - th * th.sin() / (2.0 * (1.0 - th.cos()))) / th2
    };
    let k = cross_matrix(w);
    DMat3::IDENTITY - k * 0.5 + k * k * e
}

/// The screw motion of one pose into the next: M(s) = G₀·exp(s·ξ)·((1-s)S₀ + sS₁), with
/// ξ = log(G₀⁻¹G₁) the relative rigid motion as a twist (rotation vector ω in radians, v).
#[derive(Clone, Debug)]
pub(crate) struct Screw {
    from: Split,
    s1: DMat3,
    omega: DVec3,
    v: DVec3,
    /// Rotation angle, radians, in [0, MAX_TURN].
    turn: f64,
}

/// Why two poses have no screw between them.
#[derive(Clone, Copy, Debug)]
pub(crate) enum NoScrew {
    Singular,
    MirrorFlips,
    /// The turn, radians: half a revolution or nearly.
    HalfTurn(f64),
}

impl Screw {
    pub(crate) fn between(m0: &DMat4, m1: &DMat4) -> Result<Screw, NoScrew> {
        let (Some(a), Some(b)) = (split(m0), split(m1)) else {
            return Err(NoScrew::Singular);
        };
        if a.s.determinant().signum() != b.s.determinant().signum() {
            return Err(NoScrew::MirrorFlips);
        }
        let rel_r = a.r.transpose() * b.r;
        let rel_t = a.r.transpose() * (b.t - a.t);
        let mut q = DQuat::from_mat3(&rel_r).normalize();
        if q.w < 0.0 {
            q = -q;
        }
        let xyz = DVec3::new(q.x, q.y, q.z);
        let turn = 2.0 * xyz.length().atan2(q.w);
        if turn > MAX_TURN {
            return Err(NoScrew::HalfTurn(turn));
        }
        let omega = if turn > 0.0 {
            xyz.normalize() * turn
        } else {
            DVec3::ZERO
        };
        Ok(Screw {
            from: a,
            s1: b.s,
            omega,
            v: v_inverse(omega) * rel_t,
            turn,
        })
    }

    /// The pose at s in [0, 1].
    pub(crate) fn at(&self, s: f64) -> DMat4 {
        let w = self.omega * s;
        let rot = DMat3::from_quat(DQuat::from_scaled_axis(w));
        let g_r = self.from.r * rot;
        let g_t = self.from.t + self.from.r * (v_matrix(w) * (self.v * s));
        let a = g_r * self.stretch(s);
        DMat4::from_cols(
            a.x_axis.extend(0.0),
            a.y_axis.extend(0.0),
            a.z_axis.extend(0.0),
            g_t.extend(1.0),
        )
    }

    /// The symmetric stretch at s: (1-s)S₀ + sS₁.
    fn stretch(&self, s: f64) -> DMat3 {
        self.from.s * (1.0 - s) + self.s1 * s
    }

    pub(crate) fn turn(&self) -> f64 {
        self.turn
    }

    /// Bound on the speed (d/ds) of the point M(s)·q(s) over s in [a, b], for a point q(s)
    /// of the moved frame that starts at `q0` and moves at speed at most `inner` (world units
    /// per unit of the sub-interval's parameter σ = (s - a)/(b - a)), per unit of σ. In G(a)'s
    /// frame (rigid, so lengths are the world's) the velocity is Δ·(ω × y + v) + R(s)·Δ·(S₁ -
    /// S₀)q + M(s)'s linear part · q' with y = exp(sξ)·S(s)q, Δ = b - a; the twist's own flow
    /// keeps |ω × y + v| = |ω × S(s)q + v|, convex in s (largest at a or b); |q(σ) - q0| ≤
    /// `inner`; ‖S(s)‖ ≤ max(‖S(a)‖, ‖S(b)‖) by convexity of the norm. So the speed is at most
    /// Δ·max_e |ω × S(e)q0 + v| + Δ·|(S₁-S₀)q0| + (Δ·|ω|·σ_S + Δ·‖S₁-S₀‖ + σ_S)·inner, convex
    /// in q0 (so the largest over a part is at a vertex of its outline).
    pub(crate) fn speed(&self, (a, b): (f64, f64), q0: DVec3, inner: f64) -> f64 {
        let d = b - a;
        let (sa, sb) = (self.stretch(a), self.stretch(b));
        let ds = self.s1 - self.from.s;
        let sigma = sym_norm(&sa).max(sym_norm(&sb));
        let twist = (self.omega.cross(sa * q0) + self.v)
            .length()
            .max((self.omega.cross(sb * q0) + self.v).length());
        d * (twist + (ds * q0).length())
            + (d * self.omega.length() * sigma + d * sym_norm(&ds) + sigma) * inner
    }

    /// Bound on the acceleration (d²/dσ²) of the posed point M(s)·q(σ) over s in [a, b], where
    /// q starts at `q0` and moves at speed at most `inner` and acceleration at most `inner_acc`.
    /// In G(a)'s frame y = E(σ)·u with E = exp(σΔξ) rigid and u = S(σ)q the stretched point
    /// (S(σ) = S(a) + σ·Δ(S₁ - S₀)): y'' = Δξ applied twice to E·u, plus 2Δω × R_E·u', plus
    /// R_E·u''. The first is at most θ·(the helix speed at u), θ = Δ|ω|, which moves by at
    /// most θ·|u - u(0)|; |u'| ≤ |ΔS q| + σ_S|q'| =: U₁ (ΔS = Δ(S₁ - S₀), |ΔS q| ≤ |ΔS q0| +
    /// ‖ΔS‖·inner); |u''| ≤ 2‖ΔS‖·inner + σ_S·inner_acc. So the acceleration is at most
    /// θ·(helix(S(a)q0) + θ·U₁) + 2θ·U₁ + 2‖ΔS‖·inner + σ_S·inner_acc, convex in q0.
    pub(crate) fn acceleration(
        &self,
        (a, b): (f64, f64),
        q0: DVec3,
        inner: f64,
        inner_acc: f64,
    ) -> f64 {
        let d = b - a;
        let (sa, sb) = (self.stretch(a), self.stretch(b));
        let ds = (self.s1 - self.from.s) * d;
        let (sigma, ds_norm) = (sym_norm(&sa).max(sym_norm(&sb)), sym_norm(&ds));
        let theta = d * self.omega.length();
        let helix = d * (self.omega.cross(sa * q0) + self.v).length();
        let u1 = (ds * q0).length() + (ds_norm + sigma) * inner;
        theta * (helix + theta * u1) + 2.0 * theta * u1 + 2.0 * ds_norm * inner + sigma * inner_acc
    }
}

/// An upper bound of the spectral norm of a symmetric matrix: its largest absolute row sum
/// (every induced norm bounds the spectral radius, which is the spectral norm when symmetric).
fn sym_norm(s: &DMat3) -> f64 {
    let t = s.transpose();
    [t.x_axis, t.y_axis, t.z_axis]
        .iter()
        .map(|r| r.abs().element_sum())
        .fold(0.0, f64::max)
}

/// An upper bound of the spectral norm of any 3x3 matrix: √‖AᵀA‖ (AᵀA is symmetric, and its
/// spectral norm is the square of A's): 1 for a rotation, up to rounding.
pub(crate) fn norm_bound(a: &DMat3) -> f64 {
    sym_norm(&(a.transpose() * *a)).sqrt()
}

/// How an interval's pose is made. (The screw is kept inline: world rows have one interval per
/// row pair and no other allocation; a chain's factors are on the heap anyway.)
#[derive(Clone, Debug)]
#[allow(clippy::large_enum_variant)]
pub(crate) enum Kind {
    /// The screw from one world pose to the next.
    Single(Screw),
    /// A kinematic chain (`input::chain`): the product, root first, of each node's local
    /// transform at the interval's parameter.
    Chain(Vec<Factor>),
}

/// One node of a chain over an interval: its local transform held, or moving along part
/// [a, b] of the screw between two of its rows.
#[derive(Clone, Debug)]
pub(crate) enum Factor {
    Fixed(DMat4),
    Moving { screw: Screw, span: (f64, f64) },
}

impl Factor {
    pub(crate) fn at(&self, sigma: f64) -> DMat4 {
        match self {
            Factor::Fixed(m) => *m,
            Factor::Moving { screw, span } => screw.at(span.0 + sigma * (span.1 - span.0)),
        }
    }
}

/// One interval of a part's motion: from `from` at s = 0 to the next row's pose at s = 1.
#[derive(Clone, Debug)]
pub struct Interval {
    /// The part (index into the generator's parts).
    pub part: usize,
    /// CSV lines of the two rows.
    pub lines: (u64, u64),
    pub(crate) kind: Kind,
    /// Bound on the path length of every point of the part over the interval, world units.
    pub path: f64,
    /// Rotation angle of the interval, radians (for a chain: the sum of its nodes' turns).
    pub turn: f64,
}

impl Interval {
    /// The pose at s in [0, 1].
    pub fn at(&self, s: f64) -> DMat4 {
        match &self.kind {
            Kind::Single(screw) => screw.at(s),
            Kind::Chain(factors) => factors.iter().fold(DMat4::IDENTITY, |acc, f| acc * f.at(s)),
        }
    }

    /// Equal steps of s that leave every point of the motion within `mu` of a sub-pose.
    pub fn steps(&self, mu: f64) -> u64 {
        ((self.path / (2.0 * mu)).ceil() as u64).max(1)
    }
}

/// The intervals of every part's rows, in the rows' order. Refused: rows of one part out of
/// time order, a turn of nearly half a revolution or more between two rows, a mirror that
/// flips between two rows.
pub fn intervals(
    generator: &Generator,
    trajectory: &Trajectory,
    csv_path: &Path,
    assigned: &[PartPoses],
) -> Result<Vec<Interval>, InputError> {
    check_time_order(trajectory, csv_path)?;
    let mut out = Vec::new();
    for (part, poses, _) in assigned {
        let positions = &generator.parts[*part].positions;
        for pair in poses.windows(2) {
            let ((m0, l0), (m1, l1)) = (pair[0], pair[1]);
            let (l0, l1) = (l0.unwrap_or(0), l1.unwrap_or(0));
            let name = part_name(generator, *part);
            let screw =
                Screw::between(&m0, &m1).map_err(|why| refusal(why, &name, csv_path, (l0, l1)))?;
            // Path length of point p (local frame) over s in [0, 1]: `Screw::speed` of a
            // point fixed in the part; convex in p, so the largest over the part is at a vertex.
            let mut path: f64 = 0.0;
            let mut reach: f64 = 0.0;
            for p in positions {
                let p = p.as_dvec3();
                path = path.max(screw.speed((0.0, 1.0), p, 0.0));
                reach = reach.max((m0.transform_point3(p)).abs().max_element());
                reach = reach.max((m1.transform_point3(p)).abs().max_element());
            }
            // The f64 evaluation's own error, as a distance every point may be off by.
            path += 2.0 * F64_EVAL_REL * (reach + path);
            out.push(Interval {
                part: *part,
                lines: (l0, l1),
                turn: screw.turn,
                kind: Kind::Single(screw),
                path,
            });
        }
    }
    Ok(out)
}

/// The error for two rows, at CSV lines `lines`, of `name` (a node, as the message says it)
/// with no screw between them.
pub(crate) fn refusal(
    why: NoScrew,
    name: &str,
    csv_path: &Path,
    (l0, l1): (u64, u64),
) -> InputError {
    let (message, fix) = match why {
        NoScrew::Singular => (
            format!("the pose of {name} at line {l0} or {l1} is singular"),
            "give every row an invertible transform",
        ),
        NoScrew::MirrorFlips => (
            format!("{name} is mirrored at line {l0} but not at line {l1} (or the other way): no rigid motion turns one into the other"),
            "mirror the part in every row or in none, or set $motion to discrete",
        ),
        NoScrew::HalfTurn(turn) => (
            format!(
                "{name} turns by {:.2}° between lines {l0} and {l1}: a turn of 180° or more between two rows has no single shortest motion",
                turn.to_degrees()
            ),
            "add a row between them (a pose half way), or set $motion to discrete to sweep only the listed poses",
        ),
    };
    InputError::new(csv_path, message, fix)
        .at_line(l1)
        .in_column("node")
}

/// The f64 evaluation error of a pose made of `factors` products, as a distance any point of
/// a part within `reach` of the origin may be off by, on a path of length `path`.
pub(crate) fn eval_error(factors: usize, reach: f64, path: f64) -> f64 {
    2.0 * F64_EVAL_REL * factors.max(1) as f64 * (reach + path)
}

fn part_name(generator: &Generator, part: usize) -> String {
    let p = &generator.parts[part];
    match &p.node_name {
        Some(n) => format!("node {n:?}"),
        None => format!("node {}", p.node_index),
    }
}

/// Rows of one part (one `node`, or the whole scene) must come in time order when the file has
/// a `frame` or `time` column: the motion runs from each row to the next.
fn check_time_order(trajectory: &Trajectory, csv_path: &Path) -> Result<(), InputError> {
    let mut last: HashMap<Option<&str>, (f64, u64)> = HashMap::new();
    for pose in &trajectory.poses {
        let Some(frame) = pose.frame else { continue };
        let key = pose.node.as_deref();
        if let Some(&(before, line)) = last.get(&key) {
            if frame < before {
                let whose = key.map_or("the scene".to_string(), |n| format!("node {n:?}"));
                return Err(InputError::new(
                    csv_path,
                    format!("the rows of {whose} go back in time: frame {} after frame {} (line {line})", num(frame), num(before)),
                    "sort the rows of each node by frame or time: the motion runs from each row to the next",
                )
                .at_line(pose.line));
            }
        }
        last.insert(key, (frame, pose.line));
    }
    Ok(())
}

/// The box of the whole continuous motion: each interval sampled at k₀ equal steps, each
/// sample's box widened by L/(2k₀), where every point of the motion lies (see [`Interval`]).
/// k₀ keeps that widening under 1% of `extent` (the listed poses' box), up to 4096 steps.
pub fn motion_box(generator: &Generator, intervals: &[Interval], extent: f64) -> (DVec3, DVec3) {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for iv in intervals {
        let k0 = ((iv.path / (0.01 * extent.max(f64::MIN_POSITIVE))).ceil() as u64).clamp(1, 4096);
        let pad = DVec3::splat(iv.path / (2.0 * k0 as f64));
        let positions = &generator.parts[iv.part].positions;
        for j in 0..=k0 {
            let m = iv.at(j as f64 / k0 as f64);
            for p in positions {
                let q = m.transform_point3(p.as_dvec3());
                lo = lo.min(q - pad);
                hi = hi.max(q + pad);
            }
        }
    }
    (lo, hi)
}

/// What the report says of the motion.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct MotionReport {
    /// "screw" or "discrete".
    pub model: String,
    /// Budget of the sub-pose spacing: every point of the motion is within μ of a rendered
    /// sub-pose, world units (0 for discrete motion).
    pub mu: f64,
    /// Poses rendered in all (listed rows and sub-poses between them).
    pub poses_rendered: u64,
    /// Intervals between consecutive rows of a part.
    pub intervals: u64,
    /// The largest path bound L of any interval, world units, and its rotation in degrees.
    pub max_path: f64,
    pub max_turn_degrees: f64,
    /// The most steps one interval needed, and where: the part and the two rows' CSV lines.
    pub max_steps: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_steps_at: Option<MotionPlace>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MotionPlace {
    pub part: String,
    pub lines: [u64; 2],
}

/// The steps k of every interval, in order, that leave every point of the motion within `mu`
/// of a sub-pose (k - 1 sub-poses between its rows), and the report of the poses they make:
/// each part's rows with the sub-poses of its intervals in between. Nothing is evaluated here;
/// `input::poses` makes the poses when the sweep asks for them. Refused: more poses in all
/// than the sweep can index.
pub fn sub_pose_steps(
    generator: &Generator,
    assigned: &[PartPoses],
    intervals: &[Interval],
    mu: f64,
) -> Result<(Vec<u64>, MotionReport), OptionError> {
    let mut report = MotionReport {
        model: Motion::Screw.name().into(),
        mu,
        intervals: intervals.len() as u64,
        ..Default::default()
    };
    let steps: Vec<u64> = intervals.iter().map(|iv| iv.steps(mu)).collect();
    let mut next = intervals.iter().zip(&steps).peekable();
    for (part, poses, _) in assigned {
        // The part's rows, and k - 1 sub-poses for each interval between two of them.
        let mut count = poses.len() as u64;
        for _ in 1..poses.len() {
            let (iv, &k) = next.next().expect("one interval per consecutive pair");
            debug_assert_eq!(iv.part, *part);
            count = count.saturating_add(k - 1);
            if k > report.max_steps {
                report.max_steps = k;
                report.max_steps_at = Some(MotionPlace {
                    part: part_name(generator, iv.part),
                    lines: [iv.lines.0, iv.lines.1],
                });
            }
            if iv.path > report.max_path {
                report.max_path = iv.path;
                report.max_turn_degrees = iv.turn.to_degrees();
            }
        }
        report.poses_rendered = report.poses_rendered.saturating_add(count);
    }
    debug_assert!(next.peek().is_none(), "every interval belongs to a part");
    if report.poses_rendered > MAX_POSES {
        return Err(OptionError::new(
            OptionKey::Resolution,
            format!("the continuous motion needs {} poses at this voxel size, more than the sweep can count ({MAX_POSES}; each renders every triangle of its part); use a coarser $resolution or a larger $tolerance, add rows to the trajectory, or sweep only the listed poses ($motion discrete)", report.poses_rendered),
        ));
    }
    Ok((steps, report))
}

/// The report of a discrete sweep of `poses` poses.
pub fn discrete_report(poses: u64) -> MotionReport {
    MotionReport {
        model: Motion::Discrete.name().into(),
        poses_rendered: poses,
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rigid(axis: DVec3, angle: f64, t: DVec3) -> DMat4 {
        DMat4::from_rotation_translation(DQuat::from_axis_angle(axis.normalize(), angle), t)
    }

    fn part(points: &[DVec3]) -> Generator {
        Generator {
            nodes: Vec::new(),
            parts: vec![crate::input::model::Part {
                node_index: 0,
                node_name: Some("p".into()),
                world: DMat4::IDENTITY,
                positions: points.iter().map(|p| p.as_vec3()).collect(),
                triangles: vec![[0, 1, 2]],
            }],
            warnings: vec![],
        }
    }

    fn try_interval(m0: DMat4, m1: DMat4, points: &[DVec3]) -> Result<Interval, InputError> {
        let traj = Trajectory {
            rows: Default::default(),
            poses: vec![],
            has_node_column: false,
        };
        let assigned = vec![(0, vec![(m0, Some(2)), (m1, Some(3))], false)];
        Ok(intervals(&part(points), &traj, Path::new("t.csv"), &assigned)?.remove(0))
    }

    fn interval(m0: DMat4, m1: DMat4, points: &[DVec3]) -> Interval {
        try_interval(m0, m1, points).unwrap()
    }

    fn close(a: DMat4, b: DMat4, tol: f64) -> bool {
        a.to_cols_array()
            .iter()
            .zip(b.to_cols_array())
            .all(|(x, y)| (x - y).abs() <= tol)
    }

    #[test]
    fn the_screw_meets_both_poses_and_turns_about_its_own_axis() {
        let pts = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let far = DVec3::new(1e3, -2e3, 5e2);
        let m0 = rigid(DVec3::new(1.0, 2.0, 3.0), 0.4, far);
        let m1 = m0 * rigid(DVec3::Z, 2.9, DVec3::new(0.0, 0.0, 0.5)); // 166° about the part's own z
        let iv = interval(m0, m1, &pts);
        assert!(close(iv.at(0.0), m0, 1e-9) && close(iv.at(1.0), m1, 1e-9));
        // Half way: half the turn about the same axis through the part's origin, half the rise.
        let half = m0 * rigid(DVec3::Z, 1.45, DVec3::new(0.0, 0.0, 0.25));
        assert!(close(iv.at(0.5), half, 1e-9), "{:?}", iv.at(0.5));
        assert!((iv.turn - 2.9).abs() < 1e-12);
    }

    /// The path bound is at least the length of every vertex's path, summed over fine steps,
    /// on random motions with stretch; and it is tight for a pure rotation.
    #[test]
    fn the_path_bound_covers_every_vertex_path() {
        let mut rng = fastrand::Rng::with_seed(17);
        let mut r = || rng.f64() * 2.0 - 1.0;
        for case in 0..300 {
            let pts: Vec<DVec3> = (0..4).map(|_| DVec3::new(r(), r(), r()) * 3.0).collect();
            let axis = DVec3::new(r(), r(), r()) + DVec3::splat(1e-3);
            let m0 = rigid(axis, r() * 3.0, DVec3::new(r(), r(), r()) * 10.0)
                * DMat4::from_scale(DVec3::new(1.0 + r() * 0.5, 1.0, 1.0 + r() * 0.3));
            let m1 = rigid(
                DVec3::new(r(), r(), r()),
                r() * 3.0,
                DVec3::new(r(), r(), r()) * 10.0,
            ) * DMat4::from_scale(DVec3::new(1.0, 1.0 + r() * 0.5, 1.0));
            let Ok(iv) = try_interval(m0, m1, &pts) else {
                continue; // a near half turn, refused
            };
            let steps = 2000;
            for p in &pts {
                let mut len = 0.0;
                let mut prev = iv.at(0.0).transform_point3(*p);
                for j in 1..=steps {
                    let q = iv.at(j as f64 / steps as f64).transform_point3(*p);
                    len += (q - prev).length();
                    prev = q;
                }
                assert!(
                    len <= iv.path * (1.0 + 1e-9),
                    "case {case}: {len} > {}",
                    iv.path
                );
            }
        }
        let pts = [DVec3::new(2.0, 0.0, 0.0), DVec3::ZERO, DVec3::Y];
        let iv = interval(DMat4::IDENTITY, rigid(DVec3::Z, 1.5, DVec3::ZERO), &pts);
        assert!((iv.path - 3.0).abs() < 1e-9, "{}", iv.path);
    }

    #[test]
    fn polar_split_rebuilds_the_pose_and_keeps_mirrors_in_the_stretch() {
        let m = rigid(DVec3::new(0.3, 1.0, -0.2), 1.1, DVec3::new(4.0, 5.0, 6.0))
            * DMat4::from_cols_array(&[
                2.0, 0.3, 0.0, 0.0, 0.3, 1.0, 0.1, 0.0, 0.0, 0.1, -0.5, 0.0, 0.0, 0.0, 0.0, 1.0,
            ]);
        let sp = split(&m).unwrap();
        assert!((sp.r.determinant() - 1.0).abs() < 1e-12);
        assert!(sp.s.determinant() < 0.0);
        let a = sp.r * sp.s;
        assert!((a - DMat3::from_mat4(m))
            .to_cols_array()
            .iter()
            .all(|x| x.abs() < 1e-12));
        assert!((sp.r.transpose() * sp.r - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .all(|x| x.abs() < 1e-12));
    }

    #[test]
    fn a_half_turn_and_a_mirror_flip_are_refused_by_line() {
        let pts = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let run = |m1: DMat4| try_interval(DMat4::IDENTITY, m1, &pts);
        let e = run(rigid(DVec3::Y, std::f64::consts::PI, DVec3::ZERO)).unwrap_err();
        assert_eq!(e.line, Some(3));
        assert!(
            e.message.contains("180") && e.fix.contains("add a row"),
            "{e}"
        );
        assert!(run(rigid(DVec3::Y, 179.0f64.to_radians(), DVec3::ZERO)).is_ok());
        let e = run(DMat4::from_scale(DVec3::new(-1.0, 1.0, 1.0))).unwrap_err();
        assert!(e.message.contains("mirrored"), "{e}");
    }

    #[test]
    fn sub_poses_keep_the_rows_and_space_the_path_within_mu() {
        let pts = [DVec3::new(1.0, 0.0, 0.0), DVec3::ZERO, DVec3::Y];
        let iv = interval(
            DMat4::IDENTITY,
            rigid(DVec3::Z, 1.0, DVec3::new(0.0, 0.0, 2.0)),
            &pts,
        );
        let mu = 0.05;
        let k = iv.steps(mu);
        assert!(iv.path / (2.0 * k as f64) <= mu && iv.path / (2.0 * (k - 1) as f64) > mu);
    }
}
