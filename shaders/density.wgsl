// requires: dispatch_linear_index
//
// SPH density estimation on the GPU (nimbus-density, design.md section 8): one invocation per
// voxel of the proposed bricks and per pass, each a gather over the particle cells its support
// sphere overlaps. The host (crates/density/src/gpu.rs) sorts the particles into cells once
// (counting sort) and runs, per method:
//   usl   density
//   asl2  predict, density
//   asl3  predict, correct, density
//   knn   knn, density
//   ici   ladder, (the host's rule over the whole grid, ici.rs), density
// With conserve-mass the host runs the passes before density over every chunk first, keeps
// the lengths, runs `mass` (one invocation per particle: its kernel sum S over the grid), and
// then density per chunk with the masses m / S.
// Attributes (issue #20), after the density: `attributes` per chunk of the bricks with density
// and channel group, the kernel-weighted sums the host normalises (crates/density/src/attributes.rs).
// The per-point functions mirror crates/density/src/kernel.rs line by line, and distances are
// formed as on the CPU ((voxel index as f32) - p, then (dx^2 + dy^2) + dz^2), so counts agree
// with the CPU and the brute-force reference, and densities to summation order. Densities
// leave unnormalised (sum m * m4_shape(r / h)): the host applies 1 / (pi h^3) in f64, as it
// does for the CPU's sums. Standalone: no other WGSL module is needed.

const WORKGROUP_SIZE: u32 = 64u;
const KAPPA: f32 = 2.0;
const BRICK_VOXELS: u32 = 512u;
// knn keeps the KNN_MAX nearest in a private sorted list; a larger N* bisects on the f32 bit
// pattern of the squared distance with counting passes instead (exact, slower). Twin of
// KNN_MAX in gpu.rs.
const KNN_MAX: u32 = 64u;
// Widening of a cell range so rounding in (x - r) never drops a particle's cell; the exact
// per-particle test decides.
const CELL_SLACK: f32 = 1e-3;

const METHOD_USL: u32 = 0u;
const METHOD_ASL2: u32 = 1u;
const METHOD_ASL3: u32 = 2u;
const METHOD_KNN: u32 = 3u;
const METHOD_ICI: u32 = 4u;
// Twin of kernel.rs ICI_MAX_RUNGS.
const ICI_MAX_RUNGS: u32 = 8u;

struct DensityUniforms {
    cell_origin: vec3<f32>,
    cell_edge: f32,
    cell_dims: vec3<i32>,
    n_star: f32,
    grid_dims: vec3<i32>,
    h0: f32,
    h_min: f32,
    relax: f32,
    // N* as an integer (the knn rank).
    k: u32,
    // Voxels in this chunk: bricks first_brick.. times 512.
    voxel_count: u32,
    first_brick: u32,
    method: u32,
    // Particles (the mass pass's invocations).
    particle_count: u32,
    // The mass pass's slab: z planes plane_first.. of each particle's support box, at most
    // plane_count of them (the host splits the box on adapters that cap loop iterations).
    plane_first: u32,
    plane_count: u32,
    // The attribute pass: vec4s of channel values per particle, and the two of them (eight
    // channels) this dispatch sums.
    attribute_stride: u32,
    attribute_group: u32,
    // ici: the ladder's rungs and their lengths (index units).
    ici_rungs: u32,
    ici_h: array<vec4<f32>, 2>,
}

@group(0) @binding(0) var<storage, read> u: DensityUniforms;
// Index-space position in xyz, mass in w; sorted by cell.
@group(0) @binding(1) var<storage, read> particles: array<vec4<f32>>;
// Cell c's particles are cell_start[c] .. cell_start[c + 1].
@group(0) @binding(2) var<storage, read> cell_start: array<u32>;
// Brick origins (xyz; w unused), in proposal order.
@group(0) @binding(3) var<storage, read> bricks: array<vec4<i32>>;
// Per voxel of the chunk: the count within kappa*h0 (0 = nothing to estimate), the smoothing
// length (index units), the unnormalised density and the particles used.
@group(0) @binding(4) var<storage, read_write> n0_out: array<u32>;
@group(0) @binding(5) var<storage, read_write> h_out: array<f32>;
@group(0) @binding(6) var<storage, read_write> rho_out: array<f32>;
@group(0) @binding(7) var<storage, read_write> used_out: array<u32>;

