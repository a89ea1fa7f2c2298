//! Which cache voxels to bake: shared by the CPU and GPU backends.

use glam::{DAffine3, DVec3, IVec3, Vec3};
use nimbus_optics::Camera;
use nimbus_volume::{brick_local, brick_offset, brick_origin, BrickMask, MajorantGrid, Transform, Volume, BRICK_DIM, BRICK_VOXELS};
use rayon::prelude::*;
use rustc_hash::FxHashSet;
use std::sync::atomic::{AtomicU64, Ordering};

use nimbus_photon::PhotonMap;

use nimbus_tracking::{DensityMedium, EmissionField, LightDepths};

use crate::{choose_single_lattice, BakeStats, CacheError, CacheParams, MultipleEstimator};

/// The cache lattice: the density lattice scaled by `scale`, so cache voxel c sits at density
/// index scale * c and both share the origin.
pub fn cache_transform(density: &Transform, scale: DVec3) -> Transform {
    Transform::new(density.index_to_world() * DAffine3::from_scale(scale))
        .expect("a positive scale of an invertible map is invertible")
}

/// What both backends decide before they table the lights: the parameters checked, the
/// emission the paths gather and the majorant. After the tables, [`CachePlan::for_bake`]
/// plans both. One function each, so the CPU and GPU bakes cannot drift apart in what they
/// bake.
pub(crate) struct Prologue<'a, 'e> {
    /// The medium's emission where the paths gather it, else None: the photon estimator's
    /// emission came with the photons.
    pub emission: Option<&'a EmissionField<'e>>,
    pub majorant: MajorantGrid,
    /// The stages' times so far.
    pub timed: BakeStats,
}

impl<'a, 'e> Prologue<'a, 'e> {
    pub fn new(density: &Volume<f32>, params: &CacheParams, emission: Option<&'a EmissionField<'e>>) -> Result<Self, CacheError> {
        params.validate()?;
        let emission = emission.filter(|e| e.params.is_active() && matches!(params.estimator, MultipleEstimator::Paths { .. }));
        let mut timed = BakeStats::default();
        let majorant = timed.time("majorant", || MajorantGrid::build(density));
        Ok(Prologue { emission, majorant, timed })
    }
}

/// The cache bricks to bake and, in each, the voxels to bake.
#[derive(Clone)]
pub struct CachePlan {
    pub transform: Transform,
    /// Sorted by origin.
    pub bricks: Vec<(IVec3, BrickMask)>,
    pub stats: BakeStats,
}

impl CachePlan {
    /// Cache voxels within one cache cell of density (so every trilinear cache lookup a
    /// renderer makes where there is density finds baked corners) and inside the camera's
    /// view, enlarged by the same footprint.
    pub fn new(density: &Volume<f32>, majorant: &MajorantGrid, camera: &Camera, scale: DVec3) -> CachePlan {
        let transform = cache_transform(density.transform(), scale);
        let mut candidates = FxHashSet::default();
        for brick in density.bricks() {
            if !brick.values.iter().any(|&v| v > 0.0) {
                continue;
            }
            // The density brick influences interpolation over [o-1, o+8] (density index); the
            // cache voxels within one cache cell of that.
            let lo = ((brick.origin.as_dvec3() - 1.0) / scale).floor().as_ivec3() - 1;
            let hi = ((brick.origin.as_dvec3() + BRICK_DIM as f64) / scale).ceil().as_ivec3() + 1;
            let (b0, b1) = (brick_origin(lo), brick_origin(hi));
            for x in (b0.x..=b1.x).step_by(BRICK_DIM as usize) {
                for y in (b0.y..=b1.y).step_by(BRICK_DIM as usize) {
                    for z in (b0.z..=b1.z).step_by(BRICK_DIM as usize) {
                        candidates.insert(IVec3::new(x, y, z));
                    }
                }
            }
        }
        let mut origins: Vec<IVec3> = candidates.into_iter().collect();
        origins.sort_unstable_by_key(|o| (o.x, o.y, o.z));
        // A cache voxel's interpolation footprint is the ball around it reaching its cell's
        // far corners.
        let footprint = (scale * density.transform().voxel_size()).length();
        let per_brick: Vec<(IVec3, BrickMask, BakeStats)> = origins
            .par_iter()
            .map(|&origin| {
                let mut mask = [0u64; 8];
                let mut stats = BakeStats { candidates: BRICK_VOXELS as u64, ..BakeStats::default() };
                for offset in 0..BRICK_VOXELS {
                    let c = (origin + brick_local(offset)).as_dvec3();
                    let centre = c * scale;
                    let holds_density = majorant.max_in_box(centre - scale, centre + scale) > 0.0;
                    if !holds_density {
                        stats.culled_empty += 1;
                    } else if !camera.sees_sphere(transform.to_world(c), footprint) {
                        stats.culled_view += 1;
                    } else {
                        mask[offset >> 6] |= 1 << (offset & 63);
                        stats.baked += 1;
                    }
                }
                (origin, mask, stats)
            })
            .collect();
        let mut stats = BakeStats::default();
        let mut bricks = Vec::new();
        for (origin, mask, s) in per_brick {
            stats.candidates += s.candidates;
            stats.culled_empty += s.culled_empty;
            stats.culled_view += s.culled_view;
            stats.baked += s.baked;
            if mask.iter().any(|&w| w != 0) {
                bricks.push((origin, mask));
            }
        }
        CachePlan { transform, bricks, stats }
    }

