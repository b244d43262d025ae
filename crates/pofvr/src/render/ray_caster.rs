//! The software ray caster: front-to-back emission–absorption with trilinear samples.
//!
//! Samples of a ray lie on one lattice `t_k = k·step` (t in units of the volume's smallest
//! spacing, measured from the camera), whatever box is being rendered. A box claims the
//! samples in its half-open interval `[t_near, t_far)`, computed from its face planes, and
//! neighbouring boxes compute the shared plane's `t` with the same float operations. So the
//! bricks of a grid partition every ray's samples exactly, and rendering brick by brick
//! (carrying the accumulator) performs the very operations of the whole-volume render.

use glam::DVec3;
use rayon::prelude::*;

use super::camera::{Camera, PixelRect, Ray, ViewFrame};
use super::image::Image;
use super::transfer_function::Classifier;
use crate::brick::IndexBox;
use crate::volume::{Volume, Voxel};
use crate::with_voxels;

/// Per-frame knobs of the ray caster.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Sample distance in units of the smallest spacing. Default 1.
    pub step: f32,
    /// Early ray termination: stop a ray once its opacity reaches this. Default 0.99;
    /// 1.0 (or more) disables it.
    pub ert: f32,
    /// Lambertian gradient shading with a headlight.
    pub shade: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            step: 1.0,
            ert: 0.99,
            shade: false,
        }
    }
}

/// Rays and samples a render performed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct RayStats {
    /// Rays that met the rendered box.
    pub rays: u64,
    /// Samples taken (after early termination).
    pub samples: u64,
}

impl std::ops::AddAssign for RayStats {
    fn add_assign(&mut self, o: Self) {
        self.rays += o.rays;
        self.samples += o.samples;
    }
}

/// A ray in index space with `t` in units: `p(t) = o + t·d`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexRay {
    /// Origin in voxel index coordinates.
    pub o: [f32; 3],
    /// Index-space displacement per unit of `t`.
    pub d: [f32; 3],
    /// Unit world direction (for shading).
    pub dir: [f32; 3],
}

impl IndexRay {
    /// Converts a world ray for a volume with `spacing` and smallest spacing `unit`.
    #[must_use]
    #[allow(clippy::cast_possible_truncation)]
    pub fn new(ray: &Ray, spacing: [f32; 3], unit: f32) -> Self {
        let s = DVec3::from(spacing.map(f64::from));
        let o = ray.origin / s;
        let d = ray.dir * f64::from(unit) / s;
        IndexRay {
            o: o.to_array().map(|x| x as f32),
            d: d.to_array().map(|x| x as f32),
            dir: ray.dir.to_array().map(|x| x as f32),
        }
    }

    /// The half-open `t` interval `[t_near, t_far)` inside `b`, or `None` when it misses.
    #[inline]
    #[must_use]
    pub fn span(&self, b: &IndexBox) -> Option<(f32, f32)> {
        let (mut t0, mut t1) = (f32::NEG_INFINITY, f32::INFINITY);
        for a in 0..3 {
            let d = self.d[a];
            if d == 0.0 {
                if !(b.lo[a] <= self.o[a] && self.o[a] < b.hi[a]) {
                    return None;
                }
                continue;
            }
            // Same expression for every box sharing the plane: the partition is exact.
            let ta = (b.lo[a] - self.o[a]) / d;
            let tb = (b.hi[a] - self.o[a]) / d;
            let (near, far) = if d > 0.0 { (ta, tb) } else { (tb, ta) };
            t0 = t0.max(near);
            t1 = t1.min(far);
        }
        (t0 < t1).then_some((t0, t1))
    }
}

/// First lattice index `k ≥ 0` with `k·step ≥ t`.
#[inline]
#[must_use]
#[allow(clippy::cast_possible_truncation, clippy::cast_precision_loss)]
pub fn first_sample(t: f32, step: f32) -> i32 {
    if t <= 0.0 {
        return 0;
    }
    // A ceiling by hand: `f32::ceil` is a libm call on the x86_64 baseline (no SSE4.1),
    // once per box and ray. The loops below settle the exact boundary either way.
    let q = (t / step).min(i32::MAX as f32 - 2.0);
    let mut k = q as i32;
    k += i32::from((k as f32) < q);
    // The division rounds; settle on the exact boundary under the multiplication we sample with.
    while k > 0 && (k - 1) as f32 * step >= t {
        k -= 1;
    }
    while (k as f32) * step < t {
        k += 1;
    }
    k
}

