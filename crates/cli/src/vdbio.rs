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
            if bytes.is_empty() {
                return Err(Failure::input("empty input: expected a VDB", "stdin"));
            }
            VdbFile::from_bytes(&bytes, "stdin").map_err(|e| Failure::input(e, "stdin"))
        }
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

