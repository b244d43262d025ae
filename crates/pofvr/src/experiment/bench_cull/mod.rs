//! The culling bench: frame and culling time of each cull mode at 1 to 32 ranks, the
//! culled fractions, the load balance, a sweep of views, and measures that targets name.

mod sweep;
mod targets;

pub use sweep::{sweep, sweep_views, sweep_with, Spread, SweepSummary, SweepView};
pub use targets::{evaluate_targets, Target, TargetSpec};

use serde::Serialize;

use crate::cull::{CullMode, OpacityBound};
use crate::frame::{render_frame, FrameOptions, FrameStats, RenderJob};
use crate::render::Camera;

use super::{culled_fraction, load_balance, ExperimentError, Progress};

/// The cases of the bench, (mode, ranks, replicas): the paper's deal at every count, and
/// two owners per brick where balance is the question.
pub const CASES: [(CullMode, usize, usize); 14] = [
    (CullMode::None, 1, 1),
    (CullMode::Pof, 1, 1),
    (CullMode::PofSet, 1, 1),
    (CullMode::Exact, 1, 1),
    (CullMode::Verified, 1, 1),
    (CullMode::None, 2, 1),
    (CullMode::Pof, 2, 1),
    (CullMode::None, 8, 1),
    (CullMode::Pof, 8, 1),
    (CullMode::Pof, 8, 2),
    (CullMode::Verified, 8, 1),
    (CullMode::None, 32, 1),
    (CullMode::Pof, 32, 1),
    (CullMode::Pof, 32, 2),
];

/// One case of the bench, its median frame summarised.
#[derive(Clone, Debug, Serialize)]
pub struct CullCase {
    /// Cull mode.
    pub mode: &'static str,
    /// In-process ranks.
    pub ranks: usize,
    /// Owners per brick.
    pub replicas: usize,
    /// Median frame time.
    pub median_frame_ms: f64,
    /// Median over the repetitions of the slowest rank's culling time.
    pub max_cull_ms: f64,
    /// `max_cull_ms / median_frame_ms`.
    pub cull_share_of_frame: f64,
    /// Bricks culled.
    pub culled: usize,
    /// Non-empty bricks.
    pub non_empty: usize,
    /// `culled / non_empty`.
    pub culled_fraction: f64,
    /// Samples taken.
    pub samples: u64,
    /// Max over mean samples per rank.
    pub load_balance_max_over_mean_samples: f64,
    /// Median over the repetitions of the slowest rank's verification time (0 unless
    /// verified).
    pub max_verify_ms: f64,
    /// The same for the repair.
    pub max_repair_ms: f64,
    /// Bricks repaired (of the median frame).
    pub repaired: usize,
}

impl CullCase {
    /// The median frame of `runs` (at least one) of a case, summarised.
    fn of(mode: CullMode, (ranks, replicas): (usize, usize), mut runs: Vec<FrameStats>) -> Self {
        // Each of frame and culling time is the median of its own: the slowest rank's
        // culling in one frame says little on a machine shared with other work.
        let median_of_slowest = |f: &dyn Fn(&crate::frame::RankStats) -> f64| {
            let mut v: Vec<f64> = runs
                .iter()
                .map(|st| st.ranks.iter().map(f).fold(0.0, f64::max))
                .collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let max_cull = median_of_slowest(&|r| r.cull_ms);
        let max_verify = median_of_slowest(&|r| r.verify_ms);
        let max_repair = median_of_slowest(&|r| r.repair_ms);
        runs.sort_by(|a, b| a.frame_ms.total_cmp(&b.frame_ms));
        let st = &runs[runs.len() / 2];
        CullCase {
            mode: mode.name(),
            ranks,
            replicas,
            median_frame_ms: st.frame_ms,
            max_cull_ms: max_cull,
            cull_share_of_frame: max_cull / st.frame_ms,
            culled: st.bricks.culled,
            non_empty: st.bricks.non_empty,
            culled_fraction: culled_fraction(st),
            samples: st.samples,
            load_balance_max_over_mean_samples: load_balance(st),
            max_verify_ms: max_verify,
            max_repair_ms: max_repair,
            repaired: st.bricks.repaired,
        }
    }
}

/// The bench's cases, in the order of [`CASES`].
#[derive(Clone, Debug, Serialize)]
pub struct CullBench {
    /// One per case.
    pub cases: Vec<CullCase>,
    /// Median frame time without culling over that with POF culling, at 1 rank.
    pub speedup_pof_vs_none: Option<f64>,
    /// Median frame time without culling over that with verified culling, at 1 rank.
    pub speedup_verified_vs_none: Option<f64>,
    /// The same at 8 ranks.
    pub speedup_verified_vs_none_8: Option<f64>,
}

impl CullBench {
    /// The case of `mode` at `ranks` and `replicas`.
    #[must_use]
    pub fn case(&self, mode: &str, ranks: usize, replicas: usize) -> Option<&CullCase> {
        self.cases
            .iter()
            .find(|c| c.mode == mode && c.ranks == ranks && c.replicas == replicas)
    }

