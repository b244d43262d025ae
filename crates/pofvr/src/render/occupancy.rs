//! The occupancy hierarchy the march engine skips empty space with: per 4³ trilinear cells,
//! the value range of the voxels their samples interpolate from (built once per volume),
//! and, per weights, which of those cells — and which 32³ blocks of them — can hold a
//! sample of nonzero opacity.
//!
//! A sample at index position `x` interpolates the eight corners of trilinear cell
//! `i = min(⌊x⌋, dims − 2)` per axis (the sampler's clamp), so the voxels `i` and `i + 1`.
//! Occupancy cell `c` holds trilinear cells `4c .. 4c + 4`, so its samples read voxels
//! `4c ..= 4c + 4`: the range below is over that span, one-voxel apron included. A
//! trilinear value lies within its corners' range up to the rounding of three lerps (a few
//! ulps of the largest corner), which the test widens the range by; the classification bin
//! is monotone in the value, so a cell whose widened range falls only on bins of zero
//! opacity holds only samples of zero opacity, and the engine may skip them without
//! changing a bit of the image.

use rayon::prelude::*;

use super::transfer_function::{Classifier, BIN_MAX, TF_BINS};
use crate::volume::{Volume, Voxel};
use crate::with_voxels;

/// Trilinear cells per occupancy cell along each axis.
pub const CELL: usize = 4;
/// log₂ of [`CELL`].
pub(crate) const CELL_SHIFT: u32 = 2;
/// Occupancy cells per block (the brick level of the hierarchy) along each axis.
pub const BLOCK: usize = 8;
/// log₂ of [`CELL`] · [`BLOCK`]: trilinear cells to blocks.
pub(crate) const BLOCK_SHIFT: u32 = 5;

/// Trilinear cells per axis of a volume of `dims` voxels: `dims − 1`, and one cell (which
/// reads voxel 0 only) on a one-voxel axis — the sampler's `last_cell + 1`.
fn trilinear_cells(dims: [usize; 3]) -> [usize; 3] {
    dims.map(|d| d.saturating_sub(2) + 1)
}

/// The value range of every occupancy cell's voxels (see the [module](self)): what the
/// per-weights occupancy is rebuilt from. Built once per volume.
#[derive(Clone, Debug)]
pub struct CellRanges {
    /// Occupancy cells per axis.
    cells: [usize; 3],
    /// `[min, max]` per cell, x fastest.
    range: Vec<[f32; 2]>,
}

/// `[min, max]` of `it`.
fn min_max(it: impl Iterator<Item = [f32; 2]>) -> [f32; 2] {
    it.fold([f32::INFINITY, f32::NEG_INFINITY], |[lo, hi], [a, b]| {
        [lo.min(a), hi.max(b)]
    })
}

/// The voxels occupancy cell `c` reads along an axis of `n` voxels.
fn span(c: usize, n: usize) -> std::ops::RangeInclusive<usize> {
    let lo = c * CELL;
    lo..=(lo + CELL).min(n - 1)
}

impl CellRanges {
    /// Measures `volume`: separable passes (x within a slice, then y, then z over slices),
    /// parallel over slices, so each voxel is read once.
    #[must_use]
    pub fn new(volume: &Volume) -> Self {
        let dims = volume.dims();
        let cells = trilinear_cells(dims).map(|n| n.div_ceil(CELL));
        let [nx, ny, _] = dims;
        let [cx, cy, cz] = cells;
        // Per slice z: the x-then-y reduction, cx × cy ranges.
        let slices: Vec<Vec<[f32; 2]>> = with_voxels!(volume.data(), v => {
            v.par_chunks(nx * ny).map(|slice| reduce_slice(slice, nx, ny, cx, cy)).collect()
        });
        let mut range = vec![[0f32; 2]; cx * cy * cz];
        range
            .par_chunks_mut(cx * cy)
            .enumerate()
            .for_each(|(z, out)| {
                for (i, o) in out.iter_mut().enumerate() {
                    *o = min_max(span(z, slices.len()).map(|s| slices[s][i]));
                }
            });
        CellRanges { cells, range }
    }

    /// Occupancy cells per axis.
    #[must_use]
    pub fn cells(&self) -> [usize; 3] {
        self.cells
    }

    /// `[min, max]` of the voxels the samples of cell `c` interpolate from.
    #[must_use]
    pub fn range(&self, c: [usize; 3]) -> [f32; 2] {
        self.range[(c[2] * self.cells[1] + c[1]) * self.cells[0] + c[0]]
    }
}

