//! A [`Volume`] on the GPU: a brick atlas texture plus an indirection table, sampled by the
//! functions in `shaders/volume.wgsl` (whose header documents the layout in full).

use std::collections::HashSet;

use glam::{DAffine3, DMat4, DVec3, IVec3, UVec3, Vec3};
use nimbus_volume::{brick_offset, BrickRef, Volume, Voxel, BRICK_DIM, BRICK_LOG2};

use crate::{GpuContext, GpuError};

/// Edge of an atlas slot in texels: a brick plus its one-voxel high-side apron.
pub const SLOT_DIM: u32 = BRICK_DIM as u32 + 1;
/// Slot coordinates are packed in 10 bits per axis in a table entry.
const MAX_SLOTS_PER_AXIS: u32 = 1 << 10;
const SLOT_PRESENT: u32 = 1 << 31;

/// A voxel type that can live in an atlas texture.
pub trait GpuVoxel: Voxel {
    /// R32Float for scalars; Rgba32Float for vec3 (there is no 3-channel texture format, the
    /// fourth channel is unused, so a vec3 atlas takes 16 bytes a texel).
    const FORMAT: wgpu::TextureFormat;
    /// Floats per texel of `FORMAT`.
    const CHANNELS: usize;
    fn to_texel(self) -> [f32; 4];
    fn from_texel(texel: [f32; 4]) -> Self;
}

impl GpuVoxel for f32 {
    const FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
    const CHANNELS: usize = 1;
    fn to_texel(self) -> [f32; 4] {
        [self, 0.0, 0.0, 0.0]
    }
    fn from_texel(texel: [f32; 4]) -> Self {
        texel[0]
    }
}

impl GpuVoxel for Vec3 {
    const FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
    const CHANNELS: usize = 4;
    fn to_texel(self) -> [f32; 4] {
        self.extend(0.0).to_array()
    }
    fn from_texel(texel: [f32; 4]) -> Self {
        Vec3::new(texel[0], texel[1], texel[2])
    }
}

#[derive(Clone, Debug)]
pub struct GpuVolumeOptions {
    /// Upper bound on the dense indirection table (one u32 per brick of the bounding box of
    /// the bricks). Default 2^26 entries (256 MiB), a 400^3-brick (3200^3-voxel) box.
    pub max_table_entries: u64,
}

impl Default for GpuVolumeOptions {
    fn default() -> Self {
        GpuVolumeOptions { max_table_entries: 1 << 26 }
    }
}

/// The `VolumeInfo` parameters of `volume.wgsl`, field for field.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct VolumeInfo {
    /// Column-major (world - world_origin) -> index map.
    pub world_to_index: [[f32; 4]; 4],
    pub background: [f32; 4],
    pub table_origin: [i32; 3],
    _pad0: u32,
    pub table_dims: [i32; 3],
    _pad1: u32,
    pub inv_atlas_dims: [f32; 3],
    _pad2: u32,
    pub index_min: [i32; 3],
    _pad3: u32,
    pub index_max: [i32; 3],
    _pad4: u32,
}

impl VolumeInfo {
    /// This mirror's layout, for the stages' checks against their composed WGSL
    /// ([`crate::wgsl_layout`]).
    pub fn host_layout() -> crate::wgsl_layout::HostStruct {
        crate::host_layout!(VolumeInfo { world_to_index, background, table_origin, _pad0, table_dims, _pad1, inv_atlas_dims, _pad2, index_min, _pad3, index_max, _pad4 })
    }
}

/// Sizes of an uploaded volume, for `-v` and for tests.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AtlasStats {
    pub bricks: usize,
    /// Slots for absent bricks whose cells reach into present ones (see volume.wgsl).
    pub ghost_bricks: usize,
    pub slot_grid: UVec3,
    pub atlas_texels: UVec3,
    pub table_dims: UVec3,
    /// Atlas plus table, in bytes.
    pub bytes: u64,
}

