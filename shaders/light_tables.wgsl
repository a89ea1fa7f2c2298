// requires: volume_lerp, LIGHT_TABLE_BRICK_LOG2, LIGHT_TABLE_SPREAD, LIGHT_TABLE_SINGLE_SPREAD, LIGHT_TABLE_ALONG_FLOOR
//
// The lights' tabled transmittance on the GPU (nimbus_tracking::GpuLightTables): the twin of
// nimbus_tracking::LightDepths::get (which lights have a table) and of
// OpticalDepthVolume::transmittance (a trilinear lookup on the light's sheared lattice).
//
// Composed after volume.wgsl (its volume_lerp) and the host-generated brick layout
// (LIGHT_TABLE_BRICK_LOG2, nimbus_volume::BRICK_LOG2, and LIGHT_TABLE_SPREAD,
// LIGHT_TABLE_SINGLE_SPREAD and LIGHT_TABLE_ALONG_FLOOR, nimbus_tracking's TABLED_SPREAD,
// SINGLE_SPREAD and ALONG_RAY_FLOOR:
// light_tables_wgsl prepends them).
// Binds group 2, whatever the number of lights:
// - light_tables: one LightTable per light of the scene, `tabled` 0 where the light has none
//   (point lights, dark suns, or every light when shadows are traced by rays);
// - light_table_index: per tabled light, a dense index over the bounding box (in bricks) of
//   its stored bricks, x-major and z fastest, each entry 1 + the brick's number in
//   light_table_nodes, 0 where no brick is stored;
// - light_table_nodes: every stored brick of every light, 512 transmittances each in
//   nimbus_volume::brick_offset order (x-major, z fastest) followed by the 512 nodes'
//   depth rates, extinction x density x node step (nimbus_tracking::TABLE_BRICK_VALUES), the bricks in
//   LightTablePlan::bricks' order light after light. optical_depth.wgsl writes them (hence
//   read_write), lookups read them.
// A node no brick stores holds 1, the CPU table's background: no medium lies toward the
// light from there.
//
// Positions are f32 world positions relative to the stage's origin (the one the density
// volume was told of by GpuVolume::set_world_origin). Lattice coordinates are f32 like the
// density's index coordinates, so lookups agree with the CPU's f64 ones to f32 rounding.

struct LightTable {
    // (world - origin) -> lattice index, rounded to f32 on the host from the f64 transform.
    world_to_lattice: mat4x4<f32>,
    // Brick coordinate (lattice index >> 3) of the index's entry 0, and the index's size.
    brick_min: vec3<i32>,
    // The index's first entry in light_table_index.
    index_first: u32,
    brick_dims: vec3<i32>,
    // 0: the light has no table; 1: transmittance is interpolated across the rays; 2: optical
    // depth is (an unsheared lattice, OpticalDepthVolume::depth_across).
    tabled: u32,
}

@group(2) @binding(0) var<storage, read> light_tables: array<LightTable>;
@group(2) @binding(1) var<storage, read> light_table_index: array<u32>;
@group(2) @binding(2) var<storage, read_write> light_table_nodes: array<f32>;

// No brick stores the node.
const LIGHT_TABLE_NO_SLOT: u32 = 0xffffffffu;
// A brick's edge less one (the local coordinate mask), and its offset steps along y and x
// (brick_offset: x-major, z fastest).
const LIGHT_TABLE_LOCAL_MASK: i32 = (1 << LIGHT_TABLE_BRICK_LOG2) - 1;
const LIGHT_TABLE_STEP_Y: u32 = 1u << LIGHT_TABLE_BRICK_LOG2;
const LIGHT_TABLE_STEP_X: u32 = 1u << (2u * LIGHT_TABLE_BRICK_LOG2);
const LIGHT_TABLE_BRICK_NODES: u32 = 1u << (3u * LIGHT_TABLE_BRICK_LOG2);
// A stored brick's values: its nodes' transmittances, then their densities.
const LIGHT_TABLE_BRICK_VALUES: u32 = 2u * LIGHT_TABLE_BRICK_NODES;

// Where lattice node `node` of table `t` sits in light_table_nodes, or LIGHT_TABLE_NO_SLOT.
fn light_table_slot(t: LightTable, node: vec3<i32>) -> u32 {
    let b = (node >> vec3<u32>(LIGHT_TABLE_BRICK_LOG2)) - t.brick_min;
    if (any(b < vec3<i32>(0)) || any(b >= t.brick_dims)) {
        return LIGHT_TABLE_NO_SLOT;
    }
    let entry = light_table_index[t.index_first + u32((b.x * t.brick_dims.y + b.y) * t.brick_dims.z + b.z)];
    if (entry == 0u) {
        return LIGHT_TABLE_NO_SLOT;
    }
    let l = vec3<u32>(node & vec3<i32>(LIGHT_TABLE_LOCAL_MASK));
    return (entry - 1u) * LIGHT_TABLE_BRICK_VALUES + l.x * LIGHT_TABLE_STEP_X + l.y * LIGHT_TABLE_STEP_Y + l.z;
}

// A node's transmittance (x) and depth rate (y); unstored: 1 and 0, the CPU's backgrounds.
fn light_table_node(t: LightTable, node: vec3<i32>) -> vec2<f32> {
    let slot = light_table_slot(t, node);
    if (slot == LIGHT_TABLE_NO_SLOT) {
        return vec2<f32>(1.0, 0.0);
    }
    return vec2<f32>(light_table_nodes[slot], light_table_nodes[slot + LIGHT_TABLE_BRICK_NODES]);
}

