//! The sweep's poses, made on demand: each part's rows in grid units and the screw intervals
//! between them, from which any pose is evaluated by its index (docs/design.md, "Continuous
//! motion", "Cost"). A part's poses are, in order, row 0, the k₀ - 1 sub-poses of interval 0,
//! row 1, ..., the last row; sub-pose `step` of an interval with k steps is the screw at
//! s = step/k. Nothing here grows with the number of sub-poses: memory is O(rows + intervals),
//! and the sweep asks for one batch at a time ([`PoseSource::fill`]).

use std::ops::Range;

use glam::DMat4;
use rayon::prelude::*;

use crate::input::motion::Interval;

/// Poses one [`PoseSource::fill`] call evaluates on one thread before it splits the range.
const POSES_PER_TASK: usize = 256;

/// An interval of a part's motion and its number of steps k (k ≥ 1): k - 1 sub-poses.
pub type Steps = (Interval, u64);

/// One part's poses.
#[derive(Clone, Debug)]
struct PartMotion {
    /// The rows' poses, grid units (the grid map times the row's world pose).
    rows: Vec<DMat4>,
    /// The interval from row i to row i + 1 and its number of steps k (k ≥ 1); empty for a
    /// discrete sweep or a part with one row, whose poses are its rows.
    intervals: Vec<Steps>,
    /// Index (within the part) of row i: the sum of the steps of the intervals before it.
    /// Filled only when there are intervals.
    starts: Vec<u64>,
}

impl PartMotion {
    fn count(&self) -> u64 {
        match self.starts.last() {
            Some(&last) => last + 1,
            None => self.rows.len() as u64,
        }
    }
}

/// Every part's poses as 3x4 matrices from the part's local frame to grid units, evaluated on
/// demand. Parts are indexed as [`crate::input::posed::SweepInput::parts`].
#[derive(Clone, Debug)]
pub struct PoseSource {
    /// World units to grid units.
    to_grid: DMat4,
    parts: Vec<PartMotion>,
    /// Per part, the poses this source hands out (a shard's share, `pipeline::shard`): index i
    /// of [`Self::fill`] and [`Self::grid_pose`] is pose `window.start + i` of the part. None:
    /// all of them.
    windows: Option<Vec<Range<u64>>>,
}

/// The row-major 4x4 array of `a` (its last row is 0 0 0 1 for an affine pose).
pub fn row_major(a: &DMat4) -> [f64; 16] {
    a.transpose().to_cols_array()
}

/// The f32 3x4 matrix the sweep renders with: the first three rows of `a`, each entry rounded
/// to nearest.
pub fn to_f32(rows: &[f64; 16]) -> [f32; 12] {
    std::array::from_fn(|k| rows[k] as f32)
}

impl PoseSource {
    /// Poses of parts given as (world poses of its rows, its intervals with their steps); the
    /// intervals of a part run between consecutive rows, so there are none or one fewer than
    /// rows.
    pub fn new(to_grid: DMat4, parts: Vec<(Vec<DMat4>, Vec<Steps>)>) -> PoseSource {
        let parts = parts
            .into_iter()
            .map(|(rows, intervals)| {
                assert!(
                    intervals.is_empty() || intervals.len() + 1 == rows.len(),
                    "one interval between each two rows"
                );
                assert!(intervals.iter().all(|&(_, k)| k >= 1));
                let starts = if intervals.is_empty() {
                    Vec::new()
                } else {
                    let mut at = 0u64;
                    let mut starts = Vec::with_capacity(rows.len());
                    starts.push(0);
                    for (_, k) in &intervals {
                        at += k;
                        starts.push(at);
                    }
                    starts
                };
                PartMotion {
                    rows: rows.iter().map(|m| to_grid * *m).collect(),
                    intervals,
                    starts,
                }
            })
            .collect();
        PoseSource {
            to_grid,
            parts,
            windows: None,
        }
    }

