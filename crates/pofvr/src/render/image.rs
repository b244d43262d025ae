//! Float RGBA images (premultiplied) and their outputs.

use std::io::Write;
use std::path::Path;

use crate::io::{write_atomic, WriteError};

/// A premultiplied RGBA float image, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    width: u32,
    height: u32,
    pixels: Vec<[f32; 4]>,
}

impl Image {
    /// A transparent black image.
    #[must_use]
    pub fn new(width: u32, height: u32) -> Self {
        Image {
            width,
            height,
            pixels: vec![[0.0; 4]; width as usize * height as usize],
        }
    }

    /// Wraps pixels; `None` when the count does not match.
    #[must_use]
    pub fn from_pixels(width: u32, height: u32, pixels: Vec<[f32; 4]>) -> Option<Self> {
        (pixels.len() == width as usize * height as usize).then_some(Image {
            width,
            height,
            pixels,
        })
    }

    /// Width.
    #[must_use]
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height.
    #[must_use]
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Pixels, row-major.
    #[must_use]
    pub fn pixels(&self) -> &[[f32; 4]] {
        &self.pixels
    }

    /// Mutable pixels, row-major.
    pub fn pixels_mut(&mut self) -> &mut [[f32; 4]] {
        &mut self.pixels
    }

    /// The pixel at `(x, y)`.
    #[must_use]
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 4] {
        self.pixels[y as usize * self.width as usize + x as usize]
    }

    /// 8-bit RGBA with straight (un-premultiplied) colour, as PNG expects; over black it
    /// shows exactly the premultiplied colour.
    #[must_use]
    pub fn to_rgba8(&self) -> Vec<u8> {
        let mut out = vec![0u8; self.pixels.len() * 4];
        for (o, p) in out.chunks_exact_mut(4).zip(&self.pixels) {
            let a = p[3];
            // A select, not a branch around the division, so that the loop vectorises.
            let inv = 1.0 / a;
            let inv = if a > 0.0 { inv } else { 0.0 };
            o.copy_from_slice(&[
                to_u8(p[0] * inv),
                to_u8(p[1] * inv),
                to_u8(p[2] * inv),
                to_u8(a),
            ]);
        }
        out
    }

    /// Writes an 8-bit RGBA PNG through a temp file renamed into place.
    ///
    /// # Errors
    /// [`WriteError`] naming the path.
    pub fn write_png(&self, path: &Path) -> Result<(), WriteError> {
        let rgba = self.to_rgba8();
        write_atomic(path, |w| {
            let mut enc = png::Encoder::new(w, self.width, self.height);
            enc.set_color(png::ColorType::Rgba);
            enc.set_depth(png::BitDepth::Eight);
            let mut wr = enc.write_header().map_err(std::io::Error::other)?;
            wr.write_image_data(&rgba).map_err(std::io::Error::other)?;
            wr.finish().map_err(std::io::Error::other)
        })
    }

    /// Writes the float image: little-endian f32, W×H×4, premultiplied, no header.
    ///
    /// # Errors
    /// [`WriteError`] naming the path.
    pub fn write_raw(&self, path: &Path) -> Result<(), WriteError> {
        write_atomic(path, |w| {
            let mut buf = std::io::BufWriter::new(w);
            for p in &self.pixels {
                for c in p {
                    buf.write_all(&c.to_le_bytes())?;
                }
            }
            buf.flush()
        })
    }

    /// Reads a float image written by [`Image::write_raw`].
    ///
    /// # Errors
    /// An I/O error, or `InvalidData` when the size is not `width × height × 16` bytes.
    pub fn read_raw(path: &Path, width: u32, height: u32) -> std::io::Result<Self> {
        let bytes = std::fs::read(path)?;
        if bytes.len() != width as usize * height as usize * 16 {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!(
                    "{}: {} bytes, expected {}×{}×16",
                    path.display(),
                    bytes.len(),
                    width,
                    height
                ),
            ));
        }
        let pixels = bytes
            .chunks_exact(16)
            .map(|c| {
                std::array::from_fn(|i| {
                    f32::from_le_bytes(c[i * 4..i * 4 + 4].try_into().expect("4 bytes"))
                })
            })
            .collect();
        Ok(Image {
            width,
            height,
            pixels,
        })
    }

    /// Largest absolute difference of any channel, or `None` for different sizes.
    #[must_use]
    pub fn max_abs_diff(&self, other: &Image) -> Option<f32> {
        if (self.width, self.height) != (other.width, other.height) {
            return None;
        }
        Some(
            self.pixels
                .iter()
                .zip(&other.pixels)
                .flat_map(|(a, b)| (0..4).map(move |c| (a[c] - b[c]).abs()))
                .fold(0.0, f32::max),
        )
    }

    /// Root-mean-square difference over all channels, or `None` for different sizes.
    #[must_use]
    pub fn rmse(&self, other: &Image) -> Option<f64> {
        if (self.width, self.height) != (other.width, other.height) {
            return None;
        }
        let s: f64 = self
            .pixels
            .iter()
            .zip(&other.pixels)
            .flat_map(|(a, b)| (0..4).map(move |c| f64::from(a[c] - b[c]).powi(2)))
            .sum();
        Some((s / (self.pixels.len() * 4).max(1) as f64).sqrt())
    }

    /// Mean alpha.
    #[must_use]
    pub fn mean_alpha(&self) -> f64 {
        let n = self.pixels.len().max(1) as f64;
        self.pixels.iter().map(|p| f64::from(p[3])).sum::<f64>() / n
    }
}

