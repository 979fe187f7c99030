//! The file formats (glTF and the trajectory CSV in, or a URDF robot and its joint CSV; depth images, meshes out), atomic writes
//! and the clock files record.

pub mod atomic;
pub mod clock;
pub mod exr_depth;
pub mod gltf_in;
pub mod gltf_out;
pub mod mesh_files;
pub mod mesh_formats;
pub mod shard_files;
pub mod trajectory;
pub mod urdf;
