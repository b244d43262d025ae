//! Stage 4: per-frame visibility culling of bricks (paper §3.3).
//!
//! Bricks are visited in a visibility order valid for every ray; an opacity buffer over the
//! tile accumulates a *lower bound* of what the bricks in front composite. A brick whose
//! footprint already reads ≥ the threshold at every pixel its rays reach is culled: the
//! pixels it could change are at least that opaque, so it changes them by at most
//! 1 − threshold. A visible brick adds its bound over its *core* footprint only (pixels whose
//! ray runs at least the bound's core length inside it), which is where the bound holds.

pub mod ideal;
pub mod range_bound;
#[cfg(test)]
mod test;

use std::time::Instant;

use glam::DVec3;
use rayon::prelude::*;

use crate::brick::{BrickGrid, BrickId};
use crate::render::{Camera, IndexRay, PixelRect, Projection, RayCaster, SampledTf, ViewFrame};
use crate::volume::Volume;

/// How bricks are culled.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CullMode {
    /// No culling: every non-empty brick is rendered.
    None,
    /// Conservative POF culling (Eq. 3 over the per-basis POFs).
    Pof,
    /// Aggressive POF-set culling (§3.2.2): the opacity at each basis's `q_min` pixel,
    /// which the paper calls "very likely" the block's opacity. An estimate, not a bound:
    /// where every basis is thin at some other pixel of the footprint it overestimates, and
    /// a few pixels may then break the threshold rule (seen on real data).
    PofSet,
    /// The sequential oracle: bricks are rendered front to back and tested against the
    /// opacity actually composited. Exists to measure how close POF culling gets.
    Exact,
}

impl CullMode {
    /// The flag spelling.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            CullMode::None => "none",
            CullMode::Pof => "pof",
            CullMode::PofSet => "pof-set",
            CullMode::Exact => "exact",
        }
    }

    /// True when the mode reads precomputed POFs.
    #[must_use]
    pub fn needs_pofs(self) -> bool {
        matches!(self, CullMode::Pof | CullMode::PofSet)
    }
}

impl std::str::FromStr for CullMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "none" => Ok(CullMode::None),
            "pof" => Ok(CullMode::Pof),
            "pof-set" | "pofset" | "pof_set" => Ok(CullMode::PofSet),
            "exact" => Ok(CullMode::Exact),
            other => Err(format!(
                "unknown cull mode {other:?}, expected none, pof, pof-set or exact"
            )),
        }
    }
}

/// A lower bound of a brick's composited opacity over its core footprint: what culling
/// needs of precomputed POFs.
pub trait OpacityBound: Sync {
    /// Minimum `t`-span (in units of the smallest spacing) of a ray inside a brick for the
    /// bound to hold on that ray.
    fn core_length(&self) -> f32;
    /// Bound for parallel rays of unit world direction `dir`.
    fn opacity(&self, brick: BrickId, dir: DVec3, weights: &[f32], aggressive: bool) -> f32;
    /// Bound for every ray whose direction lies within `half_angle` of `axis`.
    fn opacity_cone(
        &self,
        brick: BrickId,
        axis: DVec3,
        half_angle: f64,
        weights: &[f32],
        aggressive: bool,
    ) -> f32;
    /// A hint that [`OpacityBound::opacity`] will soon be asked for each of `bricks` along
    /// `dir`: an implementation may start loading what those lookups read.
    fn prefetch(&self, _bricks: &[BrickId], _dir: DVec3) {}
    /// A bound for rays that run further inside each brick (a longer
    /// [`OpacityBound::core_length`]), tighter where it applies; `None` when there is none.
    fn deeper(&self) -> Option<&dyn OpacityBound> {
        None
    }
    /// The grid of the bricks the bounds are for, when finer than the render bricks (each
    /// render brick then gets the bounds of its sub-bricks); `None` when they are the render
    /// bricks.
    fn grid(&self) -> Option<&BrickGrid> {
        None
    }
    /// Bounds for the sub-bricks of the render bricks (their [`OpacityBound::grid`] says
    /// which), used together with these: each pixel gets the higher of the two.
    fn sub_bricks(&self) -> Option<&dyn OpacityBound> {
        None
    }
    /// The early-termination threshold of the renderer the bounds are for: a render brick
    /// stops compositing there, so what its sub-bricks' bounds add up to is capped at it.
    fn ert(&self) -> f32 {
        1.0
    }
}

/// POF tables of one family built with different core lengths, shortest first: each pixel
/// of a brick's footprint gets the bound of the longest core its ray runs through.
///
/// Why: a POF holds for every ray running at least `L` inside the brick, so its value is
/// that of the shortest such rays; in oblique views most rays run much longer, and a table
/// built for a longer `L` bounds them far more tightly, over a smaller core.
pub struct CoreLevels {
    first: crate::pof::PofTable,
    rest: Option<Box<CoreLevels>>,
    /// The tables' brick grid when finer than the render bricks ([`OpacityBound::grid`]).
    fine: Option<BrickGrid>,
    /// Levels for sub-bricks, beside these ([`OpacityBound::sub_bricks`]).
    sub: Option<Box<CoreLevels>>,
}

impl CoreLevels {
    /// Orders `tables` by core length; `None` when there is none.
    ///
    /// # Errors
    /// A message naming two tables with the same core length.
    pub fn new(mut tables: Vec<crate::pof::PofTable>) -> Result<Option<Self>, String> {
        tables.sort_by(|a, b| a.core_length().total_cmp(&b.core_length()));
        if let Some(w) = tables
            .windows(2)
            .find(|w| w[0].core_length() == w[1].core_length())
        {
            return Err(format!(
                "two POF files with core length {}: each --pof-level needs its own --core-length",
                w[0].core_length()
            ));
        }
        let mut levels: Option<CoreLevels> = None;
        while let Some(t) = tables.pop() {
            levels = Some(CoreLevels {
                first: t,
                rest: levels.map(Box::new),
                fine: None,
                sub: None,
            });
        }
        Ok(levels)
    }

