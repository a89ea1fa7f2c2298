//! Particle attributes to grids (design.md section 8, issue #20): the attribute pass against
//! a direct sum over every particle, its normalisation (constants stay constant, linear
//! fields are reproduced to the kernel's error), non-finite values, determinism, and the
//! readers' naming rule.

use glam::{DVec3, IVec3, Vec3};
use nimbus_density::analytic::Rng;
use nimbus_density::kernel::{m4_shape, KAPPA};
use nimbus_density::*;

mod common;

fn random_clumpy(n: usize, seed: u64) -> ParticleSet {
    common::clumpy(n, seed, 4, (DVec3::new(6.0, 4.5, 4.0), 1.4), 9.0)
}

/// A jittered lattice filling the box [0, 10]^3 (spacing 0.5): a medium with a flat interior.
fn filled_box(seed: u64) -> ParticleSet {
    let mut rng = Rng::new(seed, 1);
    let mut positions = Vec::new();
    for k in 0..20 {
        for j in 0..20 {
            for i in 0..20 {
                let jitter = DVec3::new(rng.uniform(), rng.uniform(), rng.uniform()) - 0.5;
                positions.push((DVec3::new(i as f64, j as f64, k as f64) + 0.5 + 0.4 * jitter) * 0.5);
            }
        }
    }
    ParticleSet::new(positions)
}

fn params(method: Method, attributes: &[&str]) -> DensityParams {
    DensityParams {
        method,
        resolution: Resolution::Longest(32),
        smoothing_length: true,
        attributes: attributes.iter().map(|s| s.to_string()).collect(),
        ..DensityParams::default()
    }
}

fn each_active(volume: &nimbus_volume::Volume<f32>, mut f: impl FnMut(IVec3)) {
    for b in volume.bricks() {
        for (v, _) in b.values.iter().enumerate() {
            if b.active[v >> 6] & (1 << (v & 63)) != 0 {
                f(b.origin + nimbus_volume::brick_local(v));
            }
        }
    }
}

/// A volume's bricks, values as bits and masks: equal exactly when the volumes are.
fn bits(volume: &nimbus_volume::Volume<f32>) -> Vec<(IVec3, Vec<u32>, [u64; 8])> {
    volume.bricks().map(|b| (b.origin, b.values.iter().map(|v| v.to_bits()).collect(), *b.active)).collect()
}

fn float_grid(out: &DensityOutput, i: usize) -> &nimbus_volume::Volume<f32> {
    match &out.attributes[i].volume {
        AttributeVolume::Float(v) => v,
        _ => panic!("{} is not a float grid", out.attributes[i].name),
    }
}

fn vec3_grid(out: &DensityOutput, i: usize) -> &nimbus_volume::Volume<Vec3> {
    match &out.attributes[i].volume {
        AttributeVolume::Vec3(v) => v,
        _ => panic!("{} is not a vec3 grid", out.attributes[i].name),
    }
}

/// The slow, obviously correct attribute at voxel `ijk`: every particle's term summed in f64,
/// with the voxel's smoothing length from the `smoothing_length` grid and each particle's
/// density read trilinearly from the density grid.
fn direct_sum(out: &DensityOutput, particles: &ParticleSet, rho: &[f64], ijk: IVec3, value: impl Fn(usize) -> [f64; 3]) -> [f64; 3] {
    let x = voxel_world(&out.grid, ijk);
    let h = out.smoothing_length.as_ref().unwrap().get(ijk) as f64;
    let (mut sum, mut weight) = ([0.0f64; 3], 0.0f64);
    for (q, &p) in particles.positions.iter().enumerate() {
        let r = (p - x).length();
        if r >= KAPPA as f64 * h || rho[q] <= 0.0 {
            continue;
        }
        let w = particles.mass(q, 1.0) as f64 / rho[q] * m4_shape((r / h) as f32) as f64;
        let a = value(q);
        for c in 0..3 {
            sum[c] += w * a[c];
        }
        weight += w;
    }
    sum.map(|s| if weight > 0.0 { s / weight } else { 0.0 })
}

