//! particles2vdb's flags and what it writes: the particles read (PLY, CSV/TSV, OpenVDB
//! points), the density estimator's parameters from the flags, the grids and the record.

use clap::Args;
use glam::DVec3;
use nimbus_cli::{parse_dvec3, Failure, Input, Log};
use nimbus_density::{estimate_cpu, estimate_gpu, read_particles_with, Attribute, AttributeVolume, DensityError, DensityOutput, DensityParams, Format, HMin, Method, NoiseParams, ParticleSet, Resolution, H0};
use nimbus_gpu::ComputeDevice;
use nimbus_vdb::{GridClass, PointAttribute, VdbFile, VectorType};

/// particles2vdb's flags for its input, before the output's.
#[derive(Args, Debug, Clone)]
pub struct ParticleArgs {
    /// Input format when the extension does not tell (stdin): ply, csv, tsv or vdb.
    /// [default: from the extension]
    #[arg(long, help_heading = "Input")]
    format: Option<String>,
    /// OpenVDB points input only: read just the points of this point group (Houdini's groups;
    /// without it every point is read, whatever its groups).
    #[arg(long, help_heading = "Input")]
    group: Option<String>,
    /// Mass of each particle without a mass attribute.
    #[arg(long, default_value_t = 1.0, help_heading = "Input")]
    pub mass: f32,
}

/// particles2vdb's flags for the estimate, between the output's and the sequence's.
#[derive(Args, Debug, Clone)]
pub struct EstimateArgs {
    /// Smoothing-length method: ici (per grid point the length, from a ladder
    /// between --h-min and h0, whose estimated error is least, the bias from the differences
    /// between lengths averaged about the point plus the noise), usl (uniform), asl2, asl3
    /// (adaptive by a neighbour count, the paper's), knn (exact neighbour reference).
    #[arg(long, default_value = "ici", value_parser = ["usl", "asl2", "asl3", "knn", "ici"], help_heading = "Quality")]
    method: String,
    /// Upper bound of the smoothing length (world units), or auto (from a histogram of the
    /// particles' number density; -v prints the choice).
    #[arg(long, default_value = "auto", help_heading = "Quality")]
    h0: String,
    /// N*: target neighbour count of the adaptive methods (and of --h0 auto). At 80, with
    /// --h-min 1.2vox, asl3 comes within 3% of a hand-tuned --method usl on steep-contrast
    /// test scenes and a smooth plume, and puts 1-4% more mass into the grid than the
    /// particles carry where lengths vary steeply (--conserve-mass makes it exact); 32 takes
    /// about 0.6x the time; smooth media are less noisy with larger N*.
    #[arg(long, default_value_t = nimbus_density::DEFAULT_NEIGHBOURS, help_heading = "Quality")]
    neighbours: u32,
    /// asl3 relaxation s in [0,1] for overestimated lengths.
    #[arg(long, default_value_t = 0.0, help_heading = "Quality")]
    relax: f32,
    /// Smallest smoothing length: a world length, or voxel sizes with the suffix vox (0.8vox),
    /// which also works where --resolution decides the voxel size; auto is 1.2vox, and 0.75vox
    /// for --method ici (its rule goes below 1.2 only where the particles pay for it).
    #[arg(long, default_value_t = HMin::Auto, value_parser = parse_h_min, help_heading = "Quality")]
    h_min: HMin,
    /// Normalise each particle's mass by its kernel's sum over the grid, so the grid holds
    /// exactly the particles' mass where smoothing lengths vary steeply (one more kernel pass).
    #[arg(long, help_heading = "Quality")]
    conserve_mass: bool,
    /// Voxel edge (world units). [default: from --resolution]
    #[arg(long, conflicts_with = "resolution", help_heading = "Output")]
    voxel_size: Option<f64>,
    /// Voxels along the longest axis of the bounds (instead of --voxel-size). [default: 256]
    #[arg(long, help_heading = "Output")]
    resolution: Option<u32>,
    /// Grid bounds as MINX,MINY,MINZ,MAXX,MAXY,MAXZ (a list such as -1,-1,-1,1,1,1 is taken
    /// as one value). [default: the particles' bounds padded by the kernel]
    #[arg(long, value_parser = parse_bounds, allow_hyphen_values = true, help_heading = "Output")]
    bounds: Option<(DVec3, DVec3)>,
    /// Refuse grids whose bounding box would exceed this many voxels.
    #[arg(long, default_value_t = 1u64 << 30, help_heading = "Output")]
    max_voxels: u64,
    /// fBm noise amplitude on the density (0 = off).
    #[arg(long, default_value_t = 0.0, help_heading = "Medium")]
    noise: f32,
    /// Noise feature size (world units).
    #[arg(long, default_value_t = 1.0, help_heading = "Medium")]
    noise_scale: f64,
    /// Octaves of the fBm noise, each twice the frequency and half the amplitude of the last.
    #[arg(long, default_value_t = 4, help_heading = "Medium")]
    noise_octaves: u32,
    /// Evaluate the noise at this vec3 particle attribute (a rest position, Houdini's `rest`)
    /// interpolated like `--attribute`, instead of at the world position: the pattern then
    /// moves and deforms with the particles instead of the particles moving through it.
    #[arg(long, value_name = "ATTRIBUTE", help_heading = "Medium")]
    noise_rest: Option<String>,
    /// Random seed of the noise (recorded for the later tools, whose random choices it keys).
    #[arg(long, default_value_t = 0, help_heading = "Medium")]
    pub seed: u64,
    /// Also write `smoothing_length` and `neighbour_count` grids. They are not fog volumes, so
    /// `--compression zip` applies to them (OpenVDB leaves fog volumes alone) and their write
    /// takes seconds on a few million voxels, about 10x the default blosc's.
    #[arg(long, help_heading = "Output")]
    aux: bool,
    /// Print the paper's Table 2 statistics (particles used per occupied grid point).
    #[arg(long, help_heading = "Output")]
    pub stats: bool,
    /// Also write particle attribute NAME as a grid (repeatable; NAME:GRID renames it), by SPH
    /// interpolation with the density's smoothing lengths, normalised by the kernel sum. A
    /// vec3 is NAME_x NAME_y NAME_z (or NAMEx.., NAME.x.., NAME[0]..) in PLY and CSV. `v`
    /// (also found as `vel`, `velocity`) becomes the velocity grid `v`, `Cd` (`color`,
    /// `colour`) the grid `color`; other names keep theirs (`temperature`, `heat`). Both
    /// backends (`--device gpu` too).
    #[arg(long = "attribute", value_name = "NAME[:GRID]", help_heading = "Output")]
    attributes: Vec<String>,
}

