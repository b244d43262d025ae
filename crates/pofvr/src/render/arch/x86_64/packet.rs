//! The march engine's AVX2 loop over packets of eight rays: one sample of each of eight
//! neighbouring rays per lane, at the same lattice index.
//!
//! The one-ray loop ([`super::avx2::march`]) puts eight samples of one ray in the lanes, so
//! the composite, which carries the accumulator from sample to sample, runs one sample at a
//! time, and every group that meets empty space or a terminated ray pays a branch and a
//! scalar fold. Eight rays in the lanes composite lane-wise instead: a ray's samples stay
//! in order, each lane performs the float operations of the scalar definition
//! ([`super::super::generic::march`]) on its own ray's sample `k` — position `o + (k·step)·d`,
//! cell, corners, the trilinear lerps, the bin, `w = 1 − α`, `acc += w·s` — so every pixel is
//! bit for bit the reference's. A lane takes no part (its accumulator is left as it is) while
//! `k` is outside its ray's samples, once its opacity has reached the termination threshold,
//! and for a sample of zero opacity (which the reference skips).
//!
//! Empty space is skipped for the packet as a whole, by the rule of [`Skip::leap_end`]
//! evaluated lane-wise: where no live lane's sample lies in an occupied cell, each live lane
//! finds the first sample past the cube of empty cells around its own (checked by the
//! sampler's own cells), and the packet moves on to the least of those, and to no lane's
//! first sample past its start: every sample of every live lane before it lies in an empty
//! cell, of zero opacity.
//!
//! Neighbouring pixels' rays (a 4 × 2 tile) cross the same cells within a voxel of each
//! other, so the lanes mostly agree on where empty space begins and ends.

use std::arch::x86_64::{
    __m256, __m256i, _mm256_add_epi32, _mm256_add_ps, _mm256_and_ps, _mm256_and_si256,
    _mm256_andnot_si256, _mm256_blendv_ps, _mm256_castps_si256, _mm256_castsi256_ps, _mm256_cmp_ps,
    _mm256_cmpeq_epi32, _mm256_cmpgt_epi32, _mm256_cvtepi32_ps, _mm256_cvttps_epi32, _mm256_div_ps,
    _mm256_i32gather_epi32, _mm256_i32gather_ps, _mm256_loadu_si256, _mm256_max_epi32,
    _mm256_max_ps, _mm256_min_epi32, _mm256_min_ps, _mm256_movemask_ps, _mm256_mul_ps,
    _mm256_mullo_epi32, _mm256_or_si256, _mm256_permutevar8x32_epi32, _mm256_set1_epi32,
    _mm256_set1_ps, _mm256_setr_epi32, _mm256_setzero_ps, _mm256_setzero_si256, _mm256_slli_epi32,
    _mm256_srl_epi32, _mm256_srli_epi32, _mm256_storeu_ps, _mm256_storeu_si256, _mm256_sub_epi32,
    _mm256_sub_ps, _CMP_EQ_OQ, _CMP_GT_OQ, _CMP_LT_OQ, _CMP_NEQ_UQ, _CMP_NGE_UQ,
};

use super::super::MarchParams;
use super::avx2::{bins8, gradient8, lambert8, trilinear8, Gather8};
use super::prefetch;
use crate::render::lattice::IndexRay;
use crate::render::occupancy::{CELL_SHIFT, OCCUPIED};
use crate::render::sampler::TrilinearSampler;
use crate::render::skip::LEAP_MIN;

/// Rays per packet.
pub(crate) const LANES: usize = 8;

/// One packet: `N` rays (eight here, sixteen for [`super::packet16`]; a lane whose range
/// is empty takes no part), the lattice indices `k0..k1` each claims, and their
/// premultiplied RGBA so far.
#[derive(Clone)]
pub(crate) struct Packet<const N: usize = LANES> {
    pub(crate) rays: [IndexRay; N],
    pub(crate) k0: [i32; N],
    pub(crate) k1: [i32; N],
    pub(crate) acc: [[f32; 4]; N],
}

/// What the packet loop reads besides the volume and the classification: the occupancy's
/// leap entries ([`crate::render::occupancy::Occupancy::leaps`]) and its cells per axis.
pub(crate) struct PacketTables<'t> {
    pub(crate) leap: &'t [u8],
    pub(crate) cells: [i32; 3],
    /// The octant `leap` looks toward ([`crate::render::occupancy::Occupancy::leaps_toward`]),
    /// or 0 per axis where its cubes reach both ways ([`crate::render::occupancy::Occupancy::leaps`]).
    pub(crate) sign: [i8; 3],
}

/// What a packet took: lane samples marched, lane samples leapt over, and the loop's
/// steps (iterations that sampled or leapt for at least one lane).
#[derive(Clone, Copy, Default)]
pub(crate) struct PacketStats {
    pub(crate) samples: u64,
    pub(crate) skipped: u64,
    pub(crate) steps: u64,
}

/// Lanes of `m` (a comparison mask) as bits.
#[inline(always)]
fn bits(m: __m256i) -> u32 {
    // SAFETY: AVX is enabled wherever this is inlined (the callers' target features).
    unsafe { _mm256_movemask_ps(_mm256_castsi256_ps(m)) as u32 }
}

/// Lane-wise `a <= x && x <= b`.
#[target_feature(enable = "avx2")]
#[inline]
fn within(a: __m256i, x: __m256i, b: __m256i) -> __m256i {
    let out = _mm256_or_si256(_mm256_cmpgt_epi32(a, x), _mm256_cmpgt_epi32(x, b));
    _mm256_andnot_si256(out, _mm256_set1_epi32(-1))
}

/// The lanes whose opacity `a` is short of the termination threshold `ert`: the
/// reference's `acc[3] >= ert` stop, negated (so NaN stays open, as there).
#[target_feature(enable = "avx2")]
#[inline]
fn open_lanes(a: __m256, ert: __m256) -> __m256i {
    _mm256_castps_si256(_mm256_cmp_ps::<_CMP_NGE_UQ>(a, ert))
}

