//! The sweep check by the swept volume's own pieces (docs/design.md, "The sweep check by
//! pieces"): exact and cheap once the band check has passed.
//!
//! A collapse replaces the old triangles O around its edge by the new ones N; the mesh's winding
//! number changes exactly where that of the closed surface O - N is not zero. Every live triangle
//! misses the swept volume A (it lies in the tolerance volume T, or is a face of the joined
//! voxels on an outside voxel), and so does every new triangle once the band check has passed.
//! So O ∪ N misses A, and the winding number of O - N is constant on each connected subset of
//! A: the collapse leaves every point of A enclosed if, for every connected piece S of A in a
//! list covering A, it is zero at one point of S. It is zero at every point outside the box of
//! O ∪ N; so a piece with a known point outside that box needs nothing computed, and the others
//! one winding number at their first point.
//!
//! The pieces are each part's connected components (triangles sharing a vertex position) at
//! each row of its motion: a component's motion from one row to the next is connected and holds
//! it, so they cover A with the motion between rows too.

use std::collections::HashMap;
use std::hash::BuildHasherDefault;

use glam::DVec3;

use super::band::{pack_cell, KeyHasher};
use super::intersect::bounds;
use crate::input::posed::SweepInput;
use crate::union_find::UnionFind;
use crate::verify::geom::winding_share;

/// Pieces at most (two points each, 48 bytes): beyond this the region tests decide as before.
pub const MAX_PIECES: usize = 1 << 20;

/// Edge of the cells pieces are filed under (by their first point), grid units.
const CELL: f64 = 8.0;

/// How far a winding number computed in f64 may lie from an integer before the check gives up
/// (and rejects, which is sound). Points of A are at least the clearance (0.07 voxels) from
/// O and N, where the solid angles are accurate to about 1e-12.
const WINDING_SLACK: f64 = 0.1;

/// Connected pieces of the swept volume, each as two of its points (grid units): the ends of its
/// component's extent along the part's longest local axis.
pub struct Pieces {
    points: Vec<[DVec3; 2]>,
    cells: HashMap<u64, Vec<u32>, BuildHasherDefault<KeyHasher>>,
}

impl Pieces {
    /// The pieces of `input`'s swept volume: every part's components at every row. None when
    /// there would be more than [`MAX_PIECES`].
    pub fn of(input: &SweepInput) -> Option<Pieces> {
        let mut count = 0usize;
        let mut per_part = Vec::with_capacity(input.parts.len());
        for (k, part) in input.parts.iter().enumerate() {
            let start = part.tri_start as usize;
            let tris = &input.triangles[start..start + part.tri_count as usize];
            let ends = component_ends(tris);
            let rows = input.poses.rows(k);
            count = count.saturating_add(ends.len().saturating_mul(rows.len()));
            if count > MAX_PIECES {
                return None;
            }
            per_part.push((ends, rows));
        }
        let mut points = Vec::with_capacity(count);
        for (ends, rows) in per_part {
            for pose in rows {
                points.extend(ends.iter().map(|e| e.map(|p| pose.transform_point3(p))));
            }
        }
        Some(Pieces::from_points(points))
    }

    /// Pieces given by two points each (grid units).
    pub(crate) fn from_points(points: Vec<[DVec3; 2]>) -> Pieces {
        let mut cells: HashMap<u64, Vec<u32>, BuildHasherDefault<KeyHasher>> = HashMap::default();
        for (i, p) in points.iter().enumerate() {
            cells.entry(cell_key(p[0])).or_default().push(i as u32);
        }
        Pieces { points, cells }
    }

