//! Rows in parent space (`Rows::Local`, docs/design.md "Articulated motion"): the generator's
//! node hierarchy is a kinematic tree, each row sets one node's transform relative to its
//! parent, and a part's world pose is the product of its chain's local transforms, root first.
//!
//! Between two rows of a node its local transform moves by the screw from the one to the next
//! in the parent's frame (`motion::Screw`): for a revolute or prismatic joint, whose rows are
//! origin·Rot(axis, q) or origin·Trans(axis·q), that is exactly the joint-linear motion. Rows
//! of different nodes pair by their time; a node holds its first row before it and its last
//! after it, and is interpolated at the times of other nodes' rows in between. A part's poses
//! are its chain at every time some row of the chain gives, and over each interval between two
//! such times every node of the chain moves along one piece of one of its screws.
//!
//! The path bound of an interval (`Interval::path`) is built from the part's own node up to the
//! root: a point's speed in node i's parent frame is at most that node's screw speed at the
//! point's position plus what the nodes below it add, carried through the node's linear map
//! (`motion::Screw::speed`; a held node multiplies the speed by its matrix's norm). Every term
//! is convex in the point, so the largest over the part's outline bounds every point.
//!
//! Units: world units and radians; times as the CSV gives them.

use std::collections::HashMap;
use std::path::Path;

use glam::{DMat3, DMat4};
use rayon::prelude::*;

use crate::error::{num, InputError};
use crate::input::model::{Generator, LinedPose, PartPoses, Trajectory, TreeNode};
use crate::input::motion::{self, Factor, Interval, Kind, Motion, NoScrew, Screw};

/// One node's rows: times (strictly increasing), local matrices, CSV lines, and the screw
/// between each row and the next (an error kept until an instant between them is asked for).
struct Track {
    times: Vec<f64>,
    rows: Vec<DMat4>,
    lines: Vec<u64>,
    screws: Vec<Result<Screw, NoScrew>>,
}

/// Where a time falls in a track.
enum At {
    /// On or outside a row: that row's matrix holds.
    Row(usize),
    /// Strictly between rows j and j + 1.
    Between(usize),
}

impl Track {
    fn locate(&self, t: f64) -> At {
        let n = self.times.len();
        if t <= self.times[0] {
            return At::Row(0);
        }
        if t >= self.times[n - 1] {
            return At::Row(n - 1);
        }
        let j = self.times.partition_point(|&x| x <= t) - 1;
        if self.times[j] == t {
            At::Row(j)
        } else {
            At::Between(j)
        }
    }

    /// The fraction of the way from row j to row j + 1 at time t.
    fn fraction(&self, j: usize, t: f64) -> f64 {
        (t - self.times[j]) / (self.times[j + 1] - self.times[j])
    }
}

/// The tree with its tracks, and the errors' context.
struct Rig<'a> {
    nodes: &'a [TreeNode],
    tracks: HashMap<usize, Track>,
    csv_path: &'a Path,
}

impl Rig<'_> {
    fn name(&self, node: usize) -> String {
        let n = &self.nodes[node];
        match &n.name {
            Some(name) => format!("node {name:?}"),
            None => format!("nodes[{}]", n.index),
        }
    }

    fn screw(&self, node: usize, j: usize) -> Result<&Screw, InputError> {
        let track = &self.tracks[&node];
        track.screws[j].as_ref().map_err(|&why| {
            motion::refusal(
                why,
                &self.name(node),
                self.csv_path,
                (track.lines[j], track.lines[j + 1]),
            )
        })
    }

    /// The node's local transform at time t.
    fn local(&self, node: usize, t: f64) -> Result<DMat4, InputError> {
        let Some(track) = self.tracks.get(&node) else {
            return Ok(self.nodes[node].local);
        };
        Ok(match track.locate(t) {
            At::Row(j) => track.rows[j],
            At::Between(j) => self.screw(node, j)?.at(track.fraction(j, t)),
        })
    }

    /// The node's factor over [a, b], an interval between consecutive times of its chain (so
    /// within one piece of its track, or outside the track where it holds).
    fn factor(&self, node: usize, (a, b): (f64, f64)) -> Result<Factor, InputError> {
        let Some(track) = self.tracks.get(&node) else {
            return Ok(Factor::Fixed(self.nodes[node].local));
        };
        let last = track.times.len() - 1;
        if b <= track.times[0] || a >= track.times[last] {
            return self.local(node, a).map(Factor::Fixed);
        }
        let j = track.times.partition_point(|&x| x <= a) - 1;
        debug_assert!(
            b <= track.times[j + 1],
            "the chain's times include the track's"
        );
        Ok(Factor::Moving {
            screw: self.screw(node, j)?.clone(),
            span: (track.fraction(j, a), track.fraction(j, b)),
        })
    }
}

