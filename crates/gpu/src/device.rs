//! `--device auto|cpu|gpu` and the adapter choice behind it (design.md section 1).

use std::fmt;
use std::str::FromStr;
use std::sync::atomic::{AtomicUsize, Ordering};

use wgpu::DeviceType;

use crate::{GpuContext, GpuError};

/// What the user asked for with `--device`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum DeviceChoice {
    /// A hardware GPU when there is one, else the CPU backend.
    #[default]
    Auto,
    /// The CPU backend; wgpu is never touched.
    Cpu,
    /// A GPU adapter, hardware preferred, software (lavapipe) accepted; an error if none.
    Gpu,
}

impl DeviceChoice {
    pub const ALL: [DeviceChoice; 3] = [DeviceChoice::Auto, DeviceChoice::Cpu, DeviceChoice::Gpu];

    pub fn as_str(self) -> &'static str {
        match self {
            DeviceChoice::Auto => "auto",
            DeviceChoice::Cpu => "cpu",
            DeviceChoice::Gpu => "gpu",
        }
    }

    /// Resolves the choice with default [`GpuOptions`].
    pub fn resolve(self) -> Result<ComputeDevice, GpuError> {
        self.resolve_with(&GpuOptions::default())
    }

    /// Resolves the choice to a backend. `Cpu` returns at once without creating any wgpu
    /// object; `Auto` falls back to the CPU (with the reason) rather than failing; `Gpu`
    /// fails with [`GpuError::NoAdapter`] or [`GpuError::RequestDevice`].
    pub fn resolve_with(self, options: &GpuOptions) -> Result<ComputeDevice, GpuError> {
        if self == DeviceChoice::Cpu {
            return Ok(ComputeDevice::Cpu(CpuReason::Requested));
        }
        if self == DeviceChoice::Auto && !hardware_gpu_possible() {
            return Ok(ComputeDevice::Cpu(CpuReason::NoHardwareAdapter));
        }
        let instance = new_instance(options);
        let adapters = pollster::block_on(instance.enumerate_adapters(options.backends));
        let types: Vec<DeviceType> = adapters.iter().map(|a| a.get_info().device_type).collect();
        let Some(index) = pick_adapter(self, &types) else {
            return match self {
                DeviceChoice::Gpu => Err(GpuError::NoAdapter { backends: backend_names(options.backends) }),
                _ => Ok(ComputeDevice::Cpu(CpuReason::NoHardwareAdapter)),
            };
        };
        let adapter = adapters.into_iter().nth(index).expect("pick_adapter returns an index into the list");
        match GpuContext::from_adapter(instance, adapter, options) {
            Ok(ctx) => Ok(ComputeDevice::Gpu(ctx)),
            Err(e) if self == DeviceChoice::Auto => Ok(ComputeDevice::Cpu(CpuReason::DeviceFailed(e.to_string()))),
            Err(e) => Err(e),
        }
    }
}

impl fmt::Display for DeviceChoice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for DeviceChoice {
    type Err = GpuError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        DeviceChoice::ALL
            .into_iter()
            .find(|c| c.as_str().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| GpuError::ParseDevice(s.to_owned()))
    }
}

/// How a GPU context is opened.
#[derive(Clone, Debug)]
pub struct GpuOptions {
    /// Backends to look for adapters on. Default: Vulkan, Metal, DX12 (wgpu's "primary"
    /// backends; GL lacks what the stage shaders need), overridden by `WGPU_BACKEND`.
    pub backends: wgpu::Backends,
    /// Features enabled when the adapter has them. Default: FLOAT32_FILTERABLE, which lets
    /// `volume_sample_index_filtered` filter the R32Float atlas in hardware.
    pub optional_features: wgpu::Features,
}

impl Default for GpuOptions {
    fn default() -> Self {
        GpuOptions {
            backends: wgpu::Backends::PRIMARY.with_env(),
            optional_features: wgpu::Features::FLOAT32_FILTERABLE,
        }
    }
}

/// The outcome of [`DeviceChoice::resolve`]: which backend a stage runs.
#[derive(Debug)]
pub enum ComputeDevice {
    Cpu(CpuReason),
    Gpu(GpuContext),
}

impl ComputeDevice {
    pub fn gpu(&self) -> Option<&GpuContext> {
        match self {
            ComputeDevice::Gpu(ctx) => Some(ctx),
            ComputeDevice::Cpu(_) => None,
        }
    }
}

/// One line for `-v`, e.g. `gpu: llvmpipe (...) [Vulkan, software]` or `cpu (no hardware GPU adapter)`.
impl fmt::Display for ComputeDevice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ComputeDevice::Cpu(reason) => write!(f, "cpu ({reason})"),
            ComputeDevice::Gpu(ctx) => write!(f, "gpu: {}", ctx.info),
        }
    }
}

/// Why the CPU backend was chosen; printed with `-v`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CpuReason {
    Requested,
    NoHardwareAdapter,
    DeviceFailed(String),
}

impl fmt::Display for CpuReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CpuReason::Requested => f.write_str("requested"),
            CpuReason::NoHardwareAdapter => f.write_str("no hardware GPU adapter"),
            CpuReason::DeviceFailed(e) => write!(f, "GPU unusable: {e}"),
        }
    }
}

