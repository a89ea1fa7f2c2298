//! The GPU backend against the CPU one on lavapipe (or any adapter): the same plan, the same
//! voxels, values to float tolerance; the lights' tables built on the GPU and looked up by
//! both single scattering and the paths' next-event estimation.

use glam::{DVec3, IVec3, Vec3};
use nimbus_cache::{bake_cpu, bake_gpu, CacheParams, Gather, IlluminationCache, MultipleEstimator, ShadowMode};
use nimbus_optics::{Camera, Light, Medium};
use nimbus_photon::{trace_cpu, PhotonMap, PhotonParams};
use nimbus_volume::{Transform, Volume};

mod support;

/// A lumpy ball, 25 voxels across, at a large world offset (f32 positions stay relative).
fn lumpy_ball() -> Volume<f32> {
    let mut v = Volume::new(Transform::uniform(0.1, DVec3::new(1e4, -3e3, 50.0)), 0.0);
    for x in -12..=12 {
        for y in -12..=12 {
            for z in -12..=12 {
                let c = IVec3::new(x, y, z);
                let r = c.as_vec3().length() / 12.0;
                let d = (1.0 - r).max(0.0) * 4.0 + 0.3 * ((x as f32) * 0.7).sin().abs() * (r < 1.0) as i32 as f32;
                if d > 0.0 {
                    v.set(c, d);
                }
            }
        }
    }
    v
}

fn params(v: &Volume<f32>) -> CacheParams {
    let (lo, hi) = v.world_bounds().unwrap();
    let centre = 0.5 * (lo + hi);
    let lights = vec![
        Light::sun(Vec3::new(0.3, 0.2, -1.0).normalize(), Vec3::new(1.0, 2.0, 3.0)).unwrap(),
        Light::point(centre + DVec3::new(0.3, -2.0, 1.5), Vec3::splat(2.0)).unwrap(),
    ];
    let medium = Medium { extinction: 3.0, albedo: Vec3::new(0.9, 0.8, 0.7), g: 0.3 };
    CacheParams {
        step: 0.5,
        cache_scale: 1.5,
        multiple: true,
        gather: Gather::Neighbours { k: 32, max_radius: 0.6 },
        min_transmittance: 1e-4,
        ..support::params(medium, lights, Camera::default_for_bounds(lo, hi).unwrap())
    }
}

/// Li_multiple alone, by 8 paths a voxel on its own, coarser lattice (the voxel count stays
/// small for lavapipe), from the random streams of `seed`; no photons at all: paths need none.
fn paths_only(v: &Volume<f32>, seed: u64) -> CacheParams {
    CacheParams {
        single: false,
        cache_scale: 1.5,
        single_tolerance: None,
        path_tolerance: None,
        multiple_scale: Some(2.5),
        multiple_tolerance: None,
        estimator: MultipleEstimator::Paths { per_voxel: 8 },
        seed,
        ..params(v)
    }
}

fn photons(v: &Volume<f32>, p: &CacheParams) -> PhotonMap {
    let tp = PhotonParams { medium: p.medium, lights: p.lights.clone(), photons: 20_000, seed: 3, ..PhotonParams::default() };
    trace_cpu(v, &tp).unwrap().0
}

/// Largest difference over the voxels of `a`, and the peak of `a`; both grids hold the same voxels.
fn compare(a: &Volume<Vec3>, b: &Volume<Vec3>) -> (f32, f32, usize) {
    assert_eq!(a.active_voxel_count(), b.active_voxel_count());
    let (mut worst, mut peak, mut n) = (0.0f32, 0.0f32, 0);
    for brick in a.bricks() {
        for (offset, va) in brick.values.iter().enumerate() {
            let ijk = brick.origin + nimbus_volume::brick_local(offset);
            if !a.is_active(ijk) {
                continue;
            }
            assert!(b.is_active(ijk), "{ijk} baked on one backend only");

            worst = worst.max((*va - b.get(ijk)).abs().max_element());
            peak = peak.max(va.max_element());
            n += 1;
        }
    }
    (worst, peak, n)
}

fn both(v: &Volume<f32>, map: &PhotonMap, p: &CacheParams) -> Option<(IlluminationCache, IlluminationCache)> {
    let ctx = nimbus_gpu::test_context()?;
    let (cpu, cpu_stats) = bake_cpu(v, map, p).unwrap();
    let (gpu, gpu_stats) = bake_gpu(ctx, v, map, p).unwrap();
    assert_eq!(gpu_stats.baked, cpu_stats.baked);
    assert_eq!(gpu_stats.nonfinite, 0);
    assert_eq!(gpu_stats.light_table_nodes, cpu_stats.light_table_nodes, "the same tables");
    // The same photons in (nearly) every ball: a k-th-nearest tie broken differently by f32
    // rounding may swap one.
    let (a, b) = (cpu_stats.photons_gathered as f64, gpu_stats.photons_gathered as f64);
    assert!((a - b).abs() <= 1e-3 * a.max(1.0), "photons gathered: CPU {a}, GPU {b}");
    Some((cpu, gpu))
}

