//! vdbcache's flags and what it records: the cache baker's parameters from the flags, the
//! input's metadata and the --quality preset; the photons it reads, the grids it writes.

use clap::Args;
use nimbus_cache::{bake_cpu_emitting, bake_gpu_emitting, BakeStats, CacheError, CacheParams, Gather, IlluminationCache, LatticeBias, LightLattice, MultipleLattice, MultipleEstimator, ShadowMode, MAX_REFINEMENT, MULTIPLE_LATTICE_TOLERANCE, noise_short_of, PATH_TOLERANCE, SINGLE_LATTICE_TOLERANCE};
use nimbus_cli::{CameraArgs, EmissionArgs, EmissionGrids, Failure, Quality, SceneArgs, Stage};
use nimbus_gpu::ComputeDevice;
use nimbus_photon::PhotonMap;
use nimbus_vdb::{GridClass, GridKind, VdbFile};

/// vdbcache's own flags, between the output's and the sequence's.
#[derive(Args, Debug, Clone)]
pub struct BakeArgs {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    camera: CameraArgs,
    /// Simpson step toward the lights, as a fraction of the smallest voxel edge (Simpson
    /// panels also split at voxel boundaries, so the trilinear density is integrated exactly).
    #[arg(long, default_value_t = 1.0, help_heading = "Quality")]
    step: f64,
    /// Li_single's cache voxel edge in density voxels, the same on every axis (1: single
    /// scattering's shadows are as sharp as the density). [default: the --quality preset's,
    /// else 1, refined per axis where interpolating it would miss by more than
    /// --single-tolerance]
    #[arg(long, help_heading = "Quality")]
    cache_scale: Option<f64>,
    /// Li_single's lattice without --cache-scale: each axis of the preset's lattice is
    /// halved (up to 4 times finer) while the estimated relative error of interpolating
    /// Li_single between its voxels, as the camera sees it, exceeds a third of this (flat
    /// voxels, thin dense layers and grazing suns need it; 0 refines as far as it goes).
    /// [default: 0.006; the draft preset does not refine]
    #[arg(long, value_name = "TOLERANCE", conflicts_with = "cache_scale", help_heading = "Quality")]
    single_tolerance: Option<f64>,
    /// Li_multiple's own cache voxel edge in density voxels: multiple scattering is smoother
    /// than single, so a coarser lattice holds it at an eighth of the voxels. A strongly
    /// forward-scattering medium lit from behind the eye needs 1 for 2%, which the default
    /// finds by itself (--multiple-tolerance); given alone, the lattice stays as given.
    /// [default: the --quality preset's, else 2]
    #[arg(long, value_name = "SCALE", help_heading = "Quality")]
    multiple_scale: Option<f64>,
    /// Refine Li_multiple's lattice where the bias it leaves in the image, estimated from
    /// the paths' spread over each voxel's footprint, exceeds this, halving at most per pass
    /// down to half of --cache-scale (strong forward scattering lit from behind and media
    /// optically thick within a voxel need it; each pass costs up to 8x the one before); 0
    /// turns it off.
    /// [default: 0.015 without --multiple-scale or --paths, else off; the draft and preview
    /// presets do not refine]
    #[arg(long, value_name = "TOLERANCE", help_heading = "Quality")]
    multiple_tolerance: Option<f64>,
    /// Gather vdbphoton's photons for multiple scattering, K per estimate, adaptive radius
    /// (instead of --paths). [default: the --quality preset's, else 64, with --radius unset]
    #[arg(long, value_name = "K", conflicts_with = "radius", help_heading = "Quality")]
    gather_neighbours: Option<u32>,
    /// Preset: draft, preview or final (lattices, --paths and --path-tolerance; flags
    /// override, and --gather-neighbours or --radius gathers photons instead of tracing paths).
    #[arg(long, value_enum, help_heading = "Quality")]
    quality: Option<Quality>,
    /// Fixed gather radius (world units) instead of --gather-neighbours.
    #[arg(long, help_heading = "Quality")]
    radius: Option<f64>,
    /// Paths traced from the cache voxels for multiple scattering, N per voxel on average:
    /// unbiased, and needs no photons (vdbphoton can be left out of the chain). They start
    /// where the camera's rays read each voxel and go where the image depends most on it
    /// (seen through clear air, in dense medium, by many pixels); voxels no ray reads get
    /// none. [default: the --quality preset's, else 64; half that where --g is 0.5 or more in
    /// magnitude, where each collision also probes toward the lights]
    #[arg(long, value_name = "N", conflicts_with_all = ["radius", "gather_neighbours"], help_heading = "Quality")]
    paths: Option<u32>,
    /// The relative error the image may have against the path-traced reference (its RMS over
    /// its mean), a budget: a quarter of it is kept for what the bake does not estimate, the
    /// lattices' estimated biases take their share, and the paths' noise gets the rest, in
    /// quadrature (at least half of it). After the first pass of paths the bake predicts
    /// their noise from their measured spread and, where it is more than their share, traces
    /// up to 15 times as many again; 0 turns it off. [default: 0.02 without --paths, off with
    /// it; the draft preset 0.1, the preview preset 0.04]
    #[arg(long, visible_alias = "tolerance", value_name = "TOLERANCE", help_heading = "Quality")]
    path_tolerance: Option<f64>,
    /// Random seed of --paths. [default: what the input records, else 0]
    #[arg(long, help_heading = "Quality")]
    seed: Option<u64>,
    /// Largest adaptive gather radius, in density voxels.
    #[arg(long, default_value_t = 12.0, help_heading = "Quality")]
    max_radius: f64,
    /// Shadow rays stop below this transmittance.
    #[arg(long, default_value_t = 1e-4, help_heading = "Quality")]
    min_transmittance: f64,
    /// Transmittance toward the lights: `table` integrates each sun's optical depth once on
    /// a light-aligned lattice (rays half a voxel apart) and looks it up; `rays` traces a
    /// shadow ray per cache voxel and path vertex (the old way, for comparison). Point lights
    /// always trace rays.
    #[arg(long, default_value = "table", value_parser = ["table", "rays"], help_heading = "Quality")]
    shadows: String,
    /// Skip single scattering.
    #[arg(long, help_heading = "Quality")]
    no_single: bool,
    /// Skip multiple scattering.
    #[arg(long, help_heading = "Quality")]
    no_multiple: bool,
    /// Copy the photons grid to the output too.
    #[arg(long, help_heading = "Output")]
    pub keep_photons: bool,
    /// The medium's emission, which the paths gather so a fire lights its own smoke (the
    /// emission vdbmarch adds along camera rays is the same: the flags travel to it in the
    /// cache's metadata).
    #[command(flatten)]
    emission: EmissionArgs,
}

