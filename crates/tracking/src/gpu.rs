//! The GPU side of this crate: `shaders/tracking.wgsl` (the WGSL twin of the majorant DDA and
//! the free-path samplers) and the host data it reads, shared by every stage shader that
//! walks rays through the density; `shaders/path.wgsl` (the twin of [`crate::trace_path`]),
//! shared by the reference path tracer and vdbcache's path-traced multiple scattering; and
//! the lights' tables: [`GpuLightTables`] builds them (`shaders/optical_depth.wgsl`, the twin
//! of [`crate::ray_optical_depths`]) and binds them for lookups (`shaders/light_tables.wgsl`,
//! the twin of [`crate::OpticalDepthVolume::transmittance`]).

use bytemuck::{Pod, Zeroable};
use glam::{DAffine3, DMat4, DVec3, IVec3};
use nimbus_gpu::wgsl_layout::HostStruct;
use nimbus_gpu::{host_layout, storage_entry, params_entry, wgpu, GpuContext, GpuError, GpuVolume, LoopGuard, ShaderComposer};
use nimbus_optics::{blackbody_table, GpuEmissionInfo, Light, ENVIRONMENT_WGSL, OPTICS_WGSL};
use nimbus_volume::{MajorantGrid, BRICK_LOG2, BRICK_VOXELS};

use crate::{DensityMedium, LightDepths, LightLattice, LightTablePlan, OpticalDepthVolume};

/// `shaders/tracking.wgsl`: plain functions, no bindings; stage shaders concatenate it.
pub const TRACKING_WGSL: &str = include_str!("../../../shaders/tracking.wgsl");

/// `shaders/path.wgsl`: `trace_path` and its constants, no bindings; composed after
/// [`TRACKING_WGSL`] by a stage shader that provides `fn path_light(index: u32) -> Light`
/// and `fn light_table_lookup(light: u32, x: vec3<f32>) -> vec2<f32>` (the tabled transmittance and
/// the shadow ray's weight, [`crate::TabledTransmittance`]): [`light_tables_wgsl`]
/// ([`crate::Shadowing::Tabled`]) or [`NO_LIGHT_TABLES_WGSL`] ([`crate::Shadowing::RatioTracked`]).
pub const PATH_WGSL: &str = include_str!("../../../shaders/path.wgsl");

/// `shaders/light_tables.wgsl`, composed by [`light_tables_wgsl`].
const LIGHT_TABLES_WGSL: &str = include_str!("../../../shaders/light_tables.wgsl");

/// `shaders/light_tables.wgsl` after the brick layout it indexes nodes by, generated from
/// nimbus_volume's so the two cannot drift apart: the lights' tables at group 2
/// ([`GpuLightTables::layout`]) and `light_table_lookup`, their lookup; composed
/// after the volume.
pub fn light_tables_wgsl() -> String {
    let [from, to] = crate::TABLED_SPREAD;
    let [single_from, single_to] = crate::SINGLE_SPREAD;
    let floor = crate::ALONG_RAY_FLOOR;
    format!(
        "const LIGHT_TABLE_BRICK_LOG2: u32 = {BRICK_LOG2}u;\nconst LIGHT_TABLE_SPREAD: vec2<f32> = vec2<f32>({from:?}, {to:?});\nconst LIGHT_TABLE_SINGLE_SPREAD: vec2<f32> = vec2<f32>({single_from:?}, {single_to:?});\nconst LIGHT_TABLE_ALONG_FLOOR: f32 = {floor:?};\n{LIGHT_TABLES_WGSL}"
    )
}

/// What a stage whose paths ratio-track every light composes in place of
/// [`light_tables_wgsl`] (the reference path tracer: [`crate::Shadowing::RatioTracked`]): no
/// light has a table, and no bindings.
pub const NO_LIGHT_TABLES_WGSL: &str = "fn light_table_lookup(light: u32, x: vec3<f32>) -> vec2<f32> {\n    return vec2<f32>(1.0, 1.0);\n}\n";

/// `shaders/optical_depth.wgsl`: the kernel [`GpuLightTables::build`] integrates the lattice
/// rays with.
pub const OPTICAL_DEPTH_WGSL: &str = include_str!("../../../shaders/optical_depth.wgsl");