/// The eight lanes of `v` folded by the 128-bit lane-wise `op` (min, add): halves, then
/// pairs, then neighbours.
macro_rules! fold8 {
    ($v:expr, $op:ident) => {{
        use std::arch::x86_64::{
            _mm256_castsi256_si128, _mm256_extracti128_si256, _mm_cvtsi128_si32, _mm_shuffle_epi32,
        };
        let v: __m256i = $v;
        let m = $op(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
        let m = $op(m, _mm_shuffle_epi32::<0b01_00_11_10>(m));
        let m = $op(m, _mm_shuffle_epi32::<0b10_11_00_01>(m));
        _mm_cvtsi128_si32(m)
    }};
}

/// The sum of the eight lanes (each at least 0 here: a leap's length).
#[target_feature(enable = "avx2")]
#[inline]
fn hsum(v: __m256i) -> i32 {
    use std::arch::x86_64::_mm_add_epi32;
    fold8!(v, _mm_add_epi32)
}

/// The least of the eight lanes.
#[target_feature(enable = "avx2")]
#[inline]
fn hmin(v: __m256i) -> i32 {
    use std::arch::x86_64::_mm_min_epi32;
    fold8!(v, _mm_min_epi32)
}

/// Marches `pk` front to back through the volume of `tri`, skipping the empty cells of
/// `tab`, shaded when `SHADE` (then `p.shade` is set); see the [module](self).
///
/// # Safety
/// AVX2 and POPCNT are available ([`super::avx2::available`]) and [`super::avx2::fits`]
/// holds; `tab` was built for this volume and classification, with the padding it
/// documents.
// POPCNT: the counts of lanes sampled and skipped, at every step (without it they compile
// to a dozen instructions each).
#[target_feature(enable = "avx2,popcnt")]
pub(crate) unsafe fn march8<
    T: Gather8,
    const SHADE: bool,
    const OBLIQUE: bool,
    const BLOCKS: bool,
>(
    p: &MarchParams<'_>,
    tri: &TrilinearSampler<'_, T>,
    tab: &PacketTables<'_>,
    pk: &mut Packet,
) -> PacketStats {
    debug_assert!(super::avx2::fits(tri));
    debug_assert_eq!(SHADE, p.shade.is_some());
    let mut st = PacketStats::default();
    // Lane-wise from the rays.
    let ([o0, o1, o2], [d0, d1, d2], [e0, e1, e2]) = ray_axes(&pk.rays);
    let o = [vec8(o0), vec8(o1), vec8(o2)];
    let d = [vec8(d0), vec8(d1), vec8(d2)];
    let dir = [vec8(e0), vec8(e1), vec8(e2)];
    // `1 / d`, 0 where `d` is 0: for the leap estimates only.
    let inv = d.map(|d| {
        let zero = _mm256_cmp_ps::<_CMP_EQ_OQ>(d, _mm256_setzero_ps());
        _mm256_blendv_ps(
            _mm256_div_ps(_mm256_set1_ps(1.0), d),
            _mm256_setzero_ps(),
            zero,
        )
    });
    let spacing: [__m256; 3] = p.shade.unwrap_or([1.0; 3]).map(|s| _mm256_set1_ps(s));
    // SAFETY: `k0` and `k1` hold eight i32.
    let (k0v, k1v) = unsafe {
        (
            _mm256_loadu_si256(pk.k0.as_ptr().cast()),
            _mm256_loadu_si256(pk.k1.as_ptr().cast()),
        )
    };
    let k1f = _mm256_cvtepi32_ps(k1v);
    let has = _mm256_cmpgt_epi32(k1v, k0v);
    if bits(has) == 0 {
        return st;
    }
    let big = _mm256_set1_epi32(i32::MAX);
    let one = _mm256_set1_epi32(1);
    let [r, g, b, a] = channels(&pk.acc);
    let mut acc = [vec8(r), vec8(g), vec8(b), vec8(a)];
    let (step, ert) = (p.step, _mm256_set1_ps(p.ert));
    let stepv = _mm256_set1_ps(step);
    let inv_step = _mm256_set1_ps(1.0 / step);
    let zero = _mm256_setzero_ps();
    let maxv = tri.max.map(|m| _mm256_set1_ps(m));
    // Cells are below 2^24 per axis, so the floats are exact.
    let last = tri.last_cell.map(|c| _mm256_set1_ps(c as f32));
    let strides = tri.stride.map(|s| _mm256_set1_epi32(s as i32));
    // Over a blocked copy (`BLOCKS`, `TrilinearSampler::blocked`): `stride` per axis is a
    // block's, `step` a voxel's inside one.
    let inner = tri.step.map(|s| _mm256_set1_epi32(s as i32));
    let edge_mask = _mm256_set1_epi32(crate::render::blocks::EDGE as i32 - 1);
    // The element offset of cell `i` on axis `a` (its share of the corners' base).
    let axis_offset = |i: __m256i, a: usize| {
        if BLOCKS {
            let b = _mm256_srli_epi32::<{ crate::render::blocks::EDGE_SHIFT as i32 }>(i);
            let l = _mm256_and_si256(i, edge_mask);
            let l = if a == 0 {
                l
            } else {
                _mm256_mullo_epi32(l, inner[a])
            };
            _mm256_add_epi32(_mm256_mullo_epi32(b, strides[a]), l)
        } else {
            _mm256_mullo_epi32(i, strides[a])
        }
    };
    let nlast = tab.cells.map(|n| _mm256_set1_epi32(n - 1));
    let (n0, n01) = (
        _mm256_set1_epi32(tab.cells[0]),
        _mm256_set1_epi32(tab.cells[0] * tab.cells[1]),
    );
    let v = tri.v;
    let [sx, sy, sz] = tri.step;
    // The largest base whose reads stay inside the data; -1 when none does.
    let limit = (v.len() as i64 - 1 - (sx + sy + sz + T::OVERREAD) as i64).max(-1) as i32;
    let limit = _mm256_set1_epi32(limit);
    // Where the voxels exceed the cache: each lane's element offset to the corner
    // `AHEAD_VOXELS` on, and the second line of a cell across the ray (`prefetch`).
    let ahead = p.prefetch.then(|| {
        let (off, across) =
            prefetch::offsets(&pk.rays, bits(has).trailing_zeros() as usize, tri.step);
        // SAFETY: `off` holds eight i32.
        (unsafe { _mm256_loadu_si256(off.as_ptr().cast()) }, across)
    });
    let gather = p.gather;
    let cls = p.cls;
    let rgba = cls.rgba.as_ptr().cast::<f32>();
    let (lo, scale, bin_max) = (
        _mm256_set1_ps(cls.lo),
        _mm256_set1_ps(cls.scale),
        _mm256_set1_ps(crate::render::transfer_function::BIN_MAX),
    );
    // The occupancy cell per axis of each lane's sample at `t` (lane-wise `Skip::cell`).
    let cells_at = |t: __m256| {
        [0, 1, 2].map(|a| {
            let p = _mm256_add_ps(o[a], _mm256_mul_ps(t, d[a]));
            let c = _mm256_min_ps(_mm256_min_ps(_mm256_max_ps(p, zero), maxv[a]), last[a]);
            _mm256_srli_epi32::<{ CELL_SHIFT as i32 }>(_mm256_cvttps_epi32(c))
        })
    };
    let reach = |neg: bool| {
        tab.sign
            .map(|s| _mm256_set1_epi32(if s == 0 || (s < 0) == neg { -1 } else { 0 }))
    };
    let leap_ray = LeapRay {
        back: reach(true),
        ahead: reach(false),
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
    let mut last_idx = _mm256_set1_epi32(-1);
    let mut lv = _mm256_setzero_si256();
    let mut occ_bits = 0u32;
    let lane_bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
    let mask_of = |m: u32| {
        _mm256_cmpeq_epi32(
            _mm256_and_si256(_mm256_set1_epi32(m as i32), lane_bit),
            lane_bit,
        )
    };
    // Each lane's sample at `t`: its corners' base, fractions, occupancy cell per axis, and
    // that cell's index in the table (lane-wise `TrilinearSampler::cell` and `Skip::cell`).
    // On one axis (the ray's origin and direction, the data's largest position and last
    // cell there): the sampler's clamped position, cell and fraction at `t` (the whole
    // volume's: origin 0).
    let on_axis = |t: __m256, o: __m256, d: __m256, max: __m256, last: __m256| {
        let p = _mm256_add_ps(o, _mm256_mul_ps(t, d));
        let x = _mm256_min_ps(_mm256_max_ps(p, zero), max);
        let i = _mm256_cvttps_epi32(_mm256_min_ps(x, last));
        (x, i, _mm256_sub_ps(x, _mm256_cvtepi32_ps(i)))
    };
    let locate = |t: __m256| {
        let mut base = _mm256_setzero_si256();
        let mut f = [zero; 3];
        let mut cell = [_mm256_setzero_si256(); 3];
        for a in 0..3 {
            let (_, i, fa) = on_axis(t, o[a], d[a], maxv[a], last[a]);
            f[a] = fa;
            base = _mm256_add_epi32(base, axis_offset(i, a));
            cell[a] = _mm256_srli_epi32::<{ CELL_SHIFT as i32 }>(i);
        }
        let idx = _mm256_add_epi32(
            _mm256_add_epi32(
                _mm256_mullo_epi32(cell[2], n01),
                _mm256_mullo_epi32(cell[1], n0),
            ),
            cell[0],
        );
        (base, f, cell, idx)
    };
    // The entries of the lanes' cells at `idx`, and which are occupied, as bits: those of
    // the previous lookup serve while no lane changed cell (most samples, as a cell is
    // several samples long).
    let lookup = |idx: __m256i, last_idx: &mut __m256i, lv: &mut __m256i, occ: &mut u32| {
        if bits(_mm256_cmpeq_epi32(idx, *last_idx)) == 0xFF {
            return;
        }
        *last_idx = idx;
        // SAFETY: every lane's cell is inside the grid (positions are clamped), and the
        // table is padded for a word at its last entry.
        (*lv, *occ) = unsafe {
            if gather {
                leaps8(tab.leap, idx, OCCUPIED)
            } else {
                leap_bytes8(tab.leap, idx)
            }
        };
    };
    // Lanes outside `load` (those in empty cells, and those whose ray is done) take the
    // corners' base of a lane in it instead of their own: their samples classify to zero
    // opacity whatever they read (the rule the leaps rest on), and the loads then hit
    // lines already on their way in. They count as skipped, not as samples taken.
    let redirect = |base: __m256i, load: u32| {
        let src = _mm256_set1_epi32(load.trailing_zeros() as i32);
        blend_i(_mm256_permutevar8x32_epi32(base, src), base, mask_of(load))
    };
    let every = _mm256_set1_epi32(-1);
    // The line each lane last asked for (lockstep): along an axis a lane stays on one line
    // for several samples where the step is under a voxel (a CT's in-plane axes, whose
    // spacing is finer than the slices'), and asking again costs a load slot each time.
    let mut pf_last = _mm256_set1_epi32(-1);
    let line_shift = std::arch::x86_64::_mm_cvtsi32_si128(
        (64 / std::mem::size_of::<T>()).trailing_zeros() as i32,
    );
    // One sample of the lanes in `need`, read by the lanes in `load` (a superset),
    // composited into `acc` as the reference does: the same in lockstep and lane by lane.
    // `own` = `Some((reads, late))`: the lanes read their own corners, not redirected
    // ones, so that the reads need not wait for the occupancy lookup (`redirect` does):
    // gathers read the lanes in `reads` (masked) and, in a second gather, the lanes in
    // `late` (those of `load` outside `reads`); loads lane by lane read every lane's own.
    // In lockstep a lane in an empty cell sits beside lanes that sample, on the lines they
    // read: `reads` is every lane within its ray's samples, `late` none. Lane by lane, a
    // lane that has just leapt lands on a line no other lane reads, a miss on a volume
    // larger than the caches if the cell is empty (own reads of every lane: 1.23 x the
    // frame time on chest1728 30,20), so `reads` leaves out the lanes that leapt and
    // `late` takes those that landed in an occupied cell; loads lane by lane redirect
    // (`None`) there. Frames 0.87-0.97 of redirected ones (docs/results.md, stop 44).
    // A macro, so that each loop gets it inline (as `packet16`'s).
    // `fetch!` in two: the corners' reads, and the lerps and classification.
    macro_rules! read {
        ($base:expr, $load:expr, $own:expr) => {{
            let (base, load_bits, own): (__m256i, u32, Option<(__m256i, u32)>) =
                ($base, $load, $own);
            // The lines these lanes will read `AHEAD_VOXELS` on.
            if let Some((off, across)) = ahead {
                let b = _mm256_add_epi32(redirect(base, load_bits), off);
                let b = _mm256_min_epi32(_mm256_max_epi32(b, _mm256_setzero_si256()), limit);
                // In lockstep, only where some lane's line differs from the last asked for.
                let ask = OBLIQUE || {
                    let line = _mm256_srl_epi32(b, line_shift);
                    let same = bits(_mm256_cmpeq_epi32(line, pf_last));
                    pf_last = line;
                    same != 0xFF
                };
                if ask {
                    let mut at = [0i32; LANES];
                    // SAFETY: `at` holds eight i32.
                    unsafe { _mm256_storeu_si256(at.as_mut_ptr().cast(), b) };
                    prefetch::lines(v, &at, across);
                }
            }
            let (base, reads, late) = match own {
                Some((reads, late)) => (base, reads, late),
                None => (redirect(base, load_bits), every, 0),
            };
            // SAFETY: every lane's position is clamped into the data, so its cell's
            // corners are inside `v`; past `limit` the gather of a wider word would read
            // past the end.
            let c = unsafe {
                if bits(_mm256_cmpgt_epi32(base, limit)) != 0 {
                    corners_exact(v, base, tri.step)
                } else if gather {
                    let mut c = T::corners8_gathered(v, base, tri.step, reads);
                    if late != 0 {
                        let m = mask_of(late);
                        let c2 = T::corners8_gathered(v, base, tri.step, m);
                        let mf = _mm256_castsi256_ps(m);
                        for i in 0..8 {
                            c[i] = _mm256_blendv_ps(c[i], c2[i], mf);
                        }
                    }
                    c
                } else {
                    T::corners8(v, base, tri.step)
                }
            };
            c
        }};
    }
    macro_rules! classify {
        ($c:expr, $f:expr) => {{
            let (c, f): ([__m256; 8], [__m256; 3]) = ($c, $f);
            // SAFETY: AVX2 (this function's target features).
            let (lerps, bin) = unsafe {
                let l = trilinear8(&c, &f);
                let bin = bins8(l.value, lo, scale, bin_max);
                (l, bin)
            };
            // SAFETY: bins are in [0, TF_BINS), and the table holds TF_BINS entries.
            // Gathers fetch the opacity first, and the colour only for a step in which
            // some lane's sample is not transparent (the loads lane by lane come as whole
            // entries, all four channels at once).
            let (alpha, rgb) = unsafe {
                if gather {
                    (channel8(rgba, bin, 3), None)
                } else {
                    let [r, g, b, a] = rgba8(rgba, bin);
                    (a, Some([r, g, b]))
                }
            };
            (c, f, lerps, bin, alpha, rgb)
        }};
    }
    macro_rules! fetch {
        ($base:expr, $f:expr, $load:expr, $own:expr) => {{
            let c = read!($base, $load, $own);
            classify!(c, $f)
        }};
    }
    macro_rules! composite {
        ($s:expr, $need:expr, $acc:expr) => {{
            let (c, f, lerps, bin, alpha, rgb) = $s;
            let (need_bits, acc): (u32, &mut [__m256; 4]) = ($need, $acc);
            let opaque = _mm256_and_ps(
                _mm256_castsi256_ps(mask_of(need_bits)),
                _mm256_cmp_ps::<_CMP_NEQ_UQ>(alpha, zero),
            );
            if _mm256_movemask_ps(opaque) != 0 {
                // SAFETY: as above.
                let mut s = rgb
                    .unwrap_or_else(|| unsafe { std::array::from_fn(|c| channel8(rgba, bin, c)) });
                if SHADE {
                    // SAFETY: AVX2 (this function's target features).
                    let g = unsafe { gradient8(&c, &lerps, &f) };
                    let l = lambert8(g, spacing, dir);
                    // A loop: a `map` closure here can be compiled as a call (stop 45).
                    for c in &mut s {
                        *c = _mm256_mul_ps(*c, l);
                    }
                }
                let w = _mm256_sub_ps(_mm256_set1_ps(1.0), acc[3]);
                for (a, s) in acc.iter_mut().zip([s[0], s[1], s[2], alpha]) {
                    *a = _mm256_blendv_ps(*a, _mm256_add_ps(*a, _mm256_mul_ps(w, s)), opaque);
                }
            }
        }};
    }
    macro_rules! sample {
        ($base:expr, $f:expr, $need:expr, $load:expr, $own:expr, $acc:expr) => {{
            let s = fetch!($base, $f, $load, $own);
            composite!(s, $need, $acc);
        }};
    }
    if OBLIQUE {
        // Oblique rays: each lane at its own sample index, as in `packet16`. A lane in an
        // empty cell leaps on its own (by the rule of `leap_end`, lane-wise), a lane in an
        // occupied one samples, in the same iteration; each lane's samples are those of
        // the lockstep loop below, in the same order, so the pixels are the same.
        let mut kv = blend_i(k1v, k0v, has);
        // The lanes open as of an earlier step choose the lanes that move, leap and load;
        // `open`, this step's, those that composite and count (as in `packet16`).
        let mut lag = 0xFFu32;
        // The lanes that leapt a step ago: landed, on lines not read yet (`sample!`).
        let mut leapt = 0u32;
        loop {
            // As the reference's `acc[3] >= ert` stop, negated.
            let open = bits(open_lanes(acc[3], ert));
            // Lanes short of their last sample, and of those the ones open a step ago.
            let short = _mm256_and_si256(has, _mm256_cmpgt_epi32(k1v, kv));
            let go = bits(short) & std::mem::replace(&mut lag, open);
            let live = go & open;
            if live == 0 {
                break;
            }
            let t = _mm256_mul_ps(_mm256_cvtepi32_ps(kv), stepv);
            let (base, f, cell, idx) = locate(t);
            lookup(idx, &mut last_idx, &mut lv, &mut occ_bits);
            let empty = go & !occ_bits;
            let need = live & occ_bits;
            let load = go & occ_bits;
            let mut next = _mm256_add_epi32(kv, one);
            st.steps += 1;
            // Where no lane leaps, sample k + 1 too (each lane's next), so that the two
            // samples' reads and lerps overlap, as in lockstep; they composite in order,
            // the lanes of k + 1 chosen by the opacity after k's, and a lane whose k + 1
            // lies in an empty cell leaps from there next time round, as it would have.
            if empty == 0 && need != 0 {
                let go_m = mask_of(go);
                let kv2 = _mm256_add_epi32(kv, one);
                let (base2, f2, _, idx2) = locate(_mm256_mul_ps(_mm256_cvtepi32_ps(kv2), stepv));
                let own = if gather {
                    Some((_mm256_andnot_si256(mask_of(leapt), short), load & leapt))
                } else {
                    None
                };
                let s1 = fetch!(base, f, load, own);
                lookup(idx2, &mut last_idx, &mut lv, &mut occ_bits);
                let short2 =
                    _mm256_and_si256(_mm256_and_si256(has, go_m), _mm256_cmpgt_epi32(k1v, kv2));
                let go2 = bits(short2) & open;
                let load2 = go2 & occ_bits;
                let own2 = if gather { Some((short2, 0)) } else { None };
                if go2 != 0 && go2 & !occ_bits == 0 {
                    // No lane leaps at k + 1 either: k + 2 as well (frames 0.93-0.97 of
                    // pairs, chest1728 30,20 0.985-1.015; docs/results.md, stop 45). The
                    // lanes that move to k + 2 are those of k + 1, terminated ones too
                    // (their samples do not composite: `need3` asks `open3`).
                    let occ2 = occ_bits;
                    let go2_m = mask_of(go2);
                    let kv3 = _mm256_add_epi32(kv2, one);
                    let (base3, f3, _, idx3) =
                        locate(_mm256_mul_ps(_mm256_cvtepi32_ps(kv3), stepv));
                    let s2 = fetch!(base2, f2, load2, own2);
                    lookup(idx3, &mut last_idx, &mut lv, &mut occ_bits);
                    let short3 = _mm256_and_si256(
                        _mm256_and_si256(has, go2_m),
                        _mm256_cmpgt_epi32(k1v, kv3),
                    );
                    let go3 = bits(short3);
                    let load3 = go3 & occ_bits;
                    let own3 = if gather { Some((short3, 0)) } else { None };
                    let s3 = fetch!(base3, f3, load3, own3);
                    composite!(s1, need, &mut acc);
                    let open2 = bits(open_lanes(acc[3], ert));
                    let need2 = go2 & open2 & occ2;
                    composite!(s2, need2, &mut acc);
                    let open3 = bits(open_lanes(acc[3], ert));
                    let need3 = go3 & open3 & occ_bits;
                    composite!(s3, need3, &mut acc);
                    st.steps += u64::from(go2 & open2 != 0) + u64::from(go3 & open3 != 0);
                    st.samples +=
                        u64::from(need.count_ones() + need2.count_ones() + need3.count_ones());
                    kv = _mm256_sub_epi32(
                        _mm256_sub_epi32(_mm256_sub_epi32(kv, go_m), go2_m),
                        mask_of(load3),
                    );
                    lag = open3;
                    leapt = 0;
                    continue;
                }
                let s2 = fetch!(base2, f2, load2, own2);
                composite!(s1, need, &mut acc);
                let open2 = bits(open_lanes(acc[3], ert));
                let need2 = go2 & open2 & occ_bits;
                composite!(s2, need2, &mut acc);
                st.steps += u64::from(go2 & open2 != 0);
                st.samples += u64::from(need.count_ones() + need2.count_ones());
                // Lanes of step k move on one; those of k + 1 in an occupied cell a second
                // (the rest leap from k + 1 next time round).
                kv = _mm256_sub_epi32(_mm256_sub_epi32(kv, go_m), mask_of(load2));
                lag = open2;
                leapt = 0;
                continue;
            }
            if empty != 0 {
                let kb = leap_end(kv, &cell, lv, &leap_ray, &cells_at);
                let kb = _mm256_max_epi32(kb, next);
                let el = empty & live;
                st.skipped += hsum(_mm256_and_si256(_mm256_sub_epi32(kb, kv), mask_of(el))) as u64;
                next = blend_i(next, kb, mask_of(empty));
            }
            if need != 0 {
                let own = if gather {
                    Some((_mm256_andnot_si256(mask_of(leapt), short), load & leapt))
                } else {
                    None
                };
                sample!(base, f, need, load, own, &mut acc);
                st.samples += u64::from(need.count_ones());
            }
            kv = blend_i(kv, next, mask_of(go));
            leapt = empty;
        }
    } else {
        // Rays along an axis: the packet in lockstep, at one sample index `k`.
        let mut k = hmin(blend_i(big, k0v, has));
        // Every lane open as of an earlier sampling step: they choose the loads, so that
        // this step's loads need not wait for the previous step's composite (a terminated
        // lane loads once more, for nothing).
        let mut lag = 0xFFu32;
        // Rays along an axis keep their other two coordinates: where every lane's
        // position on those axes is the same at its first and last sample, it is the
        // same at every sample between (positions are rounded products and sums and a
        // clamp, monotone in `k`), so those axes' share of the base, fractions and cells
        // is worked out once and each step locates along the one axis left. Lanes off
        // their samples take the fixed coordinates too: inside the volume, read (lane
        // by lane) or masked (gathers), never composited.
        let fixed = {
            let t0 = _mm256_mul_ps(_mm256_cvtepi32_ps(k0v), stepv);
            let t1 = _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_sub_epi32(k1v, one)), stepv);
            let clamped = |t: __m256, a: usize| on_axis(t, o[a], d[a], maxv[a], last[a]).0;
            let has_bits = bits(has);
            let same: [bool; 3] = [0, 1, 2].map(|a| {
                let eq = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_EQ_OQ>(
                    clamped(t0, a),
                    clamped(t1, a),
                ));
                bits(eq) & has_bits == has_bits
            });
            match same {
                [false, true, true] => Some(0),
                [true, false, true] => Some(1),
                [true, true, false] => Some(2),
                _ => None,
            }
            .map(|m| {
                // The fixed axes at the first sample, as `locate` works them out.
                let (base, f, cell, idx) = locate(t0);
                let cm = [_mm256_set1_epi32(1), n0, n01][m];
                let (_, i_m, _) = on_axis(t0, o[m], d[m], maxv[m], last[m]);
                Fixed {
                    m,
                    base: _mm256_sub_epi32(base, axis_offset(i_m, m)),
                    idx: _mm256_sub_epi32(idx, _mm256_mullo_epi32(cell[m], cm)),
                    f,
                    cell,
                    o: o[m],
                    d: d[m],
                    max: maxv[m],
                    last: last[m],
                    cm,
                }
            })
        };
        // `locate` for a packet with `fixed` axes.
        let locate_along = |t: __m256, fx: &Fixed| {
            let (_, i, fm) = on_axis(t, fx.o, fx.d, fx.max, fx.last);
            let c = _mm256_srli_epi32::<{ CELL_SHIFT as i32 }>(i);
            let base = _mm256_add_epi32(fx.base, axis_offset(i, fx.m));
            let idx = _mm256_add_epi32(fx.idx, _mm256_mullo_epi32(c, fx.cm));
            let (mut f, mut cell) = (fx.f, fx.cell);
            match fx.m {
                0 => (f[0], cell[0]) = (fm, c),
                1 => (f[1], cell[1]) = (fm, c),
                _ => (f[2], cell[2]) = (fm, c),
            }
            (base, f, cell, idx)
        };
        // Whether a sample at corners' bases `b` whose reads are those of the lanes `w`
        // can take the corners read at `b0` for the lanes `w0`: the same base in every
        // lane, and (gathers read only the lanes asked for) no lane of `w` outside `w0`.
        let reuse = |b: __m256i, b0: __m256i, w: __m256i, w0: __m256i| {
            bits(_mm256_cmpeq_epi32(b, b0)) == 0xFF
                && (!gather || bits(_mm256_andnot_si256(w0, w)) == 0)
        };
        loop {
            let kv = _mm256_set1_epi32(k);
            // Lanes whose ray claims sample k and has not terminated.
            let started = _mm256_cmpgt_epi32(_mm256_add_epi32(kv, one), k0v);
            let before_end = _mm256_cmpgt_epi32(k1v, kv);
            // As the reference's `acc[3] >= ert` stop, negated.
            let open = open_lanes(acc[3], ert);
            let live = _mm256_and_si256(_mm256_and_si256(started, before_end), open);
            // Lanes yet to start.
            let pending = _mm256_andnot_si256(started, has);
            let live_bits = bits(live);
            if live_bits == 0 {
                if bits(pending) == 0 {
                    break;
                }
                k = hmin(blend_i(big, k0v, pending));
                continue;
            }
            // A live lane: this iteration samples or leaps.
            st.steps += 1;
            let t = _mm256_set1_ps(k as f32 * step);
            let (base, f, cell, idx) = match &fixed {
                Some(fx) => locate_along(t, fx),
                None => locate(t),
            };
            lookup(idx, &mut last_idx, &mut lv, &mut occ_bits);
            if occ_bits & live_bits == 0 {
                // Every live lane is in an empty cell: the packet leaps.
                let kb = leap_end(kv, &cell, lv, &leap_ray, &cells_at);
                let kb = blend_i(big, kb, live);
                let kb = _mm256_min_epi32(kb, blend_i(big, k0v, pending));
                let next = hmin(kb).max(k + 1);
                st.skipped += u64::from(live_bits.count_ones()) * (next - k) as u64;
                k = next;
                continue;
            }
            let need_bits = occ_bits & live_bits;
            let within = _mm256_and_si256(started, before_end);
            let open_bits = bits(open);
            let load_bits = occ_bits & bits(within) & std::mem::replace(&mut lag, open_bits);
            // Samples k + 1 (and k + 2) too where every lane stays in its cell (so in its
            // occupancy): the samples' reads and lerps are independent, and issued side by
            // side they overlap; they composite in order, each one's lanes chosen by the
            // opacity after the one before, as separate steps would. Frames 0.90-0.98 of
            // one sample a step with pairs, 0.94-0.99 of pairs with triples; four at a
            // time were slower again (docs/results.md, stop 45).
            let kv2 = _mm256_add_epi32(kv, one);
            let t2 = _mm256_set1_ps((k + 1) as f32 * step);
            let (base2, f2, _, idx2) = match &fixed {
                Some(fx) => locate_along(t2, fx),
                None => locate(t2),
            };
            let t3 = _mm256_set1_ps((k + 2) as f32 * step);
            let (base3, f3, _, idx3) = match &fixed {
                Some(fx) => locate_along(t3, fx),
                None => locate(t3),
            };
            // Positions are monotone in k: a lane in one cell at k and k + 2 is in it at
            // k + 1.
            if bits(_mm256_cmpeq_epi32(idx3, idx)) == 0xFF {
                let within_at = |j: i32| {
                    let kj = _mm256_add_epi32(kv, _mm256_set1_epi32(j));
                    _mm256_and_si256(
                        _mm256_cmpgt_epi32(_mm256_add_epi32(kj, one), k0v),
                        _mm256_cmpgt_epi32(k1v, kj),
                    )
                };
                let (w2, w3) = (within_at(1), within_at(2));
                // A sample whose every lane is on the same voxel cell as the sample before
                // (a step under a voxel along the march axis) takes that one's corners,
                // where it read every lane that this one needs.
                let c1 = read!(base, load_bits, Some((within, 0)));
                let c2 = if reuse(base2, base, w2, within) {
                    c1
                } else {
                    read!(base2, occ_bits & bits(w2) & open_bits, Some((w2, 0)))
                };
                let c3 = if reuse(base3, base2, w3, w2) {
                    c2
                } else {
                    read!(base3, occ_bits & bits(w3) & open_bits, Some((w3, 0)))
                };
                let s1 = classify!(c1, f);
                let s2 = classify!(c2, f2);
                let s3 = classify!(c3, f3);
                composite!(s1, need_bits, &mut acc);
                let mut need_sum = need_bits.count_ones();
                let mut skip_sum = (live_bits & !occ_bits).count_ones();
                // The next sample: its lanes those within their ray and open now.
                macro_rules! then {
                    ($s:expr, $w:expr) => {{
                        let o = open_lanes(acc[3], ert);
                        let l = bits(_mm256_and_si256($w, o));
                        let n = occ_bits & l;
                        composite!($s, n, &mut acc);
                        st.steps += u64::from(l != 0);
                        need_sum += n.count_ones();
                        skip_sum += (l & !occ_bits).count_ones();
                        bits(o)
                    }};
                }
                then!(s2, w2);
                lag = then!(s3, w3);
                st.samples += u64::from(need_sum);
                st.skipped += u64::from(skip_sum);
                k += 3;
                continue;
            }
            if bits(_mm256_cmpeq_epi32(idx2, idx)) == 0xFF {
                let within2 = _mm256_and_si256(
                    _mm256_cmpgt_epi32(_mm256_add_epi32(kv2, one), k0v),
                    _mm256_cmpgt_epi32(k1v, kv2),
                );
                let load2 = occ_bits & bits(within2) & open_bits;
                let c1 = read!(base, load_bits, Some((within, 0)));
                let c2 = if reuse(base2, base, within2, within) {
                    c1
                } else {
                    read!(base2, load2, Some((within2, 0)))
                };
                let s1 = classify!(c1, f);
                let s2 = classify!(c2, f2);
                composite!(s1, need_bits, &mut acc);
                let open2 = open_lanes(acc[3], ert);
                let live2 = bits(_mm256_and_si256(within2, open2));
                lag = bits(open2);
                let need2 = occ_bits & live2;
                composite!(s2, need2, &mut acc);
                st.steps += u64::from(live2 != 0);
                st.samples += u64::from(need_bits.count_ones() + need2.count_ones());
                st.skipped += u64::from(
                    (live_bits & !occ_bits).count_ones() + (live2 & !occ_bits).count_ones(),
                );
                k += 2;
                continue;
            }
            sample!(base, f, need_bits, load_bits, Some((within, 0)), &mut acc);
            st.samples += u64::from(need_bits.count_ones());
            st.skipped += u64::from((live_bits & !occ_bits).count_ones());
            k += 1;
        }
    }
    let mut out = [[0f32; LANES]; 4];
    for (o, a) in out.iter_mut().zip(acc) {
        // SAFETY: `o` holds eight f32.
        unsafe { _mm256_storeu_ps(o.as_mut_ptr(), a) };
    }
    for (j, px) in pk.acc.iter_mut().enumerate() {
        *px = [out[0][j], out[1][j], out[2][j], out[3][j]];
    }
    st
}

