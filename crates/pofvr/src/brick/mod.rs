//! Stage 2: the volume cut into bricks.
//!
//! Brick `(i, j, k)` covers the index-space box `[i·B, min((i+1)·B, dims-1)]` on each axis,
//! so neighbouring bricks share their face plane and the bricks tile the sampled box
//! `[0, dims-1]` exactly. Trilinear samples inside a brick read the voxels of that closed
//! box (the one-voxel ghost layer on the high side), and gradients read one voxel more on
//! each side; a brick can therefore be sampled on its own. Its value range is taken over
//! exactly the voxels its samples can interpolate, so it bounds every sample in it.

pub(crate) mod copy;
#[cfg(test)]
mod test;

pub use copy::{BrickCopy, BrickStore};

use rayon::prelude::*;

use crate::volume::{Volume, Voxel};
use crate::with_voxels;

/// Default brick edge in voxels.
pub const DEFAULT_BRICK_SIZE: usize = 16;

/// Index of a brick in the grid, x fastest.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
pub struct BrickId(pub u32);

impl BrickId {
    /// As a `usize` index.
    #[inline]
    #[must_use]
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// Minimum and maximum of the voxels a brick's samples can interpolate.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ValueRange {
    /// Smallest value.
    pub min: f32,
    /// Largest value.
    pub max: f32,
}

/// An index-space box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexBox {
    /// Low corner.
    pub lo: [f32; 3],
    /// High corner.
    pub hi: [f32; 3],
}

/// The volume cut into bricks, with each brick's value range.
#[derive(Clone, Debug)]
pub struct BrickGrid {
    brick_size: usize,
    volume_dims: [usize; 3],
    counts: [usize; 3],
    ranges: Vec<ValueRange>,
}

/// Errors building a brick grid.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BrickError {
    /// The brick size is unusable.
    #[error("brick size {0} is invalid: expected 2..=1024")]
    BadSize(usize),
    /// A brick id outside the grid.
    #[error("brick {id} is outside the grid of {count} bricks")]
    UnknownBrick {
        /// The id.
        id: u32,
        /// Bricks in the grid.
        count: usize,
    },
}

impl BrickGrid {
    /// Cuts `volume` into bricks of `brick_size`³ voxels and measures each brick's range.
    ///
    /// # Errors
    /// [`BrickError::BadSize`] when `brick_size` is outside `2..=1024`.
    pub fn from_volume(volume: &Volume, brick_size: usize) -> Result<Self, BrickError> {
        Self::from_volume_where(volume, brick_size, &|_| true)
    }

    /// The grid of a volume of `dims` voxels cut into `brick_size`³ bricks, no brick
    /// measured (every range empty until [`BrickGrid::set_range`]): for ranges measured
    /// elsewhere, from storage or by other ranks, without touching the volume's voxels.
    ///
    /// # Errors
    /// [`BrickError::BadSize`] when `brick_size` is outside `2..=1024`.
    pub fn unmeasured(dims: [usize; 3], brick_size: usize) -> Result<Self, BrickError> {
        let counts = Self::counts_for(dims, brick_size)?;
        let empty = ValueRange {
            min: f32::INFINITY,
            max: f32::NEG_INFINITY,
        };
        Ok(BrickGrid {
            brick_size,
            volume_dims: dims,
            counts,
            ranges: vec![empty; counts[0] * counts[1] * counts[2]],
        })
    }

    /// Bricks along x, y, z for a volume of `dims` voxels cut into `brick_size`³ bricks.
    ///
    /// # Errors
    /// [`BrickError::BadSize`] when `brick_size` is outside `2..=1024`.
    pub fn counts_for(dims: [usize; 3], brick_size: usize) -> Result<[usize; 3], BrickError> {
        if !(2..=1024).contains(&brick_size) {
            return Err(BrickError::BadSize(brick_size));
        }
        Ok(dims.map(|d| (d.saturating_sub(1)).div_ceil(brick_size).max(1)))
    }

    /// As [`BrickGrid::from_volume`], reading only the bricks `measure` selects: the others
    /// get an empty range (min +∞, max −∞) until [`BrickGrid::set_range`] fills them in.
    /// A distributed run measures each rank's own bricks and exchanges the ranges, so that
    /// no rank reads the whole volume.
    ///
    /// # Errors
    /// [`BrickError::BadSize`] when `brick_size` is outside `2..=1024`.
    pub fn from_volume_where(
        volume: &Volume,
        brick_size: usize,
        measure: &(dyn Fn(BrickId) -> bool + Sync),
    ) -> Result<Self, BrickError> {
        let dims = volume.dims();
        let counts = Self::counts_for(dims, brick_size)?;
        let n = counts[0] * counts[1] * counts[2];
        let mut grid = BrickGrid {
            brick_size,
            volume_dims: dims,
            counts,
            ranges: Vec::new(),
        };
        let unmeasured = ValueRange {
            min: f32::INFINITY,
            max: f32::NEG_INFINITY,
        };
        let ranges = with_voxels!(volume.data(), v => {
            (0..n)
                .into_par_iter()
                .map(|b| {
                    let id = BrickId(b as u32);
                    if measure(id) {
                        grid.measure(v, dims, id)
                    } else {
                        unmeasured
                    }
                })
                .collect()
        });
        grid.ranges = ranges;
        Ok(grid)
    }

    /// Sets the value range of brick `id` (measured elsewhere, e.g. by another rank).
    ///
    /// # Errors
    /// [`BrickError::UnknownBrick`] when `id` is not in the grid.
    pub fn set_range(&mut self, id: BrickId, range: ValueRange) -> Result<(), BrickError> {
        let n = self.ranges.len();
        let slot = self
            .ranges
            .get_mut(id.index())
            .ok_or(BrickError::UnknownBrick { id: id.0, count: n })?;
        *slot = range;
        Ok(())
    }

