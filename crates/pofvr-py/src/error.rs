//! The exceptions: `pofvr.Error`, the base of every error the library reports, with
//! `pofvr.InputError` (also a `ValueError`: a bad value, file content or setting) and
//! `pofvr.FileError` (also an `OSError`: a file that could not be read or written).

use pyo3::exceptions::{PyException, PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::GILOnceCell;
use pyo3::types::{PyDict, PyTuple, PyType};

pyo3::create_exception!(
    pofvr,
    Error,
    PyException,
    "Base of every error pofvr reports; its message is the library's."
);

static INPUT_ERROR: GILOnceCell<Py<PyType>> = GILOnceCell::new();
static FILE_ERROR: GILOnceCell<Py<PyType>> = GILOnceCell::new();

/// A class deriving from `pofvr.Error` and `base`: made with `type()` because a Rust-defined
/// exception has one base only.
fn subclass(
    py: Python<'_>,
    name: &str,
    base: Bound<'_, PyType>,
    doc: &str,
) -> PyResult<Py<PyType>> {
    let dict = PyDict::new(py);
    dict.set_item("__module__", "pofvr")?;
    dict.set_item("__doc__", doc)?;
    let bases = PyTuple::new(py, [py.get_type::<Error>(), base])?;
    let ty = py
        .get_type::<PyType>()
        .call1((name, bases, dict))?
        .downcast_into::<PyType>()?;
    Ok(ty.unbind())
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("Error", py.get_type::<Error>())?;
    let input = INPUT_ERROR.get_or_try_init(py, || {
        subclass(
            py,
            "InputError",
            py.get_type::<PyValueError>(),
            "A bad value, file content or setting (a ValueError).",
        )
    })?;
    m.add("InputError", input.bind(py))?;
    let file = FILE_ERROR.get_or_try_init(py, || {
        subclass(
            py,
            "FileError",
            py.get_type::<PyOSError>(),
            "A file that could not be read or written (an OSError; errno set when known).",
        )
    })?;
    m.add("FileError", file.bind(py))?;
    Ok(())
}

/// A `pofvr.InputError` (a `ValueError`) with `msg`.
pub(crate) fn input_error(msg: impl Into<String>) -> PyErr {
    Python::with_gil(|py| match INPUT_ERROR.get(py) {
        Some(t) => PyErr::from_type(t.bind(py).clone(), msg.into()),
        None => PyValueError::new_err(msg.into()),
    })
}

/// The library's error as a Python exception: `pofvr.FileError` when an I/O error caused
/// it, otherwise `pofvr.InputError`, with the library's message.
pub(crate) fn to_py(e: &(dyn std::error::Error + 'static)) -> PyErr {
    let msg = e.to_string();
    let mut cause: Option<&(dyn std::error::Error + 'static)> = Some(e);
    let mut io = None;
    while let Some(c) = cause {
        if let Some(x) = c.downcast_ref::<std::io::Error>() {
            io = Some(x);
            break;
        }
        cause = c.source();
    }
    let Some(io) = io else {
        return input_error(msg);
    };
    Python::with_gil(|py| {
        let Some(t) = FILE_ERROR.get(py) else {
            return PyOSError::new_err(msg);
        };
        match io.raw_os_error() {
            // OSError(errno, strerror) sets `errno` and prints "[Errno N] message".
            Some(n) => PyErr::from_type(t.bind(py).clone(), (n, msg)),
            None => PyErr::from_type(t.bind(py).clone(), msg),
        }
    })
}

/// `Result` with the library's errors turned into Python exceptions.
pub(crate) trait OrPy<T> {
    fn or_py(self) -> PyResult<T>;
}

impl<T, E: std::error::Error + 'static> OrPy<T> for Result<T, E> {
    fn or_py(self) -> PyResult<T> {
        self.map_err(|e| to_py(&e))
    }
}
