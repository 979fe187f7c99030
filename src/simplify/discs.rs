//! Disc patches remeshed in one checked step (docs/design.md, "Disc patches"). The triangles
//! within k rings of a vertex, when they form a disc lying over one plane, are replaced by a
//! fan from one point or by an ear triangulation of their boundary loop, which stays. The
//! checks are a collapse's: the block's border rule, every new triangle in the tolerance band,
//! the sweep check on the closed surface old - new, and the self-intersection test. The mesh
//! stays a closed 2-manifold: the loop is kept, the new triangles form a disc on it, and no new
//! edge is one the mesh already has.
//!
//! One pass (`remesh_discs`) visits the free vertices in index order once; a disc holding a
//! triangle made earlier in the same pass is skipped, so each is checked against a mesh whose
//! new triangles lie elsewhere (the self-intersection test reads the committed mesh, earlier
//! discs included).

use std::collections::HashMap;

use glam::{DVec2, DVec3};

use super::quadric::Quadric;
use super::queue::Queue;
use super::state::{Crossings, Reject, Scratch, State};
use super::SimplifyOptions;

/// The rings of a disc around its centre vertex. Two: at the first moving level (n = 256 and
/// 512) three-ring discs were taken 16 times in a pass that took 5,700 two-ring ones (their
/// neighbours' discs are taken first), and gathering them cost more than they saved.
const RINGS: usize = 2;

/// Least area a new triangle's projection on the disc's plane may have, voxel² (twice the area:
/// the cross product's component along the unit normal). Slivers below it are refused.
const MIN_AREA2: f64 = 1e-6;

/// A patch of the mesh that is a disc: its triangles, the vertices inside it, its boundary.
pub(super) struct Disc {
    /// Its triangles, sorted.
    tris: Vec<u32>,
    /// The vertices not on its boundary, sorted; all go (a fan's point reuses `centre`'s id).
    inner: Vec<u32>,
    /// The boundary loop, oriented as the triangles.
    boundary: Vec<u32>,
    centre: u32,
}

/// A disc's new triangles (ids as after the commit, places) and the fan's point if any.
pub(super) struct Remeshed {
    pub(super) disc: Disc,
    pub(super) new: Vec<([u32; 3], [DVec3; 3])>,
    /// Some for a fan from one new point (given `disc.centre`'s id), None for ears.
    pub(super) point: Option<DVec3>,
}

impl Disc {
    /// Its triangles' places in `s`.
    fn places(&self, s: &State) -> Vec<[DVec3; 3]> {
        self.tris
            .iter()
            .map(|&t| s.tris[t as usize].map(|x| s.pos[x as usize]))
            .collect()
    }
}

