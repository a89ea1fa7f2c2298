//! The GPU backend: one wgpu invocation per photon path (`shaders/photon.wgsl`), batching and
//! accounting shared with the CPU backend through [`crate::batch::run_batches`].

use std::ops::Range;

use bytemuck::{Pod, Zeroable};
use glam::{DVec3, Vec3};
use nimbus_gpu::{storage_entry, params_entry, wgpu, GpuContext, GpuError, GpuVolume, GpuVolumeOptions, LoopGuard};
use nimbus_optics::{split_u64, Environment, GpuMedium};
use nimbus_tracking::{majorant_buffer, medium_stage, EmissionField, GpuEmission, GpuMajorantInfo};
use nimbus_volume::Volume;

use crate::batch::{prepare, run_batches, Batch, BatchPhoton, PathEnd, PathSummary, Prepared, Setup, Source};
use crate::{DistanceSampling, PhotonError, PhotonMap, PhotonParams, TraceStats};

/// The photon kernel, `shaders/photon.wgsl`.
pub const PHOTON_WGSL: &str = include_str!("../../../shaders/photon.wgsl");

const WORKGROUP_SIZE: u32 = 64;
/// Most paths one dispatch traces; bounds the path buffer and (with the yield) the record one.
const MAX_CHUNK: u64 = 1 << 18;
const RECORD_BYTES: u64 = size_of::<GpuRecord>() as u64;
/// Group 1 binding of the [`LoopGuard`] flag, after the stage's buffers.
const GUARD_BINDING: u32 = 8;
/// WGSL `LIGHT_ENVIRONMENT`: a `PhotonLight` that is the environment (after LIGHT_SUN and
/// LIGHT_POINT).
const LIGHT_ENVIRONMENT: u32 = 2;
/// WGSL `LIGHT_MEDIUM`: a `PhotonLight` that is the medium's emission (medium.rs).
const LIGHT_MEDIUM: u32 = 3;
/// Group 1 binding of the medium's emitting cells.
const MEDIUM_CELLS_BINDING: u32 = 9;
/// The bind group `shaders/emission.wgsl` sits at.
const EMISSION_GROUP: u32 = 2;

/// WGSL `PhotonUniforms`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuPhotonParams {
    medium: GpuMedium,
    seed: [u32; 2],
    first_index: [u32; 2],
    count: u32,
    capacity: u32,
    light_count: u32,
    mode: u32,
    step: f32,
    max_interactions: u32,
    _pad: [u32; 2],
    grid: GpuMajorantInfo,
}

/// WGSL `PhotonLight`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuPhotonLight {
    origin: [f32; 3],
    kind: u32,
    normal: [f32; 3],
    cell: f32,
    tangent: [f32; 3],
    cdf: f32,
    bitangent: [f32; 3],
    first_cell: u32,
    weight: [f32; 3],
    cell_count: u32,
}

/// WGSL `PhotonRecord`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct GpuRecord {
    position: [f32; 3],
    path: u32,
    power: [f32; 3],
    interaction: u32,
    dir: [f32; 3],
    _pad: u32,
}

fn rel(p: DVec3, origin: DVec3) -> [f32; 3] {
    (p - origin).as_vec3().to_array()
}

/// Everything uploaded once per trace.
struct GpuTracer<'a> {
    ctx: &'a GpuContext,
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    volume_group: wgpu::BindGroup,
    uniforms: GpuPhotonParams,
    params_buffer: wgpu::Buffer,
    lights: wgpu::Buffer,
    emission_cells: wgpu::Buffer,
    /// The medium's emitting cells (MediumEmission::gpu_cells; one dummy where none).
    medium_cells: wgpu::Buffer,
    emission_group: wgpu::BindGroup,
    /// The environment environment photons leave (Environment::gpu_words).
    environment: wgpu::Buffer,
    majorant: wgpu::Buffer,
    counter: wgpu::Buffer,
    paths: wgpu::Buffer,
    records: Option<wgpu::Buffer>,
    guard: LoopGuard,
    /// Stored photons per path seen so far: sizes the next record buffer.
    yield_estimate: f64,
    chunk: u64,
    origin: DVec3,
    _volume: GpuVolume,
}

/// The tracer's shader source, on an adapter with or without FLOAT32_FILTERABLE and a loop cap.
fn photon_source(filterable: bool, loop_guard: bool) -> Result<String, GpuError> {
    Ok(medium_stage(filterable, EMISSION_GROUP, None)
        .module("loop guard", LoopGuard::wgsl_for(loop_guard, 1, GUARD_BINDING))
        .module("photon", PHOTON_WGSL)
        .build()?)
}