/// WGSL `MajorantGridInfo` (tracking.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GpuMajorantInfo {
    pub origin: [i32; 3],
    pub cell_size: f32,
    pub dims: [i32; 3],
    pub outside: f32,
}

impl GpuMajorantInfo {
    /// `outside` is the bound beyond the grid: the volume's background.
    pub fn new(grid: &MajorantGrid, outside: f32) -> Self {
        GpuMajorantInfo { origin: grid.origin().to_array(), cell_size: grid.cell_size() as f32, dims: grid.dims().to_array(), outside }
    }
}

/// The majorant bounds as a storage buffer (one dummy value for an empty grid: bindings
/// cannot be empty).
pub fn majorant_buffer(ctx: &GpuContext, grid: &MajorantGrid) -> Result<wgpu::Buffer, GpuError> {
    if grid.values().is_empty() {
        ctx.storage_buffer("majorant", &[0f32])
    } else {
        ctx.storage_buffer("majorant", grid.values())
    }
}

/// WGSL `LightTable` (light_tables.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuLightTable {
    world_to_lattice: [[f32; 4]; 4],
    brick_min: [i32; 3],
    index_first: u32,
    brick_dims: [i32; 3],
    tabled: u32,
}

/// WGSL `LightRays` (optical_depth.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuLightRays {
    across_i: [f32; 3],
    step: f32,
    across_j: [f32; 3],
    extinction: f32,
    along: [f32; 3],
    opaque_depth: f32,
    dir: [f32; 3],
    light: u32,
    grid: GpuMajorantInfo,
    first_ray: u32,
    ray_count: u32,
    _pad: [u32; 2],
}

/// WGSL `LightColumn` (optical_depth.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuLightColumn {
    x: i32,
    y: i32,
    k0: i32,
    nodes: u32,
}

/// Rays of a lattice brick column: 8 x 8.
const COLUMN_RAYS: u64 = (1 << (2 * BRICK_LOG2)) as u64;
/// Rays per dispatch: bounds how long one submission runs (drivers reset long ones).
const RAYS_PER_DISPATCH: u64 = 1 << 15;
/// Most entries of all lights' dense brick indices together: 256 MiB, as
/// `GpuVolumeOptions`' default bounds a volume's indirection table.
const MAX_INDEX_ENTRIES: u64 = 1 << 26;
/// Group 1 binding of the build's [`LoopGuard`] flag (after its three buffers).
const GUARD_BINDING: u32 = 3;

/// Every light's tabled transmittance on the GPU, the twin of [`LightDepths`]: each tabled
/// light's [`LightTablePlan`] (decided on the host, as the CPU decides it), its nodes in one
/// storage buffer for all lights, a dense brick index per light and a [`GpuLightTable`] per
/// light (its world-to-lattice map), so the bindings do not depend on the light count.
/// Bind it at group 2 of a stage that composes [`light_tables_wgsl`].
pub struct GpuLightTables {
    tables: wgpu::Buffer,
    index: wgpu::Buffer,
    nodes: wgpu::Buffer,
    /// Per light: its plan and its first brick in `nodes`, where it has a table.
    plans: Vec<Option<(LightTablePlan, usize)>>,
    opaque_depth: f64,
}

impl GpuLightTables {
    /// No light of `light_count` has a table: lookups say so and callers trace shadow rays.
    pub fn none(ctx: &GpuContext, light_count: usize) -> Result<GpuLightTables, GpuError> {
        Self::upload(ctx, (0..light_count).map(|_| None).collect(), DVec3::ZERO, 0.0)
    }