/// The lattice indices `[k0, k1)` a box claims on a ray, given its span.
#[inline]
#[must_use]
pub fn sample_range(span: (f32, f32), step: f32) -> (i32, i32) {
    (first_sample(span.0, step), first_sample(span.1, step))
}

/// Trilinear interpolation with positions clamped to the volume, over the whole volume or
/// over a copy of one box of it (a [`crate::brick::BrickCopy`]).
///
/// A copy is addressed by subtracting its integer origin from the clamped position: that
/// subtraction is exact in f32 (the origin is an integer no larger than the position, both
/// below 2²⁴), so the cell index and the fractions — and hence every sample — are bit for bit
/// those of the whole volume, as long as the position stays inside the copy.
#[derive(Clone, Copy)]
pub(crate) struct Trilinear<'v, T> {
    pub(super) v: &'v [T],
    /// The whole volume's last index per axis (the clamp).
    pub(super) max: [f32; 3],
    /// Index of voxel `v[0]` in the volume.
    pub(super) origin: [f32; 3],
    /// Last cell of the copy per axis.
    pub(super) last_cell: [usize; 3],
    pub(super) stride: [usize; 3],
    pub(super) step: [usize; 3],
}

impl<'v, T: Voxel> Trilinear<'v, T> {
    pub(crate) fn new(v: &'v [T], dims: [usize; 3]) -> Self {
        Self::local(v, dims, [0; 3], dims)
    }

    /// Over `v`, the `dims` voxels from `origin` of a volume of `volume_dims` voxels.
    #[allow(clippy::cast_precision_loss)]
    pub(crate) fn local(
        v: &'v [T],
        dims: [usize; 3],
        origin: [usize; 3],
        volume_dims: [usize; 3],
    ) -> Self {
        debug_assert_eq!(v.len(), dims[0] * dims[1] * dims[2]);
        let stride = [1, dims[0], dims[0] * dims[1]];
        Trilinear {
            v,
            max: volume_dims.map(|d| (d - 1) as f32),
            origin: origin.map(|o| o as f32),
            last_cell: dims.map(|d| d.saturating_sub(2)),
            stride,
            step: std::array::from_fn(|a| if dims[a] > 1 { stride[a] } else { 0 }),
        }
    }

    #[inline(always)]
    #[allow(
        clippy::cast_possible_truncation,
        clippy::cast_sign_loss,
        clippy::cast_precision_loss
    )]
    pub(crate) fn sample(&self, p: [f32; 3]) -> f32 {
        let mut base = 0usize;
        let mut f = [0f32; 3];
        for a in 0..3 {
            // max/min rather than clamp: clamp's `min <= max` assertion is not hoisted.
            // The origin's subtraction is exact (see the type's comment); for a copy the
            // result is ≥ 0 while the position stays inside it.
            let x = p[a].max(0.0).min(self.max[a]) - self.origin[a];
            // SAFETY: x is finite and in [0, dims-1] after the max/min above (NaN positions
            // cannot occur: rays are finite and volumes hold finite values).
            let i =
                (unsafe { x.max(0.0).to_int_unchecked::<u32>() } as usize).min(self.last_cell[a]);
            f[a] = x - i as f32;
            base += i * self.stride[a];
        }
        let [sx, sy, sz] = self.step;
        debug_assert!(
            base + sx + sy + sz < self.v.len(),
            "{base} out of {}",
            self.v.len()
        );
        // SAFETY: every axis index is clamped to [0, dims-2] (or 0 with a zero step on a
        // one-voxel axis), so base plus any combination of steps stays inside the volume.
        let at = |i: usize| unsafe { self.v.get_unchecked(i) }.to_f32();
        let c00 = at(base) + (at(base + sx) - at(base)) * f[0];
        let c10 = at(base + sy) + (at(base + sy + sx) - at(base + sy)) * f[0];
        let c01 = at(base + sz) + (at(base + sz + sx) - at(base + sz)) * f[0];
        let c11 = at(base + sz + sy) + (at(base + sz + sy + sx) - at(base + sz + sy)) * f[0];
        let c0 = c00 + (c10 - c00) * f[1];
        let c1 = c01 + (c11 - c01) * f[1];
        c0 + (c1 - c0) * f[2]
    }
}

