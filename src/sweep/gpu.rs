//! The sweep on wgpu: `shaders/sweep.wgsl` run as a compute shader. A [`Gpu`] is acquired once
//! (adapter, device, pipeline) and reused for every sweep, as a long-running daemon needs.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use anyhow::{anyhow, Context};
use bytemuck::{Pod, Zeroable};

use super::{empty_encoded, Cancelled, Observer};
use crate::depth::DepthImages;
use crate::depth::SLOTS;
use crate::input::posed::SweepInput;
use crate::voxels::VoxelBits;

pub const SHADER_SOURCE: &str = include_str!("../../shaders/sweep.wgsl");
const WORKGROUP_SIZE: u32 = 64;
const MAX_WORKGROUPS: u32 = 65535;
/// Posed triangles per dispatch: large enough to fill a big GPU, small enough that progress and
/// cancellation come several times a second on lavapipe.
const POSED_TRIANGLES_PER_DISPATCH: u64 = 1 << 23;
/// One pose: a row-major 3x4 f32 matrix.
const POSE_BYTES: u64 = 48;

/// Must match `Params` in shaders/sweep.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuParams {
    tri_start: u32,
    tri_count: u32,
    pose_start: u32,
    pose_count: u32,
    dims: [u32; 3],
    radius: f32,
    /// Bit 0: also set the reach.
    flags: u32,
    pad: [u32; 3],
}

/// A wgpu device ready to sweep.
pub struct Gpu {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::ComputePipeline,
    pub info: wgpu::AdapterInfo,
}

/// The buffers one kind of dispatch reads: its pipeline, its bind group (binding 0 the
/// parameters, 2 the poses) and those two buffers.
struct Dispatch {
    bind_group: wgpu::BindGroup,
    params: wgpu::Buffer,
    poses: wgpu::Buffer,
    pose_capacity: u32,
}

/// Rank adapters: hardware GPUs first, CPU adapters (lavapipe) last.
fn preference(info: &wgpu::AdapterInfo) -> u32 {
    use wgpu::DeviceType::*;
    match info.device_type {
        DiscreteGpu => 0,
        IntegratedGpu => 1,
        VirtualGpu => 2,
        Other => 3,
        Cpu => 4,
    }
}

/// Whether an adapter is a CPU implementation (lavapipe, llvmpipe, WARP).
pub fn is_cpu_adapter(info: &wgpu::AdapterInfo) -> bool {
    info.device_type == wgpu::DeviceType::Cpu
}