impl State {
    /// The triangles within `rings` rings of `v` when they form a disc with no locked vertex
    /// inside and none of them `taken`; else None.
    pub(super) fn disc(
        &self,
        v: u32,
        rings: usize,
        locked: &[bool],
        taken: &[bool],
    ) -> Option<Disc> {
        // Ring by ring, leaving at the first locked vertex inside or taken triangle.
        let mut inner = vec![v];
        let mut tris: Vec<u32> = self.star[v as usize].clone();
        for _ in 1..rings {
            if tris.iter().any(|&t| taken[t as usize]) {
                return None;
            }
            inner = tris.iter().flat_map(|&t| self.tris[t as usize]).collect();
            inner.sort_unstable();
            inner.dedup();
            if inner.iter().any(|&x| locked[x as usize]) {
                return None;
            }
            tris = inner
                .iter()
                .flat_map(|&x| self.star[x as usize].iter().copied())
                .collect();
            tris.sort_unstable();
            tris.dedup();
        }
        if locked[v as usize] || tris.iter().any(|&t| taken[t as usize]) {
            return None;
        }
        // Directed edges, grouped by their undirected pair: an inner edge twice (once each way),
        // a boundary edge once.
        let mut edges: Vec<(u32, u32)> = tris
            .iter()
            .flat_map(|&t| {
                let [a, b, c] = self.tris[t as usize];
                [(a, b), (b, c), (c, a)]
            })
            .collect();
        edges.sort_unstable_by_key(|&(p, q)| (p.min(q), p.max(q), p));
        let mut boundary_edges: Vec<(u32, u32)> = Vec::new();
        let mut inner_edges = 0;
        let pair = |e: &(u32, u32)| (e.0.min(e.1), e.0.max(e.1));
        for group in edges.chunk_by(|e, f| pair(e) == pair(f)) {
            match group {
                [e] => boundary_edges.push(*e),
                [e, f] if e.0 != f.0 => inner_edges += 1,
                _ => return None,
            }
        }
        // One loop through every boundary vertex once, none of them inner.
        boundary_edges.sort_unstable();
        if boundary_edges.len() < 3
            || boundary_edges.windows(2).any(|w| w[0].0 == w[1].0)
            || boundary_edges
                .iter()
                .any(|e| inner.binary_search(&e.0).is_ok())
        {
            return None;
        }
        let mut boundary = Vec::with_capacity(boundary_edges.len());
        let mut at = boundary_edges[0].0;
        loop {
            boundary.push(at);
            let k = boundary_edges.binary_search_by_key(&at, |e| e.0).ok()?;
            at = boundary_edges[k].1;
            if at == boundary[0] {
                break;
            }
            if boundary.len() > boundary_edges.len() {
                return None;
            }
        }
        // A disc: one boundary loop, every vertex inner or on it, Euler characteristic 1.
        let mut all: Vec<u32> = tris.iter().flat_map(|&t| self.tris[t as usize]).collect();
        all.sort_unstable();
        all.dedup();
        let (v_count, e_count) = (all.len(), inner_edges + boundary.len());
        if boundary.len() != boundary_edges.len()
            || v_count != inner.len() + boundary.len()
            || v_count + tris.len() != e_count + 1
        {
            return None;
        }
        Some(Disc {
            tris,
            inner,
            boundary,
            centre: v,
        })
    }

    /// The new triangles for `disc`, when it lies over one plane (every triangle facing the
    /// area-weighted normal, the boundary's projection a simple polygon): a fan from a point
    /// that sees every boundary edge, else ears of the projected polygon. None when neither
    /// gives triangles facing the normal, or an ear's diagonal is an edge of the mesh already
    /// or joins two `locked` vertices (block borders: such an edge could run along the box's
    /// face, where the next block's triangles lie; docs/design.md, "Blocks").
    pub(super) fn remesh(&self, disc: Disc, locked: &[bool]) -> Option<Remeshed> {
        let place = |t: u32| self.tris[t as usize].map(|x| self.pos[x as usize]);
        let normal = |q: &[DVec3; 3]| (q[1] - q[0]).cross(q[2] - q[0]);
        // The area-weighted normal and centroid (twice the areas).
        let (mut n, mut weighted, mut area2) = (DVec3::ZERO, DVec3::ZERO, 0.0);
        let mut normals = Vec::with_capacity(disc.tris.len());
        for &t in &disc.tris {
            let q = place(t);
            let m = normal(&q);
            n += m;
            area2 += m.length();
            weighted += m.length() * (q[0] + q[1] + q[2]);
            normals.push(m);
        }
        let n = n.try_normalize()?;
        if normals.iter().any(|m| m.dot(n) <= 0.0) {
            return None;
        }
        let b: Vec<DVec3> = disc
            .boundary
            .iter()
            .map(|&x| self.pos[x as usize])
            .collect();
        // (e1, e2, n) right-handed: a loop turning counter-clockwise about n does so in 2D.
        let e1 = n.any_orthonormal_vector();
        let e2 = n.cross(e1);
        let flat: Vec<DVec2> = b.iter().map(|p| DVec2::new(p.dot(e1), p.dot(e2))).collect();
        if !is_simple(&flat) {
            return None;
        }
        let faces = |q: &[DVec3; 3]| normal(q).dot(n) > MIN_AREA2;
        // Fan: from the boundary's centroid on the patch's mean plane, else from the centre
        // vertex on that plane, else from the centre vertex itself.
        let origin = weighted / (3.0 * area2);
        let on_plane = |p: DVec3| p - n * n.dot(p - origin);
        let centroid = b.iter().sum::<DVec3>() / b.len() as f64;
        let v = self.pos[disc.centre as usize];
        let len = b.len();
        for c in [on_plane(centroid), on_plane(v), v] {
            let fan: Vec<([u32; 3], [DVec3; 3])> = (0..len)
                .map(|i| {
                    let j = (i + 1) % len;
                    (
                        [disc.boundary[i], disc.boundary[j], disc.centre],
                        [b[i], b[j], c],
                    )
                })
                .collect();
            if fan.iter().all(|(_, q)| faces(q)) {
                return Some(Remeshed {
                    disc,
                    new: fan,
                    point: Some(c),
                });
            }
        }
        // Ears: b - 2 triangles, each with a diagonal (b ≥ 4) that must be a new edge.
        if len < 4 {
            return None;
        }
        let ears = ears(&flat)?;
        let outside = |x: u32, y: u32| {
            self.star[x as usize].iter().any(|&t| {
                disc.tris.binary_search(&t).is_err() && self.tris[t as usize].contains(&y)
            })
        };
        let mut new = Vec::with_capacity(ears.len());
        for [i, j, k] in ears {
            let ids = [i, j, k].map(|x| disc.boundary[x]);
            let q = [b[i], b[j], b[k]];
            if !faces(&q) {
                return None;
            }
            for (x, y) in [(i, j), (j, k), (k, i)] {
                let adjacent = (x + 1) % len == y || (y + 1) % len == x;
                let (x, y) = (disc.boundary[x], disc.boundary[y]);
                if !adjacent && ((locked[x as usize] && locked[y as usize]) || outside(x, y)) {
                    return None;
                }
            }
            new.push((ids, q));
        }
        Some(Remeshed {
            disc,
            new,
            point: None,
        })
    }

