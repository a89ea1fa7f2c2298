//! `shaders/optics.wgsl` compiles (naga, the compiler inside wgpu), composes with the volume
//! prelude, and its structs have exactly the fields and bytes of the Rust `Gpu*` structs.

use naga::valid::{Capabilities, ValidationFlags, Validator};
use nimbus_optics::{GpuCamera, GpuLight, GpuMedium, OPTICS_WGSL};

fn compile(source: &str) -> naga::Module {
    let module = naga::front::wgsl::parse_str(source).unwrap_or_else(|e| panic!("{}", e.emit_to_string(source)));
    Validator::new(ValidationFlags::all(), Capabilities::empty())
        .validate(&module)
        .unwrap_or_else(|e| panic!("{}", e.emit_to_string(source)));
    module
}

/// A kernel using every function, with the structs bound as uniforms (the validator checks
/// uniform layout rules) and in storage, so nothing is dead code.
const USE_EVERYTHING: &str = r#"
@group(0) @binding(0) var<storage, read> u_medium: Medium;
@group(0) @binding(1) var<storage, read> u_light: Light;
@group(0) @binding(2) var<storage, read> u_camera: Camera;
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

/// The module's own structs through the layout check every stage runs over its composed source
/// (`nimbus_gpu::wgsl_layout`; the stages take these mirrors from `nimbus_tracking::wgsl_mirror`).
#[test]
fn struct_layouts_match_the_rust_mirrors() {
    use nimbus_gpu::host_layout;
    let source = format!("{}\n{OPTICS_WGSL}", nimbus_gpu::compose_shader(false, ""));
    nimbus_gpu::wgsl_layout::check_layouts(
        &source,
        &[
            ("Medium", host_layout!(GpuMedium { albedo, extinction, g, albedo_mean, _pad })),
            ("Light", host_layout!(GpuLight { vector, kind, power, disc })),
            ("Camera", host_layout!(GpuCamera { eye, width, forward, height, right, tan_half_fov_x, up, tan_half_fov_y })),
        ],
    );
}

#[test]
fn wgsl_constants_match_rust() {
    assert!(OPTICS_WGSL.contains(&format!("const HG_G_MAX: f32 = {};", nimbus_optics::HG_G_MAX)));
    assert!(OPTICS_WGSL.contains(&format!("const LIGHT_SUN: u32 = {}u;", nimbus_optics::LIGHT_SUN)));
    assert!(OPTICS_WGSL.contains(&format!("const LIGHT_POINT: u32 = {}u;", nimbus_optics::LIGHT_POINT)));
}
