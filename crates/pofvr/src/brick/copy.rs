//! Private copies of bricks: what a distributed rank keeps of the volume.
//!
//! Bricks are dealt round-robin along a space-filling curve, so a rank's bricks are spread
//! over the whole volume, and with the file stored x-fastest one page holds rows of several
//! bricks of different ranks: sampling a memory map in place would map nearly every page of
//! the file into every rank. A rank instead copies its own bricks once, then lets the map's
//! pages go ([`crate::volume::Volume::release_pages`]), and holds about `1/ranks` of the
//! volume (times the ghost overhead, `((B+3)/B)³`).

use rayon::prelude::*;

use super::{BrickGrid, BrickId};
use crate::volume::{Volume, Voxel, VoxelData, Voxels};
use crate::with_voxels;

/// The voxels one brick's samples can read: its box plus one voxel on every side (gradients
/// at ±½ voxel, and positions that round a hair outside a face), clipped to the volume.
#[derive(Debug)]
pub struct BrickCopy {
    origin: [usize; 3],
    dims: [usize; 3],
    data: VoxelData,
}

pub(crate) fn copy_box<T: Voxel>(
    v: &[T],
    vdims: [usize; 3],
    lo: [usize; 3],
    n: [usize; 3],
) -> Vec<T> {
    let mut out = Vec::with_capacity(n[0] * n[1] * n[2]);
    for z in lo[2]..lo[2] + n[2] {
        for y in lo[1]..lo[1] + n[1] {
            let row = lo[0] + vdims[0] * (y + vdims[1] * z);
            out.extend_from_slice(&v[row..row + n[0]]);
        }
    }
    out
}

impl BrickCopy {
    /// The box a copy of brick `id` holds: its first voxel and its voxels per axis (the
    /// brick's box plus one voxel on every side, clipped to the volume).
    #[must_use]
    pub fn apron_box(grid: &BrickGrid, id: BrickId) -> ([usize; 3], [usize; 3]) {
        let (lo, hi) = grid.voxel_bounds(id);
        let vdims = grid.volume_dims();
        let origin: [usize; 3] = std::array::from_fn(|a| lo[a].saturating_sub(1));
        let dims: [usize; 3] =
            std::array::from_fn(|a| (hi[a] + 1).min(vdims[a] - 1) + 1 - origin[a]);
        (origin, dims)
    }

    /// A copy made elsewhere (read from a file by [`crate::store`]): the voxels of the box
    /// `origin`, `dims`, x fastest.
    ///
    /// # Panics
    /// When `data` does not hold `dims` voxels (a caller's bug).
    #[must_use]
    pub fn from_parts(origin: [usize; 3], dims: [usize; 3], data: VoxelData) -> Self {
        assert_eq!(data.len(), dims[0] * dims[1] * dims[2], "brick copy size");
        BrickCopy { origin, dims, data }
    }

    /// Copies brick `id` of `grid` out of `volume`.
    #[must_use]
    pub fn new(volume: &Volume, grid: &BrickGrid, id: BrickId) -> Self {
        let (origin, dims) = Self::apron_box(grid, id);
        let vdims = volume.dims();
        let data = match volume.data() {
            VoxelData::U8(x) => {
                VoxelData::U8(Voxels::owned(copy_box(x.as_slice(), vdims, origin, dims)))
            }
            VoxelData::U16(x) => {
                VoxelData::U16(Voxels::owned(copy_box(x.as_slice(), vdims, origin, dims)))
            }
            VoxelData::I16(x) => {
                VoxelData::I16(Voxels::owned(copy_box(x.as_slice(), vdims, origin, dims)))
            }
            VoxelData::F32(x) => {
                VoxelData::F32(Voxels::owned(copy_box(x.as_slice(), vdims, origin, dims)))
            }
        };
        BrickCopy { origin, dims, data }
    }

    /// Index of the copy's first voxel in the volume.
    #[must_use]
    pub fn origin(&self) -> [usize; 3] {
        self.origin
    }

    /// Voxels of the copy per axis.
    #[must_use]
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// The copied voxels, x fastest.
    #[must_use]
    pub fn data(&self) -> &VoxelData {
        &self.data
    }

    /// Bytes held.
    #[must_use]
    pub fn bytes(&self) -> usize {
        self.data.len() * self.data.data_type().size()
    }

    /// The voxel at volume index `(x, y, z)`, if the copy holds it.
    #[must_use]
    pub fn value(&self, x: usize, y: usize, z: usize) -> Option<f32> {
        let l = [x, y, z];
        if (0..3).any(|a| l[a] < self.origin[a] || l[a] >= self.origin[a] + self.dims[a]) {
            return None;
        }
        let i = (x - self.origin[0])
            + self.dims[0] * ((y - self.origin[1]) + self.dims[1] * (z - self.origin[2]));
        Some(with_voxels!(&self.data, v => v[i].to_f32()))
    }
}

/// Private copies of a set of bricks (a rank's own), by brick id.
#[derive(Debug, Default)]
pub struct BrickStore {
    copies: Vec<Option<BrickCopy>>,
    bytes: usize,
}

impl BrickStore {
    /// Copies `ids` out of `volume`, in parallel.
    #[must_use]
    pub fn new(volume: &Volume, grid: &BrickGrid, ids: &[BrickId]) -> Self {
        let made: Vec<(BrickId, BrickCopy)> = ids
            .par_iter()
            .filter(|id| id.index() < grid.len())
            .map(|id| (*id, BrickCopy::new(volume, grid, *id)))
            .collect();
        let mut copies: Vec<Option<BrickCopy>> = (0..grid.len()).map(|_| None).collect();
        let mut bytes = 0;
        for (id, c) in made {
            bytes += c.bytes();
            copies[id.index()] = Some(c);
        }
        BrickStore { copies, bytes }
    }

    /// The copy of brick `id`, if held.
    #[must_use]
    pub fn get(&self, id: BrickId) -> Option<&BrickCopy> {
        self.copies.get(id.index()).and_then(Option::as_ref)
    }

    /// Voxel bytes held over all copies.
    #[must_use]
    pub fn bytes(&self) -> usize {
        self.bytes
    }

    /// Number of bricks held.
    #[must_use]
    pub fn len(&self) -> usize {
        self.copies.iter().filter(|c| c.is_some()).count()
    }

    /// True when no brick is held.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}
