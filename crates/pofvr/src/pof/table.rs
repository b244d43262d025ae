//! The POF table: every brick's record of encoded functions, built in memory or
//! memory-mapped from a `.pof` file, with its metadata and the checks that it fits a volume.

use std::path::Path;
use std::sync::atomic::AtomicBool;

use glam::DVec3;

use super::cache::Caches;
use super::{
    build, encoding, file, range_hash, view_grid, Encoding, PofError, PofMeta, PofSettings,
};
use crate::brick::{BrickGrid, BrickId};
use crate::render::{SampledTf, TransferFunction};
use crate::volume::Volume;

/// The POFs of every brick of a volume for one family, ready for lookups; built in memory
/// or memory-mapped from a `.pof` file.
pub struct PofTable {
    pub(super) meta: PofMeta,
    pub(super) bytes: file::Bytes,
    pub(super) index_offset: usize,
    pub(super) data_offset: usize,
    pub(super) record_len: usize,
    pub(super) source: String,
    /// What lookups remember of this table.
    pub(super) caches: Caches,
}

impl std::fmt::Debug for PofTable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PofTable")
            .field("meta", &self.meta)
            .field("source", &self.source)
            .finish_non_exhaustive()
    }
}

impl PofTable {
    /// Precomputes the POFs of every non-empty brick, in parallel over bricks;
    /// `progress(done, total)` is called as bricks complete.
    ///
    /// # Errors
    /// [`PofError::Setting`] for a bad view grid, step, threshold, core length, pitch or
    /// margin, or a family whose basis count differs from `sampled`.
    pub fn build(
        volume: &Volume,
        grid: &BrickGrid,
        tf: &TransferFunction,
        sampled: &SampledTf,
        settings: &PofSettings,
        progress: &(dyn Fn(u64, u64) + Sync),
    ) -> Result<PofTable, PofError> {
        Self::build_resumable(volume, grid, tf, sampled, settings, None, progress)
    }

    /// As [`PofTable::build`], saving finished bricks to `partial` as it goes and resuming
    /// from what a previous, interrupted run left there (when it was made by the very same
    /// build; otherwise it is started afresh). The caller deletes `partial` once the table
    /// is saved.
    ///
    /// # Errors
    /// As [`PofTable::build`], plus I/O errors on `partial`.
    pub fn build_resumable(
        volume: &Volume,
        grid: &BrickGrid,
        tf: &TransferFunction,
        sampled: &SampledTf,
        settings: &PofSettings,
        partial: Option<&Path>,
        progress: &(dyn Fn(u64, u64) + Sync),
    ) -> Result<PofTable, PofError> {
        let hooks = build::Hooks {
            progress,
            cancel: None,
        };
        build::build(volume, grid, tf, sampled, settings, partial, hooks)
    }

    /// As [`PofTable::build`], stopping between bricks once `cancel` is set (by another
    /// thread, or by `progress`): no brick starts after that, and the build ends with
    /// [`PofError::Cancelled`].
    ///
    /// # Errors
    /// As [`PofTable::build`], plus [`PofError::Cancelled`].
    pub fn build_cancellable(
        volume: &Volume,
        grid: &BrickGrid,
        tf: &TransferFunction,
        sampled: &SampledTf,
        settings: &PofSettings,
        progress: &(dyn Fn(u64, u64) + Sync),
        cancel: &AtomicBool,
    ) -> Result<PofTable, PofError> {
        let hooks = build::Hooks {
            progress,
            cancel: Some(cancel),
        };
        build::build(volume, grid, tf, sampled, settings, None, hooks)
    }

    /// Writes the table to `path` (temp file + rename).
    ///
    /// # Errors
    /// [`PofError::Write`] naming the path.
    pub fn save(&self, path: &Path) -> Result<(), PofError> {
        crate::io::write_bytes_atomic(path, self.bytes.as_slice())?;
        Ok(())
    }

