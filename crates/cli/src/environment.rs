//! `--sky` and `--environment`: the World light of design.md section 4, read from flags or
//! from what an earlier tool recorded (`nimbus:environment`), and the map read from its EXR.

use std::path::{Path, PathBuf};

use clap::Args;
use glam::Vec3;
use nimbus_optics::{Environment, EnvironmentMap, EnvironmentRecord};

use crate::args::parse_rgb;
use crate::{Failure, Log, PipelineMeta};

/// `--sky`, `--environment`, `--environment-strength`, `--environment-rotation`,
/// `--no-environment`.
#[derive(Args, Debug, Clone, Default)]
#[command(next_help_heading = "Lights")]
pub struct EnvironmentArgs {
    /// Uniform sky radiance R,G,B (or one grey value) arriving from every direction, as a
    /// Blender World's Background colour. [default: what the input records, else none]
    #[arg(long, value_parser = parse_rgb, value_name = "R,G,B", conflicts_with = "environment")]
    pub sky: Option<Vec3>,
    /// An equirectangular HDR map (EXR, linear RGB) lighting the scene from every direction,
    /// mapped as Blender's World Environment Texture: +Z up, the image's centre looking
    /// along +X; its width should be twice its height (a warning says where it is not).
    /// [default: what the input records]
    #[arg(long, value_name = "FILE.exr")]
    pub environment: Option<PathBuf>,
    /// The map's strength (Blender's Background Strength). [default: what the input records,
    /// else 1]
    #[arg(long, value_name = "S", requires = "environment")]
    pub environment_strength: Option<f32>,
    /// Turns the map about +Z by DEG degrees, as a Mapping node's Z rotation in front of the
    /// Environment Texture. [default: what the input records, else 0]
    #[arg(long, value_name = "DEG", requires = "environment", allow_negative_numbers = true)]
    pub environment_rotation: Option<f32>,
    /// No environment light, even where the input records one.
    #[arg(long, conflicts_with_all = ["sky", "environment"])]
    pub no_environment: bool,
}

/// Reads an equirectangular map from an EXR file's first RGB(A) layer.
pub fn read_environment_map(path: &Path) -> Result<EnvironmentMap, Failure> {
    use exr::prelude::read_first_rgba_layer_from_file;
    let image = read_first_rgba_layer_from_file(
        path,
        |size, _| (size.width(), size.height(), vec![Vec3::ZERO; size.width() * size.height()]),
        |(width, _, texels): &mut (usize, usize, Vec<Vec3>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            texels[pos.y() * *width + pos.x()] = Vec3::new(r, g, b);
        },
    )
    .map_err(|e| Failure::input(format!("cannot read the environment map: {e}"), path.display()))?;
    let (width, height, texels) = image.layer_data.channel_data.pixels;
    EnvironmentMap::new(width as u32, height as u32, texels).map_err(|e| Failure::input(e, path.display()))
}

impl EnvironmentArgs {
    /// Whether a flag names an environment (or turns it off).
    pub fn given(&self) -> bool {
        self.sky.is_some() || self.environment.is_some() || self.no_environment
    }

    /// Flags, else what the file records, else none. A recorded map is read again from its
    /// recorded (absolute) path.
    pub fn resolve(&self, meta: &PipelineMeta, log: &Log, consistency: Option<&str>) -> Result<Option<Environment>, Failure> {
        let recorded = meta.environment()?;
        let environment = if self.no_environment {
            None
        } else if let Some(sky) = self.sky {
            Some(Environment::uniform(sky).map_err(|e| Failure::usage(format!("--sky: {e}")))?)
        } else if let Some(path) = &self.environment {
            let map = read_environment_map(path)?;
            // Only a flag's map draws the warning: later tools read the recorded one again.
            if map.width() != 2 * map.height() {
                log.warn(format!(
                    "the environment map is {} x {} pixels, not 2:1: it is read as an equirectangular (latitude-longitude) map all the same ({})",
                    map.width(),
                    map.height(),
                    path.display()
                ));
            }
            // Recorded absolute, so a later tool in another directory finds it.
            let absolute = std::fs::canonicalize(path).unwrap_or_else(|_| path.clone());
            let env = Environment::map(map, absolute.display().to_string(), self.environment_strength.unwrap_or(1.0), self.environment_rotation.unwrap_or(0.0))
                .map_err(|e| Failure::usage(format!("--environment: {e}")))?;
            Some(env)
        } else {
            match &recorded {
                None => None,
                Some(EnvironmentRecord::Uniform(c)) => Some(Environment::uniform(*c).map_err(|e| Failure::input(e, "nimbus:environment"))?),
                Some(EnvironmentRecord::Map { path, strength, rotation }) => {
                    let map = read_environment_map(Path::new(path))?;
                    Some(Environment::map(map, path.clone(), *strength, *rotation).map_err(|e| Failure::input(e, "nimbus:environment"))?)
                }
            }
        };
        if let (Some(what), true) = (consistency, self.given()) {
            if environment.as_ref().map(Environment::record) != recorded {
                log.warn(format!("the environment ({}) differs from the one {what}", describe(environment.as_ref())));
            }
        }
        if let Some(env) = &environment {
            log.verbose(format!("environment: {} ({})", env.describe(), crate::setting_source(self.given(), recorded.is_some())));
        }
        Ok(environment)
    }
}

/// The metadata text of an environment, or `none`.
pub fn describe(environment: Option<&Environment>) -> String {
    environment.map_or("none".into(), Environment::describe)
}

