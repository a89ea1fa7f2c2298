//! Emission flags (issue #19; design.md section 5), one meaning for every tool that reads
//! them: vdbphoton (photons leave from emitting voxels), vdbcache (the paths gather the
//! medium's emission, so Li holds emitted light the medium scatters) and vdbmarch (camera
//! rays add the emission itself; `--reference` everything).
//!
//! [`EmissionArgs::resolve`] reads the flags, else recognises Blender's and Houdini's fire
//! grids (`temperature`, `flame`, `heat`), and says with `-v` which grid and mapping it chose.

use glam::Vec3;
use nimbus_optics::{blackbody_rgb, Emission};
use nimbus_tracking::EmissionField;
use nimbus_vdb::{GridKind, VdbFile};
use nimbus_volume::Volume;

use crate::{parse_rgb, read_density, Failure, Log, PipelineMeta};

/// Emission (issue #19): radiance per unit length `S * color * grid(x)` and/or a blackbody
/// from a temperature grid, with Cycles' Principled Volume meaning (`nimbus_optics::Emission`).
/// Without these flags, a file with Blender's or Houdini's fire grids renders with fire.
#[derive(clap::Args, Debug, Clone, Default)]
#[command(next_help_heading = "Medium")]
pub struct EmissionArgs {
    /// The grid whose value scales the emission (e.g. Blender's `flame`). [default: a
    /// recognised fire grid (flame, heat), else none]
    #[arg(long, value_name = "NAME")]
    pub emission_grid: Option<String>,
    /// Emission strength S. [default: 1]
    #[arg(long, value_name = "S")]
    pub emission_strength: Option<f32>,
    /// Emission colour R,G,B. [default: 1,1,1]
    #[arg(long, value_parser = parse_rgb, value_name = "R,G,B")]
    pub emission_color: Option<Vec3>,
    /// The grid holding temperature, in units of --temperature-scale (e.g. `temperature`).
    /// [default: a recognised `temperature` grid, else none]
    #[arg(long, value_name = "NAME")]
    pub temperature_grid: Option<String>,
    /// Kelvin per temperature-grid unit (Cycles' Temperature). [default: 1000, or 1 for a
    /// grid whose largest value is 100 or more (kelvin already)]
    #[arg(long, value_name = "K")]
    pub temperature_scale: Option<f32>,
    /// Blackbody intensity B: 1 is physically accurate radiance sigma T^4 / pi (in Cycles'
    /// scale), coloured by the blackbody's chromaticity. [default: 1]
    #[arg(long, value_name = "B")]
    pub blackbody_intensity: Option<f32>,
    /// No emission, even where the file has fire grids.
    #[arg(long, conflicts_with_all = ["emission_grid", "temperature_grid", "emission_strength", "emission_color", "temperature_scale", "blackbody_intensity"])]
    pub no_emission: bool,
}

/// Default emission strength of a recognised `flame`/`heat` grid without a temperature grid.
const AUTO_FLAME_STRENGTH: f32 = 1.0;
/// Its colour: the blackbody's at this temperature (a flame's orange).
const AUTO_FLAME_KELVIN: f64 = 1500.0;
/// Blender's fluid domain defaults, Flame Ignition 1.5 and Maximum 3.0 (units of 1000 K),
/// between which its renders map the flame to temperature.
const BLENDER_FLAME_TEMPERATURE: (f32, f32) = (1.5, 3.0);
/// Below this flame Blender's temperature grid is 0 (no fire).
const BLENDER_FLAME_MIN: f32 = 0.01;
/// The name the derived temperature is recorded under (`Emission::describe`).
const BLENDER_FLAME_GRID: &str = "flame->temperature";

