//! Bounded simplification of the voxel boundary by edge collapses (paper section 5), with the
//! sound checks argued in docs/design.md:
//!
//! - tolerance: every new triangle lies within `eps` of ∂W (adaptive pieces with exact
//!   distances, `band::Proximity::triangle_within`), so it stays at least δ - √3/2 - eps outside the
//!   swept volume and within eps + √3/2 + δ of it where concavities are visible;
//! - sweep: every tetrahedron joining an old triangle around the edge to the new vertex holds no
//!   point of W deeper than `eps_sweep` (eps_sweep + √3/2 < δ), so the surface never passes over
//!   a point of the swept volume and every such point stays enclosed;
//! - no self-intersection: new triangles are tested against the triangles near them (a spatial
//!   hash) and each other, conservatively (`intersect::conflict`);
//! - topology: only edges with two faces whose endpoints are manifold and satisfy the link
//!   condition collapse, so the mesh stays watertight and no fan is torn; no face may flip.
//!
//! Candidates are ordered by quadric error (Garland and Heckbert), cheapest first; a target
//! triangle count stops early. Units: grid units (one voxel edge = 1).

use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashMap, VecDeque};
use std::sync::Mutex;

use rayon::prelude::*;

use glam::{DMat3, DVec3};

use crate::mesh::classify::Classifier;
use crate::mesh::Mesh;
use band::Proximity;
use intersect::{bounds, bounds_meet, boxes_meet, conflict, TriangleHash};

pub(crate) mod band;
pub(crate) mod intersect;
mod region;

use region::Region;

/// Candidates checked together (in parallel); results do not depend on the thread count.
const BATCH: usize = 64;

/// Edge of the triangle hash's cells, grid units (triangles span a few voxels).
const HASH_CELL: f64 = 2.0;

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
    /// Tolerance band half-width around ∂W for the output surface.
    pub eps: f64,
    /// Band half-width for the region swept by a collapse (must satisfy eps_sweep + √3/2 < δ).
    pub eps_sweep: f64,
    /// Smallest piece radius the adaptive region tests refine to before they reject.
    pub min_radius: f64,
    /// Stop once the mesh has at most this many triangles (the checks always win).
    pub target_triangles: usize,
}

/// Smallest piece the adaptive region tests refine to before rejecting, voxels.
const MIN_RADIUS_VOXELS: f64 = 0.05;
/// Kept between the swept region's band and the limit δ - √3h/2, voxels.
const SWEEP_MARGIN_VOXELS: f64 = 0.05;
/// Widest band the simplifier decides (exact distances reach 2 voxels), voxels.
const BAND_CAP_VOXELS: f64 = band::REACH - 0.05;

impl SimplifyOptions {
    /// The bands for a run's parameters (world units, voxel edge `h`): eps = ε and
    /// eps_sweep = δ - √3h/2 - 0.05h, in voxels, both clamped to what the proximity memo decides
    /// (narrower bands stay sound). Refused unless ε + √3h/2 < δ (docs/design.md: a point within
    /// eps of the voxel boundary is then at least δ - √3h/2 - eps from the swept volume).
    pub fn for_params(
        params: &crate::input::grid::Params,
        h: f64,
        target_triangles: usize,
    ) -> anyhow::Result<SimplifyOptions> {
        let half_diag = 3f64.sqrt() / 2.0; // voxels
        let band = SimplifyOptions {
            eps: (params.epsilon / h).min(BAND_CAP_VOXELS),
            eps_sweep: (params.delta / h - half_diag - SWEEP_MARGIN_VOXELS).min(BAND_CAP_VOXELS),
            min_radius: MIN_RADIUS_VOXELS,
            target_triangles,
        };
        if band.eps + half_diag >= params.delta / h || band.eps <= band.min_radius {
            return Err(crate::error::OptionError::new(
                crate::error::OptionKey::Epsilon,
                format!(
                    "ε = {} is too large for δ = {}: the simplifier needs ε + √3h/2 < δ; lower $epsilon or raise $delta",
                    params.epsilon, params.delta
                ),
            )
            .into());
        }
        Ok(band)
    }
}

/// Counts of what happened, for the report and the tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
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
}

impl SimplifyStats {
    fn count(&mut self, why: Reject) {
        *match why {
            Reject::Topology => &mut self.rejected_topology,
            Reject::Flip => &mut self.rejected_flip,
            Reject::Band => &mut self.rejected_band,
            Reject::Sweep => &mut self.rejected_sweep,
            Reject::Intersection => &mut self.rejected_intersection,
        } += 1;
    }
}