    /// Declares the tables to be for `fine`, a grid of sub-bricks of the render bricks
    /// (built with a brick size dividing theirs): culling then composites, over each
    /// visible brick, the bounds of its sub-bricks.
    ///
    /// Why: a POF is a minimum over a brick's footprint, so one transparent corner of a
    /// brick (the edge of a skull-stripping mask) zeroes it; sub-bricks confine that loss
    /// to the corner, while rendering keeps the larger bricks.
    #[must_use]
    pub fn with_grid(mut self, fine: BrickGrid) -> Self {
        self.fine = Some(fine);
        self
    }

    /// Adds `sub`, levels for sub-bricks (made [`CoreLevels::with_grid`]), to these levels
    /// of the render bricks: culling takes the higher of the two bounds at each pixel.
    #[must_use]
    pub fn with_sub_bricks(mut self, sub: CoreLevels) -> Self {
        self.sub = Some(Box::new(sub));
        self
    }

    /// The levels for sub-bricks, if any.
    #[must_use]
    pub fn sub_levels(&self) -> Option<&CoreLevels> {
        self.sub.as_deref()
    }

    /// The table with the shortest core (the others differ only in their core length).
    #[must_use]
    pub fn first(&self) -> &crate::pof::PofTable {
        &self.first
    }

    /// Whether every level holds POF sets (for `--cull pof-set`).
    #[must_use]
    pub fn has_sets(&self) -> bool {
        self.first.has_sets() && self.rest.as_ref().is_none_or(|r| r.has_sets())
    }

    /// The core lengths, shortest first.
    #[must_use]
    pub fn core_lengths(&self) -> Vec<f32> {
        let mut v = vec![self.first.core_length()];
        if let Some(r) = &self.rest {
            v.extend(r.core_lengths());
        }
        v
    }
}

/// One table is one level.
impl From<crate::pof::PofTable> for CoreLevels {
    fn from(first: crate::pof::PofTable) -> Self {
        CoreLevels {
            first,
            rest: None,
            fine: None,
            sub: None,
        }
    }
}

impl OpacityBound for CoreLevels {
    fn core_length(&self) -> f32 {
        self.first.core_length()
    }
    fn opacity(&self, brick: BrickId, dir: DVec3, weights: &[f32], aggressive: bool) -> f32 {
        OpacityBound::opacity(&self.first, brick, dir, weights, aggressive)
    }
    fn opacity_cone(
        &self,
        brick: BrickId,
        axis: DVec3,
        half_angle: f64,
        weights: &[f32],
        aggressive: bool,
    ) -> f32 {
        OpacityBound::opacity_cone(&self.first, brick, axis, half_angle, weights, aggressive)
    }
    fn prefetch(&self, bricks: &[BrickId], dir: DVec3) {
        OpacityBound::prefetch(&self.first, bricks, dir);
        if let Some(r) = &self.rest {
            r.prefetch(bricks, dir);
        }
    }
    fn deeper(&self) -> Option<&dyn OpacityBound> {
        self.rest.as_deref().map(|r| r as &dyn OpacityBound)
    }
    fn grid(&self) -> Option<&BrickGrid> {
        self.fine.as_ref()
    }
    fn sub_bricks(&self) -> Option<&dyn OpacityBound> {
        self.sub.as_deref().map(|s| s as &dyn OpacityBound)
    }
    fn ert(&self) -> f32 {
        self.first.ert()
    }
}

/// Per-frame geometry of the bricks: which are empty, their footprints and a visibility
/// order. Shared by every rank of a frame.
pub struct FrameBricks {
    /// Non-empty bricks in a front-to-back order valid for every ray.
    pub order: Vec<BrickId>,
    /// Footprint (clipped to the image) of each brick by id; `None` when empty or off-screen.
    pub footprints: Vec<Option<PixelRect>>,
    /// Number of bricks empty for the current weights.
    pub empty: usize,
    /// Depth key of each brick by id (its position in `order`).
    pub depth_key: Vec<i64>,
    /// The union of the footprints: the image bounding box of what can be drawn.
    pub bounds: Option<PixelRect>,
}

