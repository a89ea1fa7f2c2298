// requires: trace_path, light_table_lookup, light_table_lookup_within, CACHE_MAX_NEIGHBOURS, CACHE_PATHS_DOMAIN, CACHE_MAX_ORIGINS, BALL_SHELLS, BALL_DIRECTIONS, loop_guard_check
//
// vdbcache's GPU backend: one invocation per planned cache voxel (nimbus_cache::bake_gpu).
//
// Composed as volume.wgsl (density = default volume, group 0, sampled exactly) + optics.wgsl
// + tracking.wgsl + light_tables.wgsl (the lights' tables, group 2) + path.wgsl + the
// host-generated constants (CACHE_MAX_NEIGHBOURS, CACHE_PATHS_DOMAIN, BALL_SHELLS,
// BALL_DIRECTIONS, from crates/cache/src/cpu.rs) + this file. Mirrors crates/cache/src/cpu.rs:
// - bake_single: li_single, per light its tabled transmittance where it has a table (zero
//   below the cut-off), else one Simpson shadow ray (track_transmittance);
// - bake_multiple: li_multiple, the photons' radiance estimate over the k nearest (the same
//   shell-by-shell bounded search over the same counting-sort bins as PhotonBins::nearest,
//   with the same max-heap order) or within a fixed radius, divided by the mean sigma_s over
//   the ball (the same 42-point quadrature);
// - seed_paths then bake_paths: li_multiple_paths over the host's PathPlan (voxel v's count
//   in out.used, its paths' origins from path_origins[path_first[v]]; path.wgsl's trace_path
//   from each origin, the first direction by HG about the camera ray there, next-event
//   estimation through the lights' tables where they have one), drawing from the CPU's
//   stream: voxel i's Rng (seed, i, CACHE_PATHS_DOMAIN), one stream for all its paths in
//   turn, kept in path_rngs between dispatches. The host binds the tracking majorant
//   (MajorantGrid::for_tracking) for these, the plain one for the others.
//   The CPU decides in f64 and this in f32, so a path can take another turn now and then:
//   the two agree in distribution, not voxel for voxel.
// Positions are f32 relative to the host's origin, which is the photon bins' origin when
// there are photons, so bin-local positions are the very f32 values the CPU compares.
// Composed after nimbus_gpu::LoopGuard::wgsl (binding 11 of group 1): every voxel ends with
// loop_guard_check(), so a software adapter that cut a shadow ray, a photon search or a path
// short says so. llvmpipe (lavapipe) ends any loop of a SIMD group after 65535 iterations
// counted over the whole invocation, so each bake_paths dispatch traces a few paths per
// voxel (as reference.wgsl does a few samples per pixel), adding to what earlier ones left.

struct CacheUniforms {
    medium: Medium,
    grid: MajorantGridInfo,
    eye: vec3<f32>,
    // Simpson step toward the lights, world units.
    step: f32,
    bins_dims: vec3<i32>,
    bins_cell: f32,
    // First voxel of this dispatch and how many.
    first: u32,
    count: u32,
    light_count: u32,
    // Shadow rays stop below this transmittance.
    cutoff: f32,
    // Neighbours wanted (GATHER_NEAREST).
    k: u32,
    // Fixed radius, or the largest adaptive one; and its square rounded from f64 as the CPU does.
    radius: f32,
    radius_sq: f32,
    gather_mode: u32,
    // Shells the nearest-photon search may visit (PhotonBins::nearest's max_shell).
    max_shell: i32,
    // Mean density below which a ball counts as empty (cpu.rs EMPTY_BALL_FRACTION).
    empty_below: f32,
    // Path-traced Li_multiple: the seed (lo, hi), the most collisions per path
    // (PATH_MAX_DEPTH), and the paths first_path .. first_path + path_count of this dispatch.
    seed: vec2<u32>,
    max_depth: u32,
    first_path: u32,
    path_count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
    _pad3: u32,
    _pad4: u32,
}

