//! The only code that touches files: glTF in, trajectory CSV in, depth images out.

pub mod atomic;
pub mod exr_depth;
pub mod gltf_in;
pub mod gltf_out;
pub mod mesh_formats;
pub mod trajectory;