/// A volume uploaded for sampling in stage shaders. Bind it with [`GpuVolume::bind_group`] at
/// group 0 (the default volume of `volume.wgsl`) or with [`GpuVolume::layout_entries`] and
/// [`GpuVolume::bind_group_entries`] anywhere else.
#[derive(Debug)]
pub struct GpuVolume {
    atlas: wgpu::TextureView,
    table: wgpu::TextureView,
    sampler: wgpu::Sampler,
    info_buffer: wgpu::Buffer,
    info: VolumeInfo,
    world_to_index: DAffine3,
    filterable: bool,
    channels: usize,
    stats: AtlasStats,
}

impl GpuVolume {
    /// Uploads `volume`. Fails with [`GpuError::VolumeLayout`] when the indirection table
    /// would exceed `options.max_table_entries` or the atlas the 3D texture limit, and with
    /// an out-of-memory or validation error when the device refuses the textures.
    pub fn upload<T: GpuVoxel>(ctx: &GpuContext, volume: &Volume<T>, options: &GpuVolumeOptions) -> Result<Self, GpuError> {
        let limits = ctx.limits();
        let plan = SlotPlan::new(volume);
        let (table_origin, table_dims) = plan.table_box();
        let table_entries = table_dims.as_u64vec3().element_product();
        if table_entries > options.max_table_entries {
            return Err(GpuError::VolumeLayout(format!(
                "its bricks span {}x{}x{} bricks, an indirection table of {table_entries} entries, over the budget of {}",
                table_dims.x, table_dims.y, table_dims.z, options.max_table_entries
            )));
        }
        if table_dims.max_element() > limits.max_texture_dimension_3d {
            return Err(GpuError::VolumeLayout(format!(
                "its bricks span {} bricks on one axis, over max_texture_dimension_3d = {}",
                table_dims.max_element(),
                limits.max_texture_dimension_3d
            )));
        }
        let slot_grid = slot_grid(plan.slots.len(), limits.max_texture_dimension_3d)?;
        let atlas_texels = slot_grid * SLOT_DIM;

        let filterable = ctx.float32_filterable();
        let (atlas, table) = ctx.scoped("volume upload", || {
            let atlas = create_texture_3d(ctx, "volume atlas", atlas_texels, T::FORMAT);
            write_atlas(ctx, &atlas, volume, &plan, slot_grid);
            let table = create_texture_3d(ctx, "volume table", table_dims, wgpu::TextureFormat::R32Uint);
            let entries = table_entries_packed(&plan, slot_grid, table_origin, table_dims);
            write_texture_3d(ctx, &table, UVec3::ZERO, table_dims, bytemuck::cast_slice(&entries));
            (atlas, table)
        })?;
        let sampler = ctx.device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("volume sampler"),
            mag_filter: if filterable { wgpu::FilterMode::Linear } else { wgpu::FilterMode::Nearest },
            min_filter: if filterable { wgpu::FilterMode::Linear } else { wgpu::FilterMode::Nearest },
            ..Default::default()
        });

        let (index_min, index_max) = volume.active_index_bbox().unwrap_or((IVec3::ZERO, IVec3::NEG_ONE));
        let world_to_index = volume.transform().world_to_index();
        let info = VolumeInfo {
            world_to_index: relative_world_to_index(world_to_index, DVec3::ZERO),
            background: volume.background().to_texel(),
            table_origin: table_origin.to_array(),
            table_dims: table_dims.as_ivec3().to_array(),
            inv_atlas_dims: (1.0 / atlas_texels.as_vec3()).to_array(),
            index_min: index_min.to_array(),
            index_max: index_max.to_array(),
            ..bytemuck::Zeroable::zeroed()
        };
        let info_buffer = ctx.params_buffer("volume info", &info)?;
        let texel_bytes = (T::CHANNELS * 4) as u64;
        let stats = AtlasStats {
            bricks: volume.brick_count(),
            ghost_bricks: plan.slots.len() - volume.brick_count(),
            slot_grid,
            atlas_texels,
            table_dims,
            bytes: atlas_texels.as_u64vec3().element_product() * texel_bytes + table_entries * 4,
        };
        Ok(GpuVolume {
            atlas: atlas.create_view(&Default::default()),
            table: table.create_view(&Default::default()),
            sampler,
            info_buffer,
            info,
            world_to_index,
            filterable,
            channels: T::CHANNELS,
            stats,
        })
    }

    pub fn info(&self) -> &VolumeInfo {
        &self.info
    }

    pub fn stats(&self) -> &AtlasStats {
        &self.stats
    }

    /// Whether `volume_sample_index_filtered` filters in hardware here (else it is exact).
    pub fn filterable(&self) -> bool {
        self.filterable
    }

    /// 1 for a scalar volume, 4 for a vec3 one (Rgba32Float).
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Uploads `volume`, or an empty one (all background 0) where there is none, for a stage
    /// that binds a volume it may not read; positions relative to world point `origin`.
    pub fn upload_or_empty<T: GpuVoxel>(ctx: &GpuContext, volume: Option<&Volume<T>>, origin: DVec3) -> Result<Self, GpuError> {
        let mut g = match volume {
            Some(v) => GpuVolume::upload(ctx, v, &GpuVolumeOptions::default())?,
            None => GpuVolume::upload(ctx, &Volume::new(nimbus_volume::Transform::uniform(1.0, DVec3::ZERO), T::default()), &GpuVolumeOptions::default())?,
        };
        g.set_world_origin(ctx, origin);
        Ok(g)
    }

    /// Makes `info.world_to_index` map `world - origin` to index space. f32 world positions
    /// lose precision far from 0 (a 1e5 offset leaves ~8 mm of resolution), so stages put
    /// the origin near the camera or the volume and pass positions relative to it.
    pub fn set_world_origin(&mut self, ctx: &GpuContext, origin: DVec3) {
        self.info.world_to_index = relative_world_to_index(self.world_to_index, origin);
        ctx.queue.write_buffer(&self.info_buffer, 0, bytemuck::bytes_of(&self.info));
    }

    /// Layout entries of a volume at bindings `base..base + 4` (atlas, table, sampler, info),
    /// the order `volume.wgsl` declares them in group 0. `filterable`: [`GpuContext::float32_filterable`].
    pub fn layout_entries(base: u32, filterable: bool) -> [wgpu::BindGroupLayoutEntry; 4] {
        let entry = |offset: u32, ty| wgpu::BindGroupLayoutEntry {
            binding: base + offset,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty,
            count: None,
        };
        let texture = |sample_type| wgpu::BindingType::Texture {
            sample_type,
            view_dimension: wgpu::TextureViewDimension::D3,
            multisampled: false,
        };
        [
            entry(0, texture(wgpu::TextureSampleType::Float { filterable })),
            entry(1, texture(wgpu::TextureSampleType::Uint)),
            entry(
                2,
                wgpu::BindingType::Sampler(if filterable {
                    wgpu::SamplerBindingType::Filtering
                } else {
                    wgpu::SamplerBindingType::NonFiltering
                }),
            ),
            entry(
                3,
                wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only: true },
                    has_dynamic_offset: false,
                    min_binding_size: wgpu::BufferSize::new(size_of::<VolumeInfo>() as u64),
                },
            ),
        ]
    }

    pub fn bind_group_entries(&self, base: u32) -> [wgpu::BindGroupEntry<'_>; 4] {
        [
            wgpu::BindGroupEntry { binding: base, resource: wgpu::BindingResource::TextureView(&self.atlas) },
            wgpu::BindGroupEntry { binding: base + 1, resource: wgpu::BindingResource::TextureView(&self.table) },
            wgpu::BindGroupEntry { binding: base + 2, resource: wgpu::BindingResource::Sampler(&self.sampler) },
            wgpu::BindGroupEntry { binding: base + 3, resource: self.info_buffer.as_entire_binding() },
        ]
    }

    /// The layout of group 0 (the default volume) for this device.
    pub fn bind_group_layout(ctx: &GpuContext) -> Result<wgpu::BindGroupLayout, GpuError> {
        ctx.bind_group_layout("volume", &Self::layout_entries(0, ctx.float32_filterable()))
    }

    /// This volume as group 0, for a layout from [`GpuVolume::bind_group_layout`].
    pub fn bind_group(&self, ctx: &GpuContext, layout: &wgpu::BindGroupLayout) -> Result<wgpu::BindGroup, GpuError> {
        ctx.scoped("volume bind group", || {
            ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("volume"),
                layout,
                entries: &self.bind_group_entries(0),
            })
        })
    }
}

