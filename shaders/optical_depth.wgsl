// requires: light_table_nodes, loop_guard_check
//
// A sun's light table built on the GPU (nimbus_tracking::GpuLightTables::build): one
// invocation per ray of its lattice, the twin of nimbus_tracking::ray_optical_depths over
// the same LightTablePlan (the host decides the lattice, which bricks are stored and their
// order; only this integration is the GPU's).
//
// Composed as volume.wgsl (the density is the default volume at group 0, read by its atlas's
// exact corner loads) + optics.wgsl (tracking.wgsl's Rng) + tracking.wgsl (the majorant DDA
// that skips empty space) + light_tables.wgsl (group 2: where each node is stored, and the
// nodes this writes) + nimbus_gpu::LoopGuard::wgsl (binding 3 of group 1) + this file. Each
// dispatch takes rays first_ray .. first_ray + ray_count of one light: ray r is ray
// (r / 8 % 8, r % 8) of brick column r / 64 (for 8^3 bricks), so a workgroup is one column,
// as one CPU task is. Every ray ends with loop_guard_check(): llvmpipe (lavapipe) silently ends loops
// past 65535 iterations per SIMD group, which a ray through thousands of cells could reach.
//
// Everything is f32 (the CPU integrates in f64): the nodes agree to f32 rounding of the
// optical depth, summed over the cells a ray crosses.

struct LightRays {
    // Lattice index -> density index (linear, the origins coincide): node (i, j, k) sits at
    // i * across_i + j * across_j + k * along.
    across_i: vec3<f32>,
    // World distance between nodes along a ray.
    step: f32,
    across_j: vec3<f32>,
    extinction: f32,
    along: vec3<f32>,
    // Rays stop integrating past this optical depth (OpticalDepthVolume::opaque_depth).
    opaque_depth: f32,
    // The light's direction in density index space, per unit of world distance.
    dir: vec3<f32>,
    // Which entry of light_tables this light's nodes go to.
    light: u32,
    grid: MajorantGridInfo,
    first_ray: u32,
    ray_count: u32,
    _pad0: u32,
    _pad1: u32,
}

// A brick column of the plan: the lattice (x, y) of its bricks' origin, the lattice z of the
// first node its rays are integrated from and how many nodes (LightTablePlan::column_nodes).
struct LightColumn {
    x: i32,
    y: i32,
    k0: i32,
    nodes: u32,
}

@group(1) @binding(0) var<storage, read> rays: LightRays;
@group(1) @binding(1) var<storage, read> majorant_values: array<f32>;
@group(1) @binding(2) var<storage, read> columns: array<LightColumn>;

fn majorant_fetch(index: u32) -> f32 {
    return majorant_values[index];
}

// Volume::corners of the density cell whose lowest corner is `cell` (order 000, 001, ...,
// 111 in x, y, z), negative density clamped to 0 as every tracker here does.
fn light_ray_corners(cell: vec3<i32>) -> array<f32, 8> {
    let t = volume_locate(volume_table, volume_info, cell);
    if (t.x < 0) {
        let b = max(volume_info.background.x, 0.0);
        return array<f32, 8>(b, b, b, b, b, b, b, b);
    }
    var c: array<f32, 8>;
    for (var n = 0; n < 8; n = n + 1) {
        c[n] = max(textureLoad(volume_atlas, t + vec3<i32>((n >> 2u) & 1, (n >> 1u) & 1, n & 1), 0).x, 0.0);
    }
    return c;
}

// cubic_along: the trilinear interpolant of the cell's corners along u0 + s * du (cell-local
// coordinates) as a cubic in s, coefficients of s^0..s^3.
fn light_ray_cubic(c: array<f32, 8>, u0: vec3<f32>, du: vec3<f32>) -> vec4<f32> {
    let k0 = c[0];
    let kx = c[4] - c[0];
    let ky = c[2] - c[0];
    let kz = c[1] - c[0];
    let kxy = c[6] - c[4] - c[2] + c[0];
    let kxz = c[5] - c[4] - c[1] + c[0];
    let kyz = c[3] - c[2] - c[1] + c[0];
    let kxyz = c[7] - c[6] - c[5] - c[3] + c[4] + c[2] + c[1] - c[0];
    // Products of two linear factors: p0 + p1 s + p2 s^2.
    let xy = vec3<f32>(u0.x * u0.y, u0.x * du.y + du.x * u0.y, du.x * du.y);
    let xz = vec3<f32>(u0.x * u0.z, u0.x * du.z + du.x * u0.z, du.x * du.z);
    let yz = vec3<f32>(u0.y * u0.z, u0.y * du.z + du.y * u0.z, du.y * du.z);
    let xyz = vec4<f32>(xy[0] * u0.z, xy[0] * du.z + xy[1] * u0.z, xy[1] * du.z + xy[2] * u0.z, xy[2] * du.z);
    return vec4<f32>(
        k0 + kx * u0.x + ky * u0.y + kz * u0.z + kxy * xy[0] + kxz * xz[0] + kyz * yz[0] + kxyz * xyz[0],
        kx * du.x + ky * du.y + kz * du.z + kxy * xy[1] + kxz * xz[1] + kyz * yz[1] + kxyz * xyz[1],
        kxy * xy[2] + kxz * xz[2] + kyz * yz[2] + kxyz * xyz[2],
        kxyz * xyz[3]);
}

