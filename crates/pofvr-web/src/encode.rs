//! Frames to PNG bytes, with the optional tint over culled bricks' footprints.

use glam::DVec3;
use pofvr::brick::{BrickGrid, BrickId};
use pofvr::render::image::to_u8;
use pofvr::render::{Camera, Image, PixelRect};

/// Tint colour of culled footprints (magenta: absent from every built-in colour map).
const TINT: [f32; 3] = [1.0, 0.0, 0.85];
/// How much of the tint shows over the frame.
const TINT_ALPHA: f32 = 0.4;

/// The pixel rectangles that `bricks` may cover in `camera`'s image.
#[must_use]
pub fn footprints(
    grid: &BrickGrid,
    spacing: [f32; 3],
    camera: &Camera,
    bricks: &[BrickId],
) -> Vec<PixelRect> {
    let frame = camera.frame();
    let s = DVec3::from(spacing.map(f64::from));
    bricks
        .iter()
        .filter_map(|id| {
            let b = grid.index_box(*id);
            let lo = DVec3::from(b.lo.map(f64::from)) * s;
            let hi = DVec3::from(b.hi.map(f64::from)) * s;
            camera.footprint(&frame, lo, hi)
        })
        .collect()
}

/// 8-bit straight-alpha RGBA of `image`, with the union of `tinted` mixed with the tint.
/// Tinted pixels become opaque over black, the page's background, so the tint shows on
/// empty space too and overlapping footprints do not darken each other.
#[must_use]
pub fn rgba8_with_tint(image: &Image, tinted: &[PixelRect]) -> Vec<u8> {
    let mut rgba = image.to_rgba8();
    if tinted.is_empty() {
        return rgba;
    }
    let (w, h) = (image.width() as usize, image.height() as usize);
    let mut mask = vec![false; w * h];
    for r in tinted {
        for y in r.y0 as usize..(r.y1 as usize).min(h) {
            mask[y * w + (r.x0 as usize).min(w)..y * w + (r.x1 as usize).min(w)].fill(true);
        }
    }
    for (px, src) in rgba
        .chunks_exact_mut(4)
        .zip(image.pixels())
        .zip(&mask)
        .filter(|(_, m)| **m)
        .map(|(p, _)| p)
    {
        // `src` is premultiplied, i.e. already the colour over black.
        for c in 0..3 {
            px[c] = to_u8(src[c] * (1.0 - TINT_ALPHA) + TINT[c] * TINT_ALPHA);
        }
        px[3] = 255;
    }
    rgba
}

/// Encodes 8-bit RGBA as PNG, favouring speed over size: the frame is shown once.
///
/// # Errors
/// A message when the buffer does not match the size (a bug) or encoding fails.
pub fn png(rgba: &[u8], width: u32, height: u32) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(rgba.len() / 4 + 1024);
    let mut enc = png::Encoder::new(&mut out, width, height);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let mut wr = enc.write_header().map_err(|e| format!("PNG header: {e}"))?;
    wr.write_image_data(rgba)
        .map_err(|e| format!("PNG data: {e}"))?;
    wr.finish().map_err(|e| format!("PNG end: {e}"))?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use pofvr::render::Projection;
    use pofvr::volume::phantom::Phantom;

    #[test]
    fn tint_covers_exactly_the_union_of_the_rectangles() {
        let img = Image::new(8, 4);
        let rects = [
            PixelRect {
                x0: 1,
                y0: 0,
                x1: 3,
                y1: 2,
            },
            PixelRect {
                x0: 2,
                y0: 1,
                x1: 8,
                y1: 3,
            },
        ];
        let out = rgba8_with_tint(&img, &rects);
        for y in 0..4u32 {
            for x in 0..8u32 {
                let inside = rects
                    .iter()
                    .any(|r| (r.x0..r.x1).contains(&x) && (r.y0..r.y1).contains(&y));
                let px = &out[((y * 8 + x) * 4) as usize..][..4];
                assert_eq!(px[3] == 255, inside, "pixel {x},{y}: {px:?}");
                if inside {
                    assert!(px[0] > 90 && px[1] == 0, "pixel {x},{y}: {px:?}");
                }
            }
        }
        assert_eq!(rgba8_with_tint(&img, &[]), img.to_rgba8());
    }

    #[test]
    fn a_corner_brick_footprint_lies_inside_the_frame_and_not_everywhere() {
        let vol = Phantom::SheppLogan.generate(32);
        let grid = BrickGrid::from_volume(&vol, 16).unwrap();
        let cam = Camera::orbit(&vol, 0.0, 0.0, 64, 64, Projection::Orthographic);
        let rects = footprints(&grid, vol.spacing(), &cam, &[BrickId(0)]);
        assert_eq!(rects.len(), 1);
        assert!(
            rects[0].area() > 0 && rects[0].area() < 64 * 64 / 2,
            "{:?}",
            rects[0]
        );
    }

    #[test]
    fn png_round_trips_the_size() {
        let bytes = png(&[7u8; 5 * 3 * 4], 5, 3).unwrap();
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let reader = dec.read_info().unwrap();
        assert_eq!((reader.info().width, reader.info().height), (5, 3));
        assert!(png(&[0u8; 3], 5, 3).is_err());
    }
}
