//! The lights' tables built on the GPU (lavapipe, or any adapter) against the CPU's: the same
//! plan (bricks, their order, the lattice's transform), nodes to f32 rounding of the optical
//! depth; and the GPU's lookup against the CPU's on the same tables.

use std::time::Instant;

use glam::{DAffine3, DMat3, DVec3, IVec3, Vec3};
use nimbus_gpu::{storage_entry, GpuContext, GpuVolume, GpuVolumeOptions};
use nimbus_optics::{Light, Rng};
use nimbus_tracking::{DensityMedium, GpuLightTables, LightDepths, LightLattice, light_tables_wgsl};
use nimbus_volume::{MajorantGrid, Transform, Volume};

mod common;
use common::blob;

/// Anisotropic, sheared voxels far from the world origin (the anvil case).
fn sheared() -> Transform {
    let m = DMat3::from_cols(DVec3::new(0.06, 0.0, 0.0), DVec3::new(0.01, 0.04, 0.0), DVec3::new(0.0, 0.0, 0.02));
    Transform::new(DAffine3::from_mat3_translation(m, DVec3::new(1e6, -2e6, 3e5))).unwrap()
}

fn centre(v: &Volume<f32>) -> DVec3 {
    let (lo, hi) = v.world_bounds().unwrap();
    0.5 * (lo + hi)
}

/// Both backends' tables for `lights`: the CPU's, the GPU's read back, and the GPU's bound.
fn both(ctx: &GpuContext, v: &Volume<f32>, extinction: f32, lights: &[Light], opaque_depth: f64) -> (LightDepths, LightDepths, GpuLightTables) {
    let majorant = MajorantGrid::build(v);
    let medium = DensityMedium { motion: None, density: v, majorant: &majorant, extinction };
    let started = Instant::now();
    let cpu = LightDepths::build(medium, lights, LightLattice::default(), opaque_depth);
    let cpu_time = started.elapsed();
    let volume = GpuVolume::upload(ctx, v, &GpuVolumeOptions::default()).unwrap();
    let started = Instant::now();
    let tables = GpuLightTables::build(ctx, &volume, medium, lights, LightLattice::default(), opaque_depth, centre(v)).unwrap();
    let gpu = tables.read(ctx).unwrap();
    eprintln!(
        "{} voxels, {} lights: {} nodes; table build CPU {:.1} ms, GPU {:.1} ms (with read-back)",
        v.active_voxel_count(),
        lights.len(),
        cpu.nodes(),
        cpu_time.as_secs_f64() * 1e3,
        started.elapsed().as_secs_f64() * 1e3
    );
    assert_eq!(tables.nodes(), cpu.nodes());
    (cpu, gpu, tables)
}

/// The worst difference of the GPU's nodes from the CPU's, in optical depth relative to
/// max(1, depth) (f32 sums over the cells a ray crosses), over nodes lit above `floor`; and
/// whether every node the CPU holds below `floor` is below it on the GPU as well.
fn compare_nodes(cpu: &LightDepths, gpu: &LightDepths, floor: f32) -> (f64, f64, usize) {
    assert_eq!(cpu.per_light.len(), gpu.per_light.len());
    let (mut worst, mut deepest, mut n) = (0.0f64, 0.0f64, 0);
    for (c, g) in cpu.per_light.iter().zip(&gpu.per_light) {
        let (Some(c), Some(g)) = (c, g) else {
            assert!(c.is_none() && g.is_none(), "a light tabled on one backend only");
            continue;
        };
        let (c, g) = (&c.transmittance, &g.transmittance);
        assert_eq!(c.transform(), g.transform(), "the same lattice");
        assert_eq!(c.brick_count(), g.brick_count());
        for (bc, bg) in c.bricks().zip(g.bricks()) {
            assert_eq!(bc.origin, bg.origin, "the same bricks in the same order");
            for (&tc, &tg) in bc.values.iter().zip(bg.values) {
                assert!(tg.is_finite() && (0.0..=1.0).contains(&tg), "node {tg}");
                if tc < floor {
                    assert!(tg < floor * 1.001, "opaque on the CPU ({tc}), {tg} on the GPU");
                    continue;
                }
                let tau = -(tc as f64).ln();
                let d = ((tg as f64).ln() + tau).abs() / tau.max(1.0);
                worst = worst.max(d);
                deepest = deepest.max(tau);
                n += 1;
            }
        }
    }
    (worst, deepest, n)
}

