// requires: CACHE_FILTERED, emission_at, motion_begin_sample
//
// vdbmarch's GPU backend: one invocation per pixel (nimbus_march::render_gpu).
//
// Composed (nimbus_march's march_source) as volume.wgsl (density = default volume, group 0,
// sampled exactly) + optics.wgsl + environment.wgsl + emission.wgsl (group 2) + tracking.wgsl
// (majorant DDA; nimbus_tracking::tracking_wgsl_moving, with motion.wgsl's velocity grid at group 3
// for motion blur), nimbus_tracking::medium_stage, then `const CACHE_FILTERED` + noise.wgsl + this file.
// Mirrors crates/march/src/cpu.rs: pixel i's Rng is (seed, i, MARCH_DOMAIN) with the same
// draws in the same order (jitter x, y when spp > 1, stratified as pixel_jitter, then the
// lattice offset xi, per sample; the group member offset u from its own stream
// (seed, i, GROUP_DOMAIN)); samples on the lattice t_k = (k + xi) dt in groups by each
// non-empty majorant segment's step factor (lib.rs Groups); offset noise;
// early termination; the same per-pixel averages. Positions are f32 relative to the
// camera's eye (every volume's world_to_index is set to that origin by the host).
// Li_single and Li_multiple are two more volumes at group 1, looked up with the hardware
// filter when CACHE_FILTERED (and the device can filter R32/RGBA32 floats), else exactly.

struct MarchUniforms {
    camera: Camera,
    medium: Medium,
    grid: MajorantGridInfo,
    background: vec3<f32>,
    step: f32,
    // Noise position of the eye, split: floor(eye / scale) (wrapping) and the rest.
    noise_base: vec3<u32>,
    spp: u32,
    noise_offset: vec3<f32>,
    noise_inv_scale: f32,
    seed: vec2<u32>,
    noise_octaves: u32,
    noise_seed: u32,
    offset_noise: f32,
    min_transmittance: f32,
    // bit 0: Li_single present, bit 1: Li_multiple present.
    flags: u32,
    width: u32,
    pixel_count: u32,
    // Large images are marched in tiles of consecutive pixels (the host's MAX_TILE_PIXELS):
    // this dispatch covers pixels first_pixel .. first_pixel + tile_pixels, and writes them
    // from pixels[0].
    first_pixel: u32,
    tile_pixels: u32,
    _pad: u32,
    // The baked offset noise (crates/march/src/offsets.rs): the eye's lattice index, nodes
    // per world unit, the brick table's first brick and extent; offset_baked 0: exact.
    offset_eye: vec3<f32>,
    offset_per_world: f32,
    offset_lo: vec3<i32>,
    offset_baked: u32,
    offset_dims: vec3<i32>,
    _pad1: u32,
}

struct PixelOut {
    single: vec3<f32>,
    transmittance: f32,
    multiple: vec3<f32>,
    // Distance to the first sample where opacity passed 1%; negative for none.
    depth: f32,
    // The environment map seen through the volume, T L_env(dir) (RayResult::behind).
    behind: vec3<f32>,
    _pad: f32,
    // The medium's own emission, attenuated (RayResult::emission; emission.wgsl).
    emission: vec3<f32>,
    _pad1: f32,
}

const MARCH_DOMAIN: u32 = 0x4d415243u;
const GROUP_DOMAIN: u32 = 0x53544550u;
const FLAG_SINGLE: u32 = 1u;
const FLAG_MULTIPLE: u32 = 2u;

@group(1) @binding(0) var single_atlas: texture_3d<f32>;
@group(1) @binding(1) var single_table: texture_3d<u32>;
@group(1) @binding(2) var single_sampler: sampler;
@group(1) @binding(3) var<storage, read> single_info: VolumeInfo;
@group(1) @binding(4) var multiple_atlas: texture_3d<f32>;
@group(1) @binding(5) var multiple_table: texture_3d<u32>;
@group(1) @binding(6) var multiple_sampler: sampler;
@group(1) @binding(7) var<storage, read> multiple_info: VolumeInfo;
@group(1) @binding(8) var<storage, read> params: MarchUniforms;
// Per majorant cell its step factor (MarchParams::step_factor), 0 where empty.
@group(1) @binding(9) var<storage, read> majorant_values: array<f32>;
@group(1) @binding(10) var<storage, read_write> pixels: array<PixelOut>;
// The map seen behind the volume (Environment::gpu_words of it; kind 0 where there is none),
// read by environment.wgsl.
@group(1) @binding(11) var<storage, read> environment: array<f32>;
// The baked offset noise: per brick of 8^3 cells its slot (0xffffffff: none), and per slot
// its 9^3 nodes (x-major, z fastest), the displacement in xyz (layout.rs Lattice).
@group(1) @binding(12) var<storage, read> offset_table: array<u32>;
@group(1) @binding(13) var<storage, read> offset_nodes: array<vec4<f32>>;

