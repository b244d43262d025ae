//! Built-in transfer-function families for the generated phantoms.

use super::TransferFunction;

/// Skin (soft tissue) + bone for the Shepp–Logan phantom's u8 intensities (brain ≈ 50,
/// features 75–100, shell 250).
pub const SHEPP_LOGAN_JSON: &str = r#"{
  "bases": [
    {"name": "skin", "opacity": [[20, 0.0], [45, 0.12], [110, 0.12], [140, 0.0]]},
    {"name": "bone", "opacity": [[150, 0.0], [240, 0.6], [255, 0.6]]}
  ],
  "weights": [1.0, 1.0],
  "color": [[0, 0.0, 0.0, 0.0], [40, 0.85, 0.55, 0.45], [100, 0.95, 0.75, 0.6], [200, 1.0, 0.97, 0.9], [255, 1.0, 1.0, 1.0]]
}"#;

/// A coloured family for the smooth head's intensities (air 0, brain ≈ 50, small
/// features 75–100, skull up to 250): brain a faint rose veil, the features amber, the
/// skull translucent ivory, so a shaded frame shows the inside through the shell.
pub const SMOOTH_HEAD_JSON: &str = r#"{
  "bases": [
    {"name": "brain", "opacity": [[28, 0.0], [46, 0.008], [58, 0.008], [66, 0.0]]},
    {"name": "features", "opacity": [[66, 0.0], [76, 0.12], [102, 0.12], [112, 0.0]]},
    {"name": "skull", "opacity": [[150, 0.0], [220, 0.1], [255, 0.14]]}
  ],
  "weights": [1.0, 1.0, 1.0],
  "color": [[0, 0.3, 0.35, 0.8], [48, 0.95, 0.45, 0.5], [62, 0.95, 0.55, 0.35], [80, 1.0, 0.7, 0.15], [104, 1.0, 0.55, 0.1], [125, 0.6, 0.75, 0.95], [200, 0.95, 0.93, 0.85], [255, 1.0, 1.0, 0.95]]
}"#;

/// Two iso-bands for the Marschner–Lobb signal in [0, 1].
pub const MARSCHNER_LOBB_JSON: &str = r#"{
  "bases": [
    {"name": "low", "opacity": [[0.3, 0.0], [0.4, 0.3], [0.5, 0.0]]},
    {"name": "high", "opacity": [[0.55, 0.0], [0.7, 0.5], [1.0, 0.5]]}
  ],
  "weights": [1.0, 1.0],
  "color": [[0.0, 0.2, 0.4, 1.0], [0.5, 0.9, 0.9, 0.9], [1.0, 1.0, 0.5, 0.2]]
}"#;

/// Skin and bone for the body phantom's Hounsfield units: the skin a translucent band over
/// fat and soft tissue (lungs and air clear), bone opaque ivory.
pub const BODY_JSON: &str = r#"{
  "bases": [
    {"name": "skin", "opacity": [[-450, 0.0], [-250, 0.1], [120, 0.1], [180, 0.0]]},
    {"name": "bone", "opacity": [[160, 0.0], [450, 0.7], [1400, 0.85]]}
  ],
  "weights": [1.0, 1.0],
  "color": [[-1000, 0, 0, 0], [-300, 0.8, 0.45, 0.35], [60, 0.95, 0.7, 0.6], [350, 1.0, 0.95, 0.85], [1400, 1, 1, 1]]
}"#;

/// The built-in family for a phantom.
#[must_use]
pub fn for_phantom(p: crate::volume::phantom::Phantom) -> TransferFunction {
    let text = match p {
        crate::volume::phantom::Phantom::SheppLogan => SHEPP_LOGAN_JSON,
        crate::volume::phantom::Phantom::SmoothHead => SMOOTH_HEAD_JSON,
        crate::volume::phantom::Phantom::MarschnerLobb => MARSCHNER_LOBB_JSON,
        crate::volume::phantom::Phantom::Body => BODY_JSON,
    };
    TransferFunction::from_json(text, "<built-in>").expect("built-in family is valid")
}

/// A one-basis ramp over the upper three quarters of a value range, for volumes given
/// without a family (`info`, benchmarks).
#[must_use]
pub fn auto_ramp(range: crate::brick::ValueRange) -> TransferFunction {
    let (lo, hi) = (range.min, range.max.max(range.min + 1e-6));
    let at = |f: f32| lo + (hi - lo) * f;
    TransferFunction {
        bases: vec![super::transfer_function::Basis {
            name: "ramp".into(),
            opacity: vec![[at(0.25), 0.0], [at(1.0), 0.5]],
        }],
        weights: vec![1.0],
        color: vec![
            [lo, 0.1, 0.1, 0.3],
            [at(0.5), 0.9, 0.6, 0.3],
            [hi, 1.0, 1.0, 0.9],
        ],
    }
}
