// requires: emission_at, loop_guard_check
//
// vdbphoton's GPU backend: one invocation per photon path (nimbus_photon::trace_gpu).
//
// Composed as volume.wgsl (density = default volume, group 0) + optics.wgsl + environment.wgsl
// + emission.wgsl (group 2: the medium's emission, LIGHT_MEDIUM) + tracking.wgsl + this file.
// Mirrors crates/photon/src/cpu.rs's trace_path draw for draw: photon i's
// Rng is (seed, i, PHOTON_DOMAIN); emission (light by power CDF, a sun's marked lattice cell
// or a point light's marked direction cell), free path by the chosen mode, store after the first interaction, Russian roulette
// with probability mean(albedo), HG scattering. Positions are f32 relative to the host's
// origin (the volume's centre); the volume's world_to_index takes such positions.
//
// Output: stored photons appended through an atomic counter into `records` (bounded by
// `capacity`: past it they are counted but not written, and the host re-runs the chunk with
// a larger buffer), tagged with (path, interaction) so the host can restore the CPU's order;
// and per path (interactions, end).
//
// Composed after nimbus_gpu::LoopGuard::wgsl (binding 7 of group 1): every path ends with
// loop_guard_check(), so a software adapter that cut a path's loops short says so.

struct PhotonUniforms {
    medium: Medium,
    seed: vec2<u32>,
    // Photon index of invocation 0 (lo, hi).
    first_index: vec2<u32>,
    count: u32,
    capacity: u32,
    light_count: u32,
    // 0 simpson, 1 exponential, 2 delta.
    mode: u32,
    // Simpson step / exponential search step, world units.
    step: f32,
    max_interactions: u32,
    _pad0: u32,
    _pad1: u32,
    grid: MajorantGridInfo,
}

struct PhotonLight {
    // Sun: lowest corner of emission lattice cell (0, 0); point: position. Relative to the
    // origin.
    origin: vec3<f32>,
    kind: u32,
    // Sun: the lattice plane's normal (the direction photons travel) and cell edge; point:
    // its direction table's z axis.
    normal: vec3<f32>,
    cell: f32,
    // Sun: the lattice's column and row directions; point: its table's x and y axes.
    tangent: vec3<f32>,
    // Cumulative choice probability.
    cdf: f32,
    bitangent: vec3<f32>,
    // Its marked cells, emission_cells[first_cell .. first_cell + cell_count]: a sun's
    // lattice cells, a point light's direction cells.
    first_cell: u32,
    // Light power / choice probability.
    weight: vec3<f32>,
    cell_count: u32,
}

struct PhotonRecord {
    position: vec3<f32>,
    // Path within this dispatch.
    path: u32,
    power: vec3<f32>,
    interaction: u32,
    dir: vec3<f32>,
    _pad: u32,
}

const PHOTON_DOMAIN: u32 = 0x50484f54u;
// A point light's direction table (emission.rs).
const DIRECTION_ROWS: u32 = 256u;
const DIRECTION_COLUMNS: u32 = 512u;
const MODE_SIMPSON: u32 = 0u;
const MODE_EXPONENTIAL: u32 = 1u;
const END_ESCAPED: u32 = 0u;
const END_ABSORBED: u32 = 1u;
const END_TRUNCATED: u32 = 2u;

@group(1) @binding(0) var<storage, read> params: PhotonUniforms;
@group(1) @binding(1) var<storage, read> lights: array<PhotonLight>;
@group(1) @binding(2) var<storage, read> majorant_values: array<f32>;
@group(1) @binding(3) var<storage, read_write> records: array<PhotonRecord>;
@group(1) @binding(4) var<storage, read_write> record_count: atomic<u32>;
@group(1) @binding(5) var<storage, read_write> path_out: array<vec2<u32>>;
// Every light's marked emission cells, (column, row).
@group(1) @binding(6) var<storage, read> emission_cells: array<vec2<u32>>;
// The environment photons leave (Environment::gpu_words), read by environment.wgsl.
@group(1) @binding(7) var<storage, read> environment: array<f32>;

fn env_word(i: u32) -> f32 {
    return environment[i];
}

