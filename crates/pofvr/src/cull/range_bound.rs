//! A bound that needs no precomputation: every sample of a brick has a value in the
//! brick's range, so its extinction is at least the smallest extinction over the bins of
//! that range; a ray running `L` inside the brick takes at least ⌊L/step⌋ samples.
//! Weak (one low voxel spoils it) but provably conservative, so it is the baseline that
//! POFs must beat and a cross-check in tests.

use glam::DVec3;

use super::OpacityBound;
use crate::brick::{BrickGrid, BrickId};
use crate::render::SampledTf;

/// Per-brick, per-basis minimum extinction over the brick's value range.
pub struct RangeBound {
    /// `tau_min[brick * bases + i]`.
    tau_min: Vec<f32>,
    bases: usize,
    step: f32,
    ert: f32,
    core: f32,
}

impl RangeBound {
    /// Measures every brick's minimum extinction per basis; `core` is the span length the
    /// bound is claimed for.
    #[must_use]
    pub fn new(grid: &BrickGrid, sampled: &SampledTf, step: f32, ert: f32, core: f32) -> Self {
        let bases = sampled.basis_count();
        let mut tau_min = Vec::with_capacity(grid.len() * bases);
        for r in grid.ranges() {
            let (b0, b1) = sampled.bin_range(*r);
            for i in 0..bases {
                tau_min.push(
                    sampled.tau_table(i)[b0..=b1]
                        .iter()
                        .copied()
                        .fold(f32::INFINITY, f32::min),
                );
            }
        }
        RangeBound {
            tau_min,
            bases,
            step,
            ert,
            core,
        }
    }

    fn bound(&self, brick: BrickId, weights: &[f32]) -> f32 {
        let row = &self.tau_min[brick.index() * self.bases..(brick.index() + 1) * self.bases];
        // min over bins of Σ kᵢτᵢ ≥ Σ kᵢ·min τᵢ.
        let tau: f32 = row.iter().zip(weights).map(|(t, k)| t * k).sum();
        let samples = (self.core / self.step).floor();
        // One step's alpha compounded, computed as the renderer does per sample; the small
        // relative slack absorbs the float difference between 1−Π(1−α) and 1−exp(−Στ).
        let alpha = 1.0 - (-tau * self.step * samples).exp();
        (alpha * (1.0 - 1e-5)).min(self.ert).max(0.0)
    }
}

impl OpacityBound for RangeBound {
    fn core_length(&self) -> f32 {
        self.core
    }
    fn opacity(&self, brick: BrickId, _dir: DVec3, weights: &[f32], _aggressive: bool) -> f32 {
        self.bound(brick, weights)
    }
    fn opacity_cone(
        &self,
        brick: BrickId,
        _axis: DVec3,
        _half: f64,
        weights: &[f32],
        _aggressive: bool,
    ) -> f32 {
        self.bound(brick, weights)
    }
}
