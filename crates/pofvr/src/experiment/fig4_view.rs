//! Figure 4: culling effectiveness while the view turns about the Y axis.

use serde::Serialize;

use crate::distribute::Curve;
use crate::frame::{render_frame, FrameOptions, RenderJob};
use crate::render::{Camera, Projection};

use super::{ExperimentError, Method, Progress};

/// One view and method of figure 4.
#[derive(Clone, Debug, Serialize)]
pub struct ViewRow {
    /// Azimuth about +y, degrees.
    pub azimuth_deg: f64,
    /// Elevation, degrees (0).
    pub elevation_deg: f64,
    /// Culling method.
    pub method: &'static str,
    /// Non-empty bricks.
    pub non_empty: usize,
    /// Bricks rendered.
    pub visible: usize,
    /// Bricks culled.
    pub culled: usize,
    /// Bricks rendered after verification found them culled wrongly (verified culling;
    /// 0 for the others). Counted in `visible`.
    pub repaired: usize,
    /// Frame time.
    pub frame_ms: f64,
    /// Samples taken.
    pub samples: u64,
}

/// A method's means over the views of figure 4.
#[derive(Clone, Debug, Serialize)]
pub struct MethodMean {
    /// Culling method.
    pub method: &'static str,
    /// Mean bricks rendered.
    pub mean_visible: f64,
    /// Mean share of the non-empty bricks culled.
    pub mean_culled_fraction_of_non_empty: f64,
    /// Mean bricks repaired (verified culling; 0 for the others).
    pub mean_repaired: f64,
}

/// Figure 4's rows, view by view, and each method's means.
#[derive(Clone, Debug, Serialize)]
pub struct ViewSweep {
    /// Azimuths measured, degrees.
    pub azimuths: Vec<f64>,
    /// One row per azimuth and method, azimuth-major.
    pub rows: Vec<ViewRow>,
    /// One per method, in the order given.
    pub means: Vec<MethodMean>,
}

/// Renders each of `methods` at 18 azimuths 20° apart (elevation 0, orthographic, one
/// rank) and counts the bricks culled.
///
/// # Errors
/// [`ExperimentError::Frame`] when a frame fails.
pub fn culling_vs_view(
    job: &RenderJob,
    methods: &[Method<'_>],
    threshold: f32,
    (width, height): (u32, u32),
    progress: &dyn Progress,
) -> Result<ViewSweep, ExperimentError> {
    let azimuths: Vec<f64> = (0..18).map(|i| f64::from(i) * 20.0).collect();
    progress.begin(
        "fig 4: culling vs view",
        (azimuths.len() * methods.len()) as u64,
    );
    let mut rows = Vec::new();
    let mut sums = vec![(0.0, 0.0, 0.0); methods.len()];
    for &az in &azimuths {
        let cam = Camera::orbit(
            &job.volume,
            az,
            0.0,
            width,
            height,
            Projection::Orthographic,
        );
        for (k, m) in methods.iter().enumerate() {
            let opts = FrameOptions {
                cull: m.mode,
                cull_threshold: threshold,
                ranks: 1,
                curve: Curve::Hilbert,
                ..FrameOptions::default()
            };
            let (_, st) = render_frame(job, m.bound, &cam, &opts)?;
            let b = st.bricks;
            sums[k].0 += b.culled as f64 / b.non_empty.max(1) as f64;
            sums[k].1 += b.visible as f64;
            sums[k].2 += b.repaired as f64;
            rows.push(ViewRow {
                azimuth_deg: az,
                elevation_deg: 0.0,
                method: m.name,
                non_empty: b.non_empty,
                visible: b.visible,
                culled: b.culled,
                repaired: b.repaired,
                frame_ms: st.frame_ms,
                samples: st.samples,
            });
            progress.inc();
        }
    }
    progress.end();
    let n = azimuths.len() as f64;
    let means = methods
        .iter()
        .zip(&sums)
        .map(|(m, (f, v, r))| MethodMean {
            method: m.name,
            mean_visible: v / n,
            mean_culled_fraction_of_non_empty: f / n,
            mean_repaired: r / n,
        })
        .collect();
    Ok(ViewSweep {
        azimuths,
        rows,
        means,
    })
}
