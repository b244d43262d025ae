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
/// picks (the others empty, to be set from elsewhere). Under a `budget` the volume does not
/// fit, or when its voxels are not resident, each picked brick is read from the volume's
/// storage: positioned reads of its raw file (a memory map would keep every page touched
/// resident, and a rank's bricks are spread over the whole file), or its Zarr chunks with
/// at most half the budget (64 MiB without one) of decoded chunks cached. Otherwise the
/// bricks are measured on the voxels.
///
/// # Errors
/// [`crate::Error::Brick`] for a bad brick size, [`crate::Error::Volume`] for a failed read
/// or a missing or corrupt chunk.
pub fn measure_own(
    volume: &Volume,
    brick_size: usize,
    budget: Option<u64>,
    measure: &(dyn Fn(BrickId) -> bool + Sync),
) -> Result<BrickGrid> {
    let over = budget.is_some_and(|b| !super::fits(volume, b));
    let source = if over || !volume.is_resident() {
        BrickSource::of(volume)?
    } else {
        BrickSource::Memory
    };
    if !source.is_file() {
        return Ok(BrickGrid::from_volume_where(volume, brick_size, measure)?);
    }
    if let Some(z) = source.zarr() {
        z.set_chunk_budget(budget.map_or(64 << 20, |b| b / 2));
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
    let [min, max] = T::range_f32(v);
    ValueRange { min, max }
}
