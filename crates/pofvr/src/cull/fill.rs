//! What a visible brick adds to the opacity buffer in the POF modes: its bound, per core
//! length, over the pixels whose ray runs at least that far inside it; with bounds for
//! sub-bricks, the sub-bricks' bounds multiplied along each ray.

use glam::DVec3;

use super::spans::{PixelSpans, Region};
use super::OpacityBound;
use crate::brick::{BrickGrid, BrickId, IndexBox};
use crate::render::{Camera, PixelRect, Projection, ViewFrame};
use crate::volume::Volume;

/// The most POF levels (core lengths) culling uses.
const MAX_LEVELS: usize = 8;

/// A chain of POF levels, shortest core first, with their core lengths.
#[derive(Default)]
struct Levels<'a> {
    bounds: Vec<&'a dyn OpacityBound>,
    cores: Vec<f32>,
}

impl<'a> Levels<'a> {
    /// `first` and its deeper levels, at most [`MAX_LEVELS`].
    fn chain(first: Option<&'a dyn OpacityBound>) -> Self {
        let bounds: Vec<&dyn OpacityBound> = first
            .into_iter()
            .flat_map(|b| std::iter::once(b).chain((0..).map_while(move |k| b.deeper(k))))
            .take(MAX_LEVELS)
            .collect();
        let cores = bounds.iter().map(|l| l.core_length()).collect();
        Levels { bounds, cores }
    }
}

/// What every bound looked up and composited in one cull shares: the view and the lookup
/// mode.
#[derive(Clone, Copy)]
pub(super) struct BoundView<'v> {
    pub(super) camera: &'v Camera,
    pub(super) frame: &'v ViewFrame,
    pub(super) spans: &'v PixelSpans<'v>,
    pub(super) volume: &'v Volume,
    pub(super) weights: &'v [f32],
    /// POF-set lookups ([`crate::cull::CullMode::PofSet`]).
    pub(super) aggressive: bool,
}

/// Where [`BoundView::composite`] adds opacity.
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

/// Adds the POF bounds of visible bricks to a strip's opacity buffer.
pub(super) struct BoundFill<'a> {
    /// The bounds the culler was given (the sub-brick path caps at their `ert`).
    bounds: &'a dyn OpacityBound,
    /// The levels of the render bricks, and of their sub-bricks.
    own: Levels<'a>,
    sub: Levels<'a>,
    /// The sub-bricks' grid, when there are sub-brick bounds.
    fine: Option<&'a BrickGrid>,
    grid: &'a BrickGrid,
    view: BoundView<'a>,
    threshold: f32,
    /// Whether a brick whose own bound suffices may leave out its sub-bricks.
    skip_sub_bricks: bool,
    /// Transparency images over a brick's rectangle: its sub-bricks', its own.
    sub_t: Vec<f32>,
    own_t: Vec<f32>,
    /// A brick's sub-bricks and their ids.
    subs: Vec<(BrickId, IndexBox)>,
    sub_ids: Vec<BrickId>,
}

impl<'a> BoundFill<'a> {
    /// Fills with `bounds`, for render bricks of `grid`, up to `threshold`.
    pub(super) fn new(
        bounds: &'a dyn OpacityBound,
        grid: &'a BrickGrid,
        view: BoundView<'a>,
        threshold: f32,
        skip_sub_bricks: bool,
    ) -> Self {
        let (own, sub) = if bounds.grid().is_some() {
            (Levels::default(), Levels::chain(Some(bounds)))
        } else {
            (
                Levels::chain(Some(bounds)),
                Levels::chain(bounds.sub_bricks()),
            )
        };
        let fine = sub.bounds.first().and_then(|b| b.grid());
        BoundFill {
            bounds,
            own,
            sub,
            fine,
            grid,
            view,
            threshold,
            skip_sub_bricks,
            sub_t: Vec::new(),
            own_t: Vec::new(),
            subs: Vec::new(),
            sub_ids: Vec::new(),
        }
    }

    /// True when there are bounds for the render bricks themselves (which the culling loop
    /// prefetches by brick id).
    pub(super) fn has_own(&self) -> bool {
        !self.own.bounds.is_empty()
    }

