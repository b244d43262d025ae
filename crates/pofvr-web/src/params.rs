//! `/api/frame` query parameters: parsed and range-checked before anything is rendered.
//!
//! Every failure is a plain-text message naming the parameter, the value got and what was
//! expected; the handler answers it with HTTP 400.

use std::collections::HashSet;

use crate::frame_adapter::{CullMode, FrameOptions, Look};
use pofvr::render::Projection;

/// Largest image side in pixels.
pub const MAX_SIDE: u32 = 2048;
/// Largest basis weight.
pub const MAX_WEIGHT: f32 = 100.0;
/// Zoom factor range.
pub const ZOOM_RANGE: (f64, f64) = (0.1, 20.0);
/// Azimuth range in degrees (any angle is valid; the bound keeps it a sane number).
pub const AZIMUTH_RANGE: (f64, f64) = (-3600.0, 3600.0);
/// Longest client id.
pub const MAX_CLIENT_ID: usize = 64;

/// A validated frame request.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameParams {
    /// Azimuth in degrees.
    pub azimuth: f64,
    /// Elevation in degrees, in [-90, 90].
    pub elevation: f64,
    /// Zoom factor: 1 fits the whole volume.
    pub zoom: f64,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Projection.
    pub projection: Projection,
    /// Weights and shading.
    pub look: Look,
    /// Cull mode and threshold.
    pub options: FrameOptions,
    /// Tint culled brick footprints.
    pub overlay: bool,
    /// Who asked: a newer request from the same client supersedes this one.
    pub client: String,
    /// The client's own sequence number, echoed in the stats.
    pub seq: u64,
}

impl FrameParams {
    /// The viewer's defaults for a family whose default weights are `weights`, culled by
    /// `cull`: a 512² orthographic view at azimuth 30°, elevation 20°, zoom 1, unshaded,
    /// no overlay, client `default`, one rank. What a query leaves out takes these values
    /// ([`parse`]); the server, the tests and the fuzz target all start from here.
    #[must_use]
    pub fn new(weights: Vec<f32>, cull: CullMode) -> Self {
        FrameParams {
            azimuth: 30.0,
            elevation: 20.0,
            zoom: 1.0,
            width: 512,
            height: 512,
            projection: Projection::Orthographic,
            look: Look {
                weights,
                shade: false,
            },
            options: FrameOptions {
                cull,
                ..FrameOptions::default()
            },
            overlay: false,
            client: "default".into(),
            seq: 0,
        }
    }
}

/// Parses `pairs` (the decoded query) for a family of `basis_count` bases; absent
/// parameters take `defaults`' values.
///
/// # Errors
/// A message for an unknown or repeated parameter or an invalid value.
pub fn parse(pairs: &[(String, String)], defaults: &FrameParams) -> Result<FrameParams, String> {
    let mut p = defaults.clone();
    let mut seen = HashSet::new();
    for (key, value) in pairs {
        if !seen.insert(key.as_str()) {
            return Err(format!("{key}: given more than once"));
        }
        match key.as_str() {
            "az" => p.azimuth = number(key, value, AZIMUTH_RANGE)?,
            "el" => p.elevation = number(key, value, (-90.0, 90.0))?,
            "zoom" => p.zoom = number(key, value, ZOOM_RANGE)?,
            "w" => p.width = side(key, value)?,
            "h" => p.height = side(key, value)?,
            "proj" => {
                p.projection = match value.as_str() {
                    "ortho" | "orthographic" => Projection::Orthographic,
                    "persp" | "perspective" => Projection::Perspective,
                    _ => return Err(format!("proj: {value:?} is not ortho or persp")),
                }
            }
            "weights" => p.look.weights = weights(value, defaults.look.weights.len())?,
            "threshold" => p.options.cull_threshold = number(key, value, (0.01, 1.0))? as f32,
            "cull" => p.options.cull = value.parse::<CullMode>().map_err(|e| format!("cull: {e}"))?,
            "shade" => p.look.shade = flag(key, value)?,
            "overlay" => p.overlay = flag(key, value)?,
            "client" => p.client = client_id(value)?,
            "seq" => {
                p.seq = value
                    .parse::<u64>()
                    .ok()
                    .filter(|s| *s < 1 << 53)
                    .ok_or_else(|| format!("seq: {value:?} is not an integer in [0, 2^53)"))?;
            }
            _ => {
                return Err(format!(
                    "unknown parameter {key:?}; expected az, el, zoom, w, h, proj, weights, threshold, cull, shade, overlay, client, seq"
                ))
            }
        }
    }
    Ok(p)
}

fn number(key: &str, value: &str, (lo, hi): (f64, f64)) -> Result<f64, String> {
    let x: f64 = value
        .trim()
        .parse()
        .map_err(|_| format!("{key}: {value:?} is not a number"))?;
    if !x.is_finite() {
        return Err(format!("{key}: {value:?} is not a finite number"));
    }
    if !(lo..=hi).contains(&x) {
        return Err(format!("{key}: {x} is outside [{lo}, {hi}]"));
    }
    Ok(x)
}