/// Li_single of both backends, voxel by voxel, to f32 rounding of the peak.
fn assert_single_agrees(cpu: &IlluminationCache, gpu: &IlluminationCache, what: &str) {
    let (worst, peak, n) = compare(cpu.li_single.as_ref().unwrap(), gpu.li_single.as_ref().unwrap());
    eprintln!("single ({what}): {n} voxels, worst {worst:.3e} of peak {peak:.3e}");
    assert!(n > 1000 && peak > 0.0, "{what}: {n} voxels, peak {peak}");
    assert!(worst <= 1e-5 * peak, "single scattering ({what}): worst {worst} of peak {peak}");
}

/// Li_multiple of the photon gather on both backends: the same photons, values to 1e-4.
fn assert_multiple_agrees(cpu: &IlluminationCache, gpu: &IlluminationCache, what: &str) {
    let (worst, peak, n) = compare(cpu.li_multiple.as_ref().unwrap(), gpu.li_multiple.as_ref().unwrap());
    eprintln!("multiple ({what}): {n} voxels, worst {worst:.3e} of peak {peak:.3e}");
    assert!(peak > 0.0);
    assert!(worst <= 1e-4 * peak, "multiple scattering ({what}): worst {worst} of peak {peak}");
}

/// The transmittance grids of both backends: one for each of the `tabled` lights, the same
/// voxels, and values to 1e-5 of the transmittance itself (f32 sums of the tables' optical
/// depth; measured 2e-6) over the voxels above 1e-3, of which there must be `min_lit`, a
/// third of them in shadow below 0.5.
fn assert_transmittance_agrees(cpu: &IlluminationCache, gpu: &IlluminationCache, tabled: &[usize], min_lit: usize) {
    let lights = |c: &IlluminationCache| c.transmittance.iter().map(|(i, _)| *i).collect::<Vec<_>>();
    assert_eq!(lights(cpu), tabled, "a transmittance grid per tabled light");
    assert_eq!(lights(gpu), tabled, "a transmittance grid per tabled light");
    let (mut worst, mut n, mut shadowed) = (0.0f64, 0, 0);
    for ((_, c), (_, g)) in cpu.transmittance.iter().zip(&gpu.transmittance) {
        assert_eq!(c.transform(), g.transform());
        assert_eq!(c.active_voxel_count(), g.active_voxel_count());
        for brick in c.bricks() {
            for (offset, &tc) in brick.values.iter().enumerate() {
                let ijk = brick.origin + nimbus_volume::brick_local(offset);
                if !c.is_active(ijk) {
                    continue;
                }
                assert!(g.is_active(ijk), "{ijk} on one backend only");
                if tc > 1e-3 {
                    worst = worst.max(((g.get(ijk) - tc) / tc).abs() as f64);
                    n += 1;
                    shadowed += (tc < 0.5) as usize;
                }
            }
        }
    }
    eprintln!("transmittance grids {tabled:?}: {n} voxels lit above 1e-3 ({shadowed} below 0.5), worst relative difference {worst:.2e}");
    assert!(n >= min_lit && 3 * shadowed >= n, "{n} lit voxels, {shadowed} in shadow");
    assert!(worst <= 1e-5, "transmittance: worst relative difference {worst}");
}

#[test]
fn single_and_multiple_scattering_agree_with_the_cpu() {
    let v = lumpy_ball();
    let p = params(&v);
    let map = photons(&v, &p);
    let Some((cpu, gpu)) = both(&v, &map, &p) else { return };
    assert_single_agrees(&cpu, &gpu, "the sun tabled, the point light by shadow rays");
    // The sun's, not the point light's.
    assert_transmittance_agrees(&cpu, &gpu, &[0], 3000);
    assert_multiple_agrees(&cpu, &gpu, "k nearest");
}

/// Shadow rays instead of tables (`--shadows rays`): composite Simpson on both backends, and
/// no tables, so no transmittance grids.
#[test]
fn single_scattering_by_shadow_rays_agrees_with_the_cpu() {
    let v = lumpy_ball();
    let p = CacheParams { multiple: false, shadows: ShadowMode::Rays, ..params(&v) };
    let Some((cpu, gpu)) = both(&v, &PhotonMap::default(), &p) else { return };
    assert_single_agrees(&cpu, &gpu, "shadow rays");
    assert_transmittance_agrees(&cpu, &gpu, &[], 0);
}