/// A Blender Mantaflow fire: a non-empty `flame` grid beside a normalised `temperature`
/// grid, and no `vel` (Houdini's pyro names its velocity so, and keeps the temperature
/// mapping; Blender writes `velocity`, or nothing where a cache was trimmed, as
/// data/fire.vdb is): the flame volume and the temperature grid's largest value.
fn blender_fire(file: &VdbFile) -> Result<Option<(Volume<f32>, f32)>, Failure> {
    if file.has_grid("vel") {
        return Ok(None);
    }
    let Some((_, temperature_max)) = grid_max(file, "temperature")? else { return Ok(None) };
    if temperature_max >= KELVIN_LIKE_MIN {
        return Ok(None);
    }
    Ok(grid_max(file, "flame")?.map(|(flame, _)| (flame, temperature_max)))
}

/// A temperature grid whose largest value is below this is normalised (Blender's Mantaflow,
/// max about 3; Houdini pyro's): --temperature-scale 1000, Cycles' default Temperature, as
/// Blender's Quick Smoke fire material reads it. At or above, it is taken as kelvin.
const KELVIN_LIKE_MIN: f32 = 100.0;

/// The emission grids of the file, read, and what they mean.
pub struct EmissionGrids {
    pub params: Emission,
    pub grid: Option<Volume<f32>>,
    pub temperature: Option<Volume<f32>>,
}

impl EmissionGrids {
    /// The field the engines look emission up in.
    pub fn field(&self) -> EmissionField<'_> {
        EmissionField { grid: self.grid.as_ref(), temperature: self.temperature.as_ref(), params: &self.params }
    }
}

/// A float grid's largest value, or None when the file has no non-empty float grid of that name.
fn grid_max(file: &VdbFile, name: &str) -> Result<Option<(Volume<f32>, f32)>, Failure> {
    if !file.has_grid(name) || file.grid(name).map(|g| g.kind != GridKind::Float).unwrap_or(true) {
        return Ok(None);
    }
    let (_, v) = read_density(file, Some(name))?;
    let max = v.peak().max(0.0);
    Ok((max > 0.0).then_some((v, max)))
}

/// What [`EmissionArgs::record`] writes for `--no-emission`.
const RECORD_OFF: &str = "off";

impl EmissionArgs {
    /// Whether any emission flag was given.
    fn any(&self) -> bool {
        self.no_emission
            || self.emission_grid.is_some()
            || self.emission_strength.is_some()
            || self.emission_color.is_some()
            || self.temperature_grid.is_some()
            || self.temperature_scale.is_some()
            || self.blackbody_intensity.is_some()
    }

    /// The explicit choice, as `nimbus:emission_flags` records it so that it travels down the
    /// chain as the medium does (issue #47): `off` for `--no-emission`, else the flags given,
    /// `grid=NAME;strength=S;color=R,G,B;temperature=NAME;scale=K;blackbody=B` (only those
    /// given; `;` and `%` in a grid name escaped as `%3B` and `%25`). None where no flag was
    /// given: a recognised fire is recognised again from the same grids downstream.
    pub fn record(&self) -> Option<String> {
        if self.no_emission {
            return Some(RECORD_OFF.into());
        }
        let escape = |n: &str| n.replace('%', "%25").replace(';', "%3B");
        let mut parts = Vec::new();
        if let Some(g) = &self.emission_grid {
            parts.push(format!("grid={}", escape(g)));
        }
        if let Some(s) = self.emission_strength {
            parts.push(format!("strength={s}"));
        }
        if let Some(c) = self.emission_color {
            parts.push(format!("color={},{},{}", c.x, c.y, c.z));
        }
        if let Some(g) = &self.temperature_grid {
            parts.push(format!("temperature={}", escape(g)));
        }
        if let Some(k) = self.temperature_scale {
            parts.push(format!("scale={k}"));
        }
        if let Some(b) = self.blackbody_intensity {
            parts.push(format!("blackbody={b}"));
        }
        (!parts.is_empty()).then(|| parts.join(";"))
    }