#[test]
fn attribute_grids_match_a_direct_sum_over_every_particle() {
    let mut particles = random_clumpy(3000, 7);
    let temperature: Vec<f32> = particles.positions.iter().map(|p| (300.0 + 40.0 * p.x + 10.0 * (p.y * 1.3).sin()) as f32).collect();
    let v: Vec<Vec3> = particles.positions.iter().enumerate().map(|(i, p)| Vec3::new(p.z as f32, (i % 5) as f32 - 2.0, (p.x * p.y) as f32 * 0.1)).collect();
    particles = particles.with_attribute("temperature", Attribute::Float(temperature.clone())).with_attribute("v", Attribute::Vec3(v.clone()));
    for method in [Method::Usl, Method::Asl3, Method::Knn, Method::Ici] {
        let out = estimate_cpu(&particles, &params(method, &["temperature", "v"])).unwrap();
        let rho: Vec<f64> = particles.positions.iter().map(|&p| out.density.sample_world(p) as f64).collect();
        let (t, vg) = (float_grid(&out, 0), vec3_grid(&out, 1));
        let (mut worst_t, mut worst_v, mut count) = (0.0f64, 0.0f64, 0);
        each_active(&out.density, |ijk| {
            let want = direct_sum(&out, &particles, &rho, ijk, |q| [temperature[q] as f64, 0.0, 0.0]);
            worst_t = worst_t.max((t.get(ijk) as f64 - want[0]).abs() / want[0].abs());
            let want = direct_sum(&out, &particles, &rho, ijk, |q| v[q].as_dvec3().to_array());
            let got = vg.get(ijk).as_dvec3();
            worst_v = worst_v.max((got - DVec3::from(want)).abs().max_element() / 10.0);
            count += 1;
        });
        assert!(count > 1000, "{method:?}: {count} active voxels");
        assert!(worst_t < 2e-5 && worst_v < 2e-5, "{method:?}: worst relative error temperature {worst_t:e}, v {worst_v:e}");
        // The grids are active exactly where the density is.
        assert_eq!(t.active_voxel_count(), out.density.active_voxel_count());
        assert_eq!(vg.active_voxel_count(), out.density.active_voxel_count());
    }
}

#[test]
fn a_constant_attribute_interpolates_to_that_constant_wherever_particles_reach() {
    let n = 4000;
    let particles = random_clumpy(n, 11)
        .with_attribute("heat", Attribute::Float(vec![2.5; n]))
        .with_attribute("Cd", Attribute::Vec3(vec![Vec3::new(0.25, -2.0, 1e3); n]));
    for method in [Method::Asl3, Method::Usl] {
        let out = estimate_cpu(&particles, &DensityParams { conserve_mass: method == Method::Usl, ..params(method, &["heat", "Cd"]) }).unwrap();
        let (heat, cd) = (float_grid(&out, 0), vec3_grid(&out, 1));
        each_active(&out.density, |ijk| {
            assert!((heat.get(ijk) - 2.5).abs() <= 2.5 * 1e-5, "{method:?} heat at {ijk}: {}", heat.get(ijk));
            let c = cd.get(ijk);
            assert!((c - Vec3::new(0.25, -2.0, 1e3)).abs().cmple(Vec3::new(0.25, 2.0, 1e3) * 1e-5).all(), "{method:?} Cd at {ijk}: {c}");
        });
    }
}