    /// Each piece's two points (grid units).
    pub fn points(&self) -> &[[DVec3; 2]] {
        &self.points
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// How many pieces have both points in the box [lo, hi]: those whose winding number
    /// [`Self::swallowed`] or [`Self::swallowed_by_map`] may compute for a step of that box.
    pub fn enclosed_by(&self, (lo, hi): (DVec3, DVec3)) -> usize {
        let inside = |p: DVec3| p.cmpge(lo).all() && p.cmple(hi).all();
        self.points
            .iter()
            .filter(|[p, q]| inside(*p) && inside(*q))
            .count()
    }

    /// Whether replacing `old` by `new` (a closed surface O - N: they share their boundary; both
    /// missing the swept volume) may change the winding number at a point of a piece: true when
    /// O - N winds around a piece's first point, or when f64 cannot tell.
    pub fn swallowed(&self, old: &[[DVec3; 3]], new: &[[DVec3; 3]]) -> bool {
        let ((olo, ohi), (nlo, nhi)) = (bounds(old.as_flattened()), bounds(new.as_flattened()));
        self.any_within(olo.min(nlo), ohi.max(nhi), |p| winds(old, new, p))
    }

    /// Whether `f` says yes at the first point of some piece with both points in the box
    /// [lo, hi] (asked in the pieces' cell order, each at most once).
    fn any_within(&self, lo: DVec3, hi: DVec3, mut f: impl FnMut(DVec3) -> bool) -> bool {
        let inside = |p: DVec3| p.cmpge(lo).all() && p.cmple(hi).all();
        let mut swallows = |&[p, q]: &[DVec3; 2]| inside(p) && inside(q) && f(p);
        let (clo, chi) = (cell_of(lo), cell_of(hi));
        let cells = (0..3).fold(1.0, |n, a| n * (chi[a] - clo[a] + 1) as f64);
        if cells > self.points.len() as f64 {
            // A box wider than the pieces are many (late collapses, few pieces): each once.
            return self.points.iter().any(swallows);
        }
        for x in clo[0]..=chi[0] {
            for y in clo[1]..=chi[1] {
                for z in clo[2]..=chi[2] {
                    let Some(ids) = self.cells.get(&pack_cell([x, y, z])) else {
                        continue;
                    };
                    if ids.iter().any(|&i| swallows(&self.points[i as usize])) {
                        return true;
                    }
                }
            }
        }
        false
    }

    /// [`Self::swallowed`] for a step that maps vertices onto images (a level of clusters):
    /// O = the triangles of `moved` where they were, N = their images (those still
    /// triangles), computed by prisms so that a point costs only the triangles near it.
    ///
    /// The chain O - N is the sum over O's triangles t of the closed prism P_t = t - φ(t) -
    /// Σ_{edges u→v of t} Q(u→v), Q(u→v) the side swept by the edge, (u, v, φv, φu), split by
    /// the diagonal from its end of lower vertex id, so that Q(v→u) = -Q(u→v) exactly: the
    /// sides of the two triangles at an edge cancel, and a side whose ends are both fixed is
    /// degenerate. So the winding number of O - N at p is the sum of the prisms', and that of a
    /// closed surface is zero outside its box: only the prisms whose box holds p are summed.
    /// The pieces asked are [`Self::swallowed`]'s, so the answers are its answers (each an
    /// integer computed in f64 with `WINDING_SLACK`).
    pub fn swallowed_by_map(&self, moved: &[Mapped]) -> bool {
        if moved.is_empty() {
            return false;
        }
        let (lo, hi) = Mapped::bounds_of(moved);
        // The pieces' first points to ask about.
        let mut asked: Vec<DVec3> = Vec::new();
        self.any_within(lo, hi, |p| {
            asked.push(p);
            false
        });
        if asked.is_empty() {
            return false;
        }
        // The prisms whose box holds each point, summed in `moved`'s order.
        let mut sums = vec![0.0; asked.len()];
        for m in moved {
            let (l, h) = m.bounds();
            for (p, sum) in asked.iter().zip(&mut sums) {
                if p.cmpge(l).all() && p.cmple(h).all() {
                    *sum += m.prism_winding(*p);
                }
            }
        }
        sums.iter().any(|&w| off_zero(w))
    }
}

/// A triangle of a step that maps vertices onto images (a level of clusters): its corners'
/// vertex ids, and their places before and after (a corner that stays has one place).
#[derive(Clone, Copy, Debug)]
pub struct Mapped {
    pub ids: [u32; 3],
    pub from: [DVec3; 3],
    pub to: [DVec3; 3],
}

impl Mapped {
    /// The box of the triangle's places before and after: its prism's.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        let (a, b) = bounds(&self.from);
        let (c, d) = bounds(&self.to);
        (a.min(c), b.max(d))
    }