impl<'a> GpuTracer<'a> {
    fn new(ctx: &'a GpuContext, density: &Volume<f32>, params: &PhotonParams, setup: &Setup) -> Result<Self, GpuError> {
        let origin = 0.5 * (setup.bounds.0 + setup.bounds.1);
        let mut volume = GpuVolume::upload(ctx, density, &GpuVolumeOptions::default())?;
        volume.set_world_origin(ctx, origin);
        let volume_layout = GpuVolume::bind_group_layout(ctx)?;
        let guard = LoopGuard::new(ctx, GUARD_BINDING)?;
        let layout = ctx.bind_group_layout(
            "photon",
            &[
                params_entry(0),
                storage_entry(1, true),
                storage_entry(2, true),
                storage_entry(3, false),
                storage_entry(4, false),
                storage_entry(5, false),
                storage_entry(6, true),
                storage_entry(7, true),
                guard.layout_entry(),
                storage_entry(MEDIUM_CELLS_BINDING, true),
            ],
        )?;
        let source = photon_source(ctx.float32_filterable(), guard.enabled())?;
        let emission_layout = GpuEmission::layout(ctx)?;
        let pipeline = ctx.compute_pipeline("photon trace", &source, "trace_photons", &[&volume_layout, &layout, &emission_layout])?;
        let volume_group = volume.bind_group(ctx, &volume_layout)?;

        let e = &setup.emitter;
        let mut medium_cells = Vec::new();
        let mut field: Option<EmissionField> = None;
        // Every light's marked cells (a sun's lattice cells, a point light's direction
        // cells) in one table, each light knowing its slice.
        let mut cells: Vec<[u32; 2]> = Vec::new();
        let lights: Vec<GpuPhotonLight> = (0..e.sources.len())
            .map(|i| {
                let mut l = GpuPhotonLight { cdf: e.cdf[i], weight: e.weight[i].to_array(), ..Zeroable::zeroed() };
                match &e.sources[i] {
                    Source::Sun(sun) => {
                        l.kind = nimbus_optics::LIGHT_SUN;
                        l.origin = rel(sun.corner, origin);
                        l.normal = sun.normal.as_vec3().to_array();
                        l.tangent = sun.tangent.as_vec3().to_array();
                        l.bitangent = sun.bitangent.as_vec3().to_array();
                        l.cell = sun.cell as f32;
                        l.first_cell = cells.len() as u32;
                        l.cell_count = sun.cells.len() as u32;
                        cells.extend_from_slice(&sun.cells);
                    }
                    Source::Point(point) => {
                        l.kind = nimbus_optics::LIGHT_POINT;
                        l.origin = rel(point.position, origin);
                        l.tangent = point.frame[0].as_vec3().to_array();
                        l.bitangent = point.frame[1].as_vec3().to_array();
                        l.normal = point.frame[2].as_vec3().to_array();
                        l.first_cell = cells.len() as u32;
                        l.cell_count = point.cells.len() as u32;
                        cells.extend_from_slice(&point.cells);
                    }
                    Source::Environment(sky) => {
                        l.kind = LIGHT_ENVIRONMENT;
                        l.origin = rel(sky.centre, origin);
                        l.cell = sky.radius as f32;
                        // The flux is the shader's; this its share's reciprocal (Emitter::emit).
                        l.weight = [1.0 / e.share(i); 3];
                    }
                    Source::Medium(medium) => {
                        // The density's index-to-world map as origin + i tangent + j bitangent
                        // + k normal, relative to the origin; the ratio e(x) / w_c is the
                        // shader's, times the emitter's total (Emitter::emit).
                        let to_world = density.transform().index_to_world();
                        l.kind = LIGHT_MEDIUM;
                        l.origin = rel(to_world.translation, origin);
                        l.tangent = to_world.matrix3.x_axis.as_vec3().to_array();
                        l.bitangent = to_world.matrix3.y_axis.as_vec3().to_array();
                        l.normal = to_world.matrix3.z_axis.as_vec3().to_array();
                        l.weight = [e.weight[i].element_sum(); 3];
                        l.cell_count = medium.cells.len() as u32;
                        medium_cells = medium.gpu_cells();
                        field = Some(medium.field());
                    }
                }
                l
            })
            .collect();
        if cells.is_empty() {
            // A binding cannot be empty.
            cells.push([0; 2]);
        }
        if medium_cells.is_empty() {
            medium_cells.push(Zeroable::zeroed());
        }
        let emission_group = GpuEmission::upload(ctx, field.as_ref(), origin)?.bind_group(ctx, &emission_layout)?;
        let uniforms = GpuPhotonParams {
            medium: GpuMedium::from(&params.medium),
            seed: split_u64(params.seed),
            first_index: [0; 2],
            count: 0,
            capacity: 0,
            light_count: lights.len() as u32,
            mode: match params.distance {
                DistanceSampling::Simpson => 0,
                DistanceSampling::Exponential => 1,
                DistanceSampling::Delta => 2,
            },
            step: setup.step as f32,
            max_interactions: params.max_interactions,
            _pad: [0; 2],
            grid: GpuMajorantInfo::new(&setup.majorant, density.background()),
        };
        let limit = ctx.limits().max_storage_buffer_binding_size.min(ctx.limits().max_buffer_size);
        let chunk = MAX_CHUNK.min(limit / 8).max(1);
        Ok(GpuTracer {
            ctx,
            pipeline,
            layout,
            volume_group,
            uniforms,
            params_buffer: ctx.params_buffer("photon params", &uniforms)?,
            lights: ctx.storage_buffer("photon lights", &lights)?,
            emission_cells: ctx.storage_buffer("photon emission cells", &cells)?,
            medium_cells: ctx.storage_buffer("photon medium cells", &medium_cells)?,
            emission_group,
            environment: ctx.storage_buffer("photon environment", &Environment::gpu_words(params.environment.as_ref()))?,
            majorant: majorant_buffer(ctx, &setup.majorant)?,
            counter: ctx.storage_buffer("photon count", &[0u32])?,
            paths: ctx.storage_buffer_zeroed("photon paths", chunk * 8)?,
            records: None,
            guard,
            yield_estimate: 2.0,
            chunk,
            origin,
            _volume: volume,
        })
    }

