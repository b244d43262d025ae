//! The x86_64 sample loops: AVX2 where the CPU has it, SSE2 (the baseline) otherwise and
//! for the last cells of the data, where the eight-lane gather would read past the end.

pub(crate) mod avx2;
pub(crate) mod gather;
pub(crate) mod gather16;
pub(crate) mod packet;
pub(crate) mod packet16;
pub(crate) mod prefetch;
pub(crate) mod ranges;
pub(crate) mod sse2;

use super::{Gather, MarchParams};
use crate::brick::IndexBox;
use crate::render::lattice::{sample_range, IndexRay};
use crate::render::sampler::TrilinearSampler;
use packet::{Packet, PacketStats, PacketTables};

/// [`super::march`].
#[inline(always)]
pub(crate) fn march<T: Gather, const COPY: bool>(
    p: &MarchParams<'_>,
    tri: &TrilinearSampler<'_, T, COPY>,
    ray: &IndexRay,
    range: (i32, i32),
    acc: &mut [f32; 4],
) -> u64 {
    if p.avx2 && avx2::fits(tri) {
        let mut a = avx2::load(acc);
        // SAFETY: `avx2` is only set where the CPU has AVX2; `fits` was checked.
        let (n, rest) = unsafe {
            if p.shade.is_some() {
                avx2::march::<T, COPY, true>(p, tri, ray, range, &mut a)
            } else {
                avx2::march::<T, COPY, false>(p, tri, ray, range, &mut a)
            }
        };
        avx2::store(&a, acc);
        return match rest {
            None => n,
            // The last cells of the data: the one-sample loop finishes the ray.
            Some(k) => n + sse2::march(p, tri, ray, (k, range.1), acc),
        };
    }
    sse2::march(p, tri, ray, range, acc)
}

/// [`super::march_packet`] where the AVX2 loop runs: `None` (having done nothing)
/// elsewhere.
#[inline(always)]
pub(crate) fn march_packet<T: Gather>(
    p: &MarchParams<'_>,
    tri: &TrilinearSampler<'_, T>,
    blocked: Option<&TrilinearSampler<'_, T>>,
    tab: &PacketTables<'_>,
    pk: &mut Packet,
) -> Option<PacketStats> {
    if !(p.avx2 && avx2::fits(tri)) {
        return None;
    }
    let blocked = blocked.filter(|b| avx2::fits(*b));
    // SAFETY: `avx2` is only set where the CPU has AVX2; `fits` was checked; the tables
    // are the caller's, built for this volume and classification.
    // Oblique packets go lane by lane, those along an axis in lockstep (`packet16::oblique`):
    // two functions, so that neither loop's code depends on the other's.
    let first = (0..packet::LANES)
        .find(|&j| pk.k1[j] > pk.k0[j])
        .unwrap_or(0);
    let oblique = packet16::oblique(&pk.rays[first].d);
    // The blocked copy serves oblique packets only: a ray along an axis walks rows or
    // columns of the volume's own layout, whose lines it reads in order (along x, blocks
    // made frames 1.14 x slower; along y, no faster: docs/results.md, stop 48).
    Some(unsafe {
        match (p.shade.is_some(), oblique, blocked) {
            (true, true, Some(b)) => packet::march8::<T, true, true, true>(p, b, tab, pk),
            (false, true, Some(b)) => packet::march8::<T, false, true, true>(p, b, tab, pk),
            (true, true, None) => packet::march8::<T, true, true, false>(p, tri, tab, pk),
            (true, false, _) => packet::march8::<T, true, false, false>(p, tri, tab, pk),
            (false, true, None) => packet::march8::<T, false, true, false>(p, tri, tab, pk),
            (false, false, _) => packet::march8::<T, false, false, false>(p, tri, tab, pk),
        }
    })
}

/// [`super::march_packet16`] where the AVX-512 packet loop runs: `None` (having done
/// nothing) elsewhere.
#[inline(always)]
pub(crate) fn march_packet16<T: Gather>(
    p: &MarchParams<'_>,
    tri: &TrilinearSampler<'_, T>,
    tab: &PacketTables<'_>,
    pk: &mut Packet<{ packet16::LANES }>,
) -> Option<PacketStats> {
    if !(p.avx2 && p.avx512 && avx2::fits(tri)) {
        return None;
    }
    // SAFETY: `avx512` is only set where the CPU has AVX-512 F/BW/DQ/VL, and `avx2` where
    // it has AVX2; `fits` was checked; the tables are the caller's, built for this volume
    // and classification.
    Some(unsafe {
        if p.shade.is_some() {
            packet16::march16::<T, true>(p, tri, tab, pk)
        } else {
            packet16::march16::<T, false>(p, tri, tab, pk)
        }
    })
}

/// Sets `k0` and `k1` of each lane of `pk` whose bit is set in `valid` to the samples its
/// ray claims in `b` (`sample_range(ray.span(b)?, step)`; `(0, 0)` where it misses, and in
/// the other lanes), eight lanes at a time where AVX2 runs ([`ranges::ranges8`]); returns
/// the lanes whose ray meets `b`, as bits.
pub(crate) fn packet_ranges<const N: usize>(
    p: &MarchParams<'_>,
    pk: &mut Packet<N>,
    valid: u32,
    b: &IndexBox,
    step: f32,
) -> u32 {
    const L: usize = ranges::LANES;
    if p.avx2 && N.is_multiple_of(L) {
        let mut hit = 0;
        for g in 0..N / L {
            let r = g * L..(g + 1) * L;
            // SAFETY: `avx2` is only set where the CPU has AVX2.
            let h = unsafe {
                ranges::ranges8(
                    pk.rays[r.clone()].try_into().expect("eight rays"),
                    valid >> (g * L) & 0xFF,
                    b,
                    step,
                    (&mut pk.k0[r.clone()]).try_into().expect("eight lanes"),
                    (&mut pk.k1[r]).try_into().expect("eight lanes"),
                )
            };
            hit |= h << (g * L);
        }
        return hit;
    }
    let mut hit = 0;
    for j in 0..N {
        let span = (valid >> j & 1 != 0).then(|| pk.rays[j].span(b)).flatten();
        (pk.k0[j], pk.k1[j]) = span.map_or((0, 0), |s| sample_range(s, step));
        hit |= u32::from(span.is_some()) << j;
    }
    hit
}
