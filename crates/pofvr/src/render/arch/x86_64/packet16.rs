//! The march engine's AVX-512 loop over packets of sixteen rays (4 × 4 pixels): the loop of
//! [`super::packet`], lane for lane, on vectors twice as wide.
//!
//! Each lane performs the float operations of the scalar definition
//! ([`super::super::generic::march`]) on its own ray's sample `k`, in the same order and
//! without fused multiply–adds, so every pixel is bit for bit the reference's, as in the
//! eight-lane loop; lanes take part under the same rules (masks instead of blends), and the
//! packet leaps by the same lane-wise rule ([`crate::render::skip::Skip::leap_end`]). What
//! the wider vectors buy is the arithmetic (positions, cells, lerps, classification,
//! composite, leap estimates) at half the instructions per lane; the loads (corners,
//! occupancy entries, table entries) stay one per lane, done by the eight-lane helpers on
//! each half.
//!
//! One difference in how the packet moves: where its rays are oblique to the lattice
//! ([`oblique`]), each lane keeps its own sample index, leaping or sampling on its own,
//! instead of the packet moving in lockstep. A lane's samples, and their order, are the
//! same either way; what changes is how many iterations the packet takes (the slowest
//! lane's steps instead of the union of all lanes'). Measured in `docs/results.md`.

use std::arch::x86_64::{
    __m256, __m256i, __m512, __m512i, __mmask16, _mm512_abs_ps, _mm512_add_epi32, _mm512_add_ps,
    _mm512_castps256_ps512, _mm512_castsi512_si256, _mm512_cmp_ps_mask, _mm512_cmpeq_epi32_mask,
    _mm512_cmpgt_epi32_mask, _mm512_cvtepi32_ps, _mm512_cvttps_epi32, _mm512_div_ps,
    _mm512_extracti64x4_epi64, _mm512_insertf32x8, _mm512_loadu_epi32, _mm512_loadu_ps,
    _mm512_mask_add_epi32, _mm512_mask_add_ps, _mm512_mask_blend_epi32, _mm512_mask_blend_ps,
    _mm512_mask_reduce_add_epi32, _mm512_max_epi32, _mm512_max_ps, _mm512_min_epi32, _mm512_min_ps,
    _mm512_mul_ps, _mm512_mullo_epi32, _mm512_permutexvar_epi32, _mm512_reduce_min_epi32,
    _mm512_set1_epi32, _mm512_set1_ps, _mm512_setzero_ps, _mm512_setzero_si512, _mm512_slli_epi32,
    _mm512_sqrt_ps, _mm512_srli_epi32, _mm512_storeu_epi32, _mm512_storeu_ps, _mm512_sub_epi32,
    _mm512_sub_ps, _CMP_EQ_OQ, _CMP_GT_OQ, _CMP_LE_OQ, _CMP_LT_OQ, _CMP_NEQ_UQ, _CMP_NGE_UQ,
};

use super::super::generic::{AMBIENT, DIFFUSE};
use super::super::MarchParams;
use super::gather16::{self, Gather16};
use super::packet::{corners_exact, leap_entries, rgba8, Packet, PacketStats, PacketTables};
use super::prefetch;
use crate::render::occupancy::{CELL_SHIFT, OCCUPIED};
use crate::render::sampler::TrilinearSampler;
use crate::render::skip::LEAP_MIN;

/// Rays per packet.
pub(crate) const LANES: usize = 16;

/// Whether this CPU runs the AVX-512 packet loop: AVX-512 F, BW, DQ and VL, AVX2 and POPCNT
/// (`POFVR_SIMD=avx2` or `sse2` turns it off, for comparisons).
pub(crate) fn available() -> bool {
    std::env::var("POFVR_SIMD").map_or(true, |s| {
        !s.eq_ignore_ascii_case("avx2") && !s.eq_ignore_ascii_case("sse2")
    }) && std::arch::is_x86_feature_detected!("avx2")
        && std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512bw")
        && std::arch::is_x86_feature_detected!("avx512dq")
        && std::arch::is_x86_feature_detected!("avx512vl")
        && std::arch::is_x86_feature_detected!("popcnt")
}

/// Sixteen floats as a vector.
#[target_feature(enable = "avx512f")]
#[inline]
fn vec16(v: [f32; LANES]) -> __m512 {
    // SAFETY: `v` holds sixteen f32.
    unsafe { _mm512_loadu_ps(v.as_ptr()) }
}

