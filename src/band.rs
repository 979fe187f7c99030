//! The tolerance band around the voxel boundary: exact local distances from points to ∂W (W the
//! union of inside voxels) and the sampled, sound test "every point of a triangle is within ε of
//! ∂W" that the simplifier's checks are built on (docs/design.md).
//!
//! Units: grid units throughout (one voxel edge = 1).

use glam::DVec3;

use crate::voxel::Classifier;

/// Distance from `p` to the voxel cube `v` (closed unit cube at integer corner `v`).
fn dist_to_cube(p: DVec3, v: [isize; 3]) -> f64 {
    let mut d2 = 0.0;
    for a in 0..3 {
        let lo = v[a] as f64;
        let g = (lo - p[a]).max(p[a] - (lo + 1.0)).max(0.0);
        d2 += g * g;
    }
    d2.sqrt()
}

/// The exact distance from `p` to ∂W when it is at most `limit`, else None (farther). Only
/// voxels within `limit` of `p` are visited: (2⌈limit⌉+1)³ at most.
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
                    best = best.min(dist_to_cube(p, [i, j, k]));
                }
            }
        }
    }
    (best <= limit).then_some(best)
}

/// Points covering triangle `t`: every point of `t` is within `r` of one of them. A barycentric
/// grid with k steps per edge splits `t` into k² triangles similar to `t`, each with edges at
/// most L/k; a triangle's points are within (longest edge)/√3 of its nearest vertex.
pub fn cover_triangle(t: [DVec3; 3], r: f64) -> impl Iterator<Item = DVec3> {
    let longest = (t[1] - t[0])
        .length()
        .max((t[2] - t[1]).length())
        .max((t[0] - t[2]).length());
    let k = ((longest / (r * 3f64.sqrt())).ceil() as usize).max(1);
    (0..=k).flat_map(move |i| {
        (0..=(k - i)).map(move |j| {
            let (a, b) = (i as f64 / k as f64, j as f64 / k as f64);
            t[0] + (t[1] - t[0]) * a + (t[2] - t[0]) * b
        })
    })
}

/// Sound test that every point of triangle `t` is within `eps` of ∂W: each covering sample
/// (radius `r` < `eps`) must be within `eps - r`. May reject a triangle that is within the band;
/// never accepts one that is not.
pub fn triangle_in_band(cls: &Classifier, t: [DVec3; 3], eps: f64, r: f64) -> bool {
    debug_assert!(r > 0.0 && r < eps);
    cover_triangle(t, r).all(|s| dist_to_boundary(cls, s, eps - r).is_some())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::voxel::test_support::boxed as boxed_at;

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
        let mut seed = 7u64;
        let mut rnd = |lo: f64, hi: f64| {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            lo + (hi - lo) * ((seed >> 11) as f64 / (1u64 << 53) as f64)
        };
        for _ in 0..5000 {
            let p = DVec3::new(rnd(0.0, 6.0), rnd(0.0, 5.0), rnd(0.0, 7.0));
            let exact = box_dist(p);
            match dist_to_boundary(&cls, p, 0.9) {
                Some(d) => assert!((d - exact).abs() < 1e-12, "{p}: {d} vs {exact}"),
                None => assert!(exact > 0.9 - 1e-12, "{p}: missed {exact}"),
            }
        }
    }

    #[test]
    fn covering_samples_reach_every_point() {
        let t = [
            DVec3::ZERO,
            DVec3::new(7.0, 0.5, 0.0),
            DVec3::new(-2.0, 0.3, 1.0),
        ];
        let samples: Vec<DVec3> = cover_triangle(t, 0.25).collect();
        for i in 0..=60 {
            for j in 0..=(60 - i) {
                let p =
                    t[0] + (t[1] - t[0]) * (i as f64 / 60.0) + (t[2] - t[0]) * (j as f64 / 60.0);
                let d = samples
                    .iter()
                    .map(|s| (*s - p).length())
                    .fold(f64::INFINITY, f64::min);
                assert!(d <= 0.25 + 1e-12, "{p} is {d} from every sample");
            }
        }
    }

    #[test]
    fn band_test_accepts_near_triangles_and_rejects_far_ones() {
        let cls = boxed();
        // On the box's top face z = 5, slightly lifted: inside the band.
        let near = [
            DVec3::new(1.2, 1.2, 5.3),
            DVec3::new(3.8, 1.2, 5.3),
            DVec3::new(1.2, 2.8, 4.8),
        ];
        assert!(triangle_in_band(&cls, near, 0.866, 0.25));
        // One corner 0.9 above the face: outside a band of 0.866, must be refused.
        let far = [
            DVec3::new(1.2, 1.2, 5.9),
            DVec3::new(3.8, 1.2, 5.3),
            DVec3::new(1.2, 2.8, 5.3),
        ];
        assert!(!triangle_in_band(&cls, far, 0.866, 0.25));
        // Cutting through the box's middle: deep inside, refused.
        let deep = [
            DVec3::new(1.5, 1.5, 3.5),
            DVec3::new(3.5, 1.5, 3.5),
            DVec3::new(2.5, 2.5, 3.5),
        ];
        assert!(!triangle_in_band(&cls, deep, 0.866, 0.25));
    }
}
