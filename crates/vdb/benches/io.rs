//! VDB read/write throughput for a ~300x40x360 fog volume (4.3 M voxel bounding box),
//! through a file and through a byte stream, per compression.
//!
//!     CARGO_TARGET_DIR=... cargo bench -p nimbus-vdb --bench io
//!
//! Voxels/s counts active voxels; MB/s is the size of the encoded .vdb over the time.

use std::time::{Duration, Instant};

use glam::{DVec3, IVec3};
use nimbus_vdb::{has_blosc, Compression, GridClass, VdbFile, WriteOptions};
use nimbus_volume::{brick_local, Transform, Volume, BRICK_DIM, BRICK_VOXELS};

const DIMS: IVec3 = IVec3::new(300, 40, 360);

/// A smoke-like slab: an ellipsoid of smoothly varying density (like an SPH estimate), so
/// the compressors see realistic data rather than constants or noise.
fn fog_volume() -> Volume<f32> {
    let mut vol = Volume::new(Transform::uniform(0.01, DVec3::new(-1.5, -0.2, 0.0)), 0.0f32);
    let half = DIMS.as_dvec3() * 0.5;
    let mut values = vec![0f32; BRICK_VOXELS];
    for bx in (0..DIMS.x).step_by(BRICK_DIM as usize) {
        for by in (0..DIMS.y).step_by(BRICK_DIM as usize) {
            for bz in (0..DIMS.z).step_by(BRICK_DIM as usize) {
                let origin = IVec3::new(bx, by, bz);
                let mut mask = [0u64; 8];
                for (n, v) in values.iter_mut().enumerate() {
                    let ijk = origin + brick_local(n);
                    let p = (ijk.as_dvec3() - half) / half;
                    let r2 = p.length_squared();
                    let inside = ijk.cmplt(DIMS).all() && r2 < 1.0;
                    *v = if inside { ((1.0 - r2) * (0.8 + 0.2 * (p.x * 9.0).sin() * (p.z * 5.0).cos())) as f32 } else { 0.0 };
                    if inside {
                        mask[n / 64] |= 1 << (n % 64);
                    }
                }
                if mask.iter().any(|&w| w != 0) {
                    vol.insert_brick(origin, &values, &mask);
                }
            }
        }
    }
    vol
}

/// Best of a few runs (the machine is shared; the minimum is the least disturbed).
fn time<T>(mut f: impl FnMut() -> T) -> (Duration, T) {
    let mut best = Duration::MAX;
    let mut out = None;
    for _ in 0..3 {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed());
        out = Some(r);
    }
    (best, out.unwrap())
}

fn row(op: &str, how: &str, d: Duration, voxels: u64, bytes: usize) {
    let s = d.as_secs_f64();
    println!(
        "| {op:<28} | {how:<22} | {:>8.1} | {:>9.1} | {:>10.1} | {:>8.1} |",
        bytes as f64 / 1e6,
        s * 1e3,
        voxels as f64 / s / 1e6,
        bytes as f64 / s / 1e6
    );
}

fn main() {
    let vol = fog_volume();
    let voxels = vol.active_voxel_count();
    println!("fog volume {}x{}x{}: {} bricks, {voxels} active voxels\n", DIMS.x, DIMS.y, DIMS.z, vol.brick_count());
    println!("| {:<28} | {:<22} | {:>8} | {:>9} | {:>10} | {:>8} |", "operation", "compression", "size MB", "time ms", "Mvoxels/s", "MB/s");
    println!("|{:-<30}|{:-<24}|{:-<10}|{:-<11}|{:-<12}|{:-<10}|", "", "", "", "", "", "");

    let dir = std::env::temp_dir().join(format!("nimbus-vdb-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bench.vdb");

    let (d, file) = time(|| {
        let mut f = VdbFile::new();
        f.insert_volume("density", &vol, GridClass::FogVolume).unwrap();
        f
    });
    row("Volume -> grid (convert)", "-", d, voxels, 0);
    let mut unknown_class = VdbFile::new();
    unknown_class.insert_volume("density", &vol, GridClass::Unknown).unwrap();

    let mut cases = vec![("none", Compression::None, &file), ("zip (fog volume)", Compression::Zip, &file)];
    cases.push(("zip (class unknown)", Compression::Zip, &unknown_class));
    if has_blosc() {
        cases.push(("blosc", Compression::Blosc, &file));
    }
    for (how, compression, f) in cases {
        let opts = WriteOptions { compression, half: false };
        let (d, bytes) = time(|| f.to_bytes(&opts).unwrap());
        row("write stream (to_bytes)", how, d, voxels, bytes.len());
        let (d, ()) = time(|| f.write(&path, &opts).unwrap());
        row("write file (atomic)", how, d, voxels, bytes.len());
        let (d, _) = time(|| VdbFile::from_bytes(&bytes, "<bench>").unwrap());
        row("read stream (parse)", how, d, voxels, bytes.len());
        let (d, back) = time(|| VdbFile::open(&path).unwrap());
        row("read file (parse)", how, d, voxels, bytes.len());
        let (d, v) = time(|| back.read_float("density").unwrap());
        row("grid -> Volume (convert)", how, d, voxels, 0);
        assert_eq!(v.active_voxel_count(), voxels);
        let (d, _) = time(|| VdbFile::open(&path).unwrap().read_float("density").unwrap());
        row("read file + convert", how, d, voxels, bytes.len());
    }
    let _ = std::fs::remove_dir_all(&dir);
}