    /// The same table with its records in the other layout (`cell_major` or function-major):
    /// the same values, byte for byte, in another order. Files of format version 3 and
    /// older are function-major; `pofvr pof upgrade` rewrites them cell-major, which
    /// lookups read faster.
    #[must_use]
    pub fn relayout(&self, cell_major: bool) -> PofTable {
        let mut meta = self.meta.clone();
        meta.cell_major = cell_major && meta.encoding != Encoding::Cubic;
        let b = self.bytes.as_slice();
        let index: Vec<u32> = (0..meta.brick_count as usize)
            .map(|i| {
                let at = self.index_offset + 4 * i;
                u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
            })
            .collect();
        let mut data = b[self.data_offset..].to_vec();
        let funcs = meta.functions();
        let views = meta.views;
        let same = meta.cell_major == self.meta.cell_major;
        for (s, out) in data
            .chunks_exact_mut(self.record_len.max(1))
            .enumerate()
            .filter(|_| !same)
        {
            let rec = self.record(s);
            for i in 0..views[0] as usize {
                for j in 0..views[1] as usize {
                    for f in 0..funcs {
                        let from = encoding::value_range(
                            meta.encoding,
                            funcs,
                            f,
                            views,
                            (i, j),
                            self.meta.cell_major,
                        );
                        let to = encoding::value_range(
                            meta.encoding,
                            funcs,
                            f,
                            views,
                            (i, j),
                            meta.cell_major,
                        );
                        out[to].copy_from_slice(&rec[from]);
                    }
                }
            }
        }
        let image = file::assemble(&meta, &index, &data, self.record_len);
        file::from_bytes(file::Bytes::Owned(image), self.source.clone())
            .expect("a valid table relaid out is valid")
    }

    /// Memory-maps `path`, checks every section's CRC and that it was built for this
    /// volume, brick grid and family (weights and colours are free).
    ///
    /// # Errors
    /// [`PofError::Io`], [`PofError::Format`], [`PofError::Crc`] or
    /// [`PofError::Mismatch`], each naming the file.
    pub fn load(
        path: &Path,
        volume: &Volume,
        grid: &BrickGrid,
        tf: &TransferFunction,
    ) -> Result<PofTable, PofError> {
        let t = Self::open(path)?;
        t.check_matches(volume, grid, tf)?;
        Ok(t)
    }

    /// Memory-maps and validates `path` without comparing it to a volume (`pof info`).
    ///
    /// # Errors
    /// [`PofError::Io`], [`PofError::Format`] or [`PofError::Crc`] naming the file.
    pub fn open(path: &Path) -> Result<PofTable, PofError> {
        file::open(path)
    }

    /// Checks that the table was built for `volume`, `grid` and `tf`'s bases.
    ///
    /// # Errors
    /// [`PofError::Mismatch`] naming what differs.
    pub fn check_matches(
        &self,
        volume: &Volume,
        grid: &BrickGrid,
        tf: &TransferFunction,
    ) -> Result<(), PofError> {
        self.check_grid(volume, grid)?;
        self.check_bases(tf)
    }

    /// The [`PofError::Mismatch`] of this table's file: `what` is `in_file` here but
    /// `expected` by the caller.
    fn mismatch(
        &self,
        what: &'static str,
        in_file: String,
        expected: String,
    ) -> Result<(), PofError> {
        Err(PofError::Mismatch {
            file: self.source.clone(),
            what,
            in_file,
            expected,
        })
    }

    /// Checks that the table was built for `volume` and `grid` (size, voxel type, brick
    /// size, brick value ranges), whatever the family.
    ///
    /// # Errors
    /// [`PofError::Mismatch`] naming what differs.
    pub fn check_grid(&self, volume: &Volume, grid: &BrickGrid) -> Result<(), PofError> {
        let m = &self.meta;
        let mismatch = |what, in_file, expected| self.mismatch(what, in_file, expected);
        let dims = volume.dims().map(|d| d as u64);
        if m.dims != dims {
            return mismatch("volume size", format!("{:?}", m.dims), format!("{dims:?}"));
        }
        if m.dtype != volume.data_type() {
            return mismatch(
                "voxel type",
                m.dtype.to_string(),
                volume.data_type().to_string(),
            );
        }
        if m.brick_size as usize != grid.brick_size() {
            return mismatch(
                "brick size",
                m.brick_size.to_string(),
                grid.brick_size().to_string(),
            );
        }
        let h = range_hash(grid);
        if m.range_hash != h || m.brick_count as usize != grid.len() {
            return mismatch(
                "volume (brick value ranges)",
                format!("hash {:016x}", m.range_hash),
                format!("hash {h:016x}"),
            );
        }
        Ok(())
    }

    /// Checks that the table was built for `tf`'s bases: their count, then their shapes
    /// (names and points). A table whose shapes differ still predicts for a verified
    /// frame ([`crate::Scene::load_pof_predictions`]), but bounds nothing.
    ///
    /// # Errors
    /// [`PofError::Mismatch`] naming what differs.
    pub fn check_bases(&self, tf: &TransferFunction) -> Result<(), PofError> {
        let m = &self.meta;
        let mismatch = |what, in_file, expected| self.mismatch(what, in_file, expected);
        if m.basis_count as usize != tf.bases.len() {
            return mismatch(
                "transfer-function family (basis count)",
                m.basis_count.to_string(),
                tf.bases.len().to_string(),
            );
        }
        let f = tf.bases_fingerprint();
        if m.bases_fingerprint != f {
            return mismatch(
                "transfer-function family (bases)",
                format!("{:016x}", m.bases_fingerprint),
                format!("{f:016x}"),
            );
        }
        Ok(())
    }

