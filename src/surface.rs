//! The mesh stage as one function of the swept images: voxels classified by condition ⋆ (less
//! what a flood from outside reaches, where the job floods), pinches joined so the boundary is
//! a 2-manifold, and that boundary simplified block by block within the tolerance volume
//! (paper sections 4 and 5; docs/design.md). No files: `pipeline::finish` writes what this
//! returns, and the tests call it as the pipeline does.

use std::time::Instant;

use crate::depth::DepthImages;
use crate::mesh::classify::Classifier;
use crate::mesh::extract;
use crate::mesh::flood;
use crate::mesh::manifold::Joined;
use crate::mesh::Mesh;
use crate::simplify::blocked::{simplify_boundary, BLOCK_VOXELS};
use crate::simplify::pieces::Pieces;
use crate::simplify::{SimplifyOptions, SimplifyStats};
use crate::voxels::VoxelBits;

/// How to build the mesh.
#[derive(Clone, Copy, Debug)]
pub struct Params {
    pub simplify: SimplifyOptions,
    /// Also return the unsimplified voxel boundary (the whole start mesh at once: memory).
    pub keep_start_mesh: bool,
    /// Voxels along each edge of a simplification block.
    pub block: usize,
}

impl Params {
    pub fn new(simplify: SimplifyOptions) -> Self {
        Params {
            simplify,
            keep_start_mesh: false,
            block: BLOCK_VOXELS,
        }
    }
}

/// What the mesh stage made, grid units, with the figures the report states.
#[derive(Clone, Debug)]
pub struct Surface {
    /// The simplified boundary: a closed 2-manifold enclosing the swept volume.
    pub mesh: Mesh,
    pub stats: SimplifyStats,
    pub triangles_start: u64,
    /// The voxel boundary, when asked for.
    pub start_mesh: Option<Mesh>,
    /// Whether a flood carved the classification (the bound then holds everywhere).
    pub carved: bool,
    pub reach_voxels: Option<u64>,
    pub flooded_voxels: Option<u64>,
    pub flood_seconds: Option<f64>,
    /// Voxels the pinch join added, and how far (voxels) a point of one lies from the nearest
    /// original inside voxel's centre.
    pub joined_voxels: u64,
    pub joined_reach: f64,
    /// Seconds classifying (flood and join included), and simplifying (extraction included).
    pub classify_seconds: f64,
    pub simplify_seconds: f64,
}

/// Build the swept volume's mesh from its six depth images and, where the job floods, the
/// offset's reach; `pieces`, the swept volume's connected pieces ([`Pieces::of`] the job's
/// input), make the sweep check exact and cheap (without them the region tests decide). None
/// when `stop` said yes (asked between blocks and batches).
pub fn build(
    images: &DepthImages,
    reach: Option<VoxelBits>,
    pieces: Option<&Pieces>,
    params: &Params,
    stop: &(dyn Fn() -> bool + Sync),
) -> Option<Surface> {
    let t0 = Instant::now();
    let mut classifier = Classifier::new(images);
    let (mut reach_voxels, mut flooded_voxels, mut flood_seconds) = (None, None, None);
    if let Some(reach) = reach {
        let t = Instant::now();
        let flooded = flood::flood(&reach);
        flood_seconds = Some(t.elapsed().as_secs_f64());
        reach_voxels = Some(reach.count());
        flooded_voxels = Some(flooded.count());
        drop(reach);
        classifier = classifier.carve(flooded);
    }
    let classifier = classifier.solidify();
    if stop() {
        return None;
    }
    // Where voxels touch only along an edge or at a corner, outside voxels join them so the
    // start mesh is a 2-manifold; the simplifier keeps it one. The tolerance volume stays that
    // of the classifier's voxels (docs/design.md, "A 2-manifold start mesh").
    let joined = Joined::new(&classifier);
    let (joined_voxels, joined_reach) = (joined.added().len() as u64, joined.reach());
    let start_mesh = params.keep_start_mesh.then(|| extract::extract(&joined));
    let t1 = Instant::now();
    let simplified = simplify_boundary(
        &joined,
        &classifier,
        pieces,
        params.simplify,
        params.block,
        stop,
    )?;
    Some(Surface {
        mesh: simplified.mesh,
        stats: simplified.stats,
        triangles_start: simplified.triangles_start,
        start_mesh,
        carved: classifier.is_carved(),
        reach_voxels,
        flooded_voxels,
        flood_seconds,
        joined_voxels,
        joined_reach,
        classify_seconds: (t1 - t0).as_secs_f64(),
        simplify_seconds: t1.elapsed().as_secs_f64(),
    })
}
