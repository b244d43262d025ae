//! Stage 3: Plenoptic Opacity Functions (paper §3): per brick, per basis, the least opacity
//! the ray caster composites for the brick alone, tabulated over view directions.
//!
//! ## What a POF value guarantees
//!
//! With [`PofMethod::Bound`] (the default) the following holds rigorously for the measured
//! directions and, through `margin`, for the directions between them. A
//! [`PofMethod::Sampled`] table only aims at it: its values are measured on a finite grid
//! of rays, phases and directions, so it is an empirical bound whose margin was chosen so
//! that `pofvr pof check` finds no violation; it can be exceeded (it was, by up to 0.13, on
//! the anisotropic 64×64×93 CT head), so check a sampled table on the volume it is for.
//!
//! For brick `b`, basis `i` and the angular cell `(θ, φ)` of a view direction `d`, the
//! stored opacity `α` satisfies, for *every* ray of a direction in that cell whose `t`-span
//! inside the brick's index box is at least [`PofTable::core_length`] (`L`), and for every
//! phase of the renderer's sample lattice: the opacity that
//! [`crate::render::RayCaster::render_box`] composites for basis `i` alone (weight 1) is
//! `≥ α`. Rays shorter than `L` (the footprint's rim) are exempt: they graze an edge and
//! carry almost nothing, so a minimum over them would be 0 and cull nothing.
//!
//! Weights enter through Eq. 3 ([`PofTable::opacity`]); the result is capped at the
//! early-termination threshold because a ray stops compositing there.
//!
//! ## How it is computed (see `build.rs`; the sampled method in `sampled.rs`)
//!
//! Not by rendering every view (that is `reference.rs`, the slow twin used by tests and
//! `pofvr pof check`), but from a lower bound that holds for all continuous ray positions
//! and lattice phases at once: a chord of length `ℓ` holds `⌊ℓ/step⌋` disjoint windows of
//! length `step`, each containing exactly one sample, and each sample's extinction is at
//! least the minimum extinction over the voxel cells the window can touch.

mod build;
mod cubic;
mod encoding;
mod file;
pub mod reference;
mod sampled;
#[cfg(test)]
mod test;

use std::path::Path;

use glam::DVec3;

use crate::brick::{BrickGrid, BrickId};
use crate::render::{SampledTf, TransferFunction};
use crate::volume::Volume;

pub use encoding::Encoding;

/// Largest stored per-basis opacity: keeps `ln(1 − α)` finite so that Eq. 3 with small
/// weights never turns a saturated basis into full opacity.
pub const ALPHA_MAX: f32 = 1.0 - 1.0 / 1_048_576.0;

/// How several bases are combined at run time (paper §3.2.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PofMode {
    /// Eq. 3 on the per-basis POFs: a lower bound of every core ray's opacity.
    Conservative,
    /// The minimum over the POF-set estimates at each basis's `q_min`: closer to the truth,
    /// not guaranteed (never below `Conservative`). Needs a table built with `sets`.
    Sets,
}

/// How the builder obtains each cell's least optical depth.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum PofMethod {
    /// A rigorous lower bound over every ray position, lattice phase and direction of the
    /// measured grid (box minima of per-cell value ranges): fast, but loose.
    #[default]
    Bound,
    /// The optical depth the ray caster's own samples give, measured on a grid of parallel
    /// rays and lattice phases and kept at `margin`: tight, an empirical bound.
    Sampled,
}

impl PofMethod {
    /// Both methods.
    pub const ALL: [PofMethod; 2] = [PofMethod::Bound, PofMethod::Sampled];

    /// The name used on the command line and in `pof info`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            PofMethod::Bound => "bound",
            PofMethod::Sampled => "sampled",
        }
    }

    pub(crate) fn code(self) -> u8 {
        match self {
            PofMethod::Bound => 0,
            PofMethod::Sampled => 1,
        }
    }

    pub(crate) fn from_code(c: u8) -> Option<Self> {
        Some(match c {
            0 => PofMethod::Bound,
            1 => PofMethod::Sampled,
            _ => return None,
        })
    }
}

impl std::fmt::Display for PofMethod {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for PofMethod {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        PofMethod::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!("unknown POF method {s:?}: expected bound or sampled"))
    }
}

