// requires: Rng, majorant_fetch
//
// Rays through the density volume: the WGSL twin of crates/tracking (nimbus_tracking::MediumRay)
// and of nimbus_volume::MajorantGrid's DDA walk, shared by the photon and march stages.
//
// Composed after volume.wgsl (the density is the default volume at group 0) and optics.wgsl
// (Rng). The stage shader provides
//     fn majorant_fetch(index: u32) -> f32
// returning MajorantGrid::values()[index] (x-major, z fastest), usually from a storage buffer,
// and the MajorantGridInfo of that grid.
//
// Everything is f32 and in index space, like MediumRay (whose parameter t is the world
// distance along a unit world direction, the map being affine). The CPU reference works in
// f64, so the two agree to f32 rounding, not bit for bit.

// Stands for an infinite ray parameter (WGSL has no infinity literal).
const TRACK_FAR: f32 = 3.0e38;

struct MajorantGridInfo {
    // Index coordinate of the lowest corner of cell (0,0,0).
    origin: vec3<i32>,
    // Cell edge in voxels (a power of two).
    cell_size: f32,
    dims: vec3<i32>,
    // Bound outside the grid: the volume's background.
    outside: f32,
}

struct MajorantSegment {
    t_start: f32,
    t_end: f32,
    majorant: f32,
    // False once the walk is over.
    valid: bool,
}

// State of a DDA over the majorant grid (MajorantWalk).
struct MajorantWalk {
    t: f32,
    t_max: f32,
    pending_inside_from: f32,
    inside_until: f32,
    cell: vec3<i32>,
    step: vec3<i32>,
    t_next: vec3<f32>,
    t_delta: vec3<f32>,
}

// MajorantGrid::walk: origin and dir in index space.
fn majorant_walk_new(g: MajorantGridInfo, origin: vec3<f32>, dir: vec3<f32>, t_min: f32, t_max: f32) -> MajorantWalk {
    let scale = 1.0 / g.cell_size;
    let q0 = (origin - vec3<f32>(g.origin)) * scale;
    let dq = dir * scale;
    var ta = t_min;
    var tb = t_max;
    for (var a = 0; a < 3; a = a + 1) {
        if (dq[a] == 0.0) {
            if (q0[a] < 0.0 || q0[a] >= f32(g.dims[a])) {
                ta = TRACK_FAR;
            }
        } else {
            let inv = 1.0 / dq[a];
            let t0 = (0.0 - q0[a]) * inv;
            let t1 = (f32(g.dims[a]) - q0[a]) * inv;
            ta = max(ta, min(t0, t1));
            tb = min(tb, max(t0, t1));
        }
    }
    var w: MajorantWalk;
    w.t = t_min;
    w.t_max = t_max;
    w.inside_until = -TRACK_FAR;
    w.cell = vec3<i32>(0);
    w.step = vec3<i32>(0);
    w.t_next = vec3<f32>(TRACK_FAR);
    w.t_delta = vec3<f32>(TRACK_FAR);
    w.pending_inside_from = TRACK_FAR;
    if (ta < tb && min(g.dims.x, min(g.dims.y, g.dims.z)) > 0) {
        w.cell = clamp(vec3<i32>(floor(q0 + dq * ta)), vec3<i32>(0), g.dims - vec3<i32>(1));
        w.step = vec3<i32>(sign(dq));
        for (var a = 0; a < 3; a = a + 1) {
            if (dq[a] != 0.0) {
                let inv = 1.0 / dq[a];
                var boundary = f32(w.cell[a]);
                if (dq[a] > 0.0) {
                    boundary = f32(w.cell[a] + 1);
                }
                w.t_next[a] = (boundary - q0[a]) * inv;
                w.t_delta[a] = abs(inv);
            }
        }
        w.pending_inside_from = ta;
        w.inside_until = tb;
    }
    return w;
}

fn majorant_cell_value(g: MajorantGridInfo, c: vec3<i32>) -> f32 {
    if (all(c >= vec3<i32>(0)) && all(c < g.dims)) {
        return majorant_fetch(u32((c.x * g.dims.y + c.y) * g.dims.z + c.z));
    }
    return g.outside;
}

// The next segment of the walk (MajorantWalk::next); valid = false when it is over.
// MediumRay::segments: a segment holds medium when its majorant and the extinction are
// positive; the unbounded stretch past the grid counts as empty (a non-zero background would
// otherwise make an infinite medium). The one test every sampler uses.
fn track_segment_has_medium(seg: MajorantSegment, extinction: f32) -> bool {
    return seg.majorant > 0.0 && extinction > 0.0 && seg.t_end < 0.5 * TRACK_FAR;
}