#[test]
fn gpu_tables_hold_the_cpu_nodes_along_an_axis_and_obliquely() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = blob(Transform::uniform(0.05, DVec3::new(0.3, -1.2, 2.0)), 12);
    let point = Light::point(centre(&v) + DVec3::new(0.0, 0.0, 2.0), Vec3::ONE).unwrap();
    // A sun along an axis, a point light (no table), an oblique sun: one build, one buffer.
    let lights = [
        Light::sun(Vec3::NEG_Z, Vec3::ONE).unwrap(),
        point,
        Light::sun(Vec3::new(0.5, 0.3, -0.8).normalize(), Vec3::ONE).unwrap(),
    ];
    let (cpu, gpu, _) = both(ctx, &v, 8.0, &lights, f64::INFINITY);
    assert!(cpu.get(1).is_none() && gpu.get(1).is_none(), "point lights keep shadow rays");
    let (worst, deepest, n) = compare_nodes(&cpu, &gpu, 1e-30);
    eprintln!("axis and oblique suns: {n} nodes, worst optical-depth difference {worst:.2e} of max(1, depth), deepest {deepest:.1}");
    assert!(n > 100_000 && deepest > 5.0, "{n} nodes, deepest {deepest}: the blob must cast a deep shadow");
    // Measured 8e-7 on lavapipe.
    assert!(worst < 5e-6, "worst relative optical-depth difference {worst}");
}

#[test]
fn gpu_tables_hold_the_cpu_nodes_on_a_sheared_anisotropic_lattice_far_away() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = blob(sheared(), 12);
    let lights = [Light::sun(Vec3::new(-0.7, 0.5, -0.5).normalize(), Vec3::ONE).unwrap(), Light::sun(Vec3::new(0.0, 1.0, 0.05).normalize(), Vec3::ONE).unwrap()];
    // Rays stop past the opaque depth: the nodes beyond hold "black" on both.
    let opaque_depth = 6.0;
    let (cpu, gpu, _) = both(ctx, &v, 20.0, &lights, opaque_depth);
    let (worst, deepest, n) = compare_nodes(&cpu, &gpu, (-opaque_depth).exp() as f32);
    eprintln!("sheared lattice: {n} nodes, worst optical-depth difference {worst:.2e} of max(1, depth), deepest {deepest:.1}");
    assert!(n > 100_000 && deepest > 4.0, "{n} nodes, deepest {deepest}");
    assert!(worst < 5e-6, "worst relative optical-depth difference {worst}");
    let below = |d: &LightDepths| d.per_light.iter().flatten().flat_map(|t| t.transmittance.bricks()).flat_map(|b| b.values.iter()).filter(|&&t| t < (-opaque_depth).exp() as f32).count();
    assert!(below(&cpu) > 1000, "the opaque depth must be reached ({} nodes past it)", below(&cpu));
}

/// The GPU's `light_table_lookup` (the tabled transmittance and the shadow ray's weight) at
/// `points` (world) for every light, positions relative to `origin` as the stages pass them.
fn gpu_lookups(ctx: &GpuContext, tables: &GpuLightTables, lights: usize, points: &[DVec3], origin: DVec3) -> Vec<[f32; 2]> {
    const KERNEL: &str = r#"
@group(1) @binding(0) var<storage, read> points: array<vec4<f32>>;
@group(1) @binding(1) var<storage, read_write> results: array<vec2<f32>>;

@compute @workgroup_size(64)
fn lookup(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= arrayLength(&results)) {
        return;
    }
    let n = arrayLength(&points);
    results[i] = light_table_lookup(i / n, points[i % n].xyz);
}
"#;
    let source = ctx.compose_shader(&format!("{}\n{KERNEL}", light_tables_wgsl()));
    let empty = ctx.bind_group_layout("nothing at group 0", &[]).unwrap();
    let layout = ctx.bind_group_layout("lookups", &[storage_entry(0, true), storage_entry(1, false)]).unwrap();
    let tables_layout = GpuLightTables::layout(ctx).unwrap();
    let pipeline = ctx.compute_pipeline("lookups", &source, "lookup", &[&empty, &layout, &tables_layout]).unwrap();
    let relative: Vec<[f32; 4]> = points.iter().map(|&p| (p - origin).as_vec3().extend(0.0).to_array()).collect();
    let points_buffer = ctx.storage_buffer("points", &relative).unwrap();
    let count = (points.len() * lights) as u64;
    let results = ctx.storage_buffer_zeroed("results", count * 8).unwrap();
    let groups = [
        ctx.bind_group("nothing", &empty, &[]).unwrap(),
        ctx.buffer_bind_group("lookups", &layout, &[&points_buffer, &results]).unwrap(),
        tables.bind_group(ctx, &tables_layout).unwrap(),
    ];
    ctx.dispatch_1d("lookups", &pipeline, &[&groups[0], &groups[1], &groups[2]], count, 64).unwrap();
    ctx.read_buffer(&results).unwrap()
}

