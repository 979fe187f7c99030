//! Deviation: an upper bound on the one-sided Hausdorff distance from the mesh to the swept
//! volume, max over mesh points x of dist(x, swept volume).
//!
//! Each mesh triangle is a ball (centroid c, covering radius r); every point x of it has
//! dist(x) <= dist(c) + r, where dist(c) is taken to the posed generator surfaces (an upper
//! bound of the distance to the swept solid: points inside the solid count their distance to
//! its surface, not zero). A triangle whose bound is no larger than a distance already found at
//! some mesh point cannot raise the maximum and is done; others split into four, down to the
//! covering radius `spacing`. Distances at samples are searched to within `spacing` (the
//! candidate found is at most that much farther than the nearest). The result D satisfies
//! H <= D <= H + 2·spacing (H the true one-sided Hausdorff distance to the posed surfaces), and
//! `lower` <= H.
//!
//! With a bound B to check, a finest piece whose bound exceeds B, and whose centre is not yet
//! proven beyond B, splits on with its search tolerance shrinking with its radius, down to
//! [`finest`]`(spacing)`: the slack 2·spacing then shrinks where it decides the verdict (a run
//! at n = 1000 stays about 0.2 voxels under its stated bound, where the default spacing leaves
//! a slack of 1.6 voxels), and only the pieces near B pay for it.
//!
//! dist(c) comes from [`nearest`]'s branch and bound over (pose cluster, generator BVH node)
//! pairs in the part's frame, ending in exact point-triangle distances to posed triangles. It
//! stops early once a candidate is at most the threshold.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;

use super::geom;
use super::nearest::{self, Frames, Hit, Scratch};
use super::poses::PosedPart;
use super::Progress;

/// Where the deviation bound is reached.
#[derive(Clone, Debug, Serialize)]
pub struct DeviationPlace {
    /// The mesh sample (centre of a piece of a mesh triangle), world units.
    pub point: [f64; 3],
    /// Mesh triangle index (file order).
    pub mesh_triangle: u32,
    /// Distance from the sample to the posed generator triangle found (within `spacing` of the
    /// nearest).
    pub distance: f64,
    /// Covering radius of the sample's piece, added to the bound (0 where the bound is an
    /// exact point distance, the lower bound).
    pub radius: f64,
    /// The nearest posed triangle: part (glTF node), triangle, pose row and CSV line.
    pub node: usize,
    pub node_name: String,
    pub triangle: u32,
    pub pose_row: Option<u32>,
    pub csv_line: Option<u64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct Deviation {
    /// Upper bound: every mesh point is within this of a posed generator surface.
    pub bound: f64,
    /// A proven lower bound of the distance at some mesh point: the true value is at least this.
    pub lower: f64,
    /// Finest covering radius of the mesh samples, world units.
    pub spacing: f64,
    /// Samples (mesh triangle pieces) evaluated.
    pub samples: u64,
    pub place: Option<DeviationPlace>,
}

/// Pieces above the bound split on down to spacing / 2^this.
const EXTRA_LEVELS: i32 = 4;

/// The finest covering radius of a piece split below `spacing` (see the module's text).
pub fn finest(spacing: f64) -> f64 {
    spacing * 0.5f64.powi(EXTRA_LEVELS)
}

/// A sample that sets the bound: centre, mesh triangle, distance, radius, nearest posed triangle.
type Found = (DVec3, u32, f64, f64, Hit);

/// Bound the deviation of the mesh `tris` from the posed `parts`, finer near `limit`: the bound
/// to check, if any, and the motion's reach (a centre farther than the bound from every posed
/// surface is beyond it only by more than the reach; 0 for discrete motion).
pub fn check(
    parts: &[PosedPart],
    tris: &[[DVec3; 3]],
    spacing: f64,
    limit: Option<(f64, f64)>,
    progress: &dyn Progress,
) -> Deviation {
    // Largest exact point distance found so far (f64 bits of a non-negative number order
    // like the number), and the largest bound of a finest-level piece with its place.
    let lower = AtomicU64::new(0f64.to_bits());
    let best: Mutex<(f64, Option<Found>)> = Mutex::new((0.0, None));
    let samples = AtomicU64::new(0);
    let done = AtomicU64::new(0);
    let total = tris.len() as u64;
    // Seed the known maximum with exact distances at every mesh triangle's centroid: pieces
    // stop as soon as their bound is below it, so a maximum known early (rather than found
    // piece by piece) spares most of the refinement.
    let frames: Vec<Frames> = parts.iter().map(Frames::new).collect();
    let search = |scratch: &mut Scratch, p: DVec3, threshold: f64, tol: f64| {
        nearest::nearest(parts, &frames, scratch, p, threshold, tol)
    };
    let seed = tris
        .par_iter()
        .map_init(Scratch::default, |s, t| {
            search(s, geom::ball(t).0, f64::NEG_INFINITY, spacing).1
        })
        .reduce(|| 0.0, f64::max);
    lower.store(seed.to_bits(), Ordering::Relaxed);
    tris.par_iter()
        .enumerate()
        .for_each_init(Scratch::default, |scratch, (ti, tri)| {
            let mut stack = vec![*tri];
            while let Some(piece) = stack.pop() {
                samples.fetch_add(1, Ordering::Relaxed);
                let (c, r) = geom::ball(&piece);
                let known = f64::from_bits(lower.load(Ordering::Relaxed));
                let (hit, at_least) = search(scratch, c, known - r, spacing.min(r));
                if hit.dist + r <= known {
                    continue;
                }
                lower.fetch_max(at_least.to_bits(), Ordering::Relaxed);
                // A finest piece bounds its points by dist + r; a coarser one only proves that the
                // maximum is at least `at_least` (and splits). Near the limit, finer still.
                let undecided = limit.is_some_and(|(b, reach)| {
                    hit.dist + r > b && at_least - reach <= b && r > finest(spacing)
                });
                let terminal = r <= spacing && !undecided;
                let (value, radius) = if terminal {
                    (hit.dist + r, r)
                } else {
                    (at_least, 0.0)
                };
                {
                    let mut b = best.lock().expect("no panics while held");
                    if value > b.0 {
                        *b = (value, Some((c, ti as u32, hit.dist, radius, hit)));
                    }
                }
                if !terminal {
                    stack.extend(geom::split4(&piece));
                }
            }
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            if d % 64 == 0 || d == total {
                progress.advance(d, total);
            }
        });
    let lower = f64::from_bits(lower.into_inner());
    let (bound, place) = best.into_inner().expect("no panics while held");
    let place = place.map(|(c, ti, dist, r, hit)| {
        let part = &parts[hit.part as usize];
        let pose = &part.poses[hit.pose as usize];
        DeviationPlace {
            point: c.to_array(),
            mesh_triangle: ti,
            distance: dist,
            radius: r,
            node: part.node_index,
            node_name: part.name.clone(),
            triangle: hit.tri,
            pose_row: pose.row,
            csv_line: pose.line,
        }
    });
    Deviation {
        bound,
        lower,
        spacing,
        samples: samples.into_inner(),
        place,
    }
}
