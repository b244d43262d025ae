//! The value ranges of some bricks only (a rank's own), read from the volume's storage when
//! its voxels are not resident: what a rank of a distributed job measures before the ranks
//! exchange their ranges, so that it reads no brick it does not own.

use rayon::prelude::*;

use super::BrickSource;
use crate::brick::{BrickGrid, BrickId, ValueRange};
use crate::error::Result;
use crate::volume::{Volume, Voxel};
use crate::with_voxels;

/// The grid of `volume` in bricks of `brick_size` with the ranges of the bricks `measure`
/// picks (the others empty, to be set from elsewhere): measured on the voxels when they are
/// resident (a memory map reads only the pages of those bricks), otherwise read brick by
/// brick from the volume's Zarr chunks with at most `chunk_budget` bytes of decoded chunks
/// cached.
///
/// # Errors
/// [`crate::Error::Brick`] for a bad brick size, [`crate::Error::Volume`] for a missing or
/// corrupt chunk.
pub fn measure_own(
    volume: &Volume,
    brick_size: usize,
    chunk_budget: u64,
    measure: &(dyn Fn(BrickId) -> bool + Sync),
) -> Result<BrickGrid> {
    if volume.is_resident() {
        return Ok(BrickGrid::from_volume_where(volume, brick_size, measure)?);
    }
    let source = BrickSource::of(volume)?;
    if let Some(z) = source.zarr() {
        z.set_chunk_budget(chunk_budget);
    }
    let mut grid = BrickGrid::unmeasured(volume.dims(), brick_size)?;
    // Id order: neighbouring bricks share chunks, which then stay cached while needed.
    let ids: Vec<BrickId> = grid.ids().filter(|id| measure(*id)).collect();
    let ranges = ids
        .par_iter()
        .with_min_len(64)
        .map(|id| {
            let (lo, hi) = grid.voxel_bounds(*id);
            let n = std::array::from_fn(|a| hi[a] - lo[a] + 1);
            let data = source.read_box(volume, lo, n)?;
            Ok(with_voxels!(&data, v => range_of(v)))
        })
        .collect::<std::result::Result<Vec<ValueRange>, crate::volume::VolumeError>>()?;
    for (id, r) in ids.into_iter().zip(ranges) {
        grid.set_range(id, r)?;
    }
    Ok(grid)
}

fn range_of<T: Voxel>(v: &[T]) -> ValueRange {
    let (mut mn, mut mx) = (f32::INFINITY, f32::NEG_INFINITY);
    for x in v {
        let x = x.to_f32();
        mn = mn.min(x);
        mx = mx.max(x);
    }
    ValueRange { min: mn, max: mx }
}
