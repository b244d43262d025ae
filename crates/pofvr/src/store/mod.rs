//! Volumes larger than memory: a brick store with a memory budget.
//!
//! With `--memory-budget SIZE` a volume that does not fit the budget is not sampled through
//! one mapping of the whole file: the brick engine asks a [`BrickCache`] for each brick it
//! renders (its predicted-visible set, then its repairs), and the cache reads it, with its
//! one-voxel apron, from a [`BrickSource`] with positioned reads, keeping decoded bricks in
//! an LRU within the budget. The bricks' value ranges are measured by streaming the file
//! once, slab by slab ([`measure_grid`]). Images are the same bit for bit: a brick is
//! rendered from its copy exactly as from the volume.
//!
//! The volume itself stays memory-mapped (untouched pages cost no memory) for what must
//! see the whole lattice: the march engine and `--whole`, the exact cull mode, and the
//! ideal and proxy predictors. A budgeted scene therefore renders with the brick engine
//! unless asked otherwise.

mod cache;
mod own;
mod scan;
mod size;
mod source;
#[cfg(test)]
mod test;
#[cfg(test)]
mod test_pof;
#[cfg(test)]
mod test_zarr;
mod zarr_source;

use std::sync::Arc;

pub use cache::{BrickCache, CacheSummary, ReadCounts};
pub use own::measure_own;
pub use scan::measure_grid;
pub use size::parse_size;
pub use source::BrickSource;
pub use zarr_source::ZarrSource;

use crate::brick::BrickGrid;
use crate::error::Result;
use crate::volume::Volume;

/// Voxel bytes of `volume`.
#[must_use]
pub fn volume_bytes(volume: &Volume) -> u64 {
    volume.data().len() as u64 * volume.data_type().size() as u64
}

/// True when `volume` fits within `budget` bytes, so that it is rendered as a whole.
#[must_use]
pub fn fits(volume: &Volume, budget: u64) -> bool {
    volume_bytes(volume) <= budget
}

/// The brick cache a scene of `volume` renders from under `budget`: `None` without a
/// budget or when the volume fits it.
///
/// # Errors
/// [`crate::Error::Volume`] when the volume's file cannot be opened again.
pub fn cache_for(volume: &Volume, budget: Option<u64>) -> Result<Option<Arc<BrickCache>>> {
    match budget {
        Some(b) if !fits(volume, b) => {
            let source = BrickSource::of(volume)?;
            // A Zarr level's decoded chunks take half the budget, its bricks the rest: within a
            // frame chunks are what is reused (each brick is read once), and a frame's working
            // front of chunks must stay cached for each to be decoded about once (measured:
            // a quarter decoded the 512x512x1728 body's chunks 1.7 times each, a half 1.1).
            if let Some(z) = source.zarr() {
                z.set_chunk_budget(b / 2);
            }
            Ok(Some(Arc::new(BrickCache::new(source, b))))
        }
        _ => Ok(None),
    }
}

/// The brick grid of `volume` with its value ranges: streamed from its file (or Zarr
/// chunks) in slabs of at most a quarter of the budget when a budget is set, the volume
/// does not fit it and its voxels are in storage, or when they are not resident; measured
/// on the volume otherwise.
///
/// # Errors
/// [`crate::Error::Brick`] for a bad brick size, [`crate::Error::Volume`] for a failed read.
pub fn grid_for(volume: &Volume, brick_size: usize, budget: Option<u64>) -> Result<BrickGrid> {
    // A volume that is not resident is streamed whatever the budget (64 MiB slabs without one).
    let budget = budget
        .filter(|b| !fits(volume, *b))
        .or_else(|| (!volume.is_resident()).then_some(256 << 20));
    if let Some(b) = budget {
        let source = BrickSource::of(volume)?;
        if let Some(z) = source.zarr() {
            z.set_chunk_budget(b / 2);
        }
        if source.is_file() {
            return measure_grid(volume, &source, brick_size, b / 4);
        }
    }
    Ok(BrickGrid::from_volume(volume, brick_size)?)
}

/// This process's peak resident set size in bytes (`VmHWM`, Linux), 0 where unknown.
#[must_use]
pub fn peak_rss_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmHWM:"))
                .and_then(|v| v.split_whitespace().next()?.parse::<u64>().ok())
        })
        .map_or(0, |kib| kib * 1024)
}