impl FrameBricks {
    /// Finds the non-empty bricks, their footprints and a visibility order.
    ///
    /// The order key is a brick-grid distance that grows by one at every face a ray
    /// crosses: Σₐ sₐ·iₐ for parallel rays (sₐ the sign of the direction) and
    /// Σₐ |iₐ − eₐ| from the eye's brick cell for perspective. Along any ray the key is
    /// strictly increasing, so sorting by it is front to back for every ray at once.
    #[must_use]
    pub fn new(
        volume: &Volume,
        grid: &BrickGrid,
        sampled: &SampledTf,
        weights: &[f32],
        camera: &Camera,
    ) -> Self {
        let frame = camera.frame();
        let spacing = DVec3::from(volume.spacing().map(f64::from));
        let b = grid.brick_size() as f64;
        let eye_cell = (DVec3::from(camera.position) / spacing / b).floor();
        let mut keyed = Vec::new();
        let mut footprints = vec![None; grid.len()];
        let mut empty = 0;
        for id in grid.ids() {
            if sampled.is_empty(grid.range(id), weights) {
                empty += 1;
                continue;
            }
            let ib = grid.index_box(id);
            let lo = DVec3::from(ib.lo.map(f64::from)) * spacing;
            let hi = DVec3::from(ib.hi.map(f64::from)) * spacing;
            let Some(rect) = camera.footprint(&frame, lo, hi) else {
                continue;
            };
            footprints[id.index()] = Some(rect);
            #[allow(clippy::cast_possible_wrap, clippy::cast_possible_truncation)]
            let c = grid.coords(id).map(|x| x as i64);
            #[allow(clippy::cast_possible_truncation)]
            let key = match camera.projection {
                Projection::Orthographic => {
                    let s = [frame.forward.x, frame.forward.y, frame.forward.z].map(|x| {
                        if x > 0.0 {
                            1
                        } else if x < 0.0 {
                            -1
                        } else {
                            0
                        }
                    });
                    s[0] * c[0] + s[1] * c[1] + s[2] * c[2]
                }
                Projection::Perspective => {
                    let e = [eye_cell.x as i64, eye_cell.y as i64, eye_cell.z as i64];
                    (c[0] - e[0]).abs() + (c[1] - e[1]).abs() + (c[2] - e[2]).abs()
                }
            };
            keyed.push((key, id));
        }
        keyed.sort_unstable();
        let order: Vec<BrickId> = keyed.into_iter().map(|(_, id)| id).collect();
        let mut depth_key = vec![i64::MAX; grid.len()];
        for (i, id) in order.iter().enumerate() {
            #[allow(clippy::cast_possible_wrap)]
            {
                depth_key[id.index()] = i as i64;
            }
        }
        let bounds = footprints
            .iter()
            .flatten()
            .copied()
            .reduce(|a: PixelRect, b| PixelRect {
                x0: a.x0.min(b.x0),
                y0: a.y0.min(b.y0),
                x1: a.x1.max(b.x1),
                y1: a.y1.max(b.y1),
            });
        FrameBricks {
            order,
            footprints,
            empty,
            depth_key,
            bounds,
        }
    }
}

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
        let frame = camera.frame();
        let tw = tile.width() as usize;
        // A frame's buffer is megabytes; a fresh allocation each frame would be fresh pages,
        // each faulted in on first touch. Buffers are kept (one per concurrent culler:
        // ranks may be threads that live for one frame) and cleared instead.
        let mut buffer = BUFFERS
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .pop()
            .unwrap_or_default();
        buffer.clear();
        buffer.resize(tile.area(), 0.0);
        let mut out = CullResult::default();
        let spans = PixelSpans::new(camera, &frame, self.volume);
        // The POF levels of the render bricks and of their sub-bricks.
        let (own, sub) = match self.bounds {
            Some(b) if matches!(self.mode, CullMode::Pof | CullMode::PofSet) => {
                if b.grid().is_some() {
                    (Levels::default(), Levels::chain(Some(b)))
                } else {
                    (Levels::chain(Some(b)), Levels::chain(b.sub_bricks()))
                }
            }
            _ => (Levels::default(), Levels::default()),
        };
        let fine = sub.bounds.first().and_then(|b| b.grid());
        let view = View {
            camera,
            frame: &frame,
            spans: &spans,
            aggressive: self.mode == CullMode::PofSet,
        };
        let (mut scratch, mut own_t): (Vec<f32>, Vec<f32>) = (Vec::new(), Vec::new());
        let (mut subs, mut sub_ids) = (Vec::new(), Vec::new());
        let ortho = camera.projection == Projection::Orthographic;
        // (Sub-brick bounds are looked up by other ids: they are prefetched per brick.)
        let prefetch = !own.bounds.is_empty() && ortho;
        let ids: Vec<BrickId> = if prefetch {
            mine.iter().map(|(id, _)| *id).collect()
        } else {
            Vec::new()
        };
        for (i, &(id, rect)) in mine.iter().enumerate() {
            // The POF lookups read a few scattered lines of a large table, cold after the
            // ray casting of the previous frame: ask for the next bricks' a batch ahead.
            if prefetch && i % PREFETCH == 0 {
                if let (Some(b), Some(next)) = (self.bounds, ids.get(i + PREFETCH..)) {
                    b.prefetch(&next[..next.len().min(PREFETCH)], frame.forward);
                }
            }
            if self.mode == CullMode::None {
                out.visible.push(id);
                continue;
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
            match self.mode {
                CullMode::None => {}
                CullMode::Exact => {
                    let (frag, _) = self.caster.render_box(camera, &frame, rect, &ibox);
                    let rw = rect.width() as usize;
                    for (i, p) in frag.iter().enumerate() {
                        #[allow(clippy::cast_possible_truncation)]
                        let (x, y) = (rect.x0 + (i % rw) as u32, rect.y0 + (i / rw) as u32);
                        let b = &mut buffer[(y - tile.y0) as usize * tw + (x - tile.x0) as usize];
                        *b += (1.0 - *b) * p[3];
                    }
                }
                CullMode::Pof | CullMode::PofSet => {
                    let bounds = self.bounds.expect("POF culling needs POFs");
                    let Some(fine) = fine else {
                        // The bounds are per render brick: straight into the buffer.
                        let mut into = Sink::Buffer {
                            buffer: &mut buffer,
                            tile,
                        };
                        self.composite_bound(&own, &view, id, &ibox, rect, &mut into);
                        continue;
                    };
                    // The bounds are per sub-brick: each bounds its own stretch of a ray, and
                    // the stretches are disjoint, so their transparencies multiply. The
                    // brick stops marching at the early-termination threshold, so what it
                    // adds is capped there.
                    let cap = bounds.ert();
                    let rw = rect.width() as usize;
                    let at = |r: usize| {
                        (rect.y0 - tile.y0) as usize * tw + r * tw + (rect.x0 - tile.x0) as usize
                    };
                    // The brick's own bound first: where it alone lifts every pixel of the
                    // rectangle to the threshold, the sub-bricks cannot change what is culled
                    // (a pixel at the threshold stays there), and their eight lookups and
                    // composites, most of the culling time, are saved.
                    self.grid.sub_bricks_into(id, fine, &mut subs);
                    if ortho {
                        // Each lookup is a cache miss in a table of many megabytes: start
                        // them all now, to arrive while the brick's own bound is composited.
                        sub_ids.clear();
                        sub_ids.extend(subs.iter().map(|(cid, _)| *cid));
                        sub.bounds[0].prefetch(&sub_ids, frame.forward);
                    }
                    let has_own = !own.bounds.is_empty();
                    if has_own {
                        own_t.clear();
                        own_t.resize(rect.area(), 1.0);
                        let mut into = Sink::Transparency {
                            t: &mut own_t,
                            rect,
                        };
                        self.composite_bound(&own, &view, id, &ibox, rect, &mut into);
                        let enough = own_t.chunks_exact(rw).enumerate().all(|(r, ts)| {
                            let start = at(r);
                            buffer[start..start + rw]
                                .iter()
                                .zip(ts)
                                .all(|(b, t)| b + (1.0 - b) * (1.0 - t).min(cap) >= self.threshold)
                        });
                        if enough && may_skip_sub_bricks() {
                            flush(&mut buffer, &own_t, None, rw, cap, at);
                            continue;
                        }
                    }
                    scratch.clear();
                    scratch.resize(rect.area(), 1.0);
                    let mut into = Sink::Transparency {
                        t: &mut scratch,
                        rect,
                    };
                    for (cid, cbox) in &subs {
                        self.composite_bound(&sub, &view, *cid, cbox, rect, &mut into);
                    }
                    // The brick's own bound, where higher, bounds the same stretch of ray.
                    let own_t = has_own.then_some(own_t.as_slice());
                    flush(&mut buffer, &scratch, own_t, rw, cap, at);
                }
            }
        }
        let mut pool = BUFFERS
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        // As many as cullers ran at once (ranks as threads), within reason.
        if pool.len() < 64 {
            pool.push(buffer);
        }
        drop(pool);
        out
    }

    /// Adds the bound of brick `id` (of the bounds' grid, with index box `ibox`) to `into`
    /// over `rect`: per level (core length), the level's bound over the pixels of that
    /// level's core.
    fn composite_bound(
        &self,
        levels: &Levels<'_>,
        view: &View<'_>,
        id: BrickId,
        ibox: &crate::brick::IndexBox,
        rect: PixelRect,
        into: &mut Sink<'_>,
    ) {
        let View {
            camera,
            frame,
            spans,
            aggressive,
        } = *view;
        let (cores, levels) = (&levels.cores, &levels.bounds);
        // A longer core's pixels are in every shorter one's too.
        let mut alphas = [0f32; MAX_LEVELS];
        let mut any = false;
        for (k, level) in levels.iter().enumerate() {
            let a = self.brick_bound(*level, camera, frame, id, ibox, aggressive);
            alphas[k] = if k == 0 { a } else { a.max(alphas[k - 1]) };
            any |= alphas[k] > 0.0;
        }
        if !any {
            return;
        }
        // Orthographic: each core's pixels are a convex region, solved once per brick; its
        // runs are nested in the shorter cores' runs: fill each ring between two runs with
        // its level's bound. (A ray's length inside a box is concave in the pixel position,
        // so a row of a core is one run: `each_row_of_a_core_footprint_is_one_run`.)
        let mut regions: [Option<Region>; MAX_LEVELS] = [None; MAX_LEVELS];
        for (k, r) in regions.iter_mut().enumerate().take(levels.len()) {
            *r = spans.region(ibox, Some(cores[k]));
        }
        // A sub-brick covers a few rows of its brick's rectangle: only those can hold its
        // cores.
        let (y0, y1) = spans.rows_of(ibox).map_or((rect.y0, rect.y1), |(a, b)| {
            (a.max(rect.y0), b.min(rect.y1))
        });
        for y in y0..y1 {
            if regions[0].is_none() {
                // Perspective: the deepest level whose core holds each pixel.
                for x in rect.x0..rect.x1 {
                    let in_core = |k: &usize| spans.in_core(x, y, ibox, cores[*k]);
                    let Some(k) = (0..levels.len()).take_while(in_core).last() else {
                        continue;
                    };
                    into.add(x..x + 1, y, alphas[k]);
                }
                continue;
            }
            let mut runs: [Option<(u32, u32)>; MAX_LEVELS] = [None; MAX_LEVELS];
            let mut outer = (rect.x0, rect.x1);
            for (k, region) in regions.iter().take(levels.len()).enumerate() {
                let xs = region.as_ref().map_or(0..0, |r| r.run(y, outer));
                if xs.is_empty() {
                    break;
                }
                runs[k] = Some((xs.start, xs.end));
                outer = (xs.start, xs.end);
            }
            for k in 0..levels.len() {
                let Some((x0, x1)) = runs[k] else { break };
                match runs.get(k + 1).copied().flatten() {
                    Some((i0, i1)) => {
                        into.add(x0..i0, y, alphas[k]);
                        into.add(i1..x1, y, alphas[k]);
                    }
                    None => into.add(x0..x1, y, alphas[k]),
                }
            }
        }
    }

    fn brick_bound(
        &self,
        bounds: &dyn OpacityBound,
        camera: &Camera,
        frame: &ViewFrame,
        id: BrickId,
        ib: &crate::brick::IndexBox,
        aggressive: bool,
    ) -> f32 {
        match camera.projection {
            Projection::Orthographic => bounds.opacity(id, frame.forward, self.weights, aggressive),
            Projection::Perspective => {
                let s = DVec3::from(self.volume.spacing().map(f64::from));
                let lo = DVec3::from(ib.lo.map(f64::from)) * s;
                let hi = DVec3::from(ib.hi.map(f64::from)) * s;
                let centre = (lo + hi) * 0.5;
                let radius = (hi - lo).length() * 0.5;
                let to = centre - DVec3::from(camera.position);
                let dist = to.length();
                if dist <= radius {
                    // The eye is inside the brick's bounding sphere: rays come from anywhere.
                    return bounds.opacity_cone(
                        id,
                        frame.forward,
                        std::f64::consts::PI,
                        self.weights,
                        aggressive,
                    );
                }
                bounds.opacity_cone(
                    id,
                    to / dist,
                    (radius / dist).asin(),
                    self.weights,
                    aggressive,
                )
            }
        }
    }
}