fn relative_world_to_index(world_to_index: DAffine3, origin: DVec3) -> [[f32; 4]; 4] {
    // Composed in f64, rounded once.
    DMat4::from(world_to_index * DAffine3::from_translation(origin)).as_mat4().to_cols_array_2d()
}

/// Which bricks get an atlas slot: every brick of the volume, then the "ghost" bricks
/// (absent, but with a present brick among their high-side neighbours, so cells starting
/// in them reach into present bricks).
struct SlotPlan<'a, T> {
    /// Brick coordinate (origin >> 3) and the brick when it is present.
    slots: Vec<(IVec3, Option<BrickRef<'a, T>>)>,
}

impl<'a, T: Voxel> SlotPlan<'a, T> {
    fn new(volume: &'a Volume<T>) -> Self {
        let mut slots: Vec<(IVec3, Option<BrickRef<'a, T>>)> =
            volume.bricks().map(|b| (b.origin >> BRICK_LOG2 as i32, Some(b))).collect();
        let present: HashSet<IVec3> = slots.iter().map(|(c, _)| *c).collect();
        let mut ghosts: Vec<IVec3> = present
            .iter()
            .flat_map(|&c| (1..8).map(move |n| c - IVec3::new(n >> 2, (n >> 1) & 1, n & 1)))
            .filter(|g| !present.contains(g))
            .collect::<HashSet<_>>()
            .into_iter()
            .collect();
        // Deterministic atlas contents whatever the hash order.
        ghosts.sort_by_key(|g| (g.z, g.y, g.x));
        slots.extend(ghosts.into_iter().map(|g| (g, None)));
        SlotPlan { slots }
    }

    /// Brick-coordinate origin and size of the indirection table (1^3 for an empty volume).
    fn table_box(&self) -> (IVec3, UVec3) {
        let Some(first) = self.slots.first() else {
            return (IVec3::ZERO, UVec3::ONE);
        };
        let (lo, hi) = self.slots.iter().fold((first.0, first.0), |(lo, hi), (c, _)| (lo.min(*c), hi.max(*c)));
        (lo, (hi - lo + IVec3::ONE).as_uvec3())
    }
}

/// Slots per axis for `count` slots: near-cubic, each axis within the 3D texture limit.
fn slot_grid(count: usize, max_texture_dim: u32) -> Result<UVec3, GpuError> {
    let per_axis = u64::from((max_texture_dim / SLOT_DIM).min(MAX_SLOTS_PER_AXIS));
    let n = count.max(1) as u64;
    let x = ((n as f64).cbrt().ceil() as u64).clamp(1, per_axis);
    let y = ((n.div_ceil(x) as f64).sqrt().ceil() as u64).clamp(1, per_axis);
    let z = n.div_ceil(x * y);
    if z > per_axis {
        return Err(GpuError::VolumeLayout(format!(
            "{count} brick slots exceed the atlas capacity of {per_axis}^3 slots (max_texture_dimension_3d = {max_texture_dim})"
        )));
    }
    Ok(UVec3::new(x as u32, y as u32, z as u32))
}

fn slot_coord(slot: usize, grid: UVec3) -> UVec3 {
    let s = slot as u32;
    UVec3::new(s % grid.x, (s / grid.x) % grid.y, s / (grid.x * grid.y))
}

fn table_entries_packed<T>(plan: &SlotPlan<'_, T>, grid: UVec3, table_origin: IVec3, table_dims: UVec3) -> Vec<u32> {
    let mut entries = vec![0u32; table_dims.as_u64vec3().element_product() as usize];
    for (slot, (brick, _)) in plan.slots.iter().enumerate() {
        let t = (*brick - table_origin).as_uvec3();
        let s = slot_coord(slot, grid);
        entries[((t.z * table_dims.y + t.y) * table_dims.x + t.x) as usize] = SLOT_PRESENT | s.x | (s.y << 10) | (s.z << 20);
    }
    entries
}

/// Fills the atlas one layer of slots at a time, so host memory stays at one layer.
fn write_atlas<T: GpuVoxel>(ctx: &GpuContext, atlas: &wgpu::Texture, volume: &Volume<T>, plan: &SlotPlan<'_, T>, grid: UVec3) {
    let layer_texels = UVec3::new(grid.x * SLOT_DIM, grid.y * SLOT_DIM, SLOT_DIM);
    let row = layer_texels.x as usize;
    let image = row * layer_texels.y as usize;
    let slots_per_layer = (grid.x * grid.y) as usize;
    let background = volume.background();
    let d = SLOT_DIM as i32;
    for (layer, slots) in plan.slots.chunks(slots_per_layer).enumerate() {
        let mut data = vec![0f32; image * SLOT_DIM as usize * T::CHANNELS];
        for (i, (brick, present)) in slots.iter().enumerate() {
            let s = slot_coord(layer * slots_per_layer + i, grid);
            let origin = *brick << BRICK_LOG2 as i32;
            for z in 0..d {
                for y in 0..d {
                    for x in 0..d {
                        let local = IVec3::new(x, y, z);
                        let value = if local.max_element() < BRICK_DIM {
                            present.map_or(background, |b| b.values[brick_offset(local)])
                        } else {
                            volume.get(origin + local)
                        };
                        let texel = z as usize * image + (s.y * SLOT_DIM) as usize * row + y as usize * row + (s.x * SLOT_DIM) as usize + x as usize;
                        data[texel * T::CHANNELS..(texel + 1) * T::CHANNELS].copy_from_slice(&value.to_texel()[..T::CHANNELS]);
                    }
                }
            }
        }
        write_texture_3d(ctx, atlas, UVec3::new(0, 0, layer as u32 * SLOT_DIM), layer_texels, bytemuck::cast_slice(&data));
    }
}

fn create_texture_3d(ctx: &GpuContext, label: &str, size: UVec3, format: wgpu::TextureFormat) -> wgpu::Texture {
    ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d { width: size.x, height: size.y, depth_or_array_layers: size.z },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D3,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    })
}

