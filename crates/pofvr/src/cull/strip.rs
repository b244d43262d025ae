//! The strip culler: bricks are visited front to back over an opacity buffer of the tile,
//! in strips of rows culled in parallel; a brick is culled when every pixel its rays reach
//! is opaque enough already, and a visible brick adds what it composites at least (the
//! POF modes, [`super::fill`]) or really (the oracle, [`super::exact`]).

use std::time::Instant;

use rayon::prelude::*;

use super::fill::{BoundFill, BoundView};
use super::spans::PixelSpans;
use super::{exact, CullMode, CullScratch, FrameBricks, OpacityBound};
use crate::brick::{BrickGrid, BrickId};
use crate::render::{Camera, PixelRect, Projection, RayCaster};
use crate::volume::Volume;

/// What culling decided for one tile.
#[derive(Clone, Debug, Default)]
pub struct CullResult {
    /// Bricks overlapping the tile that must be rendered, front to back.
    pub visible: Vec<BrickId>,
    /// Bricks overlapping the tile that were culled.
    pub culled: Vec<BrickId>,
    /// Time spent, in milliseconds.
    pub cull_ms: f64,
}

/// Culls the bricks of one tile.
pub struct Culler<'a> {
    /// The volume (for rays and, in exact mode, samples).
    pub volume: &'a Volume,
    /// Its bricks.
    pub grid: &'a BrickGrid,
    /// The mode.
    pub mode: CullMode,
    /// Opacity at or above which a pixel hides what lies behind it.
    pub threshold: f32,
    /// Current basis weights.
    pub weights: &'a [f32],
    /// Precomputed bounds (POF modes).
    pub bounds: Option<&'a dyn OpacityBound>,
    /// The ray caster (exact mode renders bricks to learn their real opacity).
    pub caster: &'a RayCaster<'a>,
    /// Where the opacity buffers come from: kept by the caller from frame to frame.
    pub scratch: &'a CullScratch,
    /// Whether a brick whose own bound already lifts its whole rectangle to the threshold
    /// leaves out the bounds of its sub-bricks. Culling is the same either way (a pixel at
    /// the threshold stays there), so this is on but for tests that check just that.
    pub skip_sub_bricks: bool,
}

impl Culler<'_> {
    /// Culls the bricks of `bricks` whose footprints overlap `tile`, front to back.
    ///
    /// # Panics
    /// When a POF mode is asked for without bounds (a setup error the frame rejects first).
    #[must_use]
    pub fn cull(&self, camera: &Camera, bricks: &FrameBricks, tile: PixelRect) -> CullResult {
        let start = Instant::now();
        let strips = strips_of(tile, self.mode);
        let mine = bricks_over(bricks, tile, &strips);
        if strips.len() == 1 {
            let mut out = self.cull_strip(camera, tile, &mine[0]);
            out.cull_ms = start.elapsed().as_secs_f64() * 1e3;
            return out;
        }
        // Culling walks the bricks in order over one buffer, so it runs on one core; cut into
        // strips, each culled as a tile of its own (as the ranks' tiles are), it runs on all
        // of them. A brick is visible when it is in any strip, culled when in none.
        let parts: Vec<CullResult> = strips
            .par_iter()
            .zip(&mine)
            .map(|(s, m)| self.cull_strip(camera, *s, m))
            .collect();
        const CULLED: u8 = 1;
        const VISIBLE: u8 = 2;
        let mut state = vec![0u8; self.grid.len()];
        for p in &parts {
            for id in &p.culled {
                state[id.index()] = state[id.index()].max(CULLED);
            }
            for id in &p.visible {
                state[id.index()] = VISIBLE;
            }
        }
        let mut out = CullResult::default();
        for &id in &bricks.order {
            match state[id.index()] {
                VISIBLE => out.visible.push(id),
                CULLED => out.culled.push(id),
                _ => {}
            }
        }
        out.cull_ms = start.elapsed().as_secs_f64() * 1e3;
        out
    }

    /// [`Culler::cull`] over one strip of the tile, on this thread: `mine` are the bricks
    /// over it, in order, with their footprints in it.
    fn cull_strip(
        &self,
        camera: &Camera,
        tile: PixelRect,
        mine: &[(BrickId, PixelRect)],
    ) -> CullResult {
        let mut out = CullResult::default();
        // A verified frame culls through its predictor, not here: as without culling.
        if matches!(self.mode, CullMode::None | CullMode::Verified) {
            out.visible = mine.iter().map(|(id, _)| *id).collect();
            return out;
        }
        let frame = camera.frame();
        let tw = tile.width() as usize;
        let mut buffer = self.scratch.take(tile.area());
        let spans = PixelSpans::new(camera, &frame, self.volume);
        // What a visible brick adds to the buffer: its POF bounds, or (`None`, the oracle) the
        // opacity it composites, rendered.
        let mut fill = match self.mode {
            CullMode::None | CullMode::Verified => {
                unreachable!("every brick is visible without culling")
            }
            CullMode::Exact => None,
            CullMode::Pof | CullMode::PofSet => {
                let bounds = self.bounds.expect("POF culling needs POFs");
                let view = BoundView {
                    camera,
                    frame: &frame,
                    spans: &spans,
                    volume: self.volume,
                    weights: self.weights,
                    aggressive: self.mode == CullMode::PofSet,
                };
                Some(BoundFill::new(
                    bounds,
                    self.grid,
                    view,
                    self.threshold,
                    self.skip_sub_bricks,
                ))
            }
        };
        // The POF lookups read a few scattered lines of a large table, cold after the ray
        // casting of the previous frame: the next bricks' are asked for a batch ahead.
        // (Sub-brick bounds are looked up by other ids: they are prefetched per brick.)
        let prefetch = match (&fill, self.bounds) {
            (Some(fill), Some(b)) if fill.has_own() => {
                (camera.projection == Projection::Orthographic).then_some(b)
            }
            _ => None,
        };
        let ids: Vec<BrickId> = if prefetch.is_some() {
            mine.iter().map(|(id, _)| *id).collect()
        } else {
            Vec::new()
        };
        for (i, &(id, rect)) in mine.iter().enumerate() {
            if let Some(b) = prefetch.filter(|_| i % PREFETCH == 0) {
                if let Some(next) = ids.get(i + PREFETCH..) {
                    b.prefetch(&next[..next.len().min(PREFETCH)], frame.forward);
                }
            }
            // Occluded when every pixel whose ray meets the brick is opaque enough; the
            // cheap test over the whole rectangle settles most bricks, without the brick's
            // box.
            let mut ibox = None;
            let mut hit_region = None;
            let occluded = (rect.y0..rect.y1).all(|y| {
                let start = (y - tile.y0) as usize * tw + (rect.x0 - tile.x0) as usize;
                let row = &buffer[start..start + rect.width() as usize];
                // Only pixels below the threshold need the span test, and a culled brick has
                // none: a vectorised pass over the row settles most rows, and only a row with
                // such a pixel is looked at pixel by pixel, where its ray may meet the brick.
                if all_at_least(row, self.threshold) {
                    return true;
                }
                let ib = *ibox.get_or_insert_with(|| self.grid.index_box(id));
                let xs = hit_region
                    .get_or_insert_with(|| spans.region(&ib, None))
                    .as_ref()
                    .map_or(rect.x0..rect.x1, |r| r.candidates(y, (rect.x0, rect.x1)));
                let row = &row[(xs.start - rect.x0) as usize..(xs.end - rect.x0) as usize];
                !xs.zip(row)
                    .any(|(x, b)| *b < self.threshold && spans.hits(x, y, &ib))
            });
            if occluded {
                out.culled.push(id);
                continue;
            }
            let ibox = ibox.unwrap_or_else(|| self.grid.index_box(id));
            out.visible.push(id);
            match &mut fill {
                None => exact::add_rendered(
                    self.caster,
                    (camera, &frame),
                    &ibox,
                    rect,
                    (&mut buffer, tile),
                ),
                Some(fill) => fill.add((&mut buffer, tile), id, &ibox, rect),
            }
        }
        self.scratch.give(buffer);
        out
    }
}