/// Several suns and a point light: each sun's table in the one node buffer, found through its
/// own brick index and lattice map; the point light keeps shadow rays.
#[test]
fn every_sun_is_tabled_and_looked_up_as_on_the_cpu() {
    let v = lumpy_ball();
    let (lo, hi) = v.world_bounds().unwrap();
    let lights = vec![
        Light::sun(Vec3::new(0.3, 0.2, -1.0).normalize(), Vec3::new(1.0, 2.0, 3.0)).unwrap(),
        Light::point(0.5 * (lo + hi) + DVec3::new(0.3, -2.0, 1.5), Vec3::splat(2.0)).unwrap(),
        Light::sun(Vec3::X, Vec3::new(0.5, 0.5, 0.2)).unwrap(),
        Light::sun(Vec3::new(-0.4, 0.8, 0.3).normalize(), Vec3::splat(0.7)).unwrap(),
    ];
    let p = CacheParams { multiple: false, lights, ..params(&v) };
    let Some((cpu, gpu)) = both(&v, &PhotonMap::default(), &p) else { return };
    assert_single_agrees(&cpu, &gpu, "three suns tabled and a point light");
    assert_transmittance_agrees(&cpu, &gpu, &[0, 2, 3], 10_000);
}

#[test]
fn a_fixed_radius_gather_agrees_with_the_cpu() {
    let v = lumpy_ball();
    let p = CacheParams { single: false, gather: Gather::Radius(0.25), ..params(&v) };
    let map = photons(&v, &p);
    let Some((cpu, gpu)) = both(&v, &map, &p) else { return };
    assert!(cpu.li_single.is_none() && gpu.li_single.is_none());
    assert_multiple_agrees(&cpu, &gpu, "radius");
}

#[test]
fn too_many_neighbours_is_an_error_not_a_panic() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = lumpy_ball();
    let p = CacheParams { gather: Gather::Neighbours { k: 10_000, max_radius: 0.6 }, ..params(&v) };
    let map = photons(&v, &p);
    assert!(bake_gpu(ctx, &v, &map, &p).is_err());
}

/// 70,000 photons in one bin: every voxel's nearest-photon search within reach of it offers
/// them all, more loop iterations than a software adapter (llvmpipe: 65535 per SIMD group)
/// runs whole; it used to end the search early without an error and estimate from whichever
/// photons it had seen. A software adapter must refuse; any other must match the CPU.
#[test]
fn photon_searches_longer_than_a_software_adapter_runs_are_refused() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = support::block(IVec3::splat(-3), IVec3::splat(2), |_| 2.0);
    let n = 70_000;
    let mut rng = 12345u64;
    let mut next = move || {
        rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut map = PhotonMap::default();
    for _ in 0..n {
        map.positions.push(DVec3::new(next(), next(), next()) * 0.01 - 0.005);
        map.power.push(Vec3::splat(1e-4));
        map.dir.push(Vec3::new(next() as f32 - 0.5, next() as f32 - 0.5, 0.3).normalize());
    }
    let (lo, hi) = v.world_bounds().unwrap();
    let p = CacheParams {
        single: false,
        gather: Gather::Neighbours { k: 8, max_radius: 0.15 },
        camera: Camera::default_for_bounds(lo, hi).unwrap(),
        cache_scale: 2.0,
        single_tolerance: None,
        path_tolerance: None,
        multiple_scale: None,
        multiple_tolerance: None,
        ..params(&v)
    };
    match bake_gpu(ctx, &v, &map, &p) {
        Err(e) if ctx.loop_cap().is_some() => {
            let e = e.to_string();
            assert!(e.contains("65535") && e.contains("--device cpu"), "{e}");
        }
        Err(e) => panic!("a hardware adapter should bake it: {e}"),
        Ok((gpu, _)) => {
            let (cpu, _) = bake_cpu(&v, &map, &p).unwrap();
            let (worst, peak, n) = compare(cpu.li_multiple.as_ref().unwrap(), gpu.li_multiple.as_ref().unwrap());
            eprintln!("li_multiple over {n} voxels: worst {worst:e}, peak {peak:e}");
            assert!(peak > 0.0 && worst <= 1e-3 * peak, "li_multiple: worst {worst}, peak {peak}");
            assert!(ctx.loop_cap().is_none(), "a software adapter should refuse");
        }
    }
}

