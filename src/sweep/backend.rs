//! Which backend sweeps: a GPU device through wgpu (acquired once, reusable) or the CPU twin.

use serde::Serialize;

use super::gpu::Gpu;
use super::{cpu, reach, Observer};
use crate::depth::DepthImages;
use crate::error::{OptionError, OptionKey};
use crate::input::posed::SweepInput;
use crate::voxels::VoxelBits;

/// Which sweep implementation runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum BackendChoice {
    /// A hardware GPU if there is one, else the CPU twin.
    Auto,
    /// wgpu on any adapter, CPU adapters such as lavapipe included.
    Gpu,
    /// The CPU twin (rayon).
    Cpu,
}

/// A resolved backend: a GPU device (acquired once, reusable) or the CPU twin.
pub enum Backend {
    Gpu(Box<Gpu>),
    Cpu { reason: String },
}

impl Backend {
    /// Resolve a choice. `gpu` fails when no adapter exists; `auto` says why it falls back.
    pub fn acquire(choice: BackendChoice) -> anyhow::Result<Backend> {
        match choice {
            BackendChoice::Cpu => Ok(Backend::Cpu {
                reason: crate::error::plain("$backend cpu"),
            }),
            BackendChoice::Gpu => match Gpu::acquire(true)? {
                Some(g) => Ok(Backend::Gpu(Box::new(g))),
                None => Err(OptionError::new(
                    OptionKey::Backend,
                    "$backend gpu: no Vulkan/Metal/DX12 adapter with compute shaders found; install a driver (on Debian, lavapipe: apt-get install mesa-vulkan-drivers libvulkan1) or set $backend to cpu",
                )
                .into()),
            },
            BackendChoice::Auto => match Gpu::acquire(false)? {
                Some(g) => Ok(Backend::Gpu(Box::new(g))),
                None => Ok(Backend::Cpu {
                    reason: "no hardware GPU adapter found: falling back to the CPU twin".into(),
                }),
            },
        }
    }

    pub fn describe(&self) -> String {
        match self {
            Backend::Gpu(g) => format!("gpu: {}", g.describe()),
            Backend::Cpu { reason } => {
                format!("cpu: {} threads ({reason})", rayon::current_num_threads())
            }
        }
    }

    pub fn sweep(
        &self,
        input: &SweepInput,
        observer: &dyn Observer,
    ) -> anyhow::Result<DepthImages> {
        match self {
            Backend::Gpu(g) => g.sweep(input, observer),
            Backend::Cpu { .. } => Ok(cpu::sweep(input, observer)?),
        }
    }

    /// The sweep, and the voxels the offset reaches (`sweep::reach`) from the x axis's ray
    /// casts on the way. On a GPU whose buffers cannot hold the bits, the reach is computed on
    /// the CPU afterwards (said in the log).
    pub fn sweep_with_reach(
        &self,
        input: &SweepInput,
        observer: &dyn Observer,
    ) -> anyhow::Result<(DepthImages, VoxelBits)> {
        match self {
            Backend::Gpu(g) => {
                let (images, bits) = g.sweep_with_reach(input, observer)?;
                if let Some(bits) = bits {
                    return Ok((images, bits));
                }
                tracing::warn!(
                    "the flood's reach needs {} MiB, more than one buffer of {} holds: computing it on the CPU",
                    VoxelBits::bytes_for(input.grid.dims.map(|d| d as usize)) >> 20,
                    g.describe()
                );
                Ok((images, reach::reach(input, observer)?))
            }
            Backend::Cpu { .. } => Ok(cpu::sweep_with_reach(input, observer)?),
        }
    }
}