/// Symmetric 4x4 quadric: upper triangle of [A b; bᵀ c] for the error vᵀAv + 2bᵀv + c.
#[derive(Clone, Copy, Debug, Default)]
struct Quadric {
    a: [f64; 6], // xx xy xz yy yz zz
    b: [f64; 3],
    c: f64,
}

impl Quadric {
    /// Area-weighted plane of the triangle.
    fn plane(p: [DVec3; 3]) -> Quadric {
        let n2 = (p[1] - p[0]).cross(p[2] - p[0]);
        let area = n2.length() / 2.0;
        let Some(n) = n2.try_normalize() else {
            return Quadric::default();
        };
        let d = -n.dot(p[0]);
        Quadric {
            a: [
                n.x * n.x,
                n.x * n.y,
                n.x * n.z,
                n.y * n.y,
                n.y * n.z,
                n.z * n.z,
            ]
            .map(|x| x * area),
            b: [n.x * d, n.y * d, n.z * d].map(|x| x * area),
            c: d * d * area,
        }
    }

    fn add(&self, o: &Quadric) -> Quadric {
        Quadric {
            a: std::array::from_fn(|i| self.a[i] + o.a[i]),
            b: std::array::from_fn(|i| self.b[i] + o.b[i]),
            c: self.c + o.c,
        }
    }

    fn matrix(&self) -> DMat3 {
        let a = self.a;
        DMat3::from_cols_array(&[a[0], a[1], a[2], a[1], a[3], a[4], a[2], a[4], a[5]])
    }

    fn error(&self, v: DVec3) -> f64 {
        let b = DVec3::from_array(self.b);
        (v.dot(self.matrix() * v) + 2.0 * b.dot(v) + self.c).max(0.0)
    }

    /// The error-minimizing point, if the system is well conditioned.
    fn optimum(&self) -> Option<DVec3> {
        let m = self.matrix();
        let det = m.determinant();
        let scale = m
            .to_cols_array()
            .iter()
            .map(|x| x.abs())
            .fold(0.0, f64::max);
        (det.abs() > 1e-9 * scale * scale * scale)
            .then(|| -(m.inverse() * DVec3::from_array(self.b)))
    }
}

/// A heap entry: 16 bytes, as the heap holds about 1.5 per start triangle.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    /// Quadric error of the cheapest target (f32: only the order matters, and ties fall to
    /// [`Candidate::scatter`]).
    cost: f32,
    a: u32,
    b: u32,
    /// version[a] + version[b] when the candidate was computed. Versions only grow, so the sum
    /// changes exactly when either does: the entry is stale then (the target is recomputed
    /// when a fresh candidate is taken, keeping the heap's entries small).
    ver: u32,
}
const _: () = assert!(std::mem::size_of::<Candidate>() == 16);

impl Candidate {
    /// Tie-break among equal costs: a hash of the edge, so that equal-cost collapses (flat
    /// regions) spread over the surface instead of sweeping it in index order, and the order
    /// does not depend on the heap's history.
    fn scatter(&self) -> u64 {
        ((self.a as u64) << 32 | self.b as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
    }
}

impl PartialEq for Candidate {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Candidate {
    // Min-heap on cost; ties by edge, so the order does not depend on the heap's history.
    fn cmp(&self, o: &Self) -> Ordering {
        o.cost
            .total_cmp(&self.cost)
            .then_with(|| o.scatter().cmp(&self.scatter()))
    }
}

/// Candidates, cheapest first. Those of cost 0 (flat regions and straight creases: most of the
/// start) wait in a FIFO, first in the scattered tie order, then in the order they arise. The
/// rest wait in buckets by the top 15 bits of their cost (sign excluded: for costs ≥ 0 the bits
/// order as the values), each a small binary heap: the exact order, with short sifts that stay
/// in cache instead of one heap's ~20 levels across memory.
struct Queue {
    zero: VecDeque<Candidate>,
    buckets: Vec<BinaryHeap<Candidate>>,
    /// No greater than the first non-empty bucket.
    low: usize,
}

/// Buckets of [`Queue`]: one per value of a non-negative f32's top 16 bits.
const BUCKETS: usize = 1 << 15;

/// The bucket of a cost: negative ones (rounding) first, NaN last.
fn bucket(cost: f32) -> usize {
    if cost <= 0.0 {
        0
    } else {
        ((cost.to_bits() >> 16) as usize).min(BUCKETS - 1)
    }
}

impl Queue {
    fn new(mut all: Vec<Candidate>) -> Queue {
        // [costly | free]: the free ones move out; the costly ones go to their buckets.
        let split = partition_by(&mut all, |c| c.cost != 0.0);
        let mut zero = all.split_off(split);
        zero.sort_unstable_by_key(Candidate::scatter);
        // Split off bucket by bucket from the back of `all` sorted by bucket, shrinking it as it
        // goes, so that its freed memory serves the next buckets: the candidates are held once,
        // not twice (memory freed to the allocator mid-heap stays resident).
        all.sort_unstable_by_key(|c| bucket(c.cost));
        let mut buckets: Vec<BinaryHeap<Candidate>> =
            (0..BUCKETS).map(|_| BinaryHeap::new()).collect();
        while let Some(last) = all.last() {
            let k = bucket(last.cost);
            let start = all.partition_point(|c| bucket(c.cost) < k);
            buckets[k] = BinaryHeap::from(all.split_off(start));
            all.shrink_to_fit();
        }
        Queue {
            zero: VecDeque::from(zero),
            buckets,
            low: 0,
        }
    }