/// A chain of POF levels, shortest core first, with their core lengths.
#[derive(Default)]
struct Levels<'a> {
    bounds: Vec<&'a dyn OpacityBound>,
    cores: Vec<f32>,
}

impl<'a> Levels<'a> {
    /// `first` and the deeper levels after it, at most [`MAX_LEVELS`].
    fn chain(first: Option<&'a dyn OpacityBound>) -> Self {
        let mut bounds: Vec<&dyn OpacityBound> = Vec::new();
        let mut next = first;
        while let Some(b) = next {
            if bounds.len() == MAX_LEVELS {
                break;
            }
            bounds.push(b);
            next = b.deeper();
        }
        let cores = bounds.iter().map(|l| l.core_length()).collect();
        Levels { bounds, cores }
    }
}

/// What every bound composited in one cull shares: the view and the lookup mode.
#[derive(Clone, Copy)]
struct View<'v> {
    camera: &'v Camera,
    frame: &'v ViewFrame,
    spans: &'v PixelSpans<'v>,
    aggressive: bool,
}

/// Where [`Culler::composite_bound`] adds opacity.
enum Sink<'b> {
    /// The tile's opacity buffer.
    Buffer {
        buffer: &'b mut [f32],
        tile: PixelRect,
    },
    /// A transparency image over `rect` (sub-brick bounds of one brick, multiplied).
    Transparency { t: &'b mut [f32], rect: PixelRect },
}

