//! The opened device and the helpers every stage's GPU backend uses: buffers, read-back,
//! pipelines, bind groups and dispatch, each returning [`GpuError`] instead of panicking.

use std::fmt;
use std::sync::{mpsc, Arc, Mutex};

use bytemuck::Pod;
use wgpu::util::DeviceExt;

use crate::device::{is_hardware, GpuOptions};
use crate::dispatch::{DispatchClass, DispatchSizing};
use crate::GpuError;

/// What `-v` prints about the adapter in use.
#[derive(Clone, Debug)]
pub struct AdapterSummary {
    pub name: String,
    pub backend: wgpu::Backend,
    pub device_type: wgpu::DeviceType,
    pub driver: String,
    /// A software rasteriser (lavapipe, WARP, SwiftShader) rather than GPU hardware.
    pub is_software: bool,
}

impl fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let kind = if self.is_software { "software" } else { "hardware" };
        write!(f, "{} [{}, {kind}", self.name, self.backend)?;
        if !self.driver.is_empty() {
            write!(f, ", {}", self.driver)?;
        }
        f.write_str("]")
    }
}

/// An open GPU device. Cloning is cheap (wgpu handles are reference counted), so stages
/// share one context.
#[derive(Clone, Debug)]
pub struct GpuContext {
    pub instance: wgpu::Instance,
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: AdapterSummary,
    /// How much one dispatch of a long-loop kernel takes here (crate::dispatch).
    pub dispatch: DispatchSizing,
    /// First error raised outside any error scope: wgpu's default handler would panic, so
    /// it is parked here and returned by the next scoped operation.
    uncaptured: Arc<Mutex<Option<String>>>,
}