    fn pop(&mut self) -> Option<Candidate> {
        if let Some(c) = self.zero.pop_front() {
            return Some(c);
        }
        while self.low < BUCKETS {
            if let Some(c) = self.buckets[self.low].pop() {
                return Some(c);
            }
            self.low += 1;
        }
        None
    }
}

/// Reorders `v` so that the elements for which `pred` holds come first; returns their count.
fn partition_by<T>(v: &mut [T], pred: impl Fn(&T) -> bool) -> usize {
    let mut split = 0;
    for i in 0..v.len() {
        if pred(&v[i]) {
            v.swap(split, i);
            split += 1;
        }
    }
    split
}

/// What a worker thread keeps across checks.
struct Scratch<'c> {
    /// Distance memo, sized for the voxels near the surface: about two per start triangle.
    prox: Proximity<'c>,
    seen: IdSet,
}

impl<'c> Scratch<'c> {
    fn new(cls: &'c Classifier, triangles: usize) -> Self {
        Scratch {
            prox: Proximity::with_capacity(cls, 2 * triangles),
            seen: IdSet::new(triangles),
        }
    }
}

/// A set of triangle ids, one bit each (2 MB for 16 M triangles), empty between uses.
struct IdSet(Vec<u64>);

impl IdSet {
    fn new(ids: usize) -> Self {
        IdSet(vec![0; ids.div_ceil(64)])
    }

