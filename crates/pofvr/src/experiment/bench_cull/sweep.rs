//! The culling bench's sweep: culled fractions and balance over views spread evenly over
//! the sphere, since one view can be lucky or unlucky.

use serde::Serialize;

use crate::check::check_threshold_rule;
use crate::cull::{CullMode, OpacityBound, Predictor};
use crate::experiment::{culled_fraction, load_balance, ExperimentError, Progress};
use crate::frame::{render_frame, render_reference, FrameOptions, RenderJob};
use crate::render::{Camera, Projection};

/// `n` views spread evenly over the sphere: equal steps of sin(elevation), azimuths turned
/// by the golden angle (a Fibonacci sphere), so that no axis or plane is favoured.
#[must_use]
pub fn sweep_views(n: usize) -> Vec<[f64; 2]> {
    const GOLDEN_ANGLE: f64 = 137.507_764_050_037_85;
    (0..n)
        .map(|k| {
            let z = (k as f64 + 0.5) / n as f64 * 2.0 - 1.0;
            [(k as f64 * GOLDEN_ANGLE) % 360.0, z.asin().to_degrees()]
        })
        .collect()
}

/// One view of the sweep.
#[derive(Clone, Debug, Serialize)]
pub struct SweepView {
    /// Azimuth, degrees.
    pub azimuth: f64,
    /// Elevation, degrees.
    pub elevation: f64,
    /// Share of the non-empty bricks culled by POFs (1 rank).
    pub culled_fraction_pof: f64,
    /// The same with POF sets.
    pub culled_fraction_pof_set: f64,
    /// The same by the oracle.
    pub culled_fraction_exact: f64,
    /// The same with the ideal bound, when given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub culled_fraction_ideal: Option<f64>,
    /// Max / mean samples rendered at 32 ranks, the paper's deal.
    pub balance_32: f64,
    /// The same with two owners per brick.
    pub balance_32_replicas_2: f64,
    /// Non-empty bricks (on screen or not).
    pub non_empty: usize,
    /// Bricks the oracle renders.
    pub rendered_exact: usize,
    /// Bricks verified culling renders (with [`Predictor::BEST`], 1 rank), the repaired
    /// ones included.
    pub rendered_verified: usize,
    /// Of those, the repaired.
    pub repaired_verified: usize,
    /// Pixels of the verified frame breaking the threshold rule against the whole-volume
    /// reference.
    pub rule_violations_verified: u64,
    /// Verification time of the verified frame (1 rank), milliseconds.
    pub verify_ms: f64,
    /// Repair time of the verified frame (1 rank), milliseconds.
    pub repair_ms: f64,
}

/// Mean and worst of a measure over the sweep's views.
#[derive(Clone, Debug, Serialize)]
pub struct Spread {
    /// Mean.
    pub mean: f64,
    /// Worst (largest).
    pub worst: f64,
    /// The view (azimuth, elevation) of the worst.
    pub worst_view: [f64; 2],
}

/// The sweep's measures over all its views.
#[derive(Clone, Debug, Serialize)]
pub struct SweepSummary {
    /// Percentage points culled below the oracle, POFs.
    pub points_below_exact_pof: Option<Spread>,
    /// The same, POF sets.
    pub points_below_exact_pof_set: Option<Spread>,
    /// The same, the ideal bound (when every view has it).
    pub points_below_exact_ideal: Option<Spread>,
    /// Balance at 32 ranks.
    pub balance_32: Option<Spread>,
    /// Balance at 32 ranks, two owners per brick.
    pub balance_32_replicas_2: Option<Spread>,
    /// Bricks verified culling renders beyond the oracle's, in percent of the non-empty
    /// bricks.
    pub points_rendered_over_exact_verified: Option<Spread>,
    /// Repaired bricks in percent of those verified culling renders.
    pub repaired_percent_verified: Option<Spread>,
    /// Threshold-rule violations of verified culling, pixels per view.
    pub rule_violations_verified: Option<Spread>,
}

impl SweepSummary {
    /// The spreads of `rows` (all `None` for no rows).
    #[must_use]
    pub fn of(rows: &[SweepView]) -> Self {
        let points = |f: &dyn Fn(&SweepView) -> f64| {
            spread(rows, |v| 100.0 * (v.culled_fraction_exact - f(v)))
        };
        let ideal = rows.iter().all(|v| v.culled_fraction_ideal.is_some());
        SweepSummary {
            points_below_exact_pof: points(&|v| v.culled_fraction_pof),
            points_below_exact_pof_set: points(&|v| v.culled_fraction_pof_set),
            points_below_exact_ideal: ideal
                .then(|| points(&|v| v.culled_fraction_ideal.unwrap_or(0.0)))
                .flatten(),
            balance_32: spread(rows, |v| v.balance_32),
            balance_32_replicas_2: spread(rows, |v| v.balance_32_replicas_2),
            points_rendered_over_exact_verified: spread(rows, |v| {
                100.0 * (v.rendered_verified as f64 - v.rendered_exact as f64)
                    / v.non_empty.max(1) as f64
            }),
            repaired_percent_verified: spread(rows, |v| {
                100.0 * v.repaired_verified as f64 / v.rendered_verified.max(1) as f64
            }),
            rule_violations_verified: spread(rows, |v| v.rule_violations_verified as f64),
        }
    }
}