fn majorant_walk_next(w: ptr<function, MajorantWalk>, g: MajorantGridInfo) -> MajorantSegment {
    loop {
        if (!((*w).t < (*w).t_max)) {
            break;
        }
        let t = (*w).t;
        if (t < (*w).pending_inside_from) {
            let end = min((*w).pending_inside_from, (*w).t_max);
            (*w).t = end;
            if (end > t) {
                return MajorantSegment(t, end, g.outside, true);
            }
            continue;
        }
        (*w).pending_inside_from = -TRACK_FAR;
        if (t < (*w).inside_until) {
            let tn = (*w).t_next;
            var axis = 0;
            var m = tn.x;
            if (tn.y < m) {
                m = tn.y;
                axis = 1;
            }
            if (tn.z < m) {
                m = tn.z;
                axis = 2;
            }
            let end = min(min(m, (*w).inside_until), (*w).t_max);
            let majorant = majorant_cell_value(g, (*w).cell);
            (*w).cell[axis] = (*w).cell[axis] + (*w).step[axis];
            (*w).t_next[axis] = (*w).t_next[axis] + (*w).t_delta[axis];
            (*w).t = max(end, t);
            if (end > t) {
                return MajorantSegment(t, end, majorant, true);
            }
            continue;
        }
        (*w).t = (*w).t_max;
        return MajorantSegment(t, (*w).t_max, g.outside, true);
    }
    return MajorantSegment(0.0, 0.0, 0.0, false);
}

// ---------------------------------------------------------------------------------------
// The CPU's f64 draws (Rng::next_f64: two words, 27 + 26 bits) in f32. Drawing both words
// keeps the stream aligned with the CPU's.

// The 53 bits of Rng::next_f64 (the top 27 of one draw, then the top 26 of the next): the
// value is hi 2^-27 + lo 2^-53.
fn rng_next_f64_bits(rng: ptr<function, Rng>) -> vec2<u32> {
    let hi = rng_next_u32(rng) >> 5u;
    let lo = rng_next_u32(rng) >> 6u;
    return vec2<u32>(hi, lo);
}

// xi = Rng::next_f64 rounded to f32.
fn rng_next_f64_as_f32(rng: ptr<function, Rng>) -> f32 {
    let bits = rng_next_f64_bits(rng);
    let hi = bits.x;
    let lo = bits.y;
    // Rounding to f32 may reach 1.0; keep [0,1) as the CPU has it.
    return min(f32(hi) * (1.0 / 134217728.0) + f32(lo) * (1.0 / 9007199254740992.0), 0.99999994);
}

// -ln(1 - xi) for xi = Rng::next_f64, with 1 - xi formed without cancellation.
fn rng_next_exp1(rng: ptr<function, Rng>) -> f32 {
    let bits = rng_next_f64_bits(rng);
    let hi = bits.x;
    let lo = bits.y;
    // 1 - xi = (2^27 - hi) 2^-27 - lo 2^-53, and 2^27 - hi >= 1.
    let one_minus = f32(134217728u - hi) * (1.0 / 134217728.0) - f32(lo) * (1.0 / 9007199254740992.0);
    return -log(one_minus);
}

// ---------------------------------------------------------------------------------------
// MediumRay over the default volume: sigma_t = extinction * max(density, 0).

struct TrackRay {
    origin: vec3<f32>,   // index space
    dir: vec3<f32>,      // index space, the image of a unit world direction
    extinction: f32,
}

// The medium is static here: a stage with motion blur composes
// nimbus_tracking::tracking_wgsl_moving, which puts shaders/motion.wgsl between the markers.
// MOTION BEGIN
fn motion_back(x: vec3<f32>) -> vec3<f32> {
    return x;
}

fn motion_back_index(p: vec3<f32>) -> vec3<f32> {
    return p;
}
// MOTION END

fn track_sigma_t(r: TrackRay, t: f32) -> f32 {
    return r.extinction * max(volume_sample_index(motion_back_index(r.origin + r.dir * t)), 0.0);
}

// Solves integral_0^s q(u) du = remaining for s in [0, h], q the quadratic through (0, l),
// (h/2, m), (h, r): safeguarded Newton as in nimbus_tracking's solve_quadratic_step.
fn track_solve_quadratic_step(l: f32, m: f32, r: f32, h: f32, remaining: f32) -> f32 {
    let c = 2.0 * (l - 2.0 * m + r) / (h * h);
    let b = (r - l) / h - c * h;
    var lo = 0.0;
    var hi = h;
    let total = h * (l + h * (b / 2.0 + h * c / 3.0));
    var s = 0.5 * h;
    if (total > 0.0) {
        s = clamp(remaining / total * h, 0.0, h);
    }
    for (var i = 0; i < 40; i = i + 1) {
        let f = s * (l + s * (b / 2.0 + s * c / 3.0)) - remaining;
        if (abs(f) <= 1e-6 * max(remaining, 1e-30)) {
            break;
        }
        if (f > 0.0) {
            hi = s;
        } else {
            lo = s;
        }
        let slope = max(l + s * (b + s * c), 0.0);
        let newton = s - f / slope;
        if (slope > 0.0 && newton > lo && newton < hi) {
            s = newton;
        } else {
            s = 0.5 * (lo + hi);
        }
        if (hi - lo <= 1e-7 * h) {
            break;
        }
    }
    return s;
}

