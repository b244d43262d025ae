//! Transfer-function families (paper §3.2.1): opacity bases summed with weights.
//!
//! Each basis's `opacity` is the alpha of one *unit step*, the unit being the volume's
//! smallest spacing component. Internally bases are extinctions τᵢ = −ln(1 − αᵢ), summed as
//! τ' = Σ kᵢ τᵢ, and a step of Δ units gets α = 1 − exp(−τ' Δ), which makes the paper's
//! Eq. 3 exact for the renderer's own samples.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::brick::ValueRange;

/// Number of lookup-table bins over the volume's value range.
pub const TF_BINS: usize = 4096;

pub(crate) const BIN_MAX: f32 = (TF_BINS - 1) as f32;

/// Alpha of a unit step is capped here so that τ stays finite.
const ALPHA_CAP: f32 = 1.0 - 1e-6;

/// One basis opacity function.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Basis {
    /// Display name, e.g. "skin".
    pub name: String,
    /// `[value, alpha-per-unit-step]` points, sorted by value; clamped outside.
    pub opacity: Vec<[f32; 2]>,
}

/// A family of transfer functions: bases, their current weights and one colour map.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransferFunction {
    /// The basis opacity functions.
    pub bases: Vec<Basis>,
    /// One weight kᵢ ≥ 0 per basis; 1.0 each when absent from the file.
    #[serde(default)]
    pub weights: Vec<f32>,
    /// `[value, r, g, b]` points, sorted by value, components in [0, 1].
    pub color: Vec<[f32; 4]>,
}

/// The source that [`TfError::Field`] names for weights given apart from the family's file
/// ([`TransferFunction::set_weights`]); front ends match it to say where they came from.
pub const GIVEN_WEIGHTS: &str = "the weights given";

/// A transfer-function file or value is invalid.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TfError {
    /// The file could not be read.
    #[error("{file}: {err}")]
    Io {
        /// The file.
        file: String,
        /// The error.
        #[source]
        err: std::io::Error,
    },
    /// Not valid JSON or not the expected shape.
    #[error("{file}: {err}")]
    Json {
        /// The file.
        file: String,
        /// The parse error with line and column.
        #[source]
        err: serde_json::Error,
    },
    /// A field has an invalid value.
    #[error("{file}: {field}: {why}")]
    Field {
        /// The file (or "--weights").
        file: String,
        /// The JSON path of the field, e.g. `bases[1].opacity[3]`.
        field: String,
        /// What is wrong.
        why: String,
    },
}

