//! The tolerance volume around the voxel boundary: exact local distances from points to the
//! nearest voxel centres of each class and to ∂W (W the union of inside voxels), and the sound
//! region tests the simplifier's checks are built on (docs/design.md).
//!
//! Units: grid units throughout (one voxel edge = 1).

use glam::DVec3;

use super::cover;
use super::extruded::{Attempt, Extruded};
use crate::mesh::classify::Classifier;

/// Distances to ∂W are exact below this (the memo covers the 5×5×5 voxels around a point's
/// voxel; a voxel three steps away is at least 2 from any point of the middle one).
pub const REACH: f64 = 2.0;
/// Distances to voxel centres are exact below this (a centre three steps away is at least 2.5
/// from any point of the middle voxel).
pub const CENTRE_REACH: f64 = 2.5;
/// Half a voxel diagonal, √3/2: every point of a voxel is this near its centre.
pub const HALF_DIAGONAL: f64 = 0.866_025_403_784_438_6;

/// The tolerance volume T (grid units): the points within `outside` of some outside voxel's
/// centre and within `inside` of some inside voxel's centre. Invariant: √3/2 ≤ both <
/// `CENTRE_REACH` (2.5), so ∂W lies in T (a point of a face is within √3/2 of both voxels' centres).
/// An outside centre is farther than δ from the swept volume A and an inside one (of the
/// reach) within δ + μ + 2ρ of it, so a point of T is at least δ - `outside` from A and at most
/// `inside` + δ + μ + 2ρ from it (docs/design.md, "The simplifier").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tolerance {
    pub outside: f64,
    pub inside: f64,
}

impl Tolerance {
    fn admits(self, d_out: f64, d_in: f64) -> bool {
        d_out <= self.outside && d_in <= self.inside
    }
}

/// The centre of voxel `v`.
pub(super) fn centre(v: [isize; 3]) -> DVec3 {
    DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64) + 0.5
}

/// Squared distance from `p` to the voxel cube `v` (closed unit cube at integer corner `v`).
#[cfg(test)]
fn dist2_to_cube(p: DVec3, v: [isize; 3]) -> f64 {
    let lo = DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64);
    let g = (lo - p).max(p - (lo + 1.0)).max(DVec3::ZERO);
    g.length_squared()
}

/// The exact distance from `p` to ∂W when it is at most `limit`, else None (farther). Brute
/// force over the (2⌈limit⌉+1)³ voxels around `p`: the reference the memoized queries are
/// tested against.
#[cfg(test)]
pub fn dist_to_boundary(cls: &Classifier, p: DVec3, limit: f64) -> Option<f64> {
    let home = p.floor();
    let here = cls.inside(home.x as isize, home.y as isize, home.z as isize);
    let lo = (p - DVec3::splat(limit)).floor();
    let hi = (p + DVec3::splat(limit)).floor();
    let mut best = f64::INFINITY;
    for k in lo.z as isize..=hi.z as isize {
        for j in lo.y as isize..=hi.y as isize {
            for i in lo.x as isize..=hi.x as isize {
                if cls.inside(i, j, k) != here {
                    best = best.min(dist2_to_cube(p, [i, j, k]).sqrt());
                }
            }
        }
    }
    (best <= limit).then_some(best)
}

/// The exact distance from `p` to the nearest centre of a voxel of class `inside` when it is at
/// most `limit`, else None. Brute force: the reference for the memoized queries.
#[cfg(test)]
pub fn dist_to_centre(cls: &Classifier, p: DVec3, inside: bool, limit: f64) -> Option<f64> {
    let lo = (p - DVec3::splat(limit + 0.5)).floor();
    let hi = (p + DVec3::splat(limit + 0.5)).floor();
    let mut best = f64::INFINITY;
    for k in lo.z as isize..=hi.z as isize {
        for j in lo.y as isize..=hi.y as isize {
            for i in lo.x as isize..=hi.x as isize {
                if cls.inside(i, j, k) == inside {
                    best = best.min((p - centre([i, j, k])).length());
                }
            }
        }
    }
    (best <= limit).then_some(best)
}

pub(crate) use crate::voxels::{pack_cell, KeyHasher};

/// Offset index n of the 5×5×5 block (n = 25(dk+2) + 5(dj+2) + di+2) split per axis.
const BLOCK: [[u8; 3]; 125] = {
    let mut t = [[0u8; 3]; 125];
    let mut n = 0;
    while n < 125 {
        t[n] = [(n % 5) as u8, (n / 5 % 5) as u8, (n / 25) as u8];
        n += 1;
    }
    t
};

/// Per block offset n, the offsets whose cube is at least as near as n's to every point of the
/// middle voxel (per axis the gap to offset 0 is 0, to ±1 at most that to ±2 on the same side),
/// n itself excluded. An other-class cube with an other-class cube among its dominators never
/// decides a distance, so the memo drops it.
const DOMINATORS: [u128; 125] = {
    let mut t = [0u128; 125];
    let mut n = 0;
    while n < 125 {
        let mut m = 0;
        while m < 125 {
            let (bn, bm) = (BLOCK[n], BLOCK[m]);
            let mut all = m != n;
            let mut a = 0;
            while a < 3 {
                let (x, y) = (bm[a] as i32 - 2, bn[a] as i32 - 2); // candidate, dominated
                all &= x == y || x == 0 || (x == -1 && y == -2) || (x == 1 && y == 2);
                a += 1;
            }
            if all {
                t[n] |= 1 << m;
            }
            m += 1;
        }
        n += 1;
    }
    t
};

/// Memoized distances to ∂W near the voxel boundary: per visited voxel, the set of voxels of the
/// other class in its 5×5×5 block (bit n as in [`BLOCK`]).
pub struct Proximity<'c> {
    cls: &'c Classifier,
    /// Direct-mapped cache of memo entries, a power of two long: slot [key | OCCUPIED, low
    /// 64 bits, high 64 bits]. A new entry overwrites its slot's, so memory is fixed and the
    /// answers never depend on what the cache holds. Allocated zeroed: pages the cache never
    /// touches cost no memory.
    slots: Vec<[u64; 3]>,
    /// The last entry looked up (key, entry); key u64::MAX: none.
    last: (u64, u128),
    /// Whole triangles' verdicts, direct-mapped by their exact corners ([`Self::triangle_within`]).
    verdicts: Vec<Option<Verdict3>>,
    /// Buffers of [`Self::refine`], kept between calls.
    triangles: Refinement<3>,
    /// A step's triangles with their doubled areas squared, for [`Self::new_surface_within`]
    /// (kept between calls: the order is asked once per checked step).
    largest_first: Vec<(f64, [DVec3; 3])>,
    tetrahedra: Refinement<4>,
    /// Buffers of the certificate over walls extruded along an axis, kept between calls.
    extruded: Extruded<'c>,
}

/// The work lists of one [`Proximity::refine`]: pieces to judge, each with the index of its
/// parent's [`Near`] in `parents`, and the split of the piece last refined.
#[derive(Default)]
struct Refinement<const N: usize> {
    stack: Vec<([DVec3; N], u32, bool)>,
    parents: Vec<Near>,
    children: Vec<[DVec3; N]>,
}