#[test]
fn a_linear_velocity_field_is_reproduced_to_the_kernels_error() {
    let field = |p: DVec3| DVec3::new(1.0 + 0.5 * p.x - 0.2 * p.y, 0.3 * p.z, -1.0 + 0.1 * p.x + 0.4 * p.y);
    // |grad v| (the largest row norm): the scale of the error a one-sided kernel makes.
    let gradient = 0.5f64.hypot(0.2);
    let particles = filled_box(3);
    let v: Vec<Vec3> = particles.positions.iter().map(|&p| field(p).as_vec3()).collect();
    let particles = particles.with_attribute("v", Attribute::Vec3(v));
    let out = estimate_cpu(&particles, &DensityParams { resolution: Resolution::VoxelSize(0.25), ..params(Method::Asl3, &["v"]) }).unwrap();
    let grid = vec3_grid(&out, 0);
    let h = out.smoothing_length.as_ref().unwrap();
    let (lo, hi) = particles.positions.iter().fold((Vec3::MAX, Vec3::MIN), |(a, b), p| (a.min(p.as_vec3()), b.max(p.as_vec3())));
    let Attribute::Vec3(values) = &particles.attributes["v"] else { unreachable!() };
    let (vlo, vhi) = values.iter().fold((Vec3::MAX, Vec3::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    // Errors in units of |grad v| h(x), the scale of a kernel's first-order error.
    let (mut interior, mut rim) = (0.0f64, 0.0f64);
    let mut outside = 0;
    each_active(&out.density, |ijk| {
        let x = voxel_world(&out.grid, ijk);
        let hx = h.get(ijk) as f64;
        let got = grid.get(ijk);
        let err = (got.as_dvec3() - field(x)).length() / (gradient * hx);
        let reach = KAPPA as f64 * hx;
        if x.cmpge(DVec3::splat(reach)).all() && x.cmple(DVec3::splat(10.0 - reach)).all() {
            // The kernel's support lies inside the box the particles fill.
            interior = interior.max(err);
        } else if x.as_vec3().cmpge(lo).all() && x.as_vec3().cmple(hi).all() {
            // Inside the particles, within a support of their edge: a one-sided neighbourhood.
            rim = rim.max(err);
        } else {
            // Beyond the last particles: a weighted mean of values, never outside their range.
            assert!(got.cmpge(vlo - 1e-4).all() && got.cmple(vhi + 1e-4).all(), "{ijk}: {got} outside {vlo} .. {vhi}");
            outside += 1;
        }
    });
    eprintln!("linear field, max error / (|grad v| h): interior {interior:.4}, rim inside the particles {rim:.4}; {outside} voxels beyond them within range");
    // Inside, only the lattice's disorder is left (a linear field is exact for a symmetric
    // neighbourhood): a few percent of |grad v| h. At the rim the neighbourhood is one-sided.
    assert!(interior < 0.1, "interior error {interior} |grad v| h");
    assert!(rim < 1.0, "rim error {rim} |grad v| h");
    assert!(outside > 0);
}

#[test]
fn non_finite_attribute_values_are_left_out_of_their_grid_and_counted() {
    let n = 3000;
    let mut temperature = vec![7.0f32; n];
    for i in (0..n).step_by(97) {
        temperature[i] = if i % 2 == 0 { f32::NAN } else { f32::INFINITY };
    }
    let mut v = vec![Vec3::ONE; n];
    v[5] = Vec3::new(1.0, f32::NAN, 1.0);
    let base = random_clumpy(n, 5);
    // heat has no non-finite value: it shares the kernel sum of every particle, the others
    // have kernel sums of their own without the particles they leave out.
    let particles = base
        .clone()
        .with_attribute("temperature", Attribute::Float(temperature))
        .with_attribute("v", Attribute::Vec3(v))
        .with_attribute("heat", Attribute::Float(vec![3.0; n]));
    let out = estimate_cpu(&particles, &params(Method::Asl3, &["temperature", "heat", "v"])).unwrap();
    assert_eq!(out.attributes[0].skipped_nonfinite, n.div_ceil(97) as u64);
    assert_eq!(out.attributes[1].skipped_nonfinite, 0);
    assert_eq!(out.attributes[2].skipped_nonfinite, 1);
    let (t, heat, vg) = (float_grid(&out, 0), float_grid(&out, 1), vec3_grid(&out, 2));
    each_active(&out.density, |ijk| {
        assert!(t.get(ijk) == 0.0 || (t.get(ijk) - 7.0).abs() < 1e-4, "{ijk}: {}", t.get(ijk));
        assert!((heat.get(ijk) - 3.0).abs() < 1e-4, "{ijk}: heat {}", heat.get(ijk));
        assert!((vg.get(ijk) - Vec3::ONE).abs().max_element() < 1e-4, "{ijk}: v {}", vg.get(ijk));
    });
    // The particles keep their mass: the density is the one without attributes, bit for bit.
    let plain = estimate_cpu(&base, &params(Method::Asl3, &[])).unwrap();
    assert!(bits(&plain.density) == bits(&out.density));
}

#[test]
fn attributes_are_independent_of_the_thread_count() {
    let n = 3000;
    let particles = random_clumpy(n, 9).with_attribute("heat", Attribute::Float((0..n).map(|i| (i % 13) as f32).collect()));
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| estimate_cpu(&particles, &params(Method::Asl3, &["heat"])).unwrap())
    };
    let (one, three) = (run(1), run(3));
    assert!(bits(float_grid(&one, 0)) == bits(float_grid(&three, 0)));
    assert!(bits(&one.density) == bits(&three.density));
}