impl BakeArgs {
    /// The baker's parameters: the flags over the preset, the scene and camera over what
    /// the input records (warning where they differ from what `photons` were traced with).
    pub fn params(&self, stage: &Stage, photons: &PhotonMap) -> Result<CacheParams, Failure> {
        let (log, density, meta) = (&stage.log, &stage.density, &stage.meta);
        let traced = (!photons.is_empty()).then_some("the photons were traced with");
        let voxel = density.transform().voxel_size().min_element();
        let preset = Quality::settings_or_default(self.quality);
        let (medium, lights, environment) = stage.scene(&self.scene, traced)?;
        let estimator = match self.paths {
            Some(per_voxel) => MultipleEstimator::Paths { per_voxel },
            None if self.gather_neighbours.is_none() && self.radius.is_none() => MultipleEstimator::default_paths(preset.paths, &medium),
            None => MultipleEstimator::Photons,
        };
        let params = CacheParams {
            medium,
            lights,
            environment,
            camera: self.camera.resolve(meta, density.world_bounds(), log, None)?,
            step: self.step,
            cache_scale: self.cache_scale.unwrap_or(preset.cache_scale),
            multiple_scale: Some(self.multiple_scale.unwrap_or(preset.multiple_scale)),
            multiple_tolerance: match (self.multiple_tolerance, self.multiple_scale, self.paths) {
                (Some(t), _, _) => (t > 0.0).then_some(t),
                (None, None, None) => preset.refine_multiple.then_some(MULTIPLE_LATTICE_TOLERANCE),
                _ => None,
            },
            single_tolerance: match (self.cache_scale, self.single_tolerance) {
                (Some(_), _) => None,
                (None, Some(t)) => Some(t),
                (None, None) => preset.refine_single.then_some(SINGLE_LATTICE_TOLERANCE),
            },
            path_tolerance: match (self.path_tolerance, self.paths) {
                (Some(t), _) => (t > 0.0).then_some(t),
                (None, None) => preset.path_noise.map(|times| times * PATH_TOLERANCE),
                (None, Some(_)) => None,
            },
            single: !self.no_single,
            multiple: !self.no_multiple,
            gather: match self.radius {
                Some(r) => Gather::Radius(r),
                None => Gather::Neighbours {
                    k: self.gather_neighbours.unwrap_or(preset.gather_neighbours),
                    max_radius: self.max_radius * voxel,
                },
            },
            estimator,
            seed: self.seed.or(meta.seed()).unwrap_or(0),
            min_transmittance: self.min_transmittance,
            shadows: match self.shadows.as_str() {
                "rays" => ShadowMode::Rays,
                _ => ShadowMode::Table(LightLattice::default()),
            },
            path_max_depth: nimbus_cache::PATH_MAX_DEPTH,
        };
        params.validate().map_err(Failure::usage)?;
        if params.multiple && params.estimator == MultipleEstimator::Photons && photons.is_empty() {
            log.warn("no photons in the input: multiple scattering skipped (run vdbphoton first, or use --paths)");
        }
        if params.multiple && self.paths.is_none() && params.estimator != MultipleEstimator::Photons && !photons.is_empty() {
            log.note(format!(
                "the input's {} photons are not used: paths from the cache voxels reach 2% in less time than a photon gather (bundled plume 5 against 17 CPU s; the cloud's photons stay at 3.3% at 12.8M; docs/benchmarks.md); --gather-neighbours K gathers them",
                photons.len()
            ));
        }
        Ok(params)
    }

