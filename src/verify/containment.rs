//! Containment: every point of every posed generator triangle lies inside the mesh, with
//! clearance.
//!
//! A test item is a ball: a set of generator triangles (a BVH node, one triangle, or a piece of
//! one from midpoint subdivision) under a set of poses (a cluster). Its world ball is centred at
//! the reference pose's image of the local centre, with radius σ_max·ρ (or the exact posed
//! radius for a triangle piece) plus the cluster's spread. If no mesh triangle comes within that
//! radius, the ball lies in one connected region off the surface, where the winding number is
//! constant: one winding number at the centre decides every point of every posed triangle in it.
//! Otherwise the item splits (poses, BVH node, or the piece into four) down to pieces whose
//! covering radius is at most `floor` under a single pose; such a piece is "outside" when its
//! centre has w < 1/2. A piece whose centre is inside is certified when a separating axis
//! parts it from each mesh triangle near it by more than its pose's spread (`geom::apart`):
//! then none of its points at any instant meets the surface, so all share the centre's w,
//! whatever the clearance (a mesh that hugs a generator's face over its area, as a flat part
//! swept along a straight path leaves). Otherwise, at distance d from the mesh, it splits on
//! while d is at least the [`finest`] radius (the pieces near its centre can still be
//! certified once their radius is below d), at most `EXTRA_SPLITS` (1,024) times per posed
//! triangle; else it is "too close to certify".

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use glam::DVec3;
use serde::Serialize;

use super::bvh::Bvh;
use super::geom;
use super::poses::{Between, Cluster, PosedPart};
use super::winding::Winding;
use super::Progress;

/// Pieces too close to certify at the floor split on down to floor / 2^this: a clearance 256
/// times finer than the floor is certified.
const EXTRA_LEVELS: i32 = 8;

/// Splits below `floor` allowed per posed triangle (each costs four ball tests). Counted per
/// pose, so the budget does not depend on how the poses cluster. The bundled vibration's output
/// at n = 1500 needs up to 379 for one posed triangle (a generator triangle along the curve
/// where the mesh comes nearest); 1,024 leaves room while bounding a hugging mesh's extra work.
const EXTRA_SPLITS: u32 = 1024;

/// The finest covering radius a piece may be split to below `floor` (see the module's text).
pub fn finest(floor: f64) -> f64 {
    floor * 0.5f64.powi(EXTRA_LEVELS)
}

/// Mesh triangles near a piece that [`Target::apart`] tests before leaving it to splits.
const APART_AT_MOST: usize = 64;

/// Relative widening of every clearance test, against f64 rounding in the distances.
const REL_MARGIN: f64 = 1e-9;

/// The mesh under test, ready for queries.
pub struct Target<'a> {
    pub bvh: &'a Bvh,
    pub winding: &'a Winding<'a>,
    /// Absolute widening of clearance tests (a 1e-12 fraction of the scene size).
    pub abs_margin: f64,
}

impl Target<'_> {
    /// Every point within `r` of `p` is off the mesh surface.
    fn clear(&self, p: DVec3, r: f64) -> bool {
        !self
            .bvh
            .any_within(p, r * (1.0 + REL_MARGIN) + self.abs_margin)
    }

    /// Every point within `r` of triangle `t` is off the mesh surface, proven by a separating
    /// axis against each mesh triangle near it (at most [`APART_AT_MOST`]; else no).
    fn apart(&self, t: &[DVec3; 3], r: f64) -> bool {
        let reach = r * (1.0 + REL_MARGIN) + self.abs_margin;
        let lo = t[0].min(t[1]).min(t[2]) - DVec3::splat(reach);
        let hi = t[0].max(t[1]).max(t[2]) + DVec3::splat(reach);
        let mut near = Vec::new();
        self.bvh.for_each_overlap(lo, hi, |m| near.push(m));
        near.len() <= APART_AT_MOST
            && (near.iter()).all(|&m| geom::apart(t, &self.bvh.tris[m as usize], reach))
    }
}