// The mass pass's own group (its pipeline binds group 0 with the uniforms and particles
// only, so no pipeline exceeds eight storage buffers):
// Final smoothing length (index units) per voxel of every proposed brick, in proposal order;
// 0 where no pass evaluates the voxel.
@group(1) @binding(0) var<storage, read> lengths: array<f32>;
// Per brick of the grid (x fastest, then y, z): its proposal index, or 0xffffffff.
@group(1) @binding(1) var<storage, read> brick_slot: array<u32>;
// Per particle: S = sum over grid points x of m4_shape(|x - p| / h(x)) / (pi h(x)^3).
@group(1) @binding(2) var<storage, read_write> kernel_sum: array<f32>;

// The attribute pass's own bindings in group 1 (its pipeline binds neither the mass pass's
// nor group 0's per-voxel outputs):
// Per particle (sorted as `particles`), attribute_stride vec4s of channel values (the weight
// V_q and V_q times each component, host attributes.rs channel_values).
@group(1) @binding(3) var<storage, read> attribute_values: array<vec4<f32>>;
// Per voxel of the chunk: its final smoothing length, 0 where the density is 0 (not reached).
@group(1) @binding(4) var<storage, read> attribute_lengths: array<f32>;
// Per voxel of the chunk, two vec4s: the sums of this group's eight channels.
@group(1) @binding(5) var<storage, read_write> attribute_sums: array<vec4<f32>>;

const PI: f32 = 3.14159265358979;

// ---- kernel.rs twins ----

fn m4_shape(q: f32) -> f32 {
    let a = max(2.0 - q, 0.0);
    let b = max(1.0 - q, 0.0);
    return 0.25 * a * a * a - b * b * b;
}

fn predict_h1(n0: u32, n_star: f32, h0: f32) -> f32 {
    if (n0 == 0u) {
        return h0;
    }
    return min(h0 * pow(n_star / f32(n0), 1.0 / 3.0), h0);
}

fn correct_h(n0: u32, n1: u32, n_star: f32, h0: f32, h1: f32, relax: f32) -> f32 {
    let n0f = f32(n0);
    let n1f = f32(n1);
    if (n1f < n_star) {
        if (n0 == n1) {
            return h0;
        }
        let h0c = h0 * h0 * h0;
        let h1c = h1 * h1 * h1;
        return pow((n_star - n1f) * (h0c - h1c) / (n0f - n1f) + h1c, 1.0 / 3.0);
    } else if (n1f > n_star) {
        let alpha = 1.0 - relax * n1f / n0f;
        return alpha * h1 * pow(n_star / n1f, 1.0 / 3.0);
    }
    return h1;
}

fn clamp_h(h: f32, h_min: f32, h0: f32) -> f32 {
    return min(max(h, h_min), h0);
}

// ---- the gather ----

fn cell_of(p: vec3<f32>) -> vec3<i32> {
    return clamp(vec3<i32>(floor((p - u.cell_origin) / u.cell_edge)), vec3<i32>(0), u.cell_dims - 1);
}

fn cell_id(c: vec3<i32>) -> u32 {
    return u32((c.z * u.cell_dims.y + c.y) * u.cell_dims.x + c.x);
}

const GATHER_COUNT: u32 = 0u;
const GATHER_DENSITY: u32 = 1u;
const GATHER_KNN: u32 = 2u;
const GATHER_LADDER: u32 = 3u;

