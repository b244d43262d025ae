//! numpy arrays as volumes, borrowed and not copied.
//!
//! An array of shape `(z, y, x)` in C order is exactly the library's layout (x fastest),
//! so its buffer is served as the volume's voxels ([`pofvr::volume::Voxels::borrowed`]).
//! The volume holds a reference to the array, which keeps the buffer alive, and the array
//! is marked read-only (`flags.writeable = False`) so that Python cannot change voxels
//! that bricks, value ranges and POFs were measured on, or that a frame is reading.

use std::sync::Arc;

use numpy::{
    Element, PyArray3, PyArrayDescrMethods, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods,
};
use pofvr::volume::{VoxelData, Voxels};
use pofvr::Volume;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

use crate::error::OrPy;

/// `v` as Python writes a tuple: `(4, 4)`, `(4,)`.
fn tuple<T: std::fmt::Display>(v: &[T]) -> String {
    let items: Vec<String> = v.iter().map(ToString::to_string).collect();
    match items.as_slice() {
        [one] => format!("({one},)"),
        _ => format!("({})", items.join(", ")),
    }
}

/// What volumes made from arrays are called in messages.
pub(crate) const SOURCE: &str = "numpy array";

/// The volume of `obj`, a C-contiguous `(z, y, x)` array of u8, u16, i16 or f32 in native
/// byte order, with `spacing` `(sx, sy, sz)`.
///
/// # Errors
/// `TypeError` for something that is not a numpy array or has another dtype;
/// `ValueError` for another number of dimensions, strides that are not C order, a
/// misaligned buffer, a zero dimension, a bad spacing or NaN/Inf voxels.
pub(crate) fn volume(obj: &Bound<'_, PyAny>, spacing: [f32; 3]) -> PyResult<Volume> {
    let arr = obj.downcast::<PyUntypedArray>().map_err(|_| {
        let ty = obj
            .get_type()
            .name()
            .map_or_else(|_| "?".to_owned(), |n| n.to_string());
        PyTypeError::new_err(format!(
            "volume: expected a numpy.ndarray of shape (z, y, x), got {ty}"
        ))
    })?;
    let py = obj.py();
    let dtype = arr.dtype();
    let shape = arr.shape().to_vec();
    if shape.len() != 3 {
        return Err(PyValueError::new_err(format!(
            "volume: expected a 3-D array of shape (z, y, x), got shape {} ({} dimensions)",
            tuple(&shape),
            shape.len()
        )));
    }
    let dtype_name = dtype
        .str()
        .map_or_else(|_| "?".to_owned(), |s| s.to_string());
    let is = |d: Bound<'_, numpy::PyArrayDescr>| dtype.is_equiv_to(&d);
    let kind = if is(numpy::dtype::<u8>(py)) {
        pofvr::volume::DataType::U8
    } else if is(numpy::dtype::<u16>(py)) {
        pofvr::volume::DataType::U16
    } else if is(numpy::dtype::<i16>(py)) {
        pofvr::volume::DataType::I16
    } else if is(numpy::dtype::<f32>(py)) {
        pofvr::volume::DataType::F32
    } else {
        let hint = if dtype.byteorder() == b'>' {
            " (big-endian: convert with arr.astype(arr.dtype.newbyteorder('=')))"
        } else {
            ""
        };
        return Err(PyTypeError::new_err(format!(
            "volume: dtype {dtype_name} is not supported{hint}; expected uint8, uint16, int16 or float32"
        )));
    };
    if !arr.is_c_contiguous() {
        return Err(PyValueError::new_err(format!(
            "volume: strides {} (bytes) of shape {} are not C-contiguous; pass numpy.ascontiguousarray(arr) (a copy)",
            tuple(arr.strides()),
            tuple(&shape)
        )));
    }
    if shape.contains(&0) {
        return Err(PyValueError::new_err(format!(
            "volume: shape {} has a zero dimension; every dimension must be at least 1",
            tuple(&shape)
        )));
    }
    let dims = [shape[2], shape[1], shape[0]];
    let data = match kind {
        pofvr::volume::DataType::U8 => VoxelData::U8(borrow::<u8>(obj)?),
        pofvr::volume::DataType::U16 => VoxelData::U16(borrow::<u16>(obj)?),
        pofvr::volume::DataType::I16 => VoxelData::I16(borrow::<i16>(obj)?),
        pofvr::volume::DataType::F32 => VoxelData::F32(borrow::<f32>(obj)?),
    };
    let volume = Volume::new(dims, spacing, data, SOURCE).or_py()?;
    // Locked only once accepted, so that a rejected array is left as it was.
    obj.getattr("flags")?.setattr("writeable", false)?;
    Ok(volume)
}

/// The voxels of `obj` (a C-contiguous 3-D array of `T`), borrowed.
fn borrow<T: Element + pofvr::volume::Voxel>(obj: &Bound<'_, PyAny>) -> PyResult<Voxels<T>> {
    let arr = obj.downcast::<PyArray3<T>>()?;
    let ptr = arr.data() as *const T;
    let len = arr.len();
    if len > 0 && ptr.align_offset(std::mem::align_of::<T>()) != 0 {
        return Err(PyValueError::new_err(format!(
            "volume: the array's buffer at {ptr:p} is not aligned for its dtype; pass arr.copy()"
        )));
    }
    let owner: Arc<dyn Send + Sync> = Arc::new(arr.clone().unbind());
    // SAFETY: `ptr` is the buffer of a C-contiguous, aligned array of `len` elements of
    // `T`; `owner` holds a reference to the array, so the buffer lives as long as it does;
    // the array is made read-only before the volume is used (see the module docs: writes
    // through other views of the same memory are the caller's to avoid).
    Ok(unsafe { Voxels::borrowed(owner, ptr, len) })
}
