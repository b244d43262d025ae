//! The sample loop on AVX2: eight samples of one ray at a time.
//!
//! A ray's samples are independent of each other until they are composited, so the
//! positions, cell indices, corner gathers, trilinear weights, classification bins and
//! opacities of eight consecutive samples are computed lane-wise, with exactly the float
//! operations of the scalar definition ([`super::super::generic::march`]: no fused multiply–adds),
//! and only the composite, which carries the accumulator from sample to sample, runs one
//! sample at a time. Eight samples that all classify as transparent leave the accumulator
//! untouched and are skipped as a whole: that is most of the samples in the empty space
//! around real data.
//!
//! Shading computes the gradients of the eight lanes' cells
//! ([`crate::render::sampler::Cell::gradient`]) and their shading factors
//! ([`super::super::generic::lambert`]) lane-wise from the corners already in registers,
//! with the scalar operations in their order, only for runs of eight samples of which some
//! are not transparent: a vector operation costs the same for one live lane as for eight,
//! and the composite uses the factor only for samples whose opacity is above zero.
//!
//! The eight gathers per sample are independent loads that the core keeps in flight
//! together, where the one-sample loop issues them a sample at a time.

use std::arch::x86_64::{
    __m128, __m256, __m256i, _mm256_add_epi32, _mm256_add_ps, _mm256_and_si256,
    _mm256_castsi256_ps, _mm256_cmpgt_epi32, _mm256_cvtepi32_ps, _mm256_cvttps_epi32,
    _mm256_i32gather_ps, _mm256_mask_i32gather_epi32, _mm256_mask_i32gather_ps, _mm256_max_ps,
    _mm256_min_ps, _mm256_movemask_ps, _mm256_mul_ps, _mm256_mullo_epi32, _mm256_set1_epi32,
    _mm256_set1_ps, _mm256_setr_epi32, _mm256_setzero_ps, _mm256_setzero_si256, _mm256_slli_epi32,
    _mm256_srai_epi32, _mm256_srli_epi32, _mm256_storeu_si256, _mm256_sub_ps, _mm_add_ps,
    _mm_loadu_ps, _mm_mul_ps, _mm_set1_ps, _mm_storeu_ps,
};

use super::super::generic::{AMBIENT, DIFFUSE};
use super::super::MarchParams;

use crate::render::lattice::IndexRay;
use crate::render::sampler::TrilinearSampler;
use crate::render::transfer_function::BIN_MAX;
use crate::volume::Voxel;

/// Whether this CPU runs the AVX2 loops (`POFVR_SIMD=sse2` turns them off, for
/// comparisons). Asked once per ray caster, not per ray: the feature test is cached by the
/// standard library, and the environment is read once per caster. The packet loops count
/// lanes with POPCNT, which every CPU with AVX2 has; it is tested all the same.
pub(crate) fn available() -> bool {
    std::env::var("POFVR_SIMD").map_or(true, |s| !s.eq_ignore_ascii_case("sse2"))
        && std::arch::is_x86_feature_detected!("avx2")
        && std::arch::is_x86_feature_detected!("popcnt")
}

/// Voxel types whose eight cell corners the AVX2 loop gathers for eight samples at once.
pub(crate) trait Gather8: Voxel {
    /// True when [`Gather8::corners8`] reads each x pair as one 32-bit load, which needs a
    /// unit x step.
    const UNIT_X: bool;
    /// Elements past a cell's last corner that [`Gather8::corners8`] may read.
    const OVERREAD: usize;

    /// Corners `[c000, c100, c010, c110, c001, c101, c011, c111]` (digits: x, y, z) of the
    /// cells at `base`, lane by lane, converted to `f32`.
    ///
    /// # Safety
    /// AVX2 is available; for every lane `base + sx + sy + sz + OVERREAD < v.len()`, and
    /// `sx == 1` where `UNIT_X` is true.
    unsafe fn corners8(v: &[Self], base: __m256i, step: [usize; 3]) -> [__m256; 8];

