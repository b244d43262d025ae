//! Bricks' value ranges measured by streaming a file once, slab by slab, instead of
//! mapping the whole volume: what a store over a file needs before its first frame.

use rayon::prelude::*;

use super::BrickSource;
use crate::brick::{BrickGrid, BrickId, ValueRange};
use crate::error::Result;
use crate::volume::{Volume, Voxel};
use crate::with_voxels;

/// The brick grid of `volume` with every brick's value range (the same ranges as
/// [`BrickGrid::from_volume`]), read from `source` one layer of bricks at a time: each slab
/// holds at most `max_slab_bytes` (but at least one row of bricks), and neighbouring slabs
/// share their face plane, so the file is read about once (`(B+1)/B` times).
///
/// # Errors
/// [`crate::Error::Brick`] for a bad brick size, [`crate::Error::Volume`] when a read fails.
pub fn measure_grid(
    volume: &Volume,
    source: &BrickSource,
    brick_size: usize,
    max_slab_bytes: u64,
) -> Result<BrickGrid> {
    // No brick is measured here: every range starts empty and is set below.
    let mut grid = BrickGrid::unmeasured(volume.dims(), brick_size)?;
    let d = volume.dims();
    let c = grid.counts();
    let b = brick_size;
    let row_bytes = (d[0] * (b + 1) * (b + 1) * volume.data_type().size()) as u64;
    let rows_per_slab = (max_slab_bytes / row_bytes.max(1)).clamp(1, c[1] as u64) as usize;
    for k in 0..c[2] {
        let z0 = k * b;
        let z1 = ((k + 1) * b).min(d[2] - 1);
        for j0 in (0..c[1]).step_by(rows_per_slab) {
            let j1 = (j0 + rows_per_slab).min(c[1]);
            let y0 = j0 * b;
            let y1 = (j1 * b).min(d[1] - 1);
            let origin = [0, y0, z0];
            let n = [d[0], y1 - y0 + 1, z1 - z0 + 1];
            let slab = source.read_box(volume, origin, n)?;
            let ids: Vec<BrickId> = (j0..j1)
                .flat_map(|j| (0..c[0]).map(move |i| (i, j)))
                .map(|(i, j)| grid.id([i, j, k]))
                .collect();
            let ranges: Vec<ValueRange> = with_voxels!(&slab, v => {
                ids.par_iter()
                    .map(|id| range_in(v, &grid, *id, origin, n))
                    .collect()
            });
            for (id, r) in ids.iter().zip(ranges) {
                grid.set_range(*id, r)?;
            }
        }
    }
    Ok(grid)
}

/// The range of brick `id`'s voxels in a slab whose first voxel is `origin` and which has
/// `n` voxels per axis.
fn range_in<T: Voxel>(
    v: &[T],
    grid: &BrickGrid,
    id: BrickId,
    origin: [usize; 3],
    n: [usize; 3],
) -> ValueRange {
    let (lo, hi) = grid.voxel_bounds(id);
    let (mut mn, mut mx) = (f32::INFINITY, f32::NEG_INFINITY);
    for z in lo[2]..=hi[2] {
        for y in lo[1]..=hi[1] {
            let row = n[0] * ((y - origin[1]) + n[1] * (z - origin[2])) - origin[0];
            let [a, b] = T::range_f32(&v[row + lo[0]..=row + hi[0]]);
            mn = mn.min(a);
            mx = mx.max(b);
        }
    }
    ValueRange { min: mn, max: mx }
}