impl GpuContext {
    /// Opens `adapter` with every limit it offers (big storage buffers and 3D textures need
    /// far more than WebGPU's defaults) and those of `options.optional_features` it supports.
    pub fn from_adapter(instance: wgpu::Instance, adapter: wgpu::Adapter, options: &GpuOptions) -> Result<Self, GpuError> {
        let raw = adapter.get_info();
        let info = AdapterSummary {
            name: raw.name.clone(),
            backend: raw.backend,
            device_type: raw.device_type,
            driver: [raw.driver.as_str(), raw.driver_info.as_str()]
                .iter()
                .filter(|s| !s.is_empty())
                .copied()
                .collect::<Vec<_>>()
                .join(" "),
            is_software: !is_hardware(raw.device_type),
        };
        let desc = wgpu::DeviceDescriptor {
            label: Some("nimbus"),
            required_features: adapter.features() & options.optional_features,
            required_limits: adapter.limits(),
            ..Default::default()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&desc))
            .map_err(|source| GpuError::RequestDevice { adapter: info.name.clone(), source })?;
        let dispatch = DispatchClass::from_env()?.map_or_else(|| DispatchSizing::for_device_type(raw.device_type), DispatchClass::sizing);
        let uncaptured = Arc::new(Mutex::new(None));
        let slot = Arc::clone(&uncaptured);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            let mut slot = slot.lock().unwrap_or_else(|p| p.into_inner());
            slot.get_or_insert_with(|| e.to_string());
        }));
        Ok(GpuContext { instance, adapter, device, queue, info, dispatch, uncaptured })
    }

    /// This context with other dispatch sizes (tests: the hardware sizes on lavapipe).
    pub fn with_dispatch(&self, dispatch: DispatchSizing) -> Self {
        GpuContext { dispatch, ..self.clone() }
    }

    pub fn limits(&self) -> wgpu::Limits {
        self.device.limits()
    }

    /// Whether R32Float / Rgba32Float textures can be linearly filtered on this device.
    pub fn float32_filterable(&self) -> bool {
        self.device.features().contains(wgpu::Features::FLOAT32_FILTERABLE)
    }

    /// `volume.wgsl` + `stage` for this device; see [`crate::compose_shader`].
    pub fn compose_shader(&self, stage: &str) -> String {
        crate::compose_shader(self.float32_filterable(), stage)
    }

    /// Runs `f` inside validation, out-of-memory and internal error scopes and returns the
    /// first error any of them (or an earlier uncaptured error) caught.
    pub fn scoped<R>(&self, context: &str, f: impl FnOnce() -> R) -> Result<R, GpuError> {
        let internal = self.device.push_error_scope(wgpu::ErrorFilter::Internal);
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let result = f();
        // Scopes pop innermost first.
        let errors = [validation.pop(), oom.pop(), internal.pop()].map(pollster::block_on);
        if let Some(e) = errors.into_iter().flatten().next() {
            return Err(GpuError::from_wgpu(context, e));
        }
        if let Some(message) = self.uncaptured.lock().unwrap_or_else(|p| p.into_inner()).take() {
            return Err(GpuError::Internal { context: format!("an earlier operation (noticed in {context})"), message });
        }
        Ok(result)
    }

    fn check_size(&self, what: &str, size: u64, storage: bool) -> Result<(), GpuError> {
        let limits = self.limits();
        let too_large = |limit: u64, limit_name| GpuError::TooLarge { what: what.to_owned(), size, limit, limit_name };
        if size > limits.max_buffer_size {
            return Err(too_large(limits.max_buffer_size, "max_buffer_size"));
        }
        if storage && size > limits.max_storage_buffer_binding_size {
            return Err(too_large(limits.max_storage_buffer_binding_size, "max_storage_buffer_binding_size"));
        }
        Ok(())
    }

    /// A storage buffer holding `data` (non-empty), usable as copy source and destination.
    pub fn storage_buffer<T: Pod>(&self, label: &str, data: &[T]) -> Result<wgpu::Buffer, GpuError> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        self.check_size(label, bytes.len() as u64, true)?;
        self.scoped(label, || {
            self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytes,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            })
        })
    }

    /// A zero-filled storage buffer of `size` bytes (a multiple of 4), e.g. for results.
    pub fn storage_buffer_zeroed(&self, label: &str, size: u64) -> Result<wgpu::Buffer, GpuError> {
        self.check_size(label, size, true)?;
        self.scoped(label, || {
            self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })
    }

    /// A stage's parameters: a buffer holding `value`, bound read-only at a
    /// [`params_entry`] (`var<storage, read>` in WGSL); update it later with
    /// `queue.write_buffer`.
    ///
    /// Not a uniform buffer: lavapipe (Mesa 22.3) inlines the uniform values a shader
    /// branches or loops on and compiles the whole pipeline again at every dispatch that
    /// binds it, keeping each compiled shader; per-dispatch values (a chunk's first voxel,
    /// a pass's first path) then cost 70-130 ms and about 10 MB of host memory a dispatch
    /// (docs/benchmarks.md, issue #49). Storage buffers are never inlined. design.md
    /// section 1.
    pub fn params_buffer<T: Pod>(&self, label: &str, value: &T) -> Result<wgpu::Buffer, GpuError> {
        self.scoped(label, || {
            self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytemuck::bytes_of(value),
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            })
        })
    }

    /// Copies `buffer` (created with COPY_SRC, size a multiple of `size_of::<T>()`) back to
    /// the host, waiting for all work submitted before it.
    pub fn read_buffer<T: Pod>(&self, buffer: &wgpu::Buffer) -> Result<Vec<T>, GpuError> {
        let label = format!("read-back of a {}-byte buffer", buffer.size());
        let size = buffer.size();
        let staging = self.scoped(&label, || {
            let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("nimbus readback"),
                size,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut encoder = self.device.create_command_encoder(&Default::default());
            encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
            self.queue.submit([encoder.finish()]);
            staging
        })?;
        let (tx, rx) = mpsc::channel();
        staging.map_async(wgpu::MapMode::Read, .., move |r| {
            // The receiver outlives the poll below; a failed send only means we already bailed.
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|e| GpuError::readback(&label, e))?
            .map_err(|e| GpuError::readback(&label, e))?;
        let data = {
            let view = staging.get_mapped_range(..).map_err(|e| GpuError::readback(&label, e))?;
            bytemuck::pod_collect_to_vec(&view)
        };
        staging.unmap();
        Ok(data)
    }

    /// Blocks until all submitted work has finished.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| GpuError::Internal { context: "waiting for the GPU".into(), message: e.to_string() })
    }

    /// Compiles `source` and builds a compute pipeline for `entry_point`. With an empty
    /// `bind_group_layouts` the layout is derived from the shader; stages that bind a
    /// [`crate::GpuVolume`] must pass explicit layouts, since a derived layout always asks for
    /// a filterable texture and filtering sampler.
    pub fn compute_pipeline(
        &self,
        label: &str,
        source: &str,
        entry_point: &str,
        bind_group_layouts: &[&wgpu::BindGroupLayout],
    ) -> Result<wgpu::ComputePipeline, GpuError> {
        self.scoped(label, || {
            let module = self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
            let layout = (!bind_group_layouts.is_empty()).then(|| {
                let layouts: Vec<Option<&wgpu::BindGroupLayout>> = bind_group_layouts.iter().copied().map(Some).collect();
                self.device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some(label),
                    bind_group_layouts: &layouts,
                    immediate_size: 0,
                })
            });
            self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: layout.as_ref(),
                module: &module,
                entry_point: Some(entry_point),
                compilation_options: Default::default(),
                cache: None,
            })
        })
    }

    pub fn bind_group_layout(&self, label: &str, entries: &[wgpu::BindGroupLayoutEntry]) -> Result<wgpu::BindGroupLayout, GpuError> {
        self.scoped(label, || {
            self.device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some(label), entries })
        })
    }

    /// A bind group over `entries`, its errors caught like every other operation's.
    pub fn bind_group(&self, label: &str, layout: &wgpu::BindGroupLayout, entries: &[wgpu::BindGroupEntry]) -> Result<wgpu::BindGroup, GpuError> {
        self.scoped(label, || self.device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some(label), layout, entries }))
    }

    /// A bind group whose binding `i` is the whole of `buffers[i]`.
    pub fn buffer_bind_group(&self, label: &str, layout: &wgpu::BindGroupLayout, buffers: &[&wgpu::Buffer]) -> Result<wgpu::BindGroup, GpuError> {
        self.bind_group(label, layout, &buffer_entries(buffers))
    }

    /// Workgroup counts covering `items` invocations of a `workgroup_size`-wide kernel,
    /// spread over y and z once x reaches `max_compute_workgroups_per_dimension` (65535 on
    /// most devices, i.e. 4M items at size 64). The shader recovers the flat index with
    /// `dispatch_linear_index` and must skip indices >= items.
    pub fn workgroups_1d(&self, items: u64, workgroup_size: u32) -> Result<[u32; 3], GpuError> {
        split_workgroups(items, workgroup_size, self.limits().max_compute_workgroups_per_dimension)
    }

    /// Records and submits one compute pass (without waiting): `bind_groups[i]` at group i.
    pub fn dispatch(
        &self,
        label: &str,
        pipeline: &wgpu::ComputePipeline,
        bind_groups: &[&wgpu::BindGroup],
        workgroups: [u32; 3],
    ) -> Result<(), GpuError> {
        self.scoped(label, || {
            let mut encoder = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(label), timestamp_writes: None });
                pass.set_pipeline(pipeline);
                for (i, group) in bind_groups.iter().enumerate() {
                    pass.set_bind_group(i as u32, *group, &[]);
                }
                let [x, y, z] = workgroups;
                pass.dispatch_workgroups(x, y, z);
            }
            self.queue.submit([encoder.finish()]);
        })
    }

    /// [`Self::dispatch`] over `items` invocations of a 1D kernel (see [`Self::workgroups_1d`]).
    pub fn dispatch_1d(
        &self,
        label: &str,
        pipeline: &wgpu::ComputePipeline,
        bind_groups: &[&wgpu::BindGroup],
        items: u64,
        workgroup_size: u32,
    ) -> Result<(), GpuError> {
        let workgroups = self.workgroups_1d(items, workgroup_size)?;
        self.dispatch(label, pipeline, bind_groups, workgroups)
    }
}