impl Sink<'_> {
    /// Composites opacity `a` over pixels `xs` of row `y`.
    fn add(&mut self, xs: std::ops::Range<u32>, y: u32, a: f32) {
        if xs.is_empty() {
            return;
        }
        match self {
            Sink::Buffer { buffer, tile } => {
                let row = (y - tile.y0) as usize * tile.width() as usize;
                let run = row + (xs.start - tile.x0) as usize..row + (xs.end - tile.x0) as usize;
                for b in &mut buffer[run] {
                    *b += (1.0 - *b) * a;
                }
            }
            Sink::Transparency { t, rect } => {
                let row = (y - rect.y0) as usize * rect.width() as usize;
                let run = row + (xs.start - rect.x0) as usize..row + (xs.end - rect.x0) as usize;
                for v in &mut t[run] {
                    *v *= 1.0 - a;
                }
            }
        }
    }
}

/// Whether culling may leave out the sub-bricks of a brick whose own bound suffices; tests
/// turn it off to check that doing so changes nothing.
#[cfg(test)]
pub(crate) static SKIP_SUB_BRICKS: std::sync::atomic::AtomicBool =
    std::sync::atomic::AtomicBool::new(true);

#[inline]
fn may_skip_sub_bricks() -> bool {
    #[cfg(test)]
    return SKIP_SUB_BRICKS.load(std::sync::atomic::Ordering::Relaxed);
    #[cfg(not(test))]
    true
}

/// Composites a brick's transparency image `t` (rows of `rw` pixels; row `r` at `at(r)` in
/// `buffer`), or where lower the image `lower` of the same stretch of ray, into the opacity
/// buffer, each pixel's opacity capped at `cap`.
fn flush(
    buffer: &mut [f32],
    t: &[f32],
    lower: Option<&[f32]>,
    rw: usize,
    cap: f32,
    at: impl Fn(usize) -> usize,
) {
    for (r, ts) in t.chunks_exact(rw).enumerate() {
        let start = at(r);
        let row = &mut buffer[start..start + rw];
        match lower {
            Some(l) => {
                for ((b, t), o) in row.iter_mut().zip(ts).zip(&l[r * rw..(r + 1) * rw]) {
                    *b += (1.0 - *b) * (1.0 - t.min(*o)).min(cap);
                }
            }
            None => {
                for (b, t) in row.iter_mut().zip(ts) {
                    *b += (1.0 - *b) * (1.0 - t).min(cap);
                }
            }
        }
    }
}

/// Rows of the strips a tile is culled in, in parallel (POF modes): enough that a brick's
/// footprint seldom straddles two, few enough that a 512² frame keeps two cores busy. Fixed,
/// not one strip per thread, so that what is culled does not depend on the machine.
const STRIP_ROWS: u32 = 64;