    /// The same poses restricted to `windows` (one range of pose indices per part, within its
    /// poses): what one shard of a job sweeps. [`Self::max_over`] still covers every pose.
    pub fn windowed(&self, windows: Vec<Range<u64>>) -> PoseSource {
        assert_eq!(windows.len(), self.parts.len());
        for (part, w) in windows.iter().enumerate() {
            assert!(
                w.start <= w.end && w.end <= self.parts[part].count(),
                "{w:?}"
            );
        }
        PoseSource {
            windows: Some(windows),
            ..self.clone()
        }
    }

    /// Poses of part `part` this source hands out: its rows and the sub-poses between them, or
    /// its window's share of them.
    pub fn count(&self, part: usize) -> u64 {
        match &self.windows {
            Some(w) => w[part].end - w[part].start,
            None => self.parts[part].count(),
        }
    }

    /// Every row's pose of part `part`, grid units, whatever the window (a static part: its one
    /// pose).
    pub fn rows(&self, part: usize) -> &[DMat4] {
        &self.parts[part].rows
    }

    /// Pose `index` of part `part` in grid units, f64: a row's matrix as given, or the grid map
    /// times the screw at s = step/k.
    pub fn grid_pose(&self, part: usize, index: u64) -> DMat4 {
        assert!(
            index < self.count(part),
            "pose {index} of {}",
            self.count(part)
        );
        let index = index + self.windows.as_ref().map_or(0, |w| w[part].start);
        let p = &self.parts[part];
        if p.intervals.is_empty() {
            return p.rows[index as usize];
        }
        assert!(index < p.count(), "pose {index} of {}", p.count());
        let i = p.starts.partition_point(|&s| s <= index) - 1;
        let step = index - p.starts[i];
        if step == 0 {
            return p.rows[i];
        }
        let (iv, k) = &p.intervals[i];
        self.to_grid * iv.at(step as f64 / *k as f64)
    }

    /// The f32 matrices of poses `range` of part `part`, in order, into `out` (cleared first).
    /// Large ranges are evaluated on the rayon pool; the values do not depend on it.
    pub fn fill(&self, part: usize, range: Range<u64>, out: &mut Vec<[f32; 12]>) {
        assert!(
            range.end <= self.count(part),
            "poses {range:?} of {}",
            self.count(part)
        );
        out.clear();
        let n = range.end.saturating_sub(range.start) as usize;
        let pose = |d: usize| to_f32(&row_major(&self.grid_pose(part, range.start + d as u64)));
        if n <= POSES_PER_TASK {
            out.extend((0..n).map(pose));
        } else {
            out.par_extend(
                (0..n)
                    .into_par_iter()
                    .with_min_len(POSES_PER_TASK)
                    .map(pose),
            );
        }
    }

    /// The largest `f` over the row-major f64 matrices (see [`row_major`]) of every pose of
    /// part `part` (0 when there is none, and NaNs are skipped, as `f64::max` does): one
    /// streamed pass on the rayon pool, nothing stored. f64 max is exact, so the result does not
    /// depend on the order.
    pub fn max_over(&self, part: usize, f: impl Fn(&[f64; 16]) -> f64 + Sync) -> f64 {
        let p = &self.parts[part];
        let rows = p
            .rows
            .par_iter()
            .map(|m| f(&row_major(m)))
            .reduce(|| 0.0, f64::max);
        let subs = p
            .intervals
            .par_iter()
            .flat_map(|(iv, k)| {
                let f = &f;
                (1..*k).into_par_iter().map(move |step| {
                    f(&row_major(&(self.to_grid * iv.at(step as f64 / *k as f64))))
                })
            })
            .reduce(|| 0.0, f64::max);
        rows.max(subs)
    }

