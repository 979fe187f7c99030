//! The voxel grid and the method's parameters (paper sections 3 and 6).
//!
//! World units are those of the glTF (metres by convention). Grid units measure along the grid's
//! axes in voxel edges from its min corner: world = origin + t·h. Voxel (i, j, k) spans
//! [i, i+1] x [j, j+1] x [k, k+1] in grid units; its centre is at (i+½, j+½, k+½).

use glam::DVec3;
use serde::Serialize;

use crate::error::{num, OptionError, OptionKey};

/// δ = K_DELTA·h: the paper's tight offset radius (2√3+√2)/2n.
pub const K_DELTA: f64 = (2.0 * SQRT_3 + std::f64::consts::SQRT_2) / 2.0;
/// ε = K_EPSILON·h: half a voxel diagonal, √3/2n.
pub const K_EPSILON: f64 = SQRT_3 / 2.0;
/// σ = K_SIGMA·h = σ₁ + σ₂ = (√3+√2)/2n, the paper's sampling error.
pub const K_SIGMA: f64 = (SQRT_3 + std::f64::consts::SQRT_2) / 2.0;
/// ε_global = K_GLOBAL·h = ε + δ + σ at the tight parameters, (2√3+√2)/n.
pub const K_GLOBAL: f64 = 2.0 * SQRT_3 + std::f64::consts::SQRT_2;
/// Empty voxels kept around the offset geometry on every side.
pub const MARGIN_VOXELS: f64 = 1.0;
/// Largest grid resolution accepted (voxels along the longest edge). Beyond it f32 grid
/// coordinates leave too little precision (the rounding term would pass 0.05 voxels).
pub const MAX_RESOLUTION: u32 = 12288;
/// Smallest grid resolution accepted.
pub const MIN_RESOLUTION: u32 = 16;

const SQRT_3: f64 = 1.732_050_807_568_877_2;

/// How the user picks the voxel size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Accuracy {
    /// Voxels along the box's longest edge.
    Resolution(u32),
    /// ε_global in world units: h = t / (2√3+√2).
    Tolerance(f64),
}

impl Accuracy {
    /// When neither a resolution nor a tolerance is given.
    pub const DEFAULT: Accuracy = Accuracy::Resolution(256);

    /// The accuracy a user's options ask for: a tolerance wins over a resolution, and with
    /// neither, `default` (the CLI's [`Accuracy::DEFAULT`], or a daemon's own default for its jobs).
    pub fn choose(resolution: Option<u32>, tolerance: Option<f64>, default: Accuracy) -> Accuracy {
        match (resolution, tolerance) {
            (_, Some(t)) => Accuracy::Tolerance(t),
            (Some(n), None) => Accuracy::Resolution(n),
            (None, None) => default,
        }
    }
}

/// Optional overrides of δ and ε, world units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Overrides {
    pub delta: Option<f64>,
    pub epsilon: Option<f64>,
}

/// The axis-aligned voxel grid. Invariant: h > 0, every dim >= 1.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Grid {
    /// World position of the grid's min corner.
    pub origin: [f64; 3],
    /// Voxel edge, world units.
    pub h: f64,
    /// Voxels along x, y, z.
    pub dims: [u32; 3],
}

impl Grid {
    pub fn origin(&self) -> DVec3 {
        DVec3::from_array(self.origin)
    }

    /// World point to grid units.
    pub fn to_grid(&self, p: DVec3) -> DVec3 {
        (p - self.origin()) / self.h
    }

    /// Grid units to world point.
    pub fn to_world(&self, t: DVec3) -> DVec3 {
        self.origin() + t * self.h
    }

    /// Voxels along the longest edge (the paper's n).
    pub fn resolution(&self) -> u32 {
        self.dims.into_iter().max().unwrap_or(0)
    }
}