/// Memo entry bit holding the voxel's own class.
const INSIDE_BIT: u32 = 127;
/// Memo entry bits of the other-class voxels in the block.
const OPPOSITE_BITS: u128 = (1 << 125) - 1;

/// Marks a filled cache slot (keys use 63 bits).
const OCCUPIED: u64 = 1 << 63;

/// Cache slots per [`Proximity`]: 24 bytes each, so at most 96 MiB per worker.
const MAX_SLOTS: usize = 1 << 22;

/// Longest edge (grid units) from which [`Proximity::probes_miss`] is worth asking before the
/// refinement: at n = 512 it saved about 3% of the simplifier's time (2 and 4 voxels measured
/// alike).
const PROBE_FROM: f64 = 4.0;

/// Slots of [`Proximity::verdicts`] (about 100 bytes each).
const VERDICT_SLOTS: usize = 4096;

/// A triangle test asked and answered: [`Proximity::triangle_within`]`(t, tol, r_min)` = `within`.
#[derive(Clone, Copy)]
struct Verdict3 {
    t: [DVec3; 3],
    tol: Tolerance,
    r_min: f64,
    within: bool,
}

/// Pieces of R below this many times the smallest R are judged by [`Proximity::covered`]
/// before they split: near T's edge the refinement would otherwise split on to the smallest R
/// and reject a triangle that lies in T (docs/design.md, "The band test's last resort").
const LAST_RESORT: f64 = 2.0;

/// Nodes one region test may visit before it gives up (and rejects, which is always sound).
const NODE_BUDGET: usize = 4096;

/// Voxel `v`'s coordinates (low 21 bits each) interleaved, x lowest.
fn morton(v: [isize; 3]) -> u64 {
    let spread = |x: isize| {
        let mut x = (x as u64) & 0x1f_ffff;
        x = (x | x << 32) & 0x1f_0000_0000_ffff;
        x = (x | x << 16) & 0x1f_0000_ff00_00ff;
        x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
        x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
        (x | x << 2) & 0x1249_2492_4924_9249
    };
    spread(v[0]) | spread(v[1]) << 1 | spread(v[2]) << 2
}

/// The memo entry of voxel `v`, computed from the classifier.
fn compute(cls: &Classifier, v: [isize; 3]) -> u128 {
    let inside = cls.block5(v.map(|x| x - 2));
    let here = inside >> 62 & 1 == 1; // the middle voxel: n = 25·2 + 5·2 + 2
    let m = if here { !inside } else { inside } & OPPOSITE_BITS;
    let (mut kept, mut bits) = (0u128, m);
    while bits != 0 {
        let n = bits.trailing_zeros() as usize;
        bits &= bits - 1;
        if m & DOMINATORS[n] == 0 {
            kept |= 1 << n;
        }
    }
    kept | (here as u128) << INSIDE_BIT
}

impl<'c> Proximity<'c> {
    #[cfg(test)]
    pub fn new(cls: &'c Classifier) -> Self {
        Self::with_capacity(cls, MAX_SLOTS)
    }

    /// A memo sized for about `voxels` distinct voxels (a power of two in 2^10..=[`MAX_SLOTS`]).
    pub fn with_capacity(cls: &'c Classifier, voxels: usize) -> Self {
        let n = voxels.clamp(1 << 10, MAX_SLOTS).next_power_of_two();
        Proximity {
            cls,
            slots: vec![[0; 3]; n],
            last: (u64::MAX, 0),
            verdicts: vec![None; VERDICT_SLOTS],
            triangles: Refinement::default(),
            tetrahedra: Refinement::default(),
            largest_first: Vec::new(),
            extruded: Extruded::new(cls),
        }
    }

    /// The memo entry of voxel `v`: bits 0..125 as in [`BLOCK`] for the other-class cubes not
    /// dominated by another ([`DOMINATORS`]), bit [`INSIDE_BIT`] its class.
    fn entry(&mut self, v: [isize; 3]) -> u128 {
        let key = pack_cell(v.map(|x| x as i64));
        if self.last.0 == key {
            return self.last.1; // refinement queries the same voxel many times in a row
        }
        // Morton order: voxels near each other share cache lines of the table.
        let at = (morton(v) as usize) & (self.slots.len() - 1);
        let slot = &mut self.slots[at];
        let entry = if slot[0] == key | OCCUPIED {
            slot[1] as u128 | (slot[2] as u128) << 64
        } else {
            let e = compute(self.cls, v);
            *slot = [key | OCCUPIED, e as u64, (e >> 64) as u64];
            e
        };
        self.last = (key, entry);
        entry
    }

    /// dist(p, ∂W) when it is below [`REACH`], else REACH; and whether p's voxel is inside W.
    #[cfg(test)]
    pub fn distance(&mut self, p: DVec3) -> (f64, bool) {
        let near = self.nearest(p);
        (near.dist, near.inside)
    }

    /// Whether point `p` lies in the tolerance volume `tol`.
    pub fn point_within(&mut self, p: DVec3, tol: Tolerance) -> bool {
        let near = self.nearest_centres(p);
        let (d_out, d_in) = near.centre_distances();
        tol.admits(d_out, d_in)
    }

    /// Whether a step's new triangles (`new`, each with its vertex ids) and its new vertex
    /// `point`, if any, lie in `tol`: [`Self::triangle_within`] for every triangle, asked in the
    /// order likeliest to find a no first. A triangle already known to leave T (a step retried
    /// after a neighbour's often makes the one that failed it before), then the new vertex,
    /// then a few points of each long triangle ([`Self::probes_miss`]), then the whole
    /// triangles, largest first. The verdict is the same in any order; the order only finds a
    /// no sooner (n = 512: a step that failed on its second triangle or later cost 137 µs, on
    /// its first 28 µs; docs/perf-log.md).
    pub fn new_surface_within(
        &mut self,
        point: Option<DVec3>,
        new: &[([u32; 3], [DVec3; 3])],
        tol: Tolerance,
        r_min: f64,
    ) -> bool {
        if new.iter().any(|(_, q)| self.known_out(q, tol, r_min))
            || point.is_some_and(|p| !self.point_within(p, tol))
            || new.iter().any(|(_, q)| self.probes_miss(q, tol))
        {
            return false;
        }
        let mut largest_first = std::mem::take(&mut self.largest_first);
        largest_first.clear();
        largest_first.extend(
            new.iter()
                .map(|(_, q)| ((q[1] - q[0]).cross(q[2] - q[0]).length_squared(), *q)),
        );
        largest_first.sort_by(|x, y| y.0.total_cmp(&x.0));
        let within = largest_first
            .iter()
            .all(|(_, q)| self.triangle_within(*q, tol, r_min));
        self.largest_first = largest_first;
        within
    }

    /// Whether a long triangle `t` (an edge of [`PROBE_FROM`] or more) has its centroid or an
    /// edge's midpoint out of `tol`. Each probe is a point of t, so a yes means that t does not
    /// lie in T and [`Self::triangle_within`] says no too, only sooner: a triangle that leaves
    /// T mostly does so over a wide part, which the refinement may reach last.
    pub fn probes_miss(&mut self, t: &[DVec3; 3], tol: Tolerance) -> bool {
        let longest = (0..3)
            .map(|k| (t[k] - t[(k + 1) % 3]).length_squared())
            .fold(0.0, f64::max);
        longest >= PROBE_FROM * PROBE_FROM
            && [
                (t[0] + t[1] + t[2]) / 3.0,
                (t[0] + t[1]) / 2.0,
                (t[1] + t[2]) / 2.0,
                (t[2] + t[0]) / 2.0,
            ]
            .iter()
            .any(|p| !self.point_within(*p, tol))
    }

