//! Ray cast against the δ-offset of one triangle (paper section 4): the prism, three edge
//! cylinders and three vertex balls. This is the CPU twin of `ray_interval` in
//! `shaders/sweep.wgsl`; keep the two in step, formula for formula.
//!
//! Frame: coordinates are grid units (1 = one voxel edge) permuted to (u, v, a) where `a` is the
//! ray's axis and (u, v) its image plane, and translated so that the ray is the `a` axis itself:
//! the ray is {(0, 0, t)}. The offset of a triangle is convex, so the ray meets it in one
//! interval [t0, t1]; the union of the seven pieces is that interval, so it is enough to take
//! the least entry and the greatest exit over the pieces.
//!
//! Robustness: no piece divides by a quantity that vanishes in a degenerate configuration
//! without guarding it, and every candidate depth is evaluated at an explicit point of the
//! offset (a ball centre, a point of an edge, a point of the triangle at distance `d`), so
//! rounding moves a candidate by a few ulps of the coordinates, never by a conditioning factor.
//! The caller inflates the radius by the rounding term ρ (`input::posed::rounding_term`) to absorb that.

/// Interval [t0, t1] along the ray; empty when t0 > t1 (initially +inf, -inf).
use wide::{f32x8, CmpGe, CmpLe, CmpLt};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Interval {
    pub t0: f32,
    pub t1: f32,
}

impl Interval {
    pub const EMPTY: Interval = Interval {
        t0: f32::INFINITY,
        t1: f32::NEG_INFINITY,
    };

    pub fn is_empty(&self) -> bool {
        // Written so that NaN counts as empty.
        self.t0.is_nan() || self.t1.is_nan() || self.t0 > self.t1
    }

    fn add(&mut self, t0: f32, t1: f32) {
        self.t0 = self.t0.min(t0);
        self.t1 = self.t1.max(t1);
    }
}

/// Squared projected edge length (grid units²) below which an edge counts as parallel to the
/// ray. Keeps every quotient below finite. Same constant in the shader.
pub const MIN_PROJECTED_EDGE2: f32 = 1e-20;

/// a·b - c·d with about one rounding error (Kahan's algorithm with fused multiply-adds):
/// cross products of nearly parallel vectors (thin triangles) would otherwise lose most digits.
/// Same as `diff_of_products` in the shader.
pub fn diff_of_products(a: f32, b: f32, c: f32, d: f32) -> f32 {
    let w = c * d;
    let e = (-c).mul_add(d, w);
    let f = a.mul_add(b, -w);
    f + e
}

/// [`diff_of_products`] in eight lanes, bit-identical per lane (fused multiply-adds in hardware
/// where the target has them, else one lane at a time).
fn diff_of_products8(a: f32x8, b: f32x8, c: f32x8, d: f32x8) -> f32x8 {
    #[cfg(target_feature = "fma")]
    {
        let w = c * d;
        let e = (-c).mul_add(d, w);
        let f = a.mul_add(b, -w);
        f + e
    }
    #[cfg(not(target_feature = "fma"))]
    {
        let (a, b, c, d) = (a.to_array(), b.to_array(), c.to_array(), d.to_array());
        f32x8::new(std::array::from_fn(|i| {
            diff_of_products(a[i], b[i], c[i], d[i])
        }))
    }
}

/// The interval where the ray {(0,0,t)} is within distance `d` of triangle `q` (vertices in the
/// ray frame, components (u, v, a)). `d` > 0 in grid units.
pub fn ray_interval(q: [[f32; 3]; 3], d: f32) -> Interval {
    PreparedTriangle::new(q, d).interval_at(0.0, 0.0)
}

/// One posed triangle seen along one axis, with everything that does not depend on the pixel
/// computed once. `interval_at(pu, pv)` is the ray cast for the ray through (pu, pv).
#[derive(Clone, Copy, Debug)]
pub struct PreparedTriangle {
    d2: f32,
    /// Vertices (u, v, a), grid units.
    q: [[f32; 3]; 3],
    /// Edge k runs from q[k] to q[(k+1)%3].
    e: [[f32; 3]; 3],
    /// 1/|e_uv|², or 0 for an edge (nearly) parallel to the ray, whose extremes are its balls.
    inv_e_uv2: [f32; 3],
    /// e_a / (|e| |e_uv|): the optimal edge parameter moves by this times R.
    shift_scale: [f32; 3],
    /// Whether the prism caps can be met (non-degenerate, not edge-on).
    caps: bool,
    /// Entry foot point in the image plane, d·sign(n_a)·n_uv/|n| (the exit foot is its negative).
    foot: [f32; 2],
    /// 1/n_a for the barycentrics.
    inv_na: f32,
    /// d·|n_a|/|n|: the cap's offset along the ray from the triangle's plane.
    cap_shift: f32,
}