    /// The box of a step's triangles' places before and after (empty for none).
    pub fn bounds_of(moved: &[Mapped]) -> (DVec3, DVec3) {
        moved.iter().map(Mapped::bounds).fold(
            (DVec3::INFINITY, DVec3::NEG_INFINITY),
            |(lo, hi), (l, h)| (lo.min(l), hi.max(h)),
        )
    }

    /// The winding number at `p` of the closed prism of [`Pieces::swallowed_by_map`]: the
    /// triangle, its image reversed and its edges' sides reversed (degenerate triangles, zero
    /// chains, left out).
    fn prism_winding(&self, p: DVec3) -> f64 {
        let share = |t: [DVec3; 3]| {
            if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
                0.0
            } else {
                winding_share(p, t[0], t[1], t[2])
            }
        };
        let (f, t) = (self.from, self.to);
        let mut w = share(f) - share(t);
        for u in 0..3 {
            let v = (u + 1) % 3;
            // Q(u→v) = [u, v, φv] + [u, φv, φu] from u when its id is the lower, else
            // -Q(v→u) = -([v, u, φu] + [v, φu, φv]): the same two triangles either way round.
            w -= if self.ids[u] < self.ids[v] {
                share([f[u], f[v], t[v]]) + share([f[u], t[v], t[u]])
            } else {
                -(share([f[v], f[u], t[u]]) + share([f[v], t[u], t[v]]))
            };
        }
        w
    }
}

fn cell_of(p: DVec3) -> [i64; 3] {
    (p / CELL).floor().to_array().map(|x| x as i64)
}

fn cell_key(p: DVec3) -> u64 {
    pack_cell(cell_of(p))
}

/// The winding number of the closed surface `tris` around `p` (not on it): its triangles'
/// signed solid angles over 4π.
pub(super) fn winding(tris: &[[DVec3; 3]], p: DVec3) -> f64 {
    tris.iter()
        .map(|t| winding_share(p, t[0], t[1], t[2]))
        .sum()
}

/// Whether the closed surface `old` - `new` winds around `p` (or f64 cannot tell).
fn winds(old: &[[DVec3; 3]], new: &[[DVec3; 3]], p: DVec3) -> bool {
    off_zero(winding(old, p) - winding(new, p))
}

/// Whether a winding number computed in f64 may be anything but zero.
fn off_zero(w: f64) -> bool {
    (w - w.round()).abs() > WINDING_SLACK || w.round() != 0.0
}