// Accumulators of gather(): WGSL has no closures, so the one cell walk switches on a mode and
// leaves its results here.
var<private> acc_count: u32;
var<private> acc_rho: f32;
var<private> knn_best: array<f32, KNN_MAX>;
var<private> acc_channels: array<vec4<f32>, 2>;

// Squared distance from voxel point x to particle p, rounded as the CPU rounds it.
fn dist2(x: vec3<f32>, p: vec3<f32>) -> f32 {
    let d = x - p;
    return (d.x * d.x + d.y * d.y) + d.z * d.z;
}

// The block of cells (low, high corner) the sphere of radius sqrt(limit2) about x overlaps.
fn cells_within(x: vec3<f32>, limit2: f32) -> array<vec3<i32>, 2> {
    let reach = sqrt(limit2) + CELL_SLACK;
    return array<vec3<i32>, 2>(cell_of(x - vec3<f32>(reach)), cell_of(x + vec3<f32>(reach)));
}

// The particles (first, end) of the block's row of cells at (cy, cz): contiguous, since cell
// ids run x fastest.
fn row_particles(lo: vec3<i32>, hi: vec3<i32>, cy: i32, cz: i32) -> vec2<u32> {
    return vec2<u32>(cell_start[cell_id(vec3<i32>(lo.x, cy, cz))], cell_start[cell_id(vec3<i32>(hi.x, cy, cz)) + 1u]);
}

// Visits the particles within radius sqrt(limit2) of x (r2 < limit2):
//   GATHER_COUNT    acc_count += 1 where also r2 <= le (le = limit2 counts all)
//   GATHER_DENSITY  acc_rho += m * m4_shape(sqrt(r2) * inv_h), acc_count += 1
//   GATHER_KNN      acc_count += 1 and the k smallest r2 kept sorted in knn_best
//   GATHER_LADDER   ici's ladder_sums and ladder_squares per rung, acc_count += 1 (limit2 the
//                   top rung's support)
fn gather(x: vec3<f32>, limit2: f32, mode: u32, inv_h: f32, le: f32) {
    let cells = cells_within(x, limit2);
    let lo = cells[0];
    let hi = cells[1];
    let k = min(u.k, KNN_MAX);
    for (var cz = lo.z; cz <= hi.z; cz++) {
        for (var cy = lo.y; cy <= hi.y; cy++) {
            let row = row_particles(lo, hi, cy, cz);
            for (var i = row.x; i < row.y; i++) {
                let q = particles[i];
                let r2 = dist2(x, q.xyz);
                if (r2 >= limit2) {
                    continue;
                }
                if (mode == GATHER_COUNT) {
                    acc_count += u32(r2 <= le);
                } else if (mode == GATHER_DENSITY) {
                    acc_rho += q.w * m4_shape(sqrt(r2) * inv_h);
                    acc_count += 1u;
                } else if (mode == GATHER_LADDER) {
                    acc_count += 1u;
                    let r = sqrt(r2);
                    // Longest rung first: a particle outside rung k is outside every shorter one.
                    for (var k = u.ici_rungs; k > 0u; k--) {
                        let h = ici_rung_h(k - 1u);
                        let rad = KAPPA * h;
                        if (r2 >= rad * rad) {
                            break;
                        }
                        let w = q.w * m4_shape(r * (1.0 / h));
                        ladder_sums[k - 1u] += w;
                        ladder_squares[k - 1u] += w * w;
                    }
                } else {
                    // Insertion into the sorted list of the k smallest so far.
                    let n = acc_count;
                    acc_count += 1u;
                    if (n >= k && r2 >= knn_best[k - 1u]) {
                        continue;
                    }
                    var j = min(n, k - 1u);
                    while (j > 0u && knn_best[j - 1u] > r2) {
                        knn_best[j] = knn_best[j - 1u];
                        j -= 1u;
                    }
                    knn_best[j] = r2;
                }
            }
        }
    }
}

