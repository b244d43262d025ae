//! A POF build within a memory budget (`pofvr pof build --memory-budget SIZE`): the volume
//! is read once, slab by slab, through the store's positioned reads (or Zarr chunks), and
//! the records are written to the output file as each slab finishes, so that neither the
//! volume nor the table (946 MB for the typical build of the 512×512×1728 chest CT with
//! sets) is ever held whole.
//!
//! ## Why the file is the same, byte for byte
//!
//! A brick's record depends only on its voxels and its far ghost layer (the box
//! `lo..=hi` of [`BrickGrid::voxel_bounds`]), which a slab holds whole; the slabs are
//! layers of bricks (one z layer, a run of y rows, every x), which are runs of the id order,
//! taken in id order, so the records land in the slots the in-memory build gives them. The
//! header and index go last, over the space left for them at the file's start, with the
//! CRC32 of the records accumulated as they were written (test: every method, with slabs
//! of a few rows, against [`PofTable::build`]).

use std::io::{Seek, SeekFrom, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{PoisonError, RwLock};

use rayon::prelude::*;

use super::build::{with_plan, Plan};
use super::file::{self, Bytes};
use super::{PofError, PofSettings, PofTable};
use crate::brick::{BrickGrid, BrickId};
use crate::io::WriteError;
use crate::render::{SampledTf, TransferFunction};
use crate::store::BrickSource;
use crate::volume::{Volume, Voxel, VoxelData};
use crate::with_voxels;

/// Where a build reads its bricks' voxels.
pub(super) trait BrickVoxels: Sync {
    /// The voxels of the box `lo..=hi` (inclusive) as f32, x fastest.
    fn box_f32(&self, lo: [usize; 3], hi: [usize; 3]) -> Vec<f32>;
}

/// The in-memory build reads the volume (its mapping) directly.
impl BrickVoxels for Volume {
    fn box_f32(&self, lo: [usize; 3], hi: [usize; 3]) -> Vec<f32> {
        with_voxels!(self.data(), v => copy_f32(v, [0; 3], self.dims(), lo, hi))
    }
}

/// The box `lo..=hi` of voxels `v`, which hold the box at `origin` of `dims` voxels.
fn copy_f32<T: Voxel>(
    v: &[T],
    origin: [usize; 3],
    dims: [usize; 3],
    lo: [usize; 3],
    hi: [usize; 3],
) -> Vec<f32> {
    let n: [usize; 3] = std::array::from_fn(|a| hi[a] + 1 - lo[a]);
    let mut vox = Vec::with_capacity(n[0] * n[1] * n[2]);
    for z in lo[2]..=hi[2] {
        for y in lo[1]..=hi[1] {
            let at = lo[0] - origin[0] + dims[0] * (y - origin[1] + dims[1] * (z - origin[2]));
            vox.extend(v[at..at + n[0]].iter().map(|x| x.to_f32()));
        }
    }
    vox
}

/// The slab a streamed build holds: the box at `origin` of `n` voxels, in the stored type.
struct Slab {
    origin: [usize; 3],
    n: [usize; 3],
    data: VoxelData,
}

/// The current slab, swapped between slabs while no brick is being computed.
#[derive(Default)]
struct SlabVoxels(RwLock<Option<Slab>>);

impl BrickVoxels for SlabVoxels {
    fn box_f32(&self, lo: [usize; 3], hi: [usize; 3]) -> Vec<f32> {
        let held = self.0.read().unwrap_or_else(PoisonError::into_inner);
        let s = held
            .as_ref()
            .expect("a slab is held while its bricks are computed");
        debug_assert!((0..3).all(|a| lo[a] >= s.origin[a] && hi[a] < s.origin[a] + s.n[a]));
        with_voxels!(&s.data, v => copy_f32(v, s.origin, s.n, lo, hi))
    }
}

/// What a streamed build did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct StreamedBuild {
    /// Bricks with a stored record.
    pub stored_bricks: u64,
    /// Bricks computed (those whose value range touches a non-zero bin of some basis).
    pub computed_bricks: u64,
    /// Bytes of the file written.
    pub file_bytes: u64,
    /// Bytes read from the volume's storage (compressed bytes for a Zarr level).
    pub bytes_read: u64,
    /// Slabs read (slabs holding no brick to compute are skipped).
    pub slabs_read: u64,
    /// The most bytes one slab held (its voxels in the stored type, plus its records).
    pub slab_peak_bytes: u64,
}