/// The two eight-lane halves of `v`.
#[target_feature(enable = "avx512f")]
#[inline]
pub(super) fn halves(v: __m512i) -> [__m256i; 2] {
    [_mm512_castsi512_si256(v), _mm512_extracti64x4_epi64::<1>(v)]
}

/// Two eight-lane halves as one vector.
#[target_feature(enable = "avx512f,avx512dq")]
#[inline]
pub(super) fn join(lo: __m256, hi: __m256) -> __m512 {
    _mm512_insertf32x8::<1>(_mm512_castps256_ps512(lo), hi)
}

/// Lane-wise `a <= x && x <= b`, as bits.
#[target_feature(enable = "avx512f")]
#[inline]
fn within(a: __m512i, x: __m512i, b: __m512i) -> __mmask16 {
    !(_mm512_cmpgt_epi32_mask(a, x) | _mm512_cmpgt_epi32_mask(x, b))
}

/// [`super::avx2::lambert8`] on sixteen lanes: the same operations in the same order.
#[target_feature(enable = "avx512f")]
#[inline]
fn lambert16(g: [__m512; 3], spacing: [__m512; 3], dir: [__m512; 3]) -> __m512 {
    let g = [
        _mm512_div_ps(g[0], spacing[0]),
        _mm512_div_ps(g[1], spacing[1]),
        _mm512_div_ps(g[2], spacing[2]),
    ];
    let dot3 = |a: [__m512; 3], b: [__m512; 3]| {
        _mm512_add_ps(
            _mm512_add_ps(_mm512_mul_ps(a[0], b[0]), _mm512_mul_ps(a[1], b[1])),
            _mm512_mul_ps(a[2], b[2]),
        )
    };
    // `vsqrtps` and `vdivps` round correctly, as `f32::sqrt` and `/` do.
    let len = _mm512_sqrt_ps(dot3(g, g));
    let ndotl = _mm512_abs_ps(_mm512_div_ps(dot3(g, dir), len));
    let l = _mm512_add_ps(
        _mm512_set1_ps(AMBIENT),
        _mm512_mul_ps(_mm512_set1_ps(DIFFUSE), ndotl),
    );
    // Where the gradient gives no normal the factor is 1 (and the NaN of 0/0 is dropped).
    let flat = _mm512_cmp_ps_mask::<_CMP_LE_OQ>(len, _mm512_set1_ps(f32::EPSILON));
    _mm512_mask_blend_ps(flat, l, _mm512_set1_ps(1.0))
}