    /// Both backends' plans once the lights are tabled (`depths`): Li_single's lattice
    /// chosen from them ([`choose_single_lattice`]), its plan, Li_multiple's own plan where
    /// it has one ([`CachePlan::for_multiple`]), and their counts in `timed` with the
    /// lattice's and the plans' times.
    pub fn for_bake(medium: DensityMedium, params: &CacheParams, depths: &LightDepths, photons: &PhotonMap, emits: bool, mut timed: BakeStats) -> (CachePlan, Option<CachePlan>, BakeStats) {
        let (density, majorant) = (medium.density, medium.majorant);
        let lattice = timed.time("single lattice", || choose_single_lattice(medium, params, depths));
        let (plan, own) = timed.time("plan", || {
            let plan = CachePlan::new(density, majorant, &params.camera, lattice.scale);
            let own = CachePlan::for_multiple(density, majorant, params, &plan, photons, emits);
            (plan, own)
        });
        let stats = BakeStats {
            stages: timed.stages,
            single_lattice: (lattice.samples > 0).then_some(lattice),
            ..plan.stats_with(own.as_ref(), params.bakes_single())
        };
        (plan, own, stats)
    }

    /// Li_multiple's own plan, where it has its own lattice (`multiple_scale`) and will be
    /// baked (`emits`: the medium emits, [`CacheParams::bakes_multiple`]); None where it
    /// shares `single`'s.
    pub fn for_multiple(density: &Volume<f32>, majorant: &MajorantGrid, params: &CacheParams, single: &CachePlan, photons: &PhotonMap, emits: bool) -> Option<CachePlan> {
        let scale = DVec3::splat(params.multiple_scale());
        let transform = cache_transform(density.transform(), scale);
        (params.bakes_multiple(photons, emits) && transform != single.transform).then(|| CachePlan::new(density, majorant, &params.camera, scale))
    }

    /// The voxel counts of what is baked: this plan's where Li_single is baked on it (or
    /// Li_multiple shares it), plus Li_multiple's own plan's.
    pub fn stats_with(&self, own_multiple: Option<&CachePlan>, bakes_single: bool) -> BakeStats {
        let mut stats = if bakes_single || own_multiple.is_none() { self.stats.clone() } else { BakeStats::default() };
        if let Some(p) = own_multiple {
            stats.add(&p.stats);
        }
        stats
    }

    pub fn mask_of(&self, origin: IVec3) -> Option<&BrickMask> {
        self.brick_index(origin).map(|i| &self.bricks[i].1)
    }

    fn brick_index(&self, origin: IVec3) -> Option<usize> {
        self.bricks.binary_search_by_key(&(origin.x, origin.y, origin.z), |(o, _)| (o.x, o.y, o.z)).ok()
    }

    pub fn origins(&self) -> Vec<IVec3> {
        self.bricks.iter().map(|b| b.0).collect()
    }

    /// World positions of the planned voxels: brick by brick in `bricks` order, offsets
    /// ascending within a brick. Both backends evaluate this list; [`CachePlan::volume_of`]
    /// puts the results back.
    pub fn voxel_positions(&self) -> Vec<DVec3> {
        let mut out = Vec::with_capacity(self.stats.baked as usize);
        for (origin, mask) in &self.bricks {
            for offset in 0..BRICK_VOXELS {
                if mask_has(mask, offset) {
                    out.push(self.transform.to_world((*origin + brick_local(offset)).as_dvec3()));
                }
            }
        }
        out
    }