/// Voxel by voxel over the two caches' shared lattice: how many voxels, how many agree to
/// 1e-4 of their own value (1e-6 of the peak near zero), and the mean and standard error of the difference (GPU -
/// CPU) of the red channel. Distinct voxels draw from distinct streams, so the differences
/// are independent and their mean is zero within a few standard errors if the two agree
/// in distribution.
fn paired_differences(cpu: &Volume<Vec3>, gpu: &Volume<Vec3>) -> (usize, usize, usize, f64, f64, f64) {
    assert_eq!(cpu.transform(), gpu.transform());
    assert_eq!(cpu.active_voxel_count(), gpu.active_voxel_count());
    let mut pairs = Vec::new();
    for brick in cpu.bricks() {
        for (offset, c) in brick.values.iter().enumerate() {
            let ijk = brick.origin + nimbus_volume::brick_local(offset);
            if cpu.is_active(ijk) {
                assert!(gpu.is_active(ijk), "{ijk} baked on one backend only");
                pairs.push((c.x as f64, gpu.get(ijk).x as f64));
            }
        }
    }
    let n = pairs.len();
    let peak = pairs.iter().map(|p| p.0.max(p.1)).fold(0.0, f64::max);
    // Among the voxels either backend lights (a voxel given one path that escapes is 0 on
    // both, whatever the random numbers).
    let lit = |(c, g): &&(f64, f64)| c.max(*g) > 1e-3 * peak;
    let same = pairs.iter().filter(lit).filter(|(c, g)| (c - g).abs() <= 1e-4 * c.abs().max(g.abs()) + 1e-6 * peak).count();
    let n_lit = pairs.iter().filter(lit).count();
    let mean_cpu = pairs.iter().map(|p| p.0).sum::<f64>() / n as f64;
    let d: Vec<f64> = pairs.iter().map(|(c, g)| g - c).collect();
    let mean = d.iter().sum::<f64>() / n as f64;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    (n, n_lit, same, mean_cpu, mean, (var / n as f64).sqrt())
}

/// Asserts that both backends' Li_multiple agree in distribution ([`paired_differences`]:
/// more than 500 voxels, a non-zero level, the mean difference within four standard errors)
/// and returns the voxels, the lit ones and those the same to 1e-4.
fn assert_same_in_distribution(cpu: &Volume<Vec3>, gpu: &Volume<Vec3>, what: &str) -> (usize, usize, usize) {
    let (n, lit, same, level, mean, se) = paired_differences(cpu, gpu);
    eprintln!("{what}: {n} voxels, {lit} lit, {same} of those the same to 1e-4; mean CPU {level:.4e}, mean GPU - CPU {mean:.3e} +- {se:.3e}");
    assert!(n > 500 && level > 0.0, "{what}: {n} voxels, level {level}");
    assert!(mean.abs() <= 4.0 * se + 1e-4 * level, "{what}: mean difference {mean} against its standard error {se}");
    (n, lit, same)
}

#[test]
fn path_traced_multiple_scattering_agrees_with_the_cpu_in_distribution() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = lumpy_ball();
    let per_voxel = 8;
    let p = paths_only(&v, 5);
    let none = PhotonMap::default();
    let (cpu, cpu_stats) = bake_cpu(&v, &none, &p).unwrap();
    let (gpu, gpu_stats) = bake_gpu(ctx, &v, &none, &p).unwrap();
    eprintln!("CPU {cpu_stats:?}\nGPU {gpu_stats:?}");
    assert_eq!(gpu_stats.baked, cpu_stats.baked);
    assert_eq!(gpu_stats.nonfinite, 0);
    assert!(cpu.li_single.is_none() && gpu.li_single.is_none());
    // The host decides every voxel's count for both backends: N per voxel on average, exactly.
    let (cpu, gpu) = (cpu.li_multiple.unwrap(), gpu.li_multiple.unwrap());
    assert_eq!(cpu_stats.paths, per_voxel as u64 * cpu_stats.baked, "N paths per voxel on average");
    assert_eq!(gpu_stats.paths, cpu_stats.paths, "paths traced");
    assert_eq!(gpu_stats.culled_unseen, cpu_stats.culled_unseen, "the same path plan");
    assert!(gpu_stats.light_table_nodes > 0 && gpu_stats.light_table_nodes == cpu_stats.light_table_nodes, "the sun's table serves next-event estimation");
    let (_, lit, same) = assert_same_in_distribution(&cpu, &gpu, "paths");
    // The same stream per voxel (seed, voxel, domain): most voxels' paths take the very same
    // turns; f32 decides a few of them otherwise.
    assert!(lit > 500 && same as f64 >= 0.5 * lit as f64, "only {same} of {lit} lit voxels agree: not the CPU's random numbers?");
    // Another seed gives other paths (the seed reaches the GPU).
    let (other, _) = bake_gpu(ctx, &v, &none, &CacheParams { seed: 6, ..p.clone() }).unwrap();
    let (_, lit_other, same_other, ..) = paired_differences(&cpu, &other.li_multiple.unwrap());
    assert!((same_other as f64) < 0.5 * lit_other as f64, "seed 6 agrees with seed 5 at {same_other} of {lit_other} lit voxels");
}