    /// What [`Self::distance`] gives, with p's voxel and the other-class voxel whose centre is
    /// nearest to p (exact below [`CENTRE_REACH`]).
    pub(super) fn nearest(&mut self, p: DVec3) -> Near {
        self.lookup::<true>(p)
    }

    /// [`Self::nearest`] without dist(p, ∂W), which the triangle test never reads: its `dist`
    /// is 0, the least the distance could be.
    fn nearest_centres(&mut self, p: DVec3) -> Near {
        self.lookup::<false>(p)
    }

    /// [`Self::nearest`], with dist(p, ∂W) worked out when `BOUNDARY` (else 0).
    #[inline(always)]
    fn lookup<const BOUNDARY: bool>(&mut self, p: DVec3) -> Near {
        let v = p.floor();
        let home = [v.x as isize, v.y as isize, v.z as isize];
        let entry = self.entry(home);
        // Squared gaps per axis from p to the cubes at offsets -2..=2 (local coordinate l).
        let gaps = |l: f64| {
            let (a, b) = (1.0 - l, 2.0 - l);
            [(l + 1.0) * (l + 1.0), l * l, 0.0, a * a, b * b]
        };
        let l = p - v; // in [0, 1)³
                       // The same to the centres at offsets -2..=2.
        let centre_gaps = |l: f64| [-1.5, -0.5, 0.5, 1.5, 2.5].map(|c: f64| (c - l) * (c - l));
        let (gx, gy, gz) = (gaps(l.x), gaps(l.y), gaps(l.z));
        let (cx, cy, cz) = (centre_gaps(l.x), centre_gaps(l.y), centre_gaps(l.z));
        let mut best = REACH * REACH;
        let (mut best_centre, mut other) = (CENTRE_REACH * CENTRE_REACH, None);
        // The memo keeps the other-class voxels no other one dominates; per axis a dominator's
        // centre is as near as the dominated one's too, so the nearest centre is among them.
        let mut bits = entry & OPPOSITE_BITS;
        while bits != 0 {
            let [i, j, k] = BLOCK[bits.trailing_zeros() as usize].map(usize::from);
            bits &= bits - 1;
            if BOUNDARY {
                best = best.min(gx[i] + gy[j] + gz[k]);
            }
            let c2 = cx[i] + cy[j] + cz[k];
            if c2 < best_centre {
                best_centre = c2;
                other = Some([i, j, k]);
            }
        }
        Near {
            dist: if BOUNDARY { best.sqrt() } else { 0.0 },
            inside: entry >> INSIDE_BIT & 1 == 1,
            home,
            own_centre: (p - centre(home)).length(),
            other_centre: best_centre.sqrt(),
            other: other.map(|o| std::array::from_fn(|a| home[a] + o[a] as isize - 2)),
        }
    }

    /// Whether `points` lie in one grid plane x_a = k (k an integer) and every unit square of that
    /// plane that their bounding box meets is a face of ∂W (inside on one side, outside on the
    /// other): then every point of their convex hull lies on ∂W, at distance 0. Flat faces of the
    /// voxel boundary keep this through collapses, and checking it costs one lookup per square
    /// instead of refining large pieces.
    fn on_boundary_plane(&self, points: &[DVec3]) -> bool {
        const MAX_SQUARES: f64 = 4096.0;
        for a in 0..3 {
            let k = points[0][a];
            if k.fract() != 0.0 || points.iter().any(|p| p[a] != k) {
                continue;
            }
            let (u, w) = ((a + 1) % 3, (a + 2) % 3);
            let lo = points
                .iter()
                .fold(DVec3::INFINITY, |m, p| m.min(*p))
                .floor();
            let hi = points
                .iter()
                .fold(DVec3::NEG_INFINITY, |m, p| m.max(*p))
                .ceil();
            if (hi[u] - lo[u]) * (hi[w] - lo[w]) > MAX_SQUARES {
                return false;
            }
            let k = k as isize;
            for i in lo[u] as isize..(hi[u] as isize).max(lo[u] as isize + 1) {
                for j in lo[w] as isize..(hi[w] as isize).max(lo[w] as isize + 1) {
                    let mut below = [0isize; 3];
                    below[a] = k - 1;
                    below[u] = i;
                    below[w] = j;
                    let mut above = below;
                    above[a] = k;
                    if self.cls.inside(below[0], below[1], below[2])
                        == self.cls.inside(above[0], above[1], above[2])
                    {
                        return false;
                    }
                }
            }
            return true;
        }
        false
    }

    /// Adaptive refinement shared by the region tests. Each piece (centroid c, circumradius R
    /// about c, so the piece lies in the ball B(c, R)) passes at once when `inherited(piece,
    /// parent's Near)` says so (the voxels found for its parent often serve it too, and cost no
    /// lookup); otherwise it gets `judge(piece, R, nearest(c))`: pass, fail, or refine. A piece
    /// to refine with R < `r_min`, or more than [`NODE_BUDGET`] pieces in all, fails the
    /// region (not shown: always sound). `bare(piece, R)` may give a verdict first, without a
    /// lookup, where R alone rules out a pass on distances or a whole-piece certificate passes
    /// it; a piece it refines hands its own parent's Near on to its children. Each piece carries
    /// a flag that `bare` may clear and the piece's children inherit (the triangle test's: "try
    /// the extruded-wall certificate").
    #[allow(clippy::too_many_arguments)]
    fn refine<const N: usize, const BOUNDARY: bool>(
        &mut self,
        work: &mut Refinement<N>,
        start: [DVec3; N],
        r_min: f64,
        mut bare: impl FnMut(&mut Self, &[DVec3; N], f64, &mut bool) -> Option<Verdict>,
        mut judge: impl FnMut(&mut Self, &[DVec3; N], f64, &Near) -> Verdict,
        inherited: impl Fn(&[DVec3; N], &Near) -> bool,
        split: impl Fn(&[DVec3; N], &mut Vec<[DVec3; N]>),
    ) -> bool {
        let Refinement {
            stack,
            parents,
            children,
        } = work;
        stack.clear();
        parents.clear();
        stack.push((start, u32::MAX, true));
        let mut visited = 0;
        while let Some((piece, parent, mut walls)) = stack.pop() {
            visited += 1;
            if visited > NODE_BUDGET {
                return false;
            }
            if parent != u32::MAX && inherited(&piece, &parents[parent as usize]) {
                continue;
            }
            let c = piece.iter().sum::<DVec3>() / N as f64;
            let r = piece
                .iter()
                .map(|x| (*x - c).length_squared())
                .fold(0.0, f64::max)
                .sqrt();
            match bare(self, &piece, r, &mut walls) {
                Some(Verdict::Pass) => continue,
                Some(Verdict::Fail) => return false,
                Some(Verdict::Refine) if r < r_min => return false,
                Some(Verdict::Refine) => {
                    children.clear();
                    split(&piece, children);
                    stack.extend(children.iter().map(|ch| (*ch, parent, walls)));
                    continue;
                }
                None => {}
            }
            let near = self.lookup::<BOUNDARY>(c);
            match judge(self, &piece, r, &near) {
                Verdict::Pass => {}
                Verdict::Fail => return false,
                Verdict::Refine if r < r_min => return false,
                Verdict::Refine => {
                    children.clear();
                    split(&piece, children);
                    let at = parents.len() as u32;
                    parents.push(near);
                    stack.extend(children.iter().map(|ch| (*ch, at, walls)));
                }
            }
        }
        true
    }

