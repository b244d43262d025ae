//! `pofvr.Frame`: a rendered image with its statistics and camera, as numpy arrays, dicts,
//! PNG bytes (which Jupyter shows) and files.

use std::path::PathBuf;

use numpy::{IntoPyArray, PyArray3, PyArrayMethods};
use pofvr::{Camera, Image};
use pyo3::prelude::*;
use pyo3::types::PyBytes;

use crate::error::OrPy;
use crate::json;

/// A rendered frame.
///
/// `rgba` is the image as the PNG holds it (uint8, straight alpha), `rgba_float` as
/// `pofvr render --out-raw` writes it (float32, premultiplied), both of shape
/// `(height, width, 4)` with row 0 at the top. `stats` holds the keys of `--stats`,
/// `camera` the camera JSON (pass it back as `Scene.render(camera=...)`).
#[pyclass(module = "pofvr", name = "Frame", frozen)]
pub(crate) struct PyFrame {
    image: Image,
    /// The statistics as `--stats` writes them.
    stats: String,
    camera: Camera,
}

impl PyFrame {
    pub(crate) fn new(image: Image, stats: String, camera: Camera) -> Self {
        PyFrame {
            image,
            stats,
            camera,
        }
    }

    fn png(&self) -> PyResult<Vec<u8>> {
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, self.image.width(), self.image.height());
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        let encode = |enc: png::Encoder<'_, &mut Vec<u8>>| -> Result<(), png::EncodingError> {
            let mut w = enc.write_header()?;
            w.write_image_data(&self.image.to_rgba8())?;
            w.finish()
        };
        encode(enc).map_err(|e| crate::error::input_error(format!("PNG encoding: {e}")))?;
        Ok(out)
    }

    fn shape(&self) -> [usize; 3] {
        [self.image.height() as usize, self.image.width() as usize, 4]
    }
}

#[pymethods]
impl PyFrame {
    /// Width in pixels.
    #[getter]
    fn width(&self) -> u32 {
        self.image.width()
    }

    /// Height in pixels.
    #[getter]
    fn height(&self) -> u32 {
        self.image.height()
    }

    /// The image as the PNG holds it: `(height, width, 4)` uint8 RGBA, straight alpha.
    #[getter]
    fn rgba<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<u8>>> {
        self.image.to_rgba8().into_pyarray(py).reshape(self.shape())
    }

    /// The float image as `--out-raw` writes it: `(height, width, 4)` float32 RGBA,
    /// premultiplied by alpha.
    #[getter]
    fn rgba_float<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let flat: Vec<f32> = self.image.pixels().iter().flatten().copied().collect();
        flat.into_pyarray(py).reshape(self.shape())
    }

    /// The frame's statistics: the keys `pofvr render --stats` writes for one frame.
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json::loads(py, &self.stats)
    }

    /// The camera, as the camera JSON (`--camera-out`) holds it.
    #[getter]
    fn camera<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json::loads(py, &self.camera.to_json())
    }

    /// Writes the image to `path`: a PNG (as `rgba`), or with a `.raw` extension the float
    /// image (as `rgba_float`, little-endian). Written to a temporary file and renamed.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let raw = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("raw"));
        let image = &self.image;
        py.allow_threads(|| {
            if raw {
                image.write_raw(&path)
            } else {
                image.write_png(&path)
            }
        })
        .or_py()
    }

    /// The PNG bytes (Jupyter shows a frame with them).
    fn _repr_png_<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        Ok(PyBytes::new(py, &self.png()?))
    }

    fn __repr__(&self) -> String {
        format!(
            "<pofvr.Frame {}x{}>",
            self.image.width(),
            self.image.height()
        )
    }
}