/// Builds the POFs of `grid`'s bricks as [`super::PofTable::build`] does, but reads
/// `volume`'s voxels from `source` one slab of bricks at a time (each slab at most half of
/// `budget`, voxels plus records, but at least one row of bricks) and writes the table to
/// `out` (a temp file beside it, renamed into place when complete) as it goes. The file is
/// the one the in-memory build saves, byte for byte. `progress(done, total)` is called as
/// bricks finish.
///
/// # Errors
/// [`PofError::Setting`] for bad settings, [`PofError::Volume`] when a read fails (naming
/// the volume's file or chunk), [`PofError::Write`] naming `out` when it cannot be
/// written (nothing is left under its name then).
#[allow(clippy::too_many_arguments)]
pub fn build_streamed(
    volume: &Volume,
    source: &BrickSource,
    grid: &BrickGrid,
    tf: &TransferFunction,
    sampled: &SampledTf,
    settings: &PofSettings,
    budget: u64,
    out: &Path,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<StreamedBuild, PofError> {
    let slabs = SlabVoxels::default();
    with_plan(volume, &slabs, grid, tf, sampled, settings, |plan| {
        let hooks = Hooks {
            progress,
            cancel: None,
        };
        crate::io::write_atomic_with(out, |f| {
            stream(volume, source, &slabs, &plan, budget, (f, out), &hooks)
        })
    })
}

/// As [`build_streamed`], the table built in memory instead of written to a file: the
/// volume is still read slab by slab from `source` (never sampled through its mapping),
/// and the table is held once (the in-memory build holds its records three times on the
/// way). Stops between bricks once `cancel` is set, with [`PofError::Cancelled`].
///
/// # Errors
/// As [`build_streamed`], plus [`PofError::Cancelled`].
#[allow(clippy::too_many_arguments)]
pub fn build_streamed_in_memory(
    volume: &Volume,
    source: &BrickSource,
    grid: &BrickGrid,
    tf: &TransferFunction,
    sampled: &SampledTf,
    settings: &PofSettings,
    budget: u64,
    progress: &(dyn Fn(u64, u64) + Sync),
    cancel: Option<&AtomicBool>,
) -> Result<(PofTable, StreamedBuild), PofError> {
    let slabs = SlabVoxels::default();
    with_plan(volume, &slabs, grid, tf, sampled, settings, |plan| {
        let mut image = std::io::Cursor::new(Vec::new());
        let hooks = Hooks { progress, cancel };
        let name = Path::new("<built in memory>");
        let report = stream(
            volume,
            source,
            &slabs,
            &plan,
            budget,
            (&mut image, name),
            &hooks,
        )?;
        let table = file::from_bytes(Bytes::Owned(image.into_inner()), name.display().to_string())?;
        Ok((table, report))
    })
}

/// What a streamed build reports to, and what stops it.
struct Hooks<'a> {
    progress: &'a (dyn Fn(u64, u64) + Sync),
    cancel: Option<&'a AtomicBool>,
}

