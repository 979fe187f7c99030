//! The sweep check of a collapse as the region between the old and the new surface, on pieces
//! of their common projection instead of the tetrahedra from the new vertex (docs/design.md,
//! "The region between the surfaces").
//!
//! O: the triangles the collapse removes or moves (old places); N: the moved ones (new places).
//! They share their boundary, so O - N is a closed surface and the mesh's winding number
//! changes exactly where that of O - N is not zero. Project along a direction d that every
//! triangle of O and N faces (n·d > 0) and whose boundary projects to a simple closed curve:
//! then each surface lies over every point x inside that curve exactly once (an orientation-
//! preserving map covers a point as often as its boundary winds around it), and the winding
//! number of O - N at a point over x is ±1 between the two heights over x and 0 elsewhere.
//! Over a piece P of the overlay of O's and N's projected triangles (one old triangle o and one
//! new triangle n over all of P), the region is the set between two planes, inside the convex
//! hull of P's corners lifted onto both: it passes when those six points are within `limit` of
//! one outside voxel centre (a convex distance), within `limit` - R of the outside centre
//! nearest their centroid (R their radius), or when the ball of radius R about the centroid
//! holds no point of W. It fails (exactly) when the planes do not cross over P and the centroid,
//! then between them, is inside W and farther than `limit` from every outside centre. Pieces
//! are otherwise halved at their longest edge, down to `r_min`, within a budget (both reject).
//!
//! Rounding: the overlay's pieces are checked to add up to each new triangle's area (else the
//! tetrahedra decide); lifted points carry rounding far below the [`ROUNDING`] kept off `limit`
//! (slivers the rounding leaves between pieces lie within it of a checked piece's hull).

use glam::{DVec2, DVec3};

use super::band::Proximity;

/// Smallest cosine between a triangle's normal and the projection direction: steeper triangles
/// leave the check to the tetrahedra.
const MIN_COS: f64 = 1e-3;
/// |cosine| below which a triangle counts as standing along the projection direction.
const EDGEWISE: f64 = 1e-12;
/// Kept off `limit` for the rounding of lifted points and of the overlay, grid units.
const ROUNDING: f64 = 1e-7;
/// Pieces one check may visit before it gives up (and rejects).
const NODE_BUDGET: usize = 4096;

/// A triangle of O or N in the projection frame: 2D corners (counter-clockwise), and the height
/// of its plane as an affine function of the 2D position (t = h0 + h·x).
#[derive(Clone, Copy)]
struct Sheet {
    corners: [DVec2; 3],
    h0: f64,
    h: DVec2,
}

impl Sheet {
    fn height(&self, x: DVec2) -> f64 {
        self.h0 + self.h.dot(x)
    }
}

/// The projection frame: heights along `d`, plane coordinates along `e1`, `e2` (right-handed).
struct Frame {
    d: DVec3,
    e1: DVec3,
    e2: DVec3,
}

impl Frame {
    fn flat(&self, p: DVec3) -> DVec2 {
        DVec2::new(p.dot(self.e1), p.dot(self.e2))
    }

    fn lift(&self, x: DVec2, t: f64) -> DVec3 {
        self.e1 * x.x + self.e2 * x.y + self.d * t
    }

    /// Triangle `p` as a sheet, when it faces along d at least [`MIN_COS`]; edgewise when it
    /// stands along d (within [`EDGEWISE`]: its projection a segment, over no area).
    fn sheet(&self, p: &[DVec3; 3]) -> Facing {
        let n = (p[1] - p[0]).cross(p[2] - p[0]);
        let len = n.length();
        let cos = n.dot(self.d) / len;
        if len.is_nan() {
            return Facing::Away;
        }
        if len == 0.0 || cos.abs() <= EDGEWISE {
            return Facing::Edgewise;
        }
        if cos < MIN_COS {
            return Facing::Away;
        }
        let c = p.map(|x| self.flat(x));
        let t = p.map(|x| x.dot(self.d));
        let (u, w) = (c[1] - c[0], c[2] - c[0]);
        let det = u.perp_dot(w);
        if det <= 0.0 {
            return Facing::Away;
        }
        let (du, dw) = (t[1] - t[0], t[2] - t[0]);
        let h = DVec2::new(du * w.y - dw * u.y, dw * u.x - du * w.x) / det;
        Facing::Sheet(Sheet {
            corners: c,
            h0: t[0] - h.dot(c[0]),
            h,
        })
    }
}

