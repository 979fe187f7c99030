//! Independent oracles for the tests: exact f64 geometry that shares no code with the sweep.
#![allow(dead_code)]

pub type V3 = [f64; 3];

fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Distance from p to segment [a, b].
pub fn dist_segment(p: V3, a: V3, b: V3) -> f64 {
    let ab = sub(b, a);
    let l2 = dot(ab, ab);
    let s = if l2 > 0.0 {
        (dot(sub(p, a), ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let c = [a[0] + s * ab[0], a[1] + s * ab[1], a[2] + s * ab[2]];
    let d = sub(p, c);
    dot(d, d).sqrt()
}

/// Distance from p to the closed triangle t (any shape, degenerate included): the distance to
/// the plane where p projects inside, else to the nearest edge.
pub fn dist_triangle(p: V3, t: [V3; 3]) -> f64 {
    let n = cross(sub(t[1], t[0]), sub(t[2], t[0]));
    let nn = dot(n, n);
    let edges = (0..3)
        .map(|i| dist_segment(p, t[i], t[(i + 1) % 3]))
        .fold(f64::INFINITY, f64::min);
    if nn > 0.0 {
        let inside = (0..3).all(|i| {
            let e = sub(t[(i + 1) % 3], t[i]);
            dot(cross(e, sub(p, t[i])), n) >= 0.0
        });
        if inside {
            return (dot(sub(p, t[0]), n) / nn.sqrt()).abs().min(edges);
        }
    }
    edges
}

/// The interval of t where point (u, v, t) along axis `axis` (u, v on the other two axes in the
/// order given) is within `d` of triangle `tri`, by minimizing the convex distance along the line
/// and bisecting both sides. None when the line misses the offset.
pub fn line_interval(
    tri: [V3; 3],
    axis: usize,
    uv: [(usize, f64); 2],
    d: f64,
) -> Option<(f64, f64)> {
    let point = |t: f64| {
        let mut p = [0.0; 3];
        p[axis] = t;
        p[uv[0].0] = uv[0].1;
        p[uv[1].0] = uv[1].1;
        p
    };
    let f = |t: f64| dist_triangle(point(t), tri);
    let lo0 = tri.iter().map(|v| v[axis]).fold(f64::INFINITY, f64::min) - d - 1.0;
    let hi0 = tri
        .iter()
        .map(|v| v[axis])
        .fold(f64::NEG_INFINITY, f64::max)
        + d
        + 1.0;
    // Golden-section search for the minimum of a convex function.
    let (mut a, mut b) = (lo0, hi0);
    let g = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..120 {
        let c = b - g * (b - a);
        let e = a + g * (b - a);
        if f(c) <= f(e) {
            b = e;
        } else {
            a = c;
        }
    }
    let tm = (a + b) / 2.0;
    if f(tm) > d {
        return None;
    }
    let bisect = |mut inside: f64, mut outside: f64| {
        for _ in 0..80 {
            let mid = (inside + outside) / 2.0;
            if f(mid) <= d {
                inside = mid;
            } else {
                outside = mid;
            }
        }
        inside
    };
    Some((bisect(tm, lo0), bisect(tm, hi0)))
}

/// Small deterministic PRNG (xorshift64*), so failures reproduce from the printed seed.
pub struct Rng(pub u64);
impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in [0, 1).
    pub fn f(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f()
    }
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }
}
