// vdbmarch --reference on the GPU: one invocation per pixel (nimbus_march::render_reference_gpu).
//
// Composed as volume.wgsl (density = default volume, group 0) + optics.wgsl + tracking.wgsl +
// this file. Mirrors crates/march/src/reference/cpu.rs draw for draw: sample s of pixel i
// draws from the Rng (seed, (i, s), REFERENCE_DOMAIN); per sample the pixel jitter, the camera ray's transmittance by
// ratio tracking, then the path: delta-tracked free flights, albedo at each collision,
// next-event estimation toward every light with ratio-tracked shadow rays, Russian roulette
// from ROULETTE_FROM_DEPTH, HG scattering. Positions are f32 relative to the camera's eye.
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
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

struct PixelOut {
    single: vec3<f32>,
    transmittance: f32,
    multiple: vec3<f32>,
    depth: f32,
}

const REFERENCE_DOMAIN: u32 = 0x52454650u;
const ROULETTE_FROM_DEPTH: u32 = 3u;
const RATIO_ROULETTE: f32 = 0.05;

@group(1) @binding(0) var<uniform> params: ReferenceUniforms;
@group(1) @binding(1) var<storage, read> lights: array<Light>;
@group(1) @binding(2) var<storage, read> majorant_values: array<f32>;
@group(1) @binding(3) var<storage, read_write> pixels: array<PixelOut>;

fn majorant_fetch(index: u32) -> f32 {
    return majorant_values[index];
}

fn track_ray(x: vec3<f32>, w: vec3<f32>) -> TrackRay {
    let to_index = volume_info.world_to_index;
    return TrackRay((to_index * vec4<f32>(x, 1.0)).xyz, (to_index * vec4<f32>(w, 0.0)).xyz, params.medium.extinction);
}

// One path from the eye along `dir`: (single, multiple) in a PixelOut.
fn trace_path(dir: vec3<f32>, rng: ptr<function, Rng>) -> PixelOut {
    let m = params.medium;
    var out = PixelOut(vec3<f32>(0.0), 0.0, vec3<f32>(0.0), -1.0);
    var x = params.camera.eye;
    var w = dir;
    var beta = vec3<f32>(1.0);
    for (var depth = 1u; depth <= params.max_depth; depth = depth + 1u) {
        let t = track_sample_delta(track_ray(x, w), params.grid, rng);
        if (t < 0.0) {
            break;
        }
        x = x + w * t;
        beta = beta * m.albedo;
        var direct = vec3<f32>(0.0);
        for (var i = 0u; i < params.light_count; i = i + 1u) {
            let inc = light_incident(lights[i], x);
            if (all(inc.irradiance == vec3<f32>(0.0))) {
                continue;
            }
            let tr = track_transmittance_ratio(track_ray(x, inc.to_light), params.grid, min(inc.distance, TRACK_FAR),
                                               RATIO_ROULETTE, rng);
            if (tr > 0.0) {
                direct = direct + inc.irradiance * (tr * hg_eval(m.g, dot(-inc.to_light, -w)));
            }
        }
        if (depth == 1u) {
            out.single = out.single + beta * direct;
        } else {
            out.multiple = out.multiple + beta * direct;
        }
        if (depth >= ROULETTE_FROM_DEPTH) {
            let q = max(beta.x, max(beta.y, beta.z));
            if (q <= 0.0) {
                break;
            }
            if (q < 1.0) {
                if (rng_next_f32(rng) >= q) {
                    break;
                }
                beta = beta / q;
            }
        }
        w = normalize(hg_sample(m.g, w, rng_next_vec2(rng)).w_out);
    }
    return out;
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
    var sum = PixelOut(vec3<f32>(0.0), 0.0, vec3<f32>(0.0), -1.0);
    if (params.first_sample > 0u) {
        sum = pixels[local];
    }
    let end = min(params.first_sample + params.sample_count, params.spp);
    for (var s = params.first_sample; s < end; s = s + 1u) {
        var rng = rng_new(params.seed, vec2<u32>(index, s), REFERENCE_DOMAIN);
        let j = vec2<f32>(rng_next_f64_as_f32(&rng), rng_next_f64_as_f32(&rng));
        let dir = camera_ray(params.camera, vec2<f32>(px, py) + j);
        sum.transmittance = sum.transmittance + track_transmittance_ratio(track_ray(params.camera.eye, dir), params.grid,
                                                                          TRACK_FAR, RATIO_ROULETTE, &rng);
        let path = trace_path(dir, &rng);
        sum.single = sum.single + path.single;
        sum.multiple = sum.multiple + path.multiple;
    }
    if (end == params.spp) {
        let inv = 1.0 / f32(params.spp);
        sum = PixelOut(sum.single * inv, sum.transmittance * inv, sum.multiple * inv, -1.0);
    }
    pixels[local] = sum;
    loop_guard_check();
}