    /// Whether every point of triangle `t` lies in the tolerance volume `tol`. A piece passes
    /// when
    /// - its centroid's distances to the nearest outside and inside centres plus R are within
    ///   `tol` (distances are 1-Lipschitz; for c's own class its own voxel's centre serves), or
    /// - its corners are within `tol.outside` of one outside centre and within `tol.inside` of one
    ///   inside centre (c's own voxel's and the nearest other-class one's; a piece first tries
    ///   its parent's pair): the distance to a point is convex, so at most that over the piece; or
    /// - it lies on ∂W ([`Self::on_boundary_plane`]), which T holds, or
    /// - it is large and lies over a wall extruded along an axis, certified in the plane across
    ///   that axis (`extruded`, docs/design.md "Walls extruded along an axis").
    ///
    /// It fails when c is farther than `tol` allows from the other class's centres (c itself is
    /// out). Pieces split into four at their edge midpoints. Sound: may reject, never wrongly
    /// accepts.
    ///
    /// The verdict is a function of `t`, `tol` and `r_min` alone (the memo only saves work), so
    /// it is kept per exact triangle: a collapse retried after a neighbour's often asks about
    /// the same large triangles again (at n = 256, 2.7% of the calls but 17% of the lookups).
    pub fn triangle_within(&mut self, t: [DVec3; 3], tol: Tolerance, r_min: f64) -> bool {
        debug_assert!(tol.outside.max(tol.inside) < CENTRE_REACH && r_min > 0.0);
        let slot = verdict_slot(&t);
        if let Some(within) = self.kept(slot, &t, tol, r_min) {
            return within;
        }
        let within = self.refine_triangle(t, tol, r_min);
        self.verdicts[slot] = Some(Verdict3 {
            t,
            tol,
            r_min,
            within,
        });
        within
    }

    /// Whether [`Self::triangle_within`]`(t, tol, r_min)` is known to say no without working
    /// it out: its verdict is kept, and it is no.
    pub fn known_out(&self, t: &[DVec3; 3], tol: Tolerance, r_min: f64) -> bool {
        self.kept(verdict_slot(t), t, tol, r_min) == Some(false)
    }

    /// The verdict kept for `t` in `slot`, if any.
    fn kept(&self, slot: usize, t: &[DVec3; 3], tol: Tolerance, r_min: f64) -> Option<bool> {
        self.verdicts[slot]
            .filter(|k| k.t == *t && k.tol == tol && k.r_min == r_min)
            .map(|k| k.within)
    }

    /// [`Self::triangle_within`], decided.
    fn refine_triangle(&mut self, t: [DVec3; 3], tol: Tolerance, r_min: f64) -> bool {
        self.refine_triangle_splitting_above(t, tol, r_min, lookup_free_above(tol))
    }

    /// Whether every point of triangle `t` is within `tol.outside` of one of the outside centres
    /// nearest to its corners and centroid (`at_centroid`), and within `tol.inside` of one of
    /// the inside centres nearest to them ([`cover::within`], exact for those centres). The
    /// whole class is never farther than a few of its centres, so a yes is sound; a corner
    /// with no other-class centre within [`CENTRE_REACH`] is out of T, a no.
    fn covered(&mut self, t: &[DVec3; 3], at_centroid: &Near, tol: Tolerance) -> bool {
        let (mut outside, mut inside) = ([DVec3::ZERO; 4], [DVec3::ZERO; 4]);
        let (mut n_out, mut n_in) = (0, 0);
        let corners = [t[0], t[1], t[2]].map(|p| self.nearest_centres(p));
        for near in corners.iter().chain([at_centroid]) {
            let Some((o, i)) = near.pair() else {
                return false;
            };
            for (v, list, n) in [(o, &mut outside, &mut n_out), (i, &mut inside, &mut n_in)] {
                let c = centre(v);
                if !list[..*n].contains(&c) {
                    list[*n] = c;
                    *n += 1;
                }
            }
        }
        cover::within(t, &outside[..n_out], tol.outside)
            && cover::within(t, &inside[..n_in], tol.inside)
    }

    /// [`Self::refine_triangle`] with pieces of R above `large` split without a lookup.
    fn refine_triangle_splitting_above(
        &mut self,
        t: [DVec3; 3],
        tol: Tolerance,
        r_min: f64,
        large: f64,
    ) -> bool {
        let flat_from = tol.outside.min(tol.inside) - HALF_DIAGONAL;
        let judge = |me: &mut Self, piece: &[DVec3; 3], r: f64, near: &Near| {
            let (d_out, d_in) = near.centre_distances();
            if tol.admits(d_out + r, d_in + r)
                || near.hugged(piece, tol)
                || (r > flat_from && me.on_boundary_plane(piece))
            {
                Verdict::Pass
            } else if !tol.admits(d_out, d_in) {
                Verdict::Fail
            } else if r < LAST_RESORT * r_min && me.covered(piece, near, tol) {
                Verdict::Pass
            } else {
                Verdict::Refine
            }
        };
        // A large piece flat on ∂W passes; else one over a wall extruded along an axis may
        // (`extruded`), tried again on its children unless none of them can be certified so.
        let bare = |me: &mut Self, piece: &[DVec3; 3], r: f64, walls: &mut bool| {
            (r > large).then(|| {
                if me.on_boundary_plane(piece) {
                    return Verdict::Pass;
                }
                if *walls {
                    match me.extruded.within(piece, [tol.outside, tol.inside]) {
                        Attempt::Certified => return Verdict::Pass,
                        Attempt::Pieces => {}
                        Attempt::Never => *walls = false,
                    }
                }
                Verdict::Refine
            })
        };
        let inherited = |piece: &[DVec3; 3], parent: &Near| parent.hugged(piece, tol);
        let split = |t: &[DVec3; 3], out: &mut Vec<[DVec3; 3]>| {
            let m = [
                (t[0] + t[1]) / 2.0,
                (t[1] + t[2]) / 2.0,
                (t[2] + t[0]) / 2.0,
            ];
            out.extend([
                [t[0], m[0], m[2]],
                [m[0], t[1], m[1]],
                [m[2], m[1], t[2]],
                [m[0], m[1], m[2]],
            ]);
        };
        let mut work = std::mem::take(&mut self.triangles);
        let within = self.refine::<3, false>(&mut work, t, r_min, bare, judge, inherited, split);
        self.triangles = work;
        within
    }