    /// Drops every id from `ids` that an earlier one repeats, keeping the order.
    fn keep_first(&mut self, ids: &mut Vec<u32>) {
        let bits = &mut self.0;
        ids.retain(|&u| {
            let (word, bit) = (u as usize / 64, 1u64 << (u % 64));
            let first = bits[word] & bit == 0;
            bits[word] |= bit;
            first
        });
        for &u in ids.iter() {
            bits[u as usize / 64] &= !(1u64 << (u % 64));
        }
    }
}

/// A collapse that passed [`Region::check`]: b merges into a at v.
struct Plan {
    a: usize,
    b: usize,
    v: DVec3,
    /// The two triangles on the edge (they disappear).
    shared: Vec<u32>,
    /// The surviving triangles around the edge that move, with their new positions (those that
    /// stay keep their hash cells and cannot meet anything new).
    changed: Vec<(u32, [DVec3; 3])>,
    /// The same with their vertex ids after the collapse.
    new: Vec<([u32; 3], [DVec3; 3])>,
    /// a's neighbours after the collapse, with the cost of collapsing the edge to each (read
    /// before the batch: no other collapse of the batch moves them or a).
    fresh: Vec<(u32, f64)>,
    /// The triangles around the edge before the collapse, sorted.
    around: Vec<u32>,
    /// The surviving triangles around the edge that stay where they are (ids after the
    /// collapse, places).
    unchanged: Vec<([u32; 3], [DVec3; 3])>,
    /// The collapse keeps the surface's point set ([`Region::keeps_surface`]).
    in_plane: bool,
}

/// The triangles a committed plan moved, as after its collapse (ids, places), and their box.
struct Moved {
    fan: (DVec3, DVec3),
    tris: Vec<([u32; 3], [DVec3; 3])>,
}

#[derive(Clone, Copy, Debug)]
enum Reject {
    Topology,
    Flip,
    Band,
    Sweep,
    Intersection,
}

struct State {
    /// Every live triangle under the cells its current box meets (plus stale entries).
    hash: TriangleHash,
    pos: Vec<DVec3>,
    tris: Vec<[u32; 3]>,
    tri_alive: Vec<bool>,
    /// Live triangles around each vertex.
    star: Vec<Vec<u32>>,
    vert_alive: Vec<bool>,
    version: Vec<u32>,
    quadric: Vec<Quadric>,
    live_tris: usize,
    stats: SimplifyStats,
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
    assert!(opts.min_radius > 0.0 && opts.eps < band::REACH && opts.eps_sweep < band::REACH);
    let t_count = mesh.triangles.len();
    let n = mesh.positions.len();
    let mut s = State::new(mesh);
    let mut all = Vec::with_capacity(3 * t_count / 2);
    for tri in &s.tris {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            if a < b {
                all.push(s.candidate(a, b));
            }
        }
    }
    let mut heap = Queue::new(all);
    // One scratch per worker thread, kept across batches.
    let scratches: Vec<Mutex<Scratch>> = (0..rayon::current_num_threads())
        .map(|_| Mutex::new(Scratch::new(cls, t_count)))
        .collect();
    let scratch = || {
        let worker = rayon::current_thread_index().unwrap_or(0) % scratches.len();
        scratches[worker].lock().expect("one user per worker")
    };
    let mut gatherer = Gatherer::new(n);
    // Rejected edges by endpoint (each under both), retried once a collapse changes the
    // triangles around them.
    let mut parked: HashMap<u32, Vec<u32>> = HashMap::new();
    // A pipeline of batches: while one commits, the next gets its local checks (on copies of
    // its regions, disjoint from those in flight); its self-intersection checks, which read the
    // committed mesh, run while the one after it is gathered. Batches, and so the result, do
    // not depend on the thread count.
    let mut ready: Vec<((u32, u32), Result<Plan, Reject>)> = Vec::new();
    let (mut next, mut deferred) = gatherer.gather(&s, &mut heap);
    loop {
        if stop() {
            return None;
        }
        let target = opts.target_triangles;
        let (reached, local) = rayon::join(
            || s.commit_batch(&mut heap, &mut parked, ready, deferred, target),
            || {
                next.par_iter()
                    .map(|r| r.check(&mut scratch().prox, &opts, r.target()))
                    .collect::<Vec<_>>()
            },
        );
        if reached {
            break;
        }
        let ((gathered, later), checked) = rayon::join(
            || gatherer.gather(&s, &mut heap),
            || {
                local
                    .into_par_iter()
                    .map(|outcome| {
                        let plan = outcome?;
                        if !plan.in_plane {
                            s.crosses_nothing(&mut scratch().seen, &plan)?;
                        }
                        Ok(plan)
                    })
                    .collect::<Vec<_>>()
            },
        );
        ready = next.iter().map(|r| (r.a, r.b)).zip(checked).collect();
        (next, deferred) = (gathered, later);
        // An empty batch means an empty queue: a candidate is deferred only for meeting the
        // regions of this batch or of the one before.
        if ready.is_empty() && next.is_empty() {
            break;
        }
    }
    Some((s.compact(), s.stats))
}

/// Draws batches from the queue: candidates still current whose regions (a, b and their
/// neighbours) meet no region in flight.
struct Gatherer {
    /// Per vertex, the number of the last batch whose region held it.
    stamp: Vec<u32>,
    batch_no: u32,
    region: Vec<usize>,
}

impl Gatherer {
    /// For a mesh of `n` vertices. Batches are numbered from 2 up, and batch k conflicts with
    /// the stamps k and k - 1: the initial stamps, 0, with none.
    fn new(n: usize) -> Self {
        Gatherer {
            stamp: vec![0; n],
            batch_no: 1,
            region: Vec::new(),
        }
    }

    /// The next batch (up to [`BATCH`] regions, cheapest first) and the candidates deferred
    /// because their regions meet this batch's or the previous one's (not yet committed):
    /// they go back to the queue once that one commits.
    fn gather(&mut self, s: &State, heap: &mut Queue) -> (Vec<Region>, Vec<Candidate>) {
        self.batch_no += 1;
        let (mut batch, mut deferred) = (Vec::with_capacity(BATCH), Vec::new());
        while batch.len() < BATCH {
            let Some(c) = heap.pop() else { break };
            if !s.is_current(&c) {
                continue;
            }
            let region = &mut self.region;
            region.clear();
            s.star_vertices(c.a as usize, region);
            s.star_vertices(c.b as usize, region);
            if region.iter().any(|&x| self.stamp[x] + 1 >= self.batch_no) {
                deferred.push(c);
                continue;
            }
            for &x in region.iter() {
                self.stamp[x] = self.batch_no;
            }
            batch.push(s.region(c.a, c.b));
        }
        (batch, deferred)
    }
}

