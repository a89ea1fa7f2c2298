//! The pinhole camera (design.md section 4).
//!
//! Image plane convention: pixel (0,0) is the top-left; pixel (i,j) covers the continuous
//! pixel coordinates [i, i+1) x [j, j+1), so its centre is (i + 0.5, j + 0.5); x grows toward
//! image right = cross(forward, up), y grows downward. The horizontal field of view spans
//! x in [0, width]; pixels are square, so the vertical one follows from the aspect ratio.
//! Positions are f64 throughout: worlds from simulations sit far from their origin.

use std::fmt;
use std::str::FromStr;

use glam::{DVec2, DVec3};

use crate::params::{join, KeyValues, ParseError};

/// The largest image side and pixel count a camera accepts: 16K x 16K, twice 8K's width.
/// Beyond that the renderers' per-pixel buffers (tens of bytes a pixel) stop fitting in
/// memory and their size arithmetic could overflow, so such a size is refused up front.
pub const MAX_SIDE: u32 = 1 << 15;
pub const MAX_PIXELS: u64 = 1 << 28;

/// Why a camera was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    #[error("camera eye, look-at and up must be finite")]
    NotFinite,
    #[error("camera eye and look-at are the same point")]
    EyeAtLookAt,
    #[error("camera up ({}) is zero or parallel to the viewing direction", join(&.0.to_array()))]
    UpParallelToForward(DVec3),
    #[error("camera fov must be in (0,180) degrees, got {0}")]
    Fov(f64),
    #[error("camera image size must be at least 1x1, got {0}x{1}")]
    Size(u32, u32),
    #[error("camera image of {0}x{1} pixels is larger than {MAX_PIXELS} pixels or {MAX_SIDE} on a side")]
    TooLarge(u32, u32),
    #[error("bounding box is empty or not finite (min {}, max {})", join(&.0.to_array()), join(&.1.to_array()))]
    Bounds(DVec3, DVec3),
}

/// A pinhole camera. Built by [`Camera::new`] (validated) or parsed from
/// `eye=X,Y,Z,look-at=X,Y,Z,up=X,Y,Z,fov=DEG,width=W,height=H`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    eye: DVec3,
    look_at: DVec3,
    up: DVec3,
    fov_deg: f64,
    width: u32,
    height: u32,
    // Derived frame: forward, image right and image up are orthonormal.
    forward: DVec3,
    right: DVec3,
    image_up: DVec3,
    tan_half_fov_x: f64,
    tan_half_fov_y: f64,
}

/// Default field of view and image size (design.md section 4).
pub const DEFAULT_FOV_DEG: f64 = 40.0;
pub const DEFAULT_WIDTH: u32 = 960;
pub const DEFAULT_HEIGHT: u32 = 540;

impl Camera {
    pub fn new(eye: DVec3, look_at: DVec3, up: DVec3, fov_deg: f64, width: u32, height: u32) -> Result<Camera, CameraError> {
        if !(eye.is_finite() && look_at.is_finite() && up.is_finite()) {
            return Err(CameraError::NotFinite);
        }
        if !(fov_deg > 0.0 && fov_deg < 180.0) {
            return Err(CameraError::Fov(fov_deg));
        }
        if width == 0 || height == 0 {
            return Err(CameraError::Size(width, height));
        }
        if width > MAX_SIDE || height > MAX_SIDE || width as u64 * height as u64 > MAX_PIXELS {
            return Err(CameraError::TooLarge(width, height));
        }
        let forward = (look_at - eye).normalize_or_zero();
        if forward == DVec3::ZERO {
            return Err(CameraError::EyeAtLookAt);
        }
        // Relative test: |forward x up| / |up| = sin of the angle between them.
        let side = forward.cross(up);
        if side.length() <= 1e-9 * up.length() {
            return Err(CameraError::UpParallelToForward(up));
        }
        let right = side.normalize();
        let image_up = right.cross(forward);
        let tan_half_fov_x = (0.5 * fov_deg).to_radians().tan();
        let tan_half_fov_y = tan_half_fov_x * height as f64 / width as f64;
        Ok(Camera { eye, look_at, up, fov_deg, width, height, forward, right, image_up, tan_half_fov_x, tan_half_fov_y })
    }