    /// Replaces the disc's triangles by the new ones (reusing the first of their ids), removes
    /// its inner vertices (a fan's point takes the centre's id, with all their quadrics; ears
    /// give each inner vertex's quadric to the boundary vertex nearest it) and refiles the
    /// moved triangles. Returns the vertices whose edges changed (boundary and point).
    pub(super) fn commit_disc(&mut self, plan: Remeshed) -> Vec<u32> {
        let Remeshed { disc, new, point } = plan;
        let was = disc.places(self);
        for &x in &disc.boundary {
            self.star[x as usize].retain(|t| disc.tris.binary_search(t).is_err());
        }
        let mut sum = Quadric::default();
        for &x in &disc.inner {
            self.star[x as usize].clear();
            self.vert_alive[x as usize] = false;
            let q = self.quadric[x as usize];
            sum = sum.add(&q);
            if point.is_none() {
                let p = self.pos[x as usize];
                let nearest = *disc
                    .boundary
                    .iter()
                    .min_by(|&&u, &&w| {
                        let d = |y: u32| (self.pos[y as usize] - p).length_squared();
                        d(u).total_cmp(&d(w))
                    })
                    .expect("a boundary");
                self.quadric[nearest as usize] = self.quadric[nearest as usize].add(&q);
            }
        }
        if let Some(c) = point {
            let x = disc.centre as usize;
            self.vert_alive[x] = true;
            self.pos[x] = c;
            self.quadric[x] = sum;
        }
        for &t in &disc.tris[new.len()..] {
            self.tri_alive[t as usize] = false;
        }
        self.live_tris -= disc.tris.len() - new.len();
        for (&t, (ids, _)) in disc.tris.iter().zip(&new) {
            self.tris[t as usize] = *ids;
            for &x in ids {
                self.star[x as usize].push(t);
            }
        }
        let (tris, pos, alive) = (&self.tris, &self.pos, &self.tri_alive);
        let current = |u: u32| alive[u as usize].then(|| tris[u as usize].map(|x| pos[x as usize]));
        match self.hash.as_mut() {
            Some(hash) => {
                for ((&t, (_, q)), w) in disc.tris.iter().zip(&new).zip(&was) {
                    hash.insert(t, q, Some(w), current);
                }
            }
            None => assert!(
                self.crossings == Crossings::Neighbours,
                "triangles filed before a disc moves them"
            ),
        }
        let mut touched = disc.boundary;
        touched.extend(point.map(|_| disc.centre));
        for &x in &touched {
            self.version[x as usize] += 1;
        }
        self.stats.discs += 1;
        self.stats.disc_vertices += (disc.inner.len() - point.is_some() as usize) as u64;
        touched
    }
}

