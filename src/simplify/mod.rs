//! Bounded simplification of the voxel boundary by edge collapses (paper section 5), with the
//! sound checks argued in docs/design.md:
//!
//! - tolerance: every new triangle lies in the tolerance volume T, the points within
//!   `tolerance.outside` of an outside voxel's centre and within `tolerance.inside` of an inside
//!   one's (adaptive pieces with exact distances, `band::Proximity::triangle_within`; pieces near
//!   T's edge by the Voronoi cells of their nearest centres, `cover`), so it
//!   stays at least δ - outside from the swept volume and within inside + δ + μ + 2ρ of it;
//! - sweep: no point of the swept volume changes its winding number: exactly, by the winding
//!   number of the old and new triangles at one point of each of the swept volume's connected
//!   pieces (`pieces`, where the job's are known), else sufficiently, by every point of the region
//!   between the old and the new surface (`between`) or of the tetrahedra joining the old
//!   triangles to the new vertex being within `sweep` < δ of an outside voxel's centre;
//! - no self-intersection: new triangles are tested against the triangles near them (a spatial
//!   hash) and each other, conservatively (`intersect::conflict_with_normals`);
//! - topology: only edges with two faces whose endpoints are manifold and satisfy the link
//!   condition collapse, so the mesh stays watertight and no fan is torn; no face may flip.
//!
//! Candidates are ordered by quadric error (Garland and Heckbert), cheapest first; a target
//! triangle count stops early. Units: grid units (one voxel edge = 1).
//!
//! The loop below (`simplify_in_pool`) runs these phases, batch after batch: `quadric` prices
//! each edge, `queue` holds the candidates cheapest first, `batch` draws up to `BATCH` (64) whose
//! regions are disjoint from those in flight, `region` checks each on a copy of its region
//! (topology, flips, band, sweep), `state` checks the survivors against the committed mesh
//! (self-intersection) and commits them. The block by block simplifier (`blocked`) runs the same
//! checks one candidate at a time per block, and once per block remeshes whole disc patches in
//! one checked step (`discs`).

use std::collections::{HashMap, VecDeque};
use std::sync::Mutex;

use rayon::prelude::*;

use crate::mesh::classify::Classifier;
use crate::mesh::Mesh;
pub use band::Tolerance;

pub(crate) mod band;
mod batch;
mod between;
pub mod blocked;
mod clusters;
mod cover;
mod discs;
mod extruded;
pub(crate) mod intersect;
pub mod pieces;
mod quadric;
mod queue;
mod region;
mod state;

use batch::{Gatherer, InFlight};
use pieces::Pieces;
use queue::Queue;
use state::{Plan, Region, Reject, Scratch, State};

/// Candidates checked together (in parallel); results do not depend on the thread count.
const BATCH: usize = 64;

/// How often a long pass says how far it is.
const PROGRESS_EVERY: std::time::Duration = std::time::Duration::from_secs(30);

/// Edge of the triangle hash's cells, grid units (triangles span a few voxels). With the cells'
/// faces off the lattice (`intersect::CELL_OFFSET`), 3 measured 2-3% faster than 2 at n = 256
/// and 512 and 4 no better (docs/perf-log.md, "The hash's cells off the lattice").
const HASH_CELL: f64 = 3.0;

/// The rule for lists pruned when full (the queue's FIFO and buckets, the triangle hash's
/// cells): after pruning, grow by the whole capacity when less than a quarter was freed, so
/// pushes stay amortized O(1) even where most entries are live. The room to reserve.
pub(crate) fn regrow(len: usize, capacity: usize) -> usize {
    if len * 4 > capacity * 3 {
        capacity
    } else {
        0
    }
}

/// What the simplifier may do, grid units.
#[derive(Clone, Copy, Debug)]
pub struct SimplifyOptions {
    /// The tolerance volume every new triangle must lie in.
    pub tolerance: Tolerance,
    /// Every point swept by a collapse must lie within this of an outside voxel's centre (below
    /// δ, so the sweep never passes over a point of the swept volume).
    pub sweep: f64,
    /// Smallest piece radius the adaptive region tests refine to before they reject.
    pub min_radius: f64,
    /// Stop once the mesh has at most this many triangles (the checks always win).
    pub target_triangles: usize,
}

/// Smallest piece the adaptive region tests refine to before rejecting, voxels.
const MIN_RADIUS_VOXELS: f64 = 0.05;
/// Kept between the swept region's radius and δ, voxels.
const SWEEP_MARGIN_VOXELS: f64 = 0.05;
/// Largest radius the simplifier decides (exact centre distances reach 2.5 voxels), voxels.
const RADIUS_CAP_VOXELS: f64 = band::CENTRE_REACH - 0.05;

impl SimplifyOptions {
    /// The radii for a run's parameters (world units, voxel edge `h`), in voxels:
    /// outside = inside = ε + √3h/2 (T then holds the ε-neighbourhood of ∂W: a point within ε
    /// of a face is within ε + √3h/2 of both its voxels' centres), sweep = δ - 0.05h; each
    /// clamped to what the proximity memo decides (smaller radii stay sound). Refused unless ε + √3h/2 < δ (docs/design.md: a
    /// point of T is then at least δ - ε - √3h/2 from the swept volume).
    pub fn for_params(
        params: &crate::input::grid::Params,
        h: f64,
        target_triangles: usize,
    ) -> anyhow::Result<SimplifyOptions> {
        let outside = (params.epsilon / h + band::HALF_DIAGONAL).min(RADIUS_CAP_VOXELS);
        let opts = SimplifyOptions {
            tolerance: Tolerance {
                outside,
                inside: outside,
            },
            sweep: (params.delta / h - SWEEP_MARGIN_VOXELS).min(RADIUS_CAP_VOXELS),
            min_radius: MIN_RADIUS_VOXELS,
            target_triangles,
        };
        if outside >= params.delta / h || params.epsilon / h <= opts.min_radius {
            return Err(crate::error::OptionError::new(
                crate::error::OptionKey::Epsilon,
                format!(
                    "ε = {} is too large for δ = {}: the simplifier needs ε + √3h/2 < δ; lower $epsilon or raise $delta",
                    params.epsilon, params.delta
                ),
            )
            .into());
        }
        Ok(opts)
    }
}

