// requires: majorant_fetch, env_word, emission_active, emission_at, path_light, light_table_lookup
//
// Volumetric path tracing: the WGSL twin of nimbus_tracking::trace_path, shared by the
// reference path tracer (shaders/reference.wgsl: paths from the eye) and vdbcache's
// path-traced multiple scattering (shaders/cache.wgsl: paths from a cache voxel).
//
// Composed after volume.wgsl (the density is the default volume at group 0), optics.wgsl and
// tracking.wgsl, environment.wgsl and emission.wgsl (nimbus_tracking::emission_wgsl, at
// the stage's free group; nothing emits where emission_active() is false). The stage shader provides, besides tracking.wgsl's
// majorant_fetch and environment.wgsl's env_word,
//     fn path_light(index: u32) -> Light
// returning light `index` of the scene (usually from a storage buffer), and
//     fn light_table_lookup(light: u32, x: vec3<f32>) -> vec2<f32>
// the light's tabled transmittance at x and the weight of a shadow ray beside it (1 where it
// has no table): light_tables.wgsl's
// (nimbus_tracking::Shadowing::Tabled, vdbcache's paths) or NO_LIGHT_TABLES_WGSL's, which
// has none (Shadowing::RatioTracked, the reference's); what else differs
// between the two users (where the path starts, the medium, the majorant grid, which must
// suit delta tracking: MajorantGrid::for_tracking, the depth bound, the light count) comes in
// as arguments. Positions are f32 world positions relative to the stage's origin (the volume
// was told of it by GpuVolume::set_world_origin).
//
// The CPU decides in f64 and this in f32, so a path can take another turn now and then: the
// two agree in distribution (to Monte Carlo error), not path for path.

// Bounce from which Russian roulette may end a path (nimbus_tracking::ROULETTE_FROM_DEPTH).
const ROULETTE_FROM_DEPTH: u32 = 3u;
// Ratio-tracking estimates below this go to Russian roulette (nimbus_tracking::RATIO_ROULETTE).
const RATIO_ROULETTE: f32 = 0.05;
// From this |g| on, each collision sends a probe toward the lights (nimbus_tracking::PROBE_FROM_G).
const PROBE_FROM_G: f32 = 0.5;

// One path's light, split by the collision it was scattered at: the first (single) and every
// later one (multiple), and the medium's own emission (from every collision).
struct PathLight {
    single: vec3<f32>,
    multiple: vec3<f32>,
    emission: vec3<f32>,
}

// The ray from world point x along unit world direction w, in index space.
fn path_track_ray(x: vec3<f32>, w: vec3<f32>, extinction: f32) -> TrackRay {
    let to_index = volume_info.world_to_index;
    return TrackRay((to_index * vec4<f32>(x, 1.0)).xyz, (to_index * vec4<f32>(w, 0.0)).xyz, extinction);
}

// The power heuristic weight of a sample of density a against another of density b
// (nimbus_optics::power_heuristic).
fn power_heuristic(a: f32, b: f32) -> f32 {
    let a2 = a * a;
    let s = a2 + b * b;
    if (s > 0.0) {
        return a2 / s;
    }
    return 0.0;
}

// Next-event estimation of the environment at x toward w_out (nimbus_tracking::
// environment_nee): a direction drawn from it (environment.wgsl's env_sample), its
// ratio-tracked transmittance, weighed against HG sampling unless `alone`. A uniform sky
// takes none but `alone` (Environment::wants_next_event): escaping flights carry it.
fn environment_nee(x: vec3<f32>, w_out: vec3<f32>, m: Medium, grid: MajorantGridInfo, alone: bool,
                   rng: ptr<function, Rng>) -> vec3<f32> {
    if (!alone && env_kind() != 2u) {
        return vec3<f32>(0.0);
    }
    let s = env_sample(rng_next_vec2(rng));
    if (s.pdf <= 0.0 || all(s.radiance == vec3<f32>(0.0))) {
        _ = rng_next_f32(rng);
        return vec3<f32>(0.0);
    }
    let p = hg_eval(m.g, dot(-s.toward, w_out));
    var weight = 1.0;
    if (!alone) {
        weight = power_heuristic(s.pdf, p);
    }
    if (p * weight <= 0.0) {
        _ = rng_next_f32(rng);
        return vec3<f32>(0.0);
    }
    let tr = track_transmittance_ratio(path_track_ray(x, s.toward, m.extinction), grid, TRACK_FAR, RATIO_ROULETTE, rng);
    return s.radiance * (tr * p * weight / s.pdf);
}

