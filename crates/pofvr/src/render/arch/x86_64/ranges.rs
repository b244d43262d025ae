//! The sample range of each ray of a packet, eight lanes at a time: [`IndexRay::span`] of
//! the volume's box and then [`sample_range`], value for value.
//!
//! Per ray that is six divisions, a comparison chain per axis and two lattice searches
//! whose loops branch on the rounding of `t / step`: done one ray at a time it took about
//! a sixth of a march frame on the head CT (whose rays mostly leap through air), as much as
//! the packet loop's sampling. Lane-wise it is the same float operations (divisions,
//! `min`/`max`, comparisons, all correctly rounded), so the ranges are those of the scalar
//! code; the one place where the scalar code loops (settling `first_sample` on the exact
//! lattice boundary) is settled here by checking the candidate, and a lane whose candidate
//! fails the check (none in practice) takes the scalar function.

use std::arch::x86_64::{
    __m256, __m256i, _mm256_add_epi32, _mm256_and_ps, _mm256_andnot_ps, _mm256_blendv_ps,
    _mm256_castps_si256, _mm256_castsi256_ps, _mm256_cmp_ps, _mm256_cmpgt_epi32,
    _mm256_cvtepi32_ps, _mm256_cvttps_epi32, _mm256_div_ps, _mm256_max_ps, _mm256_min_ps,
    _mm256_movemask_ps, _mm256_mul_ps, _mm256_or_ps, _mm256_set1_epi32, _mm256_set1_ps,
    _mm256_setzero_ps, _mm256_setzero_si256, _mm256_storeu_ps, _mm256_storeu_si256,
    _mm256_sub_epi32, _mm256_sub_ps, _CMP_EQ_OQ, _CMP_GE_OQ, _CMP_GT_OQ, _CMP_LE_OQ, _CMP_LT_OQ,
};

use crate::brick::IndexBox;
use crate::render::lattice::{first_sample, IndexRay};

/// Rays per call of [`ranges8`].
pub(crate) const LANES: usize = 8;

/// Past this `t / step` the lattice search is left to the scalar function: `k as f32` is
/// no longer exact, and the scalar code saturates where the vector conversion does not.
const EXACT_Q: f32 = 16_777_216.0;

/// Lanes of the comparison mask `m` as bits.
#[target_feature(enable = "avx2")]
#[inline]
fn bits(m: __m256) -> u32 {
    _mm256_movemask_ps(m) as u32
}

