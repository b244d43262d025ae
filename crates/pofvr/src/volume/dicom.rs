//! A folder of single-frame DICOM slices (CT, MR) as one volume, through dicom-rs.
//!
//! The slices of one series are sorted along the slice normal (the cross product of the
//! two `ImageOrientationPatient` directions) by the projection of `ImagePositionPatient`;
//! the slice spacing is the distance between those projections, not `SliceThickness`
//! (which scanners set to the reconstructed thickness, not the step). Voxels keep their
//! stored type when `RescaleSlope`/`RescaleIntercept` are the identity; integral rescales
//! whose range fits become i16 (CT in Hounsfield units); anything else becomes f32.
//! Native (uncompressed, little-endian) and RLE Lossless pixel data are read.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dicom_dictionary_std::tags;
use dicom_encoding::TransferSyntaxIndex;
use dicom_object::{DefaultDicomObject, OpenFileOptions, Tag};
use dicom_transfer_syntax_registry::TransferSyntaxRegistry;
use rayon::prelude::*;

use super::{Volume, VolumeError, VoxelData, Voxels};

/// True when `path` is a folder holding at least one DICOM file (a `DICM` preamble).
#[must_use]
pub fn is_series_dir(path: &Path) -> bool {
    path.is_dir()
        && std::fs::read_dir(path)
            .map(|mut it| it.any(|e| e.is_ok_and(|e| has_dicm_magic(&e.path()))))
            .unwrap_or(false)
}

/// A DICOM Part 10 file: 128 bytes of preamble, then `DICM`.
fn has_dicm_magic(path: &Path) -> bool {
    use std::io::Read;
    let mut head = [0u8; 132];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok()
        && &head[128..] == b"DICM"
}

/// What a slice's header says, read without its pixel data.
struct Slice {
    file: PathBuf,
    series: String,
    position: [f64; 3],
    orientation: [f64; 6],
    rows: usize,
    cols: usize,
    pixel_spacing: [f64; 2],
    bits_allocated: u16,
    bits_stored: u16,
    signed: bool,
    slope: f64,
    intercept: f64,
    transfer_syntax: String,
}

fn tag_name(tag: Tag) -> String {
    let name = match tag {
        tags::IMAGE_POSITION_PATIENT => "ImagePositionPatient",
        tags::IMAGE_ORIENTATION_PATIENT => "ImageOrientationPatient",
        tags::SERIES_INSTANCE_UID => "SeriesInstanceUID",
        tags::ROWS => "Rows",
        tags::COLUMNS => "Columns",
        tags::PIXEL_SPACING => "PixelSpacing",
        tags::BITS_ALLOCATED => "BitsAllocated",
        tags::BITS_STORED => "BitsStored",
        tags::PIXEL_REPRESENTATION => "PixelRepresentation",
        tags::SAMPLES_PER_PIXEL => "SamplesPerPixel",
        tags::NUMBER_OF_FRAMES => "NumberOfFrames",
        tags::RESCALE_SLOPE => "RescaleSlope",
        tags::RESCALE_INTERCEPT => "RescaleIntercept",
        tags::PIXEL_DATA => "PixelData",
        tags::TRANSFER_SYNTAX_UID => "TransferSyntaxUID",
        _ => "",
    };
    format!("{name} ({:04X},{:04X})", tag.group(), tag.element())
}

/// The RLE Lossless transfer syntax, the one compressed syntax read.
const RLE_LOSSLESS: &str = "1.2.840.10008.1.2.5";

fn bad(file: &Path, tag: Tag, why: impl Into<String>) -> VolumeError {
    VolumeError::header(file, &tag_name(tag), why)
}

fn floats(
    obj: &DefaultDicomObject,
    file: &Path,
    tag: Tag,
    n: usize,
) -> Result<Vec<f64>, VolumeError> {
    let e = obj.element(tag).map_err(|_| bad(file, tag, "missing"))?;
    let v = e
        .to_multi_float64()
        .map_err(|err| bad(file, tag, format!("not numbers: {err}")))?;
    if v.len() != n || v.iter().any(|x| !x.is_finite()) {
        return Err(bad(
            file,
            tag,
            format!("expected {n} finite numbers, got {v:?}"),
        ));
    }
    Ok(v)
}

