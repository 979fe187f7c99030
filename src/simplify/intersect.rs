//! Triangle-pair predicates for keeping a mesh free of self-intersections, and a spatial hash of
//! the triangles to find the pairs worth testing.
//!
//! The predicates are conservative for the simplifier's use: with a tolerance `TOUCH` (grid
//! units), pairs that come closer than it (without sharing a vertex) count as intersecting, so a
//! rejection may be spurious but an accepted pair is apart by at least `TOUCH` in f64.

use std::collections::HashMap;
use std::hash::BuildHasherDefault;

use glam::DVec3;

use crate::closest::{closest_on_triangle, segment_segment};

use crate::simplify::band::{pack_cell, KeyHasher};
use crate::simplify::regrow;

/// Distance below which two triangles without a common vertex count as touching, grid units.
pub const TOUCH: f64 = 1e-6;
/// Cosine beyond which two triangles with a common edge count as folded onto each other (their
/// dihedral angle is within about 0.08° of zero).
const FOLDED_COS: f64 = 1.0 - 1e-6;
/// |cos| beyond which two triangles with a common vertex are treated as coplanar.
const COPLANAR_COS: f64 = 1.0 - 1e-9;

/// Distance from segment [p, q] to triangle `t`.
fn segment_triangle(p: DVec3, q: DVec3, t: [DVec3; 3]) -> f64 {
    let n = (t[1] - t[0]).cross(t[2] - t[0]);
    let (sp, sq) = (n.dot(p - t[0]), n.dot(q - t[0]));
    if n.length_squared() > 0.0 && sp * sq <= 0.0 && sp != sq {
        // The segment meets the plane at x: inside the triangle means distance 0.
        let x = p + (q - p) * (sp / (sp - sq));
        if inside_prism(x, t, n) {
            return 0.0;
        }
    }
    let mut best = (closest_on_triangle(p, t) - p)
        .length()
        .min((closest_on_triangle(q, t) - q).length());
    for k in 0..3 {
        best = best.min(segment_segment(p, q, t[k], t[(k + 1) % 3]));
    }
    best
}

/// Whether segment [p, q] comes within [`TOUCH`] of triangle `t`: `segment_triangle(p, q, t) <
/// TOUCH`, answered no at once when an axis separates them clearly (the separating axis test:
/// t's normal, its in-plane edge normals, and the segment's direction crossed with t's edges).
/// Projections more than TOUCH·|u| apart along an axis u prove the distance exceeds TOUCH; the
/// early no asks for 2·TOUCH·|u|, far above the rounding of projections taken relative to t[0]
/// (relative error about 1e-16 of |u| times the pair's extent, a few hundred grid units at most).
fn segment_near(p: DVec3, q: DVec3, t: [DVec3; 3]) -> bool {
    let (lp, lq) = (p - t[0], q - t[0]);
    let corners = [DVec3::ZERO, t[1] - t[0], t[2] - t[0]];
    let edges = [corners[1], corners[2] - corners[1], -corners[2]];
    let n = edges[0].cross(corners[2]);
    let d = lq - lp;
    let separated = |u: DVec3| {
        let (a, b) = (u.dot(lp), u.dot(lq));
        let c = corners.map(|x| u.dot(x));
        let (tlo, thi) = (c[0].min(c[1]).min(c[2]), c[0].max(c[1]).max(c[2]));
        (tlo - a.max(b)).max(a.min(b) - thi) > 2.0 * TOUCH * u.length()
    };
    if separated(n)
        || edges
            .iter()
            .any(|e| separated(n.cross(*e)) || separated(d.cross(*e)))
    {
        return false;
    }
    segment_triangle(p, q, t) < TOUCH
}

/// Whether two triangles come within [`TOUCH`] (`triangle_distance(s, t) < TOUCH`): an edge of
/// one then does of the other.
fn triangles_near(s: [DVec3; 3], t: [DVec3; 3]) -> bool {
    if triangles_separated(s, t) {
        return false;
    }
    (0..3).any(|k| segment_near(s[k], s[(k + 1) % 3], t) || segment_near(t[k], t[(k + 1) % 3], s))
}

/// Whether an axis separates triangles `s` and `t` by more than 2·TOUCH (the separating axis
/// test for two triangles: their edges crossed pairwise; the normals were tried by the caller),
/// so that they are more than TOUCH apart. Projections are taken relative to s[0], as in
/// [`segment_near`].
fn triangles_separated(s: [DVec3; 3], t: [DVec3; 3]) -> bool {
    let ls = [DVec3::ZERO, s[1] - s[0], s[2] - s[0]];
    let lt = t.map(|p| p - s[0]);
    let es = [ls[1], ls[2] - ls[1], -ls[2]];
    let et = [lt[1] - lt[0], lt[2] - lt[1], lt[0] - lt[2]];
    let span = |u: DVec3, x: &[DVec3; 3]| {
        let d = x.map(|p| u.dot(p));
        (d[0].min(d[1]).min(d[2]), d[0].max(d[1]).max(d[2]))
    };
    es.iter().any(|a| {
        et.iter().any(|b| {
            let u = a.cross(*b);
            let ((slo, shi), (tlo, thi)) = (span(u, &ls), span(u, &lt));
            (tlo - shi).max(slo - thi) > 2.0 * TOUCH * u.length()
        })
    })
}

/// Whether `x` (on the plane of `t`, normal `n`) is inside or on `t`.
fn inside_prism(x: DVec3, t: [DVec3; 3], n: DVec3) -> bool {
    (0..3).all(|k| (t[(k + 1) % 3] - t[k]).cross(x - t[k]).dot(n) >= 0.0)
}