    /// The default camera for a world bounding box (design.md section 4): from -Y looking at
    /// the box centre, Z up, fov 40, 960 x 540, as far back as needed for the whole box to be
    /// in view horizontally and vertically, with a 5% margin around it.
    ///
    /// For a box corner at offset o from the centre, seen from distance D along +Y, the corner
    /// is at depth D + o.y and in view when |o.x| <= tan_x (D + o.y) and
    /// |o.z| <= tan_y (D + o.y); D is the smallest distance satisfying that for all 8 corners
    /// (which also puts the eye outside the box). A box of zero size gets distance 1.
    pub fn default_for_bounds(min: DVec3, max: DVec3) -> Result<Camera, CameraError> {
        if !(min.is_finite() && max.is_finite()) || min.cmpgt(max).any() {
            return Err(CameraError::Bounds(min, max));
        }
        let centre = 0.5 * (min + max);
        let half = 0.5 * (max - min);
        let margin = 0.95;
        let tan_x = (0.5 * DEFAULT_FOV_DEG).to_radians().tan() * margin;
        let tan_y = tan_x * DEFAULT_HEIGHT as f64 / DEFAULT_WIDTH as f64;
        // The binding corners are those nearest the camera (o.y = -half.y).
        let distance = (half.x / tan_x).max(half.z / tan_y) + half.y;
        let distance = if distance > 0.0 { distance } else { 1.0 };
        Camera::new(centre - DVec3::Y * distance, centre, DVec3::Z, DEFAULT_FOV_DEG, DEFAULT_WIDTH, DEFAULT_HEIGHT)
    }

    pub fn eye(&self) -> DVec3 {
        self.eye
    }
    pub fn look_at(&self) -> DVec3 {
        self.look_at
    }
    /// The up vector as given (not orthogonalised).
    pub fn up(&self) -> DVec3 {
        self.up
    }
    pub fn fov_deg(&self) -> f64 {
        self.fov_deg
    }
    /// The width a pixel spans at `distance` from the eye (world units), at the image's
    /// centre.
    pub fn pixel_width_at(&self, distance: f64) -> f64 {
        2.0 * distance * self.tan_half_fov_x / self.width as f64
    }
    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
    /// Unit viewing direction.
    pub fn forward(&self) -> DVec3 {
        self.forward
    }
    /// Unit image right, cross(forward, up) normalised.
    pub fn right(&self) -> DVec3 {
        self.right
    }
    /// Unit image up, orthogonal to forward and right (the given up, orthogonalised).
    pub fn image_up(&self) -> DVec3 {
        self.image_up
    }
    /// tan of half the horizontal and vertical fields of view.
    pub fn tan_half_fov(&self) -> DVec2 {
        DVec2::new(self.tan_half_fov_x, self.tan_half_fov_y)
    }

    /// The ray through continuous pixel coordinates (px, py): origin the eye, unit direction.
    /// (px, py) = (i + 0.5, j + 0.5) is pixel (i, j)'s centre; a box filter draws px, py
    /// uniformly over [i, i+1) x [j, j+1).
    #[inline]
    pub fn ray(&self, px: f64, py: f64) -> (DVec3, DVec3) {
        let sx = (2.0 * px / self.width as f64 - 1.0) * self.tan_half_fov_x;
        let sy = (1.0 - 2.0 * py / self.height as f64) * self.tan_half_fov_y;
        (self.eye, (self.forward + sx * self.right + sy * self.image_up).normalize())
    }

    /// Continuous pixel coordinates of a world point, or `None` when it is not in front of
    /// the eye. The inverse of [`Camera::ray`]: `project(eye + t * ray(px, py).1) = (px, py)`.
    /// Points outside the image get coordinates outside [0,width] x [0,height].
    #[inline]
    pub fn project(&self, p: DVec3) -> Option<DVec2> {
        let d = p - self.eye;
        let depth = d.dot(self.forward);
        if depth.is_nan() || depth <= 0.0 {
            return None;
        }
        let sx = d.dot(self.right) / (depth * self.tan_half_fov_x);
        let sy = d.dot(self.image_up) / (depth * self.tan_half_fov_y);
        Some(DVec2::new(0.5 * (sx + 1.0) * self.width as f64, 0.5 * (1.0 - sy) * self.height as f64))
    }

