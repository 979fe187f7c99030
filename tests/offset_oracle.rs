//! The f32 ray cast of one triangle's offset against the independent f64 oracle, on random and
//! adversarial configurations (degenerate and edge-on triangles, edges near-parallel to the ray,
//! grazing rays, far-from-origin coordinates). Asserts containment with the rounding budget the
//! sweep adds to δ, tightness within twice that budget, and that the real error uses well under
//! the budget.

mod common;
use common::{line_interval, Rng, V3};
use sweptvol::sweep::offset::ray_interval;

/// The ray-cast share of the rounding term for coordinates up to `b` grid units (job.rs).
fn budget(b: f64) -> f64 {
    64.0 * (f32::EPSILON as f64 / 2.0) * b
}

/// A random triangle near the ray (0, 0, t), in grid units, of one of several adversarial kinds.
fn random_case(rng: &mut Rng, d: f64, far: f64) -> [V3; 3] {
    let size = [0.0, 0.3, 2.0, 20.0, 300.0][rng.below(5) as usize];
    let a_base = rng.range(0.0, far);
    let pt = |rng: &mut Rng| -> V3 {
        [
            rng.range(-size - d, size + d),
            rng.range(-size - d, size + d),
            a_base + rng.range(-size, size),
        ]
    };
    let mut t = [pt(rng), pt(rng), pt(rng)];
    match rng.below(7) {
        0 => t[1] = t[0],   // segment
        1 => t = [t[0]; 3], // point
        2 => {
            // edge-on: all three vertices in a plane containing the ray direction
            let ang = rng.range(0.0, 6.3);
            let (c, s) = (ang.cos(), ang.sin());
            let off = rng.range(-d * 1.2, d * 1.2);
            for v in t.iter_mut() {
                let along = rng.range(-size - d, size + d);
                v[0] = off * c - along * s;
                v[1] = off * s + along * c;
            }
        }
        3 => {
            // an edge nearly parallel to the ray
            let tilt = 10f64.powf(-rng.range(1.0, 9.0));
            t[1] = [t[0][0] + tilt, t[0][1] - tilt * 0.5, t[0][2] + size + 1.0];
        }
        4 => {
            // grazing: a vertex at distance ~d from the ray
            let ang = rng.range(0.0, 6.3);
            let r = d * (1.0 + rng.range(-1e-4, 1e-4));
            t[0][0] = r * ang.cos();
            t[0][1] = r * ang.sin();
        }
        _ => {}
    }
    // The sweep's triangles are f32: make the oracle see exactly what the f32 code sees.
    t.map(|v| v.map(|c| c as f32 as f64))
}

#[test]
fn ray_cast_contains_exact_offset_and_stays_tight() {
    let d = grid_delta();
    let mut worst_fraction: f64 = 0.0;
    let mut hits = 0;
    for seed in 1..=20_000u64 {
        let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
        let far = [10.0, 1500.0, 16000.0][(seed % 3) as usize];
        let tri = random_case(&mut rng, d, far);
        let b = far + 300.0 + 2.0 * d;
        let rho = budget(b);
        let q = tri.map(|v| v.map(|c| c as f32));
        let exact = line_interval(tri, 2, [(0, 0.0), (1, 0.0)], d);
        let got = ray_interval(q, (d + rho) as f32);
        if let Some((t0, t1)) = exact {
            hits += 1;
            assert!(
                (got.t0 as f64) <= t0 && (got.t1 as f64) >= t1,
                "seed {seed}: exact [{t0}, {t1}] not inside computed [{}, {}] (rho {rho}) for {tri:?}",
                got.t0,
                got.t1
            );
            // How much of the budget the f32 computation really needed, at the same radius.
            let same = ray_interval(q, d as f32);
            if !same.is_empty() {
                let err = (same.t0 as f64 - t0).max(t1 - same.t1 as f64).max(0.0);
                worst_fraction = worst_fraction.max(err / rho);
            }
        }
        if !got.is_empty() {
            // Tightness: never beyond the offset of radius d + 2·rho (+ the oracle's precision).
            let wide = line_interval(tri, 2, [(0, 0.0), (1, 0.0)], d + 2.0 * rho)
                .unwrap_or_else(|| panic!("seed {seed}: computed a hit where d + 2 rho misses"));
            let slack = 1e-9 * b;
            assert!(
                got.t0 as f64 >= wide.0 - slack && got.t1 as f64 <= wide.1 + slack,
                "seed {seed}: computed [{}, {}] exceeds the offset of radius d + 2 rho [{}, {}]",
                got.t0,
                got.t1,
                wide.0,
                wide.1
            );
        }
    }
    println!(
        "{hits} hits; worst f32 error used {:.1}% of the rounding budget",
        100.0 * worst_fraction
    );
    assert!(hits > 5000, "too few hits ({hits}) to mean anything");
    assert!(
        worst_fraction < 0.25,
        "f32 error used {worst_fraction} of the budget: the budget is too thin"
    );
}

/// The paper's tight δ in voxels.
fn grid_delta() -> f64 {
    sweptvol::grid::K_DELTA
}