#[test]
fn gpu_lookups_agree_with_the_cpu_lookups_of_the_same_tables() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = blob(sheared(), 10);
    let c = centre(&v);
    let lights = [
        Light::sun(Vec3::new(0.5, 0.3, -0.8).normalize(), Vec3::ONE).unwrap(),
        Light::point(c + DVec3::new(0.0, 0.0, 1.0), Vec3::ONE).unwrap(),
        Light::sun(Vec3::X, Vec3::ONE).unwrap(),
    ];
    let (_, gpu, tables) = both(ctx, &v, 6.0, &lights, f64::INFINITY);
    // Points inside the medium and around it (where no brick is stored the table reads 1).
    let mut rng = Rng::new(11, 0);
    let points: Vec<DVec3> = (0..4000).map(|_| v.transform().to_world((DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 2.0 - 1.0) * 14.0)).collect();
    let got = gpu_lookups(ctx, &tables, lights.len(), &points, c);
    let (mut worst, mut worst_weight, mut shadowed, mut outside, mut edges) = (0.0f64, 0.0f64, 0, 0, 0);
    for (l, table) in gpu.per_light.iter().enumerate() {
        for (i, &x) in points.iter().enumerate() {
            let [g, weight] = got[l * points.len() + i].map(f64::from);
            let Some(table) = table else {
                assert_eq!(weight, 1.0, "light {l} has no table: the lookup leaves it to the shadow ray");
                continue;
            };
            let want = table.lookup(x);
            worst = worst.max((g - want.table).abs());
            worst_weight = worst_weight.max((weight - want.ray_weight).abs());
            shadowed += (want.table < 0.5) as usize;
            outside += (want.table == 1.0) as usize;
            edges += (want.ray_weight > 0.0) as usize;
        }
    }
    eprintln!("{} lookups: worst |dT| {worst:.2e}, worst ray weight difference {worst_weight:.2e}; {shadowed} in deep shadow, {outside} where nothing lies toward the light, {edges} across sharp edges", 2 * points.len());
    assert!(shadowed > 200 && outside > 200, "the points must cover shadow and clear air");
    // f32 lattice coordinates move the trilinear weights by ~1e-7 (measured 1.2e-7).
    assert!(worst < 1e-6, "worst lookup difference {worst}");
    // The spread of the same nodes, through the blend's 10x slope.
    assert!(worst_weight < 1e-5, "worst ray weight difference {worst_weight}");
}

/// A ray through 12,000 cells takes more loop iterations per SIMD group than a software
/// adapter (llvmpipe: 65535) runs whole: it must refuse, not table a ray cut short; any
/// other adapter must table what the CPU does.
#[test]
fn rays_longer_than_a_software_adapter_runs_are_refused() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let mut v = Volume::new(Transform::uniform(0.01, DVec3::ZERO), 0.0f32);
    for z in 0..12_000 {
        for x in 0..2 {
            for y in 0..2 {
                v.set(IVec3::new(x, y, z), 1.0);
            }
        }
    }
    let majorant = MajorantGrid::build(&v);
    // Thin: no ray reaches an opaque depth and stops early.
    let medium = DensityMedium { motion: None, density: &v, majorant: &majorant, extinction: 1e-3 };
    let lights = [Light::sun(Vec3::NEG_Z, Vec3::ONE).unwrap()];
    let volume = GpuVolume::upload(ctx, &v, &GpuVolumeOptions::default()).unwrap();
    match GpuLightTables::build(ctx, &volume, medium, &lights, LightLattice::default(), f64::INFINITY, DVec3::ZERO) {
        Err(e) if ctx.loop_cap().is_some() => {
            let e = e.to_string();
            assert!(e.contains("light table") && e.contains("65535") && e.contains("--device cpu"), "{e}");
        }
        Err(e) => panic!("a hardware adapter should build it: {e}"),
        Ok(tables) => {
            assert!(ctx.loop_cap().is_none(), "a software adapter should refuse");
            let cpu = LightDepths::build(medium, &lights, LightLattice::default(), f64::INFINITY);
            let (worst, _, _) = compare_nodes(&cpu, &tables.read(ctx).unwrap(), 1e-30);
            assert!(worst < 5e-6, "worst relative optical-depth difference {worst}");
        }
    }
}