impl TransferFunction {
    /// Reads and validates a family file.
    ///
    /// # Errors
    /// [`TfError`] naming the file and the offending field.
    pub fn from_file(path: &Path) -> Result<Self, TfError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|err| TfError::Io {
            file: file.clone(),
            err,
        })?;
        Self::from_json(&text, &file)
    }

    /// Parses and validates JSON text; `file` names it in errors.
    ///
    /// # Errors
    /// [`TfError`] naming `file` and the offending field.
    pub fn from_json(text: &str, file: &str) -> Result<Self, TfError> {
        let mut tf: TransferFunction = serde_json::from_str(text).map_err(|err| TfError::Json {
            file: file.to_string(),
            err,
        })?;
        if tf.weights.is_empty() {
            tf.weights = vec![1.0; tf.bases.len()];
        }
        tf.validate(file)?;
        Ok(tf)
    }

    /// Checks every field; `file` names the source in errors.
    ///
    /// # Errors
    /// [`TfError::Field`] for no bases, unsorted points, alpha or colour outside [0, 1],
    /// non-finite numbers, negative weights or a weight count that does not match.
    pub fn validate(&self, file: &str) -> Result<(), TfError> {
        let err = |field: String, why: String| TfError::Field {
            file: file.to_string(),
            field,
            why,
        };
        if self.bases.is_empty() {
            return Err(err(
                "bases".into(),
                "no bases: at least one basis is needed".into(),
            ));
        }
        for (i, b) in self.bases.iter().enumerate() {
            if b.opacity.is_empty() {
                return Err(err(format!("bases[{i}].opacity"), "no points".into()));
            }
            for (j, [v, a]) in b.opacity.iter().enumerate() {
                let f = format!("bases[{i}].opacity[{j}]");
                if !v.is_finite() || !a.is_finite() {
                    return Err(err(f, "not a finite number".into()));
                }
                if !(0.0..=1.0).contains(a) {
                    return Err(err(f, format!("alpha {a} is outside [0, 1]")));
                }
                if j > 0 && *v < b.opacity[j - 1][0] {
                    return Err(err(
                        f,
                        format!("values not sorted: {v} after {}", b.opacity[j - 1][0]),
                    ));
                }
            }
        }
        self.validate_weights(&self.weights, file)?;
        if self.color.is_empty() {
            return Err(err("color".into(), "no points".into()));
        }
        for (j, p) in self.color.iter().enumerate() {
            let f = format!("color[{j}]");
            if p.iter().any(|x| !x.is_finite()) {
                return Err(err(f, "not a finite number".into()));
            }
            if p[1..].iter().any(|c| !(0.0..=1.0).contains(c)) {
                return Err(err(f, "colour components must be in [0, 1]".into()));
            }
            if j > 0 && p[0] < self.color[j - 1][0] {
                return Err(err(
                    f,
                    format!("values not sorted: {} after {}", p[0], self.color[j - 1][0]),
                ));
            }
        }
        Ok(())
    }

    /// Checks a weight vector against this family.
    ///
    /// # Errors
    /// [`TfError::Field`] when the count differs from the bases or a weight is negative or
    /// not finite.
    pub fn validate_weights(&self, weights: &[f32], file: &str) -> Result<(), TfError> {
        let err = |field: String, why: String| TfError::Field {
            file: file.to_string(),
            field,
            why,
        };
        if weights.len() != self.bases.len() {
            return Err(err(
                "weights".into(),
                format!(
                    "got {} weights, expected one per basis ({})",
                    weights.len(),
                    self.bases.len()
                ),
            ));
        }
        for (i, k) in weights.iter().enumerate() {
            if !k.is_finite() || *k < 0.0 {
                return Err(err(
                    format!("weights[{i}]"),
                    format!("weight {k} must be finite and ≥ 0"),
                ));
            }
        }
        Ok(())
    }

    /// Replaces the weights after validating them.
    ///
    /// # Errors
    /// As [`TransferFunction::validate_weights`], naming [`GIVEN_WEIGHTS`] as the source.
    pub fn set_weights(&mut self, weights: Vec<f32>) -> Result<(), TfError> {
        self.validate_weights(&weights, GIVEN_WEIGHTS)?;
        self.weights = weights;
        Ok(())
    }

    /// A stable hash of the bases only (names and points): weights and colour are free at
    /// run time and do not invalidate precomputed opacity.
    #[must_use]
    pub fn bases_fingerprint(&self) -> u64 {
        let mut h = Fnv::default();
        for b in &self.bases {
            h.write(b.name.as_bytes());
            h.write(&[0xff]);
            for [v, a] in &b.opacity {
                h.write(&v.to_le_bytes());
                h.write(&a.to_le_bytes());
            }
            h.write(&[0xfe]);
        }
        h.0
    }
}

/// FNV-1a, 64-bit: stable across platforms and versions, unlike `DefaultHasher`.
pub(crate) struct Fnv(pub(crate) u64);
impl Default for Fnv {
    fn default() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
}
impl Fnv {
    pub(crate) fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 ^= u64::from(*b);
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
    }
}

fn piecewise(points: &[[f32; 2]], v: f32) -> f32 {
    let first = points[0];
    let last = points[points.len() - 1];
    if v <= first[0] {
        return first[1];
    }
    if v >= last[0] {
        return last[1];
    }
    let i = points.partition_point(|p| p[0] <= v);
    let (a, b) = (points[i - 1], points[i]);
    if b[0] <= a[0] {
        return b[1];
    }
    a[1] + (b[1] - a[1]) * (v - a[0]) / (b[0] - a[0])
}

