//! Figure 6: frame time, speedup and load balance against the number of ranks.

use serde::Serialize;

use crate::distribute::Curve;
use crate::frame::{FrameOptions, RenderJob};
use crate::render::Camera;

use super::{load_balance, timed_point, ExperimentError, Method, Progress};

/// Rank counts 1, 2, 4, … up to `max`, and `max` itself.
#[must_use]
pub fn rank_counts(max: usize) -> Vec<usize> {
    let mut v = Vec::new();
    let mut r = 1;
    while r <= max {
        v.push(r);
        r *= 2;
    }
    if v.last() != Some(&max) {
        v.push(max);
    }
    v
}

/// One point of figure 6.
#[derive(Clone, Debug, Serialize)]
pub struct SpeedupRow {
    /// Curve the bricks are dealt along.
    pub curve: Curve,
    /// Culling method.
    pub method: &'static str,
    /// Ranks.
    pub ranks: usize,
    /// Median frame time.
    pub frame_ms: f64,
    /// Frame time at 1 rank (the first count) over this one.
    pub speedup: f64,
    /// Speedup per rank.
    pub efficiency: f64,
    /// Max over mean samples per rank.
    pub load_balance_max_over_mean_samples: f64,
    /// Samples taken.
    pub samples: u64,
    /// Bricks rendered.
    pub visible: usize,
}

/// The best speedup of figure 6.
#[derive(Clone, Debug, Serialize)]
pub struct BestSpeedup {
    /// `CURVE, cull METHOD`.
    pub best: String,
    /// Ranks.
    pub ranks: usize,
    /// Speedup.
    pub speedup: f64,
}

/// Figure 6: curve-major, then method, then rank count.
#[derive(Clone, Debug, Serialize)]
pub struct Speedup {
    /// Rank counts measured.
    pub rank_counts: Vec<usize>,
    /// The points.
    pub rows: Vec<SpeedupRow>,
    /// The highest speedup (the first of equals).
    pub best: Option<BestSpeedup>,
}

/// Timed points (median of `reps` frames, one core per rank) at each of `rank_counts`, for
/// the Hilbert and Z curves and each of `methods`, seen by `camera`.
///
/// # Errors
/// [`ExperimentError`] when a frame fails.
pub fn speedup(
    job: &RenderJob,
    methods: &[Method<'_>],
    camera: &Camera,
    threshold: f32,
    rank_counts: &[usize],
    reps: usize,
    progress: &dyn Progress,
) -> Result<Speedup, ExperimentError> {
    let curves = [Curve::Hilbert, Curve::Z];
    progress.begin(
        "fig 6: speedup",
        (curves.len() * methods.len() * rank_counts.len()) as u64,
    );
    let mut rows = Vec::new();
    let mut best: Option<BestSpeedup> = None;
    for curve in curves {
        for m in methods {
            let mut t1 = None;
            for &r in rank_counts {
                let opts = FrameOptions {
                    cull: m.mode,
                    cull_threshold: threshold,
                    ranks: r,
                    curve,
                    ..FrameOptions::default()
                };
                let st = timed_point(job, m, camera, &opts, reps)?;
                let speedup = *t1.get_or_insert(st.frame_ms) / st.frame_ms;
                let better = match &best {
                    Some(b) => b.speedup < speedup,
                    None => true,
                };
                if better {
                    best = Some(BestSpeedup {
                        best: format!("{curve}, cull {}", m.name),
                        ranks: r,
                        speedup,
                    });
                }
                rows.push(SpeedupRow {
                    curve,
                    method: m.name,
                    ranks: r,
                    frame_ms: st.frame_ms,
                    speedup,
                    efficiency: speedup / r as f64,
                    load_balance_max_over_mean_samples: load_balance(&st),
                    samples: st.samples,
                    visible: st.bricks.visible,
                });
                progress.inc();
            }
        }
    }
    progress.end();
    Ok(Speedup {
        rank_counts: rank_counts.to_vec(),
        rows,
        best,
    })
}