/// The strips `tile` is culled in: the whole tile for the modes that gain nothing (`none`)
/// or must stay sequential (`exact`, the oracle), and for small tiles.
fn strips_of(tile: PixelRect, mode: CullMode) -> Vec<PixelRect> {
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

/// The most POF levels (core lengths) culling uses.
const MAX_LEVELS: usize = 8;

/// Bricks per prefetch batch, and how far ahead of the culling loop the batch is.
const PREFETCH: usize = 16;

/// Opacity buffers [`Culler::cull`] reuses.
static BUFFERS: std::sync::Mutex<Vec<Vec<f32>>> = std::sync::Mutex::new(Vec::new());

/// A convex region of the image, `c0 + cy·y + cx·x ≥ 0` for each of its half-planes, with
/// pixel centres at integer `(x, y)` (see [`PixelSpans::region`]). Kept as what a row
/// needs: the left bounds `x ≥ p + q·y`, the right bounds `x ≤ p + q·y` and the rows.
#[derive(Clone, Copy)]
struct Region {
    /// The left bounds first, the right bounds from the end: a region has at most
    /// [`MAX_PLANES`] of both together, and it is copied about, so it is kept small.
    lines: [(f64, f64); MAX_PLANES],
    n_left: usize,
    n_right: usize,
    /// Rows `y_lo ≤ y ≤ y_hi` (from the half-planes that do not depend on x).
    y_lo: f64,
    y_hi: f64,
    /// False when a coefficient is not finite (which finite cameras never cause): every
    /// run is then empty and every row a candidate, both safe.
    finite: bool,
}

/// The most half-planes of a region that depend on x: three far-plane bounds and six
/// far-after-near pairs of three slabs (with a slab parallel to the rays, fewer: its two
/// bounds replace four pairs).
const MAX_PLANES: usize = 9;

/// How far inside its bounds a pixel must be to count as surely in a [`Region`], in pixels:
/// far above the rounding of the solve (about 1e-12 of the coordinates), far below a pixel.
const REGION_MARGIN: f64 = 1e-6;

impl Region {
    fn new() -> Self {
        Region {
            lines: [(0.0, 0.0); MAX_PLANES],
            n_left: 0,
            n_right: 0,
            y_lo: f64::NEG_INFINITY,
            y_hi: f64::INFINITY,
            finite: true,
        }
    }

    /// Adds `c0 + cy·y + cx·x ≥ 0`, with `inv` = `1/cx` (precomputed per frame: the
    /// slopes are the view's, not the box's).
    fn push(&mut self, c0: f64, cy: f64, cx: f64, inv: f64) {
        self.finite &= c0.is_finite() && cy.is_finite() && cx.is_finite();
        if cx == 0.0 {
            if cy == 0.0 {
                if c0 < 0.0 {
                    self.y_lo = f64::INFINITY;
                }
            } else if cy > 0.0 {
                self.y_lo = self.y_lo.max(-c0 / cy);
            } else {
                self.y_hi = self.y_hi.min(-c0 / cy);
            }
            return;
        }
        self.finite &= inv.is_finite();
        // Left and right bounds share one array from both ends.
        assert!(
            self.n_left + self.n_right < MAX_PLANES,
            "a region has at most {MAX_PLANES} bounds that depend on x"
        );
        let line = (-c0 * inv, -cy * inv);
        if cx > 0.0 {
            self.lines[self.n_left] = line;
            self.n_left += 1;
        } else {
            self.n_right += 1;
            self.lines[MAX_PLANES - self.n_right] = line;
        }
    }

    /// The real interval of row `y` inside the region, its rows widened (`margin` > 0) or
    /// narrowed (< 0) by `margin`: empty when `lo > hi`.
    #[inline]
    fn interval(&self, y: u32, margin: f64) -> (f64, f64) {
        let fy = f64::from(y);
        if fy < self.y_lo - margin || fy > self.y_hi + margin {
            return (f64::INFINITY, f64::NEG_INFINITY);
        }
        let mut lo = f64::NEG_INFINITY;
        for &(p, q) in &self.lines[..self.n_left] {
            lo = lo.max(p + q * fy);
        }
        let mut hi = f64::INFINITY;
        for &(p, q) in &self.lines[MAX_PLANES - self.n_right..] {
            hi = hi.min(p + q * fy);
        }
        (lo, hi)
    }

    /// The pixels of row `y`, clipped to `x0..x1`, that are surely inside: the exact test
    /// passes each of them.
    #[inline]
    fn run(&self, y: u32, (x0, x1): (u32, u32)) -> std::ops::Range<u32> {
        let (lo, hi) = self.interval(y, -REGION_MARGIN);
        let (lo, hi) = (lo + REGION_MARGIN, hi - REGION_MARGIN);
        if !self.finite || lo > hi {
            return x0..x0;
        }
        // The integers in [lo, hi] and in x0..x1: ⌈lo⌉ and ⌊hi⌋ + 1, clamped first so that
        // the conversions (which truncate) see non-negative values below 2³². `hi` is clamped
        // to one left of x0 at least, so that a region wholly left of the window leaves the
        // run empty instead of holding x0.
        let (fx0, fx1) = (f64::from(x0), f64::from(x1));
        let (lo, hi1) = (lo.clamp(fx0, fx1), hi.clamp(fx0 - 1.0, fx1) + 1.0);
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let (a, b) = {
            let t = lo as u32;
            (t + u32::from(f64::from(t) < lo), (hi1 as u32).min(x1))
        };
        if b > a {
            a..b
        } else {
            x0..x0
        }
    }

    /// The pixels of row `y` that may be inside, widened by a pixel each side and clipped
    /// to `x0..x1`: the exact test passes none outside them.
    fn candidates(&self, y: u32, (x0, x1): (u32, u32)) -> std::ops::Range<u32> {
        let (lo, hi) = self.interval(y, REGION_MARGIN);
        if !self.finite {
            return x0..x1;
        }
        if lo > hi {
            return x0..x0;
        }
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let clip = |x: f64| x.clamp(f64::from(x0), f64::from(x1)) as u32;
        clip(lo.floor() - 1.0)..clip(hi.ceil() + 2.0)
    }
}

/// True when every value of `row` is at least `threshold`: in blocks of eight without an
/// early exit, which compile to vector compares, the tail as one more (overlapping) block.
#[inline]
fn all_at_least(row: &[f32], threshold: f32) -> bool {
    let block = |c: &[f32]| c.iter().fold(true, |all, b| all & (*b >= threshold));
    if row.len() < 8 {
        return block(row);
    }
    row.chunks_exact(8).fold(true, |all, c| all & block(c)) & block(&row[row.len() - 8..])
}

/// Slack, in `t` units, by which span tests err on the safe side: a pixel counts as meeting
/// a brick when its ray misses by less, and as in the core only when its span exceeds the
/// core length by more. Both only make culling harder, never wrong.
const SPAN_SLACK: f64 = 1e-3;

/// Ray spans of the pixels of a view. Orthographic rays differ only by an affine offset of
/// their origin, so their spans come from a few multiply-adds per pixel instead of a camera
/// ray each; perspective views use the renderer's own rays.
// One per culled tile and frame: the size difference costs nothing.
#[allow(clippy::large_enum_variant)]
enum PixelSpans<'a> {
    Orthographic {
        o00: [f64; 3],
        du: [f64; 3],
        dv: [f64; 3],
        d: [f64; 3],
        /// `1/d` per axis (0 where `d` is): a multiply per slab instead of a divide; the
        /// rounding difference is far below [`SPAN_SLACK`].
        inv_d: [f64; 3],
        /// `1/du` per axis (0 where `du` is).
        inv_du: [f64; 3],
        /// How fast each slab's crossings move along a row: `−du·inv_d` per axis.
        slope: [f64; 3],
        /// `1/slope[a]` on the diagonal, `1/(slope[a] − slope[b])` off it (0 for a zero
        /// denominator).
        inv_slope: [[f64; 3]; 3],
        /// The image row of a point `p` is `row · (p − o00)`.
        row: [f64; 3],
    },
    Perspective {
        camera: &'a Camera,
        frame: &'a ViewFrame,
        spacing: [f32; 3],
        unit: f32,
    },
}

