//! sweptvol: conservative swept volumes of triangle meshes along discrete trajectories.
//!
//! The modules follow the data, one way (docs/design.md has the arguments; tests/layout.rs
//! fails on any import circle, between files or top-level modules):
//!
//! - [`io`]: the file formats, glTF and CSV in, EXR, glTF, STL, PLY, OBJ out, the shard files,
//!   and atomic writes. (Not the only code that touches files: `pipeline` checks existing
//!   outputs, `cluster` writes its scripts, `watch` its status files, lock and scans.)
//! - [`input`]: parts and poses become the sweep's input in grid units, with the voxel grid, the
//!   parameters (δ, ε), the f32 rounding term ρ and the memory estimate.
//! - [`sweep`]: the δ-offset of every posed triangle ray cast into six depth images, on the GPU
//!   (wgpu) or its CPU twin (paper section 4); [`sweep::backend`] chooses which.
//! - [`depth`]: the six images and their encoding, the contract between the sweep and the mesh
//!   stage (it imports nothing from `sweep`).
//! - [`voxels`]: one bit per voxel, for the offset's reach ([`sweep::reach`]), the flood and the
//!   classes.
//! - [`mesh`]: voxels classified by condition ⋆ ([`mesh::classify`]) less what a flood from
//!   outside reaches ([`mesh::flood`]), pinches joined so the
//!   boundary is a 2-manifold ([`mesh::manifold`]), the voxel boundary extracted
//!   ([`mesh::extract`]), or one block's patch of it ([`mesh::blocks`]).
//! - [`simplify`]: edge collapses inside the tolerance volume (paper section 5), block by block
//!   and then along the seams ([`simplify::blocked`]): quadric costs, a queue, per-region checks
//!   (band, sweep, topology), then the self-intersection check and the commit.
//! - [`surface`]: the mesh stage as one function, images in, mesh out, for every caller.
//! - [`job`]: a job's options as one typed value, job.json's schema and the command line's.
//! - [`pipeline`]: one run, files in to files out, with its named outputs and its report;
//!   [`watch`] and `main.rs` are its shells, and [`cluster`] runs it on SLURM in shards.
//! - [`verify`]: an independent certificate for any swept-volume mesh.
//! - [`clearance`]: how far the swept volume stays from obstacles, as a guaranteed interval
//!   (`pipeline::clearance` runs it on files); [`closest`], the exact closest points it shares
//!   with the simplifier; [`union_find`], the connected components `verify` and the simplifier
//!   both count.

pub mod clearance;
pub mod closest;
pub mod cluster;
pub mod depth;
pub mod error;
pub mod input;
pub mod io;
pub mod job;
pub mod mesh;
pub mod pipeline;
pub mod simplify;
pub mod surface;
pub mod sweep;
pub mod union_find;
pub mod verify;
pub mod voxels;
pub mod watch;
