//! The reference path tracer (`vdbmarch --reference`) against closed forms and against the
//! cached chain.

mod common;

use glam::{DVec3, IVec3, Vec3};
use nimbus_march::{render_cpu, render_reference_cpu, render_reference_gpu, Image, MarchParams, MediumFields, ReferenceParams};
use nimbus_optics::{Camera, Light, Medium};
use nimbus_volume::Volume;

const VOXEL: f64 = 0.05;

fn no_progress(_: u64) {}

fn ball() -> Volume<f32> {
    common::soft_ball(VOXEL)
}

fn params(medium: Medium, lights: Vec<Light>, camera: Camera, spp: u32) -> ReferenceParams {
    ReferenceParams { environment: None, environment_visible: false, medium, lights, camera, spp, max_depth: ReferenceParams::DEFAULT_MAX_DEPTH, background: Vec3::ZERO, seed: 7, aovs: true }
}

fn mean(values: impl Iterator<Item = Vec3>) -> Vec3 {
    let (sum, n) = values.fold((Vec3::ZERO, 0), |(s, n), v| (s + v, n + 1));
    sum / n as f32
}

#[test]
fn slab_transmittance_matches_the_closed_form() {
    // Unit density |z| <= 10 voxels (the trilinear ramps add half a voxel each side), seen
    // face-on through a 2 degree lens: tau = extinction * 21 voxels.
    let slab = common::filled(VOXEL, IVec3::new(-40, -40, -10), IVec3::new(40, 40, 10), |_| true);
    let medium = Medium { extinction: 1.0, albedo: Vec3::splat(0.5), g: 0.0 };
    let camera = Camera::new(DVec3::new(0.0, 0.0, 3.0), DVec3::ZERO, DVec3::Y, 2.0, 8, 8).unwrap();
    let mut p = params(medium, vec![Light::default_sun()], camera, 64);
    p.background = Vec3::new(1.0, 2.0, 3.0);
    let image = render_reference_cpu(&slab, &p, &no_progress).unwrap();
    let expected = (-1.0 * 21.0 * VOXEL).exp();
    let n = (8 * 8 * 64) as f64;
    let got = image.aovs.as_ref().unwrap().transmittance.iter().map(|&t| t as f64).sum::<f64>() / 64.0;
    // Ratio tracking against a tight majorant is a Bernoulli trial in the slab's interior:
    // the binomial standard error bounds the estimate.
    let sigma = (expected * (1.0 - expected) / n).sqrt();
    assert!((got - expected).abs() < 4.0 * sigma, "transmittance {got}, closed form {expected} (sigma {sigma})");
    // Alpha is 1 - T and the background shows through T.
    let px = image.rgba[27];
    let t = image.aovs.as_ref().unwrap().transmittance[27];
    assert!((px.w - (1.0 - t)).abs() < 1e-6);
    assert!(px.z >= 3.0 * t - 1e-5);
}

#[test]
fn single_scattering_matches_the_cached_chain() {
    let density = ball();
    let medium = Medium { extinction: 2.0, albedo: Vec3::new(0.9, 0.8, 0.7), g: 0.4 };
    let sun = Light::sun(Vec3::new(0.4, 0.2, -0.9).normalize(), Vec3::splat(3.0)).unwrap();
    let camera = Camera::new(DVec3::new(0.1, -3.0, 0.4), DVec3::ZERO, DVec3::Z, 30.0, 20, 16).unwrap();
    let (cache, march) = common::single_scattering_chain(&density, medium, sun, &camera, VOXEL / 4.0);
    let march = MarchParams { max_step_factor: MarchParams::DEFAULT_MAX_STEP_FACTOR, spp: 4, aovs: true, ..march };
    let chain = render_cpu(&density, &cache, &march).unwrap();
    let reference = render_reference_cpu(&density, &params(medium, vec![sun], camera, 256), &no_progress).unwrap();
    let (c, r) = (chain.aovs.as_ref().unwrap(), reference.aovs.as_ref().unwrap());
    let (mc, mr) = (mean(c.single.iter().copied()), mean(r.single.iter().copied()));
    let ratio = mr / mc;
    eprintln!("single scattering, image mean: reference {mr} / chain {mc} = {ratio}");
    assert!(mc.x > 0.0);
    // 320 pixels x 256 paths: the mean's Monte Carlo error is well under 1%.
    assert!((ratio - Vec3::ONE).abs().max_element() < 0.02, "reference / chain = {ratio}");
    // Transmittance (alpha) agrees too: the chain marches it, the reference ratio-tracks it.
    let (tc, tr) = (c.transmittance.iter().sum::<f32>() / 320.0, r.transmittance.iter().sum::<f32>() / 320.0);
    assert!((tc - tr).abs() < 0.01, "mean transmittance: chain {tc}, reference {tr}");
    assert!(r.multiple.iter().any(|m| m.x > 0.0), "albedo 0.9 scatters more than once");
}

