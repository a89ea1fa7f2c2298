// Sparse-volume sampling shared by every nimbus stage shader.
//
// requires: VOLUME_FILTERABLE
//
// Stage shaders are compiled as `volume.wgsl + stage.wgsl` (nimbus_gpu::compose_shader), which
// also prepends `const VOLUME_FILTERABLE: bool` telling whether the device can linearly filter
// 32-bit float textures (wgpu Features::FLOAT32_FILTERABLE).
//
// Data layout (built by nimbus_gpu::GpuVolume; design.md section 2 for the sampling rule):
// - atlas: 3D texture of brick slots, 9^3 texels each: the brick's 8^3 voxels plus a one-voxel
//   apron on the high side holding the neighbouring bricks' values (or the background), so
//   all 8 corners of any cell whose lowest corner is in the brick lie in the same slot.
//   Absent bricks whose high-side neighbours are present also get a slot ("ghost" bricks),
//   so the rule "the slot of the brick holding floor(p) has every corner" holds everywhere.
//   R32Float for scalar volumes, Rgba32Float (w unused) for vec3 volumes.
// - table: 3D texture of u32, one texel per brick over the bricks' bounding box; 0 means
//   no slot (every corner is background), else bit 31 set and the slot's coordinates in
//   units of slots packed in bits 0-9 (x), 10-19 (y), 20-29 (z).
// - info: the uniform below.
//
// Positions are in index space unless named otherwise: voxel (i,j,k)'s value sits at the
// integer point (i,j,k), as in OpenVDB. f32 index coordinates resolve a cell to 1/2^(23-log2|i|)
// of a voxel: 2^-9 at |i| = 16384, plenty for trilinear weights.

struct VolumeInfo {
    // (world - world_origin) -> index, rounded to f32 on the host from the f64 transform.
    // world_origin is chosen by the host (GpuVolume::set_world_origin), so a stage working
    // far from the world origin passes camera-relative positions and loses no precision.
    world_to_index: mat4x4<f32>,
    background: vec4<f32>,
    // Brick coordinate (voxel index >> 3) of table texel (0,0,0), and the table's size.
    table_origin: vec3<i32>,
    _pad0: u32,
    table_dims: vec3<i32>,
    _pad1: u32,
    // 1 / atlas size in texels, for normalised coordinates of the filtered path.
    inv_atlas_dims: vec3<f32>,
    _pad2: u32,
    // Inclusive index bounding box of the active voxels (min > max when there are none),
    // for stages that clip rays to the volume.
    index_min: vec3<i32>,
    _pad3: u32,
    index_max: vec3<i32>,
    _pad4: u32,
}

const VOLUME_SLOT_DIM: i32 = 9;
const VOLUME_SLOT_PRESENT: u32 = 0x80000000u;

// The default volume: group 0 belongs to it in every stage pipeline. A stage that samples a
// second volume declares its own four bindings (GpuVolume::layout_entries) and calls the
// `volume_*_in` functions with them.
@group(0) @binding(0) var volume_atlas: texture_3d<f32>;
@group(0) @binding(1) var volume_table: texture_3d<u32>;
@group(0) @binding(2) var volume_sampler: sampler;
@group(0) @binding(3) var<storage, read> volume_info: VolumeInfo;

// Atlas texel of the lowest corner of `cell`, or x = -1 when the cell's brick has no slot.
fn volume_locate(table: texture_3d<u32>, info: VolumeInfo, cell: vec3<i32>) -> vec3<i32> {
    let t = (cell >> vec3<u32>(3u)) - info.table_origin;
    if (any(t < vec3<i32>(0)) || any(t >= info.table_dims)) {
        return vec3<i32>(-1);
    }
    let packed = textureLoad(table, t, 0).x;
    if ((packed & VOLUME_SLOT_PRESENT) == 0u) {
        return vec3<i32>(-1);
    }
    let slot = vec3<i32>(vec3<u32>(packed, packed >> 10u, packed >> 20u) & vec3<u32>(1023u));
    return slot * VOLUME_SLOT_DIM + (cell & vec3<i32>(7));
}