impl<'a> PixelSpans<'a> {
    fn new(camera: &'a Camera, frame: &'a ViewFrame, volume: &Volume) -> Self {
        let spacing = volume.spacing();
        let unit = volume.unit();
        if camera.projection == Projection::Perspective {
            return PixelSpans::Perspective {
                camera,
                frame,
                spacing,
                unit,
            };
        }
        let s = DVec3::from(spacing.map(f64::from));
        let at = |x: f64, y: f64| camera.ray(frame, x, y).origin / s;
        let o00 = at(0.5, 0.5);
        let du = at(1.5, 0.5) - o00;
        let dv = at(0.5, 1.5) - o00;
        let d = frame.forward * f64::from(unit) / s;
        let recip = |x: f64| if x == 0.0 { 0.0 } else { 1.0 / x };
        let inv_d = d.to_array().map(recip);
        let du = du.to_array();
        let slope: [f64; 3] = std::array::from_fn(|a| -du[a] * inv_d[a]);
        let inv_slope = std::array::from_fn(|a| {
            std::array::from_fn(|b| {
                recip(if a == b {
                    slope[a]
                } else {
                    slope[a] - slope[b]
                })
            })
        });
        // p − o00 = x·du + y·dv + t·d: the second row of the inverse gives y.
        let inv = glam::DMat3::from_cols(DVec3::from(du), dv, d).inverse();
        let row = inv.row(1).to_array();
        PixelSpans::Orthographic {
            row,
            o00: o00.to_array(),
            du,
            dv: dv.to_array(),
            d: d.to_array(),
            inv_d,
            inv_du: du.map(recip),
            slope,
            inv_slope,
        }
    }

    /// Orthographic views: the image rows `y0..y1` whose pixels' rays may meet `b` (with a
    /// row of margin each side); `None` for perspective views.
    fn rows_of(&self, b: &crate::brick::IndexBox) -> Option<(u32, u32)> {
        let PixelSpans::Orthographic { o00, row, .. } = self else {
            return None;
        };
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for corner in 0..8 {
            let mut y = 0.0;
            for a in 0..3 {
                let c = if corner >> a & 1 == 0 {
                    b.lo[a]
                } else {
                    b.hi[a]
                };
                y += row[a] * (f64::from(c) - o00[a]);
            }
            lo = lo.min(y);
            hi = hi.max(y);
        }
        if !(lo.is_finite() && hi.is_finite()) {
            return None;
        }
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let clip = |y: f64| y.clamp(0.0, f64::from(u32::MAX)) as u32;
        Some((clip(lo.floor() - 1.0), clip(hi.ceil() + 2.0)))
    }

    /// The pixel's `t` span inside `b` (unclipped; may be empty: `t1 < t0`).
    fn span(&self, x: u32, y: u32, b: &crate::brick::IndexBox) -> (f64, f64) {
        match self {
            PixelSpans::Orthographic {
                o00,
                du,
                dv,
                d,
                inv_d,
                ..
            } => {
                let (fx, fy) = (f64::from(x), f64::from(y));
                let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
                for a in 0..3 {
                    let o = o00[a] + fx * du[a] + fy * dv[a];
                    let (lo, hi) = (f64::from(b.lo[a]), f64::from(b.hi[a]));
                    if d[a] == 0.0 {
                        // Parallel to the slab: all or nothing, judged with the slack.
                        if o < lo - SPAN_SLACK || o > hi + SPAN_SLACK {
                            return (0.0, -1.0);
                        }
                        if o < lo + SPAN_SLACK || o > hi - SPAN_SLACK {
                            t1 = t1.min(t0.max(0.0));
                        }
                        continue;
                    }
                    let (ta, tb) = ((lo - o) * inv_d[a], (hi - o) * inv_d[a]);
                    t0 = t0.max(ta.min(tb));
                    t1 = t1.min(ta.max(tb));
                }
                (t0, t1)
            }
            PixelSpans::Perspective {
                camera,
                frame,
                spacing,
                unit,
            } => {
                let r = IndexRay::new(
                    &camera.ray(frame, f64::from(x) + 0.5, f64::from(y) + 0.5),
                    *spacing,
                    *unit,
                );
                // The renderer's own ray and span test: no slack needed.
                match r.span(b) {
                    Some((t0, t1)) => (f64::from(t0).max(0.0), f64::from(t1)),
                    None => (0.0, -1.0),
                }
            }
        }
    }