/// A lockstep packet's two fixed axes (`march8`): their share of the lanes' corners'
/// base and cell index, their fractions and cells (those of axis `m` unused), and axis
/// `m`'s constants.
struct Fixed {
    m: usize,
    base: __m256i,
    idx: __m256i,
    f: [__m256; 3],
    cell: [__m256i; 3],
    o: __m256,
    d: __m256,
    max: __m256,
    last: __m256,
    cm: __m256i,
}

/// The table entries `rgba[bin]` of the eight lanes' bins, as red, green, blue and
/// opacity vectors: eight loads of an entry and a transpose, cheaper than four gathers.
///
/// # Safety
/// `rgba` holds an entry (four floats) for every lane's bin.
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) unsafe fn rgba8(rgba: *const f32, bin: __m256i) -> [__m256; 4] {
    use std::arch::x86_64::{
        _mm256_castpd_ps, _mm256_castps128_ps256, _mm256_castps_pd, _mm256_insertf128_ps,
        _mm256_unpackhi_pd, _mm256_unpackhi_ps, _mm256_unpacklo_pd, _mm256_unpacklo_ps,
        _mm_loadu_ps,
    };
    let mut b = [0u32; LANES];
    // SAFETY: `b` holds eight u32; every entry is inside the table (caller).
    unsafe {
        _mm256_storeu_si256(b.as_mut_ptr().cast(), bin);
        let q = |j: usize| _mm_loadu_ps(rgba.add(b[j] as usize * 4));
        let pair = |j: usize| _mm256_insertf128_ps::<1>(_mm256_castps128_ps256(q(j)), q(j + 4));
        let (t0, t1, t2, t3) = (pair(0), pair(1), pair(2), pair(3));
        // [r0 r1 g0 g1 | r4 r5 g4 g5], [b0 b1 a0 a1 | b4 b5 a4 a5], and lanes 2, 3, 6, 7.
        let (u0, u1) = (_mm256_unpacklo_ps(t0, t1), _mm256_unpackhi_ps(t0, t1));
        let (u2, u3) = (_mm256_unpacklo_ps(t2, t3), _mm256_unpackhi_ps(t2, t3));
        let lo = |a: __m256, b: __m256| {
            _mm256_castpd_ps(_mm256_unpacklo_pd(_mm256_castps_pd(a), _mm256_castps_pd(b)))
        };
        let hi = |a: __m256, b: __m256| {
            _mm256_castpd_ps(_mm256_unpackhi_pd(_mm256_castps_pd(a), _mm256_castps_pd(b)))
        };
        [lo(u0, u2), hi(u0, u2), lo(u1, u3), hi(u1, u3)]
    }
}