    /// Adds the bound of visible brick `id` (index box `ibox`, footprint `rect`) to
    /// `buffer`, the opacity of the pixels of `tile`.
    pub(super) fn add(
        &mut self,
        (buffer, tile): (&mut [f32], PixelRect),
        id: BrickId,
        ibox: &IndexBox,
        rect: PixelRect,
    ) {
        let view = self.view;
        let Some(fine) = self.fine else {
            // The bounds are per render brick: straight into the buffer.
            let mut into = Sink::Buffer { buffer, tile };
            view.composite(&self.own, id, ibox, rect, &mut into);
            return;
        };
        // The bounds are per sub-brick: each bounds its own stretch of a ray, and the
        // stretches are disjoint, so their transparencies multiply. The brick stops
        // marching at the early-termination threshold, so what it adds is capped there.
        let cap = self.bounds.ert();
        let tw = tile.width() as usize;
        let rw = rect.width() as usize;
        let at =
            |r: usize| (rect.y0 - tile.y0) as usize * tw + r * tw + (rect.x0 - tile.x0) as usize;
        // The brick's own bound first: where it alone lifts every pixel of the rectangle to
        // the threshold, the sub-bricks cannot change what is culled (a pixel at the
        // threshold stays there), and their eight lookups and composites, most of the
        // culling time, are saved.
        self.grid.sub_bricks_into(id, fine, &mut self.subs);
        if view.camera.projection == Projection::Orthographic {
            // Each lookup is a cache miss in a table of many megabytes: start them all now,
            // to arrive while the brick's own bound is composited.
            self.sub_ids.clear();
            self.sub_ids.extend(self.subs.iter().map(|(cid, _)| *cid));
            self.sub.bounds[0].prefetch(&self.sub_ids, view.frame.forward);
        }
        let has_own = self.has_own();
        if has_own {
            self.own_t.clear();
            self.own_t.resize(rect.area(), 1.0);
            let mut into = Sink::Transparency {
                t: &mut self.own_t,
                rect,
            };
            view.composite(&self.own, id, ibox, rect, &mut into);
            let threshold = self.threshold;
            let enough = self.own_t.chunks_exact(rw).enumerate().all(|(r, ts)| {
                let start = at(r);
                buffer[start..start + rw]
                    .iter()
                    .zip(ts)
                    .all(|(b, t)| b + (1.0 - b) * (1.0 - t).min(cap) >= threshold)
            });
            if enough && self.skip_sub_bricks {
                flush(buffer, &self.own_t, None, rw, cap, at);
                return;
            }
        }
        self.sub_t.clear();
        self.sub_t.resize(rect.area(), 1.0);
        let mut into = Sink::Transparency {
            t: &mut self.sub_t,
            rect,
        };
        for (cid, cbox) in &self.subs {
            view.composite(&self.sub, *cid, cbox, rect, &mut into);
        }
        // The brick's own bound, where higher, bounds the same stretch of ray.
        let own_t = has_own.then_some(self.own_t.as_slice());
        flush(buffer, &self.sub_t, own_t, rw, cap, at);
    }
}

impl BoundView<'_> {
    /// Adds the bound of brick `id` (of the bounds' grid, with index box `ibox`) to `into`
    /// over `rect`: per level (core length), the level's bound over the pixels of that
    /// level's core.
    fn composite(
        &self,
        levels: &Levels<'_>,
        id: BrickId,
        ibox: &IndexBox,
        rect: PixelRect,
        into: &mut Sink<'_>,
    ) {
        let spans = self.spans;
        let (cores, levels) = (&levels.cores, &levels.bounds);
        // A longer core's pixels are in every shorter one's too.
        let mut alphas = [0f32; MAX_LEVELS];
        let mut any = false;
        for (k, level) in levels.iter().enumerate() {
            let a = self.brick_bound(*level, id, ibox);
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

    /// The bound of brick `id` (index box `ib`) for the rays of this view: along the view
    /// direction (orthographic), or over the cone under which the eye sees the brick
    /// (perspective).
    fn brick_bound(&self, bounds: &dyn OpacityBound, id: BrickId, ib: &IndexBox) -> f32 {
        let (camera, frame, weights, aggressive) =
            (self.camera, self.frame, self.weights, self.aggressive);
        match camera.projection {
            Projection::Orthographic => bounds.opacity(id, frame.forward, weights, aggressive),
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
                        weights,
                        aggressive,
                    );
                }
                bounds.opacity_cone(id, to / dist, (radius / dist).asin(), weights, aggressive)
            }
        }
    }
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
