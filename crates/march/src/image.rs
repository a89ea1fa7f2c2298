//! The rendered image and its files: RGBA float32 EXR with optional diagnostic layers, and a
//! tone-mapped sRGB PNG preview.

use std::io::Cursor;

use exr::prelude::{AnyChannel, AnyChannels, Encoding, FlatSamples, Layer, LayerAttributes, Vec2, WritableImage};
use glam::{Vec3, Vec4};

use crate::RayResult;

/// A rendered image: premultiplied RGBA per pixel (A = 1 - transmittance), top row first,
/// plus the diagnostic layers when asked for.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<Vec4>,
    /// `single`, `multiple` (RGB), `transmittance` (Y) and `depth` (Z), when kept.
    pub aovs: Option<Aovs>,
    /// Pixels that came out non-finite and were written as zero.
    pub nonfinite: u64,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Aovs {
    pub single: Vec<Vec3>,
    pub multiple: Vec<Vec3>,
    pub transmittance: Vec<f32>,
    pub depth: Vec<f32>,
}

#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("EXR encoding failed: {0}")]
    Exr(String),
    #[error("PNG encoding failed: {0}")]
    Png(String),
}

impl Image {
    /// Composes per-pixel ray results over the background. Non-finite values never reach a
    /// file: they become zero and are counted.
    pub fn from_rays(width: u32, height: u32, rays: &[RayResult], background: Vec3, keep_aovs: bool) -> Image {
        let mut nonfinite = 0;
        let rgba = rays
            .iter()
            .map(|r| {
                let c = r.single + r.multiple + background * r.transmittance;
                let p = Vec4::new(c.x, c.y, c.z, 1.0 - r.transmittance);
                if p.is_finite() {
                    p
                } else {
                    nonfinite += 1;
                    Vec4::ZERO
                }
            })
            .collect();
        let finite3 = |v: Vec3| if v.is_finite() { v } else { Vec3::ZERO };
        let aovs = keep_aovs.then(|| Aovs {
            single: rays.iter().map(|r| finite3(r.single)).collect(),
            multiple: rays.iter().map(|r| finite3(r.multiple)).collect(),
            transmittance: rays.iter().map(|r| r.transmittance).collect(),
            // No opaque sample: the depth layer holds +inf would be "non-finite"; 0 is what
            // compositors treat as "nothing here" for Z.
            depth: rays.iter().map(|r| if r.depth.is_finite() { r.depth } else { 0.0 }).collect(),
        });
        Image { width, height, rgba, aovs, nonfinite }
    }

    /// The EXR file: one part, float32 channels R, G, B, A, and with the diagnostic layers
    /// `single.{R,G,B}`, `multiple.{R,G,B}`, `transmittance.Y`, `depth.Z` (the layer.channel
    /// naming Nuke, Blender and exrheader understand).
    pub fn to_exr(&self) -> Result<Vec<u8>, ImageError> {
        let size = Vec2(self.width as usize, self.height as usize);
        let channel = |name: &str, values: Vec<f32>| AnyChannel::new(name, FlatSamples::F32(values));
        let mut channels = vec![
            channel("R", self.rgba.iter().map(|p| p.x).collect()),
            channel("G", self.rgba.iter().map(|p| p.y).collect()),
            channel("B", self.rgba.iter().map(|p| p.z).collect()),
            channel("A", self.rgba.iter().map(|p| p.w).collect()),
        ];
        if let Some(a) = &self.aovs {
            for (layer, values) in [("single", &a.single), ("multiple", &a.multiple)] {
                channels.push(channel(&format!("{layer}.R"), values.iter().map(|v| v.x).collect()));
                channels.push(channel(&format!("{layer}.G"), values.iter().map(|v| v.y).collect()));
                channels.push(channel(&format!("{layer}.B"), values.iter().map(|v| v.z).collect()));
            }
            channels.push(channel("transmittance.Y", a.transmittance.clone()));
            channels.push(channel("depth.Z", a.depth.clone()));
        }
        let layer = Layer::new(
            size,
            LayerAttributes::named(""),
            Encoding::SMALL_LOSSLESS,
            AnyChannels::sort(channels.into()),
        );
        let image = exr::image::Image::from_layer(layer);
        let mut bytes = Cursor::new(Vec::new());
        image.write().to_buffered(&mut bytes).map_err(|e| ImageError::Exr(e.to_string()))?;
        Ok(bytes.into_inner())
    }

    /// An 8-bit sRGB PNG of the image over black, scaled by 2^exposure and tone-mapped by a
    /// simple Reinhard curve so highlights roll off instead of clipping.
    pub fn to_png(&self, exposure: f32) -> Result<Vec<u8>, ImageError> {
        let scale = exposure.exp2();
        let encode = |c: f32| {
            let v = c * scale;
            let v = if v.is_finite() { (v / (1.0 + v)).clamp(0.0, 1.0) } else { 0.0 };
            let s = if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
            (s * 255.0 + 0.5) as u8
        };
        let data: Vec<u8> = self.rgba.iter().flat_map(|p| [encode(p.x), encode(p.y), encode(p.z)]).collect();
        let mut out = Vec::new();
        {
            let mut encoder = png::Encoder::new(&mut out, self.width, self.height);
            encoder.set_color(png::ColorType::Rgb);
            encoder.set_depth(png::BitDepth::Eight);
            let mut writer = encoder.write_header().map_err(|e| ImageError::Png(e.to_string()))?;
            writer.write_image_data(&data).map_err(|e| ImageError::Png(e.to_string()))?;
        }
        Ok(out)
    }

    /// Mean of the RGB channels over all pixels.
    pub fn mean_rgb(&self) -> Vec3 {
        self.rgba.iter().map(|p| p.truncate()).sum::<Vec3>() / self.rgba.len().max(1) as f32
    }
}