    fn measure<T: Voxel>(&self, v: &[T], dims: [usize; 3], id: BrickId) -> ValueRange {
        let (lo, hi) = self.voxel_bounds(id);
        let (mut mn, mut mx) = (f32::INFINITY, f32::NEG_INFINITY);
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                let row = dims[0] * (y + dims[1] * z);
                let [a, b] = T::range_f32(&v[row + lo[0]..=row + hi[0]]);
                mn = mn.min(a);
                mx = mx.max(b);
            }
        }
        ValueRange { min: mn, max: mx }
    }

    /// Inclusive voxel index bounds of the samples of brick `id` (its box, ghost included).
    #[must_use]
    pub fn voxel_bounds(&self, id: BrickId) -> ([usize; 3], [usize; 3]) {
        self.voxel_bounds_at(self.coords(id))
    }

    /// [`BrickGrid::voxel_bounds`] of the brick at coordinates `c`.
    #[inline]
    fn voxel_bounds_at(&self, c: [usize; 3]) -> ([usize; 3], [usize; 3]) {
        let lo: [usize; 3] = std::array::from_fn(|a| c[a] * self.brick_size);
        let hi: [usize; 3] =
            std::array::from_fn(|a| ((c[a] + 1) * self.brick_size).min(self.volume_dims[a] - 1));
        (lo, hi)
    }

    /// The brick's index-space box.
    #[must_use]
    pub fn index_box(&self, id: BrickId) -> IndexBox {
        self.index_box_at(self.coords(id))
    }

    /// [`BrickGrid::index_box`] of the brick at coordinates `c` (no division by the
    /// counts: culling asks for the boxes of eight sub-bricks per visible brick).
    #[inline]
    #[must_use]
    fn index_box_at(&self, c: [usize; 3]) -> IndexBox {
        let (lo, hi) = self.voxel_bounds_at(c);
        IndexBox {
            lo: lo.map(|x| x as f32),
            hi: hi.map(|x| x as f32),
        }
    }

    /// Brick coordinates `(i, j, k)` of `id`.
    #[inline]
    #[must_use]
    pub fn coords(&self, id: BrickId) -> [usize; 3] {
        let i = id.index();
        [
            i % self.counts[0],
            (i / self.counts[0]) % self.counts[1],
            i / (self.counts[0] * self.counts[1]),
        ]
    }

    /// The id of the brick at coordinates `c`.
    #[inline]
    #[must_use]
    pub fn id(&self, c: [usize; 3]) -> BrickId {
        BrickId((c[0] + self.counts[0] * (c[1] + self.counts[1] * c[2])) as u32)
    }

    /// The bricks of `fine` (a grid of the same volume with a brick size dividing this
    /// one's) that make up brick `id`, with their index boxes.
    ///
    /// # Panics
    /// When `fine`'s brick size does not divide this grid's (a setup error).
    #[must_use]
    pub fn sub_bricks(&self, id: BrickId, fine: &BrickGrid) -> Vec<(BrickId, IndexBox)> {
        let mut out = Vec::new();
        self.sub_bricks_into(id, fine, &mut out);
        out
    }

    /// [`BrickGrid::sub_bricks`] into `out` (cleared first), x fastest: culling asks for
    /// them for every visible brick, into one reused vector.
    ///
    /// # Panics
    /// When `fine`'s brick size does not divide this grid's (a setup error).
    pub fn sub_bricks_into(
        &self,
        id: BrickId,
        fine: &BrickGrid,
        out: &mut Vec<(BrickId, IndexBox)>,
    ) {
        assert!(
            self.brick_size.is_multiple_of(fine.brick_size),
            "sub-bricks of {} need a dividing brick size, not {}",
            self.brick_size,
            fine.brick_size
        );
        out.clear();
        let k = self.brick_size / fine.brick_size;
        let c = self.coords(id).map(|x| x * k);
        let n = fine.counts;
        for z in c[2]..(c[2] + k).min(n[2]) {
            for y in c[1]..(c[1] + k).min(n[1]) {
                for x in c[0]..(c[0] + k).min(n[0]) {
                    let f = [x, y, z];
                    out.push((fine.id(f), fine.index_box_at(f)));
                }
            }
        }
    }

    /// Bricks along x, y, z.
    #[must_use]
    pub fn counts(&self) -> [usize; 3] {
        self.counts
    }

    /// Total number of bricks.
    #[must_use]
    pub fn len(&self) -> usize {
        self.ranges.len()
    }

    /// True when the grid has no bricks (never, for a valid volume).
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.ranges.is_empty()
    }

    /// Brick edge in voxels.
    #[must_use]
    pub fn brick_size(&self) -> usize {
        self.brick_size
    }

    /// Voxel counts of the volume the grid was cut from.
    #[must_use]
    pub fn volume_dims(&self) -> [usize; 3] {
        self.volume_dims
    }

    /// The value range of brick `id`.
    #[must_use]
    pub fn range(&self, id: BrickId) -> ValueRange {
        self.ranges[id.index()]
    }

    /// Every brick's value range, by id.
    #[must_use]
    pub fn ranges(&self) -> &[ValueRange] {
        &self.ranges
    }

    /// All brick ids.
    pub fn ids(&self) -> impl Iterator<Item = BrickId> + '_ {
        (0..self.len() as u32).map(BrickId)
    }

    /// The value range of the whole volume.
    #[must_use]
    pub fn value_range(&self) -> ValueRange {
        self.ranges.iter().fold(
            ValueRange {
                min: f32::INFINITY,
                max: f32::NEG_INFINITY,
            },
            |a, r| ValueRange {
                min: a.min.min(r.min),
                max: a.max.max(r.max),
            },
        )
    }
}
