//! The WGSL volume samplers against `Volume::sample_index` (the CPU reference, itself held
//! to OpenVDB's BoxSampler by the vdb crate's tests). Runs on any adapter, lavapipe included.

mod common;

use common::{brick_bounds, gpu, random_sparse_volume, Rng};
use glam::{IVec3, Vec3};
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
