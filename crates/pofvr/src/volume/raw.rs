//! Headerless raw files, and the shared back end of every reader: map or decode the
//! voxel bytes once, check their size, keep them in their stored type.

use std::fs::File;
use std::io::Read;
use std::path::Path;
use std::sync::Arc;

use memmap2::Mmap;

use super::{checked_voxel_count, DataType, Volume, VolumeError, VoxelData, Voxels};

/// Byte order of stored voxels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Endian {
    /// Least significant byte first (the default, and what every file in the catalogue uses).
    #[default]
    Little,
    /// Most significant byte first.
    Big,
}

impl std::str::FromStr for Endian {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "little" | "le" => Ok(Endian::Little),
            "big" | "be" => Ok(Endian::Big),
            other => Err(format!(
                "unknown endianness {other:?}, expected little or big"
            )),
        }
    }
}

/// The layout of a headerless raw file.
#[derive(Clone, Debug, PartialEq)]
pub struct RawSpec {
    /// Voxel counts along x, y, z.
    pub dims: [usize; 3],
    /// Stored type.
    pub dtype: DataType,
    /// Byte order.
    pub endian: Endian,
    /// World spacing along x, y, z.
    pub spacing: [f32; 3],
    /// Bytes to skip at the start of the file.
    pub offset: u64,
}

impl RawSpec {
    /// A little-endian layout with unit spacing and no header.
    #[must_use]
    pub fn new(dims: [usize; 3], dtype: DataType) -> Self {
        RawSpec {
            dims,
            dtype,
            endian: Endian::Little,
            spacing: [1.0; 3],
            offset: 0,
        }
    }
}

/// Opens a raw file: memory-mapped, its size checked exactly against the layout.
///
/// # Errors
/// [`VolumeError::SizeMismatch`] when the file is shorter or longer than `offset + dims ×
/// type`, [`VolumeError::BadDims`] for zero or overflowing dims, I/O errors.
pub fn open(path: &Path, spec: &RawSpec) -> Result<Volume, VolumeError> {
    let source = path.display().to_string();
    let n = checked_voxel_count(&source, spec.dims)?;
    let file = File::open(path).map_err(|e| VolumeError::io(path, e))?;
    let len = file.metadata().map_err(|e| VolumeError::io(path, e))?.len();
    let expected = n as u64 * spec.dtype.size() as u64;
    if len.checked_sub(spec.offset) != Some(expected) {
        return Err(VolumeError::SizeMismatch {
            file: source,
            expected: expected.saturating_add(spec.offset),
            got: len,
        });
    }
    // SAFETY: the map is read-only; a file truncated underneath us by another process is
    // outside what any reader can defend against, as with every mmap-based tool.
    let map = unsafe { Mmap::map(&file) }.map_err(|e| VolumeError::io(path, e))?;
    #[cfg(unix)]
    {
        // Bricks are touched in space-filling-curve order, not file order.
        let _ = map.advise(memmap2::Advice::Random);
    }
    let data = typed_from_map(
        Arc::new(map),
        usize::try_from(spec.offset).unwrap_or(0),
        n,
        spec,
    );
    let mut vol = Volume::new(spec.dims, spec.spacing, data, source)?;
    vol.raw_file = Some((path.to_path_buf(), spec.clone()));
    Ok(vol)
}

fn typed_from_map(map: Arc<Mmap>, offset: usize, n: usize, spec: &RawSpec) -> VoxelData {
    let big = spec.endian == Endian::Big;
    match spec.dtype {
        DataType::U8 => VoxelData::U8(Voxels::from_map(map, offset, n, big)),
        DataType::U16 => VoxelData::U16(Voxels::from_map(map, offset, n, big)),
        DataType::I16 => VoxelData::I16(Voxels::from_map(map, offset, n, big)),
        DataType::F32 => VoxelData::F32(Voxels::from_map(map, offset, n, big)),
    }
}

/// Decodes exactly the voxel bytes of `spec` from a stream (gzip or zlib data of NRRD and
/// MetaImage files); the stream must end where the voxels do.
///
/// # Errors
/// [`VolumeError::Decode`] when the stream is truncated or corrupt,
/// [`VolumeError::SizeMismatch`] when it holds more data than the layout.
pub fn from_reader(
    source: &Path,
    mut reader: impl Read,
    spec: &RawSpec,
) -> Result<Volume, VolumeError> {
    let name = source.display().to_string();
    let n = checked_voxel_count(&name, spec.dims)?;
    let expected = n * spec.dtype.size();
    // The buffer grows with the data that actually arrives: the header's sizes are a claim,
    // and a few bytes of stream claiming 10¹² voxels must fail as truncated, not allocate.
    let mut bytes = Vec::with_capacity(expected.min(1 << 20));
    let filled = (&mut reader)
        .take(expected as u64)
        .read_to_end(&mut bytes)
        .map_err(|e| VolumeError::Decode {
            file: name.clone(),
            why: e.to_string(),
        })?;
    if filled < expected {
        return Err(VolumeError::Decode {
            file: name,
            why: format!("data end after {filled} of {expected} bytes (truncated?)"),
        });
    }
    bytes.shrink_to_fit();
    let mut extra = [0u8; 1];
    match reader.read(&mut extra) {
        Ok(0) => {}
        Ok(_) => {
            return Err(VolumeError::SizeMismatch {
                file: name,
                expected: expected as u64,
                got: expected as u64
                    + 1
                    + std::io::copy(&mut reader, &mut std::io::sink()).unwrap_or(0),
            })
        }
        Err(e) => {
            return Err(VolumeError::Decode {
                file: name,
                why: e.to_string(),
            })
        }
    }
    let big = spec.endian == Endian::Big;
    let data = match spec.dtype {
        DataType::U8 => VoxelData::U8(Voxels::owned(bytes)),
        DataType::U16 => VoxelData::U16(Voxels::from_bytes(&bytes, big)),
        DataType::I16 => VoxelData::I16(Voxels::from_bytes(&bytes, big)),
        DataType::F32 => VoxelData::F32(Voxels::from_bytes(&bytes, big)),
    };
    Volume::new(spec.dims, spec.spacing, data, name)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fuzz finding (nrrd target): a gzip NRRD whose `sizes` claim 10¹² voxels allocated
    /// them all before reading the stream, and aborted the process.
    #[test]
    fn a_stream_claiming_more_voxels_than_it_holds_fails_before_allocating_them() {
        let spec = RawSpec::new([10_000, 10_000, 10_000], DataType::F32);
        let err = from_reader(Path::new("huge.nrrd"), &[1u8, 2, 3][..], &spec).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("huge.nrrd") && msg.contains("after 3 of 4000000000000 bytes"),
            "{msg}"
        );
        let spec = RawSpec::new([2, 2, 1], DataType::U16);
        let v = from_reader(Path::new("ok.nrrd"), &[1u8, 0, 2, 0, 3, 0, 4, 0][..], &spec).unwrap();
        assert_eq!(v.value(1, 1, 0), 4.0);
    }
}