    /// Whether every point of tetrahedron `t` is within `limit` (√3/2 ≤ limit < [`CENTRE_REACH`])
    /// of an outside voxel's centre (hence farther than δ - `limit` from the swept volume). A
    /// piece passes when
    /// - the distance from its centroid c to the nearest outside centre plus R is within `limit`,
    ///   or
    /// - c lies outside W with dist(c, ∂W) ≥ R (the open ball then holds no point of W, and
    ///   every point outside W is within √3/2 of its own voxel's centre), or
    /// - its corners are within `limit` of one outside centre (c's own voxel's when c is outside,
    ///   else the nearest outside one; a piece first tries its parent's): a convex distance, or
    /// - it is flat on ∂W.
    ///
    /// It fails when c is inside W and farther than `limit` from every outside centre. Pieces
    /// split in two at the midpoint of their longest edge. Sound: may reject, never wrongly
    /// accepts.
    pub fn tetrahedron_shallow(&mut self, t: [DVec3; 4], limit: f64, r_min: f64) -> bool {
        debug_assert!((HALF_DIAGONAL..CENTRE_REACH).contains(&limit) && r_min > 0.0);
        let judge = |me: &mut Self, piece: &[DVec3; 4], r: f64, near: &Near| {
            let (d_out, _) = near.centre_distances();
            if d_out + r <= limit
                || (!near.inside && near.dist >= r)
                || near.outside_hugs(piece, limit)
                || (r > limit - HALF_DIAGONAL && me.on_boundary_plane(piece))
            {
                Verdict::Pass
            } else if near.inside && d_out > limit {
                Verdict::Fail
            } else {
                Verdict::Refine
            }
        };
        let inherited = |piece: &[DVec3; 4], parent: &Near| parent.outside_hugs(piece, limit);
        let split = |t: &[DVec3; 4], out: &mut Vec<[DVec3; 4]>| {
            let (mut a, mut b, mut longest) = (0, 1, -1.0);
            for i in 0..4 {
                for j in i + 1..4 {
                    let l = (t[i] - t[j]).length_squared();
                    if l > longest {
                        (a, b, longest) = (i, j, l);
                    }
                }
            }
            let m = (t[a] + t[b]) / 2.0;
            let (mut left, mut right) = (*t, *t);
            left[a] = m;
            right[b] = m;
            out.extend([left, right]);
        };
        let mut work = std::mem::take(&mut self.tetrahedra);
        let none = |_: &mut Self, _: &[DVec3; 4], _: f64, _: &mut bool| None;
        let shallow = self.refine::<4, true>(&mut work, t, r_min, none, judge, inherited, split);
        self.tetrahedra = work;
        shallow
    }
}

/// The slot of triangle `t`'s verdict in [`Proximity::verdicts`], by its exact corners.
fn verdict_slot(t: &[DVec3; 3]) -> usize {
    t.iter().flat_map(|p| p.to_array()).fold(0u64, |h, x| {
        (h ^ x.to_bits()).wrapping_mul(0x9e37_79b9_7f4a_7c15)
    }) as usize
        >> 7
        & (VERDICT_SLOTS - 1)
}

/// The R above which a piece of the triangle test splits without a lookup. A piece whose corners
/// lie within ρ of one point o has R ≤ 4ρ/3 about its centroid (each corner is a third of
/// 2(p_i - o) - (p_j - o) - (p_k - o) from it), so above 4/3 of the smaller radius neither the
/// distance test (R ≤ the radius) nor the corner test can pass it: only flat on ∂W can.
fn lookup_free_above(tol: Tolerance) -> f64 {
    4.0 / 3.0 * tol.outside.min(tol.inside)
}

/// What [`Proximity::nearest`] finds about a point p.
#[derive(Clone, Copy)]
pub(super) struct Near {
    /// dist(p, ∂W) when below [`REACH`], else REACH; 0 from the triangle test's lookups, which
    /// leave it out (the least it could be).
    pub(super) dist: f64,
    /// Whether p's voxel is inside W.
    pub(super) inside: bool,
    /// p's voxel.
    pub(super) home: [isize; 3],
    /// The distance from p to its own voxel's centre.
    own_centre: f64,
    /// The distance from p to the nearest other-class voxel's centre when below
    /// [`CENTRE_REACH`], else CENTRE_REACH.
    other_centre: f64,
    /// That voxel, when its centre is within [`CENTRE_REACH`].
    other: Option<[isize; 3]>,
}

impl Near {
    /// (distance to an outside centre, distance to an inside centre) from p: exact for the other class, its own voxel's centre for its own class (an
    /// upper bound, within √3/2, which `Tolerance` always admits).
    pub(super) fn centre_distances(&self) -> (f64, f64) {
        if self.inside {
            (self.other_centre, self.own_centre)
        } else {
            (self.own_centre, self.other_centre)
        }
    }

    /// (outside voxel, inside voxel): p's own and the nearest other-class one.
    pub(super) fn pair(&self) -> Option<([isize; 3], [isize; 3])> {
        let o = self.other?;
        Some(if self.inside {
            (o, self.home)
        } else {
            (self.home, o)
        })
    }

    /// Whether `piece`'s corners are within `tol.outside` of the pair's outside centre and
    /// within `tol.inside` of its inside centre (the triangle test's corner condition).
    fn hugged<const N: usize>(&self, piece: &[DVec3; N], tol: Tolerance) -> bool {
        self.pair().is_some_and(|(out, ins)| {
            corners_within(piece, out, tol.outside) && corners_within(piece, ins, tol.inside)
        })
    }

    /// Whether `piece`'s corners are within `limit` of one outside centre: p's own voxel's when
    /// it is outside, else the nearest outside one (the tetrahedron test's corner condition).
    fn outside_hugs<const N: usize>(&self, piece: &[DVec3; N], limit: f64) -> bool {
        self.pair()
            .map(|(out, _)| out)
            .or((!self.inside).then_some(self.home))
            .is_some_and(|o| corners_within(piece, o, limit))
    }
}

/// Whether every corner of a piece is within `limit` of the centre of voxel `v` (then every
/// point of the piece is: the distance to a point is convex).
fn corners_within<const N: usize>(piece: &[DVec3; N], v: [isize; 3], limit: f64) -> bool {
    let (c, limit2) = (centre(v), limit * limit);
    piece.iter().all(|p| (*p - c).length_squared() <= limit2)
}

/// What [`Proximity::refine`] does with a piece.
enum Verdict {
    Pass,
    Fail,
    Refine,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::classify::test_support::{boxed as boxed_at, random as random_at};

    /// The box [1, 4) x [1, 3) x [2, 5) of a 6x5x7 grid.
    fn boxed() -> Classifier {
        boxed_at([6, 5, 7], [1.0, 1.0, 2.0], [4.0, 3.0, 5.0])
    }

    /// Brute force: distance to the box surface [1,4]x[1,3]x[2,5].
    fn box_dist(p: DVec3) -> f64 {
        let (lo, hi) = (DVec3::new(1.0, 1.0, 2.0), DVec3::new(4.0, 3.0, 5.0));
        let outside = (lo - p).max(p - hi).max(DVec3::ZERO);
        if outside.length() > 0.0 {
            outside.length()
        } else {
            (p - lo).min(hi - p).min_element()
        }
    }