    fn record_limit(&self) -> u64 {
        let limits = self.ctx.limits();
        limits.max_storage_buffer_binding_size.min(limits.max_buffer_size) / RECORD_BYTES
    }

    /// Runs one dispatch of `count` paths from photon `first` with room for `capacity`
    /// records; returns how many records the paths stored (possibly more than `capacity`).
    fn dispatch(&mut self, first: u64, count: u64, capacity: u64) -> Result<u64, GpuError> {
        let ctx = self.ctx;
        let have = self.records.as_ref().map_or(0, |b| b.size() / RECORD_BYTES);
        if have < capacity {
            self.records = Some(ctx.storage_buffer_zeroed("photon records", capacity.max(1) * RECORD_BYTES)?);
        }
        let records = self.records.as_ref().expect("allocated above");
        self.uniforms.first_index = split_u64(first);
        self.uniforms.count = count as u32;
        self.uniforms.capacity = (records.size() / RECORD_BYTES) as u32;
        ctx.queue.write_buffer(&self.params_buffer, 0, bytemuck::bytes_of(&self.uniforms));
        ctx.queue.write_buffer(&self.counter, 0, bytemuck::bytes_of(&0u32));
        let buffers = [&self.params_buffer, &self.lights, &self.majorant, records, &self.counter, &self.paths, &self.emission_cells, &self.environment];
        let mut entries: Vec<wgpu::BindGroupEntry> =
            buffers.iter().enumerate().map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() }).collect();
        entries.push(self.guard.bind_group_entry());
        entries.push(wgpu::BindGroupEntry { binding: MEDIUM_CELLS_BINDING, resource: self.medium_cells.as_entire_binding() });
        let group = ctx.bind_group("photon", &self.layout, &entries)?;
        ctx.dispatch_1d("photon trace", &self.pipeline, &[&self.volume_group, &group, &self.emission_group], count, WORKGROUP_SIZE)?;
        self.guard.check(ctx, format_args!("tracing photon paths {first}..{}", first + count), "")?;
        let stored: Vec<u32> = ctx.read_buffer(&self.counter)?;
        Ok(stored[0] as u64)
    }

    /// Traces photons `range`, in dispatches of at most `self.chunk` paths.
    fn batch(&mut self, range: Range<u64>) -> Result<Batch, PhotonError> {
        let mut batch = Batch::default();
        let mut first = range.start;
        while first < range.end {
            let count = (range.end - first).min(self.chunk);
            let limit = self.record_limit();
            let estimate = ((count as f64 * self.yield_estimate * 1.25) as u64 + 1024).min(limit);
            let mut stored = self.dispatch(first, count, estimate)?;
            let capacity = self.records.as_ref().map_or(0, |b| b.size() / RECORD_BYTES);
            if stored > capacity {
                if stored > limit {
                    // Too many records for one binding: trace fewer paths at a time.
                    if count == 1 {
                        return Err(GpuError::TooLarge {
                            what: "one photon path's stored records".into(),
                            size: stored * RECORD_BYTES,
                            limit: limit * RECORD_BYTES,
                            limit_name: "max_storage_buffer_binding_size",
                        }
                        .into());
                    }
                    self.chunk = (count / 2).max(1);
                    continue;
                }
                // Deterministic: the same paths again, with room for all of them.
                stored = self.dispatch(first, count, stored)?;
            }
            self.yield_estimate = 0.5 * self.yield_estimate + 0.5 * (stored as f64 / count as f64);
            self.collect(&mut batch, first - range.start, count, stored)?;
            first += count;
        }
        Ok(batch)
    }

    /// Reads back `count` path summaries and `stored` records, appending them to `batch`
    /// with path numbers offset by `offset`, records in (path, interaction) order.
    fn collect(&self, batch: &mut Batch, offset: u64, count: u64, stored: u64) -> Result<(), GpuError> {
        let ctx = self.ctx;
        let paths: Vec<[u32; 2]> = read_prefix(ctx, &self.paths, count * 8)?;
        batch.paths.extend(paths.iter().map(|&[interactions, end]| PathSummary {
            interactions,
            end: match end {
                0 => PathEnd::Escaped,
                1 => PathEnd::Absorbed,
                _ => PathEnd::Truncated,
            },
        }));
        if stored == 0 {
            return Ok(());
        }
        let records = self.records.as_ref().expect("a dispatch ran");
        let mut records: Vec<GpuRecord> = read_prefix(ctx, records, stored * RECORD_BYTES)?;
        records.sort_unstable_by_key(|r| (r.path, r.interaction));
        batch.photons.extend(records.iter().map(|r| BatchPhoton {
            path: (offset + r.path as u64) as u32,
            position: self.origin + Vec3::from(r.position).as_dvec3(),
            power: Vec3::from(r.power),
            dir: Vec3::from(r.dir),
        }));
        Ok(())
    }
}