/// Counts of what happened, for the report and the tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SimplifyStats {
    pub collapses: u64,
    /// Collapses that kept the surface's point set (flat or straight-crease vertices merged
    /// along it: `Region::keeps_surface`).
    pub collapses_in_plane: u64,
    pub rejected_topology: u64,
    pub rejected_flip: u64,
    pub rejected_band: u64,
    pub rejected_sweep: u64,
    pub rejected_intersection: u64,
    /// Collapses a block's (or group's) pass left to a later pass: they would have moved the
    /// surface onto its box (docs/design.md, "Blocks").
    pub deferred_at_block_border: u64,
    /// Disc patches remeshed in one step (`discs`), and the vertices they removed.
    #[serde(default)]
    pub discs: u64,
    #[serde(default)]
    pub disc_vertices: u64,
    /// Blocks, groups of blocks and seam passes whose pass, with crossings tested against the
    /// neighbours only, ended with a crossing pair and was done again testing every near
    /// triangle (`blocked`).
    #[serde(default)]
    pub blocks_redone: u64,
    /// Clusters made one vertex at a block's start (`clusters`), summed over its levels (a
    /// cluster of a coarser level's vertices counts again), and the vertices they removed.
    #[serde(default)]
    pub clusters: u64,
    #[serde(default)]
    pub cluster_vertices: u64,
    /// Groups of blocks (2×2×2, then groups of those) simplified together after their blocks,
    /// their seams inside the group free (`blocked`).
    #[serde(default)]
    pub groups: u64,
}

impl SimplifyStats {
    fn count(&mut self, why: Reject) {
        *match why {
            Reject::Topology => &mut self.rejected_topology,
            Reject::Flip => &mut self.rejected_flip,
            Reject::Band => &mut self.rejected_band,
            Reject::Sweep => &mut self.rejected_sweep,
            Reject::Intersection => &mut self.rejected_intersection,
            Reject::Border => &mut self.deferred_at_block_border,
        } += 1;
    }

    fn add(&mut self, o: &SimplifyStats) {
        self.collapses += o.collapses;
        self.collapses_in_plane += o.collapses_in_plane;
        self.rejected_topology += o.rejected_topology;
        self.rejected_flip += o.rejected_flip;
        self.rejected_band += o.rejected_band;
        self.rejected_sweep += o.rejected_sweep;
        self.rejected_intersection += o.rejected_intersection;
        self.deferred_at_block_border += o.deferred_at_block_border;
        self.discs += o.discs;
        self.disc_vertices += o.disc_vertices;
        self.blocks_redone += o.blocks_redone;
        self.clusters += o.clusters;
        self.cluster_vertices += o.cluster_vertices;
        self.groups += o.groups;
    }
}

/// Simplify `mesh` (the voxel boundary of `cls`) within the bands of `opts`.
pub fn simplify(mesh: &Mesh, cls: &Classifier, opts: SimplifyOptions) -> (Mesh, SimplifyStats) {
    simplify_until(mesh.clone(), cls, opts, &|| false).expect("never stopped")
}

/// [`simplify`], asking `stop` between batches of candidates (milliseconds apart): None when it
/// said yes. Takes the mesh so that its memory serves the simplifier's state.
pub fn simplify_until(
    mesh: Mesh,
    cls: &Classifier,
    opts: SimplifyOptions,
    stop: &(dyn Fn() -> bool + Sync),
) -> Option<(Mesh, SimplifyStats)> {
    // On a worker of the pool, the loop's own thread takes part in the parallel checks (a
    // caller outside the pool would sleep through each and wait to be woken).
    rayon::scope(|_| simplify_in_pool(mesh, cls, opts, stop))
}

fn simplify_in_pool(
    mesh: Mesh,
    cls: &Classifier,
    opts: SimplifyOptions,
    stop: &(dyn Fn() -> bool + Sync),
) -> Option<(Mesh, SimplifyStats)> {
    let s = State::new(mesh);
    let heap = Queue::new(all_edges(&s));
    let s = run_batches(s, heap, HashMap::new(), cls, None, opts, stop)?;
    Some((s.compact(), s.stats))
}

/// Every edge of the mesh as a candidate, once.
fn all_edges(s: &State) -> Vec<queue::Candidate> {
    let mut all = Vec::with_capacity(3 * s.tris.len() / 2);
    for tri in &s.tris {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            if a < b {
                all.push(s.candidate(a, b));
            }
        }
    }
    all
}

/// The radii the proximity memo decides (a checked precondition of every pass).
fn check_radii(opts: &SimplifyOptions) {
    let radii = [opts.tolerance.outside, opts.tolerance.inside, opts.sweep];
    assert!(
        opts.min_radius > 0.0
            && radii
                .iter()
                .all(|r| (band::HALF_DIAGONAL..band::CENTRE_REACH).contains(r))
    );
}

