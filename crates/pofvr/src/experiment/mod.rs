//! The paper's §5 experiments and the culling bench as functions that return their
//! measurements, one per figure; writing them as CSV, SVG or HTML is the caller's business.
//!
//! Every number comes from a frame rendered with [`crate::frame::render_frame`] (or, for
//! the timed points, [`render_frame_on`](crate::frame::render_frame_on) with one core per
//! rank); nothing is estimated.
//!
//! - [`pof_construction`] (figure 1): build time and storage of each POF encoding.
//! - [`culling_vs_view`] (figure 4): visible and culled bricks while the view turns.
//! - [`rank_breakdown`] (figure 5): time per rank of one frame.
//! - [`speedup`] (figure 6): frame time, speedup and load balance against the rank count.
//! - [`tf_family`] (figure 8): culling as the family's weights change.
//! - [`audit`]: the threshold rule checked on random views.
//! - [`bench_cull`]: the culling bench (cases, view sweep, named measures and targets).
//! - [`bench_render`]: the ray caster's samples per second.

mod audit;
pub mod bench_cull;
pub mod bench_frame;
mod bench_render;
mod fig1_pof;
mod fig4_view;
mod fig5_ranks;
mod fig6_speedup;
mod fig8_tf_family;
mod method;
mod progress;
mod timing;

pub use audit::{audit, Audit, AuditMethod, AuditRow};
pub use bench_cull::{bench_cull, CullBench, CullCase};
pub use bench_frame::{
    bench_frame, FrameBench, FrameCase, FrameEngine, FrameVolume, FRAME_ENGINES,
};
pub use bench_render::{bench_render, RenderCase};
pub use fig1_pof::{pof_construction, PofBuild, PofBuildRow, PofSource};
pub use fig4_view::{culling_vs_view, MethodMean, ViewRow, ViewSweep};
pub use fig5_ranks::{rank_breakdown, RankBreakdown, RankFrame};
pub use fig6_speedup::{rank_counts, speedup, BestSpeedup, Speedup, SpeedupRow};
pub use fig8_tf_family::{tf_family, weight_grid, PaperImage, TfFamily, TfFamilyRow};
pub use method::{
    honour_budget, methods, range_bound, Method, NO_EXACT_UNDER_BUDGET, PAPER_WEIGHTS,
};
pub use progress::{NoProgress, Progress};
pub use timing::{culled_fraction, load_balance, median_frame, one_core_per_rank, timed_point};

use crate::frame::FrameError;
use crate::pof::PofError;
use crate::render::TfError;

/// Errors of an experiment.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExperimentError {
    /// A frame failed.
    #[error(transparent)]
    Frame(#[from] FrameError),
    /// POFs could not be built.
    #[error(transparent)]
    Pof(#[from] PofError),
    /// The family's weights could not be set.
    #[error(transparent)]
    Tf(#[from] TfError),
    /// The worker threads of a timed point could not be started.
    #[error("cannot start the worker threads of a timed point: {0}")]
    Threads(#[from] rayon::ThreadPoolBuildError),
    /// A cross-check of two ways of computing one thing failed.
    #[error("{0}")]
    Check(String),
    /// A frame of a [`crate::Scene`] failed.
    #[error(transparent)]
    Scene(#[from] crate::Error),
    /// A setting out of range (names the setting, the value and the range).
    #[error("{0}")]
    Setting(String),
}

/// The culling method of a figure that has one method besides no culling: the first of
/// `methods` named `pof-table` that can run, else `range-bound`.
///
/// # Errors
/// [`ExperimentError::Setting`] when neither is in `methods`.
pub fn primary<'m, 'a>(methods: &'m [Method<'a>]) -> Result<&'m Method<'a>, ExperimentError> {
    ["pof-table", "range-bound"]
        .iter()
        .find_map(|n| methods.iter().find(|m| m.name == *n && m.available()))
        .ok_or_else(|| {
            ExperimentError::Setting("no pof-table or range-bound culling method given".into())
        })
}

#[cfg(test)]
mod test;
