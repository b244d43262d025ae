//! Figure 5: the time of each rank in one frame, without culling and with it.

use serde::Serialize;

use crate::distribute::Curve;
use crate::frame::{FrameOptions, FrameStats, RenderJob};
use crate::render::Camera;

use super::{load_balance, timed_point, ExperimentError, Method, Progress};

/// One method's frame of figure 5.
#[derive(Clone, Debug, Serialize)]
pub struct RankFrame {
    /// Culling method.
    pub method: &'static str,
    /// Ranks of the frame.
    pub ranks: usize,
    /// Median frame time.
    pub frame_ms: f64,
    /// Bricks culled.
    pub culled: usize,
    /// Bricks rendered.
    pub visible: usize,
    /// Bricks rendered after verification found them culled wrongly (verified culling;
    /// 0 for the others). Counted in `visible`.
    pub repaired: usize,
    /// Max over mean samples per rank.
    pub load_balance_max_over_mean_samples: f64,
    /// The frame's statistics, one entry per rank in `stats.ranks`.
    #[serde(skip)]
    pub stats: FrameStats,
}

/// Figure 5: one frame per method.
#[derive(Clone, Debug, Serialize)]
pub struct RankBreakdown {
    /// One per method, in the order given.
    pub frames: Vec<RankFrame>,
}

/// The median of `reps` frames of `ranks` ranks (one core each, Hilbert curve) for each of
/// `methods`, seen by `camera`.
///
/// # Errors
/// [`ExperimentError`] when a frame fails.
pub fn rank_breakdown(
    job: &RenderJob,
    methods: &[Method<'_>],
    camera: &Camera,
    threshold: f32,
    ranks: usize,
    reps: usize,
    progress: &dyn Progress,
) -> Result<RankBreakdown, ExperimentError> {
    progress.begin("fig 5: per-rank breakdown", methods.len() as u64);
    let mut frames = Vec::new();
    for m in methods {
        let opts = FrameOptions {
            cull: m.mode,
            cull_threshold: threshold,
            ranks,
            curve: Curve::Hilbert,
            ..FrameOptions::default()
        };
        let st = timed_point(job, m, camera, &opts, reps)?;
        frames.push(RankFrame {
            method: m.name,
            ranks,
            frame_ms: st.frame_ms,
            culled: st.bricks.culled,
            visible: st.bricks.visible,
            repaired: st.bricks.repaired,
            load_balance_max_over_mean_samples: load_balance(&st),
            stats: st,
        });
        progress.inc();
    }
    progress.end();
    Ok(RankBreakdown { frames })
}