/// Distance between two triangles: zero when they intersect (some edge of one then meets the
/// other), else reached between a vertex and a face or between two edges.
#[cfg(test)]
pub fn triangle_distance(s: [DVec3; 3], t: [DVec3; 3]) -> f64 {
    let mut best = f64::INFINITY;
    for k in 0..3 {
        best = best
            .min(segment_triangle(s[k], s[(k + 1) % 3], t))
            .min(segment_triangle(t[k], t[(k + 1) % 3], s));
        if best == 0.0 {
            break;
        }
    }
    best
}

/// [`conflict_with_normals`] for tests, the normals computed here.
#[cfg(test)]
pub fn conflict(si: [u32; 3], s: [DVec3; 3], ti: [u32; 3], t: [DVec3; 3]) -> bool {
    conflict_with_normals(si, s, unit_normal(s), ti, t, unit_normal(t))
}

/// Triangle `s`'s unit normal (zero when degenerate).
pub fn unit_normal(s: [DVec3; 3]) -> DVec3 {
    (s[1] - s[0]).cross(s[2] - s[0]).normalize_or_zero()
}

/// A triangle as the pair tests read it: ids, places, box and unit normal, each worked out once
/// however many pairs it is in.
pub struct Facet {
    ids: [u32; 3],
    pub at: [DVec3; 3],
    bounds: (DVec3, DVec3),
    normal: DVec3,
}

impl Facet {
    pub fn new((ids, at): ([u32; 3], [DVec3; 3])) -> Self {
        Facet {
            ids,
            at,
            bounds: bounds(&at),
            normal: unit_normal(at),
        }
    }

    /// Whether the two have a vertex id in common that `set` (sorted) holds.
    pub fn shares_one_of(&self, o: &Facet, set: &[u32]) -> bool {
        self.ids
            .iter()
            .any(|x| o.ids.contains(x) && set.binary_search(x).is_ok())
    }

    /// Whether the two conflict ([`conflict_with_normals`]), boxes first.
    pub fn meets(&self, o: &Facet) -> bool {
        bounds_meet(self.bounds, o.bounds)
            && conflict_with_normals(self.ids, self.at, self.normal, o.ids, o.at, o.normal)
    }
}

/// Whether two mesh triangles (vertex ids `si`, `ti`, positions `s`, `t`; `ns`, `nt` their
/// [`unit_normal`]s, given since each triangle meets dozens of pair tests) overlap beyond what
/// they share: a pair with no common vertex closer than [`TOUCH`]; a pair with a common edge
/// folded flat onto itself; a pair with one common vertex whose far edges cross the other
/// triangle, or, when coplanar, whose corners at that vertex overlap; the same triangle twice.
pub fn conflict_with_normals(
    si: [u32; 3],
    s: [DVec3; 3],
    ns: DVec3,
    ti: [u32; 3],
    t: [DVec3; 3],
    nt: DVec3,
) -> bool {
    // Shared vertices as (index in s, index in t); a triangle's ids are distinct, so at most 3.
    let mut common = [(0usize, 0usize); 3];
    let mut shared = 0;
    for (i, x) in si.iter().enumerate() {
        for (j, y) in ti.iter().enumerate() {
            if x == y && shared < 3 {
                common[shared] = (i, j);
                shared += 1;
            }
        }
    }
    match shared {
        0 => {
            if apart(s, ns, &t) || apart(t, nt, &s) {
                false
            } else if coplanar(s, ns, &t) {
                !separated_in_plane(s, t, ns)
            } else {
                triangles_near(s, t)
            }
        }
        1 => {
            let (i, j) = common[0];
            let p = s[i];
            let (a, b) = (s[(i + 1) % 3], s[(i + 2) % 3]);
            let (c, d) = (t[(j + 1) % 3], t[(j + 2) % 3]);
            if coplanar(s, ns, &[c, d]) {
                // Both lie in one plane, each inside its corner at p: they meet beyond p only
                // if the corners overlap.
                return corners_overlap(p, [a, b], [c, d], ns);
            }
            if (!apart(s, ns, &[c, d]) && segment_near(c, d, s))
                || (!apart(t, nt, &[a, b]) && segment_near(a, b, t))
            {
                return true;
            }
            ns.dot(nt).abs() > COPLANAR_COS && corners_overlap(p, [a, b], [c, d], ns)
        }
        2 => {
            // Planes meeting at the common edge pq cross only along it, unless the two lie
            // folded onto each other: coplanar with their far vertices on the same side.
            let i = common[0].0;
            let (p, e) = (s[i], s[common[1].0] - s[i]);
            let far = |x: [DVec3; 3], ids: [u32; 3]| {
                let k = (0..3).find(|&k| ids[k] != si[i] && ids[k] != si[common[1].0]);
                e.cross(x[k.expect("a third vertex")] - p)
            };
            let (cs, ct) = (far(s, si), far(t, ti));
            cs.dot(ct) > FOLDED_COS * cs.length() * ct.length()
        }
        _ => true,
    }
}

/// Whether `points` all lie farther than [`TOUCH`] on one side of the plane of `s` (unit normal
/// `n`, zero for a degenerate `s`): then nothing of theirs comes within TOUCH of `s`.
fn apart(s: [DVec3; 3], n: DVec3, points: &[DVec3]) -> bool {
    if n == DVec3::ZERO {
        return false;
    }
    let d = |p: &DVec3| n.dot(*p - s[0]);
    points.iter().all(|p| d(p) > TOUCH) || points.iter().all(|p| d(p) < -TOUCH)
}

