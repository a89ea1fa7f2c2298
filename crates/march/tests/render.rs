use glam::{DVec3, IVec3, Vec3};
use nimbus_cache::IlluminationCache;
use nimbus_march::{render_cpu, MarchParams};
use nimbus_optics::{Camera, Medium};
use nimbus_volume::{Transform, Volume};

mod common;
use common::filled;

const VOXEL: f64 = 0.05;

/// A cache holding the same Li everywhere near the density.
fn constant_cache(density: &Volume<f32>, li: Vec3) -> IlluminationCache {
    let mut cache = density.map(Vec3::ZERO, |_| li);
    // Cover the ramps around the density too: every corner of every cell that touches density.
    for brick in density.bricks() {
        for o in 0..512 {
            if brick.is_active(o) {
                let c = brick.origin + nimbus_volume::brick_local(o);
                for n in 0..27 {
                    cache.set(c + IVec3::new(n % 3 - 1, (n / 3) % 3 - 1, n / 9 - 1), li);
                }
            }
        }
    }
    IlluminationCache { li_single: Some(cache), li_multiple: None, ..Default::default() }
}

fn params(camera: Camera, step: f64) -> MarchParams {
    MarchParams {
        environment: None,
        environment_visible: false,
        medium: Medium { extinction: 4.0, albedo: Vec3::new(0.9, 0.5, 0.2), g: 0.0 },
        camera,
        step,
        // The closed forms and convergence in the step are for the plain lattice.
        max_step_factor: 1,
        spp: 1,
        background: Vec3::ZERO,
        offset_noise: 0.0,
        noise_scale: 1.0,
        noise_octaves: 1,
        noise_eval: Default::default(),
        min_transmittance: 0.0,
        seed: 1,
        aovs: true,
    }
}

/// Optical thickness of the unit-density slab |z| <= 10 voxels seen along z: 20 voxels
/// between the outer planes plus the half voxel each interpolation ramp adds.
fn slab_tau(extinction: f64) -> f64 {
    extinction * 21.0 * VOXEL
}

#[test]
fn slab_with_constant_li_equals_the_closed_form_and_converges_with_step() {
    let v = filled(VOXEL, IVec3::new(-30, -30, -10), IVec3::new(30, 30, 10), |_| true);
    let li = Vec3::new(2.0, 1.0, 0.5);
    let cache = constant_cache(&v, li);
    // Looking straight down the z axis through the middle.
    let camera = Camera::new(DVec3::new(0.0, 0.0, 5.0), DVec3::ZERO, DVec3::Y, 2.0, 9, 9).unwrap();
    let tau = slab_tau(4.0);
    let want = Vec3::new(0.9, 0.5, 0.2) * li * (1.0 - (-tau).exp()) as f32;
    let mut errors = vec![];
    for step in [VOXEL * 2.0, VOXEL, VOXEL / 2.0, VOXEL / 4.0] {
        let image = render_cpu(&v, &cache, &params(camera, step)).unwrap();
        let centre = image.rgba[4 * 9 + 4];
        let err = ((centre.truncate() - want) / want).abs().max_element();
        errors.push(err);
        let aovs = image.aovs.as_ref().unwrap();
        assert!((aovs.transmittance[40] as f64 - (-tau).exp()).abs() < 0.02, "T {}", aovs.transmittance[40]);
        assert!((centre.w - (1.0 - aovs.transmittance[40])).abs() < 1e-6);
    }
    eprintln!("relative error by step (2, 1, 1/2, 1/4 voxel): {errors:?}");
    assert!(errors[3] < 2e-3, "{errors:?}");
    assert!(errors[3] <= errors[0], "{errors:?}");
}