    /// [`Gather8::corners8`] by `vpgatherdd`, one instruction per word for the eight lanes
    /// (the packet loop's form where gathers measured faster, `super::gather`): the same
    /// words, so the same corners, for the lanes whose sign bit is set in `mask`; the
    /// others read nothing and their corners are 0. The packet loop masks the lanes
    /// outside their ray's samples (and, lane by lane, those that have just leapt), so
    /// that no read waits on the occupancy lookup (`packet::march8`'s `sample!`).
    ///
    /// # Safety
    /// As [`Gather8::corners8`], for the lanes in `mask`.
    unsafe fn corners8_gathered(
        v: &[Self],
        base: __m256i,
        step: [usize; 3],
        mask: __m256i,
    ) -> [__m256; 8];
}

/// The four 32-bit words at elements `base`, `base + sy`, `base + sz`, `base + sy + sz`,
/// lane by lane: a corner and its x neighbour for 16-bit voxels, and two more bytes for
/// 8-bit ones. Scalar loads rather than `vpgatherdd`, which on common cores is slower
/// than eight loads.
///
/// # Safety
/// Every word lies inside `v`'s allocation.
#[inline(always)]
unsafe fn words<T>(v: &[T], base: __m256i, sy: usize, sz: usize) -> [__m256i; 4] {
    let mut b = [0u32; 8];
    unsafe {
        _mm256_storeu_si256(b.as_mut_ptr().cast(), base);
        let p = v.as_ptr();
        let at = |i: u32, off: usize| p.add(i as usize + off).cast::<i32>().read_unaligned();
        let w = |off: usize| {
            std::arch::x86_64::_mm256_setr_epi32(
                at(b[0], off),
                at(b[1], off),
                at(b[2], off),
                at(b[3], off),
                at(b[4], off),
                at(b[5], off),
                at(b[6], off),
                at(b[7], off),
            )
        };
        [w(0), w(sy), w(sz), w(sy + sz)]
    }
}

/// The words of [`words`] by four `vpgatherdd`, for elements `S` bytes wide, of the lanes
/// whose sign bit is set in `mask` (0 in the others, which read nothing).
///
/// # Safety
/// AVX2 is available; every word of a lane in `mask` lies inside `v`'s allocation;
/// offsets are below 2^31 ([`fits`]).
#[inline(always)]
unsafe fn words_gathered<T, const S: i32>(
    v: &[T],
    base: __m256i,
    sy: usize,
    sz: usize,
    mask: __m256i,
) -> [__m256i; 4] {
    let p = v.as_ptr().cast::<i32>();
    // SAFETY: the caller's.
    let at = |off: usize| unsafe {
        _mm256_mask_i32gather_epi32::<S>(
            _mm256_setzero_si256(),
            p,
            _mm256_add_epi32(base, _mm256_set1_epi32(off as i32)),
            mask,
        )
    };
    [at(0), at(sy), at(sz), at(sy + sz)]
}

/// The corners of [`Gather8::corners8`] from the four words of [`words`]: `lo` and `hi`
/// take a word's corner and its x neighbour.
#[inline(always)]
fn pairs(
    words: [__m256i; 4],
    lo: impl Fn(__m256i) -> __m256,
    hi: impl Fn(__m256i) -> __m256,
) -> [__m256; 8] {
    let [w00, w10, w01, w11] = words;
    [
        lo(w00),
        hi(w00),
        lo(w10),
        hi(w10),
        lo(w01),
        hi(w01),
        lo(w11),
        hi(w11),
    ]
}

/// 8-bit corners from their words: a corner in the low byte, its x neighbour above it.
///
/// # Safety
/// AVX2 is available.
#[inline(always)]
unsafe fn u8_pairs(w: [__m256i; 4]) -> [__m256; 8] {
    // SAFETY: the caller's.
    unsafe {
        let m = _mm256_set1_epi32(0xFF);
        let lo = |w| _mm256_cvtepi32_ps(_mm256_and_si256(w, m));
        let hi = |w| _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32::<8>(w), m));
        pairs(w, lo, hi)
    }
}

/// Unsigned 16-bit corners from their words: a corner in the low half, its x neighbour in
/// the high one.
///
/// # Safety
/// AVX2 is available.
#[inline(always)]
unsafe fn u16_pairs(w: [__m256i; 4]) -> [__m256; 8] {
    // SAFETY: the caller's.
    unsafe {
        let m = _mm256_set1_epi32(0xFFFF);
        let lo = |w| _mm256_cvtepi32_ps(_mm256_and_si256(w, m));
        let hi = |w| _mm256_cvtepi32_ps(_mm256_srli_epi32::<16>(w));
        pairs(w, lo, hi)
    }
}