/// One channel in 8 bits: `x` clamped to [0, 1], times 255, rounded half away from zero
/// (NaN gives 0), exactly `(x.clamp(0.0, 1.0) * 255.0).round() as u8`, but without
/// `round`, a call into libm per channel on the x86-64 baseline, so that
/// [`Image::to_rgba8`] vectorises: a 512² image took 7.8 ms that way and takes 0.7 ms now,
/// against 15–35 ms for a march frame of that size (every frame the CLI writes and the
/// viewer sends is converted; `docs/results.md`, stop 39).
#[inline]
pub fn to_u8(x: f32) -> u8 {
    // Not `clamp`: `max` turns a NaN into 0 (where `clamp` keeps it, and the cast of
    // the reference then gives 0 too), so `y` is in [0, 255].
    #[allow(clippy::manual_clamp)]
    let y = x.max(0.0).min(1.0) * 255.0;
    // SAFETY: `y` is in [0, 255]. The truncation is the floor here, and `y − i` is exact,
    // as `i ≤ y < i + 1` (Sterbenz), so the comparison is the rounding.
    let i = unsafe { y.to_int_unchecked::<i32>() };
    (i + i32::from(y - i as f32 >= 0.5)) as u8
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn eight_bits_round_as_round_does_for_every_float_in_range() {
        let reference = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
        // Every float from 0 to 1 and 1.0's neighbours above; negatives on a stride.
        let bad = (0..=1.0f32.to_bits() + 1000)
            .into_par_iter()
            .filter(|&b| {
                let x = f32::from_bits(b);
                to_u8(x) != reference(x) || (b % 4099 == 0 && to_u8(-x) != reference(-x))
            })
            .count();
        assert_eq!(bad, 0);
        for x in [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            2.0,
            1e30,
            -1e-30,
        ] {
            assert_eq!(to_u8(x), reference(x), "{x}");
        }
    }

    #[test]
    fn eight_bit_pixels_are_straight_colour() {
        let img = Image::from_pixels(
            3,
            1,
            vec![[0.25, 0.125, 0.0, 0.5], [0.0; 4], [0.3, 0.2, 0.1, 1.0]],
        )
        .unwrap();
        assert_eq!(
            img.to_rgba8(),
            [128, 64, 0, 128, 0, 0, 0, 0, 77, 51, 26, 255]
        );
    }
}