#[test]
fn sphere_with_constant_li_matches_chord_lengths() {
    let r = 16;
    let v = filled(VOXEL, IVec3::splat(-r), IVec3::splat(r), |c| c.length_squared() <= r * r);
    let li = Vec3::ONE;
    let cache = constant_cache(&v, li);
    let camera = Camera::new(DVec3::new(0.0, -40.0, 0.0), DVec3::ZERO, DVec3::Z, 2.0, 24, 24).unwrap();
    let image = render_cpu(&v, &cache, &params(camera, VOXEL / 8.0)).unwrap();
    // The closed form 0.9 (1 - exp(-tau)) with tau the optical depth of the voxelised ball
    // along the pixel's ray, integrated independently here by a fine midpoint rule.
    let mut worst = 0.0f64;
    for py in 0..24 {
        for px in 0..24 {
            let (o, d) = camera.ray(px as f64 + 0.5, py as f64 + 0.5);
            let n = 20_000;
            let (t0, t1) = (30.0, 50.0);
            let dt = (t1 - t0) / n as f64;
            let tau: f64 = (0..n).map(|i| v.sample_world(o + d * (t0 + (i as f64 + 0.5) * dt)) as f64).sum::<f64>() * 4.0 * dt;
            let want = 0.9 * (1.0 - (-tau).exp());
            let got = image.rgba[py * 24 + px].x as f64;
            worst = worst.max((got - want).abs());
        }
    }
    assert!(worst <= 2e-3, "worst absolute error {worst}");

}

#[test]
fn looking_away_costs_nothing_and_gives_background() {
    let v = filled(VOXEL, IVec3::splat(-4), IVec3::splat(4), |_| true);
    let cache = constant_cache(&v, Vec3::ONE);
    let camera = Camera::new(DVec3::new(0.0, -5.0, 0.0), DVec3::new(0.0, -10.0, 0.0), DVec3::Z, 40.0, 8, 8).unwrap();
    let mut p = params(camera, VOXEL);
    p.background = Vec3::new(0.1, 0.2, 0.3);
    let image = render_cpu(&v, &cache, &p).unwrap();
    for px in &image.rgba {
        assert_eq!(px.truncate(), Vec3::new(0.1, 0.2, 0.3));
        assert_eq!(px.w, 0.0);
    }
}

#[test]
fn camera_inside_and_axis_aligned_rays_stay_finite() {
    let v = filled(VOXEL, IVec3::splat(-8), IVec3::splat(8), |_| true);
    let cache = constant_cache(&v, Vec3::ONE);
    for (eye, look) in [(DVec3::ZERO, DVec3::X), (DVec3::new(0.0, 0.0, 3.0), DVec3::ZERO), (DVec3::splat(1e-9), DVec3::Z)] {
        let along_z = (look - eye).normalize().dot(DVec3::Z).abs() > 0.9;
        let camera = Camera::new(eye, look, if along_z { DVec3::Y } else { DVec3::Z }, 60.0, 7, 5).unwrap();
        let image = render_cpu(&v, &cache, &params(camera, VOXEL)).unwrap();
        assert_eq!(image.nonfinite, 0);
        assert!(image.rgba.iter().all(|p| p.is_finite() && p.w >= 0.0 && p.w <= 1.0));
        assert!(image.mean_rgb().x > 0.0);
    }
}

#[test]
fn exr_and_png_encode() {
    let v = filled(VOXEL, IVec3::splat(-4), IVec3::splat(4), |_| true);
    let cache = constant_cache(&v, Vec3::ONE);
    let camera = Camera::new(DVec3::new(0.0, -2.0, 0.0), DVec3::ZERO, DVec3::Z, 40.0, 16, 8).unwrap();
    let image = render_cpu(&v, &cache, &params(camera, VOXEL)).unwrap();
    let exr = image.to_exr().unwrap();
    assert_eq!(&exr[..4], &[0x76, 0x2f, 0x31, 0x01], "EXR magic number");
    let png = image.to_png(0.0, nimbus_march::ViewTransform::Agx).unwrap();
    assert_eq!(&png[1..4], b"PNG");
}

