//! Figure 8: one set of bricks, the family's weights changed at run time.

use serde::Serialize;

use crate::distribute::Curve;
use crate::frame::{render_frame, FrameOptions, RenderJob};
use crate::render::{Camera, Image};

use super::{ExperimentError, Method, Progress, PAPER_WEIGHTS};

/// The weights of the first two bases that figure 8 measures: (k0 values, k1 values),
/// a smaller grid when `quick`.
#[must_use]
pub fn weight_grid(quick: bool) -> (Vec<f32>, Vec<f32>) {
    if quick {
        (vec![0.05, 0.25, 0.8], vec![0.5, 0.9, 1.0])
    } else {
        (vec![0.05, 0.25, 0.5, 0.8, 1.0], vec![0.25, 0.5, 0.9, 1.0])
    }
}

/// One weighting and method of figure 8.
#[derive(Clone, Debug, Serialize)]
pub struct TfFamilyRow {
    /// Weight of the first basis.
    pub k0: f32,
    /// Weight of the second basis (absent for a one-basis family).
    pub k1: Option<f32>,
    /// Culling method.
    pub method: &'static str,
    /// Non-empty bricks at these weights.
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
}

/// One of the paper's three weightings, rendered.
#[derive(Clone, Debug, Serialize)]
pub struct PaperImage {
    /// Weight of the first basis.
    pub k0: f32,
    /// Weight of the second basis (absent for a one-basis family).
    pub k1: Option<f32>,
    /// Culling method.
    pub method: &'static str,
    /// Bricks rendered.
    pub visible: usize,
    /// Bricks culled.
    pub culled: usize,
    /// Non-empty bricks.
    pub non_empty: usize,
    /// Bricks repaired (verified culling; 0 for the others).
    pub repaired: usize,
    /// The frame.
    #[serde(skip)]
    pub image: Image,
}

/// Figure 8's rows and images.
#[derive(Clone, Debug, Serialize)]
pub struct TfFamily {
    /// Bases of the family.
    pub bases: usize,
    /// Weighting-major, then no culling and each method in the order given.
    pub rows: Vec<TfFamilyRow>,
    /// The paper's weightings ([`PAPER_WEIGHTS`]), culled by the primary method.
    pub images: Vec<PaperImage>,
}

/// At each weighting of `k0s` × `k1s` (`k1s` unused with one basis; the other weights as
/// the job has them), renders without culling and with each of `methods`; then renders
/// [`PAPER_WEIGHTS`] culled by `primary`. The job's weights are restored at the end.
///
/// # Errors
/// [`ExperimentError`] when a frame fails or the weights cannot be set.
pub fn tf_family(
    job: &mut RenderJob,
    methods: &[Method<'_>],
    primary: &Method<'_>,
    camera: &Camera,
    threshold: f32,
    (k0s, k1s): (&[f32], &[f32]),
    progress: &dyn Progress,
) -> Result<TfFamily, ExperimentError> {
    let base = job.tf.weights.clone();
    let result = measure(
        job,
        methods,
        primary,
        camera,
        threshold,
        (k0s, k1s),
        progress,
    );
    job.tf.set_weights(base)?;
    result
}

fn measure(
    job: &mut RenderJob,
    methods: &[Method<'_>],
    primary: &Method<'_>,
    camera: &Camera,
    threshold: f32,
    (k0s, k1s): (&[f32], &[f32]),
    progress: &dyn Progress,
) -> Result<TfFamily, ExperimentError> {
    let bases = job.tf.bases.len();
    let base = job.tf.weights.clone();
    let k1s: Vec<Option<f32>> = if bases < 2 {
        vec![None]
    } else {
        k1s.iter().copied().map(Some).collect()
    };
    let weights = |k0: f32, k1: Option<f32>| {
        let mut w = base.clone();
        w[0] = k0;
        if let Some(k1) = k1 {
            w[1] = k1;
        }
        w
    };
    let opts = |m: &Method<'_>| FrameOptions {
        cull: m.mode,
        cull_threshold: threshold,
        ranks: 1,
        curve: Curve::Hilbert,
        ..FrameOptions::default()
    };
    progress.begin(
        "fig 8: transfer-function family",
        (k0s.len() * k1s.len() * (1 + methods.len()) + PAPER_WEIGHTS.len()) as u64,
    );
    let none = Method::none();
    let mut rows = Vec::new();
    for &k0 in k0s {
        for &k1 in &k1s {
            job.tf.set_weights(weights(k0, k1))?;
            for m in std::iter::once(&none).chain(methods) {
                let (_, st) = render_frame(job, m.bound, camera, &opts(m))?;
                rows.push(TfFamilyRow {
                    k0,
                    k1,
                    method: m.name,
                    non_empty: st.bricks.non_empty,
                    visible: st.bricks.visible,
                    culled: st.bricks.culled,
                    repaired: st.bricks.repaired,
                    frame_ms: st.frame_ms,
                });
                progress.inc();
            }
        }
    }
    let mut images = Vec::new();
    for (k0, k1) in PAPER_WEIGHTS {
        let k1 = (bases >= 2).then_some(k1);
        job.tf.set_weights(weights(k0, k1))?;
        let (image, st) = render_frame(job, primary.bound, camera, &opts(primary))?;
        images.push(PaperImage {
            k0,
            k1,
            method: primary.name,
            visible: st.bricks.visible,
            culled: st.bricks.culled,
            non_empty: st.bricks.non_empty,
            repaired: st.bricks.repaired,
            image,
        });
        progress.inc();
    }
    progress.end();
    Ok(TfFamily {
        bases,
        rows,
        images,
    })
}