/// The quadric error and position of the cheapest target for merging a vertex with quadric
/// `qa` at `pa` and one with `qb` at `pb`: an endpoint, the midpoint or the quadric's optimum
/// (the first of the cheapest, in that order).
fn cheapest(qa: &Quadric, pa: DVec3, qb: &Quadric, pb: DVec3) -> (f64, DVec3) {
    let q = qa.add(qb);
    let mid = (pa + pb) / 2.0;
    let mut best = (q.error(pa), pa);
    for v in [pb, mid] {
        let e = q.error(v);
        if e < best.0 {
            best = (e, v);
        }
    }
    if let Some(o) = q.optimum() {
        // Keep the optimum near the edge: far-flung optima are numerical accidents.
        if (o - mid).length() <= (pb - pa).length() {
            let e = q.error(o);
            if e < best.0 {
                best = (e, o);
            }
        }
    }
    best
}

/// Whether triangle `t` (ids, places) conflicts with one of `others` ([`conflict`], boxes first).
fn meets_any<'a>(
    t: &([u32; 3], [DVec3; 3]),
    mut others: impl Iterator<Item = &'a ([u32; 3], [DVec3; 3])>,
) -> bool {
    let (ti, q) = t;
    others.any(|(ui, up)| boxes_meet(q, up) && conflict(*ti, *q, *ui, *up))
}

/// Parks rejected edge (a, b) under both endpoints, once.
fn park(parked: &mut HashMap<u32, Vec<u32>>, a: u32, b: u32) {
    for (x, y) in [(a, b), (b, a)] {
        let list = parked.entry(x).or_default();
        if !list.contains(&y) {
            list.push(y);
        }
    }
}

impl State {
    /// Stars, quadrics and the triangle hash of `mesh`.
    fn new(mesh: Mesh) -> State {
        let n = mesh.positions.len();
        let t_count = mesh.triangles.len();
        let mut s = State {
            hash: TriangleHash::new(HASH_CELL),
            pos: mesh.positions,
            tris: mesh.triangles,
            tri_alive: vec![true; t_count],
            star: vec![Vec::new(); n],
            vert_alive: vec![true; n],
            version: vec![0; n],
            quadric: vec![Quadric::default(); n],
            live_tris: t_count,
            stats: SimplifyStats::default(),
        };
        for t in 0..t_count {
            let tri = s.tris[t];
            let (tris, pos) = (&s.tris, &s.pos);
            let p = tri.map(|i| pos[i as usize]);
            let start = |u: u32| Some(tris[u as usize].map(|x| pos[x as usize]));
            s.hash.insert(t as u32, &p, None, start);
            let q = Quadric::plane(p);
            for &v in &tri {
                s.star[v as usize].push(t as u32);
                s.quadric[v as usize] = s.quadric[v as usize].add(&q);
            }
        }
        s
    }

    /// Pushes the parked edges at `v` back onto the heap (those still edges, except the one to
    /// `fresh`, whose candidate is already new) and unparks them under both endpoints.
    fn retry_parked(
        &self,
        parked: &mut HashMap<u32, Vec<u32>>,
        heap: &mut Queue,
        v: u32,
        fresh: u32,
    ) {
        let Some(others) = parked.remove(&v) else {
            return;
        };
        let still = self.neighbours(v as usize);
        for x in others {
            if let Some(list) = parked.get_mut(&x) {
                list.retain(|&y| y != v);
            }
            if x != fresh && still.binary_search(&(x as usize)).is_ok() {
                self.push(heap, self.candidate(v, x));
            }
        }
    }

    /// Whether `c` still describes its edge (both ends alive, neither moved since).
    fn is_current(&self, c: &Candidate) -> bool {
        let (a, b) = (c.a as usize, c.b as usize);
        self.vert_alive[a] && self.vert_alive[b] && self.version[a] + self.version[b] == c.ver
    }

    /// Pushes `c`. A full FIFO first drops its stale entries rather than growing (they are most
    /// of it: every collapse makes the entries at its kept vertex stale), and grows only when
    /// that frees less than a quarter; each bucket of 64 entries or more likewise. (A costly
    /// bucket is emptied by pops only when it is the cheapest, so its stale entries wait for it
    /// to fill: at n = 1500 the buckets hold about 0.35 GB more than one heap pruned as a whole
    /// did. Pruning them all together against a capacity budget thrashed; against an entry
    /// budget it saved 11 MB of 1.02 GB at n = 700.)
    fn push(&self, queue: &mut Queue, c: Candidate) {
        if c.cost == 0.0 {
            let zero = &mut queue.zero;
            if zero.len() == zero.capacity() {
                zero.retain(|c| self.is_current(c));
                zero.reserve(regrow(zero.len(), zero.capacity()));
            }
            zero.push_back(c);
            return;
        }
        let k = bucket(c.cost);
        queue.low = queue.low.min(k);
        let heap = &mut queue.buckets[k];
        if heap.len() == heap.capacity() && heap.len() >= 64 {
            heap.retain(|c| self.is_current(c));
            heap.reserve(regrow(heap.len(), heap.capacity()));
        }
        heap.push(c);
    }

