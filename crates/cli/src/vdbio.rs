//! Reading and writing the VDB that flows through the chain.

use nimbus_vdb::{GridKind, VdbFile};
use rayon::prelude::*;
use nimbus_volume::Volume;

use crate::{Failure, Input, Output, PipelineMeta, VdbOutputArgs};

/// Reads the whole input VDB (file or stdin). Anything that is not a readable VDB is bad
/// input (exit code 2).
pub fn read_vdb(input: &Input) -> Result<VdbFile, Failure> {
    match input {
        Input::Path(p) => VdbFile::open(p).map_err(|e| Failure::input(e, p.display())),
        Input::Stdin => {
            let bytes = input.read_all()?;
            // A tool before this one in a pipe wrote nothing: it failed and said why. This
            // tool says so once; the tools after it, handed the marker, say nothing more.
            if bytes.is_empty() {
                pass_on_upstream_failure();
                return Err(Failure::input("empty input: the tool before this one in the pipe wrote nothing (it likely failed: see its error above)", "stdin"));
            }
            if bytes == UPSTREAM_FAILED {
                pass_on_upstream_failure();
                return Err(Failure::reported(2));
            }
            VdbFile::from_bytes(&bytes, "stdin").map_err(|e| Failure::input(e, "stdin"))
        }
    }
}

/// What a tool writes to a piped stdout in place of a VDB when its own input was empty: the
/// next tool then fails quietly (exit 2) instead of repeating the first tool's complaint.
/// Not a VDB (whose files begin with the bytes ` BDV`), and only ever written to a pipe.
pub const UPSTREAM_FAILED: &[u8] = b"nimbus: an earlier tool in the pipe failed\n";

/// Writes [`UPSTREAM_FAILED`] to stdout where stdout is a pipe (the next tool's stdin).
fn pass_on_upstream_failure() {
    use std::io::Write;
    // SAFETY: fstat on fd 1 with a zeroed stat buffer of the right type.
    let piped = unsafe {
        let mut st: libc::stat = std::mem::zeroed();
        libc::fstat(1, &mut st) == 0 && (st.st_mode & libc::S_IFMT) == libc::S_IFIFO
    };
    if piped {
        let mut out = std::io::stdout().lock();
        let _ = out.write_all(UPSTREAM_FAILED).and_then(|_| out.flush());
    }
}

/// The density grid: `--grid`, else the one the chain recorded, else `density`. It must be a
/// float (or half/double) grid with an affine transform.
pub fn read_density(file: &VdbFile, grid: Option<&str>) -> Result<(String, Volume<f32>), Failure> {
    let meta = PipelineMeta::of(file);
    let name = grid.or(meta.density_grid()).unwrap_or("density").to_string();
    if !file.has_grid(&name) {
        let names = file.grid_names().join(", ");
        return Err(Failure::input(
            format!("no grid named '{name}' (grids: {}; choose one with --grid)", if names.is_empty() { "none" } else { &names }),
            file.label(),
        ));
    }
    let info = file.grid(&name).map_err(|e| Failure::input(e, file.label()))?;
    if info.kind != GridKind::Float {
        return Err(Failure::input(format!("grid '{name}' holds {} values, not a scalar density", info.value_type), file.label()));
    }
    let volume = file.read_float(&name).map_err(|e| Failure::input(e, file.label()))?;
    let nonfinite: u64 = volume.par_bricks().map(|b| b.values.iter().filter(|v| !v.is_finite()).count() as u64).sum();
    if nonfinite > 0 {
        return Err(Failure::input(format!("grid '{name}' holds {nonfinite} non-finite values"), file.label()));
    }
    Ok((name, volume))
}

/// A vec3 grid (e.g. `Li_single`), or `None` when the file has no grid of that name.
pub fn read_vec3_grid(file: &VdbFile, name: &str) -> Result<Option<Volume<glam::Vec3>>, Failure> {
    if !file.has_grid(name) {
        return Ok(None);
    }
    let info = file.grid(name).map_err(|e| Failure::input(e, file.label()))?;
    if info.kind != GridKind::Vec3 {
        return Err(Failure::input(format!("grid '{name}' is not a vec3 grid"), file.label()));
    }
    file.read_vec3(name).map(Some).map_err(|e| Failure::input(e, file.label()))
}

/// Writes the output VDB to a file (atomically) or stdout.
pub fn write_vdb(file: &VdbFile, args: &VdbOutputArgs) -> Result<(), Failure> {
    let output = Output::from_arg(args.output.as_deref())?;
    let options = args.write_options()?;
    match &output {
        Output::Path(p) => file.write(p, &options).map_err(|e| Failure::runtime(e, p.display())),
        Output::Stdout => {
            let bytes = file.to_bytes(&options).map_err(|e| Failure::runtime(e, "stdout"))?;
            output.write(&bytes)
        }
    }
}


/// The `-v` line of a density grid a tool read (issue #31, framing): the world bounds of its
/// active voxels (each voxel's whole cell, what the default camera frames), the range of the
/// active values, and the counts.
pub fn describe_density(name: &str, volume: &Volume<f32>) -> String {
    let counts = format!("{} active voxels in {} bricks", volume.active_voxel_count(), volume.brick_count());
    let Some((lo, hi)) = volume.world_bounds() else {
        return format!("density grid '{name}': no active voxels ({counts})");
    };
    let (min, max) = volume
        .par_bricks()
        .map(|b| (0..b.values.len()).filter(|&o| b.is_active(o)).fold((f32::INFINITY, f32::NEG_INFINITY), |(a, z), o| (a.min(b.values[o]), z.max(b.values[o]))))
        .reduce(|| (f32::INFINITY, f32::NEG_INFINITY), |a, b| (a.0.min(b.0), a.1.max(b.1)));
    let size = hi - lo;
    format!(
        "density grid '{name}': world bounds {:.6},{:.6},{:.6} to {:.6},{:.6},{:.6} (size {:.6} x {:.6} x {:.6}, centre {:.6},{:.6},{:.6}), values {min} to {max}, {counts}",
        lo.x,
        lo.y,
        lo.z,
        hi.x,
        hi.y,
        hi.z,
        size.x,
        size.y,
        size.z,
        0.5 * (lo.x + hi.x),
        0.5 * (lo.y + hi.y),
        0.5 * (lo.z + hi.z)
    )
}