/// Signed 16-bit corners from their words, as [`u16_pairs`]: arithmetic shifts
/// sign-extend each half.
///
/// # Safety
/// AVX2 is available.
#[inline(always)]
unsafe fn i16_pairs(w: [__m256i; 4]) -> [__m256; 8] {
    // SAFETY: the caller's.
    unsafe {
        let lo = |w| _mm256_cvtepi32_ps(_mm256_srai_epi32::<16>(_mm256_slli_epi32::<16>(w)));
        let hi = |w| _mm256_cvtepi32_ps(_mm256_srai_epi32::<16>(w));
        pairs(w, lo, hi)
    }
}

impl Gather8 for u8 {
    const UNIT_X: bool = true;
    const OVERREAD: usize = 2;

    #[inline(always)]
    unsafe fn corners8(v: &[u8], base: __m256i, [_, sy, sz]: [usize; 3]) -> [__m256; 8] {
        // SAFETY: each 32-bit word starts at a corner and ends OVERREAD bytes past its x
        // neighbour (caller).
        unsafe { u8_pairs(words(v, base, sy, sz)) }
    }

    #[inline(always)]
    unsafe fn corners8_gathered(
        v: &[u8],
        base: __m256i,
        [_, sy, sz]: [usize; 3],
        mask: __m256i,
    ) -> [__m256; 8] {
        // SAFETY: as `corners8`, for the lanes in `mask`.
        unsafe { u8_pairs(words_gathered::<u8, 1>(v, base, sy, sz, mask)) }
    }
}

impl Gather8 for u16 {
    const UNIT_X: bool = true;
    const OVERREAD: usize = 0;

    #[inline(always)]
    unsafe fn corners8(v: &[u16], base: __m256i, [_, sy, sz]: [usize; 3]) -> [__m256; 8] {
        // SAFETY: each 32-bit word is a corner and its x neighbour (caller).
        unsafe { u16_pairs(words(v, base, sy, sz)) }
    }

    #[inline(always)]
    unsafe fn corners8_gathered(
        v: &[u16],
        base: __m256i,
        [_, sy, sz]: [usize; 3],
        mask: __m256i,
    ) -> [__m256; 8] {
        // SAFETY: as `corners8`, for the lanes in `mask`.
        unsafe { u16_pairs(words_gathered::<u16, 2>(v, base, sy, sz, mask)) }
    }
}

impl Gather8 for i16 {
    const UNIT_X: bool = true;
    const OVERREAD: usize = 0;

    #[inline(always)]
    unsafe fn corners8(v: &[i16], base: __m256i, [_, sy, sz]: [usize; 3]) -> [__m256; 8] {
        // SAFETY: each 32-bit word is a corner and its x neighbour (caller).
        unsafe { i16_pairs(words(v, base, sy, sz)) }
    }

    #[inline(always)]
    unsafe fn corners8_gathered(
        v: &[i16],
        base: __m256i,
        [_, sy, sz]: [usize; 3],
        mask: __m256i,
    ) -> [__m256; 8] {
        // SAFETY: as `corners8`, for the lanes in `mask`.
        unsafe { i16_pairs(words_gathered::<i16, 2>(v, base, sy, sz, mask)) }
    }
}

impl Gather8 for f32 {
    const UNIT_X: bool = false;
    const OVERREAD: usize = 0;

    #[inline(always)]
    unsafe fn corners8_gathered(
        v: &[f32],
        base: __m256i,
        [sx, sy, sz]: [usize; 3],
        mask: __m256i,
    ) -> [__m256; 8] {
        let p = v.as_ptr();
        // SAFETY: every offset of a lane in `mask` is a corner of its cell (caller).
        unsafe {
            let mask = _mm256_castsi256_ps(mask);
            let at = |off: usize| {
                let off = _mm256_set1_epi32(off as i32);
                _mm256_mask_i32gather_ps::<4>(
                    _mm256_setzero_ps(),
                    p,
                    _mm256_add_epi32(base, off),
                    mask,
                )
            };
            [
                at(0),
                at(sx),
                at(sy),
                at(sy + sx),
                at(sz),
                at(sz + sx),
                at(sz + sy),
                at(sz + sy + sx),
            ]
        }
    }