// A PhotonLight that is the environment: origin the bounding sphere's centre, cell its radius,
// weight (total power / the source's) in every channel.
const LIGHT_ENVIRONMENT: u32 = 2u;
// A PhotonLight that is the medium's emission (medium.rs MediumEmission): origin, tangent,
// bitangent and normal the density's index-to-world map (origin-relative), cell_count its
// emitting cells in medium_cells, weight the emitter's total power in every channel.
const LIGHT_MEDIUM: u32 = 3u;

// An emitting lattice cell (MediumEmission::gpu_cells): its lower corner (density index), its
// weight w_c, and its cumulative weight as the integer ceil(cdf 2^53) in bits 26.. and 0..26.
struct MediumCell {
    cell: vec3<i32>,
    weight: f32,
    threshold: vec2<u32>,
    _pad: vec2<u32>,
}

@group(1) @binding(9) var<storage, read> medium_cells: array<MediumCell>;

// MediumEmission::sample: a cell by the CDF (the 53 bits of an f64 draw compared exactly with
// the thresholds: partition_point(cdf <= u)), a point uniform in it, a direction uniform on
// the sphere; the power factor e(x) [density(x) > 0] / w_c. Returns the point, and sets
// *dir and *ratio.
fn medium_emission_sample(light: PhotonLight, rng: ptr<function, Rng>, dir: ptr<function, vec3<f32>>,
                          ratio: ptr<function, vec3<f32>>) -> vec3<f32> {
    let bits = rng_next_f64_bits(rng);
    let hi = bits.x;
    let lo = bits.y;
    var first = 0u;
    var last = light.cell_count;
    loop {
        if (first >= last) {
            break;
        }
        let mid = (first + last) / 2u;
        let t = medium_cells[mid].threshold;
        if (hi > t.x || (hi == t.x && lo >= t.y)) {
            first = mid + 1u;
        } else {
            last = mid;
        }
    }
    let c = medium_cells[min(first, light.cell_count - 1u)];
    let offset = vec3<f32>(rng_next_f64_as_f32(rng), rng_next_f64_as_f32(rng), rng_next_f64_as_f32(rng));
    let index = vec3<f32>(c.cell) + offset;
    let x = light.origin + index.x * light.tangent + index.y * light.bitangent + index.z * light.normal;
    *dir = normalize(sample_uniform_sphere(rng_next_vec2(rng)));
    if (volume_sample_index(index) > 0.0) {
        *ratio = emission_at(x) / c.weight;
    } else {
        *ratio = vec3<f32>(0.0);
    }
    return x;
}

fn majorant_fetch(index: u32) -> f32 {
    return majorant_values[index];
}

const WORKGROUP_SIZE: u32 = 64u;

// A cell index uniform over 0..n from the 64-bit word hi:lo, floor(word x n / 2^64)
// (emission.rs index_from_words): the high word of hi x n + the high word of lo x n.
fn emission_index_from_words(hi: u32, lo: u32, n: u32) -> u32 {
    let high = philox_mulhilo(hi, n);
    let low_top = philox_mulhilo(lo, n).x;
    let sum = high.y + low_top;
    return high.x + select(0u, 1u, sum < low_top);
}

fn emission_cell_index(rng: ptr<function, Rng>, n: u32) -> u32 {
    let hi = rng_next_u32(rng);
    let lo = rng_next_u32(rng);
    return emission_index_from_words(hi, lo, n);
}

// A sun photon's starting point, uniform over its marked cells (SunEmission::sample_point).
fn emission_point(light: PhotonLight, rng: ptr<function, Rng>) -> vec3<f32> {
    let c = vec2<f32>(emission_cells[light.first_cell + emission_cell_index(rng, light.cell_count)]);
    let u = rng_next_vec2(rng);
    return light.origin + ((c.x + u.x) * light.tangent + (c.y + u.y) * light.bitangent) * light.cell;
}

// A point light photon's direction, uniform over its marked direction cells
// (PointEmission::sample_direction).
fn emission_direction(light: PhotonLight, rng: ptr<function, Rng>) -> vec3<f32> {
    let c = vec2<f32>(emission_cells[light.first_cell + emission_cell_index(rng, light.cell_count)]);
    let u = rng_next_vec2(rng);
    let square = vec2<f32>((c.y + u.x) / f32(DIRECTION_ROWS), (c.x + u.y) / f32(DIRECTION_COLUMNS));
    let d = sample_uniform_sphere(square);
    return normalize(d.x * light.tangent + d.y * light.bitangent + d.z * light.normal);
}

