//! The WGSL volume samplers against `Volume::sample_index` (the CPU reference, itself held
//! to OpenVDB's BoxSampler by the vdb crate's tests). Runs on any adapter, lavapipe included.

mod common;

use common::{brick_bounds, gpu, random_sparse_volume, Rng};
use glam::{IVec3, Vec3, Vec4};
use nimbus_gpu::{DeviceChoice, GpuError, GpuOptions, GpuVolume, GpuVolumeOptions, PointSampler, SampleMode};
use nimbus_volume::{Transform, Volume, BRICK_DIM};

/// Exact sampler: both sides evaluate the same nested a + (b - a) * w in f32 from the same
/// corner values and bit-identical weights (p is f32 on both sides), so they differ only by
/// rounding (e.g. a fused multiply-add on the GPU): 1e-5 of the value scale.
const EXACT_TOLERANCE: f32 = 1e-5;

/// Filtered sampler: hardware quantises each trilinear weight to its sub-texel precision
/// (8 bits on lavapipe and common GPUs), so the error is a few 1/256 steps of the corner
/// range. Allowed: 1/64 of the value range.
const FILTERED_TOLERANCE: f32 = 1.0 / 64.0;

/// Points that stress the layout: random ones over the bricks and the gaps and beyond them,
/// plus ones on and right next to brick faces and lattice points.
fn test_points(volume: &Volume<f32>, rng: &mut Rng, random: usize) -> Vec<Vec3> {
    let (lo, hi) = brick_bounds(volume, 6.0);
    let mut points: Vec<Vec3> = (0..random).map(|_| rng.point_in(lo, hi)).collect();
    for brick in volume.bricks() {
        for _ in 0..40 {
            let along = |rng: &mut Rng| {
                let face = [0.0, 7.0, 7.5, 8.0][rng.below(4) as usize];
                face + [0.0, -1e-3, 1e-3, 0.25][rng.below(4) as usize]
            };
            let local = Vec3::new(along(rng), rng.range(-1.0, 9.0), along(rng));
            points.push(brick.origin.as_vec3() + local);
            points.push((brick.origin.as_vec3() + local).floor());
        }
    }
    points
}

fn cpu_samples(volume: &Volume<f32>, points: &[Vec3]) -> Vec<f32> {
    points.iter().map(|p| volume.sample_index(p.as_dvec3())).collect()
}

/// Largest |gpu - cpu| over the points, with the worst point for the failure message.
fn max_difference(cpu: &[f32], gpu: &[f32], points: &[Vec3]) -> (f32, Vec3, f32, f32) {
    assert_eq!(cpu.len(), gpu.len());
    (0..cpu.len())
        .map(|i| ((cpu[i] - gpu[i]).abs(), points[i], cpu[i], gpu[i]))
        .fold((0.0, Vec3::ZERO, 0.0, 0.0), |worst, d| if d.0 > worst.0 || d.0.is_nan() { d } else { worst })
}

#[test]
fn exact_sampler_matches_the_cpu() {
    let Some(ctx) = gpu() else { return };
    let mut rng = Rng::new(1);
    let volume = random_sparse_volume(&mut rng, 14);
    let gpu_volume = GpuVolume::upload(ctx, &volume, &GpuVolumeOptions::default()).unwrap();
    assert!(gpu_volume.stats().ghost_bricks > 0, "the test should exercise ghost bricks");
    let points = test_points(&volume, &mut rng, 4000);
    let gpu_samples: Vec<f32> = PointSampler::new(ctx).unwrap().sample(ctx, &gpu_volume, &points, SampleMode::Exact).unwrap();
    let (diff, at, cpu, gpu) = max_difference(&cpu_samples(&volume, &points), &gpu_samples, &points);
    eprintln!("exact: {} points, {:?}, max |gpu - cpu| = {diff:e}", points.len(), gpu_volume.stats());
    // Values lie in [-1, 2): the value scale is 2.
    assert!(diff <= EXACT_TOLERANCE * 2.0, "at {at}: cpu {cpu}, gpu {gpu}");
    let background = points.iter().zip(&gpu_samples).filter(|(_, &g)| g == 0.25).count();
    assert!(background > 100, "the points should include gaps and the outside ({background} background samples)");
}

#[test]
fn filtered_sampler_is_close_to_the_cpu() {
    let Some(ctx) = gpu() else { return };
    let mut rng = Rng::new(2);
    let volume = random_sparse_volume(&mut rng, 14);
    let gpu_volume = GpuVolume::upload(ctx, &volume, &GpuVolumeOptions::default()).unwrap();
    let points = test_points(&volume, &mut rng, 4000);
    let gpu_samples: Vec<f32> = PointSampler::new(ctx).unwrap().sample(ctx, &gpu_volume, &points, SampleMode::Filtered).unwrap();
    let (diff, at, cpu, gpu) = max_difference(&cpu_samples(&volume, &points), &gpu_samples, &points);
    eprintln!("filtered (hardware filtering: {}): max |gpu - cpu| = {diff:e}", gpu_volume.filterable());
    // Values lie in [-1, 2): the value range is 3.
    assert!(diff <= FILTERED_TOLERANCE * 3.0, "at {at}: cpu {cpu}, gpu {gpu}");
}