    /// Reads [`EmissionArgs::record`]'s text back.
    pub fn parse_record(text: &str) -> Result<EmissionArgs, String> {
        let mut args = EmissionArgs::default();
        if text == RECORD_OFF {
            args.no_emission = true;
            return Ok(args);
        }
        let unescape = |n: &str| n.replace("%3B", ";").replace("%25", "%");
        let number = |key: &str, v: &str| v.parse::<f32>().map_err(|_| format!("{key}={v} is not a number"));
        for part in text.split(';').filter(|p| !p.is_empty()) {
            let (key, value) = part.split_once('=').ok_or_else(|| format!("'{part}' is not key=value"))?;
            match key {
                "grid" => args.emission_grid = Some(unescape(value)),
                "strength" => args.emission_strength = Some(number(key, value)?),
                "color" => args.emission_color = Some(parse_rgb(value)?),
                "temperature" => args.temperature_grid = Some(unescape(value)),
                "scale" => args.temperature_scale = Some(number(key, value)?),
                "blackbody" => args.blackbody_intensity = Some(number(key, value)?),
                _ => return Err(format!("unknown key '{key}'")),
            }
        }
        Ok(args)
    }

    /// The flags over the choice an earlier tool recorded (`nimbus:emission_flags`), flag by
    /// flag, as the medium's flags go over its record; `--no-emission` on either side stands
    /// alone (a later tool's emission flags lift an earlier `--no-emission`). The second value
    /// says where the choice came from, for `-v`.
    pub fn over_record(&self, meta: &PipelineMeta) -> Result<(EmissionArgs, &'static str), Failure> {
        let Some(recorded) = meta.emission_flags()? else {
            return Ok((self.clone(), if self.any() { "flags" } else { "recognised from the grids" }));
        };
        if self.no_emission || (recorded.no_emission && self.any()) {
            return Ok((self.clone(), "flags"));
        }
        if recorded.no_emission {
            return Ok((recorded, "the input's record"));
        }
        let merged = EmissionArgs {
            emission_grid: self.emission_grid.clone().or(recorded.emission_grid),
            emission_strength: self.emission_strength.or(recorded.emission_strength),
            emission_color: self.emission_color.or(recorded.emission_color),
            temperature_grid: self.temperature_grid.clone().or(recorded.temperature_grid),
            temperature_scale: self.temperature_scale.or(recorded.temperature_scale),
            blackbody_intensity: self.blackbody_intensity.or(recorded.blackbody_intensity),
            no_emission: false,
        };
        Ok((merged, if self.any() { "flags over the input's record" } else { "the input's record" }))
    }

    /// The emission of the stage's file: the flags over what an earlier tool recorded
    /// ([`EmissionArgs::over_record`]), resolved by [`EmissionArgs::resolve`]; returns the
    /// merged flags too, for the tool to record in turn.
    pub fn resolve_over(&self, file: &VdbFile, meta: &PipelineMeta, log: &Log) -> Result<(Option<EmissionGrids>, EmissionArgs), Failure> {
        let (args, source) = self.over_record(meta)?;
        let grids = args.resolve(file, log)?;
        log.verbose(format!("emission: {} ({source})", grids.as_ref().map_or("none".to_string(), |g| g.params.describe())));
        Ok((grids, args))
    }