// The delta lights' next-event estimate at x toward w_out (nimbus_tracking's lights_nee):
// each light's E p(w_light, w_out) T, T from the light's table where it has one and
// ratio-tracked otherwise; a sun's disc takes one direction per estimate (no draw for
// parallel light). With `add_lobes`, a lobe toward each light that lights x goes to `lobes`.
fn lights_nee(x: vec3<f32>, w_out: vec3<f32>, m: Medium, grid: MajorantGridInfo, light_count: u32, add_lobes: bool,
              lobes: ptr<function, LightLobes>, rng: ptr<function, Rng>) -> vec3<f32> {
    var direct = vec3<f32>(0.0);
    for (var i = 0u; i < light_count; i = i + 1u) {
        let light = path_light(i);
        var inc = light_incident(light, x);
        if (light.disc > 0.0) {
            inc = light_incident_over_disc(light, x, rng_next_vec2(rng));
        }
        if (all(inc.irradiance == vec3<f32>(0.0))) {
            continue;
        }
        if (add_lobes) {
            light_lobes_add(lobes, inc.to_light, luminance(inc.irradiance));
        }
        // The shadow ray with probability table.y in place of the blend: the same
        // expectation (TabledTransmittance::sample), a ray at that fraction of the lookups.
        let table = light_table_lookup(i, x);
        var tr = table.x;
        if (table.y >= 1.0 || (table.y > 0.0 && rng_next_f64_as_f32(rng) < table.y)) {
            tr = track_transmittance_ratio(path_track_ray(x, inc.to_light, m.extinction), grid,
                                           min(inc.distance, TRACK_FAR), RATIO_ROULETTE, rng);
        }
        if (tr > 0.0) {
            direct = direct + inc.irradiance * (tr * hg_eval(m.g, dot(-inc.to_light, w_out)));
        }
    }
    return direct;
}

// The radiance arriving at `origin` from direction -dir, scattered in the medium, by one
// path: delta-tracked free flights, albedo at each collision, next-event estimation toward
// every light, its transmittance looked up where the light has a table and ratio-tracked
// otherwise, Russian roulette from ROULETTE_FROM_DEPTH, HG scattering; at most `max_depth`
// collisions. The environment (environment.wgsl; none where env_kind() is 0) enters where
// phase-sampled flights escape, weighed by the power heuristic against environment_nee at
// each collision for a map; a uniform sky by escapes alone (and environment_nee at the last
// collision, which no flight follows). `first_pdf` is the HG density `dir` was drawn with at
// the origin (PathStart::Scattered), or negative for a camera ray (PathStart::Camera), whose
// escape is the caller's background.
fn trace_path(origin: vec3<f32>, dir: vec3<f32>, m: Medium, grid: MajorantGridInfo, max_depth: u32, light_count: u32,
              first_pdf: f32, rng: ptr<function, Rng>) -> PathLight {
    var out = PathLight(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0));
    let emits = emission_active();
    var x = origin;
    var w = dir;
    var beta = vec3<f32>(1.0);
    let kind = env_kind();
    var flight_pdf = first_pdf;
    // Probes toward the lights where the phase function is peaked (nimbus_tracking::PROBE_FROM_G).
    let probes = abs(m.g) >= PROBE_FROM_G;
    var probed = false;
    var probed_lobes = light_lobes_none();
    var probed_w_in = vec3<f32>(0.0);
    for (var depth = 1u; depth <= max_depth; depth = depth + 1u) {
        let t = track_sample_delta(path_track_ray(x, w, m.extinction), grid, rng);
        if (t < 0.0) {
            if (kind != 0u && flight_pdf >= 0.0) {
                var weight = 1.0;
                if (kind == 2u) {
                    weight = power_heuristic(flight_pdf, env_pdf(w));
                }
                let seen = beta * env_radiance(w) * weight;
                if (depth <= 2u) {
                    out.single = out.single + seen;
                } else {
                    out.multiple = out.multiple + seen;
                }
            }
            break;
        }
        x = x + w * t;
        // The collision estimator of emission (trace_path): beta e(x) / sigma_t(x).
        if (emits) {
            let frame_x = motion_back(x);
            let sigma_t = m.extinction * max(volume_sample_index(volume_world_to_index(frame_x)), 0.0);
            if (sigma_t > 0.0) {
                out.emission = out.emission + beta * emission_at(frame_x) * (1.0 / sigma_t);
            }
        }
        beta = beta * m.albedo;
        var lobes = light_lobes_none();
        var direct = lights_nee(x, -w, m, grid, light_count, true, &lobes, rng);
        // The previous collision's probe reached these lights' estimate too (LightLobes).
        if (probed) {
            direct = direct * light_lobes_phase_weight(m.g, probed_lobes, probed_w_in, w);
        }
        if (kind != 0u) {
            direct = direct + environment_nee(x, -w, m, grid, depth == max_depth, rng);
        }
        if (depth == 1u) {
            out.single = out.single + beta * direct;
        } else {
            out.multiple = out.multiple + beta * direct;
        }
        probed = false;
        if (probes && depth < max_depth && lobes.count > 0u) {
            let pick = rng_next_f32(rng);
            let toward = light_lobes_sample(m.g, lobes, pick, rng_next_vec2(rng));
            let tp = track_sample_delta(path_track_ray(x, toward, m.extinction), grid, rng);
            if (tp >= 0.0) {
                var none = light_lobes_none();
                let seen = lights_nee(x + toward * tp, -toward, m, grid, light_count, false, &none, rng);
                out.multiple = out.multiple + beta * m.albedo * seen * light_lobes_phase_weight(m.g, lobes, w, toward);
            }
            probed = true;
            probed_lobes = lobes;
            probed_w_in = w;
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
        let next = hg_sample(m.g, w, rng_next_vec2(rng));
        w = normalize(next.w_out);
        flight_pdf = next.pdf;
    }
    return out;
}