fn piecewise_rgb(points: &[[f32; 4]], v: f32) -> [f32; 3] {
    std::array::from_fn(|c| {
        let ch: Vec<[f32; 2]> = points.iter().map(|p| [p[0], p[c + 1]]).collect();
        piecewise(&ch, v)
    })
}

/// The family tabulated over a volume's value range: per-basis extinction per unit length
/// and colour, at [`TF_BINS`] bin centres. This table *is* the transfer function the
/// renderer applies; emptiness and opacity bounds are decided on the same bins.
#[derive(Clone, Debug)]
pub struct SampledTf {
    lo: f32,
    scale: f32,
    tau: Vec<Vec<f32>>,
    /// Per basis, the number of non-zero bins below each bin (TF_BINS + 1 entries): a
    /// brick's emptiness is then two lookups per basis rather than a scan of its bins, for
    /// every brick of every frame.
    nonzero_below: Vec<Vec<u32>>,
    color: Vec<[f32; 3]>,
    names: Vec<String>,
}

/// [`SampledTf::nonzero_below`] of each table.
fn nonzero_below(tau: &[Vec<f32>]) -> Vec<Vec<u32>> {
    tau.iter()
        .map(|t| {
            std::iter::once(0)
                .chain(t.iter().scan(0u32, |n, x| {
                    *n += u32::from(*x != 0.0);
                    Some(*n)
                }))
                .collect()
        })
        .collect()
}

impl SampledTf {
    /// Tabulates `tf` over `domain` (the volume's value range).
    #[must_use]
    pub fn new(tf: &TransferFunction, domain: ValueRange) -> Self {
        let lo = domain.min;
        let width = (domain.max - domain.min).max(f32::MIN_POSITIVE * 1e6);
        let scale = TF_BINS as f32 / width;
        let centre = |b: usize| lo + (b as f32 + 0.5) / scale;
        let tau: Vec<Vec<f32>> = tf
            .bases
            .iter()
            .map(|basis| {
                (0..TF_BINS)
                    .map(|b| -(1.0 - piecewise(&basis.opacity, centre(b)).min(ALPHA_CAP)).ln())
                    .collect()
            })
            .collect();
        let color = (0..TF_BINS)
            .map(|b| piecewise_rgb(&tf.color, centre(b)))
            .collect();
        SampledTf {
            lo,
            scale,
            nonzero_below: nonzero_below(&tau),
            tau,
            color,
            names: tf.bases.iter().map(|b| b.name.clone()).collect(),
        }
    }

    /// A one-basis table of the family's extinction at `weights`, `Σ kᵢ τᵢ` bin by bin (the
    /// "basis" of the joint POF). Summed in basis order, as the classifier sums it.
    #[must_use]
    pub fn joint(&self, weights: &[f32]) -> SampledTf {
        let mut sum = vec![0f32; TF_BINS];
        for (t, k) in self.tau.iter().zip(weights) {
            if *k > 0.0 {
                for (s, x) in sum.iter_mut().zip(t) {
                    *s += k * x;
                }
            }
        }
        let tau = vec![sum];
        SampledTf {
            lo: self.lo,
            scale: self.scale,
            nonzero_below: nonzero_below(&tau),
            tau,
            color: self.color.clone(),
            names: vec!["joint".to_owned()],
        }
    }

    /// Number of bases.
    #[must_use]
    pub fn basis_count(&self) -> usize {
        self.tau.len()
    }

    /// Basis names.
    #[must_use]
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The bin of value `v`.
    #[inline(always)]
    #[must_use]
    pub fn bin(&self, v: f32) -> usize {
        (((v - self.lo) * self.scale).max(0.0) as usize).min(TF_BINS - 1)
    }

    /// `(lo, scale)` of the bin lookup: bin = ⌊(v − lo)·scale⌋ clamped, as the classifier
    /// computes it.
    #[must_use]
    pub(crate) fn bin_params(&self) -> (f32, f32) {
        (self.lo, self.scale)
    }

    /// Inclusive bin range that values in `r` fall in.
    #[must_use]
    pub fn bin_range(&self, r: ValueRange) -> (usize, usize) {
        (self.bin(r.min), self.bin(r.max))
    }