@compute @workgroup_size(64)
fn trace_photons(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) lid: u32) {
    let path = dispatch_linear_index(wid, nwg, lid, WORKGROUP_SIZE);
    if (path >= params.count) {
        return;
    }
    trace_path(path);
    loop_guard_check();
}

// Photon path `path` of this dispatch, from emission to its end.
fn trace_path(path: u32) {
    let lo = params.first_index.x + path;
    let hi = params.first_index.y + select(0u, 1u, lo < params.first_index.x);
    var rng = rng_new(params.seed, vec2<u32>(lo, hi), PHOTON_DOMAIN);

    // Emission (Emitter::emit).
    let u = rng_next_f32(&rng);
    var li = params.light_count - 1u;
    for (var i = 0u; i < params.light_count; i = i + 1u) {
        if (u < lights[i].cdf) {
            li = i;
            break;
        }
    }
    let light = lights[li];
    var x: vec3<f32>;
    var w: vec3<f32>;
    var power = light.weight;
    if (light.kind == LIGHT_SUN) {
        x = emission_point(light, &rng);
        w = light.normal;
    } else if (light.kind == LIGHT_ENVIRONMENT) {
        // batch.rs EnvironmentEmission::sample: a direction from the environment, a point on
        // the disc of radius `cell` about `origin` facing it; the flux L pi R^2 / pdf over
        // the source's share (the weight's factor).
        let s = env_sample(rng_next_vec2(&rng));
        let disc = sample_uniform_disk_concentric(rng_next_vec2(&rng)) * light.cell;
        let frame = orthonormal_basis(s.toward);
        x = light.origin + s.toward * (2.0 * light.cell) + frame[0] * disc.x + frame[1] * disc.y;
        w = -normalize(s.toward);
        if (s.pdf > 0.0) {
            power = light.weight * s.radiance * (OPTICS_PI * light.cell * light.cell / s.pdf);
        } else {
            power = vec3<f32>(0.0);
        }
    } else if (light.kind == LIGHT_MEDIUM) {
        var ratio = vec3<f32>(0.0);
        x = medium_emission_sample(light, &rng, &w, &ratio);
        power = light.weight * ratio;
    } else {
        x = light.origin;
        w = emission_direction(light, &rng);
    }

    let m = params.medium;
    let survival = m.albedo_mean;
    let to_index = volume_info.world_to_index;
    for (var interaction = 0u; interaction < params.max_interactions; interaction = interaction + 1u) {
        let ray = TrackRay((to_index * vec4<f32>(x, 1.0)).xyz, (to_index * vec4<f32>(w, 0.0)).xyz, m.extinction);
        var t: f32;
        if (params.mode == MODE_SIMPSON) {
            t = track_sample_simpson(ray, params.grid, rng_next_exp1(&rng), params.step);
        } else if (params.mode == MODE_EXPONENTIAL) {
            t = track_sample_exponential(ray, params.grid, rng_next_exp1(&rng), params.step);
        } else {
            t = track_sample_delta(ray, params.grid, &rng);
        }
        if (t < 0.0) {
            path_out[path] = vec2<u32>(interaction, END_ESCAPED);
            return;
        }
        x = x + w * t;
        // Environment and medium photons are stored from their first interaction (batch.rs
        // store_first).
        if (interaction > 0u || light.kind == LIGHT_ENVIRONMENT || light.kind == LIGHT_MEDIUM) {
            let slot = atomicAdd(&record_count, 1u);
            if (slot < params.capacity) {
                records[slot] = PhotonRecord(x, path, power * m.albedo, interaction, w, 0u);
            }
        }
        if (rng_next_f32(&rng) >= survival) {
            path_out[path] = vec2<u32>(interaction + 1u, END_ABSORBED);
            return;
        }
        power = power * (m.albedo / survival);
        w = normalize(hg_sample(m.g, w, rng_next_vec2(&rng)).w_out);
    }
    path_out[path] = vec2<u32>(params.max_interactions, END_TRUNCATED);
}