/// The dispatch sizes of both kinds of adapter (nimbus_gpu::DispatchSizing) on this one: a
/// voxel's paths in one dispatch (the hardware's sizes) or one a dispatch (a software
/// adapter's, at its least) are the same paths, from the same stream, summed in the same
/// order: the same values, and the CPU's in distribution.
#[test]
fn the_paths_are_the_same_whatever_the_dispatch_sizes() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = lumpy_ball();
    // A thin medium: its paths are short enough that all of a voxel's run whole in one
    // dispatch on a software adapter too.
    let thin = paths_only(&v, 5);
    let p = CacheParams { medium: Medium { extinction: 0.5, ..thin.medium }, ..thin };
    let none = PhotonMap::default();
    let hardware = ctx.with_dispatch(nimbus_gpu::DispatchSizing::HARDWARE);
    let one_a_pass = ctx.with_dispatch(nimbus_gpu::DispatchSizing { max_repeats: 1, ..nimbus_gpu::DispatchSizing::SOFTWARE });
    let (all, all_stats) = bake_gpu(&hardware, &v, &none, &p).unwrap();
    let (each, each_stats) = bake_gpu(&one_a_pass, &v, &none, &p).unwrap();
    assert_eq!(all_stats.paths, each_stats.paths);
    let (all, each) = (all.li_multiple.unwrap(), each.li_multiple.unwrap());
    let (worst, peak, n) = compare(&all, &each);
    assert!(n > 500 && worst == 0.0, "{n} voxels differ by up to {worst} (peak {peak}) between the dispatch sizes");
    let (cpu, _) = bake_cpu(&v, &none, &p).unwrap();
    assert_same_in_distribution(&cpu.li_multiple.unwrap(), &all, "paths at the hardware's sizes");
}

/// The top-up (budget.rs) on both backends: the GPU's paths report their mean squares as the
/// CPU's do, so both predict the same noise, trace a second pass of about the same size from
/// the second pass's streams, and agree in distribution after it.
#[test]
fn paths_topped_up_to_a_tolerance_agree_with_the_cpu() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = lumpy_ball();
    let none = PhotonMap::default();
    // The first pass alone, its noise predicted (a tolerance no bake misses).
    let first = CacheParams { path_tolerance: Some(1.0), ..paths_only(&v, 5) };
    let (_, cpu_first) = bake_cpu(&v, &none, &first).unwrap();
    let (_, gpu_first) = bake_gpu(ctx, &v, &none, &first).unwrap();
    let (cpu_noise, gpu_noise) = (cpu_first.path_noise.unwrap().0, gpu_first.path_noise.unwrap().0);
    eprintln!("predicted noise after the first pass: CPU {cpu_noise:.4}, GPU {gpu_noise:.4}");
    assert!(cpu_noise > 0.0 && (gpu_noise / cpu_noise - 1.0).abs() < 0.05, "CPU {cpu_noise}, GPU {gpu_noise}");
    // Half of it: about four times the paths in all.
    let p = CacheParams { path_tolerance: Some(cpu_noise / 2.0), ..first };
    let (cpu, cpu_stats) = bake_cpu(&v, &none, &p).unwrap();
    let (gpu, gpu_stats) = bake_gpu(ctx, &v, &none, &p).unwrap();
    let growth = cpu_stats.paths as f64 / cpu_first.paths as f64;
    eprintln!("CPU {:?} {} paths, GPU {:?} {} paths ({growth:.2}x the first pass)", cpu_stats.path_noise, cpu_stats.paths, gpu_stats.path_noise, gpu_stats.paths);
    assert!((3.5..4.7).contains(&growth), "about four times the paths: {growth}");
    assert!((gpu_stats.paths as f64 / cpu_stats.paths as f64 - 1.0).abs() < 0.05, "CPU {} paths, GPU {}", cpu_stats.paths, gpu_stats.paths);
    assert_same_in_distribution(&cpu.li_multiple.unwrap(), &gpu.li_multiple.unwrap(), "topped up");
}

