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
//! The caller inflates the radius by the rounding term of `bounds::RoundingBound` to absorb that.

/// Interval [t0, t1] along the ray; empty when t0 > t1 (initially +inf, -inf).
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

fn cross2(a: [f32; 2], b: [f32; 2]) -> f32 {
    a[0] * b[1] - a[1] * b[0]
}

fn dot2(a: [f32; 2], b: [f32; 2]) -> f32 {
    a[0] * b[0] + a[1] * b[1]
}

/// The interval where the ray {(0,0,t)} is within distance `d` of triangle `q` (vertices in the
/// ray frame, components (u, v, a)). `d` > 0 in grid units.
pub fn ray_interval(q: [[f32; 3]; 3], d: f32) -> Interval {
    let d2 = d * d;
    let mut out = Interval::EMPTY;

    // Vertex balls: the ray meets B_d(q) where u²+v² <= d².
    for p in q {
        let r2 = p[0] * p[0] + p[1] * p[1];
        if r2 <= d2 {
            let s = (d2 - r2).sqrt();
            out.add(p[2] - s, p[2] + s);
        }
    }

    // Edge cylinders (lateral surface). Along the edge a + s·e, s in [0, 1], the ray points
    // within d of the edge point form [a_a + s e_a - w(s), a_a + s e_a + w(s)] with
    // w(s) = sqrt(d² - |a_uv + s e_uv|²). Entry and exit are extremes of these convex/concave
    // functions of s; their unconstrained optima are s* ∓ R e_a / (|e| |e_uv|) with s* the
    // closest approach in the image plane and R = sqrt(d² - m²), m the distance from the ray to
    // the projected line. Clamping to [0, 1] gives the constrained optimum (at an end it is the
    // ball's value). Whatever rounding does to s, the depth is evaluated at that s exactly, so it
    // is a point within d of the edge: at worst slightly suboptimal, by O(error²).
    for (i, j) in [(0usize, 1usize), (1, 2), (2, 0)] {
        let a = q[i];
        let e = [q[j][0] - a[0], q[j][1] - a[1], q[j][2] - a[2]];
        let e_uv2 = e[0] * e[0] + e[1] * e[1];
        if e_uv2 <= MIN_PROJECTED_EDGE2 {
            // Parallel to the ray (or a point): the balls at both ends give the extremes. An edge
            // this close to parallel has its lateral extremes within 1e-10 of its ends.
            continue;
        }
        let a_uv = [a[0], a[1]];
        let e_uv = [e[0], e[1]];
        let c = cross2(a_uv, e_uv);
        let m2 = c * c / e_uv2;
        if m2 >= d2 {
            continue;
        }
        let r = (d2 - m2).sqrt();
        let e_len = (e_uv2 + e[2] * e[2]).sqrt();
        let s_star = -dot2(a_uv, e_uv) / e_uv2;
        let shift = r * e[2] / (e_len * e_uv2.sqrt());
        for (s, sign) in [(s_star - shift, -1.0f32), (s_star + shift, 1.0f32)] {
            let s = s.clamp(0.0, 1.0);
            let pu = a[0] + s * e[0];
            let pv = a[1] + s * e[1];
            let rho2 = pu * pu + pv * pv;
            if rho2 <= d2 {
                let t = a[2] + s * e[2] + sign * (d2 - rho2).sqrt();
                out.add(t, t);
            }
        }
    }

    // Prism caps T ± d·n. A cap point is y + λn with y in T and |λ| = d; on the ray its image-plane
    // part is 0, so y_uv = -λ n_uv. Entry takes λ n_a = -d|n_a|, exit +d|n_a|. The foot y_uv is
    // tested against the projected triangle by barycentrics; y_a = Σ β_i q_i,a with all β >= 0,
    // so the depth is that of a point of the prism. Feet just outside T are left
    // to the cylinders, whose surface the cap border lies on.
    let e1 = [q[1][0] - q[0][0], q[1][1] - q[0][1], q[1][2] - q[0][2]];
    let e2 = [q[2][0] - q[0][0], q[2][1] - q[0][1], q[2][2] - q[0][2]];
    let n = [
        e1[1] * e2[2] - e1[2] * e2[1],
        e1[2] * e2[0] - e1[0] * e2[2],
        e1[0] * e2[1] - e1[1] * e2[0],
    ];
    let n_len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    // n[2] is also twice the signed area of the projected triangle.
    if n_len > 0.0 && n[2] != 0.0 {
        let sgn = if n[2] > 0.0 { 1.0f32 } else { -1.0f32 };
        let na_abs = n[2].abs() / n_len;
        let foot_scale = d * sgn / n_len;
        for (side, dir) in [(1.0f32, -1.0f32), (-1.0f32, 1.0f32)] {
            // Entry: foot = d·sign(n_a)·n_uv; exit: the opposite foot.
            let f = [side * foot_scale * n[0], side * foot_scale * n[1]];
            let g = [f[0] - q[0][0], f[1] - q[0][1]];
            let b1 = cross2(g, [e2[0], e2[1]]) / n[2];
            let b2 = cross2([e1[0], e1[1]], g) / n[2];
            if b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0 {
                let y_a = q[0][2] + b1 * e1[2] + b2 * e2[2];
                let t = y_a + dir * d * na_abs;
                out.add(t, t);
            }
        }
    }
    out
}

/// Order-preserving map from f32 to u32: a < b (as floats, no NaN) iff enc(a) < enc(b) (as u32).
/// Lets atomic min/max on u32 act as min/max on depths. Same as `encode_depth` in the shader.
pub fn encode(x: f32) -> u32 {
    let b = x.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// Inverse of [`encode`].
pub fn decode(e: u32) -> f32 {
    if e & 0x8000_0000 != 0 {
        f32::from_bits(e & 0x7FFF_FFFF)
    } else {
        f32::from_bits(!e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encoding_preserves_order() {
        let xs = [
            f32::NEG_INFINITY,
            -1e30,
            -2.5,
            -1e-40,
            -0.0,
            0.0,
            1e-40,
            0.5,
            3.0,
            1e30,
            f32::INFINITY,
        ];
        for w in xs.windows(2) {
            assert!(encode(w[0]) <= encode(w[1]), "{} vs {}", w[0], w[1]);
            assert_eq!(decode(encode(w[1])).to_bits(), w[1].to_bits());
        }
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