/// Per connected component of `tris` (local f32 vertices; triangles sharing a vertex position
/// are connected), the component's vertices with the least and the greatest coordinate along
/// the axis where all of `tris` extend most.
fn component_ends(tris: &[[f32; 9]]) -> Vec<[DVec3; 2]> {
    let vertex = |t: &[f32; 9], k: usize| {
        DVec3::new(t[3 * k] as f64, t[3 * k + 1] as f64, t[3 * k + 2] as f64)
    };
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for t in tris {
        for k in 0..3 {
            lo = lo.min(vertex(t, k));
            hi = hi.max(vertex(t, k));
        }
    }
    let axis = (hi - lo).max_position();
    // Sets of vertex positions (exact bits): each triangle joins its three.
    let mut id: HashMap<[u32; 3], u32> = HashMap::new();
    let mut sets = UnionFind::new(0);
    let mut corner = Vec::with_capacity(tris.len() * 3);
    for t in tris {
        let ids: [u32; 3] = std::array::from_fn(|k| {
            let key = [
                t[3 * k].to_bits(),
                t[3 * k + 1].to_bits(),
                t[3 * k + 2].to_bits(),
            ];
            *id.entry(key).or_insert_with(|| sets.push())
        });
        for k in 1..3 {
            sets.join(ids[0], ids[k]);
        }
        corner.extend((0..3).map(|k| (ids[k], vertex(t, k))));
    }
    // Per root: (least, greatest) vertex along the axis, in first-seen order of the roots.
    let mut ends: Vec<[DVec3; 2]> = Vec::new();
    let mut slot: HashMap<u32, usize> = HashMap::new();
    for (v, p) in corner {
        let root = sets.find(v);
        let at = *slot.entry(root).or_insert_with(|| {
            ends.push([p, p]);
            ends.len() - 1
        });
        let e = &mut ends[at];
        if p[axis] < e[0][axis] {
            e[0] = p;
        }
        if p[axis] > e[1][axis] {
            e[1] = p;
        }
    }
    ends
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::verify::geom::dist_triangle;

    fn v(x: f64, y: f64, z: f64) -> DVec3 {
        DVec3::new(x, y, z)
    }

    /// A closed octahedron around `c` (radius r), outward faces.
    fn octahedron(c: DVec3, r: f64) -> Vec<[DVec3; 3]> {
        let (px, nx, py, ny, pz, nz) = (
            c + v(r, 0.0, 0.0),
            c - v(r, 0.0, 0.0),
            c + v(0.0, r, 0.0),
            c - v(0.0, r, 0.0),
            c + v(0.0, 0.0, r),
            c - v(0.0, 0.0, r),
        );
        vec![
            [px, py, pz],
            [py, nx, pz],
            [nx, ny, pz],
            [ny, px, pz],
            [py, px, nz],
            [nx, py, nz],
            [ny, nx, nz],
            [px, ny, nz],
        ]
    }

    #[test]
    fn winding_of_a_closed_surface_counts_what_it_encloses() {
        let o = octahedron(v(0.0, 0.0, 0.0), 2.0);
        assert!(winds(&o, &[], v(0.1, 0.2, -0.3)));
        assert!(!winds(&o, &[], v(3.0, 0.0, 0.0)));
        // Beyond the face x + y + z = 2.
        assert!(!winds(&o, &[], v(1.0, 1.0, 1.0)));
        // The same surface as old and new: nothing changes anywhere.
        assert!(!winds(&o, &o, v(0.1, 0.2, -0.3)));
    }

    #[test]
    fn a_piece_is_swallowed_only_when_both_its_points_lie_in_the_box_and_it_is_enclosed() {
        let o = octahedron(v(10.0, 10.0, 10.0), 2.0);
        let inside = Pieces::from_points(vec![[v(10.2, 10.0, 10.0), v(9.8, 10.1, 10.0)]]);
        assert!(inside.swallowed(&o, &[]));
        // Its second point outside the box: the piece reaches out of the region, so (missing
        // O and N) it cannot lie in it.
        let reaching = Pieces::from_points(vec![[v(10.2, 10.0, 10.0), v(13.0, 10.0, 10.0)]]);
        assert!(!reaching.swallowed(&o, &[]));
        let outside = Pieces::from_points(vec![[v(11.5, 11.5, 10.0), v(11.5, 11.5, 10.0)]]);
        assert!(!outside.swallowed(&o, &[]));
        // Many pieces over many cells, some in the box but outside the surface (|x - 10| + 1.9
        // + 1.9 > 2), none enclosed; then one enclosed.
        let many: Vec<[DVec3; 2]> = (0..50)
            .map(|i| {
                let p = v(i as f64 * 0.7, 11.9, 11.9);
                [p, p]
            })
            .collect();
        let mut with = many.clone();
        with.push([v(10.3, 10.0, 10.0), v(10.3, 10.0, 10.0)]);
        assert!(!Pieces::from_points(many).swallowed(&o, &[]));
        // Few pieces under a box of many cells: looked at one by one, same answers.
        let wide = octahedron(v(10.0, 10.0, 10.0), 30.0);
        assert!(!Pieces::from_points(vec![[v(35.0, 35.0, 10.0); 2]]).swallowed(&wide, &[]));
        assert!(Pieces::from_points(vec![[v(10.0, 10.0, 10.0); 2]]).swallowed(&wide, &[]));
        assert!(Pieces::from_points(with).swallowed(&o, &[]));
    }

    /// A height-field patch of 7 × 7 vertices whose interior vertices are mapped by a random
    /// clustering (groups of 2 × 2 onto one point off the surface, or left), boundary fixed: the
    /// moved triangles, O and N.
    fn mapped_patch(seed: u64) -> (Vec<Mapped>, Vec<[DVec3; 3]>, Vec<[DVec3; 3]>) {
        let mut state = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        let mut rnd = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let k = 7usize;
        let id = |i: usize, j: usize| (i * k + j) as u32;
        let mut from = vec![DVec3::ZERO; k * k];
        for i in 0..k {
            for j in 0..k {
                from[id(i, j) as usize] = v(i as f64, j as f64, 0.5 * rnd());
            }
        }
        // Each group of 2 × 2 interior vertices onto one point, or (a third of them) left.
        let mut to = from.clone();
        let mut target = std::collections::HashMap::new();
        for i in 1..k - 1 {
            for j in 1..k - 1 {
                let group = (i / 2, j / 2);
                let point = *target.entry(group).or_insert_with(|| {
                    (rnd() < 0.67).then(|| {
                        v(
                            2.0 * group.0 as f64 + rnd(),
                            2.0 * group.1 as f64 + rnd(),
                            2.0 * rnd() - 0.7,
                        )
                    })
                });
                if let Some(p) = point {
                    to[id(i, j) as usize] = p;
                }
            }
        }
        let (mut moved, mut old, mut new) = (Vec::new(), Vec::new(), Vec::new());
        for i in 0..k - 1 {
            for j in 0..k - 1 {
                let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
                for ids in [[a, b, c], [a, c, d]] {
                    let m = Mapped {
                        ids,
                        from: ids.map(|x| from[x as usize]),
                        to: ids.map(|x| to[x as usize]),
                    };
                    if m.from != m.to {
                        old.push(m.from);
                        if m.to[0] != m.to[1] && m.to[1] != m.to[2] && m.to[2] != m.to[0] {
                            new.push(m.to);
                        }
                        moved.push(m);
                    }
                }
            }
        }
        (moved, old, new)
    }

    #[test]
    fn prisms_wind_as_the_old_and_new_surfaces_do() {
        let mut compared = 0;
        let mut enclosed = 0;
        for seed in 0..40u64 {
            let (moved, old, new) = mapped_patch(seed);
            let mut state = seed + 1000;
            let mut rnd = move || {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1);
                (state >> 11) as f64 / (1u64 << 53) as f64
            };
            let near = |p: DVec3, tris: &[[DVec3; 3]]| {
                tris.iter()
                    .any(|t| dist_triangle(p, t[0], t[1], t[2]) < 1e-3)
            };
            for _ in 0..400 {
                let p = v(6.4 * rnd() - 0.2, 6.4 * rnd() - 0.2, 2.0 * rnd() - 0.9);
                if near(p, &old) || near(p, &new) {
                    continue;
                }
                // Every prism, and the prisms whose box holds p only: both O - N's winding.
                let want = winding(&old, p) - winding(&new, p);
                let all: f64 = moved.iter().map(|m| m.prism_winding(p)).sum();
                let boxed: f64 = moved
                    .iter()
                    .filter(|m| {
                        let (l, h) = m.bounds();
                        p.cmpge(l).all() && p.cmple(h).all()
                    })
                    .map(|m| m.prism_winding(p))
                    .sum();
                assert!(
                    (want - want.round()).abs() < 1e-6,
                    "seed {seed}: {want} at {p}"
                );
                assert!(
                    (all - want).abs() < 1e-6,
                    "seed {seed}: prisms {all}, O - N {want}"
                );
                assert!(
                    (boxed - want).abs() < 1e-6,
                    "seed {seed}: boxed {boxed}, O - N {want}"
                );
                let pieces = Pieces::from_points(vec![[p, p]]);
                assert_eq!(
                    pieces.swallowed_by_map(&moved),
                    pieces.swallowed(&old, &new)
                );
                compared += 1;
                enclosed += usize::from(want.round() != 0.0);
            }
        }
        // Both answers met often enough to mean something.
        assert!(
            compared > 10_000 && enclosed > 500,
            "{compared} points, {enclosed} enclosed"
        );
    }

    #[test]
    fn components_are_joined_by_shared_vertex_positions() {
        let t = |a: [f32; 3], b: [f32; 3], c: [f32; 3]| {
            [a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2]]
        };
        let tris = vec![
            t([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            t([5.0, 0.0, 0.0], [6.0, 0.0, 0.0], [5.0, 1.0, 0.0]),
            t([1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 1.0, 0.0]), // joins the first
        ];
        let ends = component_ends(&tris);
        assert_eq!(ends.len(), 2);
        assert_eq!(ends[0], [v(0.0, 0.0, 0.0), v(2.0, 0.0, 0.0)]);
        assert_eq!(ends[1][0].x, 5.0);
        assert_eq!(ends[1][1].x, 6.0);
    }
}
