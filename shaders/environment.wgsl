// requires: env_word
//
// The environment on the GPU: the WGSL twin of nimbus_optics::Environment's radiance,
// sampling and pdf, reading the array Environment::gpu_words packs (header: kind 0 none,
// 1 uniform, 2 map; width, height, strength, cos and sin of the rotation; a uniform sky's RGB
// at 5..8; then a map's texels, row cdf, row pdfs, column cdfs, column pdfs). The stage
// provides
//     fn env_word(i: u32) -> f32
// reading that array (usually from a storage buffer). Directions are `toward`: from a point
// toward the sky it sees.

const ENV_HEADER: u32 = 8u;

struct EnvSample {
    toward: vec3<f32>,
    radiance: vec3<f32>,
    pdf: f32,
}

fn env_kind() -> u32 {
    return u32(env_word(0u));
}

fn env_width() -> u32 {
    return u32(env_word(1u));
}

fn env_height() -> u32 {
    return u32(env_word(2u));
}

fn env_texel(col: i32, row: i32) -> vec3<f32> {
    let w = i32(env_width());
    let h = i32(env_height());
    let c = ((col % w) + w) % w;
    let r = clamp(row, 0, h - 1);
    let i = ENV_HEADER + 3u * u32(r * w + c);
    return vec3<f32>(env_word(i), env_word(i + 1u), env_word(i + 2u));
}

// Bilinear read at image coordinates (s, t), t = 0 the top edge (EnvironmentMap::lookup).
fn env_lookup(s: f32, t: f32) -> vec3<f32> {
    let x = s * f32(env_width()) - 0.5;
    let y = t * f32(env_height()) - 0.5;
    let x0 = floor(x);
    let y0 = floor(y);
    let fx = x - x0;
    let fy = y - y0;
    let c = i32(x0);
    let r = i32(y0);
    let top = env_texel(c, r) * (1.0 - fx) + env_texel(c + 1, r) * fx;
    let bottom = env_texel(c, r + 1) * (1.0 - fx) + env_texel(c + 1, r + 1) * fx;
    return top * (1.0 - fy) + bottom * fy;
}

// The map frame's direction of a world `toward` (the Z rotation).
fn env_to_map(d: vec3<f32>) -> vec3<f32> {
    let c = env_word(4u);
    let s = env_word(5u);
    return vec3<f32>(c * d.x - s * d.y, s * d.x + c * d.y, d.z);
}

fn env_image_coords(d: vec3<f32>) -> vec2<f32> {
    let s = 0.5 - atan2(d.y, d.x) / (2.0 * OPTICS_PI);
    return vec2<f32>(s - floor(s), acos(clamp(d.z, -1.0, 1.0)) / OPTICS_PI);
}

fn env_radiance(toward: vec3<f32>) -> vec3<f32> {
    let kind = env_kind();
    if (kind == 1u) {
        return vec3<f32>(env_word(5u), env_word(6u), env_word(7u));
    }
    if (kind != 2u) {
        return vec3<f32>(0.0);
    }
    let st = env_image_coords(env_to_map(toward));
    return env_lookup(st.x, st.y) * env_word(3u);
}

// Offsets of the map's tables.
fn env_rows_cdf() -> u32 {
    return ENV_HEADER + 3u * env_width() * env_height();
}

fn env_rows_pdf() -> u32 {
    return env_rows_cdf() + env_height() + 1u;
}

fn env_cols_cdf(row: u32) -> u32 {
    return env_rows_pdf() + env_height() + row * (env_width() + 1u);
}

fn env_cols_pdf(row: u32) -> u32 {
    return env_rows_pdf() + env_height() + env_height() * (env_width() + 1u) + row * env_width();
}

// Distribution1D::sample over the n cells whose cdf (n + 1 values) starts at `cdf`: the
// point in [0, 1) and its cell.
fn env_sample_cells(cdf: u32, n: u32, u: f32) -> vec2<f32> {
    // The last cell whose cdf is <= u (partition_point - 1, clamped).
    var lo = 0u;
    var hi = n + 1u;
    while (lo < hi) {
        let mid = (lo + hi) / 2u;
        if (env_word(cdf + mid) <= u) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    let i = min(max(lo, 1u) - 1u, n - 1u);
    let a = env_word(cdf + i);
    let b = env_word(cdf + i + 1u);
    var frac = 0.5;
    if (b > a) {
        frac = clamp((u - a) / (b - a), 0.0, 1.0);
    }
    let x = min((f32(i) + frac) / f32(n), 1.0 - 5.9604645e-8);
    return vec2<f32>(x, f32(i));
}

fn env_sample(u: vec2<f32>) -> EnvSample {
    let kind = env_kind();
    if (kind == 1u) {
        return EnvSample(sample_uniform_sphere(u), vec3<f32>(env_word(5u), env_word(6u), env_word(7u)), 1.0 / (4.0 * OPTICS_PI));
    }
    if (kind != 2u) {
        return EnvSample(vec3<f32>(0.0, 0.0, 1.0), vec3<f32>(0.0), 0.0);
    }
    let w = env_width();
    let h = env_height();
    let tr = env_sample_cells(env_rows_cdf(), h, u.y);
    let row = u32(tr.y);
    let sc = env_sample_cells(env_cols_cdf(row), w, u.x);
    let col = u32(sc.y);
    let theta = OPTICS_PI * tr.x;
    let phi = OPTICS_PI - 2.0 * OPTICS_PI * sc.x;
    let d = vec3<f32>(sin(theta) * cos(phi), sin(theta) * sin(phi), cos(theta));
    let sin_theta = sqrt(max(1.0 - d.z * d.z, 0.0));
    if (sin_theta <= 0.0) {
        return EnvSample(vec3<f32>(0.0, 0.0, 1.0), vec3<f32>(0.0), 0.0);
    }
    let pdf = env_word(env_rows_pdf() + row) * env_word(env_cols_pdf(row) + col) / (2.0 * OPTICS_PI * OPTICS_PI * sin_theta);
    let c = env_word(4u);
    let s = env_word(5u);
    let toward = vec3<f32>(c * d.x + s * d.y, -s * d.x + c * d.y, d.z);
    return EnvSample(toward, env_lookup(sc.x, tr.x) * env_word(3u), pdf);
}

fn env_pdf(toward: vec3<f32>) -> f32 {
    let kind = env_kind();
    if (kind == 1u) {
        return 1.0 / (4.0 * OPTICS_PI);
    }
    if (kind != 2u) {
        return 0.0;
    }
    let d = env_to_map(toward);
    let st = env_image_coords(d);
    let sin_theta = sqrt(max(1.0 - d.z * d.z, 0.0));
    if (sin_theta <= 0.0) {
        return 0.0;
    }
    let w = env_width();
    let h = env_height();
    let row = min(u32(st.y * f32(h)), h - 1u);
    let col = min(u32(st.x * f32(w)), w - 1u);
    return env_word(env_rows_pdf() + row) * env_word(env_cols_pdf(row) + col) / (2.0 * OPTICS_PI * OPTICS_PI * sin_theta);
}
