//! NIfTI-1 reader: `.nii` and `.nii.gz`, the header parsed by the `nifti` crate.
//!
//! The voxels do not go through the crate's volume types, which would read the whole file
//! into an owned buffer: an uncompressed `.nii` is memory-mapped at `vox_offset` by the raw
//! back end (the file must end where the voxels do), and a `.nii.gz` (recognised by its
//! gzip magic, whatever the name) is decompressed once, streamed from the header through
//! the extensions into the voxel buffer.
//!
//! Supported: 3D images, or 4D and up whose extra dimensions are all 1; datatypes uint8,
//! int16, uint16 and float32, kept in their stored type. Spacing is `|pixdim[1..=3]|`
//! (orientation lives in qform/sform, which this renderer does not use).
//!
//! Scaling: `scl_slope` 0 or NaN means "no scaling" (NIfTI-1 §scl_slope), as does slope 1
//! with intercept 0. Any other slope/intercept is applied, and then the volume is converted
//! to f32 (`stored × slope + inter`) in an owned buffer, since the scaled values no longer
//! fit the stored integer type. A non-finite intercept with a valid slope is read as 0.

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

use flate2::read::MultiGzDecoder;

use super::{raw, DataType, Endian, RawSpec, Volume, VolumeError, Voxel, VoxelData, Voxels};

/// Size of the NIfTI-1 header; the data never start before it.
const HEADER_BYTES: u64 = 348;

/// The linear scaling a NIfTI header asks for, or `None` when values are used as stored.
#[must_use]
pub fn scaling(slope: f32, inter: f32) -> Option<(f32, f32)> {
    if slope == 0.0 || !slope.is_finite() {
        return None;
    }
    let inter = if inter.is_finite() { inter } else { 0.0 };
    if slope == 1.0 && inter == 0.0 {
        None
    } else {
        Some((slope, inter))
    }
}

/// Opens a `.nii` or `.nii.gz` file.
///
/// # Errors
/// [`VolumeError::Header`] for a header that is not NIfTI-1 or describes an unsupported
/// image (dimensions, datatype, detached `.hdr`/`.img`), [`VolumeError::SizeMismatch`] when a
/// `.nii` is shorter or longer than `vox_offset` + dims × type, [`VolumeError::Decode`] for
/// truncated or corrupt gzip data, and the errors of [`Volume::new`].
pub fn open(path: &Path) -> Result<Volume, VolumeError> {
    let mut file = File::open(path).map_err(|e| VolumeError::io(path, e))?;
    let mut magic = [0u8; 2];
    let got = read_full(&mut file, &mut magic).map_err(|e| VolumeError::io(path, e))?;
    let gz = got == 2 && magic == [0x1f, 0x8b];
    drop(file);
    let file = File::open(path).map_err(|e| VolumeError::io(path, e))?;
    let mut reader: Box<dyn Read> = if gz {
        Box::new(MultiGzDecoder::new(BufReader::new(file)))
    } else {
        Box::new(BufReader::new(file))
    };
    let h = ::nifti::NiftiHeader::from_reader(&mut reader).map_err(|e| match e {
        ::nifti::NiftiError::Io(io) if gz && io.kind() != std::io::ErrorKind::UnexpectedEof => {
            VolumeError::Decode {
                file: path.display().to_string(),
                why: io.to_string(),
            }
        }
        ::nifti::NiftiError::Io(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            VolumeError::header(
                path,
                "header",
                format!("the file ends inside the {HEADER_BYTES}-byte NIfTI-1 header"),
            )
        }
        ::nifti::NiftiError::InvalidFormat => VolumeError::header(
            path,
            "magic",
            "not a NIfTI-1 file (magic is neither \"n+1\" nor \"ni1\")",
        ),
        other => VolumeError::header(path, "header", other.to_string()),
    })?;
    let layout = check_header(path, &h)?;
    let spec = RawSpec {
        dims: layout.dims,
        dtype: layout.dtype,
        endian: layout.endian,
        spacing: layout.spacing,
        offset: layout.vox_offset,
    };
    let vol =
        if gz {
            // Extensions between the header and vox_offset are skipped, not parsed.
            let skip = layout.vox_offset - HEADER_BYTES;
            let skipped = std::io::copy(&mut (&mut reader).take(skip), &mut std::io::sink())
                .map_err(|e| VolumeError::Decode {
                    file: path.display().to_string(),
                    why: e.to_string(),
                })?;
            if skipped != skip {
                return Err(VolumeError::Decode {
                    file: path.display().to_string(),
                    why: format!(
                        "data end after {} bytes, before vox_offset {} (truncated?)",
                        HEADER_BYTES + skipped,
                        layout.vox_offset
                    ),
                });
            }
            raw::from_reader(path, reader, &RawSpec { offset: 0, ..spec })?
        } else {
            raw::open(path, &spec)?
        };
    match layout.scaling {
        None => Ok(vol),
        Some((slope, inter)) => {
            let (dims, spacing, source) = (vol.dims, vol.spacing, vol.source.clone());
            let scaled: Vec<f32> = crate::with_voxels!(vol.data(), v => scale(v, slope, inter));
            Volume::new(dims, spacing, VoxelData::F32(Voxels::owned(scaled)), source)
        }
    }
}

