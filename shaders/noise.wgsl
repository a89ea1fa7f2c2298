// Seeded 3D gradient (Perlin) noise and fBm: the WGSL twin of nimbus_optics::noise
// (crates/optics/src/noise.rs), for any stage shader (vdbmarch's offset noise today). No
// bindings; concatenate it.
//
// The integer hash (PCG output hash of the lattice point and seed) is bit-for-bit the CPU's:
// WGSL u32 arithmetic wraps like Rust's wrapping_mul/wrapping_add. The interpolation is f32
// as on the CPU, which however splits its f64 position into a lattice cell and an f32
// fraction. Here positions come split the same way, as a lattice point `base` (u32,
// wrapping, i.e. the CPU's `cell as i64 as u32`) plus an f32 `offset`, so a host that keeps
// world coordinates far from the origin passes floor(origin / scale) as base and the rest
// as offset, and loses nothing. Agreement with the CPU: exact hash, values to f32 rounding.

fn noise_pcg(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

fn noise_lattice_hash(p: vec3<u32>, seed: u32) -> u32 {
    return noise_pcg(p.x ^ noise_pcg(p.y ^ noise_pcg(p.z ^ noise_pcg(seed))));
}

fn noise_grad(hash: u32, d: vec3<f32>) -> f32 {
    let h = hash & 15u;
    let u = select(d.y, d.x, h < 8u);
    var v = d.z;
    if (h < 4u) {
        v = d.y;
    } else if (h == 12u || h == 14u) {
        v = d.x;
    }
    return select(-u, u, (h & 1u) == 0u) + select(-v, v, (h & 2u) == 0u);
}

fn noise_fade(t: f32) -> f32 {
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
}

fn noise_lerp(a: f32, b: f32, t: f32) -> f32 {
    return a + t * (b - a);
}

fn noise_corner(cell: vec3<u32>, f: vec3<f32>, d: vec3<u32>, seed: u32) -> f32 {
    return noise_grad(noise_lattice_hash(cell + d, seed), f - vec3<f32>(d));
}

// perlin3 at the lattice cell `cell` (wrapping u32) and fraction f in [0,1)^3.
fn noise_perlin3_cell(cell: vec3<u32>, f: vec3<f32>, seed: u32) -> f32 {
    let u = noise_fade(f.x);
    let v = noise_fade(f.y);
    let w = noise_fade(f.z);
    let c000 = noise_corner(cell, f, vec3<u32>(0u, 0u, 0u), seed);
    let c001 = noise_corner(cell, f, vec3<u32>(0u, 0u, 1u), seed);
    let c010 = noise_corner(cell, f, vec3<u32>(0u, 1u, 0u), seed);
    let c011 = noise_corner(cell, f, vec3<u32>(0u, 1u, 1u), seed);
    let c100 = noise_corner(cell, f, vec3<u32>(1u, 0u, 0u), seed);
    let c101 = noise_corner(cell, f, vec3<u32>(1u, 0u, 1u), seed);
    let c110 = noise_corner(cell, f, vec3<u32>(1u, 1u, 0u), seed);
    let c111 = noise_corner(cell, f, vec3<u32>(1u, 1u, 1u), seed);
    return noise_lerp(
        noise_lerp(noise_lerp(c000, c001, w), noise_lerp(c010, c011, w), v),
        noise_lerp(noise_lerp(c100, c101, w), noise_lerp(c110, c111, w), v),
        u);
}

// perlin3 at base + offset (see the header).
fn noise_perlin3_split(base: vec3<u32>, offset: vec3<f32>, seed: u32) -> f32 {
    let fl = floor(offset);
    return noise_perlin3_cell(base + vec3<u32>(vec3<i32>(fl)), offset - fl, seed);
}

// nimbus_optics::noise::perlin3(p, seed) for a position small enough for f32.
fn noise_perlin3(p: vec3<f32>, seed: u32) -> f32 {
    return noise_perlin3_split(vec3<u32>(0u), p, seed);
}

// Fbm::new(octaves, seed).eval(base + offset): lacunarity 2, gain 1/2, octave o shifted by
// o * SHIFT and seeded seed + o. Octave o's lattice point is base * 2^o (wrapping, as the
// CPU's i64 -> u32 cast) and its offset offset * 2^o (exact in f32).
fn noise_fbm3_split(base: vec3<u32>, offset: vec3<f32>, octaves: u32, seed: u32) -> f32 {
    let shift = vec3<f32>(0.318309886, 0.577215665, 0.693147181);
    var sum = 0.0;
    var norm = 0.0;
    var amp = 1.0;
    var freq = 1.0;
    for (var o = 0u; o < octaves; o = o + 1u) {
        let b = select(vec3<u32>(0u), base << vec3<u32>(o), o < 32u);
        sum = sum + amp * noise_perlin3_split(b, offset * freq + shift * f32(o), seed + o);
        norm = norm + amp;
        freq = freq * 2.0;
        amp = amp * 0.5;
    }
    if (norm > 0.0) {
        return sum / norm;
    }
    return 0.0;
}

// fbm3_vec: three fBm channels seeded seed, seed + 101, seed + 202.
fn noise_fbm3_vec_split(base: vec3<u32>, offset: vec3<f32>, octaves: u32, seed: u32) -> vec3<f32> {
    return vec3<f32>(
        noise_fbm3_split(base, offset, octaves, seed),
        noise_fbm3_split(base, offset, octaves, seed + 101u),
        noise_fbm3_split(base, offset, octaves, seed + 202u));
}