    /// The medium's emission, where the flags or the input's fire grids give one; warns
    /// where a photon gather would take another from the photons than the flags give.
    /// Returns the emission flags in force too (the flags over the input's record), which the
    /// cache records for vdbmarch.
    pub fn emission(&self, stage: &Stage, params: &CacheParams) -> Result<(Option<EmissionGrids>, EmissionArgs), Failure> {
        let (emission, flags) = self.emission.resolve_over(&stage.file, &stage.meta, &stage.log)?;
        let photons_emission = stage.meta.emission().unwrap_or("none");
        if let (Some(e), false) = (&emission, paths(params)) {
            if e.params.describe() != photons_emission {
                stage.log.warn(format!(
                    "the photon gather takes emission from the photons, traced with emission '{photons_emission}', not '{}' (pass the same emission flags to vdbphoton, or use --paths)",
                    e.params.describe()
                ));
            }
        }
        Ok((emission, flags))
    }
}

fn paths(params: &CacheParams) -> bool {
    matches!(params.estimator, MultipleEstimator::Paths { .. })
}

/// vdbphoton's photons in `file` (none where it has no `photons` grid).
pub fn read_photons(file: &VdbFile) -> Result<PhotonMap, Failure> {
    if !file.has_grid("photons") {
        return Ok(PhotonMap::default());
    }
    let info = file.grid("photons").map_err(|e| Failure::input(e, file.label()))?;
    if info.kind != GridKind::Points {
        return Err(Failure::input("grid 'photons' is not a points grid", file.label()));
    }
    let points = file.read_points("photons").map_err(|e| Failure::input(e, file.label()))?;
    // OpenVDB keeps the attribute descriptor in the leaves: a points grid with no points (what
    // vdbphoton writes when nothing scatters) carries no attributes at all.
    if points.is_empty() {
        return Ok(PhotonMap::default());
    }
    let attr = |name: &str| {
        points.vec3(name).map(<[_]>::to_vec).ok_or_else(|| Failure::input(format!("photons lack the vec3 attribute '{name}'"), file.label()))
    };
    let (power, dir) = (attr("power")?, attr("dir")?);
    let finite = points.positions.iter().all(|p| p.is_finite()) && power.iter().all(|p| p.is_finite()) && dir.iter().all(|d| d.is_finite());
    if !finite {
        return Err(Failure::input("photons hold non-finite values", file.label()));
    }
    Ok(PhotonMap { positions: points.positions, power, dir })
}

