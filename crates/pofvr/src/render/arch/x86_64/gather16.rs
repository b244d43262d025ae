//! The sixteen-lane loop's loads by `vpgatherdd`: a cell's corners, the classification's
//! entries and the occupancy's, one gather instruction per word for all sixteen lanes,
//! where the other form ([`super::avx2`]'s `words`, `rgba8`, a scalar lookup loop) loads
//! each lane's word on its own and inserts it into a vector. Which form a process takes is
//! measured ([`super::gather`]); both read the same words, so the image is the same
//! either way.

use std::arch::x86_64::{
    __m512, __m512i, __mmask16, _mm512_add_epi32, _mm512_and_si512, _mm512_cvtepi32_ps,
    _mm512_i32gather_epi32, _mm512_i32gather_ps, _mm512_set1_epi32, _mm512_slli_epi32,
    _mm512_srai_epi32, _mm512_srli_epi32, _mm512_test_epi32_mask,
};

use super::avx2::Gather8;

/// Voxel types whose cell corners the sixteen-lane loop can gather.
pub(crate) trait Gather16: Gather8 {
    /// [`Gather8::corners8`] on sixteen lanes, by 512-bit gathers of the same words.
    ///
    /// # Safety
    /// AVX-512 F is available; as [`Gather8::corners8`], for every lane.
    unsafe fn corners16(v: &[Self], base: __m512i, step: [usize; 3]) -> [__m512; 8];
}

/// The four 32-bit words at elements `base`, `base + sy`, `base + sz`, `base + sy + sz` of
/// `v`, whose elements are `S` bytes wide, lane by lane (as `avx2`'s `words`).
///
/// # Safety
/// AVX-512 F is available; every word lies inside `v`'s allocation.
#[inline(always)]
unsafe fn words16<T, const S: i32>(v: &[T], base: __m512i, sy: usize, sz: usize) -> [__m512i; 4] {
    let p = v.as_ptr().cast::<i32>();
    // SAFETY: the words are inside `v` (caller); offsets are below 2^31 (`avx2::fits`).
    let at = |off: usize| unsafe {
        _mm512_i32gather_epi32::<S>(_mm512_add_epi32(base, _mm512_set1_epi32(off as i32)), p)
    };
    [at(0), at(sy), at(sz), at(sy + sz)]
}

