//! `render_frame`: the one place where the stages are chained.

use std::time::Instant;

use serde::Serialize;

use crate::brick::{BrickError, BrickGrid};
use crate::render::{
    Camera, Image, RayCaster, RayStats, RenderSettings, SampledTf, TfError, TransferFunction,
};
use crate::volume::Volume;

/// Everything a frame needs that does not change with the camera: the opened volume, its
/// bricks and the tabulated transfer-function family.
pub struct RenderJob {
    /// The volume.
    pub volume: Volume,
    /// Its bricks.
    pub grid: BrickGrid,
    /// The family with its current weights.
    pub tf: TransferFunction,
    /// The family tabulated over the volume's value range.
    pub sampled: SampledTf,
    /// Ray-caster settings.
    pub settings: RenderSettings,
}

/// Errors setting up a job.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum JobError {
    /// Bad brick size.
    #[error(transparent)]
    Brick(#[from] BrickError),
    /// Bad transfer function or weights.
    #[error(transparent)]
    Tf(#[from] TfError),
    /// Bad setting.
    #[error("{0}")]
    Setting(String),
}

impl RenderJob {
    /// Bricks the volume and tabulates the family over its value range.
    ///
    /// # Errors
    /// [`JobError`] for a bad brick size, step or early-termination threshold.
    pub fn new(
        volume: Volume,
        tf: TransferFunction,
        brick_size: usize,
        settings: RenderSettings,
    ) -> Result<Self, JobError> {
        if !(settings.step.is_finite() && settings.step > 1e-3 && settings.step <= 64.0) {
            return Err(JobError::Setting(format!(
                "--step {} must be in (0.001, 64]",
                settings.step
            )));
        }
        if !(settings.ert > 0.0 && settings.ert.is_finite()) {
            return Err(JobError::Setting(format!(
                "--ert {} must be > 0 (≥ 1 disables it)",
                settings.ert
            )));
        }
        let grid = BrickGrid::from_volume(&volume, brick_size)?;
        let sampled = SampledTf::new(&tf, grid.value_range());
        Ok(RenderJob {
            volume,
            grid,
            tf,
            sampled,
            settings,
        })
    }

    /// Number of bricks that are empty for the current weights.
    #[must_use]
    pub fn empty_bricks(&self) -> usize {
        self.grid
            .ranges()
            .iter()
            .filter(|r| self.sampled.is_empty(**r, &self.tf.weights))
            .count()
    }
}

/// Figures of one frame, written by `--stats`.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FrameStats {
    /// Wall time of the frame in milliseconds.
    pub frame_ms: f64,
    /// Rays that met the volume.
    pub rays: u64,
    /// Samples taken.
    pub samples: u64,
    /// `samples / frame time`.
    pub samples_per_second: f64,
    /// Worker threads used.
    pub threads: usize,
}

impl FrameStats {
    fn from_rays(st: RayStats, seconds: f64) -> Self {
        #[allow(clippy::cast_precision_loss)]
        let sps = if seconds > 0.0 {
            st.samples as f64 / seconds
        } else {
            0.0
        };
        FrameStats {
            frame_ms: seconds * 1e3,
            rays: st.rays,
            samples: st.samples,
            samples_per_second: sps,
            threads: rayon::current_num_threads(),
        }
    }
}

/// Renders the whole volume with the reference ray caster (no bricks, no culling).
#[must_use]
pub fn render_reference(job: &RenderJob, camera: &Camera) -> (Image, FrameStats) {
    let start = Instant::now();
    let cls = job.sampled.classify(&job.tf.weights, job.settings.step);
    let (image, st) = RayCaster::new(&job.volume, &cls, job.settings).render(camera);
    (
        image,
        FrameStats::from_rays(st, start.elapsed().as_secs_f64()),
    )
}