#[test]
fn max_depth_one_and_albedo_zero_leave_no_multiple_scattering() {
    let density = ball();
    let camera = Camera::new(DVec3::new(0.1, -3.0, 0.4), DVec3::ZERO, DVec3::Z, 30.0, 8, 6).unwrap();
    let medium = Medium { extinction: 2.0, albedo: Vec3::splat(0.95), g: 0.0 };
    let mut p = params(medium, vec![Light::default_sun()], camera, 8);
    p.max_depth = 1;
    let image = render_reference_cpu(&density, &p, &no_progress).unwrap();
    let a = image.aovs.as_ref().unwrap();
    assert!(a.multiple.iter().all(|m| *m == Vec3::ZERO));
    assert!(a.single.iter().any(|s| s.x > 0.0));

    let black = Medium { albedo: Vec3::ZERO, ..medium };
    let image = render_reference_cpu(&density, &params(black, vec![Light::default_sun()], camera, 8), &no_progress).unwrap();
    assert!(image.rgba.iter().all(|c| c.truncate() == Vec3::ZERO));
    assert!(image.rgba.iter().any(|c| c.w > 0.5), "an absorbing ball still blocks the background");
}

fn relative_rmse(image: &Image, reference: &Image) -> f64 {
    let sq: f64 = image.rgba.iter().zip(&reference.rgba).map(|(a, b)| ((a.truncate() - b.truncate()).length_squared()) as f64).sum();
    let level: f64 = reference.rgba.iter().map(|b| b.truncate().length() as f64).sum::<f64>() / reference.rgba.len() as f64;
    (sq / image.rgba.len() as f64).sqrt() / level
}

#[test]
fn error_halves_when_paths_quadruple_and_renders_repeat() {
    let density = ball();
    let medium = Medium { extinction: 3.0, albedo: Vec3::splat(0.9), g: 0.3 };
    let camera = Camera::new(DVec3::new(0.1, -3.0, 0.4), DVec3::ZERO, DVec3::Z, 20.0, 12, 9).unwrap();
    let sun = vec![Light::sun(Vec3::new(-0.3, 0.5, -0.8).normalize(), Vec3::splat(2.0)).unwrap()];
    let converged = render_reference_cpu(&density, &ReferenceParams { seed: 99, ..params(medium, sun.clone(), camera, 4096) }, &no_progress).unwrap();
    let errors: Vec<f64> = [16, 64, 256]
        .iter()
        .map(|&spp| relative_rmse(&render_reference_cpu(&density, &params(medium, sun.clone(), camera, spp), &no_progress).unwrap(), &converged))
        .collect();
    eprintln!("relative RMSE at 16/64/256 spp: {errors:?}");
    for pair in errors.windows(2) {
        let ratio = pair[0] / pair[1];
        // 1/sqrt(spp): 2 per quadrupling (the 4096-spp stand-in's own noise shrinks the last ratio a little).
        assert!((1.6..2.5).contains(&ratio), "error ratio {ratio} for 4x paths: {errors:?}");
    }
    let again = render_reference_cpu(&density, &params(medium, sun, camera, 16), &no_progress).unwrap();
    assert_eq!(relative_rmse(&again, &converged), errors[0], "same seed, same image");
}

#[test]
fn gpu_and_cpu_agree_in_distribution() {
    gpu_and_cpu_agree_at(0.3);
}

/// Where |g| >= PROBE_FROM_G both backends send a probe toward the lights at each collision
/// (nimbus_tracking::trace_path): the WGSL twin must draw the same streams in the same order.
#[test]
fn gpu_and_cpu_agree_in_distribution_with_probes_toward_the_lights() {
    assert!(0.8 >= nimbus_tracking::PROBE_FROM_G);
    gpu_and_cpu_agree_at(0.8);
}