    /// True when `p` projects inside the image (edges included) in front of the eye.
    #[inline]
    pub fn sees(&self, p: DVec3) -> bool {
        self.project(p).is_some_and(|q| q.x >= 0.0 && q.x <= self.width as f64 && q.y >= 0.0 && q.y <= self.height as f64)
    }

    /// Conservative frustum test for a sphere: false only when no part of the ball of
    /// `radius` around `centre` lies inside the view pyramid (four side planes through the
    /// eye, and the plane through the eye facing forward). What the cache baker uses to skip
    /// voxels: a voxel whose centre is out of view can still feed the trilinear lookups of
    /// visible samples, so it tests a ball covering the voxel's interpolation footprint.
    pub fn sees_sphere(&self, centre: DVec3, radius: f64) -> bool {
        let d = centre - self.eye;
        let z = d.dot(self.forward);
        if z < -radius {
            return false;
        }
        let x = d.dot(self.right);
        let y = d.dot(self.image_up);
        // Side plane |x| = tan * z has unit normal (1, -tan)/sqrt(1 + tan^2) in (x, z).
        let outside = |lateral: f64, tan: f64| (lateral.abs() - tan * z) / (1.0 + tan * tan).sqrt() > radius;
        !(outside(x, self.tan_half_fov_x) || outside(y, self.tan_half_fov_y))
    }
}

/// `eye=X,Y,Z,look-at=X,Y,Z,up=X,Y,Z,fov=DEG,width=W,height=H`, numbers in shortest
/// round-trip form.
impl fmt::Display for Camera {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "eye={},look-at={},up={},fov={},width={},height={}",
            join(&self.eye.to_array()),
            join(&self.look_at.to_array()),
            join(&self.up.to_array()),
            self.fov_deg,
            self.width,
            self.height
        )
    }
}

/// Reads [`Camera`]'s `Display` form. `eye` and `look-at` (or `look_at`) are required; `up`
/// defaults to 0,0,1, `fov` to 40, `width` x `height` to 960 x 540 (or `size=WxH`).
impl FromStr for Camera {
    type Err = ParseError;

    fn from_str(s: &str) -> Result<Camera, ParseError> {
        let mut kv = KeyValues::parse("camera", s)?;
        let eye = kv.dvec3("eye")?.ok_or_else(|| kv.error("eye=X,Y,Z is required"))?;
        let look_at = kv.dvec3("look-at")?.ok_or_else(|| kv.error("look-at=X,Y,Z is required"))?;
        let up = kv.dvec3("up")?.unwrap_or(DVec3::Z);
        let fov = kv.f64("fov")?.unwrap_or(DEFAULT_FOV_DEG);
        let (mut width, mut height) = (kv.u32("width")?, kv.u32("height")?);
        if let Some(size) = kv.take_raw("size") {
            let parsed = match size[..] {
                [text] => text.split_once('x').and_then(|(w, h)| Some((w.trim().parse::<u32>().ok()?, h.trim().parse::<u32>().ok()?))),
                _ => None,
            };
            let Some((w, h)) = parsed else { return Err(kv.error("size must be WIDTHxHEIGHT, e.g. size=960x540")) };
            if width.is_some() || height.is_some() {
                return Err(kv.error("give either size or width/height, not both"));
            }
            (width, height) = (Some(w), Some(h));
        }
        kv.finish("eye, look-at, up, fov, width, height, size")?;
        Camera::new(eye, look_at, up, fov, width.unwrap_or(DEFAULT_WIDTH), height.unwrap_or(DEFAULT_HEIGHT))
            .map_err(|e| ParseError { what: "camera", input: s.to_string(), reason: e.to_string() })
    }
}