fn int(
    obj: &DefaultDicomObject,
    file: &Path,
    tag: Tag,
    default: Option<u32>,
) -> Result<u32, VolumeError> {
    match obj.element_opt(tag).ok().flatten() {
        Some(e) => e
            .to_int::<u32>()
            .map_err(|err| bad(file, tag, format!("not an integer: {err}"))),
        None => default.ok_or_else(|| bad(file, tag, "missing")),
    }
}

fn float_or(
    obj: &DefaultDicomObject,
    file: &Path,
    tag: Tag,
    default: f64,
) -> Result<f64, VolumeError> {
    match obj.element_opt(tag).ok().flatten() {
        Some(e) => {
            let v = e
                .to_float64()
                .map_err(|err| bad(file, tag, format!("not a number: {err}")))?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(bad(file, tag, format!("not finite: {v}")))
            }
        }
        None => Ok(default),
    }
}

/// Reads `file` whole (a slice is small) and walks its element headers
/// ([`super::dicom_scan`]) before dicom-rs reserves what they claim; with the file's size.
fn check_file(file: &Path) -> Result<u64, VolumeError> {
    let bytes = std::fs::read(file).map_err(|e| VolumeError::io(file, e))?;
    super::dicom_scan::check_lengths(&bytes).map_err(|b| match b.tag {
        Some(tag) => bad(file, tag, b.why),
        None => VolumeError::Decode {
            file: file.display().to_string(),
            why: format!("not a readable DICOM file: {}", b.why),
        },
    })?;
    Ok(bytes.len() as u64)
}

