//! The clearance map: at each obstacle vertex, the lower end of the clearance there, and a
//! colour for it.

use rayon::prelude::*;

use super::{pair, Guarantee, Obstacle, Swept, Verdict};

/// Per vertex of `o`: a guaranteed lower bound of its distance to the swept volume, world
/// units: dist(v, mesh) + c for a vertex outside the mesh (the segment to any point of the
/// swept volume crosses the mesh's surface), 0 inside it. `verdict` is the obstacle's: where
/// it is clear, no vertex is inside and the inside test is skipped.
pub fn lower_ends(swept: &Swept, g: &Guarantee, o: &Obstacle, verdict: Verdict) -> Vec<f64> {
    let allowance = super::rounding_allowance(swept, o);
    o.positions
        .par_iter()
        .map(|&v| {
            if verdict != Verdict::Clear && pair::inside(&swept.bvh, v, None) {
                return 0.0;
            }
            let (d, _) = swept.bvh.nearest(v);
            (d + g.clearance - allowance).max(0.0)
        })
        .collect()
}

/// The colour of a lower end `x` on a ramp red (0: may touch) - yellow - green (`scale` and
/// beyond), linear RGB.
pub fn colour(x: f64, scale: f64) -> [f32; 3] {
    let t = if scale > 0.0 {
        (x / scale).clamp(0.0, 1.0) as f32
    } else {
        1.0
    };
    if x <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    if t < 0.5 {
        [1.0, 2.0 * t, 0.0]
    } else {
        [2.0 * (1.0 - t), 1.0, 0.0]
    }
}
