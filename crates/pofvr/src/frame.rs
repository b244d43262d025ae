//! `render_frame`: the one place where the stages are chained.

use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use crate::brick::{BrickError, BrickGrid, BrickId};
use crate::cull::{CullMode, Culler, FrameBricks, OpacityBound};
use crate::render::{
    Camera, Image, PixelRect, RayCaster, RayStats, RenderSettings, SampledTf, TfError,
    TransferFunction,
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
    /// Rays that met the volume (reference) or a rendered brick (brick path; a ray crossing
    /// several bricks counts once per brick).
    pub rays: u64,
    /// Samples taken.
    pub samples: u64,
    /// `samples / frame time`.
    pub samples_per_second: f64,
    /// Worker threads used.
    pub threads: usize,
    /// Cull mode used.
    pub cull: Option<CullMode>,
    /// Brick counts for the mode used.
    pub bricks: BrickCounts,
    /// Per-rank breakdown.
    pub ranks: Vec<RankStats>,
    /// Ids of the culled bricks (for overlays and experiments).
    #[serde(skip)]
    pub culled_bricks: Vec<BrickId>,
}

/// Brick counts of a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct BrickCounts {
    /// All bricks.
    pub total: usize,
    /// Bricks empty for the current weights (skipped in every mode).
    pub empty: usize,
    /// `total − empty`.
    pub non_empty: usize,
    /// Non-empty bricks culled (never loaded, sampled or sent).
    pub culled: usize,
    /// Non-empty bricks rendered (`non_empty − culled`, less bricks off-screen).
    pub visible: usize,
}

/// One rank's share of a frame.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RankStats {
    /// The rank.
    pub rank: usize,
    /// Bricks it ray-cast.
    pub bricks_rendered: usize,
    /// Samples it took.
    pub samples: u64,
    /// Culling time for its tile.
    pub cull_ms: f64,
    /// Ray-casting time.
    pub raycast_ms: f64,
    /// Compositing time.
    pub composite_ms: f64,
    /// Time in communication (exchanges and waits).
    pub comm_ms: f64,
    /// Bytes it sent.
    pub bytes_sent: u64,
}

/// Per-frame choices.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameOptions {
    /// Cull mode.
    pub cull: CullMode,
    /// Opacity at which a pixel hides what is behind it.
    pub cull_threshold: f32,
}

impl Default for FrameOptions {
    fn default() -> Self {
        FrameOptions {
            cull: CullMode::Pof,
            cull_threshold: 0.95,
        }
    }
}

/// Errors of one frame.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FrameError {
    /// A POF mode without POFs.
    #[error("--cull {0} needs precomputed POFs (--pof FILE.pof, built by `pofvr pof build`)")]
    NoPofs(&'static str),
    /// Bad option.
    #[error("{0}")]
    Option(String),
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
            ..FrameStats::default()
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

/// A brick's partial image: premultiplied RGBA over its footprint, composited in `order`.
struct Fragment {
    order: usize,
    rect: PixelRect,
    pixels: Vec<[f32; 4]>,
}

/// Renders a frame the paper's way: cull bricks, ray-cast each visible brick over its own
/// footprint, composite the partial images in visibility order.
///
/// # Errors
/// [`FrameError`] when a POF mode has no bounds or an option is out of range.
pub fn render_frame(
    job: &RenderJob,
    bounds: Option<&dyn OpacityBound>,
    camera: &Camera,
    opts: &FrameOptions,
) -> Result<(Image, FrameStats), FrameError> {
    if opts.cull.needs_pofs() && bounds.is_none() {
        return Err(FrameError::NoPofs(opts.cull.name()));
    }
    if !(opts.cull_threshold > 0.0 && opts.cull_threshold <= 1.0) {
        return Err(FrameError::Option(format!(
            "--cull-threshold {} must be in (0, 1]",
            opts.cull_threshold
        )));
    }
    let start = Instant::now();
    let weights = &job.tf.weights;
    let cls = job.sampled.classify(weights, job.settings.step);
    let caster = RayCaster::new(&job.volume, &cls, job.settings);
    let bricks = FrameBricks::new(&job.volume, &job.grid, &job.sampled, weights, camera);
    let culler = Culler {
        volume: &job.volume,
        grid: &job.grid,
        mode: opts.cull,
        threshold: opts.cull_threshold,
        weights,
        bounds,
        caster: &caster,
    };
    let whole = PixelRect {
        x0: 0,
        y0: 0,
        x1: camera.width,
        y1: camera.height,
    };
    let culled = culler.cull(camera, &bricks, whole);
    let t_cast = Instant::now();
    let frame = camera.frame();
    let order_of: std::collections::HashMap<BrickId, usize> = bricks
        .order
        .iter()
        .enumerate()
        .map(|(i, id)| (*id, i))
        .collect();
    let (mut frags, rays): (Vec<Fragment>, Vec<RayStats>) = culled
        .visible
        .par_iter()
        .map(|id| {
            let rect = bricks.footprints[id.index()].expect("visible bricks are on screen");
            let (pixels, st) = caster.render_box(camera, &frame, rect, &job.grid.index_box(*id));
            (
                Fragment {
                    order: order_of[id],
                    rect,
                    pixels,
                },
                st,
            )
        })
        .unzip();
    let raycast_ms = t_cast.elapsed().as_secs_f64() * 1e3;
    let t_comp = Instant::now();
    frags.sort_unstable_by_key(|f| f.order);
    let mut image = Image::new(camera.width, camera.height);
    let w = camera.width as usize;
    for f in &frags {
        let fw = f.rect.width() as usize;
        for (row, src_row) in f.pixels.chunks_exact(fw).enumerate() {
            let y = f.rect.y0 as usize + row;
            let dst_row = &mut image.pixels_mut()[y * w + f.rect.x0 as usize..][..fw];
            for (d, s) in dst_row.iter_mut().zip(src_row) {
                let k = 1.0 - d[3];
                for c in 0..4 {
                    d[c] += k * s[c];
                }
            }
        }
    }
    let composite_ms = t_comp.elapsed().as_secs_f64() * 1e3;
    let mut total = RayStats::default();
    for r in rays {
        total += r;
    }
    let seconds = start.elapsed().as_secs_f64();
    let mut stats = FrameStats::from_rays(total, seconds);
    let non_empty = job.grid.len() - bricks.empty;
    stats.cull = Some(opts.cull);
    stats.bricks = BrickCounts {
        total: job.grid.len(),
        empty: bricks.empty,
        non_empty,
        culled: culled.culled.len(),
        visible: culled.visible.len(),
    };
    stats.ranks = vec![RankStats {
        rank: 0,
        bricks_rendered: culled.visible.len(),
        samples: total.samples,
        cull_ms: culled.cull_ms,
        raycast_ms,
        composite_ms,
        comm_ms: 0.0,
        bytes_sent: 0,
    }];
    stats.culled_bricks = culled.culled;
    Ok((image, stats))
}