/// The checks of a remeshed disc, a collapse's: `may_move` (the block's border rule) on the new
/// triangles, each of them in the tolerance band, the sweep check on old - new, and the
/// self-intersection test against the committed mesh.
pub(super) fn check(
    s: &State,
    scratch: &mut Scratch,
    opts: &SimplifyOptions,
    plan: &Remeshed,
    may_move: &impl Fn(&[([u32; 3], [DVec3; 3])]) -> Result<(), Reject>,
) -> Result<(), Reject> {
    may_move(&plan.new)?;
    let prox = &mut scratch.prox;
    let (tol, r_min) = (opts.tolerance, opts.min_radius);
    if !prox.new_surface_within(plan.point, &plan.new, tol, r_min) {
        return Err(Reject::Band);
    }
    let old = plan.disc.places(s);
    let moved: Vec<[DVec3; 3]> = plan.new.iter().map(|(_, q)| *q).collect();
    // As for a collapse (`region::band_and_sweep`): with the pieces known, exactly; else every
    // point where old - new winds lies in a tetrahedron joining a triangle of old - new to one
    // apex (the cone decomposition of a closed surface), and each must be within `sweep` of an
    // outside voxel's centre. Triangles through the apex give flat tetrahedra.
    if let Some(pieces) = scratch.pieces {
        if pieces.swallowed(&old, &moved) {
            return Err(Reject::Sweep);
        }
    } else {
        let apex = plan.point.unwrap_or(moved[0][0]);
        for p in old.iter().chain(&moved) {
            if p.contains(&apex) {
                continue;
            }
            if !prox.tetrahedron_shallow([p[0], p[1], p[2], apex], opts.sweep, r_min) {
                return Err(Reject::Sweep);
            }
        }
    }
    s.crosses_nothing_of(&mut scratch.crossing, &plan.new, &[], &plan.disc.tris)
}

/// One pass of disc remeshing over the free vertices (`locked` false), in index order: the
/// [`RINGS`]-ring disc at each is remeshed where it lies over a plane and passes the checks,
/// until the mesh has at most `target` triangles (0: no target). The edges at the vertices a
/// disc changes get fresh candidates in `heap` (both ends free) and leave `parked`. Asks
/// `stop` every 1024 vertices; true when it said yes (the pass then ends where it was).
#[allow(clippy::too_many_arguments)]
pub(super) fn remesh_discs(
    s: &mut State,
    heap: &mut Queue,
    parked: &mut HashMap<u32, Vec<u32>>,
    scratch: &mut Scratch,
    opts: &SimplifyOptions,
    locked: &[bool],
    target: usize,
    may_move: impl Fn(&[([u32; 3], [DVec3; 3])]) -> Result<(), Reject>,
    stop: &(dyn Fn() -> bool + Sync),
) -> bool {
    // Each remeshed disc is checked for self-intersection, which reads the triangle hash
    // (unless the pass checks neighbours only).
    s.file();
    let mut taken = vec![false; s.tris.len()];
    // Vertices whose disc would hold a taken triangle (those of the new triangles and their
    // neighbours), skipped without gathering it.
    let mut near_taken = vec![false; s.pos.len()];
    for v in 0..s.pos.len() as u32 {
        if target > 0 && s.live_tris <= target {
            return false;
        }
        if v % 1024 == 0 && stop() {
            return true;
        }
        if !s.vert_alive[v as usize] || locked[v as usize] || near_taken[v as usize] {
            continue;
        }
        let Some(plan) = s
            .disc(v, RINGS, locked, &taken)
            .and_then(|d| s.remesh(d, locked))
        else {
            continue;
        };
        if check(s, scratch, opts, &plan, &may_move).is_err() {
            continue;
        }
        for &t in &plan.disc.tris[..plan.new.len()] {
            taken[t as usize] = true;
        }
        let touched = s.commit_disc(plan);
        for &x in &touched {
            if let Some(others) = parked.remove(&x) {
                for y in others {
                    if let Some(list) = parked.get_mut(&y) {
                        list.retain(|&z| z != x);
                    }
                }
            }
        }
        for &x in &touched {
            near_taken[x as usize] = true;
            for y in s.neighbours(x as usize) {
                near_taken[y] = true;
                let y = y as u32;
                // Each edge once: from its smaller end, or from x when y was not touched.
                if !locked[x as usize] && !locked[y as usize] && (x < y || !touched.contains(&y)) {
                    s.push(heap, s.candidate(x, y));
                }
            }
        }
    }
    false
}