fn parse_bounds(s: &str) -> Result<(DVec3, DVec3), String> {
    let v: Vec<&str> = s.split(',').collect();
    if v.len() != 6 {
        return Err(format!("'{s}': expected MINX,MINY,MINZ,MAXX,MAXY,MAXZ"));
    }
    let lo = parse_dvec3(&v[..3].join(","))?;
    let hi = parse_dvec3(&v[3..].join(","))?;
    if !(hi.cmpgt(lo).all()) {
        return Err(format!("'{s}': max must exceed min on every axis"));
    }
    Ok((lo, hi))
}

/// `--h-min`: a world length, or a number of voxels with the suffix `vox`.
fn parse_h_min(text: &str) -> Result<HMin, String> {
    let text = text.trim();
    if text == "auto" {
        return Ok(HMin::Auto);
    }
    let (number, voxels) = match text.strip_suffix("vox") {
        Some(n) => (n.trim_end(), true),
        None => (text, false),
    };
    let value: f64 = number.parse().map_err(|_| format!("expected a length or a voxel count like 1.2vox, got '{text}'"))?;
    if !(value.is_finite() && value > 0.0) {
        return Err(format!("must be positive and finite, got '{text}'"));
    }
    Ok(if voxels { HMin::Voxels(value) } else { HMin::World(value) })
}

/// One `--attribute NAME[:GRID]`: the attribute, the grid it becomes and how.
struct AttributeSpec {
    name: String,
    grid: String,
    /// Velocity: a vec3 grid is written contravariant relative (Houdini's and Blender's).
    velocity: bool,
}

impl AttributeSpec {
    /// `NAME` or `NAME:GRID`; the default grid of the velocity names is `v`, of the colour
    /// names `color`, else NAME.
    fn parse(text: &str) -> Result<AttributeSpec, Failure> {
        let (name, grid) = match text.split_once(':') {
            Some((n, g)) => (n, Some(g)),
            None => (text, None),
        };
        let aliases = nimbus_density::attribute_aliases(name);
        let velocity = aliases.contains(&"v");
        let default = if velocity {
            "v"
        } else if aliases.contains(&"Cd") {
            "color"
        } else {
            name
        };
        let grid = grid.unwrap_or(default);
        if name.is_empty() || grid.is_empty() {
            return Err(Failure::usage(format!("--attribute expects NAME or NAME:GRID, got '{text}'")));
        }
        if matches!(grid, "density" | "smoothing_length" | "neighbour_count") {
            return Err(Failure::usage(format!("--attribute {text}: the grid name '{grid}' is particles2vdb's own (rename it with NAME:GRID)")));
        }
        Ok(AttributeSpec { name: name.to_string(), grid: grid.to_string(), velocity })
    }
}