/// The build proper: records to `file` after its head, then the head (`out` names it in
/// errors).
fn stream<W: Write + Seek>(
    volume: &Volume,
    source: &BrickSource,
    slabs: &SlabVoxels,
    plan: &Plan<'_>,
    budget: u64,
    (file, out): (&mut W, &Path),
    hooks: &Hooks<'_>,
) -> Result<StreamedBuild, PofError> {
    let progress = hooks.progress;
    let cancelled = || hooks.cancel.is_some_and(|c| c.load(Ordering::Relaxed));
    let Plan {
        ctx,
        meta,
        todo,
        record_len,
    } = plan;
    let grid = ctx.grid;
    let wrap = |err| {
        PofError::Write(WriteError {
            path: out.to_path_buf(),
            err,
        })
    };
    let mut wanted = vec![false; grid.len()];
    for id in todo {
        wanted[id.index()] = true;
    }
    let total = todo.len() as u64;
    let counter = AtomicU64::new(0);
    progress(0, total);

    let d = volume.dims();
    let c = grid.counts();
    let b = grid.brick_size();
    let row_bytes =
        (d[0] * (b + 1) * (b + 1) * volume.data_type().size() + c[0] * record_len) as u64;
    let rows_per_slab = (budget / 2 / row_bytes.max(1)).clamp(1, c[1] as u64) as usize;

    let data_offset = file::data_offset(grid.len());
    file.seek(SeekFrom::Start(data_offset as u64))
        .map_err(wrap)?;
    let mut w = std::io::BufWriter::with_capacity(1 << 20, &mut *file);
    let mut crc = crc32fast::Hasher::new();
    let mut index = vec![u32::MAX; grid.len()];
    let mut slot = 0u32;
    let mut data_len = 0usize;
    let mut report = StreamedBuild {
        computed_bricks: total,
        ..StreamedBuild::default()
    };
    for k in 0..c[2] {
        for j0 in (0..c[1]).step_by(rows_per_slab) {
            let j1 = (j0 + rows_per_slab).min(c[1]);
            // A run of the id order: rows j0..j1 of layer k, every x.
            let ids: Vec<BrickId> = (j0..j1)
                .flat_map(|j| (0..c[0]).map(move |i| (i, j)))
                .map(|(i, j)| grid.id([i, j, k]))
                .filter(|id| wanted[id.index()])
                .collect();
            if ids.is_empty() {
                continue;
            }
            let origin = [0, j0 * b, k * b];
            let hi = [
                d[0] - 1,
                (j1 * b).min(d[1] - 1),
                ((k + 1) * b).min(d[2] - 1),
            ];
            let n: [usize; 3] = std::array::from_fn(|a| hi[a] + 1 - origin[a]);
            let (data, bytes) = source.read_box_counted(volume, origin, n)?;
            report.bytes_read += bytes;
            report.slabs_read += 1;
            let slab_bytes = (data.len() * data.data_type().size()) as u64;
            *slabs.0.write().unwrap_or_else(PoisonError::into_inner) =
                Some(Slab { origin, n, data });
            let records: Vec<Option<Vec<u8>>> = ids
                .par_iter()
                .map(|id| {
                    if cancelled() {
                        return None;
                    }
                    let r = ctx.brick_record(*id);
                    progress(counter.fetch_add(1, Ordering::Relaxed) + 1, total);
                    r
                })
                .collect();
            *slabs.0.write().unwrap_or_else(PoisonError::into_inner) = None;
            if cancelled() {
                return Err(PofError::Cancelled {
                    done: counter.load(Ordering::Relaxed),
                    total,
                });
            }
            let held: usize = records.iter().flatten().map(Vec::len).sum();
            report.slab_peak_bytes = report.slab_peak_bytes.max(slab_bytes + held as u64);
            for (id, rec) in ids.iter().zip(&records) {
                if let Some(rec) = rec {
                    index[id.index()] = slot;
                    slot += 1;
                    crc.update(rec);
                    w.write_all(rec).map_err(wrap)?;
                    data_len += rec.len();
                }
            }
        }
    }
    w.flush().map_err(wrap)?;
    drop(w);
    let head = file::head(meta, &index, data_len, crc.finalize(), *record_len);
    file.seek(SeekFrom::Start(0)).map_err(wrap)?;
    file.write_all(&head).map_err(wrap)?;
    report.stored_bricks = u64::from(slot);
    report.file_bytes = (data_offset + data_len) as u64;
    Ok(report)
}
