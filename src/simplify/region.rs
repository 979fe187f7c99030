//! The local checks of one collapse, on a copy of the triangles around its edge: topology,
//! flips, whether the surface keeps its point set, the tolerance band and the swept region. They
//! read nothing else, so they run while earlier batches commit (the self-intersection test,
//! which reads the whole mesh, follows the commit: `State::crosses_nothing`).

use glam::DVec3;

use super::band::Proximity;
use super::between::Between;
use super::pieces::Pieces;
use super::quadric::{cheapest, Quadric};
use super::SimplifyOptions;
use crate::mesh::classify::Classifier;

/// What a worker thread keeps across checks.
pub(super) struct Scratch<'c> {
    /// Distance memo, sized for the voxels near the surface: about two per start triangle.
    pub(super) prox: Proximity<'c>,
    pub(super) crossing: Crossing,
    pub(super) between: Between,
    /// The swept volume's pieces, when known: the sweep check then asks whether a collapse
    /// winds around one of them (`pieces`), else the region tests decide.
    pub(super) pieces: Option<&'c Pieces>,
}

impl<'c> Scratch<'c> {
    pub(super) fn new(cls: &'c Classifier, pieces: Option<&'c Pieces>, triangles: usize) -> Self {
        Scratch {
            prox: Proximity::with_capacity(cls, 2 * triangles),
            crossing: Crossing {
                seen: IdSet::new(triangles),
                ..Crossing::default()
            },
            between: Between::default(),
            pieces,
        }
    }
}

/// The self-intersection test's buffers (`State::crosses_nothing`), kept between checks.
#[derive(Default)]
pub(super) struct Crossing {
    pub(super) seen: IdSet,
    /// The new triangles' corners.
    pub(super) points: Vec<DVec3>,
    /// Ids the hash files near them.
    pub(super) near: Vec<u32>,
    /// The live triangles they are tested against, and the new ones.
    pub(super) others: Vec<super::intersect::Facet>,
    pub(super) fan: Vec<super::intersect::Facet>,
    /// The new triangles' vertices, one vertex's fan after the change, and the vertices whose
    /// fans project one to one (`State::fans_one_to_one`).
    pub(super) verts: Vec<u32>,
    pub(super) corners: Vec<(u32, u32, DVec3, DVec3)>,
    pub(super) passed: Vec<u32>,
}

/// A set of triangle ids, one bit each (2 MB for 16 M triangles), empty between uses.
#[derive(Default)]
pub(super) struct IdSet(Vec<u64>);

impl IdSet {
    pub(super) fn new(ids: usize) -> Self {
        IdSet(vec![0; ids.div_ceil(64)])
    }