fn read_header(file: &Path) -> Result<Slice, VolumeError> {
    let file_len = check_file(file)?;
    let obj = OpenFileOptions::new()
        .read_until(tags::PIXEL_DATA)
        .open_file(file)
        .map_err(|e| VolumeError::Decode {
            file: file.display().to_string(),
            why: format!("not a readable DICOM file: {e}"),
        })?;
    let series = obj
        .element(tags::SERIES_INSTANCE_UID)
        .ok()
        .and_then(|e| {
            e.to_str()
                .ok()
                .map(|s| s.trim_end_matches('\0').trim().to_string())
        })
        .ok_or_else(|| bad(file, tags::SERIES_INSTANCE_UID, "missing"))?;
    let p = floats(&obj, file, tags::IMAGE_POSITION_PATIENT, 3)?;
    let o = floats(&obj, file, tags::IMAGE_ORIENTATION_PATIENT, 6)?;
    let ps = floats(&obj, file, tags::PIXEL_SPACING, 2)?;
    if ps.iter().any(|s| *s <= 0.0) {
        return Err(bad(
            file,
            tags::PIXEL_SPACING,
            format!("must be > 0, got {ps:?}"),
        ));
    }
    let frames = int(&obj, file, tags::NUMBER_OF_FRAMES, Some(1))?;
    if frames != 1 {
        return Err(bad(
            file,
            tags::NUMBER_OF_FRAMES,
            format!("{frames} frames: only single-frame slices are read"),
        ));
    }
    let samples = int(&obj, file, tags::SAMPLES_PER_PIXEL, Some(1))?;
    if samples != 1 {
        return Err(bad(
            file,
            tags::SAMPLES_PER_PIXEL,
            format!("{samples} samples per pixel: only grey-scale slices are read"),
        ));
    }
    let bits_allocated = int(&obj, file, tags::BITS_ALLOCATED, None)?;
    if bits_allocated != 8 && bits_allocated != 16 {
        return Err(bad(
            file,
            tags::BITS_ALLOCATED,
            format!("{bits_allocated}: only 8 and 16 are read"),
        ));
    }
    let bits_stored = int(&obj, file, tags::BITS_STORED, Some(bits_allocated))?;
    if bits_stored == 0 || bits_stored > bits_allocated {
        return Err(bad(
            file,
            tags::BITS_STORED,
            format!("{bits_stored} with BitsAllocated {bits_allocated}"),
        ));
    }
    let rows = int(&obj, file, tags::ROWS, None)? as usize;
    let cols = int(&obj, file, tags::COLUMNS, None)? as usize;
    if rows == 0 || cols == 0 {
        return Err(bad(file, tags::ROWS, format!("{cols}×{rows} pixels")));
    }
    let transfer_syntax = obj
        .meta()
        .transfer_syntax()
        .trim_end_matches('\0')
        .to_string();
    // The pixels a slice claims must fit in its file (RLE expands a byte pair to at most
    // 128 bytes): the series' buffer is sized by these claims.
    let need = (rows * cols * (bits_allocated as usize / 8)) as u64;
    let rle = transfer_syntax == RLE_LOSSLESS;
    if need > file_len.saturating_mul(if rle { 64 } else { 1 }) {
        return Err(bad(
            file,
            tags::PIXEL_DATA,
            format!("{cols}×{rows} pixels of {bits_allocated} bits do not fit in a file of {file_len} bytes"),
        ));
    }
    let slope = float_or(&obj, file, tags::RESCALE_SLOPE, 1.0)?;
    if slope == 0.0 {
        return Err(bad(file, tags::RESCALE_SLOPE, "must not be 0"));
    }
    Ok(Slice {
        file: file.to_path_buf(),
        series,
        position: [p[0], p[1], p[2]],
        orientation: std::array::from_fn(|i| o[i]),
        rows,
        cols,
        pixel_spacing: [ps[0], ps[1]],
        bits_allocated: bits_allocated as u16,
        bits_stored: bits_stored as u16,
        signed: int(&obj, file, tags::PIXEL_REPRESENTATION, Some(0))? == 1,
        slope,
        intercept: float_or(&obj, file, tags::RESCALE_INTERCEPT, 0.0)?,
        transfer_syntax,
    })
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The stored type the series is given.
#[derive(Clone, Copy, PartialEq)]
enum Out {
    U8,
    U16,
    I16,
    F32,
}

/// Opens the DICOM series in folder `dir`; `series` picks one SeriesInstanceUID when the
/// folder holds several.
///
/// # Errors
/// A [`VolumeError`] naming the file and the DICOM tag for a folder with no DICOM slices,
/// several series and none picked, differing orientations or sizes, duplicate or missing
/// slices, uneven slice spacing, unsupported pixel formats, and truncated pixel data.
pub fn open(dir: &Path, series: Option<&str>) -> Result<Volume, VolumeError> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| VolumeError::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && has_dicm_magic(p))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(VolumeError::Header {
            file: dir.display().to_string(),
            field: "folder".into(),
            why: "no DICOM files (with a DICM preamble) in it".into(),
        });
    }
    let headers: Vec<Slice> = files
        .par_iter()
        .map(|f| read_header(f))
        .collect::<Result<_, _>>()?;
    let mut by_series: BTreeMap<&str, Vec<&Slice>> = BTreeMap::new();
    for h in &headers {
        by_series.entry(&h.series).or_default().push(h);
    }
    let listing = || {
        by_series
            .iter()
            .map(|(uid, v)| format!("{uid} ({} slices)", v.len()))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let folder_err = |why: String| VolumeError::Header {
        file: dir.display().to_string(),
        field: tag_name(tags::SERIES_INSTANCE_UID),
        why,
    };
    let mut slices = match series {
        Some(uid) => by_series.get(uid).cloned().ok_or_else(|| {
            folder_err(format!(
                "no series {uid:?} here; the series are {}",
                listing()
            ))
        })?,
        None if by_series.len() == 1 => by_series.values().next().cloned().unwrap_or_default(),
        None => {
            return Err(folder_err(format!(
                "{} series in one folder, pick one: {}",
                by_series.len(),
                listing()
            )))
        }
    };
    let first = slices[0];
    for s in &slices[1..] {
        if s.orientation
            .iter()
            .zip(first.orientation)
            .any(|(a, b)| (a - b).abs() > 1e-4)
        {
            return Err(bad(
                &s.file,
                tags::IMAGE_ORIENTATION_PATIENT,
                format!(
                    "{:?} differs from {:?} in {}",
                    s.orientation,
                    first.orientation,
                    first.file.display()
                ),
            ));
        }
        let same = |a: f64, b: f64| (a - b).abs() <= 1e-4 * a.abs().max(b.abs());
        if s.rows != first.rows || s.cols != first.cols {
            return Err(bad(
                &s.file,
                tags::ROWS,
                format!(
                    "{}×{} pixels, but {} has {}×{}",
                    s.cols,
                    s.rows,
                    first.file.display(),
                    first.cols,
                    first.rows
                ),
            ));
        }
        if !(same(s.pixel_spacing[0], first.pixel_spacing[0])
            && same(s.pixel_spacing[1], first.pixel_spacing[1]))
        {
            return Err(bad(
                &s.file,
                tags::PIXEL_SPACING,
                format!(
                    "{:?}, but {} has {:?}",
                    s.pixel_spacing,
                    first.file.display(),
                    first.pixel_spacing
                ),
            ));
        }
        if s.bits_allocated != first.bits_allocated || s.signed != first.signed {
            return Err(bad(
                &s.file,
                tags::BITS_ALLOCATED,
                format!(
                    "{} bits ({}), but {} has {} bits ({})",
                    s.bits_allocated,
                    if s.signed { "signed" } else { "unsigned" },
                    first.file.display(),
                    first.bits_allocated,
                    if first.signed { "signed" } else { "unsigned" }
                ),
            ));
        }
    }
    let o = first.orientation;
    let normal = cross([o[0], o[1], o[2]], [o[3], o[4], o[5]]);
    if (dot(normal, normal) - 1.0).abs() > 1e-3 {
        return Err(bad(
            &first.file,
            tags::IMAGE_ORIENTATION_PATIENT,
            format!("{o:?} are not two orthogonal unit vectors"),
        ));
    }
    slices.sort_by(|a, b| dot(a.position, normal).total_cmp(&dot(b.position, normal)));
    let dz = slice_spacing(&slices, normal)?;
    let dims = [first.cols, first.rows, slices.len()];
    let spacing = [
        first.pixel_spacing[1] as f32,
        first.pixel_spacing[0] as f32,
        dz as f32,
    ];
    let out = output_type(&slices);
    let plane = dims[0] * dims[1];
    let source = dir.display().to_string();
    super::checked_voxel_count(&source, dims)?;
    let data = match out {
        Out::U8 => VoxelData::U8(Voxels::owned(read_all(&slices, plane, |v| v as u8)?)),
        Out::U16 => VoxelData::U16(Voxels::owned(read_all(&slices, plane, |v| v as u16)?)),
        Out::I16 => VoxelData::I16(Voxels::owned(read_all(&slices, plane, |v| v as i16)?)),
        Out::F32 => VoxelData::F32(Voxels::owned(read_all(&slices, plane, |v| v as f32)?)),
    };
    Volume::new(dims, spacing, data, source)
}

