//! Whether a triangle lies within a radius of a few points (voxel centres): the exact maximum
//! over the triangle of the distance to the nearest of them, taken over each point's Voronoi
//! cell clipped to the triangle (docs/design.md, "The band test's last resort").
//!
//! Units: grid units (one voxel edge = 1).

use glam::DVec3;

/// At most this many points: each cell is clipped by every other point's bisector.
pub const MAX_POINTS: usize = 12;

/// Taken off the squared radius (grid units²) for the rounding of the distances.
const MARGIN: f64 = 1e-9;
/// How far (grid units) each cell's bisectors are moved away from its point. Rounding moves a
/// clipped corner by a few ulps at the scale of the triangle (coordinates are taken relative to
/// its first corner), far less, so a computed cell holds the true one: the cells still cover
/// the triangle, and each one's maximum is taken over a superset.
const SLACK: f64 = 1e-9;

/// Whether every point of triangle `t` lies within `radius` of one of `points`. Decided
/// exactly (up to [`MARGIN`] and [`SLACK`]): the triangle is the union of the points' Voronoi
/// cells clipped to it, and over each cell the distance to its own point is convex, so its
/// maximum is at a corner of the clipped polygon. Sound: a yes means max over t of
/// min_j |x - p_j| ≤ radius.
/// No for an empty or too long list ([`MAX_POINTS`]).
pub fn within(t: &[DVec3; 3], points: &[DVec3], radius: f64) -> bool {
    if points.is_empty() || points.len() > MAX_POINTS {
        return false;
    }
    let limit = radius * radius - MARGIN;
    let o = t[0];
    let tri = t.map(|x| x - o);
    let mut p = [DVec3::ZERO; MAX_POINTS];
    for (q, x) in p.iter_mut().zip(points) {
        *q = *x - o;
    }
    let p = &p[..points.len()];
    // Each corner against its nearest point first: the usual way out.
    let nearest = |x: DVec3| {
        p.iter()
            .map(|c| (x - *c).length_squared())
            .fold(f64::MAX, f64::min)
    };
    if tri.iter().any(|x| nearest(*x) > limit) {
        return false;
    }
    let (mut a, mut b) = ([DVec3::ZERO; 3 + MAX_POINTS], [DVec3::ZERO; 3 + MAX_POINTS]);
    let mut side = [0.0; 3 + MAX_POINTS];
    for (j, &pj) in p.iter().enumerate() {
        // The whole triangle within pj's ball: so is its cell.
        if tri.iter().all(|x| (*x - pj).length_squared() <= limit) {
            continue;
        }
        let (mut poly, mut next) = (&mut a, &mut b);
        poly[..3].copy_from_slice(&tri);
        let mut len = 3;
        for (m, &pm) in p.iter().enumerate() {
            if m == j {
                continue;
            }
            // Keep the side of the bisector nearer pj, (pm - pj)·(x - mid) ≤ 0, moved [`SLACK`]
            // towards pm.
            let (w, mid) = (pm - pj, (pm + pj) / 2.0);
            let slack = SLACK * w.length();
            let mut cut = 0;
            for k in 0..len {
                side[k] = w.dot(poly[k] - mid) - slack;
                cut += usize::from(side[k] > 0.0);
            }
            if cut == 0 {
                continue;
            }
            if cut == len {
                len = 0;
                break;
            }
            let mut out = 0;
            for k in 0..len {
                let l = if k + 1 == len { 0 } else { k + 1 };
                let (fa, fb) = (side[k], side[l]);
                if fa <= 0.0 {
                    next[out] = poly[k];
                    out += 1;
                }
                if (fa <= 0.0) != (fb <= 0.0) {
                    next[out] = poly[k] + (poly[l] - poly[k]) * (fa / (fa - fb));
                    out += 1;
                }
            }
            len = out;
            std::mem::swap(&mut poly, &mut next);
        }
        if poly[..len]
            .iter()
            .any(|x| (*x - pj).length_squared() > limit)
        {
            return false;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force: the largest distance to the nearest point over a fine barycentric grid of
    /// the triangle (a lower bound of the true maximum, within 1e-3 of it here).
    fn sampled(t: &[DVec3; 3], points: &[DVec3]) -> f64 {
        let n = 200;
        let mut m = 0.0f64;
        for i in 0..=n {
            for j in 0..=n - i {
                let (a, b) = (i as f64 / n as f64, j as f64 / n as f64);
                let x = t[0] + (t[1] - t[0]) * a + (t[2] - t[0]) * b;
                let d = points
                    .iter()
                    .map(|c| (x - *c).length())
                    .fold(f64::MAX, f64::min);
                m = m.max(d);
            }
        }
        m
    }

    /// Random triangles of a few voxels among random voxel centres: a yes is never given where
    /// a sampled point of the triangle is farther than the radius from every centre, and a no
    /// is never given where the sampled maximum is below it by more than the sampling's error.
    /// Dropping the bisector clipping (each cell the whole triangle) accepts too little; taking
    /// only the corners (no clipped corners) accepts points beyond the radius.
    #[test]
    fn agrees_with_a_sampled_maximum() {
        let mut rng = fastrand::Rng::with_seed(11);
        let (mut yes, mut no) = (0, 0);
        for _ in 0..3000 {
            let k = 1 + rng.usize(..MAX_POINTS);
            let mut centres: Vec<DVec3> = (0..k)
                .map(|_| {
                    DVec3::new(
                        rng.i32(0..4) as f64,
                        rng.i32(0..4) as f64,
                        rng.i32(0..4) as f64,
                    ) + 0.5
                })
                .collect();
            centres.sort_by(|a, b| a.to_array().partial_cmp(&b.to_array()).unwrap());
            centres.dedup();
            let t: [DVec3; 3] =
                std::array::from_fn(|_| DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 4.0);
            let radius = 1.0 + 1.5 * rng.f64();
            let truth = sampled(&t, &centres);
            if within(&t, &centres, radius) {
                yes += 1;
                assert!(truth <= radius, "{t:?} {centres:?}: {truth} > {radius}");
            } else {
                no += 1;
                let longest = (0..3)
                    .map(|i| (t[i] - t[(i + 1) % 3]).length())
                    .fold(0.0, f64::max);
                // The grid's spacing bounds how far the sampled maximum can be below the true one.
                assert!(
                    truth > radius - longest / 200.0 - 1e-6,
                    "{t:?} {centres:?}: refused at {truth} < {radius}"
                );
            }
        }
        assert!(yes > 300 && no > 300, "yes {yes}, no {no}");
    }

    /// Over a flat wall of centres (the plane z = 0.5) a triangle in the plane z = -0.78 lies
    /// within 1.466 of them (the envelope between four centres is at z = 0.5 - √(1.466² - 1/2)
    /// ≈ -0.784); at z = -0.79 a point between four centres is out. Exactly what the tolerance
    /// volume's slab over a wall says (docs/design.md).
    #[test]
    fn a_wall_of_centres_holds_its_slab() {
        let wall: Vec<DVec3> = (0..3)
            .flat_map(|i| (0..3).map(move |j| DVec3::new(i as f64 + 0.5, j as f64 + 0.5, 0.5)))
            .collect();
        let at = |z: f64| {
            [
                DVec3::new(0.6, 0.6, z),
                DVec3::new(2.4, 0.6, z),
                DVec3::new(0.6, 2.4, z),
            ]
        };
        assert!(within(&at(-0.78), &wall, 1.466));
        assert!(!within(&at(-0.79), &wall, 1.466));
        // Two points of the wall alone leave the cells of the others uncovered.
        assert!(!within(&at(-0.5), &wall[..2], 1.466));
        assert!(!within(&at(0.0), &[], 1.466));
    }
}