/// [`super::packet`]'s `leap_end` on sixteen lanes, step for step: each lane's sample `k`
/// lies in the empty cell `c` with entry `leap`; the first sample, in `k + 1 ..= k1`, past
/// the cube of empty cells around it, every sample before it checked by the sampler's own
/// cells. Lanes whose entry is below [`LEAP_MIN`] get the exit of their own cell.
///
/// A macro, expanded in [`march16`]: as a function (with `march16`'s target features, so
/// that its closure `cells_at` could be inlined into it), whether it was inlined into
/// `march16` depended on unrelated code elsewhere in the crate (an edit to the image
/// conversion turned it into a call, `docs/results.md`, stop 39), and every leap then paid
/// two calls with their vectors through memory (3–7 % of a frame, stop 31). A
/// `#[target_feature]` function cannot be `#[inline(always)]`.
macro_rules! leap_end {
    ($kv:expr, $c:expr, $leap:expr, $r:expr, $cells_at:expr) => {{
        let (kv, c, leap, r, cells_at): (__m512i, &[__m512i; 3], __m512i, &LeapRay, _) =
            ($kv, $c, $leap, $r, $cells_at);
        let one = _mm512_set1_epi32(1);
        // The cube's half-width: distance − 1 where leaps are worth it, else the cell alone.
        let far = _mm512_cmpgt_epi32_mask(leap, _mm512_set1_epi32(LEAP_MIN - 1));
        let zero_i = _mm512_setzero_si512();
        let rad = _mm512_mask_blend_epi32(far, zero_i, _mm512_sub_epi32(leap, one));
        let zero = _mm512_setzero_ps();
        let mut lo = [zero_i; 3];
        let mut hi = [zero_i; 3];
        let mut te = _mm512_set1_ps(f32::INFINITY);
        for a in 0..3 {
            lo[a] = _mm512_max_epi32(_mm512_sub_epi32(c[a], rad), zero_i);
            hi[a] = _mm512_min_epi32(_mm512_add_epi32(c[a], rad), r.nlast[a]);
            let pos = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(r.d[a], zero);
            let neg = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(r.d[a], zero);
            let up = pos & _mm512_cmpgt_epi32_mask(r.nlast[a], hi[a]);
            let down = neg & _mm512_cmpgt_epi32_mask(lo[a], zero_i);
            let face = _mm512_mask_blend_epi32(
                up,
                _mm512_slli_epi32::<CELL_SHIFT>(lo[a]),
                _mm512_slli_epi32::<CELL_SHIFT>(_mm512_add_epi32(hi[a], one)),
            );
            let ta = _mm512_mul_ps(_mm512_sub_ps(_mm512_cvtepi32_ps(face), r.o[a]), r.inv[a]);
            let ta = _mm512_mask_blend_ps(up | down, _mm512_set1_ps(f32::INFINITY), ta);
            te = _mm512_min_ps(te, ta);
        }
        // The first sample at or past `te`, and at least the next one.
        let q = _mm512_max_ps(_mm512_min_ps(_mm512_mul_ps(te, r.inv_step), r.k1f), zero);
        let kq = _mm512_cvttps_epi32(q);
        let up = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(_mm512_cvtepi32_ps(kq), q);
        let kb = _mm512_mask_blend_epi32(up, kq, _mm512_add_epi32(kq, one));
        let kb = _mm512_min_epi32(_mm512_max_epi32(kb, _mm512_add_epi32(kv, one)), r.k1v);
        let inside = |k: __m512i| {
            let t = _mm512_mul_ps(_mm512_cvtepi32_ps(k), r.stepv);
            let c = cells_at(t);
            within(lo[0], c[0], hi[0]) & within(lo[1], c[1], hi[1]) & within(lo[2], c[2], hi[2])
        };
        // Settled by one sample where a rounding put the estimate past a face.
        let kb1 = _mm512_sub_epi32(kb, one);
        let in1 = inside(kb1);
        if in1 == 0xFFFF {
            kb
        } else {
            let in2 = inside(_mm512_sub_epi32(kb1, one));
            let fallback = _mm512_mask_blend_epi32(in2, _mm512_add_epi32(kv, one), kb1);
            _mm512_mask_blend_epi32(in1, fallback, kb)
        }
    }};
}

