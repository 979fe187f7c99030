//! Rows in parent space as the verifier reads them, sharing nothing with `input::chain` but the
//! rule of docs/design.md ("Articulated motion"): a part's world pose is the product, root
//! first, of its chain's local transforms; a node with rows moves by the screw between two of
//! its rows in its parent's frame (the verifier's own axis-point screw, `verify::motion`),
//! holds its first row before them and its last after; rows of different nodes pair by time.
//!
//! The motion between two consecutive times of a part's chain is covered as in
//! `verify::motion`: middle poses of m sub-intervals, each with a reach L/(2m), where L bounds
//! every point's speed. L is built from the part's own node up to the root: a node's screw
//! moves a point at its rigid helix speed at the stretched point plus the stretch's own
//! motion, and carries the speed of the point within its frame through its linear map (at most
//! its largest singular value, bounded through the Gram matrix).

use std::collections::HashMap;
use std::path::Path;

use glam::{DMat3, DMat4, DVec3};

use super::motion::{MotionCheck, Screw};
use super::poses::{Between, PartPose};
use crate::error::InputError;
use crate::input::model::{Generator, Trajectory};

/// A node's rows: times, local matrices, CSV lines and row indices, in time order.
struct Track {
    times: Vec<f64>,
    rows: Vec<DMat4>,
    lines: Vec<u64>,
    index: Vec<u32>,
}

/// The hierarchy (positions into `generator.nodes`) and every node's rows.
pub struct Rig<'a> {
    generator: &'a Generator,
    parent: Vec<Option<usize>>,
    tracks: HashMap<usize, Track>,
    csv_path: &'a Path,
}

fn refuse(csv_path: &Path, line: u64, message: String, fix: &str) -> InputError {
    InputError::new(csv_path, message, fix).at_line(line)
}