/// Bakes the cache on `device` (timed as the stage `bake`), warning of non-finite voxels.
pub fn bake(stage: &Stage, device: &ComputeDevice, photons: &PhotonMap, params: &CacheParams, emission: Option<&EmissionGrids>) -> Result<(IlluminationCache, BakeStats), Failure> {
    let (log, density) = (&stage.log, &stage.density);
    let field = emission.map(EmissionGrids::field);
    let (cache, stats) = log
        .stage(
            "bake",
            || match device.gpu() {
                Some(ctx) => bake_gpu_emitting(ctx, density, photons, params, field.as_ref()),
                None => bake_cpu_emitting(density, photons, params, field.as_ref()),
            },
            |r| r.as_ref().map(|(_, s)| summary(s)).unwrap_or_default(),
        )
        .map_err(|e| match e {
            CacheError::Param(_) => Failure::usage(e),
            CacheError::Gpu(_) => Failure::runtime(e, "GPU cache baker"),
        })?;
    if stats.nonfinite > 0 {
        log.warn(format!("{} cache voxels came out non-finite and were set to zero", stats.nonfinite));
    }
    if let Some(cut) = stats.paths_cut_at {
        log.warn(format!(
            "this GPU adapter has a loop cap (a software one): Li_multiple's paths stop at {cut} collisions, not {}, and at albedo {:.3} that leaves the image up to a few percent dark where the medium is lit (1% on a generated scene at albedo 0.999); --device cpu traces them whole",
            params.path_max_depth,
            params.medium.albedo.max_element()
        ));
    }
    // A refined lattice costs up to eight times the bake: say why, rather than only under -v.
    if let Some(l) = stats.multiple_lattice.as_ref().filter(|l| l.scale != l.first_scale) {
        log.note(format!(
            "Li_multiple's lattice refined from {} to {} density voxels: the bias the coarser one leaves in the image was estimated at {:.1}% (taken as {:.1}%, as the estimates under-read), above --multiple-tolerance {:.1}%{}",
            l.first_scale,
            l.scale,
            100.0 * l.first_bias.relative(),
            100.0 * l.first_bias.budgeted(),
            100.0 * params.multiple_tolerance.unwrap_or(0.0),
            l.bias.measured.map_or(String::new(), |[fine, _]| format!("; the last lattice's, measured against the one before it, {:.1}%", 100.0 * fine))
        ));
    }
    // The finest lattice the bake takes can still leave more than the tolerance (a medium
    // optically thick within a voxel: its lit skin is thinner than the lattice): the image
    // is then off by about that much, which the user should hear without -v.
    if let (Some(l), Some(tolerance)) = (stats.multiple_lattice.as_ref(), params.multiple_tolerance) {
        if l.bias.exceeds(tolerance) {
            log.note(format!(
                "Li_multiple's lattice stops at {} density voxels, the finest the bake takes here, with its bias in the image still estimated at {:.1}%, above --multiple-tolerance {:.1}%: the image may be off by about that much (vdbmarch --verify measures it)",
                l.scale,
                100.0 * l.bias.budgeted(),
                100.0 * tolerance
            ));
        }
    }
    if let Some(l) = stats.single_lattice.as_ref().filter(|l| l.direct) {
        log.note(format!(
            "Li_single's interpolation would miss by {:.1}% even on a lattice {MAX_REFINEMENT} times finer (the light's transmittance bends within it): vdbmarch will trace single scattering's shadow rays at its samples instead",
            100.0 * l.estimate.element_sum() / (MAX_REFINEMENT * MAX_REFINEMENT) as f64
        ));
    }
    // The top-up stops at a multiple of the first pass: say so where that left the
    // image noisier than asked (strong forward scattering can), rather than only under -v.
    if let Some(tolerance) = stats.path_noise_tolerance {
        if let Some(last) = noise_short_of(tolerance, stats.path_noise, stats.path_growth_cap) {
            log.note(format!(
                "the paths' noise in the image is predicted at {:.2}%, above their share {:.2}% of --path-tolerance {:.2}%, after the most paths the bake adds ({} times the first pass's); a larger --paths with --path-tolerance raises that limit",
                100.0 * last,
                100.0 * tolerance,
                100.0 * params.path_tolerance.unwrap_or(f64::NAN),
                stats.path_growth_cap
            ));
        }
    }
    Ok((cache, stats))
}