// Where a free path ends: t >= 0, or -1 when it escapes.
const TRACK_ESCAPED: f32 = -1.0;

// Where a composite-Simpson walk (MediumRay::simpson_panels: panels at most `step` long,
// split at voxel boundaries) over t in [0, t_max] stopped: the panel in which the optical
// depth reached `tau_target` (crossed), or the whole ray's optical depth when it never did.
struct TrackSimpsonStop {
    crossed: bool,
    // Optical depth before the crossing panel, or over the whole ray.
    tau: f32,
    // The crossing panel: start, length and sigma_t at its start, middle and end.
    t0: f32,
    h: f32,
    left: f32,
    mid: f32,
    right: f32,
}

fn track_simpson_until(r: TrackRay, g: MajorantGridInfo, t_max: f32, tau_target: f32, step: f32) -> TrackSimpsonStop {
    var walk = majorant_walk_new(g, r.origin, r.dir, 0.0, t_max);
    var tau = 0.0;
    loop {
        let seg = majorant_walk_next(&walk, g);
        if (!seg.valid) {
            break;
        }
        // Empty, or beyond the grid (where the CPU would integrate the background forever).
        if (!track_segment_has_medium(seg, r.extinction)) {
            continue;
        }
        let a = seg.t_start;
        let b = seg.t_end;
        var next = vec3<f32>(TRACK_FAR);
        var inc = vec3<f32>(TRACK_FAR);
        for (var axis = 0; axis < 3; axis = axis + 1) {
            let d = r.dir[axis];
            if (d != 0.0) {
                let c = r.origin[axis] + a * d;
                var plane = ceil(c) - 1.0;
                if (d > 0.0) {
                    plane = floor(c) + 1.0;
                }
                next[axis] = (plane - r.origin[axis]) / d;
                inc[axis] = 1.0 / abs(d);
            }
        }
        var t = a;
        var left = track_sigma_t(r, t);
        while (t < b) {
            let cross = min(min(min(next.x, next.y), next.z), b);
            if (cross > t) {
                let n = max(ceil((cross - t) / step), 1.0);
                let h = (cross - t) / n;
                let count = u32(n);
                for (var i = 0u; i < count; i = i + 1u) {
                    let t0 = t + f32(i) * h;
                    var t1 = t0 + h;
                    if (i + 1u == count) {
                        t1 = cross;
                    }
                    let hh = t1 - t0;
                    let mid = track_sigma_t(r, t0 + 0.5 * hh);
                    let right = track_sigma_t(r, t1);
                    let integral = hh / 6.0 * (left + 4.0 * mid + right);
                    if (tau + integral >= tau_target && integral > 0.0) {
                        return TrackSimpsonStop(true, tau, t0, hh, left, mid, right);
                    }
                    tau = tau + integral;
                    left = right;
                }
                t = cross;
            }
            for (var axis = 0; axis < 3; axis = axis + 1) {
                while (next[axis] <= t) {
                    next[axis] = next[axis] + inc[axis];
                }
            }
        }
    }
    return TrackSimpsonStop(false, tau, 0.0, 0.0, 0.0, 0.0, 0.0);
}

// MediumRay::sample_simpson: the distance where the composite-Simpson optical depth reaches
// tau_target, exactly within the crossing panel by the quadratic through its samples.
// t from 0 to infinity.
fn track_sample_simpson(r: TrackRay, g: MajorantGridInfo, tau_target: f32, step: f32) -> f32 {
    let s = track_simpson_until(r, g, TRACK_FAR, tau_target, step);
    if (s.crossed) {
        return s.t0 + track_solve_quadratic_step(s.left, s.mid, s.right, s.h, tau_target - s.tau);
    }
    return TRACK_ESCAPED;
}

// MediumRay::transmittance over t in [0, t_max]: exp(-optical depth) by composite Simpson,
// 0 once it falls below `cutoff` (the walk stops there: shadow rays into dense cores end early).
fn track_transmittance(r: TrackRay, g: MajorantGridInfo, t_max: f32, step: f32, cutoff: f32) -> f32 {
    // The CPU clamps the cutoff at 1e-300; f32 stops at the smallest normal.
    let tau_cut = -log(max(cutoff, 1.0e-37));
    let s = track_simpson_until(r, g, min(t_max, TRACK_FAR), tau_cut, step);
    if (s.crossed) {
        return 0.0;
    }
    return exp(-s.tau);
}

