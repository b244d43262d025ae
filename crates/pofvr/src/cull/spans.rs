//! Which pixels' rays meet a brick, and which run at least a core length inside it: the
//! ray span of a pixel, and for orthographic views the same tests solved once per box as
//! a convex region of the image.

use glam::DVec3;

use crate::brick::IndexBox;
use crate::render::{Camera, IndexRay, Projection, ViewFrame};
use crate::volume::Volume;

/// A convex region of the image, `c0 + cy·y + cx·x ≥ 0` for each of its half-planes, with
/// pixel centres at integer `(x, y)` (see [`PixelSpans::region`]). Kept as what a row
/// needs: the left bounds `x ≥ p + q·y`, the right bounds `x ≤ p + q·y` and the rows.
#[derive(Clone, Copy)]
pub(super) struct Region {
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
    pub(super) fn run(&self, y: u32, (x0, x1): (u32, u32)) -> std::ops::Range<u32> {
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
    pub(super) fn candidates(&self, y: u32, (x0, x1): (u32, u32)) -> std::ops::Range<u32> {
        let (lo, hi) = self.interval(y, REGION_MARGIN);
        if !self.finite {
            return x0..x1;
        }
        if lo > hi {
            return x0..x0;
        }
        let clip = |x: f64| x.clamp(f64::from(x0), f64::from(x1)) as u32;
        clip(lo.floor() - 1.0)..clip(hi.ceil() + 2.0)
    }
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
pub(super) enum PixelSpans<'a> {
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
    pub(super) fn new(camera: &'a Camera, frame: &'a ViewFrame, volume: &Volume) -> Self {
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
    pub(super) fn rows_of(&self, b: &IndexBox) -> Option<(u32, u32)> {
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
        let clip = |y: f64| y.clamp(0.0, f64::from(u32::MAX)) as u32;
        Some((clip(lo.floor() - 1.0), clip(hi.ceil() + 2.0)))
    }

    /// The pixel's `t` span inside `b` (unclipped; may be empty: `t1 < t0`).
    fn span(&self, x: u32, y: u32, b: &IndexBox) -> (f64, f64) {
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
    pub(super) fn region(&self, b: &IndexBox, core: Option<f32>) -> Option<Region> {
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
    pub(super) fn row_candidates(
        &self,
        y: u32,
        b: &IndexBox,
        core: Option<f32>,
        (x0, x1): (u32, u32),
    ) -> Option<std::ops::Range<u32>> {
        Some(self.region(b, core)?.candidates(y, (x0, x1)))
    }

    /// True when the pixel's ray may take a sample in `b` (conservatively).
    pub(super) fn hits(&self, x: u32, y: u32, b: &IndexBox) -> bool {
        let (t0, t1) = self.span(x, y, b);
        t1 - t0 > -SPAN_SLACK && t1 > -SPAN_SLACK
    }

    /// True when the pixel's ray surely runs at least `core` inside `b`.
    pub(super) fn in_core(&self, x: u32, y: u32, b: &IndexBox, core: f32) -> bool {
        let (t0, t1) = self.span(x, y, b);
        t1 - t0.max(0.0) >= f64::from(core) + SPAN_SLACK
    }
}
