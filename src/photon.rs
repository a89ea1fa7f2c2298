//! vdbphoton's flags and what it records: the photon tracer's parameters from the flags,
//! the input's metadata and the --quality preset; the photon map as a points grid.

use clap::Args;
use nimbus_cli::{EmissionArgs, EmissionGrids, Failure, Quality, SceneArgs, Stage};
use nimbus_gpu::ComputeDevice;
use nimbus_photon::{trace_cpu_emitting, trace_gpu_emitting, DistanceSampling, PhotonError, PhotonMap, PhotonParams, TraceStats};
use nimbus_vdb::{PointSet, VdbFile};

/// vdbphoton's own flags, between the output's and the sequence's.
#[derive(Args, Debug, Clone)]
pub struct TraceArgs {
    /// The sky or environment map among the lights: photons also leave it, stored from their
    /// first interaction.
    #[command(flatten)]
    scene: SceneArgs,
    /// Free-path sampling: delta (delta tracking, unbiased: 1.4-2.1x more
    /// accurate than simpson at equal time), simpson (the paper's Eq. 2) or exponential
    /// (Eq. 1, biased); the last two for comparison. [default: delta]
    #[arg(long, help_heading = "Quality")]
    distance: Option<DistanceSampling>,
    /// Simpson step (and exponential search step), as a fraction of the smallest voxel edge;
    /// delta tracking takes none.
    #[arg(long, default_value_t = 0.5, help_heading = "Quality")]
    step: f64,
    /// Photons to store. [default: the --quality preset's, else 200000]
    #[arg(long, help_heading = "Quality")]
    photons: Option<u64>,
    /// Preset: draft, preview or final (photon count and distance mode; flags override).
    #[arg(long, value_enum, help_heading = "Quality")]
    quality: Option<Quality>,
    /// Stop emitting after this many photons even if fewer were stored.
    #[arg(long, default_value_t = 50_000_000, help_heading = "Quality")]
    max_emitted: u64,
    /// Interactions after which a path ends.
    #[arg(long, default_value_t = 64, help_heading = "Quality")]
    max_interactions: u32,
    /// Random seed. [default: what the input records, else 0]
    #[arg(long, help_heading = "Quality")]
    seed: Option<u64>,
    /// The medium's emission: photons also leave the emitting voxels, stored from their first
    /// interaction on (a fire lights its own smoke through the photon gather).
    #[command(flatten)]
    emission: EmissionArgs,
}

impl TraceArgs {
    /// The tracer's parameters: the flags over the preset, the scene over what the input
    /// records, the seed the input records.
    pub fn params(&self, stage: &Stage) -> Result<PhotonParams, Failure> {
        let preset = self.quality.map(Quality::settings);
        let (medium, lights, environment) = stage.scene(&self.scene, None)?;
        let params = PhotonParams {
            medium,
            lights,
            environment,
            distance: match (self.distance, preset) {
                (Some(d), _) => d,
                (None, Some(q)) => q.distance.parse().map_err(Failure::usage)?,
                (None, None) => PhotonParams::default().distance,
            },
            step: self.step,
            photons: self.photons.or(preset.map(|q| q.photons)).unwrap_or(200_000),
            max_emitted: self.max_emitted,
            max_interactions: self.max_interactions,
            seed: self.seed.or(stage.meta.seed()).unwrap_or(0),
        };
        params.validate().map_err(Failure::usage)?;
        Ok(params)
    }

    /// The medium's emission, where the flags or the input's fire grids give one.
    /// Returns the emission flags in force too, which the photon file records for later tools.
    pub fn emission(&self, stage: &Stage) -> Result<(Option<EmissionGrids>, EmissionArgs), Failure> {
        self.emission.resolve_over(&stage.file, &stage.meta, &stage.log)
    }
}

/// Traces the photons on `device` (timed as the stage `trace`), warning where fewer were
/// stored than asked for.
pub fn trace(stage: &Stage, device: &ComputeDevice, params: &PhotonParams, emission: Option<&EmissionGrids>) -> Result<(PhotonMap, TraceStats), Failure> {
    let (log, field) = (&stage.log, emission.map(EmissionGrids::field));
    let traced = log.stage(
        "trace",
        || match device.gpu() {
            Some(ctx) => trace_gpu_emitting(ctx, &stage.density, params, field.as_ref()),
            None => trace_cpu_emitting(&stage.density, params, field.as_ref()),
        },
        |r| {
            r.as_ref()
                .map(|(_, s)| {
                    format!(
                        "emitted {}, stored {}, escaped {}, absorbed {}, cut {}, {:.2} interactions per photon",
                        s.emitted, s.stored, s.escaped, s.absorbed, s.truncated, s.mean_interactions()
                    )
                })
                .unwrap_or_default()
        },
    );
    let (map, stats) = traced.map_err(|e| match e {
        PhotonError::Param(_) => Failure::usage(e),
        PhotonError::Gpu(_) => Failure::runtime(e, "GPU photon tracer"),
    })?;
    if let Some(why) = &stats.skipped {
        log.warn(format!("no photons traced: {why}; writing an empty photon map"));
    } else if stats.stored < params.photons {
        log.warn(format!("stored {} of {} photons before --max-emitted {} was reached", stats.stored, params.photons, params.max_emitted));
    }
    Ok((map, stats))
}

/// Puts the photon map in `file` as the points grid `photons` (replacing any earlier one).
pub fn store(file: &mut VdbFile, map: PhotonMap) -> Result<(), Failure> {
    file.remove_grid("photons");
    let points = PointSet::new(map.positions).with_vec3("power", map.power).with_vec3("dir", map.dir);
    file.insert_points("photons", &points, None).map_err(|e| Failure::runtime(e, "photons grid"))
}

/// vdbphoton's record (`nimbus:vdbphoton`).
pub fn record(params: &PhotonParams, stats: &TraceStats) -> Vec<(&'static str, String)> {
    vec![
        ("distance", params.distance.name().to_string()),
        ("step", params.step.to_string()),
        ("photons", params.photons.to_string()),
        ("max_emitted", params.max_emitted.to_string()),
        ("max_interactions", params.max_interactions.to_string()),
        ("emitted", stats.emitted.to_string()),
        ("stored", stats.stored.to_string()),
        ("escaped", stats.escaped.to_string()),
        ("absorbed", stats.absorbed.to_string()),
        ("truncated", stats.truncated.to_string()),
        ("interactions", stats.interactions.to_string()),
    ]
}

/// The emission the photons carry (vdbcache's photon gather holds it scattered): none
/// where nothing was traced.
pub fn carried_emission(emission: Option<&EmissionGrids>, stats: &TraceStats) -> String {
    match (emission, &stats.skipped) {
        (Some(e), None) => e.params.describe(),
        _ => "none".to_string(),
    }
}