#[test]
fn an_unknown_attribute_is_an_error_listing_the_available_ones() {
    let particles = random_clumpy(100, 1).with_attribute("heat", Attribute::Float(vec![1.0; 100]));
    let err = estimate_cpu(&particles, &params(Method::Asl3, &["temperature"])).err().expect("an error");
    let text = err.to_string();
    assert!(text.contains("temperature") && text.contains("available: heat"), "{text}");
}

#[test]
fn readers_find_attributes_by_the_naming_rule() {
    let csv = "x,y,z,vx,vy,vz,Cd_x,Cd_y,Cd_z,temperature,name\n\
               0,0,0,1,2,3,0.5,0.25,1,300,a\n\
               1,1,1,4,5,6,0.1,0.2,0.3,nan,b\n";
    let want = |names: &[&str]| names.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let (set, _) = read_particles_with(csv.as_bytes(), Format::Csv, &want(&["v", "color", "temperature", "vy"])).unwrap();
    assert_eq!(set.attributes["v"], Attribute::Vec3(vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.0)]));
    assert_eq!(set.attributes["color"], Attribute::Vec3(vec![Vec3::new(0.5, 0.25, 1.0), Vec3::new(0.1, 0.2, 0.3)]));
    let Attribute::Float(t) = &set.attributes["temperature"] else { panic!() };
    assert!(t[0] == 300.0 && t[1].is_nan(), "{t:?}");
    assert_eq!(set.attributes["vy"], Attribute::Float(vec![2.0, 5.0]));

    let ply = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
               property double vel_x\nproperty double vel_y\nproperty double vel_z\nproperty int heat\n\
               property float nx\nproperty float ny\nproperty float nz\nproperty float N[0]\nproperty float N[1]\nproperty float N[2]\nend_header\n\
               0 0 0 1 2 3 7 0 0 1 9 8 7\n1 1 1 4 5 6 -2 0 1 0 6 5 4\n";
    let (set, _) = read_particles_with(ply.as_bytes(), Format::Ply, &want(&["v", "heat", "n", "N"])).unwrap();
    assert_eq!(set.attributes["v"], Attribute::Vec3(vec![Vec3::new(1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.0)]));
    assert_eq!(set.attributes["heat"], Attribute::Float(vec![7.0, -2.0]));
    assert_eq!(set.attributes["n"], Attribute::Vec3(vec![Vec3::new(0.0, 0.0, 1.0), Vec3::new(0.0, 1.0, 0.0)]));
    assert_eq!(set.attributes["N"], Attribute::Vec3(vec![Vec3::new(9.0, 8.0, 7.0), Vec3::new(6.0, 5.0, 4.0)]));

    let err = read_particles_with(csv.as_bytes(), Format::Csv, &want(&["density"])).unwrap_err().to_string();
    assert!(err.contains("`density`") && err.contains("available: vx, vy, vz, Cd_x, Cd_y, Cd_z, temperature, name, v, Cd"), "{err}");
}

