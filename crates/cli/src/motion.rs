//! Motion blur flags (issue #20; design.md section 4): vdbmarch's march and `--reference`
//! blur the medium along a velocity grid, Eulerian as Cycles and Arnold blur volumes.
//!
//! [`MotionArgs::resolve`] finds the velocity grid (`--velocity-grid`, else the first of
//! OpenVDB's and Houdini's `v`, Houdini's `vel` and Blender's `velocity`), scales it to world
//! units per second and gives the shutter in seconds (`--shutter` frames over `--fps`,
//! centred on the frame as Blender's default Center position).

use clap::Args;
use glam::Vec3;
use nimbus_vdb::{GridKind, VdbFile};
use nimbus_volume::Volume;

use crate::{Failure, Log};

/// The names a velocity grid goes by, in the order they are looked for.
pub const VELOCITY_GRIDS: [&str; 3] = ["v", "vel", "velocity"];

#[derive(Args, Debug, Clone)]
#[command(next_help_heading = "Camera")]
pub struct MotionArgs {
    /// Blur the medium along its velocity grid over the shutter (Eulerian motion blur: each
    /// camera sample looks the volume up at its position moved back along the velocity).
    #[arg(long)]
    pub motion_blur: bool,
    /// Shutter time in frames, centred on the frame (Blender's Shutter). [default: 0.5]
    #[arg(long, requires = "motion_blur")]
    pub shutter: Option<f64>,
    /// Frames per second. [default: 24]
    #[arg(long, requires = "motion_blur")]
    pub fps: Option<f64>,
    /// The velocity grid, a vec3 grid. [default: v, vel or velocity, the first present]
    #[arg(long, requires = "motion_blur")]
    pub velocity_grid: Option<String>,
    /// Multiplies the velocity grid to world units per second (1: the grid is in world units
    /// per second, as Houdini's and OpenVDB's; the fps for a grid per frame). [default: 1]
    #[arg(long, requires = "motion_blur")]
    pub velocity_scale: Option<f64>,
}

/// What the render blurs over: the velocity, in world units per second, and the shutter.
pub struct Velocity {
    pub grid: String,
    pub volume: Volume<Vec3>,
    /// Seconds the shutter is open.
    pub shutter: f64,
    pub fps: f64,
    pub scale: f64,
}

impl Velocity {
    /// The engines' view of it.
    pub fn blur(&self) -> nimbus_tracking::MotionBlur<'_> {
        nimbus_tracking::MotionBlur { velocity: &self.volume, shutter: self.shutter }
    }

    /// The `nimbus:motion_blur` record: `grid=NAME,shutter=FRAMES,fps=F,scale=S`.
    pub fn describe(&self) -> String {
        format!("grid={},shutter={},fps={},scale={}", self.grid, self.shutter * self.fps, self.fps, self.scale)
    }
}

impl MotionArgs {
    /// The velocity and shutter with `--motion-blur`, else None.
    pub fn resolve(&self, file: &VdbFile, log: &Log) -> Result<Option<Velocity>, Failure> {
        if !self.motion_blur {
            return Ok(None);
        }
        let frames = self.shutter.unwrap_or(0.5);
        let fps = self.fps.unwrap_or(24.0);
        let scale = self.velocity_scale.unwrap_or(1.0);
        if !(frames.is_finite() && frames >= 0.0) {
            return Err(Failure::usage(format!("--shutter must be finite and >= 0 frames, got {frames}")));
        }
        if !(fps.is_finite() && fps > 0.0) {
            return Err(Failure::usage(format!("--fps must be finite and > 0, got {fps}")));
        }
        if !scale.is_finite() {
            return Err(Failure::usage(format!("--velocity-scale must be finite, got {scale}")));
        }
        let vec3_grids: Vec<String> =
            file.grids().map_err(|e| Failure::input(e, file.label()))?.into_iter().filter(|g| g.kind == GridKind::Vec3).map(|g| g.name).collect();
        let name = match &self.velocity_grid {
            Some(name) => name.clone(),
            None => VELOCITY_GRIDS.iter().find(|n| vec3_grids.iter().any(|g| g == *n)).map(|n| n.to_string()).ok_or_else(|| {
                Failure::input(
                    format!("--motion-blur needs a velocity grid (v, vel or velocity; name one with --velocity-grid); the vec3 grids are: {}", list(&vec3_grids)),
                    file.label(),
                )
            })?,
        };
        let Some(mut volume) = crate::read_vec3_grid(file, &name)? else {
            return Err(Failure::input(format!("no grid '{name}' for --velocity-grid; the vec3 grids are: {}", list(&vec3_grids)), file.label()));
        };
        // Non-finite velocities would send lookups nowhere: they are set to zero, and said.
        let bad = std::sync::atomic::AtomicUsize::new(0);
        let background = volume.background() * scale as f32;
        volume = volume.map(if background.is_finite() { background } else { Vec3::ZERO }, |v| {
            let v = v * scale as f32;
            if v.is_finite() {
                v
            } else {
                bad.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                Vec3::ZERO
            }
        });
        let nonfinite = bad.into_inner();
        if nonfinite > 0 {
            log.warn(format!("velocity grid '{name}': {nonfinite} non-finite values set to zero"));
        }
        let velocity = Velocity { grid: name, volume, shutter: frames / fps, fps, scale };
        let speed = velocity.blur().max_speed();
        log.verbose(format!(
            "motion blur: velocity grid '{}' (fastest {speed:.4} world units a second), shutter {frames} frames at {fps} fps = {:.5} s: the medium moves up to {:.4} world units",
            velocity.grid,
            velocity.shutter,
            speed * velocity.shutter
        ));
        Ok(Some(velocity))
    }
}

fn list(names: &[String]) -> String {
    if names.is_empty() {
        "none".into()
    } else {
        names.join(", ")
    }
}