    /// Tables each light [`LightDepths::build`] tables, on the GPU: `density` is `medium`'s
    /// density uploaded, `origin` the world origin lookups' positions are relative to.
    /// [`GpuLightTables::read`] then holds what [`LightDepths::build`] holds, to f32 rounding.
    #[allow(clippy::too_many_arguments)]
    pub fn build(
        ctx: &GpuContext,
        density: &GpuVolume,
        medium: DensityMedium,
        lights: &[Light],
        lattice: LightLattice,
        opaque_depth: f64,
        origin: DVec3,
    ) -> Result<GpuLightTables, GpuError> {
        let plans: Vec<Option<LightTablePlan>> =
            lights.iter().map(|light| LightDepths::tabled_direction(light).map(|dir| LightTablePlan::new(medium.density, dir, lattice))).collect();
        let tables = Self::upload(ctx, plans, origin, opaque_depth)?;
        if tables.plans.iter().flatten().all(|(plan, _)| plan.brick_count() == 0) {
            return Ok(tables);
        }
        let volume_layout = GpuVolume::bind_group_layout(ctx)?;
        let volume_group = density.bind_group(ctx, &volume_layout)?;
        let guard = LoopGuard::new(ctx, GUARD_BINDING)?;
        let layout = ctx.bind_group_layout("light rays", &[params_entry(0), storage_entry(1, true), storage_entry(2, true), guard.layout_entry()])?;
        let tables_layout = Self::layout(ctx)?;
        let tables_group = tables.bind_group(ctx, &tables_layout)?;
        let source = light_rays_source(ctx.float32_filterable(), guard.enabled())?;
        let pipeline = ctx.compute_pipeline("light rays", &source, "integrate_light_rays", &[&volume_layout, &layout, &tables_layout])?;
        let majorant = majorant_buffer(ctx, medium.majorant)?;
        let grid = GpuMajorantInfo::new(medium.majorant, medium.density.background());
        for (light, entry) in tables.plans.iter().enumerate() {
            let Some((plan, _)) = entry else { continue };
            if plan.brick_count() == 0 {
                continue;
            }
            let columns: Vec<GpuLightColumn> = plan
                .columns()
                .iter()
                .map(|&((x, y), ref ks)| {
                    let (k0, nodes) = LightTablePlan::column_nodes(ks);
                    GpuLightColumn { x, y, k0, nodes: nodes as u32 }
                })
                .collect();
            let columns_buffer = ctx.storage_buffer("light columns", &columns)?;
            let m = plan.to_density();
            let uniforms = GpuLightRays {
                across_i: m.x_axis.as_vec3().to_array(),
                step: plan.step() as f32,
                across_j: m.y_axis.as_vec3().to_array(),
                extinction: medium.extinction,
                along: m.z_axis.as_vec3().to_array(),
                // WGSL has no infinity; past f32's range every ray integrates to its end.
                opaque_depth: opaque_depth.min(f32::MAX as f64) as f32,
                dir: plan.dir_index().as_vec3().to_array(),
                light: light as u32,
                grid,
                first_ray: 0,
                ray_count: 0,
                _pad: [0; 2],
            };
            let rays = columns.len() as u64 * COLUMN_RAYS;
            let mut first = 0;
            while first < rays {
                let count = (rays - first).min(RAYS_PER_DISPATCH);
                let dispatch = GpuLightRays { first_ray: first as u32, ray_count: count as u32, ..uniforms };
                let params_buffer = ctx.params_buffer("light rays", &dispatch)?;
                let group = guard.buffer_bind_group(ctx, "light rays", &layout, &[&params_buffer, &majorant, &columns_buffer])?;
                ctx.dispatch_1d("light rays", &pipeline, &[&volume_group, &group, &tables_group], count, COLUMN_RAYS as u32)?;
                first += count;
            }
        }
        guard.check(ctx, "a light table's ray", "or --shadows rays")?;
        Ok(tables)
    }