/// Li_multiple's lattice bias (multiple_lattice.rs) from the GPU's paths as from the CPU's:
/// the same streams summed by the same parities and origin octants give the same estimate,
/// and a tolerance below it refines both to the same finer lattice.
#[test]
fn the_lattice_bias_is_estimated_and_acted_on_as_on_the_cpu() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = lumpy_ball();
    let none = PhotonMap::default();
    let keep = CacheParams { multiple_tolerance: Some(1.0), ..paths_only(&v, 5) };
    let (_, cpu) = bake_cpu(&v, &none, &keep).unwrap();
    let (_, gpu) = bake_gpu(ctx, &v, &none, &keep).unwrap();
    let (c, g) = (cpu.multiple_lattice.unwrap(), gpu.multiple_lattice.unwrap());
    eprintln!("CPU {c:?}\nGPU {g:?}");
    assert_eq!((c.first_scale, c.scale), (2.5, 2.5), "a tolerance of 100% keeps the lattice");
    assert_eq!((g.first_scale, g.scale), (2.5, 2.5));
    assert!(c.bias.rays > 100 && c.bias.rays == g.bias.rays, "the same importance rays");
    assert!(c.bias.squared > 0.0, "the ball's footprints leave some bias: {c:?}");
    let spread = 4.0 * (c.bias.standard_error.powi(2) + g.bias.standard_error.powi(2)).sqrt();
    assert!((c.bias.squared - g.bias.squared).abs() <= spread, "CPU {:?}, GPU {:?}", c.bias, g.bias);
    // A tolerance far below the estimate: both refine, halving at most per pass, until the
    // finer lattice's own estimate is within its error or the floor (half of Li_single's 1.5
    // voxels) is reached, and both stop at the same lattice.
    let refine = CacheParams { multiple_tolerance: Some(1e-4), ..keep };
    let (cpu_cache, cpu) = bake_cpu(&v, &none, &refine).unwrap();
    let (gpu_cache, gpu) = bake_gpu(ctx, &v, &none, &refine).unwrap();
    let (c, g) = (cpu.multiple_lattice.unwrap(), gpu.multiple_lattice.unwrap());
    eprintln!("refined: CPU {c:?}\nGPU {g:?}");
    assert!(c.first_scale == 2.5 && (0.75..=1.25).contains(&c.scale), "{c:?}");
    // The refined lattice's bias measured against the bake before it, from both backends.
    let ([cf, cc], [gf, gc]) = (c.bias.measured.unwrap(), g.bias.measured.unwrap());
    assert!(cf.is_finite() && gf.is_finite() && cc >= cf && gc >= gf, "{c:?} {g:?}");
    assert_eq!((g.first_scale, g.scale), (c.first_scale, c.scale), "{g:?}");
    let (cpu_li, gpu_li) = (cpu_cache.li_multiple.unwrap(), gpu_cache.li_multiple.unwrap());
    assert!((cpu_li.transform().voxel_size().x - 0.1 * c.scale).abs() < 1e-12, "the finer lattice is what is stored");
    assert_eq!(cpu.baked, gpu.baked);
    assert_same_in_distribution(&cpu_li, &gpu_li, "refined lattice");
}

/// A uniform sky and a map through the paths on both backends: escaping flights, and for
/// the map next-event estimation at the voxel and at every collision, from the same random
/// streams.
#[test]
fn the_environment_in_the_paths_agrees_with_the_cpu_in_distribution() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = lumpy_ball();
    let sky = nimbus_optics::Environment::uniform(Vec3::new(0.3, 0.5, 0.9)).unwrap();
    for (sky, lights) in [(sky.clone(), vec![]), (sky, params(&v).lights), (test_map(), vec![])] {
        let p = CacheParams { environment: Some(sky.clone()), lights: lights.clone(), ..paths_only(&v, 9) };
        let none = PhotonMap::default();
        let (cpu, _) = bake_cpu(&v, &none, &p).unwrap();
        let (gpu, gpu_stats) = bake_gpu(ctx, &v, &none, &p).unwrap();
        assert_eq!(gpu_stats.nonfinite, 0);
        let what = format!("{}, {} lights", if sky.wants_next_event() { "map" } else { "sky" }, lights.len());
        let (_, lit, same) = assert_same_in_distribution(&cpu.li_multiple.unwrap(), &gpu.li_multiple.unwrap(), &what);
        assert!(lit > 500, "{what}: {lit} lit voxels");
        assert!(same as f64 >= 0.3 * lit as f64, "only {same} of {lit} lit voxels agree: not the CPU's estimator?");
    }
}

/// A sun with a disc (10 degrees) on both backends: Li_single's rays over the disc (at other
/// directions per point on each: the offset hashes of positions differ) and the paths'
/// next-event estimates over it (the same streams).
#[test]
fn a_sun_with_a_disc_agrees_with_the_cpu_in_distribution() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = lumpy_ball();
    let sun = Light::sun_with_angle(Vec3::new(-0.3, 0.5, -0.8).normalize(), Vec3::splat(2.0), 10.0).unwrap();
    let p = CacheParams {
        cache_scale: 1.5,
        single_tolerance: None,
        path_tolerance: None,
        multiple_scale: Some(2.5),
        multiple_tolerance: None,
        estimator: MultipleEstimator::Paths { per_voxel: 8 },
        lights: vec![sun],
        seed: 3,
        ..params(&v)
    };
    let none = PhotonMap::default();
    let (cpu, _) = bake_cpu(&v, &none, &p).unwrap();
    let (gpu, stats) = bake_gpu(ctx, &v, &none, &p).unwrap();
    assert_eq!(stats.nonfinite, 0);
    assert_eq!(stats.light_table_nodes, 0, "a sun with a disc has no table");
    let mean = |c: &IlluminationCache, single: bool| {
        let v = if single { c.li_single.as_ref() } else { c.li_multiple.as_ref() }.unwrap();
        let (sum, n) = v.bricks().flat_map(|b| b.values.iter()).fold((0.0f64, 0usize), |(s, n), x| (s + x.x as f64, n + 1));
        sum / n as f64
    };
    for single in [true, false] {
        let (c, g) = (mean(&cpu, single), mean(&gpu, single));
        eprintln!("disc sun, {}: cpu {c:.5e}, gpu {g:.5e}", if single { "single" } else { "multiple" });
        assert!(c > 0.0 && (g / c - 1.0).abs() < 0.02, "{c} vs {g}");
    }
    let (n, lit, same, ..) = paired_differences(&cpu.li_multiple.unwrap(), &gpu.li_multiple.unwrap());
    assert!(n > 500 && same as f64 >= 0.3 * lit as f64, "only {same} of {lit} lit voxels agree: not the CPU's estimator?");
}

