//! Pockets: where the mesh strays farther than a bound B from the swept volume, is that place
//! hidden from all six axis directions?
//!
//! `sweptvol run` states its Hausdorff bound B only where the swept volume's concavities are
//! visible along an axis. The precise, checkable form of that statement: **every mesh point x
//! either lies within B of the swept volume, or each of its six axis rays (±x, ±y, ±z) comes
//! within B of it.** (Proof sketch: x is within ε of an inside voxel whose centre c is within
//! ε + √3h/2 of x; c is inside because every axis ray from c meets the δ-offset (condition ⋆),
//! and c's ray runs parallel to x's at that distance; so x's ray comes within ε + √3h/2 + δ + 2ρ
//! = B of the volume.) A point beyond B with an escaping ray would be a broken promise of `run`.
//!
//! For a mesh piece (centre c, covering radius r) beyond B, this module proves one of:
//! - *hidden*: each of c's six rays comes within B - 2r of the posed surfaces. Then every point
//!   x of the piece has all six rays within B, or is itself within B (a point of c's ray at
//!   parameter s is within r of x's ray at s - (x-c)·a when that is >= 0, and within 2r of x
//!   otherwise);
//! - *visible*: c is farther than B from every posed surface and one of its rays stays farther
//!   than B from them all the way out of the volume's bounding box (a counterexample);
//! - neither, after splitting the piece a few times more: *undetermined*.
//!
//! Rays are sphere-traced: at a ray point q with proven distance d > B' to the posed surfaces,
//! the ball of radius d - B' around q holds no point within B' of them, so the ray advances by
//! d - B'. Distances are to the posed *surfaces*; a ray that enters the solid crosses its
//! surface, so it cannot pass through unnoticed.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;

use super::geom;
use super::nearest::{self, Frames, Scratch};
use super::poses::PosedPart;
use super::Progress;

/// Sphere-tracing steps per ray before the ray counts as undetermined.
const MAX_STEPS: u32 = 20_000;
/// Pieces neither hidden nor visible split down to the deviation's spacing / 2^this.
const EXTRA_LEVELS: i32 = 3;

/// How one axis ray from a point ends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ray {
    /// Comes within the threshold of a posed surface.
    Blocked,
    /// Leaves the volume's bounding box (grown by the threshold) without coming that close.
    Escapes,
    /// Grazes: `MAX_STEPS` steps were not enough to decide.
    Undetermined,
}

/// A point beyond B with an axis ray that escapes: a place where `run`'s bound is broken.
#[derive(Clone, Debug, Serialize)]
pub struct VisiblePlace {
    pub point: [f64; 3],
    pub mesh_triangle: u32,
    /// Proven lower bound of the point's distance to the posed surfaces (> B).
    pub distance: f64,
    /// The escaping direction, e.g. "+x".
    pub direction: String,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct Pockets {
    /// The bound B the pieces were tested against, world units.
    pub bound: f64,
    /// Mesh pieces (of any size) settled beyond B: hidden + visible + undetermined.
    pub pieces_beyond: u64,
    /// Pieces proven hidden from all six axis directions.
    pub hidden: u64,
    /// Pieces with a point beyond B that sees out along an axis (the search stops at the
    /// first, so 0 or 1).
    pub visible: u64,
    /// Pieces neither proven hidden nor visible at the finest size.
    pub undetermined: u64,
    /// Rays traced and sphere-tracing steps taken.
    pub rays: u64,
    pub steps: u64,
    pub first_visible: Option<VisiblePlace>,
}

impl Pockets {
    fn merge(mut self, o: Pockets) -> Pockets {
        self.bound = self.bound.max(o.bound);
        self.pieces_beyond += o.pieces_beyond;
        self.hidden += o.hidden;
        self.visible += o.visible;
        self.undetermined += o.undetermined;
        self.rays += o.rays;
        self.steps += o.steps;
        self.first_visible = self.first_visible.or(o.first_visible);
        self
    }

    /// Every piece beyond B is hidden from all six axes: `run`'s bound holds in its scope.
    pub fn holds(&self) -> bool {
        self.visible == 0 && self.undetermined == 0
    }
}

const DIRECTIONS: [(usize, f64, &str); 6] = [
    (0, 1.0, "+x"),
    (0, -1.0, "-x"),
    (1, 1.0, "+y"),
    (1, -1.0, "-y"),
    (2, 1.0, "+z"),
    (2, -1.0, "-z"),
];

/// The searcher and the volume's box, shared by all rays.
struct Tracer<'a> {
    parts: &'a [PosedPart],
    frames: Vec<Frames>,
    /// Box of every posed surface point (from the BVH root balls of every pose).
    lo: DVec3,
    hi: DVec3,
}