fn gpu_and_cpu_agree_at(g: f32) {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let density = ball();
    let medium = Medium { extinction: 3.0, albedo: Vec3::new(0.9, 0.85, 0.8), g };
    let camera = Camera::new(DVec3::new(0.1, -3.0, 0.4), DVec3::ZERO, DVec3::Z, 20.0, 12, 9).unwrap();
    let lights = vec![
        Light::sun(Vec3::new(-0.3, 0.5, -0.8).normalize(), Vec3::splat(2.0)).unwrap(),
        Light::point(DVec3::new(0.5, -1.0, 1.0), Vec3::splat(0.5)).unwrap(),
    ];
    let p = params(medium, lights, camera, 256);
    let cpu = render_reference_cpu(&density, &p, &no_progress).unwrap();
    // Tiles of 50 pixels: the tile loop and progress run too.
    let done = std::sync::atomic::AtomicU64::new(0);
    let gpu = render_reference_gpu(ctx, &density, &p, 50, &|n| {
        done.fetch_add(n, std::sync::atomic::Ordering::Relaxed);
    })
    .unwrap();
    assert_eq!(done.into_inner(), 108);
    let (c, g) = (cpu.aovs.as_ref().unwrap(), gpu.aovs.as_ref().unwrap());
    for (name, a, b) in [("single", &c.single, &g.single), ("multiple", &c.multiple, &g.multiple)] {
        let (ma, mb) = (mean(a.iter().copied()), mean(b.iter().copied()));
        eprintln!("{name}: cpu {ma} gpu {mb}");
        assert!(ma.x > 0.0);
        // 108 pixels x 256 paths each: image means within 3%.
        assert!(((mb - ma) / ma).abs().max_element() < 0.03, "{name}: cpu {ma}, gpu {mb}");
    }
    let (ta, tb) = (c.transmittance.iter().sum::<f32>() / 108.0, g.transmittance.iter().sum::<f32>() / 108.0);
    assert!((ta - tb).abs() < 0.01, "transmittance: cpu {ta}, gpu {tb}");
    // Both draw the same streams, so most pixels agree to f32 rounding; a path that turns
    // otherwise at an f32/f64 decision changes its pixel. (Before samples went in separate
    // dispatches, lavapipe's 65535-iteration loop cap truncated whole SIMD groups of pixels
    // to about half their value: this catches that.)
    let close = cpu.rgba.iter().zip(&gpu.rgba).filter(|(a, b)| (**a - **b).abs().max_element() <= 1e-3 * a.max_element().max(1e-3)).count();
    eprintln!("{close} of 108 pixels equal to 1e-3");
    assert!(close >= 80, "only {close} of 108 pixels agree to 1e-3");
}

#[test]
fn the_environment_renders_alike_on_gpu_and_cpu() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let density = ball();
    let medium = Medium { extinction: 3.0, albedo: Vec3::new(0.9, 0.85, 0.8), g: 0.3 };
    let camera = Camera::new(DVec3::new(0.1, -3.0, 0.4), DVec3::ZERO, DVec3::Z, 20.0, 12, 9).unwrap();
    let texels = (0..16 * 8).map(|i| if i % 16 == 5 && i / 16 == 2 { Vec3::new(20.0, 18.0, 15.0) } else { Vec3::new(0.2, 0.3, 0.5 + 0.05 * (i / 16) as f32) }).collect();
    let map = nimbus_optics::Environment::map(nimbus_optics::EnvironmentMap::new(16, 8, texels).unwrap(), "test.exr", 1.5, 30.0).unwrap();
    for environment in [nimbus_optics::Environment::uniform(Vec3::new(0.2, 0.4, 0.8)).unwrap(), map] {
    let mut p = params(medium, vec![], camera.clone(), 256);
    p.environment = Some(environment);
    // Seen behind the ball too: the map through the shader, a sky as the background.
    p.environment_visible = true;
    let cpu = render_reference_cpu(&density, &p, &no_progress).unwrap();
    let gpu = render_reference_gpu(ctx, &density, &p, 64, &|_| {}).unwrap();
    let (c, g) = (cpu.aovs.as_ref().unwrap(), gpu.aovs.as_ref().unwrap());
    for (name, a, b) in [("single", &c.single, &g.single), ("multiple", &c.multiple, &g.multiple)] {
        let (ma, mb) = (mean(a.iter().copied()), mean(b.iter().copied()));
        eprintln!("sky, {name}: cpu {ma} gpu {mb}");
        assert!(ma.z > 0.0);
        assert!(((mb - ma) / ma).abs().max_element() < 0.03, "{name}: cpu {ma}, gpu {mb}");
    }
    // The sky is seen behind the ball on both.
    let (mc, mg) = (cpu.mean_rgb(), gpu.mean_rgb());
    assert!(((mg - mc) / mc).abs().max_element() < 0.02, "image: cpu {mc}, gpu {mg}");
    let close = cpu.rgba.iter().zip(&gpu.rgba).filter(|(a, b)| (**a - **b).abs().max_element() <= 1e-3 * a.max_element().max(1e-3)).count();
    eprintln!("sky: {close} of 108 pixels equal to 1e-3");
    assert!(close >= 60, "only {close} of 108 pixels agree to 1e-3");
    }
}

