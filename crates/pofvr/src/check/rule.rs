//! The threshold rule: what culling may change in a frame.
//!
//! A brick is culled only where the pixels of its footprint have reached the cull threshold
//! `t` in front of it. So, against the frame rendered without culling:
//!
//! - a pixel whose unculled opacity is below `t` is the same in the culled frame (nothing
//!   behind it was culled: culling never reaches it);
//! - no pixel differs by more than `1 − t` in any channel (what a culled brick could have
//!   added behind a pixel of opacity ≥ `t` is at most its remaining transmittance).
//!
//! This is the one place the rule is written; tests, `pof check` and the experiments call it.

use std::fmt;

use crate::render::Image;

/// Channel difference below which two pixels count as the same. Culled and unculled frames
/// blend the same fragments in the same order, so they agree bit for bit in practice; the
/// tolerance only absorbs a different order of operations in an engine (see the engines'
/// reference tests).
pub const IDENTICAL: f32 = 1e-6;

/// What [`check_threshold_rule`] found in one culled frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RuleReport {
    /// The threshold the frame was culled at.
    pub threshold: f32,
    /// Pixels compared.
    pub pixels: u64,
    /// Pixels whose unculled opacity is below the threshold.
    pub pixels_below: u64,
    /// Of those, pixels that differ (by more than [`IDENTICAL`]).
    pub below_changed: u64,
    /// Pixels that differ by more than `1 − threshold` (plus [`IDENTICAL`]).
    pub over_bound: u64,
    /// Pixels breaking either part of the rule (each counted once).
    pub violations: u64,
    /// The largest channel difference anywhere (infinite for a NaN or a size mismatch).
    pub max_diff: f32,
    /// The first pixel (row-major index) that breaks the rule.
    pub first_violation: Option<u64>,
}

impl RuleReport {
    /// True when the culled frame obeys the rule.
    #[must_use]
    pub fn holds(&self) -> bool {
        self.violations == 0
    }
}

impl fmt::Display for RuleReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "threshold rule at {}: {} of {} pixels break it ({} below the threshold changed, \
             {} off by more than {}), largest difference {}",
            self.threshold,
            self.violations,
            self.pixels,
            self.below_changed,
            self.over_bound,
            1.0 - self.threshold,
            self.max_diff
        )?;
        if let Some(i) = self.first_violation {
            write!(f, ", first at pixel {i}")?;
        }
        Ok(())
    }
}

/// The largest channel difference of two pixels; infinite where either holds a NaN.
fn difference(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let d = (0..4).map(|k| (a[k] - b[k]).abs()).fold(0.0, f32::max);
    if d.is_nan() || a.iter().chain(b).any(|v| v.is_nan()) {
        f32::INFINITY
    } else {
        d
    }
}

/// Compares `culled` with `unculled`, the same frame rendered without culling, at the
/// cull threshold `threshold`. Frames of different sizes break the rule at every pixel.
#[must_use]
pub fn check_threshold_rule(unculled: &Image, culled: &Image, threshold: f32) -> RuleReport {
    let mut r = RuleReport {
        threshold,
        pixels: unculled.pixels().len() as u64,
        ..RuleReport::default()
    };
    if unculled.width() != culled.width() || unculled.height() != culled.height() {
        r.violations = r.pixels.max(1);
        r.over_bound = r.violations;
        r.max_diff = f32::INFINITY;
        r.first_violation = Some(0);
        return r;
    }
    let bound = 1.0 - threshold + IDENTICAL;
    for (i, (u, c)) in unculled.pixels().iter().zip(culled.pixels()).enumerate() {
        let d = difference(u, c);
        let below = u[3] < threshold;
        let changed = below && d > IDENTICAL;
        let over = d > bound;
        r.pixels_below += u64::from(below);
        r.below_changed += u64::from(changed);
        r.over_bound += u64::from(over);
        if changed || over {
            r.violations += 1;
            r.first_violation.get_or_insert(i as u64);
        }
        r.max_diff = r.max_diff.max(d);
    }
    r
}

#[cfg(test)]
mod test {
    use super::*;

    fn image(pixels: Vec<[f32; 4]>) -> Image {
        let w = u32::try_from(pixels.len()).unwrap();
        Image::from_pixels(w, 1, pixels).unwrap()
    }

    #[test]
    fn identical_frames_obey_the_rule() {
        let a = image(vec![[0.1, 0.2, 0.3, 0.5], [0.9, 0.9, 0.9, 0.97]]);
        let r = check_threshold_rule(&a, &a, 0.95);
        assert!(r.holds(), "{r}");
        assert_eq!((r.pixels, r.pixels_below, r.max_diff), (2, 1, 0.0));
    }

    #[test]
    fn a_change_below_the_threshold_breaks_it() {
        let a = image(vec![[0.0; 4], [0.1, 0.1, 0.1, 0.5]]);
        let b = image(vec![[0.0; 4], [0.1, 0.1, 0.1, 0.5 + 1e-4]]);
        let r = check_threshold_rule(&a, &b, 0.95);
        assert!(!r.holds());
        assert_eq!(
            (r.below_changed, r.over_bound, r.first_violation),
            (1, 0, Some(1))
        );
        assert!(r.to_string().contains("1 of 2 pixels"), "{r}");
    }

    #[test]
    fn above_the_threshold_a_pixel_may_move_by_one_minus_threshold_and_no_more() {
        let u = image(vec![[0.5, 0.5, 0.5, 0.96]]);
        let within = image(vec![[0.5, 0.5, 0.5, 0.96 - 0.049]]);
        assert!(check_threshold_rule(&u, &within, 0.95).holds());
        let beyond = image(vec![[0.5, 0.5, 0.5 - 0.06, 0.96]]);
        let r = check_threshold_rule(&u, &beyond, 0.95);
        assert_eq!((r.violations, r.over_bound, r.below_changed), (1, 1, 0));
    }

    #[test]
    fn nan_and_size_mismatch_break_it() {
        let a = image(vec![[0.0; 4]]);
        let nan = image(vec![[f32::NAN, 0.0, 0.0, 0.0]]);
        let r = check_threshold_rule(&a, &nan, 0.95);
        assert!(!r.holds() && r.max_diff.is_infinite());
        let two = image(vec![[0.0; 4]; 2]);
        assert!(!check_threshold_rule(&a, &two, 0.95).holds());
    }
}