    #[inline(always)]
    unsafe fn corners8(v: &[f32], base: __m256i, [sx, sy, sz]: [usize; 3]) -> [__m256; 8] {
        let p = v.as_ptr();
        // SAFETY: every offset is a corner of the cell (caller).
        unsafe {
            let at = |off: usize| {
                let off = _mm256_set1_epi32(off as i32);
                _mm256_i32gather_ps::<4>(p, _mm256_add_epi32(base, off))
            };
            [
                at(0),
                at(sx),
                at(sy),
                at(sy + sx),
                at(sz),
                at(sz + sx),
                at(sz + sy),
                at(sz + sy + sx),
            ]
        }
    }
}

/// A cell's trilinear interpolation, lane-wise, in the reference's order
/// ([`crate::render::sampler::Cell`]): the x lerps, the y lerps, and the value, kept for
/// [`gradient8`].
pub(crate) struct Lerps8 {
    pub(crate) c00: __m256,
    pub(crate) c10: __m256,
    pub(crate) c01: __m256,
    pub(crate) c11: __m256,
    pub(crate) c0: __m256,
    pub(crate) c1: __m256,
    pub(crate) value: __m256,
}

/// `a + (b − a)·w`, lane-wise (the reference's lerp: no fused multiply–add).
///
/// # Safety
/// AVX is available.
#[inline(always)]
unsafe fn lerp8(a: __m256, b: __m256, w: __m256) -> __m256 {
    // SAFETY: the caller's.
    unsafe { _mm256_add_ps(a, _mm256_mul_ps(_mm256_sub_ps(b, a), w)) }
}

/// The trilinear value of corners `c` (as [`Gather8::corners8`] orders them) at
/// fractions `f`, for the sample loops of one ray and of packets alike.
///
/// # Safety
/// AVX is available.
#[inline(always)]
pub(crate) unsafe fn trilinear8(c: &[__m256; 8], f: &[__m256; 3]) -> Lerps8 {
    let [c000, c100, c010, c110, c001, c101, c011, c111] = *c;
    // SAFETY: the caller's.
    unsafe {
        let (c00, c10) = (lerp8(c000, c100, f[0]), lerp8(c010, c110, f[0]));
        let (c01, c11) = (lerp8(c001, c101, f[0]), lerp8(c011, c111, f[0]));
        let (c0, c1) = (lerp8(c00, c10, f[1]), lerp8(c01, c11, f[1]));
        let value = lerp8(c0, c1, f[2]);
        Lerps8 {
            c00,
            c10,
            c01,
            c11,
            c0,
            c1,
            value,
        }
    }
}

/// `Cell::gradient`, lane-wise, from the corners and the lerps of [`trilinear8`].
///
/// # Safety
/// AVX is available.
#[inline(always)]
pub(crate) unsafe fn gradient8(c: &[__m256; 8], l: &Lerps8, f: &[__m256; 3]) -> [__m256; 3] {
    let [c000, c100, c010, c110, c001, c101, c011, c111] = *c;
    // SAFETY: the caller's.
    unsafe {
        let (d00, d10) = (_mm256_sub_ps(c100, c000), _mm256_sub_ps(c110, c010));
        let (d01, d11) = (_mm256_sub_ps(c101, c001), _mm256_sub_ps(c111, c011));
        let (e0, e1) = (_mm256_sub_ps(l.c10, l.c00), _mm256_sub_ps(l.c11, l.c01));
        let (x0, x1) = (lerp8(d00, d10, f[1]), lerp8(d01, d11, f[1]));
        [
            lerp8(x0, x1, f[2]),
            lerp8(e0, e1, f[2]),
            _mm256_sub_ps(l.c1, l.c0),
        ]
    }
}

/// The classification's bins of `value`, as `ClassifierView::sample`: `maxps` returns its
/// second operand (0) for NaN.
///
/// # Safety
/// AVX is available.
#[inline(always)]
pub(crate) unsafe fn bins8(value: __m256, lo: __m256, scale: __m256, bin_max: __m256) -> __m256i {
    // SAFETY: the caller's.
    unsafe {
        let x = _mm256_min_ps(
            _mm256_max_ps(
                _mm256_mul_ps(_mm256_sub_ps(value, lo), scale),
                _mm256_setzero_ps(),
            ),
            bin_max,
        );
        _mm256_cvttps_epi32(x)
    }
}

