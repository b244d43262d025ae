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
    memory_budget: Option<u64>,
    march_blocks: Option<bool>,
}

impl SceneBuilder {
    pub(super) fn new(volume: Volume, family: TransferFunction) -> Self {
        SceneBuilder {
            volume,
            family,
            brick_size: 16,
            grid: None,
            settings: RenderSettings::default(),
            memory_budget: None,
            march_blocks: None,
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

    /// At most this many bytes of voxels in memory for the bricks ([`crate::store`]): a
    /// volume larger than the budget is rendered by the brick engine, each brick read on
    /// demand (from the file for raw, NRRD and MetaImage raw data) into an LRU cache within
    /// the budget, and its bricks' ranges measured by streaming the file. `None` (the
    /// default), or a volume that fits, samples the whole volume. The images are the same.
    pub fn memory_budget(mut self, bytes: Option<u64>) -> Self {
        self.memory_budget = bytes;
        self
    }

    /// Whether the march engine's eight-ray packets read a blocked copy of the volume
    /// ([`crate::render::MarchBlocks`]: 1.2 × the voxels' memory more, faster on volumes
    /// far larger than the caches): `Some(true)` always, `Some(false)` never, `None` (the
    /// default) for volumes of 256 MiB and more whose copy fits half the available memory
    /// (or as `POFVR_BLOCKS=on|off` says). Under a [`Self::memory_budget`], only where the
    /// volume and its copy fit it together. The images are the same.
    pub fn march_blocks(mut self, on: Option<bool>) -> Self {
        self.march_blocks = on;
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
            None => crate::store::grid_for(&self.volume, self.brick_size, self.memory_budget)?,
        };
        let store = crate::store::cache_for(&self.volume, self.memory_budget)?;
        // A budget the volume fits but not beside its copy rules the copy out.
        let volume_bytes = crate::render::blocks::voxel_bytes(&self.volume);
        let over = self.memory_budget.is_some_and(|b| {
            (volume_bytes as u64)
                .saturating_add(crate::render::blocks::copy_bytes(&self.volume) as u64)
                > b
        });
        let march_blocks = if over { Some(false) } else { self.march_blocks };
        let mut job = RenderJob::with_grid(self.volume, self.family, grid, self.settings)?;
        job.store = store;
        let mut scene = Scene::adopt(job);
        scene.blocks_policy = march_blocks;
        Ok(scene)
    }
}
