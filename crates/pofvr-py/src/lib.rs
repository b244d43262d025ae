//! `pofvr` for Python: scenes of numpy arrays (borrowed, not copied) or volume files,
//! rendered with the GIL released into frames that numpy, Pillow and Jupyter read.
//!
//! The module is the [`pofvr::Scene`] facade with Python types at its edges: `Scene`
//! ([`scene`]), `Frame` ([`frame`]), `open` and the exceptions ([`error`]). Its stubs
//! are `pofvr.pyi` next to this crate's `Cargo.toml`.

mod array;
mod build;
mod error;
mod frame;
mod json;
mod memory;
mod options;
mod scene;

use pyo3::prelude::*;

/// The extension module `pofvr`.
#[pymodule]
#[pyo3(name = "pofvr")]
fn pofvr_module(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    error::register(m)?;
    m.add_class::<scene::PyScene>()?;
    m.add_class::<frame::PyFrame>()?;
    m.add_function(wrap_pyfunction!(scene::open, m)?)?;
    Ok(())
}