/// Voxel types whose 8 cell corners the SIMD sample loops gather.
#[cfg(target_arch = "x86_64")]
pub(crate) trait Gather: super::avx2::Gather8 + GatherOne {}
#[cfg(target_arch = "x86_64")]
impl<T: super::avx2::Gather8 + GatherOne> Gather for T {}
#[cfg(not(target_arch = "x86_64"))]
pub(crate) trait Gather: GatherOne {}
#[cfg(not(target_arch = "x86_64"))]
impl<T: GatherOne> Gather for T {}

/// Voxel types whose 8 cell corners the one-sample SIMD loop gathers.
pub(crate) trait GatherOne: Voxel {
    /// True when [`GatherOne::corners`] has a faster form for a unit x step (`sx == 1`).
    const PAIRS: bool = false;

    /// Corners `[c000, c001, c010, c011]` (low x) and `[c100, c101, c110, c111]` (high x) of
    /// the cell at `base` (lanes: z fastest, then y), converted to `f32`.
    ///
    /// # Safety
    /// `base + sx + sy + sz < v.len()`, and `sx == 1` where `PAIRS` is true.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn corners(v: &[Self], base: usize, step: [usize; 3]) -> (X86F32x4, X86F32x4) {
        // SAFETY: forwarded from the caller.
        unsafe { corners_generic(v, base, step) }
    }
}

#[cfg(target_arch = "x86_64")]
type X86F32x4 = std::arch::x86_64::__m128;

/// [`GatherOne::corners`] with one scalar load and conversion per corner.
///
/// # Safety
/// `base + sx + sy + sz < v.len()`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn corners_generic<T: Voxel>(
    v: &[T],
    base: usize,
    [sx, sy, sz]: [usize; 3],
) -> (X86F32x4, X86F32x4) {
    use std::arch::x86_64::_mm_setr_ps;
    debug_assert!(base + sx + sy + sz < v.len());
    // SAFETY: every index below is at most base + sx + sy + sz (caller).
    let at = |i: usize| unsafe { v.get_unchecked(i) }.to_f32();
    // SAFETY: SSE is part of the x86_64 baseline.
    unsafe {
        (
            _mm_setr_ps(at(base), at(base + sz), at(base + sy), at(base + sy + sz)),
            _mm_setr_ps(
                at(base + sx),
                at(base + sz + sx),
                at(base + sy + sx),
                at(base + sy + sz + sx),
            ),
        )
    }
}

impl GatherOne for u16 {}
impl GatherOne for i16 {}
impl GatherOne for f32 {}

impl GatherOne for u8 {
    const PAIRS: bool = true;

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn corners(v: &[u8], base: usize, step: [usize; 3]) -> (X86F32x4, X86F32x4) {
        use std::arch::x86_64::{
            _mm_and_si128, _mm_cvtepi32_ps, _mm_cvtsi32_si128, _mm_insert_epi16, _mm_set1_epi32,
            _mm_setzero_si128, _mm_srli_epi32, _mm_unpacklo_epi8,
        };
        let [sx, sy, sz] = step;
        debug_assert_eq!(sx, 1, "a one-voxel x axis takes corners_generic");
        debug_assert!(base + 1 + sy + sz < v.len());
        // The x neighbours of a corner are adjacent bytes: one 16-bit load per pair.
        // SAFETY: i + 1 ≤ base + 1 + sy + sz < v.len() for every pair (caller).
        let pair =
            |i: usize| i32::from(unsafe { v.as_ptr().add(i).cast::<u16>().read_unaligned() });
        // SAFETY: SSE2 is part of the x86_64 baseline.
        unsafe {
            let w = _mm_cvtsi32_si128(pair(base) | (pair(base + sz) << 16));
            let w = _mm_insert_epi16::<2>(w, pair(base + sy));
            let w = _mm_insert_epi16::<3>(w, pair(base + sy + sz));
            // Bytes c000 c100 c001 c101 c010 c110 c011 c111 → 32-bit lanes `lo | hi << 16`.
            let w = _mm_unpacklo_epi8(w, _mm_setzero_si128());
            let lo = _mm_and_si128(w, _mm_set1_epi32(0xFFFF));
            let hi = _mm_srli_epi32::<16>(w);
            (_mm_cvtepi32_ps(lo), _mm_cvtepi32_ps(hi))
        }
    }
}

