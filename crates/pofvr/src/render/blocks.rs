//! A copy of the volume in blocks, for the march engine's packet loop on volumes far
//! larger than the caches.
//!
//! Voxels are stored x fastest, so a ray that moves along z meets a new slice (512 KB on
//! a 512² i16 slice) at every sample or so: each sample's corners lie on lines of their
//! own, in pages of their own, that no hardware prefetcher follows. The packet loop's
//! software prefetch hides part of that. In blocks of [`EDGE`]³ cells, a ray's next
//! samples lie a few hundred bytes on, in lines the core fetches in pairs, and the
//! prefetches' offsets along the ray hold inside a block.
//!
//! Each block holds its cells' far corners too (an apron of one voxel: [`SIDE`]³ voxels,
//! 1.2 × the volume's size), so that a cell's eight corners lie at the same offsets from
//! its first one as in any other cell, `[1, SIDE, SIDE²]`, and the loops read them as they
//! read the volume's. The apron past the volume's last voxel repeats it (the clamp), and
//! no cell reads it. A sample's corners are the volume's voxels, so the image is the
//! same bit for bit; only the addresses differ.
//!
//! Measured in `docs/results.md` ("Stop 48"): frames 0.79 of the volume's own layout on
//! the 906 MB chest at 30,20 (pinned, one thread), none gained on a 35 MB MRI; so only
//! above [`MIN_BYTES`] and where memory allows ([`pays`]).

use crate::volume::{DataType, Volume, Voxel, VoxelData, Voxels};

/// Cells per block edge (a power of two: the loops split a cell index by shift and mask).
pub(crate) const EDGE: usize = 16;
/// `log2(EDGE)`.
pub(crate) const EDGE_SHIFT: u32 = EDGE.trailing_zeros();
/// Voxels per block edge: its cells and their far corners.
pub(crate) const SIDE: usize = EDGE + 1;
/// Voxels per block.
pub(crate) const BLOCK: usize = SIDE * SIDE * SIDE;

/// Volumes of at least this many bytes of voxels get blocks (by default): 256 MiB, eight
/// times the cache one core can count on. A 35 MB volume gained nothing, a 906 MB one
/// 21 % (`docs/results.md`, stop 48).
pub(crate) const MIN_BYTES: usize = 256 << 20;

/// The blocked copy of a volume's voxels (see the [module](self)).
pub struct MarchBlocks {
    data: VoxelData,
    /// Blocks per axis.
    blocks: [usize; 3],
}

impl std::fmt::Debug for MarchBlocks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MarchBlocks")
            .field("blocks", &self.blocks)
            .field("bytes", &self.bytes())
            .finish()
    }
}

/// Blocks per axis for a volume of `dims` voxels: enough for its cells (one fewer than
/// its voxels, at least one).
pub(crate) fn blocks_of(dims: [usize; 3]) -> [usize; 3] {
    dims.map(|d| d.saturating_sub(2) / EDGE + 1)
}

/// Whether the march engine should block `volume` (see [`MIN_BYTES`]): a resident volume
/// of at least that size whose copy fits the 32-bit indices of the loops and half of the
/// memory the system has available, or as `POFVR_BLOCKS` says (`on`, `off`; anything
/// else: by size).
#[must_use]
pub fn pays(volume: &Volume) -> bool {
    let possible = volume.is_resident() && copy_len(volume.dims()) < i32::MAX as usize;
    let bytes = voxel_bytes(volume);
    let copy = copy_bytes(volume);
    match std::env::var("POFVR_BLOCKS").as_deref() {
        Ok(s) if s.eq_ignore_ascii_case("on") => possible,
        Ok(s) if s.eq_ignore_ascii_case("off") => false,
        _ => possible && bytes >= MIN_BYTES && available_memory().is_none_or(|m| copy <= m / 2),
    }
}

/// The bytes of `volume`'s voxels.
pub(crate) fn voxel_bytes(volume: &Volume) -> usize {
    volume.dims().iter().product::<usize>() * volume.data_type().size()
}

/// The bytes a blocked copy of `volume` takes.
#[must_use]
pub fn copy_bytes(volume: &Volume) -> usize {
    copy_len(volume.dims()).saturating_mul(volume.data_type().size())
}

/// Elements of the blocked copy of a volume of `dims` voxels.
fn copy_len(dims: [usize; 3]) -> usize {
    blocks_of(dims)
        .iter()
        .product::<usize>()
        .saturating_mul(BLOCK)
}

/// The system's available memory in bytes (`MemAvailable` of `/proc/meminfo`), where it
/// says.
fn available_memory() -> Option<usize> {
    let s = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = s.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: usize = line.split_whitespace().nth(1)?.parse().ok()?;
    kb.checked_mul(1024)
}

impl MarchBlocks {
    /// Copies `volume`'s voxels into blocks (in parallel over blocks); `None` for a volume
    /// whose voxels are not in memory.
    #[must_use]
    pub fn new(volume: &Volume) -> Option<Self> {
        if !volume.is_resident() {
            return None;
        }
        let dims = volume.dims();
        let data = match volume.data() {
            VoxelData::U8(v) => VoxelData::U8(Voxels::owned(copy(v.as_slice(), dims))),
            VoxelData::U16(v) => VoxelData::U16(Voxels::owned(copy(v.as_slice(), dims))),
            VoxelData::I16(v) => VoxelData::I16(Voxels::owned(copy(v.as_slice(), dims))),
            VoxelData::F32(v) => VoxelData::F32(Voxels::owned(copy(v.as_slice(), dims))),
        };
        Some(MarchBlocks {
            data,
            blocks: blocks_of(dims),
        })
    }

