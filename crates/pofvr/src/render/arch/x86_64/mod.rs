//! The x86_64 sample loops: AVX2 where the CPU has it, SSE2 (the baseline) otherwise and
//! for the last cells of the data, where the eight-lane gather would read past the end.

pub(crate) mod avx2;
pub(crate) mod packet;
pub(crate) mod packet16;
pub(crate) mod sse2;

use super::{Gather, MarchParams};
use crate::render::lattice::IndexRay;
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
    tab: &PacketTables<'_>,
    pk: &mut Packet,
) -> Option<PacketStats> {
    if !(p.avx2 && avx2::fits(tri)) {
        return None;
    }
    // SAFETY: `avx2` is only set where the CPU has AVX2; `fits` was checked; the tables
    // are the caller's, built for this volume and classification.
    Some(unsafe {
        if p.shade.is_some() {
            packet::march8::<T, true>(p, tri, tab, pk)
        } else {
            packet::march8::<T, false>(p, tri, tab, pk)
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