/// The GPU's attribute pass (shaders/density.wgsl `attributes`) against the direct sum with
/// its own lengths and density, and against the CPU backend: ten channels (two dispatch
/// groups of eight), among them an attribute with non-finite values and so a weight channel
/// of its own. Small: lavapipe runs on two cores.
#[test]
fn the_gpu_attribute_pass_matches_a_direct_sum_and_the_cpu() {
    let Some(ctx) = nimbus_gpu::test_context() else { return };
    let n = 1500;
    let base = random_clumpy(n, 13);
    let mut temperature: Vec<f32> = base.positions.iter().map(|p| (300.0 + 40.0 * p.x) as f32).collect();
    for i in (0..n).step_by(101) {
        temperature[i] = f32::NAN;
    }
    let v: Vec<Vec3> = base.positions.iter().map(|p| Vec3::new(p.z as f32, -(p.y as f32), (p.x * p.y) as f32 * 0.1)).collect();
    let colour: Vec<Vec3> = (0..n).map(|i| Vec3::new((i % 3) as f32, (i % 5) as f32 * 0.25, 1.0)).collect();
    let heat: Vec<f32> = (0..n).map(|i| (i % 11) as f32).collect();
    let particles = base
        .with_attribute("temperature", Attribute::Float(temperature.clone()))
        .with_attribute("v", Attribute::Vec3(v.clone()))
        .with_attribute("Cd", Attribute::Vec3(colour.clone()))
        .with_attribute("heat", Attribute::Float(heat.clone()));
    let params = DensityParams { neighbours: 20, resolution: Resolution::Longest(24), ..params(Method::Asl3, &["temperature", "v", "Cd", "heat"]) };
    let cpu = estimate_cpu(&particles, &params).unwrap();
    let gpu = estimate_gpu(ctx, &particles, &params).unwrap();
    assert_eq!(gpu.attributes[0].skipped_nonfinite, n.div_ceil(101) as u64);
    let rho: Vec<f64> = particles.positions.iter().map(|&p| gpu.density.sample_world(p) as f64).collect();
    let finite = |q: usize| temperature[q].is_finite();
    let (mut worst_direct, mut worst_cpu, mut count) = (0.0f64, 0.0f64, 0);
    each_active(&gpu.density, |ijk| {
        // The direct sum leaves the non-finite temperatures out by giving them no weight.
        let x = voxel_world(&gpu.grid, ijk);
        let h = gpu.smoothing_length.as_ref().unwrap().get(ijk) as f64;
        let (mut t_sum, mut t_weight) = (0.0, 0.0);
        for (q, &p) in particles.positions.iter().enumerate() {
            let r = (p - x).length();
            if r < KAPPA as f64 * h && rho[q] > 0.0 && finite(q) {
                let w = particles.mass(q, 1.0) as f64 / rho[q] * m4_shape((r / h) as f32) as f64;
                t_sum += w * temperature[q] as f64;
                t_weight += w;
            }
        }
        let wants = [
            (float_grid(&gpu, 0).get(ijk) as f64, float_grid(&cpu, 0).get(ijk) as f64, if t_weight > 0.0 { t_sum / t_weight } else { 0.0 }, 700.0),
            (float_grid(&gpu, 3).get(ijk) as f64, float_grid(&cpu, 3).get(ijk) as f64, direct_sum(&gpu, &particles, &rho, ijk, |q| [heat[q] as f64, 0.0, 0.0])[0], 10.0),
        ];
        let vecs = [(1, direct_sum(&gpu, &particles, &rho, ijk, |q| v[q].as_dvec3().to_array()), 10.0), (2, direct_sum(&gpu, &particles, &rho, ijk, |q| colour[q].as_dvec3().to_array()), 2.0)];
        for (got, on_cpu, want, scale) in wants {
            worst_direct = worst_direct.max((got - want).abs() / scale);
            worst_cpu = worst_cpu.max((got - on_cpu).abs() / scale);
        }
        for (i, want, scale) in vecs {
            let (got, on_cpu) = (vec3_grid(&gpu, i).get(ijk).as_dvec3(), vec3_grid(&cpu, i).get(ijk).as_dvec3());
            worst_direct = worst_direct.max((got - DVec3::from(want)).abs().max_element() / scale);
            worst_cpu = worst_cpu.max((got - on_cpu).abs().max_element() / scale);
        }
        count += 1;
    });
    eprintln!("GPU attribute pass over {count} voxels: worst {worst_direct:e} from the direct sum, {worst_cpu:e} from the CPU");
    assert!(count > 1000, "{count} active voxels");
    assert!(worst_direct < 2e-5, "GPU against the direct sum: worst {worst_direct:e} of each attribute's range");
    assert!(worst_cpu < 1e-4, "GPU against the CPU: worst {worst_cpu:e} of each attribute's range");
    assert_eq!(vec3_grid(&gpu, 2).active_voxel_count(), gpu.density.active_voxel_count());
}

