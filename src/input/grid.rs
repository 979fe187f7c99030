//! The voxel grid and the method's parameters (paper sections 3 and 6).
//!
//! World units are those of the glTF (metres by convention). Grid units measure along the grid's
//! axes in voxel edges from its min corner: world = origin + t·h. Voxel (i, j, k) spans
//! [i, i+1] x [j, j+1] x [k, k+1] in grid units; its centre is at (i+½, j+½, k+½).

use glam::DVec3;
use serde::Serialize;

use crate::error::{num, OptionError, OptionKey};

/// δ = K_DELTA·h: the paper's tight offset radius (2√3+√2)/2n ([`Radii::Paper`]).
pub const K_DELTA: f64 = (2.0 * SQRT_3 + std::f64::consts::SQRT_2) / 2.0;
/// ε = K_EPSILON·h: half a voxel diagonal, √3/2n ([`Radii::Paper`]).
pub const K_EPSILON: f64 = SQRT_3 / 2.0;
/// ε = K_EPSILON_EXACT·h for [`Radii::Exact`] (docs/design.md, "The radii").
pub const K_EPSILON_EXACT: f64 = 0.6;
/// The clearance c = δ - √3h/2 - ε kept by [`Radii::Exact`], voxels: room for the output's f32
/// rounding (refused above 0.01h) and the Blender add-on's sampling threshold.
pub const K_CLEARANCE_EXACT: f64 = 0.07;
/// A joined voxel's reach when it shares a face with an original one, √11/2 voxels
/// (`mesh::manifold::Joined::reach`).
pub const FACE_JOIN_REACH: f64 = 1.658_312_395_177_7;
/// Smallest ε accepted, voxels: the smallest piece the simplifier's checks refine to.
pub const MIN_EPSILON_VOXELS: f64 = 0.05;
/// Smallest clearance δ - √3h/2 - ε accepted, voxels: above the output rounding's 0.01h.
pub const MIN_CLEARANCE_VOXELS: f64 = 0.02;
/// Allowance for 2ρ and the output rounding in the voxel size a tolerance sets, voxels.
pub const TOLERANCE_ALLOWANCE: f64 = 0.1;
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
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Accuracy {
    /// Voxels along the box's longest edge.
    Resolution(u32),
    /// The stated bound in world units: h = t / (k_tolerance + μ/h) ([`Radii::k_tolerance`]).
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

/// Which δ and ε a run takes where the user gives neither.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Radii {
    /// Radii for the simplifier's exact checks (docs/design.md, "The radii"): ε = 0.6h,
    /// δ = ε + √3h/2 + 0.07h ≈ 1.536h; stated bound about 3.2h + μ.
    #[default]
    Exact,
    /// The paper's: δ = (2√3+√2)h/2 ≈ 2.475h, ε = √3h/2; stated bound about 4.17h + μ.
    Paper,
}

impl Radii {
    pub fn name(self) -> &'static str {
        match self {
            Radii::Exact => "exact",
            Radii::Paper => "paper",
        }
    }

    /// ε / h.
    pub fn k_epsilon(self) -> f64 {
        match self {
            Radii::Exact => K_EPSILON_EXACT,
            Radii::Paper => K_EPSILON,
        }
    }

    /// δ / h.
    pub fn k_delta(self) -> f64 {
        match self {
            Radii::Exact => K_EPSILON_EXACT + SQRT_3 / 2.0 + K_CLEARANCE_EXACT,
            Radii::Paper => K_DELTA,
        }
    }

    /// The stated bound / h a tolerance is mapped to (before μ): the paper's ε_global for
    /// [`Radii::Paper`]; for [`Radii::Exact`] the report's bound with a face-joined reach,
    /// max(ε + √3h/2, √11h/2) + δ, plus [`TOLERANCE_ALLOWANCE`].
    pub fn k_tolerance(self) -> f64 {
        match self {
            Radii::Exact => {
                (self.k_epsilon() + SQRT_3 / 2.0).max(FACE_JOIN_REACH)
                    + self.k_delta()
                    + TOLERANCE_ALLOWANCE
            }
            Radii::Paper => K_GLOBAL,
        }
    }
}

/// Optional overrides of δ and ε (world units), and the rule for those not given.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct Overrides {
    pub delta: Option<f64>,
    pub epsilon: Option<f64>,
    pub radii: Radii,
}

/// The axis-aligned voxel grid. Invariant: h > 0, every dim >= 1.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
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