/// An albedo-1 cube 300 mean free paths across: a path random-walks tens of thousands of
/// bounces before it leaves, more loop iterations than a software adapter (llvmpipe: 65535 per
/// SIMD group) runs whole; it used to end the walks early without an error and return far too
/// little multiple scattering. A software adapter must refuse; any other must match the CPU
/// in distribution.
#[test]
fn paths_longer_than_a_software_adapter_runs_are_refused() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let cube = common::filled(0.1, IVec3::splat(-5), IVec3::splat(4), |_| true).map(0.0, |d| d * 300.0);
    let medium = Medium { extinction: 1.0, albedo: Vec3::ONE, g: 0.0 };
    let camera = Camera::new(DVec3::new(0.0, -3.0, 0.0), DVec3::ZERO, DVec3::Z, 8.0, 8, 8).unwrap();
    let p = ReferenceParams { max_depth: 1_000_000, ..params(medium, vec![Light::default_sun()], camera, 4) };
    match render_reference_gpu(ctx, &cube, &p, 64, &no_progress) {
        Err(e) if ctx.loop_cap().is_some() => {
            let e = e.to_string();
            assert!(e.contains("65535") && e.contains("--device cpu"), "{e}");
        }
        Err(e) => panic!("a hardware adapter should render it: {e}"),
        Ok(gpu) => {
            let cpu = render_reference_cpu(&cube, &p, &no_progress).unwrap();
            let (c, g) = (cpu.aovs.as_ref().unwrap(), gpu.aovs.as_ref().unwrap());
            let (mc, mg) = (mean(c.multiple.iter().copied()), mean(g.multiple.iter().copied()));
            eprintln!("multiple: cpu {mc} gpu {mg}");
            assert!(mc.x > 0.0 && ((mg - mc) / mc).abs().max_element() < 0.3, "multiple: cpu {mc}, gpu {mg}");
            assert!(ctx.loop_cap().is_none(), "a software adapter should refuse");
        }
    }
}

/// Chandrasekhar's H-function for isotropic scattering with single-scattering albedo `a`:
/// the fixed point of H(mu) = 1 / (1 - mu * (a/2) * integral_0^1 H(mu') / (mu + mu') dmu'),
/// by 64-point Gauss-Legendre quadrature.
fn chandrasekhar_h(a: f64, mu: f64) -> f64 {
    let n = 64;
    // Gauss-Legendre nodes on [0, 1] by Newton iteration on P_n.
    let mut nodes = Vec::with_capacity(n);
    for i in 0..n {
        let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, x);
            for k in 2..=n {
                let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
            let dx = p1 / dp;
            x -= dx;
            if dx.abs() < 1e-15 {
                break;
            }
        }
        nodes.push((0.5 * (x + 1.0), 1.0 / ((1.0 - x * x) * dp * dp)));
    }
    let mut h = vec![1.0; n];
    let at = |h: &[f64], m: f64| 1.0 / (1.0 - m * 0.5 * a * nodes.iter().zip(h).map(|(&(x, w), &hx)| w * hx / (m + x)).sum::<f64>());
    for _ in 0..500 {
        h = nodes.iter().map(|&(x, _)| at(&h, x)).collect();
    }
    at(&h, mu)
}