/// A posed-generator point found outside the mesh.
#[derive(Clone, Debug, Serialize)]
pub struct OutsidePoint {
    /// Distance from the point to the mesh surface, world units.
    pub distance: f64,
    pub point: [f64; 3],
    /// glTF node index and name of the generator part.
    pub node: usize,
    pub node_name: String,
    /// Triangle index within the part's mesh (primitives concatenated in file order).
    pub triangle: u32,
    /// Trajectory row (0-based) and its CSV line; None for a part that no row moves.
    pub pose_row: Option<u32>,
    pub csv_line: Option<u64>,
    /// For continuous motion: the instant is on the way from that row to a later one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub between: Option<Between>,
}

/// Counts are of posed triangles (generator triangle × pose), unless named samples.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Containment {
    pub posed_triangles: u64,
    /// Every point proven inside with clearance.
    pub certified: u64,
    /// Some sample proven outside (w < 1/2).
    pub outside: u64,
    /// Not outside, but some piece at the finest radius could not be proven inside.
    pub too_close: u64,
    /// Balls found outside the mesh (each a point proven outside, with the ball around it).
    pub outside_samples: u64,
    /// Finest-level pieces neither proven inside nor outside.
    pub too_close_samples: u64,
    /// Pieces at the finest level certified by a separating axis from each mesh triangle near
    /// them instead of by a clear ball (a mesh that hugs a generator's face).
    pub separated_samples: u64,
    /// Ball tests made (each an exact distance query on the mesh BVH).
    pub ball_tests: u64,
    /// Winding numbers evaluated.
    pub winding_evaluations: u64,
    /// The farthest outside of the points found outside.
    pub worst_outside: Option<OutsidePoint>,
    /// The search stopped at the first point proven outside (fail fast): the counts cover only
    /// the posed triangles finished by then.
    pub stopped_early: bool,
}

impl Containment {
    pub fn merge(mut self, o: Containment) -> Containment {
        self.posed_triangles += o.posed_triangles;
        self.certified += o.certified;
        self.outside += o.outside;
        self.too_close += o.too_close;
        self.outside_samples += o.outside_samples;
        self.too_close_samples += o.too_close_samples;
        self.separated_samples += o.separated_samples;
        self.ball_tests += o.ball_tests;
        self.winding_evaluations += o.winding_evaluations;
        self.stopped_early |= o.stopped_early;
        self.worst_outside = match (self.worst_outside, o.worst_outside) {
            (Some(a), Some(b)) => Some(if b.distance > a.distance { b } else { a }),
            (a, b) => a.or(b),
        };
        self
    }

    pub fn holds(&self) -> bool {
        self.certified == self.posed_triangles
    }
}

struct Ctx<'a> {
    part: &'a PosedPart,
    target: &'a Target<'a>,
    floor: f64,
    progress: &'a dyn Progress,
    done: &'a AtomicU64,
    total: u64,
    /// Set at the first point proven outside; None: search on and find every failure.
    stop: Option<&'a AtomicBool>,
}

impl Ctx<'_> {
    fn stopped(&self) -> bool {
        self.stop.is_some_and(|s| s.load(Ordering::Relaxed))
    }
    /// A point is proven outside: the certificate fails whatever the rest holds.
    fn found_outside(&self) {
        if let Some(s) = self.stop {
            s.store(true, Ordering::Relaxed);
        }
    }
}

/// Check every posed triangle of `part`. `floor`: the covering radius pieces split to, world
/// units (those inside but nearer the mesh on down to [`finest`]`(floor)`).
/// With `stop`, the search ends soon after a point is proven outside (the flag is shared, so
/// one part's failure stops the others); without it every failure is found and counted.
pub fn check(
    part: &PosedPart,
    target: &Target,
    floor: f64,
    progress: &dyn Progress,
    done: &AtomicU64,
    total: u64,
    stop: Option<&AtomicBool>,
) -> Containment {
    let ctx = Ctx {
        part,
        target,
        floor,
        progress,
        done,
        total,
        stop,
    };
    let mut out = visit(&ctx, 0, 0);
    out.stopped_early = ctx.stopped();
    out
}

