//! The input stage: parts and poses as read ([`model`]) become the sweep's input in grid units
//! ([`posed`]): which poses move which part, the voxel grid and the method's parameters
//! ([`grid`]), pose matrices in grid units and the f32 rounding term; [`poses`] makes the poses
//! (sub-poses of the motion included) on demand; [`memory`] estimates what a run on that grid
//! needs before anything large is allocated; [`outline`] keeps the vertices that can be extreme,
//! for the bounds taken over every row.

pub mod chain;
pub mod grid;
pub mod memory;
pub mod model;
pub mod motion;
pub mod outline;
pub mod posed;
pub mod poses;
pub mod relative;