    /// The emission: from the flags, else recognised from the file's grids (Blender's
    /// `temperature` and `flame`, Houdini pyro's `temperature`, `heat`, `flame`), else none.
    /// Tools call [`EmissionArgs::resolve_over`], which puts the flags over the file's record.
    pub fn resolve(&self, file: &VdbFile, log: &Log) -> Result<Option<EmissionGrids>, Failure> {
        let args = self;
        if args.no_emission {
            return Ok(None);
        }
        let mut params = Emission::default();
        let read = |name: &str| -> Result<Volume<f32>, Failure> { read_density(file, Some(name)).map(|(_, v)| v) };
        let explicit = args.emission_grid.is_some() || args.temperature_grid.is_some();
        let (mut grid, mut temperature) = (None, None);
        if explicit {
            if let Some(name) = &args.emission_grid {
                grid = Some(read(name)?);
                params.grid = Some(name.clone());
                params.strength = args.emission_strength.unwrap_or(1.0);
                params.color = args.emission_color.unwrap_or(Vec3::ONE);
            }
            if let Some(name) = &args.temperature_grid {
                temperature = Some(read(name)?);
                params.temperature_grid = Some(name.clone());
                params.temperature_scale = args.temperature_scale.unwrap_or(1000.0);
                params.blackbody_intensity = args.blackbody_intensity.unwrap_or(1.0);
            }
        } else if let Some((flame, temperature_max)) = blender_fire(file)? {
            // Blender's domain renders its fire from the flame, not from the file's
            // `temperature` (Mantaflow's heat, which also fills the smoke above the flame):
            // T = ignition + flame (max - ignition) where flame > 0.01, else 0, in units
            // of Cycles' 1000 K (rna_fluid's temperature grid, what Quick Smoke's fire
            // material reads). Rendering the heat instead was 39% off Cycles' image of the
            // bundled fire; this 6.3% (docs/benchmarks.md).
            let (ignition, hottest) = BLENDER_FLAME_TEMPERATURE;
            let scale = args.temperature_scale.unwrap_or(1000.0);
            params.temperature_grid = Some(BLENDER_FLAME_GRID.into());
            params.temperature_scale = scale;
            params.blackbody_intensity = args.blackbody_intensity.unwrap_or(1.0);
            log.verbose(format!(
                "emission: recognised a Blender Mantaflow fire (grids 'flame' and normalised 'temperature', max {temperature_max:.3}): blackbody from the flame as Blender renders it, {ignition} + flame x {} units of {scale} K where flame > {BLENDER_FLAME_MIN} ({:.0} to {:.0} K), intensity {}; the file's 'temperature' (Mantaflow's heat) is not used (--temperature-grid temperature uses it; --no-emission turns emission off)",
                hottest - ignition,
                ignition * scale,
                hottest * scale,
                params.blackbody_intensity
            ));
            temperature = Some(flame.map(0.0, |f| if f > BLENDER_FLAME_MIN { ignition + f * (hottest - ignition) } else { 0.0 }));
        } else if let Some((v, max)) = grid_max(file, "temperature")? {
            let kelvin = max >= KELVIN_LIKE_MIN;
            params.temperature_grid = Some("temperature".into());
            params.temperature_scale = args.temperature_scale.unwrap_or(if kelvin { 1.0 } else { 1000.0 });
            params.blackbody_intensity = args.blackbody_intensity.unwrap_or(1.0);
            log.verbose(format!(
                "emission: recognised grid 'temperature' (max {max:.3}, {}): blackbody, {} K per unit (hottest {:.0} K), intensity {} (Blender's Quick Smoke fire; --no-emission turns it off)",
                if kelvin { "kelvin" } else { "normalised" },
                params.temperature_scale,
                max * params.temperature_scale,
                params.blackbody_intensity
            ));
            temperature = Some(v);
        } else {
            for name in ["flame", "heat"] {
                if let Some((v, max)) = grid_max(file, name)? {
                    params.grid = Some(name.into());
                    params.strength = args.emission_strength.unwrap_or(AUTO_FLAME_STRENGTH);
                    params.color = args.emission_color.unwrap_or_else(|| blackbody_rgb(AUTO_FLAME_KELVIN));
                    log.verbose(format!(
                        "emission: recognised grid '{name}' (max {max:.3}): strength {} x colour {:.3},{:.3},{:.3} (a {AUTO_FLAME_KELVIN} K blackbody's) x grid; --no-emission turns it off",
                        params.strength, params.color.x, params.color.y, params.color.z
                    ));
                    grid = Some(v);
                    break;
                }
            }
        }
        params.validate().map_err(Failure::usage)?;
        if !params.is_active() {
            let given = [
                (args.emission_strength.is_some(), "--emission-strength"),
                (args.emission_color.is_some(), "--emission-color"),
                (args.temperature_scale.is_some(), "--temperature-scale"),
                (args.blackbody_intensity.is_some(), "--blackbody-intensity"),
            ];
            for (_, flag) in given.iter().filter(|(g, _)| *g) {
                log.warn(format!("{flag} changes nothing: no emission (no fire grid recognised; name one with --emission-grid or --temperature-grid)"));
            }
            return Ok(None);
        }
        Ok(Some(EmissionGrids { params, grid, temperature }))
    }
}