/// Channel `c` (0–3: r, g, b, alpha) of the classification's entries (four floats each)
/// at `bin`, by one gather: as [`rgba8`] gives it.
///
/// # Safety
/// AVX2 is available; `c < 4`; `rgba` holds an entry for every lane's bin.
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) unsafe fn channel8(rgba: *const f32, bin: __m256i, c: usize) -> __m256 {
    // SAFETY: channel `c` of entry `b` is float `4b + c` of the table (caller).
    unsafe { _mm256_i32gather_ps::<4>(rgba.add(c), _mm256_slli_epi32::<2>(bin)) }
}

/// The occupancy entries of cells `idx` by one gather, and which of them have `occupied`
/// set, as bits.
///
/// # Safety
/// AVX2 is available; `leap` holds every lane's cell and the three bytes after it
/// (`Occupancy::leaps`' padding).
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) unsafe fn leaps8(leap: &[u8], idx: __m256i, occupied: u8) -> (__m256i, u32) {
    // SAFETY: each 32-bit word starts at a lane's entry and stays inside `leap` (caller).
    let w = unsafe { _mm256_i32gather_epi32::<1>(leap.as_ptr().cast(), idx) };
    let e = _mm256_and_si256(w, _mm256_set1_epi32(0xFF));
    let m = _mm256_set1_epi32(i32::from(occupied));
    (e, bits(_mm256_cmpeq_epi32(_mm256_and_si256(e, m), m)))
}