const CERTIFIED: u8 = 0;
const TOO_CLOSE: u8 = 1;
const OUTSIDE: u8 = 2;

fn visit(ctx: &Ctx, node: u32, cluster: u32) -> Containment {
    if ctx.stopped() {
        return Containment::default();
    }
    let part = ctx.part;
    let n = &part.bvh.nodes[node as usize];
    let c = &part.tree.clusters[cluster as usize];
    if n.count == 1 {
        let t = part.bvh.order[n.first as usize];
        let out = triangle(ctx, t, cluster);
        report_progress(ctx, out.posed_triangles);
        return out;
    }
    let pose = &part.poses[c.reference as usize];
    let q = pose.matrix.transform_point3(n.centre);
    let spread = c.spread(part.tree.origin, n.centre, n.radius);
    let own = pose.sigma_max * n.radius;
    let count = subtree_tris(part, node) as u64 * c.pose_count() as u64;
    let mut out = Containment {
        ball_tests: 1,
        ..Default::default()
    };
    if ctx.target.clear(q, own + spread) {
        out.posed_triangles = count;
        out.winding_evaluations = 1;
        if ctx.target.winding.at(q) >= 0.5 {
            out.certified = count;
        } else {
            out.outside = count;
            out.outside_samples = 1;
            ctx.found_outside();
            // A real point in the ball: the first triangle's centroid under the reference pose.
            let first = first_triangle(part, node);
            let (lc, _) = geom::ball(&part.bvh.tris[first as usize]);
            out.worst_outside = Some(outside_point(
                ctx,
                pose.matrix.transform_point3(lc),
                first,
                c.reference,
            ));
        }
        report_progress(ctx, count);
        return out;
    }
    let split_poses = !c.is_leaf() && spread > own;
    let (a, b) = if split_poses {
        ((node, c.left), (node, c.right))
    } else {
        ((n.left, cluster), (n.right, cluster))
    };
    let (x, y) = if count > 64 {
        rayon::join(|| visit(ctx, a.0, a.1), || visit(ctx, b.0, b.1))
    } else {
        (visit(ctx, a.0, a.1), visit(ctx, b.0, b.1))
    };
    out.merge(x).merge(y)
}

fn report_progress(ctx: &Ctx, n: u64) {
    let before = ctx.done.fetch_add(n, Ordering::Relaxed);
    // About a thousand updates over the whole check.
    let step = (ctx.total / 1000).max(1);
    if (before + n) / step != before / step {
        ctx.progress.advance(before + n, ctx.total);
    }
}

fn subtree_tris(part: &PosedPart, node: u32) -> u32 {
    let n = &part.bvh.nodes[node as usize];
    if n.count > 0 {
        return n.count;
    }
    // Leaves hold consecutive ranges of `order`: the subtree spans first-leaf..last-leaf.
    let (mut l, mut r) = (n, n);
    while l.count == 0 {
        l = &part.bvh.nodes[l.left as usize];
    }
    while r.count == 0 {
        r = &part.bvh.nodes[r.right as usize];
    }
    r.first + r.count - l.first
}

fn first_triangle(part: &PosedPart, node: u32) -> u32 {
    let mut n = &part.bvh.nodes[node as usize];
    while n.count == 0 {
        n = &part.bvh.nodes[n.left as usize];
    }
    part.bvh.order[n.first as usize]
}

fn outside_point(ctx: &Ctx, p: DVec3, triangle: u32, pose: u32) -> OutsidePoint {
    let pose = &ctx.part.poses[pose as usize];
    OutsidePoint {
        distance: ctx.target.bvh.nearest(p).0,
        point: p.to_array(),
        node: ctx.part.node_index,
        node_name: ctx.part.name.clone(),
        triangle,
        pose_row: pose.row,
        csv_line: pose.line,
        between: pose.between,
    }
}