/// The bake's -v line.
fn summary(s: &BakeStats) -> String {
    format!(
        "baked {} cache voxels of {} candidates ({} out of view, {} empty, {} unseen by the camera's rays), {} photons gathered, {} paths traced{}, {} light table nodes{}{}; {}",
        s.baked, s.candidates, s.culled_view, s.culled_empty, s.culled_unseen, s.photons_gathered, s.paths,
        s.path_noise.map_or(String::new(), |(first, last)| format!(
            " (their noise in the image predicted at {:.2}% after the first pass, {:.2}% after all, held to {:.2}%: their share of the tolerance after the lattices' estimated biases and the margin)",
            100.0 * first,
            100.0 * last,
            100.0 * s.path_noise_tolerance.unwrap_or(f64::NAN)
        )),
        s.light_table_nodes,
        s.single_lattice.as_ref().map_or(String::new(), |l| format!(
            "; Li_single's lattice {} x {} x {} density voxels (interpolation error estimated at {:.2}%, {:.2}%, {:.2}% per axis on the unrefined lattice, from {} voxels{})",
            l.scale.x, l.scale.y, l.scale.z, 100.0 * l.estimate.x, 100.0 * l.estimate.y, 100.0 * l.estimate.z, l.samples,
            if l.direct { "; no finer lattice would do: vdbmarch traces single scattering's shadow rays" } else { "" }
        )),
        s.multiple_lattice.as_ref().map_or(String::new(), multiple_lattice_summary),
        s.describe_stages()
    )
}

/// How Li_multiple's lattice was settled, for the -v line.
fn multiple_lattice_summary(l: &MultipleLattice) -> String {
    let signed = |s: f64| 100.0 * s.signum() * s.abs().sqrt();
    let bias = |b: &LatticeBias| {
        format!(
            "{:.2}%, taken as {:.2}% (standard error of its square {:.2}%^2; octants {:.2}%, Taylor {:.2}%, halving {:.2}%{})",
            100.0 * b.relative(),
            100.0 * b.budgeted(),
            1e4 * b.standard_error,
            signed(b.octants),
            signed(b.taylor),
            signed(b.halving),
            b.measured.map_or(String::new(), |[fine, coarser]| format!("; measured against the bake before it {:.2}%, that bake's {:.2}%", 100.0 * fine, 100.0 * coarser))
        )
    };
    if l.scale == l.first_scale {
        format!("; Li_multiple's lattice {} density voxels (its bias in the image estimated at {})", l.scale, bias(&l.bias))
    } else {
        format!("; Li_multiple's lattice refined from {} to {} density voxels (its bias in the image estimated at {}, then {})", l.first_scale, l.scale, bias(&l.first_bias), bias(&l.bias))
    }
}