/// `(k0, k1)` of each ray of `rays` whose bit is set in `valid`, as
/// `sample_range(ray.span(b)?, step)` gives it (`(0, 0)` where the ray misses `b`, and for
/// lanes outside `valid`), and the lanes whose ray meets `b`, as bits.
///
/// # Safety
/// AVX2 is available.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn ranges8(
    rays: &[IndexRay; LANES],
    valid: u32,
    b: &IndexBox,
    step: f32,
    k0: &mut [i32; LANES],
    k1: &mut [i32; LANES],
) -> u32 {
    let lane = |f: &dyn Fn(usize) -> f32| {
        let a: [f32; LANES] = std::array::from_fn(f);
        // SAFETY: `a` holds eight f32.
        unsafe { std::arch::x86_64::_mm256_loadu_ps(a.as_ptr()) }
    };
    let zero = _mm256_setzero_ps();
    let mut t0 = _mm256_set1_ps(f32::NEG_INFINITY);
    let mut t1 = _mm256_set1_ps(f32::INFINITY);
    let mut miss = 0u32;
    for a in 0..3 {
        let o = lane(&|j| rays[j].o[a]);
        let d = lane(&|j| rays[j].d[a]);
        let (lo, hi) = (_mm256_set1_ps(b.lo[a]), _mm256_set1_ps(b.hi[a]));
        let flat = _mm256_cmp_ps::<_CMP_EQ_OQ>(d, zero);
        // Parallel to the axis: in the slab or not at all.
        let inside = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_LE_OQ>(lo, o),
            _mm256_cmp_ps::<_CMP_LT_OQ>(o, hi),
        );
        miss |= bits(_mm256_andnot_ps(inside, flat));
        let ta = _mm256_div_ps(_mm256_sub_ps(lo, o), d);
        let tb = _mm256_div_ps(_mm256_sub_ps(hi, o), d);
        let pos = _mm256_cmp_ps::<_CMP_GT_OQ>(d, zero);
        let near = _mm256_blendv_ps(tb, ta, pos);
        let far = _mm256_blendv_ps(ta, tb, pos);
        // `f32::max(t0, near)`: `vmaxps` returns its second operand where either is NaN,
        // `f32::max` the operand that is not NaN; `t0` never is.
        let (nt0, nt1) = (_mm256_max_ps(near, t0), _mm256_min_ps(far, t1));
        t0 = _mm256_blendv_ps(nt0, t0, flat);
        t1 = _mm256_blendv_ps(nt1, t1, flat);
    }
    let hit = valid & !miss & bits(_mm256_cmp_ps::<_CMP_LT_OQ>(t0, t1));
    let (mut a, mut c) = ([0i32; LANES], [0i32; LANES]);
    if hit != 0 {
        let stepv = _mm256_set1_ps(step);
        for (t, out) in [(t0, &mut a), (t1, &mut c)] {
            let (k, bad) = first_samples(t, stepv);
            // SAFETY: `out` holds eight i32.
            unsafe { _mm256_storeu_si256(out.as_mut_ptr().cast(), k) };
            let mut bad = bad & hit;
            if bad != 0 {
                let mut ts = [0f32; LANES];
                // SAFETY: `ts` holds eight f32.
                unsafe { _mm256_storeu_ps(ts.as_mut_ptr(), t) };
                while bad != 0 {
                    let j = bad.trailing_zeros() as usize;
                    out[j] = first_sample(ts[j], step);
                    bad &= bad - 1;
                }
            }
        }
    }
    for j in 0..LANES {
        let on = hit >> j & 1 != 0;
        k0[j] = if on { a[j] } else { 0 };
        k1[j] = if on { c[j] } else { 0 };
    }
    hit
}

/// `first_sample(t, step)` lane-wise, and the lanes (as bits) whose candidate failed its
/// check, for the scalar function to settle.
///
/// The scalar function returns the least `k ≥ 0` with `k·step ≥ t` (in f32; 0 where
/// `t ≤ 0`): the product is monotone in `k`, so that `k` is unique, and whatever candidate
/// passes `(k = 0 or (k − 1)·step < t) and k·step ≥ t` is it.
#[target_feature(enable = "avx2")]
#[inline]
fn first_samples(t: __m256, step: __m256) -> (__m256i, u32) {
    let zero = _mm256_setzero_ps();
    let one = _mm256_set1_epi32(1);
    let nonpos = _mm256_cmp_ps::<_CMP_LE_OQ>(t, zero);
    let q = _mm256_div_ps(t, step);
    // Large, infinite or NaN quotients go to the scalar function.
    let big = _mm256_andnot_ps(
        _mm256_cmp_ps::<_CMP_LT_OQ>(q, _mm256_set1_ps(EXACT_Q)),
        _mm256_set1_ps(f32::from_bits(u32::MAX)),
    );
    let q = _mm256_min_ps(q, _mm256_set1_ps(EXACT_Q));
    let mut k = _mm256_cvttps_epi32(q);
    // The ceiling: one up where the truncation fell below.
    let below = _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_cvtepi32_ps(k), q);
    k = _mm256_sub_epi32(k, _mm256_castps_si256(below));
    let at = |k: __m256i| _mm256_mul_ps(_mm256_cvtepi32_ps(k), step);
    // One step down where the sample below is still at or past `t`, then one up where
    // this one is before it: the rounding of the division moves the candidate by one at
    // most in practice.
    let down = _mm256_and_ps(
        _mm256_castsi256_ps(_mm256_cmpgt_epi32(k, _mm256_setzero_si256())),
        _mm256_cmp_ps::<_CMP_GE_OQ>(at(_mm256_sub_epi32(k, one)), t),
    );
    k = _mm256_add_epi32(k, _mm256_castps_si256(down));
    let up = _mm256_cmp_ps::<_CMP_LT_OQ>(at(k), t);
    k = _mm256_sub_epi32(k, _mm256_castps_si256(up));
    let ok = _mm256_and_ps(
        _mm256_or_ps(
            _mm256_castsi256_ps(_mm256_cmpgt_epi32(one, k)),
            _mm256_cmp_ps::<_CMP_LT_OQ>(at(_mm256_sub_epi32(k, one)), t),
        ),
        _mm256_cmp_ps::<_CMP_GE_OQ>(at(k), t),
    );
    let settled = _mm256_or_ps(nonpos, _mm256_andnot_ps(big, ok));
    let k = _mm256_castps_si256(_mm256_andnot_ps(nonpos, _mm256_castsi256_ps(k)));
    let bad = !bits(settled) & 0xFF;
    (k, bad)
}

