//! The conservativeness audit: culled frames of random views checked against the
//! unculled frame by the threshold rule ([`check_threshold_rule`]).

use serde::Serialize;

use crate::check::check_threshold_rule;
use crate::distribute::Curve;
use crate::frame::{render_frame, FrameOptions, RenderJob};
use crate::render::{Camera, Projection};

use super::{ExperimentError, Method, Progress};

/// Ranks of the audit's frames: more than one, so the rule is checked across ranks.
const AUDIT_RANKS: usize = 2;

/// A deterministic generator for the audit's views (SplitMix64).
pub(crate) struct SplitMix(pub(crate) u64);

impl SplitMix {
    /// The next number in `[0, 1)`.
    pub(crate) fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// One view and method of the audit.
#[derive(Clone, Debug, Serialize)]
pub struct AuditRow {
    /// View number.
    pub view: usize,
    /// Azimuth about +y, degrees.
    pub azimuth_deg: f64,
    /// Elevation, degrees.
    pub elevation_deg: f64,
    /// `orthographic` or `perspective`.
    pub projection: &'static str,
    /// Culling method.
    pub method: &'static str,
    /// Whether the method is guaranteed to follow the rule.
    pub conservative: bool,
    /// Bricks culled.
    pub culled: usize,
    /// Pixels below the threshold unculled that changed.
    pub pixels_below_threshold_changed: u64,
    /// Pixels that differ by more than 1 − threshold.
    pub pixels_over_max_diff: u64,
    /// Pixels breaking the rule.
    pub violations: u64,
    /// Largest difference of any channel.
    pub max_abs_diff: f64,
}

/// A method's totals over the audit's views.
#[derive(Clone, Debug, Serialize)]
pub struct AuditMethod {
    /// Culling method.
    pub method: &'static str,
    /// Whether it is guaranteed to follow the rule.
    pub conservative: bool,
    /// Pixels breaking the rule over all views.
    pub violations: u64,
    /// Bricks culled over all views.
    pub bricks_culled_over_all_views: u64,
    /// Largest difference over all views.
    pub max_abs_diff: f32,
}

/// The audit's rows and totals.
#[derive(Clone, Debug, Serialize)]
pub struct Audit {
    /// Views audited.
    pub views: usize,
    /// Pixels of each frame.
    pub pixels_per_view: u64,
    /// The culling threshold.
    pub threshold: f32,
    /// Pixels breaking the rule, summed over the conservative methods.
    pub conservative_violations: u64,
    /// One row per view and method, view-major.
    #[serde(skip)]
    pub rows: Vec<AuditRow>,
    /// One per method, in the order given.
    pub methods: Vec<AuditMethod>,
}

impl Audit {
    /// True when no conservative method broke the rule.
    #[must_use]
    pub fn passed(&self) -> bool {
        self.conservative_violations == 0
    }
}

/// Renders `views` random views (uniform over the sphere from `seed`, every third one in
/// perspective: the rule holds for any camera) unculled and culled by each of `methods`,
/// on two ranks, and checks each culled frame against the unculled one.
///
/// # Errors
/// [`ExperimentError::Frame`] when a frame fails.
pub fn audit(
    job: &RenderJob,
    methods: &[Method<'_>],
    threshold: f32,
    views: usize,
    seed: u64,
    (width, height): (u32, u32),
    progress: &dyn Progress,
) -> Result<Audit, ExperimentError> {
    progress.begin(
        "audit: culled vs unculled",
        (views * (1 + methods.len())) as u64,
    );
    let opts = |m: &Method<'_>| FrameOptions {
        cull: m.mode,
        cull_threshold: threshold,
        ranks: AUDIT_RANKS,
        curve: Curve::Hilbert,
        ..FrameOptions::default()
    };
    let mut rng = SplitMix(seed);
    let mut rows = Vec::new();
    let mut totals: Vec<AuditMethod> = methods
        .iter()
        .map(|m| AuditMethod {
            method: m.name,
            conservative: m.conservative,
            violations: 0,
            bricks_culled_over_all_views: 0,
            max_abs_diff: 0.0,
        })
        .collect();
    for v in 0..views {
        let az = rng.next_f64() * 360.0;
        let el = (2.0 * rng.next_f64() - 1.0)
            .clamp(-1.0, 1.0)
            .asin()
            .to_degrees();
        let projection = if v % 3 == 2 {
            Projection::Perspective
        } else {
            Projection::Orthographic
        };
        let cam = Camera::orbit(&job.volume, az, el, width, height, projection);
        let (unculled, _) = render_frame(job, None, &cam, &opts(&Method::none()))?;
        progress.inc();
        for (m, t) in methods.iter().zip(&mut totals) {
            let (img, st) = render_frame(job, m.bound, &cam, &opts(m))?;
            let c = check_threshold_rule(&unculled, &img, threshold);
            rows.push(AuditRow {
                view: v,
                azimuth_deg: az,
                elevation_deg: el,
                projection: if projection == Projection::Perspective {
                    "perspective"
                } else {
                    "orthographic"
                },
                method: m.name,
                conservative: m.conservative,
                culled: st.bricks.culled,
                pixels_below_threshold_changed: c.below_changed,
                pixels_over_max_diff: c.over_bound,
                violations: c.violations,
                max_abs_diff: f64::from(c.max_diff),
            });
            t.violations += c.violations;
            t.bricks_culled_over_all_views += st.bricks.culled as u64;
            t.max_abs_diff = t.max_abs_diff.max(c.max_diff);
            progress.inc();
        }
    }
    progress.end();
    let conservative_violations = totals
        .iter()
        .filter(|t| t.conservative)
        .map(|t| t.violations)
        .sum();
    Ok(Audit {
        views,
        pixels_per_view: u64::from(width) * u64::from(height),
        threshold,
        conservative_violations,
        rows,
        methods: totals,
    })
}