#[test]
fn vec3_volumes_sample_every_channel() {
    let Some(ctx) = gpu() else { return };
    let mut rng = Rng::new(3);
    let scalar = random_sparse_volume(&mut rng, 8);
    let volume = scalar.map(Vec3::new(1.0, -2.0, 0.5), |v| Vec3::new(v, -2.0 * v, 0.5 + v));
    let gpu_volume = GpuVolume::upload(ctx, &volume, &GpuVolumeOptions::default()).unwrap();
    assert_eq!(gpu_volume.channels(), 4);
    let points = test_points(&scalar, &mut rng, 2000);
    let gpu_samples: Vec<Vec3> = PointSampler::new(ctx).unwrap().sample(ctx, &gpu_volume, &points, SampleMode::Exact).unwrap();
    for (p, g) in points.iter().zip(&gpu_samples) {
        let c = volume.sample_index(p.as_dvec3());
        assert!((c - *g).abs().max_element() <= EXACT_TOLERANCE * 4.0, "at {p}: cpu {c}, gpu {g}");
    }
}

#[test]
fn without_float32_filtering_the_filtered_sampler_is_exact() {
    let Some(shared) = gpu() else { return };
    // A second device on the same kind of adapter, opened without FLOAT32_FILTERABLE.
    let options = GpuOptions { optional_features: nimbus_gpu::wgpu::Features::empty(), ..GpuOptions::default() };
    let device = DeviceChoice::Gpu.resolve_with(&options).unwrap();
    let ctx = device.gpu().unwrap();
    assert_eq!(ctx.info.name, shared.info.name);
    assert!(!ctx.float32_filterable());
    let mut rng = Rng::new(4);
    let volume = random_sparse_volume(&mut rng, 6);
    let gpu_volume = GpuVolume::upload(ctx, &volume, &GpuVolumeOptions::default()).unwrap();
    let points = test_points(&volume, &mut rng, 1000);
    let gpu_samples: Vec<f32> = PointSampler::new(ctx).unwrap().sample(ctx, &gpu_volume, &points, SampleMode::Filtered).unwrap();
    let (diff, at, cpu, gpu) = max_difference(&cpu_samples(&volume, &points), &gpu_samples, &points);
    assert!(diff <= EXACT_TOLERANCE * 2.0, "at {at}: cpu {cpu}, gpu {gpu}");
}

#[test]
fn an_empty_volume_samples_as_background() {
    let Some(ctx) = gpu() else { return };
    let volume = Volume::new(Transform::uniform(1.0, Default::default()), 0.5f32);
    let gpu_volume = GpuVolume::upload(ctx, &volume, &GpuVolumeOptions::default()).unwrap();
    let points = [Vec3::ZERO, Vec3::new(-3.5, 7.25, 100.0)];
    for mode in [SampleMode::Exact, SampleMode::Filtered] {
        let samples: Vec<f32> = PointSampler::new(ctx).unwrap().sample(ctx, &gpu_volume, &points, mode).unwrap();
        assert_eq!(samples, [0.5, 0.5]);
    }
}

#[test]
fn a_table_over_budget_is_a_clear_error() {
    let Some(ctx) = gpu() else { return };
    let mut volume = Volume::new(Transform::uniform(1.0, Default::default()), 0.0f32);
    volume.set(IVec3::ZERO, 1.0);
    volume.set(IVec3::splat(100 * BRICK_DIM), 1.0);
    let options = GpuVolumeOptions { max_table_entries: 1000 };
    match GpuVolume::upload(ctx, &volume, &options) {
        Err(GpuError::VolumeLayout(message)) => assert!(message.contains("indirection table"), "{message}"),
        other => panic!("expected a layout error, got {other:?}"),
    }
}