/// A 16 x 8 map with a bright patch, turned by 30 degrees: what the GPU's map sampling
/// (environment.wgsl) must draw as the CPU does.
pub fn test_map() -> nimbus_optics::Environment {
    let texels = (0..16 * 8).map(|i| if i % 16 == 5 && i / 16 == 2 { Vec3::new(20.0, 18.0, 15.0) } else { Vec3::new(0.2, 0.3, 0.5 + 0.05 * (i / 16) as f32) }).collect();
    let map = nimbus_optics::EnvironmentMap::new(16, 8, texels).unwrap();
    nimbus_optics::Environment::map(map, "test.exr", 1.5, 30.0).unwrap()
}

#[test]
fn li_multiple_takes_its_own_lattice_on_the_gpu_as_on_the_cpu() {
    let v = lumpy_ball();
    let p = CacheParams { multiple_scale: Some(3.0), ..params(&v) };
    let map = photons(&v, &p);
    let Some((cpu, gpu)) = both(&v, &map, &p) else { return };
    let (single, multiple) = (gpu.li_single.as_ref().unwrap(), gpu.li_multiple.as_ref().unwrap());
    assert_eq!(single.transform(), cpu.li_single.as_ref().unwrap().transform());
    assert_eq!(multiple.transform(), cpu.li_multiple.as_ref().unwrap().transform());
    assert_ne!(single.transform(), multiple.transform(), "Li_multiple has its own lattice");
    assert!(multiple.active_voxel_count() < single.active_voxel_count() / 3);
    let (worst, peak, _) = compare(cpu.li_single.as_ref().unwrap(), single);
    assert!(peak > 0.0 && worst <= 1e-5 * peak, "single scattering: worst {worst} of peak {peak}");
    let (worst, peak, n) = compare(cpu.li_multiple.as_ref().unwrap(), multiple);
    eprintln!("multiple on its own lattice: {n} voxels, worst {worst:.3e} of peak {peak:.3e}");
    assert!(peak > 0.0 && worst <= 1e-4 * peak, "multiple scattering: worst {worst} of peak {peak}");
}

/// Paths of 512 collisions each (albedo 1, so roulette never ends them, in a cube 300 mean
/// free paths across, which they never leave), with shadow rays toward six suns at every
/// collision: at the hardware's dispatch sizes (as many paths a dispatch as the work allows)
/// more loop iterations per SIMD group than a software adapter (llvmpipe: 65535) runs whole.
/// A software adapter must refuse them; any other must trace the CPU's count of paths. At a
/// software adapter's own sizes (one path a dispatch, nothing being absorbed) it bakes them
/// as the CPU does.
#[test]
fn paths_longer_than_a_software_adapter_runs_are_refused() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = support::block(IVec3::splat(-5), IVec3::splat(4), |_| 300.0);
    let (lo, hi) = v.world_bounds().unwrap();
    let suns = [(0.3, 0.2, -1.0), (-0.5, 0.1, -0.8), (0.1, -0.9, -0.3), (0.7, 0.7, 0.1), (-0.2, 0.4, 0.9), (0.0, 0.0, 1.0)];
    // Shadow rays (tables would look the suns up, with no loop to run out of).
    let p = CacheParams {
        shadows: ShadowMode::Rays,
        medium: Medium { extinction: 1.0, albedo: Vec3::ONE, g: 0.0 },
        lights: suns.iter().map(|&(x, y, z)| Light::sun(Vec3::new(x, y, z).normalize(), Vec3::ONE).unwrap()).collect(),
        camera: Camera::default_for_bounds(lo, hi).unwrap(),
        single: false,
        cache_scale: 2.0,
        single_tolerance: None,
        path_tolerance: None,
        multiple_scale: None,
        multiple_tolerance: None,
        estimator: MultipleEstimator::Paths { per_voxel: 4 },
        // Where a software adapter cuts them, on both backends.
        path_max_depth: nimbus_cache::SOFTWARE_PATH_MAX_DEPTH,
        ..params(&v)
    };
    let none = PhotonMap::default();
    let (cpu, cpu_stats) = bake_cpu(&v, &none, &p).unwrap();
    match bake_gpu(&ctx.with_dispatch(nimbus_gpu::DispatchSizing::HARDWARE), &v, &none, &p) {
        Err(e) if ctx.loop_cap().is_some() => {
            let e = e.to_string();
            assert!(e.contains("paths") && e.contains("65535") && e.contains("--device cpu"), "{e}");
        }
        Err(e) => panic!("a hardware adapter should bake it: {e}"),
        Ok((_, gpu_stats)) => {
            assert_eq!(gpu_stats.paths, cpu_stats.paths);
            assert!(ctx.loop_cap().is_none(), "a software adapter should refuse");
        }
    }
    let (gpu, gpu_stats) = bake_gpu(ctx, &v, &none, &p).unwrap();
    assert_eq!(gpu_stats.paths, cpu_stats.paths);
    assert_same_in_distribution(&cpu.li_multiple.unwrap(), &gpu.li_multiple.unwrap(), "paths one a dispatch");
}

