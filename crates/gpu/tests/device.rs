//! `--device` parsing and resolution, and the context helpers (buffers, pipelines, dispatch,
//! error scopes).

mod common;

use common::gpu;
use nimbus_gpu::wgpu::{self, DeviceType};
use nimbus_gpu::{
    is_hardware, pick_adapter, split_workgroups, storage_entry, ComputeDevice, CpuReason, DeviceChoice, GpuError, GpuOptions,
};

#[test]
fn device_choice_parses_like_the_flag() {
    assert_eq!("auto".parse::<DeviceChoice>().unwrap(), DeviceChoice::Auto);
    assert_eq!(" CPU ".parse::<DeviceChoice>().unwrap(), DeviceChoice::Cpu);
    assert_eq!("gpu".parse::<DeviceChoice>().unwrap(), DeviceChoice::Gpu);
    let err = "tpu".parse::<DeviceChoice>().unwrap_err();
    assert_eq!(err.to_string(), "invalid device 'tpu' (expected auto, cpu or gpu)");
    for choice in DeviceChoice::ALL {
        assert_eq!(choice.to_string().parse::<DeviceChoice>().unwrap(), choice);
    }
}

#[test]
fn auto_wants_hardware_and_gpu_takes_anything() {
    use DeviceType::*;
    // Only a software adapter (lavapipe): auto -> CPU backend, gpu -> lavapipe.
    assert_eq!(pick_adapter(DeviceChoice::Auto, &[Cpu]), None);
    assert_eq!(pick_adapter(DeviceChoice::Gpu, &[Cpu]), Some(0));
    // Nothing at all.
    assert_eq!(pick_adapter(DeviceChoice::Auto, &[]), None);
    assert_eq!(pick_adapter(DeviceChoice::Gpu, &[]), None);
    // Hardware beats software, discrete beats integrated beats virtual.
    assert_eq!(pick_adapter(DeviceChoice::Auto, &[Cpu, IntegratedGpu]), Some(1));
    assert_eq!(pick_adapter(DeviceChoice::Gpu, &[Cpu, IntegratedGpu, DiscreteGpu]), Some(2));
    assert_eq!(pick_adapter(DeviceChoice::Auto, &[VirtualGpu, Other]), Some(0));
    assert_eq!(pick_adapter(DeviceChoice::Gpu, &[Other, Cpu]), Some(1));
    assert_eq!(pick_adapter(DeviceChoice::Cpu, &[DiscreteGpu]), None);
}

#[test]
fn no_adapter_is_an_error_for_gpu_and_the_cpu_for_auto() {
    let nothing = GpuOptions { backends: wgpu::Backends::empty(), ..GpuOptions::default() };
    match DeviceChoice::Gpu.resolve_with(&nothing) {
        Err(e @ GpuError::NoAdapter { .. }) => assert!(e.to_string().contains("--device cpu"), "{e}"),
        other => panic!("expected NoAdapter, got {other:?}"),
    }
    let auto = DeviceChoice::Auto.resolve_with(&nothing).unwrap();
    assert!(matches!(auto, ComputeDevice::Cpu(CpuReason::NoHardwareAdapter)), "{auto}");
    assert_eq!(auto.to_string(), "cpu (no hardware GPU adapter)");
}

#[test]
fn auto_on_this_machine_takes_a_gpu_only_if_it_is_hardware() {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
    let adapters = pollster::block_on(instance.enumerate_adapters(GpuOptions::default().backends));
    let has_hardware = adapters.iter().any(|a| is_hardware(a.get_info().device_type));
    let resolved = DeviceChoice::Auto.resolve().unwrap();
    eprintln!("adapters: {:?}; auto -> {resolved}", adapters.iter().map(|a| a.get_info().name).collect::<Vec<_>>());
    match resolved {
        ComputeDevice::Gpu(ctx) => assert!(has_hardware && !ctx.info.is_software, "{}", ctx.info),
        // With lavapipe as the only adapter (this machine, CI), auto is the CPU backend.
        ComputeDevice::Cpu(reason) => assert!(!has_hardware || matches!(reason, CpuReason::DeviceFailed(_)), "{reason}"),
    }
}

