//! What a POF file was built for, and the fingerprint of a volume's bricks it is checked
//! against.

use super::{Encoding, PofMethod};
use crate::brick::BrickGrid;

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
    /// [`crate::render::TransferFunction::bases_fingerprint`].
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