/// The occupancy entries of cells `idx` by eight byte loads, widened to words, and which
/// of them are occupied, as bits: for cores whose gathers are slow. The bytes go into one
/// vector as they load, so that the occupied flags come out by one byte mask.
///
/// # Safety
/// AVX2 is available; every lane's cell is an entry of `leap`.
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) unsafe fn leap_bytes8(leap: &[u8], idx: __m256i) -> (__m256i, u32) {
    use std::arch::x86_64::{_mm256_cvtepu8_epi32, _mm_insert_epi8, _mm_movemask_epi8};
    // The byte mask reads each entry's top bit.
    const _: () = assert!(OCCUPIED == 0x80);
    let mut ci = [0u32; LANES];
    // SAFETY: `ci` holds eight u32.
    unsafe { _mm256_storeu_si256(ci.as_mut_ptr().cast(), idx) };
    // SAFETY: the caller's.
    let e = |j: usize| i32::from(unsafe { *leap.get_unchecked(ci[j] as usize) });
    let mut b = std::arch::x86_64::_mm_setzero_si128();
    b = _mm_insert_epi8::<0>(b, e(0));
    b = _mm_insert_epi8::<1>(b, e(1));
    b = _mm_insert_epi8::<2>(b, e(2));
    b = _mm_insert_epi8::<3>(b, e(3));
    b = _mm_insert_epi8::<4>(b, e(4));
    b = _mm_insert_epi8::<5>(b, e(5));
    b = _mm_insert_epi8::<6>(b, e(6));
    b = _mm_insert_epi8::<7>(b, e(7));
    (
        _mm256_cvtepu8_epi32(b),
        (_mm_movemask_epi8(b) & 0xFF) as u32,
    )
}