#[test]
fn workgroups_spread_over_y_and_z_past_the_limit() {
    assert_eq!(split_workgroups(0, 64, 65535).unwrap(), [1, 1, 1]);
    assert_eq!(split_workgroups(100, 64, 65535).unwrap(), [2, 1, 1]);
    assert_eq!(split_workgroups(65535 * 64, 64, 65535).unwrap(), [65535, 1, 1]);
    assert_eq!(split_workgroups(65535 * 64 + 1, 64, 65535).unwrap(), [65535, 2, 1]);
    assert_eq!(split_workgroups(250, 1, 10).unwrap(), [10, 10, 3]);
    assert_eq!(split_workgroups(1000, 1, 10).unwrap(), [10, 10, 10]);
    assert!(matches!(split_workgroups(1001, 1, 10), Err(GpuError::TooLarge { .. })));
}

#[test]
fn a_large_1d_dispatch_reaches_every_item_once() {
    let Some(ctx) = gpu() else { return };
    // Workgroups of one invocation, so a modest item count exceeds the x limit.
    let items = u64::from(ctx.limits().max_compute_workgroups_per_dimension) + 4000;
    let source = ctx.compose_shader(
        "@group(1) @binding(0) var<storage, read_write> hits: array<u32>;
         @compute @workgroup_size(1)
         fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) lid: u32) {
             let i = dispatch_linear_index(wid, nwg, lid, 1u);
             if (i < arrayLength(&hits)) { hits[i] += i + 1u; }
         }",
    );
    let empty = ctx.bind_group_layout("empty", &[]).unwrap();
    let layout = ctx.bind_group_layout("hits", &[storage_entry(0, false)]).unwrap();
    let pipeline = ctx.compute_pipeline("hits", &source, "main", &[&empty, &layout]).unwrap();
    let hits = ctx.storage_buffer_zeroed("hits", items * 4).unwrap();
    let empty_group = ctx.buffer_bind_group("empty", &empty, &[]).unwrap();
    let group = ctx.buffer_bind_group("hits", &layout, &[&hits]).unwrap();
    assert!(ctx.workgroups_1d(items, 1).unwrap()[1] > 1);
    ctx.dispatch_1d("hits", &pipeline, &[&empty_group, &group], items, 1).unwrap();
    let hits: Vec<u32> = ctx.read_buffer(&hits).unwrap();
    assert!(hits.iter().enumerate().all(|(i, &h)| h == i as u32 + 1));
}

#[test]
fn buffers_round_trip() {
    let Some(ctx) = gpu() else { return };
    let data: Vec<[f32; 3]> = (0..1000).map(|i| [i as f32, -(i as f32), 0.5]).collect();
    let buffer = ctx.storage_buffer("round trip", &data).unwrap();
    assert_eq!(ctx.read_buffer::<[f32; 3]>(&buffer).unwrap(), data);
    let params = ctx.params_buffer("params", &[1u32, 2, 3, 4]).unwrap();
    assert_eq!(ctx.read_buffer::<u32>(&params).unwrap(), [1, 2, 3, 4]);
}

#[test]
fn shader_and_size_errors_are_values_not_panics() {
    let Some(ctx) = gpu() else { return };
    let err = ctx.compute_pipeline("broken", "fn main( {", "main", &[]).unwrap_err();
    assert!(matches!(err, GpuError::Validation { .. }), "{err}");
    let err = ctx.compute_pipeline("no entry", "@compute @workgroup_size(1) fn main() {}", "missing", &[]).unwrap_err();
    assert!(matches!(err, GpuError::Validation { .. }), "{err}");
    let too_big = ctx.limits().max_buffer_size.saturating_add(4);
    let err = ctx.storage_buffer_zeroed("huge", too_big).unwrap_err();
    assert!(matches!(err, GpuError::TooLarge { .. }), "{err}");
    // The device is still usable afterwards.
    assert!(ctx.storage_buffer("fine", &[1u32]).is_ok());
}

#[test]
fn the_volume_wgsl_compiles_on_its_own() {
    let Some(ctx) = gpu() else { return };
    let source = ctx.compose_shader(
        "@group(1) @binding(0) var<storage, read_write> out: array<vec4<f32>>;
         @compute @workgroup_size(1) fn main() {
             let p = volume_world_to_index(vec3<f32>(1.0, 2.0, 3.0));
             out[0] = vec4<f32>(volume_sample_index(p), volume_sample_index_filtered(p),
                                volume_sample_index3(p).x, volume_sample_index3_filtered(p).y);
         }",
    );
    let volume_layout = nimbus_gpu::GpuVolume::bind_group_layout(ctx).unwrap();
    let layout = ctx.bind_group_layout("out", &[storage_entry(0, false)]).unwrap();
    ctx.compute_pipeline("volume.wgsl", &source, "main", &[&volume_layout, &layout]).unwrap();
}
