//! The rendered image and its files: RGBA float32 EXR with optional diagnostic layers, and an
//! 8-bit PNG preview through a view transform (AgX, Filmic or Standard; `view.rs`).

use std::io::Cursor;

use exr::prelude::{AnyChannel, AnyChannels, Encoding, FlatSamples, Layer, LayerAttributes, Vec2, WritableImage};
use glam::{Vec3, Vec4};

use crate::{RayResult, ViewTransform};

/// Puts a single-part EXR header's attributes in name order, in place.
///
/// The exr crate keeps header attributes in a hash map, so their order differs from run to
/// run; renders of the same frame must be byte-identical (design.md section 9), and OpenEXR
/// reads attributes in any order. The header's length does not change, so the offset table
/// after it stays valid.
fn sort_header_attributes(bytes: &mut [u8]) {
    const MULTIPART: u32 = 0x1000;
    if bytes.len() < 8 || u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]) & MULTIPART != 0 {
        return;
    }
    let cstr_end = |from: usize| bytes.get(from..)?.iter().position(|b| *b == 0).map(|i| from + i);
    let mut records: Vec<(usize, usize)> = Vec::new();
    let mut at = 8;
    while at < bytes.len() && bytes[at] != 0 {
        let Some(name_end) = cstr_end(at) else { return };
        let Some(type_end) = cstr_end(name_end + 1) else { return };
        let size_at = type_end + 1;
        let Some(size) = bytes.get(size_at..size_at + 4).map(|s| i32::from_le_bytes([s[0], s[1], s[2], s[3]])) else { return };
        let end = size_at + 4 + size.max(0) as usize;
        if size < 0 || end > bytes.len() {
            return;
        }
        records.push((at, end));
        at = end;
    }
    let name = |r: &[u8]| r[..r.iter().position(|b| *b == 0).unwrap_or(r.len())].to_vec();
    let mut sorted: Vec<&[u8]> = records.iter().map(|&(a, b)| &bytes[a..b]).collect();
    sorted.sort_by_key(|r| name(r));
    let header = sorted.concat();
    bytes[8..8 + header.len()].copy_from_slice(&header);
}

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
    /// Text attributes for the EXR header (`nimbus:` keys, e.g. `nimbus:emission`).
    pub metadata: Vec<(String, String)>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Aovs {
    pub single: Vec<Vec3>,
    pub multiple: Vec<Vec3>,
    pub transmittance: Vec<f32>,
    pub depth: Vec<f32>,
    /// The medium's own emission (RGB), written as the `emission` layer where any pixel
    /// has some.
    pub emission: Vec<Vec3>,
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
                let c = r.single + r.multiple + r.emission + r.behind + background * r.transmittance;
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
            emission: rays.iter().map(|r| finite3(r.emission)).collect(),
        });
        Image { width, height, rgba, aovs, nonfinite, metadata: Vec::new() }
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
            let emits = a.emission.iter().any(|e| *e != Vec3::ZERO);
            let layers = [("single", &a.single), ("multiple", &a.multiple), ("emission", &a.emission)];
            for (layer, values) in layers.into_iter().filter(|(name, _)| emits || *name != "emission") {
                channels.push(channel(&format!("{layer}.R"), values.iter().map(|v| v.x).collect()));
                channels.push(channel(&format!("{layer}.G"), values.iter().map(|v| v.y).collect()));
                channels.push(channel(&format!("{layer}.B"), values.iter().map(|v| v.z).collect()));
            }
            channels.push(channel("transmittance.Y", a.transmittance.clone()));
            channels.push(channel("depth.Z", a.depth.clone()));
        }
        let mut attributes = LayerAttributes::named("");
        for (key, value) in &self.metadata {
            attributes.other.insert(exr::meta::attribute::Text::from(key.as_str()), exr::meta::attribute::AttributeValue::Text(exr::meta::attribute::Text::from(value.as_str())));
        }
        let layer = Layer::new(
            size,
            attributes,
            Encoding::SMALL_LOSSLESS,
            AnyChannels::sort(channels.into()),
        );
        let image = exr::image::Image::from_layer(layer);
        let mut bytes = Cursor::new(Vec::new());
        image.write().to_buffered(&mut bytes).map_err(|e| ImageError::Exr(e.to_string()))?;
        let mut bytes = bytes.into_inner();
        sort_header_attributes(&mut bytes);
        Ok(bytes)
    }

    /// An 8-bit RGB PNG preview: the image's colour (already composited over the background,
    /// so over black by default; no alpha channel) scaled by 2^exposure and shown through
    /// `view` (Blender's view transforms, `view.rs`). The EXR stays scene-linear.
    pub fn to_png(&self, exposure: f32, view: ViewTransform) -> Result<Vec<u8>, ImageError> {
        let rgb: Vec<[f32; 3]> = self.rgba.iter().map(|p| [p.x, p.y, p.z]).collect();
        let data = view.encode_8bit(&rgb, exposure);
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