#[cfg(test)]
mod tests {
    use super::*;

    fn args(f: impl FnOnce(&mut EmissionArgs)) -> EmissionArgs {
        let mut a = EmissionArgs::default();
        f(&mut a);
        a
    }

    /// The record reads back as the flags it was written from, a grid name with the
    /// separator in it included.
    #[test]
    fn the_record_reads_back_as_the_flags() {
        let given = args(|a| {
            a.emission_grid = Some("fl;a%me".into());
            a.emission_strength = Some(5.0);
            a.emission_color = Some(Vec3::new(1.0, 0.5, 0.2));
            a.temperature_grid = Some("temperature".into());
            a.temperature_scale = Some(800.0);
            a.blackbody_intensity = Some(0.25);
        });
        let text = given.record().unwrap();
        assert_eq!(text, "grid=fl%3Ba%25me;strength=5;color=1,0.5,0.2;temperature=temperature;scale=800;blackbody=0.25");
        let back = EmissionArgs::parse_record(&text).unwrap();
        assert_eq!(back.record().unwrap(), text);
        assert_eq!(back.emission_grid.as_deref(), Some("fl;a%me"));
        assert_eq!(EmissionArgs::parse_record("off").unwrap().no_emission, true);
        assert_eq!(args(|a| a.no_emission = true).record().as_deref(), Some("off"));
        assert!(EmissionArgs::default().record().is_none(), "no flags, no record: the grids are recognised again");
        assert!(EmissionArgs::parse_record("strength=x").is_err());
        assert!(EmissionArgs::parse_record("colour=1,1,1").is_err());
        assert!(EmissionArgs::parse_record("grid").is_err());
    }

    fn meta_with(record: Option<&str>) -> PipelineMeta {
        let mut file = VdbFile::new();
        if let Some(r) = record {
            file.set_metadata(crate::meta::EMISSION_FLAGS, r.to_string()).unwrap();
        }
        PipelineMeta::of(&file)
    }

    /// Flags go over the record flag by flag; `--no-emission` stands alone on either side.
    #[test]
    fn flags_go_over_the_record() {
        let recorded = meta_with(Some("grid=flame;strength=5;color=1,0.5,0.2"));
        let (merged, source) = EmissionArgs::default().over_record(&recorded).unwrap();
        assert_eq!(merged.record().as_deref(), Some("grid=flame;strength=5;color=1,0.5,0.2"));
        assert_eq!(source, "the input's record");
        let (merged, source) = args(|a| a.emission_strength = Some(2.0)).over_record(&recorded).unwrap();
        assert_eq!(merged.record().as_deref(), Some("grid=flame;strength=2;color=1,0.5,0.2"));
        assert_eq!(source, "flags over the input's record");
        let (merged, _) = args(|a| a.no_emission = true).over_record(&recorded).unwrap();
        assert!(merged.no_emission);
        let off = meta_with(Some("off"));
        assert!(EmissionArgs::default().over_record(&off).unwrap().0.no_emission, "an upstream --no-emission travels");
        let (lifted, _) = args(|a| a.emission_grid = Some("heat".into())).over_record(&off).unwrap();
        assert!(!lifted.no_emission && lifted.emission_grid.as_deref() == Some("heat"), "a later flag lifts it");
        let (none, source) = EmissionArgs::default().over_record(&meta_with(None)).unwrap();
        assert!(none.record().is_none());
        assert_eq!(source, "recognised from the grids");
        assert!(EmissionArgs::default().over_record(&meta_with(Some("nonsense"))).is_err(), "a bad record is an input error");
    }
}