/// Each part's poses at the times its chain's rows give, and (for screw motion) the intervals
/// between them with their path bounds over the part's vertices as `generator` holds them (its
/// outline will do). Refused by line and column: rows that name no node or an ambiguous one,
/// rows of several nodes without a time to pair them, a node's rows out of time order or two at
/// one time, and the screw refusals of `motion` where an interval needs the screw.
pub fn resolve(
    generator: &Generator,
    trajectory: &Trajectory,
    csv_path: &Path,
    motion: Motion,
) -> Result<(Vec<PartPoses>, Vec<Interval>), InputError> {
    let rig = Rig {
        nodes: &generator.nodes,
        tracks: tracks(generator, trajectory, csv_path)?,
        csv_path,
    };
    let position: HashMap<usize, usize> = generator
        .nodes
        .iter()
        .enumerate()
        .map(|(i, n)| (n.index, i))
        .collect();
    let mut assigned = Vec::new();
    let mut intervals = Vec::new();
    for (k, part) in generator.parts.iter().enumerate() {
        let chain = chain_of(&generator.nodes, &position, part.node_index);
        let mut times: Vec<f64> = chain
            .iter()
            .filter_map(|n| rig.tracks.get(n))
            .flat_map(|t| t.times.iter().copied())
            .collect();
        times.sort_by(f64::total_cmp);
        times.dedup();
        if times.is_empty() {
            assigned.push((k, vec![(part.world, None)], true));
            continue;
        }
        let mut poses: Vec<LinedPose> = Vec::with_capacity(times.len());
        for &t in &times {
            let mut m = DMat4::IDENTITY;
            for &n in &chain {
                m *= rig.local(n, t)?;
            }
            poses.push((m, line_at(&rig, &chain, t)));
        }
        if motion == Motion::Screw {
            let mut pieces = Vec::with_capacity(times.len() - 1);
            for (w, pair) in times.windows(2).enumerate() {
                let factors = chain
                    .iter()
                    .map(|&n| rig.factor(n, (pair[0], pair[1])))
                    .collect::<Result<Vec<_>, _>>()?;
                let lines = (poses[w].1.unwrap_or(0), poses[w + 1].1.unwrap_or(0));
                pieces.push((lines, factors));
            }
            // The bounds on all threads; collect keeps the order (and the values do not
            // depend on the threads).
            let bounded: Vec<Interval> = pieces
                .into_par_iter()
                .map(|(lines, factors)| interval(generator, k, lines, factors))
                .collect();
            intervals.extend(bounded);
        }
        assigned.push((k, poses, false));
    }
    Ok((assigned, intervals))
}

/// Pieces of an interval for the second bound (`interval`).
/// Pieces of an interval for the second bound (`interval`): at least the first, at most the
/// second; in between, enough to make the acceleration's share A/K a twentieth of the speed.
const PIECES: (usize, usize) = (16, 512);