/// Collapses candidates from `heap` in batches until none is left (or the target count is
/// reached); `parked` holds rejected edges by endpoint, retried when a collapse changes the
/// triangles around them. None when `stop` said yes.
fn run_batches(
    mut s: State,
    mut heap: Queue,
    mut parked: HashMap<u32, Vec<u32>>,
    cls: &Classifier,
    pieces: Option<&Pieces>,
    opts: SimplifyOptions,
    stop: &(dyn Fn() -> bool + Sync),
) -> Option<State> {
    check_radii(&opts);
    let t_count = s.tris.len();
    // One scratch per worker thread, kept across batches.
    let scratches: Vec<Mutex<Scratch>> = (0..rayon::current_num_threads())
        .map(|_| Mutex::new(Scratch::new(cls, pieces, t_count)))
        .collect();
    let scratch = || {
        let worker = rayon::current_thread_index().unwrap_or(0) % scratches.len();
        scratches[worker].lock().expect("one user per worker")
    };
    let mut gatherer = Gatherer::new(s.pos.len());
    // A pipeline of batches: the local checks of the batches in flight (on copies of their
    // regions, disjoint from one another) run as tasks on the pool while the oldest checked
    // batch commits and the next one is gathered, so a thread that finishes its share takes up
    // a later batch's checks instead of waiting for the slowest region. The self-intersection
    // checks read the committed mesh. Batches, and so the result, do not depend on the thread
    // count or on the order in which the tasks run.
    let check = |r: &Region| r.check(&mut scratch(), &opts, r.target());
    rayon::scope_fifo(|pool| {
        let mut ready: Vec<((u32, u32), Result<Plan, Reject>)> = Vec::new();
        let mut in_flight = VecDeque::new();
        let mut deferred = Vec::new();
        for _ in 1..batch::IN_FLIGHT {
            let (batch, later) = gatherer.gather(&s, &mut heap);
            in_flight.push_back(InFlight::start(pool, batch, &check));
            deferred.extend(later);
        }
        // Progress on long passes (the seam pass at n = 4096 runs for minutes): a line every
        // `PROGRESS_EVERY`.
        let mut said = std::time::Instant::now();
        loop {
            if stop() {
                return None;
            }
            if said.elapsed() >= PROGRESS_EVERY {
                said = std::time::Instant::now();
                tracing::info!(
                    "simplifying: {} triangles left after {} collapses",
                    s.live_tris,
                    s.stats.collapses
                );
            }
            let target = opts.target_triangles;
            if s.commit_batch(&mut heap, &mut parked, ready, deferred, target) {
                break;
            }
            let (gathered, later) = gatherer.gather(&s, &mut heap);
            in_flight.push_back(InFlight::start(pool, gathered, &check));
            deferred = later;
            let (keys, local) = in_flight.pop_front().expect("batches in flight").wait();
            let checked: Vec<_> = local
                .into_par_iter()
                .map(|outcome| {
                    let plan = outcome?;
                    if !plan.in_plane {
                        s.crosses_nothing(&mut scratch().crossing, &plan)?;
                    }
                    Ok(plan)
                })
                .collect();
            ready = keys.into_iter().zip(checked).collect();
            // Empty batches in flight after an empty one mean an empty queue: a candidate is
            // deferred only for meeting the regions in flight, so the last gather took the
            // first current candidate (its cap on deferrals was not reached before it).
            if ready.is_empty() && deferred.is_empty() && in_flight.iter().all(InFlight::is_empty) {
                break;
            }
        }
        Some(s)
    })
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::intersect::conflict;
    use super::region::IdSet;
    use super::region::Region;
    use super::*;
    use crate::mesh::classify::test_support::boxed;
    use crate::mesh::extract::extract;
    use crate::simplify::band::dist_to_centre;

    /// A band refusal parks its edge to be tried again after a neighbour's collapse; the
    /// retry's refusal does not, until one of the edge's ends changes (other refusals always
    /// park).
    #[test]
    fn an_edge_refused_by_the_band_is_retried_once_per_state_of_its_ends() {
        let cls = crate::mesh::classify::test_support::random([8, 8, 8], 1);
        let mut s = State::new(extract(&cls));
        let [a, b, _] = s.tris[0];
        let mut heap = Queue::new(Vec::new());
        let mut parked: HashMap<u32, Vec<u32>> = HashMap::new();
        let mut refuse = |s: &mut State, why: Reject| {
            parked.clear(); // as a neighbour's collapse takes the edge out to retry it
            s.commit_batch(
                &mut heap,
                &mut parked,
                vec![((a, b), Err(why))],
                Vec::new(),
                0,
            );
            parked.get(&a).is_some_and(|l| l.contains(&b))
        };
        assert!(refuse(&mut s, Reject::Band), "the first refusal parks");
        assert!(
            !refuse(&mut s, Reject::Band),
            "the retry's refusal does not"
        );
        assert!(!refuse(&mut s, Reject::Band));
        assert!(refuse(&mut s, Reject::Flip), "other refusals park");
        s.version[b as usize] += 1;
        assert!(
            refuse(&mut s, Reject::Band),
            "a changed end starts the count again"
        );
        assert!(!refuse(&mut s, Reject::Band));
        assert_eq!(s.stats.rejected_band, 5);
    }

    /// The flip test on the live mesh (`State::flips`, which a block's pass asks before copying
    /// a region) says yes exactly where the region's checks refuse a collapse for a flip, at
    /// targets near and off each edge of rough random surfaces, some of them already coarsened:
    /// a yes is always a refusal there (Flip, or Topology found first), and every Flip refusal
    /// is a yes. Both answers occur.
    #[test]
    fn flips_on_the_live_mesh_agree_with_the_region_check() {
        let (mut yes, mut no) = (0, 0);
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        let mut unit = || {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for case in 0..3 {
            let cls = crate::mesh::classify::test_support::random([12, 12, 12], case);
            let opts = defaults();
            let mut start = extract(&cls);
            if case > 0 {
                // Coarsened part of the way, so that stars are larger and less regular.
                let target_triangles = start.triangles.len() * (4 - case as usize) / 4;
                let coarser = SimplifyOptions {
                    target_triangles,
                    ..opts
                };
                start = simplify(&start, &cls, coarser).0;
            }
            let s = State::new(start);
            let mut scratch = Scratch::new(&cls, None, s.tris.len());
            let live: Vec<[u32; 3]> = (0..s.tris.len())
                .filter(|&t| s.tri_alive[t])
                .map(|t| s.tris[t])
                .collect();
            for tri in live.iter().step_by(5) {
                let (a, b) = (tri[0], tri[1]);
                let mid = (s.pos[a as usize] + s.pos[b as usize]) / 2.0;
                let off = DVec3::new(unit(), unit(), unit()) * 3.0;
                for v in [s.best_target(a, b).1, mid, mid + off] {
                    let flips = s.flips(a, b, v);
                    let outcome = s.region(a, b).check(&mut scratch, &opts, v);
                    if flips {
                        yes += 1;
                        assert!(
                            matches!(outcome, Err(Reject::Flip | Reject::Topology)),
                            "edge ({a}, {b}) to {v}: flips, but the region check says {:?}",
                            outcome.as_ref().err()
                        );
                    } else {
                        no += 1;
                        assert!(
                            !matches!(outcome, Err(Reject::Flip)),
                            "edge ({a}, {b}) to {v}: a Flip refusal that State::flips missed"
                        );
                    }
                }
            }
        }
        assert!(
            yes > 50 && no > 50,
            "{yes} flips and {no} not: both should occur"
        );
    }

    /// The sweep check by pieces, wired in: a collapse whose old and new triangles wind around a
    /// piece's point is rejected (Sweep), the same collapse with the piece far away passes.
    /// Points are found where the region between the surfaces has winding number ±1.
    #[test]
    fn a_collapse_winding_around_a_piece_is_rejected() {
        let mut found = 0;
        for seed in 0..3 {
            let cls = crate::mesh::classify::test_support::random([14, 14, 14], seed);
            let s = State::new(extract(&cls));
            let mut plain = Scratch::new(&cls, None, s.tris.len());
            for t in (0..s.tris.len()).step_by(7) {
                let tri = s.tris[t];
                let (a, b) = (tri[0], tri[1]);
                let v = (s.pos[a as usize] + s.pos[b as usize]) / 2.0;
                let region = s.region(a, b);
                let Ok(plan) = region.check(&mut plain, &defaults(), v) else {
                    continue;
                };
                if plan.in_plane {
                    continue;
                }
                let place = |u: u32| s.tris[u as usize].map(|x| s.pos[x as usize]);
                let moved: Vec<u32> = plan.changed.iter().map(|c| c.0).collect();
                let mut surface: Vec<[DVec3; 3]> = plan
                    .around
                    .iter()
                    .filter(|u| plan.shared.contains(u) || moved.contains(u))
                    .map(|&u| place(u))
                    .collect();
                surface.extend(plan.new.iter().map(|(_, q)| [q[0], q[2], q[1]]));
                // Between the moving endpoints' old places and v.
                let Some(p) = [0.25, 0.5, 0.75]
                    .into_iter()
                    .flat_map(|f| [s.pos[a as usize], s.pos[b as usize]].map(|e| e + (v - e) * f))
                    .find(|&p| (pieces::winding(&surface, p).abs() - 1.0).abs() < 1e-9)
                else {
                    continue;
                };
                found += 1;
                let near = pieces::Pieces::from_points(vec![[p, p]]);
                let far = pieces::Pieces::from_points(vec![[p + 50.0, p + 50.0]]);
                let with = |pieces: &pieces::Pieces| {
                    let mut scratch = Scratch::new(&cls, Some(pieces), s.tris.len());
                    region.check(&mut scratch, &defaults(), v).map(|_| ())
                };
                assert!(
                    matches!(with(&near), Err(Reject::Sweep)),
                    "seed {seed}, edge {a}-{b}"
                );
                assert!(with(&far).is_ok(), "seed {seed}, edge {a}-{b}");
            }
        }
        assert!(
            found > 20,
            "only {found} collapses with a point between the surfaces"
        );
    }

    /// Brute force: whether `p` lies in the tolerance volume of `opts`.
    pub(super) fn in_volume(cls: &Classifier, p: DVec3, opts: SimplifyOptions) -> bool {
        dist_to_centre(cls, p, false, opts.tolerance.outside).is_some()
            && dist_to_centre(cls, p, true, opts.tolerance.inside).is_some()
    }

    /// Whether voxel (i, j, k) is inside W and farther than `opts.sweep` from every outside
    /// voxel's centre: what no collapse may sweep over.
    pub(super) fn deep(cls: &Classifier, [i, j, k]: [isize; 3], opts: SimplifyOptions) -> bool {
        let c = DVec3::new(i as f64, j as f64, k as f64) + 0.5;
        cls.inside(i, j, k) && dist_to_centre(cls, c, false, opts.sweep).is_none()
    }

    /// Generalized winding number of a closed mesh at `p` (solid angles, Van Oosterom and
    /// Strackee).
    pub(super) fn winding_number(m: &Mesh, p: DVec3) -> f64 {
        let mut sum = 0.0;
        for t in &m.triangles {
            let [a, b, c] = t.map(|v| m.positions[v as usize] - p);
            let (la, lb, lc) = (a.length(), b.length(), c.length());
            let num = a.dot(b.cross(c));
            let den = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
            sum += 2.0 * num.atan2(den);
        }
        sum / (4.0 * std::f64::consts::PI)
    }

    fn defaults() -> SimplifyOptions {
        SimplifyOptions {
            tolerance: Tolerance {
                outside: 1.732,
                inside: 1.732,
            },
            sweep: 1.9,
            min_radius: 0.05,
            target_triangles: 0,
        }
    }

    /// The radii the report's clearance and bound are derived from (docs/design.md).
    #[test]
    fn radii_follow_the_parameters() {
        use crate::input::grid::{fit_grid, Accuracy, Overrides, Radii};
        for radii in [Radii::Exact, Radii::Paper] {
            let overrides = Overrides {
                radii,
                ..Overrides::default()
            };
            let (g, p) = fit_grid(
                DVec3::ZERO,
                DVec3::ONE,
                Accuracy::Resolution(64),
                overrides,
                0.0,
            )
            .unwrap();
            let o = SimplifyOptions::for_params(&p, g.h, 0).unwrap();
            let r = p.epsilon / g.h + 3f64.sqrt() / 2.0;
            assert!((o.tolerance.outside - r).abs() < 1e-12, "{radii:?} {o:?}");
            assert!((o.tolerance.inside - r).abs() < 1e-12, "{radii:?} {o:?}");
            assert!(
                (o.sweep - (p.delta / g.h - 0.05)).abs() < 1e-12,
                "{radii:?} {o:?}"
            );
            assert!(o.tolerance.outside < p.delta / g.h && o.tolerance.outside <= o.sweep);
        }
    }

    #[test]
    fn a_block_of_voxels_simplifies_to_a_box_of_twelve_triangles() {
        let cls = boxed([8, 8, 8], [2.0, 2.0, 2.0], [6.0, 6.0, 6.0]);
        let start = extract(&cls);
        assert_eq!(start.triangles.len(), 6 * 16 * 2);
        // With radius 1.2 no cut of a corner stays in T; with the default 1.732 one can (a cut
        // plane near a corner stays within 1.732 of the outside centres beside the faces).
        let tight = SimplifyOptions {
            tolerance: Tolerance {
                outside: 1.2,
                inside: 1.2,
            },
            sweep: 1.2,
            ..defaults()
        };
        let (out, stats) = simplify(&start, &cls, tight);
        assert_eq!(out.triangles.len(), 12, "{stats:?}");
        assert_eq!(out.positions.len(), 8);
        assert!(out.unpaired_edges().is_empty());
        assert!(
            (out.volume() - 64.0).abs() < 1e-9,
            "volume {}",
            out.volume()
        );
    }

    /// One voxel, the unit cube [1, 2]³: collapses cut it only as far as T allows (every
    /// sampled point of every output triangle in T by brute force), more with a wider T.
    #[test]
    fn one_voxel_is_cut_only_as_far_as_the_volume_allows() {
        let cls = boxed([3, 3, 3], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]);
        let start = extract(&cls);
        let mut rng = fastrand::Rng::with_seed(3);
        let mut counts = Vec::new();
        for r in [0.87, 1.05] {
            let opts = SimplifyOptions {
                tolerance: Tolerance {
                    outside: r,
                    inside: r,
                },
                sweep: r,
                min_radius: 0.01,
                target_triangles: 0,
            };
            let (out, stats) = simplify(&start, &cls, opts);
            assert!(out.unpaired_edges().is_empty());
            assert!(out.volume() > 0.0 && out.volume() < 1.0 + 1e-12);
            for t in &out.triangles {
                let p = t.map(|v| out.positions[v as usize]);
                for _ in 0..500 {
                    let (a, b) = (rng.f64(), rng.f64());
                    let (a, b) = if a + b > 1.0 {
                        (1.0 - a, 1.0 - b)
                    } else {
                        (a, b)
                    };
                    let x = p[0] + (p[1] - p[0]) * a + (p[2] - p[0]) * b;
                    assert!(in_volume(&cls, x, opts), "r {r}: {x} out of T, {stats:?}");
                }
            }
            counts.push(out.triangles.len());
        }
        // The middle of the cube is exactly 1 from six outside centres: radius 1.05 lets the cube
        // go down to a tetrahedron, 0.87 does not.
        assert!(counts[0] > counts[1] && counts[1] == 4, "{counts:?}");
    }

    /// Review finding: small isolated components collapsed to two coincident triangles of
    /// volume 0 (a tetrahedron's edge collapse) under the default band.
    #[test]
    fn small_components_never_collapse_to_coincident_triangles() {
        for hi in [
            [2.0, 2.0, 2.0],
            [2.0, 2.0, 3.0],
            [2.0, 2.0, 4.0],
            [2.0, 3.0, 3.0],
        ] {
            let cls = boxed([4, 5, 6], [1.0, 1.0, 1.0], hi);
            let (out, _) = simplify(&extract(&cls), &cls, defaults());
            assert!(out.unpaired_edges().is_empty());
            assert!(out.volume() > 0.1, "box to {hi:?}: volume {}", out.volume());
            let mut keys: Vec<[u32; 3]> = out
                .triangles
                .iter()
                .map(|t| {
                    let mut k = *t;
                    k.sort_unstable();
                    k
                })
                .collect();
            keys.sort_unstable();
            let n = keys.len();
            keys.dedup();
            assert_eq!(keys.len(), n, "box to {hi:?}: duplicate triangles");
        }
    }

    /// Collapses that skip the geometric checks must leave the surface the same point set:
    /// on a block and rough random voxel sets, every collapse `check` marks `in_plane` (flat vertices and
    /// straight creases, to either endpoint) is applied, and the triangles around it before and
    /// after cover the same points (dense samples of each on the other, equal areas).
    #[test]
    fn in_plane_collapses_keep_the_surface_point_set() {
        let area = |t: &[DVec3; 3]| (t[1] - t[0]).cross(t[2] - t[0]).length() / 2.0;
        let samples = |t: &[DVec3; 3]| {
            let mut out = Vec::new();
            for i in 0..=6 {
                for j in 0..=6 - i {
                    let (u, v) = (i as f64 / 6.0, j as f64 / 6.0);
                    out.push(t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v);
                }
            }
            out
        };
        let covered = |p: DVec3, by: &[[DVec3; 3]]| {
            by.iter()
                .any(|t| crate::verify::geom::dist_triangle(p, t[0], t[1], t[2]) < 1e-9)
        };
        let (mut flat, mut crease) = (0, 0);
        let block = boxed([14, 14, 14], [2.0, 2.0, 2.0], [12.0, 12.0, 12.0]);
        let rough =
            (0..3).map(|seed| crate::mesh::classify::test_support::random([14, 14, 14], seed));
        for (seed, cls) in std::iter::once(block).chain(rough).enumerate() {
            let mut s = State::new(extract(&cls));
            let mut scratch = Scratch::new(&cls, None, s.tris.len());
            for round in 0..4 {
                for t in 0..s.tris.len() {
                    if !s.tri_alive[t] {
                        continue;
                    }
                    let tri = s.tris[t];
                    let (a, b) = (tri[round % 3] as usize, tri[(round + 1) % 3] as usize);
                    let v = if round % 2 == 0 { s.pos[a] } else { s.pos[b] };
                    let region = s.region(a as u32, b as u32);
                    let Ok(plan) = region.check(&mut scratch, &defaults(), v) else {
                        continue;
                    };
                    if !plan.in_plane {
                        continue;
                    }
                    let moving = if v == s.pos[a] { b } else { a };
                    let t0 = s.tris[s.star[moving][0] as usize].map(|x| s.pos[x as usize]);
                    let n0 = (t0[1] - t0[0]).cross(t0[2] - t0[0]);
                    let is_flat = s.star[moving].iter().all(|&u| {
                        s.tris[u as usize]
                            .iter()
                            .all(|&x| n0.dot(s.pos[x as usize] - t0[0]) == 0.0)
                    });
                    if is_flat {
                        flat += 1;
                    } else {
                        crease += 1;
                    }
                    let mut around: Vec<u32> =
                        s.star[a].iter().chain(&s.star[b]).copied().collect();
                    around.sort_unstable();
                    around.dedup();
                    let before: Vec<[DVec3; 3]> = around
                        .iter()
                        .map(|&u| s.tris[u as usize].map(|x| s.pos[x as usize]))
                        .collect();
                    assert!(s.commit(plan, &mut Vec::new()));
                    let after: Vec<[DVec3; 3]> = around
                        .iter()
                        .filter(|&&u| s.tri_alive[u as usize])
                        .map(|&u| s.tris[u as usize].map(|x| s.pos[x as usize]))
                        .collect();
                    for (from, to) in [(&before, &after), (&after, &before)] {
                        for t in from.iter() {
                            for p in samples(t) {
                                assert!(covered(p, to), "seed {seed}: {p} left uncovered");
                            }
                        }
                    }
                    let (a0, a1): (f64, f64) =
                        (before.iter().map(area).sum(), after.iter().map(area).sum());
                    assert!((a0 - a1).abs() < 1e-9 * a0, "area {a0} -> {a1}");
                }
            }
        }
        assert!(flat > 100 && crease > 100, "flat {flat}, crease {crease}");
    }

    /// A block's pass files its triangles in the hash only after the collapses that keep the
    /// surface (`State::unfiled`): filed then, every live triangle is found from its own
    /// points, in its reshaped form, as the self-intersection checks assume.
    #[test]
    fn triangles_filed_after_in_plane_collapses_are_found() {
        let cls = crate::mesh::classify::test_support::random([14, 14, 14], 7);
        let mut s = State::unfiled(extract(&cls), None);
        let mut scratch = Scratch::new(&cls, None, s.tris.len());
        let mut collapsed = 0;
        for t in 0..s.tris.len() {
            if !s.tri_alive[t] {
                continue;
            }
            let [a, b, _] = s.tris[t];
            let region = s.region(a, b);
            match region.check(&mut scratch, &defaults(), s.pos[a as usize]) {
                Ok(plan) if plan.in_plane => {
                    assert!(s.commit(plan, &mut Vec::new()));
                    collapsed += 1;
                }
                _ => {}
            }
        }
        assert!(collapsed > 50, "{collapsed} collapses in a plane");
        s.file();
        let hash = s.hash.as_ref().expect("filed");
        let mut near = Vec::new();
        for t in (0..s.tris.len()).filter(|&t| s.tri_alive[t]) {
            let p = s.tris[t].map(|x| s.pos[x as usize]);
            hash.near(&p, &mut near);
            assert!(
                near.contains(&(t as u32)),
                "triangle {t} at {p:?} not filed"
            );
        }
    }

    /// Batches in flight never share a vertex of their regions, and the first batch is full
    /// (later ones are, or stopped at the cap on deferrals): four batches gathered back to
    /// back from a fresh block, each against the `IN_FLIGHT - 1` before it.
    #[test]
    fn batches_in_flight_have_disjoint_regions() {
        let cls = boxed([30, 30, 30], [2.0, 2.0, 2.0], [28.0, 28.0, 28.0]);
        let s = State::new(extract(&cls));
        let mut all = Vec::new();
        for tri in &s.tris {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                if a < b {
                    all.push(s.candidate(a, b));
                }
            }
        }
        let total = all.len();
        let mut heap = Queue::new(all);
        let mut gatherer = Gatherer::new(s.pos.len());
        let vertices = |batch: &[Region]| -> Vec<u32> {
            let mut v: Vec<u32> = batch
                .iter()
                .flat_map(|r| r.verts.iter().map(|x| x.0))
                .collect();
            v.sort_unstable();
            v
        };
        let mut previous: VecDeque<Vec<u32>> = VecDeque::new();
        let mut deferred = 0;
        for round in 0..4 {
            let (batch, later) = gatherer.gather(&s, &mut heap);
            assert!(
                batch.len() == BATCH || (round > 0 && later.len() == batch::DEFER_AT_MOST),
                "round {round}: a batch of {} with {} deferred",
                batch.len(),
                later.len()
            );
            let mut here = vertices(&batch);
            let count = here.len();
            here.dedup();
            assert_eq!(
                here.len(),
                count,
                "round {round}: regions of one batch overlap"
            );
            assert!(
                (previous.iter()).all(|p| here.iter().all(|v| p.binary_search(v).is_err())),
                "round {round}: a region meets a batch in flight"
            );
            deferred += later.len();
            previous.push_back(here);
            if previous.len() == batch::IN_FLIGHT as usize {
                previous.pop_front();
            }
        }
        assert!(
            deferred < total / 2,
            "{deferred} of {total} candidates deferred"
        );
    }

    /// The local checks of a batch in flight come back in the batch's order whichever thread
    /// ran them and however long each took, and a check that panics makes the wait panic
    /// instead of waiting forever for it.
    #[test]
    fn checks_in_flight_come_back_in_order_and_a_panic_ends_the_wait() {
        let cls = boxed([14, 14, 14], [2.0, 2.0, 2.0], [12.0, 12.0, 12.0]);
        let s = State::new(extract(&cls));
        let mut heap = Queue::new(all_edges(&s));
        let (batch, _) = Gatherer::new(s.pos.len()).gather(&s, &mut heap);
        let keys: Vec<(u32, u32)> = batch.iter().map(|r| (r.a, r.b)).collect();
        assert!(keys.len() > 8, "a batch of {}", keys.len());
        let regions = || {
            keys.iter()
                .map(|&(a, b)| s.region(a, b))
                .collect::<Vec<_>>()
        };
        let named = |a: u32| {
            Err(if a % 2 == 0 {
                Reject::Band
            } else {
                Reject::Flip
            })
        };
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        // The first check is the slowest: the others finish first, on either thread.
        let check = |r: &Region| -> Result<Plan, Reject> {
            if r.a == keys[0].0 {
                std::thread::sleep(std::time::Duration::from_millis(50));
            }
            named(r.a)
        };
        let (got, outcomes) =
            pool.install(|| rayon::scope_fifo(|p| InFlight::start(p, regions(), &check).wait()));
        assert_eq!(got, keys);
        for (&(a, _), outcome) in keys.iter().zip(&outcomes) {
            assert_eq!(
                outcome.as_ref().err(),
                named(a).err().as_ref(),
                "edge from {a}"
            );
        }
        // A check that panics: the wait ends (with a panic) within the time limit.
        let (tx, rx) = std::sync::mpsc::channel();
        let broken = keys[1].0;
        let regions = regions();
        std::thread::spawn(move || {
            let check = |r: &Region| -> Result<Plan, Reject> {
                assert!(r.a != broken, "a check that fails (on purpose)");
                Err(Reject::Band)
            };
            let waited = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                pool.install(|| rayon::scope_fifo(|p| InFlight::start(p, regions, &check).wait()))
            }));
            tx.send(waited.is_err()).unwrap();
        });
        let ended = rx.recv_timeout(std::time::Duration::from_secs(30));
        assert_eq!(
            ended,
            Ok(true),
            "the wait on a panicked check did not end in a panic"
        );
    }

    /// A gather defers at most `DEFER_AT_MOST` candidates and loses none: gathered back to back
    /// with nothing committed and the deferred ones queued again, every edge of a box is
    /// batched exactly once, and the late gathers, whose queue lies around the batches in
    /// flight, stop at the cap.
    #[test]
    fn gathers_stop_at_the_cap_and_lose_no_candidate() {
        let cls = boxed([14, 14, 14], [2.0, 2.0, 2.0], [12.0, 12.0, 12.0]);
        let s = State::new(extract(&cls));
        let all = all_edges(&s);
        let total = all.len();
        let mut heap = Queue::new(all);
        let mut gatherer = Gatherer::new(s.pos.len());
        let mut batched: Vec<(u32, u32)> = Vec::new();
        let mut capped = 0;
        loop {
            let (batch, later) = gatherer.gather(&s, &mut heap);
            assert!(
                later.len() <= batch::DEFER_AT_MOST,
                "{} deferred",
                later.len()
            );
            capped += usize::from(later.len() == batch::DEFER_AT_MOST);
            if batch.is_empty() && later.is_empty() {
                break;
            }
            batched.extend(batch.iter().map(|r| (r.a, r.b)));
            for c in later {
                s.push(&mut heap, c);
            }
        }
        let count = batched.len();
        batched.sort_unstable();
        batched.dedup();
        assert_eq!(
            (count, batched.len()),
            (total, total),
            "every edge batched once"
        );
        assert!(capped > 0, "no gather reached the cap: the test misses it");
    }

    #[test]
    fn id_set_keeps_first_occurrences_and_empties_itself() {
        let mut set = IdSet::new(200);
        let mut ids = vec![5, 130, 5, 64, 199, 130, 0, 64, 5];
        set.keep_first(&mut ids);
        assert_eq!(ids, [5, 130, 64, 199, 0]);
        let mut again = vec![199, 0, 199];
        set.keep_first(&mut again);
        assert_eq!(again, [199, 0], "the set was not emptied");
    }

    #[test]
    fn a_stop_request_ends_it_without_a_mesh() {
        let cls = boxed([8, 8, 8], [2.0, 2.0, 2.0], [6.0, 6.0, 6.0]);
        let start = extract(&cls);
        assert!(simplify_until(start.clone(), &cls, defaults(), &|| true).is_none());
        assert!(simplify_until(start, &cls, defaults(), &|| false).is_some());
    }

    #[test]
    fn target_count_stops_early() {
        let cls = boxed([8, 8, 8], [2.0, 2.0, 2.0], [6.0, 6.0, 6.0]);
        let start = extract(&cls);
        let (out, _) = simplify(
            &start,
            &cls,
            SimplifyOptions {
                target_triangles: 100,
                ..defaults()
            },
        );
        assert!(
            out.triangles.len() <= 100 && out.triangles.len() >= 98,
            "{}",
            out.triangles.len()
        );
        assert!(out.unpaired_edges().is_empty());
    }

    /// Rough random voxel sets (tunnels, pinches, thin walls): the result stays watertight and
    /// no two of its triangles meet beyond what they share. Without the intersection test every
    /// seed here ends with 6 to 34 such pairs.
    #[test]
    fn random_voxel_sets_simplify_without_self_intersection() {
        for seed in 0..3 {
            let cls = crate::mesh::classify::test_support::random([20, 20, 20], seed);
            let start = extract(&cls);
            let (out, stats) = simplify(&start, &cls, defaults());
            assert!(out.unpaired_edges().is_empty());
            assert!(out.triangles.len() * 2 < start.triangles.len(), "{stats:?}");
            assert!(stats.rejected_intersection > 0, "{stats:?}");
            // Every vertex and triangle centroid in the tolerance volume; every voxel centre of W
            // farther than the sweep radius from the outside centres still enclosed (winding
            // number 1).
            for t in &out.triangles {
                let p = t.map(|v| out.positions[v as usize]);
                for x in [p[0], (p[0] + p[1] + p[2]) / 3.0] {
                    assert!(in_volume(&cls, x, defaults()), "{x} out of the volume");
                }
            }
            let mut deep = 0;
            for k in 0..20 {
                for j in 0..20 {
                    for i in 0..20 {
                        let c = DVec3::new(i as f64, j as f64, k as f64) + 0.5;
                        if self::deep(&cls, [i, j, k], defaults()) {
                            deep += 1;
                            let w = winding_number(&out, c);
                            assert!((w - 1.0).abs() < 1e-6, "seed {seed}: {c} has winding {w}");
                        }
                    }
                }
            }
            assert!(deep > 30, "seed {seed}: only {deep} deep voxels");
            for (i, ti) in out.triangles.iter().enumerate() {
                for tj in &out.triangles[i + 1..] {
                    let [s, t] = [ti, tj].map(|x| x.map(|v| out.positions[v as usize]));
                    assert!(
                        !conflict(*ti, s, *tj, t),
                        "seed {seed}: {s:?} and {t:?} meet"
                    );
                }
            }
        }
    }

    /// The start mesh of joined voxels (a 2-manifold) simplifies to a 2-manifold, and every
    /// output point is within the band of the classifier's voxel boundary or on an unchanged
    /// face of the joined voxels, the two places the report's bounds cover.
    #[test]
    fn joined_voxel_sets_simplify_to_a_manifold() {
        let mut joined_any = 0;
        for seed in 0..3 {
            let cls = crate::mesh::classify::test_support::random([20, 20, 20], seed);
            let joined = crate::mesh::manifold::Joined::new(&cls);
            joined_any += joined.added().len();
            let start = extract(&joined);
            assert!(start.manifold_defects().is_manifold());
            let (out, stats) = simplify(&start, &cls, defaults());
            let defects = out.manifold_defects();
            assert!(defects.is_manifold(), "seed {seed}: {defects:?} {stats:?}");
            assert!(out.triangles.len() * 2 < start.triangles.len(), "{stats:?}");
            // x is on the joined voxels' boundary when the voxels whose closures hold it are of
            // both classes.
            let on_joined_face = |x: DVec3| {
                let range = |c: f64| {
                    let f = c.floor() as isize;
                    if c.fract() == 0.0 {
                        f - 1..=f
                    } else {
                        f..=f
                    }
                };
                let mut classes = [false; 2];
                for k in range(x.z) {
                    for j in range(x.y) {
                        for i in range(x.x) {
                            classes[crate::mesh::classify::VoxelSet::inside(&joined, i, j, k)
                                as usize] = true;
                        }
                    }
                }
                classes == [true; 2]
            };
            for t in &out.triangles {
                let p = t.map(|v| out.positions[v as usize]);
                for x in [p[0], (p[0] + p[1] + p[2]) / 3.0] {
                    assert!(
                        in_volume(&cls, x, defaults()) || on_joined_face(x),
                        "seed {seed}: {x} neither in the tolerance volume nor on a joined face"
                    );
                }
            }
            for k in 0..20 {
                for j in 0..20 {
                    for i in 0..20 {
                        let c = DVec3::new(i as f64, j as f64, k as f64) + 0.5;
                        if deep(&cls, [i, j, k], defaults()) {
                            let w = winding_number(&out, c);
                            assert!((w - 1.0).abs() < 1e-6, "seed {seed}: {c} has winding {w}");
                        }
                    }
                }
            }
        }
        assert!(joined_any > 0, "the random sets had no pinches to join");
    }
}