/// The method's distances, world units. Invariant (checked by [`fit_grid`]):
/// δ > ε + √3h/2 + 0.02h and ε > 0.05h.
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
            // n·h = longest + 2δ + 2·(margin + μ/h)·h, with δ either fixed or k_delta·h.
            let free = n as f64 - 2.0 * (MARGIN_VOXELS + mu_voxels);
            match overrides.delta {
                Some(delta) => (longest + 2.0 * delta) / free,
                None => longest / (free - 2.0 * overrides.radii.k_delta()),
            }
        }
        Accuracy::Tolerance(t) => {
            if !(t.is_finite() && t > 0.0) {
                return Err(OptionError::new(
                    OptionKey::Tolerance,
                    format!("$tolerance {t} must be a positive number of world units"),
                ));
            }
            t / (overrides.radii.k_tolerance() + mu_voxels)
        }
    };
    let params = Params {
        delta: overrides.delta.unwrap_or(overrides.radii.k_delta() * h),
        epsilon: overrides.epsilon.unwrap_or(overrides.radii.k_epsilon() * h),
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
    if overrides.epsilon.is_some() && p.epsilon <= MIN_EPSILON_VOXELS * h {
        return Err(OptionError::new(
            OptionKey::Epsilon,
            format!(
                "$epsilon {} must exceed {MIN_EPSILON_VOXELS}h = {} (h = {}), the smallest piece the simplifier's checks refine to; raise it or refine the grid",
                num(p.epsilon),
                num(MIN_EPSILON_VOXELS * h),
                num(h)
            ),
        ));
    }
    let least_delta = p.epsilon + (SQRT_3 / 2.0 + MIN_CLEARANCE_VOXELS) * h;
    if (overrides.delta.is_some() || overrides.epsilon.is_some()) && p.delta <= least_delta {
        // The key is the one the user gave; with both, δ is the one the message says to raise.
        let key = if overrides.delta.is_some() {
            OptionKey::Delta
        } else {
            OptionKey::Epsilon
        };
        return Err(OptionError::new(
            key,
            format!(
                "δ = {} must exceed ε + √3h/2 + {MIN_CLEARANCE_VOXELS}h = {} (ε = {}, h = {}: the output's clearance from the swept volume); raise $delta or lower $epsilon",
                num(p.delta),
                num(least_delta),
                num(p.epsilon),
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
        assert!((p.delta - Radii::Exact.k_delta() * g.h).abs() < 1e-15);
        assert!((p.epsilon - 0.6 * g.h).abs() < 1e-15);
        // The clearance the exact radii keep: δ - √3h/2 - ε = 0.07h.
        assert!((p.delta - p.epsilon - SQRT_3 / 2.0 * g.h - 0.07 * g.h).abs() < 1e-12);
        // The offset box plus the margin fits on every side.
        for a in 0..3 {
            let lo = g.origin[a];
            let hi = lo + g.dims[a] as f64 * g.h;
            let geo_hi = [2.0, 1.0, 0.5][a];
            assert!(lo <= -p.delta - g.h * 0.999 && hi >= geo_hi + p.delta + g.h * 0.999);
        }
    }

    #[test]
    fn constants_are_what_they_say() {
        assert!((FACE_JOIN_REACH - 11f64.sqrt() / 2.0).abs() < 1e-15);
        assert!((K_DELTA - (2.0 * SQRT_3 + 2f64.sqrt()) / 2.0).abs() < 1e-15);
        // The exact radii: the stated bound's factor, for discrete motion, is below 3.2.
        let bound = FACE_JOIN_REACH + Radii::Exact.k_delta();
        assert!((bound - 3.1943).abs() < 1e-4, "{bound}");
        assert!((Radii::Exact.k_tolerance() - bound - TOLERANCE_ALLOWANCE).abs() < 1e-15);
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
        // The exact radii: the stated bound with a face-joined reach, √11h/2 + δ, plus the
        // allowance, is the tolerance.
        assert!((g.h * (FACE_JOIN_REACH + TOLERANCE_ALLOWANCE) + p.delta - 0.01).abs() < 1e-15);
        let (g, p) = fit_grid(
            DVec3::ZERO,
            DVec3::ONE,
            Accuracy::Tolerance(0.01),
            Overrides {
                radii: Radii::Paper,
                ..Overrides::default()
            },
            0.0,
        )
        .unwrap();
        assert!((g.h * K_GLOBAL - 0.01).abs() < 1e-15);
        assert!((p.delta + p.epsilon + p.sigma - 0.01).abs() < 1e-12);
        assert!((p.delta - K_DELTA * g.h).abs() < 1e-15);
        assert!((p.epsilon - K_EPSILON * g.h).abs() < 1e-15);
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
                    ..Overrides::default()
                },
                0.0,
            )
        };
        let e = fit(Some(0.001), None).unwrap_err();
        assert_eq!(e.key, OptionKey::Delta);
        assert!(
            e.to_string()
                .starts_with("δ = 0.001 must exceed ε + √3h/2 + 0.02h"),
            "{e}"
        );
        assert!(
            e.worded(OptionKey::flag)
                .contains("raise --delta or lower --epsilon"),
            "{e}"
        );
        let e = fit(None, Some(0.0001)).unwrap_err();
        assert_eq!(e.key, OptionKey::Epsilon);
        assert!(e.to_string().contains("the smallest piece"), "{e}");
        assert!(fit(Some(0.1), Some(0.02)).is_ok());
        // h = 1/96 here: ε = 0.005 = 0.48h needs δ > 0.0148, the ε-only override keeps the
        // default δ ≈ 1.536h = 0.016.
        assert!(fit(None, Some(0.005)).is_ok());
        let e = fit(None, Some(0.007)).unwrap_err();
        assert_eq!(e.key, OptionKey::Epsilon);
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
        let (g, q) = fit_grid(p, p, Accuracy::Tolerance(0.1), Overrides::default(), 0.0).unwrap();
        // The offset and the margin on both sides: 2·(1.536 + 1) voxels, rounded up.
        let least = (2.0 * (q.delta / g.h + MARGIN_VOXELS)).ceil() as u32;
        assert!(least == 6 && g.dims.iter().all(|&d| d >= least), "{g:?}");
    }
}