/// The method's distances, world units. Invariant (checked by [`fit_grid`]): δ > ε + σ or the
/// paper's tight defaults, ε >= √3h/2.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Params {
    /// Offset radius δ rendered around every posed triangle (before the rounding term).
    pub delta: f64,
    /// Tolerance ε of the simplification.
    pub epsilon: f64,
    /// Sampling error σ = σ₁ + σ₂ = (√3+√2)h/2.
    pub sigma: f64,
}

/// Fit a grid around the axis-aligned box [lo, hi] of all posed geometry. `mu_voxels` is the
/// motion budget μ/h the sweep renders beyond δ (0 for discrete motion): the grid leaves room
/// for it, and a tolerance then counts it in (h = t/(K_GLOBAL + μ/h)), so the stated bound
/// stays within the tolerance.
/// Errors name the option at fault and what to do about it.
pub fn fit_grid(
    lo: DVec3,
    hi: DVec3,
    accuracy: Accuracy,
    overrides: Overrides,
    mu_voxels: f64,
) -> Result<(Grid, Params), OptionError> {
    let extent = hi - lo;
    let longest = extent.max_element();
    let accuracy_key = match accuracy {
        Accuracy::Resolution(_) => OptionKey::Resolution,
        Accuracy::Tolerance(_) => OptionKey::Tolerance,
    };
    if !(longest.is_finite() && lo.is_finite()) {
        return Err(OptionError::new(
            accuracy_key,
            "the posed geometry has a non-finite bounding box",
        ));
    }
    let h = match accuracy {
        Accuracy::Resolution(n) => {
            if !(MIN_RESOLUTION..=MAX_RESOLUTION).contains(&n) {
                return Err(OptionError::new(
                    OptionKey::Resolution,
                    format!("$resolution {n} is outside {MIN_RESOLUTION}..={MAX_RESOLUTION}; pick a resolution in that range"),
                ));
            }
            if longest <= 0.0 {
                return Err(OptionError::new(
                    OptionKey::Resolution,
                    "the posed geometry has zero extent, so $resolution cannot set the voxel size; give $tolerance instead",
                ));
            }
            // n·h = longest + 2δ + 2·(margin + μ/h)·h, with δ either fixed or K_DELTA·h.
            let free = n as f64 - 2.0 * (MARGIN_VOXELS + mu_voxels);
            match overrides.delta {
                Some(delta) => (longest + 2.0 * delta) / free,
                None => longest / (free - 2.0 * K_DELTA),
            }
        }
        Accuracy::Tolerance(t) => {
            if !(t.is_finite() && t > 0.0) {
                return Err(OptionError::new(
                    OptionKey::Tolerance,
                    format!("$tolerance {t} must be a positive number of world units"),
                ));
            }
            t / (K_GLOBAL + mu_voxels)
        }
    };
    let params = Params {
        delta: overrides.delta.unwrap_or(K_DELTA * h),
        epsilon: overrides.epsilon.unwrap_or(K_EPSILON * h),
        sigma: K_SIGMA * h,
    };
    check_params(&params, h, overrides)?;
    let pad = params.delta + (MARGIN_VOXELS + mu_voxels) * h;
    let mut dims = [0u32; 3];
    for a in 0..3 {
        let voxels = ((extent[a] + 2.0 * pad) / h * (1.0 - 1e-12)).ceil();
        if voxels > MAX_RESOLUTION as f64 {
            return Err(OptionError::new(
                accuracy_key,
                format!(
                    "the grid would need {voxels} voxels along {}, more than {MAX_RESOLUTION}; give a larger $tolerance",
                    ["x", "y", "z"][a]
                ),
            ));
        }
        dims[a] = (voxels as u32).max(1);
    }
    let size = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64) * h;
    let origin = (lo + hi) / 2.0 - size / 2.0;
    Ok((
        Grid {
            origin: origin.to_array(),
            h,
            dims,
        },
        params,
    ))
}