    fn candidate(&self, a: u32, b: u32) -> Candidate {
        Candidate {
            cost: self.best_target(a, b).0 as f32,
            a,
            b,
            ver: self.version[a as usize] + self.version[b as usize],
        }
    }

    /// The quadric error and position of the cheapest target for collapsing edge (a, b).
    fn best_target(&self, a: u32, b: u32) -> (f64, DVec3) {
        let (a, b) = (a as usize, b as usize);
        cheapest(&self.quadric[a], self.pos[a], &self.quadric[b], self.pos[b])
    }

    /// Appends the vertices of v's triangles to `out` (v and repeats included).
    fn star_vertices(&self, v: usize, out: &mut Vec<usize>) {
        out.extend(
            self.star[v]
                .iter()
                .flat_map(|&t| self.tris[t as usize])
                .map(|x| x as usize),
        );
    }

    fn neighbours(&self, v: usize) -> Vec<usize> {
        let mut out: Vec<usize> = self.star[v]
            .iter()
            .flat_map(|&t| self.tris[t as usize])
            .map(|x| x as usize)
            .filter(|&x| x != v)
            .collect();
        out.sort_unstable();
        out.dedup();
        out
    }

    /// The triangles around edge (a, b) and their vertices, copied.
    fn region(&self, a: u32, b: u32) -> Region {
        let mut tris: Vec<(u32, [u32; 3])> = self.star[a as usize]
            .iter()
            .chain(&self.star[b as usize])
            .map(|&t| (t, self.tris[t as usize]))
            .collect();
        tris.sort_unstable_by_key(|x| x.0);
        tris.dedup_by_key(|x| x.0);
        let mut ids: Vec<u32> = tris.iter().flat_map(|x| x.1).collect();
        ids.sort_unstable();
        ids.dedup();
        let verts = ids
            .into_iter()
            .map(|x| (x, self.pos[x as usize], self.quadric[x as usize]))
            .collect();
        Region { a, b, tris, verts }
    }

    /// The self-intersection check of a plan that moves the surface ([`Plan::in_plane`] false):
    /// each new triangle against the other live triangles near it, the other new ones (ids as
    /// after the collapse: b becomes a) and the unchanged ones. Reads the mesh as committed:
    /// the plans committed before this one in its batch are checked at its commit.
    fn crosses_nothing(&self, seen: &mut IdSet, plan: &Plan) -> Result<(), Reject> {
        let (new, unchanged, around) = (&plan.new, &plan.unchanged, &plan.around);
        let fan: Vec<DVec3> = new.iter().flat_map(|(_, q)| *q).collect();
        let fan_box = bounds(&fan);
        let mut near = Vec::new();
        self.hash.near(&fan, &mut near);
        // Distinct ids first: the hash repeats a triangle once per cell it is filed under,
        // a large one hundreds of times.
        seen.keep_first(&mut near);
        let others: Vec<([u32; 3], [DVec3; 3])> = near
            .iter()
            .filter(|u| self.tri_alive[**u as usize] && around.binary_search(u).is_err())
            .map(|&u| {
                let ui = self.tris[u as usize];
                (ui, ui.map(|x| self.pos[x as usize]))
            })
            .filter(|(_, up)| bounds_meet(fan_box, bounds(up)))
            .collect();
        for (k, t) in new.iter().enumerate() {
            if meets_any(t, others.iter().chain(&new[k + 1..]).chain(unchanged)) {
                return Err(Reject::Intersection);
            }
        }
        Ok(())
    }