/// Rows of the strips a tile is culled in, in parallel (POF modes): enough that a brick's
/// footprint seldom straddles two, few enough that a 512² frame keeps two cores busy. Fixed,
/// not one strip per thread, so that what is culled does not depend on the machine.
pub(super) const STRIP_ROWS: u32 = 64;

/// The strips `tile` is culled in: the whole tile for the modes that gain nothing (`none`)
/// or must stay sequential (`exact`, the oracle), and for small tiles.
pub(super) fn strips_of(tile: PixelRect, mode: CullMode) -> Vec<PixelRect> {
    if !matches!(mode, CullMode::Pof | CullMode::PofSet) || tile.height() < 2 * STRIP_ROWS {
        return vec![tile];
    }
    let n = tile.height().div_ceil(STRIP_ROWS);
    (0..n)
        .map(|k| PixelRect {
            y0: tile.y0 + k * tile.height() / n,
            y1: tile.y0 + (k + 1) * tile.height() / n,
            ..tile
        })
        .collect()
}

/// The bricks over each of `strips` (the rows of `tile`, in order), in visibility order,
/// with their footprint in the strip: one pass over the frame's bricks for all strips.
fn bricks_over(
    bricks: &FrameBricks,
    tile: PixelRect,
    strips: &[PixelRect],
) -> Vec<Vec<(BrickId, PixelRect)>> {
    let mut out = vec![Vec::new(); strips.len()];
    for &id in &bricks.order {
        let Some(rect) = bricks.footprints[id.index()].and_then(|r| r.intersect(&tile)) else {
            continue;
        };
        // The first strip the footprint reaches, then on while they overlap.
        let k0 = strips.partition_point(|s| s.y1 <= rect.y0);
        for (k, s) in strips.iter().enumerate().skip(k0) {
            match rect.intersect(s) {
                Some(r) => out[k].push((id, r)),
                None => break,
            }
        }
    }
    out
}

/// Bricks per prefetch batch, and how far ahead of the culling loop the batch is.
const PREFETCH: usize = 16;

/// True when every value of `row` is at least `threshold`: in blocks of eight without an
/// early exit, which compile to vector compares, the tail as one more (overlapping) block.
#[inline]
pub(super) fn all_at_least(row: &[f32], threshold: f32) -> bool {
    let block = |c: &[f32]| c.iter().fold(true, |all, b| all & (*b >= threshold));
    if row.len() < 8 {
        return block(row);
    }
    row.chunks_exact(8).fold(true, |all, c| all & block(c)) & block(&row[row.len() - 8..])
}