fn check_params(p: &Params, h: f64, overrides: Overrides) -> Result<(), OptionError> {
    for (key, v) in [
        (OptionKey::Delta, overrides.delta),
        (OptionKey::Epsilon, overrides.epsilon),
    ] {
        if let Some(v) = v {
            if !(v.is_finite() && v > 0.0) {
                return Err(OptionError::new(
                    key,
                    format!(
                        "${} {v} must be a positive number of world units",
                        key.name()
                    ),
                ));
            }
        }
    }
    if overrides.epsilon.is_some() && p.epsilon <= K_EPSILON * h {
        return Err(OptionError::new(
            OptionKey::Epsilon,
            format!(
                "$epsilon {} must exceed half a voxel diagonal √3h/2 = {} (h = {}); raise it or refine the grid",
                num(p.epsilon),
                num(K_EPSILON * h),
                num(h)
            ),
        ));
    }
    if (overrides.delta.is_some() || overrides.epsilon.is_some()) && p.delta <= p.epsilon + p.sigma
    {
        // The key is the one the user gave; with both, δ is the one the message says to raise.
        let key = if overrides.delta.is_some() {
            OptionKey::Delta
        } else {
            OptionKey::Epsilon
        };
        return Err(OptionError::new(
            key,
            format!(
                "δ = {} must exceed ε + σ = {} + {} (h = {}); raise $delta or lower $epsilon",
                num(p.delta),
                num(p.epsilon),
                num(p.sigma),
                num(h)
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resolution_sets_longest_edge() {
        let (g, p) = fit_grid(
            DVec3::ZERO,
            DVec3::new(2.0, 1.0, 0.5),
            Accuracy::Resolution(100),
            Overrides::default(),
            0.0,
        )
        .unwrap();
        assert_eq!(g.dims[0], 100);
        assert!((p.delta - K_DELTA * g.h).abs() < 1e-15);
        // The offset box plus the margin fits on every side.
        for a in 0..3 {
            let lo = g.origin[a];
            let hi = lo + g.dims[a] as f64 * g.h;
            let geo_hi = [2.0, 1.0, 0.5][a];
            assert!(lo <= -p.delta - g.h * 0.999 && hi >= geo_hi + p.delta + g.h * 0.999);
        }
    }

    #[test]
    fn tolerance_sets_voxel_size() {
        let (g, p) = fit_grid(
            DVec3::ZERO,
            DVec3::ONE,
            Accuracy::Tolerance(0.01),
            Overrides::default(),
            0.0,
        )
        .unwrap();
        assert!((g.h * K_GLOBAL - 0.01).abs() < 1e-15);
        assert!((p.delta + p.epsilon + p.sigma - 0.01).abs() < 1e-12);
    }

    #[test]
    fn bad_overrides_are_refused() {
        let fit = |d, e| {
            fit_grid(
                DVec3::ZERO,
                DVec3::ONE,
                Accuracy::Resolution(100),
                Overrides {
                    delta: d,
                    epsilon: e,
                },
                0.0,
            )
        };
        let e = fit(Some(0.001), None).unwrap_err();
        assert_eq!(e.key, OptionKey::Delta);
        assert!(
            e.to_string().starts_with("δ = 0.001 must exceed ε + σ"),
            "{e}"
        );
        assert!(
            e.worded(OptionKey::flag)
                .contains("raise --delta or lower --epsilon"),
            "{e}"
        );
        let e = fit(None, Some(0.0001)).unwrap_err();
        assert_eq!(e.key, OptionKey::Epsilon);
        assert!(e.to_string().contains("half a voxel diagonal"), "{e}");
        assert!(fit(Some(0.1), Some(0.02)).is_ok());
        let e = fit(Some(-1.0), None).unwrap_err();
        assert_eq!(
            (e.key, e.to_string().contains("positive")),
            (OptionKey::Delta, true)
        );
    }

    #[test]
    fn zero_extent_needs_a_tolerance() {
        let p = DVec3::new(1.0, 2.0, 3.0);
        assert!(fit_grid(p, p, Accuracy::Resolution(64), Overrides::default(), 0.0).is_err());
        let (g, _) = fit_grid(p, p, Accuracy::Tolerance(0.1), Overrides::default(), 0.0).unwrap();
        assert!(g.dims.iter().all(|&d| d >= 7));
    }
}