#[test]
fn exr_headers_come_out_in_one_order() {
    // Each write builds a fresh hash map of header attributes with its own random order; the
    // bytes must not depend on it, and every attribute must still read back.
    let v = filled(VOXEL, IVec3::splat(-4), IVec3::splat(4), |_| true);
    let cache = constant_cache(&v, Vec3::ONE);
    let camera = Camera::new(DVec3::new(0.0, -2.0, 0.0), DVec3::ZERO, DVec3::Z, 40.0, 8, 4).unwrap();
    let mut image = render_cpu(&v, &cache, &params(camera, VOXEL)).unwrap();
    image.metadata = (0..12).map(|i| (format!("nimbus:key{i:02}"), format!("value {i}"))).collect();
    let first = image.to_exr().unwrap();
    for _ in 0..8 {
        assert!(image.to_exr().unwrap() == first, "two writes of one image differ");
    }
    // The pixels still read: the offset table after the reordered header is untouched.
    use exr::prelude::ReadChannels as _;
    use exr::prelude::ReadLayers as _;
    let pixels = exr::prelude::read().no_deep_data().largest_resolution_level().all_channels().all_layers().all_attributes().from_buffered(std::io::Cursor::new(&first)).unwrap();
    let red = &pixels.layer_data[0].channel_data.list.iter().find(|c| c.name == exr::meta::attribute::Text::from("R")).unwrap().sample_data;
    assert_eq!(red.len(), 32);
    assert!((red.value_by_flat_index(0).to_f32() - image.rgba[0].x).abs() == 0.0);
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(&first), true).unwrap();
    for (key, value) in &image.metadata {
        let got = meta.headers[0].own_attributes.other.get(&exr::meta::attribute::Text::from(key.as_str()));
        assert_eq!(got, Some(&exr::meta::attribute::AttributeValue::Text(exr::meta::attribute::Text::from(value.as_str()))), "{key}");
    }
}

#[test]
fn one_pixel_images_and_huge_world_offsets() {
    let v = filled(VOXEL, IVec3::splat(-8), IVec3::splat(8), |c| c.length_squared() <= 64);
    let cache = constant_cache(&v, Vec3::ONE);
    let one = Camera::new(DVec3::new(0.0, -2.0, 0.0), DVec3::ZERO, DVec3::Z, 10.0, 1, 1).unwrap();
    let image = render_cpu(&v, &cache, &params(one, VOXEL / 2.0)).unwrap();
    assert_eq!(image.rgba.len(), 1);
    assert!(image.rgba[0].w > 0.5, "the one pixel looks straight through the ball");

    // The same scene a million units away renders the same image: positions stay f64 until
    // they are relative to the volume.
    let offset = DVec3::new(1e6, -2e6, 5e5);
    let near = Camera::new(DVec3::new(0.3, -2.0, 0.2), DVec3::ZERO, DVec3::Z, 40.0, 16, 12).unwrap();
    let far = Camera::new(near.eye() + offset, offset, DVec3::Z, 40.0, 16, 12).unwrap();
    let mut moved = v.clone();
    moved.set_transform(Transform::uniform(VOXEL, offset));
    let mut moved_cache = constant_cache(&v, Vec3::ONE);
    moved_cache.li_single.as_mut().unwrap().set_transform(Transform::uniform(VOXEL, offset));
    let a = render_cpu(&v, &cache, &params(near, VOXEL / 2.0)).unwrap();
    let b = render_cpu(&moved, &moved_cache, &params(far, VOXEL / 2.0)).unwrap();
    let worst = a.rgba.iter().zip(&b.rgba).map(|(p, q)| (*p - *q).abs().max_element()).fold(0.0f32, f32::max);
    assert!(worst < 1e-3, "offset scene differs by {worst}");
    assert!(a.mean_rgb().x > 0.0);
}

