//! Reads the one `.npy` layout the VTK peer writes: little-endian f32, C order,
//! shape `(H, W, 4)`, rows top first.

use crate::render::Image;

/// The image in `bytes`, or what is wrong with them.
///
/// # Errors
/// A message naming the first part of the file that is not a `(H, W, 4)` `<f4` C-order array.
pub fn read_rgba_f32(bytes: &[u8]) -> Result<Image, String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a .npy file (no \\x93NUMPY magic)".into());
    }
    let (header_len, start) = match bytes[6] {
        1 => (usize::from(u16::from_le_bytes([bytes[8], bytes[9]])), 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => return Err(format!("unsupported .npy version {v}")),
    };
    let header = bytes
        .get(start..start + header_len)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or("truncated .npy header")?;
    if !header.contains("'descr': '<f4'") {
        return Err(format!("not little-endian f32: {header}"));
    }
    if !header.contains("'fortran_order': False") {
        return Err(format!("not C order: {header}"));
    }
    let shape = header
        .split("'shape': (")
        .nth(1)
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| format!("no shape: {header}"))?;
    let dims: Vec<usize> = shape
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().map_err(|_| format!("bad shape {shape:?}")))
        .collect::<Result<_, _>>()?;
    let [h, w, 4] = dims[..] else {
        return Err(format!("shape ({shape}) is not (H, W, 4)"));
    };
    let data = &bytes[start + header_len..];
    if data.len() != h * w * 16 {
        return Err(format!("{} data bytes for shape ({shape})", data.len()));
    }
    let pixels = data
        .chunks_exact(16)
        .map(|c| {
            let f = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
            [f(0), f(4), f(8), f(12)]
        })
        .collect();
    Image::from_pixels(w as u32, h as u32, pixels).ok_or_else(|| "image size".into())
}

/// Peak signal-to-noise ratio of `a` against `b` over all four premultiplied channels, peak
/// 1; `None` for images of different sizes, infinite for equal ones.
#[must_use]
pub fn psnr(a: &Image, b: &Image) -> Option<f64> {
    let rmse = a.rmse(b)?;
    Some(-20.0 * rmse.log10())
}
