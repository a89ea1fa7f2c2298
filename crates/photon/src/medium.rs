//! Photons from the medium's own emission (issue #19: a fire lights its own smoke).
//!
//! Emitted radiance per unit length e(x) (`nimbus_tracking::EmissionField`, counted only where
//! the density is positive, as the march and the reference count it) leaves isotropically, so
//! a volume element emits power 4 pi e dV and the medium `4 pi integral e dV` per channel.
//!
//! Positions are drawn in proportion to emitted power through a CDF over the density's
//! lattice cells (the cube between eight voxel positions): a cell emits where some corner's
//! density is positive (trilinear weights are all positive inside a cell, so the density is
//! positive throughout its interior then, and zero throughout otherwise), with weight w_c the
//! mean of e over its eight corners summed over RGB. A photon picks a cell by w_c, a point x
//! uniformly in it, a direction uniformly on the sphere, and carries
//! `e(x) [density(x) > 0] / w_c` times the emitter's total (before dividing by the photons
//! emitted): importance sampling of the cells, so the expected power is exactly
//! `4 pi integral e dV` whatever the cell weights, as long as no cell that emits gets weight
//! 0. That holds where the emission grids share the density's lattice (Blender's and Houdini's
//! files; e is then positive inside a cell only where a corner's is, the blackbody's T^4
//! included, as it rises with T); grids on another lattice could emit inside a cell whose
//! corners read 0, and that light would be missed. The medium's power the emitter states,
//! `4 pi V sum_c w_c` per channel, is exact for an emission grid on the density's lattice
//! (trilinear e integrates to its corners' mean) and an estimate for a blackbody.

use std::f64::consts::PI;

use glam::{DVec3, IVec3, Vec3};
use nimbus_optics::{sample_uniform_sphere, Rng};
use nimbus_tracking::EmissionField;
use nimbus_volume::{brick_local, Volume, BRICK_DIM};
use rayon::prelude::*;

/// Lattice points along a brick's edge with the far corners of its cells.
const CORNERS: i32 = BRICK_DIM + 1;

/// WGSL `MediumCell` (photon.wgsl): [`MediumEmission::gpu_cells`].
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuMediumCell {
    pub cell: [i32; 3],
    pub weight: f32,
    /// `ceil(cdf 2^53)`: bits 26.. and 0..26.
    pub threshold: [u32; 2],
    pub _pad: [u32; 2],
}

/// The emitting cells of the medium and what a photon needs to leave one.
#[derive(Clone)]
pub struct MediumEmission<'a> {
    /// Lower corners (density index) of the cells that emit, in brick order.
    pub cells: Vec<IVec3>,
    /// Each cell's weight: the mean emitted radiance over its corners, summed over RGB.
    weights: Vec<f32>,
    /// Normalised cumulative weights.
    cdf: Vec<f64>,
    /// 4 pi V sum_c (mean of e over the corners of c), RGB.
    power: Vec3,
    density: &'a Volume<f32>,
    field: EmissionField<'a>,
}