/// Whether [`march`] can take `tri`: 32-bit lane indices, and the unit x step the type's
/// gather needs.
pub(crate) fn fits<T: Gather8, const COPY: bool>(tri: &TrilinearSampler<'_, T, COPY>) -> bool {
    tri.v.len() < i32::MAX as usize && (!T::UNIT_X || tri.step[0] == 1)
}

/// The loop's state at a sample index: premultiplied RGBA so far (`a3` is its alpha, kept
/// apart so that the termination test reads a scalar register).
pub(crate) struct Acc {
    pub(crate) a: __m128,
    pub(crate) a3: f32,
}

/// The shading factors of eight samples, lane-wise [`super::super::generic::lambert`] of
/// the gradients `g` (index space) with the volume's `spacing` and the ray's `dir`.
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) fn lambert8(g: [__m256; 3], spacing: [__m256; 3], dir: [__m256; 3]) -> __m256 {
    use std::arch::x86_64::{
        _mm256_andnot_ps, _mm256_blendv_ps, _mm256_cmp_ps, _mm256_div_ps, _mm256_sqrt_ps,
        _CMP_LE_OQ,
    };
    let g = [
        _mm256_div_ps(g[0], spacing[0]),
        _mm256_div_ps(g[1], spacing[1]),
        _mm256_div_ps(g[2], spacing[2]),
    ];
    let dot3 = |a: [__m256; 3], b: [__m256; 3]| {
        _mm256_add_ps(
            _mm256_add_ps(_mm256_mul_ps(a[0], b[0]), _mm256_mul_ps(a[1], b[1])),
            _mm256_mul_ps(a[2], b[2]),
        )
    };
    // `sqrtps` and `divps` round correctly, as `f32::sqrt` and `/` do.
    let len = _mm256_sqrt_ps(dot3(g, g));
    let ndotl = _mm256_andnot_ps(_mm256_set1_ps(-0.0), _mm256_div_ps(dot3(g, dir), len));
    let l = _mm256_add_ps(
        _mm256_set1_ps(AMBIENT),
        _mm256_mul_ps(_mm256_set1_ps(DIFFUSE), ndotl),
    );
    // Where the gradient gives no normal the factor is 1 (and the NaN of 0/0 is dropped).
    let flat = _mm256_cmp_ps::<_CMP_LE_OQ>(len, _mm256_set1_ps(f32::EPSILON));
    _mm256_blendv_ps(l, _mm256_set1_ps(1.0), flat)
}