    /// The cache volume holding `values[i]` at the i-th of [`CachePlan::voxel_positions`],
    /// and how many values were non-finite: those are stored as zero, never written.
    pub fn volume_of(&self, values: &[Vec3]) -> (Volume<Vec3>, u64) {
        assert_eq!(values.len() as u64, self.stats.baked, "one value per planned voxel");
        let first = self.first_voxels();
        let nonfinite = AtomicU64::new(0);
        let volume = Volume::from_brick_fn(self.transform, Vec3::ZERO, &self.origins(), |origin, brick| {
            let b = self.brick_index(origin).expect("planned brick");
            let mask = self.bricks[b].1;
            let mut i = first[b];
            for (offset, slot) in brick.iter_mut().enumerate() {
                if mask_has(&mask, offset) {
                    let li = values[i];
                    i += 1;
                    *slot = if li.is_finite() {
                        li
                    } else {
                        nonfinite.fetch_add(1, Ordering::Relaxed);
                        Vec3::ZERO
                    };
                }
            }
            mask
        });
        (volume, nonfinite.into_inner())
    }
}

impl CachePlan {
    /// Where each brick's run of voxels starts in plan order.
    fn first_voxels(&self) -> Vec<usize> {
        self.bricks
            .iter()
            .scan(0usize, |next, (_, mask)| {
                let start = *next;
                *next += mask.iter().map(|w| w.count_ones() as usize).sum::<usize>();
                Some(start)
            })
            .collect()
    }

    /// Looks planned voxels up by lattice coordinate.
    pub(crate) fn voxel_index(&self) -> VoxelIndex<'_> {
        let first = self.first_voxels();
        let lo = self.bricks.iter().fold(IVec3::MAX, |a, b| a.min(b.0));
        let hi = self.bricks.iter().fold(IVec3::MIN, |a, b| a.max(b.0));
        let (origin, dims) = if self.bricks.is_empty() { (IVec3::ZERO, IVec3::ZERO) } else { (lo, (hi - lo) / BRICK_DIM + 1) };
        let mut table = vec![u32::MAX; (dims.x as usize) * (dims.y as usize) * (dims.z as usize)];
        let mut below = Vec::with_capacity(self.bricks.len());
        for (b, (o, mask)) in self.bricks.iter().enumerate() {
            let c = (*o - origin) / BRICK_DIM;
            table[((c.x * dims.y + c.y) * dims.z + c.z) as usize] = b as u32;
            let mut words = [0u32; 8];
            for w in 1..8 {
                words[w] = words[w - 1] + mask[w - 1].count_ones();
            }
            below.push(words);
        }
        VoxelIndex { plan: self, first, origin, dims, table, below }
    }
}

/// Cache lattice coordinate -> position in plan order ([`CachePlan::voxel_positions`]),
/// through a dense table of the plan's bricks over their bounding box (a plan holds a few
/// thousand bricks, and the importance rays look up eight corners a sample).
pub(crate) struct VoxelIndex<'a> {
    plan: &'a CachePlan,
    first: Vec<usize>,
    origin: IVec3,
    /// Bricks per axis of the table.
    dims: IVec3,
    /// Brick number in `plan.bricks`, or u32::MAX.
    table: Vec<u32>,
    /// Per brick, the planned voxels in the mask words before each word.
    below: Vec<[u32; 8]>,
}

impl VoxelIndex<'_> {
    /// The planned voxel at `ijk`, if it is planned.
    #[inline]
    pub(crate) fn get(&self, ijk: IVec3) -> Option<usize> {
        let c = (brick_origin(ijk) - self.origin) / BRICK_DIM;
        if c.cmplt(IVec3::ZERO).any() || c.cmpge(self.dims).any() {
            return None;
        }
        let b = self.table[((c.x * self.dims.y + c.y) * self.dims.z + c.z) as usize];
        if b == u32::MAX {
            return None;
        }
        let mask = &self.plan.bricks[b as usize].1;
        let offset = brick_offset(ijk - brick_origin(ijk));
        if !mask_has(mask, offset) {
            return None;
        }
        let (word, bit) = (offset >> 6, offset & 63);
        let below = self.below[b as usize][word] as usize + (mask[word] & ((1u64 << bit) - 1)).count_ones() as usize;
        Some(self.first[b as usize] + below)
    }
}

fn mask_has(mask: &BrickMask, offset: usize) -> bool {
    mask[offset >> 6] & (1 << (offset & 63)) != 0
}