/// Twice the signed area of triangle (a, b, c): positive when it turns counter-clockwise.
fn orient(a: DVec2, b: DVec2, c: DVec2) -> f64 {
    (b - a).perp_dot(c - a)
}

/// Whether the closed polygon `p` is simple: no two edges meet but consecutive ones at their
/// shared corner (touching counts as meeting), and no corner turns straight back.
fn is_simple(p: &[DVec2]) -> bool {
    let n = p.len();
    // Strictly on one side: neither zero.
    let apart = |x: f64, y: f64| (x > 0.0 && y > 0.0) || (x < 0.0 && y < 0.0);
    for i in 0..n {
        let (a, b) = (p[i], p[(i + 1) % n]);
        if a == b {
            return false;
        }
        // A straight turn back: the next edge runs along this one.
        let c = p[(i + 2) % n];
        if orient(a, b, c) == 0.0 && (b - a).dot(c - b) < 0.0 {
            return false;
        }
        for j in i + 2..n {
            if (j + 1) % n == i {
                continue;
            }
            let (c, d) = (p[j], p[(j + 1) % n]);
            let (d1, d2) = (orient(a, b, c), orient(a, b, d));
            let (d3, d4) = (orient(c, d, a), orient(c, d, b));
            if !apart(d1, d2) && !apart(d3, d4) {
                return false;
            }
        }
    }
    true
}