    #[test]
    fn distance_to_the_voxel_boundary_is_exact() {
        let cls = boxed();
        assert!(
            cls.inside(1, 1, 2)
                && cls.inside(3, 2, 4)
                && !cls.inside(0, 1, 2)
                && !cls.inside(3, 3, 4)
        );
        let mut rng = fastrand::Rng::with_seed(7);
        let mut rnd = |lo: f64, hi: f64| lo + (hi - lo) * rng.f64();
        for _ in 0..5000 {
            let p = DVec3::new(rnd(0.0, 6.0), rnd(0.0, 5.0), rnd(0.0, 7.0));
            let exact = box_dist(p);
            match dist_to_boundary(&cls, p, 0.9) {
                Some(d) => assert!((d - exact).abs() < 1e-12, "{p}: {d} vs {exact}"),
                None => assert!(exact > 0.9 - 1e-12, "{p}: missed {exact}"),
            }
        }
    }

    /// Uniform random points of a simplex (barycentric weights from exponentials).
    fn simplex_point<const N: usize>(v: [DVec3; N], rnd: &mut impl FnMut() -> f64) -> DVec3 {
        let w: [f64; N] = std::array::from_fn(|_| -rnd().max(1e-300).ln());
        let sum: f64 = w.iter().sum();
        v.iter().zip(w).map(|(p, w)| *p * (w / sum)).sum()
    }

    /// N corners drawn uniformly from the cube of edge `size` centred on `c`.
    fn corners_around<const N: usize>(
        c: DVec3,
        size: f64,
        rnd: &mut impl FnMut() -> f64,
    ) -> [DVec3; N] {
        std::array::from_fn(|_| c + (DVec3::new(rnd(), rnd(), rnd()) - 0.5) * size)
    }

    /// A triangle's circumradius about its centroid (the refinement's R).
    fn centroid_radius(t: &[DVec3; 3]) -> f64 {
        let c = (t[0] + t[1] + t[2]) / 3.0;
        t.iter().map(|p| (*p - c).length()).fold(0.0, f64::max)
    }