/// How a triangle stands to the projection direction.
enum Facing {
    Sheet(Sheet),
    /// Along it: over no area of the plane, so over no piece (its points are limits of the
    /// region over the pieces beside it).
    Edgewise,
    /// Against it, or too steep to lift soundly.
    Away,
}

/// A piece of the overlay: 2D corners (counter-clockwise), its new and old sheet, and the
/// outside voxel that served its parent (u32::MAX: none; else an index of `parents`).
#[derive(Clone, Copy)]
struct Piece {
    corners: [DVec2; 3],
    new: u16,
    old: u16,
    parent: u32,
}

/// Buffers of [`Proximity::between_shallow`], kept between calls.
#[derive(Default)]
pub(super) struct Between {
    sheets: Vec<Sheet>,
    stack: Vec<Piece>,
    parents: Vec<[isize; 3]>,
    clip: Vec<DVec2>,
    clip_next: Vec<DVec2>,
    edges: Vec<(DVec3, DVec3)>,
}

/// The part of convex polygon `poly` (counter-clockwise) left of line (a, b), into `out`.
fn clip_left(poly: &[DVec2], a: DVec2, b: DVec2, out: &mut Vec<DVec2>) {
    out.clear();
    let side = |p: DVec2| (b - a).perp_dot(p - a);
    for (i, &p) in poly.iter().enumerate() {
        let q = poly[(i + 1) % poly.len()];
        let (sp, sq) = (side(p), side(q));
        if sp >= 0.0 {
            out.push(p);
        }
        if (sp >= 0.0) != (sq >= 0.0) {
            out.push(p + (q - p) * (sp / (sp - sq)));
        }
    }
}

fn area2(p: &[DVec2; 3]) -> f64 {
    (p[1] - p[0]).perp_dot(p[2] - p[0])
}

/// Whether 2D segments (a, b) and (c, d) come within `eps` of meeting.
fn segments_meet(a: DVec2, b: DVec2, c: DVec2, d: DVec2, eps: f64) -> bool {
    let side = |p: DVec2, q: DVec2, x: DVec2| {
        let l = (q - p).length().max(f64::MIN_POSITIVE);
        (q - p).perp_dot(x - p) / l
    };
    let (s1, s2) = (side(a, b, c), side(a, b, d));
    let (s3, s4) = (side(c, d, a), side(c, d, b));
    s1.min(s2) <= eps && s1.max(s2) >= -eps && s3.min(s4) <= eps && s3.max(s4) >= -eps
}

