// Optics shared by every nimbus stage shader: the WGSL twins of the nimbus-optics crate
// (crates/optics). Plain functions and structs, no bindings: a stage shader concatenates this
// file and declares the uniforms it needs with the structs below, uploading
// nimbus_optics::{GpuMedium, GpuLight, GpuCamera}, which have the same bytes.
//
// Conventions (design.md sections 3-5, 7; the Rust side documents each in full):
// - cos t = dot(w_in, w_out), w_in the direction light travels before scattering, so g > 0
//   scatters forward.
// - A sun's `vector` is the direction its light travels; a point light's is its position
//   relative to the host-chosen origin that every position in a stage shader is relative to.
// - Random numbers: Philox4x32-10 keyed by (seed, item index, domain), bit-exact with
//   nimbus_optics::Rng. Seeds and indices are u64 on the host, vec2<u32>(lo, hi) here.
// Everything else agrees with the CPU to f32 rounding: GPUs may fuse multiply-adds and their
// sqrt/division/sin/cos are not always correctly rounded.

const OPTICS_PI: f32 = 3.14159265358979323846;
const OPTICS_INV_4PI: f32 = 0.07957747154594767;

// ---------------------------------------------------------------------------------------
// Medium (design.md section 3)

struct Medium {
    albedo: vec3<f32>,
    extinction: f32,
    g: f32,
    // Mean of albedo's channels: the photon tracer's Russian-roulette survival probability.
    albedo_mean: f32,
    _pad0: f32,
    _pad1: f32,
}

fn medium_sigma_t(m: Medium, density: f32) -> f32 {
    return m.extinction * density;
}

fn medium_sigma_s(m: Medium, density: f32) -> vec3<f32> {
    return m.albedo * medium_sigma_t(m, density);
}

// ---------------------------------------------------------------------------------------
// Henyey-Greenstein phase function. See nimbus_optics::HenyeyGreenstein for why the
// formulas are arranged as sums and products of non-negative terms: it keeps g = +-0.999
// accurate in f32 and needs no special case at g = 0.

const HG_G_MAX: f32 = 0.9999;

// HG from 1 - cos and 1 + cos given separately (each known more precisely than cos).
fn hg_eval_sided(g_in: f32, one_minus_cos: f32, one_plus_cos: f32) -> f32 {
    let g = clamp(g_in, -HG_G_MAX, HG_G_MAX);
    var denom: f32;
    if (g >= 0.0) {
        denom = (1.0 - g) * (1.0 - g) + 2.0 * g * one_minus_cos;
    } else {
        denom = (1.0 + g) * (1.0 + g) - 2.0 * g * one_plus_cos;
    }
    return OPTICS_INV_4PI * (1.0 - g) * (1.0 + g) / (denom * sqrt(denom));
}

// p(cos t) = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos t)^1.5), cos t = dot(w_in, w_out).
fn hg_eval(g: f32, cos_theta: f32) -> f32 {
    let c = clamp(cos_theta, -1.0, 1.0);
    return hg_eval_sided(g, 1.0 - c, 1.0 + c);
}

// A scattering angle distributed exactly as HG: (cos, sin, 1 - cos, 1 + cos); xi in [0,1).
fn hg_sample_angle(g_in: f32, xi: f32) -> vec4<f32> {
    let g = clamp(g_in, -HG_G_MAX, HG_G_MAX);
    var d: f32;
    if (g >= 0.0) {
        d = (1.0 - g) + 2.0 * g * (1.0 - xi);
    } else {
        d = (1.0 + g) - 2.0 * g * xi;
    }
    let inv_d2 = 1.0 / (d * d);
    let one_minus_cos = (1.0 - g) * (1.0 - g) * xi * (1.0 + g + d) * inv_d2;
    let one_plus_cos = (1.0 + g) * (1.0 + g) * (1.0 - xi) * (1.0 - g + d) * inv_d2;
    let cos_theta = select(one_plus_cos - 1.0, 1.0 - one_minus_cos, one_minus_cos < one_plus_cos);
    let sin_theta = min(sqrt(max(one_minus_cos * one_plus_cos, 0.0)), 1.0);
    return vec4<f32>(clamp(cos_theta, -1.0, 1.0), sin_theta, one_minus_cos, one_plus_cos);
}