    /// Drops every id from `ids` that an earlier one repeats, keeping the order.
    pub(super) fn keep_first(&mut self, ids: &mut Vec<u32>) {
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
pub(super) struct Plan {
    pub(super) a: usize,
    pub(super) b: usize,
    pub(super) v: DVec3,
    /// The two triangles on the edge (they disappear).
    pub(super) shared: Vec<u32>,
    /// The surviving triangles around the edge that move, with their new positions (those that
    /// stay keep their hash cells and cannot meet anything new).
    pub(super) changed: Vec<(u32, [DVec3; 3])>,
    /// The same with their vertex ids after the collapse.
    pub(super) new: Vec<([u32; 3], [DVec3; 3])>,
    /// a's neighbours after the collapse, with the cost of collapsing the edge to each (read
    /// before the batch: no other collapse of the batch moves them or a).
    pub(super) fresh: Vec<(u32, f64)>,
    /// The triangles around the edge before the collapse, sorted.
    pub(super) around: Vec<u32>,
    /// The surviving triangles around the edge that stay where they are (ids after the
    /// collapse, places).
    pub(super) unchanged: Vec<([u32; 3], [DVec3; 3])>,
    /// The collapse keeps the surface's point set ([`Region::keeps_surface`]).
    pub(super) in_plane: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Reject {
    /// A block's pass would move the surface onto its box's faces (`blocked`): left to the seams.
    Border,
    Topology,
    Flip,
    Band,
    Sweep,
    Intersection,
}

/// Whether a triangle at `old` that a collapse moves to `new` (same corners in the same order)
/// degenerates (twice its area at most 10⁻⁹ voxel²) or turns over (its normal no longer on the
/// old one's side): a flip, refused.
pub(super) fn flipped(old: &[DVec3; 3], new: &[DVec3; 3]) -> bool {
    let n_old = (old[1] - old[0]).cross(old[2] - old[0]);
    let n_new = (new[1] - new[0]).cross(new[2] - new[0]);
    n_new.length_squared() <= 1e-18 || n_old.dot(n_new) <= 0.0
}

/// The triangles around edge (a, b) and their vertices, copied from the mesh when the edge joins
/// a batch. The regions of the batches in flight are disjoint (their vertex sets), and a commit
/// changes only its own region's triangles and vertices, so the copy stays exact until this
/// edge's own commit.
pub(super) struct Region {
    pub a: u32,
    pub b: u32,
    /// The triangles with a or b: (id, vertex ids), sorted by id.
    pub tris: Vec<(u32, [u32; 3])>,
    /// Their vertices: (id, position, quadric), sorted by id.
    pub verts: Vec<(u32, DVec3, Quadric)>,
}

impl Region {
    fn vert(&self, x: u32) -> &(u32, DVec3, Quadric) {
        let at = self.verts.binary_search_by_key(&x, |v| v.0);
        &self.verts[at.expect("a vertex of the region")]
    }

    fn pos(&self, x: u32) -> DVec3 {
        self.vert(x).1
    }

    fn places(&self, tri: [u32; 3]) -> [DVec3; 3] {
        tri.map(|x| self.pos(x))
    }

    /// v's triangles (v = a or b: the region holds their whole stars).
    fn star(&self, v: u32) -> impl Iterator<Item = &(u32, [u32; 3])> {
        self.tris.iter().filter(move |(_, tri)| tri.contains(&v))
    }

    /// v's neighbours, sorted (v = a or b).
    fn neighbours(&self, v: u32) -> Vec<u32> {
        // Sized once: a collected filter would grow it two or three times.
        let mut out = Vec::with_capacity(2 * self.tris.len());
        out.extend(self.star(v).flat_map(|(_, tri)| *tri).filter(|&x| x != v));
        out.sort_unstable();
        out.dedup();
        out
    }

    /// The cheapest target for the collapse ([`cheapest`]).
    pub fn target(&self) -> DVec3 {
        let ((_, pa, qa), (_, pb, qb)) = (self.vert(self.a), self.vert(self.b));
        cheapest(qa, *pa, qb, *pb).1
    }

    /// Whether v's triangles form one closed fan (a disc around v); v = a or b.
    fn is_manifold(&self, v: u32) -> bool {
        // Each triangle contributes its edge opposite v, oriented; one fan means these edges
        // chain into a single cycle through every link vertex once.
        let mut link: Vec<(u32, u32)> = Vec::with_capacity(16);
        for (_, tri) in self.star(v) {
            let k = tri.iter().position(|&x| x == v).expect("v in its star");
            let (p, q) = (tri[(k + 1) % 3], tri[(k + 2) % 3]);
            if link.iter().any(|e| e.0 == p) {
                return false;
            }
            link.push((p, q));
        }
        let Some(&(start, _)) = link.first() else {
            return false;
        };
        let (mut at, mut steps) = (start, 0);
        loop {
            let Some(&(_, n)) = link.iter().find(|e| e.0 == at) else {
                return false;
            };
            at = n;
            steps += 1;
            if at == start {
                return steps == link.len();
            }
            if steps > link.len() {
                return false;
            }
        }
    }

    /// The checks of collapsing the edge to `v` that read only the region: topology, flips, and
    /// unless the surface keeps its point set, the tolerance band and the swept region (`prox`:
    /// the worker's distance memo).
    pub fn check(
        &self,
        scratch: &mut Scratch,
        opts: &SimplifyOptions,
        v: DVec3,
    ) -> Result<Plan, Reject> {
        self.check_moving(scratch, opts, v, |_| Ok(()))
    }

    /// [`Self::check`] with a caller's rule on where the moved triangles (new places, ids as
    /// after the collapse) may go, judged before the band and sweep checks, which cost the most:
    /// a collapse that moves the surface is refused with the rule's reason first.
    pub fn check_moving(
        &self,
        scratch: &mut Scratch,
        opts: &SimplifyOptions,
        v: DVec3,
        may_move: impl Fn(&[([u32; 3], [DVec3; 3])]) -> Result<(), Reject>,
    ) -> Result<Plan, Reject> {
        let (a, b) = (self.a, self.b);
        // Topology: a two-face edge between manifold vertices, and the link condition.
        let mut on_edge = self.star(a).filter(|(_, tri)| tri.contains(&b));
        let on_edge = match (on_edge.next(), on_edge.next(), on_edge.next()) {
            (Some(s), Some(t), None) => [s, t],
            _ => return Err(Reject::Topology),
        };
        if !self.is_manifold(a) || !self.is_manifold(b) {
            return Err(Reject::Topology);
        }
        let shared = vec![on_edge[0].0, on_edge[1].0];
        let third = |tri: &[u32; 3]| *tri.iter().find(|&&x| x != a && x != b).expect("a third");
        let (c, d) = (third(&on_edge[0].1), third(&on_edge[1].1));
        let (na, nb) = (self.neighbours(a), self.neighbours(b));
        let common = na.iter().filter(|x| nb.binary_search(x).is_ok()).count();
        // The edge part of the link condition: if triangles (a, c, d) and (b, c, d) both exist
        // for the opposite vertices c, d (a tetrahedron-like component), the collapse would
        // leave two coincident triangles enclosing nothing.
        let spans_cd = |v: u32| {
            self.star(v)
                .any(|(_, tri)| tri.contains(&c) && tri.contains(&d))
        };
        if common != 2 || c == d || (spans_cd(a) && spans_cd(b)) {
            return Err(Reject::Topology);
        }

        // The triangles around the edge before, and those that survive with a, b moved to v.
        let old: Vec<[DVec3; 3]> = self.tris.iter().map(|(_, tri)| self.places(*tri)).collect();
        let mut survivors: Vec<Survivor> = Vec::with_capacity(self.tris.len());
        for ((t, tri), p) in self.tris.iter().zip(&old) {
            if shared.contains(t) {
                continue;
            }
            let q = tri.map(|x| if x == a || x == b { v } else { self.pos(x) });
            survivors.push(Survivor {
                id: *t,
                ids: tri.map(|x| if x == b { a } else { x }),
                new: q,
                old: *p,
            });
        }
        if survivors.iter().any(|c| flipped(&c.old, &c.new)) {
            return Err(Reject::Flip);
        }
        // Triangles of the kept endpoint's star that do not hold the other one stay where they
        // are when v is that endpoint: they are already within the band and cross nothing, so
        // only the moved ones are checked (against the unchanged ones too) and re-filed.
        let mut unchanged = Vec::with_capacity(survivors.len());
        let mut changed = Vec::with_capacity(survivors.len());
        let mut new = Vec::with_capacity(survivors.len());
        for c in &survivors {
            if c.new == c.old {
                unchanged.push((c.ids, c.new));
            } else {
                changed.push((c.id, c.new));
                new.push((c.ids, c.new));
            }
        }
        let in_plane = self.keeps_surface(v);
        if !in_plane {
            may_move(&new)?;
            // What the collapse takes away or moves, at its old places.
            let mut swept: Vec<[DVec3; 3]> = Vec::with_capacity(old.len());
            swept.extend(
                self.tris
                    .iter()
                    .zip(&old)
                    .filter(|((t, _), _)| shared.contains(t) || changed.iter().any(|c| c.0 == *t))
                    .map(|(_, p)| *p),
            );
            band_and_sweep(scratch, opts, v, &old, &swept, &new)?;
        }
        let (qa, qb) = (&self.vert(a).2, &self.vert(b).2);
        let qv = qa.add(qb);
        let mut around_v: Vec<u32> = Vec::with_capacity(na.len() + nb.len());
        around_v.extend(na.iter().chain(&nb).filter(|&&x| x != a && x != b));
        around_v.sort_unstable();
        around_v.dedup();
        let fresh = around_v
            .into_iter()
            .map(|x| {
                let (_, p, q) = self.vert(x);
                (x, cheapest(&qv, v, q, *p).0)
            })
            .collect();
        Ok(Plan {
            a: a as usize,
            b: b as usize,
            v,
            shared,
            around: self.tris.iter().map(|(t, _)| *t).collect(),
            changed,
            new,
            unchanged,
            fresh,
            in_plane,
        })
    }

    /// Whether collapsing (a, b) to `v` leaves the surface the same point set, so that the
    /// band, sweep and intersection checks hold without being run (the flip check has passed:
    /// no new triangle is degenerate or turned against its old normal).
    ///
    /// So it is when v is one endpoint, k, and the other, m, is flat or on a straight crease
    /// through k:
    /// - flat: m's triangles lie in one plane, facing the same way, winding once around m
    ///   (angles summing to 2π). They tile the polygon L of their outer edges, star-shaped from
    ///   m; after the collapse the fan from k over the same outer edges has boundary L as well,
    ///   and with every new triangle facing the plane's way, the number of new triangles over a
    ///   point is L's winding number there: they tile L exactly;
    /// - crease: m's triangles lie in two planes, both through k, each plane's triangles
    ///   contiguous around m with angles summing to π, and the two crease edges are (m, k) and
    ///   (m, k') with m strictly between k and k'. Each plane's half is then a polygon whose
    ///   corner at m is straight (on the segment k k'), and the same argument tiles it with the
    ///   fan from k.
    ///
    /// Nothing moves: every point of W and of the swept volume stays on its side, and no new
    /// crossing can arise. (In an embedded mesh "k lies in every plane of m's triangles" already
    /// forces one of the two shapes; the walk checks them rather than rely on that.)
    ///
    /// Exact: only for integer coordinates below 2^15 in magnitude (voxel corners, and
    /// endpoints chosen by earlier collapses like this one). Then the normals' components
    /// (< 2^33) and the plane tests n·(x - o) (< 2^51) are exact in f64. The angle sums are
    /// rounded, but π and 2π are far from the other multiples of π they could be.
    fn keeps_surface(&self, v: DVec3) -> bool {
        let (a, b) = (self.a, self.b);
        let (m, k) = if v == self.pos(a) {
            (b, a)
        } else if v == self.pos(b) {
            (a, b)
        } else {
            return false;
        };
        let lattice = |p: &DVec3| {
            p.to_array()
                .iter()
                .all(|x| x.fract() == 0.0 && x.abs() < 32768.0)
        };
        let (o, pk) = (self.pos(m), self.pos(k));
        // m's triangles in order around m, starting with the one whose link edge leaves k:
        // (link edge p -> q, positions of the triangle, its normal).
        let mut fan: Vec<(u32, u32, [DVec3; 3], DVec3)> = Vec::new();
        for (_, tri) in self.star(m) {
            let p = self.places(*tri);
            if !p.iter().all(lattice) {
                return false;
            }
            let i = tri.iter().position(|&x| x == m).expect("m in its star");
            let n = (p[1] - p[0]).cross(p[2] - p[0]);
            // k must lie in every plane of m's triangles.
            if n == DVec3::ZERO || n.dot(pk - o) != 0.0 {
                return false;
            }
            fan.push((tri[(i + 1) % 3], tri[(i + 2) % 3], p, n));
        }
        let mut at = k;
        for i in 0..fan.len() {
            let Some(j) = (i..fan.len()).find(|&j| fan[j].0 == at) else {
                return false;
            };
            fan.swap(i, j);
            at = fan[i].1;
        }
        if at != k {
            return false;
        }
        // Walk around: a plane change between consecutive triangles happens at their common
        // edge (m, q); sum the angles at m per plane.
        let same_plane = |n: DVec3, p: &[DVec3; 3]| p.iter().all(|&x| n.dot(x - o) == 0.0);
        let facing = |n: DVec3, u: DVec3| {
            let j = u.abs().max_position();
            n[j] * u[j] > 0.0
        };
        let mut changes = Vec::new();
        let mut angles = [0.0f64; 2];
        let mut plane = 0;
        for i in 0..fan.len() {
            let (p, q, _, n) = fan[i];
            let (e1, e2) = (self.pos(p) - o, self.pos(q) - o);
            angles[plane] += e1.cross(e2).length().atan2(e1.dot(e2));
            let next = &fan[(i + 1) % fan.len()];
            if !(same_plane(n, &next.2) && facing(n, next.3)) {
                changes.push(q);
                plane = 1 - plane;
            }
        }
        let pi = std::f64::consts::PI;
        match changes.as_slice() {
            [] => (angles[0] - 2.0 * pi).abs() < 1e-6,
            [k2, k1] if *k1 == k => {
                let d = self.pos(*k2) - o;
                let e = pk - o;
                e.cross(d) == DVec3::ZERO
                    && e.dot(d) < 0.0
                    && (angles[0] - pi).abs() < 1e-6
                    && (angles[1] - pi).abs() < 1e-6
            }
            _ => false,
        }
    }
}

/// A triangle around the edge that survives the collapse.
struct Survivor {
    id: u32,
    /// Its vertex ids after the collapse (b becomes a).
    ids: [u32; 3],
    /// Its places after and before.
    new: [DVec3; 3],
    old: [DVec3; 3],
}

/// The band and sweep checks of a collapse to `v`: the triangles around the edge at their `old`
/// places (those it removes or moves: `swept`), `new` the survivors that move (ids after the
/// collapse, new places).
fn band_and_sweep(
    scratch: &mut Scratch,
    opts: &SimplifyOptions,
    v: DVec3,
    old: &[[DVec3; 3]],
    swept: &[[DVec3; 3]],
    new: &[([u32; 3], [DVec3; 3])],
) -> Result<(), Reject> {
    let prox = &mut scratch.prox;
    let (tol, r_min) = (opts.tolerance, opts.min_radius);
    if !prox.new_surface_within(Some(v), new, tol, r_min) {
        return Err(Reject::Band);
    }
    let moved: Vec<[DVec3; 3]> = new.iter().map(|(_, q)| *q).collect();
    // With the swept volume's pieces known, exactly: the band check has put the new triangles
    // in T, so the old and new ones both miss the swept volume, and the winding number of
    // old - new is constant on each piece (docs/design.md, "The sweep check by pieces").
    if let Some(pieces) = scratch.pieces {
        return if pieces.swallowed(swept, &moved) {
            Err(Reject::Sweep)
        } else {
            Ok(())
        };
    }
    // Else sufficiently: every point whose winding number the collapse changes must be within
    // `sweep` < δ of an outside voxel's centre, hence outside the swept volume. First as the
    // region between the old and the new surface (`between`), where a projection lays each
    // over the plane once; else as the tetrahedra (old triangle, v). A tetrahedron with v
    // at a corner of its triangle is that flat triangle, which passes when tol.outside <= sweep:
    // every live triangle lies in T (a checked one) or is an unchanged face of the joined
    // voxels, on a voxel outside W (within √3/2 of its centre).
    let sweep = opts.sweep;
    match prox.between_shallow(&mut scratch.between, swept, &moved, sweep, r_min) {
        Some(true) => return Ok(()),
        Some(false) => return Err(Reject::Sweep),
        None => {}
    }
    for p in old {
        if tol.outside <= sweep && p.contains(&v) {
            continue;
        }
        if !prox.tetrahedron_shallow([p[0], p[1], p[2], v], sweep, r_min) {
            return Err(Reject::Sweep);
        }
    }
    Ok(())
}
