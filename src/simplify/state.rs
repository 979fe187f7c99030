//! The mesh as the simplifier holds it, with what each collapse reads and changes: stars,
//! versions, quadrics, the triangle hash; the checks that read the committed mesh and the commit.

use std::collections::HashMap;
use std::hash::BuildHasherDefault;

use glam::DVec3;

use super::intersect::{bounds, bounds_meet, fan_one_to_one, Facet, TriangleHash};
use super::quadric::{cheapest, Quadric};
use super::queue::{bucket, Candidate, Queue};
// Scratch, IdSet, Plan and Reject live with the checks that make them (region.rs), which
// import nothing from here.
use super::region::flipped;
pub(super) use super::region::{Crossing, IdSet, Plan, Region, Reject, Scratch};
use super::{regrow, SimplifyStats, HASH_CELL};
use crate::mesh::Mesh;
use crate::voxels::KeyHasher;

/// Times an edge refused by the band is tried again while neither end changes: after that it
/// waits for a collapse at one of its ends. Retries after a neighbour's collapse pass rarely
/// (3.7% on the n = 512 assembly path): one retry left 0.7% more triangles than every retry
/// (none left 2% more, two 1%) and ran 5-11% faster paired on one thread (docs/perf-log.md,
/// "One retry after a band refusal"). Refusing is always sound.
const BAND_RETRIES: u8 = 1;

/// The triangles a committed plan moved, as after its collapse (ids, places), and their box.
pub(super) struct Moved {
    pub(super) fan: (DVec3, DVec3),
    pub(super) tris: Vec<([u32; 3], [DVec3; 3])>,
}

/// Which live triangles a step's new triangles are tested against for crossings
/// (docs/design.md, "Self-intersection").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Crossings {
    /// Every live triangle whose box comes near them (the triangle hash): each accepted step
    /// keeps the mesh free of crossing pairs.
    Near,
    /// Only those that share a vertex with them, read from the stars: no hash is filed. The
    /// pass's result must be certified ([`State::crossing_free`]), and the pass redone with
    /// `Near` when it holds a crossing pair.
    Neighbours,
}

pub(super) struct State {
    /// Every live triangle under the cells its current box meets (plus stale entries); None
    /// until [`Self::file`] when made by [`Self::unfiled`], and always with
    /// [`Crossings::Neighbours`].
    pub(super) hash: Option<TriangleHash>,
    /// What a step's crossing test reads: `Near` unless a block's first pass says otherwise.
    pub(super) crossings: Crossings,
    pub(super) pos: Vec<DVec3>,
    pub(super) tris: Vec<[u32; 3]>,
    pub(super) tri_alive: Vec<bool>,
    /// Live triangles around each vertex.
    pub(super) star: Vec<Vec<u32>>,
    pub(super) vert_alive: Vec<bool>,
    pub(super) version: Vec<u32>,
    pub(super) quadric: Vec<Quadric>,
    pub(super) live_tris: usize,
    pub(super) stats: SimplifyStats,
    /// Band refusals per edge and state of its ends: (lower id, higher id, the ends' versions
    /// summed, which grows whenever either end changes). One entry per refused state, never
    /// dropped: a pass's refusals bound it (36,475 on the n = 512 assembly path, all passes).
    band_refusals: HashMap<(u32, u32, u32), u8, BuildHasherDefault<KeyHasher>>,
}

/// Parks rejected edge (a, b) under both endpoints, once.
pub(super) fn park(parked: &mut HashMap<u32, Vec<u32>>, a: u32, b: u32) {
    for (x, y) in [(a, b), (b, a)] {
        let list = parked.entry(x).or_default();
        if !list.contains(&y) {
            list.push(y);
        }
    }
}

impl State {
    /// Stars, quadrics and the triangle hash of `mesh`.
    pub(super) fn new(mesh: Mesh) -> State {
        Self::with_quadrics(mesh, None)
    }

    /// Files every live triangle in the triangle hash, unless it is filed already or the
    /// checks read the stars only ([`Crossings::Neighbours`]).
    pub(super) fn file(&mut self) {
        if self.hash.is_none() && self.crossings == Crossings::Near {
            self.hash = Some(self.filed());
        }
    }