// The attribute pass's walk over the same cells (a function of its own: a mode of gather()
// would make every pass's pipeline bind the attribute buffers): acc_channels +=
// m4_shape(r / h) times the particle's values of channel group attribute_group, two vec4s
// and no inner loop, since a software adapter's loop cap counts nested iterations.
fn gather_attributes(x: vec3<f32>, limit2: f32, inv_h: f32) {
    let cells = cells_within(x, limit2);
    let lo = cells[0];
    let hi = cells[1];
    for (var cz = lo.z; cz <= hi.z; cz++) {
        for (var cy = lo.y; cy <= hi.y; cy++) {
            let row = row_particles(lo, hi, cy, cz);
            for (var i = row.x; i < row.y; i++) {
                let r2 = dist2(x, particles[i].xyz);
                if (r2 >= limit2) {
                    continue;
                }
                let w = m4_shape(sqrt(r2) * inv_h);
                let at = i * u.attribute_stride + 2u * u.attribute_group;
                acc_channels[0] += w * attribute_values[at];
                acc_channels[1] += w * attribute_values[at + 1u];
            }
        }
    }
}

// ici's ladder over the same cells: per rung k, the sum of m m4_shape(r / h_k) and of its
// square over the particles within kappa*h_k (cpu.rs splat_ladder's terms); acc_count is the
// count within the top rung.
var<private> ladder_sums: array<f32, ICI_MAX_RUNGS>;
var<private> ladder_squares: array<f32, ICI_MAX_RUNGS>;

fn ici_rung_h(k: u32) -> f32 {
    return u.ici_h[k / 4u][k % 4u];
}

fn gather_ladder(x: vec3<f32>) {
    let rungs = u.ici_rungs;
    for (var k = 0u; k < ICI_MAX_RUNGS; k++) {
        ladder_sums[k] = 0.0;
        ladder_squares[k] = 0.0;
    }
    acc_count = 0u;
    let r_top = KAPPA * ici_rung_h(rungs - 1u);
    gather(x, r_top * r_top, GATHER_LADDER, 0.0, 0.0);
}

fn count_within(x: vec3<f32>, r: f32) -> u32 {
    acc_count = 0u;
    let r2 = r * r;
    gather(x, r2, GATHER_COUNT, 0.0, r2);
    return acc_count;
}

// The voxel of invocation i: its global index point, or w = 0 when it lies outside the grid
// (an edge brick) or the chunk.
fn voxel_point(i: u32) -> vec4<i32> {
    if (i >= u.voxel_count) {
        return vec4<i32>(0);
    }
    let v = i % BRICK_VOXELS;
    let local = vec3<i32>(i32(v >> 6u), i32((v >> 3u) & 7u), i32(v & 7u));
    let ijk = bricks[u.first_brick + i / BRICK_VOXELS].xyz + local;
    return vec4<i32>(ijk, i32(all(ijk < u.grid_dims)));
}

// asl2 / asl3 pass 1: N0 within kappa*h0 and the predicted h1 (final for asl2).
@compute @workgroup_size(WORKGROUP_SIZE)
fn predict(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let i = dispatch_linear_index(wid, nwg, lid, WORKGROUP_SIZE);
    if (i >= u.voxel_count) {
        return;
    }
    let x = voxel_point(i);
    var n0 = 0u;
    if (x.w != 0) {
        n0 = count_within(vec3<f32>(x.xyz), KAPPA * u.h0);
    }
    var h = predict_h1(n0, u.n_star, u.h0);
    if (u.method == METHOD_ASL2) {
        h = clamp_h(h, u.h_min, u.h0);
    }
    n0_out[i] = n0;
    h_out[i] = h;
}