/// The occupancy's entries of the cells `ci`, lane by lane, into `lv`, and which are
/// occupied, as bits: scalar loads, for both packet loops where they load lane by lane
/// (the entries are wanted as bits, and `N` byte loads cost less than a gather on cores
/// whose gathers are slow).
///
/// # Safety
/// Every cell of `ci` is an entry of `leap`.
#[inline(always)]
pub(crate) unsafe fn leap_entries<const N: usize>(
    leap: &[u8],
    ci: &[u32; N],
    lv: &mut [i32; N],
) -> u32 {
    let mut occ = 0;
    for (j, (&c, l)) in ci.iter().zip(lv.iter_mut()).enumerate() {
        // SAFETY: the caller's.
        let e = unsafe { *leap.get_unchecked(c as usize) };
        *l = i32::from(e);
        occ |= u32::from(e & OCCUPIED != 0) << j;
    }
    occ
}

/// `m ? b : a`, lane-wise on integers.
#[target_feature(enable = "avx2")]
#[inline]
fn blend_i(a: __m256i, b: __m256i, m: __m256i) -> __m256i {
    _mm256_castps_si256(_mm256_blendv_ps(
        _mm256_castsi256_ps(a),
        _mm256_castsi256_ps(b),
        _mm256_castsi256_ps(m),
    ))
}