// (cos_theta, sin_theta) of a sampled scattering angle.
fn hg_sample_cos_theta(g: f32, xi: f32) -> vec2<f32> {
    return hg_sample_angle(g, xi).xy;
}

struct HgSample {
    w_out: vec3<f32>,
    pdf: f32,
}

// The direction after scattering for light travelling along unit w_in; u.x picks the angle
// to w_in, u.y the azimuth. pdf = hg_eval(g, dot(w_in, w_out)).
fn hg_sample(g: f32, w_in: vec3<f32>, u: vec2<f32>) -> HgSample {
    let a = hg_sample_angle(g, u.x);
    let phi = 2.0 * OPTICS_PI * u.y;
    let frame = orthonormal_basis(w_in);
    let w_out = a.y * (cos(phi) * frame[0] + sin(phi) * frame[1]) + a.x * w_in;
    return HgSample(w_out, hg_eval_sided(g, a.z, a.w));
}

// The phase function's lobes about the directions toward the lights at a collision, a
// second way to reach the next collision's light (nimbus_optics::LightLobes: why; the same
// bound GUIDED_LIGHTS). Shares are unnormalised (each light's luminance at the collision).
const GUIDED_LIGHTS: u32 = 4u;

struct LightLobes {
    toward: array<vec3<f32>, 4>,
    share: vec4<f32>,
    count: u32,
}

fn light_lobes_none() -> LightLobes {
    return LightLobes(array<vec3<f32>, 4>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0)), vec4<f32>(0.0), 0u);
}

// Rec. 709 luminance (nimbus_optics::luminance).
fn luminance(c: vec3<f32>) -> f32 {
    return 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z;
}

fn light_lobes_add(lobes: ptr<function, LightLobes>, toward: vec3<f32>, strength: f32) {
    let n = (*lobes).count;
    if (n < GUIDED_LIGHTS && strength > 0.0 && strength < 3.0e38) {
        (*lobes).toward[n] = toward;
        (*lobes).share[n] = strength;
        (*lobes).count = n + 1u;
    }
}

// The lobes' density for w (0 without lobes).
fn light_lobes_pdf(g: f32, lobes_in: LightLobes, w: vec3<f32>) -> f32 {
    var lobes = lobes_in;
    let total = dot(lobes.share, vec4<f32>(1.0));
    var pdf = 0.0;
    for (var i = 0u; i < lobes.count; i = i + 1u) {
        pdf = pdf + lobes.share[i] / total * hg_eval(g, dot(lobes.toward[i], w));
    }
    return pdf;
}

// A direction from the lobes (call only with lobes): pick in [0,1) the lobe, u the direction.
fn light_lobes_sample(g: f32, lobes_in: LightLobes, pick: f32, u: vec2<f32>) -> vec3<f32> {
    var lobes = lobes_in;
    var rest = pick * dot(lobes.share, vec4<f32>(1.0));
    var axis = lobes.toward[lobes.count - 1u];
    for (var i = 0u; i < lobes.count; i = i + 1u) {
        rest = rest - lobes.share[i];
        if (rest < 0.0) {
            axis = lobes.toward[i];
            break;
        }
    }
    return normalize(hg_sample(g, axis, u).w_out);
}

// The balance heuristic's weight of the phase-sampled flight along w from a collision whose
// path travelled along w_in, against one probe from the lobes (the probe's: one less this).
fn light_lobes_phase_weight(g: f32, lobes: LightLobes, w_in: vec3<f32>, w: vec3<f32>) -> f32 {
    let phase = hg_eval(g, dot(w_in, w));
    let sum = phase + light_lobes_pdf(g, lobes, w);
    return select(0.0, phase / sum, sum > 0.0);
}

// ---------------------------------------------------------------------------------------
// Sampling helpers

