//! Where a brick store's voxels come from: a file read at positions (raw data at an offset,
//! in its stored type and byte order), a Zarr level's chunks decoded on demand, or a volume
//! already in memory.

use std::fs::File;
use std::path::{Path, PathBuf};

use super::zarr_source::ZarrSource;
use crate::volume::{DataType, Endian, RawSpec, Volume, VolumeError, Voxel, VoxelData, Voxels};

/// The origin of the voxels a store reads.
#[derive(Debug)]
pub enum BrickSource {
    /// Uncompressed voxels in a file: each box is read with positioned reads (`pread`),
    /// one per row of the box, or one per plane or slab when the rows are contiguous.
    File {
        /// The open file.
        file: File,
        /// Its path, for messages.
        path: PathBuf,
        /// The layout: dims, type, byte order, offset.
        spec: RawSpec,
    },
    /// A Zarr level that is not resident: boxes assembled from its chunks, decoded on
    /// demand into a cache of decoded chunks ([`ZarrSource`]).
    Zarr(ZarrSource),
    /// The volume's own voxels, copied out (a generated or decoded volume, already in
    /// memory: the store then bounds the copies, not the volume).
    Memory,
}

impl BrickSource {
    /// Positioned reads of `path` with layout `spec`.
    ///
    /// # Errors
    /// [`VolumeError::Io`] naming the file when it cannot be opened.
    pub fn file(path: &Path, spec: &RawSpec) -> Result<Self, VolumeError> {
        let file = File::open(path).map_err(|e| VolumeError::io(path, e))?;
        Ok(BrickSource::File {
            file,
            path: path.to_path_buf(),
            spec: spec.clone(),
        })
    }

    /// The file source of `volume` when its voxels are stored uncompressed in a file, its
    /// Zarr source when they are not resident (a decoded-chunk cache of 0 bytes until
    /// [`ZarrSource::set_chunk_budget`]), otherwise [`BrickSource::Memory`].
    ///
    /// # Errors
    /// [`VolumeError::Io`] when the file cannot be opened again.
    pub fn of(volume: &Volume) -> Result<Self, VolumeError> {
        if let Some(level) = volume.zarr_level() {
            return Ok(BrickSource::Zarr(ZarrSource::new(level.clone(), 0)));
        }
        match volume.raw_file() {
            Some((path, spec)) => Self::file(path, spec),
            None => Ok(BrickSource::Memory),
        }
    }

    /// True when boxes are read from storage (a raw file or a Zarr store), not copied
    /// from memory: the volume is then never sampled whole.
    #[must_use]
    pub fn is_file(&self) -> bool {
        !matches!(self, BrickSource::Memory)
    }

    /// A name for `--stats`: "raw file", "zarr chunks" or "memory".
    #[must_use]
    pub fn kind(&self) -> &'static str {
        match self {
            BrickSource::File { .. } => "raw file",
            BrickSource::Zarr(_) => "zarr chunks",
            BrickSource::Memory => "memory",
        }
    }

    /// The Zarr source, when boxes come from a Zarr level's chunks.
    #[must_use]
    pub fn zarr(&self) -> Option<&ZarrSource> {
        match self {
            BrickSource::Zarr(z) => Some(z),
            _ => None,
        }
    }

    /// The voxels of the box at `origin` with `n` voxels per axis, x fastest, in the
    /// stored type; `volume` is the volume the source belongs to.
    ///
    /// # Errors
    /// [`VolumeError::Io`] naming the file when a read fails (e.g. the file was truncated
    /// after it was opened).
    pub fn read_box(
        &self,
        volume: &Volume,
        origin: [usize; 3],
        n: [usize; 3],
    ) -> Result<VoxelData, VolumeError> {
        Ok(self.read_box_counted(volume, origin, n)?.0)
    }

    /// [`BrickSource::read_box`], with the bytes read for it from storage: the box's bytes
    /// for a file or memory, the encoded (compressed) bytes of the chunks decoded for it
    /// for a Zarr level (0 when they were all cached).
    ///
    /// # Errors
    /// As [`BrickSource::read_box`]; for a Zarr level [`VolumeError::Decode`] naming a
    /// missing or corrupt chunk.
    pub fn read_box_counted(
        &self,
        volume: &Volume,
        origin: [usize; 3],
        n: [usize; 3],
    ) -> Result<(VoxelData, u64), VolumeError> {
        let (data, bytes, _) = self.read_box_decoding(volume, origin, n)?;
        Ok((data, bytes))
    }

    /// [`BrickSource::read_box_counted`], with the number of Zarr chunks decoded for the box
    /// (0 for a file or memory, and for chunks found in the chunk cache).
    ///
    /// # Errors
    /// As [`BrickSource::read_box_counted`].
    pub fn read_box_decoding(
        &self,
        volume: &Volume,
        origin: [usize; 3],
        n: [usize; 3],
    ) -> Result<(VoxelData, u64, u64), VolumeError> {
        let plain = |d: VoxelData| {
            let b = d.len() as u64 * d.data_type().size() as u64;
            (d, b, 0)
        };
        match self {
            BrickSource::Zarr(z) => z.read_box_decoding(origin, n),
            BrickSource::Memory => Ok(plain(copy_from_memory(volume, origin, n))),
            BrickSource::File { file, path, spec } => {
                let r = FileBox {
                    file,
                    path,
                    spec,
                    origin,
                    n,
                };
                Ok(plain(match spec.dtype {
                    DataType::U8 => VoxelData::U8(Voxels::owned(r.read()?)),
                    DataType::U16 => VoxelData::U16(Voxels::owned(r.read()?)),
                    DataType::I16 => VoxelData::I16(Voxels::owned(r.read()?)),
                    DataType::F32 => VoxelData::F32(Voxels::owned(r.finite(r.read()?)?)),
                }))
            }
        }
    }
}

