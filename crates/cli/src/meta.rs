//! The pipeline's metadata: what each tool records under `nimbus:` keys in the file so the
//! next tool can use it as defaults (design.md section 6).
//!
//! Shared keys: `nimbus:medium`, `nimbus:lights`, `nimbus:environment`, `nimbus:camera` (each
//! in the text form the flags take), `nimbus:seed`, `nimbus:density_grid` (the grid the chain
//! treats as density), `nimbus:emission` (the medium's emission the file's light includes:
//! vdbphoton's photons leave from it, vdbcache's Li holds it scattered by the medium; `none`,
//! or `nimbus_optics::Emission::describe`'s text, as vdbmarch's EXR header records it).
//! Per tool: `nimbus:<tool>` holds `key=value` pairs of its parameters and counts, and
//! `nimbus:<tool>:timings` its stage times in seconds.

use nimbus_optics::{parse_lights, Camera, Environment, EnvironmentRecord, Light, Medium};
use nimbus_vdb::{MetaValue, Metadata, VdbFile};

use crate::{Failure, StageTimes};

pub const MEDIUM: &str = "nimbus:medium";
pub const LIGHTS: &str = "nimbus:lights";
pub const CAMERA: &str = "nimbus:camera";
pub const SEED: &str = "nimbus:seed";
pub const DENSITY_GRID: &str = "nimbus:density_grid";
pub const ENVIRONMENT: &str = "nimbus:environment";
pub const EMISSION: &str = "nimbus:emission";
/// The emission flags given to an earlier tool (`EmissionArgs::record`), so a later tool
/// takes the same choice over its own recognition of the grids (issue #47).
pub const EMISSION_FLAGS: &str = "nimbus:emission_flags";

/// A file's metadata, read as the pipeline's shared parameters.
pub struct PipelineMeta {
    meta: Metadata,
    file: String,
}

impl PipelineMeta {
    pub fn of(file: &VdbFile) -> PipelineMeta {
        PipelineMeta { meta: file.metadata(), file: file.label().to_string() }
    }

    pub fn empty() -> PipelineMeta {
        PipelineMeta { meta: Metadata::new(), file: String::new() }
    }

    fn text(&self, key: &str) -> Option<&str> {
        self.meta.get(key).and_then(MetaValue::as_str)
    }

    fn parsed<T>(&self, key: &str, parse: impl FnOnce(&str) -> Result<T, nimbus_optics::ParseError>) -> Result<Option<T>, Failure> {
        match self.text(key) {
            None => Ok(None),
            Some(s) => parse(s).map(Some).map_err(|e| Failure::input(format!("bad metadata {key}: {e}"), &self.file)),
        }
    }

    pub fn medium(&self) -> Result<Option<Medium>, Failure> {
        self.parsed(MEDIUM, str::parse)
    }

    pub fn lights(&self) -> Result<Option<Vec<Light>>, Failure> {
        self.parsed(LIGHTS, parse_lights)
    }

    pub fn camera(&self) -> Result<Option<Camera>, Failure> {
        self.parsed(CAMERA, str::parse)
    }

    /// The recorded environment (`none` or absent: none).
    pub fn environment(&self) -> Result<Option<EnvironmentRecord>, Failure> {
        Ok(self.parsed(ENVIRONMENT, Environment::parse_record)?.flatten())
    }

    pub fn seed(&self) -> Option<u64> {
        self.meta.get(SEED).and_then(MetaValue::as_i64).map(|s| s as u64)
    }

    pub fn density_grid(&self) -> Option<&str> {
        self.text(DENSITY_GRID)
    }

    /// The emission the file's light includes ([`EMISSION`]); None where no tool recorded one
    /// (files from before emission lit the medium: their light holds none).
    pub fn emission(&self) -> Option<&str> {
        self.text(EMISSION)
    }

    /// The emission flags an earlier tool was given ([`EMISSION_FLAGS`]).
    pub fn emission_flags(&self) -> Result<Option<crate::EmissionArgs>, Failure> {
        match self.text(EMISSION_FLAGS) {
            None => Ok(None),
            Some(s) => crate::EmissionArgs::parse_record(s).map(Some).map_err(|e| Failure::input(format!("bad metadata {EMISSION_FLAGS}: {e}"), &self.file)),
        }
    }

    /// A value from a tool's `key=value` record, e.g. `tool_value("vdbphoton", "distance")`.
    pub fn tool_value(&self, tool: &str, key: &str) -> Option<String> {
        let record = self.text(&format!("nimbus:{tool}"))?;
        record.split(',').filter_map(|kv| kv.split_once('=')).find(|(k, _)| *k == key).map(|(_, v)| v.to_string())
    }
}

/// Writes the shared keys and one tool's record into `file`.
pub struct MetaWriter<'a> {
    file: &'a mut VdbFile,
}

impl<'a> MetaWriter<'a> {
    pub fn new(file: &'a mut VdbFile) -> Self {
        MetaWriter { file }
    }

    fn set(&mut self, key: &str, value: impl Into<MetaValue>) -> Result<(), Failure> {
        self.file.set_metadata(key, value).map_err(|e| Failure::runtime(e, "metadata"))
    }

    pub fn medium(&mut self, medium: &Medium) -> Result<&mut Self, Failure> {
        self.set(MEDIUM, medium.to_string())?;
        Ok(self)
    }

    pub fn lights(&mut self, lights: &[Light]) -> Result<&mut Self, Failure> {
        self.set(LIGHTS, nimbus_optics::format_lights(lights))?;
        Ok(self)
    }

    /// `nimbus:environment`: its text form, or `none`.
    pub fn environment(&mut self, environment: Option<&Environment>) -> Result<&mut Self, Failure> {
        self.set(ENVIRONMENT, crate::environment::describe(environment))?;
        Ok(self)
    }

    pub fn camera(&mut self, camera: &Camera) -> Result<&mut Self, Failure> {
        self.set(CAMERA, camera.to_string())?;
        Ok(self)
    }

    pub fn seed(&mut self, seed: u64) -> Result<&mut Self, Failure> {
        self.set(SEED, seed as i64)?;
        Ok(self)
    }

    pub fn density_grid(&mut self, name: &str) -> Result<&mut Self, Failure> {
        self.set(DENSITY_GRID, name.to_string())?;
        Ok(self)
    }

    /// [`EMISSION`]: `describe` is `nimbus_optics::Emission::describe`'s text, or `none`.
    pub fn emission(&mut self, describe: &str) -> Result<&mut Self, Failure> {
        self.set(EMISSION, describe.to_string())?;
        Ok(self)
    }

    /// [`EMISSION_FLAGS`], where emission flags were given (to this tool or an earlier one).
    pub fn emission_flags(&mut self, args: &crate::EmissionArgs) -> Result<&mut Self, Failure> {
        if let Some(record) = args.record() {
            self.set(EMISSION_FLAGS, record)?;
        }
        Ok(self)
    }

    /// `nimbus:<tool>` = `k1=v1,k2=v2,...` and `nimbus:<tool>:timings`.
    pub fn tool(&mut self, tool: &str, record: &[(&str, String)], times: &StageTimes) -> Result<&mut Self, Failure> {
        let text = record.iter().map(|(k, v)| format!("{k}={v}")).collect::<Vec<_>>().join(",");
        self.set(&format!("nimbus:{tool}"), text)?;
        self.set(&format!("nimbus:{tool}:timings"), times.to_metadata())?;
        Ok(self)
    }
}