#[test]
fn multiple_scattering_matches_chandrasekhars_semi_infinite_reflection() {
    // An independent ground truth for multiple scattering, not just our own estimators
    // agreeing: sunlight falling straight down on a homogeneous isotropic half-space, seen
    // straight down. Radiance reflected (Chandrasekhar, Radiative Transfer, 1950, eq. for
    // diffuse reflection with pi F = E): L = a E / (4 pi) * mu0 / (mu + mu0) * H(mu) H(mu0),
    // of which single scattering is the same with H = 1.
    // The slab: 20 mean free paths deep and 12 wide either side of the 10-unit patch the
    // camera sees (mean free path 5 voxels), so the half-space is exact to well under 0.1%.
    let slab = common::filled(1.0, IVec3::new(-60, -60, -100), IVec3::new(60, 60, -1), |_| true);
    let albedo = 0.8;
    let medium = Medium { extinction: 0.2, albedo: Vec3::splat(albedo as f32), g: 0.0 };
    let camera = Camera::new(DVec3::new(0.0, 0.0, 300.0), DVec3::ZERO, DVec3::Y, 2.0, 8, 8).unwrap();
    let image = render_reference_cpu(&slab, &params(medium, vec![Light::default_sun()], camera, 2048), &no_progress).unwrap();
    let aovs = image.aovs.as_ref().unwrap();
    let (h1, e) = (chandrasekhar_h(albedo, 1.0), 1.0);
    let single = albedo * e / (4.0 * std::f64::consts::PI) * 0.5;
    let multiple = single * (h1 * h1 - 1.0);
    for (name, values, expected) in [("single", &aovs.single, single), ("multiple", &aovs.multiple, multiple)] {
        let v: Vec<f64> = values.iter().map(|c| c.x as f64).collect();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let sem = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (v.len() * (v.len() - 1)) as f64).sqrt();
        // 4 standard errors, plus 0.5% for the half-voxel density ramp at the surface (the
        // top 0.05 mean free paths are half as dense as the half-space).
        let tolerance = 4.0 * sem + 0.005 * expected;
        assert!((mean - expected).abs() < tolerance, "{name}: {mean:.6} against Chandrasekhar's {expected:.6} (H(1) = {h1:.5}, tolerance {tolerance:.6})");
    }
}

/// The medium's emission in the GPU reference (path.wgsl's collision estimator with
/// emission.wgsl), with a sun: a fire inside the soft ball, both terms. The same streams, so
/// most pixels agree to f32 rounding and the emission layer's mean within Monte Carlo noise.
#[test]
fn emission_renders_alike_on_gpu_and_cpu() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let density = ball();
    let (flame, temperature, emission) = common::fire(DVec3::ZERO);
    let field = nimbus_march::EmissionField { grid: Some(&flame), temperature: Some(&temperature), params: &emission };
    let medium = Medium { extinction: 3.0, albedo: Vec3::new(0.9, 0.85, 0.8), g: 0.3 };
    let camera = Camera::new(DVec3::new(0.1, -3.0, 0.4), DVec3::ZERO, DVec3::Z, 20.0, 12, 9).unwrap();
    let lights = vec![Light::sun(Vec3::new(-0.3, 0.5, -0.8).normalize(), Vec3::splat(0.5)).unwrap()];
    let p = params(medium, lights, camera, 64);
    let cpu = nimbus_march::render_reference_cpu_with(&density, &p, MediumFields { emission: Some(&field), ..MediumFields::default() }, &no_progress).unwrap();
    let gpu = nimbus_march::render_reference_gpu_with(ctx, &density, &p, MediumFields { emission: Some(&field), ..MediumFields::default() }, 64, &|_| {}).unwrap();
    let (c, g) = (cpu.aovs.as_ref().unwrap(), gpu.aovs.as_ref().unwrap());
    let (mc, mg) = (mean(c.emission.iter().copied()), mean(g.emission.iter().copied()));
    eprintln!("emission: cpu {mc} gpu {mg}");
    assert!(mc.min_element() > 0.0);
    assert!(((mg - mc) / mc).abs().max_element() < 0.02, "emission: cpu {mc}, gpu {mg}");
    let close = cpu.rgba.iter().zip(&gpu.rgba).filter(|(a, b)| (**a - **b).abs().max_element() <= 1e-3 * a.max_element().max(1e-3)).count();
    eprintln!("emission: {close} of 108 pixels equal to 1e-3");
    assert!(close >= 80, "only {close} of 108 pixels agree to 1e-3");
    // Without the field the GPU's paths gather none.
    let dark = render_reference_gpu(ctx, &density, &p, 64, &|_| {}).unwrap();
    assert!(dark.aovs.as_ref().unwrap().emission.iter().all(|e| *e == Vec3::ZERO));
}