fn env_word(i: u32) -> f32 {
    return environment[i];
}

fn majorant_fetch(index: u32) -> f32 {
    return majorant_values[index];
}

fn li_single(x: vec3<f32>) -> vec3<f32> {
    let p = volume_world_to_index_in(single_info, x);
    if (CACHE_FILTERED) {
        return volume_sample_index_filtered_in(single_atlas, single_table, single_sampler, single_info, p).xyz;
    }
    return volume_sample_index_in(single_atlas, single_table, single_info, p).xyz;
}

fn li_multiple(x: vec3<f32>) -> vec3<f32> {
    let p = volume_world_to_index_in(multiple_info, x);
    if (CACHE_FILTERED) {
        return volume_sample_index_filtered_in(multiple_atlas, multiple_table, multiple_sampler, multiple_info, p).xyz;
    }
    return volume_sample_index_in(multiple_atlas, multiple_table, multiple_info, p).xyz;
}

// The baked displacement at x (relative to the eye): Lattice::sample over the offset
// lattice, its lerps in the same order (z, then y, then x); zero outside the baked bricks.
fn offset_baked(x: vec3<f32>) -> vec3<f32> {
    let p = params.offset_eye + x * params.offset_per_world;
    let f = floor(p);
    let i = vec3<i32>(f);
    let b = (i >> vec3<u32>(3u)) - params.offset_lo;
    let dims = params.offset_dims;
    if (any(b < vec3<i32>(0)) || any(b >= dims)) {
        return vec3<f32>(0.0);
    }
    let slot = offset_table[u32((b.x * dims.y + b.y) * dims.z + b.z)];
    if (slot == 0xffffffffu) {
        return vec3<f32>(0.0);
    }
    let l = vec3<u32>(i & vec3<i32>(7));
    let n = slot * 729u + (l.x * 9u + l.y) * 9u + l.z;
    let w = p - f;
    let c00 = mix(offset_nodes[n].xyz, offset_nodes[n + 1u].xyz, w.z);
    let c01 = mix(offset_nodes[n + 9u].xyz, offset_nodes[n + 10u].xyz, w.z);
    let c10 = mix(offset_nodes[n + 81u].xyz, offset_nodes[n + 82u].xyz, w.z);
    let c11 = mix(offset_nodes[n + 90u].xyz, offset_nodes[n + 91u].xyz, w.z);
    return mix(mix(c00, c01, w.y), mix(c10, c11, w.y), w.x);
}

// 1 - exp(-x) for x >= 0 without the cancellation that costs thin media their precision.
fn one_minus_exp_neg(x: f32) -> f32 {
    if (x < 0.03) {
        return x * (1.0 - 0.5 * x * (1.0 - x / 3.0 * (1.0 - 0.25 * x)));
    }
    return 1.0 - exp(-x);
}