    /// Orthographic views: the pixels that pass [`PixelSpans::hits`] (`core` is `None`) or
    /// [`PixelSpans::in_core`] (`Some(core)`) for `b`, as a convex region of the image;
    /// `None` for perspective views.
    ///
    /// Why: the near and far plane crossings of each slab are affine in the pixel position,
    /// so both tests are a conjunction of a dozen half-planes. Solving them once per box
    /// turns every row's run into a few multiply-adds instead of span tests per pixel.
    fn region(&self, b: &crate::brick::IndexBox, core: Option<f32>) -> Option<Region> {
        let PixelSpans::Orthographic {
            o00,
            du,
            dv,
            inv_d,
            inv_du,
            slope,
            inv_slope,
            ..
        } = self
        else {
            return None;
        };
        // The least length, and the least far crossing, the test asks for.
        let need = core.map_or(-SPAN_SLACK, |c| f64::from(c) + SPAN_SLACK);
        let mut r = Region::new();
        // Near and far crossings of each slab at x = 0 as (intercept, y slope), and its
        // x slope.
        let mut slabs = [((0.0, 0.0), (0.0, 0.0), 0usize); 3];
        let mut n = 0;
        for a in 0..3 {
            let (lo, hi) = (f64::from(b.lo[a]), f64::from(b.hi[a]));
            if inv_d[a] == 0.0 {
                // Parallel to the slab: o(x, y) = o00 + x·du + y·dv must lie inside it, by
                // the slack outside (hits) or inside (core).
                let e = if core.is_some() {
                    SPAN_SLACK
                } else {
                    -SPAN_SLACK
                };
                r.push(o00[a] - (lo + e), dv[a], du[a], inv_du[a]);
                r.push((hi - e) - o00[a], -dv[a], -du[a], -inv_du[a]);
                continue;
            }
            let ty = -dv[a] * inv_d[a];
            let (ta, tb) = ((lo - o00[a]) * inv_d[a], (hi - o00[a]) * inv_d[a]);
            slabs[n] = ((ta.min(tb), ty), (ta.max(tb), ty), a);
            n += 1;
        }
        for &(_, (far, far_y), a) in &slabs[..n] {
            r.push(far - need, far_y, slope[a], inv_slope[a][a]);
            for &((near, near_y), _, b) in &slabs[..n] {
                // (a = b: the slab's own thickness along the ray, the same for every pixel.)
                let (cy, cx) = if a == b {
                    (0.0, 0.0)
                } else {
                    (far_y - near_y, slope[a] - slope[b])
                };
                r.push(far - near - need, cy, cx, inv_slope[a][b]);
            }
        }
        Some(r)
    }

    /// Orthographic views: the pixels of row `y` that may pass [`PixelSpans::hits`]
    /// (`core` is `None`) or [`PixelSpans::in_core`] (`Some(core)`) for `b`, widened by a
    /// pixel each side and clipped to `x0..x1`; `None` for perspective views.
    #[cfg(test)]
    fn row_candidates(
        &self,
        y: u32,
        b: &crate::brick::IndexBox,
        core: Option<f32>,
        (x0, x1): (u32, u32),
    ) -> Option<std::ops::Range<u32>> {
        Some(self.region(b, core)?.candidates(y, (x0, x1)))
    }

    /// True when the pixel's ray may take a sample in `b` (conservatively).
    fn hits(&self, x: u32, y: u32, b: &crate::brick::IndexBox) -> bool {
        let (t0, t1) = self.span(x, y, b);
        t1 - t0 > -SPAN_SLACK && t1 > -SPAN_SLACK
    }

    /// True when the pixel's ray surely runs at least `core` inside `b`.
    fn in_core(&self, x: u32, y: u32, b: &crate::brick::IndexBox, core: f32) -> bool {
        let (t0, t1) = self.span(x, y, b);
        t1 - t0.max(0.0) >= f64::from(core) + SPAN_SLACK
    }
}

/// Culling reads POFs through [`OpacityBound`]; the POF module knows nothing of culling.
impl OpacityBound for crate::pof::PofTable {
    fn core_length(&self) -> f32 {
        crate::pof::PofTable::core_length(self)
    }
    fn opacity(&self, brick: BrickId, dir: DVec3, weights: &[f32], aggressive: bool) -> f32 {
        crate::pof::PofTable::opacity(self, brick, dir, weights, pof_mode(self, aggressive))
    }
    fn prefetch(&self, bricks: &[BrickId], dir: DVec3) {
        crate::pof::PofTable::prefetch(self, bricks, dir);
    }
    fn ert(&self) -> f32 {
        crate::pof::PofTable::ert(self)
    }
    fn opacity_cone(
        &self,
        brick: BrickId,
        axis: DVec3,
        half_angle: f64,
        weights: &[f32],
        aggressive: bool,
    ) -> f32 {
        crate::pof::PofTable::opacity_cone(
            self,
            brick,
            axis,
            half_angle,
            weights,
            pof_mode(self, aggressive),
        )
    }
}

fn pof_mode(table: &crate::pof::PofTable, aggressive: bool) -> crate::pof::PofMode {
    // A table without sets answers the aggressive mode conservatively.
    if aggressive && table.has_sets() {
        crate::pof::PofMode::Sets
    } else {
        crate::pof::PofMode::Conservative
    }
}
