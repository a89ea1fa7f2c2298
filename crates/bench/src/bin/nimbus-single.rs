//! An independent brute-force single-scattering render of a cache VDB's scene, the yardstick
//! for the chain's single scattering (`make bench`): camera rays marched in steps of an
//! eighth of a voxel, and at every step a shadow ray toward each light integrated by composite
//! Simpson through the trilinear density (no cache, no table, no cut-off).
//!
//!     nimbus-single CACHE.vdb -o single.exr
//!
//! It reads the density, medium, lights and camera the file records, renders each pixel's
//! centre ray (as `vdbmarch` does at 1 sample per pixel) and writes RGBA (A = 1 -
//! transmittance), to be compared with `vdbmarch --no-multiple`'s image of the same cache.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;
use glam::{DVec3, Vec3};
use nimbus_cli::{read_density, read_vdb, Input, PipelineMeta};
use nimbus_march::{Image, RayResult};
use nimbus_tracking::{DensityMedium, MediumRay};
use nimbus_volume::MajorantGrid;
use rayon::prelude::*;

#[path = "../image.rs"]
mod image;

#[derive(Parser, Debug)]
#[command(name = "nimbus-single", about = "Brute-force single scattering of a cache VDB's scene, for comparison")]
struct Args {
    input: PathBuf,
    #[arg(short, long)]
    output: PathBuf,
    /// Images to score against the brute-force render (relative RMSE after 2x2 blocks over
    /// covered pixels, as nimbus-bench scores; and the mean ratio).
    #[arg(long)]
    compare: Vec<PathBuf>,
    /// Camera-ray steps per smallest voxel edge.
    #[arg(long, default_value_t = 8.0)]
    steps_per_voxel: f64,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let file = read_vdb(&Input::Path(args.input.clone())).map_err(|e| anyhow::anyhow!("{e}"))?;
    let (_, density) = read_density(&file, None).map_err(|e| anyhow::anyhow!("{e}"))?;
    let meta = PipelineMeta::of(&file);
    let medium = meta.medium().map_err(|e| anyhow::anyhow!("{e}"))?.context("no medium recorded")?;
    let lights = meta.lights().map_err(|e| anyhow::anyhow!("{e}"))?.context("no lights recorded")?;
    let camera = meta.camera().map_err(|e| anyhow::anyhow!("{e}"))?.context("no camera recorded")?;
    let majorant = MajorantGrid::build(&density);
    let dm = DensityMedium { motion: None, density: &density, majorant: &majorant, extinction: medium.extinction };
    let voxel = density.transform().voxel_size().min_element();
    let dt = voxel / args.steps_per_voxel;
    let shadow_step = voxel / 4.0;
    let phase = medium.phase();
    let (w, h) = (camera.width() as usize, camera.height() as usize);
    let rays: Vec<RayResult> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (origin, dir) = camera.ray((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
            let (o, d) = (density.transform().to_index(origin), density.transform().dir_to_index(dir));
            let w_out = (-dir).as_vec3();
            let (mut tr, mut radiance) = (1.0f64, DVec3::ZERO);
            'ray: for seg in majorant.walk(o, d, 0.0, f64::INFINITY) {
                if !(seg.majorant > 0.0) || !seg.t_end.is_finite() {
                    continue;
                }
                let n = ((seg.t_end - seg.t_start) / dt).ceil().max(1.0) as usize;
                let h = (seg.t_end - seg.t_start) / n as f64;
                for k in 0..n {
                    let x = origin + dir * (seg.t_start + (k as f64 + 0.5) * h);
                    let sigma_t = medium.extinction as f64 * density.sample_world(x).max(0.0) as f64;
                    if sigma_t <= 0.0 {
                        continue;
                    }
                    let li: Vec3 = lights
                        .iter()
                        .map(|l| {
                            let inc = l.incident(x);
                            if inc.irradiance == Vec3::ZERO {
                                return Vec3::ZERO;
                            }
                            let t_light = MediumRay::new(dm, x, inc.to_light.as_dvec3(), 0.0, inc.distance).transmittance(shadow_step, 0.0);
                            inc.irradiance * (t_light as f32 * phase.eval_dirs(-inc.to_light, w_out))
                        })
                        .sum();
                    let step_tr = (-sigma_t * h).exp();
                    radiance += tr * (1.0 - step_tr) * (medium.albedo * li).as_dvec3();
                    tr *= step_tr;
                    if tr < 1e-7 {
                        break 'ray;
                    }
                }
            }
            RayResult { behind: Vec3::ZERO, single: radiance.as_vec3(), multiple: Vec3::ZERO, transmittance: tr as f32, depth: f32::INFINITY, emission: Vec3::ZERO }
        })
        .collect();
    let rendered = Image::from_rays(camera.width(), camera.height(), &rays, Vec3::ZERO, false);
    std::fs::write(&args.output, rendered.to_exr()?).with_context(|| format!("writing {}", args.output.display()))?;
    let truth = image::read(&args.output)?;
    for other in &args.compare {
        let e = image::compare(&image::read(other)?, &truth);
        println!("{}: relative RMSE {:.4}, mean ratio {:.4}", other.display(), e.relative_rmse, e.mean_ratio);
    }
    Ok(())
}