/// The corners from the four words of [`words16`]: `lo` and `hi` take a word's corner and
/// its x neighbour.
#[inline(always)]
fn pairs16(
    [w00, w10, w01, w11]: [__m512i; 4],
    lo: impl Fn(__m512i) -> __m512,
    hi: impl Fn(__m512i) -> __m512,
) -> [__m512; 8] {
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

impl Gather16 for u8 {
    #[inline(always)]
    unsafe fn corners16(v: &[u8], base: __m512i, [_, sy, sz]: [usize; 3]) -> [__m512; 8] {
        // SAFETY: each word starts at a corner and ends OVERREAD bytes past its x
        // neighbour; AVX-512 F (caller).
        unsafe {
            let w = words16::<u8, 1>(v, base, sy, sz);
            let m = _mm512_set1_epi32(0xFF);
            let lo = |w| _mm512_cvtepi32_ps(_mm512_and_si512(w, m));
            let hi = |w| _mm512_cvtepi32_ps(_mm512_and_si512(_mm512_srli_epi32::<8>(w), m));
            pairs16(w, lo, hi)
        }
    }
}

impl Gather16 for u16 {
    #[inline(always)]
    unsafe fn corners16(v: &[u16], base: __m512i, [_, sy, sz]: [usize; 3]) -> [__m512; 8] {
        // SAFETY: each word is a corner and its x neighbour; AVX-512 F (caller).
        unsafe {
            let w = words16::<u16, 2>(v, base, sy, sz);
            let m = _mm512_set1_epi32(0xFFFF);
            let lo = |w| _mm512_cvtepi32_ps(_mm512_and_si512(w, m));
            let hi = |w| _mm512_cvtepi32_ps(_mm512_srli_epi32::<16>(w));
            pairs16(w, lo, hi)
        }
    }
}

impl Gather16 for i16 {
    #[inline(always)]
    unsafe fn corners16(v: &[i16], base: __m512i, [_, sy, sz]: [usize; 3]) -> [__m512; 8] {
        // SAFETY: each word is a corner and its x neighbour; AVX-512 F (caller).
        unsafe {
            let w = words16::<i16, 2>(v, base, sy, sz);
            // Arithmetic shifts sign-extend each half.
            let lo = |w| _mm512_cvtepi32_ps(_mm512_srai_epi32::<16>(_mm512_slli_epi32::<16>(w)));
            let hi = |w| _mm512_cvtepi32_ps(_mm512_srai_epi32::<16>(w));
            pairs16(w, lo, hi)
        }
    }
}

impl Gather16 for f32 {
    #[inline(always)]
    unsafe fn corners16(v: &[f32], base: __m512i, [sx, sy, sz]: [usize; 3]) -> [__m512; 8] {
        let p = v.as_ptr();
        // SAFETY: every offset is a corner of the cell; AVX-512 F (caller).
        let at = |off: usize| unsafe {
            _mm512_i32gather_ps::<4>(_mm512_add_epi32(base, _mm512_set1_epi32(off as i32)), p)
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

/// Channel `c` (0–3: r, g, b, alpha) of the classification's entries (four floats each)
/// at `bin`, as `packet`'s `rgba8` gives it for each half.
///
/// # Safety
/// AVX-512 F is available; `c < 4`; `rgba` holds an entry for every lane's bin.
#[target_feature(enable = "avx512f")]
#[inline]
pub(crate) unsafe fn channel16(rgba: *const f32, bin: __m512i, c: usize) -> __m512 {
    // SAFETY: channel `c` of entry `b` is float `4b + c` of the table (caller).
    unsafe { _mm512_i32gather_ps::<4>(_mm512_slli_epi32::<2>(bin), rgba.add(c)) }
}

/// The occupancy entries of cells `idx`, and which of them have `occupied` set, as bits.
///
/// # Safety
/// AVX-512 F is available; `leap` holds every lane's cell and the three bytes after it
/// (`Occupancy::leaps`' padding).
#[target_feature(enable = "avx512f")]
#[inline]
pub(crate) unsafe fn leaps16(leap: &[u8], idx: __m512i, occupied: u8) -> (__m512i, __mmask16) {
    // SAFETY: each 32-bit word starts at a lane's entry and stays inside `leap` (caller).
    let w = unsafe { _mm512_i32gather_epi32::<1>(idx, leap.as_ptr().cast()) };
    let e = _mm512_and_si512(w, _mm512_set1_epi32(0xFF));
    (
        e,
        _mm512_test_epi32_mask(e, _mm512_set1_epi32(i32::from(occupied))),
    )
}

#[cfg(test)]
mod tests {
    use super::super::packet16::{halves, join, LANES};
    use super::*;
    use std::arch::x86_64::_mm512_loadu_epi32;

    #[test]
    fn gathers_read_the_words_the_per_lane_loads_read() {
        if !super::super::packet16::available() {
            println!("skipped: this CPU does not run the sixteen-lane loop");
            return;
        }
        // Each type's corners of the same cells, both ways, bit for bit; bases up to the
        // last one whose words stay inside the data.
        fn check<T: Gather16>(v: &[T], step: [usize; 3]) {
            let last = (v.len() - 1 - step[0] - step[1] - step[2] - T::OVERREAD) as i32;
            let b: [i32; LANES] = std::array::from_fn(|j| last - (j as i32 * 37) % (last + 1));
            // SAFETY: this CPU runs the loop; every base leaves its words inside `v`.
            let (g, l) = unsafe { corners_both(v, &b, step) };
            assert_eq!(g, l, "{}", std::any::type_name::<T>());
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

    /// The corners of the cells at `b` by [`Gather16::corners16`] and by
    /// [`Gather8::corners8`] on each half, as bits.
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512dq,avx512vl")]
    unsafe fn corners_both<T: Gather16>(
        v: &[T],
        b: &[i32; LANES],
        step: [usize; 3],
    ) -> ([[u32; LANES]; 8], [[u32; LANES]; 8]) {
        let bits = |c: [__m512; 8]| {
            c.map(|c| {
                let mut o = [0f32; LANES];
                // SAFETY: `o` holds sixteen f32.
                unsafe { std::arch::x86_64::_mm512_storeu_ps(o.as_mut_ptr(), c) };
                o.map(f32::to_bits)
            })
        };
        // SAFETY: caller.
        unsafe {
            let base = _mm512_loadu_epi32(b.as_ptr());
            let [b0, b1] = halves(base);
            let (h0, h1) = (T::corners8(v, b0, step), T::corners8(v, b1, step));
            (
                bits(T::corners16(v, base, step)),
                bits(std::array::from_fn(|i| join(h0[i], h1[i]))),
            )
        }
    }

    #[test]
    fn the_table_lookups_match_the_per_lane_ones() {
        if !super::super::packet16::available() {
            println!("skipped: this CPU does not run the sixteen-lane loop");
            return;
        }
        let rgba: Vec<f32> = (0..64 * 4).map(|i| i as f32 * 0.5).collect();
        let leap: Vec<u8> = (0..40u8)
            .map(|i| if i % 3 == 0 { 0x80 | i } else { i })
            .collect();
        let bins: [i32; LANES] = std::array::from_fn(|j| (j as i32 * 13) % 64);
        let cells: [i32; LANES] = std::array::from_fn(|j| 36 - j as i32 * 2);
        // SAFETY: this CPU runs the loop; every bin is in the table, every cell's word
        // is inside `leap`.
        let (q, e, m) = unsafe { lookups(&rgba, &leap, &bins, &cells) };
        for j in 0..LANES {
            let b = bins[j] as usize;
            assert_eq!(q.map(|c| c[j]), [0, 1, 2, 3].map(|c| rgba[4 * b + c]));
            let want = leap[cells[j] as usize];
            assert_eq!(e[j], i32::from(want));
            assert_eq!(m >> j & 1 != 0, want & 0x80 != 0);
        }
    }

    /// [`channel16`] at `bins` and [`leaps16`] at `cells`, as arrays.
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512dq,avx512vl")]
    unsafe fn lookups(
        rgba: &[f32],
        leap: &[u8],
        bins: &[i32; LANES],
        cells: &[i32; LANES],
    ) -> ([[f32; LANES]; 4], [i32; LANES], __mmask16) {
        // SAFETY: caller.
        unsafe {
            let bin = _mm512_loadu_epi32(bins.as_ptr());
            let q: [__m512; 4] = std::array::from_fn(|c| channel16(rgba.as_ptr(), bin, c));
            let (e, m) = leaps16(leap, _mm512_loadu_epi32(cells.as_ptr()), 0x80);
            let mut eo = [0i32; LANES];
            std::arch::x86_64::_mm512_storeu_epi32(eo.as_mut_ptr(), e);
            let q = q.map(|c| {
                let mut o = [0f32; LANES];
                std::arch::x86_64::_mm512_storeu_ps(o.as_mut_ptr(), c);
                o
            });
            (q, eo, m)
        }
    }
}