/// The medium's emission gathered by the paths on both backends (path.wgsl's collision
/// estimator with emission.wgsl at group 3): a fire alone (no lights: the paths are planned
/// for the emission) and with the lights, from the same random streams.
#[test]
fn emission_in_the_paths_agrees_with_the_cpu_in_distribution() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = lumpy_ball();
    // The emission grid is the density itself; the blackbody from a temperature grid on
    // another lattice (a coarser copy, shifted).
    let mut temperature = Volume::new(Transform::uniform(0.15, DVec3::new(1e4 + 0.04, -3e3, 50.0)), 0.0);
    for c in (-8..=8).flat_map(|x| (-8..=8).flat_map(move |y| (-8..=8).map(move |z| IVec3::new(x, y, z)))) {
        let r = c.as_vec3().length() / 8.0;
        if r < 1.0 {
            temperature.set(c, 1.0 + 1.5 * (1.0 - r));
        }
    }
    let emission = nimbus_optics::Emission {
        grid: Some("density".into()),
        strength: 0.3,
        color: Vec3::new(1.0, 0.5, 0.2),
        temperature_grid: Some("temperature".into()),
        temperature_scale: 1000.0,
        blackbody_intensity: 0.2,
    };
    let field = nimbus_tracking::EmissionField { grid: Some(&v), temperature: Some(&temperature), params: &emission };
    for lights in [vec![], params(&v).lights] {
        let p = CacheParams { lights: lights.clone(), ..paths_only(&v, 4) };
        let none = PhotonMap::default();
        let (cpu, cpu_stats) = nimbus_cache::bake_cpu_emitting(&v, &none, &p, Some(&field)).unwrap();
        let (gpu, gpu_stats) = nimbus_cache::bake_gpu_emitting(ctx, &v, &none, &p, Some(&field)).unwrap();
        assert_eq!(gpu_stats.nonfinite, 0);
        assert_eq!(gpu_stats.paths, cpu_stats.paths, "the same path plan");
        let what = format!("emission, {} lights", lights.len());
        let (_, lit, same) = assert_same_in_distribution(&cpu.li_multiple.unwrap(), &gpu.li_multiple.unwrap(), &what);
        assert!(lit > 500, "{what}: {lit} lit voxels");
        assert!(same as f64 >= 0.5 * lit as f64, "only {same} of {lit} lit voxels agree: not the CPU's estimator?");
    }
    // Without the field and without lights the GPU bakes nothing, as the CPU.
    let p = CacheParams { single: false, estimator: MultipleEstimator::Paths { per_voxel: 8 }, lights: vec![], ..params(&v) };
    let (dark, _) = nimbus_cache::bake_gpu_emitting(ctx, &v, &PhotonMap::default(), &p, None).unwrap();
    assert!(dark.li_multiple.is_none());
}

/// A software adapter cuts the paths at its 512 collisions, and says so where the medium's
/// albedo lets paths get that far (a cloud's 0.999), not where it does not (0.9).
#[test]
fn a_software_adapter_says_where_it_cuts_the_paths() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let v = lumpy_ball();
    let none = PhotonMap::default();
    let bright = CacheParams { medium: Medium { extinction: 3.0, albedo: Vec3::splat(0.999), g: 0.3 }, ..paths_only(&v, 3) };
    let (_, stats) = bake_gpu(ctx, &v, &none, &bright).unwrap();
    let expected = ctx.loop_cap().map(|_| nimbus_cache::SOFTWARE_PATH_MAX_DEPTH);
    assert_eq!(stats.paths_cut_at, expected, "albedo 0.999 on {:?}", ctx.loop_cap());
    let (_, stats) = bake_gpu(ctx, &v, &none, &paths_only(&v, 3)).unwrap();
    assert_eq!(stats.paths_cut_at, None, "albedo 0.9 loses nothing at 512 collisions");
    let (_, stats) = bake_cpu(&v, &none, &bright).unwrap();
    assert_eq!(stats.paths_cut_at, None, "the CPU traces them to {}", nimbus_cache::PATH_MAX_DEPTH);
}