/// Composites samples `k0..k1` of `ray` into `acc` as [`super::super::generic::march`] does, bit
/// for bit, shaded when `SHADE` (then `p.shade` is set); returns the samples taken and, when
/// a cell near the end of the data would have made a gather read past it, the sample index
/// to go on from with another path.
///
/// # Safety
/// AVX2 is available and [`fits`] holds.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn march<T: Gather8, const COPY: bool, const SHADE: bool>(
    p: &MarchParams<'_>,
    tri: &TrilinearSampler<'_, T, COPY>,
    ray: &IndexRay,
    (k0, k1): (i32, i32),
    acc: &mut Acc,
) -> (u64, Option<i32>) {
    debug_assert!(fits(tri));
    debug_assert_eq!(SHADE, p.shade.is_some());
    let (cls, step, ert) = (p.cls, p.step, p.ert);
    let splat = |v: [f32; 3]| std::array::from_fn(|a| _mm256_set1_ps(v[a]));
    let (spacing, dir) = (splat(p.shade.unwrap_or([1.0; 3])), splat(ray.dir));
    let mut light = [1f32; 8];
    let v = tri.v;
    let [_, s1, s2] = tri.stride;
    let [sx, sy, sz] = tri.step;
    // The largest base whose reads stay inside the data; -1 when none does.
    let limit = (v.len() as i64 - 1 - (sx + sy + sz + T::OVERREAD) as i64).max(-1) as i32;
    let limit = _mm256_set1_epi32(limit);
    let zero = _mm256_setzero_ps();
    let axis = |a: usize| {
        (
            _mm256_set1_ps(ray.o[a]),
            _mm256_set1_ps(ray.d[a]),
            _mm256_set1_ps(tri.max[a]),
            _mm256_set1_ps(tri.origin[a]),
            // Cells are below 2^24 per axis, so the float is exact.
            _mm256_set1_ps(tri.last_cell[a] as f32),
        )
    };
    let axes = [axis(0), axis(1), axis(2)];
    let strides = [
        _mm256_set1_epi32(1),
        _mm256_set1_epi32(s1 as i32),
        _mm256_set1_epi32(s2 as i32),
    ];
    let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let stepv = _mm256_set1_ps(step);
    let (lo, scale, bin_max) = (
        _mm256_set1_ps(cls.lo),
        _mm256_set1_ps(cls.scale),
        _mm256_set1_ps(BIN_MAX),
    );
    let rgba = cls.rgba;
    let mut bins = [0i32; 8];
    let mut n = 0u64;
    let mut k = k0;
    while k < k1 {
        if acc.a3 >= ert {
            break;
        }
        // t = k·step and p = o + t·d, lane-wise as the scalar expression.
        let t = _mm256_mul_ps(
            _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(k), lanes)),
            stepv,
        );
        let mut base = _mm256_setzero_si256();
        let mut f = [zero; 3];
        for (a, &(o, d, max, origin, last)) in axes.iter().enumerate() {
            let p = _mm256_add_ps(o, _mm256_mul_ps(t, d));
            let x = _mm256_sub_ps(_mm256_min_ps(_mm256_max_ps(p, zero), max), origin);
            let i = _mm256_cvttps_epi32(_mm256_min_ps(_mm256_max_ps(x, zero), last));
            f[a] = _mm256_sub_ps(x, _mm256_cvtepi32_ps(i));
            base = _mm256_add_epi32(base, _mm256_mullo_epi32(i, strides[a]));
        }
        let count = (k1 - k).min(8);
        if _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(base, limit))) != 0 {
            return (n, Some(k));
        }
        // SAFETY: every lane's position is clamped into the data, so its cell's corners are
        // inside `v`, and `limit` keeps the overread inside too.
        let c = unsafe { T::corners8(v, base, tri.step) };
        // SAFETY: AVX2 (this function's target features).
        let (l, b) = unsafe {
            let l = trilinear8(&c, &f);
            let b = bins8(l.value, lo, scale, bin_max);
            (l, b)
        };
        // SAFETY: `bins` holds eight i32.
        unsafe { _mm256_storeu_si256(bins.as_mut_ptr().cast(), b) };
        let live = &bins[..count as usize];
        // Opacities are ≥ 0, so their bits are all zero exactly when they are 0.
        // SAFETY: bins are in [0, TF_BINS) and the table holds TF_BINS entries.
        let opaque = live.iter().fold(0u32, |o, &bin| {
            o | unsafe { rgba.get_unchecked(bin as u32 as usize) }[3].to_bits()
        });
        if opaque == 0 {
            n += count as u64;
            k += 8;
            continue;
        }
        if SHADE {
            // SAFETY: AVX2 (this function's target features).
            let g = unsafe { gradient8(&c, &l, &f) };
            // SAFETY: `light` holds eight f32.
            unsafe {
                std::arch::x86_64::_mm256_storeu_ps(light.as_mut_ptr(), lambert8(g, spacing, dir));
            }
        }
        for (&bin, &l) in live.iter().zip(&light) {
            if acc.a3 >= ert {
                return (n, None);
            }
            n += 1;
            // SAFETY: as for the gather above.
            let s = unsafe { rgba.get_unchecked(bin as u32 as usize) };
            if s[3] == 0.0 {
                continue;
            }
            let w = 1.0 - acc.a3;
            // SAFETY: `s` holds four floats.
            let mut sv = unsafe { _mm_loadu_ps(s.as_ptr()) };
            if SHADE {
                // Colour times l, opacity times 1 (exact).
                sv = _mm_mul_ps(sv, std::arch::x86_64::_mm_setr_ps(l, l, l, 1.0));
            }
            acc.a = _mm_add_ps(acc.a, _mm_mul_ps(_mm_set1_ps(w), sv));
            acc.a3 += w * s[3];
        }
        k += 8;
    }
    (n, None)
}

