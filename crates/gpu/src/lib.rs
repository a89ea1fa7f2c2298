//! The wgpu layer under every nimbus stage's GPU backend.
//!
//! # Choosing a device
//!
//! Each tool takes `--device auto|cpu|gpu` ([`DeviceChoice`], parsed with `FromStr`, or as a
//! `clap::ValueEnum` with this crate's `clap` feature) and resolves it once:
//!
//! ```no_run
//! use nimbus_gpu::{ComputeDevice, DeviceChoice};
//! let device = "auto".parse::<DeviceChoice>()?.resolve()?;
//! eprintln!("device: {device}"); // what -v prints
//! match &device {
//!     ComputeDevice::Cpu(_) => { /* rayon backend */ }
//!     ComputeDevice::Gpu(ctx) => { /* wgpu backend, ctx: &GpuContext */ }
//! }
//! # Ok::<(), nimbus_gpu::GpuError>(())
//! ```
//!
//! `auto` takes a hardware adapter (discrete, integrated or virtual GPU) and otherwise the CPU
//! backend; `gpu` also accepts a software adapter (Mesa lavapipe, how CI runs the GPU code)
//! and is an error, never a panic, when there is no adapter at all; `cpu` creates no wgpu
//! object. The device is opened with every limit the adapter offers (large storage buffers
//! and 3D textures) and with FLOAT32_FILTERABLE where available. Backends default to
//! Vulkan/Metal/DX12, overridable with `WGPU_BACKEND`.
//!
//! # Helpers
//!
//! [`GpuContext`] wraps buffer creation ([`GpuContext::storage_buffer`],
//! [`GpuContext::params_buffer`]), read-back ([`GpuContext::read_buffer`]), pipelines from
//! WGSL ([`GpuContext::compute_pipeline`]) and dispatch of 1D workloads of any size
//! ([`GpuContext::dispatch_1d`], split over a 3D grid of workgroups; the shader side is
//! `dispatch_linear_index`). All of them run inside wgpu error scopes
//! ([`GpuContext::scoped`]), so a WGSL compile error, a validation error or an out-of-memory
//! becomes a [`GpuError`]; errors raised outside any scope are parked and reported by the next
//! scoped call rather than panicking.
//!
//! # Software adapters' loop cap
//!
//! llvmpipe (lavapipe) silently ends loops once a SIMD group has run 65535 iterations; every
//! stage guards against it through [`GpuContext::check_loop_bound`] (before dispatch, where
//! an invocation's iterations can be bounded) or [`LoopGuard`] (a flag the shader raises when
//! its group's budget ran out); both error with [`GpuContext::beyond_loop_cap`]. See
//! `loop_cap.rs` for what was measured.
//!
//! # Shaders and volumes
//!
//! A stage shader is `shaders/<stage>.wgsl` composed after [`VOLUME_WGSL`]
//! (`shaders/volume.wgsl`) and the shared modules it needs, by a [`ShaderComposer`] (an
//! ordered list of named modules that checks each module's `// requires:` names are defined),
//! or for a single kernel with [`GpuContext::compose_shader`]. The host structs uploaded to
//! WGSL structs are checked against the composed source through naga ([`wgsl_layout`]). A [`GpuVolume`] uploads a
//! `nimbus_volume::Volume<f32>` (R32Float) or `Volume<Vec3>` (Rgba32Float) as a brick atlas
//! (9^3-texel slots: the brick plus a high-side apron of neighbour values) and a dense
//! indirection table over the bricks' bounding box. Group 0 of every stage pipeline is the
//! default volume ([`GpuVolume::bind_group_layout`]); stage bindings start at group 1. WGSL
//! then calls `volume_sample_index(p)` (exact trilinear from 8 `textureLoad`s, agreeing with
//! `Volume::sample_index` to a few ulps) or `volume_sample_index_filtered(p)` (one
//! hardware-filtered fetch, weights quantised to the adapter's sub-texel precision, about
//! 1/256 of the corner range), with `p` in index space; `volume_world_to_index` maps
//! positions relative to a host-chosen origin ([`GpuVolume::set_world_origin`]) so large
//! world offsets keep their precision in f32. `volume.wgsl`'s header documents the layout.
//!
//! [`PointSampler`] runs either sampler over a list of points; the tests and the `sampling`
//! bench use it to compare against the CPU.

mod compose;
mod context;
mod device;
mod dispatch;
mod error;
mod loop_cap;
mod sampler;
mod volume;
pub mod wgsl_layout;