    /// Extinction per unit length of basis `i` at bin `b`.
    #[must_use]
    pub fn tau(&self, basis: usize, bin: usize) -> f32 {
        self.tau[basis][bin]
    }

    /// Per-bin extinction table of basis `i`.
    #[must_use]
    pub fn tau_table(&self, basis: usize) -> &[f32] {
        &self.tau[basis]
    }

    /// True when every basis with weight > 0 is zero on every bin of `r`: a brick with this
    /// value range contributes nothing and is skipped.
    #[must_use]
    pub fn is_empty(&self, r: ValueRange, weights: &[f32]) -> bool {
        let (b0, b1) = self.bin_range(r);
        let empty = self
            .nonzero_below
            .iter()
            .zip(weights)
            .filter(|(_, k)| **k > 0.0)
            .all(|(n, _)| n[b1 + 1] == n[b0]);
        debug_assert_eq!(
            empty,
            self.tau
                .iter()
                .zip(weights)
                .filter(|(_, k)| **k > 0.0)
                .all(|(t, _)| t[b0..=b1].iter().all(|x| *x == 0.0))
        );
        empty
    }

    /// Per-bin premultiplied RGBA of one step of `step` units with `weights`.
    #[must_use]
    pub fn classify(&self, weights: &[f32], step: f32) -> Classifier {
        let rgba = (0..TF_BINS)
            .map(|b| {
                let tau: f32 = self.tau.iter().zip(weights).map(|(t, k)| k * t[b]).sum();
                let a = 1.0 - (-tau * step).exp();
                let c = self.color[b];
                [c[0] * a, c[1] * a, c[2] * a, a]
            })
            .collect();
        Classifier {
            lo: self.lo,
            scale: self.scale,
            rgba,
        }
    }
}

/// Per-bin premultiplied RGBA for one fixed step length and weight vector: what the sample
/// loop reads.
#[derive(Clone, Debug)]
pub struct Classifier {
    lo: f32,
    scale: f32,
    rgba: Vec<[f32; 4]>,
}

impl Classifier {
    /// Premultiplied RGBA of one step at value `v`.
    #[inline(always)]
    #[must_use]
    pub fn sample(&self, v: f32) -> [f32; 4] {
        self.view().sample(v)
    }

    /// The lookup by value, copied out for a sample loop to keep in registers.
    #[inline(always)]
    pub(crate) fn view(&self) -> ClassifierView<'_> {
        debug_assert_eq!(self.rgba.len(), TF_BINS);
        ClassifierView {
            lo: self.lo,
            scale: self.scale,
            rgba: &self.rgba,
        }
    }
}

/// A [`Classifier`]'s lookup: the one definition of [`Classifier::sample`].
#[derive(Clone, Copy)]
pub(crate) struct ClassifierView<'c> {
    pub(crate) lo: f32,
    pub(crate) scale: f32,
    /// Always TF_BINS entries.
    pub(crate) rgba: &'c [[f32; 4]],
}