/// The interval of part `part` moved by `factors` (root first), with its path bound: the
/// smaller of two bounds on every point's speed, each the largest over the part's outline.
/// The first adds the nodes' speeds up the chain (`Screw::speed`). The second cuts the
/// interval into K pieces: on a piece of length 1/K the speed differs from the chord's mean
/// speed K·|x(σₖ₊₁) - x(σₖ)| by at most A/K, A a bound on the acceleration built up the chain
/// the same way (`Screw::acceleration`); it is near the true largest speed where the first
/// adds up speeds that point different ways.
fn interval(
    generator: &Generator,
    part: usize,
    lines: (u64, u64),
    factors: Vec<Factor>,
) -> Interval {
    let mut reach: f64 = 0.0;
    // Per vertex: its speed bound by the sum and its acceleration bound.
    let bounds: Vec<(f64, f64)> = generator.parts[part]
        .positions
        .iter()
        .map(|p| {
            // From the part's own node up: q is the point in the current node's parent frame
            // at the interval's start; speed and acc bound its speed and acceleration there.
            let mut q = p.as_dvec3();
            let (mut speed, mut acc) = (0.0, 0.0);
            for f in factors.iter().rev() {
                match f {
                    Factor::Fixed(m) => {
                        let norm = motion::norm_bound(&DMat3::from_mat4(*m));
                        (speed, acc) = (speed * norm, acc * norm);
                        q = m.transform_point3(q);
                    }
                    Factor::Moving { screw, span } => {
                        acc = screw.acceleration(*span, q, speed, acc);
                        speed = screw.speed(*span, q, speed);
                        q = screw.at(span.0).transform_point3(q);
                    }
                }
                reach = reach.max(q.abs().max_element());
            }
            (speed, acc)
        })
        .collect();
    let first = bounds.iter().map(|b| b.0).fold(0.0, f64::max);
    let acc_max = bounds.iter().map(|b| b.1).fold(0.0, f64::max);
    let second = (first > 0.0).then(|| {
        let k = ((20.0 * acc_max / first).ceil() as usize).clamp(PIECES.0, PIECES.1);
        let poses: Vec<DMat4> = (0..=k)
            .map(|j| {
                let s = j as f64 / k as f64;
                factors.iter().fold(DMat4::IDENTITY, |m, f| m * f.at(s))
            })
            .collect();
        let bound = generator.parts[part]
            .positions
            .iter()
            .zip(&bounds)
            .map(|(p, &(_, a))| {
                let p = p.as_dvec3();
                let chords = poses
                    .windows(2)
                    .map(|w| (w[1].transform_point3(p) - w[0].transform_point3(p)).length())
                    .fold(0.0, f64::max);
                chords * k as f64 + a / k as f64
            })
            .fold(0.0, f64::max);
        // The chords' f64 error is multiplied by K: K times the evaluation's own allowance.
        bound + k as f64 * motion::eval_error(factors.len(), reach, bound)
    });
    let path = second.map_or(first, |s| first.min(s));
    let turn = factors
        .iter()
        .map(|f| match f {
            Factor::Fixed(_) => 0.0,
            Factor::Moving { screw, span } => screw.turn() * (span.1 - span.0),
        })
        .sum();
    let path = path + motion::eval_error(factors.len(), reach, path);
    Interval {
        part,
        lines,
        kind: Kind::Chain(factors),
        path,
        turn,
    }
}

/// The CSV line of a row at time t of the deepest node of `chain` that has one.
fn line_at(rig: &Rig, chain: &[usize], t: f64) -> Option<u64> {
    chain.iter().rev().find_map(|n| {
        let track = rig.tracks.get(n)?;
        let j = track.times.partition_point(|&x| x < t);
        (j < track.times.len() && track.times[j] == t).then(|| track.lines[j])
    })
}

/// Positions in `nodes` of the chain from the root to the node with document index `index`.
fn chain_of(nodes: &[TreeNode], position: &HashMap<usize, usize>, index: usize) -> Vec<usize> {
    let mut chain = Vec::new();
    let mut at = position.get(&index).copied();
    while let Some(i) = at {
        chain.push(i);
        at = nodes[i].parent.and_then(|p| position.get(&p).copied());
    }
    chain.reverse();
    chain
}