/// Whether `points` all lie within [`TOUCH`] of the plane of `s` (unit normal `n`).
fn coplanar(s: [DVec3; 3], n: DVec3, points: &[DVec3]) -> bool {
    n != DVec3::ZERO && points.iter().all(|p| n.dot(*p - s[0]).abs() <= TOUCH)
}

/// For `t` within TOUCH of the plane of `s` (unit normal `n`): whether an edge normal in that
/// plane separates their projections by more than [`TOUCH`] (the separating axis theorem for
/// convex polygons in a plane: no such axis means they overlap).
fn separated_in_plane(s: [DVec3; 3], t: [DVec3; 3], n: DVec3) -> bool {
    let edges = (0..3).flat_map(|k| [s[(k + 1) % 3] - s[k], t[(k + 1) % 3] - t[k]]);
    edges.into_iter().any(|e| {
        let axis = n.cross(e).normalize_or_zero();
        let span = |x: &[DVec3; 3]| {
            let d = x.map(|p| axis.dot(p));
            (d[0].min(d[1]).min(d[2]), d[0].max(d[1]).max(d[2]))
        };
        let ((slo, shi), (tlo, thi)) = (span(&s), span(&t));
        axis != DVec3::ZERO && (tlo - shi > TOUCH || slo - thi > TOUCH)
    })
}

/// Whether the corners at `p` of two coplanar triangles (far vertices `ab`, `cd`, normal `n`)
/// overlap: one holds an edge direction or the bisector of the other strictly inside.
fn corners_overlap(p: DVec3, ab: [DVec3; 2], cd: [DVec3; 2], n: DVec3) -> bool {
    let within = |cone: [DVec3; 2], x: DVec3| {
        let (u, w) = (cone[0] - p, cone[1] - p);
        let side = u.cross(w).dot(n).signum();
        let x = x - p;
        u.cross(x).dot(n) * side > 0.0 && x.cross(w).dot(n) * side > 0.0
    };
    let mid = |e: [DVec3; 2]| p + (e[0] - p).normalize_or_zero() + (e[1] - p).normalize_or_zero();
    within(ab, cd[0])
        || within(ab, cd[1])
        || within(ab, mid(cd))
        || within(cd, ab[0])
        || within(cd, ab[1])
        || within(cd, mid(ab))
}

/// Where the hash's cell faces lie: at CELL_OFFSET + k·cell on each axis (grid units), off the
/// integers and halves most vertices sit on (voxel corners and the midpoints of their edges, at
/// least 0.2 from any face). A face through a box's side would add a layer of cells to each
/// query and each filing, since boxes are widened by TOUCH: with faces on the lattice a query
/// met 38 cells on average at n = 256, and the check took 7% longer overall.
const CELL_OFFSET: f64 = 0.3;

/// Cell size at which an insert prunes the cell (a queried cell of 3 voxels held 34 ids on average
/// at n = 256, live and stale; pruning at 16 measured no different).
const PRUNE_AT: usize = 32;

/// Triangle ids by the cells their bounding boxes meet (cells their plane misses by more than
/// TOUCH left out), an id possibly more than once per cell until the cell is pruned. A triangle
/// that moves is filed again under the cells it newly reaches, so every live triangle is found
/// in each cell that holds a point within TOUCH of it; inserts prune the cells they touch.
pub struct TriangleHash {
    cell: f64,
    cells: HashMap<u64, Vec<u32>, BuildHasherDefault<KeyHasher>>,
}

impl TriangleHash {
    /// `cell`: edge of a hash cell, grid units.
    pub fn new(cell: f64) -> Self {
        TriangleHash {
            cell,
            cells: HashMap::default(),
        }
    }

    fn cell_range(&self, t: &[DVec3]) -> ([i64; 3], [i64; 3]) {
        let (lo, hi) = bounds(t);
        let (lo, hi) = (lo - DVec3::splat(TOUCH), hi + DVec3::splat(TOUCH));
        let f = |v: DVec3| {
            let c = ((v - CELL_OFFSET) / self.cell).floor();
            [c.x as i64, c.y as i64, c.z as i64]
        };
        (f(lo), f(hi))
    }

    fn key(c: [i64; 3]) -> u64 {
        // Cells lie in [-1, 12288/cell + 1].
        pack_cell(c)
    }

    /// The cells a triangle at `t` is filed under: those its box meets that its plane comes
    /// within TOUCH of (every cell of the box for a degenerate triangle).
    fn reach(&self, t: &[DVec3; 3]) -> Reach {
        let (lo, hi) = self.cell_range(t);
        let n = (t[1] - t[0]).cross(t[2] - t[0]);
        let (n_abs, half) = (n.abs(), DVec3::splat(self.cell / 2.0 + TOUCH));
        Reach {
            lo,
            hi,
            cell: self.cell,
            n,
            offset: n.dot(t[0]),
            margin: n_abs.dot(half) + 1e-9 * (n_abs.dot(t[0].abs()) + n_abs.dot(half)),
        }
    }