impl Proximity<'_> {
    /// Whether every point whose winding number the collapse changes is within `limit` of an
    /// outside voxel's centre (`old`, `new` as in the module comment). None where the
    /// projection does not lay each surface over the plane once (then the tetrahedra decide).
    pub(super) fn between_shallow(
        &mut self,
        work: &mut Between,
        old: &[[DVec3; 3]],
        new: &[[DVec3; 3]],
        limit: f64,
        r_min: f64,
    ) -> Option<bool> {
        if new.is_empty() || old.len() + new.len() > u16::MAX as usize {
            return None;
        }
        let normal = |p: &[DVec3; 3]| (p[1] - p[0]).cross(p[2] - p[0]);
        // The first direction every triangle faces (or stands along): the mean normal of all,
        // of the new ones, of the old ones, then the axis nearest the mean.
        let all = old.iter().chain(new).map(normal).sum::<DVec3>();
        let axis = {
            let j = all.abs().max_position();
            let mut a = DVec3::ZERO;
            a[j] = all[j].signum();
            a
        };
        let candidates = [
            all,
            new.iter().map(normal).sum::<DVec3>(),
            old.iter().map(normal).sum::<DVec3>(),
            axis,
        ];
        let Between {
            sheets,
            stack,
            parents,
            clip,
            clip_next,
            edges,
        } = work;
        let mut found = None;
        'directions: for d in candidates {
            let Some(d) = d.try_normalize() else {
                continue;
            };
            let (e1, e2) = d.any_orthonormal_pair();
            let (e1, e2) = if e1.cross(e2).dot(d) > 0.0 {
                (e1, e2)
            } else {
                (e2, e1)
            };
            let frame = Frame { d, e1, e2 };
            sheets.clear();
            let mut n_new = 0;
            for (k, p) in new.iter().chain(old).enumerate() {
                match frame.sheet(p) {
                    Facing::Sheet(sh) => sheets.push(sh),
                    Facing::Edgewise => {}
                    Facing::Away => continue 'directions,
                }
                if k + 1 == new.len() {
                    n_new = sheets.len();
                }
            }
            found = Some((frame, n_new));
            break;
        }
        let (frame, n_new) = found?;
        // The boundary: edges of one new triangle only, to project to a simple curve.
        edges.clear();
        for p in new {
            for e in 0..3 {
                let (a, b) = (p[e], p[(e + 1) % 3]);
                match edges.iter().position(|&(x, y)| x == b && y == a) {
                    Some(i) => {
                        edges.swap_remove(i);
                    }
                    None => edges.push((a, b)),
                }
            }
        }
        for (i, &(a, b)) in edges.iter().enumerate() {
            for &(c, e) in &edges[i + 1..] {
                let shared = a == c || a == e || b == c || b == e;
                if !shared
                    && segments_meet(
                        frame.flat(a),
                        frame.flat(b),
                        frame.flat(c),
                        frame.flat(e),
                        1e-7,
                    )
                {
                    return None;
                }
            }
        }
        stack.clear();
        parents.clear();
        // The overlay: each new triangle's projection cut by each old one's.
        for n in 0..n_new {
            let sn = sheets[n];
            let mut area = 0.0;
            for (o, so) in sheets.iter().enumerate().skip(n_new) {
                clip.clear();
                clip.extend_from_slice(&sn.corners);
                for e in 0..3 {
                    clip_left(clip, so.corners[e], so.corners[(e + 1) % 3], clip_next);
                    std::mem::swap(clip, clip_next);
                    if clip.len() < 3 {
                        break;
                    }
                }
                for k in 1..clip.len().saturating_sub(1) {
                    let p = [clip[0], clip[k], clip[k + 1]];
                    let a = area2(&p);
                    if a > 0.0 {
                        area += a;
                        stack.push(Piece {
                            corners: p,
                            new: n as u16,
                            old: o as u16,
                            parent: u32::MAX,
                        });
                    }
                }
            }
            let whole = area2(&sn.corners);
            if (area - whole).abs() > 1e-9 * whole {
                return None;
            }
        }
        let reach = limit - ROUNDING;
        let within = |points: &[DVec3; 6], o: [isize; 3]| {
            let c = super::band::centre(o);
            points
                .iter()
                .all(|y| (*y - c).length_squared() <= reach * reach)
        };
        let mut visited = 0;
        while let Some(piece) = stack.pop() {
            visited += 1;
            if visited > NODE_BUDGET {
                return Some(false);
            }
            let p = piece.corners;
            let (sn, so) = (sheets[piece.new as usize], sheets[piece.old as usize]);
            let mut lifted = [DVec3::ZERO; 6];
            for k in 0..3 {
                lifted[k] = frame.lift(p[k], sn.height(p[k]));
                lifted[k + 3] = frame.lift(p[k], so.height(p[k]));
            }
            if piece.parent != u32::MAX && within(&lifted, parents[piece.parent as usize]) {
                continue;
            }
            let c = lifted.iter().sum::<DVec3>() / 6.0;
            let r = lifted
                .iter()
                .map(|y| (*y - c).length_squared())
                .fold(0.0, f64::max)
                .sqrt();
            let near = self.nearest(c);
            let (d_out, _) = near.centre_distances();
            let outside = near
                .pair()
                .map(|(o, _)| o)
                .or((!near.inside).then_some(near.home));
            if d_out + r <= reach
                || (!near.inside && near.dist >= r + ROUNDING)
                || outside.is_some_and(|o| within(&lifted, o))
            {
                continue;
            }
            // c is the midpoint between the planes over P's centroid: in the region when they
            // are apart there.
            let x = (p[0] + p[1] + p[2]) / 3.0;
            if near.inside && d_out > limit && sn.height(x) != so.height(x) {
                return Some(false);
            }
            if r < r_min {
                return Some(false);
            }
            let parent = match outside {
                Some(o) => {
                    parents.push(o);
                    parents.len() as u32 - 1
                }
                None => u32::MAX,
            };
            // Halve at the longest edge: overlay pieces are often slivers.
            let len = |i: usize| (p[(i + 1) % 3] - p[i]).length_squared();
            let e = (0..3)
                .max_by(|&x, &y| len(x).total_cmp(&len(y)))
                .unwrap_or(0);
            let (a, b, c) = (p[e], p[(e + 1) % 3], p[(e + 2) % 3]);
            let m = (a + b) / 2.0;
            for child in [[a, m, c], [m, b, c]] {
                stack.push(Piece {
                    corners: child,
                    parent,
                    ..piece
                });
            }
        }
        Some(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::classify::test_support::random;
    use crate::simplify::band::dist_to_centre;

    /// Winding number of the closed surface `tris` at `p` (solid angles).
    fn winding(tris: &[[DVec3; 3]], p: DVec3) -> f64 {
        let mut sum = 0.0;
        for t in tris {
            let [a, b, c] = t.map(|x| x - p);
            let (la, lb, lc) = (a.length(), b.length(), c.length());
            let num = a.dot(b.cross(c));
            let den = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
            sum += 2.0 * num.atan2(den);
        }
        sum / (4.0 * std::f64::consts::PI)
    }

    /// Random fans over random voxel sets: two cones over one random loop (the old one from a,
    /// the new one from v). Wherever the check accepts, every sampled point whose winding
    /// number the change alters is within the limit of an outside centre (brute force); it
    /// accepts and rejects both, and gives way (None) on folded fans.
    #[test]
    fn accepted_regions_stay_near_the_outside() {
        let (mut accepted, mut rejected, mut declined, mut checked) = (0, 0, 0, 0);
        let mut rng = fastrand::Rng::with_seed(11);
        for seed in 0..4 {
            let cls = random([16, 16, 16], seed);
            let mut prox = Proximity::new(&cls);
            let mut work = Between::default();
            for _ in 0..150 {
                let centre = DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 8.0 + 4.0;
                let size = 0.5 + 3.0 * rng.f64();
                let k = 4 + rng.usize(..5);
                let normal =
                    DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5).normalize();
                let (u, w) = normal.any_orthonormal_pair();
                let ring: Vec<DVec3> = (0..k)
                    .map(|i| {
                        let angle = std::f64::consts::TAU * (i as f64 + 0.3 * rng.f64()) / k as f64;
                        let r = size * (0.6 + 0.4 * rng.f64());
                        centre
                            + (u * angle.cos() + w * angle.sin()) * r
                            + normal * (rng.f64() - 0.5) * size * 0.5
                    })
                    .collect();
                let mut ring = ring;
                if rng.f64() < 0.15 {
                    ring.swap(0, 2); // a folded loop
                }
                let apex = |h: f64| centre + normal * h * size;
                let (a, v) = (apex(rng.f64() - 0.5), apex(rng.f64() - 0.5));
                let cone = |p: DVec3| -> Vec<[DVec3; 3]> {
                    (0..k).map(|i| [p, ring[i], ring[(i + 1) % k]]).collect()
                };
                let (old, new) = (cone(a), cone(v));
                let limit = 1.9;
                match prox.between_shallow(&mut work, &old, &new, limit, 0.05) {
                    None => declined += 1,
                    Some(false) => rejected += 1,
                    Some(true) => {
                        accepted += 1;
                        let closed: Vec<[DVec3; 3]> = old
                            .iter()
                            .copied()
                            .chain(new.iter().map(|t| [t[0], t[2], t[1]]))
                            .collect();
                        let lo = closed
                            .iter()
                            .flatten()
                            .fold(DVec3::INFINITY, |m, p| m.min(*p));
                        let hi = closed
                            .iter()
                            .flatten()
                            .fold(DVec3::NEG_INFINITY, |m, p| m.max(*p));
                        for _ in 0..400 {
                            let p = lo + (hi - lo) * DVec3::new(rng.f64(), rng.f64(), rng.f64());
                            if winding(&closed, p).abs() > 0.5 {
                                checked += 1;
                                assert!(
                                    dist_to_centre(&cls, p, false, limit).is_some(),
                                    "{p} changes its winding number but is farther than {limit} from every outside centre"
                                );
                            }
                        }
                    }
                }
            }
        }
        assert!(
            accepted > 100 && rejected > 20 && declined > 10 && checked > 5000,
            "{accepted} accepted, {rejected} rejected, {declined} declined, {checked} points checked"
        );
    }
}