impl Gpu {
    /// The best adapter on Vulkan, Metal or DX12. With `allow_cpu_adapter` false, CPU adapters
    /// are not taken (`--backend auto` then falls back to the CPU twin, which is faster).
    /// Returns Ok(None) when no suitable adapter exists.
    pub fn acquire(allow_cpu_adapter: bool) -> anyhow::Result<Option<Gpu>> {
        // Vulkan, Metal, DX12 only (WGPU_BACKEND may narrow it further): the GL backend has no
        // storage-buffer atomics on many drivers and probing it logs EGL noise.
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        desc.backends &= wgpu::Backends::PRIMARY;
        let instance = wgpu::Instance::new(desc);
        let mut adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::PRIMARY));
        adapters.retain(|a| allow_cpu_adapter || !is_cpu_adapter(&a.get_info()));
        adapters.retain(|a| {
            a.get_downlevel_capabilities()
                .flags
                .contains(wgpu::DownlevelFlags::COMPUTE_SHADERS)
        });
        adapters.sort_by_key(|a| preference(&a.get_info()));
        let Some(adapter) = adapters.into_iter().next() else {
            return Ok(None);
        };
        let info = adapter.get_info();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("sweptvol"),
            required_features: wgpu::Features::empty(),
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .with_context(|| format!("could not open the GPU device {}", info.name))?;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("sweep.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER_SOURCE.into()),
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("sweep"),
            layout: None,
            module: &module,
            entry_point: Some("sweep_main"),
            compilation_options: Default::default(),
            cache: None,
        });
        Ok(Some(Gpu {
            device,
            queue,
            pipeline,
            info,
        }))
    }

    /// A one-line description of the adapter for logs and reports.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.device_type, self.info.backend
        )
    }

    fn storage(&self, label: &str, bytes: &[u8], extra: wgpu::BufferUsages) -> wgpu::Buffer {
        // Bindings may not be empty: pad to one word.
        let size = (bytes.len() as u64).max(4);
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | extra,
            mapped_at_creation: false,
        });
        if !bytes.is_empty() {
            self.queue.write_buffer(&buffer, 0, bytes);
        }
        buffer
    }

    /// Render every posed triangle of `input` into fresh depth images.
    pub fn sweep(
        &self,
        input: &SweepInput,
        observer: &dyn Observer,
    ) -> anyhow::Result<DepthImages> {
        Ok(self.render(input, observer, false)?.0)
    }

    /// The same, and the offset's reach from the x axis's ray casts on the way (`sweep::reach`'s
    /// bits); None for the reach when its bits exceed what one GPU buffer may hold.
    pub fn sweep_with_reach(
        &self,
        input: &SweepInput,
        observer: &dyn Observer,
    ) -> anyhow::Result<(DepthImages, Option<VoxelBits>)> {
        self.render(input, observer, true)
    }

    fn render(
        &self,
        input: &SweepInput,
        observer: &dyn Observer,
        want_reach: bool,
    ) -> anyhow::Result<(DepthImages, Option<VoxelBits>)> {
        let encoded = empty_encoded(input);
        let image_bytes: u64 = encoded
            .iter()
            .map(|e| 4 * e.len() as u64)
            .max()
            .unwrap_or(0);
        let tris = self.input_buffers(input, image_bytes)?;
        let images: Vec<wgpu::Buffer> = encoded
            .iter()
            .enumerate()
            .map(|(a, e)| {
                self.storage(
                    &format!("image {a}"),
                    bytemuck::cast_slice(e),
                    wgpu::BufferUsages::COPY_SRC,
                )
            })
            .collect();
        drop(encoded);
        let d = input.grid.dims;
        let dims = [d[0] as usize, d[1] as usize, d[2] as usize];
        let limits = self.device.limits();
        let binding_limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let reach_bytes = VoxelBits::bytes_for(dims);
        let reach = want_reach && reach_bytes <= binding_limit;
        // The reach's bits, zeroed; a one-word placeholder when not wanted (sweep_main binds it).
        let bits = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("reach"),
            size: if reach { reach_bytes.max(4) } else { 4 },
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let dispatch = self.dispatch(
            input,
            &tris,
            &[
                (3, &images[0]),
                (4, &images[1]),
                (5, &images[2]),
                (6, &bits),
            ],
        );
        self.dispatch_all(input, &dispatch, observer, reach as u32)?;
        let mut out = Vec::with_capacity(3);
        for buffer in &images {
            out.push(self.read_back(buffer)?);
        }
        let encoded: [Vec<u32>; 3] = out.try_into().map_err(|_| anyhow!("three images"))?;
        debug_assert!(encoded.iter().all(|e| e.len() % SLOTS == 0));
        let images = DepthImages::from_encoded(input.grid, encoded);
        if !reach {
            return Ok((images, None));
        }
        let words: Vec<u64> = self
            .read_back(&bits)?
            .chunks_exact(2)
            .map(|w| w[0] as u64 | (w[1] as u64) << 32)
            .collect();
        Ok((images, Some(VoxelBits::from_words(dims, words))))
    }

    /// Check that the input and an output of `output_bytes` fit the device's buffers, and
    /// upload the triangles.
    fn input_buffers(&self, input: &SweepInput, output_bytes: u64) -> anyhow::Result<wgpu::Buffer> {
        let limits = self.device.limits();
        let pose_bytes = POSE_BYTES * pose_capacity(input) as u64;
        let input_bytes = (36 * input.triangles.len() as u64).max(pose_bytes);
        let binding_limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        if output_bytes.max(input_bytes) > binding_limit {
            return Err(crate::error::OptionError::new(
                crate::error::OptionKey::Backend,
                format!(
                    "the sweep needs a {} MiB GPU buffer but {} allows {} MiB; lower $resolution or set $backend to cpu",
                    output_bytes.max(input_bytes) >> 20,
                    self.info.name,
                    binding_limit >> 20
                ),
            )
            .into());
        }
        Ok(self.storage(
            "triangles",
            bytemuck::cast_slice(&input.triangles),
            wgpu::BufferUsages::empty(),
        ))
    }

    /// The parameters, the pose buffer and the bind group of `pipeline` over `tris` and the
    /// output buffers at their bindings.
    fn dispatch(
        &self,
        input: &SweepInput,
        tris: &wgpu::Buffer,
        outputs: &[(u32, &wgpu::Buffer)],
    ) -> Dispatch {
        // Poses go up one dispatch's worth at a time into a buffer of at most MAX_WORKGROUPS
        // poses (3 MiB): the sub-poses of a motion are made on demand, never all stored.
        let pose_capacity = pose_capacity(input);
        let poses = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("poses"),
            size: POSE_BYTES * pose_capacity as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let params = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("params"),
            size: std::mem::size_of::<GpuParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut entries = vec![entry(0, &params), entry(1, tris), entry(2, &poses)];
        entries.extend(outputs.iter().map(|&(binding, b)| entry(binding, b)));
        let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("sweep"),
            layout: &self.pipeline.get_bind_group_layout(0),
            entries: &entries,
        });
        Dispatch {
            bind_group,
            params,
            poses,
            pose_capacity,
        }
    }

    /// Run `dispatch` over every posed triangle of `input`, one dispatch per batch of
    /// triangles × poses, with `flags` for the shader.
    fn dispatch_all(
        &self,
        input: &SweepInput,
        dispatch: &Dispatch,
        observer: &dyn Observer,
        flags: u32,
    ) -> anyhow::Result<()> {
        let total = input.posed_triangles();
        let done = Arc::new(AtomicU64::new(0));
        let mut previous: Option<wgpu::SubmissionIndex> = None;
        let mut pose_batch = Vec::with_capacity(dispatch.pose_capacity as usize);
        let max_tris_per_dispatch = MAX_WORKGROUPS * WORKGROUP_SIZE;
        for (index, part) in input.parts.iter().enumerate() {
            let mut tri_offset = 0;
            while tri_offset < part.tri_count {
                let tri_count = (part.tri_count - tri_offset).min(max_tris_per_dispatch);
                let batch = (POSED_TRIANGLES_PER_DISPATCH / tri_count as u64)
                    .clamp(1, MAX_WORKGROUPS as u64) as u32;
                let mut pose_offset = 0;
                while pose_offset < part.pose_count {
                    if observer.cancelled() {
                        self.wait(None)?;
                        return Err(Cancelled.into());
                    }
                    let pose_count = (part.pose_count - pose_offset).min(batch);
                    // This dispatch's poses, made while the one before runs. The queue writes
                    // them after the work already submitted (which reads the buffer's old
                    // contents) and before this dispatch, like the parameters.
                    let first = pose_offset as u64;
                    input
                        .poses
                        .fill(index, first..first + pose_count as u64, &mut pose_batch);
                    self.queue
                        .write_buffer(&dispatch.poses, 0, bytemuck::cast_slice(&pose_batch));
                    let p = GpuParams {
                        tri_start: part.tri_start + tri_offset,
                        tri_count,
                        pose_start: 0,
                        pose_count,
                        dims: input.grid.dims,
                        radius: input.radius,
                        flags,
                        pad: [0; 3],
                    };
                    self.queue
                        .write_buffer(&dispatch.params, 0, bytemuck::bytes_of(&p));
                    let mut encoder = self.device.create_command_encoder(&Default::default());
                    {
                        let mut pass = encoder.begin_compute_pass(&Default::default());
                        pass.set_pipeline(&self.pipeline);
                        pass.set_bind_group(0, &dispatch.bind_group, &[]);
                        pass.dispatch_workgroups(tri_count.div_ceil(WORKGROUP_SIZE), pose_count, 1);
                    }
                    let index = self.queue.submit([encoder.finish()]);
                    let work = tri_count as u64 * pose_count as u64;
                    let counter = done.clone();
                    self.queue.on_submitted_work_done(move || {
                        counter.fetch_add(work, Ordering::Relaxed);
                    });
                    // At most two submissions in flight: the GPU stays busy, progress stays fresh.
                    if let Some(prev) = previous.replace(index) {
                        self.wait(Some(prev))?;
                    }
                    observer.progress(done.load(Ordering::Relaxed), total);
                    pose_offset += pose_count;
                }
                tri_offset += tri_count;
            }
        }
        self.wait(None)?;
        observer.progress(done.load(Ordering::Relaxed), total);
        Ok(())
    }

    fn wait(&self, index: Option<wgpu::SubmissionIndex>) -> anyhow::Result<()> {
        self.device
            .poll(wgpu::PollType::Wait {
                submission_index: index,
                timeout: None,
            })
            .map(|_| ())
            .map_err(|e| anyhow!("GPU device error while sweeping: {e}"))
    }

    fn read_back(&self, buffer: &wgpu::Buffer) -> anyhow::Result<Vec<u32>> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read back"),
            size: buffer.size(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, buffer.size());
        self.queue.submit([encoder.finish()]);
        let slice = staging.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait(None)?;
        rx.recv()
            .map_err(|_| anyhow!("GPU read-back was dropped"))?
            .map_err(|e| anyhow!("GPU read-back failed: {e}"))?;
        let data = {
            let view = slice
                .get_mapped_range()
                .map_err(|e| anyhow!("GPU read-back failed: {e:?}"))?;
            bytemuck::cast_slice::<u8, u32>(&view).to_vec()
        };
        staging.unmap();
        Ok(data)
    }
}

/// Poses one dispatch holds at most: the largest part's pose count, at most MAX_WORKGROUPS.
fn pose_capacity(input: &SweepInput) -> u32 {
    input
        .parts
        .iter()
        .map(|p| p.pose_count)
        .max()
        .unwrap_or(1)
        .clamp(1, MAX_WORKGROUPS)
}

fn entry(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: buffer.as_entire_binding(),
    }
}