impl<'a> Rig<'a> {
    /// Read the rows of `trajectory` as local transforms of the nodes they name.
    pub fn new(
        generator: &'a Generator,
        trajectory: &Trajectory,
        csv_path: &'a Path,
    ) -> Result<Rig<'a>, InputError> {
        let nodes = &generator.nodes;
        let position: HashMap<usize, usize> = nodes
            .iter()
            .enumerate()
            .map(|(i, n)| (n.index, i))
            .collect();
        let parent = nodes
            .iter()
            .map(|n| n.parent.and_then(|p| position.get(&p).copied()))
            .collect();
        let mut tracks: HashMap<usize, Track> = HashMap::new();
        for (row, pose) in trajectory.poses.iter().enumerate() {
            let name = pose.node.as_deref().unwrap_or_default();
            let found: Vec<usize> = (0..nodes.len())
                .filter(|&i| nodes[i].name.as_deref() == Some(name))
                .collect();
            let [node] = found[..] else {
                return Err(refuse(
                    csv_path,
                    pose.line,
                    format!(
                        "the row names node {name:?}, which {} nodes of the hierarchy carry",
                        found.len()
                    ),
                    "name exactly one node of the generator in each row",
                ));
            };
            let track = tracks.entry(node).or_insert(Track {
                times: vec![],
                rows: vec![],
                lines: vec![],
                index: vec![],
            });
            let t = pose.frame.unwrap_or(track.times.len() as f64);
            if track.times.last().is_some_and(|&last| t <= last) {
                return Err(refuse(
                    csv_path,
                    pose.line,
                    format!("the rows of node {name:?} are not in strictly increasing time"),
                    "give each node one row per time, sorted by time",
                ));
            }
            track.times.push(t);
            track.rows.push(pose.matrix);
            track.lines.push(pose.line);
            track.index.push(row as u32);
        }
        Ok(Rig {
            generator,
            parent,
            tracks,
            csv_path,
        })
    }

    /// Positions of the nodes from the root to part `part`'s node.
    fn chain(&self, part: usize) -> Vec<usize> {
        let index = self.generator.parts[part].node_index;
        let mut at = self.generator.nodes.iter().position(|n| n.index == index);
        let mut chain = Vec::new();
        while let Some(i) = at {
            chain.push(i);
            at = self.parent[i];
        }
        chain.reverse();
        chain
    }

    /// The screw of node `node` from its row j to row j + 1.
    fn screw(&self, node: usize, j: usize) -> Result<Screw, InputError> {
        let track = &self.tracks[&node];
        Screw::new(&track.rows[j], &track.rows[j + 1]).map_err(|why| {
            refuse(
                self.csv_path,
                track.lines[j + 1],
                format!(
                    "the motion of node {:?} between lines {} and {} cannot be followed: {why}",
                    self.generator.nodes[node].name.as_deref().unwrap_or(""),
                    track.lines[j],
                    track.lines[j + 1]
                ),
                "add a row between them, or verify with --motion discrete",
            )
        })
    }

    /// Node `node`'s local transform at time t, and the piece of its track that moves it over
    /// [t, t2] when t < t2 lie within one piece: (screw, fractions at t and t2).
    fn local(&self, node: usize, t: f64) -> Result<DMat4, InputError> {
        let Some(track) = self.tracks.get(&node) else {
            return Ok(self.generator.nodes[node].local);
        };
        let n = track.times.len();
        if t <= track.times[0] {
            return Ok(track.rows[0]);
        }
        if t >= track.times[n - 1] {
            return Ok(track.rows[n - 1]);
        }
        let j = track
            .times
            .iter()
            .rposition(|&x| x <= t)
            .expect("t > times[0]");
        if track.times[j] == t {
            return Ok(track.rows[j]);
        }
        let s = (t - track.times[j]) / (track.times[j + 1] - track.times[j]);
        Ok(self.screw(node, j)?.at(s))
    }

    /// The times of part `part`'s chain's rows, sorted, and for each the row (index, line) of
    /// the deepest node that has one then.
    fn times(&self, chain: &[usize]) -> Vec<(f64, u32, u64)> {
        let mut out: Vec<(f64, u32, u64)> = Vec::new();
        for node in chain {
            if let Some(track) = self.tracks.get(node) {
                for k in 0..track.times.len() {
                    match out.iter_mut().find(|e| e.0 == track.times[k]) {
                        Some(e) => (e.1, e.2) = (track.index[k], track.lines[k]),
                        None => out.push((track.times[k], track.index[k], track.lines[k])),
                    }
                }
            }
        }
        out.sort_by(|a, b| a.0.total_cmp(&b.0));
        out
    }

    fn world(&self, chain: &[usize], t: f64) -> Result<DMat4, InputError> {
        chain
            .iter()
            .try_fold(DMat4::IDENTITY, |m, &n| Ok(m * self.local(n, t)?))
    }

    /// Every part's poses at its chain's row times (a part no row moves: where it stands).
    pub fn listed(&self) -> Result<Vec<Vec<PartPose>>, InputError> {
        (0..self.generator.parts.len())
            .map(|part| {
                let chain = self.chain(part);
                self.at_times(part, &chain, &self.times(&chain))
            })
            .collect()
    }

    /// Part `part`'s poses at `times` (of its chain), or where it stands when there are none.
    fn at_times(
        &self,
        part: usize,
        chain: &[usize],
        times: &[(f64, u32, u64)],
    ) -> Result<Vec<PartPose>, InputError> {
        if times.is_empty() {
            return Ok(vec![PartPose::new(
                self.generator.parts[part].world,
                None,
                None,
            )]);
        }
        times
            .iter()
            .map(|&(t, row, line)| Ok(PartPose::new(self.world(chain, t)?, Some(row), Some(line))))
            .collect()
    }

    /// Every part's motion between its chain's row times as middle poses of sub-intervals whose
    /// reach is at most `reach`.
    pub fn continuous(&self, reach: f64) -> Result<(Vec<Vec<PartPose>>, MotionCheck), InputError> {
        let mut check = MotionCheck {
            model: "screw",
            ..Default::default()
        };
        let mut out = Vec::new();
        for part in 0..self.generator.parts.len() {
            let chain = self.chain(part);
            let times = self.times(&chain);
            if times.len() < 2 {
                check.poses += 1;
                out.push(self.at_times(part, &chain, &times)?);
                continue;
            }
            let mut poses = Vec::new();
            for w in times.windows(2) {
                let ((ta, row, line), (tb, to_row, to_line)) = (w[0], w[1]);
                let path = self.path(part, &chain, (ta, tb))?;
                let m = check.interval(path, reach, self.csv_path)?;
                for j in 0..m {
                    let s = (j as f64 + 0.5) / m as f64;
                    let mut pose = PartPose::new(
                        self.world(&chain, ta + s * (tb - ta))?,
                        Some(row),
                        Some(line),
                    );
                    pose.reach = path / (2.0 * m as f64);
                    pose.between = Some(Between { to_row, to_line, s });
                    poses.push(pose);
                }
            }
            out.push(poses);
        }
        Ok((out, check))
    }

    /// Bound on the speed, per unit of the interval's parameter, of every point of part
    /// `part` over [ta, tb] (consecutive times of its chain), with the f64 evaluation's error.
    fn path(&self, part: usize, chain: &[usize], (ta, tb): (f64, f64)) -> Result<f64, InputError> {
        // Per node, from the part's own up: None (held at its matrix at ta) or the screw and
        // the fractions of its piece at ta and tb.
        let mut pieces = Vec::with_capacity(chain.len());
        for &node in chain {
            let held = self.local(node, ta)?;
            let piece = match self.tracks.get(&node) {
                Some(track) if ta < track.times[track.times.len() - 1] && tb > track.times[0] => {
                    let j = track
                        .times
                        .iter()
                        .rposition(|&x| x <= ta)
                        .expect("ta ≥ times[0]");
                    let span = track.times[j + 1] - track.times[j];
                    Some((
                        self.screw(node, j)?,
                        (ta - track.times[j]) / span,
                        (tb - track.times[j]) / span,
                    ))
                }
                _ => None,
            };
            pieces.push((held, piece));
        }
        let mut path: f64 = 0.0;
        let mut far: f64 = 0.0;
        for p in &self.generator.parts[part].positions {
            let mut q = p.as_dvec3();
            let mut speed = 0.0;
            for (held, piece) in pieces.iter().rev() {
                match piece {
                    None => speed *= sigma_bound(&DMat3::from_mat4(*held)),
                    Some((screw, a, b)) => speed = screw.chain_speed((*a, *b), q, speed),
                }
                q = held.transform_point3(q);
                far = far.max(q.length());
            }
            path = path.max(speed);
        }
        // Generous f64 error: 2¹⁰ ulps of the farthest coordinate per node of the chain.
        Ok(path + 1024.0 * f64::EPSILON * chain.len() as f64 * (far + path))
    }
}