pub use compose::{ComposeError, ShaderComposer};
pub use context::{split_workgroups, storage_entry, params_entry, AdapterSummary, GpuContext};
pub use device::{is_hardware, pick_adapter, wgpu_instances_created, ComputeDevice, CpuReason, DeviceChoice, GpuOptions};
pub use dispatch::{DispatchClass, DispatchSizing};
pub use error::GpuError;
pub use loop_cap::{LoopGuard, SOFTWARE_LOOP_CAP};
pub use sampler::{PointSampler, SampleMode};
pub use volume::{AtlasStats, GpuVolume, GpuVolumeOptions, GpuVoxel, VolumeInfo, SLOT_DIM};
pub use wgpu;

/// The flat invocation index of a 1D workload dispatched as a 3D grid
/// (`dispatch_linear_index`, `shaders/dispatch.wgsl`): no bindings, so shaders that read no
/// volume compose it too.
pub const DISPATCH_WGSL: &str = include_str!("../../../shaders/dispatch.wgsl");

/// Sparse-volume sampling shared by every stage shader (`shaders/volume.wgsl`).
pub const VOLUME_WGSL: &str = include_str!("../../../shaders/volume.wgsl");

/// The kernel behind [`PointSampler`] (`shaders/sample_points.wgsl`); compose before use.
pub const SAMPLE_POINTS_WGSL: &str = include_str!("../../../shaders/sample_points.wgsl");

/// A stage shader's full source: the `VOLUME_FILTERABLE` switch, [`DISPATCH_WGSL`],
/// [`VOLUME_WGSL`], then `stage`. `filterable` must be [`GpuContext::float32_filterable`] of the device the
/// pipeline is built on (prefer [`GpuContext::compose_shader`]).
pub fn compose_shader(filterable: bool, stage: &str) -> String {
    ShaderComposer::stage(filterable).module("stage", stage).source()
}

/// The process-wide device for tests and benchmarks: any adapter, software (lavapipe)
/// included. `None`, after a loud message on stderr, only when the machine has no adapter at
/// all; CI has lavapipe, so there the GPU tests always run. An adapter that exists but cannot
/// be used is a failure, not a skip.
///
/// The calling thread holds the device until it ends ([`hold_test_device`]): a test drives it
/// alone, as the tools do.
pub fn test_context() -> Option<&'static GpuContext> {
    static CTX: std::sync::OnceLock<Option<GpuContext>> = std::sync::OnceLock::new();
    let ctx = CTX.get_or_init(|| match DeviceChoice::Gpu.resolve() {
        Ok(device) => {
            let ctx = device.gpu().expect("--device gpu resolves to a GPU").clone();
            eprintln!("GPU tests run on {} (FLOAT32_FILTERABLE: {})", ctx.info, ctx.float32_filterable());
            Some(ctx)
        }
        Err(e @ GpuError::NoAdapter { .. }) => {
            eprintln!("\n!!!!!!!! SKIPPING GPU TEST: {e} !!!!!!!!\n");
            None
        }
        Err(e) => panic!("a GPU adapter exists but cannot be used: {e}"),
    })
    .as_ref()?;
    hold_test_device();
    Some(ctx)
}

/// Takes the process-wide test device for the calling thread until the thread ends (libtest
/// runs each test on its own thread); a second call on the same thread is free.
///
/// Why: the tools drive their device from one thread, but libtest ran a binary's GPU tests on
/// parallel threads against the one shared device, and under a loaded `make test` that met
/// wgpu-core 30.0.1's resource registry panicking on an id it no longer held (`storage.rs:114`,
/// epoch mismatch, in the march's GPU tests) and, on CI, a GPU render of the emission test that
/// did not repeat itself (184 pixels changed, rendered again on the same inputs; the CPU
/// changed none). Both were seen only with a binary's tests running side by side, and never
/// reproduced alone. A test must therefore not
/// wait on another thread that calls [`test_context`].
fn hold_test_device() {
    use std::cell::RefCell;
    use std::sync::{Mutex, MutexGuard, PoisonError};
    static DEVICE: Mutex<()> = Mutex::new(());
    thread_local! {
        static HELD: RefCell<Option<MutexGuard<'static, ()>>> = const { RefCell::new(None) };
    }
    HELD.with(|held| {
        let mut held = held.borrow_mut();
        if held.is_none() {
            // A test that failed while holding it poisons nothing the next one needs.
            *held = Some(DEVICE.lock().unwrap_or_else(PoisonError::into_inner));
        }
    });
}
