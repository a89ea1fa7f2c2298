// The medium's emission (issue #19): the WGSL twin of nimbus_tracking::EmissionField::at and
// nimbus_optics::Emission::emitted, shared by every stage that meets emission (the march's
// camera rays, path.wgsl's collision estimator for the reference and vdbcache's paths,
// vdbphoton's photons from emitting cells).
//
// Composed after volume.wgsl by nimbus_tracking::emission_wgsl(group), which puts these
// bindings at the stage's free bind group (the token EMISSION_GROUP below):
// - the emission grid and the temperature grid, each a volume in its own index space (its
//   own transform), sampled exactly as the CPU's Volume::sample_world (an absent grid is an
//   empty volume, and its term's flag is clear);
// - EmissionInfo (nimbus_optics::GpuEmissionInfo): strength, colour, kelvin per unit,
//   Cycles' blackbody intensity, and the blackbody colour table's extent;
// - the table itself (nimbus_optics::blackbody_table: Planck x CIE 1931 every 10 K,
//   interpolated as blackbody_rgb does).
// Positions are world positions relative to the stage's origin (GpuVolume::set_world_origin).

struct EmissionInfo {
    color: vec3<f32>,
    strength: f32,
    temperature_scale: f32,
    blackbody_intensity: f32,
    // Bit 0: the grid term, bit 1: the blackbody term; 0: nothing emits.
    flags: u32,
    table_len: u32,
    table_min: f32,
    table_max: f32,
    table_inv_step: f32,
    // sigma_SB 1e-6 / pi (Cycles' scale).
    stefan_boltzmann: f32,
}

@group(EMISSION_GROUP) @binding(0) var emission_grid_atlas: texture_3d<f32>;
@group(EMISSION_GROUP) @binding(1) var emission_grid_table: texture_3d<u32>;
@group(EMISSION_GROUP) @binding(2) var emission_grid_sampler: sampler;
@group(EMISSION_GROUP) @binding(3) var<storage, read> emission_grid_info: VolumeInfo;
@group(EMISSION_GROUP) @binding(4) var emission_temperature_atlas: texture_3d<f32>;
@group(EMISSION_GROUP) @binding(5) var emission_temperature_table: texture_3d<u32>;
@group(EMISSION_GROUP) @binding(6) var emission_temperature_sampler: sampler;
@group(EMISSION_GROUP) @binding(7) var<storage, read> emission_temperature_info: VolumeInfo;
@group(EMISSION_GROUP) @binding(8) var<storage, read> emission_info: EmissionInfo;
@group(EMISSION_GROUP) @binding(9) var<storage, read> emission_blackbody: array<vec4<f32>>;

const EMISSION_GRID_TERM: u32 = 1u;
const EMISSION_BLACKBODY_TERM: u32 = 2u;

fn emission_active() -> bool {
    return emission_info.flags != 0u;
}

// nimbus_optics::blackbody_rgb: the table's linear interpolation, clamped to its ends, and
// negative components clamped to 0.
fn emission_blackbody_rgb(t: f32) -> vec3<f32> {
    let x = max((clamp(t, emission_info.table_min, emission_info.table_max) - emission_info.table_min)
                * emission_info.table_inv_step, 0.0);
    let i = min(u32(floor(x)), emission_info.table_len - 2u);
    let f = min(x - f32(i), 1.0);
    let c = emission_blackbody[i].xyz * (1.0 - f) + emission_blackbody[i + 1u].xyz * f;
    return max(c, vec3<f32>(0.0));
}

// The emitted radiance per unit length at x (EmissionField::at): S color grid(x), plus the
// blackbody sigma 1e-6 / pi ((1 - B) + B T^4) rgb(T) at T = scale temperature(x).
fn emission_at(x: vec3<f32>) -> vec3<f32> {
    var e = vec3<f32>(0.0);
    if ((emission_info.flags & EMISSION_GRID_TERM) != 0u) {
        let p = volume_world_to_index_in(emission_grid_info, x);
        let g = volume_sample_index_in(emission_grid_atlas, emission_grid_table, emission_grid_info, p).x;
        e = e + emission_info.color * (emission_info.strength * max(g, 0.0));
    }
    if ((emission_info.flags & EMISSION_BLACKBODY_TERM) != 0u) {
        let p = volume_world_to_index_in(emission_temperature_info, x);
        let temperature = volume_sample_index_in(emission_temperature_atlas, emission_temperature_table,
                                                 emission_temperature_info, p).x;
        let t = max(emission_info.temperature_scale * max(temperature, 0.0), 0.0);
        let b = emission_info.blackbody_intensity;
        let t2 = t * t;
        let intensity = emission_info.stefan_boltzmann * ((1.0 - b) + b * (t2 * t2));
        if (intensity > 0.0) {
            e = e + emission_blackbody_rgb(t) * intensity;
        }
    }
    return e;
}