/// The first `bytes` of `buffer`, through a copy so only those bytes cross back.
pub(crate) fn read_prefix<T: Pod>(ctx: &GpuContext, buffer: &wgpu::Buffer, bytes: u64) -> Result<Vec<T>, GpuError> {
    if bytes == buffer.size() {
        return ctx.read_buffer(buffer);
    }
    let staging = ctx.storage_buffer_zeroed("read-back prefix", bytes)?;
    ctx.scoped("read-back prefix copy", || {
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, bytes);
        ctx.queue.submit([encoder.finish()]);
    })?;
    ctx.read_buffer(&staging)
}

/// Traces photons through `density` on the GPU until `params.photons` are stored (or
/// `params.max_emitted` have left the lights): the same emission, free paths, roulette and
/// stopping rule as [`crate::trace_cpu`], in f32.
pub fn trace_gpu(ctx: &GpuContext, density: &Volume<f32>, params: &PhotonParams) -> Result<(PhotonMap, TraceStats), PhotonError> {
    trace_gpu_emitting(ctx, density, params, None)
}

/// [`trace_gpu`] with the medium's emission, the twin of [`crate::trace_cpu_emitting`]:
/// photons also leave the emitting cells (photon.wgsl's `LIGHT_MEDIUM`, the same cell, point
/// and direction from the same draws), stored from their first interaction.
pub fn trace_gpu_emitting(ctx: &GpuContext, density: &Volume<f32>, params: &PhotonParams, emission: Option<&EmissionField>) -> Result<(PhotonMap, TraceStats), PhotonError> {
    let setup = match prepare(density, params, emission)? {
        Prepared::Trace(setup) => setup,
        Prepared::Skip(map, stats) => return Ok((map, stats)),
    };
    let mut tracer = GpuTracer::new(ctx, density, params, &setup)?;
    run_batches(params, |range| tracer.batch(range))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::emission::index_from_words;

    #[test]
    fn layouts_match_the_wgsl_structs() {
        use crate::medium::GpuMediumCell;
        use nimbus_gpu::host_layout;
        for (filterable, loop_guard) in [(false, false), (true, true)] {
            let mut mirrors = nimbus_tracking::wgsl_mirrors(&["Medium", "MajorantGridInfo", "EmissionInfo", "VolumeInfo"]);
            mirrors.extend([
                (
                    "PhotonUniforms",
                    host_layout!(GpuPhotonParams { medium, seed, first_index, count, capacity, light_count, mode, step, max_interactions, _pad, grid }),
                ),
                (
                    "PhotonLight",
                    host_layout!(GpuPhotonLight { origin, kind, normal, cell, tangent, cdf, bitangent, first_cell, weight, cell_count }),
                ),
                ("PhotonRecord", host_layout!(GpuRecord { position, path, power, interaction, dir, _pad })),
                ("MediumCell", host_layout!(GpuMediumCell { cell, weight, threshold, _pad })),
            ]);
            nimbus_gpu::wgsl_layout::check_layouts(&photon_source(filterable, loop_guard).unwrap(), &mirrors);
        }
    }

    /// The shader's cell index against `index_from_words`, bit for bit, on words where the
    /// low product's carry decides the result (rare among random words: about n / 2^32).
    #[test]
    fn the_shader_knows_the_environment_light_kind() {
        assert!(PHOTON_WGSL.contains(&format!("const LIGHT_ENVIRONMENT: u32 = {LIGHT_ENVIRONMENT}u;")));
        assert!(PHOTON_WGSL.contains(&format!("const LIGHT_MEDIUM: u32 = {LIGHT_MEDIUM}u;")));
        assert!(PHOTON_WGSL.contains(&format!("@group(1) @binding({MEDIUM_CELLS_BINDING}) var<storage, read> medium_cells")));
    }

    #[test]
    fn the_shader_picks_the_same_emission_cell() {
        let Some(ctx) = nimbus_gpu::test_context() else { return };
        let start = PHOTON_WGSL.find("fn emission_index_from_words").expect("the shader's index function");
        let function = &PHOTON_WGSL[start..start + PHOTON_WGSL[start..].find("\n}\n").expect("its end") + 3];
        let kernel = r#"
@group(0) @binding(0) var<storage, read> words: array<vec4<u32>>;
@group(0) @binding(1) var<storage, read_write> indices: array<u32>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x < arrayLength(&words)) {
        let w = words[id.x];
        indices[id.x] = emission_index_from_words(w.x, w.y, w.z);
    }
}
"#;
        let mut rng = nimbus_optics::Rng::new(4, 0);
        let mut cases: Vec<[u32; 4]> = vec![[0, 0, 7, 0], [u32::MAX, u32::MAX, 7, 0], [u32::MAX, u32::MAX, u32::MAX, 0]];
        for _ in 0..64 {
            let n = (1 << 20) + (rng.next_u32() >> 11);
            // A high word whose product's low word lies within n of 2^32, and the largest low
            // word: the carry turns the index over to the next one.
            let mut hi = rng.next_u32();
            while hi.wrapping_mul(n) <= u32::MAX - n {
                hi = hi.wrapping_add(1);
            }
            cases.push([hi, u32::MAX, n, 0]);
            cases.push([hi, 0, n, 0]);
            cases.push([rng.next_u32(), rng.next_u32(), rng.next_u32().max(1), 0]);
        }
        assert!(cases.iter().any(|c| index_from_words(c[0], c[1], c[2]) != index_from_words(c[0], 0, c[2])), "no case carries");
        let layout = ctx.bind_group_layout("index test", &[storage_entry(0, true), storage_entry(1, false)]).unwrap();
        let source = format!("{}\n{function}\n{kernel}", nimbus_optics::OPTICS_WGSL);
        let pipeline = ctx.compute_pipeline("index test", &source, "main", &[&layout]).unwrap();
        let words = ctx.storage_buffer("words", &cases).unwrap();
        let indices = ctx.storage_buffer_zeroed("indices", cases.len() as u64 * 4).unwrap();
        let group = ctx.buffer_bind_group("index test", &layout, &[&words, &indices]).unwrap();
        ctx.dispatch_1d("index test", &pipeline, &[&group], cases.len() as u64, 64).unwrap();
        let got: Vec<u32> = ctx.read_buffer(&indices).unwrap();
        for (c, g) in cases.iter().zip(got) {
            assert_eq!(g, index_from_words(c[0], c[1], c[2]), "words {:08x}:{:08x}, n {}", c[0], c[1], c[2]);
        }
    }

    #[test]
    fn the_shader_uses_the_cpu_random_domain_and_direction_table() {
        assert!(PHOTON_WGSL.contains(&format!("PHOTON_DOMAIN: u32 = 0x{:08x}u", crate::batch::PHOTON_DOMAIN)));
        assert!(PHOTON_WGSL.contains(&format!("DIRECTION_ROWS: u32 = {}u", crate::emission::DIRECTION_ROWS)));
        assert!(PHOTON_WGSL.contains(&format!("DIRECTION_COLUMNS: u32 = {}u", crate::emission::DIRECTION_COLUMNS)));
    }
}