/// At least the largest singular value: the square root of the largest column sum of |AᵀA|
/// (an induced norm of AᵀA bounds its largest eigenvalue, σ_max²); 1 for a rotation.
fn sigma_bound(a: &DMat3) -> f64 {
    let g = a.transpose() * *a;
    [g.x_axis, g.y_axis, g.z_axis]
        .iter()
        .map(|c| c.abs().element_sum())
        .fold(0.0, f64::max)
        .sqrt()
}

impl Screw {
    /// Speed per unit of σ (s = a + σ(b - a)) of the posed point M(s)·q(σ), where q(0) = `q0`
    /// and q moves at most at `inner`: (b - a)·(the rigid helix speed at S(s)q0, largest at an
    /// end since it is convex along the stretch's straight line) + (b - a)·|(S₁ - S₀)q0| + the
    /// same terms' change with q, and the linear map's norm times `inner`.
    pub(super) fn chain_speed(&self, (a, b): (f64, f64), q0: DVec3, inner: f64) -> f64 {
        let d = b - a;
        let (sa, sb) = (self.stretch(a), self.stretch(b));
        let norm = sigma_bound(&sa).max(sigma_bound(&sb));
        let ds = self.s1 - self.s0;
        let helix = self.rigid_speed(sa * q0).max(self.rigid_speed(sb * q0));
        let rate = self.theta * norm + sigma_bound(&ds);
        d * (helix + (ds * q0).length()) + (d * rate + norm) * inner
    }
}