// asl3 pass 2: N1 within kappa*h1, then the corrector and the clamp.
@compute @workgroup_size(WORKGROUP_SIZE)
fn correct(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let i = dispatch_linear_index(wid, nwg, lid, WORKGROUP_SIZE);
    if (i >= u.voxel_count) {
        return;
    }
    let n0 = n0_out[i];
    let h1 = h_out[i];
    var n1 = 0u;
    if (n0 > 0u) {
        n1 = count_within(vec3<f32>(voxel_point(i).xyz), KAPPA * h1);
    }
    h_out[i] = clamp_h(correct_h(n0, n1, u.n_star, u.h0, h1, u.relax), u.h_min, u.h0);
}

// knn: the distance to the N*-th nearest within kappa*h0, / kappa (h0 when fewer), clamped.
@compute @workgroup_size(WORKGROUP_SIZE)
fn knn(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
       @builtin(local_invocation_index) lid: u32) {
    let i = dispatch_linear_index(wid, nwg, lid, WORKGROUP_SIZE);
    if (i >= u.voxel_count) {
        return;
    }
    let x4 = voxel_point(i);
    let x = vec3<f32>(x4.xyz);
    let r0 = KAPPA * u.h0;
    let limit2 = r0 * r0;
    acc_count = 0u;
    var kth = limit2;
    if (x4.w != 0) {
        if (u.k <= KNN_MAX) {
            gather(x, limit2, GATHER_KNN, 0.0, 0.0);
            if (acc_count >= u.k) {
                kth = knn_best[u.k - 1u];
            }
        } else {
            acc_count = count_within(x, r0);
            if (acc_count >= u.k) {
                // The smallest t (as ordered f32 bits, r2 >= 0) with #{r2 <= t} >= k.
                let total = acc_count;
                var lo = 0u;
                var hi = bitcast<u32>(limit2);
                while (lo < hi) {
                    let mid = lo + (hi - lo) / 2u;
                    acc_count = 0u;
                    gather(x, limit2, GATHER_COUNT, 0.0, bitcast<f32>(mid));
                    if (acc_count >= u.k) {
                        hi = mid;
                    } else {
                        lo = mid + 1u;
                    }
                }
                kth = bitcast<f32>(lo);
                acc_count = total;
            }
        }
    }
    n0_out[i] = acc_count;
    var h = u.h0;
    if (acc_count >= u.k) {
        h = clamp_h(sqrt(kth) / KAPPA, u.h_min, u.h0);
    }
    h_out[i] = h;
}

// ici pass 1: the ladder at the voxel, written to rho_out (sized for it on this method):
// ICI_MAX_RUNGS sums, then as many sums of squares, per voxel; n0_out is whether the voxel is
// reached (a particle within the top rung). The host's rule over the whole grid (ici.rs)
// turns them into lengths for the density pass.
@compute @workgroup_size(WORKGROUP_SIZE)
fn ladder(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
          @builtin(local_invocation_index) lid: u32) {
    let i = dispatch_linear_index(wid, nwg, lid, WORKGROUP_SIZE);
    if (i >= u.voxel_count) {
        return;
    }
    let x = voxel_point(i);
    // Private variables start at zero: a voxel outside the grid writes zero sums.
    var reached = false;
    if (x.w != 0) {
        gather_ladder(vec3<f32>(x.xyz));
        reached = acc_count > 0u;
    }
    for (var k = 0u; k < ICI_MAX_RUNGS; k++) {
        rho_out[i * 2u * ICI_MAX_RUNGS + k] = ladder_sums[k];
        rho_out[i * 2u * ICI_MAX_RUNGS + ICI_MAX_RUNGS + k] = ladder_squares[k];
    }
    n0_out[i] = select(0u, 1u, reached);
}

