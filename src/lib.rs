//! sweptvol: conservative swept volumes of triangle meshes along discrete trajectories.
//!
//! Data flows one way: inputs (`io`) -> `job` (parts, poses, grid) -> `sweep`
//! (GPU or its CPU twin) -> `depth::DepthImages`, the contract with the mesh stage.

pub mod band;
pub mod depth;
pub mod error;
pub mod extract;
pub mod grid;
pub mod intersect;
pub mod io;
pub mod job;
pub mod manifold;
pub mod memory;
pub mod mesh;
pub mod model;
pub mod pipeline;
pub mod simplify;
pub mod sweep;
pub mod verify;
pub mod voxel;
pub mod watch;