/// Ear clipping of the simple counter-clockwise polygon `p`: n - 2 triangles (corner indices,
/// counter-clockwise), each clipped ear the best shaped of those available. None when some
/// step finds no ear with area above [`MIN_AREA2`] and no other corner in it.
fn ears(p: &[DVec2]) -> Option<Vec<[usize; 3]>> {
    let n = p.len();
    let mut prev: Vec<usize> = (0..n).map(|i| (i + n - 1) % n).collect();
    let mut next: Vec<usize> = (0..n).map(|i| (i + 1) % n).collect();
    let mut alive = vec![true; n];
    // The ear at i: its shape (4√3·area / Σ edge², 1 for equilateral) when it is one.
    let ear = |i: usize, prev: &[usize], next: &[usize], alive: &[bool]| -> Option<f64> {
        let (a, b, c) = (prev[i], i, next[i]);
        let area2 = orient(p[a], p[b], p[c]);
        if area2 <= MIN_AREA2 {
            return None;
        }
        let holds = |x: DVec2| {
            orient(p[a], p[b], x) >= 0.0
                && orient(p[b], p[c], x) >= 0.0
                && orient(p[c], p[a], x) >= 0.0
        };
        if (0..n).any(|x| alive[x] && x != a && x != b && x != c && holds(p[x])) {
            return None;
        }
        let edges = (p[a] - p[b]).length_squared()
            + (p[b] - p[c]).length_squared()
            + (p[c] - p[a]).length_squared();
        Some(2.0 * 3f64.sqrt() * area2 / edges)
    };
    let mut shape: Vec<Option<f64>> = (0..n).map(|i| ear(i, &prev, &next, &alive)).collect();
    let mut out = Vec::with_capacity(n - 2);
    for _ in 3..n {
        let (i, _) = shape
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.map(|s| (i, s)))
            .fold(None, |best: Option<(usize, f64)>, (i, s)| match best {
                Some((_, b)) if b >= s => best,
                _ => Some((i, s)),
            })?;
        let (a, c) = (prev[i], next[i]);
        out.push([a, i, c]);
        alive[i] = false;
        shape[i] = None;
        next[a] = c;
        prev[c] = a;
        shape[a] = ear(a, &prev, &next, &alive);
        shape[c] = ear(c, &prev, &next, &alive);
    }
    let i = (0..n).find(|&i| alive[i])?;
    let (a, c) = (prev[i], next[i]);
    if orient(p[a], p[i], p[c]) <= MIN_AREA2 {
        return None;
    }
    out.push([a, i, c]);
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::blocks::{blocks, extract_block};
    use crate::mesh::classify::test_support::ball;
    use crate::mesh::manifold::Joined;
    use crate::simplify::band::Tolerance;

    /// Over the discs of balls' block patches: every new edge is fresh (no live triangle outside
    /// the disc has it) and has an end that is not locked. Two locked ends may lie on the
    /// block's face, where the next block can clip the same ear the other way: at n = 256 on
    /// the bundled example that welded into an edge of four triangles. Allowing such ears fails
    /// this test.
    #[test]
    fn new_edges_are_fresh_and_never_join_two_locked_vertices() {
        let (mut fans, mut ears) = (0, 0);
        for (k, r) in [7.3f32, 8.6, 9.2].into_iter().enumerate() {
            let cls = ball([24, 24, 24], [11.0 + 0.3 * k as f32, 10.6, 10.2], r);
            let joined = Joined::new(&cls);
            for size in [5, 7, 9] {
                for b in blocks(crate::mesh::classify::VoxelSet::dims(&joined), size) {
                    let patch = extract_block(&joined, &b);
                    let locked = patch.locked;
                    let s = State::new(patch.mesh);
                    let taken = vec![false; s.tris.len()];
                    for v in 0..s.pos.len() as u32 {
                        if locked[v as usize] {
                            continue;
                        }
                        let Some(plan) = s
                            .disc(v, 2, &locked, &taken)
                            .and_then(|d| s.remesh(d, &locked))
                        else {
                            continue;
                        };
                        let loop_edge = |x: u32, y: u32| {
                            let n = plan.disc.boundary.len();
                            (0..n).any(|i| {
                                let (p, q) =
                                    (plan.disc.boundary[i], plan.disc.boundary[(i + 1) % n]);
                                (p, q) == (x, y) || (q, p) == (x, y)
                            })
                        };
                        for (ids, _) in &plan.new {
                            for k in 0..3 {
                                let (x, y) = (ids[k], ids[(k + 1) % 3]);
                                if loop_edge(x, y) {
                                    continue;
                                }
                                assert!(
                                    !(locked[x as usize] && locked[y as usize]),
                                    "a new edge {x}-{y} between locked vertices"
                                );
                                let elsewhere = s.star[x as usize].iter().any(|&t| {
                                    plan.disc.tris.binary_search(&t).is_err()
                                        && s.tris[t as usize].contains(&y)
                                });
                                assert!(!elsewhere, "new edge {x}-{y} is an edge already");
                            }
                        }
                        if plan.point.is_some() {
                            fans += 1;
                        } else {
                            ears += 1;
                        }
                    }
                }
            }
        }
        assert!(fans > 100 && ears > 100, "fans {fans}, ears {ears}");
    }

    /// Every 2-ring disc of `s` that remeshes, with nothing locked or taken.
    fn remeshed(s: &State) -> Vec<Remeshed> {
        let locked = vec![false; s.pos.len()];
        let taken = vec![false; s.tris.len()];
        (0..s.pos.len() as u32)
            .filter_map(|v| {
                s.disc(v, RINGS, &locked, &taken)
                    .and_then(|d| s.remesh(d, &locked))
            })
            .collect()
    }

    /// A tolerance volume of radius 1.2 voxels, with the sweep radius `sweep`.
    fn narrow(sweep: f64) -> SimplifyOptions {
        SimplifyOptions {
            tolerance: Tolerance {
                outside: 1.2,
                inside: 1.2,
            },
            sweep,
            min_radius: 0.05,
            target_triangles: 0,
        }
    }

    /// Every disc of rough random voxel sets' and balls' boundaries, checked with a narrow
    /// tolerance volume and without the swept volume's pieces, with a sweep radius above it and
    /// one below: each disc accepted has every sampled point of its new triangles in T and
    /// sweeps over no voxel centre farther than the sweep radius from the outside (old - new
    /// winds 0 there), and many are refused by each check. With the band check skipped,
    /// accepted fans leave T; with the sweep check's tetrahedra skipped, they sweep over such
    /// centres.
    #[test]
    fn accepted_discs_stay_in_the_band_and_sweep_no_deep_point() {
        use crate::simplify::pieces::winding;
        use crate::simplify::tests::{deep, in_volume};
        let (mut accepted, mut band, mut sweep) = (0, 0, 0);
        for o in [narrow(1.25), narrow(0.9)] {
            let shapes = (0..4)
                .map(|seed| crate::mesh::classify::test_support::random([16, 16, 16], seed))
                .chain([7.3, 8.6].map(|r| ball([24, 24, 24], [11.2, 10.6, 10.2], r)));
            for (seed, cls) in shapes.enumerate() {
                let s = State::new(crate::mesh::extract::extract(&cls));
                let mut scratch = Scratch::new(&cls, None, s.tris.len());
                for plan in remeshed(&s) {
                    match check(&s, &mut scratch, &o, &plan, &|_| Ok(())) {
                        Err(Reject::Band) => band += 1,
                        Err(Reject::Sweep) => sweep += 1,
                        Err(_) => {}
                        Ok(()) => {
                            accepted += 1;
                            let mut surface = plan.disc.places(&s);
                            for (_, q) in &plan.new {
                                for i in 0..=4 {
                                    for j in 0..=4 - i {
                                        let (a, b) = (i as f64 / 4.0, j as f64 / 4.0);
                                        let x = q[0] + (q[1] - q[0]) * a + (q[2] - q[0]) * b;
                                        assert!(in_volume(&cls, x, o), "seed {seed}: {x} out of T");
                                    }
                                }
                                surface.push([q[0], q[2], q[1]]);
                            }
                            let (lo, hi) = super::super::intersect::bounds(surface.as_flattened());
                            let (lo, hi) = (lo.floor().as_ivec3(), hi.ceil().as_ivec3());
                            for i in lo.x..hi.x {
                                for j in lo.y..hi.y {
                                    for k in lo.z..hi.z {
                                        let [i, j, k] = [i, j, k].map(|c| c as isize);
                                        if !deep(&cls, [i, j, k], o) {
                                            continue;
                                        }
                                        let c = DVec3::new(i as f64, j as f64, k as f64) + 0.5;
                                        let w = winding(&surface, c);
                                        assert!(
                                            w.abs() < 1e-6,
                                            "seed {seed}: swept over {c} ({w})"
                                        );
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
        assert!(
            accepted > 50 && band > 50 && sweep > 50,
            "accepted {accepted}, band {band}, sweep {sweep}"
        );
    }

    /// The sweep check by pieces, wired in: an accepted disc whose old and new triangles wind
    /// around a piece's point is refused (Sweep); the same disc with the piece far away passes.
    #[test]
    fn a_disc_winding_around_a_piece_is_refused() {
        use crate::simplify::pieces::{winding, Pieces};
        let o = narrow(1.25);
        let mut found = 0;
        for seed in 0..3 {
            let cls = crate::mesh::classify::test_support::random([16, 16, 16], seed);
            let s = State::new(crate::mesh::extract::extract(&cls));
            let mut plain = Scratch::new(&cls, None, s.tris.len());
            for plan in remeshed(&s) {
                if check(&s, &mut plain, &o, &plan, &|_| Ok(())).is_err() {
                    continue;
                }
                let old = plan.disc.places(&s);
                let mut surface = old.clone();
                surface.extend(plan.new.iter().map(|(_, q)| [q[0], q[2], q[1]]));
                // Between the removed centre vertex and the old triangles' centroids, off the
                // surface (where the winding number is not defined).
                let centre = s.pos[plan.disc.centre as usize];
                let off = |p: DVec3| {
                    surface
                        .iter()
                        .all(|t| crate::verify::geom::dist_triangle(p, t[0], t[1], t[2]) > 1e-6)
                };
                let Some(p) = old
                    .iter()
                    .map(|t| (t[0] + t[1] + t[2]) / 3.0)
                    .flat_map(|c| [0.25, 0.5, 0.75].map(|f| c + (centre - c) * f))
                    .find(|&p| off(p) && (winding(&surface, p).abs() - 1.0).abs() < 1e-9)
                else {
                    continue;
                };
                found += 1;
                let near = Pieces::from_points(vec![[p, p]]);
                let mut scratch = Scratch::new(&cls, Some(&near), s.tris.len());
                assert!(
                    matches!(
                        check(&s, &mut scratch, &o, &plan, &|_| Ok(())),
                        Err(Reject::Sweep)
                    ),
                    "seed {seed}: a disc winding around {p} passed"
                );
                let far = Pieces::from_points(vec![[p + 100.0, p + 100.0]]);
                let mut scratch = Scratch::new(&cls, Some(&far), s.tris.len());
                assert!(check(&s, &mut scratch, &o, &plan, &|_| Ok(())).is_ok());
            }
        }
        assert!(found > 20, "only {found} discs with a point between");
    }

    /// A stop request ends the pass: asked at its first vertex, nothing is remeshed and it
    /// says so; never asked to stop, the same pass remeshes discs.
    #[test]
    fn a_stop_request_ends_the_pass() {
        let cls = ball([24, 24, 24], [11.2, 10.6, 10.2], 8.6);
        let mesh = crate::mesh::extract::extract(&cls);
        for stop in [true, false] {
            let mut s = State::new(mesh.clone());
            let mut scratch = Scratch::new(&cls, None, s.tris.len());
            let (mut heap, mut parked) = (Queue::new(Vec::new()), HashMap::new());
            let locked = vec![false; s.pos.len()];
            let o = narrow(1.25);
            let stopped = remesh_discs(
                &mut s,
                &mut heap,
                &mut parked,
                &mut scratch,
                &o,
                &locked,
                0,
                |_| Ok(()),
                &|| stop,
            );
            assert_eq!(stopped, stop);
            assert_eq!(s.stats.discs == 0, stop, "{} discs", s.stats.discs);
        }
    }

    /// The self-intersection check, wired in: a disc that passes every check is refused
    /// (Intersection) once a separate triangle pierces one of its new triangles, the rest of
    /// the mesh unchanged. Without that check in `check` every such disc here would pass.
    #[test]
    fn a_disc_through_another_triangle_is_refused() {
        let o = narrow(1.25);
        let cls = ball([24, 24, 24], [11.2, 10.6, 10.2], 8.6);
        let mesh = crate::mesh::extract::extract(&cls);
        let s = State::new(mesh.clone());
        let mut scratch = Scratch::new(&cls, None, s.tris.len());
        let accepted: Vec<Remeshed> = remeshed(&s)
            .into_iter()
            .filter(|plan| check(&s, &mut scratch, &o, plan, &|_| Ok(())).is_ok())
            .take(40)
            .collect();
        assert!(
            accepted.len() >= 20,
            "only {} discs accepted",
            accepted.len()
        );
        for plan in &accepted {
            // A needle through the largest new triangle's centroid, across its plane.
            let area = |q: &[DVec3; 3]| (q[1] - q[0]).cross(q[2] - q[0]).length();
            let q = (plan.new.iter().map(|(_, q)| *q))
                .max_by(|a, b| area(a).total_cmp(&area(b)))
                .expect("a new triangle");
            let g = (q[0] + q[1] + q[2]) / 3.0;
            let n = (q[1] - q[0]).cross(q[2] - q[0]).normalize();
            let u = (q[1] - q[0]).normalize() * 0.05;
            let mut pierced = mesh.clone();
            let at = pierced.positions.len() as u32;
            pierced
                .positions
                .extend([g + n * 0.3 + u, g - n * 0.3 + u, g + n * 0.3 - u]);
            pierced.triangles.push([at, at + 1, at + 2]);
            let t = State::new(pierced);
            let mut scratch = Scratch::new(&cls, None, t.tris.len());
            let (locked, taken) = (vec![false; t.pos.len()], vec![false; t.tris.len()]);
            let again = t
                .disc(plan.disc.centre, RINGS, &locked, &taken)
                .and_then(|d| t.remesh(d, &locked))
                .expect("the same disc");
            assert_eq!(again.new, plan.new);
            assert!(
                matches!(
                    check(&t, &mut scratch, &o, &again, &|_| Ok(())),
                    Err(Reject::Intersection)
                ),
                "a disc at {} passed through a needle",
                plan.disc.centre
            );
        }
    }
}