/// A stage that samples two volumes: the second one bound through `layout_entries` at
/// another group and sampled with the `_in` functions, at world positions given relative to
/// a far-away origin.
#[test]
fn a_second_volume_binds_anywhere_and_world_positions_stay_precise() {
    use glam::{DAffine3, DQuat, DVec3};
    use nimbus_gpu::{storage_entry, wgpu};

    let Some(ctx) = gpu() else { return };
    let mut rng = Rng::new(5);
    let first = random_sparse_volume(&mut rng, 5);
    let mut second = random_sparse_volume(&mut rng, 5);
    // Rotated, anisotropic voxels 100 km from the world origin, where absolute f32 world
    // coordinates would resolve only ~1 cm, about one voxel.
    let far = DVec3::new(1.0e5, -2.0e5, 3.0e4);
    let index_to_world = DAffine3::from_scale_rotation_translation(
        DVec3::new(0.01, 0.02, 0.015),
        DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1),
        far,
    );
    second.set_transform(Transform::new(index_to_world).unwrap());
    let gpu_first = GpuVolume::upload(ctx, &first, &GpuVolumeOptions::default()).unwrap();
    let mut gpu_second = GpuVolume::upload(ctx, &second, &GpuVolumeOptions::default()).unwrap();
    let origin = far + DVec3::new(0.3, 0.1, -0.2);
    gpu_second.set_world_origin(ctx, origin);

    let (lo, hi) = brick_bounds(&second, 2.0);
    let index_points: Vec<Vec3> = (0..500).map(|_| rng.point_in(lo, hi)).collect();
    let relative: Vec<Vec4> =
        index_points.iter().map(|p| (second.transform().to_world(p.as_dvec3()) - origin).as_vec3().extend(0.0)).collect();

    let source = ctx.compose_shader(
        "@group(1) @binding(0) var second_atlas: texture_3d<f32>;
         @group(1) @binding(1) var second_table: texture_3d<u32>;
         @group(1) @binding(2) var second_sampler: sampler;
         @group(1) @binding(3) var<storage, read> second_info: VolumeInfo;
         @group(1) @binding(4) var<storage, read> points: array<vec4<f32>>;
         @group(1) @binding(5) var<storage, read_write> out: array<vec4<f32>>;
         @compute @workgroup_size(64)
         fn main(@builtin(global_invocation_id) id: vec3<u32>) {
             let i = id.x;
             if (i >= arrayLength(&points)) { return; }
             let p = volume_world_to_index_in(second_info, points[i].xyz);
             out[2u * i] = vec4<f32>(p, 0.0);
             out[2u * i + 1u] = vec4<f32>(
                 volume_sample_index_in(second_atlas, second_table, second_info, p).x,
                 volume_sample_index(p), 0.0, 0.0);
         }",
    );
    let mut entries = GpuVolume::layout_entries(0, ctx.float32_filterable()).to_vec();
    entries.extend([storage_entry(4, true), storage_entry(5, false)]);
    let first_layout = GpuVolume::bind_group_layout(ctx).unwrap();
    let second_layout = ctx.bind_group_layout("second", &entries).unwrap();
    let pipeline = ctx.compute_pipeline("two volumes", &source, "main", &[&first_layout, &second_layout]).unwrap();

    let points = ctx.storage_buffer("points", &relative).unwrap();
    let out = ctx.storage_buffer_zeroed("out", relative.len() as u64 * 32).unwrap();
    let mut group_entries = gpu_second.bind_group_entries(0).to_vec();
    group_entries.push(wgpu::BindGroupEntry { binding: 4, resource: points.as_entire_binding() });
    group_entries.push(wgpu::BindGroupEntry { binding: 5, resource: out.as_entire_binding() });
    let second_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("second"),
        layout: &second_layout,
        entries: &group_entries,
    });
    let first_group = gpu_first.bind_group(ctx, &first_layout).unwrap();
    ctx.dispatch_1d("two volumes", &pipeline, &[&first_group, &second_group], relative.len() as u64, 64).unwrap();
    let out: Vec<Vec4> = ctx.read_buffer(&out).unwrap();

    let mut worst_index_error = 0.0f32;
    for (i, p) in index_points.iter().enumerate() {
        let (p_gpu, samples) = (out[2 * i].truncate(), out[2 * i + 1]);
        worst_index_error = worst_index_error.max((p_gpu - *p).abs().max_element());
        // Each volume sampled at the GPU's own index position, as in the exact test.
        let second_cpu = second.sample_index(p_gpu.as_dvec3());
        let first_cpu = first.sample_index(p_gpu.as_dvec3());
        assert!((samples.x - second_cpu).abs() <= EXACT_TOLERANCE * 2.0, "second volume at {p_gpu}: cpu {second_cpu}, gpu {}", samples.x);
        assert!((samples.y - first_cpu).abs() <= EXACT_TOLERANCE * 2.0, "first volume at {p_gpu}: cpu {first_cpu}, gpu {}", samples.y);
    }
    eprintln!("world -> index relative to an origin 1e5 away: max index error {worst_index_error:e} voxels");
    // Only the f32 rounding of a relative position of a few metres and of the matrix: ~1e-5.
    assert!(worst_index_error < 1e-3, "{worst_index_error}");
}