/// One slice's ranges over the x then y spans of every cell.
fn reduce_slice<T: Voxel>(
    slice: &[T],
    nx: usize,
    ny: usize,
    cx: usize,
    cy: usize,
) -> Vec<[f32; 2]> {
    let rows: Vec<[f32; 2]> = slice
        .chunks_exact(nx)
        .flat_map(|row| {
            (0..cx).map(move |c| {
                min_max(span(c, nx).map(|x| {
                    let v = row[x].to_f32();
                    [v, v]
                }))
            })
        })
        .collect();
    (0..cy)
        .flat_map(|c| {
            let rows = &rows;
            (0..cx).map(move |x| min_max(span(c, ny).map(|y| rows[y * cx + x])))
        })
        .collect()
}

/// Which cells and blocks can hold a sample of nonzero opacity under one classification:
/// rebuilt from [`CellRanges`] whenever the weights (or the step) change.
#[derive(Clone, Debug)]
pub struct Occupancy {
    cells: [usize; 3],
    cell: Vec<bool>,
    blocks: [usize; 3],
    block: Vec<bool>,
    /// Blocks where at least half the cells are occupied: the engine marches through them
    /// without walking their cells, whose crossings would cost more than the few empty
    /// samples they skip (marching a sample of zero opacity changes nothing).
    dense: Vec<bool>,
}

impl Occupancy {
    /// The occupancy of `ranges` under `cls`: a cell is occupied when some bin its widened
    /// range falls on has nonzero opacity; a block when one of its cells is.
    #[must_use]
    pub fn new(ranges: &CellRanges, cls: &Classifier) -> Self {
        let view = cls.view();
        // Bins of nonzero opacity below each bin.
        let mut below = vec![0u32; TF_BINS + 1];
        for (b, s) in view.rgba.iter().enumerate() {
            below[b + 1] = below[b] + u32::from(s[3] != 0.0);
        }
        // The classifier's bin of `v` (`ClassifierView::sample`), monotone in `v`; not
        // clamp, as there: `max` maps NaN to bin 0.
        #[allow(clippy::manual_clamp)]
        let bin = |v: f32| ((v - view.lo) * view.scale).max(0.0).min(BIN_MAX) as usize;
        let cell: Vec<bool> = ranges
            .range
            .par_iter()
            .map(|&[lo, hi]| {
                // The rounding of the trilinear lerps stays within a few ulps of the
                // largest corner; widen by more than that.
                let m = lo.abs().max(hi.abs()) * (8.0 * f32::EPSILON) + f32::MIN_POSITIVE;
                below[bin(hi + m) + 1] > below[bin(lo - m)]
            })
            .collect();
        let cells = ranges.cells;
        let blocks = cells.map(|n| n.div_ceil(BLOCK));
        let n = blocks[0] * blocks[1] * blocks[2];
        let (mut occupied, mut all) = (vec![0u32; n], vec![0u32; n]);
        for z in 0..cells[2] {
            for y in 0..cells[1] {
                let row = &cell[(z * cells[1] + y) * cells[0]..][..cells[0]];
                let b = ((z / BLOCK) * blocks[1] + y / BLOCK) * blocks[0];
                for (x, &occ) in row.iter().enumerate() {
                    occupied[b + x / BLOCK] += u32::from(occ);
                    all[b + x / BLOCK] += 1;
                }
            }
        }
        let block = occupied.iter().map(|o| *o > 0).collect();
        let dense = occupied
            .iter()
            .zip(&all)
            .map(|(o, a)| 2 * o >= *a)
            .collect();
        Occupancy {
            cells,
            cell,
            blocks,
            block,
            dense,
        }
    }

    /// Whether occupancy cell `c` can hold a sample of nonzero opacity.
    #[inline(always)]
    #[must_use]
    pub fn cell(&self, c: [u32; 3]) -> bool {
        let [cx, cy, _] = self.cells;
        self.cell[(c[2] as usize * cy + c[1] as usize) * cx + c[0] as usize]
    }

    /// Whether block `b` (of [`BLOCK`]³ cells) holds an occupied cell.
    #[inline(always)]
    #[must_use]
    pub fn block(&self, b: [u32; 3]) -> bool {
        let [bx, by, _] = self.blocks;
        self.block[(b[2] as usize * by + b[1] as usize) * bx + b[0] as usize]
    }

    /// Whether block `b` is occupied and dense (see the field).
    #[inline(always)]
    #[must_use]
    pub(crate) fn dense(&self, b: [u32; 3]) -> bool {
        let [bx, by, _] = self.blocks;
        self.dense[(b[2] as usize * by + b[1] as usize) * bx + b[0] as usize]
    }

    /// Occupied cells, and all cells.
    #[must_use]
    pub fn occupied_cells(&self) -> (usize, usize) {
        (self.cell.iter().filter(|c| **c).count(), self.cell.len())
    }
}
