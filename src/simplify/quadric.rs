//! Garland and Heckbert's quadric error: the cost that orders the collapses, and the target
//! each collapse moves to.

use glam::{DMat3, DVec3};

/// Symmetric 4x4 quadric: upper triangle of [A b; bᵀ c] for the error vᵀAv + 2bᵀv + c.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Quadric {
    pub(super) a: [f64; 6], // xx xy xz yy yz zz
    pub(super) b: [f64; 3],
    pub(super) c: f64,
}

impl Quadric {
    /// Area-weighted plane of the triangle.
    pub(super) fn plane(p: [DVec3; 3]) -> Quadric {
        let n2 = (p[1] - p[0]).cross(p[2] - p[0]);
        let area = n2.length() / 2.0;
        let Some(n) = n2.try_normalize() else {
            return Quadric::default();
        };
        let d = -n.dot(p[0]);
        Quadric {
            a: [
                n.x * n.x,
                n.x * n.y,
                n.x * n.z,
                n.y * n.y,
                n.y * n.z,
                n.z * n.z,
            ]
            .map(|x| x * area),
            b: [n.x * d, n.y * d, n.z * d].map(|x| x * area),
            c: d * d * area,
        }
    }

    pub(super) fn add(&self, o: &Quadric) -> Quadric {
        Quadric {
            a: std::array::from_fn(|i| self.a[i] + o.a[i]),
            b: std::array::from_fn(|i| self.b[i] + o.b[i]),
            c: self.c + o.c,
        }
    }

    pub(super) fn matrix(&self) -> DMat3 {
        let a = self.a;
        DMat3::from_cols_array(&[a[0], a[1], a[2], a[1], a[3], a[4], a[2], a[4], a[5]])
    }

    pub(super) fn error(&self, v: DVec3) -> f64 {
        let b = DVec3::from_array(self.b);
        (v.dot(self.matrix() * v) + 2.0 * b.dot(v) + self.c).max(0.0)
    }

    /// The error-minimizing point, if the system is well conditioned.
    pub(super) fn optimum(&self) -> Option<DVec3> {
        let m = self.matrix();
        let det = m.determinant();
        let scale = m
            .to_cols_array()
            .iter()
            .map(|x| x.abs())
            .fold(0.0, f64::max);
        (det.abs() > 1e-9 * scale * scale * scale)
            .then(|| -(m.inverse() * DVec3::from_array(self.b)))
    }
}

/// An endpoint target is taken over the midpoint or the optimum when its quadric error is at
/// most this many times theirs. A collapse to an endpoint moves only the other endpoint's
/// triangles, so its checks cover about half the area; measured on the bundled bunny at
/// n = 512 (docs/benchmarks.md, "The mesh stage at engineering resolutions"): 1.5 takes a quarter
/// off the simplifier's time for 1% more triangles; 3 costs 25% more triangles.
const ENDPOINT_PREFERENCE: f64 = 1.5;

/// The quadric error and position of the cheapest target for merging a vertex with quadric
/// `qa` at `pa` and one with `qb` at `pb`: an endpoint (the first of the cheaper), unless the
/// midpoint or the quadric's optimum is cheaper by more than [`ENDPOINT_PREFERENCE`].
pub(super) fn cheapest(qa: &Quadric, pa: DVec3, qb: &Quadric, pb: DVec3) -> (f64, DVec3) {
    let q = qa.add(qb);
    let mid = (pa + pb) / 2.0;
    let mut end = (q.error(pa), pa);
    let e = q.error(pb);
    if e < end.0 {
        end = (e, pb);
    }
    let mut best = end;
    let e = q.error(mid);
    if e < best.0 {
        best = (e, mid);
    }
    if let Some(o) = q.optimum() {
        // Keep the optimum near the edge: far-flung optima are numerical accidents.
        if (o - mid).length() <= (pb - pa).length() {
            let e = q.error(o);
            if e < best.0 {
                best = (e, o);
            }
        }
    }
    if end.0 <= ENDPOINT_PREFERENCE * best.0 {
        end
    } else {
        best
    }
}