/// Knobs of the precompute.
#[derive(Clone, Debug, PartialEq)]
pub struct PofSettings {
    /// How cell values are obtained. Default [`PofMethod::Bound`].
    pub method: PofMethod,
    /// Sample views over (θ, φ): θ ∈ [0, π] in `views[0]` rows, φ ∈ [0, 2π) in `views[1]`
    /// columns. Default `[36, 36]`.
    pub views: [usize; 2],
    /// How each POF is stored. Default [`Encoding::Table`].
    pub encoding: Encoding,
    /// Also store POF sets (the aggressive multi-basis mode). Default false.
    pub sets: bool,
    /// The renderer's sample distance, in units of the smallest spacing. Default 1.
    pub step: f32,
    /// The renderer's early-termination threshold; lookups are capped here. Default 0.99.
    pub ert: f32,
    /// Core length `L` in `t` units; `None` = half a brick. Default `None`.
    ///
    /// Longer cores give higher POFs over fewer pixels. On the 128³ head (36×36 views),
    /// L = 4 / 8 / 12 gave a mean POF of 0.016 / 0.041 / 0.066 with the core covering
    /// 79 % / 61 % / 45 % of the footprint: half a brick keeps most of the gain while the
    /// core stays the larger part of the footprint.
    pub core_length: Option<f32>,
    /// `Bound`: edge of the entry-face patches the bound is evaluated on, in voxels (≤ 0.5
    /// keeps a patch inside at most two cells per axis for step ≤ 0.5). Default 0.5.
    /// `Sampled`: spacing of the measured parallel rays, in voxels. Default
    /// [`SAMPLED_PITCH`].
    pub pitch: f32,
    /// `Sampled` only: lattice phases measured per ray, evenly spread over a step (an
    /// evenly spread set is symmetric under reversal, which lets one hemisphere of
    /// directions stand for both). Default [`SAMPLED_PHASES`].
    pub phases: usize,
    /// Directions measured per cell edge: a cell's value is the minimum over a
    /// `(subdiv+1)²` grid of directions including its borders. Default 2.
    pub subdiv: usize,
    /// Fraction of the measured optical depth kept, for directions between the measured
    /// ones (and, for `Sampled`, for ray positions and phases between the measured ones).
    /// Applied to optical depth so that Eq. 3 stays exact for one basis. Default 0.9
    /// (`Bound`) or [`SAMPLED_MARGIN`] (`Sampled`).
    pub margin: f32,
    /// Also store the POF of the whole family at the build's weights `a` (the *joint*
    /// POF), for families of two or more bases. Default true.
    ///
    /// Per-basis POFs are loose when the bases take turns along a ray (grey and white
    /// matter): each basis's minimum is on a ray where the other carries the opacity, and
    /// Eq. 3 combines the two minima. Opacity only grows with every weight, so for any
    /// weights `w` the joint POF scaled to `c = minᵢ wᵢ/aᵢ` is still a lower bound, and a
    /// lookup takes the larger of it and Eq. 3 (exact again for weights along `a`).
    pub joint: bool,
}

/// Most bases a joint POF is stored for (the anchor weights live in the file header).
pub const JOINT_MAX_BASES: usize = 16;

/// Default ray spacing of the sampled method, in voxels.
pub const SAMPLED_PITCH: f32 = 1.0;
/// Default lattice phases of the sampled method.
pub const SAMPLED_PHASES: usize = 2;
/// Default optical-depth margin of the sampled method.
pub const SAMPLED_MARGIN: f32 = 0.7;

impl Default for PofSettings {
    fn default() -> Self {
        Self::for_method(PofMethod::default())
    }
}

impl PofSettings {
    /// The defaults of `method`: pitch, phases and margin differ between methods.
    #[must_use]
    pub fn for_method(method: PofMethod) -> Self {
        let sampled = method == PofMethod::Sampled;
        PofSettings {
            method,
            views: [36, 36],
            encoding: Encoding::Table,
            sets: false,
            step: 1.0,
            ert: 0.99,
            core_length: None,
            pitch: if sampled { SAMPLED_PITCH } else { 0.5 },
            phases: if sampled { SAMPLED_PHASES } else { 1 },
            subdiv: 2,
            margin: if sampled { SAMPLED_MARGIN } else { 0.9 },
            joint: true,
        }
    }
}

