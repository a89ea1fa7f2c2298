//! Particle attributes to grids (design.md section 8, issue #20): SPH interpolation with the
//! density's own smoothing lengths, normalised by the kernel sum (Shepard).
//!
//! At a voxel x with the final smoothing length h(x) of the density pass,
//!
//! ```text
//! A(x) = sum_q V_q A_q W(|x - x_q|, h(x)) / sum_q V_q W(|x - x_q|, h(x)),   V_q = m_q / rho_q
//! ```
//!
//! over the particles within kappa*h(x), wherever the denominator is positive, which is
//! wherever the density is (the same particles reach the voxel); elsewhere the attribute is 0
//! and inactive. The division is done everywhere, not only where the kernel sum falls short
//! of 1: the weights are then a convex combination, so a constant attribute is that constant
//! at every voxel any particle reaches, the grid never leaves the range of the particles'
//! values, and at the rim (the last voxel or two a kernel reaches) the value is the mean of
//! the few particles in reach instead of fading to 0 with the density. The kernel's
//! 1/(pi h^3) is common to both sums at a voxel and cancels.
//!
//! rho_q is the estimator's density at the particle: the density grid (before noise and the
//! activity threshold) read trilinearly at x_q. That is the SPH density with the same
//! smoothing lengths (the gather estimate has a length per grid point, not per particle),
//! and it is positive: every corner of the particle's cell lies within its kernel (h >= h_min
//! and the default h_min of 1.2 voxels exceeds half the cell's diagonal); a particle whose
//! rho_q is 0 all the same (a much smaller `--h-min`) or whose mass is 0 has no weight. A
//! particle whose value of an attribute is not finite is left out of that attribute's sums
//! (its mass stays in the density and the other attributes) and counted.
//!
//! The grids are active where the density is: same bricks, same voxel masks.

use glam::{IVec3, Vec3};
use nimbus_volume::{brick_offset, Volume, BRICK_DIM, BRICK_VOXELS};
use rayon::prelude::*;

use crate::setup::{dense_index, floor_i, Prepared};
use crate::{Attribute, BrickResult, DensityError, ParticleSet};

/// An interpolated attribute grid, active where the density grid is.
#[derive(Clone, Debug)]
pub enum AttributeVolume {
    Float(Volume<f32>),
    Vec3(Volume<Vec3>),
}

/// One requested attribute's grid and what was left out of it.
#[derive(Clone, Debug)]
pub struct AttributeOutput {
    /// The attribute's name in the particle set (as requested).
    pub name: String,
    pub volume: AttributeVolume,
    /// Particles left out for a non-finite value.
    pub skipped_nonfinite: u64,
}

/// The attributes `names` of `particles`, checked: each must exist with one value per
/// particle.
pub(crate) fn check<'a>(particles: &'a ParticleSet, names: &[String]) -> Result<Vec<&'a Attribute>, DensityError> {
    names
        .iter()
        .map(|name| {
            let a = particles.attributes.get(name).ok_or_else(|| DensityError::UnknownAttribute {
                name: name.clone(),
                available: if particles.attributes.is_empty() { "none".into() } else { particles.attributes.keys().cloned().collect::<Vec<_>>().join(", ") },
            })?;
            if a.len() != particles.len() {
                return Err(DensityError::InvalidParam { name: "attribute", value: name.clone(), why: "has not one value per particle" });
            }
            Ok(a)
        })
        .collect()
}

/// The density at each particle (world units, `Prepared` order): the raw density of the
/// bricks read trilinearly at the particle's index position, 0 outside them.
pub(crate) fn particle_density(prep: &Prepared, bricks: &[BrickResult]) -> Vec<f32> {
    let dims = prep.grid.dims;
    let brick_dims = (dims + (BRICK_DIM - 1)) / BRICK_DIM;
    let mut slot = vec![u32::MAX; brick_dims.as_i64vec3().element_product() as usize];
    for (i, b) in bricks.iter().enumerate() {
        slot[dense_index(b.origin / BRICK_DIM, brick_dims)] = i as u32;
    }
    let rho_at = |v: IVec3| -> f32 {
        if !(v.cmpge(IVec3::ZERO).all() && v.cmplt(dims).all()) {
            return 0.0;
        }
        match slot[dense_index(v / BRICK_DIM, brick_dims)] {
            u32::MAX => 0.0,
            s => bricks[s as usize].rho[brick_offset(v % BRICK_DIM)],
        }
    };
    prep.positions
        .par_iter()
        .map(|&p| {
            let base = floor_i(p);
            let f = p - base.as_vec3();
            let mut rho = 0.0f32;
            for corner in 0..8 {
                let c = IVec3::new(corner & 1, (corner >> 1) & 1, corner >> 2);
                let w = Vec3::select(c.cmpeq(IVec3::ONE).into(), f, Vec3::ONE - f).element_product();
                if w > 0.0 {
                    rho += w * rho_at(base + c);
                }
            }
            rho
        })
        .collect()
}