/// One generator triangle under the poses of `cluster`: pieces and pose sets, with a status
/// per pose (worst over the pieces).
fn triangle(ctx: &Ctx, t: u32, cluster: u32) -> Containment {
    let part = ctx.part;
    let root = &part.tree.clusters[cluster as usize];
    let mut status = vec![CERTIFIED; root.pose_count() as usize];
    let mut out = Containment::default();
    let mut stack: Vec<([DVec3; 3], u32)> = vec![(part.bvh.tris[t as usize], cluster)];
    // Splits below the floor so far, per pose of the root cluster.
    let mut extra_splits = vec![0u32; status.len()];
    while let Some((piece, ci)) = stack.pop() {
        if ctx.stopped() {
            // Unfinished poses prove nothing: count only those already proven outside.
            let outside = status.iter().filter(|s| **s == OUTSIDE).count() as u64;
            out.posed_triangles = outside;
            out.outside = outside;
            return out;
        }
        let c: &Cluster = &part.tree.clusters[ci as usize];
        let pose = &part.poses[c.reference as usize];
        let world = piece.map(|v| pose.matrix.transform_point3(v));
        let (q, own) = geom::ball(&world);
        let (lc, lr) = geom::ball(&piece);
        let spread = c.spread(part.tree.origin, lc, lr);
        let range = (c.lo - root.lo) as usize..(c.hi - root.lo) as usize;
        out.ball_tests += 1;
        let mark = |s: u8, status: &mut Vec<u8>| {
            for x in &mut status[range.clone()] {
                *x = (*x).max(s);
            }
        };
        if ctx.target.clear(q, own + spread) {
            out.winding_evaluations += 1;
            if ctx.target.winding.at(q) < 0.5 {
                mark(OUTSIDE, &mut status);
                out.outside_samples += 1;
                ctx.found_outside();
                let p = outside_point(ctx, q, t, c.reference);
                if out
                    .worst_outside
                    .as_ref()
                    .is_none_or(|w| p.distance > w.distance)
                {
                    out.worst_outside = Some(p);
                }
            }
            continue;
        }
        if !c.is_leaf() && (spread > own || own <= ctx.floor) {
            stack.push((piece, c.left));
            stack.push((piece, c.right));
        } else if own > ctx.floor {
            stack.extend(geom::split4(&piece).map(|p| (p, ci)));
        } else {
            // Finest level under one pose: classify the centre.
            let p = outside_point(ctx, q, t, c.reference);
            let on_surface = p.distance <= ctx.target.abs_margin;
            out.winding_evaluations += !on_surface as u64;
            let inside = !on_surface && ctx.target.winding.at(q) >= 0.5;
            // No mesh triangle meets the piece's points (at every instant its pose stands for,
            // all within `spread`): they form one connected set off the surface, where the
            // winding number is the centre's. Certified at any clearance, without splitting.
            if inside && ctx.target.apart(&world, spread) {
                out.separated_samples += 1;
                continue;
            }
            let finer = own > finest(ctx.floor) && p.distance >= finest(ctx.floor);
            // A piece at the floor is under one pose (a leaf cluster): its budget.
            let budget = &mut extra_splits[range.start];
            if inside && finer && *budget < EXTRA_SPLITS {
                // Inside with some clearance: smaller pieces may still be certified.
                *budget += 1;
                stack.extend(geom::split4(&piece).map(|p| (p, ci)));
            } else if !on_surface && !inside {
                mark(OUTSIDE, &mut status);
                out.outside_samples += 1;
                ctx.found_outside();
                if out
                    .worst_outside
                    .as_ref()
                    .is_none_or(|w| p.distance > w.distance)
                {
                    out.worst_outside = Some(p);
                }
            } else {
                mark(TOO_CLOSE, &mut status);
                out.too_close_samples += 1;
            }
        }
    }
    out.posed_triangles = status.len() as u64;
    for s in status {
        match s {
            CERTIFIED => out.certified += 1,
            TOO_CLOSE => out.too_close += 1,
            _ => out.outside += 1,
        }
    }
    out
}