/// Errors building, reading or writing POF tables.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PofError {
    /// A setting is out of range.
    #[error("POF setting {field}: {why}")]
    Setting {
        /// The setting.
        field: &'static str,
        /// What is wrong.
        why: String,
    },
    /// The file could not be read.
    #[error("{file}: {err}")]
    Io {
        /// The file.
        file: String,
        /// The cause.
        #[source]
        err: std::io::Error,
    },
    /// The file could not be written.
    #[error(transparent)]
    Write(#[from] crate::io::WriteError),
    /// Not a POF file, or a structurally invalid one.
    #[error("{file}: not a valid POF file: {why}")]
    Format {
        /// The file.
        file: String,
        /// What is wrong.
        why: String,
    },
    /// A section's bytes do not match its checksum.
    #[error("{file}: {section} section is corrupted: CRC32 {got:08x}, expected {expected:08x}")]
    Crc {
        /// The file.
        file: String,
        /// Which section.
        section: &'static str,
        /// Stored checksum.
        expected: u32,
        /// Checksum of the bytes read.
        got: u32,
    },
    /// The file was built for another volume, brick size or family.
    #[error("{file}: built for a different {what}: file has {in_file}, expected {expected} (rebuild it with `pofvr pof build`)")]
    Mismatch {
        /// The file.
        file: String,
        /// What differs.
        what: &'static str,
        /// The file's value.
        in_file: String,
        /// The value of the volume/family given.
        expected: String,
    },
    /// POF sets were asked for but the table has none.
    #[error("{file}: the table has no POF sets (build it with --sets)")]
    NoSets {
        /// The file.
        file: String,
    },
}

/// What a POF file was built for: the volume's and family's fingerprints and the knobs.
#[derive(Clone, Debug, PartialEq)]
pub struct PofMeta {
    /// Voxel counts.
    pub dims: [u64; 3],
    /// Stored voxel type.
    pub dtype: crate::volume::DataType,
    /// Brick edge.
    pub brick_size: u32,
    /// Number of bricks.
    pub brick_count: u32,
    /// FNV-1a hash of every brick's value range.
    pub range_hash: u64,
    /// [`TransferFunction::bases_fingerprint`].
    pub bases_fingerprint: u64,
    /// Number of bases.
    pub basis_count: u32,
    /// View grid `[rows over θ, columns over φ]`.
    pub views: [u32; 2],
    /// Encoding.
    pub encoding: Encoding,
    /// POF sets present.
    pub sets: bool,
    /// Sample step.
    pub step: f32,
    /// Early termination threshold.
    pub ert: f32,
    /// Core length `L`.
    pub core_length: f32,
    /// Optical-depth margin.
    pub margin: f32,
    /// Patch pitch.
    pub pitch: f32,
    /// Direction subdivisions per cell.
    pub subdiv: u32,
    /// Builder method (files of format version 1 are all `Bound`).
    pub method: PofMethod,
    /// Lattice phases measured (`Sampled`; 1 for `Bound`, which covers every phase).
    pub phases: u32,
    /// The anchor weights of the joint POF, when the file has one (format version 3).
    pub joint: Option<Vec<f32>>,
    /// Records hold each view cell's values of every function side by side (format version
    /// 4, table encodings), so that a lookup reads one cache line instead of one per
    /// function; otherwise each function's cells are contiguous.
    pub cell_major: bool,
}

impl PofMeta {
    /// Encoded functions per record: p POFs, the sets, the joint POF.
    #[must_use]
    pub fn functions(&self) -> usize {
        let p = self.basis_count as usize;
        p + if self.sets { p * (p - 1) } else { 0 } + usize::from(self.joint.is_some())
    }
}

/// The POFs of every brick of a volume for one family, ready for lookups; built in memory
/// or memory-mapped from a `.pof` file.
pub struct PofTable {
    meta: PofMeta,
    bytes: file::Bytes,
    index_offset: usize,
    data_offset: usize,
    record_len: usize,
    source: String,
    /// Tells this table from every other in per-thread lookup caches.
    uid: u64,
    /// Per record, each function's largest value over the cells that meet at a border
    /// direction ([`PofTable::border_values`]), by the cells' list: made on first use.
    borders: std::sync::Mutex<Vec<BorderValues>>,
}

/// The cells meeting at a border direction, and per record each function's largest value
/// over them.
type BorderValues = (Vec<(usize, usize)>, std::sync::Arc<[f32]>);

