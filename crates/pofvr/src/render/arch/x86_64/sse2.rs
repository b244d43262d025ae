//! The sample loop on SSE2 (part of the x86_64 baseline), one sample at a time: the
//! position's three axes, the four x-lerps of a cell, the two y-lerps, the two y-lerps of
//! the x edges (for the gradient) and the RGBA composite each take one vector operation
//! per scalar operation they replace, with exactly the float operations of the scalar
//! loop; the rest of the gradient and the shading factor are the scalar code itself.

use std::arch::x86_64::__m128;

use super::super::generic::lambert;
use super::super::MarchParams;
use crate::render::lattice::IndexRay;
use crate::render::sampler::TrilinearSampler;
use crate::volume::Voxel;

/// Voxel types whose 8 cell corners the one-sample loop gathers.
pub(crate) trait GatherOne: Voxel {
    /// True when [`GatherOne::corners`] has a faster form for a unit x step (`sx == 1`).
    const PAIRS: bool = false;

    /// Corners `[c000, c001, c010, c011]` (low x) and `[c100, c101, c110, c111]` (high x) of
    /// the cell at `base` (lanes: z fastest, then y), converted to `f32`.
    ///
    /// # Safety
    /// `base + sx + sy + sz < v.len()`, and `sx == 1` where `PAIRS` is true.
    #[inline(always)]
    unsafe fn corners(v: &[Self], base: usize, step: [usize; 3]) -> (__m128, __m128) {
        // SAFETY: forwarded from the caller.
        unsafe { corners_generic(v, base, step) }
    }
}

/// [`GatherOne::corners`] with one scalar load and conversion per corner.
///
/// # Safety
/// `base + sx + sy + sz < v.len()`.
#[inline(always)]
unsafe fn corners_generic<T: Voxel>(
    v: &[T],
    base: usize,
    [sx, sy, sz]: [usize; 3],
) -> (__m128, __m128) {
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

    #[inline(always)]
    unsafe fn corners(v: &[u8], base: usize, step: [usize; 3]) -> (__m128, __m128) {
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

/// Composites samples `k0..k1` of `ray` behind `acc`, shaded or not, as
/// [`super::super::generic::march`] does, bit for bit; returns the samples taken.
#[inline(always)]
pub(crate) fn march<T: GatherOne, const COPY: bool>(
    p: &MarchParams<'_>,
    tri: &TrilinearSampler<'_, T, COPY>,
    ray: &IndexRay,
    range: (i32, i32),
    acc: &mut [f32; 4],
) -> u64 {
    // Decided once per ray rather than per sample.
    if T::PAIRS && tri.step[0] == 1 {
        march_with::<T, COPY, true>(p, tri, ray, range, acc)
    } else {
        march_with::<T, COPY, false>(p, tri, ray, range, acc)
    }
}

/// [`march`] with the corner gather fixed: [`GatherOne::corners`] when `PAIRS` (then
/// `T::PAIRS` and a unit x step), [`corners_generic`] otherwise.
#[inline(always)]
fn march_with<T: GatherOne, const COPY: bool, const PAIRS: bool>(
    p: &MarchParams<'_>,
    tri: &TrilinearSampler<'_, T, COPY>,
    ray: &IndexRay,
    (k0, k1): (i32, i32),
    acc: &mut [f32; 4],
) -> u64 {
    debug_assert!(!PAIRS || (T::PAIRS && tri.step[0] == 1));
    let (v, steps) = (tri.v, tri.step);
    let cls = p.cls;
    use std::arch::x86_64::{
        _mm_add_ps, _mm_cvtepi32_ps, _mm_cvtsi128_si32, _mm_cvtss_f32, _mm_cvttps_epi32,
        _mm_loadu_ps, _mm_max_ps, _mm_min_ps, _mm_movehl_ps, _mm_mul_ps, _mm_set1_ps, _mm_setr_ps,
        _mm_setzero_ps, _mm_shuffle_epi32, _mm_shuffle_ps, _mm_storeu_ps, _mm_sub_ps,
    };
    let (step, ert, shade) = (p.step, p.ert, p.shade);
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
            // The x edges [d00, d01, d10, d11] = hi − lo, and the x-lerps
            // [c00, c01, c10, c11] = lo + d·fx.
            let dx = _mm_sub_ps(hi, lo);
            let c = _mm_add_ps(lo, _mm_mul_ps(dx, _mm_shuffle_ps::<0x00>(f, f)));
            // [e0, e1, …] = [c10, c11] − [c00, c01], and [c0, c1, …] = [c00, c01] + e·fy.
            let fy = _mm_shuffle_ps::<0x55>(f, f);
            let e = _mm_sub_ps(_mm_movehl_ps(c, c), c);
            let c = _mm_add_ps(c, _mm_mul_ps(e, fy));
            let c0 = _mm_cvtss_f32(c);
            let c1 = _mm_cvtss_f32(_mm_shuffle_ps::<0x55>(c, c));
            let fz = _mm_cvtss_f32(_mm_shuffle_ps::<0xAA>(f, f));
            let s = cls.sample(c0 + (c1 - c0) * fz);
            n += 1;
            if s[3] == 0.0 {
                continue;
            }
            // SAFETY (loads): `s` holds four floats.
            let mut sv = _mm_loadu_ps(s.as_ptr());
            if let Some(spacing) = shade {
                // `Cell::gradient`: [x0, x1, …] = [d00, d01] + ([d10, d11] − [d00, d01])·fy.
                let x = _mm_add_ps(dx, _mm_mul_ps(_mm_sub_ps(_mm_movehl_ps(dx, dx), dx), fy));
                let (x0, x1) = (
                    _mm_cvtss_f32(x),
                    _mm_cvtss_f32(_mm_shuffle_ps::<0x55>(x, x)),
                );
                let (e0, e1) = (
                    _mm_cvtss_f32(e),
                    _mm_cvtss_f32(_mm_shuffle_ps::<0x55>(e, e)),
                );
                let g = [x0 + (x1 - x0) * fz, e0 + (e1 - e0) * fz, c1 - c0];
                let l = lambert(g, spacing, ray.dir);
                // Colour times l, opacity times 1 (exact).
                sv = _mm_mul_ps(sv, _mm_setr_ps(l, l, l, 1.0));
            }
            let w = 1.0 - a3;
            a = _mm_add_ps(a, _mm_mul_ps(_mm_set1_ps(w), sv));
            a3 += w * s[3];
        }
        // SAFETY (stores): `acc` holds four floats.
        _mm_storeu_ps(acc.as_mut_ptr(), a);
        debug_assert!(acc[3].to_bits() == a3.to_bits());
        n
    }
}