// integral_0^s of the cubic.
fn light_ray_integral(a: vec4<f32>, s: f32) -> f32 {
    return s * (a[0] + s * (a[1] / 2.0 + s * (a[2] / 3.0 + s * a[3] / 4.0)));
}

// Writes node k of the ray whose first node is lattice node `first`, optical depth `tau`,
// as the transmittance the table holds, and the node's depth rate (extinction x density x
// step) beside it, where a stored brick holds it.
fn light_ray_store(t: LightTable, first: vec3<i32>, k: u32, tau: f32) {
    let node = first + vec3<i32>(0, 0, i32(k));
    let slot = light_table_slot(t, node);
    if (slot != LIGHT_TABLE_NO_SLOT) {
        light_table_nodes[slot] = exp(-tau);
        let p = rays.across_i * f32(node.x) + rays.across_j * f32(node.y) + rays.along * f32(node.z);
        light_table_nodes[slot + LIGHT_TABLE_BRICK_NODES] = rays.extinction * rays.step * max(volume_sample_index(p), 0.0);
    }
}

// ray_optical_depths from lattice node `first` over `count` nodes: the optical depth at each
// node, integrated from the first (where the ray has not yet met medium) cell by cell in
// closed form, the nodes past opaque_depth keeping the depth reached.
fn integrate_light_ray(first: vec3<i32>, count: u32) {
    let t_table = light_tables[rays.light];
    let origin = rays.across_i * f32(first.x) + rays.across_j * f32(first.y) + rays.along * f32(first.z);
    let dir = rays.dir;
    let step = rays.step;
    let ext = rays.extinction;
    let t_end = step * (f32(count) - 1.0);
    var tau = 0.0;
    var k = 0u;
    var opaque = false;
    var walk = majorant_walk_new(rays.grid, origin, dir, 0.0, t_end);
    loop {
        if (opaque) {
            break;
        }
        let seg = majorant_walk_next(&walk, rays.grid);
        if (!seg.valid) {
            break;
        }
        if (!track_segment_has_medium(seg, ext)) {
            continue;
        }
        // Nodes before this segment (in empty space) hold the depth so far.
        while (k < count && f32(k) * step <= seg.t_start) {
            light_ray_store(t_table, first, k, tau);
            k = k + 1u;
        }
        var next = vec3<f32>(TRACK_FAR);
        var inc = vec3<f32>(TRACK_FAR);
        for (var axis = 0; axis < 3; axis = axis + 1) {
            let d = dir[axis];
            if (d != 0.0) {
                let c = origin[axis] + seg.t_start * d;
                var plane = ceil(c) - 1.0;
                if (d > 0.0) {
                    plane = floor(c) + 1.0;
                }
                next[axis] = (plane - origin[axis]) / d;
                inc[axis] = 1.0 / abs(d);
            }
        }
        var t = seg.t_start;
        while (t < seg.t_end) {
            let cross = min(min(min(next.x, next.y), next.z), seg.t_end);
            if (cross > t) {
                let cell = floor(origin + dir * (0.5 * (t + cross)));
                let cubic = light_ray_cubic(light_ray_corners(vec3<i32>(cell)), origin + dir * t - cell, dir);
                while (k < count && f32(k) * step <= cross) {
                    light_ray_store(t_table, first, k, tau + ext * light_ray_integral(cubic, f32(k) * step - t));
                    k = k + 1u;
                }
                tau = tau + ext * light_ray_integral(cubic, cross - t);
                t = cross;
                if (tau > rays.opaque_depth) {
                    opaque = true;
                    break;
                }
            }
            for (var axis = 0; axis < 3; axis = axis + 1) {
                while (next[axis] <= t) {
                    next[axis] = next[axis] + inc[axis];
                }
            }
        }
    }
    while (k < count) {
        light_ray_store(t_table, first, k, tau);
        k = k + 1u;
    }
}

// The rays of a brick column: a brick's edge of them on each lattice axis across the light.
const LIGHT_COLUMN_EDGE: u32 = 1u << LIGHT_TABLE_BRICK_LOG2;
const LIGHT_COLUMN_RAYS: u32 = LIGHT_COLUMN_EDGE * LIGHT_COLUMN_EDGE;

@compute @workgroup_size(LIGHT_COLUMN_RAYS)
fn integrate_light_rays(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                        @builtin(local_invocation_index) local: u32) {
    let i = dispatch_linear_index(wg, nwg, local, LIGHT_COLUMN_RAYS);
    if (i >= rays.ray_count) {
        return;
    }
    let r = rays.first_ray + i;
    let column = columns[r / LIGHT_COLUMN_RAYS];
    let across = vec2<u32>(r / LIGHT_COLUMN_EDGE % LIGHT_COLUMN_EDGE, r % LIGHT_COLUMN_EDGE);
    integrate_light_ray(vec3<i32>(column.x + i32(across.x), column.y + i32(across.y), column.k0), column.nodes);
    loop_guard_check();
}
