//! Keyword arguments into library values: names as the command line spells them, errors
//! as `pofvr.InputError` naming the argument.

use std::path::PathBuf;

use pofvr::render::{families, Camera, Projection, TransferFunction};
use pofvr::volume::phantom::Phantom;
use pofvr::{CullMode, Curve, Engine};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};

use crate::error::{input_error, OrPy};
use crate::json;

/// `name`'s value parsed by its `FromStr`, or an error naming `name`.
pub(crate) fn parse<T: std::str::FromStr<Err = String>>(name: &str, s: &str) -> PyResult<T> {
    s.parse()
        .map_err(|e: String| input_error(format!("{name}: {e}")))
}

/// The family given as `tf=`: a path to a family JSON file, or a dict of the same content.
pub(crate) fn family(tf: &Bound<'_, PyAny>) -> PyResult<TransferFunction> {
    if tf.is_instance_of::<PyDict>() {
        return TransferFunction::from_json(&json::dumps(tf)?, "tf dict").or_py();
    }
    if tf.is_instance_of::<PyString>() || tf.hasattr("__fspath__")? {
        let path: PathBuf = tf.extract()?;
        return TransferFunction::from_file(&path).or_py();
    }
    Err(pyo3::exceptions::PyTypeError::new_err(format!(
        "tf: expected a path to a family JSON file or a dict (bases, weights, color), got {}",
        tf.get_type().name()?
    )))
}

/// The family with `weights` as its own, when given.
pub(crate) fn with_weights(
    mut tf: TransferFunction,
    weights: Option<Vec<f32>>,
) -> PyResult<TransferFunction> {
    if let Some(w) = weights {
        tf.set_weights(w).or_py()?;
    }
    Ok(tf)
}

/// A phantom named `phantom:KIND[:N]` (as the command line names them) and its family.
pub(crate) fn phantom(spec: &str) -> PyResult<Option<(Phantom, usize)>> {
    let Some(rest) = spec.strip_prefix("phantom:") else {
        return Ok(None);
    };
    let mut parts = rest.split(':');
    let kind: Phantom = parse(spec, parts.next().unwrap_or("head"))?;
    let n = match parts.next() {
        Some(n) => n
            .parse::<usize>()
            .map_err(|_| input_error(format!("{spec}: size {n:?} is not a number")))?,
        None => 128,
    };
    if !(2..=2048).contains(&n) {
        return Err(input_error(format!(
            "{spec}: phantom size must be 2..=2048"
        )));
    }
    Ok(Some((kind, n)))
}

/// The phantom's built-in family.
pub(crate) fn phantom_family(kind: Phantom) -> TransferFunction {
    families::for_phantom(kind)
}

/// The camera of `camera=` (a dict as `camera.json` holds), checked as a camera file is.
pub(crate) fn camera(dict: &Bound<'_, PyAny>) -> PyResult<Camera> {
    let cam: Camera = serde_json::from_str(&json::dumps(dict)?)
        .map_err(|e| input_error(format!("camera: {e}")))?;
    cam.validate("camera").or_py()?;
    Ok(cam)
}

/// `(width, height)` in 1..=16384, as `--size` accepts.
pub(crate) fn size(size: (u32, u32)) -> PyResult<(u32, u32)> {
    let (w, h) = size;
    if !(1..=16384).contains(&w) || !(1..=16384).contains(&h) {
        return Err(input_error(format!(
            "size: ({w}, {h}) is out of range 1..=16384 (width, height)"
        )));
    }
    Ok((w, h))
}

/// A finite `(azimuth, elevation)` in degrees.
pub(crate) fn view(view: (f64, f64)) -> PyResult<(f64, f64)> {
    if !(view.0.is_finite() && view.1.is_finite()) {
        return Err(input_error(format!(
            "view: ({}, {}) is not a finite (azimuth, elevation) in degrees",
            view.0, view.1
        )));
    }
    Ok(view)
}

/// The cull mode named `none`, `exact`, `pof` or `pof-set`.
pub(crate) fn cull(name: &str) -> PyResult<CullMode> {
    parse("cull", name)
}

/// The engine named `march` or `bricks`.
pub(crate) fn engine(name: &str) -> PyResult<Engine> {
    parse("engine", name)
}

/// The curve named `hilbert` or `z`.
pub(crate) fn curve(name: &str) -> PyResult<Curve> {
    name.parse::<Curve>()
        .map_err(|e| input_error(format!("curve: {e}")))
}

/// The projection named `orthographic` or `perspective`.
pub(crate) fn projection(name: &str) -> PyResult<Projection> {
    parse("projection", name)
}
