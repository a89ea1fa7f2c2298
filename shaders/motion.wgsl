// Eulerian motion blur (issue #20): the WGSL twin of nimbus_tracking::Motion. The medium a
// sample sees at world point x at time t in the shutter is the frame's medium at
// x - t v(x), v the velocity grid in world units a second.
//
// nimbus_tracking::tracking_wgsl_moving puts this file in place of tracking.wgsl's static
// motion_back / motion_back_index, with its bindings at bind group MOTION_GROUP (the stage's
// first free one); bind a nimbus_tracking::GpuMotion there. Composed after volume.wgsl (the
// density is the default volume). The stage sets the sample's time with motion_begin_sample
// before it looks at the medium: one time for the whole sample, camera ray and path alike,
// as the CPU gives each sample one Motion.

@group(MOTION_GROUP) @binding(0) var velocity_atlas: texture_3d<f32>;
@group(MOTION_GROUP) @binding(1) var velocity_table: texture_3d<u32>;
@group(MOTION_GROUP) @binding(2) var velocity_sampler: sampler;
@group(MOTION_GROUP) @binding(3) var<storage, read> velocity_info: VolumeInfo;

// nimbus_tracking::GpuMotionInfo.
struct MotionInfo {
    // Density index space -> velocity index space (the two grids' transforms composed on the
    // host in f64, so no world position is formed in f32).
    density_to_velocity: mat4x4<f32>,
    // Seconds the shutter is open; 0 without motion blur.
    shutter: f32,
    _pad0: f32,
    _pad1: f32,
    _pad2: f32,
}
@group(MOTION_GROUP) @binding(4) var<storage, read> motion_info: MotionInfo;

// The stream a sample's time is drawn from (nimbus_march::MOTION_DOMAIN), so the sample's
// other draws are the same with and without blur.
const MOTION_DOMAIN: u32 = 0x4d4f5445u;

// The current sample's time in seconds from the frame (0: the frame's own medium).
var<private> motion_time: f32;

// The sample at shutter fraction u in [0, 1) sees the medium at time (u - 1/2) shutter
// (nimbus_tracking::MotionBlur::at).
fn motion_begin_sample(u: f32) {
    motion_time = (u - 0.5) * motion_info.shutter;
}

fn motion_velocity_at_index(p_velocity_index: vec3<f32>) -> vec3<f32> {
    return volume_sample_index_in(velocity_atlas, velocity_table, velocity_info, p_velocity_index).xyz;
}

// Motion::back: where the medium at world point x (relative to the stage's origin) now was
// in the frame.
fn motion_back(x: vec3<f32>) -> vec3<f32> {
    if (motion_time == 0.0) {
        return x;
    }
    return x - motion_velocity_at_index(volume_world_to_index_in(velocity_info, x)) * motion_time;
}

// The same for a point p of the density's index space (tracking.wgsl's rays live there).
fn motion_back_index(p: vec3<f32>) -> vec3<f32> {
    if (motion_time == 0.0) {
        return p;
    }
    let v = motion_velocity_at_index((motion_info.density_to_velocity * vec4<f32>(p, 1.0)).xyz);
    return p - (volume_info.world_to_index * vec4<f32>(v, 0.0)).xyz * motion_time;
}