/// Mean and worst (largest) of `f` over the sweep.
fn spread(rows: &[SweepView], f: impl Fn(&SweepView) -> f64) -> Option<Spread> {
    let worst = rows.iter().max_by(|a, b| f(a).total_cmp(&f(b)))?;
    Some(Spread {
        mean: rows.iter().map(&f).sum::<f64>() / rows.len() as f64,
        worst: f(worst),
        worst_view: [worst.azimuth, worst.elevation],
    })
}

/// The culled fractions (1 rank) and the 32-rank balance at each of `views`, with `bounds`
/// for the POF modes and `ideal` beside them when given. No timings: these are
/// deterministic.
///
/// # Errors
/// [`ExperimentError::Frame`] when a frame fails.
pub fn sweep(
    job: &RenderJob,
    bounds: &dyn OpacityBound,
    ideal: Option<&dyn OpacityBound>,
    views: &[[f64; 2]],
    size: (u32, u32),
    progress: &dyn Progress,
) -> Result<Vec<SweepView>, ExperimentError> {
    sweep_with(job, bounds, ideal, views, size, Predictor::BEST, progress)
}

/// [`sweep`] with `predictor` for the verified frames (`bench cull --predictor`): e.g.
/// [`Predictor::Pof`] to measure typical-value POFs as predictors against the oracle.
///
/// # Errors
/// [`ExperimentError::Frame`] when a frame fails.
pub fn sweep_with(
    job: &RenderJob,
    bounds: &dyn OpacityBound,
    ideal: Option<&dyn OpacityBound>,
    views: &[[f64; 2]],
    (w, h): (u32, u32),
    predictor: Predictor,
    progress: &dyn Progress,
) -> Result<Vec<SweepView>, ExperimentError> {
    progress.begin("view sweep", views.len() as u64);
    let mut out = Vec::with_capacity(views.len());
    for &[az, el] in views {
        let cam = Camera::orbit(&job.volume, az, el, w, h, Projection::Orthographic);
        let run_with = |bound: &dyn OpacityBound, cull, ranks, replicas| {
            let opts = FrameOptions {
                cull,
                ranks,
                replicas,
                ..FrameOptions::default()
            };
            render_frame(job, Some(bound), &cam, &opts).map(|(_, st)| st)
        };
        let run = |cull, ranks, replicas| run_with(bounds, cull, ranks, replicas);
        let exact = run(CullMode::Exact, 1, 1)?;
        let (image, verified) = render_frame(
            job,
            Some(bounds),
            &cam,
            &FrameOptions {
                cull: CullMode::Verified,
                predictor,
                ..FrameOptions::default()
            },
        )?;
        let (reference, _) = render_reference(job, &cam);
        let rule = check_threshold_rule(&reference, &image, FrameOptions::default().cull_threshold);
        out.push(SweepView {
            azimuth: az,
            elevation: el,
            culled_fraction_pof: culled_fraction(&run(CullMode::Pof, 1, 1)?),
            culled_fraction_pof_set: culled_fraction(&run(CullMode::PofSet, 1, 1)?),
            culled_fraction_exact: culled_fraction(&exact),
            culled_fraction_ideal: match ideal {
                Some(i) => Some(culled_fraction(&run_with(i, CullMode::Pof, 1, 1)?)),
                None => None,
            },
            balance_32: load_balance(&run(CullMode::Pof, 32, 1)?),
            balance_32_replicas_2: load_balance(&run(CullMode::Pof, 32, 2)?),
            non_empty: verified.bricks.non_empty,
            rendered_exact: exact.bricks.visible,
            rendered_verified: verified.bricks.visible,
            repaired_verified: verified.bricks.repaired,
            rule_violations_verified: rule.violations,
            verify_ms: verified
                .ranks
                .iter()
                .map(|r| r.verify_ms)
                .fold(0.0, f64::max),
            repair_ms: verified
                .ranks
                .iter()
                .map(|r| r.repair_ms)
                .fold(0.0, f64::max),
        });
        progress.inc();
    }
    progress.end();
    Ok(out)
}

#[cfg(test)]
mod test {
    use super::sweep_views;

    #[test]
    fn sweep_views_cover_the_sphere_in_equal_area_bands() {
        let n = 24;
        let v = sweep_views(n);
        assert_eq!(v.len(), n);
        for (k, [az, el]) in v.iter().enumerate() {
            assert!((0.0..360.0).contains(az), "{az}");
            assert!(el.abs() < 90.0, "{el}");
            // Equal steps of sin(elevation): each view stands for the same share of the
            // sphere's area.
            let want = (k as f64 + 0.5) / n as f64 * 2.0 - 1.0;
            assert!((el.to_radians().sin() - want).abs() < 1e-12, "{k}: {el}");
        }
        // Neighbours in elevation are far apart in azimuth, so no meridian is favoured.
        for w in v.windows(2) {
            let d = (w[1][0] - w[0][0]).rem_euclid(360.0);
            assert!(d > 90.0 && d < 270.0, "{w:?}");
        }
    }
}