// Every method's last pass: the density with each voxel's h (h0 for usl).
@compute @workgroup_size(WORKGROUP_SIZE)
fn density(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let i = dispatch_linear_index(wid, nwg, lid, WORKGROUP_SIZE);
    if (i >= u.voxel_count) {
        return;
    }
    let x = voxel_point(i);
    var h = u.h0;
    var reached = x.w != 0;
    if (u.method != METHOD_USL) {
        h = h_out[i];
        reached = reached && n0_out[i] > 0u;
    }
    acc_count = 0u;
    acc_rho = 0.0;
    if (reached) {
        let r = KAPPA * h;
        gather(vec3<f32>(x.xyz), r * r, GATHER_DENSITY, 1.0 / h, 0.0);
    }
    h_out[i] = h;
    rho_out[i] = acc_rho;
    used_out[i] = acc_count;
}

// conserve-mass: particle i's kernel sum over the grid with the final lengths, the terms the
// density pass will give it (without its mass; host crate: cpu.rs splat_weights, the same
// sum splatted per brick). A gather over the grid points of the particle's support box, since
// the per-voxel passes cannot scatter into a particle's sum without float atomics.
@compute @workgroup_size(WORKGROUP_SIZE)
fn mass(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let i = dispatch_linear_index(wid, nwg, lid, WORKGROUP_SIZE);
    if (i >= u.particle_count) {
        return;
    }
    let p = particles[i].xyz;
    let r0 = KAPPA * u.h0;
    let lo = max(vec3<i32>(ceil(p - vec3<f32>(r0))), vec3<i32>(0));
    let hi = min(vec3<i32>(floor(p + vec3<f32>(r0))), u.grid_dims - 1);
    let brick_dims = (u.grid_dims + 7) / 8;
    // A later slab adds to the sum so far (one invocation per particle per dispatch, so no
    // two write it at once).
    var sum = 0.0;
    if (u.plane_first > 0u) {
        sum = kernel_sum[i];
    }
    let z_lo = lo.z + i32(u.plane_first);
    let z_hi = min(hi.z, z_lo + i32(u.plane_count) - 1);
    // Summed by row, then plane, then slab: a support ~60 points across has ~10^5 terms,
    // and one running f32 sum drifts ~1e-4 from the CPU's (which sums per brick in lanes,
    // then in f64).
    for (var z = z_lo; z <= z_hi; z++) {
        var plane = 0.0;
        for (var y = lo.y; y <= hi.y; y++) {
            var row = 0.0;
            for (var x = lo.x; x <= hi.x; x++) {
                let ijk = vec3<i32>(x, y, z);
                let b = ijk / 8;
                let slot = brick_slot[(b.z * brick_dims.y + b.y) * brick_dims.x + b.x];
                if (slot == 0xffffffffu) {
                    continue;
                }
                let l = ijk % 8;
                let h = lengths[slot * BRICK_VOXELS + u32((l.x << 6u) | (l.y << 3u) | l.z)];
                let r = KAPPA * h;
                let r2 = dist2(vec3<f32>(ijk), p);
                if (h > 0.0 && r2 < r * r) {
                    row += m4_shape(sqrt(r2) * (1.0 / h)) / (PI * h * h * h);
                }
            }
            plane += row;
        }
        sum += plane;
    }
    kernel_sum[i] = sum;
}

// Attributes: one channel group's kernel-weighted sums at voxel i with its final length, over
// the particles within kappa*h (as the CPU's splat_attributes). The chunk's bricks are the
// ones with density, in the host's order.
@compute @workgroup_size(WORKGROUP_SIZE)
fn attributes(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) lid: u32) {
    let i = dispatch_linear_index(wid, nwg, lid, WORKGROUP_SIZE);
    if (i >= u.voxel_count) {
        return;
    }
    let h = attribute_lengths[i];
    acc_channels[0] = vec4<f32>(0.0);
    acc_channels[1] = vec4<f32>(0.0);
    if (h > 0.0) {
        let r = KAPPA * h;
        gather_attributes(vec3<f32>(voxel_point(i).xyz), r * r, 1.0 / h);
    }
    attribute_sums[2u * i] = acc_channels[0];
    attribute_sums[2u * i + 1u] = acc_channels[1];
}