/// Every named node's rows, checked.
fn tracks(
    generator: &Generator,
    trajectory: &Trajectory,
    csv_path: &Path,
) -> Result<HashMap<usize, Track>, InputError> {
    let first_line = trajectory.poses.first().map_or(1, |p| p.line);
    if !trajectory.has_node_column {
        return Err(InputError::new(
            csv_path,
            "rows in parent space ($rows local) set one node's transform each, but the trajectory has no node column",
            "add a node column naming the node each row moves (its transform relative to its parent), or give world-space rows ($rows world)",
        )
        .at_line(first_line));
    }
    let mut rows: HashMap<usize, Vec<(f64, DMat4, u64)>> = HashMap::new();
    let mut order = 0.0;
    for pose in &trajectory.poses {
        let name = pose.node.as_deref().unwrap_or_default();
        let node = node_named(&generator.nodes, name, csv_path, pose.line)?;
        let t = pose.frame.unwrap_or_else(|| {
            order += 1.0;
            order
        });
        rows.entry(node)
            .or_default()
            .push((t, pose.matrix, pose.line));
    }
    if trajectory.poses.iter().all(|p| p.frame.is_none()) && rows.len() > 1 {
        return Err(InputError::new(
            csv_path,
            format!("rows in parent space of {} nodes, but no frame or time column to say which rows belong together", rows.len()),
            "add a frame or time column: a node's transform at each time is composed with its parents' at the same time",
        )
        .at_line(first_line));
    }
    let mut out = HashMap::new();
    for (node, list) in rows {
        for pair in list.windows(2) {
            let ((t0, _, l0), (t1, _, l1)) = (pair[0], pair[1]);
            if t1 <= t0 {
                let name = match &generator.nodes[node].name {
                    Some(n) => format!("node {n:?}"),
                    None => format!("nodes[{}]", generator.nodes[node].index),
                };
                let what = if t1 == t0 {
                    "a second row at"
                } else {
                    "a row back in time, at"
                };
                return Err(InputError::new(
                    csv_path,
                    format!("{what} time {} for {name} (its row at line {l0} has time {})", num(t1), num(t0)),
                    "give each node one row per time, sorted by time: the motion runs from each row to the next",
                )
                .at_line(l1));
            }
        }
        let screws = list
            .windows(2)
            .map(|pair| Screw::between(&pair[0].1, &pair[1].1))
            .collect();
        out.insert(
            node,
            Track {
                times: list.iter().map(|r| r.0).collect(),
                rows: list.iter().map(|r| r.1).collect(),
                lines: list.iter().map(|r| r.2).collect(),
                screws,
            },
        );
    }
    Ok(out)
}

/// The position in `nodes` of the one node called `name`, for the row at `line`.
fn node_named(
    nodes: &[TreeNode],
    name: &str,
    csv_path: &Path,
    line: u64,
) -> Result<usize, InputError> {
    let hits: Vec<usize> = (0..nodes.len())
        .filter(|&i| nodes[i].name.as_deref() == Some(name))
        .collect();
    let error = match hits.len() {
        1 => return Ok(hits[0]),
        0 => {
            let known: Vec<&str> = nodes.iter().filter_map(|n| n.name.as_deref()).collect();
            let shown = known.len().min(12);
            let more = if known.len() > shown {
                format!(" and {} more", known.len() - shown)
            } else {
                String::new()
            };
            InputError::new(
                csv_path,
                format!("no node named {name:?} in the generator's hierarchy"),
                format!("use one of its nodes: {}{more}", known[..shown].join(", ")),
            )
        }
        n => InputError::new(
            csv_path,
            format!("node name {name:?} is ambiguous: {n} nodes carry it"),
            "give the glTF nodes unique names",
        ),
    };
    Err(error.at_line(line).in_column("node"))
}