impl ClassifierView<'_> {
    /// Premultiplied RGBA of one step at value `v`.
    #[inline(always)]
    pub(crate) fn sample(self, v: f32) -> [f32; 4] {
        // Not clamp: `max` turns a NaN into 0, which keeps the unchecked cast sound.
        #[allow(clippy::manual_clamp)]
        let x = ((v - self.lo) * self.scale).max(0.0).min(BIN_MAX);
        // SAFETY: x is in [0, TF_BINS-1]; `max` maps NaN to 0. (Through i32, whose
        // conversion zero-extends for free, unlike u32's.)
        let b = unsafe { x.to_int_unchecked::<i32>() } as u32 as usize;
        debug_assert_eq!(self.rgba.len(), TF_BINS);
        // SAFETY: `rgba` always holds TF_BINS entries (built by `SampledTf::classify`, the
        // only maker of a `Classifier`, whose `view` is the only maker of this) and `b` is
        // clamped below TF_BINS.
        *unsafe { self.rgba.get_unchecked(b) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn family() -> &'static str {
        r#"{"bases":[{"name":"skin","opacity":[[0,0],[50,0.2],[100,0]]},
                     {"name":"bone","opacity":[[150,0],[200,0.9]]}],
            "weights":[1.0,0.5],
            "color":[[0,1,0.8,0.6],[255,1,1,1]]}"#
    }

    #[test]
    fn parses_and_defaults_weights() {
        let tf = TransferFunction::from_json(family(), "f.json").unwrap();
        assert_eq!(tf.weights, vec![1.0, 0.5]);
        let no_w = family().replace(r#""weights":[1.0,0.5],"#, "");
        assert_eq!(
            TransferFunction::from_json(&no_w, "f.json")
                .unwrap()
                .weights,
            vec![1.0, 1.0]
        );
    }

    fn field_error(text: &str) -> String {
        TransferFunction::from_json(text, "bad.json")
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn errors_name_file_and_field() {
        let e = field_error(&family().replace("[100,0]", "[40,0]"));
        assert!(
            e.contains("bad.json") && e.contains("bases[0].opacity[2]") && e.contains("sorted"),
            "{e}"
        );
        let e = field_error(&family().replace("0.9", "1.5"));
        assert!(
            e.contains("bases[1].opacity[1]") && e.contains("outside [0, 1]"),
            "{e}"
        );
        let e = field_error(&family().replace("[1.0,0.5]", "[1.0,-0.5]"));
        assert!(e.contains("weights[1]"), "{e}");
        let e = field_error(&family().replace("[1.0,0.5]", "[1.0]"));
        assert!(
            e.contains("weights") && e.contains("expected one per basis"),
            "{e}"
        );
        let e = field_error(r#"{"bases":[],"color":[[0,1,1,1]]}"#);
        assert!(e.contains("bases") && e.contains("no bases"), "{e}");
        let e = field_error("{\"bases\": [");
        assert!(e.contains("bad.json") && e.contains("line"), "{e}");
    }

    #[test]
    fn fingerprint_ignores_weights_and_colour_but_not_bases() {
        let a = TransferFunction::from_json(family(), "f").unwrap();
        let mut b = a.clone();
        b.weights = vec![0.1, 3.0];
        b.color[0][1] = 0.0;
        assert_eq!(a.bases_fingerprint(), b.bases_fingerprint());
        b.bases[1].opacity[1][1] = 0.8;
        assert_ne!(a.bases_fingerprint(), b.bases_fingerprint());
    }

    #[test]
    fn emptiness_follows_active_bases_on_the_bins() {
        let tf = TransferFunction::from_json(family(), "f").unwrap();
        let s = SampledTf::new(
            &tf,
            ValueRange {
                min: 0.0,
                max: 255.0,
            },
        );
        let skin_only = ValueRange {
            min: 20.0,
            max: 60.0,
        };
        let bone_only = ValueRange {
            min: 170.0,
            max: 210.0,
        };
        let nothing = ValueRange {
            min: 110.0,
            max: 140.0,
        };
        assert!(!s.is_empty(skin_only, &[1.0, 1.0]));
        assert!(s.is_empty(skin_only, &[0.0, 1.0]));
        assert!(!s.is_empty(bone_only, &[0.0, 1.0]));
        assert!(s.is_empty(nothing, &[1.0, 1.0]));
    }

    #[test]
    fn unit_step_alpha_is_the_file_alpha_and_extinctions_add() {
        let tf = TransferFunction::from_json(
            r#"{"bases":[{"name":"a","opacity":[[0,0.3],[10,0.3]]},{"name":"b","opacity":[[0,0.5],[10,0.5]]}],
                "color":[[0,1,1,1]]}"#,
            "f",
        )
        .unwrap();
        let s = SampledTf::new(
            &tf,
            ValueRange {
                min: 0.0,
                max: 10.0,
            },
        );
        let one = s.classify(&[1.0, 0.0], 1.0).sample(5.0)[3];
        assert!((one - 0.3).abs() < 1e-6);
        let both = s.classify(&[1.0, 1.0], 1.0).sample(5.0)[3];
        assert!((both - (1.0 - 0.7 * 0.5)).abs() < 1e-6);
        let half_step = s.classify(&[2.0, 0.0], 0.5).sample(5.0)[3];
        assert!((half_step - 0.3).abs() < 1e-6);
    }
}
