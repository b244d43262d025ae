//! Python values to and from JSON text, through Python's own `json` module, so that dicts
//! the library reads (families, cameras) and writes (statistics, cameras) keep exactly the
//! keys and numbers of the files the command line reads and writes.

use pyo3::prelude::*;

/// `json.dumps(value)`.
pub(crate) fn dumps(value: &Bound<'_, PyAny>) -> PyResult<String> {
    let py = value.py();
    py.import("json")?
        .call_method1("dumps", (value,))?
        .extract()
}

/// `json.loads(text)`.
pub(crate) fn loads<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (text,))
}