impl<'a> MediumEmission<'a> {
    /// The cells of `density` that emit under `field`; None where none does.
    pub fn new(density: &'a Volume<f32>, field: EmissionField<'a>) -> Option<MediumEmission<'a>> {
        if !field.params.is_active() {
            return None;
        }
        // A cell's corners lie in its own brick or the next one along each axis: the cells of
        // the density's bricks and of the bricks just below them hold every cell touching a
        // positive voxel.
        let mut origins: Vec<IVec3> = density
            .bricks()
            .filter(|b| b.values.iter().any(|&d| d > 0.0))
            .flat_map(|b| (0..8).map(move |k| b.origin - IVec3::new(k & 1, (k >> 1) & 1, (k >> 2) & 1) * BRICK_DIM))
            .collect();
        origins.sort_unstable_by_key(|o| (o.x, o.y, o.z));
        origins.dedup();
        let transform = *density.transform();
        let per_brick: Vec<Vec<(IVec3, Vec3)>> = origins
            .par_iter()
            .map(|&origin| {
                let at = |i: i32, j: i32, k: i32| ((i * CORNERS + j) * CORNERS + k) as usize;
                let mut dens = vec![0.0f32; (CORNERS * CORNERS * CORNERS) as usize];
                for i in 0..CORNERS {
                    for j in 0..CORNERS {
                        for k in 0..CORNERS {
                            dens[at(i, j, k)] = density.get(origin + IVec3::new(i, j, k));
                        }
                    }
                }
                if !dens.iter().any(|&d| d > 0.0) {
                    return Vec::new();
                }
                let mut emitted = vec![Vec3::ZERO; dens.len()];
                for i in 0..CORNERS {
                    for j in 0..CORNERS {
                        for k in 0..CORNERS {
                            emitted[at(i, j, k)] = field.at(transform.to_world((origin + IVec3::new(i, j, k)).as_dvec3()));
                        }
                    }
                }
                let mut cells = Vec::new();
                for offset in 0..(BRICK_DIM * BRICK_DIM * BRICK_DIM) as usize {
                    let l = brick_local(offset);
                    let corners = (0..8).map(|c| at(l.x + (c & 1), l.y + ((c >> 1) & 1), l.z + ((c >> 2) & 1)));
                    if !corners.clone().any(|c| dens[c] > 0.0) {
                        continue;
                    }
                    let mean = corners.map(|c| emitted[c]).sum::<Vec3>() / 8.0;
                    // The grids are finite (the tools refuse others), but a temperature whose
                    // T^4 overflows f32 is not: such a cell is left out rather than send an
                    // infinite power into the photon map.
                    if mean.element_sum() > 0.0 && mean.is_finite() {
                        cells.push((origin + l, mean));
                    }
                }
                cells
            })
            .collect();
        let (mut cells, mut weights, mut cdf) = (Vec::new(), Vec::new(), Vec::new());
        let (mut sum, mut rgb) = (0.0f64, glam::DVec3::ZERO);
        for (cell, mean) in per_brick.into_iter().flatten() {
            sum += mean.element_sum() as f64;
            rgb += mean.as_dvec3();
            cells.push(cell);
            weights.push(mean.element_sum());
            cdf.push(sum);
        }
        if cells.is_empty() || !(sum > 0.0 && sum.is_finite()) {
            return None;
        }
        cdf.iter_mut().for_each(|c| *c /= sum);
        let power = (rgb * (4.0 * PI * transform.voxel_volume())).as_vec3();
        Some(MediumEmission { cells, weights, cdf, power, density, field })
    }

    /// The emitting field (its grids for the GPU's lookups).
    pub fn field(&self) -> EmissionField<'a> {
        self.field
    }

    /// The cells as photon.wgsl's `MediumCell`s: lower corner, weight, and the cumulative
    /// weight as the integer threshold `ceil(cdf 2^53)` split at bit 26, against which the
    /// shader compares a draw's 53 bits exactly as [`MediumEmission::sample`] compares the
    /// f64 (a draw `u = k 2^-53` passes cdf `p` where `p <= u`, that is `ceil(p 2^53) <= k`).
    pub fn gpu_cells(&self) -> Vec<GpuMediumCell> {
        self.cells
            .iter()
            .zip(&self.weights)
            .zip(&self.cdf)
            .map(|((c, &weight), &p)| {
                let threshold = (p * 9_007_199_254_740_992.0).ceil() as u64;
                GpuMediumCell { cell: c.to_array(), weight, threshold: [(threshold >> 26) as u32, (threshold & ((1 << 26) - 1)) as u32], _pad: [0; 2] }
            })
            .collect()
    }

    /// The power the medium emits, 4 pi integral e dV per channel (see the module's notes).
    pub fn power(&self) -> Vec3 {
        self.power
    }

    /// A photon's origin, unit direction and `e(x) [density(x) > 0] / w_c`, the factor of
    /// the emitter's total power it carries.
    pub fn sample(&self, rng: &mut Rng) -> (DVec3, DVec3, Vec3) {
        let u = rng.next_f64();
        let c = self.cdf.partition_point(|&p| p <= u).min(self.cells.len() - 1);
        let offset = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64());
        let index = self.cells[c].as_dvec3() + offset;
        let x = self.density.transform().to_world(index);
        let dir = sample_uniform_sphere(rng.next_vec2()).as_dvec3().normalize();
        // The medium carries the emission: nothing leaves where the density is 0 (at the
        // cell's faces and corners only, by the note on trilinear weights above).
        let ratio = if self.density.sample_index(index) > 0.0 { self.field.at(x) / self.weights[c] } else { Vec3::ZERO };
        (x, dir, ratio)
    }
}