    /// Add `id` (positions `t`) under every cell of its [`Self::reach`] not already reached from
    /// `was`, where it was filed before (its cells hold it already). A full cell holding
    /// [`PRUNE_AT`] ids or more first drops repeats and those that `current` says are gone or
    /// have moved away from it (`current`: a triangle's positions now, None when it is gone).
    pub fn insert(
        &mut self,
        id: u32,
        t: &[DVec3; 3],
        was: Option<&[DVec3; 3]>,
        current: impl Fn(u32) -> Option<[DVec3; 3]>,
    ) {
        let now = self.reach(t);
        let before = was.map(|w| self.reach(w));
        let cell = self.cell;
        for k in now.lo[2]..=now.hi[2] {
            for j in now.lo[1]..=now.hi[1] {
                for i in now.lo[0]..=now.hi[0] {
                    let c = [i, j, k];
                    if !now.meets(c) || before.as_ref().is_some_and(|r| r.meets(c)) {
                        continue;
                    }
                    let ids = self.cells.entry(Self::key(c)).or_default();
                    // Prune only when the list is full (about to reallocate), and grow it when
                    // pruning frees less than a quarter: amortized O(1) per insert even in
                    // cells that hold many live triangles. A triangle that left a cell and came
                    // back may be pushed twice: pruning drops the repeats.
                    if ids.len() >= PRUNE_AT && ids.len() == ids.capacity() {
                        let (clo, chi) = Reach::bounds(c, cell);
                        ids.retain(|&u| {
                            current(u).is_some_and(|p| bounds_meet(bounds(&p), (clo, chi)))
                        });
                        ids.sort_unstable();
                        ids.dedup();
                        ids.reserve(regrow(ids.len(), ids.capacity()));
                    }
                    if ids.last() != Some(&id) {
                        ids.push(id);
                    }
                }
            }
        }
    }

    /// Ids whose cells meet the box of `t`'s points (a superset of the live triangles near
    /// them; dead ids may remain), with repeats (one per cell: callers filter first, then
    /// dedup the few left).
    pub fn near(&self, t: &[DVec3], out: &mut Vec<u32>) {
        out.clear();
        let (lo, hi) = self.cell_range(t);
        for k in lo[2]..=hi[2] {
            for j in lo[1]..=hi[1] {
                for i in lo[0]..=hi[0] {
                    if let Some(ids) = self.cells.get(&Self::key([i, j, k])) {
                        out.extend_from_slice(ids);
                    }
                }
            }
        }
    }
}

/// The cells a triangle is filed under ([`TriangleHash::reach`]).
struct Reach {
    lo: [i64; 3],
    hi: [i64; 3],
    cell: f64,
    /// The triangle's (unnormalized) normal and n·t[0].
    n: DVec3,
    offset: f64,
    /// How far n·x - offset may be from 0 at a cell's centre for its plane to come within
    /// TOUCH of the cell, rounding included.
    margin: f64,
}

impl Reach {
    /// Cell `c`'s box (lo, hi).
    fn bounds(c: [i64; 3], cell: f64) -> (DVec3, DVec3) {
        let lo = DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * cell + CELL_OFFSET;
        (lo, lo + DVec3::splat(cell))
    }

    /// Whether cell `c` is one of them: in the box, and (a large tilted triangle's box spans
    /// many cells its plane never comes near) its box widened by TOUCH meets the plane. Sound
    /// for `near`: a point within TOUCH of the triangle lies in a cell the plane comes within
    /// TOUCH of.
    fn meets(&self, c: [i64; 3]) -> bool {
        let inside = (0..3).all(|a| self.lo[a] <= c[a] && c[a] <= self.hi[a]);
        let (lo, hi) = Self::bounds(c, self.cell);
        inside && (self.n.dot((lo + hi) / 2.0) - self.offset).abs() <= self.margin
    }
}

/// Bounding box (lo, hi) of `points`.
pub fn bounds(points: &[DVec3]) -> (DVec3, DVec3) {
    points
        .iter()
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        })
}

/// Whether two boxes (lo, hi) come within [`TOUCH`] of each other.
pub fn bounds_meet((slo, shi): (DVec3, DVec3), (tlo, thi): (DVec3, DVec3)) -> bool {
    (slo - thi).max_element() <= TOUCH && (tlo - shi).max_element() <= TOUCH
}

/// Least cosine between a fan triangle's normal and the direction d of [`fan_one_to_one`]:
/// nearer upright triangles leave the fan to the pair tests, and two neighbours of a fan that
/// passes are never folded by [`conflict_with_normals`]'s measure (their normals then differ by
/// at least 2·10⁻² rad, far beyond `FOLDED_COS`).
const FAN_MIN_FACING: f64 = 1e-2;

/// Most triangles around a vertex that [`fan_one_to_one`] judges (a larger fan: false).
const FAN_MAX: usize = 32;

/// Whether the triangles around a vertex at `x`, each given by its other two corners in the
/// triangle's order (ids and places: (x, p, q)), form one closed fan that projects one to one
/// along some direction d: every triangle faces d (cosine above [`FAN_MIN_FACING`]) and a ray
/// from x across d lies in exactly one triangle's corner at x. d starts as the summed normal
/// and turns towards the triangle that faces it least, a few times at most.
///
/// Then no two of them meet beyond what they share (docs/design.md, "Self-intersection"): the
/// projected corners at x are convex (each triangle faces d) and cover every ray from x as
/// often as the fan winds about x (a link with several cycles winds once per cycle), here
/// once, so they tile the plane about x; two projections meet only on a shared ray, where
/// each triangle's preimage is its own edge, so the triangles meet only along shared edges or
/// at x. False for an open fan, one of fewer than three or more than [`FAN_MAX`] triangles,
/// and where no d was found.
pub fn fan_one_to_one(x: DVec3, fan: &[(u32, u32, DVec3, DVec3)]) -> bool {
    if fan.len() < 3 || fan.len() > FAN_MAX {
        return false;
    }
    // Closed: the far edges' starts are distinct and are their ends (a permutation).
    for (i, &(p, ..)) in fan.iter().enumerate() {
        let starts = fan[i + 1..].iter().filter(|f| f.0 == p).count();
        let ends = fan.iter().filter(|f| f.1 == p).count();
        if starts != 0 || ends != 1 {
            return false;
        }
    }
    let mut unit = [DVec3::ZERO; FAN_MAX];
    let mut d = DVec3::ZERO;
    for (k, &(_, _, p, q)) in fan.iter().enumerate() {
        let n = (p - x).cross(q - x);
        d += n;
        unit[k] = n.normalize_or_zero();
    }
    let unit = &unit[..fan.len()];
    for _ in 0..6 {
        d = d.normalize_or_zero();
        let worst = unit
            .iter()
            .copied()
            .min_by(|m, n| m.dot(d).total_cmp(&n.dot(d)))
            .unwrap_or_default();
        if worst.dot(d) > FAN_MIN_FACING {
            return covered_once(x, fan, d);
        }
        d += worst;
    }
    false
}

