//! Ideal POFs, a diagnostic: each brick's core-footprint minimum measured by rendering it
//! alone along the frame's own direction ([`crate::pof::reference::core_min`]), at the
//! moment culling asks for it.
//!
//! Why: culling with stored POFs falls short of the `exact` oracle for two reasons, the
//! bound's slack (a table cell covers many directions; a rigorous bound covers every ray
//! and lattice phase) and what any single number per brick cannot say (where in its
//! footprint a brick is opaque). Culling with the measured minima instead of the tables
//! removes the first and leaves the second, so comparing `pof`, ideal and `exact` splits
//! the gap in two. Not a bound: a measurement on a ray grid, too slow for frames (one
//! brick render per brick and level), orthographic views only.

use std::collections::HashMap;
use std::sync::Mutex;

use glam::DVec3;

use super::OpacityBound;
use crate::brick::{BrickGrid, BrickId};
use crate::pof::reference::{core_min, ReferenceProbe};
use crate::render::SampledTf;
use crate::volume::Volume;

/// Measured core minima, one level per core length (shortest first, as
/// [`super::CoreLevels`]).
pub struct IdealPofs<'a> {
    /// By core length, shortest first; never empty.
    levels: Vec<IdealLevel<'a>>,
}

/// The measured minima for one core length.
struct IdealLevel<'a> {
    volume: &'a Volume,
    grid: &'a BrickGrid,
    sampled: &'a SampledTf,
    step: f32,
    ert: f32,
    core: f32,
    /// Minima already measured, by brick, direction and weights (a frame asks once per
    /// brick; the key keeps later frames right).
    measured: Mutex<HashMap<Key, f32>>,
}

type Key = (u32, [u64; 3], Vec<u32>);

/// Rays per voxel of the measuring render, along each image axis.
const PIXEL: f64 = 0.5;

impl<'a> IdealPofs<'a> {
    /// Levels for `core_lengths` (any order; empty gives `None`), measured with the
    /// renderer's `step` and early-termination threshold `ert`.
    #[must_use]
    pub fn new(
        volume: &'a Volume,
        grid: &'a BrickGrid,
        sampled: &'a SampledTf,
        (step, ert): (f32, f32),
        core_lengths: &[f32],
    ) -> Option<Self> {
        let mut cores = core_lengths.to_vec();
        cores.sort_by(f32::total_cmp);
        let levels: Vec<IdealLevel<'a>> = cores
            .into_iter()
            .map(|core| IdealLevel {
                volume,
                grid,
                sampled,
                step,
                ert,
                core,
                measured: Mutex::new(HashMap::new()),
            })
            .collect();
        (!levels.is_empty()).then_some(IdealPofs { levels })
    }
}

/// The levels measure as their shortest core does; the longer ones are
/// [`OpacityBound::deeper`].
impl OpacityBound for IdealPofs<'_> {
    fn core_length(&self) -> f32 {
        self.levels[0].core_length()
    }

    fn opacity(&self, brick: BrickId, dir: DVec3, weights: &[f32], aggressive: bool) -> f32 {
        self.levels[0].opacity(brick, dir, weights, aggressive)
    }

    fn opacity_cone(
        &self,
        brick: BrickId,
        axis: DVec3,
        half_angle: f64,
        weights: &[f32],
        aggressive: bool,
    ) -> f32 {
        self.levels[0].opacity_cone(brick, axis, half_angle, weights, aggressive)
    }

    fn deeper(&self, k: usize) -> Option<&dyn OpacityBound> {
        self.levels.get(k + 1).map(|l| l as &dyn OpacityBound)
    }

    fn ert(&self) -> f32 {
        self.levels[0].ert()
    }
}

impl OpacityBound for IdealLevel<'_> {
    fn core_length(&self) -> f32 {
        self.core
    }

    fn opacity(&self, brick: BrickId, dir: DVec3, weights: &[f32], _aggressive: bool) -> f32 {
        let key = (
            brick.0,
            dir.to_array().map(f64::to_bits),
            weights.iter().map(|w| w.to_bits()).collect(),
        );
        let measured = || {
            self.measured
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
        };
        if let Some(a) = measured().get(&key) {
            return *a;
        }
        let probe = ReferenceProbe {
            dir,
            phase: 0.0,
            jitter: [0.0, 0.0],
            pixel: PIXEL,
        };
        let view = core_min(
            self.volume,
            self.grid,
            self.sampled,
            brick,
            weights,
            self.step,
            self.ert,
            self.core,
            &probe,
        );
        let a = view.core_min.unwrap_or(0.0);
        measured().insert(key, a);
        a
    }

    /// Nothing: the measurement is for one direction, not a cone (perspective views).
    fn opacity_cone(
        &self,
        _brick: BrickId,
        _axis: DVec3,
        _half_angle: f64,
        _weights: &[f32],
        _aggressive: bool,
    ) -> f32 {
        0.0
    }

    fn ert(&self) -> f32 {
        self.ert
    }
}