/// True for adapters that run on real GPU hardware (or a hypervisor's virtual GPU).
pub fn is_hardware(device_type: DeviceType) -> bool {
    matches!(device_type, DeviceType::DiscreteGpu | DeviceType::IntegratedGpu | DeviceType::VirtualGpu)
}

/// The adapter (index into `types`) a choice takes: the best hardware adapter (discrete,
/// then integrated, then virtual); for `Gpu` only, else a software one (`Cpu`, e.g. lavapipe)
/// and last an unclassified one (`Other`). `None`: use the CPU backend (or fail, for `Gpu`).
pub fn pick_adapter(choice: DeviceChoice, types: &[DeviceType]) -> Option<usize> {
    let rank = |t: DeviceType| match t {
        DeviceType::DiscreteGpu => 0,
        DeviceType::IntegratedGpu => 1,
        DeviceType::VirtualGpu => 2,
        DeviceType::Cpu => 3,
        DeviceType::Other => 4,
    };
    let acceptable = |t: DeviceType| match choice {
        DeviceChoice::Cpu => false,
        DeviceChoice::Auto => is_hardware(t),
        DeviceChoice::Gpu => true,
    };
    types
        .iter()
        .enumerate()
        .filter(|(_, &t)| acceptable(t))
        .min_by_key(|(_, &t)| rank(t))
        .map(|(i, _)| i)
}

/// Whether this machine can have a hardware GPU adapter at all. Creating a wgpu instance
/// loads every installed Vulkan driver (lavapipe brings LLVM with it): about 50 ms of each
/// tool's start on a machine without a GPU, only to find the software adapters `auto` never
/// takes. CPU-only render nodes start the tools for every frame, so `auto` skips that when
/// the kernel shows no GPU. On Linux every driver wgpu can reach has a device node in /dev:
/// `dri/` (Mesa's drivers and NVIDIA's DRM module), `nvidia*` (NVIDIA's proprietary driver)
/// or `dxg` (WSL2's GPU). Elsewhere the probe always runs.
fn hardware_gpu_possible() -> bool {
    if cfg!(target_os = "linux") { gpu_device_nodes_in(std::path::Path::new("/dev")) } else { true }
}

/// Whether the device directory `dev` holds a GPU device node (see [`hardware_gpu_possible`]);
/// true when it cannot be read, so an unusual /dev never hides a GPU.
fn gpu_device_nodes_in(dev: &std::path::Path) -> bool {
    let Ok(entries) = std::fs::read_dir(dev) else { return true };
    entries.flatten().any(|e| {
        let name = e.file_name();
        let name = name.to_string_lossy();
        name == "dri" || name == "dxg" || name.starts_with("nvidia")
    })
}

static INSTANCES_CREATED: AtomicUsize = AtomicUsize::new(0);

/// How many wgpu instances this process has created; lets tests prove `--device cpu`
/// never loads a GPU driver.
#[doc(hidden)]
pub fn wgpu_instances_created() -> usize {
    INSTANCES_CREATED.load(Ordering::SeqCst)
}

/// Mesa's Vulkan drivers probe for a Wayland display while the instance is created, and
/// libwayland prints "error: XDG_RUNTIME_DIR is invalid or not set" to stderr when that
/// variable is missing (headless machines, CI, cron). The tools compute only and never show a
/// window, and an `error:` line that is not ours misleads users, so point the variable at the
/// temporary directory when it is unset: the probe then fails quietly.
fn quiet_wayland_probe() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
            // SAFETY (edition 2021 API): done once, before wgpu or the driver start threads
            // that read the environment.
            std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir());
        }
    });
}

/// "vulkan, metal" for the backends that were both asked for and compiled in.
fn backend_names(backends: wgpu::Backends) -> String {
    let names: Vec<String> = (backends & wgpu::Instance::enabled_backend_features())
        .iter_names()
        .map(|(name, _)| name.to_lowercase())
        .collect();
    if names.is_empty() { "none".to_owned() } else { names.join(", ") }
}

fn new_instance(options: &GpuOptions) -> wgpu::Instance {
    INSTANCES_CREATED.fetch_add(1, Ordering::SeqCst);
    quiet_wayland_probe();
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle().with_env();
    desc.backends = options.backends;
    wgpu::Instance::new(desc)
}

#[cfg(test)]
mod tests {
    use super::gpu_device_nodes_in;

    #[test]
    fn auto_probes_for_a_gpu_only_where_the_kernel_shows_one() {
        let dev = std::env::temp_dir().join(format!("nimbus-dev-{}", std::process::id()));
        std::fs::create_dir_all(&dev).unwrap();
        std::fs::write(dev.join("null"), b"").unwrap();
        assert!(!gpu_device_nodes_in(&dev), "no GPU node yet");
        for node in ["dri", "nvidia0", "nvidiactl", "dxg"] {
            std::fs::write(dev.join(node), b"").unwrap();
            assert!(gpu_device_nodes_in(&dev), "{node}");
            std::fs::remove_file(dev.join(node)).unwrap();
        }
        std::fs::remove_dir_all(&dev).unwrap();
        assert!(gpu_device_nodes_in(&dev), "an unreadable /dev must not hide a GPU");
    }
}
