//! The report written beside the outputs (`<name>.report.json`): what was computed, from what,
//! with which parameters, and the guarantee in world units.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::input::grid::Grid;
use crate::input::motion::MotionReport;
use crate::input::posed::PartRange;
use crate::mesh::ManifoldDefects;
use crate::simplify::SimplifyStats;

/// What the report's `hausdorff_bound` covers (paper, section 4).
pub(super) const HAUSDORFF_SCOPE: &str = "wherever the swept volume's concavities are visible along some axis; concavities hidden from all six directions are filled and can lie farther: measure with sweptvol verify";

/// What the bound covers with the flood classification: everything.
pub(super) const HAUSDORFF_SCOPE_FLOOD: &str = "everywhere: the flood from outside opens every concavity it can reach without crossing the rendered offset, so no pocket is filled (voids sealed inside the swept volume are filled, and have no surface)";

/// How the voxels were classified, and why (`--classify`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ClassificationReport {
    /// `flood` (condition ⋆ less the flood from outside) or `axes` (condition ⋆ alone).
    pub method: String,
    /// What was asked: `auto`, `flood` or `axes`.
    pub asked: String,
    pub reason: String,
    /// Voxels whose centres the rendered offset covers (flood only).
    pub reach_voxels: Option<u64>,
    /// Voxels the flood from outside reaches (flood only).
    pub flooded_voxels: Option<u64>,
    /// Seconds spent on the flood (flood only; part of `timings.mesh`). The reach is set by
    /// the sweep's x axis on the way (part of `timings.sweep`).
    pub flood_seconds: Option<f64>,
}

/// The report written beside the depth images (`<name>.report.json`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Report {
    pub sweptvol_version: String,
    pub inputs: InputsReport,
    pub grid: Grid,
    /// Voxels along the longest edge (the paper's n).
    pub resolution: u32,
    pub parameters: ParametersReport,
    /// The motion between rows: the model, the budget μ, the poses rendered.
    pub motion: MotionReport,
    pub classification: ClassificationReport,
    pub backend: String,
    pub counts: CountsReport,
    /// Seconds per stage.
    pub timings: TimingsReport,
    pub outputs: Vec<PathBuf>,
    pub depth_images: DepthImagesReport,
    pub mesh: MeshReport,
    /// With obstacles (`against`): each one's clearance from the swept volume.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clearance: Option<crate::clearance::ClearanceSection>,
    pub warnings: Vec<String>,
}

/// The output mesh. Distances in world units.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MeshReport {
    pub file: PathBuf,
    /// Triangles of the voxel boundary (the paper's T_start) and of the output (T_final).
    pub triangles_start: u64,
    pub triangles_final: u64,
    pub vertices: u64,
    /// Every edge in exactly two triangles, every vertex's triangles one fan, no two vertices
    /// at one position (checked on the output; `manifold_defects` counts what is not).
    pub manifold: bool,
    pub manifold_defects: ManifoldDefects,
    /// Outside voxels made inside so that voxels touching only along an edge or at a corner
    /// are joined (the start mesh is then a 2-manifold).
    pub joined_voxels: u64,
    /// How far a point of a joined voxel can be from the centre of an original inside voxel,
    /// world units (0 when none was joined); enters `hausdorff_bound` when it exceeds ε + √3h/2.
    pub joined_voxel_reach: f64,
    /// Whether the output was simplified (edge collapses inside the tolerance volume).
    pub simplified: bool,
    /// Collapses done and candidates refused, by reason.
    pub simplification: SimplifyStats,
    /// Enclosed volume, world units³.
    pub volume: f64,
    /// Guaranteed one-sided Hausdorff distance from the mesh to the swept volume wherever its
    /// concavities are visible along some axis: max(ε + √3h/2, joined voxel reach) + δ + μ +
    /// 2ρ + output rounding (μ: the motion budget, 0 for discrete motion).
    pub hausdorff_bound: f64,
    /// Where `hausdorff_bound` holds, in words (it is not a global bound).
    pub hausdorff_bound_scope: String,
    /// Every point of the mesh is at least this far outside the swept volume (of the whole
    /// motion for screw motion: μ is rendered beyond δ and spent again on the motion between
    /// sub-poses): δ - √3h/2 - ε - output rounding.
    pub clearance: f64,
    /// Farthest a vertex moves when written as f32 (Euclidean, world units).
    pub output_rounding: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct InputsReport {
    pub generator: PathBuf,
    pub trajectory: PathBuf,
    /// The node whose frame the outputs are in (`relative_to`); none: the world.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relative_to: Option<String>,
    /// What the trajectory's rows are: world-space transforms, or each node's own relative to
    /// its parent (`local`; a robot's joint rows).
    #[serde(default)]
    pub rows: crate::input::model::Rows,
    /// Where a robot's `package://` meshes were looked for.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub package_dir: Vec<PathBuf>,
    pub parts: Vec<PartRange>,
    /// Parts that no trajectory row names: included once where they stand.
    pub static_parts: Vec<String>,
}

/// Distances in world units.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ParametersReport {
    /// The rule δ and ε were taken from where not given: "exact" or "paper".
    pub radii: crate::input::grid::Radii,
    pub voxel_size: f64,
    pub delta: f64,
    pub epsilon: f64,
    pub sigma: f64,
    /// Added to δ against f32 rounding (derived in `input::posed::rounding_term`).
    pub rounding: f64,
    /// The radius rendered: δ + μ (the motion budget) + rounding.
    pub delta_rendered: f64,
    /// Every depth lies within the offset of radius δ + μ + 2·rounding of the rendered poses.
    pub delta_upper: f64,
    /// The paper's ε_global = ε + δ + σ for the mesh stage, plus μ for screw motion.
    pub epsilon_global: f64,
    /// The tolerance volume's radius about voxel centres, ε + √3h/2 (docs/design.md).
    pub tolerance_radius: f64,
    /// Every point a collapse sweeps over is within this of an outside voxel's centre.
    pub sweep_radius: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CountsReport {
    pub triangles: u64,
    pub poses: u64,
    pub posed_triangles: u64,
    /// Pixels hit per image axis (x, y, z).
    pub hit_pixels: [u64; 3],
}

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct TimingsReport {
    pub read_inputs: f64,
    pub setup: f64,
    pub sweep: f64,
    /// Voxel classification and boundary extraction.
    pub mesh: f64,
    /// Bounded edge collapses.
    pub simplify: f64,
    pub write_outputs: f64,
    pub total: f64,
    /// Posed triangles per second in the sweep stage.
    pub posed_triangles_per_second: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct DepthImagesReport {
    pub layout: String,
    pub empty_pixels: String,
    pub files: Vec<PathBuf>,
}