// nimbus_tracking::along_ray: the transmittance at fraction u from a ray's node k (t0, depth
// rate d0) to node k + 1 (t1, d1), their optical depth spread as the integral of the linearly
// interpolated density, blended into the plain exponential below ALONG_RAY_FLOOR.
fn light_table_along_ray(t0: f32, t1: f32, d0: f32, d1: f32, u: f32) -> f32 {
    let tiny = 1.17549435e-38;
    let depth = max(log(max(t0, tiny) / max(t1, tiny)), 0.0);
    let shape = (d0 * u + 0.5 * (d1 - d0) * u * u + LIGHT_TABLE_ALONG_FLOOR * u) / (0.5 * (d0 + d1) + LIGHT_TABLE_ALONG_FLOOR);
    return t0 * exp(-depth * shape);
}

// Transmittance toward light `light` from x as its table resolves it
// (OpticalDepthVolume::lookup): x, along each of the four rays around it by
// light_table_along_ray, then bilinear across them in Volume::sample_index's corner order (in
// optical depth where `tabled` is 2, else in transmittance); y, the weight of the caller's own
// shadow ray beside it, 1 where the light has no table, rising across LIGHT_TABLE_SPREAD as
// the nodes stray from the interpolation (their weighted mean absolute deviation from it) over
// a shadow edge sharper than the lattice.
fn light_table_lookup(light: u32, x: vec3<f32>) -> vec2<f32> {
    return light_table_lookup_within(light, x, LIGHT_TABLE_SPREAD);
}

// light_table_lookup, the shadow ray blended in across `spread` instead
// (OpticalDepthVolume::lookup_within; LIGHT_TABLE_SINGLE_SPREAD for single scattering).
fn light_table_lookup_within(light: u32, x: vec3<f32>, spread: vec2<f32>) -> vec2<f32> {
    let t = light_tables[light];
    if (t.tabled == 0u) {
        return vec2<f32>(1.0, 1.0);
    }
    let p = (t.world_to_lattice * vec4<f32>(x, 1.0)).xyz;
    let base = floor(p);
    let w = p - base;
    let c = vec3<i32>(base);
    var v: array<f32, 8>;
    var r: array<f32, 8>;
    let local = c & vec3<i32>(LIGHT_TABLE_LOCAL_MASK);
    if (all(local < vec3<i32>(LIGHT_TABLE_LOCAL_MASK))) {
        // The whole cell lies in one brick: one index lookup, eight loads (Volume::corners).
        let s = light_table_slot(t, c);
        if (s == LIGHT_TABLE_NO_SLOT) {
            return vec2<f32>(1.0, 0.0);
        }
        let sy = LIGHT_TABLE_STEP_Y;
        let sx = LIGHT_TABLE_STEP_X;
        v = array<f32, 8>(light_table_nodes[s], light_table_nodes[s + 1u], light_table_nodes[s + sy], light_table_nodes[s + sy + 1u],
                          light_table_nodes[s + sx], light_table_nodes[s + sx + 1u], light_table_nodes[s + sx + sy], light_table_nodes[s + sx + sy + 1u]);
        let d = s + LIGHT_TABLE_BRICK_NODES;
        r = array<f32, 8>(light_table_nodes[d], light_table_nodes[d + 1u], light_table_nodes[d + sy], light_table_nodes[d + sy + 1u],
                          light_table_nodes[d + sx], light_table_nodes[d + sx + 1u], light_table_nodes[d + sx + sy], light_table_nodes[d + sx + sy + 1u]);
    } else {
        for (var n = 0; n < 8; n = n + 1) {
            let node = light_table_node(t, c + vec3<i32>((n >> 2u) & 1, (n >> 1u) & 1, n & 1));
            v[n] = node.x;
            r[n] = node.y;
        }
    }
    // Along the rays (corner bit 0, the lattice z), then bilinear across them.
    let a00 = light_table_along_ray(v[0], v[1], r[0], r[1], w.z);
    let a01 = light_table_along_ray(v[2], v[3], r[2], r[3], w.z);
    let a10 = light_table_along_ray(v[4], v[5], r[4], r[5], w.z);
    let a11 = light_table_along_ray(v[6], v[7], r[6], r[7], w.z);
    var l: vec4<f32>;
    if (t.tabled == 2u) {
        let tiny = 1.17549435e-38;
        let depth = volume_lerp(volume_lerp(vec4<f32>(-log(max(a00, tiny))), vec4<f32>(-log(max(a01, tiny))), w.y),
                                volume_lerp(vec4<f32>(-log(max(a10, tiny))), vec4<f32>(-log(max(a11, tiny))), w.y), w.x);
        l = exp(-depth);
    } else {
        l = volume_lerp(volume_lerp(vec4<f32>(a00), vec4<f32>(a01), w.y), volume_lerp(vec4<f32>(a10), vec4<f32>(a11), w.y), w.x);
    }
    var deviation = 0.0;
    for (var n = 0; n < 8; n = n + 1) {
        let f = select(vec3<f32>(1.0) - w, w, vec3<bool>(((n >> 2u) & 1) == 1, ((n >> 1u) & 1) == 1, (n & 1) == 1));
        deviation = deviation + f.x * f.y * f.z * abs(v[n] - l.x);
    }
    let ray_weight = clamp((deviation - spread.x) / (spread.y - spread.x), 0.0, 1.0);
    return vec2<f32>(l.x, ray_weight);
}