/// Where each attribute's sums go among the channels: channel 0 is the kernel sum of every
/// particle with a weight, shared by the attributes whose values are all finite; an attribute
/// with non-finite values (left out per particle) has a weight channel of its own. Then
/// each attribute's components.
struct Layout {
    channels: usize,
    /// Per attribute: (its weight channel, its first component channel, its width).
    at: Vec<(usize, usize, usize)>,
}

impl Layout {
    fn new(attributes: &[&Attribute], skipped: &[u64]) -> Layout {
        let mut channels = 1;
        let at = attributes
            .iter()
            .zip(skipped)
            .map(|(a, &skipped)| {
                let weight = if skipped > 0 {
                    channels += 1;
                    channels - 1
                } else {
                    0
                };
                let first = channels;
                channels += a.width();
                (weight, first, a.width())
            })
            .collect();
        Layout { channels, at }
    }
}

/// Per particle (`Prepared` order), the channels the attribute pass sums ([`Layout`]): the
/// weight V_q and V_q times each component; zero where the value is not finite (its own
/// weight channel too) or the particle has no weight.
fn channel_values(prep: &Prepared, attributes: &[&Attribute], layout: &Layout, rho: &[f32]) -> Vec<f32> {
    let channels = layout.channels;
    let mut values = vec![0.0f32; prep.positions.len() * channels];
    values.par_chunks_mut(channels).enumerate().for_each(|(q, out)| {
        let rho_q = rho[q];
        let weight = if rho_q > 0.0 && rho_q.is_finite() { prep.masses[q] / rho_q } else { 0.0 };
        if !(weight > 0.0 && weight.is_finite()) {
            return;
        }
        let src = prep.source[q] as usize;
        out[0] = weight;
        for (a, &(w, first, k)) in attributes.iter().zip(&layout.at) {
            let value = a.get(src);
            if value[..k].iter().all(|x| x.is_finite()) {
                out[w] = weight;
                for c in 0..k {
                    out[first + c] = weight * value[c];
                }
            }
        }
    });
    values
}

/// Bricks one call of the backend's splat covers: bounds the raw sums held at once (8
/// channels of 4096 bricks: 64 MiB) next to the normalised grids they become.
const SPLAT_CHUNK_BRICKS: usize = 1 << 12;

/// The CPU's attribute splat (rayon over the bricks, cpu.rs `splat_attributes` per brick);
/// the GPU's is gpu.rs `AttributePass`. For a slice of the bricks with density (final lengths
/// kept), per brick and channel, sum_q values[q][c] * m4_shape(r / h) over the particles
/// within kappa*h of each voxel where the density is positive; `values` holds `channels`
/// floats per particle in [`Prepared`] order.
pub(crate) fn splat_cpu(prep: &Prepared, _: &crate::PointParams, bricks: &[BrickResult], values: &[f32], channels: usize) -> Result<Vec<Vec<[f32; BRICK_VOXELS]>>, DensityError> {
    Ok(bricks
        .par_iter()
        .map(|b| {
            let h = b.h.as_ref().expect("lengths kept for the attribute pass");
            let reached: [bool; BRICK_VOXELS] = std::array::from_fn(|v| b.rho[v] > 0.0);
            crate::cpu::splat_attributes(prep, b.origin, h, &reached, values, channels)
        })
        .collect())
}

/// Runs the attribute pass over every brick with density, the sums from `splat`, and stores
/// each brick's normalised components (attribute by attribute, component by component) in
/// `BrickResult::attributes`; returns each attribute's count of particles left out for a
/// non-finite value. The bricks must hold their lengths (`Keep::h`). `splat(bricks, values,
/// channels)` is the backend's kernel sums ([`splat_cpu`]).
pub(crate) fn interpolate(
    prep: &Prepared,
    attributes: &[&Attribute],
    bricks: &mut [BrickResult],
    mut splat: impl FnMut(&[BrickResult], &[f32], usize) -> Result<Vec<Vec<[f32; BRICK_VOXELS]>>, DensityError>,
) -> Result<Vec<u64>, DensityError> {
    let skipped: Vec<u64> = attributes
        .iter()
        .map(|a| prep.source.par_iter().filter(|&&src| !a.get(src as usize)[..a.width()].iter().all(|x| x.is_finite())).count() as u64)
        .collect();
    let layout = Layout::new(attributes, &skipped);
    let rho = particle_density(prep, bricks);
    let values = channel_values(prep, attributes, &layout, &rho);
    drop(rho);
    for chunk in bricks.chunks_mut(SPLAT_CHUNK_BRICKS) {
        let sums = splat(chunk, &values, layout.channels)?;
        chunk.par_iter_mut().zip(sums).for_each(|(b, sums)| {
            let mut out = Vec::with_capacity(layout.channels);
            for &(w, first, k) in &layout.at {
                let weight = &sums[w];
                for c in 0..k {
                    let sum = &sums[first + c];
                    out.push(Box::new(std::array::from_fn(|v| if weight[v] > 0.0 { sum[v] / weight[v] } else { 0.0 })));
                }
            }
            b.attributes = out;
        });
    }
    Ok(skipped)
}