// MediumRay::sample_exponential: sigma_t frozen at the first non-empty point of the lattice
// t = k step within non-empty segments.
fn track_sample_exponential(r: TrackRay, g: MajorantGridInfo, tau_target: f32, step: f32) -> f32 {
    var walk = majorant_walk_new(g, r.origin, r.dir, 0.0, TRACK_FAR);
    loop {
        let seg = majorant_walk_next(&walk, g);
        if (!seg.valid) {
            break;
        }
        if (!track_segment_has_medium(seg, r.extinction)) {
            continue;
        }
        // sigma_t is divided by, so rounding noise matters: where the CPU's f64 trilinear
        // weight is exactly 0 (a sample on a voxel plane, as an axis-aligned sun's are every
        // other step) the f32 one can be 1e-7, and 1 / 1e-7 sends the photon a million
        // voxels away. Values under the f32 resolution of the weights (1e-6 of the
        // segment's majorant) count as empty.
        let floor = 1e-6 * seg.majorant * r.extinction;
        // On the ray's lattice t = k step, as the CPU (not from the segment start, which lies
        // on the voxel plane where the support begins).
        var t = ceil(seg.t_start / step) * step;
        while (t < seg.t_end) {
            let s = track_sigma_t(r, t);
            if (s > floor) {
                // Beyond the last non-empty segment the photon has left the medium.
                let d = t + tau_target / s;
                var medium_end = seg.t_end;
                loop {
                    let rest = majorant_walk_next(&walk, g);
                    if (!rest.valid) {
                        break;
                    }
                    if (track_segment_has_medium(rest, r.extinction)) {
                        medium_end = rest.t_end;
                    }
                }
                if (d < medium_end) {
                    return d;
                }
                return TRACK_ESCAPED;
            }
            t = t + step;
        }
    }
    return TRACK_ESCAPED;
}

// MediumRay::sample_delta: delta tracking against each segment's majorant, one exponential
// draw of majorant optical depth per tentative collision carried across segment boundaries;
// draws an f64-style pair per tentative collision (and one for the escape) and an f32 per
// acceptance test, as the CPU does.
fn track_sample_delta(r: TrackRay, g: MajorantGridInfo, rng: ptr<function, Rng>) -> f32 {
    var walk = majorant_walk_new(g, r.origin, r.dir, 0.0, TRACK_FAR);
    var tau = rng_next_exp1(rng);
    loop {
        let seg = majorant_walk_next(&walk, g);
        if (!seg.valid) {
            break;
        }
        if (!track_segment_has_medium(seg, r.extinction)) {
            continue;
        }
        let majorant = seg.majorant * r.extinction;
        var t = seg.t_start;
        loop {
            let dt = tau / majorant;
            if (t + dt >= seg.t_end) {
                tau = tau - (seg.t_end - t) * majorant;
                break;
            }
            t = t + dt;
            if (rng_next_f32(rng) * majorant < track_sigma_t(r, t)) {
                return t;
            }
            tau = rng_next_exp1(rng);
        }
    }
    return TRACK_ESCAPED;
}

// MediumRay::transmittance_ratio over [0, t_max]: the product of (1 - sigma_t / majorant) at
// tentative collisions, Russian roulette (survive with 1/2, weight x2) once it falls below
// `roulette_below`; the same draws as the CPU (an f64-style pair per tentative collision and
// per roulette test).
fn track_transmittance_ratio(r: TrackRay, g: MajorantGridInfo, t_max: f32, roulette_below: f32,
                             rng: ptr<function, Rng>) -> f32 {
    var tr = 1.0;
    var walk = majorant_walk_new(g, r.origin, r.dir, 0.0, t_max);
    var tau = rng_next_exp1(rng);
    loop {
        let seg = majorant_walk_next(&walk, g);
        if (!seg.valid) {
            break;
        }
        if (!track_segment_has_medium(seg, r.extinction)) {
            continue;
        }
        let majorant = seg.majorant * r.extinction;
        var t = seg.t_start;
        loop {
            let dt = tau / majorant;
            if (t + dt >= seg.t_end) {
                tau = tau - (seg.t_end - t) * majorant;
                break;
            }
            t = t + dt;
            tr = tr * (1.0 - track_sigma_t(r, t) / majorant);
            if (tr < roulette_below) {
                if (rng_next_f64_as_f32(rng) >= 0.5) {
                    return 0.0;
                }
                tr = tr * 2.0;
            }
            tau = rng_next_exp1(rng);
        }
    }
    return tr;
}