/// Density noise at rest positions (`noise_rest`, Houdini's `rest`) moves with the particles:
/// the same particles translated, with the same rest positions, give the same noisy density
/// translated (the grid follows the particles' bounds). Noise anchored in the world does not
/// (the particles move through its pattern), which is what makes the check able to fail.
#[test]
fn noise_at_rest_positions_moves_with_the_particles() {
    let base = random_clumpy(3000, 21);
    let rest: Vec<Vec3> = base.positions.iter().map(|p| p.as_vec3()).collect();
    let shift = DVec3::new(2.0, -1.0, 0.5);
    let moved = ParticleSet { positions: base.positions.iter().map(|&p| p + shift).collect(), ..base.clone() };
    let [base, moved] = [base, moved].map(|set| set.with_attribute("rest", Attribute::Vec3(rest.clone())));
    let noisy = |rest: Option<&str>| DensityParams {
        resolution: Resolution::VoxelSize(0.25),
        noise: NoiseParams { amplitude: 0.8, scale: 0.7, octaves: 3, seed: 4 },
        noise_rest: rest.map(str::to_string),
        ..DensityParams::default()
    };
    let worst = |params: &DensityParams| {
        let (a, b) = (estimate_cpu(&base, params).unwrap(), estimate_cpu(&moved, params).unwrap());
        assert_eq!(a.grid.dims, b.grid.dims);
        let (mut worst, mut count) = (0.0f32, 0);
        each_active(&a.density, |ijk| {
            worst = worst.max((a.density.get(ijk) - b.density.get(ijk)).abs() / a.stats.max_density);
            count += 1;
        });
        assert!(count > 1000, "{count} voxels");
        worst
    };
    let (at_rest, in_world) = (worst(&noisy(Some("rest"))), worst(&noisy(None)));
    eprintln!("translated particles, largest change of the density (of its maximum): rest {at_rest:e}, world {in_world:e}");
    assert!(at_rest < 1e-4, "noise at rest positions changed the density by {at_rest} of its maximum");
    assert!(in_world > 0.05, "world noise moved with the particles ({in_world})");

    // A rest attribute that is not a vec3 is refused.
    let flat = base.clone().with_attribute("restx", Attribute::Float(vec![0.0; 3000]));
    let err = estimate_cpu(&flat, &noisy(Some("restx"))).err().expect("an error").to_string();
    assert!(err.contains("restx") && err.contains("vec3"), "{err}");
}