    /// The buffers for `plans`: the tables, the brick indices, and room for the nodes.
    fn upload(ctx: &GpuContext, plans: Vec<Option<LightTablePlan>>, origin: DVec3, opaque_depth: f64) -> Result<GpuLightTables, GpuError> {
        let mut tables = Vec::with_capacity(plans.len());
        let mut index: Vec<u32> = Vec::new();
        let mut bricks = 0usize;
        let mut placed = Vec::with_capacity(plans.len());
        for plan in plans {
            let Some(plan) = plan else {
                tables.push(GpuLightTable::zeroed());
                placed.push(None);
                continue;
            };
            let coords: Vec<IVec3> = plan.bricks().map(|o| o >> BRICK_LOG2 as i32).collect();
            let lo = coords.iter().fold(IVec3::MAX, |a, &c| a.min(c));
            let hi = coords.iter().fold(IVec3::MIN, |a, &c| a.max(c));
            let dims = if coords.is_empty() { IVec3::ZERO } else { hi - lo + 1 };
            let entries = dims.as_i64vec3().element_product() as u64;
            if index.len() as u64 + entries > MAX_INDEX_ENTRIES {
                return Err(GpuError::VolumeLayout(format!(
                    "a light table's bricks span {}x{}x{} bricks, a brick index of {entries} entries, over the budget of {MAX_INDEX_ENTRIES} for all lights",
                    dims.x, dims.y, dims.z
                )));
            }
            let first = index.len();
            index.resize(first + entries as usize, 0);
            for (n, c) in coords.iter().enumerate() {
                let b = *c - lo;
                index[first + ((b.x * dims.y + b.y) * dims.z + b.z) as usize] = (bricks + n + 1) as u32;
            }
            let world_to_lattice = DMat4::from(plan.transform().world_to_index() * DAffine3::from_translation(origin));
            tables.push(GpuLightTable {
                world_to_lattice: world_to_lattice.as_mat4().to_cols_array_2d(),
                brick_min: lo.to_array(),
                index_first: first as u32,
                brick_dims: dims.to_array(),
                tabled: if plan.depth_across() { 2 } else { 1 },
            });
            placed.push(Some((plan, bricks)));
            bricks += coords.len();
        }
        // Bindings cannot be empty.
        if tables.is_empty() {
            tables.push(GpuLightTable::zeroed());
        }
        if index.is_empty() {
            index.push(0);
        }
        let node_bytes = (bricks.max(1) * crate::TABLE_BRICK_VALUES * size_of::<f32>()) as u64;
        Ok(GpuLightTables {
            tables: ctx.storage_buffer("light tables", &tables)?,
            index: ctx.storage_buffer("light table index", &index)?,
            nodes: ctx.storage_buffer_zeroed("light table nodes", node_bytes)?,
            plans: placed,
            opaque_depth,
        })
    }

    /// The layout of group 2 for [`light_tables_wgsl`].
    pub fn layout(ctx: &GpuContext) -> Result<wgpu::BindGroupLayout, GpuError> {
        ctx.bind_group_layout("light tables", &[storage_entry(0, true), storage_entry(1, true), storage_entry(2, false)])
    }

    /// These tables as group 2, for a layout from [`GpuLightTables::layout`].
    pub fn bind_group(&self, ctx: &GpuContext, layout: &wgpu::BindGroupLayout) -> Result<wgpu::BindGroup, GpuError> {
        ctx.buffer_bind_group("light tables", layout, &[&self.tables, &self.index, &self.nodes])
    }

    /// Nodes stored over all lights (as [`LightDepths::nodes`]).
    pub fn nodes(&self) -> u64 {
        self.plans.iter().flatten().map(|(plan, _)| (plan.brick_count() * BRICK_VOXELS) as u64).sum()
    }

    /// The tables read back: what [`LightDepths::build`] would hold, from the GPU's nodes.
    pub fn read(&self, ctx: &GpuContext) -> Result<LightDepths, GpuError> {
        let nodes: Vec<f32> = if self.nodes() == 0 { Vec::new() } else { ctx.read_buffer(&self.nodes)? };
        let per_light = self
            .plans
            .iter()
            .map(|entry| {
                entry.as_ref().map(|(plan, first)| {
                    let range = first * crate::TABLE_BRICK_VALUES..(first + plan.brick_count()) * crate::TABLE_BRICK_VALUES;
                    OpticalDepthVolume::from_nodes(plan, &nodes[range], self.opaque_depth)
                })
            })
            .collect();
        Ok(LightDepths { per_light })
    }
}

/// The head of every stage shader that walks the medium: [`ShaderComposer::stage`] (the
/// volume), optics, environment, emission (its bindings at `emission_group`, see
/// [`emission_wgsl`]) and tracking: static, or over a moving medium with motion.wgsl's
/// bindings at `motion_group` ([`tracking_wgsl_moving`]). The stage adds its own modules.
pub fn medium_stage(filterable: bool, emission_group: u32, motion_group: Option<u32>) -> ShaderComposer {
    let composer = ShaderComposer::stage(filterable)
        .module("optics", OPTICS_WGSL)
        .module("environment", ENVIRONMENT_WGSL)
        .module("emission", emission_wgsl(emission_group));
    match motion_group {
        Some(group) => composer.module("tracking (moving)", tracking_wgsl_moving(group)),
        None => composer.module("tracking", TRACKING_WGSL),
    }
}