// a + (b - a) * w, the form Volume::sample_index (and OpenVDB's BoxSampler) uses; mix() may
// be lowered differently and would cost the bit-level agreement with the CPU.
fn volume_lerp(a: vec4<f32>, b: vec4<f32>, w: f32) -> vec4<f32> {
    return a + (b - a) * w;
}

// Exact trilinear interpolation from the 8 corner texels, nested like the CPU sampler
// (z first, then y, then x), so the two agree to a few ulps.
fn volume_sample_index_in(atlas: texture_3d<f32>, table: texture_3d<u32>, info: VolumeInfo,
                          p: vec3<f32>) -> vec4<f32> {
    let base = floor(p);
    let w = p - base;
    let t = volume_locate(table, info, vec3<i32>(base));
    if (t.x < 0) {
        return info.background;
    }
    let c000 = textureLoad(atlas, t, 0);
    let c001 = textureLoad(atlas, t + vec3<i32>(0, 0, 1), 0);
    let c010 = textureLoad(atlas, t + vec3<i32>(0, 1, 0), 0);
    let c011 = textureLoad(atlas, t + vec3<i32>(0, 1, 1), 0);
    let c100 = textureLoad(atlas, t + vec3<i32>(1, 0, 0), 0);
    let c101 = textureLoad(atlas, t + vec3<i32>(1, 0, 1), 0);
    let c110 = textureLoad(atlas, t + vec3<i32>(1, 1, 0), 0);
    let c111 = textureLoad(atlas, t + vec3<i32>(1, 1, 1), 0);
    return volume_lerp(
        volume_lerp(volume_lerp(c000, c001, w.z), volume_lerp(c010, c011, w.z), w.y),
        volume_lerp(volume_lerp(c100, c101, w.z), volume_lerp(c110, c111, w.z), w.y),
        w.x);
}

// One hardware-filtered fetch instead of eight loads. Filtering hardware quantises the
// weights (Vulkan guarantees only 4 sub-texel bits, common hardware and lavapipe have 8),
// so the result is within about |corner range| / 256 of the exact sampler. Without
// FLOAT32_FILTERABLE the sampler cannot filter R32Float, so this falls back to the exact path.
fn volume_sample_index_filtered_in(atlas: texture_3d<f32>, table: texture_3d<u32>, samp: sampler,
                                   info: VolumeInfo, p: vec3<f32>) -> vec4<f32> {
    if (!VOLUME_FILTERABLE) {
        return volume_sample_index_in(atlas, table, info, p);
    }
    let base = floor(p);
    let t = volume_locate(table, info, vec3<i32>(base));
    if (t.x < 0) {
        return info.background;
    }
    // Texel centres sit at +0.5 in texture coordinates.
    let uvw = (vec3<f32>(t) + (p - base) + 0.5) * info.inv_atlas_dims;
    return textureSampleLevel(atlas, samp, uvw, 0.0);
}

fn volume_world_to_index_in(info: VolumeInfo, p_world_rel: vec3<f32>) -> vec3<f32> {
    return (info.world_to_index * vec4<f32>(p_world_rel, 1.0)).xyz;
}

// Shorthands on the default volume (group 0). Scalar volumes read .x, vec3 volumes .xyz.

fn volume_sample_index(p: vec3<f32>) -> f32 {
    return volume_sample_index_in(volume_atlas, volume_table, volume_info, p).x;
}

fn volume_sample_index_filtered(p: vec3<f32>) -> f32 {
    return volume_sample_index_filtered_in(volume_atlas, volume_table, volume_sampler, volume_info, p).x;
}

fn volume_sample_index3(p: vec3<f32>) -> vec3<f32> {
    return volume_sample_index_in(volume_atlas, volume_table, volume_info, p).xyz;
}

fn volume_sample_index3_filtered(p: vec3<f32>) -> vec3<f32> {
    return volume_sample_index_filtered_in(volume_atlas, volume_table, volume_sampler, volume_info, p).xyz;
}

fn volume_world_to_index(p_world_rel: vec3<f32>) -> vec3<f32> {
    return volume_world_to_index_in(volume_info, p_world_rel);
}