/// Particles from a VDB's points grid (Houdini's `P` and optional `mass`), and the requested
/// float and vec3 point attributes (any codec) under the names asked for.
fn particles_from_vdb(bytes: &[u8], label: &str, requested: &[String], group: Option<&str>) -> Result<ParticleSet, Failure> {
    let file = VdbFile::from_bytes(bytes, label).map_err(|e| Failure::input(e, label))?;
    let grid = file
        .grids()
        .map_err(|e| Failure::input(e, label))?
        .into_iter()
        .find(|g| g.kind == nimbus_vdb::GridKind::Points)
        .ok_or_else(|| Failure::input("no points grid in the VDB", label))?;
    let mut points = file.read_points(&grid.name).map_err(|e| Failure::input(e, label))?;
    let masses = points.float("mass").map(|m| m.to_vec());
    let names: Vec<String> = points.attributes.keys().cloned().collect();
    let available: Vec<&str> = names.iter().map(String::as_str).collect();
    let mut attributes = std::collections::BTreeMap::new();
    for want in requested {
        let Some(found) = nimbus_density::find_attribute(&available, want) else {
            let list = if available.is_empty() { "none".to_string() } else { available.join(", ") };
            return Err(Failure::input(format!("no particle attribute `{want}` in points grid '{}' (available: {list})", grid.name), label));
        };
        let values = match points.attributes.get(found).expect("listed") {
            PointAttribute::Float(v) => Attribute::Float(v.clone()),
            PointAttribute::Vec3(v) => Attribute::Vec3(v.clone()),
        };
        attributes.insert(want.clone(), values);
    }
    points.attributes.clear();
    let mut set = ParticleSet { positions: points.positions, masses, attributes };
    if let Some(group) = group {
        let groups = file.point_groups(&grid.name).map_err(|e| Failure::input(e, label))?;
        if !groups.iter().any(|g| g == group) {
            let list = if groups.is_empty() { "none".to_string() } else { groups.join(", ") };
            return Err(Failure::input(format!("no point group `{group}` in points grid '{}' (groups: {list})", grid.name), label));
        }
        let member = file.read_point_group(&grid.name, group).map_err(|e| Failure::input(e, label))?;
        set = keep_members(set, &member);
    }
    Ok(set)
}

/// The particles whose `member` entry is true, with their masses and attributes.
fn keep_members(set: ParticleSet, member: &[bool]) -> ParticleSet {
    fn keep<T: Copy>(values: &[T], member: &[bool]) -> Vec<T> {
        values.iter().zip(member).filter(|(_, &m)| m).map(|(v, _)| *v).collect()
    }
    ParticleSet {
        positions: keep(&set.positions, member),
        masses: set.masses.as_deref().map(|m| keep(m, member)),
        attributes: set
            .attributes
            .iter()
            .map(|(name, a)| {
                let a = match a {
                    Attribute::Float(v) => Attribute::Float(keep(v, member)),
                    Attribute::Vec3(v) => Attribute::Vec3(keep(v, member)),
                };
                (name.clone(), a)
            })
            .collect(),
    }
}

impl ParticleArgs {
    /// The particle format of `input`: --format, else its extension (`None`: a VDB's points).
    pub fn format(&self, input: &Input) -> Result<Option<Format>, Failure> {
        match self.format.as_deref().or(input.extension().as_deref()) {
            Some("ply") => Ok(Some(Format::Ply)),
            Some("csv") | Some("txt") | Some("xyz") => Ok(Some(Format::Csv)),
            Some("tsv") => Ok(Some(Format::Tsv)),
            Some("vdb") => Ok(None),
            Some(other) => Err(Failure::usage(format!("unknown particle format '{other}' (ply, csv, tsv or vdb; see --format)"))),
            None => Err(Failure::usage("cannot tell the particle format from stdin: give --format ply|csv|tsv|vdb")),
        }
    }

