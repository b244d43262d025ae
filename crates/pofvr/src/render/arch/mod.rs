//! The sample loops, laid out by architecture: [`generic`] holds the scalar loop, the
//! reference every other one equals bit for bit, shaded or not (no fused multiply–adds
//! anywhere, the same float operations per sample), and the definition of shading;
//! `x86_64` holds the SSE2 loop (part of the baseline) and the eight-samples-at-a-time
//! AVX2 loop, chosen at run time. All of them sample through one
//! [`super::sampler::TrilinearSampler`] and shade from its [`super::sampler::Cell`].

pub(crate) mod generic;
#[cfg(target_arch = "x86_64")]
pub(crate) mod x86_64;

use super::lattice::IndexRay;
use super::sampler::TrilinearSampler;
use super::transfer_function::ClassifierView;
#[cfg(not(target_arch = "x86_64"))]
use crate::volume::Voxel;

/// What a sample loop needs of the ray caster.
#[derive(Clone, Copy)]
pub(crate) struct MarchParams<'c> {
    /// The classification by value.
    pub(crate) cls: ClassifierView<'c>,
    /// Sample distance in units of the smallest spacing.
    pub(crate) step: f32,
    /// Early ray termination opacity.
    pub(crate) ert: f32,
    /// Gradient shading, with the volume's voxel spacing; `None` when off.
    pub(crate) shade: Option<[f32; 3]>,
    /// Whether the AVX2 loop may run (set only where the CPU has it).
    pub(crate) avx2: bool,
    /// Whether the march engine's packets go sixteen rays at a time on AVX-512 (set only
    /// where the CPU has it, and with `avx2`); eight on AVX2 otherwise.
    pub(crate) avx512: bool,
    /// Whether to run the scalar reference loop whatever the CPU has (for comparisons).
    pub(crate) scalar: bool,
    /// Whether the march engine's packet loops prefetch the voxels ahead of their rays
    /// (`x86_64::prefetch`: by default, where the voxels exceed the last-level cache).
    /// Prefetches change no result.
    pub(crate) prefetch: bool,
    /// Whether the packet loop that runs (sixteen lanes or eight) loads its corners and
    /// table entries by gathers (`x86_64::gather`: by default, where they measured faster
    /// than loads lane by lane in that loop). Either form reads the same words.
    pub(crate) gather: bool,
}

/// Voxel types every loop can sample.
#[cfg(target_arch = "x86_64")]
pub(crate) trait Gather:
    x86_64::avx2::Gather8 + x86_64::sse2::GatherOne + x86_64::gather16::Gather16
{
}
#[cfg(target_arch = "x86_64")]
impl<T: x86_64::avx2::Gather8 + x86_64::sse2::GatherOne + x86_64::gather16::Gather16> Gather for T {}
/// Voxel types every loop can sample.
#[cfg(not(target_arch = "x86_64"))]
pub(crate) trait Gather: Voxel {}
#[cfg(not(target_arch = "x86_64"))]
impl<T: Voxel> Gather for T {}

/// Whether this CPU runs the AVX2 loop.
pub(crate) fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    return x86_64::avx2::available();
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// Whether this CPU runs the AVX-512 packet loop (`POFVR_SIMD=avx2` turns it off).
pub(crate) fn avx512_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    return x86_64::packet16::available();
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// Whether the march engine's packet loops should prefetch for a volume of
/// `voxel_bytes` (`x86_64::prefetch::pays`; never where there is no such loop).
pub(crate) fn prefetch_pays(voxel_bytes: usize) -> bool {
    #[cfg(target_arch = "x86_64")]
    return x86_64::prefetch::pays(voxel_bytes);
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = voxel_bytes;
        false
    }
}

/// Whether the march engine's packet loop of sixteen lanes (`sixteen`) or of eight should
/// load by gathers on this CPU (`x86_64::gather::pays`; never where there is no such loop).
pub(crate) fn gather_pays(sixteen: bool) -> bool {
    #[cfg(target_arch = "x86_64")]
    return x86_64::gather::pays(sixteen);
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = sixteen;
        false
    }
}

/// Composites samples `range` of `ray` behind `acc`; returns the samples taken. Every
/// loop performs, for every sample, the float operations of [`generic::march`], so they
/// agree bit for bit and any of them may be taken: the scalar one where `p.scalar` asks
/// for it, the fastest the CPU runs otherwise.
#[inline(always)]
pub(crate) fn march<T: Gather, const COPY: bool>(
    p: &MarchParams<'_>,
    tri: &TrilinearSampler<'_, T, COPY>,
    ray: &IndexRay,
    range: (i32, i32),
    acc: &mut [f32; 4],
) -> u64 {
    #[cfg(target_arch = "x86_64")]
    if !p.scalar {
        return x86_64::march(p, tri, ray, range, acc);
    }
    generic::march(p, tri, ray, range, acc)
}

/// Whether [`march_packet`] runs for `p` and `tri`: the AVX2 loop over packets of eight
/// rays, where the CPU has AVX2 and the scalar loop is not asked for.
#[inline(always)]
pub(crate) fn packets<T: Gather>(p: &MarchParams<'_>, tri: &TrilinearSampler<'_, T>) -> bool {
    #[cfg(target_arch = "x86_64")]
    return !p.scalar && p.avx2 && x86_64::avx2::fits(tri);
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (p, tri);
        false
    }
}

/// Marches the eight rays of `pk` through the whole volume, each as [`march`] would, bit
/// for bit, leaving out the samples in the empty cells of `tab`'s occupancy. Only where
/// [`packets`] holds (it returns `None`, having done nothing, elsewhere). `blocked`, the
/// same volume over its blocked copy ([`TrilinearSampler::blocked`]), is read instead of
/// `tri` where given; the pixels are the same.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn march_packet<T: Gather>(
    p: &MarchParams<'_>,
    tri: &TrilinearSampler<'_, T>,
    blocked: Option<&TrilinearSampler<'_, T>>,
    tab: &x86_64::packet::PacketTables<'_>,
    pk: &mut x86_64::packet::Packet,
) -> Option<x86_64::packet::PacketStats> {
    if p.scalar {
        return None;
    }
    x86_64::march_packet(p, tri, blocked, tab, pk)
}

/// [`march_packet`] for packets of sixteen rays, on AVX-512: only where [`packets`] holds
/// and `p.avx512` is set (it returns `None`, having done nothing, elsewhere).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn march_packet16<T: Gather>(
    p: &MarchParams<'_>,
    tri: &TrilinearSampler<'_, T>,
    tab: &x86_64::packet::PacketTables<'_>,
    pk: &mut x86_64::packet::Packet<{ x86_64::packet16::LANES }>,
) -> Option<x86_64::packet::PacketStats> {
    if p.scalar {
        return None;
    }
    x86_64::march_packet16(p, tri, tab, pk)
}

/// The loop the march engine's packets take with `p`: "avx512" (sixteen rays), "avx2"
/// (eight), or "none" (rays walk one at a time).
pub(crate) fn packet_name(p: &MarchParams<'_>) -> &'static str {
    match (p.scalar, p.avx2, p.avx512) {
        (false, true, true) => "avx512",
        (false, true, false) => "avx2",
        _ => "none",
    }
}

/// The loop [`march`] takes with `p`: "avx2", "sse2" or "scalar".
pub(crate) fn name(p: &MarchParams<'_>) -> &'static str {
    match (p.scalar, p.avx2, cfg!(target_arch = "x86_64")) {
        (false, true, _) => "avx2",
        (false, false, true) => "sse2",
        _ => "scalar",
    }
}