/// The light-rays kernel's source ([`GpuLightTables::build`]'s pipeline) on an adapter with
/// or without FLOAT32_FILTERABLE and a loop cap.
fn light_rays_source(filterable: bool, loop_guard: bool) -> Result<String, GpuError> {
    Ok(ShaderComposer::stage(filterable)
        .module("optics", OPTICS_WGSL)
        .module("tracking", TRACKING_WGSL)
        .module("light_tables", light_tables_wgsl())
        .module("loop guard", LoopGuard::wgsl_for(loop_guard, 1, GUARD_BINDING))
        .module("optical_depth", OPTICAL_DEPTH_WGSL)
        .build()?)
}

/// The host mirror of the WGSL struct `wgsl_name` among those shared by the stages
/// (optics', this crate's and the volume's), for [`nimbus_gpu::wgsl_layout::check_layouts`]
/// over a stage's source.
pub fn wgsl_mirror(wgsl_name: &str) -> HostStruct {
    use nimbus_optics::{GpuCamera, GpuLight, GpuMedium};
    match wgsl_name {
        "Medium" => host_layout!(GpuMedium { albedo, extinction, g, albedo_mean, _pad }),
        "Light" => host_layout!(GpuLight { vector, kind, power, disc }),
        "Camera" => host_layout!(GpuCamera { eye, width, forward, height, right, tan_half_fov_x, up, tan_half_fov_y }),
        "EmissionInfo" => host_layout!(GpuEmissionInfo {
            color,
            strength,
            temperature_scale,
            blackbody_intensity,
            flags,
            table_len,
            table_min,
            table_max,
            table_inv_step,
            stefan_boltzmann
        }),
        "MajorantGridInfo" => host_layout!(GpuMajorantInfo { origin, cell_size, dims, outside }),
        "LightTable" => host_layout!(GpuLightTable { world_to_lattice, brick_min, index_first, brick_dims, tabled }),
        "MotionInfo" => host_layout!(GpuMotionInfo { density_to_velocity, shutter, _pad }),
        "VolumeInfo" => nimbus_gpu::VolumeInfo::host_layout(),
        _ => panic!("no shared host mirror of WGSL struct {wgsl_name}"),
    }
}

/// [`wgsl_mirror`] of each name, paired with it for [`nimbus_gpu::wgsl_layout::check_layouts`].
pub fn wgsl_mirrors<'a>(wgsl_names: &[&'a str]) -> Vec<(&'a str, HostStruct)> {
    wgsl_names.iter().map(|&n| (n, wgsl_mirror(n))).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nimbus_gpu::wgsl_layout::check_layouts;

    #[test]
    fn layouts_match_the_wgsl_structs() {
        for (filterable, loop_guard) in [(false, false), (true, true)] {
            let mut mirrors = wgsl_mirrors(&["MajorantGridInfo", "LightTable", "VolumeInfo"]);
            mirrors.push((
                "LightRays",
                host_layout!(GpuLightRays { across_i, step, across_j, extinction, along, opaque_depth, dir, light, grid, first_ray, ray_count, _pad }),
            ));
            mirrors.push(("LightColumn", host_layout!(GpuLightColumn { x, y, k0, nodes })));
            check_layouts(&light_rays_source(filterable, loop_guard).unwrap(), &mirrors);
        }
    }

    /// The host dispatches a brick column's rays per workgroup, as the kernel takes them.
    #[test]
    fn a_workgroup_is_one_brick_column() {
        assert_eq!(super::COLUMN_RAYS, nimbus_volume::BRICK_DIM as u64 * nimbus_volume::BRICK_DIM as u64);
        assert!(super::OPTICAL_DEPTH_WGSL.contains("@workgroup_size(LIGHT_COLUMN_RAYS)"));
        assert!(super::light_tables_wgsl().starts_with(&format!("const LIGHT_TABLE_BRICK_LOG2: u32 = {}u;", nimbus_volume::BRICK_LOG2)));
    }

    #[test]
    fn path_constants_match_the_wgsl() {
        use crate::{RATIO_ROULETTE, ROULETTE_FROM_DEPTH};
        assert!(super::PATH_WGSL.contains(&format!("const ROULETTE_FROM_DEPTH: u32 = {ROULETTE_FROM_DEPTH}u;")));
        assert!(super::PATH_WGSL.contains(&format!("const RATIO_ROULETTE: f32 = {RATIO_ROULETTE:?};")));
    }
}