/// The rays' origins, displacements and directions, each axis by axis across the lanes.
// Plain loops, not closures in `map`: those were sometimes compiled as calls, one per lane
// and axis of every packet (up to 9 % of a frame, stop 41; 7-10 % of a sixteen-lane frame
// when an unrelated change to this file moved LLVM's inlining, stop 45).
#[inline(always)]
pub(crate) fn ray_axes<const N: usize>(rays: &[IndexRay; N]) -> (Axes<N>, Axes<N>, Axes<N>) {
    let (mut o, mut d, mut dir) = ([[0f32; N]; 3], [[0f32; N]; 3], [[0f32; N]; 3]);
    for (j, r) in rays.iter().enumerate() {
        for a in 0..3 {
            o[a][j] = r.o[a];
            d[a][j] = r.d[a];
            dir[a][j] = r.dir[a];
        }
    }
    (o, d, dir)
}

/// Three axes of `N` lanes.
pub(crate) type Axes<const N: usize> = [[f32; N]; 3];

/// The lanes' premultiplied RGBA, channel by channel (a loop, as [`ray_axes`]).
#[inline(always)]
pub(crate) fn channels<const N: usize>(acc: &[[f32; 4]; N]) -> [[f32; N]; 4] {
    let mut out = [[0f32; N]; 4];
    for (j, px) in acc.iter().enumerate() {
        for c in 0..4 {
            out[c][j] = px[c];
        }
    }
    out
}