// march_ray: the ray eye + t dir (dir unit, world) with lattice offset xi and group member
// offset u (lib.rs Groups): the lattice t_k = (k + xi) dt in groups as long as the step
// factor of the cell their first point lies in, group g's sample its member floor(u g),
// standing for its g steps.
fn march_ray(dir: vec3<f32>, xi: f32, u: f32) -> PixelOut {
    let eye = params.camera.eye;
    let o = volume_world_to_index(eye);
    let d = (volume_info.world_to_index * vec4<f32>(dir, 0.0)).xyz;
    let dt = params.step;
    let m = params.medium;
    let jitter = params.offset_noise > 0.0;
    var r = PixelOut(vec3<f32>(0.0), 1.0, vec3<f32>(0.0), -1.0, vec3<f32>(0.0), 0.0, vec3<f32>(0.0), 0.0);
    var tr = 1.0;
    let emits = emission_active();
    // Groups tile the lattice across adjacent non-empty segments: the next segment starts
    // with the first point no group took (next) rather than recomputing it from t_start,
    // which in f32 can skip or repeat a point lying on the boundary within rounding. After
    // a gap (skipped empty segments) it is recomputed.
    var next = -3.0e38;
    var prev_end = -1.0;
    var walk = majorant_walk_new(params.grid, o, d, 0.0, TRACK_FAR);
    loop {
        let seg = majorant_walk_next(&walk, params.grid);
        if (!seg.valid) {
            break;
        }
        if (!track_segment_has_medium(seg, m.extinction)) {
            continue;
        }
        // The walk reads step factors (march_pixels' host side).
        let g = seg.majorant;
        let step = g * dt;
        var start = next;
        if (seg.t_start != prev_end) {
            start = max(ceil(seg.t_start / dt - xi), next);
        }
        let member = min(floor(u * g), g - 1.0);
        loop {
            if ((start + xi) * dt >= seg.t_end) {
                break;
            }
            let t = (start + member + xi) * dt;
            start = start + g;
            var x = eye + dir * t;
            if (jitter) {
                if (params.offset_baked != 0u) {
                    x = x + offset_baked(x);
                } else {
                    let q = params.noise_offset + x * params.noise_inv_scale;
                    x = x + noise_fbm3_vec_split(params.noise_base, q, params.noise_octaves, params.noise_seed) * params.offset_noise;
                }
            }
            x = motion_back(x);
            let sigma_t = m.extinction * max(volume_sample_index(volume_world_to_index(x)), 0.0);
            if (sigma_t <= 0.0) {
                continue;
            }
            let absorbed = one_minus_exp_neg(sigma_t * step);
            let weight = tr * absorbed;
            // T e(x) (1 - exp(-sigma_t dt)) / sigma_t (cpu.rs march_ray_emitting).
            if (emits) {
                r.emission = r.emission + emission_at(x) * (weight / sigma_t);
            }
            if ((params.flags & FLAG_SINGLE) != 0u) {
                r.single = r.single + weight * m.albedo * li_single(x);
            }
            if ((params.flags & FLAG_MULTIPLE) != 0u) {
                r.multiple = r.multiple + weight * m.albedo * li_multiple(x);
            }
            tr = tr * exp(-sigma_t * step);
            if (r.depth < 0.0 && tr < 0.99) {
                r.depth = t;
            }
            if (tr < params.min_transmittance) {
                r.transmittance = 0.0;
                return r;
            }
        }
        next = start;
        prev_end = seg.t_end;
    }
    r.transmittance = tr;
    return r;
}

const WORKGROUP_SIZE: u32 = 64u;

// cpu.rs pixel_jitter: jittered within cell s of an n x n grid over the pixel (n the integer
// square root of spp), anywhere for the samples past n^2.
fn pixel_jitter(s: u32, spp: u32, uv: vec2<f32>) -> vec2<f32> {
    var n = u32(sqrt(f32(spp)));
    if (n * n > spp) {
        n = n - 1u;
    }
    if ((n + 1u) * (n + 1u) <= spp) {
        n = n + 1u;
    }
    if (s < n * n) {
        return (vec2<f32>(f32(s % n), f32(s / n)) + uv) / f32(n);
    }
    return uv;
}

@compute @workgroup_size(64)
fn march_pixels(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                @builtin(local_invocation_index) lid: u32) {
    let local = dispatch_linear_index(wid, nwg, lid, WORKGROUP_SIZE);
    if (local >= params.tile_pixels) {
        return;
    }
    let index = params.first_pixel + local;
    let px = f32(index % params.width);
    let py = f32(index / params.width);
    var rng = rng_new(params.seed, vec2<u32>(index, 0u), MARCH_DOMAIN);
    var members = rng_new(params.seed, vec2<u32>(index, 0u), GROUP_DOMAIN);
    var times = rng_new(params.seed, vec2<u32>(index, 0u), MOTION_DOMAIN);
    var sum = PixelOut(vec3<f32>(0.0), 0.0, vec3<f32>(0.0), -1.0, vec3<f32>(0.0), 0.0, vec3<f32>(0.0), 0.0);
    let map_behind = env_kind() == 2u;
    for (var s = 0u; s < params.spp; s = s + 1u) {
        var j = vec2<f32>(0.5);
        if (params.spp != 1u) {
            j.x = rng_next_f64_as_f32(&rng);
            j.y = rng_next_f64_as_f32(&rng);
            j = pixel_jitter(s, params.spp, j);
        }
        let xi = rng_next_f64_as_f32(&rng);
        let u = rng_next_f64_as_f32(&members);
        let dir = camera_ray(params.camera, vec2<f32>(px, py) + j);
        motion_begin_sample(rng_next_f64_as_f32(&times));
        let r = march_ray(dir, xi, u);
        sum.single = sum.single + r.single;
        sum.multiple = sum.multiple + r.multiple;
        sum.transmittance = sum.transmittance + r.transmittance;
        sum.emission = sum.emission + r.emission;
        if (map_behind) {
            sum.behind = sum.behind + env_radiance(dir) * r.transmittance;
        }
        if (r.depth >= 0.0 && (sum.depth < 0.0 || r.depth < sum.depth)) {
            sum.depth = r.depth;
        }
    }
    let inv = 1.0 / f32(params.spp);
    pixels[local] = PixelOut(sum.single * inv, sum.transmittance * inv, sum.multiple * inv, sum.depth, sum.behind * inv, 0.0,
                             sum.emission * inv, 0.0);
}