    /// The copy's size in bytes.
    #[must_use]
    pub fn bytes(&self) -> usize {
        let (n, size) = match &self.data {
            VoxelData::U8(v) => (v.len(), 1),
            VoxelData::U16(v) => (v.len(), 2),
            VoxelData::I16(v) => (v.len(), 2),
            VoxelData::F32(v) => (v.len(), 4),
        };
        n * size
    }

    /// Blocks per axis.
    #[must_use]
    pub fn blocks(&self) -> [usize; 3] {
        self.blocks
    }

    /// The blocks' voxels as `T`, block after block (x fastest, then y, then z), each
    /// [`SIDE`]³ voxels x fastest; `None` where the volume's voxels are not `T`.
    pub(crate) fn voxels<T: Voxel>(&self) -> Option<&[T]> {
        let (ty, bytes): (DataType, &[u8]) = match &self.data {
            VoxelData::U8(v) => (DataType::U8, bytemuck::cast_slice(v.as_slice())),
            VoxelData::U16(v) => (DataType::U16, bytemuck::cast_slice(v.as_slice())),
            VoxelData::I16(v) => (DataType::I16, bytemuck::cast_slice(v.as_slice())),
            VoxelData::F32(v) => (DataType::F32, bytemuck::cast_slice(v.as_slice())),
        };
        // The same type, so the bytes are aligned for it.
        (ty == T::TYPE).then(|| bytemuck::cast_slice(bytes))
    }
}

/// The blocked copy of `v`, voxels of a volume of `dims` x fastest.
fn copy<T: Voxel>(v: &[T], dims: [usize; 3]) -> Vec<T> {
    use rayon::prelude::*;
    let nb = blocks_of(dims);
    let n = nb.iter().product::<usize>() * BLOCK;
    let mut out = vec![bytemuck::Zeroable::zeroed(); n];
    let [nx, ny, nz] = dims;
    out.par_chunks_mut(BLOCK).enumerate().for_each(|(b, blk)| {
        let (bx, by, bz) = (b % nb[0], b / nb[0] % nb[1], b / (nb[0] * nb[1]));
        // The block's voxels per axis, clamped to the volume's last (the apron past it).
        let at = |b: usize, l: usize, n: usize| (b * EDGE + l).min(n - 1);
        for lz in 0..SIDE {
            let z = at(bz, lz, nz);
            for ly in 0..SIDE {
                let row = &v[(z * ny + at(by, ly, ny)) * nx..][..nx];
                let out = &mut blk[(lz * SIDE + ly) * SIDE..][..SIDE];
                let x0 = bx * EDGE;
                let full = (nx - x0).min(SIDE);
                out[..full].copy_from_slice(&row[x0..x0 + full]);
                out[full..].fill(row[nx - 1]);
            }
        }
    });
    out
}

/// The element offset of voxel `i` of a volume of `dims` in its blocked copy (for
/// tests: the loops compute it lane-wise).
#[cfg(test)]
pub(crate) fn offset(dims: [usize; 3], i: [usize; 3]) -> usize {
    let nb = blocks_of(dims);
    let b = i.map(|x| x / EDGE);
    let l = [0, 1, 2].map(|a| i[a] % EDGE);
    ((b[2] * nb[1] + b[1]) * nb[0] + b[0]) * BLOCK + (l[2] * SIDE + l[1]) * SIDE + l[0]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_voxel_of_every_cell_is_at_its_offset_in_its_cells_block() {
        // Dims that are not multiples of the edge, one of them a single voxel.
        for dims in [[37usize, 20, 18], [17, 33, 1], [2, 2, 2], [16, 17, 18]] {
            let n: usize = dims.iter().product();
            let v: Vec<u16> = (0..n as u16).collect();
            let b = copy(&v, dims);
            assert_eq!(b.len(), copy_len(dims));
            let cells = dims.map(|d| d.saturating_sub(1).max(1));
            for z in 0..cells[2] {
                for y in 0..cells[1] {
                    for x in 0..cells[0] {
                        // The cell's first corner, addressed by its block.
                        let base = offset(dims, [x, y, z]);
                        for (dz, dy, dx) in (0..8).map(|c| (c >> 2 & 1, c >> 1 & 1, c & 1)) {
                            let i = [
                                (x + dx).min(dims[0] - 1),
                                (y + dy).min(dims[1] - 1),
                                (z + dz).min(dims[2] - 1),
                            ];
                            let want = v[(i[2] * dims[1] + i[1]) * dims[0] + i[0]];
                            let got = b[base + (dz * SIDE + dy) * SIDE + dx];
                            assert_eq!(
                                got,
                                want,
                                "dims {dims:?} cell {:?} corner {:?}",
                                [x, y, z],
                                (dx, dy, dz)
                            );
                        }
                    }
                }
            }
        }
    }
}
