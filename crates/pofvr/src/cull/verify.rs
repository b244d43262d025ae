//! Verification: a tile owner blends its fragments front to back and, at every culled
//! brick over its tile, tests that the opacity blended so far has reached the threshold at
//! every pixel of the tile whose ray meets the brick. A brick that fails is repaired
//! (rendered and blended in) by the frame.
//!
//! Why this makes the threshold rule hold whatever the prediction: opacity blended front
//! to back only grows as fragments are added, and a brick passes only where what lies in
//! front of it along every ray (bricks of smaller depth key, by the visibility order) is
//! already at the threshold with a subset of the bricks that end up rendered. So the pixels
//! a culled brick could change are at least that opaque in the final frame, and it could
//! change them by at most 1 − threshold; no pixel below the threshold is touched.

use crate::brick::{BrickGrid, BrickId};
use crate::composite::{SparseTile, TileFragment};
use crate::render::{Camera, PixelRect};
use crate::volume::Volume;

use super::spans::PixelSpans;
use super::strip::all_at_least;
use super::FrameBricks;

/// A fragment as verification reads it: its key and what it blends into an opacity
/// buffer.
pub trait AlphaLayer {
    /// The fragment's brick.
    fn brick(&self) -> BrickId;
    /// Front-to-back key: the brick's position in the visibility order.
    fn depth_key(&self) -> i64;
    /// Blends the fragment's opacity behind `alpha`, the opacity of the pixels of `tile`
    /// (row-major), with the blend of [`crate::composite::over`] (its alpha channel).
    fn blend_alpha(&self, alpha: &mut [f32], tile: PixelRect);
}

impl AlphaLayer for TileFragment {
    fn brick(&self) -> BrickId {
        self.brick
    }
    fn depth_key(&self) -> i64 {
        self.depth_key
    }
    fn blend_alpha(&self, alpha: &mut [f32], tile: PixelRect) {
        let Some(r) = self.rect.intersect(&tile) else {
            return;
        };
        let (fw, tw) = (self.rect.width() as usize, tile.width() as usize);
        for y in r.y0..r.y1 {
            let src = &self.pixels[(y - self.rect.y0) as usize * fw..]
                [(r.x0 - self.rect.x0) as usize..][..r.width() as usize];
            let dst = &mut alpha[(y - tile.y0) as usize * tw..][(r.x0 - tile.x0) as usize..]
                [..r.width() as usize];
            for (d, s) in dst.iter_mut().zip(src) {
                *d += (1.0 - *d) * s[3];
            }
        }
    }
}

impl AlphaLayer for SparseTile {
    fn brick(&self) -> BrickId {
        SparseTile::brick(self)
    }
    fn depth_key(&self) -> i64 {
        SparseTile::depth_key(self)
    }
    fn blend_alpha(&self, alpha: &mut [f32], tile: PixelRect) {
        self.blend_alpha_into(alpha, tile);
    }
}

/// What verification found in one tile.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Verdict {
    /// Culled bricks that are not hidden: they must be repaired.
    pub failing: Vec<BrickId>,
    /// Rendered bricks not hidden by what lies in front of them in this tile: the bricks
    /// the frame needed here (the previous-frame predictor's set).
    pub needed: Vec<BrickId>,
}

/// The frame's geometry verification reads.
pub struct VerifyView<'a> {
    /// The camera.
    pub camera: &'a Camera,
    /// The volume (rays in index space).
    pub volume: &'a Volume,
    /// Its bricks.
    pub grid: &'a BrickGrid,
    /// The frame's bricks: footprints and depth keys.
    pub bricks: &'a FrameBricks,
}

/// Verifies `culled` (bricks over `tile` that were not rendered) against `layers`, this
/// tile's fragments, at `threshold`: walks the fragments front to back, blending their
/// opacity, and tests each culled brick (and each rendered one, for
/// [`Verdict::needed`]) at its place in the order.
#[must_use]
pub fn verify_tile<L: AlphaLayer>(
    view: &VerifyView<'_>,
    tile: PixelRect,
    layers: &[L],
    culled: &[BrickId],
    threshold: f32,
) -> Verdict {
    let mut out = Verdict::default();
    if tile.area() == 0 {
        return out;
    }
    let frame = view.camera.frame();
    let spans = PixelSpans::new(view.camera, &frame, view.volume);
    let key = |b: BrickId| view.bricks.depth_key[b.index()];
    let mut layers: Vec<&L> = layers.iter().collect();
    layers.sort_unstable_by_key(|l| (l.depth_key(), l.brick()));
    let mut culled: Vec<BrickId> = culled.to_vec();
    culled.sort_unstable_by_key(|b| (key(*b), *b));
    let mut alpha = vec![0f32; tile.area()];
    let hidden = |alpha: &[f32], b: BrickId| -> bool {
        let Some(rect) = view.bricks.footprints[b.index()].and_then(|r| r.intersect(&tile)) else {
            return true;
        };
        occluded(&spans, view.grid, (alpha, tile), b, rect, threshold)
    };
    let mut next = culled.iter().peekable();
    for l in layers {
        while let Some(&&c) = next.peek() {
            if key(c) >= l.depth_key() {
                break;
            }
            if !hidden(&alpha, c) {
                out.failing.push(c);
            }
            next.next();
        }
        if !hidden(&alpha, l.brick()) {
            out.needed.push(l.brick());
        }
        l.blend_alpha(&mut alpha, tile);
    }
    for &c in next {
        if !hidden(&alpha, c) {
            out.failing.push(c);
        }
    }
    out
}

/// True when every pixel of `rect` (inside the tile of `buffer`) whose ray may meet brick
/// `id` is at least `threshold` opaque: the test the strip culler makes, on blended opacity.
fn occluded(
    spans: &PixelSpans<'_>,
    grid: &BrickGrid,
    (buffer, tile): (&[f32], PixelRect),
    id: BrickId,
    rect: PixelRect,
    threshold: f32,
) -> bool {
    let tw = tile.width() as usize;
    let mut ibox = None;
    let mut region = None;
    (rect.y0..rect.y1).all(|y| {
        let start = (y - tile.y0) as usize * tw + (rect.x0 - tile.x0) as usize;
        let row = &buffer[start..start + rect.width() as usize];
        if all_at_least(row, threshold) {
            return true;
        }
        let ib = *ibox.get_or_insert_with(|| grid.index_box(id));
        let xs = region
            .get_or_insert_with(|| spans.region(&ib, None))
            .as_ref()
            .map_or(rect.x0..rect.x1, |r| r.candidates(y, (rect.x0, rect.x1)));
        let row = &row[(xs.start - rect.x0) as usize..(xs.end - rect.x0) as usize];
        !xs.zip(row)
            .any(|(x, b)| *b < threshold && spans.hits(x, y, &ib))
    })
}