    /// Bytes this source holds on the heap: proportional to rows and intervals, whatever the
    /// number of sub-poses.
    pub fn heap_bytes(&self) -> usize {
        self.parts.capacity() * std::mem::size_of::<PartMotion>()
            + self
                .parts
                .iter()
                .map(|p| {
                    p.rows.capacity() * std::mem::size_of::<DMat4>()
                        + p.intervals.capacity() * std::mem::size_of::<Steps>()
                        + p.starts.capacity() * std::mem::size_of::<u64>()
                })
                .sum::<usize>()
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use glam::{DQuat, DVec3};

    use super::*;
    use crate::input::model::{Generator, Part, Trajectory};
    use crate::input::motion;

    fn generator(rng: &mut fastrand::Rng) -> Generator {
        let mut r = || rng.f64() * 2.0 - 1.0;
        Generator {
            nodes: Vec::new(),
            parts: vec![Part {
                node_index: 0,
                node_name: Some("p".into()),
                world: DMat4::IDENTITY,
                positions: (0..4)
                    .map(|_| DVec3::new(r(), r(), r()).as_vec3() * 2.0)
                    .collect(),
                triangles: vec![[0, 1, 2], [0, 3, 1]],
            }],
            warnings: vec![],
        }
    }

    /// Random rows (rigid, some stretched) of one part, each turning less than 170° from the
    /// last, and their intervals.
    fn random_motion(rng: &mut fastrand::Rng, g: &Generator) -> (Vec<DMat4>, Vec<Interval>) {
        let rows = 2 + rng.usize(..6);
        let mut m = DMat4::IDENTITY;
        let mut out = Vec::new();
        for _ in 0..rows {
            let mut r = || rng.f64() * 2.0 - 1.0;
            let axis = DVec3::new(r(), r(), r() + 1.5).normalize();
            let step = DMat4::from_rotation_translation(
                DQuat::from_axis_angle(axis, r() * 2.9),
                DVec3::new(r(), r(), r()) * 20.0,
            );
            m = step * m;
            let stretch = DMat4::from_scale(DVec3::new(1.0 + 0.2 * r(), 1.0, 1.0 + 0.1 * r()));
            out.push(m * stretch);
        }
        let traj = Trajectory {
            rows: Default::default(),
            poses: vec![],
            has_node_column: false,
        };
        let assigned = vec![(0, out.iter().map(|m| (*m, Some(2))).collect(), false)];
        let intervals = motion::intervals(g, &traj, Path::new("t.csv"), &assigned).unwrap();
        (out, intervals)
    }

    /// The poses as the sweep's input listed them before they were made on demand: each row,
    /// then the sub-poses of the interval after it, every one the grid map times the world pose.
    fn listed_f64(to_grid: DMat4, rows: &[DMat4], steps: &[Steps]) -> Vec<DMat4> {
        let mut out = Vec::new();
        for (j, row) in rows.iter().enumerate() {
            out.push(to_grid * *row);
            if let Some((iv, k)) = steps.get(j) {
                for step in 1..*k {
                    out.push(to_grid * iv.at(step as f64 / *k as f64));
                }
            }
        }
        out
    }

    /// As the sweep renders them: transposed, the first twelve entries rounded to f32.
    fn listed(to_grid: DMat4, rows: &[DMat4], steps: &[Steps]) -> Vec<[f32; 12]> {
        listed_f64(to_grid, rows, steps)
            .iter()
            .map(|m| {
                let a = m.transpose().to_cols_array();
                let mut out = [0f32; 12];
                for (k, x) in out.iter_mut().enumerate() {
                    *x = a[k] as f32;
                }
                out
            })
            .collect()
    }

    /// Made on demand, in any batches, the poses are bit for bit those of the listed form, and
    /// the streamed maximum is the maximum over the list.
    #[test]
    fn filled_batches_are_the_listed_poses_bit_for_bit() {
        let mut rng = fastrand::Rng::with_seed(16);
        for case in 0..60 {
            let g = generator(&mut rng);
            let (rows, intervals) = random_motion(&mut rng, &g);
            let steps: Vec<Steps> = intervals
                .into_iter()
                .map(|iv| {
                    let k = match rng.u32(..4) {
                        0 => 1,
                        1 => 2 + rng.u64(..5),
                        _ => 1 + rng.u64(..700),
                    };
                    (iv, k)
                })
                .collect();
            let to_grid = DMat4::from_scale(DVec3::splat(1.0 + rng.f64() * 50.0))
                * DMat4::from_translation(DVec3::new(rng.f64(), -rng.f64(), 3.0) * 40.0);
            let want = listed(to_grid, &rows, &steps);
            // A second part without intervals (discrete rows), and a one-row part.
            let source = PoseSource::new(
                to_grid,
                vec![
                    (rows.clone(), steps.clone()),
                    (rows.clone(), Vec::new()),
                    (vec![rows[0]], Vec::new()),
                ],
            );
            assert_eq!(source.count(0), want.len() as u64, "case {case}");
            assert_eq!(source.count(1), rows.len() as u64);
            assert_eq!(source.count(2), 1);
            let bits = |v: &[[f32; 12]]| -> Vec<[u32; 12]> {
                v.iter().map(|m| m.map(f32::to_bits)).collect()
            };
            let mut got = Vec::new();
            let mut batch = Vec::new();
            let mut at = 0u64;
            while at < source.count(0) {
                let n = match rng.u32(..3) {
                    0 => 1,
                    1 => 1 + rng.u64(..40),
                    _ => 1 + rng.u64(..1200),
                };
                let end = (at + n).min(source.count(0));
                source.fill(0, at..end, &mut batch);
                assert_eq!(batch.len() as u64, end - at);
                got.extend_from_slice(&batch);
                at = end;
            }
            assert_eq!(bits(&got), bits(&want), "case {case}");
            // f32 rounding hides most one-ulp slips in s: the f64 poses match bit for bit too.
            for (j, m) in listed_f64(to_grid, &rows, &steps).iter().enumerate() {
                let (a, b) = (source.grid_pose(0, j as u64), *m);
                assert!(
                    a.to_cols_array().map(f64::to_bits) == b.to_cols_array().map(f64::to_bits),
                    "case {case}, pose {j}: {a} != {b}"
                );
            }
            source.fill(1, 0..rows.len() as u64, &mut batch);
            let rows_only: Vec<_> = rows
                .iter()
                .map(|m| listed(to_grid, &[*m], &[])[0])
                .collect();
            assert_eq!(bits(&batch), bits(&rows_only));
            source.fill(2, 0..1, &mut batch);
            assert_eq!(bits(&batch), bits(&rows_only[..1]));
            // The streamed maximum of a function of the f64 matrices: that of the list.
            let f = |a: &[f64; 16]| a[3].abs() + a[5] * a[10] - a[7];
            let mut direct: f64 = 0.0;
            for (j, row) in rows.iter().enumerate() {
                direct = direct.max(f(&(to_grid * *row).transpose().to_cols_array()));
                if let Some((iv, k)) = steps.get(j) {
                    for step in 1..*k {
                        let m = to_grid * iv.at(step as f64 / *k as f64);
                        direct = direct.max(f(&m.transpose().to_cols_array()));
                    }
                }
            }
            assert_eq!(
                source.max_over(0, f).to_bits(),
                direct.to_bits(),
                "case {case}"
            );
        }
    }

    /// A motion of a million sub-poses holds no more than one of a few: the source keeps rows
    /// and intervals, and makes any pose on demand.
    #[test]
    fn a_million_sub_poses_take_no_memory() {
        let mut rng = fastrand::Rng::with_seed(3);
        let g = generator(&mut rng);
        let (rows, intervals) = random_motion(&mut rng, &g);
        let n = intervals.len() as u64;
        let with = |k: u64| {
            let steps = intervals.iter().map(|iv| (iv.clone(), k)).collect();
            PoseSource::new(DMat4::IDENTITY, vec![(rows.clone(), steps)])
        };
        let (small, large) = (with(2), with(1_000_000 / n + 1));
        assert!(large.count(0) > 1_000_000);
        assert_eq!(small.heap_bytes(), large.heap_bytes());
        assert!(
            large.heap_bytes() < 1000 * (rows.len() + 1),
            "{}",
            large.heap_bytes()
        );
        // The last poses of the large motion are there all the same: its last row.
        let mut batch = Vec::new();
        let end = large.count(0);
        large.fill(0, end - 3..end, &mut batch);
        let last = to_f32(&row_major(rows.last().unwrap()));
        assert_eq!(batch[2].map(f32::to_bits), last.map(f32::to_bits));
    }
}