/// The step between slices from their positions along the normal: it must be even, with
/// no duplicates and no gaps.
fn slice_spacing(slices: &[&Slice], normal: [f64; 3]) -> Result<f64, VolumeError> {
    if slices.len() < 2 {
        // One slice: the in-plane spacing is the best guess for a slab one voxel deep.
        return Ok(slices[0].pixel_spacing[0].min(slices[0].pixel_spacing[1]));
    }
    let d: Vec<f64> = slices.iter().map(|s| dot(s.position, normal)).collect();
    let steps: Vec<f64> = d.windows(2).map(|w| w[1] - w[0]).collect();
    let mut sorted = steps.clone();
    sorted.sort_by(f64::total_cmp);
    let step = sorted[sorted.len() / 2];
    for (i, s) in steps.iter().enumerate() {
        let (a, b) = (slices[i], slices[i + 1]);
        if *s < 1e-4 * step.max(1e-6) || *s < 1e-6 {
            return Err(bad(
                &b.file,
                tags::IMAGE_POSITION_PATIENT,
                format!("the same slice position as {}", a.file.display()),
            ));
        }
        let ratio = s / step;
        if (ratio - 1.0).abs() > 0.02 {
            let missing = ratio.round();
            let why = if missing >= 2.0 && (ratio - missing).abs() < 0.05 {
                format!(
                    "{} slice(s) missing between {} and this one: a gap of {s:.4} mm where the step is {step:.4} mm",
                    missing as u64 - 1,
                    a.file.display()
                )
            } else {
                format!(
                    "uneven slice spacing: {s:.4} mm after {} where the step is {step:.4} mm",
                    a.file.display()
                )
            };
            return Err(bad(&b.file, tags::IMAGE_POSITION_PATIENT, why));
        }
    }
    Ok((d[d.len() - 1] - d[0]) / (d.len() - 1) as f64)
}

/// The stored range of a slice's pixels.
fn stored_range(s: &Slice) -> (f64, f64) {
    let bits = i32::from(s.bits_stored);
    if s.signed {
        (-(2f64.powi(bits - 1)), 2f64.powi(bits - 1) - 1.0)
    } else {
        (0.0, 2f64.powi(bits) - 1.0)
    }
}