impl PreparedTriangle {
    pub fn new(q: [[f32; 3]; 3], d: f32) -> Self {
        let sub = |a: [f32; 3], b: [f32; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let e = [sub(q[1], q[0]), sub(q[2], q[1]), sub(q[0], q[2])];
        let mut inv_e_uv2 = [0.0; 3];
        let mut shift_scale = [0.0; 3];
        for k in 0..3 {
            let e_uv2 = e[k][0] * e[k][0] + e[k][1] * e[k][1];
            if e_uv2 > MIN_PROJECTED_EDGE2 {
                inv_e_uv2[k] = 1.0 / e_uv2;
                let e_len = (e_uv2 + e[k][2] * e[k][2]).sqrt();
                shift_scale[k] = e[k][2] / (e_len * e_uv2.sqrt());
            }
        }
        // Normal from the two edges at q[0] (e2 = q2 - q0 = -e[2]).
        let (e1, e2) = (e[0], sub(q[2], q[0]));
        let n = [
            diff_of_products(e1[1], e2[2], e1[2], e2[1]),
            diff_of_products(e1[2], e2[0], e1[0], e2[2]),
            diff_of_products(e1[0], e2[1], e1[1], e2[0]),
        ];
        let n_len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        let caps = n_len > 0.0 && n[2] != 0.0;
        let (mut foot, mut inv_na, mut cap_shift) = ([0.0; 2], 0.0, 0.0);
        if caps {
            let scale = d * n[2].signum() / n_len;
            foot = [scale * n[0], scale * n[1]];
            inv_na = 1.0 / n[2];
            cap_shift = d * (n[2].abs() / n_len);
        }
        PreparedTriangle {
            d2: d * d,
            q,
            e,
            inv_e_uv2,
            shift_scale,
            caps,
            foot,
            inv_na,
            cap_shift,
        }
    }

    /// The ray cast for the ray through image-plane point (pu, pv).
    pub fn interval_at(&self, pu: f32, pv: f32) -> Interval {
        let d2 = self.d2;
        let mut out = Interval::EMPTY;
        // Vertices relative to the ray.
        let rel = self.q.map(|p| [p[0] - pu, p[1] - pv]);

        // Vertex balls: the ray meets B_d(q) where u²+v² <= d².
        for (r, q) in rel.iter().zip(&self.q) {
            let r2 = r[0] * r[0] + r[1] * r[1];
            if r2 <= d2 {
                let s = (d2 - r2).sqrt();
                out.add(q[2] - s, q[2] + s);
            }
        }

        // Edge cylinders (lateral surface). Along the edge a + s·e, s in [0, 1], the ray points
        // within d of the edge point form [a_a + s e_a - w(s), a_a + s e_a + w(s)] with
        // w(s) = sqrt(d² - |a_uv + s e_uv|²). Entry and exit are extremes of these convex/concave
        // functions of s; their unconstrained optima are s* ∓ R e_a / (|e| |e_uv|) with s* the
        // closest approach in the image plane and R = sqrt(d² - m²), m the distance from the ray
        // to the projected line. Clamping to [0, 1] gives the constrained optimum (at an end it is
        // the ball's value). Whatever rounding does to s, the depth is evaluated at that s
        // exactly, so it is a point within d of the edge: at worst suboptimal by O(error²).
        for (k, &a) in rel.iter().enumerate() {
            let inv = self.inv_e_uv2[k];
            if inv == 0.0 {
                continue;
            }
            let e = self.e[k];
            let c = a[0] * e[1] - a[1] * e[0];
            let m2 = c * c * inv;
            if m2 >= d2 {
                continue;
            }
            let shift = (d2 - m2).sqrt() * self.shift_scale[k];
            let s_star = -(a[0] * e[0] + a[1] * e[1]) * inv;
            for (s_opt, sign) in [(s_star - shift, -1.0f32), (s_star + shift, 1.0f32)] {
                // An unclamped optimum is within d of the ray exactly (ρ(s*)² < d²); near an
                // edge almost parallel to the ray rounding can still push rho2 past d2, so it is
                // taken regardless. A clamped one is the end's ball, taken when within d.
                let unclamped = (0.0..=1.0).contains(&s_opt);
                let s = s_opt.clamp(0.0, 1.0);
                let pu = a[0] + s * e[0];
                let pv = a[1] + s * e[1];
                let rho2 = pu * pu + pv * pv;
                if unclamped || rho2 <= d2 {
                    let t = self.q[k][2] + s * e[2] + sign * (d2 - rho2).max(0.0).sqrt();
                    out.add(t, t);
                }
            }
        }

        // Prism caps T ± d·n. A cap point is y + λn with y in T and |λ| = d; on the ray its
        // image-plane part is 0, so y_uv = -λ n_uv. Entry takes λ n_a = -d|n_a|, exit +d|n_a|.
        // The foot y_uv is tested against the projected triangle by barycentrics;
        // y_a = Σ β_i q_i,a with all β >= 0, so the depth is that of a point of the prism. Feet
        // just outside T are left to the cylinders, whose surface the cap border lies on.
        if self.caps {
            let (e1, e2) = (self.e[0], [-self.e[2][0], -self.e[2][1], -self.e[2][2]]);
            for (side, dir) in [(1.0f32, -1.0f32), (-1.0f32, 1.0f32)] {
                let g = [
                    side * self.foot[0] - rel[0][0],
                    side * self.foot[1] - rel[0][1],
                ];
                let b1 = diff_of_products(g[0], e2[1], g[1], e2[0]) * self.inv_na;
                let b2 = diff_of_products(e1[0], g[1], e1[1], g[0]) * self.inv_na;
                if b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0 {
                    let y_a = self.q[0][2] + b1 * e1[2] + b2 * e2[2];
                    let t = y_a + dir * self.cap_shift;
                    out.add(t, t);
                }
            }
        }
        out
    }
}

impl PreparedTriangle {
    /// [`interval_at`](Self::interval_at) for the 8 rays through (pu\[i\], pv), i = 0..8: the same
    /// IEEE operations in the same order in every lane, with masks for the branches, so each
    /// lane's result is bit-identical to the scalar one (a test checks it). Lanes that miss are
    /// empty (t0 = +inf, t1 = -inf).
    pub fn interval_at_x8(&self, pu: f32x8, pv: f32) -> (f32x8, f32x8) {
        let zero = f32x8::ZERO;
        let d2 = f32x8::splat(self.d2);
        let mut t0 = f32x8::splat(f32::INFINITY);
        let mut t1 = f32x8::splat(f32::NEG_INFINITY);
        let rel_u = self.q.map(|p| f32x8::splat(p[0]) - pu);
        let rel_v = self.q.map(|p| f32x8::splat(p[1] - pv));
        let qa = self.q.map(|p| f32x8::splat(p[2]));

        for k in 0..3 {
            let r2 = rel_u[k] * rel_u[k] + rel_v[k] * rel_v[k];
            let hit = r2.cmp_le(d2);
            let s = (d2 - r2).fast_max(zero).sqrt();
            t0 = hit.blend(t0.fast_min(qa[k] - s), t0);
            t1 = hit.blend(t1.fast_max(qa[k] + s), t1);
        }

        for k in 0..3 {
            let inv = self.inv_e_uv2[k];
            if inv == 0.0 {
                continue;
            }
            let (a_u, a_v) = (rel_u[k], rel_v[k]);
            let e = self.e[k].map(f32x8::splat);
            let inv = f32x8::splat(inv);
            let c = a_u * e[1] - a_v * e[0];
            let m2 = c * c * inv;
            let near = m2.cmp_lt(d2);
            if near.none() {
                continue;
            }
            let shift = (d2 - m2).fast_max(zero).sqrt() * f32x8::splat(self.shift_scale[k]);
            let s_star = -(a_u * e[0] + a_v * e[1]) * inv;
            for (s_opt, sign) in [(s_star - shift, -1.0f32), (s_star + shift, 1.0f32)] {
                let unclamped = s_opt.cmp_ge(zero) & s_opt.cmp_le(f32x8::ONE);
                let s = s_opt.fast_max(zero).fast_min(f32x8::ONE);
                let pu = a_u + s * e[0];
                let pv = a_v + s * e[1];
                let rho2 = pu * pu + pv * pv;
                let hit = near & (unclamped | rho2.cmp_le(d2));
                let t = qa[k] + s * e[2] + f32x8::splat(sign) * (d2 - rho2).fast_max(zero).sqrt();
                t0 = hit.blend(t0.fast_min(t), t0);
                t1 = hit.blend(t1.fast_max(t), t1);
            }
        }

        if self.caps {
            let e1 = self.e[0].map(f32x8::splat);
            let e2 = self.e[2].map(|c| f32x8::splat(-c));
            let inv_na = f32x8::splat(self.inv_na);
            for (side, dir) in [(1.0f32, -1.0f32), (-1.0f32, 1.0f32)] {
                let g_u = f32x8::splat(side * self.foot[0]) - rel_u[0];
                let g_v = f32x8::splat(side * self.foot[1]) - rel_v[0];
                let b1 = diff_of_products8(g_u, e2[1], g_v, e2[0]) * inv_na;
                let b2 = diff_of_products8(e1[0], g_v, e1[1], g_u) * inv_na;
                let hit = b1.cmp_ge(zero) & b2.cmp_ge(zero) & (b1 + b2).cmp_le(f32x8::ONE);
                let y_a = qa[0] + b1 * e1[2] + b2 * e2[2];
                let t = y_a + f32x8::splat(dir * self.cap_shift);
                t0 = hit.blend(t0.fast_min(t), t0);
                t1 = hit.blend(t1.fast_max(t), t1);
            }
        }
        (t0, t1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eight_lanes_equal_the_scalar_ray_cast_bit_for_bit() {
        let mut rng = fastrand::Rng::with_seed(0x1234_5678_9abc_def0);
        let mut rnd = |lo: f32, hi: f32| lo + (hi - lo) * rng.f32();
        let mut hits = 0;
        for case in 0..20_000 {
            let mut q = [[0f32; 3]; 3];
            for v in q.iter_mut() {
                *v = [rnd(0.0, 12.0), rnd(0.0, 12.0), rnd(100.0, 110.0)];
            }
            match case % 4 {
                0 => q[1] = q[0],
                1 => q[2][2] = q[0][2] + (q[2][0] - q[0][0]) * 1e-6,
                _ => {}
            }
            let tri = PreparedTriangle::new(q, rnd(0.5, 3.0));
            let pv = rnd(0.0, 12.0).floor() + 0.5;
            let u0 = rnd(0.0, 8.0).floor() + 0.5;
            let pu = f32x8::new(std::array::from_fn(|i| u0 + i as f32));
            let (t0, t1) = tri.interval_at_x8(pu, pv);
            for (i, (a, b)) in t0.to_array().into_iter().zip(t1.to_array()).enumerate() {
                let s = tri.interval_at(u0 + i as f32, pv);
                assert_eq!(
                    (a.to_bits(), b.to_bits()),
                    (s.t0.to_bits(), s.t1.to_bits()),
                    "case {case} lane {i}"
                );
                hits += usize::from(!s.is_empty());
            }
        }
        assert!(hits > 10_000, "{hits}");
    }

    #[test]
    fn triangle_seen_along_its_normal() {
        // Triangle in the plane a = 5, ray through its interior: prism caps at 5 ± d.
        let q = [[-1.0, -1.0, 5.0], [3.0, -1.0, 5.0], [-1.0, 3.0, 5.0]];
        let i = ray_interval(q, 2.0);
        assert_eq!((i.t0, i.t1), (3.0, 7.0));
    }

    #[test]
    fn point_triangle_is_a_ball() {
        let q = [[0.6, 0.8, 2.0]; 3];
        let i = ray_interval(q, 2.0);
        let s = (4.0f32 - 1.0).sqrt();
        assert!((i.t0 - (2.0 - s)).abs() < 1e-6 && (i.t1 - (2.0 + s)).abs() < 1e-6);
        assert!(ray_interval(q, 0.9).is_empty());
    }

    #[test]
    fn edge_across_the_ray_is_a_cylinder() {
        // Segment along u at a = 1, v = 0.5, ray at the origin: cylinder of radius 1.
        let q = [[-4.0, 0.5, 1.0], [4.0, 0.5, 1.0], [4.0, 0.5, 1.0]];
        let i = ray_interval(q, 1.0);
        let s = (1.0f32 - 0.25).sqrt();
        assert!((i.t0 - (1.0 - s)).abs() < 1e-6 && (i.t1 - (1.0 + s)).abs() < 1e-6);
    }
}
