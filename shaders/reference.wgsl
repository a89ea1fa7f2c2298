// requires: trace_path, motion_begin_sample, loop_guard_check
//
// vdbmarch --reference on the GPU: one invocation per pixel (nimbus_march::render_reference_gpu).
//
// Composed as volume.wgsl (density = default volume, group 0) + optics.wgsl + environment.wgsl
// + emission.wgsl (group 2) + tracking.wgsl + path.wgsl + this file. Mirrors crates/march/src/reference/cpu.rs draw for draw: sample s of
// pixel i draws from the Rng (seed, (i, s), REFERENCE_DOMAIN); per sample the pixel jitter,
// the camera ray's transmittance by ratio tracking, then the path from the eye (path.wgsl's
// trace_path, the twin of nimbus_tracking::trace_path). Positions are f32 relative to the
// camera's eye.
// Each dispatch takes samples first_sample .. first_sample + sample_count of its tile's
// pixels and adds them to what earlier dispatches left in `pixels`; the last one divides by
// spp. Few samples per dispatch, because llvmpipe (lavapipe) ends any loop of a SIMD group
// after 65535 iterations counted over the whole invocation, which silently truncated
// 256-sample pixels; a desktop GPU's watchdog likes short dispatches too. Delta tracking
// through an optically huge medium can still run out (its null collisions are random), so
// this is composed after nimbus_gpu::LoopGuard::wgsl (binding 4 of group 1) and every pixel
// ends with loop_guard_check().
// The CPU decides in f64 and the GPU in f32, so a path can take another turn now and then:
// the two images agree in distribution (to Monte Carlo error), not pixel for pixel.

struct ReferenceUniforms {
    camera: Camera,
    medium: Medium,
    grid: MajorantGridInfo,
    background: vec3<f32>,
    spp: u32,
    seed: vec2<u32>,
    max_depth: u32,
    light_count: u32,
    width: u32,
    first_pixel: u32,
    tile_pixels: u32,
    first_sample: u32,
    sample_count: u32,
    // Camera rays that leave the volume see the environment map (a uniform sky is added on
    // the host as the constant background).
    map_visible: u32,
    _pad1: u32,
    _pad2: u32,
}

struct PixelOut {
    single: vec3<f32>,
    transmittance: f32,
    multiple: vec3<f32>,
    depth: f32,
    // The environment map seen through the volume (RayResult::behind).
    behind: vec3<f32>,
    _pad: f32,
    // The medium's own emission (RayResult::emission; path.wgsl's collision estimator).
    emission: vec3<f32>,
    _pad1: f32,
}

const REFERENCE_DOMAIN: u32 = 0x52454650u;

@group(1) @binding(0) var<storage, read> params: ReferenceUniforms;
@group(1) @binding(1) var<storage, read> lights: array<Light>;
@group(1) @binding(2) var<storage, read> majorant_values: array<f32>;
@group(1) @binding(3) var<storage, read_write> pixels: array<PixelOut>;
// The environment (nimbus_optics::Environment::gpu_words), read by environment.wgsl.
@group(1) @binding(4) var<storage, read> environment: array<f32>;

fn env_word(i: u32) -> f32 {
    return environment[i];
}

fn majorant_fetch(index: u32) -> f32 {
    return majorant_values[index];
}

fn path_light(index: u32) -> Light {
    return lights[index];
}

const WORKGROUP_SIZE: u32 = 64u;

@compute @workgroup_size(64)
fn reference_pixels(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                    @builtin(local_invocation_index) lid: u32) {
    let local = dispatch_linear_index(wid, nwg, lid, WORKGROUP_SIZE);
    if (local >= params.tile_pixels) {
        return;
    }
    let index = params.first_pixel + local;
    let px = f32(index % params.width);
    let py = f32(index / params.width);
    var sum = PixelOut(vec3<f32>(0.0), 0.0, vec3<f32>(0.0), -1.0, vec3<f32>(0.0), 0.0, vec3<f32>(0.0), 0.0);
    if (params.first_sample > 0u) {
        sum = pixels[local];
    }
    let end = min(params.first_sample + params.sample_count, params.spp);
    for (var s = params.first_sample; s < end; s = s + 1u) {
        var rng = rng_new(params.seed, vec2<u32>(index, s), REFERENCE_DOMAIN);
        // The whole sample, camera ray and path, sees the medium at one time in the shutter,
        // from a stream of its own (reference/cpu.rs).
        var times = rng_new(params.seed, vec2<u32>(index, s), MOTION_DOMAIN);
        motion_begin_sample(rng_next_f64_as_f32(&times));
        let j = vec2<f32>(rng_next_f64_as_f32(&rng), rng_next_f64_as_f32(&rng));
        let dir = camera_ray(params.camera, vec2<f32>(px, py) + j);
        let m = params.medium;
        let tr = track_transmittance_ratio(path_track_ray(params.camera.eye, dir, m.extinction), params.grid, TRACK_FAR,
                                           RATIO_ROULETTE, &rng);
        sum.transmittance = sum.transmittance + tr;
        if (params.map_visible != 0u) {
            sum.behind = sum.behind + env_radiance(dir) * tr;
        }
        let path = trace_path(params.camera.eye, dir, m, params.grid, params.max_depth, params.light_count, -1.0, &rng);
        sum.single = sum.single + path.single;
        sum.multiple = sum.multiple + path.multiple;
        sum.emission = sum.emission + path.emission;
    }
    if (end == params.spp) {
        let inv = 1.0 / f32(params.spp);
        sum = PixelOut(sum.single * inv, sum.transmittance * inv, sum.multiple * inv, -1.0, sum.behind * inv, 0.0,
                       sum.emission * inv, 0.0);
    }
    pixels[local] = sum;
    loop_guard_check();
}
