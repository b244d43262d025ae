//! [`SceneBuilder`]: the settings a [`Scene`] is made with.

use crate::brick::BrickGrid;
use crate::error::Result;
use crate::frame::RenderJob;
use crate::render::{RenderSettings, TransferFunction};
use crate::volume::Volume;

use super::Scene;

/// Makes a [`Scene`]: [`Scene::builder`], the settings, then [`SceneBuilder::build`].
#[must_use = "a builder does nothing until `build` is called"]
#[derive(Debug)]
pub struct SceneBuilder {
    volume: Volume,
    family: TransferFunction,
    brick_size: usize,
    grid: Option<BrickGrid>,
    settings: RenderSettings,
}

impl SceneBuilder {
    pub(super) fn new(volume: Volume, family: TransferFunction) -> Self {
        SceneBuilder {
            volume,
            family,
            brick_size: 16,
            grid: None,
            settings: RenderSettings::default(),
        }
    }

    /// Brick edge in voxels, 2..=1024. Default 16.
    pub fn brick_size(mut self, voxels: usize) -> Self {
        self.brick_size = voxels;
        self
    }

    /// The brick grid, already cut from this volume with its value ranges (e.g. measured
    /// in pieces by several ranks); replaces [`SceneBuilder::brick_size`].
    pub fn grid(mut self, grid: BrickGrid) -> Self {
        self.grid = Some(grid);
        self
    }

    /// Sample distance in units of the smallest voxel spacing, in (0.001, 64]. Default 1.
    pub fn step(mut self, step: f32) -> Self {
        self.settings.step = step;
        self
    }

    /// Opacity at which a ray stops, > 0 (1 or more disables early termination). Default
    /// 0.99.
    pub fn early_termination(mut self, ert: f32) -> Self {
        self.settings.ert = ert;
        self
    }

    /// Jittered ray starts with this seed (see [`crate::render::jitter`]); `None`, the
    /// default, samples every ray on the unshifted lattice.
    pub fn jitter(mut self, seed: Option<u32>) -> Self {
        self.settings.jitter = seed;
        self
    }

    /// Checks the settings and the family's weights, bricks the volume (unless given a
    /// grid) and tabulates the family over its value range.
    ///
    /// # Errors
    /// [`crate::Error::OutOfRange`] for a bad step or threshold, [`crate::Error::Brick`]
    /// for a bad brick size, [`crate::Error::GridMismatch`] for a grid of another volume,
    /// [`crate::Error::WeightCount`] or [`crate::Error::Weight`] for bad default weights.
    pub fn build(self) -> Result<Scene> {
        crate::frame::check_settings(&self.settings)?;
        super::check_weights(&self.family, &self.family.weights)?;
        let grid = match self.grid {
            Some(g) => g,
            None => BrickGrid::from_volume(&self.volume, self.brick_size)?,
        };
        let job = RenderJob::with_grid(self.volume, self.family, grid, self.settings)?;
        Ok(Scene::adopt(job))
    }
}