/// Puts the cache in `file`: `Li_single`, `Li_multiple` and the transmittance grids replace
/// any earlier ones; the photons go unless `keep_photons`.
pub fn store(file: &mut VdbFile, cache: &IlluminationCache, lights: usize, keep_photons: bool) -> Result<(), Failure> {
    if !keep_photons {
        file.remove_grid("photons");
    }
    for (name, volume) in [("Li_single", &cache.li_single), ("Li_multiple", &cache.li_multiple)] {
        file.remove_grid(name);
        if let Some(v) = volume {
            file.insert_volume(name, v, GridClass::Unknown).map_err(|e| Failure::runtime(e, name))?;
        }
    }
    for name in file.grid_names().into_iter().filter(|n| n == "transmittance" || n.starts_with("transmittance_")) {
        file.remove_grid(&name);
    }
    for (index, volume) in &cache.transmittance {
        let name = transmittance_grid_name(*index, lights);
        file.insert_volume(&name, volume, GridClass::FogVolume).map_err(|e| Failure::runtime(e, &name))?;
    }
    Ok(())
}

/// The transmittance grid of light `index` of `lights`: `transmittance` where the scene has
/// one light, `transmittance_<index>` where it has several.
fn transmittance_grid_name(index: usize, lights: usize) -> String {
    if lights == 1 {
        "transmittance".into()
    } else {
        format!("transmittance_{index}")
    }
}

/// vdbcache's record (`nimbus:vdbcache`).
pub fn record(params: &CacheParams, stats: &BakeStats, cache: &IlluminationCache) -> Vec<(&'static str, String)> {
    vec![
        ("step", params.step.to_string()),
        ("cache_scale", params.cache_scale.to_string()),
        ("single_scale", match &stats.single_lattice {
            // ':' as the record's other compound values: ',' separates its entries.
            Some(l) => format!("{}:{}:{}", l.scale.x, l.scale.y, l.scale.z),
            None => params.cache_scale.to_string(),
        }),
        // Where no Li_single lattice would do, vdbmarch traces single scattering itself.
        ("single_direct", stats.single_lattice.as_ref().is_some_and(|l| l.direct).to_string()),
        ("multiple_scale", stats.multiple_lattice.as_ref().map_or(params.multiple_scale(), |l| l.scale).to_string()),
        ("gather", match params.gather {
            Gather::Radius(r) => format!("radius:{r}"),
            Gather::Neighbours { k, max_radius } => format!("neighbours:{k}:{max_radius}"),
        }),
        ("multiple_estimator", params.estimator.describe()),
        ("single", (cache.li_single.is_some()).to_string()),
        ("multiple", (cache.li_multiple.is_some()).to_string()),
        ("candidates", stats.candidates.to_string()),
        ("baked", stats.baked.to_string()),
        ("culled_view", stats.culled_view.to_string()),
        ("culled_empty", stats.culled_empty.to_string()),
        ("photons_gathered", stats.photons_gathered.to_string()),
        ("paths", stats.paths.to_string()),
        ("path_noise", stats.path_noise.map_or("none".to_string(), |(first, last)| format!("{first:.4}:{last:.4}"))),
        ("seed", params.seed.to_string()),
        ("shadows", params.shadows.describe()),
    ]
}

/// What emission the cache's Li holds scattered by the medium (vdbmarch reads it to say
/// so, and to warn where it adds another): the paths' own, the photons' for a gather.
pub fn scattered_emission(stage: &Stage, params: &CacheParams, cache: &IlluminationCache, emission: Option<&EmissionGrids>) -> String {
    match (&cache.li_multiple, emission) {
        (None, _) => "none".to_string(),
        (Some(_), Some(e)) if paths(params) => e.params.describe(),
        (Some(_), _) if paths(params) => "none".to_string(),
        (Some(_), _) => stage.meta.emission().unwrap_or("none").to_string(),
    }
}