/// `shaders/emission.wgsl`, composed by [`emission_wgsl`].
const EMISSION_WGSL: &str = include_str!("../../../shaders/emission.wgsl");

/// `shaders/emission.wgsl` with its bindings at bind group `group` (the stage's first free
/// one): `emission_active()` and `emission_at(x)`, the twin of [`crate::EmissionField::at`].
/// Composed after the volume; bind a [`GpuEmission`] there.
pub fn emission_wgsl(group: u32) -> String {
    EMISSION_WGSL.replace("EMISSION_GROUP", &group.to_string())
}

/// The medium's emission on the GPU, the twin of [`crate::EmissionField`]: its emission and
/// temperature grids (each in its own index space, sampled exactly), its parameters and the
/// blackbody colour table, for a stage that composes [`emission_wgsl`]. Where nothing emits
/// it binds empty volumes and `emission_active()` is false.
pub struct GpuEmission {
    grid: GpuVolume,
    temperature: GpuVolume,
    info: wgpu::Buffer,
    table: wgpu::Buffer,
    active: bool,
}

impl GpuEmission {
    /// Uploads `field` (None: no emission) with positions relative to world point `origin`,
    /// as the stage's other volumes are.
    pub fn upload(ctx: &GpuContext, field: Option<&crate::EmissionField>, origin: DVec3) -> Result<GpuEmission, GpuError> {
        let field = field.filter(|f| f.params.is_active());
        // An absent grid reads 0 on both sides (EmissionField::at; an empty volume's background).
        let info = field.map_or_else(GpuEmissionInfo::none, |f| GpuEmissionInfo::new(f.params));
        let (table, _, _) = blackbody_table();
        let texels: Vec<[f32; 4]> = table.iter().map(|c| c.extend(0.0).to_array()).collect();
        Ok(GpuEmission {
            grid: GpuVolume::upload_or_empty(ctx, field.and_then(|f| f.grid), origin)?,
            temperature: GpuVolume::upload_or_empty(ctx, field.and_then(|f| f.temperature), origin)?,
            info: ctx.params_buffer("emission info", &info)?,
            table: ctx.storage_buffer("blackbody table", &texels)?,
            active: info.flags != 0,
        })
    }

    /// Whether anything emits (`emission_active()` in the shader).
    pub fn is_active(&self) -> bool {
        self.active
    }

    /// The layout of the group [`emission_wgsl`] declares.
    pub fn layout(ctx: &GpuContext) -> Result<wgpu::BindGroupLayout, GpuError> {
        let filterable = ctx.float32_filterable();
        let mut entries = GpuVolume::layout_entries(0, filterable).to_vec();
        entries.extend(GpuVolume::layout_entries(4, filterable));
        entries.extend([params_entry(8), storage_entry(9, true)]);
        ctx.bind_group_layout("emission", &entries)
    }

    /// This emission as a group for a layout from [`GpuEmission::layout`].
    pub fn bind_group(&self, ctx: &GpuContext, layout: &wgpu::BindGroupLayout) -> Result<wgpu::BindGroup, GpuError> {
        let mut entries = self.grid.bind_group_entries(0).to_vec();
        entries.extend(self.temperature.bind_group_entries(4));
        entries.extend([
            wgpu::BindGroupEntry { binding: 8, resource: self.info.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 9, resource: self.table.as_entire_binding() },
        ]);
        ctx.bind_group("emission", layout, &entries)
    }
}

/// `shaders/motion.wgsl`, composed by [`tracking_wgsl_moving`].
const MOTION_WGSL: &str = include_str!("../../../shaders/motion.wgsl");

/// [`TRACKING_WGSL`]'s static `motion_back` / `motion_back_index`, which a moving stage
/// replaces.
fn static_motion_block() -> (usize, usize) {
    let begin = TRACKING_WGSL.find("// MOTION BEGIN").expect("tracking.wgsl marks its motion block");
    let end = TRACKING_WGSL.find("// MOTION END").expect("tracking.wgsl marks its motion block") + "// MOTION END".len();
    (begin, end)
}