    /// Reads the particles (timed as the stage `read`) with the attributes `params` asks
    /// for (and the noise's rest positions); refuses an input without any.
    pub fn read(&self, log: &Log, input: &Input, format: Option<Format>, params: &DensityParams) -> Result<ParticleSet, Failure> {
        let requested = &params.attributes;
        let read: Vec<String> = requested.iter().chain(params.noise_rest.as_ref().filter(|r| !requested.contains(r))).cloned().collect();
        let particles = log.stage(
            "read",
            || -> Result<ParticleSet, Failure> {
                match format {
                    None => particles_from_vdb(&input.read_all()?, &input.name(), &read, self.group.as_deref()),
                    Some(_) if self.group.is_some() => Err(Failure::usage("--group selects OpenVDB point groups: the input is not a VDB")),
                    Some(format) => {
                        let (set, report) = read_particles_with(input.open()?, format, &read).map_err(|e| Failure::input(e, input.name()))?;
                        if report.skipped_nonfinite > 0 {
                            log.warn(format!("skipped {} particles with non-finite positions or masses ({})", report.skipped_nonfinite, input.name()));
                        }
                        Ok(set)
                    }
                }
            },
            |r| r.as_ref().map(|p| format!("{} particles", p.len())).unwrap_or_default(),
        )?;
        if particles.positions.is_empty() {
            return Err(Failure::input("no particles", input.name()));
        }
        Ok(particles)
    }
}

/// The estimate's grids: `--attribute`s as asked for, the estimator's parameters.
pub struct Estimate {
    pub params: DensityParams,
    specs: Vec<AttributeSpec>,
}

impl EstimateArgs {
    /// The estimator's parameters from the flags, particles without a mass weighing `mass`.
    pub fn params(&self, mass: f32) -> Result<Estimate, Failure> {
        let method = Method::from_name(&self.method).expect("clap checked the method");
        let h0 = match self.h0.as_str() {
            "auto" => H0::Auto,
            v => H0::Fixed(v.parse::<f64>().map_err(|_| Failure::usage(format!("--h0 must be a length or auto, got '{v}'")))?),
        };
        let specs = self.attributes.iter().map(|a| AttributeSpec::parse(a)).collect::<Result<Vec<_>, _>>()?;
        if let Some(twice) = specs.iter().enumerate().find(|(i, s)| specs[..*i].iter().any(|t| t.grid == s.grid)) {
            return Err(Failure::usage(format!("--attribute: two attributes would write the grid '{}'", twice.1.grid)));
        }
        let params = DensityParams {
            method,
            neighbours: self.neighbours,
            h0,
            h_min: self.h_min,
            relax: self.relax,
            mass,
            conserve_mass: self.conserve_mass,
            resolution: match self.voxel_size {
                Some(v) => Resolution::VoxelSize(v),
                None => Resolution::Longest(self.resolution.unwrap_or(256)),
            },
            bounds: self.bounds,
            max_voxels: self.max_voxels,
            noise: NoiseParams { amplitude: self.noise, scale: self.noise_scale, octaves: self.noise_octaves, seed: self.seed as u32 },
            smoothing_length: self.aux,
            neighbour_count: self.aux,
            attributes: specs.iter().map(|s| s.name.clone()).collect(),
            noise_rest: self.noise_rest.clone(),
            ..DensityParams::default()
        };
        params.validate().map_err(|e| Failure::usage(e.to_string()))?;
        Ok(Estimate { params, specs })
    }
}