    /// A triangle hash of the live triangles.
    fn filed(&self) -> TriangleHash {
        let mut hash = TriangleHash::new(HASH_CELL);
        let (tris, pos) = (&self.tris, &self.pos);
        let now = |u: u32| Some(tris[u as usize].map(|x| pos[x as usize]));
        for t in (0..tris.len()).filter(|&t| self.tri_alive[t]) {
            let p = tris[t].map(|x| pos[x as usize]);
            hash.insert(t as u32, &p, None, now);
        }
        hash
    }

    /// Whether no two live triangles conflict by the rules of the per-step test
    /// ([`Facet::meets`]): the certificate of a pass with [`Crossings::Neighbours`]. Every pair
    /// closer than the test's reach is found: a point of one within that reach of the other
    /// lies in a cell the first is filed under and the second's widened box meets.
    pub(super) fn crossing_free(&self) -> bool {
        self.conflicts(true).is_empty()
    }

    /// The pairs of live triangles that conflict ([`Self::crossing_free`]), lower id first;
    /// only the first when `first`.
    pub(super) fn conflicts(&self, first: bool) -> Vec<(u32, u32)> {
        let hash = self.filed();
        // Each live triangle's box and normal once, however many pairs it is in (indexed by
        // `slot`: the state's arrays also hold the many triangles gone before).
        let mut slot = vec![u32::MAX; self.tris.len()];
        let mut facets = Vec::with_capacity(self.live_tris);
        for t in (0..self.tris.len()).filter(|&t| self.tri_alive[t]) {
            let ids = self.tris[t];
            slot[t] = facets.len() as u32;
            facets.push((t, Facet::new((ids, ids.map(|x| self.pos[x as usize])))));
        }
        // A triangle filed under several of the cells near t is tested once (no sort of the
        // lists); the pairs are sorted at the end.
        let mut seen = IdSet::new(self.tris.len());
        let (mut near, mut pairs) = (Vec::new(), Vec::new());
        for (t, me) in &facets {
            hash.near(&me.at, &mut near);
            near.retain(|&u| u as usize > *t && slot[u as usize] != u32::MAX);
            seen.keep_first(&mut near);
            for &u in &near {
                if me.meets(&facets[slot[u as usize] as usize].1) {
                    pairs.push((*t as u32, u));
                    if first {
                        return pairs;
                    }
                }
            }
        }
        pairs.sort_unstable();
        pairs
    }

    /// [`Self::new`] with each vertex's quadric given (the sum of the planes of the start
    /// triangles it stands for), or made from `mesh`'s triangles when None.
    pub(super) fn with_quadrics(mesh: Mesh, quadrics: Option<Vec<Quadric>>) -> State {
        let mut s = Self::unfiled(mesh, quadrics);
        s.file();
        s
    }

    /// [`Self::with_quadrics`] without the triangle hash, which only the self-intersection
    /// checks read: a block's pass first runs its collapses that keep the surface, which never
    /// ask for it, so it files the triangles left after them ([`Self::file`]) instead of filing
    /// every start triangle and then refiling each one such a collapse reshapes.
    pub(super) fn unfiled(mesh: Mesh, quadrics: Option<Vec<Quadric>>) -> State {
        let n = mesh.positions.len();
        let t_count = mesh.triangles.len();
        let mut s = State {
            hash: None,
            crossings: Crossings::Near,
            pos: mesh.positions,
            tris: mesh.triangles,
            tri_alive: vec![true; t_count],
            star: vec![Vec::new(); n],
            vert_alive: vec![true; n],
            version: vec![0; n],
            quadric: Vec::new(),
            live_tris: t_count,
            stats: SimplifyStats::default(),
            band_refusals: HashMap::default(),
        };
        let given = quadrics.is_some();
        s.quadric = quadrics.unwrap_or_else(|| vec![Quadric::default(); n]);
        assert_eq!(s.quadric.len(), n, "a quadric per vertex");
        for t in 0..t_count {
            let tri = s.tris[t];
            let q = (!given).then(|| Quadric::plane(tri.map(|i| s.pos[i as usize])));
            for &v in &tri {
                s.star[v as usize].push(t as u32);
                if let Some(q) = &q {
                    s.quadric[v as usize] = s.quadric[v as usize].add(q);
                }
            }
        }
        s
    }