/// [`TRACKING_WGSL`] over a medium that moves: `shaders/motion.wgsl` (the twin of
/// [`crate::Motion`], its bindings at bind group `group`, the stage's first free one) in
/// place of the static medium, so every density lookup of the tracking and path code
/// (`track_sigma_t`, the path's collisions) sees the sample's time. Composed after the
/// volume; bind a [`GpuMotion`] there, and set each sample's time with
/// `motion_begin_sample(u)`. Without motion blur the bound [`GpuMotion`] has no shutter and
/// every lookup is the frame's.
pub fn tracking_wgsl_moving(group: u32) -> String {
    let (begin, end) = static_motion_block();
    format!("{}{}{}", &TRACKING_WGSL[..begin], MOTION_WGSL.replace("MOTION_GROUP", &group.to_string()), &TRACKING_WGSL[end..])
}

/// WGSL `MotionInfo` (motion.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuMotionInfo {
    density_to_velocity: [[f32; 4]; 4],
    shutter: f32,
    _pad: [f32; 3],
}

/// A shutter over a velocity grid on the GPU, the twin of [`crate::MotionBlur`], for a stage
/// that composes [`tracking_wgsl_moving`].
pub struct GpuMotion {
    velocity: GpuVolume,
    info: wgpu::Buffer,
}

impl GpuMotion {
    /// Uploads `motion` (None: a static medium, an empty velocity grid and no shutter) over
    /// `density`, with world positions relative to `origin` as the stage's other volumes.
    pub fn upload(ctx: &GpuContext, motion: Option<&crate::MotionBlur>, density: &nimbus_volume::Volume<f32>, origin: DVec3) -> Result<GpuMotion, GpuError> {
        let density_to_velocity = match motion {
            // Composed in f64: both are near the identity's scale, whatever the world offset.
            Some(m) => DMat4::from(m.velocity.transform().world_to_index() * density.transform().index_to_world()),
            None => DMat4::IDENTITY,
        };
        let info = GpuMotionInfo {
            density_to_velocity: density_to_velocity.as_mat4().to_cols_array_2d(),
            shutter: motion.map_or(0.0, |m| m.shutter as f32),
            _pad: [0.0; 3],
        };
        Ok(GpuMotion {
            velocity: GpuVolume::upload_or_empty(ctx, motion.map(|m| m.velocity), origin)?,
            info: ctx.params_buffer("motion info", &info)?,
        })
    }

    /// The layout of the group [`tracking_wgsl_moving`] declares.
    pub fn layout(ctx: &GpuContext) -> Result<wgpu::BindGroupLayout, GpuError> {
        let mut entries = GpuVolume::layout_entries(0, ctx.float32_filterable()).to_vec();
        entries.push(params_entry(4));
        ctx.bind_group_layout("motion", &entries)
    }

    /// This motion as a group for a layout from [`GpuMotion::layout`].
    pub fn bind_group(&self, ctx: &GpuContext, layout: &wgpu::BindGroupLayout) -> Result<wgpu::BindGroup, GpuError> {
        let mut entries = self.velocity.bind_group_entries(0).to_vec();
        entries.push(wgpu::BindGroupEntry { binding: 4, resource: self.info.as_entire_binding() });
        ctx.bind_group("motion", layout, &entries)
    }
}

#[cfg(test)]
mod motion_tests {
    #[test]
    fn the_moving_tracking_replaces_the_static_medium() {
        let moving = super::tracking_wgsl_moving(3);
        assert!(!moving.contains("// MOTION BEGIN") && !moving.contains("return x;\n}\n\nfn motion_back_index(p: vec3<f32>) -> vec3<f32> {\n    return p;"));
        assert!(moving.contains("@group(3) @binding(4) var<storage, read> motion_info: MotionInfo;"));
        assert_eq!(moving.matches("fn motion_back(").count(), 1);
        assert_eq!(moving.matches("fn track_sigma_t(").count(), 1);
        assert_eq!(std::mem::size_of::<super::GpuMotionInfo>(), 80);
    }
}