/// What the header says about the voxels, checked.
#[derive(Debug)]
struct Layout {
    dims: [usize; 3],
    dtype: DataType,
    endian: Endian,
    spacing: [f32; 3],
    vox_offset: u64,
    scaling: Option<(f32, f32)>,
}

fn check_header(path: &Path, h: &::nifti::NiftiHeader) -> Result<Layout, VolumeError> {
    if h.sizeof_hdr != 348 {
        return Err(VolumeError::header(
            path,
            "sizeof_hdr",
            format!("{} (NIfTI-2?): only NIfTI-1 (348) is read", h.sizeof_hdr),
        ));
    }
    if &h.magic == ::nifti::header::MAGIC_CODE_NI1 {
        return Err(VolumeError::header(
            path,
            "magic",
            "\"ni1\" is a detached .hdr/.img pair, which is not supported: use a single .nii",
        ));
    }
    let ndim = usize::from(h.dim[0]);
    if !(3..=7).contains(&ndim) || h.dim[4..=ndim].iter().any(|d| *d != 1) {
        return Err(VolumeError::header(
            path,
            "dim",
            format!(
                "unsupported image dimensions {:?}: only 3D volumes (or 4D and up with one volume) are read",
                &h.dim[1..=ndim.clamp(1, 7)]
            ),
        ));
    }
    let dtype = match h.datatype {
        2 => DataType::U8,
        4 => DataType::I16,
        512 => DataType::U16,
        16 => DataType::F32,
        code => {
            let name = h
                .data_type()
                .map_or_else(|_| "unknown".to_string(), |t| format!("{t:?}"));
            return Err(VolumeError::header(
                path,
                "datatype",
                format!("unsupported datatype {code} ({name}): pofvr reads uint8, int16, uint16 and float32"),
            ));
        }
    };
    let vox_offset = h.vox_offset;
    let vox = if vox_offset.is_finite()
        && vox_offset >= HEADER_BYTES as f32
        && vox_offset.fract() == 0.0
        // A bound keeps the offset arithmetic far from overflow; no real header comes near.
        && vox_offset < 1e12
    {
        vox_offset as u64
    } else {
        return Err(VolumeError::header(
            path,
            "vox_offset",
            format!("{vox_offset} is not a whole byte offset at or after the {HEADER_BYTES}-byte header"),
        ));
    };
    Ok(Layout {
        dims: [
            usize::from(h.dim[1]),
            usize::from(h.dim[2]),
            usize::from(h.dim[3]),
        ],
        dtype,
        endian: if h.endianness == ::nifti::Endianness::Big {
            Endian::Big
        } else {
            Endian::Little
        },
        spacing: [h.pixdim[1].abs(), h.pixdim[2].abs(), h.pixdim[3].abs()],
        vox_offset: vox,
        scaling: scaling(h.scl_slope, h.scl_inter),
    })
}

fn scale<T: Voxel>(v: &[T], slope: f32, inter: f32) -> Vec<f32> {
    let (s, i) = (f64::from(slope), f64::from(inter));
    v.iter()
        .map(|x| (f64::from(x.to_f32()) * s + i) as f32)
        .collect()
}

/// Reads until `buf` is full or the stream ends; the count read.
fn read_full(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A single-file NIfTI-1 of 4³ u8 voxels with the given `pixdim[1..4]`.
    fn nii(pixdim: [f32; 3]) -> Vec<u8> {
        let mut h = vec![0u8; 352];
        h[0..4].copy_from_slice(&348i32.to_le_bytes());
        for (i, d) in [3i16, 4, 4, 4, 1, 1, 1, 1].iter().enumerate() {
            h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
        }
        h[70..72].copy_from_slice(&2i16.to_le_bytes());
        h[72..74].copy_from_slice(&8i16.to_le_bytes());
        for (i, p) in [1.0f32, pixdim[0], pixdim[1], pixdim[2]].iter().enumerate() {
            h[76 + 4 * i..80 + 4 * i].copy_from_slice(&p.to_le_bytes());
        }
        h[108..112].copy_from_slice(&352f32.to_le_bytes());
        h[344..348].copy_from_slice(b"n+1\0");
        h.extend(0..64u8);
        h
    }

    /// Fuzz finding (nifti target): a finite pixdim whose product with the voxel count
    /// overflows f32 gave an infinite world extent, and NaN cameras and rays.
    #[test]
    fn a_spacing_whose_world_extent_overflows_is_rejected() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("v.nii");
        std::fs::write(&p, nii([1.0, 1.5, 2.0])).unwrap();
        assert_eq!(open(&p).unwrap().spacing(), [1.0, 1.5, 2.0]);
        std::fs::write(&p, nii([1.0, 1.0, -1.7e38])).unwrap();
        let msg = open(&p).unwrap_err().to_string();
        assert!(
            msg.contains("v.nii") && msg.contains("bad spacing"),
            "{msg}"
        );
    }
}
