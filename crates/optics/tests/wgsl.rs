//! `shaders/optics.wgsl` compiles (naga, the compiler inside wgpu), composes with the volume
//! prelude, and its structs have exactly the bytes of the Rust `Gpu*` structs, in both the
//! uniform and storage address spaces.

use std::mem::{offset_of, size_of};

use naga::valid::{Capabilities, ValidationFlags, Validator};
use nimbus_optics::{GpuCamera, GpuLight, GpuMedium, OPTICS_WGSL};

fn compile(source: &str) -> naga::Module {
    let module = naga::front::wgsl::parse_str(source).unwrap_or_else(|e| panic!("{}", e.emit_to_string(source)));
    Validator::new(ValidationFlags::all(), Capabilities::empty())
        .validate(&module)
        .unwrap_or_else(|e| panic!("{}", e.emit_to_string(source)));
    module
}

/// (size, [(member, offset)]) of a WGSL struct.
fn layout(module: &naga::Module, name: &str) -> (u32, Vec<(String, u32)>) {
    for (_, ty) in module.types.iter() {
        if ty.name.as_deref() == Some(name) {
            if let naga::TypeInner::Struct { members, span } = &ty.inner {
                return (*span, members.iter().map(|m| (m.name.clone().unwrap_or_default(), m.offset)).collect());
            }
        }
    }
    panic!("no struct {name} in optics.wgsl");
}

/// A kernel using every function, with the structs bound as uniforms (the validator checks
/// uniform layout rules) and in storage, so nothing is dead code.
const USE_EVERYTHING: &str = r#"
@group(0) @binding(0) var<uniform> u_medium: Medium;
@group(0) @binding(1) var<uniform> u_light: Light;
@group(0) @binding(2) var<uniform> u_camera: Camera;
@group(0) @binding(3) var<storage, read> s_lights: array<Light>;
@group(0) @binding(4) var<storage, read_write> out: array<vec4<f32>>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    var rng = rng_new(vec2<u32>(1u, 2u), vec2<u32>(id.x, 0u), 0u);
    let u = rng_next_vec2(&rng);
    let s = hg_sample(u_medium.g, camera_ray(u_camera, u * 10.0), u);
    let inc = light_incident(s_lights[0], light_incident(u_light, vec3<f32>(0.0)).to_light);
    let e = medium_sigma_s(u_medium, 0.5) * inc.irradiance * hg_eval(u_medium.g, 0.5);
    let d = sample_uniform_disk_concentric(u);
    let c = hg_sample_cos_theta(0.5, rng_next_f32(&rng));
    out[id.x] = vec4<f32>(e + sample_uniform_sphere(u) + s.w_out, s.pdf + d.x + c.x + f32(rng_next_u32(&rng)));
}
"#;

#[test]
fn optics_wgsl_compiles_and_every_function_validates() {
    compile(OPTICS_WGSL);
    compile(&format!("{OPTICS_WGSL}\n{USE_EVERYTHING}"));
}

#[test]
fn optics_wgsl_composes_with_the_volume_prelude() {
    // The order a stage shader uses: volume prelude, optics, stage code. Names must not clash.
    let volume = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shaders/volume.wgsl"));
    let Ok(volume) = volume else {
        eprintln!("shaders/volume.wgsl not found, skipped");
        return;
    };
    compile(&format!("const VOLUME_FILTERABLE: bool = false;\n{volume}\n{OPTICS_WGSL}\n{USE_EVERYTHING}"));
}

macro_rules! rust_layout {
    ($t:ty; $($field:ident),*) => {
        (size_of::<$t>() as u32, vec![$((stringify!($field).to_string(), offset_of!($t, $field) as u32)),*])
    };
}

#[test]
fn struct_layouts_match_the_rust_mirrors() {
    let module = compile(OPTICS_WGSL);

    let (size, members) = layout(&module, "Medium");
    let (rsize, rmembers) = rust_layout!(GpuMedium; albedo, extinction, g, albedo_mean, _pad);
    assert_eq!((size, rsize), (32, 32));
    // WGSL pads with two f32 where Rust has one [f32; 2].
    assert_eq!(members[..4], rmembers[..4]);
    assert_eq!((members[4].1, members[5].1), (rmembers[4].1, rmembers[4].1 + 4));

    let (size, members) = layout(&module, "Light");
    let (rsize, rmembers) = rust_layout!(GpuLight; vector, kind, power, disc);
    assert_eq!((size, &members), (rsize, &rmembers));
    assert_eq!(size, 32);

    let (size, members) = layout(&module, "Camera");
    let (rsize, rmembers) = rust_layout!(GpuCamera; eye, width, forward, height, right, tan_half_fov_x, up, tan_half_fov_y);
    assert_eq!((size, &members), (rsize, &rmembers));
    assert_eq!(size, 64);
}

#[test]
fn wgsl_constants_match_rust() {
    assert!(OPTICS_WGSL.contains(&format!("const HG_G_MAX: f32 = {};", nimbus_optics::HG_G_MAX)));
    assert!(OPTICS_WGSL.contains(&format!("const LIGHT_SUN: u32 = {}u;", nimbus_optics::LIGHT_SUN)));
    assert!(OPTICS_WGSL.contains(&format!("const LIGHT_POINT: u32 = {}u;", nimbus_optics::LIGHT_POINT)));
}