/// Writes a tightly packed box of texels (x fastest) at `origin`.
fn write_texture_3d(ctx: &GpuContext, texture: &wgpu::Texture, origin: UVec3, size: UVec3, data: &[u8]) {
    let texel_bytes = data.len() as u32 / size.element_product();
    ctx.queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d { x: origin.x, y: origin.y, z: origin.z },
            aspect: wgpu::TextureAspect::All,
        },
        data,
        wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(size.x * texel_bytes), rows_per_image: Some(size.y) },
        wgpu::Extent3d { width: size.x, height: size.y, depth_or_array_layers: size.z },
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slot_grid_holds_every_slot_within_the_texture_limit() {
        for count in [0, 1, 2, 27, 28, 1000, 8550, 100_000] {
            let g = slot_grid(count, 2048).unwrap();
            assert!(g.element_product() as usize >= count.max(1), "{count} -> {g}");
            assert!(g.max_element() * SLOT_DIM <= 2048, "{count} -> {g}");
        }
        assert!(matches!(slot_grid(227usize.pow(3) + 1, 2048), Err(GpuError::VolumeLayout(_))));
    }

    #[test]
    fn slot_coordinates_are_unique() {
        let grid = UVec3::new(3, 4, 5);
        let coords: HashSet<UVec3> = (0..60).map(|s| slot_coord(s, grid)).collect();
        assert_eq!(coords.len(), 60);
        assert!(coords.iter().all(|c| c.cmplt(grid).all()));
    }

    #[test]
    fn info_matches_the_wgsl_struct() {
        // As every stage composes volume.wgsl (PointSampler's source here), on both kinds of adapter.
        for filterable in [false, true] {
            crate::wgsl_layout::check_layouts(&crate::sampler::sampler_source(filterable).unwrap(), &[("VolumeInfo", VolumeInfo::host_layout())]);
        }
        assert_eq!(size_of::<VolumeInfo>(), 160);
    }
}