// Photons sorted by bin; `index` is the photon's number in the map (the CPU's tie-break).
struct CachePhoton {
    position: vec3<f32>,
    index: u32,
    power: vec3<f32>,
    _pad0: u32,
    dir: vec3<f32>,
    _pad1: u32,
}

struct CacheOut {
    li: vec3<f32>,
    // Photons the estimate used; for the paths, the voxel's path count.
    used: u32,
    // The paths' mean square over the colour channels (budget.rs), else 0.
    square: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// PathMoments::halves: a voxel's paths' estimates (the channels' mean) summed at
// 8 * (path index parity) + (origin's octant about the node), for the lattice's bias.
struct PathHalves {
    sums: array<f32, 16>,
}

const GATHER_NEAREST: u32 = 0u;
const GATHER_RADIUS: u32 = 1u;

@group(1) @binding(0) var<storage, read> params: CacheUniforms;
@group(1) @binding(1) var<storage, read> majorant_values: array<f32>;
@group(1) @binding(2) var<storage, read> lights: array<Light>;
@group(1) @binding(3) var<storage, read> points: array<vec4<f32>>;
@group(1) @binding(4) var<storage, read> bin_starts: array<u32>;
@group(1) @binding(5) var<storage, read> photons: array<CachePhoton>;
@group(1) @binding(6) var<storage, read_write> out: array<CacheOut>;
// Each voxel's path Rng between the dispatches of bake_paths.
@group(1) @binding(7) var<storage, read_write> path_rngs: array<Rng>;
// PathPlan::first and PathPlan::origins (relative to the host's origin, w the origin's
// octant, PathPlan::octants) for bake_paths.
@group(1) @binding(8) var<storage, read> path_first: array<u32>;
@group(1) @binding(9) var<storage, read> path_origins: array<vec4<f32>>;
// The environment (nimbus_optics::Environment::gpu_words), read by environment.wgsl.
@group(1) @binding(10) var<storage, read> environment: array<f32>;
// PathHalves per voxel for bake_paths (one dummy for the other kernels).
@group(1) @binding(11) var<storage, read_write> path_halves: array<PathHalves>;

fn env_word(i: u32) -> f32 {
    return environment[i];
}

fn majorant_fetch(index: u32) -> f32 {
    return majorant_values[index];
}

fn path_light(index: u32) -> Light {
    return lights[index];
}

// Unit direction toward the eye (zero at the eye, as normalize_or_zero).
fn toward_eye(x: vec3<f32>) -> vec3<f32> {
    let d = params.eye - x;
    let l = length(d);
    if (l > 0.0) {
        return d / l;
    }
    return vec3<f32>(0.0);
}

// ---------------------------------------------------------------------------------------
// Single scattering: sum over lights of p(w_light, w_out) E T_light(x).

// Single scattering from a sun with a disc (cpu.rs sun_disc_single): the mean over
// SUN_DISC_RAYS Simpson shadow rays spread over the disc by the R2 sequence, offset by a hash
// of x. The CPU hashes x's f64 bits and this its f32 bits relative to the origin, so the two
// take other directions at a point and agree in distribution.
const SUN_DISC_RAYS: u32 = 8u;

fn sun_disc_single(light: Light, x: vec3<f32>, w_out: vec3<f32>) -> vec3<f32> {
    let o = volume_world_to_index(x);
    let bits = bitcast<vec3<u32>>(x);
    var rng = rng_new(vec2<u32>(bits.x ^ (bits.z * 0x9E3779B9u), bits.y), vec2<u32>(0u, 0u), 0u);
    let h = rng_next_vec2(&rng);
    var sum = vec3<f32>(0.0);
    for (var k = 0u; k < SUN_DISC_RAYS; k = k + 1u) {
        let u = fract(h + vec2<f32>(0.7548776662, 0.5698402910) * f32(k));
        let inc = light_incident_over_disc(light, x, u);
        if (all(inc.irradiance == vec3<f32>(0.0))) {
            return vec3<f32>(0.0);
        }
        let d = (volume_info.world_to_index * vec4<f32>(inc.to_light, 0.0)).xyz;
        var tr = track_transmittance(TrackRay(o, d, params.medium.extinction), params.grid, inc.distance, params.step, params.cutoff);
        if (tr < params.cutoff) {
            tr = 0.0;
        }
        sum = sum + inc.irradiance * tr * hg_eval(params.medium.g, dot(-inc.to_light, w_out));
    }
    return sum / f32(SUN_DISC_RAYS);
}

fn li_single(x: vec3<f32>, w_out: vec3<f32>) -> vec3<f32> {
    let o = volume_world_to_index(x);
    var sum = vec3<f32>(0.0);
    for (var i = 0u; i < params.light_count; i = i + 1u) {
        if (lights[i].disc > 0.0) {
            sum = sum + sun_disc_single(lights[i], x, w_out);
            continue;
        }
        let inc = light_incident(lights[i], x);
        if (all(inc.irradiance == vec3<f32>(0.0))) {
            continue;
        }
        // The light's table, and a shadow ray where it does not resolve x
        // (LightDepths::transmittance_within, SINGLE_SPREAD).
        let table = light_table_lookup_within(i, x, LIGHT_TABLE_SINGLE_SPREAD);
        var tr = table.x;
        if (table.y > 0.0) {
            let d = (volume_info.world_to_index * vec4<f32>(inc.to_light, 0.0)).xyz;
            let ray = TrackRay(o, d, params.medium.extinction);
            tr = mix(table.x, track_transmittance(ray, params.grid, inc.distance, params.step, params.cutoff), table.y);
        }
        if (tr < params.cutoff) {
            tr = 0.0;
        }
        sum = sum + inc.irradiance * tr * hg_eval(params.medium.g, dot(-inc.to_light, w_out));
    }
    return sum;
}

// ---------------------------------------------------------------------------------------
// Multiple scattering.

// The k nearest so far: a binary max-heap on (squared distance, photon index), the order of
// the CPU's BinaryHeap<(f32 bits, index)>. heap_j holds slots of `photons`.
var<private> heap_d: array<f32, CACHE_MAX_NEIGHBOURS>;
var<private> heap_j: array<u32, CACHE_MAX_NEIGHBOURS>;

fn heap_above(a: u32, b: u32) -> bool {
    let da = heap_d[a];
    let db = heap_d[b];
    return da > db || (da == db && photons[heap_j[a]].index > photons[heap_j[b]].index);
}

fn heap_swap(a: u32, b: u32) {
    let d = heap_d[a];
    let j = heap_j[a];
    heap_d[a] = heap_d[b];
    heap_j[a] = heap_j[b];
    heap_d[b] = d;
    heap_j[b] = j;
}

fn heap_push(len: u32, d: f32, j: u32) {
    heap_d[len] = d;
    heap_j[len] = j;
    var i = len;
    while (i > 0u) {
        let parent = (i - 1u) / 2u;
        if (!heap_above(i, parent)) {
            break;
        }
        heap_swap(i, parent);
        i = parent;
    }
}

fn heap_replace_top(len: u32, d: f32, j: u32) {
    heap_d[0] = d;
    heap_j[0] = j;
    var i = 0u;
    loop {
        let l = 2u * i + 1u;
        let r = l + 1u;
        var m = i;
        if (l < len && heap_above(l, m)) {
            m = l;
        }
        if (r < len && heap_above(r, m)) {
            m = r;
        }
        if (m == i) {
            break;
        }
        heap_swap(i, m);
        i = m;
    }
}

fn bin_id(c: vec3<i32>) -> u32 {
    let d = params.bins_dims;
    return u32((c.x * d.y + c.y) * d.z + c.z);
}

// Offers the photons in slots [a, b) to the heap of `len` entries; returns the new length.
fn offer_run(a: u32, b: u32, q: vec3<f32>, len_in: u32) -> u32 {
    var len = len_in;
    for (var j = a; j < b; j = j + 1u) {
        let e = photons[j].position - q;
        let d2 = dot(e, e);
        if (d2 > params.radius_sq) {
            continue;
        }
        if (len < params.k) {
            heap_push(len, d2, j);
            len = len + 1u;
        } else if (d2 < heap_d[0]) {
            heap_replace_top(len, d2, j);
        }
    }
    return len;
}

struct Gathered {
    sum: vec3<f32>,
    used: u32,
    radius: f32,
}

fn photon_term(j: u32, w_out: vec3<f32>) -> vec3<f32> {
    let p = photons[j];
    return p.power * hg_eval(params.medium.g, dot(p.dir, w_out));
}

// PhotonBins::nearest: shells of cells outward from q's cell, stopping once the next shell
// cannot hold anything nearer than the current k-th. The shell's cells are visited as rows
// along z (contiguous in the bins) rather than by testing every cell of its cube.
fn gather_nearest(q: vec3<f32>, w_out: vec3<f32>) -> Gathered {
    let cell = params.bins_cell;
    let dims = params.bins_dims;
    let centre = vec3<i32>(floor(q / cell));
    var len = 0u;
    for (var shell = 0; shell <= params.max_shell; shell = shell + 1) {
        let reach = f32(max(shell - 1, 0)) * cell;
        if (reach * reach > params.radius_sq || (len == params.k && reach * reach > heap_d[0])) {
            break;
        }
        let lo = centre - vec3<i32>(shell);
        let hi = centre + vec3<i32>(shell);
        let clo = max(lo, vec3<i32>(0));
        let chi = min(hi, dims - vec3<i32>(1));
        for (var x = clo.x; x <= chi.x; x = x + 1) {
            for (var y = clo.y; y <= chi.y; y = y + 1) {
                if (x == lo.x || x == hi.x || y == lo.y || y == hi.y) {
                    if (clo.z <= chi.z) {
                        len = offer_run(bin_starts[bin_id(vec3<i32>(x, y, clo.z))], bin_starts[bin_id(vec3<i32>(x, y, chi.z)) + 1u], q, len);
                    }
                } else {
                    // Inside the cube's x-y extent only the two z faces are on the shell.
                    if (lo.z >= 0 && lo.z < dims.z) {
                        let id = bin_id(vec3<i32>(x, y, lo.z));
                        len = offer_run(bin_starts[id], bin_starts[id + 1u], q, len);
                    }
                    if (hi.z != lo.z && hi.z >= 0 && hi.z < dims.z) {
                        let id = bin_id(vec3<i32>(x, y, hi.z));
                        len = offer_run(bin_starts[id], bin_starts[id + 1u], q, len);
                    }
                }
            }
        }
    }
    var g = Gathered(vec3<f32>(0.0), len, params.radius);
    for (var i = 0u; i < len; i = i + 1u) {
        g.sum = g.sum + photon_term(heap_j[i], w_out);
    }
    // Fewer than k photons within reach: the ball is the whole reach. Otherwise the k-th
    // photon lies on the surface and counts k-1 (cpu.rs li_multiple).
    if (len == params.k) {
        g.radius = sqrt(heap_d[0]);
        if (len >= 2u) {
            g.sum = g.sum * (f32(len - 1u) / f32(len));
        }
    }
    return g;
}

// PhotonBins::for_each_within: every photon within the fixed radius.
fn gather_within(q: vec3<f32>, w_out: vec3<f32>) -> Gathered {
    let cell = params.bins_cell;
    let r = params.radius;
    let lo = max(vec3<i32>(floor((q - vec3<f32>(r)) / cell)), vec3<i32>(0));
    let hi = min(vec3<i32>(floor((q + vec3<f32>(r)) / cell)), params.bins_dims - vec3<i32>(1));
    var g = Gathered(vec3<f32>(0.0), 0u, r);
    if (lo.z > hi.z) {
        return g;
    }
    for (var x = lo.x; x <= hi.x; x = x + 1) {
        for (var y = lo.y; y <= hi.y; y = y + 1) {
            let a = bin_starts[bin_id(vec3<i32>(x, y, lo.z))];
            let b = bin_starts[bin_id(vec3<i32>(x, y, hi.z)) + 1u];
            for (var j = a; j < b; j = j + 1u) {
                let e = photons[j].position - q;
                if (dot(e, e) <= params.radius_sq) {
                    g.sum = g.sum + photon_term(j, w_out);
                    g.used = g.used + 1u;
                }
            }
        }
    }
    return g;
}

// mean_density_in_ball: 14 directions on 3 equal-volume shells, equally weighted.
fn mean_density_in_ball(x: vec3<f32>, radius: f32) -> f32 {
    var sum = 0.0;
    for (var s = 0u; s < 3u; s = s + 1u) {
        for (var d = 0u; d < 14u; d = d + 1u) {
            let p = x + BALL_DIRECTIONS[d] * (BALL_SHELLS[s] * radius);
            sum = sum + max(volume_sample_index(volume_world_to_index(p)), 0.0);
        }
    }
    return sum / 42.0;
}

fn li_multiple(x: vec3<f32>, w_out: vec3<f32>) -> CacheOut {
    var g: Gathered;
    if (params.gather_mode == GATHER_RADIUS) {
        g = gather_within(x, w_out);
    } else {
        g = gather_nearest(x, w_out);
    }
    if (g.used == 0u || g.radius <= 0.0) {
        return CacheOut(vec3<f32>(0.0), g.used, 0.0, 0u, 0u, 0u);
    }
    let mean_density = mean_density_in_ball(x, g.radius);
    if (mean_density < params.empty_below) {
        return CacheOut(vec3<f32>(0.0), g.used, 0.0, 0u, 0u, 0u);
    }
    let volume = 4.0 / 3.0 * OPTICS_PI * g.radius * g.radius * g.radius;
    let mean_sigma_s = medium_sigma_s(params.medium, mean_density);
    let estimate = g.sum / volume;
    let li = select(vec3<f32>(0.0), estimate / mean_sigma_s, mean_sigma_s > vec3<f32>(0.0));
    return CacheOut(li, g.used, 0.0, 0u, 0u, 0u);
}

// ---------------------------------------------------------------------------------------
// Multiple scattering by paths (cpu.rs li_multiple_paths; the counts from importance.rs).

// Before a voxel's first paths: its Rng. Its path count came from the host in `used`, with
// a zero sum.
fn start_paths(v: u32) {
    var rng = rng_new(params.seed, vec2<u32>(v, 0u), CACHE_PATHS_DOMAIN);
    // The first four words rotate the halves' R2 sequences of first directions (path_offset).
    for (var k = 0u; k < 4u; k = k + 1u) {
        _ = rng_next_u32(&rng);
    }
    path_rngs[v] = rng;
}

// The rotations of voxel v's two R2 sequences (even paths, odd paths): the first four words
// of its stream, as the CPU's li_multiple_paths draws them before its first path.
fn path_offsets(v: u32) -> vec4<u32> {
    var rng = rng_new(params.seed, vec2<u32>(v, 0u), CACHE_PATHS_DOMAIN);
    let a = rng_next_u32(&rng);
    let b = rng_next_u32(&rng);
    let c = rng_next_u32(&rng);
    return vec4<u32>(a, b, c, rng_next_u32(&rng));
}

// Paths first_path .. first_path + path_count of voxel v (those it has), path p from the
// voxel's origin p modulo its origins' count (at most CACHE_MAX_ORIGINS, as PathPlan keeps),
// with w_out toward the eye from there, added to its sum; the dispatch that traces its last
// path divides by the count.
fn continue_paths(v: u32) {
    let n = out[v].used;
    if (params.first_path >= n) {
        return;
    }
    var rng = path_rngs[v];
    let offsets = path_offsets(v);
    var sum = out[v].li;
    var squares = out[v].square;
    var halves = path_halves[v].sums;
    let end = min(params.first_path + params.path_count, n);
    for (var p = params.first_path; p < end; p = p + 1u) {
        let origin = path_origins[path_first[v] + p % min(n, CACHE_MAX_ORIGINS)];
        let x = origin.xyz;
        let w_out = toward_eye(x);
        // At the eye itself there is no camera ray; any axis serves.
        var axis = vec3<f32>(0.0, 0.0, 1.0);
        if (any(w_out != vec3<f32>(0.0))) {
            axis = -w_out;
        }
        // The environment scattered at the origin itself: a next-event estimate there (a map's)
        // and the first flight below when it escapes (li_multiple_paths).
        var estimate = vec3<f32>(0.0);
        if (env_kind() == 2u) {
            estimate = environment_nee(x, -axis, params.medium, params.grid, false, &rng);
        }
        // From the phase function about the camera ray's direction (the phase weight cancels),
        // by its half's rotated R2 sequence (li_multiple_paths).
        let offset = select(offsets.xy, offsets.zw, (p & 1u) == 1u);
        let first = hg_sample(params.medium.g, axis, r2_point(offset, p >> 1u));
        let dir = normalize(first.w_out);
        let path = trace_path(x, dir, params.medium, params.grid, params.max_depth, params.light_count, first.pdf, &rng);
        estimate = estimate + (path.single + path.multiple + path.emission);
        sum = sum + estimate;
        squares = squares + dot(estimate, estimate) / 3.0;
        let half = 8u * (p & 1u) + u32(origin.w);
        halves[half] = halves[half] + (estimate.x + estimate.y + estimate.z) / 3.0;
    }
    if (end == n) {
        sum = sum / f32(n);
        squares = squares / f32(n);
    }
    out[v].li = sum;
    out[v].square = squares;
    path_halves[v].sums = halves;
    path_rngs[v] = rng;
}

// ---------------------------------------------------------------------------------------

const WORKGROUP_SIZE: u32 = 64u;

@compute @workgroup_size(64)
fn bake_single(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) local: u32) {
    let i = dispatch_linear_index(wg, nwg, local, WORKGROUP_SIZE);
    if (i >= params.count) {
        return;
    }
    let v = params.first + i;
    let x = points[v].xyz;
    out[v] = CacheOut(li_single(x, toward_eye(x)), 0u, 0.0, 0u, 0u, 0u);
    loop_guard_check();
}

@compute @workgroup_size(64)
fn bake_multiple(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) local: u32) {
    let i = dispatch_linear_index(wg, nwg, local, WORKGROUP_SIZE);
    if (i >= params.count) {
        return;
    }
    let v = params.first + i;
    let x = points[v].xyz;
    out[v] = li_multiple(x, toward_eye(x));
    loop_guard_check();
}

// Path-traced Li_multiple in dispatches: first this one (the Rngs), then bake_paths once per
// path_count paths. `params.grid` is the tracking majorant here.
@compute @workgroup_size(64)
fn seed_paths(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                    @builtin(local_invocation_index) local: u32) {
    let i = dispatch_linear_index(wg, nwg, local, WORKGROUP_SIZE);
    if (i >= params.count) {
        return;
    }
    start_paths(params.first + i);
    loop_guard_check();
}

@compute @workgroup_size(64)
fn bake_paths(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) local: u32) {
    let i = dispatch_linear_index(wg, nwg, local, WORKGROUP_SIZE);
    if (i >= params.count) {
        return;
    }
    continue_paths(params.first + i);
    loop_guard_check();
}