/// Marches `pk` front to back through the volume of `tri`, skipping the empty cells of
/// `tab`, shaded when `SHADE` (then `p.shade` is set); see the [module](self) and
/// [`super::packet::march8`], whose steps this follows one for one.
///
/// # Safety
/// AVX-512 F/BW/DQ/VL, AVX2 and POPCNT are available ([`available`]) and
/// [`super::avx2::fits`] holds; `tab` was built for this volume and classification, with
/// the padding it documents.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512dq,avx512vl,popcnt")]
pub(crate) unsafe fn march16<T: Gather16, const SHADE: bool>(
    p: &MarchParams<'_>,
    tri: &TrilinearSampler<'_, T>,
    tab: &PacketTables<'_>,
    pk: &mut Packet<LANES>,
) -> PacketStats {
    debug_assert!(super::avx2::fits(tri));
    debug_assert_eq!(SHADE, p.shade.is_some());
    let mut st = PacketStats::default();
    // Lane-wise from the rays (`packet::ray_axes`: loops, not closures).
    let ([o0, o1, o2], [d0, d1, d2], [e0, e1, e2]) = super::packet::ray_axes(&pk.rays);
    let o = [vec16(o0), vec16(o1), vec16(o2)];
    let d = [vec16(d0), vec16(d1), vec16(d2)];
    let dir = [vec16(e0), vec16(e1), vec16(e2)];
    // `1 / d`, 0 where `d` is 0: for the leap estimates only.
    let inv = d.map(|d| {
        let zero = _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(d, _mm512_setzero_ps());
        _mm512_mask_blend_ps(
            zero,
            _mm512_div_ps(_mm512_set1_ps(1.0), d),
            _mm512_setzero_ps(),
        )
    });
    let spacing: [__m512; 3] = p.shade.unwrap_or([1.0; 3]).map(|s| _mm512_set1_ps(s));
    // SAFETY: `k0` and `k1` hold sixteen i32.
    let (k0v, k1v) = unsafe {
        (
            _mm512_loadu_epi32(pk.k0.as_ptr()),
            _mm512_loadu_epi32(pk.k1.as_ptr()),
        )
    };
    let k1f = _mm512_cvtepi32_ps(k1v);
    let has = _mm512_cmpgt_epi32_mask(k1v, k0v);
    if has == 0 {
        return st;
    }
    let big = _mm512_set1_epi32(i32::MAX);
    let one = _mm512_set1_epi32(1);
    let hmin =
        |m: __mmask16, v: __m512i| _mm512_reduce_min_epi32(_mm512_mask_blend_epi32(m, big, v));
    let [r, g, b, a] = super::packet::channels(&pk.acc);
    let mut acc = [vec16(r), vec16(g), vec16(b), vec16(a)];
    let (step, ert) = (p.step, _mm512_set1_ps(p.ert));
    let stepv = _mm512_set1_ps(step);
    let inv_step = _mm512_set1_ps(1.0 / step);
    let zero = _mm512_setzero_ps();
    let maxv = tri.max.map(|m| _mm512_set1_ps(m));
    // Cells are below 2^24 per axis, so the floats are exact.
    let last = tri.last_cell.map(|c| _mm512_set1_ps(c as f32));
    let [_, s1, s2] = tri.stride;
    let strides = [1, s1 as i32, s2 as i32].map(|s| _mm512_set1_epi32(s));
    // This loop's leaps reach both ways (the octant tables are the eight-lane loop's).
    debug_assert_eq!(tab.sign, [0; 3]);
    let nlast = tab.cells.map(|n| _mm512_set1_epi32(n - 1));
    let (n0, n01) = (
        _mm512_set1_epi32(tab.cells[0]),
        _mm512_set1_epi32(tab.cells[0] * tab.cells[1]),
    );
    let v = tri.v;
    let [sx, sy, sz] = tri.step;
    // The largest base whose reads stay inside the data; -1 when none does.
    let limit = (v.len() as i64 - 1 - (sx + sy + sz + T::OVERREAD) as i64).max(-1) as i32;
    let limit = _mm512_set1_epi32(limit);
    // Where the voxels exceed the cache: each lane's element offset to the corner
    // `AHEAD_VOXELS` on, and the second line of a cell across the ray (`prefetch`).
    let ahead = p.prefetch.then(|| {
        let (off, across) = prefetch::offsets(&pk.rays, has.trailing_zeros() as usize, tri.step);
        // SAFETY: `off` holds sixteen i32.
        (unsafe { _mm512_loadu_epi32(off.as_ptr()) }, across)
    });
    let gather = p.gather;
    let cls = p.cls;
    let rgba = cls.rgba.as_ptr().cast::<f32>();
    let (lo, scale, bin_max) = (
        _mm512_set1_ps(cls.lo),
        _mm512_set1_ps(cls.scale),
        _mm512_set1_ps(crate::render::transfer_function::BIN_MAX),
    );
    let shift = |i: __m512i| _mm512_srli_epi32::<CELL_SHIFT>(i);
    // The occupancy cell per axis of each lane's sample at `t` (lane-wise `Skip::cell`).
    let cells_at = |t: __m512| {
        [0, 1, 2].map(|a| {
            let p = _mm512_add_ps(o[a], _mm512_mul_ps(t, d[a]));
            let c = _mm512_min_ps(_mm512_min_ps(_mm512_max_ps(p, zero), maxv[a]), last[a]);
            shift(_mm512_cvttps_epi32(c))
        })
    };
    let leap_ray = LeapRay {
        o,
        d,
        inv,
        k1v,
        k1f,
        nlast,
        stepv,
        inv_step,
    };
    // The occupancy cells of the last sample looked up (none yet), their entries, and
    // which of them are occupied, as bits.
    let mut last_idx = _mm512_set1_epi32(-1);
    let mut lv = [0i32; LANES];
    let mut occ_bits: __mmask16 = 0;
    // Each lane's sample at `t`: its corners' base, fractions, occupancy cell per axis, and
    // that cell's index in the table (lane-wise `TrilinearSampler::cell` and `Skip::cell`).
    let locate = |t: __m512| {
        let mut base = _mm512_setzero_si512();
        let mut f = [zero; 3];
        let mut cell = [_mm512_setzero_si512(); 3];
        for a in 0..3 {
            // The sampler's clamp, cell and fraction (the whole volume's: origin 0).
            let p = _mm512_add_ps(o[a], _mm512_mul_ps(t, d[a]));
            let x = _mm512_min_ps(_mm512_max_ps(p, zero), maxv[a]);
            let i = _mm512_cvttps_epi32(_mm512_min_ps(x, last[a]));
            f[a] = _mm512_sub_ps(x, _mm512_cvtepi32_ps(i));
            base = _mm512_add_epi32(base, _mm512_mullo_epi32(i, strides[a]));
            cell[a] = shift(i);
        }
        let idx = _mm512_add_epi32(
            _mm512_add_epi32(
                _mm512_mullo_epi32(cell[2], n01),
                _mm512_mullo_epi32(cell[1], n0),
            ),
            cell[0],
        );
        (base, f, cell, idx)
    };
    // The entries of the lanes' cells at `idx`, and which are occupied, as bits: those of
    // the previous lookup serve while no lane changed cell.
    let lookup =
        |idx: __m512i, last_idx: &mut __m512i, lv: &mut [i32; LANES], occ_bits: &mut __mmask16| {
            if _mm512_cmpeq_epi32_mask(idx, *last_idx) != 0xFFFF {
                *last_idx = idx;
                if gather {
                    // SAFETY: every lane's cell is inside the grid (positions are clamped),
                    // and the table is padded for a word at its last entry; `lv` holds
                    // sixteen i32.
                    unsafe {
                        let (e, occ) = gather16::leaps16(tab.leap, idx, OCCUPIED);
                        _mm512_storeu_epi32(lv.as_mut_ptr(), e);
                        *occ_bits = occ;
                    }
                    return;
                }
                let mut ci = [0u32; LANES];
                // SAFETY: `ci` holds sixteen u32.
                unsafe { _mm512_storeu_epi32(ci.as_mut_ptr().cast(), idx) };
                // SAFETY: every lane's cell is inside the grid (positions are clamped);
                // sixteen lanes' bits fit a u16.
                *occ_bits = unsafe { leap_entries(tab.leap, &ci, lv) } as u16;
            }
        };
    // Lanes outside `need` (those in occupied cells) take the corners' base of a lane in
    // it instead of their own: their samples classify to zero opacity whatever they read
    // (the rule the leaps rest on), and the loads (and prefetches) then hit lines already
    // on their way in. They count as skipped, not as samples taken.
    let redirect = |base: __m512i, need: __mmask16| {
        let src = _mm512_set1_epi32(need.trailing_zeros() as i32);
        _mm512_mask_blend_epi32(need, _mm512_permutexvar_epi32(src, base), base)
    };
    // One sample of the lanes in `need`, from bases `redirect` gave, composited into `acc`
    // as the reference does: the same in lockstep and lane by lane.
    // A macro rather than a closure, so that both loops get it inline: as a closure it
    // was one call with the accumulators through memory per sample step, not inlined
    // at two call sites (frames up to 10 % slower, `docs/results.md`).
    // In two halves, `fetch` (reads, lerps, bins, opacity) and `composite`, so that two
    // samples' fetches can be issued side by side (`pair` below).
    macro_rules! fetch {
        ($base:expr, $f:expr) => {{
            let (base, f): (__m512i, [__m512; 3]) = ($base, $f);
            // SAFETY: every lane's position is clamped into the data, so its cell's corners
            // are inside `v`; past `limit` the gather of a wider word would read past the end.
            let c: [__m512; 8] = unsafe {
                let inside = _mm512_cmpgt_epi32_mask(base, limit) == 0;
                if inside && gather {
                    T::corners16(v, base, tri.step)
                } else {
                    let [b0, b1] = halves(base);
                    let (h0, h1) = if inside {
                        (T::corners8(v, b0, tri.step), T::corners8(v, b1, tri.step))
                    } else {
                        (
                            corners_exact(v, b0, tri.step),
                            corners_exact(v, b1, tri.step),
                        )
                    };
                    std::array::from_fn(|i| join(h0[i], h1[i]))
                }
            };
            let [c000, c100, c010, c110, c001, c101, c011, c111] = c;
            let lerp = |a: __m512, b: __m512, w: __m512| {
                _mm512_add_ps(a, _mm512_mul_ps(_mm512_sub_ps(b, a), w))
            };
            let c00 = lerp(c000, c100, f[0]);
            let c10 = lerp(c010, c110, f[0]);
            let c01 = lerp(c001, c101, f[0]);
            let c11 = lerp(c011, c111, f[0]);
            let c0 = lerp(c00, c10, f[1]);
            let c1 = lerp(c01, c11, f[1]);
            let value = lerp(c0, c1, f[2]);
            // As `ClassifierView::sample`: `vmaxps` returns its second operand (0) for NaN.
            let x = _mm512_min_ps(
                _mm512_max_ps(_mm512_mul_ps(_mm512_sub_ps(value, lo), scale), zero),
                bin_max,
            );
            let bin = _mm512_cvttps_epi32(x);
            // SAFETY: bins are in [0, TF_BINS), and the table holds TF_BINS entries.
            // Gathers fetch the opacity first, and the colour only for a step in which
            // some lane's sample is not transparent (the loads lane by lane come as
            // whole entries, all four channels at once).
            let (alpha, rgb): (__m512, Option<[__m512; 3]>) = unsafe {
                if gather {
                    (gather16::channel16(rgba, bin, 3), None)
                } else {
                    let [bl, bh] = halves(bin);
                    let (q0, q1) = (rgba8(rgba, bl), rgba8(rgba, bh));
                    let [r, g, b, a] = std::array::from_fn(|i| join(q0[i], q1[i]));
                    (a, Some([r, g, b]))
                }
            };
            (c, [c00, c10, c01, c11, c0, c1], f, bin, alpha, rgb)
        }};
    }
    macro_rules! composite {
        ($s:expr, $need:expr, $acc:expr) => {{
            let (c, [c00, c10, c01, c11, c0, c1], f, bin, alpha, rgb) = $s;
            let [c000, c100, c010, c110, c001, c101, c011, c111] = c;
            let (need, acc): (__mmask16, &mut [__m512; 4]) = ($need, $acc);
            let lerp = |a: __m512, b: __m512, w: __m512| {
                _mm512_add_ps(a, _mm512_mul_ps(_mm512_sub_ps(b, a), w))
            };
            let opaque = need & _mm512_cmp_ps_mask::<_CMP_NEQ_UQ>(alpha, zero);
            if opaque != 0 {
                // SAFETY: as above.
                let mut s = rgb.unwrap_or_else(|| unsafe {
                    std::array::from_fn(|c| gather16::channel16(rgba, bin, c))
                });
                if SHADE {
                    // `Cell::gradient`, lane-wise.
                    let (d00, d10) = (_mm512_sub_ps(c100, c000), _mm512_sub_ps(c110, c010));
                    let (d01, d11) = (_mm512_sub_ps(c101, c001), _mm512_sub_ps(c111, c011));
                    let (e0, e1) = (_mm512_sub_ps(c10, c00), _mm512_sub_ps(c11, c01));
                    let (x0, x1) = (lerp(d00, d10, f[1]), lerp(d01, d11, f[1]));
                    let g = [
                        lerp(x0, x1, f[2]),
                        lerp(e0, e1, f[2]),
                        _mm512_sub_ps(c1, c0),
                    ];
                    let l = lambert16(g, spacing, dir);
                    // A loop: a `map` closure here can be compiled as a call (stop 45).
                    for c in &mut s {
                        *c = _mm512_mul_ps(*c, l);
                    }
                }
                let w = _mm512_sub_ps(_mm512_set1_ps(1.0), acc[3]);
                for (a, s) in acc.iter_mut().zip([s[0], s[1], s[2], alpha]) {
                    *a = _mm512_mask_add_ps(*a, opaque, *a, _mm512_mul_ps(w, s));
                }
            }
        }};
    }
    macro_rules! sample {
        ($base:expr, $f:expr, $need:expr, $acc:expr) => {{
            let s = fetch!($base, $f);
            composite!(s, $need, $acc);
        }};
    }
    // The lines the lanes will read `AHEAD_VOXELS` on, from bases `redirect` gave.
    macro_rules! prefetch {
        ($base:expr) => {{
            if let Some((off, across)) = ahead {
                let b = _mm512_add_epi32($base, off);
                let b = _mm512_min_epi32(_mm512_max_epi32(b, _mm512_setzero_si512()), limit);
                let mut at = [0i32; LANES];
                // SAFETY: `at` holds sixteen i32.
                unsafe { _mm512_storeu_epi32(at.as_mut_ptr(), b) };
                prefetch::lines(v, &at, across);
            }
        }};
    }
    if oblique(&pk.rays[has.trailing_zeros() as usize].d) {
        // Oblique rays: each lane at its own sample index. A lane in an empty cell leaps on
        // its own (by the rule of `leap_end`, lane-wise), a lane in an occupied one samples,
        // in the same iteration; each lane's samples are those of the lockstep loop below, in
        // the same order, so the pixels are the same.
        let mut kv = _mm512_mask_blend_epi32(has, k1v, k0v);
        // The lanes open (not terminated) as of an earlier step: they choose the lanes
        // that move, leap and load, while `open`, this step's, chooses those that
        // composite and count. Were the loads chosen by `open`, each step's gathers would
        // wait for the previous step's composite (opacity, compare, mask, redirect:
        // a chain through the whole step); chosen a step late, they overlap it. A lane
        // that terminated then moves and loads once more, for nothing: its samples do not
        // composite, and its position stays clamped inside the volume. Opacity only
        // grows, so `lag` holds every lane of `open`. (Frames 2–11 % faster,
        // `docs/results.md`, stop 38.)
        let mut lag: __mmask16 = 0xFFFF;
        loop {
            // As the reference's `acc[3] >= ert` stop, negated.
            let open = _mm512_cmp_ps_mask::<_CMP_NGE_UQ>(acc[3], ert);
            // Lanes short of their last sample that were open a step ago.
            let go = _mm512_cmpgt_epi32_mask(k1v, kv) & has & std::mem::replace(&mut lag, open);
            let live = go & open;
            if live == 0 {
                break;
            }
            let t = _mm512_mul_ps(_mm512_cvtepi32_ps(kv), stepv);
            let (base, f, cell, idx) = locate(t);
            lookup(idx, &mut last_idx, &mut lv, &mut occ_bits);
            let empty = go & !occ_bits;
            let need = live & occ_bits;
            let load = go & occ_bits;
            let mut next = _mm512_add_epi32(kv, one);
            st.steps += 1;
            // Where no lane leaps, sample k + 1 too (each lane's next), so that the two
            // samples' reads and lerps overlap; they composite in order, the lanes of
            // k + 1 chosen by the opacity after k's, and a lane whose k + 1 lies in an
            // empty cell leaps from there next time round, as it would have (as
            // `packet::march8`).
            if empty == 0 && need != 0 {
                let kv2 = next;
                let (base2, f2, _, idx2) = locate(_mm512_mul_ps(_mm512_cvtepi32_ps(kv2), stepv));
                let b1 = redirect(base, load);
                prefetch!(b1);
                let s1 = fetch!(b1, f);
                lookup(idx2, &mut last_idx, &mut lv, &mut occ_bits);
                let go2 = _mm512_cmpgt_epi32_mask(k1v, kv2) & go & open;
                let load2 = go2 & occ_bits;
                let b2 = redirect(base2, load2);
                prefetch!(b2);
                let s2 = fetch!(b2, f2);
                composite!(s1, need, &mut acc);
                let open2 = _mm512_cmp_ps_mask::<_CMP_NGE_UQ>(acc[3], ert);
                let need2 = go2 & open2 & occ_bits;
                composite!(s2, need2, &mut acc);
                st.steps += u64::from(go2 & open2 != 0);
                st.samples += u64::from(need.count_ones() + need2.count_ones());
                kv = _mm512_mask_add_epi32(kv, go, kv, one);
                kv = _mm512_mask_add_epi32(kv, load2, kv, one);
                lag = open2;
                continue;
            }
            if empty != 0 {
                // SAFETY: `lv` holds sixteen i32.
                let leap = unsafe { _mm512_loadu_epi32(lv.as_ptr()) };
                let kb = leap_end!(kv, &cell, leap, &leap_ray, &cells_at);
                let kb = _mm512_max_epi32(kb, next);
                // Each lane leaps less than 2^24 samples (indices are exact in f32), so the
                // sum over sixteen lanes fits an i32.
                let gone = _mm512_mask_reduce_add_epi32(empty & live, _mm512_sub_epi32(kb, kv));
                st.skipped += gone as u64;
                next = _mm512_mask_blend_epi32(empty, next, kb);
            }
            if need != 0 {
                let base = redirect(base, load);
                prefetch!(base);
                sample!(base, f, need, &mut acc);
                st.samples += u64::from(need.count_ones());
            }
            kv = _mm512_mask_blend_epi32(go, kv, next);
        }
    } else {
        // Rays along an axis: the packet in lockstep, at one sample index `k`.
        let mut k = hmin(has, k0v);
        // As in the oblique loop: the lanes open as of an earlier sampling step, which
        // choose the loads (a terminated lane loads its own corners once more).
        let mut lag: __mmask16 = 0xFFFF;
        loop {
            let kv = _mm512_set1_epi32(k);
            // Lanes whose ray claims sample k and has not terminated.
            let started = _mm512_cmpgt_epi32_mask(_mm512_add_epi32(kv, one), k0v);
            let before_end = _mm512_cmpgt_epi32_mask(k1v, kv);
            // As the reference's `acc[3] >= ert` stop, negated.
            let open = _mm512_cmp_ps_mask::<_CMP_NGE_UQ>(acc[3], ert);
            let live = started & before_end & open;
            // Lanes yet to start.
            let pending = !started & has;
            if live == 0 {
                if pending == 0 {
                    break;
                }
                k = hmin(pending, k0v);
                continue;
            }
            // A live lane: this iteration samples or leaps.
            st.steps += 1;
            let t = _mm512_set1_ps(k as f32 * step);
            let (base, f, cell, idx) = locate(t);
            lookup(idx, &mut last_idx, &mut lv, &mut occ_bits);
            if occ_bits & live == 0 {
                // SAFETY: `lv` holds sixteen i32.
                let leap = unsafe { _mm512_loadu_epi32(lv.as_ptr()) };
                // Every live lane is in an empty cell: the packet leaps.
                let kb = leap_end!(kv, &cell, leap, &leap_ray, &cells_at);
                let kb = _mm512_mask_blend_epi32(live, big, kb);
                let kb = _mm512_min_epi32(kb, _mm512_mask_blend_epi32(pending, big, k0v));
                let next = _mm512_reduce_min_epi32(kb).max(k + 1);
                st.skipped += u64::from(live.count_ones()) * (next - k) as u64;
                k = next;
                continue;
            }
            let need = occ_bits & live;
            let load = occ_bits & started & before_end & std::mem::replace(&mut lag, open);
            // Sample k + 1 too where every lane stays in its cell (so in its occupancy):
            // the two samples' reads and lerps overlap; they composite in order, k + 1's
            // lanes chosen by the opacity after k's, as two steps would.
            let kv2 = _mm512_add_epi32(kv, one);
            let (base2, f2, _, idx2) = locate(_mm512_set1_ps((k + 1) as f32 * step));
            if _mm512_cmpeq_epi32_mask(idx2, idx) == 0xFFFF {
                let within2 = _mm512_cmpgt_epi32_mask(_mm512_add_epi32(kv2, one), k0v)
                    & _mm512_cmpgt_epi32_mask(k1v, kv2);
                let b1 = redirect(base, load);
                prefetch!(b1);
                let s1 = fetch!(b1, f);
                let b2 = redirect(base2, occ_bits & within2 & open);
                prefetch!(b2);
                let s2 = fetch!(b2, f2);
                composite!(s1, need, &mut acc);
                let open2 = _mm512_cmp_ps_mask::<_CMP_NGE_UQ>(acc[3], ert);
                let live2 = within2 & open2;
                lag = open2;
                let need2 = occ_bits & live2;
                composite!(s2, need2, &mut acc);
                st.steps += u64::from(live2 != 0);
                st.samples += u64::from(need.count_ones() + need2.count_ones());
                st.skipped +=
                    u64::from((live & !occ_bits).count_ones() + (live2 & !occ_bits).count_ones());
                k += 2;
                continue;
            }
            let base = redirect(base, load);
            prefetch!(base);
            sample!(base, f, need, &mut acc);
            st.samples += u64::from(need.count_ones());
            st.skipped += u64::from((live & !occ_bits).count_ones());
            k += 1;
        }
    }
    let mut out = [[0f32; LANES]; 4];
    for (o, a) in out.iter_mut().zip(acc) {
        // SAFETY: `o` holds sixteen f32.
        unsafe { _mm512_storeu_ps(o.as_mut_ptr(), a) };
    }
    for (j, px) in pk.acc.iter_mut().enumerate() {
        *px = [out[0][j], out[1][j], out[2][j], out[3][j]];
    }
    st
}

/// A packet's rays as [`leap_end`] reads them.
struct LeapRay {
    o: [__m512; 3],
    d: [__m512; 3],
    inv: [__m512; 3],
    k1v: __m512i,
    k1f: __m512,
    nlast: [__m512i; 3],
    stepv: __m512,
    inv_step: __m512,
}

/// Whether rays of index-space direction `d` are oblique to the lattice: further than
/// about 10° from every axis. Rays along an axis cross the cell faces across their path
/// at the same sample index, lane for lane, so the packet moves in lockstep at no cost
/// and its lanes read the same slices; oblique ones cross them at different indices, and
/// a packet in lockstep would take the union of its lanes' steps, so each lane goes on
/// its own.
pub(super) fn oblique(d: &[f32; 3]) -> bool {
    let m = d.iter().fold(0f32, |m, x| m.max(x.abs()));
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    m < OBLIQUE_COS * n
}

/// cos 10°: see [`oblique`].
const OBLIQUE_COS: f32 = 0.984_807_7;
