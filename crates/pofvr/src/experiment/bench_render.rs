//! The ray caster's bench: samples per second per core, with and without early
//! termination, axis-aligned and oblique, and the SIMD loop against the one-sample loop.

use std::time::Instant;

use serde::Serialize;

use crate::frame::RenderJob;
use crate::render::{Camera, CellRanges, Occupancy, Projection, RayCaster, RenderSettings};

use super::{ExperimentError, Progress};

/// One case of the render bench.
#[derive(Clone, Debug, Serialize)]
pub struct RenderCase {
    /// The volume's name as given.
    pub volume: String,
    /// `axis-aligned` or `oblique`.
    pub view: &'static str,
    /// Whether rays stop at the early-termination threshold.
    pub early_termination: bool,
    /// Median frame time.
    pub median_ms: f64,
    /// Samples of the frame.
    pub samples: u64,
    /// Samples per second per worker thread.
    pub samples_per_second_per_core: f64,
    /// The sample loop measured: "avx2" (eight samples at a time) or "sse2".
    pub simd: &'static str,
    /// The same frame with the one-sample SSE2 loop (reps interleaved with the above), when
    /// the loop measured is another.
    pub one_sample_loop_ms: Option<f64>,
    /// `one_sample_loop_ms / median_ms`.
    pub speedup_over_one_sample_loop: Option<f64>,
    /// The same frame by the march engine (reps interleaved), occupancy rebuild included:
    /// median time, samples taken and lattice samples skipped as empty.
    pub march_ms: f64,
    /// Samples the march engine took.
    pub march_samples: u64,
    /// Samples the march engine skipped in empty space.
    pub march_skipped_samples: u64,
}

/// The views of the bench: (name, azimuth, elevation).
const VIEWS: [(&str, f64, f64); 2] = [("axis-aligned", 0.0, 0.0), ("oblique", 33.0, 27.0)];

/// Renders each named job at each view with early termination on and off, `reps` times
/// (at least once; the median is reported), whole volume, no bricks.
///
/// # Errors
/// [`ExperimentError::Check`] when the SIMD and one-sample loops count different samples.
pub fn bench_render(
    jobs: &[(String, RenderJob)],
    (w, h): (u32, u32),
    reps: usize,
    progress: &dyn Progress,
) -> Result<Vec<RenderCase>, ExperimentError> {
    progress.begin("bench render", (jobs.len() * VIEWS.len() * 2 * reps) as u64);
    let threads = rayon::current_num_threads();
    let mut cases = Vec::new();
    for (name, job) in jobs {
        let cells = CellRanges::new(&job.volume);
        for (view, az, el) in VIEWS {
            for ert in [true, false] {
                let settings = RenderSettings {
                    ert: if ert { 0.99 } else { 2.0 },
                    ..job.settings
                };
                let cls = job.sampled.classify(&job.tf.weights, settings.step);
                let cam = Camera::orbit(&job.volume, az, el, w, h, Projection::Orthographic);
                let caster = RayCaster::new(&job.volume, &cls, settings);
                let one = RayCaster::new(&job.volume, &cls, settings).with_avx2(false);
                let compare = caster.simd() != one.simd();
                let (mut times, mut one_times, mut march_times) =
                    (Vec::new(), Vec::new(), Vec::new());
                let mut samples = 0;
                let mut march = crate::render::MarchStats::default();
                for _ in 0..reps.max(1) {
                    let t = Instant::now();
                    let (_, st) = caster.render(&cam);
                    times.push(t.elapsed().as_secs_f64());
                    samples = st.samples;
                    if compare {
                        // Interleaved, so that both loops see the same machine.
                        let t = Instant::now();
                        let (_, st1) = one.render(&cam);
                        one_times.push(t.elapsed().as_secs_f64());
                        if st1 != st {
                            return Err(ExperimentError::Check(format!(
                                "the sample loops disagree on {name}"
                            )));
                        }
                    }
                    let t = Instant::now();
                    let occ = Occupancy::new(&cells, &cls);
                    (_, march) = caster.render_march(&cam, &occ);
                    march_times.push(t.elapsed().as_secs_f64());
                    progress.inc();
                }
                let med = median(times).unwrap_or(f64::NAN);
                let one_med = median(one_times);
                cases.push(RenderCase {
                    volume: name.clone(),
                    view,
                    early_termination: ert,
                    median_ms: med * 1e3,
                    samples,
                    samples_per_second_per_core: samples as f64 / med / threads as f64,
                    simd: caster.simd(),
                    one_sample_loop_ms: one_med.map(|m| m * 1e3),
                    speedup_over_one_sample_loop: one_med.map(|m| m / med),
                    march_ms: median(march_times).unwrap_or(f64::NAN) * 1e3,
                    march_samples: march.rays.samples,
                    march_skipped_samples: march.skipped_samples,
                });
            }
        }
    }
    progress.end();
    Ok(cases)
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}