/// The ray caster: renders a box of the volume over a pixel rectangle, or the whole volume.
pub struct RayCaster<'a> {
    volume: &'a Volume,
    cls: &'a Classifier,
    settings: RenderSettings,
    /// Whether the eight-sample AVX2 loop runs (see `avx2::available`).
    avx2: bool,
}

fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    return super::avx2::available();
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// Rows per parallel work item of a full-frame render.
const TILE_ROWS: usize = 8;

/// Columns of the pixel tiles a band is traversed in.
const TILE_COLS: usize = 8;

impl<'a> RayCaster<'a> {
    /// A caster for `volume` with the classification `cls` (built for `settings.step`).
    #[must_use]
    pub fn new(volume: &'a Volume, cls: &'a Classifier, settings: RenderSettings) -> Self {
        RayCaster {
            volume,
            cls,
            settings,
            avx2: avx2_available(),
        }
    }

    /// The same caster with the AVX2 loop on or off (on only where the CPU has it): every
    /// loop gives the same image, bit for bit; this is for comparing them.
    #[must_use]
    pub fn with_avx2(mut self, on: bool) -> Self {
        self.avx2 = on && avx2_available();
        self
    }

    /// The sample loop this caster runs: "avx2", "sse2" or "scalar" (shading).
    #[must_use]
    pub fn simd(&self) -> &'static str {
        match (self.settings.shade, self.avx2, cfg!(target_arch = "x86_64")) {
            (false, true, _) => "avx2",
            (false, false, true) => "sse2",
            _ => "scalar",
        }
    }

    /// The settings.
    #[must_use]
    pub fn settings(&self) -> RenderSettings {
        self.settings
    }

    /// The index-space box of the whole volume.
    #[must_use]
    #[allow(clippy::cast_precision_loss)]
    pub fn volume_box(&self) -> IndexBox {
        IndexBox {
            lo: [0.0; 3],
            hi: self.volume.dims().map(|d| (d - 1) as f32),
        }
    }

    /// The index ray through the centre of pixel `(x, y)`.
    #[must_use]
    pub fn pixel_ray(&self, camera: &Camera, frame: &ViewFrame, x: u32, y: u32) -> IndexRay {
        let r = camera.ray(frame, f64::from(x) + 0.5, f64::from(y) + 0.5);
        IndexRay::new(&r, self.volume.spacing(), self.volume.unit())
    }

    /// Renders the whole volume (the reference, no bricks, no culling), in parallel over
    /// bands of rows.
    #[must_use]
    pub fn render(&self, camera: &Camera) -> (Image, RayStats) {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let mut image = Image::new(camera.width, camera.height);
        let frame = camera.frame();
        let vbox = self.volume_box();
        let stats = with_voxels!(self.volume.data(), v => {
            let tri = Trilinear::new(v, self.volume.dims());
            image
                .pixels_mut()
                .par_chunks_mut(w * TILE_ROWS)
                .enumerate()
                .map(|(band, rows)| {
                    let mut st = RayStats::default();
                    // Tiles of TILE_ROWS × TILE_COLS pixels: neighbouring rays share cache lines.
                    for x0 in (0..w).step_by(TILE_COLS) {
                        for r in 0..rows.len() / w {
                            for x in x0..(x0 + TILE_COLS).min(w) {
                                #[allow(clippy::cast_possible_truncation)]
                                let ray = self.pixel_ray(camera, &frame, x as u32, (band * TILE_ROWS + r) as u32);
                                if let Some(span) = ray.span(&vbox) {
                                    st.rays += 1;
                                    let range = sample_range(span, self.settings.step);
                                    st.samples += self.march(&tri, &ray, range, &mut rows[r * w + x]);
                                }
                            }
                        }
                    }
                    st
                })
                .reduce(RayStats::default, |mut a, b| {
                    a += b;
                    a
                })
        });
        debug_assert_eq!(image.pixels().len(), w * h);
        (image, stats)
    }

    /// Renders the index box `b` alone over `rect` (row-major premultiplied RGBA, starting
    /// from transparent), serially: callers parallelise over boxes.
    #[must_use]
    pub fn render_box(
        &self,
        camera: &Camera,
        frame: &ViewFrame,
        rect: PixelRect,
        b: &IndexBox,
    ) -> (Vec<[f32; 4]>, RayStats) {
        let mut out = vec![[0f32; 4]; rect.area()];
        let st = self.render_box_into(camera, frame, rect, b, &mut out);
        (out, st)
    }

    /// As [`RayCaster::render_box`], compositing behind what `out` already holds.
    pub fn render_box_into(
        &self,
        camera: &Camera,
        frame: &ViewFrame,
        rect: PixelRect,
        b: &IndexBox,
        out: &mut [[f32; 4]],
    ) -> RayStats {
        with_voxels!(self.volume.data(), v => {
            let tri = Trilinear::new(v, self.volume.dims());
            self.march_rect(&tri, camera, frame, rect, b, out)
        })
    }

    /// As [`RayCaster::render_box`], sampling the private copy `copy` of the box's voxels
    /// instead of the volume: the same samples, bit for bit (see `Trilinear`).
    #[must_use]
    pub fn render_box_copy(
        &self,
        camera: &Camera,
        frame: &ViewFrame,
        rect: PixelRect,
        b: &IndexBox,
        copy: &crate::brick::BrickCopy,
    ) -> (Vec<[f32; 4]>, RayStats) {
        let mut out = vec![[0f32; 4]; rect.area()];
        debug_assert_eq!(copy.data().data_type(), self.volume.data_type());
        let st = with_voxels!(copy.data(), v => {
            let tri = Trilinear::local(v, copy.dims(), copy.origin(), self.volume.dims());
            self.march_rect(&tri, camera, frame, rect, b, &mut out)
        });
        (out, st)
    }

    /// Marches every pixel of `rect` through the box `b`, compositing behind `out`
    /// (row-major over `rect`).
    fn march_rect<T: Gather>(
        &self,
        tri: &Trilinear<'_, T>,
        camera: &Camera,
        frame: &ViewFrame,
        rect: PixelRect,
        b: &IndexBox,
        out: &mut [[f32; 4]],
    ) -> RayStats {
        let mut st = RayStats::default();
        let w = rect.width() as usize;
        for (i, px) in out.iter_mut().enumerate() {
            #[allow(clippy::cast_possible_truncation)]
            let (x, y) = (rect.x0 + (i % w) as u32, rect.y0 + (i / w) as u32);
            let ray = self.pixel_ray(camera, frame, x, y);
            if let Some(span) = ray.span(b) {
                st.rays += 1;
                st.samples += self.march(tri, &ray, sample_range(span, self.settings.step), px);
            }
        }
        st
    }

    /// Composites samples `k0..k1` of `ray` behind `acc`; returns the samples taken.
    ///
    /// Every path performs, for every sample, the float operations of
    /// [`RayCaster::march_scalar`] (no fused multiply–adds anywhere), so they agree bit for
    /// bit and `render` and `render_box_into` may take any of them.
    #[inline(always)]
    pub(super) fn march<T: Gather>(
        &self,
        tri: &Trilinear<'_, T>,
        ray: &IndexRay,
        range: (i32, i32),
        acc: &mut [f32; 4],
    ) -> u64 {
        #[cfg(target_arch = "x86_64")]
        if !self.settings.shade {
            return self.march_sse(tri, ray, range, acc);
        }
        self.march_scalar(tri, ray, range, acc)
    }

    /// [`RayCaster::march`] without shading, four lanes at a time (SSE2, part of the x86_64
    /// baseline): the position's three axes, the four x-lerps of a cell, the two y-lerps and
    /// the RGBA composite each take one vector operation per scalar operation they replace.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn march_sse<T: Gather>(
        &self,
        tri: &Trilinear<'_, T>,
        ray: &IndexRay,
        range: (i32, i32),
        acc: &mut [f32; 4],
    ) -> u64 {
        if self.avx2 && super::avx2::fits(tri) {
            let mut a = super::avx2::load(acc);
            // SAFETY: `avx2` is only set where the CPU has AVX2; `fits` was checked.
            let (n, rest) = unsafe {
                super::avx2::march(
                    tri,
                    self.cls.view(),
                    self.settings.step,
                    self.settings.ert,
                    ray,
                    range,
                    &mut a,
                )
            };
            super::avx2::store(&a, acc);
            return match rest {
                None => n,
                // The last cells of the data: the one-sample loop finishes the ray.
                Some(k) => n + self.march_sse_one(tri, ray, (k, range.1), acc),
            };
        }
        self.march_sse_one(tri, ray, range, acc)
    }

    /// [`RayCaster::march_sse`] one sample at a time.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn march_sse_one<T: Gather>(
        &self,
        tri: &Trilinear<'_, T>,
        ray: &IndexRay,
        range: (i32, i32),
        acc: &mut [f32; 4],
    ) -> u64 {
        // Decided once per ray rather than per sample.
        if T::PAIRS && tri.step[0] == 1 {
            self.march_sse_with::<T, true>(tri, ray, range, acc)
        } else {
            self.march_sse_with::<T, false>(tri, ray, range, acc)
        }
    }

    /// [`RayCaster::march_sse`] with the corner gather fixed: [`GatherOne::corners`] when
    /// `PAIRS` (then `T::PAIRS` and a unit x step), [`corners_generic`] otherwise.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    #[allow(clippy::cast_precision_loss, clippy::cast_sign_loss)]
    fn march_sse_with<T: Gather, const PAIRS: bool>(
        &self,
        tri: &Trilinear<'_, T>,
        ray: &IndexRay,
        (k0, k1): (i32, i32),
        acc: &mut [f32; 4],
    ) -> u64 {
        debug_assert!(!PAIRS || (T::PAIRS && tri.step[0] == 1));
        let (v, steps) = (tri.v, tri.step);
        let cls = self.cls.view();
        use std::arch::x86_64::{
            _mm_add_ps, _mm_cvtepi32_ps, _mm_cvtsi128_si32, _mm_cvtss_f32, _mm_cvttps_epi32,
            _mm_loadu_ps, _mm_max_ps, _mm_min_ps, _mm_movehl_ps, _mm_mul_ps, _mm_set1_ps,
            _mm_setr_ps, _mm_setzero_ps, _mm_shuffle_epi32, _mm_shuffle_ps, _mm_storeu_ps,
            _mm_sub_ps,
        };
        debug_assert!(!self.settings.shade);
        let step = self.settings.step;
        let ert = self.settings.ert;
        // SAFETY: SSE2 is part of the x86_64 baseline; the loads, stores and gathers are
        // justified where they happen.
        unsafe {
            let o = _mm_setr_ps(ray.o[0], ray.o[1], ray.o[2], 0.0);
            let d = _mm_setr_ps(ray.d[0], ray.d[1], ray.d[2], 0.0);
            let zero = _mm_setzero_ps();
            let max = _mm_setr_ps(tri.max[0], tri.max[1], tri.max[2], 0.0);
            let origin = _mm_setr_ps(tri.origin[0], tri.origin[1], tri.origin[2], 0.0);
            // min(floor(x), last) = floor(min(x, last)) for x ≥ 0 and an integer `last`; cells
            // are below 2^24 per axis, so the float is exact.
            let last = _mm_setr_ps(
                tri.last_cell[0] as f32,
                tri.last_cell[1] as f32,
                tri.last_cell[2] as f32,
                0.0,
            );
            let [_, s1, s2] = tri.stride;
            debug_assert_eq!(tri.stride[0], 1);
            // SAFETY (loads): `acc` holds four floats.
            let mut a = _mm_loadu_ps(acc.as_ptr());
            let mut a3 = acc[3];
            let mut n = 0u64;
            for k in k0..k1 {
                if a3 >= ert {
                    break;
                }
                let t = k as f32 * step;
                // Lane-wise o + t·d: the scalar expression per axis (lane 3 stays 0).
                let p = _mm_add_ps(o, _mm_mul_ps(_mm_set1_ps(t), d));
                // As `p.max(0.0).min(max)`: `maxps` returns its second operand (0) for NaN.
                let x = _mm_max_ps(p, zero);
                let x = _mm_sub_ps(_mm_min_ps(x, max), origin);
                let i = _mm_cvttps_epi32(_mm_min_ps(_mm_max_ps(x, zero), last));
                let f = _mm_sub_ps(x, _mm_cvtepi32_ps(i));
                // Non-negative: zero extension (free) rather than sign extension.
                let i0 = _mm_cvtsi128_si32(i) as u32 as usize;
                let i1 = _mm_cvtsi128_si32(_mm_shuffle_epi32::<0x55>(i)) as u32 as usize;
                let i2 = _mm_cvtsi128_si32(_mm_shuffle_epi32::<0xAA>(i)) as u32 as usize;
                let base = i0 + i1 * s1 + i2 * s2;
                debug_assert!(base + tri.step.iter().sum::<usize>() < tri.v.len());
                // SAFETY: each axis index is clamped to [0, dims-2] (or 0 with a zero step on a
                // one-voxel axis), so base plus any combination of steps stays inside the volume.
                let (lo, hi) = if PAIRS {
                    T::corners(v, base, steps)
                } else {
                    corners_generic(v, base, steps)
                };
                // [c00, c01, c10, c11] = lo + (hi − lo)·fx
                let c = _mm_add_ps(
                    lo,
                    _mm_mul_ps(_mm_sub_ps(hi, lo), _mm_shuffle_ps::<0x00>(f, f)),
                );
                // [c0, c1, …] = [c00, c01] + ([c10, c11] − [c00, c01])·fy
                let c = _mm_add_ps(
                    c,
                    _mm_mul_ps(
                        _mm_sub_ps(_mm_movehl_ps(c, c), c),
                        _mm_shuffle_ps::<0x55>(f, f),
                    ),
                );
                let c0 = _mm_cvtss_f32(c);
                let c1 = _mm_cvtss_f32(_mm_shuffle_ps::<0x55>(c, c));
                let fz = _mm_cvtss_f32(_mm_shuffle_ps::<0xAA>(f, f));
                let s = cls.sample(c0 + (c1 - c0) * fz);
                n += 1;
                if s[3] == 0.0 {
                    continue;
                }
                let w = 1.0 - a3;
                // SAFETY (loads): `s` holds four floats.
                let sv = _mm_loadu_ps(s.as_ptr());
                a = _mm_add_ps(a, _mm_mul_ps(_mm_set1_ps(w), sv));
                a3 += w * s[3];
            }
            // SAFETY (stores): `acc` holds four floats.
            _mm_storeu_ps(acc.as_mut_ptr(), a);
            debug_assert!(acc[3].to_bits() == a3.to_bits());
            n
        }
    }

    /// The scalar sample loop: the definition every path of [`RayCaster::march`] follows.
    #[inline(always)]
    #[allow(clippy::cast_precision_loss)]
    fn march_scalar<T: Voxel>(
        &self,
        tri: &Trilinear<'_, T>,
        ray: &IndexRay,
        (k0, k1): (i32, i32),
        acc: &mut [f32; 4],
    ) -> u64 {
        let step = self.settings.step;
        let ert = self.settings.ert;
        let mut n = 0u64;
        for k in k0..k1 {
            if acc[3] >= ert {
                break;
            }
            let t = k as f32 * step;
            let p = [
                ray.o[0] + t * ray.d[0],
                ray.o[1] + t * ray.d[1],
                ray.o[2] + t * ray.d[2],
            ];
            let mut s = self.cls.sample(tri.sample(p));
            n += 1;
            if s[3] == 0.0 {
                continue;
            }
            if self.settings.shade {
                let l = self.lambert(tri, p, ray.dir);
                s[0] *= l;
                s[1] *= l;
                s[2] *= l;
            }
            let w = 1.0 - acc[3];
            acc[0] += w * s[0];
            acc[1] += w * s[1];
            acc[2] += w * s[2];
            acc[3] += w * s[3];
        }
        n
    }

    /// Ambient + diffuse factor with a headlight; the gradient uses central differences at
    /// ±½ voxel so that it reads only the brick's ghost layer.
    fn lambert<T: Voxel>(&self, tri: &Trilinear<'_, T>, p: [f32; 3], dir: [f32; 3]) -> f32 {
        let sp = self.volume.spacing();
        let mut g = [0f32; 3];
        for a in 0..3 {
            let (mut lo, mut hi) = (p, p);
            lo[a] -= 0.5;
            hi[a] += 0.5;
            g[a] = (tri.sample(hi) - tri.sample(lo)) / sp[a];
        }
        let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        if len <= f32::EPSILON {
            return 1.0;
        }
        let ndotl = ((g[0] * dir[0] + g[1] * dir[1] + g[2] * dir[2]) / len).abs();
        0.3 + 0.7 * ndotl
    }
}