/// A fresh [`PofTable::uid`].
pub(crate) fn next_uid() -> u64 {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

/// Where the lookups of one view direction read: one cell, or (a direction on the border
/// of several cells) the per-function maxima over them.
enum Lookup {
    Cell((usize, usize)),
    Border(std::sync::Arc<[f32]>),
}

impl std::fmt::Debug for PofTable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PofTable")
            .field("meta", &self.meta)
            .field("source", &self.source)
            .finish_non_exhaustive()
    }
}

/// Fingerprint of a volume's bricks: FNV-1a over every brick's value range.
#[must_use]
pub fn range_hash(grid: &BrickGrid) -> u64 {
    let mut h = crate::render::transfer_function::Fnv::default();
    for r in grid.ranges() {
        h.write(&r.min.to_le_bytes());
        h.write(&r.max.to_le_bytes());
    }
    h.0
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
        build::build(volume, grid, tf, sampled, settings, partial, progress)
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
        let m = &self.meta;
        let mismatch = |what, in_file: String, expected: String| {
            Err(PofError::Mismatch {
                file: self.source.clone(),
                what,
                in_file,
                expected,
            })
        };
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
    #[allow(clippy::cast_precision_loss)]
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

    fn slot(&self, brick: BrickId) -> Option<usize> {
        let i = brick.index();
        if i >= self.meta.brick_count as usize {
            return None;
        }
        let at = self.index_offset + 4 * i;
        let b = self.bytes.as_slice();
        let s = u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]);
        (s != u32::MAX).then_some(s as usize)
    }

    fn record(&self, slot: usize) -> &[u8] {
        let start = self.data_offset + slot * self.record_len;
        &self.bytes.as_slice()[start..start + self.record_len]
    }

    /// The view cell `(row, column)` of a direction.
    #[must_use]
    pub fn cell_of(&self, dir: DVec3) -> (usize, usize) {
        cell_of(self.meta.views, dir)
    }

    /// Decoded per-basis opacity of `brick` in cell `(i, j)` for basis `basis`
    /// (0 for empty bricks). `set_of`: `Some(s)` reads basis `basis` at basis `s`'s `q_min`.
    fn value(&self, rec: &[u8], basis: usize, set_of: Option<usize>, cell: (usize, usize)) -> f32 {
        self.function_value(rec, self.function_index(basis, set_of), cell)
    }

    /// Which encoded function holds basis `basis` (at basis `s`'s `q_min` for
    /// `set_of = Some(s)`).
    #[inline]
    fn function_index(&self, basis: usize, set_of: Option<usize>) -> usize {
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
    fn function_value(&self, rec: &[u8], idx: usize, cell: (usize, usize)) -> f32 {
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

    fn cell_opacity(
        &self,
        rec: &[u8],
        cell: (usize, usize),
        weights: &[f32],
        mode: PofMode,
    ) -> f32 {
        self.combine(|f| self.function_value(rec, f, cell), weights, mode)
    }

    /// The run-time opacity from the values of one view cell's functions (`value(f)`: the
    /// `f`-th encoded function, in record order).
    #[inline]
    fn combine(&self, value: impl Fn(usize) -> f32, weights: &[f32], mode: PofMode) -> f32 {
        let p = self.meta.basis_count as usize;
        let combine = |set_of: Option<usize>| -> f32 {
            // Eq. 3: 1 − Π (1 − αᵢ)^kᵢ. A weight of 1 (the common case) needs no power:
            // culling asks this for every visible brick and sub-brick of every frame.
            let mut t = 1.0f64;
            for (i, k) in weights.iter().enumerate().take(p) {
                if *k > 0.0 {
                    let mut a = value(i);
                    if let Some(s) = set_of {
                        // Each set entry is at least the basis's own POF; separately fitted
                        // cubics could lose that, so it is restored here.
                        a = a.max(value(self.function_index(i, Some(s))));
                    }
                    if a <= 0.0 {
                        continue;
                    }
                    let a = f64::from(a.min(ALPHA_MAX));
                    t *= if *k == 1.0 {
                        1.0 - a
                    } else {
                        (1.0 - a).powf(f64::from(*k))
                    };
                }
            }
            #[allow(clippy::cast_possible_truncation)]
            let a = (1.0 - t) as f32;
            a
        };
        let a = match mode {
            PofMode::Sets if self.meta.sets => (0..p)
                .map(|s| combine(Some(s)))
                .fold(f32::INFINITY, f32::min),
            _ => combine(None),
        };
        let joint = if self.meta.joint.is_some() {
            self.joint_opacity(value(self.meta.functions() - 1), weights)
        } else {
            0.0
        };
        a.max(joint).clamp(0.0, self.meta.ert)
    }

    /// The joint POF scaled to `weights`: with anchor `a`, every weight vector is at least
    /// `c·a` for `c = minᵢ wᵢ/aᵢ` over the bases with `aᵢ > 0`, and a ray's optical depth
    /// grows with every weight, so `1 − (1 − α_joint)^c` stays a lower bound.
    fn joint_opacity(&self, stored: f32, weights: &[f32]) -> f32 {
        let Some(anchor) = &self.meta.joint else {
            return 0.0;
        };
        let mut c = f64::INFINITY;
        for (i, a) in anchor.iter().enumerate() {
            if *a > 0.0 {
                let w = weights.get(i).copied().unwrap_or(0.0).max(0.0);
                c = c.min(f64::from(w) / f64::from(*a));
            }
        }
        if !(c.is_finite() && c > 0.0) {
            return 0.0;
        }
        let aj = stored.clamp(0.0, ALPHA_MAX);
        if c == 1.0 || aj <= 0.0 {
            // The anchor's own weights (the common case): the joint POF as stored.
            return aj;
        }
        #[allow(clippy::cast_possible_truncation)]
        let a = (1.0 - (1.0 - f64::from(aj)).powf(c)) as f32;
        a
    }

    /// Run-time opacity of `brick` seen along `view_dir` (unit world direction, eye to
    /// scene) with basis weights `weights`: every ray of that direction whose span in the
    /// brick is at least [`PofTable::core_length`] composites at least this much
    /// (`Conservative`). `Sets` on a table without sets falls back to `Conservative`.
    #[must_use]
    pub fn opacity(&self, brick: BrickId, view_dir: DVec3, weights: &[f32], mode: PofMode) -> f32 {
        let Some(s) = self.slot(brick) else {
            return 0.0;
        };
        self.with_lookup(view_dir, |at| match at {
            Lookup::Cell(cell) => self.cell_opacity(self.record(s), *cell, weights, mode),
            Lookup::Border(values) => {
                let funcs = self.meta.functions();
                let v = &values[s * funcs..(s + 1) * funcs];
                self.combine(|f| v[f], weights, mode)
            }
        })
    }

    /// Runs `f` with where the lookups along `dir` read, remembered per thread for the
    /// last directions: a frame asks for one direction thousands of times (orthographic
    /// views), and the angles cost an `acos` and an `atan2`. A few entries, not one: tables
    /// of different view grids (core levels, sub-brick tables) are looked up in turn, and
    /// one entry would miss every time.
    fn with_lookup<R>(&self, dir: DVec3, f: impl FnOnce(&Lookup) -> R) -> R {
        type Key = ([u64; 3], u64);
        type Entry = Option<(Key, Lookup)>;
        const WAYS: usize = 4;
        thread_local! {
            // The entries and the next one to replace (borrowed in place, not copied out).
            static LAST: std::cell::RefCell<([Entry; WAYS], usize)> =
                const { std::cell::RefCell::new(([None, None, None, None], 0)) };
        }
        let key = (dir.to_array().map(f64::to_bits), self.uid);
        LAST.with_borrow_mut(|(ways, next)| {
            if let Some((_, at)) = ways.iter().flatten().find(|(k, _)| *k == key) {
                return f(at);
            }
            let cells = border_cells(self.meta.views, dir);
            let at = match cells.as_slice() {
                [one] => Lookup::Cell(*one),
                // Cubic POFs are smooth across cells: nothing to gain on a border.
                _ if self.meta.encoding == Encoding::Cubic => Lookup::Cell(self.cell_of(dir)),
                _ => Lookup::Border(self.border_values(cells)),
            };
            let r = f(&at);
            ways[*next] = Some((key, at));
            *next = (*next + 1) % WAYS;
            r
        })
    }

    #[cfg(test)]
    /// [`PofTable::cell_of`], through the per-thread cache of [`PofTable::with_lookup`].
    fn cell_of_cached(&self, dir: DVec3) -> (usize, usize) {
        self.with_lookup(dir, |at| match at {
            Lookup::Cell(c) => *c,
            Lookup::Border(_) => self.cell_of(dir),
        })
    }

    /// Per record, each function's largest value over `cells`, the cells whose borders
    /// meet at one direction (the poles, where a whole row of cells meets, and the axes and
    /// grid lines between two or four).
    ///
    /// Why: every cell's value bounds every direction of the cell *and its border*, so a
    /// direction on the border is bounded by each of them, per basis and for the joint POF:
    /// by the largest. Axis-aligned views, the commonest of all, look along such directions;
    /// with one cell chosen by rounding, a brick read as transparent there when a
    /// neighbouring cell knew better.
    fn border_values(&self, cells: Vec<(usize, usize)>) -> std::sync::Arc<[f32]> {
        let mut made = self
            .borders
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some((_, v)) = made.iter().find(|(c, _)| *c == cells) {
            return v.clone();
        }
        let funcs = self.meta.functions();
        let slots =
            self.bytes.as_slice().len().saturating_sub(self.data_offset) / self.record_len.max(1);
        let mut values = vec![0f32; slots * funcs];
        for (s, out) in values.chunks_exact_mut(funcs).enumerate() {
            let rec = self.record(s);
            for (f, o) in out.iter_mut().enumerate() {
                *o = cells
                    .iter()
                    .map(|c| self.function_value(rec, f, *c))
                    .fold(0.0, f32::max);
            }
        }
        let values: std::sync::Arc<[f32]> = values.into();
        made.push((cells, values.clone()));
        values
    }

    /// Starts loading the cache lines [`PofTable::opacity`] reads for each of `bricks`
    /// along `view_dir` (each function's value in the direction's cell), without waiting.
    pub fn prefetch(&self, bricks: &[BrickId], view_dir: DVec3) {
        // Border directions read a small array of their own, not the records.
        let Some(cell) = self.with_lookup(view_dir, |at| match at {
            Lookup::Cell(c) => Some(*c),
            Lookup::Border(_) => None,
        }) else {
            return;
        };
        let funcs = self.meta.functions();
        let range = |f: usize| {
            encoding::value_range(
                self.meta.encoding,
                funcs,
                f,
                self.meta.views,
                cell,
                self.meta.cell_major,
            )
        };
        // The first byte of each function's value in the cell; in a cell-major record they
        // are side by side, so the first and last byte cover them (across a line boundary).
        // Culling calls this per visible brick: no allocation.
        let (first, last) = (range(0).start, range(funcs - 1).end - 1);
        let step = if self.meta.cell_major {
            0
        } else {
            range(1.min(funcs - 1)).start - first
        };
        let data = self.bytes.as_slice();
        for &b in bricks {
            if let Some(s) = self.slot(b) {
                let rec = self.data_offset + s * self.record_len;
                if self.meta.cell_major {
                    for i in [first, last] {
                        if let Some(x) = data.get(rec + i) {
                            prefetch_line(x);
                        }
                    }
                } else {
                    for f in 0..funcs {
                        if let Some(x) = data.get(rec + first + f * step) {
                            prefetch_line(x);
                        }
                    }
                }
            }
        }
    }

    /// As [`PofTable::opacity`] for every direction within `half_angle` radians of `axis`
    /// (perspective views: the cone under which the eye sees the brick): the minimum over
    /// every view cell the cone touches.
    #[must_use]
    pub fn opacity_cone(
        &self,
        brick: BrickId,
        axis: DVec3,
        half_angle: f64,
        weights: &[f32],
        mode: PofMode,
    ) -> f32 {
        let Some(s) = self.slot(brick) else {
            return 0.0;
        };
        let rec = self.record(s);
        let mut m = f32::INFINITY;
        for cell in cone_cells(self.meta.views, axis, half_angle) {
            m = m.min(self.cell_opacity(rec, cell, weights, mode));
            if m <= 0.0 {
                break;
            }
        }
        if m.is_finite() {
            m
        } else {
            0.0
        }
    }
}

/// `(θ, φ)` of a unit direction: θ from +z in [0, π], φ from +x towards +y in [0, 2π).
#[must_use]
pub fn angles(dir: DVec3) -> (f64, f64) {
    let d = dir.normalize_or_zero();
    let theta = d.z.clamp(-1.0, 1.0).acos();
    let phi = d.y.atan2(d.x).rem_euclid(std::f64::consts::TAU);
    (theta, phi)
}

/// The unit direction of `(θ, φ)`.
#[must_use]
pub fn direction(theta: f64, phi: f64) -> DVec3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    DVec3::new(st * cp, st * sp, ct)
}