/// Eight floats as a vector.
#[target_feature(enable = "avx2")]
#[inline]
fn vec8(v: [f32; LANES]) -> __m256 {
    // SAFETY: `v` holds eight f32.
    unsafe { std::arch::x86_64::_mm256_loadu_ps(v.as_ptr()) }
}

/// A packet's rays as [`leap_end`] reads them.
struct LeapRay {
    /// Per axis, all ones where the table's boxes reach back (down) from the cell, and
    /// ahead (up).
    back: [__m256i; 3],
    ahead: [__m256i; 3],
    o: [__m256; 3],
    d: [__m256; 3],
    inv: [__m256; 3],
    k1v: __m256i,
    k1f: __m256,
    nlast: [__m256i; 3],
    stepv: __m256,
    inv_step: __m256,
}

/// [`crate::render::skip::Skip::leap_end`] lane-wise: each lane's sample `k` lies in the
/// empty cell `c` with entry `leap`; the first sample, in `k + 1 ..= k1`, past the cube of
/// empty cells around it, every sample before it checked by the sampler's own cells.
/// Lanes whose entry is below [`LEAP_MIN`] get the exit of their own cell (a cube of one).
#[target_feature(enable = "avx2")]
#[inline]
fn leap_end(
    kv: __m256i,
    c: &[__m256i; 3],
    leap: __m256i,
    r: &LeapRay,
    cells_at: &impl Fn(__m256) -> [__m256i; 3],
) -> __m256i {
    let one = _mm256_set1_epi32(1);
    // The cube's half-width: distance − 1 where leaps are worth it, else the cell alone.
    let far = _mm256_cmpgt_epi32(leap, _mm256_set1_epi32(LEAP_MIN - 1));
    let rad = _mm256_and_si256(_mm256_sub_epi32(leap, one), far);
    let zero_i = _mm256_setzero_si256();
    let zero = _mm256_setzero_ps();
    let mut lo = [zero_i; 3];
    let mut hi = [zero_i; 3];
    let mut te = _mm256_set1_ps(f32::INFINITY);
    for a in 0..3 {
        let (down, up) = (
            _mm256_and_si256(rad, r.back[a]),
            _mm256_and_si256(rad, r.ahead[a]),
        );
        lo[a] = _mm256_max_epi32(_mm256_sub_epi32(c[a], down), zero_i);
        hi[a] = _mm256_min_epi32(_mm256_add_epi32(c[a], up), r.nlast[a]);
        let pos = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_GT_OQ>(r.d[a], zero));
        let neg = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LT_OQ>(r.d[a], zero));
        let up = _mm256_and_si256(pos, _mm256_cmpgt_epi32(r.nlast[a], hi[a]));
        let down = _mm256_and_si256(neg, _mm256_cmpgt_epi32(lo[a], zero_i));
        let face = blend_i(
            _mm256_slli_epi32::<{ CELL_SHIFT as i32 }>(lo[a]),
            _mm256_slli_epi32::<{ CELL_SHIFT as i32 }>(_mm256_add_epi32(hi[a], one)),
            up,
        );
        let ta = _mm256_mul_ps(_mm256_sub_ps(_mm256_cvtepi32_ps(face), r.o[a]), r.inv[a]);
        let ta = _mm256_blendv_ps(
            _mm256_set1_ps(f32::INFINITY),
            ta,
            _mm256_castsi256_ps(_mm256_or_si256(up, down)),
        );
        te = _mm256_min_ps(te, ta);
    }
    // The first sample at or past `te`, and at least the next one.
    let q = _mm256_max_ps(_mm256_min_ps(_mm256_mul_ps(te, r.inv_step), r.k1f), zero);
    let kq = _mm256_cvttps_epi32(q);
    let up = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_cvtepi32_ps(kq), q));
    // `up` is all ones (−1) where the ceiling is one more.
    let kb = _mm256_sub_epi32(kq, up);
    let kb = _mm256_min_epi32(_mm256_max_epi32(kb, _mm256_add_epi32(kv, one)), r.k1v);
    let inside = |k: __m256i| {
        let t = _mm256_mul_ps(_mm256_cvtepi32_ps(k), r.stepv);
        let c = cells_at(t);
        _mm256_and_si256(
            _mm256_and_si256(within(lo[0], c[0], hi[0]), within(lo[1], c[1], hi[1])),
            within(lo[2], c[2], hi[2]),
        )
    };
    // Settled by one sample where a rounding put the estimate past a face.
    let kb1 = _mm256_sub_epi32(kb, one);
    let in1 = inside(kb1);
    if bits(in1) == 0xFF {
        return kb;
    }
    let in2 = inside(_mm256_sub_epi32(kb1, one));
    let fallback = blend_i(_mm256_add_epi32(kv, one), kb1, in2);
    blend_i(fallback, kb, in1)
}

/// The corners of [`Gather8::corners8`] one voxel at a time: for cells whose wider reads
/// would pass the end of the data.
///
/// # Safety
/// For every lane `base + sx + sy + sz < v.len()`.
// Never inlined: a cold path (the last cells of the data), kept out of the eight-lane
// loop's code.
#[target_feature(enable = "avx2")]
#[inline(never)]
pub(crate) unsafe fn corners_exact<T: Gather8>(
    v: &[T],
    base: __m256i,
    [sx, sy, sz]: [usize; 3],
) -> [__m256; 8] {
    let mut b = [0u32; LANES];
    // SAFETY: `b` holds eight u32.
    unsafe { _mm256_storeu_si256(b.as_mut_ptr().cast(), base) };
    let offs = [0, sx, sy, sy + sx, sz, sz + sx, sz + sy, sz + sy + sx];
    // SAFETY: every corner is inside `v` (caller).
    offs.map(|off| {
        vec8(std::array::from_fn(|j| unsafe {
            v.get_unchecked(b[j] as usize + off).to_f32()
        }))
    })
}