fn output_type(slices: &[&Slice]) -> Out {
    let identity = slices.iter().all(|s| s.slope == 1.0 && s.intercept == 0.0);
    let first = slices[0];
    if identity {
        return match (first.bits_allocated, first.signed) {
            (8, false) => Out::U8,
            (8, true) | (16, true) => Out::I16,
            _ => Out::U16,
        };
    }
    let fits_i16 = slices.iter().all(|s| {
        let integral = s.slope.fract() == 0.0 && s.intercept.fract() == 0.0;
        let (lo, hi) = stored_range(s);
        let (a, b) = (lo * s.slope + s.intercept, hi * s.slope + s.intercept);
        integral && a.min(b) >= f64::from(i16::MIN) && a.max(b) <= f64::from(i16::MAX)
    });
    if fits_i16 {
        Out::I16
    } else {
        Out::F32
    }
}

/// Reads every slice's pixels (in parallel) into one buffer, rescaled and converted.
fn read_all<T: Send + Copy + Default>(
    slices: &[&Slice],
    plane: usize,
    convert: impl Fn(f64) -> T + Sync,
) -> Result<Vec<T>, VolumeError> {
    let mut out = vec![T::default(); plane * slices.len()];
    out.par_chunks_mut(plane)
        .zip(slices.par_iter())
        .try_for_each(|(dst, s)| {
            let bytes = pixel_bytes(s)?;
            let bpp = usize::from(s.bits_allocated / 8);
            let mask: u32 = (1u32 << s.bits_stored) - 1;
            let sign = 1u32 << (s.bits_stored - 1);
            for (i, d) in dst.iter_mut().enumerate() {
                let raw = if bpp == 1 {
                    u32::from(bytes[i])
                } else {
                    u32::from(u16::from_le_bytes([bytes[2 * i], bytes[2 * i + 1]]))
                } & mask;
                let v = if s.signed && raw & sign != 0 {
                    f64::from(raw) - f64::from(mask) - 1.0
                } else {
                    f64::from(raw)
                };
                *d = convert(v * s.slope + s.intercept);
            }
            Ok(())
        })?;
    Ok(out)
}

/// A slice's pixel bytes, little-endian, exactly rows × columns × bytes long.
fn pixel_bytes(s: &Slice) -> Result<Vec<u8>, VolumeError> {
    let file = &s.file;
    // The file may have changed since its header was read.
    check_file(file)?;
    let obj = dicom_object::open_file(file).map_err(|e| VolumeError::Decode {
        file: file.display().to_string(),
        why: format!("{}: {e}", tag_name(tags::PIXEL_DATA)),
    })?;
    let expected = s.rows * s.cols * usize::from(s.bits_allocated / 8);
    let ts = TransferSyntaxRegistry
        .get(&s.transfer_syntax)
        .ok_or_else(|| {
            bad(
                file,
                tags::TRANSFER_SYNTAX_UID,
                format!("unknown transfer syntax {:?}", s.transfer_syntax),
            )
        })?;
    let bytes = if ts.is_encapsulated_pixel_data() {
        if s.transfer_syntax != RLE_LOSSLESS {
            return Err(bad(
                file,
                tags::TRANSFER_SYNTAX_UID,
                format!(
                    "{} ({}) is not decoded here: uncompressed and RLE Lossless are",
                    ts.name(),
                    s.transfer_syntax
                ),
            ));
        }
        // Decoded by our own checked decoder (dicom-rs's indexes past short segments).
        let fragments = obj
            .element(tags::PIXEL_DATA)
            .ok()
            .and_then(|e| e.value().fragments())
            .ok_or_else(|| bad(file, tags::PIXEL_DATA, "no RLE fragments"))?;
        super::dicom_rle::decode(fragments, s.rows, s.cols, usize::from(s.bits_allocated / 8))
            .map_err(|why| {
                bad(
                    file,
                    tags::PIXEL_DATA,
                    format!("RLE data do not decode: {why}"),
                )
            })?
    } else {
        if ts.endianness() != dicom_encoding::transfer_syntax::Endianness::Little {
            return Err(bad(
                file,
                tags::TRANSFER_SYNTAX_UID,
                "big-endian pixel data are not read",
            ));
        }
        let e = obj
            .element(tags::PIXEL_DATA)
            .map_err(|_| bad(file, tags::PIXEL_DATA, "missing"))?;
        e.to_bytes()
            .map_err(|err| bad(file, tags::PIXEL_DATA, format!("not bytes: {err}")))?
            .into_owned()
    };
    if bytes.len() < expected {
        return Err(bad(
            file,
            tags::PIXEL_DATA,
            format!(
                "truncated: {} bytes where {}×{} pixels of {} bits need {expected}",
                bytes.len(),
                s.cols,
                s.rows,
                s.bits_allocated
            ),
        ));
    }
    Ok(bytes)
}