    /// Commits a checked batch in its order (a rejected edge is parked), then returns the
    /// `deferred` candidates to the queue. True once the mesh has at most `target` triangles.
    fn commit_batch(
        &mut self,
        heap: &mut Queue,
        parked: &mut HashMap<u32, Vec<u32>>,
        ready: Vec<((u32, u32), Result<Plan, Reject>)>,
        deferred: Vec<Candidate>,
        target: usize,
    ) -> bool {
        let mut batch_moved = Vec::new();
        for ((a, b), outcome) in ready {
            if self.live_tris <= target {
                return true;
            }
            let mut plan = match outcome {
                Ok(plan) => plan,
                Err(why) => {
                    self.stats.count(why);
                    park(parked, a, b);
                    continue;
                }
            };
            let fresh = std::mem::take(&mut plan.fresh);
            if !self.commit(plan, &mut batch_moved) {
                park(parked, a, b);
                continue;
            }
            // Edges at a have a new cost: fresh candidates (their old entries are stale by a's
            // version). Edges at a's neighbours keep their cost and their heap entries, but
            // their stars now hold moved triangles, so those rejected earlier may pass now:
            // they come back.
            parked.remove(&a);
            for (nb, cost) in fresh {
                let c = Candidate {
                    cost: cost as f32,
                    a,
                    b: nb,
                    ver: self.version[a as usize] + self.version[nb as usize],
                };
                self.push(heap, c);
                self.retry_parked(parked, heap, nb, a);
            }
        }
        for c in deferred {
            self.push(heap, c);
        }
        self.live_tris <= target
    }

    /// Apply a checked plan unless its new triangles meet a triangle moved earlier in this batch
    /// (`batch_moved`, the new triangles of each earlier plan, ids and positions as now, with
    /// their bounding box; the plan's own are added to it).
    fn commit(&mut self, plan: Plan, batch_moved: &mut Vec<Moved>) -> bool {
        let Plan {
            a,
            b,
            v,
            shared,
            changed,
            new,
            in_plane,
            ..
        } = plan;
        // The same test against the triangles that earlier collapses of this batch moved, which
        // `check` saw at their old places. A collapse in a plane covers the same points before
        // and after, so it neither needs the test nor adds to it.
        if in_plane {
            self.stats.collapses_in_plane += 1;
        } else {
            let places: Vec<DVec3> = new.iter().flat_map(|(_, q)| *q).collect();
            let fan = bounds(&places);
            for earlier in batch_moved.iter().filter(|m| bounds_meet(m.fan, fan)) {
                if new.iter().any(|t| meets_any(t, earlier.tris.iter())) {
                    self.stats.rejected_intersection += 1;
                    return false;
                }
            }
            batch_moved.push(Moved { fan, tris: new });
        }

        // Apply: b merges into a at v.
        let was: Vec<[DVec3; 3]> = changed
            .iter()
            .map(|(t, _)| self.tris[*t as usize].map(|x| self.pos[x as usize]))
            .collect();
        for &t in &shared {
            self.tri_alive[t as usize] = false;
            self.live_tris -= 1;
            for x in self.tris[t as usize] {
                self.star[x as usize].retain(|&u| u != t);
            }
        }
        let moved: Vec<u32> = self.star[b].clone();
        for t in moved {
            for x in self.tris[t as usize].iter_mut() {
                if *x as usize == b {
                    *x = a as u32;
                }
            }
            self.star[a].push(t);
        }
        self.star[b] = Vec::new(); // b is gone: free its star
        self.vert_alive[b] = false;
        self.pos[a] = v;
        let (tris, pos, alive) = (&self.tris, &self.pos, &self.tri_alive);
        let current = |u: u32| alive[u as usize].then(|| tris[u as usize].map(|x| pos[x as usize]));
        for ((t, q), w) in changed.iter().zip(&was) {
            self.hash.insert(*t, q, Some(w), current);
        }
        self.quadric[a] = self.quadric[a].add(&self.quadric[b]);
        self.version[a] += 1;
        self.stats.collapses += 1;
        true
    }