/// See [`GpuContext::workgroups_1d`]; separate so the arithmetic is testable without a device.
pub fn split_workgroups(items: u64, workgroup_size: u32, max_per_dim: u32) -> Result<[u32; 3], GpuError> {
    let groups = items.div_ceil(u64::from(workgroup_size.max(1)));
    let max = u64::from(max_per_dim.max(1));
    let x = groups.clamp(1, max);
    let y = groups.div_ceil(x).clamp(1, max);
    let z = groups.div_ceil(x * y).max(1);
    if z > max {
        return Err(GpuError::TooLarge {
            what: format!("a dispatch of {items} items"),
            size: items,
            limit: max * max * max * u64::from(workgroup_size),
            limit_name: "max_compute_workgroups_per_dimension^3 x workgroup size",
        });
    }
    Ok([x as u32, y as u32, z as u32])
}

/// Bind group entries whose binding `i` is the whole of `buffers[i]`.
pub(crate) fn buffer_entries<'a>(buffers: &[&'a wgpu::Buffer]) -> Vec<wgpu::BindGroupEntry<'a>> {
    buffers.iter().enumerate().map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() }).collect()
}

/// Layout entry for a storage buffer visible to compute shaders.
pub fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    buffer_entry(binding, wgpu::BufferBindingType::Storage { read_only })
}

/// Layout entry for a stage's parameters ([`GpuContext::params_buffer`]): a read-only
/// storage buffer, never a uniform one.
pub fn params_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    storage_entry(binding, true)
}

fn buffer_entry(binding: u32, ty: wgpu::BufferBindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
        count: None,
    }
}