    /// Pushes the parked edges at `v` back onto the heap (those still edges, except the one to
    /// `fresh`, whose candidate is already new) and unparks them under both endpoints.
    pub(super) fn retry_parked(
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
    pub(super) fn is_current(&self, c: &Candidate) -> bool {
        self.vert_alive[c.a as usize]
            && self.vert_alive[c.b as usize]
            && self.ends(c.a, c.b) == c.ver
    }

    /// The versions of edge (a, b)'s ends summed: versions only grow, so the sum changes
    /// exactly when either end does.
    pub(super) fn ends(&self, a: u32, b: u32) -> u32 {
        self.version[a as usize] + self.version[b as usize]
    }

    /// Pushes `c`. A full FIFO first drops its stale entries rather than growing (they are most
    /// of it: every collapse makes the entries at its kept vertex stale), and grows only when
    /// that frees less than a quarter; each bucket of 64 entries or more likewise. (A costly
    /// bucket is emptied by pops only when it is the cheapest, so its stale entries wait for it
    /// to fill: at n = 1500 the buckets hold about 0.35 GB more than one heap pruned as a whole
    /// did. Pruning them all together against a capacity budget thrashed; against an entry
    /// budget it saved 11 MB of 1.02 GB at n = 700.)
    pub(super) fn push(&self, queue: &mut Queue, c: Candidate) {
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

    pub(super) fn candidate(&self, a: u32, b: u32) -> Candidate {
        Candidate {
            cost: self.best_target(a, b).0 as f32,
            a,
            b,
            ver: self.ends(a, b),
        }
    }

    /// The quadric error and position of the cheapest target for collapsing edge (a, b).
    pub(super) fn best_target(&self, a: u32, b: u32) -> (f64, DVec3) {
        let (a, b) = (a as usize, b as usize);
        cheapest(&self.quadric[a], self.pos[a], &self.quadric[b], self.pos[b])
    }

    /// Appends the vertices of v's triangles to `out` (v and repeats included).
    pub(super) fn star_vertices(&self, v: usize, out: &mut Vec<usize>) {
        out.extend(
            self.star[v]
                .iter()
                .flat_map(|&t| self.tris[t as usize])
                .map(|x| x as usize),
        );
    }

    pub(super) fn neighbours(&self, v: usize) -> Vec<usize> {
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

    /// Whether collapsing edge (a, b) to `v` would flip or flatten one of the triangles around
    /// a or b that does not hold both ([`flipped`]): the flip test of [`Region::check_moving`]
    /// on the live mesh, without copying the region. Where the edge is a two-face edge its two
    /// faces are the triangles holding both, so a yes here is a refusal there (Flip, or
    /// Topology found first).
    pub(super) fn flips(&self, a: u32, b: u32, v: DVec3) -> bool {
        let stars = self.star[a as usize].iter().chain(&self.star[b as usize]);
        for &t in stars {
            let tri = self.tris[t as usize];
            if tri.contains(&a) && tri.contains(&b) {
                continue;
            }
            let p = tri.map(|x| self.pos[x as usize]);
            let q = tri.map(|x| {
                if x == a || x == b {
                    v
                } else {
                    self.pos[x as usize]
                }
            });
            if flipped(&p, &q) {
                return true;
            }
        }
        false
    }

    /// The triangles around edge (a, b) and their vertices, copied.
    pub(super) fn region(&self, a: u32, b: u32) -> Region {
        let mut tris: Vec<(u32, [u32; 3])> = self.star[a as usize]
            .iter()
            .chain(&self.star[b as usize])
            .map(|&t| (t, self.tris[t as usize]))
            .collect();
        tris.sort_unstable_by_key(|x| x.0);
        tris.dedup_by_key(|x| x.0);
        let mut ids: Vec<u32> = Vec::with_capacity(3 * tris.len());
        ids.extend(tris.iter().flat_map(|x| x.1));
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
    pub(super) fn crosses_nothing(&self, buf: &mut Crossing, plan: &Plan) -> Result<(), Reject> {
        self.crosses_nothing_of(buf, &plan.new, &plan.unchanged, &plan.around)
    }

    /// Which vertices of the new triangles have, after replacing `around` by `new` and
    /// `unchanged`, a fan that projects one to one ([`fan_one_to_one`]): `buf.passed`, sorted.
    /// No two triangles of such a fan meet beyond what they share. (The pair rules also flag
    /// such pairs within 10⁻⁶ of touching; a block's certificate still tests those.) True when
    /// every vertex's fan does.
    fn fans_one_to_one(
        &self,
        buf: &mut Crossing,
        new: &[([u32; 3], [DVec3; 3])],
        unchanged: &[([u32; 3], [DVec3; 3])],
        around: &[u32],
    ) -> bool {
        let Crossing {
            verts,
            corners,
            passed,
            ..
        } = buf;
        verts.clear();
        verts.extend(new.iter().flat_map(|(ids, _)| *ids));
        verts.sort_unstable();
        verts.dedup();
        passed.clear();
        passed.extend(verts.iter().copied().filter(|&x| {
            corners.clear();
            let mut at = None;
            for (ids, q) in new.iter().chain(unchanged) {
                if let Some(k) = ids.iter().position(|&y| y == x) {
                    let (i, j) = ((k + 1) % 3, (k + 2) % 3);
                    corners.push((ids[i], ids[j], q[i], q[j]));
                    at = Some(q[k]);
                }
            }
            for &t in &self.star[x as usize] {
                if !self.tri_alive[t as usize] || around.binary_search(&t).is_ok() {
                    continue;
                }
                let ids = self.tris[t as usize];
                let k = ids.iter().position(|&y| y == x).expect("a star's vertex");
                let (i, j) = (ids[(k + 1) % 3], ids[(k + 2) % 3]);
                corners.push((i, j, self.pos[i as usize], self.pos[j as usize]));
            }
            at.is_some_and(|p| fan_one_to_one(p, corners))
        }));
        passed.len() == verts.len()
    }

    /// The same test for any replacement of the live triangles `around` (sorted) by `new` and
    /// `unchanged` (ids as after it, places): each new triangle against the live triangles near
    /// it but `around`, the unchanged ones and the new ones after it. A pair with a common
    /// vertex whose fan projects one to one ([`Self::fans_one_to_one`]) is not tested: with
    /// crossings read from the neighbours, where every such fan does, no pair is left but new
    /// ones without a common vertex (a collapse's all hold the kept vertex, so none).
    pub(super) fn crosses_nothing_of(
        &self,
        buf: &mut Crossing,
        new: &[([u32; 3], [DVec3; 3])],
        unchanged: &[([u32; 3], [DVec3; 3])],
        around: &[u32],
    ) -> Result<(), Reject> {
        let fans = self.fans_one_to_one(buf, new, unchanged, around);
        let Crossing {
            seen,
            points,
            near,
            others,
            fan,
            verts,
            passed,
            ..
        } = buf;
        points.clear();
        points.extend(new.iter().flat_map(|(_, q)| *q));
        let fan_box = bounds(points);
        match self.crossings {
            Crossings::Near => self
                .hash
                .as_ref()
                .expect("triangles filed before a check that moves the surface")
                .near(points, near),
            Crossings::Neighbours => {
                // After the change the triangles that share a vertex with the new ones are
                // those of their vertices' stars but `around`, and `unchanged`; the stars of
                // vertices whose fans pass need no test.
                near.clear();
                for &x in verts.iter().filter(|x| passed.binary_search(x).is_err()) {
                    near.extend_from_slice(&self.star[x as usize]);
                }
            }
        }
        // Distinct ids first: the hash repeats a triangle once per cell it is filed under,
        // a large one hundreds of times.
        seen.keep_first(near);
        others.clear();
        others.extend(
            near.iter()
                .filter(|u| self.tri_alive[**u as usize])
                .filter_map(|&u| {
                    let ui = self.tris[u as usize];
                    let up = ui.map(|x| self.pos[x as usize]);
                    // Most are too far: the box first, then whether it is around the edge.
                    (bounds_meet(fan_box, bounds(&up)) && around.binary_search(&u).is_err())
                        .then_some((ui, up))
                })
                .chain(unchanged.iter().copied().filter(|_| !fans))
                .map(Facet::new),
        );
        fan.clear();
        fan.extend(new.iter().copied().map(Facet::new));
        for (k, t) in fan.iter().enumerate() {
            let mut pairs = others.iter().chain(&fan[k + 1..]);
            if pairs.any(|u| !t.shares_one_of(u, passed) && t.meets(u)) {
                return Err(Reject::Intersection);
            }
        }
        Ok(())
    }

    /// Commits a checked batch in its order (a rejected edge is parked), then returns the
    /// `deferred` candidates to the queue. True once the mesh has at most `target` triangles.
    pub(super) fn commit_batch(
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
                    if why != Reject::Band || self.band_retry_left(a, b) {
                        park(parked, a, b);
                    }
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
                    ver: self.ends(a, nb),
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

    /// Whether edge (a, b), just refused by the band, may be tried again after a neighbour's
    /// collapse ([`BAND_RETRIES`] times while neither end changes); counts the refusal.
    fn band_retry_left(&mut self, a: u32, b: u32) -> bool {
        let ver = self.ends(a, b);
        let refusals = self
            .band_refusals
            .entry((a.min(b), a.max(b), ver))
            .or_insert(0);
        *refusals = refusals.saturating_add(1);
        *refusals <= BAND_RETRIES
    }

    /// Apply a checked plan unless its new triangles meet a triangle moved earlier in this batch
    /// (`batch_moved`, the new triangles of each earlier plan, ids and positions as now, with
    /// their bounding box; the plan's own are added to it).
    pub(super) fn commit(&mut self, plan: Plan, batch_moved: &mut Vec<Moved>) -> bool {
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
            let ours: Vec<Facet> = new.iter().copied().map(Facet::new).collect();
            for earlier in batch_moved.iter().filter(|m| bounds_meet(m.fan, fan)) {
                let theirs: Vec<Facet> = earlier.tris.iter().copied().map(Facet::new).collect();
                if ours.iter().any(|t| theirs.iter().any(|u| t.meets(u))) {
                    self.stats.rejected_intersection += 1;
                    return false;
                }
            }
            batch_moved.push(Moved { fan, tris: new });
        }

        // Apply: b merges into a at v.
        // The changed triangles' old places, for refiling them (none while unfiled).
        let was: Vec<[DVec3; 3]> = match self.hash {
            Some(_) => changed
                .iter()
                .map(|(t, _)| self.tris[*t as usize].map(|x| self.pos[x as usize]))
                .collect(),
            None => Vec::new(),
        };
        for &t in &shared {
            self.tri_alive[t as usize] = false;
            self.live_tris -= 1;
            for x in self.tris[t as usize] {
                self.star[x as usize].retain(|&u| u != t);
            }
        }
        // b is gone: its star's triangles join a's, and its own list is freed.
        let moved = std::mem::take(&mut self.star[b]);
        self.star[a].reserve(moved.len());
        for t in moved {
            for x in self.tris[t as usize].iter_mut() {
                if *x as usize == b {
                    *x = a as u32;
                }
            }
            self.star[a].push(t);
        }
        self.vert_alive[b] = false;
        self.pos[a] = v;
        let (tris, pos, alive) = (&self.tris, &self.pos, &self.tri_alive);
        let current = |u: u32| alive[u as usize].then(|| tris[u as usize].map(|x| pos[x as usize]));
        // Unfiled, only a collapse that keeps the surface can come here: one that moves it was
        // checked against the filed triangles.
        match &mut self.hash {
            Some(hash) => {
                for ((t, q), w) in changed.iter().zip(&was) {
                    hash.insert(*t, q, Some(w), current);
                }
            }
            None => assert!(
                in_plane || self.crossings == Crossings::Neighbours,
                "a moving collapse committed to an unfiled state"
            ),
        }
        self.quadric[a] = self.quadric[a].add(&self.quadric[b]);
        self.version[a] += 1;
        self.stats.collapses += 1;
        true
    }

    pub(super) fn compact(&self) -> Mesh {
        self.compact_with_map().0
    }

    /// The live mesh, and each old vertex id's new one (u32::MAX: gone).
    pub(super) fn compact_with_map(&self) -> (Mesh, Vec<u32>) {
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
        (out, map)
    }
}