impl Estimate {
    /// Estimates the density on `device` (timed as the stage `estimate`); with -v says how,
    /// with --stats prints the paper's Table 2 statistics.
    pub fn run(&self, log: &Log, device: &ComputeDevice, particles: &ParticleSet, input: &Input, stats: bool) -> Result<DensityOutput, Failure> {
        let params = &self.params;
        let output = log.stage(
            "estimate",
            || match device.gpu() {
                Some(ctx) => estimate_gpu(ctx, particles, params),
                None => estimate_cpu(particles, params),
            },
            |r| r.as_ref().map(|o| format!("{} active voxels in {} bricks", o.stats.active_voxels, o.density.brick_count())).unwrap_or_default(),
        );
        let output = output.map_err(|e| match e {
            DensityError::NoParticles => Failure::input(e, input.name()),
            e @ DensityError::Gpu(_) => Failure::runtime(e, "--device gpu"),
            e => Failure::usage(e),
        })?;
        log.verbose(nimbus_cli::describe_density("density", &output.density));
        let s = &output.stats;
        log.verbose(format!(
            "method {}, h0 {:.6} ({}), voxel {:.6}, conserve mass {}, grid mass {:.6}, max density {:.6}",
            params.method.name(),
            output.grid.h0,
            if params.h0 == H0::Auto { "auto" } else { "given" },
            output.grid.voxel_size,
            params.conserve_mass,
            s.grid_mass,
            s.max_density
        ));
        let t = &s.timings;
        log.verbose(format!(
            "estimate: prepare {:.3} s (h0, grid, binning), passes {:.3} s ({} bricks), finish {:.3} s",
            t.prepare.as_secs_f64(),
            t.estimate.as_secs_f64(),
            s.bricks_proposed,
            t.finish.as_secs_f64()
        ));
        if !output.attributes.is_empty() {
            log.verbose(format!("attributes: {:.3} s for {}", t.attributes.as_secs_f64(), params.attributes.join(", ")));
        }
        for a in &output.attributes {
            if a.skipped_nonfinite > 0 {
                log.warn(format!("left {} particles with non-finite `{}` out of its grid ({})", a.skipped_nonfinite, a.name, input.name()));
            }
        }
        if stats {
            eprintln!("particles used per occupied grid point: mean {:.2}, std {:.2} over {} points ({})", s.used_mean, s.used_std, s.used_points, params.method.name());
        }
        Ok(output)
    }

    /// A new VDB with the estimate's grids: `density`, with --aux `smoothing_length` and
    /// `neighbour_count`, and the `--attribute`s.
    pub fn grids(&self, output: &DensityOutput) -> Result<VdbFile, Failure> {
        let mut file = VdbFile::new();
        file.insert_volume("density", &output.density, GridClass::FogVolume).map_err(|e| Failure::runtime(e, "density grid"))?;
        for (name, volume) in [("smoothing_length", &output.smoothing_length), ("neighbour_count", &output.neighbour_count)] {
            if let Some(v) = volume {
                file.insert_volume(name, v, GridClass::Unknown).map_err(|e| Failure::runtime(e, format!("{name} grid")))?;
            }
        }
        // Float attributes as fog volumes (as Houdini writes temperature and heat), vec3 ones with
        // no class and their vector type: velocity contravariant relative, others invariant.
        for (spec, a) in self.specs.iter().zip(&output.attributes) {
            let place = format!("{} grid", spec.grid);
            match &a.volume {
                AttributeVolume::Float(v) => file.insert_volume(&spec.grid, v, GridClass::FogVolume).map_err(|e| Failure::runtime(e, &place))?,
                AttributeVolume::Vec3(v) => {
                    file.insert_volume(&spec.grid, v, GridClass::Unknown).map_err(|e| Failure::runtime(e, &place))?;
                    let vector_type = if spec.velocity { VectorType::ContravariantRelative } else { VectorType::Invariant };
                    file.set_vector_type(&spec.grid, vector_type).map_err(|e| Failure::runtime(e, &place))?;
                }
            }
        }
        Ok(file)
    }

    /// particles2vdb's record (`nimbus:particles2vdb`).
    pub fn record(&self, output: &DensityOutput) -> Vec<(&'static str, String)> {
        let (params, s) = (&self.params, &output.stats);
        let attribute_record: Vec<String> = self.specs.iter().map(|s| format!("{}:{}", s.name, s.grid)).collect();
        vec![
            ("method", params.method.name().to_string()),
            ("h0", format!("{}", output.grid.h0)),
            ("h0_auto", (params.h0 == H0::Auto).to_string()),
            ("neighbours", params.neighbours.to_string()),
            ("relax", params.relax.to_string()),
            ("h_min", format!("{}", output.grid.h_min)),
            ("voxel_size", format!("{}", output.grid.voxel_size)),
            ("mass", params.mass.to_string()),
            ("conserve_mass", params.conserve_mass.to_string()),
            ("noise", params.noise.amplitude.to_string()),
            ("noise_scale", params.noise.scale.to_string()),
            ("noise_rest", params.noise_rest.clone().unwrap_or_default()),
            ("particles", s.particles.to_string()),
            ("skipped", s.skipped_nonfinite.to_string()),
            ("active_voxels", s.active_voxels.to_string()),
            ("grid_mass", format!("{}", s.grid_mass)),
            ("used_mean", format!("{:.3}", s.used_mean)),
            ("used_std", format!("{:.3}", s.used_std)),
            ("attributes", attribute_record.join(";")),
        ]
    }
}