#[allow(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_precision_loss
)]
fn cell_of(views: [u32; 2], dir: DVec3) -> (usize, usize) {
    let (n, m) = (views[0] as usize, views[1] as usize);
    let (theta, phi) = angles(dir);
    let i = ((theta / std::f64::consts::PI * n as f64) as usize).min(n - 1);
    let j = ((phi / std::f64::consts::TAU * m as f64) as usize).min(m - 1);
    (i, j)
}

/// Every view cell whose closure holds `dir`: one for most directions; two or four on
/// the lines between cells; a whole row at a pole. A direction within a hair (1e-9 of a
/// cell) of a line counts as on it: far below what the cells' margin covers.
#[allow(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_precision_loss
)]
fn border_cells(views: [u32; 2], dir: DVec3) -> Vec<(usize, usize)> {
    const HAIR: f64 = 1e-9;
    let (n, m) = (views[0] as usize, views[1] as usize);
    let (theta, phi) = angles(dir);
    let u = theta / std::f64::consts::PI * n as f64;
    if u <= HAIR || u >= n as f64 - HAIR {
        let i = if u <= HAIR { 0 } else { n - 1 };
        return (0..m).map(|j| (i, j)).collect();
    }
    let near = |x: f64, count: usize, wrap: bool| -> Vec<usize> {
        let k = x.round();
        let i = (x as usize).min(count - 1);
        if (x - k).abs() > HAIR {
            return vec![i];
        }
        let k = k as usize;
        if wrap {
            vec![(k + count - 1) % count, k % count]
        } else {
            vec![k - 1, k.min(count - 1)]
        }
    };
    let rows = near(u, n, false);
    let cols = near(phi / std::f64::consts::TAU * m as f64, m, true);
    let mut out: Vec<(usize, usize)> = rows
        .iter()
        .flat_map(|i| cols.iter().map(move |j| (*i, *j)))
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// Every view cell that directions within `half_angle` of `axis` can fall in.
#[allow(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_precision_loss,
    clippy::cast_possible_wrap
)]
fn cone_cells(views: [u32; 2], axis: DVec3, half_angle: f64) -> Vec<(usize, usize)> {
    use std::f64::consts::{PI, TAU};
    let (n, m) = (views[0] as usize, views[1] as usize);
    let (theta, phi) = angles(axis);
    let beta = half_angle.max(0.0);
    if beta >= PI {
        return (0..n).flat_map(|i| (0..m).map(move |j| (i, j))).collect();
    }
    let (t0, t1) = ((theta - beta).max(0.0), (theta + beta).min(PI));
    let i0 = ((t0 / PI * n as f64) as usize).min(n - 1);
    let i1 = ((t1 / PI * n as f64) as usize).min(n - 1);
    // The cone's azimuth spread about its axis is asin(sin β / sin θ); a pole inside the
    // cone spreads it over every azimuth.
    let all_phi = theta - beta <= 0.0 || theta + beta >= PI || beta.sin() >= theta.sin();
    let cols: Vec<usize> = if all_phi {
        (0..m).collect()
    } else {
        let dphi = (beta.sin() / theta.sin()).asin();
        let w = TAU / m as f64;
        let j0 = ((phi - dphi) / w).floor() as i64;
        let j1 = ((phi + dphi) / w).floor() as i64;
        let span = (j1 - j0 + 1).min(m as i64);
        (0..span)
            .map(|k| (j0 + k).rem_euclid(m as i64) as usize)
            .collect()
    };
    (i0..=i1)
        .flat_map(|i| cols.iter().map(move |j| (i, *j)))
        .collect()
}

/// Asks the CPU to bring the cache line holding `b` closer: a hint, with no effect on
/// results.
#[inline]
fn prefetch_line(b: &u8) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch reads nothing architecturally and cannot fault; SSE is part of the
    // x86_64 baseline.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
            std::ptr::from_ref(b).cast::<i8>(),
        );
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = b;
}