/// Stores the accumulator back.
pub(crate) fn store(acc: &Acc, out: &mut [f32; 4]) {
    // SAFETY: SSE is part of the x86_64 baseline; `out` holds four floats.
    unsafe { _mm_storeu_ps(out.as_mut_ptr(), acc.a) };
    debug_assert_eq!(out[3].to_bits(), acc.a3.to_bits());
}

/// Loads the accumulator.
pub(crate) fn load(acc: &[f32; 4]) -> Acc {
    // SAFETY: SSE is part of the x86_64 baseline; `acc` holds four floats.
    Acc {
        a: unsafe { _mm_loadu_ps(acc.as_ptr()) },
        a3: acc[3],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::arch::x86_64::_mm256_loadu_si256;

    #[test]
    fn masked_gathers_read_the_words_the_per_lane_loads_read() {
        if !available() {
            println!("skipped: this CPU does not run the AVX2 loops");
            return;
        }
        // Each type's corners of the same cells, both ways, bit for bit, in the lanes of
        // the mask, and 0 in the others, whose bases lie far outside the data (a masked
        // lane reads nothing).
        fn check<T: Gather8>(v: &[T], step: [usize; 3]) {
            let last = (v.len() - 1 - step[0] - step[1] - step[2] - T::OVERREAD) as i32;
            for mask in [0xFFu32, 0xA5, 0x01, 0] {
                let b: [i32; 8] = std::array::from_fn(|j| {
                    if mask >> j & 1 != 0 {
                        last - (j as i32 * 37) % (last + 1)
                    } else {
                        i32::MAX / 2
                    }
                });
                let inside = b.map(|b| b.min(last));
                let lanes: [i32; 8] = std::array::from_fn(|j| -((mask >> j & 1) as i32));
                // SAFETY: this CPU runs the loops; every base of a lane in the mask leaves
                // its words inside `v`, and the per-lane loads read the clamped bases.
                let (g, l) = unsafe { corners_both(v, &b, &inside, &lanes, step) };
                for j in 0..8 {
                    let want = if mask >> j & 1 != 0 {
                        l.map(|c| c[j])
                    } else {
                        [0; 8]
                    };
                    assert_eq!(
                        g.map(|c| c[j]),
                        want,
                        "{} lane {j}",
                        std::any::type_name::<T>()
                    );
                }
            }
        }
        let n = 6 * 5 * 4;
        let step = [1, 6, 30];
        check::<u8>(
            &(0..n).map(|i| (i * 7 % 256) as u8).collect::<Vec<_>>(),
            step,
        );
        check::<u16>(&(0..n).map(|i| (i * 977) as u16).collect::<Vec<_>>(), step);
        check::<i16>(
            &(0..n)
                .map(|i| (i * 977) as i16 - 20_000)
                .collect::<Vec<_>>(),
            step,
        );
        check::<f32>(&(0..n).map(|i| i as f32 * -0.37).collect::<Vec<_>>(), step);
    }

    /// The corners of the cells at `b` by [`Gather8::corners8_gathered`] in the lanes of
    /// `mask` (all bits set or none, lane by lane), and those at `inside` by
    /// [`Gather8::corners8`], as bits.
    #[target_feature(enable = "avx2")]
    unsafe fn corners_both<T: Gather8>(
        v: &[T],
        b: &[i32; 8],
        inside: &[i32; 8],
        mask: &[i32; 8],
        step: [usize; 3],
    ) -> ([[u32; 8]; 8], [[u32; 8]; 8]) {
        let bits = |c: [__m256; 8]| {
            c.map(|c| {
                let mut o = [0f32; 8];
                // SAFETY: `o` holds eight f32.
                unsafe { std::arch::x86_64::_mm256_storeu_ps(o.as_mut_ptr(), c) };
                o.map(f32::to_bits)
            })
        };
        // SAFETY: caller; each array holds eight i32.
        unsafe {
            let load = |a: &[i32; 8]| _mm256_loadu_si256(a.as_ptr().cast());
            (
                bits(T::corners8_gathered(v, load(b), step, load(mask))),
                bits(T::corners8(v, load(inside), step)),
            )
        }
    }
}