    /// The measures targets can name, by name, in a fixed order.
    #[must_use]
    pub fn measures(&self) -> Vec<(String, f64)> {
        let mut out = Vec::new();
        if let Some(c) = self.case("pof", 1, 1) {
            out.push((
                "culling share of the frame (pof, 1 rank)".to_string(),
                c.cull_share_of_frame,
            ));
        }
        if let Some(e) = self.case("exact", 1, 1) {
            for m in ["pof", "pof-set"] {
                if let Some(c) = self.case(m, 1, 1) {
                    // pof-set is the paper's estimate, not a bound: named so beside the
                    // conservative mode's.
                    out.push((
                        format!(
                            "points culled below exact ({m}{})",
                            if m == "pof-set" { ", an estimate" } else { "" }
                        ),
                        100.0 * (e.culled_fraction - c.culled_fraction),
                    ));
                }
            }
        }
        for k in [1, 2] {
            if let Some(c) = self.case("pof", 32, k) {
                out.push((
                    format!(
                        "load balance at 32 ranks ({k} replica{})",
                        if k == 1 { "" } else { "s" }
                    ),
                    c.load_balance_max_over_mean_samples,
                ));
            }
        }
        if let Some(x) = self.speedup_pof_vs_none {
            out.push(("frame speed-up, pof over none (1 rank)".to_string(), x));
        }
        if let Some(x) = self.speedup_verified_vs_none {
            out.push(("frame speed-up, verified over none (1 rank)".to_string(), x));
        }
        if let Some(x) = self.speedup_verified_vs_none_8 {
            out.push((
                "frame speed-up, verified over none (8 ranks)".to_string(),
                x,
            ));
        }
        out
    }
}

/// Renders every case of [`CASES`] `reps` times (at least once) with `bounds` for the POF
/// modes, seen by `camera`. Repetitions interleave the cases (one frame of each in turn),
/// so that the machine's drift during the run weighs on every case alike and the ratios
/// compare like with like; the oracle, slow and deterministic, runs once.
///
/// # Errors
/// [`ExperimentError::Frame`] when a frame fails.
pub fn bench_cull(
    job: &RenderJob,
    bounds: &dyn OpacityBound,
    camera: &Camera,
    reps: usize,
    progress: &dyn Progress,
) -> Result<CullBench, ExperimentError> {
    let reps = reps.max(1);
    progress.begin("bench cull", (CASES.len() * reps) as u64);
    let mut runs: Vec<Vec<FrameStats>> = vec![Vec::new(); CASES.len()];
    for rep in 0..reps {
        for (k, &(mode, ranks, replicas)) in CASES.iter().enumerate() {
            progress.inc();
            if mode == CullMode::Exact && rep > 0 {
                continue;
            }
            let opts = FrameOptions {
                cull: mode,
                ranks,
                replicas,
                ..FrameOptions::default()
            };
            runs[k].push(render_frame(job, Some(bounds), camera, &opts)?.1);
        }
    }
    progress.end();
    let cases: Vec<CullCase> = CASES
        .iter()
        .zip(runs)
        .map(|(&(mode, ranks, replicas), r)| CullCase::of(mode, (ranks, replicas), r))
        .collect();
    let mut bench = CullBench {
        cases,
        speedup_pof_vs_none: None,
        speedup_verified_vs_none: None,
        speedup_verified_vs_none_8: None,
    };
    let speedup = |mode, ranks| match (bench.case("none", ranks, 1), bench.case(mode, ranks, 1)) {
        (Some(none), Some(m)) => Some(none.median_frame_ms / m.median_frame_ms),
        _ => None,
    };
    let (one, eight) = (speedup("verified", 1), speedup("verified", 8));
    bench.speedup_verified_vs_none = one;
    bench.speedup_verified_vs_none_8 = eight;
    bench.speedup_pof_vs_none = match (bench.case("none", 1, 1), bench.case("pof", 1, 1)) {
        (Some(none), Some(pof)) => Some(none.median_frame_ms / pof.median_frame_ms),
        _ => None,
    };
    Ok(bench)
}

/// One frame culled (POF mode, one rank) with `bound`, e.g. ideal POFs, seen by `camera`.
///
/// # Errors
/// [`ExperimentError::Frame`] when the frame fails.
pub fn cull_once(
    job: &RenderJob,
    bound: &dyn OpacityBound,
    camera: &Camera,
) -> Result<FrameStats, ExperimentError> {
    let opts = FrameOptions {
        cull: CullMode::Pof,
        ..FrameOptions::default()
    };
    Ok(render_frame(job, Some(bound), camera, &opts)?.1)
}