    /// What the table was built for.
    #[must_use]
    pub fn meta(&self) -> &PofMeta {
        &self.meta
    }

    /// Core length `L` in the `t` units of [`crate::render::IndexRay`].
    #[must_use]
    pub fn core_length(&self) -> f32 {
        self.meta.core_length
    }

    /// The sample step the table bounds.
    #[must_use]
    pub fn step(&self) -> f32 {
        self.meta.step
    }

    /// The early-termination threshold lookups are capped at.
    #[must_use]
    pub fn ert(&self) -> f32 {
        self.meta.ert
    }

    /// True when the table holds POF sets.
    #[must_use]
    pub fn has_sets(&self) -> bool {
        self.meta.sets
    }

    /// Bytes of one basis's POF for one brick: the encoding's cost, the figure the paper
    /// compares (table vs polynomial). Sets and the joint POF add to [`PofTable::bytes_per_brick`].
    #[must_use]
    pub fn bytes_per_brick_per_basis(&self) -> f64 {
        self.meta.encoding.function_bytes(self.meta.views) as f64
    }

    /// Stored bytes per non-empty brick: every basis's POF, the sets and the joint POF.
    #[must_use]
    pub fn bytes_per_brick(&self) -> usize {
        self.record_len
    }

    /// Total file size in bytes.
    #[must_use]
    pub fn file_len(&self) -> usize {
        self.bytes.as_slice().len()
    }

    /// Number of bricks with a stored POF (not empty for every basis).
    #[must_use]
    pub fn stored_bricks(&self) -> usize {
        let n = self.meta.brick_count as usize;
        (0..n)
            .filter(|b| self.slot(BrickId(*b as u32)).is_some())
            .count()
    }

    pub(super) fn slot(&self, brick: BrickId) -> Option<usize> {
        let i = brick.index();
        if i >= self.meta.brick_count as usize {
            return None;
        }
        let at = self.index_offset + 4 * i;
        let b = self.bytes.as_slice();
        let s = u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]);
        (s != u32::MAX).then_some(s as usize)
    }

    pub(super) fn record(&self, slot: usize) -> &[u8] {
        let start = self.data_offset + slot * self.record_len;
        &self.bytes.as_slice()[start..start + self.record_len]
    }

    /// The view cell `(row, column)` of a direction.
    #[must_use]
    pub fn cell_of(&self, dir: DVec3) -> (usize, usize) {
        view_grid::cell_of(self.meta.views, dir)
    }

    /// Decoded per-basis opacity of `brick` in cell `(i, j)` for basis `basis`
    /// (0 for empty bricks). `set_of`: `Some(s)` reads basis `basis` at basis `s`'s `q_min`.
    pub(super) fn value(
        &self,
        rec: &[u8],
        basis: usize,
        set_of: Option<usize>,
        cell: (usize, usize),
    ) -> f32 {
        self.function_value(rec, self.function_index(basis, set_of), cell)
    }

    /// Which encoded function holds basis `basis` (at basis `s`'s `q_min` for
    /// `set_of = Some(s)`).
    #[inline]
    pub(super) fn function_index(&self, basis: usize, set_of: Option<usize>) -> usize {
        let p = self.meta.basis_count as usize;
        match set_of {
            None => basis,
            Some(s) if s == basis => basis,
            // Sets of basis s: the p−1 other bases in order, after the p conservative POFs.
            Some(s) => p + s * (p - 1) + if basis < s { basis } else { basis - 1 },
        }
    }

    /// Decoded value of encoded function `idx` of record `rec` in view cell `cell`.
    #[inline]
    pub(super) fn function_value(&self, rec: &[u8], idx: usize, cell: (usize, usize)) -> f32 {
        encoding::decode_in_record(
            self.meta.encoding,
            rec,
            self.meta.functions(),
            idx,
            self.meta.views,
            cell,
            self.meta.cell_major,
        )
    }

    /// The per-basis opacities of `brick` in view cell `cell` (conservative POFs).
    #[must_use]
    pub fn basis_opacities(&self, brick: BrickId, cell: (usize, usize)) -> Vec<f32> {
        let p = self.meta.basis_count as usize;
        match self.slot(brick) {
            None => vec![0.0; p],
            Some(s) => {
                let rec = self.record(s);
                (0..p).map(|i| self.value(rec, i, None, cell)).collect()
            }
        }
    }
}