    /// Uniform numbers in [0, 1), reproducible from `seed`.
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut rng = fastrand::Rng::with_seed(seed);
        move || rng.f64()
    }

    #[test]
    fn memoized_distance_matches_brute_force() {
        for seed in 0..4 {
            let cls = random_at([14, 12, 13], seed);
            // Odd seeds with the smallest memo, whose slots are overwritten all the time.
            let mut prox = if seed % 2 == 1 {
                Proximity::with_capacity(&cls, 0)
            } else {
                Proximity::new(&cls)
            };
            let mut rnd = uniform(seed + 100);
            let mut near = 0;
            for _ in 0..20_000 {
                let p = DVec3::new(rnd() * 16.0 - 1.0, rnd() * 14.0 - 1.0, rnd() * 15.0 - 1.0);
                let (d, inside) = prox.distance(p);
                let f = p.floor();
                assert_eq!(inside, cls.inside(f.x as isize, f.y as isize, f.z as isize));
                // The nearest other-class centre, exact below CENTRE_REACH.
                let other = prox.nearest(p).other_centre;
                match dist_to_centre(&cls, p, !inside, CENTRE_REACH) {
                    Some(exact) if exact < CENTRE_REACH => {
                        assert!((other - exact).abs() < 1e-12, "{p}: {other} vs {exact}")
                    }
                    _ => assert_eq!(other, CENTRE_REACH, "{p}: {other}, brute force finds none"),
                }
                match dist_to_boundary(&cls, p, REACH) {
                    Some(exact) if exact < REACH => {
                        near += 1;
                        assert!((d - exact).abs() < 1e-12, "{p}: {d} vs {exact}");
                    }
                    _ => assert_eq!(d, REACH, "{p}: {d}, brute force finds nothing nearer"),
                }
            }
            assert!(
                near > 5000,
                "seed {seed}: only {near} points near the boundary"
            );
        }
    }

    /// The tolerance volume of the defaults' radius for ε = √3/2.
    const TOL: Tolerance = Tolerance {
        outside: 1.732,
        inside: 1.732,
    };

    /// Brute force: whether `p` lies in the tolerance volume.
    fn in_volume(cls: &Classifier, p: DVec3, tol: Tolerance) -> bool {
        dist_to_centre(cls, p, false, tol.outside).is_some()
            && dist_to_centre(cls, p, true, tol.inside).is_some()
    }

    #[test]
    fn tolerance_test_accepts_near_triangles_and_rejects_far_ones() {
        let cls = boxed();
        let mut prox = Proximity::new(&cls);
        // On the box's top face z = 5, slightly lifted: inside T.
        let near = [
            DVec3::new(1.2, 1.2, 5.3),
            DVec3::new(3.8, 1.2, 5.3),
            DVec3::new(1.2, 2.8, 4.8),
        ];
        assert!(prox.triangle_within(near, TOL, 0.05));
        // One corner 1.4 above the face over a corner voxel: its nearest inside centre, (1.5,
        // 1.5, 4.5), is 1.95 away, beyond 1.732: refused.
        let far = [
            DVec3::new(1.2, 1.2, 6.4),
            DVec3::new(3.8, 1.2, 5.3),
            DVec3::new(1.2, 2.8, 5.3),
        ];
        assert!(!in_volume(&cls, far[0], TOL));
        assert!(!prox.triangle_within(far, TOL, 0.05));
        // Cutting through the box's middle: its point (2.5, 2, 3.5) is 1.5 from the nearest
        // outside centres, (2.5, 0.5, 3.5) and (2.5, 3.5, 3.5): in T, but refused by a narrower
        // outside radius.
        let deep = [
            DVec3::new(1.5, 1.5, 3.5),
            DVec3::new(3.5, 1.5, 3.5),
            DVec3::new(2.5, 2.5, 3.5),
        ];
        assert!(prox.triangle_within(deep, TOL, 0.05));
        let narrow = Tolerance {
            outside: 1.2,
            ..TOL
        };
        assert!(!in_volume(&cls, DVec3::new(2.5, 2.0, 3.5), narrow));
        assert!(!prox.triangle_within(deep, narrow, 0.05));
        // The same volume holds the ε = √3/2 band about ∂W: a triangle 0.85 below the top face.
        let below = [
            DVec3::new(1.2, 1.2, 4.15),
            DVec3::new(3.8, 1.2, 4.15),
            DVec3::new(1.2, 2.8, 4.15),
        ];
        assert!(prox.triangle_within(below, TOL, 0.05));
    }

    /// Over a flat wall (inside below z = 6) T is the slab |z - 6| ≤ √(r² - 1/2) - 1/2 (0.784
    /// at r = 1.466, between four centres of a layer). A wide triangle at z = 6.78 lies in it
    /// with 0.004 to spare, less than the smallest piece, so the refinement alone splits down
    /// to it and rejects; the last resort decides it, and a sample of points agrees. At 6.79 a
    /// point between four centres is out, and the triangle is refused. Without the last resort
    /// the first assertion fails.
    #[test]
    fn a_triangle_near_the_slab_edge_is_decided_exactly() {
        let cls = boxed_at([12, 12, 12], [0.0, 0.0, 0.0], [12.0, 12.0, 6.0]);
        let tol = Tolerance {
            outside: 1.466,
            inside: 1.466,
        };
        let at = |z: f64| {
            [
                DVec3::new(3.2, 3.3, z),
                DVec3::new(8.6, 3.7, z),
                DVec3::new(4.1, 8.4, z),
            ]
        };
        let sampled_in = |t: &[DVec3; 3]| {
            let mut prox = Proximity::new(&cls);
            (0..=60).all(|i| {
                (0..=60 - i).all(|j| {
                    let (a, b) = (i as f64 / 60.0, j as f64 / 60.0);
                    prox.point_within(t[0] + (t[1] - t[0]) * a + (t[2] - t[0]) * b, tol)
                })
            })
        };
        let mut prox = Proximity::new(&cls);
        assert!(sampled_in(&at(6.78)) && prox.triangle_within(at(6.78), tol, 0.05));
        // (5, 5) lies between four centres of each layer, and in the triangle.
        assert!(!prox.point_within(DVec3::new(5.0, 5.0, 6.79), tol));
        assert!(!prox.triangle_within(at(6.79), tol, 0.05));
    }

    /// The two shortcuts of the triangle test answer what the refinement does: a kept verdict
    /// (asked again after thousands of other triangles, so slots are shared and overwritten)
    /// and the probes of long triangles (a miss only where the refinement says no).
    #[test]
    fn kept_verdicts_and_probes_agree_with_the_refinement() {
        let (mut probed_out, mut within, mut outside) = (0, 0, 0);
        for seed in 0..2 {
            let cls = random_at([16, 16, 16], seed + 40);
            let (mut kept, mut fresh) = (Proximity::new(&cls), Proximity::new(&cls));
            let mut rnd = uniform(seed + 90);
            let triangles: Vec<[DVec3; 3]> = (0..VERDICT_SLOTS + 1500)
                .map(|_| {
                    let c = DVec3::new(rnd(), rnd(), rnd()) * 16.0;
                    let size = 0.2 + 9.0 * rnd() * rnd();
                    corners_around(c, size, &mut rnd)
                })
                .collect();
            for round in 0..2 {
                for t in &triangles {
                    let truth = fresh.refine_triangle(*t, TOL, 0.05);
                    assert_eq!(
                        kept.triangle_within(*t, TOL, 0.05),
                        truth,
                        "round {round}: {t:?}"
                    );
                    if round == 0 {
                        if fresh.probes_miss(t, TOL) {
                            assert!(!truth, "{t:?}: a probe missed, the refinement accepts");
                            probed_out += 1;
                        }
                        if truth {
                            within += 1;
                        } else {
                            outside += 1;
                        }
                    }
                }
            }
        }
        assert!(
            probed_out > 100 && within > 500 && outside > 500,
            "{probed_out} {within} {outside}"
        );
    }

    /// A kept no is known before any work, a yes or an unasked triangle never is; and a step's
    /// new surface is judged as every triangle and its new vertex are, asked one by one on a
    /// fresh memo, whatever the order and whatever the memo already holds.
    #[test]
    fn known_noes_and_the_new_surface_agree_with_the_refinement() {
        let (mut known, mut yes, mut no) = (0, 0, 0);
        for seed in 0..2 {
            let cls = random_at([16, 16, 16], seed + 60);
            let mut kept = Proximity::new(&cls);
            let mut rnd = uniform(seed + 70);
            for _ in 0..600 {
                let v = DVec3::new(rnd(), rnd(), rnd()) * 16.0;
                let fan: Vec<([u32; 3], [DVec3; 3])> = (0..2 + (rnd() * 5.0) as usize)
                    .map(|k| {
                        let size = 0.3 + 4.0 * rnd();
                        let t: [DVec3; 3] = corners_around(v, size, &mut rnd);
                        ([0, k as u32, k as u32 + 1], [v, t[1], t[2]])
                    })
                    .collect();
                let mut fresh = Proximity::new(&cls);
                let truth = fresh.point_within(v, TOL)
                    && fan
                        .iter()
                        .all(|(_, q)| fresh.refine_triangle(*q, TOL, 0.05));
                for (_, q) in &fan {
                    let known_no = kept.known_out(q, TOL, 0.05);
                    assert!(!known_no || !fresh.refine_triangle(*q, TOL, 0.05), "{q:?}");
                }
                assert_eq!(kept.new_surface_within(Some(v), &fan, TOL, 0.05), truth);
                let mut reversed = fan.clone();
                reversed.reverse();
                assert_eq!(
                    kept.new_surface_within(Some(v), &reversed, TOL, 0.05),
                    truth
                );
                // A no asked once is known from then on (the triangle that said it is kept).
                if !truth
                    && fan
                        .iter()
                        .any(|(_, q)| !fresh.refine_triangle(*q, TOL, 0.05))
                {
                    let inside = fan
                        .iter()
                        .filter(|(_, q)| kept.triangle_within(*q, TOL, 0.05))
                        .count();
                    assert!(inside < fan.len());
                    assert!(fan.iter().any(|(_, q)| kept.known_out(q, TOL, 0.05)));
                    assert!(!kept.new_surface_within(None, &fan, TOL, 0.05));
                    known += 1;
                }
                if truth {
                    yes += 1;
                    assert!(fan.iter().all(|(_, q)| !kept.known_out(q, TOL, 0.05)));
                } else {
                    no += 1;
                }
            }
        }
        assert!(known > 50 && yes > 100 && no > 100, "{known} {yes} {no}");
    }

    /// Random triangles near random voxel sets: whatever the test accepts has every sampled
    /// point in the tolerance volume by brute force, and it accepts and rejects both; so do
    /// narrower, lopsided volumes.
    #[test]
    fn triangle_test_is_sound_on_random_voxel_sets() {
        for tol in [
            TOL,
            Tolerance {
                outside: 1.2,
                inside: 1.9,
            },
            Tolerance {
                outside: 2.3,
                inside: 0.9,
            },
        ] {
            let (mut accepted, mut rejected) = (0, 0);
            for seed in 0..3 {
                let cls = random_at([14, 14, 14], seed);
                let mut prox = Proximity::new(&cls);
                let mut rnd = uniform(seed + 7);
                for _ in 0..2000 {
                    let c = DVec3::new(rnd(), rnd(), rnd()) * 14.0;
                    let size = 0.2 + 3.0 * rnd();
                    let t: [DVec3; 3] = corners_around(c, size, &mut rnd);
                    if !prox.triangle_within(t, tol, 0.05) {
                        rejected += 1;
                        continue;
                    }
                    accepted += 1;
                    for k in 0..300 {
                        let p = if k < 3 {
                            t[k]
                        } else {
                            simplex_point(t, &mut rnd)
                        };
                        assert!(
                            in_volume(&cls, p, tol),
                            "{tol:?}: {t:?} accepted but {p} is out of the volume"
                        );
                    }
                }
            }
            assert!(
                accepted > 200 && rejected > 200,
                "{tol:?}: {accepted} accepted, {rejected} rejected"
            );
        }
    }

    /// Long triangles over a wall extruded along y pass the band test (which tries the
    /// extruded-wall certificate on them whole), as the certificate alone says they lie in T.
    #[test]
    fn triangles_over_an_extruded_wall_pass_whole() {
        use crate::simplify::extruded::tests::{tilted_wall, wall_triangles, TOLERANCES};
        use crate::simplify::extruded::{Attempt, Extruded};
        let [outside, inside] = TOLERANCES[0];
        let tol = Tolerance { outside, inside };
        let cls = tilted_wall(|_| 38);
        let (mut prox, mut walls) = (Proximity::new(&cls), Extruded::new(&cls));
        let mut passed = 0;
        for t in wall_triangles(28.0) {
            if walls.within(&t, TOLERANCES[0]) == Attempt::Certified {
                assert!(prox.triangle_within(t, tol, 0.05), "{t:?}");
                passed += 1;
            }
        }
        assert!(passed >= 38, "{passed} of 40");
    }

    /// Large triangles over a wall that drifts along y (extruded piece by piece: no column near
    /// it is uniform over all of a triangle's 100 layers) pass the band test. The certificate
    /// does not certify them whole, and says so with `Pieces`: the band test's 3D pieces span
    /// fewer layers and are certified. Left to the 3D refinement alone after the whole
    /// triangle's no (the rule until 2026-12-07), they were refused.
    #[test]
    fn triangles_over_a_drifting_wall_pass_by_pieces() {
        use crate::simplify::extruded::tests::TOLERANCES;
        use crate::simplify::extruded::{Attempt, Extruded};
        let [outside, inside] = TOLERANCES[0];
        let tol = Tolerance { outside, inside };
        let plane = |x: f64, y: f64| 14.0 + 0.04 * y - 0.37 * x;
        let cls = crate::mesh::classify::test_support::from_voxels([40, 120, 24], |v| {
            let (x, y, z) = (v[0] as f64 + 0.5, v[1] as f64 + 0.5, v[2] as f64 + 0.5);
            z < plane(x, y) && (2..118).contains(&v[1])
        });
        let on_wall = |x: f64, y: f64| DVec3::new(x, y, plane(x, y));
        let (mut prox, mut walls) = (Proximity::new(&cls), Extruded::new(&cls));
        for k in 0..8 {
            let s = 0.4 * k as f64;
            let t = [
                on_wall(2.0 + s, 4.0),
                on_wall(28.0 + s, 6.0),
                on_wall(3.0 + s, 110.0),
            ];
            assert_eq!(walls.within(&t, TOLERANCES[0]), Attempt::Pieces, "{t:?}");
            assert!(prox.triangle_within(t, tol, 0.05), "{t:?}");
            // And they do lie in T, by brute-force distances at points across them.
            for (a, b) in (0..=40).flat_map(|i| (0..=40 - i).map(move |j| (i, j))) {
                let (a, b) = (a as f64 / 40.0, b as f64 / 40.0);
                let p = t[0] + a * (t[1] - t[0]) + b * (t[2] - t[0]);
                assert!(dist_to_centre(&cls, p, false, outside).is_some(), "{p}");
                assert!(dist_to_centre(&cls, p, true, inside).is_some(), "{p}");
            }
        }
    }

    /// Splitting large pieces without a lookup changes no verdict: on random voxel sets the
    /// triangle test says the same with the rule and without it (a rule that passed a large
    /// piece it should refine would accept what the full test rejects), on triangles large
    /// enough for the rule to act. And the bound it rests on: corners within ρ of a point lie
    /// within 4ρ/3 of their centroid, nearly reached by thin triangles.
    #[test]
    fn lookup_free_splits_change_no_verdict() {
        let mut rnd = uniform(11);
        let mut nearest_to_bound = 0.0f64;
        // Points of the unit ball, crowded towards its surface.
        let in_ball = |rnd: &mut dyn FnMut() -> f64| {
            let d = DVec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5).normalize_or_zero();
            d * rnd().sqrt().sqrt()
        };
        for _ in 0..20_000 {
            let t: [DVec3; 3] = std::array::from_fn(|_| in_ball(&mut rnd));
            let r = centroid_radius(&t);
            assert!(r <= 4.0 / 3.0 + 1e-12, "{t:?}: R = {r}");
            nearest_to_bound = nearest_to_bound.max(r);
        }
        assert!(nearest_to_bound > 1.2, "{nearest_to_bound}");
        let mut large_ones = 0;
        for tol in [
            TOL,
            Tolerance {
                outside: 1.2,
                inside: 1.9,
            },
        ] {
            for seed in 0..3 {
                let cls = random_at([14, 14, 14], seed);
                let mut prox = Proximity::new(&cls);
                let mut rnd = uniform(seed + 17);
                for _ in 0..1500 {
                    let c = DVec3::new(rnd(), rnd(), rnd()) * 14.0;
                    let size = 0.2 + 4.0 * rnd();
                    let t: [DVec3; 3] = corners_around(c, size, &mut rnd);
                    let with_rule = prox.refine_triangle(t, tol, 0.05);
                    let without = prox.refine_triangle_splitting_above(t, tol, 0.05, f64::INFINITY);
                    assert_eq!(with_rule, without, "{tol:?}: {t:?}");
                    large_ones += (centroid_radius(&t) > lookup_free_above(tol)) as usize;
                }
            }
        }
        assert!(large_ones > 500, "{large_ones}");
    }

    /// Random tetrahedra: whatever the test accepts has every sampled point within the limit of
    /// an outside centre; one reaching a box's middle is rejected; one entirely outside passes.
    #[test]
    fn tetrahedron_test_is_sound_on_random_voxel_sets() {
        let (mut accepted, mut rejected) = (0, 0);
        for seed in 0..3 {
            let cls = random_at([20, 20, 20], seed + 10);
            let mut prox = Proximity::new(&cls);
            let mut rnd = uniform(seed + 70);
            for _ in 0..2000 {
                let c = DVec3::splat(3.0) + DVec3::new(rnd(), rnd(), rnd()) * 14.0;
                let size = 0.2 + 4.0 * rnd();
                let t: [DVec3; 4] = corners_around(c, size, &mut rnd);
                if !prox.tetrahedron_shallow(t, 2.3, 0.05) {
                    rejected += 1;
                    continue;
                }
                accepted += 1;
                for k in 0..400 {
                    let p = if k < 4 {
                        t[k]
                    } else {
                        simplex_point(t, &mut rnd)
                    };
                    assert!(
                        dist_to_centre(&cls, p, false, 2.3).is_some(),
                        "{t:?} accepted but {p} is farther than 2.3 from every outside centre"
                    );
                }
            }
        }
        assert!(
            accepted > 300 && rejected > 300,
            "{accepted} accepted, {rejected} rejected"
        );

        let cls = boxed_at([9, 9, 9], [1.0, 1.0, 1.0], [8.0, 8.0, 8.0]);
        let mut prox = Proximity::new(&cls);
        // Flat on the top face z = 8, reaching 1.2 below it (1.7 from the outside centres above):
        // passes.
        let flat = [
            DVec3::new(1.5, 1.5, 8.3),
            DVec3::new(7.5, 1.5, 8.3),
            DVec3::new(1.5, 7.5, 8.3),
            DVec3::new(4.0, 4.0, 6.8),
        ];
        assert!(prox.tetrahedron_shallow(flat, 2.3, 0.05));
        // The same with its apex at the box's middle, 3.5 deep: refused.
        let deep = [flat[0], flat[1], flat[2], DVec3::new(4.5, 4.5, 4.5)];
        assert!(!prox.tetrahedron_shallow(deep, 2.3, 0.05));
        // Outside the box, far from it: passes (no point of W at all).
        let away = DVec3::new(-6.0, 0.0, 0.0);
        assert!(prox.tetrahedron_shallow(deep.map(|p| p + away), 2.3, 0.05));
    }
}
