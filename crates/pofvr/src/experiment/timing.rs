//! Timed frames: the median of repetitions, and frames with one core per rank.

use crate::comm::{Communicator, LocalCommunicator};
use crate::frame::{render_frame_on, FrameError, FrameOptions, FrameStats, RenderJob};
use crate::render::{Camera, Image};

use super::{ExperimentError, Method};

/// The frame of median time out of `reps` (at least one) renders by `render`.
///
/// # Errors
/// The first error of `render`.
pub fn median_frame<E>(
    reps: usize,
    mut render: impl FnMut() -> Result<(Image, FrameStats), E>,
) -> Result<(Image, FrameStats), E> {
    let mut runs = Vec::new();
    for _ in 0..reps.max(1) {
        runs.push(render()?);
    }
    runs.sort_by(|a, b| a.1.frame_ms.total_cmp(&b.1.frame_ms));
    let mid = runs.len() / 2;
    Ok(runs.swap_remove(mid))
}

/// One frame of `opts.ranks` in-process ranks, each rank's work (its culling, the
/// parallel loops over its bricks and rays) on a worker thread of its own, as the paper
/// gives each rank one processor: the frame time then measures the ranks, not how one
/// shared pool of threads spreads their work.
///
/// # Errors
/// [`ExperimentError::Threads`] when a rank's thread cannot start; [`FrameError`] from the
/// frame, rank 0's first (it holds the frame), another's when rank 0 only saw the abort.
pub fn one_core_per_rank(
    job: &RenderJob,
    m: &Method<'_>,
    camera: &Camera,
    opts: &FrameOptions,
) -> Result<(Image, FrameStats), ExperimentError> {
    let ranks = opts.ranks.max(1);
    let pools = (0..ranks)
        .map(|_| rayon::ThreadPoolBuilder::new().num_threads(1).build())
        .collect::<Result<Vec<_>, _>>()?;
    let opts = FrameOptions {
        cull: m.mode,
        ..opts.clone()
    };
    let mut results = LocalCommunicator::run(ranks, |comm| {
        let rank = comm.rank().0 as usize;
        pools[rank].install(|| render_frame_on(comm, job, m.bound, camera, &opts))
    });
    let first = results.remove(0);
    let frame = match first {
        Ok(Some(frame)) => frame,
        Ok(None) => return Err(FrameError::Gather("rank 0 returned no frame".into()).into()),
        Err(e) => {
            return Err(results
                .into_iter()
                .find_map(|r| r.err().filter(|e| !e.is_abort()))
                .unwrap_or(e)
                .into())
        }
    };
    let (image, mut st) = frame;
    st.threads = ranks;
    Ok((image, st))
}

/// The median of `reps` frames of [`one_core_per_rank`]: a timed point of figures 5 and 6.
///
/// # Errors
/// As [`one_core_per_rank`].
pub fn timed_point(
    job: &RenderJob,
    m: &Method<'_>,
    camera: &Camera,
    opts: &FrameOptions,
    reps: usize,
) -> Result<FrameStats, ExperimentError> {
    median_frame(reps, || one_core_per_rank(job, m, camera, opts)).map(|(_, st)| st)
}

/// Max over mean samples rendered per rank (1 for a balanced frame, or one with none).
#[must_use]
pub fn load_balance(st: &FrameStats) -> f64 {
    let n = st.ranks.len().max(1) as f64;
    let mean = st.ranks.iter().map(|r| r.samples as f64).sum::<f64>() / n;
    let max = st.ranks.iter().map(|r| r.samples).max().unwrap_or(0) as f64;
    if mean > 0.0 {
        max / mean
    } else {
        1.0
    }
}

/// Share of the frame's non-empty bricks that were culled.
#[must_use]
pub fn culled_fraction(st: &FrameStats) -> f64 {
    st.bricks.culled as f64 / st.bricks.non_empty.max(1) as f64
}