    fn compact(&self) -> Mesh {
        let mut map = vec![u32::MAX; self.pos.len()];
        let mut out = Mesh::default();
        for (t, tri) in self.tris.iter().enumerate() {
            if !self.tri_alive[t] {
                continue;
            }
            out.triangles.push(tri.map(|x| {
                if map[x as usize] == u32::MAX {
                    map[x as usize] = out.positions.len() as u32;
                    out.positions.push(self.pos[x as usize]);
                }
                map[x as usize]
            }));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::classify::test_support::boxed;
    use crate::mesh::extract::extract;
    use crate::simplify::band::dist_to_boundary;

    /// Generalized winding number of a closed mesh at `p` (solid angles, Van Oosterom and
    /// Strackee).
    fn winding_number(m: &Mesh, p: DVec3) -> f64 {
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
            eps: 0.866,
            eps_sweep: 1.5,
            min_radius: 0.05,
            target_triangles: 0,
        }
    }

    #[test]
    fn a_block_of_voxels_simplifies_to_a_box_of_twelve_triangles() {
        let cls = boxed([8, 8, 8], [2.0, 2.0, 2.0], [6.0, 6.0, 6.0]);
        let start = extract(&cls);
        assert_eq!(start.triangles.len(), 6 * 16 * 2);
        let (out, stats) = simplify(&start, &cls, defaults());
        assert_eq!(out.triangles.len(), 12, "{stats:?}");
        assert_eq!(out.positions.len(), 8);
        assert!(out.unpaired_edges().is_empty());
        assert!(
            (out.volume() - 64.0).abs() < 1e-9,
            "volume {}",
            out.volume()
        );
    }

    #[test]
    fn one_voxel_keeps_its_corners_in_a_narrow_band() {
        // Cutting a unit cube's corner moves some new triangle's points at least 1/6 inside
        // (the shallowest cut, collapsing a face edge to its midpoint, leaves the centroid
        // (11/6, 5/3, 4/3) 1/6 below the face x = 2): a band of 0.1 keeps all 12 triangles.
        let cls = boxed([3, 3, 3], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]);
        let start = extract(&cls);
        let narrow = SimplifyOptions {
            eps: 0.1,
            eps_sweep: 0.6,
            min_radius: 0.01,
            target_triangles: 0,
        };
        let (out, _) = simplify(&start, &cls, narrow);
        assert_eq!(out.triangles.len(), 12);
        assert!((out.volume() - 1.0).abs() < 1e-12);
        // A band of 0.3 admits that cut (every point of its triangles is within 1/6 of the
        // surface); every point of a unit cube is within 1/2 of its surface, so the swept-region
        // test cannot object: corners go, the mesh stays closed.
        let (out, stats) = simplify(&start, &cls, SimplifyOptions { eps: 0.3, ..narrow });
        assert!(out.triangles.len() < 12, "{stats:?}");
        assert!(out.unpaired_edges().is_empty());
        assert!(
            out.volume() > 0.25 && out.volume() < 1.0,
            "{}",
            out.volume()
        );
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
            let mut scratch = Scratch::new(&cls, s.tris.len());
            for round in 0..4 {
                for t in 0..s.tris.len() {
                    if !s.tri_alive[t] {
                        continue;
                    }
                    let tri = s.tris[t];
                    let (a, b) = (tri[round % 3] as usize, tri[(round + 1) % 3] as usize);
                    let v = if round % 2 == 0 { s.pos[a] } else { s.pos[b] };
                    let region = s.region(a as u32, b as u32);
                    let Ok(plan) = region.check(&mut scratch.prox, &defaults(), v) else {
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

    /// Batches in flight never share a vertex of their regions, and the first batch is full:
    /// three batches gathered back to back from a fresh block, each against the one before.
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
        let mut previous: Vec<u32> = Vec::new();
        let mut deferred = 0;
        for round in 0..3 {
            let (batch, later) = gatherer.gather(&s, &mut heap);
            assert_eq!(batch.len(), BATCH, "round {round}: a full batch");
            let mut here = vertices(&batch);
            let count = here.len();
            here.dedup();
            assert_eq!(
                here.len(),
                count,
                "round {round}: regions of one batch overlap"
            );
            assert!(
                here.iter().all(|v| previous.binary_search(v).is_err()),
                "round {round}: a region meets the batch in flight"
            );
            deferred += later.len();
            previous = here;
        }
        assert!(
            deferred < total / 2,
            "{deferred} of {total} candidates deferred"
        );
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
            // Every vertex and triangle centroid within the band; every voxel centre of W deeper
            // than eps_sweep still enclosed (winding number 1).
            for t in &out.triangles {
                let p = t.map(|v| out.positions[v as usize]);
                for x in [p[0], (p[0] + p[1] + p[2]) / 3.0] {
                    assert!(
                        dist_to_boundary(&cls, x, defaults().eps).is_some(),
                        "{x} off band"
                    );
                }
            }
            let mut deep = 0;
            for k in 0..20 {
                for j in 0..20 {
                    for i in 0..20 {
                        let c = DVec3::new(i as f64, j as f64, k as f64) + 0.5;
                        if cls.inside(i, j, k) && dist_to_boundary(&cls, c, 1.5).is_none() {
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
                        dist_to_boundary(&cls, x, defaults().eps).is_some() || on_joined_face(x),
                        "seed {seed}: {x} neither in the band nor on a joined face"
                    );
                }
            }
            for k in 0..20 {
                for j in 0..20 {
                    for i in 0..20 {
                        let c = DVec3::new(i as f64, j as f64, k as f64) + 0.5;
                        if cls.inside(i, j, k) && dist_to_boundary(&cls, c, 1.5).is_none() {
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