// Columns (t, b, n): unit n completed to a right-handed orthonormal frame (Duff et al. 2017,
// pbrt-v4's CoordinateSystem; the sign uses >= 0 so -0.0 acts as +0.0, as on the CPU).
fn orthonormal_basis(n: vec3<f32>) -> mat3x3<f32> {
    let sign = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let t = vec3<f32>(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let bt = vec3<f32>(b, sign + n.y * n.y * a, -n.y);
    return mat3x3<f32>(t, bt, n);
}

// Uniform direction on the sphere (pdf 1 / 4 pi).
fn sample_uniform_sphere(u: vec2<f32>) -> vec3<f32> {
    let z = 1.0 - 2.0 * u.x;
    let r = sqrt(max(1.0 - z * z, 0.0));
    let phi = 2.0 * OPTICS_PI * u.y;
    return vec3<f32>(r * cos(phi), r * sin(phi), z);
}

// Uniform point on the unit disc (pdf 1 / pi), Shirley-Chiu concentric map.
fn sample_uniform_disk_concentric(u: vec2<f32>) -> vec2<f32> {
    let o = 2.0 * u - vec2<f32>(1.0);
    if (o.x == 0.0 && o.y == 0.0) {
        return vec2<f32>(0.0);
    }
    var r: f32;
    var theta: f32;
    if (abs(o.x) > abs(o.y)) {
        r = o.x;
        theta = 0.25 * OPTICS_PI * (o.y / o.x);
    } else {
        r = o.y;
        theta = 0.5 * OPTICS_PI - 0.25 * OPTICS_PI * (o.x / o.y);
    }
    return r * vec2<f32>(cos(theta), sin(theta));
}

// ---------------------------------------------------------------------------------------
// Lights (design.md sections 4, 5)

const LIGHT_SUN: u32 = 0u;
const LIGHT_POINT: u32 = 1u;
// Stands for an infinite distance (WGSL has no infinity literal).
const LIGHT_FAR: f32 = 3.40282347e38;

struct Light {
    // Sun: unit direction the light travels. Point: position relative to the stage's origin.
    vector: vec3<f32>,
    kind: u32,
    // Sun: irradiance E. Point: intensity I.
    power: vec3<f32>,
    // Sun: 1 - cos of its disc's angular radius (0: parallel). Point: 0.
    disc: f32,
}

struct LightIncident {
    // Unit vector toward the light; the light arrives travelling along w_in = -to_light.
    to_light: vec3<f32>,
    // Distance to the light, LIGHT_FAR for a sun.
    distance: f32,
    // E for a sun, I / r^2 for a point light (0 at r = 0 rather than infinity).
    irradiance: vec3<f32>,
}

fn light_incident(light: Light, p: vec3<f32>) -> LightIncident {
    if (light.kind == LIGHT_SUN) {
        return LightIncident(-light.vector, LIGHT_FAR, light.power);
    }
    let offset = light.vector - p;
    let r2 = dot(offset, offset);
    if (r2 == 0.0) {
        return LightIncident(vec3<f32>(0.0, 0.0, 1.0), 0.0, vec3<f32>(0.0));
    }
    let r = sqrt(r2);
    return LightIncident(offset / r, r, light.power * (1.0 / r2));
}

// light_incident with the direction drawn uniformly over a sun's disc (its solid angle) by u
// in [0,1)^2 (Light::incident_over_disc); the same as light_incident for parallel suns and
// point lights.
fn light_incident_over_disc(light: Light, p: vec3<f32>, u: vec2<f32>) -> LightIncident {
    var inc = light_incident(light, p);
    if (light.kind == LIGHT_SUN && light.disc > 0.0) {
        let c = 1.0 - u.x * light.disc;
        let s = sqrt(max(1.0 - c * c, 0.0));
        let phi = 2.0 * OPTICS_PI * u.y;
        let frame = orthonormal_basis(inc.to_light);
        inc.to_light = normalize(s * (cos(phi) * frame[0] + sin(phi) * frame[1]) + c * inc.to_light);
    }
    return inc;
}

// ---------------------------------------------------------------------------------------
// Camera (design.md section 4): pinhole, pixel (0,0) top-left, pixel centres at +0.5.

struct Camera {
    eye: vec3<f32>,
    width: f32,
    forward: vec3<f32>,
    height: f32,
    right: vec3<f32>,
    tan_half_fov_x: f32,
    up: vec3<f32>,
    tan_half_fov_y: f32,
}

// Unit direction of the ray from cam.eye through continuous pixel coordinates `pixel`.
fn camera_ray(cam: Camera, pixel: vec2<f32>) -> vec3<f32> {
    let sx = (2.0 * pixel.x / cam.width - 1.0) * cam.tan_half_fov_x;
    let sy = (1.0 - 2.0 * pixel.y / cam.height) * cam.tan_half_fov_y;
    return normalize(cam.forward + sx * cam.right + sy * cam.up);
}

// ---------------------------------------------------------------------------------------
// Counter-based random numbers (design.md section 7): Philox4x32-10, Salmon et al. 2011.
// Key = seed (lo, hi); counter = (block, domain, index lo, index hi); four words per block.

const PHILOX_M0: u32 = 0xD2511F53u;
const PHILOX_M1: u32 = 0xCD9E8D57u;
const PHILOX_W0: u32 = 0x9E3779B9u;
const PHILOX_W1: u32 = 0xBB67AE85u;

// (hi, lo) words of the 64-bit product a * b, from 16-bit halves: WGSL has no u64.
fn philox_mulhilo(a: u32, b: u32) -> vec2<u32> {
    let a_lo = a & 0xFFFFu;
    let a_hi = a >> 16u;
    let b_lo = b & 0xFFFFu;
    let b_hi = b >> 16u;
    let ll = a_lo * b_lo;
    let lh = a_lo * b_hi;
    let hl = a_hi * b_lo;
    let hh = a_hi * b_hi;
    // Carries out of the middle 32 bits; no partial sum here can overflow.
    let mid = (ll >> 16u) + (lh & 0xFFFFu) + (hl & 0xFFFFu);
    let hi = hh + (lh >> 16u) + (hl >> 16u) + (mid >> 16u);
    return vec2<u32>(hi, a * b);
}

fn philox4x32_10(counter: vec4<u32>, key: vec2<u32>) -> vec4<u32> {
    var c = counter;
    var k = key;
    for (var r = 0u; r < 10u; r = r + 1u) {
        if (r > 0u) {
            k = k + vec2<u32>(PHILOX_W0, PHILOX_W1);
        }
        let p0 = philox_mulhilo(PHILOX_M0, c.x);
        let p1 = philox_mulhilo(PHILOX_M1, c.z);
        c = vec4<u32>(p1.x ^ c.y ^ k.x, p1.y, p0.x ^ c.w ^ k.y, p0.y);
    }
    return c;
}

struct Rng {
    key: vec2<u32>,
    counter: vec4<u32>,
    block: vec4<u32>,
    // Next unused word of block; 4 means generate the next block.
    slot: u32,
}

// The stream of item `index` (lo, hi) in a run with `seed` (lo, hi); domain 0 is
// nimbus_optics::Rng::new, others Rng::with_domain.
fn rng_new(seed: vec2<u32>, index: vec2<u32>, domain: u32) -> Rng {
    return Rng(seed, vec4<u32>(0u, domain, index.x, index.y), vec4<u32>(0u), 4u);
}

fn rng_next_u32(rng: ptr<function, Rng>) -> u32 {
    if ((*rng).slot == 4u) {
        (*rng).block = philox4x32_10((*rng).counter, (*rng).key);
        (*rng).counter.x = (*rng).counter.x + 1u;
        (*rng).slot = 0u;
    }
    let value = (*rng).block[(*rng).slot];
    (*rng).slot = (*rng).slot + 1u;
    return value;
}

// Top 24 bits times 2^-24: exact, in [0,1), never 1.0.
fn rng_unit_f32(bits: u32) -> f32 {
    return f32(bits >> 8u) * (1.0 / 16777216.0);
}

fn rng_next_f32(rng: ptr<function, Rng>) -> f32 {
    return rng_unit_f32(rng_next_u32(rng));
}

// Point j of the R2 sequence rotated by `offset` (nimbus_optics::r2_point): integer
// arithmetic, bit for bit the CPU's.
fn r2_point(offset: vec2<u32>, j: u32) -> vec2<f32> {
    return vec2<f32>(rng_unit_f32(offset.x + j * 3242174889u), rng_unit_f32(offset.y + j * 2447445413u));
}

// x drawn first, then y.
fn rng_next_vec2(rng: ptr<function, Rng>) -> vec2<f32> {
    let x = rng_next_f32(rng);
    let y = rng_next_f32(rng);
    return vec2<f32>(x, y);
}