#[cfg(test)]
mod test {
    use super::*;
    use crate::render::lattice::sample_range;

    /// A reproducible stream of floats in `[0, 1)`.
    fn uniform(seed: &mut u64) -> f32 {
        *seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (*seed >> 40) as f32 / (1u64 << 24) as f32
    }

    #[test]
    fn eight_lanes_give_the_scalar_ranges_of_every_kind_of_ray() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            println!("skipped: this CPU has no AVX2");
            return;
        }
        let b = IndexBox {
            lo: [0.0; 3],
            hi: [255.0, 127.0, 63.0],
        };
        let mut seed = 7;
        let mut kinds = [0usize; 3];
        for case in 0..20_000 {
            let step = [1.0, 0.5, 0.37, 2.0][case % 4];
            let rays: [IndexRay; LANES] = std::array::from_fn(|j| {
                let mut u = || uniform(&mut seed);
                let mut d = [u() - 0.5, u() - 0.5, u() - 0.5];
                // Some axes parallel to the ray, some origins inside the box, some on
                // lattice-friendly values.
                for x in &mut d {
                    if u() < 0.2 {
                        *x = 0.0;
                    }
                }
                if d == [0.0; 3] {
                    d[j % 3] = 1.0;
                }
                let o = if u() < 0.3 {
                    [u() * 255.0, u() * 127.0, u() * 63.0]
                } else if u() < 0.1 {
                    [(u() * 256.0).floor(), 0.0, (u() * 64.0).floor()]
                } else {
                    [
                        u() * 900.0 - 300.0,
                        u() * 500.0 - 200.0,
                        u() * 300.0 - 100.0,
                    ]
                };
                IndexRay { o, d, dir: d }
            });
            let valid = (uniform(&mut seed) * 256.0) as u32 | 1;
            let (mut k0, mut k1) = ([-1; LANES], [-1; LANES]);
            // SAFETY: AVX2 was detected.
            let hit = unsafe { ranges8(&rays, valid, &b, step, &mut k0, &mut k1) };
            for j in 0..LANES {
                let span = (valid >> j & 1 != 0).then(|| rays[j].span(&b)).flatten();
                let want = span.map_or((0, 0), |s| sample_range(s, step));
                assert_eq!((k0[j], k1[j]), want, "case {case} lane {j}: {:?}", rays[j]);
                assert_eq!(hit >> j & 1 != 0, span.is_some(), "case {case} lane {j}");
                kinds[usize::from(span.is_some()) + usize::from(want.0 < want.1)] += 1;
            }
        }
        // Misses, hits between lattice samples, and hits with samples all came up.
        assert!(kinds.iter().all(|&n| n > 100), "{kinds:?}");
    }
}