fn copy_from_memory(volume: &Volume, lo: [usize; 3], n: [usize; 3]) -> VoxelData {
    // The brick engine's own box copy: the same rows, the same order.
    use crate::brick::copy::copy_box as copy;
    let vd = volume.dims();
    match volume.data() {
        VoxelData::U8(x) => VoxelData::U8(Voxels::owned(copy(x.as_slice(), vd, lo, n))),
        VoxelData::U16(x) => VoxelData::U16(Voxels::owned(copy(x.as_slice(), vd, lo, n))),
        VoxelData::I16(x) => VoxelData::I16(Voxels::owned(copy(x.as_slice(), vd, lo, n))),
        VoxelData::F32(x) => VoxelData::F32(Voxels::owned(copy(x.as_slice(), vd, lo, n))),
    }
}

/// One box of a file to read.
struct FileBox<'a> {
    file: &'a File,
    path: &'a Path,
    spec: &'a RawSpec,
    origin: [usize; 3],
    n: [usize; 3],
}

impl FileBox<'_> {
    fn read<T: Voxel>(&self) -> Result<Vec<T>, VolumeError> {
        let [n0, n1, n2] = self.n;
        let d = self.spec.dims;
        let o = self.origin;
        let mut out = vec![T::zeroed(); n0 * n1 * n2];
        let size = std::mem::size_of::<T>() as u64;
        let at =
            |y: usize, z: usize| self.spec.offset + size * (o[0] + d[0] * (y + d[1] * z)) as u64;
        // Rows that follow each other in the file are read in one call.
        if n0 == d[0] && n1 == d[1] {
            self.read_at(bytemuck::cast_slice_mut(&mut out), at(o[1], o[2]))?;
        } else if n0 == d[0] {
            for (k, plane) in out.chunks_exact_mut(n0 * n1).enumerate() {
                self.read_at(bytemuck::cast_slice_mut(plane), at(o[1], o[2] + k))?;
            }
        } else {
            for (r, row) in out.chunks_exact_mut(n0).enumerate() {
                let (y, z) = (o[1] + r % n1, o[2] + r / n1);
                self.read_at(bytemuck::cast_slice_mut(row), at(y, z))?;
            }
        }
        if self.spec.endian == Endian::Big && size > 1 {
            for x in &mut out {
                *x = x.swap_bytes();
            }
        }
        Ok(out)
    }

    /// Float voxels stay finite: the volume was checked when opened, but the file may
    /// have changed since. The error gives the voxel's index in the volume.
    fn finite(&self, v: Vec<f32>) -> Result<Vec<f32>, VolumeError> {
        let Some(i) = v.iter().position(|x| !x.is_finite()) else {
            return Ok(v);
        };
        let (n, o, d) = (self.n, self.origin, self.spec.dims);
        let (x, y, z) = (
            o[0] + i % n[0],
            o[1] + (i / n[0]) % n[1],
            o[2] + i / (n[0] * n[1]),
        );
        Err(VolumeError::NonFinite {
            file: self.path.display().to_string(),
            index: (x + d[0] * (y + d[1] * z)) as u64,
            value: v[i],
        })
    }

    fn read_at(&self, buf: &mut [u8], offset: u64) -> Result<(), VolumeError> {
        read_exact_at(self.file, buf, offset).map_err(|e| VolumeError::io(self.path, e))
    }
}

#[cfg(unix)]
fn read_exact_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, offset)
}

#[cfg(not(unix))]
fn read_exact_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    // A handle of its own, so that concurrent reads do not share a file position.
    let mut f = file.try_clone()?;
    f.seek(SeekFrom::Start(offset))?;
    f.read_exact(buf)
}