#[test]
fn a_4096_square_image_renders_and_encodes() {
    // 16.7M pixels, the ball a small spot mid-frame: the cost is the image's size (per-pixel
    // set-up, rays that miss, assembly, EXR encoding), not marching.
    let v = filled(VOXEL, IVec3::splat(-8), IVec3::splat(8), |c| c.length_squared() <= 64);
    let cache = constant_cache(&v, Vec3::ONE);
    let camera = Camera::new(DVec3::new(0.5, -12.0, 1.0), DVec3::ZERO, DVec3::Z, 30.0, 4096, 4096).unwrap();
    let mut p = params(camera, VOXEL / 2.0);
    p.aovs = false;
    let image = render_cpu(&v, &cache, &p).unwrap();
    assert_eq!((image.width, image.height, image.rgba.len()), (4096, 4096, 4096 * 4096));
    assert_eq!(image.nonfinite, 0);
    let covered = image.rgba.iter().filter(|c| c.w > 0.5).count();
    assert!((1000..4096 * 4096 / 10).contains(&covered), "the ball covers {covered} pixels");
    let exr = image.to_exr().unwrap();
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(&exr), true).unwrap();
    assert_eq!(meta.headers[0].layer_size, exr::math::Vec2(4096, 4096));
}

/// A dense cloud (optical depth about 0.8 a default step at its peak), its single scattering
/// marched at the default step, at the step vdbmarch takes there (`step_subdivision`: cut
/// so that a step through the densest medium holds at most 1/4), and at a sixty-fourth of the
/// default step: the cut march comes within a fraction of the default's error of the fine
/// one, and a thin cloud keeps its step. Grouping the cut lattice back up where the majorant
/// allows (`max_step_factor`) is measured beside it, and came out worse than the plain step.
#[test]
fn dense_media_are_marched_in_steps_of_bounded_optical_depth() {
    use common::{camera, cloud, single_scattering_chain};
    use nimbus_march::{default_step, step_subdivision};
    let centre = DVec3::new(0.2, -0.1, 0.3);
    let error = |a: &nimbus_march::Image, b: &nimbus_march::Image| {
        let (mut e2, mut sum) = (0.0f64, 0.0f64);
        for (p, q) in a.rgba.iter().zip(&b.rgba) {
            e2 += ((p[0] - q[0]) as f64).powi(2);
            sum += q[0] as f64;
        }
        (e2 / a.rgba.len() as f64).sqrt() / (sum / a.rgba.len() as f64)
    };
    for (peak, dense) in [(0.2f32, false), (14.0, true)] {
        let density = cloud(24, peak, centre);
        let cam = camera(centre, 40, 30);
        let medium = Medium { extinction: 1.0, albedo: Vec3::splat(0.9), g: 0.3 };
        let sun = nimbus_optics::Light::parse_sun("dir=0.3,0.5,-0.8,irradiance=2").unwrap();
        let base = default_step(density.transform());
        let (cache, march) = single_scattering_chain(&density, medium, sun, &cam, base);
        let max = density.peak();
        let k = step_subdivision(base, medium.extinction, max);
        assert_eq!(k > 1, dense, "peak {peak}: subdivision {k}");
        let plain = render_cpu(&density, &cache, &march).unwrap();
        let cut = render_cpu(&density, &cache, &MarchParams { step: base / k as f64, ..march.clone() }).unwrap();
        let grouped = render_cpu(&density, &cache, &MarchParams { step: base / k as f64, max_step_factor: k, ..march.clone() }).unwrap();
        let fine = render_cpu(&density, &cache, &MarchParams { step: base / 64.0, ..march.clone() }).unwrap();
        let (e_plain, e_cut, e_grouped) = (error(&plain, &fine), error(&cut, &fine), error(&grouped, &fine));
        eprintln!("peak {peak}: subdivision {k}; off a 1/64 step: default step {e_plain:.5}, cut {e_cut:.5}, cut and grouped {e_grouped:.5}");
        if dense {
            assert!(e_cut < 0.3 * e_plain && e_cut < 0.002, "peak {peak}: {e_cut} against {e_plain}");
        } else {
            assert_eq!(plain.rgba, cut.rgba, "a thin medium keeps its step");
        }
    }
    assert_eq!(step_subdivision(0.1, 1.0, f32::NAN), 1);
    assert_eq!(step_subdivision(0.1, 1.0, 2.0), 1, "optical depth 0.2 a step");
    assert_eq!(step_subdivision(0.1, 5.0, 1.0), 2, "0.5 a step: two of a quarter");
    assert_eq!(step_subdivision(1.0, 100.0, 2.0), nimbus_march::MAX_STEP_SUBDIVISION);
}