/// Whether one ray from x across unit `d` lies in exactly one of the fan's corners at x, each
/// taken half-open [p - x, q - x) so that a ray along a shared edge counts once; with every
/// corner convex about d, that count is the fan's winding number.
fn covered_once(x: DVec3, fan: &[(u32, u32, DVec3, DVec3)], d: DVec3) -> bool {
    // A ray off the lattice's directions, which a voxel mesh's edges often follow.
    const SKEW: DVec3 = DVec3::new(0.577_215_664_9, 0.330_725_471_3, 0.751_125_544_4);
    let u = d
        .cross(SKEW)
        .try_normalize()
        .unwrap_or(d.any_orthonormal_vector());
    // Each edge's side of the ray, the same sign in both corners it bounds; an edge within
    // 10⁻⁹ of the ray's line leaves the fan to the pair tests, so that rounding (about 10⁻¹⁶
    // of the edge) cannot change the count.
    let side = |p: DVec3| {
        let e = p - x;
        let s = e.cross(u).dot(d);
        (s.abs() > 1e-9 * e.length()).then_some(s > 0.0)
    };
    let mut covering = 0;
    for &(_, _, p, q) in fan {
        match (side(p), side(q)) {
            (Some(after_start), Some(after_end)) => covering += (after_start && !after_end) as u32,
            _ => return false,
        }
    }
    covering == 1
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Uniform numbers in [0, 1), reproducible from `seed`.
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut rng = fastrand::Rng::with_seed(seed);
        move || rng.f64()
    }

    /// A uniform random point of triangle `t`.
    fn point_on(t: &[DVec3; 3], f: &mut impl FnMut() -> f64) -> DVec3 {
        let (u, v) = (f(), f());
        let (u, v) = if u + v > 1.0 {
            (1.0 - u, 1.0 - v)
        } else {
            (u, v)
        };
        t[0] + u * (t[1] - t[0]) + v * (t[2] - t[0])
    }

    fn v(x: f64, y: f64, z: f64) -> DVec3 {
        DVec3::new(x, y, z)
    }

    #[test]
    fn triangle_distance_on_hand_made_pairs() {
        let s = [v(0.0, 0.0, 0.0), v(2.0, 0.0, 0.0), v(0.0, 2.0, 0.0)];
        // Parallel, 0.5 above: distance 0.5.
        let t = s.map(|p| p + v(0.1, 0.1, 0.5));
        assert!((triangle_distance(s, t) - 0.5).abs() < 1e-12);
        // Piercing through the middle: 0.
        let pierce = [v(0.5, 0.5, -1.0), v(0.6, 0.5, 1.0), v(0.5, 0.6, 1.0)];
        assert_eq!(triangle_distance(s, pierce), 0.0);
        // Coplanar and overlapping, no edge of one crossing the plane: 0.
        let overlap = [v(0.2, 0.2, 0.0), v(0.6, 0.2, 0.0), v(0.2, 0.6, 0.0)];
        assert_eq!(triangle_distance(s, overlap), 0.0);
        // Edge against edge, skew: the distance between the lines.
        let skew = [v(1.0, 1.5, 0.3), v(1.0, 1.5, 2.0), v(3.0, 3.0, 3.0)];
        let d = triangle_distance(s, skew);
        let by_samples = (0..=200)
            .flat_map(|i| (0..=(200 - i)).map(move |j| (i, j)))
            .map(|(i, j)| {
                let p =
                    s[0] + (s[1] - s[0]) * (i as f64 / 200.0) + (s[2] - s[0]) * (j as f64 / 200.0);
                (closest_on_triangle(p, skew) - p).length()
            })
            .fold(f64::INFINITY, f64::min);
        assert!(
            d <= by_samples + 1e-12 && d > by_samples - 0.02,
            "{d} vs {by_samples}"
        );
    }

    /// Random closed fans about the origin, winding once or twice, flat to steep, some with a
    /// link vertex thrown far up or down: every fan [`fan_one_to_one`] passes has no pair of
    /// triangles that conflict by the pair rules, no fan that winds twice passes, and most
    /// gentle fans that wind once do (so the shortcut is worth having).
    #[test]
    fn fans_that_project_one_to_one_hold_no_conflicting_pair() {
        let mut f = uniform(7);
        let (mut gentle, mut gentle_passed, mut passed) = (0, 0, 0);
        for case in 0..20_000 {
            let winds = 1 + case % 2;
            // Corners below π about z, so that the fan faces z and winds `winds` times.
            let k = 2 * winds + 1 + (f() * 10.0) as usize;
            let gaps: Vec<f64> = (0..k).map(|_| 0.2 + f()).collect();
            let scale = std::f64::consts::TAU * winds as f64 / gaps.iter().sum::<f64>();
            if gaps.iter().any(|g| g * scale > 3.1) {
                continue;
            }
            let turns: Vec<f64> = gaps
                .iter()
                .scan(0.0, |at, g| {
                    *at += g * scale;
                    Some(*at)
                })
                .collect();
            let height = [0.05, 0.5, 2.0][case / 2 % 3];
            let thrown = (case / 6 % 4 == 0).then(|| (f() * k as f64) as usize);
            let link: Vec<DVec3> = turns
                .iter()
                .enumerate()
                .map(|(i, a)| {
                    let r = 0.3 + 2.0 * f();
                    let z = if thrown == Some(i) {
                        8.0 * (f() - 0.5)
                    } else {
                        height * (f() - 0.5)
                    };
                    v(r * a.cos(), r * a.sin(), z)
                })
                .collect();
            let fan: Vec<(u32, u32, DVec3, DVec3)> = (0..k)
                .map(|i| {
                    let j = (i + 1) % k;
                    (i as u32 + 1, j as u32 + 1, link[i], link[j])
                })
                .collect();
            let x = DVec3::ZERO;
            let ok = fan_one_to_one(x, &fan);
            if winds == 1 && height < 1.0 && thrown.is_none() && k >= 4 {
                gentle += 1;
                gentle_passed += ok as u32;
            }
            if !ok {
                continue;
            }
            passed += 1;
            assert_eq!(winds, 1, "case {case}: a fan winding twice passed");
            let tri = |(p, q, a, b): (u32, u32, DVec3, DVec3)| ([0, p, q], [x, a, b]);
            for i in 0..k {
                for j in i + 1..k {
                    let ((si, sp), (ti, tp)) = (tri(fan[i]), tri(fan[j]));
                    assert!(
                        !conflict(si, sp, ti, tp),
                        "case {case}: triangles {i} and {j} conflict"
                    );
                }
            }
        }
        assert!(
            gentle_passed * 10 > gentle * 9,
            "{gentle_passed} of {gentle} gentle fans passed"
        );
        assert!(passed > 4000, "{passed} fans passed");
        // An open fan (one triangle dropped) never passes.
        let link = [
            v(1.0, 0.0, 0.0),
            v(0.0, 1.0, 0.1),
            v(-1.0, 0.0, 0.0),
            v(0.0, -1.0, 0.1),
        ];
        let closed: Vec<_> = (0..4)
            .map(|i| (i as u32, (i as u32 + 1) % 4, link[i], link[(i + 1) % 4]))
            .collect();
        assert!(fan_one_to_one(DVec3::ZERO, &closed));
        assert!(!fan_one_to_one(DVec3::ZERO, &closed[..3]));
    }

    #[test]
    fn conflicts_by_what_the_pair_shares() {
        let ids = [0, 1, 2];
        let s = [v(0.0, 0.0, 0.0), v(2.0, 0.0, 0.0), v(0.0, 2.0, 0.0)];
        // A hinge along edge 0-1: open is fine, folded flat onto s is not.
        let open = [v(0.0, 0.0, 0.0), v(2.0, 0.0, 0.0), v(1.0, -1.0, 0.5)];
        assert!(!conflict(ids, s, [1, 0, 3], open));
        let folded = [v(2.0, 0.0, 0.0), v(0.0, 0.0, 0.0), v(0.5, 1.0, 0.0)];
        assert!(conflict(ids, s, [1, 0, 3], folded));
        // A common vertex: a fan neighbour beside s is fine, one lying over s in its plane is
        // not, nor one whose far edge pierces s.
        let beside = [v(0.0, 0.0, 0.0), v(0.0, -2.0, 0.0), v(2.0, -1.0, 0.0)];
        assert!(!conflict(ids, s, [0, 4, 5], beside));
        let over = [v(0.0, 0.0, 0.0), v(1.0, 0.2, 0.0), v(0.2, 1.0, 0.0)];
        assert!(conflict(ids, s, [0, 4, 5], over));
        let through = [v(0.0, 0.0, 0.0), v(0.5, 0.5, -1.0), v(0.5, 0.6, 1.0)];
        assert!(conflict(ids, s, [0, 4, 5], through));
        let tilted = [v(0.0, 0.0, 0.0), v(1.0, 1.0, 1.0), v(0.0, 1.0, 1.0)];
        assert!(!conflict(ids, s, [0, 4, 5], tilted));
        // Nothing shared: touching counts, apart does not; the same triangle twice conflicts.
        let touching = s.map(|p| p + v(0.0, 0.0, TOUCH / 2.0));
        assert!(conflict(ids, s, [6, 7, 8], touching));
        let apart = s.map(|p| p + v(0.0, 0.0, 0.01));
        assert!(!conflict(ids, s, [6, 7, 8], apart));
        assert!(conflict(ids, s, [2, 0, 1], [s[2], s[0], s[1]]));
    }

    /// Random pairs, many intersecting: the distance never exceeds that of any sampled point of
    /// one to the other, and is within the samples' covering radius of their minimum.
    #[test]
    fn triangle_distance_matches_dense_samples() {
        let mut rnd = uniform(11);
        let k = 60;
        let (mut hits, mut misses) = (0, 0);
        for _ in 0..300 {
            let mut tri = |c: f64| -> [DVec3; 3] {
                std::array::from_fn(|_| v(rnd() * 2.0 + c, rnd() * 2.0, rnd() * 2.0))
            };
            let (s, t) = (tri(0.0), tri(0.8));
            let d = triangle_distance(s, t);
            let mut sampled = f64::INFINITY;
            let mut longest: f64 = 0.0;
            for (a, b) in [(s, t), (t, s)] {
                for m in 0..3 {
                    longest = longest.max((a[m] - a[(m + 1) % 3]).length());
                }
                for i in 0..=k {
                    for j in 0..=(k - i) {
                        let p = a[0]
                            + (a[1] - a[0]) * (i as f64 / k as f64)
                            + (a[2] - a[0]) * (j as f64 / k as f64);
                        sampled = sampled.min((closest_on_triangle(p, b) - p).length());
                    }
                }
            }
            assert!(d <= sampled + 1e-12, "{s:?} {t:?}: {d} > sampled {sampled}");
            // Barycentric grid pieces have edges at most longest/k: covering radius below that.
            assert!(
                d >= sampled - longest / k as f64,
                "{s:?} {t:?}: {d} << sampled {sampled}"
            );
            if d == 0.0 {
                hits += 1;
            } else {
                misses += 1;
            }
        }
        assert!(
            hits > 30 && misses > 30,
            "{hits} intersecting, {misses} apart"
        );
    }

    /// How many cases of an agreement test were near (below TOUCH), far, and just over TOUCH.
    #[derive(Default)]
    struct Tally {
        near: usize,
        far: usize,
        close_calls: usize,
    }

    impl Tally {
        fn add(&mut self, exact: f64) {
            if exact < TOUCH {
                self.near += 1;
            } else {
                self.far += 1;
            }
            if exact > TOUCH && exact < 4.0 * TOUCH {
                self.close_calls += 1;
            }
        }

        /// The cases covered both answers and the hard ones between.
        fn assert_at_least(&self, near: usize, far: usize, close_calls: usize) {
            assert!(
                self.near > near && self.far > far && self.close_calls > close_calls,
                "{} near, {} far, {} just over TOUCH",
                self.near,
                self.far,
                self.close_calls
            );
        }
    }

    /// The early answer of `segment_near` never changes the exact one: random segments and
    /// triangles, many of them passing the triangle's plane or edges within a few TOUCH.
    #[test]
    fn segment_near_agrees_with_the_distance() {
        let mut f = uniform(0x9e37_79b9_7f4a_7c15);
        let mut tally = Tally::default();
        for round in 0..200_000 {
            let t: [DVec3; 3] = std::array::from_fn(|_| v(f() * 4.0, f() * 4.0, f() * 4.0));
            // A segment through a point of t or of an edge of t, shifted off it by a few TOUCH
            // (or by up to a unit), pointing anywhere.
            let on = if round % 2 == 0 {
                point_on(&t, &mut f)
            } else {
                let k = round % 3;
                t[k] + (t[(k + 1) % 3] - t[k]) * f()
            };
            let off = if round % 3 == 0 { 1.0 } else { 4.0 * TOUCH };
            let shift = v(f() - 0.5, f() - 0.5, f() - 0.5) * 2.0 * off;
            let dir = v(f() - 0.5, f() - 0.5, f() - 0.5) * 3.0;
            let (p, q) = (on + shift - dir * f(), on + shift + dir * f());
            let exact = segment_triangle(p, q, t);
            assert_eq!(
                segment_near(p, q, t),
                exact < TOUCH,
                "{p} {q} {t:?}: {exact}"
            );
            tally.add(exact);
        }
        tally.assert_at_least(10_000, 10_000, 1000);
    }

    /// The triangle-pair test with its separating axes first answers as the exact distance does,
    /// on pairs placed a few TOUCH apart (and some a unit apart), point to point or across
    /// edges.
    #[test]
    fn triangles_near_agrees_with_the_distance() {
        let mut f = uniform(0x51_7cc1_b727_220a);
        let mut tally = Tally::default();
        for round in 0..100_000 {
            let s: [DVec3; 3] = std::array::from_fn(|_| v(f() * 4.0, f() * 4.0, f() * 4.0));
            // Three kinds of t, at about d from s: a unit away anywhere; a triangle of s's plane
            // lifted by d (over s, so d is the distance); one whose nearest vertex lies d
            // beyond an edge of s, in s's plane, the rest farther out.
            let n = unit_normal(s);
            let d = 4.0 * TOUCH * f();
            let t: [DVec3; 3] = match round % 3 {
                0 => {
                    let shift = v(f() - 0.5, f() - 0.5, f() - 0.5) * 2.0;
                    std::array::from_fn(|_| point_on(&s, &mut f) + shift)
                }
                1 => std::array::from_fn(|_| point_on(&s, &mut f) + n * d),
                _ => {
                    let k = (round / 3) % 3;
                    let (a, b) = (s[k], s[(k + 1) % 3]);
                    let on = a + (b - a) * f();
                    let w = n.cross(b - a).normalize();
                    // Outward: away from the third vertex.
                    let w = if w.dot(s[(k + 2) % 3] - a) > 0.0 {
                        -w
                    } else {
                        w
                    };
                    [
                        on + w * d,
                        on + w * (d + f() + 0.1) + n * (f() - 0.5),
                        on + w * (d + f() + 0.1) + (b - a) * (f() - 0.5),
                    ]
                }
            };
            let exact = triangle_distance(s, t);
            assert_eq!(triangles_near(s, t), exact < TOUCH, "{s:?} {t:?}: {exact}");
            tally.add(exact);
        }
        tally.assert_at_least(5_000, 5_000, 500);
    }

    /// Any triangle through a point of an inserted one finds it, however large and tilted the
    /// inserted one is (most of its box's cells are skipped).
    #[test]
    fn hash_finds_every_triangle_through_a_point_of_an_inserted_one() {
        let mut f = uniform(3);
        let mut hash = TriangleHash::new(2.0);
        let mut tris = Vec::new();
        for id in 0..200u32 {
            let c = DVec3::new(f(), f(), f()) * 40.0;
            let span = if id % 4 == 0 { 25.0 } else { 3.0 };
            let t = [0, 1, 2].map(|_| c + (DVec3::new(f(), f(), f()) - 0.5) * span);
            tris.push(t);
            hash.insert(id, &t, None, |u| Some(tris[u as usize]));
        }
        let mut skipped = 0;
        let mut out = Vec::new();
        for (id, t) in tris.iter().enumerate() {
            for _ in 0..20 {
                let y = point_on(t, &mut f);
                let q = [0, 1, 2].map(|_| y + (DVec3::new(f(), f(), f()) - 0.5) * 0.1);
                let q = [y, q[1], q[2]];
                hash.near(&q, &mut out);
                assert!(
                    out.contains(&(id as u32)),
                    "triangle {id} not found through {y}"
                );
            }
            let (lo, hi) = hash.cell_range(t);
            let boxed = (0..3).map(|a| hi[a] - lo[a] + 1).product::<i64>();
            let held = hash
                .cells
                .values()
                .filter(|ids| ids.contains(&(id as u32)))
                .count();
            skipped += boxed as usize - held;
        }
        assert!(skipped > 1000, "only {skipped} cells skipped");
    }

    /// Triangles moved many times (re-filed from where they were, in cells crowded enough to be
    /// pruned, some removed) are still found through every point of where they are now.
    #[test]
    fn hash_finds_triangles_after_moves_and_prunes() {
        let mut f = uniform(11);
        let mut hash = TriangleHash::new(2.0);
        let mut tris: Vec<Option<[DVec3; 3]>> = Vec::new();
        for id in 0..600u32 {
            let c = DVec3::new(f(), f(), f()) * 6.0;
            let t = [0, 1, 2].map(|_| c + (DVec3::new(f(), f(), f()) - 0.5) * 1.5);
            tris.push(Some(t));
            hash.insert(id, &t, None, |u| tris[u as usize]);
        }
        assert_filed(&hash, &tris, 0);
        for step in 0..20_000 {
            let id = (f() * 600.0) as usize;
            let Some(was) = tris[id] else { continue };
            if step % 50 == 0 {
                tris[id] = None;
                continue;
            }
            // Small moves mostly, now and then a jump across several cells.
            let reach = if step % 10 == 0 { 6.0 } else { 0.7 };
            let k = (f() * 3.0) as usize;
            let mut t = was;
            t[k] += (DVec3::new(f(), f(), f()) - 0.5) * reach;
            tris[id] = Some(t);
            let current = |u: u32| tris[u as usize];
            hash.insert(id as u32, &t, Some(&was), current);
            if step % 500 == 0 {
                assert_filed(&hash, &tris, step);
            }
        }
        let mut out = Vec::new();
        let mut crowded = 0;
        for ids in hash.cells.values() {
            crowded += usize::from(ids.len() >= PRUNE_AT);
        }
        assert!(
            crowded > 10,
            "only {crowded} cells were crowded enough to prune"
        );
        for (id, t) in tris.iter().enumerate() {
            let Some(t) = t else { continue };
            for _ in 0..20 {
                let y = point_on(t, &mut f);
                hash.near(&[y], &mut out);
                assert!(
                    out.contains(&(id as u32)),
                    "moved triangle {id} not found through {y}"
                );
            }
        }
    }

    /// The invariant: every live triangle is held by every cell of its reach.
    fn assert_filed(hash: &TriangleHash, tris: &[Option<[DVec3; 3]>], step: usize) {
        for (u, t) in tris.iter().enumerate() {
            let Some(t) = t else { continue };
            let r = hash.reach(t);
            for k in r.lo[2]..=r.hi[2] {
                for j in r.lo[1]..=r.hi[1] {
                    for i in r.lo[0]..=r.hi[0] {
                        let c = [i, j, k];
                        let held = hash
                            .cells
                            .get(&TriangleHash::key(c))
                            .is_some_and(|ids| ids.contains(&(u as u32)));
                        assert!(
                            held || !r.meets(c),
                            "after {step} moves, triangle {u} is missing from cell {c:?}"
                        );
                    }
                }
            }
        }
    }

    /// Boxes with corners on the lattice of halves (where most vertices sit) meet no more cells
    /// once widened by TOUCH than they overlap: no cell face lies on them. With the faces on
    /// the integers (no offset) every such box would gain a layer of cells.
    #[test]
    fn lattice_boxes_meet_only_the_cells_they_overlap() {
        for cell in [2.0, 3.0, 4.0] {
            let hash = TriangleHash::new(cell);
            for a in -40..40 {
                for len in 0..8 {
                    let (lo, hi) = (a as f64 / 2.0, (a + len) as f64 / 2.0);
                    let (l, h) = hash.cell_range(&[DVec3::splat(lo), DVec3::splat(hi)]);
                    let exact = |x: f64| ((x - CELL_OFFSET) / cell).floor() as i64;
                    assert_eq!(
                        (l[0], h[0]),
                        (exact(lo), exact(hi)),
                        "cell {cell}: [{lo}, {hi}]"
                    );
                }
            }
        }
    }
}