fn side(key: &str, value: &str) -> Result<u32, String> {
    let n: u32 = value
        .trim()
        .parse()
        .map_err(|_| format!("{key}: {value:?} is not a whole number of pixels"))?;
    if !(1..=MAX_SIDE).contains(&n) {
        return Err(format!("{key}: {n} is outside [1, {MAX_SIDE}] pixels"));
    }
    Ok(n)
}

fn flag(key: &str, value: &str) -> Result<bool, String> {
    match value {
        "1" | "true" | "on" => Ok(true),
        "0" | "false" | "off" => Ok(false),
        _ => Err(format!("{key}: {value:?} is not 0 or 1")),
    }
}

fn weights(value: &str, expected: usize) -> Result<Vec<f32>, String> {
    let parts: Vec<&str> = value.split(',').collect();
    if parts.len() != expected {
        return Err(format!(
            "weights: got {} values in {value:?}, expected one per basis ({expected})",
            parts.len()
        ));
    }
    parts
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let k = number(&format!("weights[{i}]"), s, (0.0, f64::from(MAX_WEIGHT)))?;
            Ok(k as f32)
        })
        .collect()
}

fn client_id(value: &str) -> Result<String, String> {
    let ok = !value.is_empty()
        && value.len() <= MAX_CLIENT_ID
        && value
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
    if !ok {
        return Err(format!(
            "client: expected 1 to {MAX_CLIENT_ID} characters of A-Z a-z 0-9 - _"
        ));
    }
    Ok(value.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn defaults() -> FrameParams {
        FrameParams::new(vec![1.0, 1.0], CullMode::None)
    }

    fn q(s: &str) -> Vec<(String, String)> {
        s.split('&')
            .filter(|x| !x.is_empty())
            .map(|kv| {
                let (k, v) = kv.split_once('=').unwrap_or((kv, ""));
                (k.to_string(), v.to_string())
            })
            .collect()
    }

    #[test]
    fn empty_query_gives_the_defaults() {
        assert_eq!(parse(&[], &defaults()), Ok(defaults()));
    }

    #[test]
    fn every_parameter_is_read() {
        let p = parse(
            &q("az=-45.5&el=90&zoom=2&w=64&h=32&proj=persp&weights=0.5,3&threshold=0.5&cull=pof-set&shade=1&overlay=true&client=a-1_b&seq=7"),
            &defaults(),
        )
        .unwrap();
        assert_eq!(
            (p.azimuth, p.elevation, p.zoom, p.width, p.height),
            (-45.5, 90.0, 2.0, 64, 32)
        );
        assert_eq!(p.projection, Projection::Perspective);
        assert_eq!(
            p.look,
            Look {
                weights: vec![0.5, 3.0],
                shade: true
            }
        );
        assert_eq!(
            (p.options.cull, p.options.cull_threshold),
            (CullMode::PofSet, 0.5)
        );
        assert!(p.overlay);
        assert_eq!((p.client.as_str(), p.seq), ("a-1_b", 7));
    }

    #[test]
    fn bad_values_name_the_parameter() {
        for (query, needle) in [
            ("el=91", "el: 91 is outside"),
            ("az=NaN", "az: \"NaN\" is not a finite"),
            ("az=inf", "not a finite"),
            ("zoom=abc", "zoom: \"abc\" is not a number"),
            ("zoom=0", "zoom: 0 is outside"),
            ("w=0", "w: 0 is outside"),
            ("h=4096", "h: 4096 is outside [1, 2048]"),
            ("w=-3", "w: \"-3\" is not a whole number"),
            ("proj=fisheye", "proj:"),
            ("weights=1", "got 1 values"),
            ("weights=1,2,3", "got 3 values"),
            ("weights=1,-1", "weights[1]: -1 is outside"),
            ("weights=1,1e9", "weights[1]"),
            ("weights=1,", "weights[1]: \"\" is not a number"),
            ("threshold=2", "threshold: 2 is outside"),
            ("cull=all", "cull: unknown cull mode"),
            ("shade=maybe", "shade: \"maybe\" is not 0 or 1"),
            ("client=", "client: expected"),
            ("client=../../etc", "client: expected"),
            ("seq=-1", "seq:"),
            ("path=/etc/passwd", "unknown parameter \"path\""),
            ("az=1&az=2", "az: given more than once"),
        ] {
            let e = parse(&q(query), &defaults()).unwrap_err();
            assert!(e.contains(needle), "{query}: {e}");
        }
        let long = format!("client={}", "x".repeat(MAX_CLIENT_ID + 1));
        assert!(parse(&q(&long), &defaults()).is_err());
    }
}
