//! The trilinear sampler: the one definition of a sample's value, shared by the scalar
//! ray caster, its shading and the sampled POF builder; the SIMD loops compute the same
//! float operations lane-wise.

use crate::volume::Voxel;

/// Trilinear interpolation with positions clamped to the volume, over the whole volume or
/// over a copy of one box of it (a [`crate::brick::BrickCopy`]).
///
/// A copy is addressed by subtracting its integer origin from the clamped position: that
/// subtraction is exact in f32 (the origin is an integer no larger than the position, both
/// below 2²⁴), so the cell index and the fractions — and hence every sample — are bit for bit
/// those of the whole volume, as long as the position stays inside the copy.
///
/// `COPY` says which: the whole volume's sampler skips the origin (zero) and what it
/// guards, which the sampled POF builder's inner loop would otherwise pay for.
#[derive(Clone, Copy)]
pub(crate) struct TrilinearSampler<'v, T, const COPY: bool = false> {
    pub(super) v: &'v [T],
    /// The whole volume's last index per axis (the clamp).
    pub(super) max: [f32; 3],
    /// Index of voxel `v[0]` in the volume.
    pub(super) origin: [f32; 3],
    /// Last cell of the copy per axis.
    pub(super) last_cell: [usize; 3],
    /// `last_cell` as floats (exact: cells are below 2²⁴ per axis).
    last: [f32; 3],
    pub(super) stride: [usize; 3],
    pub(super) step: [usize; 3],
}

impl<'v, T: Voxel> TrilinearSampler<'v, T> {
    /// Over the whole data `v` of `dims` voxels.
    pub(crate) fn new(v: &'v [T], dims: [usize; 3]) -> Self {
        Self::over(v, dims, [0; 3], dims)
    }
}

impl<'v, T: Voxel> TrilinearSampler<'v, T> {
    /// `lin`'s volume over its blocked copy `v` ([`super::blocks`]): the same clamp and
    /// cells; `stride` holds the blocks' element strides per axis, and `step` the corners'
    /// offsets inside a block. Only the packet loop, which splits a cell index into its
    /// block and its place in it, may address it.
    pub(crate) fn blocked(v: &'v [T], lin: &Self) -> Self {
        use super::blocks::{BLOCK, EDGE, SIDE};
        let nb = lin.last_cell.map(|c| c / EDGE + 1);
        debug_assert_eq!(v.len(), nb[0] * nb[1] * nb[2] * BLOCK);
        TrilinearSampler {
            v,
            stride: [BLOCK, nb[0] * BLOCK, nb[0] * nb[1] * BLOCK],
            step: [1, SIDE, SIDE * SIDE],
            ..*lin
        }
    }
}

impl<'v, T: Voxel> TrilinearSampler<'v, T, true> {
    /// Over `v`, the `dims` voxels from `origin` of a volume of `volume_dims` voxels.
    pub(crate) fn local(
        v: &'v [T],
        dims: [usize; 3],
        origin: [usize; 3],
        volume_dims: [usize; 3],
    ) -> Self {
        Self::over(v, dims, origin, volume_dims)
    }
}

impl<'v, T: Voxel, const COPY: bool> TrilinearSampler<'v, T, COPY> {
    fn over(v: &'v [T], dims: [usize; 3], origin: [usize; 3], volume_dims: [usize; 3]) -> Self {
        debug_assert_eq!(v.len(), dims[0] * dims[1] * dims[2]);
        let stride = [1, dims[0], dims[0] * dims[1]];
        TrilinearSampler {
            v,
            max: volume_dims.map(|d| (d - 1) as f32),
            origin: origin.map(|o| o as f32),
            last_cell: dims.map(|d| d.saturating_sub(2)),
            last: dims.map(|d| d.saturating_sub(2) as f32),
            stride,
            step: std::array::from_fn(|a| if dims[a] > 1 { stride[a] } else { 0 }),
        }
    }

    /// The value at `p`: the trilinear interpolation in its cell.
    #[inline(always)]
    pub(crate) fn sample(&self, p: [f32; 3]) -> f32 {
        self.cell(p).value()
    }