impl<'a> Tracer<'a> {
    fn new(parts: &'a [PosedPart]) -> Tracer<'a> {
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for part in parts {
            let root = &part.bvh.nodes[0];
            for pose in &part.poses {
                let c = pose.matrix.transform_point3(root.centre);
                // Widened against the rounding of the transform.
                let r = pose.sigma_max * root.radius * (1.0 + 1e-9) + 1e-12 * c.abs().max_element();
                lo = lo.min(c - DVec3::splat(r));
                hi = hi.max(c + DVec3::splat(r));
            }
        }
        Tracer {
            parts,
            frames: parts.iter().map(Frames::new).collect(),
            lo,
            hi,
        }
    }

    /// Proven distance interval at `p` when it exceeds `threshold`: (found, lower bound); None
    /// when a posed triangle lies within `threshold`.
    fn clear(&self, s: &mut Scratch, p: DVec3, threshold: f64, tol: f64) -> Option<(f64, f64)> {
        let (hit, lower) = nearest::nearest(self.parts, &self.frames, s, p, threshold, tol);
        (hit.dist > threshold).then_some((hit.dist, lower))
    }

    /// Sphere-trace the ray from `o` along axis `axis`, direction `sign`: Blocked when a ray
    /// point is found within `t + slack` of a posed surface, Escapes when every ray point is
    /// proven farther than `t`. Each step advances at least slack/2 (`slack` > 0), so grazing
    /// rays end too, as Undetermined after `MAX_STEPS`.
    fn trace(
        &self,
        s: &mut Scratch,
        o: DVec3,
        axis: usize,
        sign: f64,
        t: f64,
        slack: f64,
    ) -> (Ray, u32) {
        let mut along = 0.0;
        let mut tol = t.abs();
        for step in 0..MAX_STEPS {
            let mut q = o;
            q[axis] += sign * along;
            // Past the box (grown by t) along the ray's axis, nothing is within t any more.
            if (sign > 0.0 && q[axis] > self.hi[axis] + t)
                || (sign < 0.0 && q[axis] < self.lo[axis] - t)
            {
                return (Ray::Escapes, step);
            }
            let Some((d, mut lower)) = self.clear(s, q, t + slack, tol) else {
                return (Ray::Blocked, step);
            };
            if lower - t < 0.5 * (d - t) {
                // The candidate is far but the proof is loose: search exactly.
                match self.clear(s, q, t + slack, 0.0) {
                    None => return (Ray::Blocked, step),
                    Some((_, l)) => lower = l,
                }
            }
            // Within `lower - t` of q every point is at least t from the surfaces, and strictly
            // farther within a hair less. Aim the next search's tolerance at a quarter of the
            // clearance.
            tol = 0.25 * (d - t);
            along += (lower - t) * (1.0 - 1e-9);
        }
        (Ray::Undetermined, MAX_STEPS)
    }
}

/// Find the mesh's pieces farther than `bound` from the posed surfaces and settle each: hidden
/// from all six axes, or visible (a counterexample; the search stops at the first), or
/// undetermined. A piece that cannot be settled splits 1:4, down to covering radius
/// `spacing` / 2^EXTRA_LEVELS; counterexamples are looked for once pieces reach `spacing`.
pub fn classify(
    parts: &[PosedPart],
    tris: &[[DVec3; 3]],
    bound: f64,
    reach: f64,
    spacing: f64,
    progress: &dyn Progress,
) -> Pockets {
    let tracer = Tracer::new(parts);
    let stop = AtomicBool::new(false);
    let done = AtomicU64::new(0);
    let total = tris.len() as u64;
    let finest = finest(spacing);
    let mut out = tris
        .par_iter()
        .enumerate()
        .map_init(Scratch::default, |s, (ti, tri)| {
            let mut out = Pockets::default();
            let mut stack = vec![*tri];
            while let Some(piece) = stack.pop() {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                match settle(&tracer, s, &piece, bound, reach, spacing, &mut out) {
                    Settled::Within => {}
                    Settled::Hidden => out.hidden += 1,
                    Settled::Visible(place) => {
                        out.visible += 1;
                        out.first_visible = Some(VisiblePlace {
                            mesh_triangle: ti as u32,
                            ..place
                        });
                        stop.store(true, Ordering::Relaxed);
                    }
                    Settled::Open if geom::ball(&piece).1 > finest => {
                        stack.extend(geom::split4(&piece))
                    }
                    Settled::Open => out.undetermined += 1,
                }
            }
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            if d % 64 == 0 || d == total {
                progress.advance(d, total);
            }
            out
        })
        .reduce(Pockets::default, Pockets::merge);
    out.bound = bound;
    out.pieces_beyond = out.hidden + out.visible + out.undetermined;
    out
}

/// Covering radius below which pieces are not split further.
pub fn finest(spacing: f64) -> f64 {
    spacing * 0.5f64.powi(EXTRA_LEVELS)
}

enum Settled {
    /// Every point of the piece is within the bound.
    Within,
    Hidden,
    Visible(VisiblePlace),
    /// Neither, at this size.
    Open,
}

/// Decide one piece (centre c, covering radius r). `reach`: how far an instant of the motion
/// may be from the posed surfaces (the middle poses' reach for screw motion, 0 for discrete):
/// nearness to a posed surface is nearness to the swept volume, but farness from every posed
/// surface proves farness from the swept volume only beyond the reach.
fn settle(
    tracer: &Tracer,
    s: &mut Scratch,
    tri: &[DVec3; 3],
    bound: f64,
    reach: f64,
    spacing: f64,
    out: &mut Pockets,
) -> Settled {
    let (c, r) = geom::ball(tri);
    // Every point is within dist(c) + r (exact distances below the deviation's spacing).
    let tol = if r <= spacing { 0.0 } else { spacing };
    let Some((found, _)) = tracer.clear(s, c, bound - r, tol) else {
        return Settled::Within;
    };
    if found + r <= bound {
        return Settled::Within;
    }
    // Above the deviation's spacing, only pieces whose centre is beyond B try rays (the
    // others split: they are mostly within B, and rays that escape are long to trace).
    if r > spacing && found - tol <= bound {
        return Settled::Open;
    }
    // Hidden: all six rays of c come within B - 2r (proofs of "blocked" may overshoot their
    // threshold by `slack`).
    let slack = 0.01 * r;
    let t = bound - 2.0 * r - slack;
    if t > 0.0 {
        let mut blocked = 0;
        for (axis, sign, _) in DIRECTIONS {
            let (ray, steps) = tracer.trace(s, c, axis, sign, t, slack);
            out.rays += 1;
            out.steps += steps as u64;
            if ray != Ray::Blocked {
                break;
            }
            blocked += 1;
        }
        if blocked == DIRECTIONS.len() {
            return Settled::Hidden;
        }
    }
    // A counterexample: c itself beyond B (exactly, the motion's reach included) with a ray
    // that escapes as far.
    if r <= spacing {
        if let Some((dist, _)) = tracer.clear(s, c, bound + reach, 0.0) {
            for (axis, sign, name) in DIRECTIONS {
                let (ray, steps) = tracer.trace(s, c, axis, sign, bound + reach, slack);
                out.rays += 1;
                out.steps += steps as u64;
                if ray == Ray::Escapes {
                    return Settled::Visible(VisiblePlace {
                        point: c.to_array(),
                        mesh_triangle: 0,
                        distance: dist - reach,
                        direction: name.to_string(),
                    });
                }
            }
        }
    }
    Settled::Open
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::verify::poses::PartPose;
    use crate::verify::Silent;
    use glam::DMat4;

    /// One part at one pose (identity): the triangles of the boxes [lo, hi].
    fn boxes(list: &[([f64; 3], [f64; 3])]) -> [PosedPart; 1] {
        let tris = list
            .iter()
            .flat_map(|(lo, hi)| geom::box_triangles(DVec3::from(*lo), DVec3::from(*hi)))
            .collect();
        let poses = vec![PartPose::new(DMat4::IDENTITY, Some(0), Some(2))];
        [PosedPart::new(0, "p".into(), tris, poses)]
    }

    /// Classify one tiny mesh piece (radius ~1e-4) around `p` against `bound`.
    fn classify_at(parts: &[PosedPart], p: [f64; 3], bound: f64) -> Pockets {
        classify_within(parts, p, bound, 0.0)
    }

    /// The same with posed surfaces that are instants of a motion up to `reach` apart.
    fn classify_within(parts: &[PosedPart], p: [f64; 3], bound: f64, reach: f64) -> Pockets {
        let (p, e) = (DVec3::from(p), 1e-4);
        let piece = [
            p + DVec3::new(e, 0.0, 0.0),
            p + DVec3::new(-e, e, 0.0),
            p + DVec3::new(-e, -e, 0.0),
        ];
        classify(parts, &[piece], bound, reach, 1e-3, &Silent)
    }

    #[test]
    fn a_point_inside_a_closed_box_is_hidden_and_one_outside_is_visible() {
        // Hollow box surface [0,4]³: its centre is 2 from every face, so beyond B = 1, and every
        // axis ray meets a face. A point 2 outside the box has a ray straight away from it.
        let parts = boxes(&[([0.0; 3], [4.0; 3])]);
        let p = classify_at(&parts, [2.0; 3], 1.0);
        assert_eq!((p.pieces_beyond, p.hidden, p.visible), (1, 1, 0), "{p:?}");
        assert!(p.holds());

        let p = classify_at(&parts, [6.0, 2.0, 2.0], 1.0);
        assert_eq!((p.hidden, p.visible, p.undetermined), (0, 1, 0), "{p:?}");
        let v = p.first_visible.as_ref().expect("a visible place");
        assert_eq!(v.direction, "+x");
        assert!((v.distance - 2.0).abs() < 1e-3, "{v:?}");
        assert!(!p.holds());

        // The same surfaces as middle poses of a motion whose instants may lie 1.5 nearer: 2 from
        // them no longer proves the point farther than B = 1 from the swept volume; 0.5 does.
        let p = classify_within(&parts, [6.0, 2.0, 2.0], 1.0, 1.5);
        assert_eq!((p.hidden, p.visible), (0, 0), "{p:?}");
        assert!(p.undetermined > 0 && !p.holds(), "{p:?}");
        let p = classify_within(&parts, [6.0, 2.0, 2.0], 1.0, 0.5);
        let v = p.first_visible.as_ref().expect("a visible place");
        assert!((v.distance - 1.5).abs() < 1e-3, "{v:?}");
    }

    #[test]
    fn a_slot_open_along_one_axis_is_visible_only_through_that_axis() {
        // Two slabs x in [0,1] and [3,4] (y, z in [0,10]) leave a slot between them, open
        // along ±y and ±z. The slot's middle (2, 5, 5) is 1 from both slabs.
        let slabs = [
            ([0.0, 0.0, 0.0], [1.0, 10.0, 10.0]),
            ([3.0, 0.0, 0.0], [4.0, 10.0, 10.0]),
        ];
        // B = 0.5: the slot's middle is beyond it and sees out along y and z.
        let p = classify_at(&boxes(&slabs), [2.0, 5.0, 5.0], 0.5);
        assert_eq!(p.visible, 1, "{p:?}");
        let dir = p.first_visible.unwrap().direction;
        assert!(["+y", "-y", "+z", "-z"].contains(&dir.as_str()), "{dir}");
        // Closing the slot's ends with caps along y and z hides it.
        let caps = [
            ([1.0, -1.0, 0.0], [3.0, 0.0, 10.0]),
            ([1.0, 10.0, 0.0], [3.0, 11.0, 10.0]),
            ([1.0, 0.0, -1.0], [3.0, 10.0, 0.0]),
            ([1.0, 0.0, 10.0], [3.0, 10.0, 11.0]),
        ];
        let p = classify_at(
            &boxes(&[&slabs[..], &caps[..]].concat()),
            [2.0, 5.0, 5.0],
            0.5,
        );
        assert_eq!((p.hidden, p.visible), (1, 0), "{p:?}");
    }

    #[test]
    fn rays_end_the_way_a_brute_force_march_says() {
        // Random small triangles; rays from random points, threshold t. The brute force
        // marches at a step of t/8 with exact distances to every triangle and decides with
        // margins: a ray whose closest approach (sampled) is below 0.9 t is blocked; one that
        // stays above 1.1 t (sampled, plus the step's reach) escapes.
        let mut rng = geom::Rng::with_seed(11);
        let mut tris = Vec::new();
        for _ in 0..60 {
            let c = geom::cube_point(&mut rng, 8.0);
            tris.push([
                c,
                c + geom::cube_point(&mut rng, 0.6),
                c + geom::cube_point(&mut rng, 0.6),
            ]);
        }
        let poses = vec![PartPose::new(DMat4::IDENTITY, Some(0), Some(2))];
        let parts = [PosedPart::new(0, "p".into(), tris.clone(), poses)];
        let tracer = Tracer::new(&parts);
        let mut s = Scratch::default();
        let t = 0.3;
        let dist = |p: DVec3| {
            tris.iter()
                .map(|x| geom::dist_triangle(p, x[0], x[1], x[2]))
                .fold(f64::INFINITY, f64::min)
        };
        let mut checked = 0;
        for _ in 0..300 {
            let o = geom::cube_point(&mut rng, 8.0);
            let (axis, sign, _) = DIRECTIONS[(rng.f64() * 6.0) as usize % 6];
            let mut closest = f64::INFINITY;
            let mut k = 0.0;
            loop {
                let mut q = o;
                q[axis] += sign * k;
                closest = closest.min(dist(q));
                if q[axis] > 12.0 || q[axis] < -12.0 {
                    break;
                }
                k += t / 8.0;
            }
            let (ray, _) = tracer.trace(&mut s, o, axis, sign, t, 1e-6);
            if closest < 0.9 * t {
                assert_eq!(ray, Ray::Blocked, "closest {closest}");
                checked += 1;
            } else if closest > 1.1 * t + t / 16.0 {
                assert_eq!(ray, Ray::Escapes, "closest {closest}");
                checked += 1;
            }
        }
        assert!(
            checked > 200,
            "only {checked} rays were decided by the march"
        );
    }
}