    /// The cell that holds `p` (after the clamp), with its eight corners and `p`'s
    /// fractions in it.
    #[inline(always)]
    pub(crate) fn cell(&self, p: [f32; 3]) -> Cell {
        let mut base = 0usize;
        let mut f = [0f32; 3];
        for a in 0..3 {
            // max/min rather than clamp: clamp's `min <= max` assertion is not hoisted.
            // The origin's subtraction is exact (see the type's comment); for a copy the
            // result is ≥ 0 while the position stays inside it.
            let x = p[a].max(0.0).min(self.max[a]);
            let (x, c) = if COPY {
                let x = x - self.origin[a];
                (x, x.max(0.0))
            } else {
                // The origin is 0: x is ≥ 0 already.
                (x, x)
            };
            // The cell: ⌊min(x, last)⌋ = min(⌊x⌋, last) for x ≥ 0 and an integer `last`.
            let c = c.min(self.last[a]);
            // SAFETY: c is finite and in [0, last] after the max/min above (NaN positions
            // cannot occur: rays are finite and volumes hold finite values).
            let i = unsafe { c.to_int_unchecked::<u32>() } as usize;
            f[a] = x - i as f32;
            // (x is the unit stride: a constant, not a load and a multiply.)
            base += if a == 0 { i } else { i * self.stride[a] };
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
        Cell {
            c: [
                at(base),
                at(base + sx),
                at(base + sy),
                at(base + sy + sx),
                at(base + sz),
                at(base + sz + sx),
                at(base + sz + sy),
                at(base + sz + sy + sx),
            ],
            f,
        }
    }
}

/// One cell of the lattice around a position: its corners
/// `[c000, c100, c010, c110, c001, c101, c011, c111]` (digits: x, y, z) and the position's
/// fractions `f` in it. Every loop computes [`Cell::value`] and [`Cell::gradient`] with
/// these float operations in this order (no fused multiply–adds), lane-wise where it is a
/// vector loop.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Cell {
    pub(crate) c: [f32; 8],
    pub(crate) f: [f32; 3],
}

impl Cell {
    /// The trilinear interpolation: four x-lerps, two y-lerps, one z-lerp.
    #[inline(always)]
    pub(crate) fn value(&self) -> f32 {
        let ([c000, c100, c010, c110, c001, c101, c011, c111], [fx, fy, fz]) = (self.c, self.f);
        let c00 = c000 + (c100 - c000) * fx;
        let c10 = c010 + (c110 - c010) * fx;
        let c01 = c001 + (c101 - c001) * fx;
        let c11 = c011 + (c111 - c011) * fx;
        let c0 = c00 + (c10 - c00) * fy;
        let c1 = c01 + (c11 - c01) * fy;
        c0 + (c1 - c0) * fz
    }

    /// The derivative of [`Cell::value`] with respect to the index position: the
    /// gradient of the trilinear interpolant itself, in value per voxel.
    ///
    /// Shading takes this gradient rather than central differences, for cost and for
    /// what it reads. It comes from the eight corners the sample has already gathered: a
    /// dozen subtractions and lerps, lane-wise in the vector loops, and no load. Central
    /// differences on the cached corners (a gradient at each corner, interpolated) need the
    /// 24 voxels around the cell as well, four times the gathers of the sample itself, and
    /// reach a voxel beyond the cell, which a brick's private copy does not hold for
    /// samples at its faces; six more trilinear samples cost more still. In image quality
    /// it is the exact normal of the field being composited, the trilinear interpolant; its
    /// one artefact is that across a cell face the component normal to that face may jump,
    /// which shows as cell-sized facets only where a voxel covers several pixels.
    ///
    /// Each component is the difference of the two opposite faces' bilinear values,
    /// computed from the edge differences along the axis with the same lerp order as
    /// [`Cell::value`]: z from the two y-lerps, y from the x-lerps, x from the x edges.
    #[inline(always)]
    pub(crate) fn gradient(&self) -> [f32; 3] {
        let ([c000, c100, c010, c110, c001, c101, c011, c111], [fx, fy, fz]) = (self.c, self.f);
        let (d00, d10, d01, d11) = (c100 - c000, c110 - c010, c101 - c001, c111 - c011);
        let c00 = c000 + d00 * fx;
        let c10 = c010 + d10 * fx;
        let c01 = c001 + d01 * fx;
        let c11 = c011 + d11 * fx;
        let (e0, e1) = (c10 - c00, c11 - c01);
        let c0 = c00 + e0 * fy;
        let c1 = c01 + e1 * fy;
        let x0 = d00 + (d10 - d00) * fy;
        let x1 = d01 + (d11 - d01) * fy;
        [x0 + (x1 - x0) * fz, e0 + (e1 - e0) * fz, c1 - c0]
    }
}
