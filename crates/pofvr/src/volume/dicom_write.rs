//! Writes an integer volume as a folder of single-frame CT slices (one file per z), the
//! layout [`super::dicom::open`] reads: for exporting volumes and for building test series.

use std::path::Path;

use dicom_core::value::{PixelFragmentSequence, PrimitiveValue};
use dicom_core::{DataElement, VR};
use dicom_dictionary_std::{tags, uids};
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};

use super::{Volume, VolumeError};

/// How to write a series.
#[derive(Clone, Debug)]
pub struct SeriesOptions {
    /// The SeriesInstanceUID of every slice.
    pub series_uid: String,
    /// RLE Lossless pixel data instead of uncompressed.
    pub rle: bool,
    /// Stored = value − intercept, written with `RescaleIntercept` so a reader gets the
    /// values back (CT scanners store unsigned with −1024).
    pub intercept: i32,
    /// Where the first slice sits (ImagePositionPatient), millimetres.
    pub origin: [f64; 3],
}

impl Default for SeriesOptions {
    fn default() -> Self {
        SeriesOptions {
            series_uid: "1.2.826.0.1.3680043.10.1".into(),
            rle: false,
            intercept: 0,
            origin: [0.0; 3],
        }
    }
}

/// Writes `volume` (u8, u16 or i16) as `dir/slice_NNNN.dcm`, axial, in file order z.
///
/// # Errors
/// [`VolumeError::Header`] for float volumes or values that do not fit 16 bits after the
/// intercept; [`VolumeError::Io`] when a file cannot be written.
pub fn write_series(volume: &Volume, dir: &Path, opts: &SeriesOptions) -> Result<(), VolumeError> {
    if volume.data_type() == super::DataType::F32 {
        return Err(VolumeError::header(
            Path::new(volume.source()),
            "type",
            "DICOM slices are written from integer volumes only",
        ));
    }
    std::fs::create_dir_all(dir).map_err(|e| VolumeError::io(dir, e))?;
    let [nx, ny, nz] = volume.dims();
    let sp = volume.spacing();
    let stored: Vec<i64> = (0..nx * ny * nz)
        .map(|i| {
            let (x, y, z) = (i % nx, (i / nx) % ny, i / (nx * ny));
            volume.value(x, y, z) as i64 - i64::from(opts.intercept)
        })
        .collect();
    let (lo, hi) = stored
        .iter()
        .fold((i64::MAX, i64::MIN), |(a, b), v| (a.min(*v), b.max(*v)));
    let signed = lo < 0;
    let fits = if signed {
        lo >= i64::from(i16::MIN) && hi <= i64::from(i16::MAX)
    } else {
        hi <= i64::from(u16::MAX)
    };
    if !fits {
        return Err(VolumeError::header(
            Path::new(volume.source()),
            "value range",
            format!("{lo}..{hi} after the intercept does not fit 16 bits"),
        ));
    }
    // As scanners do: unsigned data store only the bits they use (12 for CT), which tells a
    // reader that the rescaled range fits i16.
    let bits_stored = if signed {
        16
    } else {
        (64 - (hi.max(1) as u64).leading_zeros()).max(12) as u16
    };
    for z in 0..nz {
        let plane = &stored[z * nx * ny..(z + 1) * nx * ny];
        let bytes: Vec<u8> = plane
            .iter()
            .flat_map(|v| (*v as i16 as u16).to_le_bytes())
            .collect();
        let instance = format!("{}.{}", opts.series_uid, z + 1);
        let mut obj = InMemDicomObject::new_empty();
        let put_str = |obj: &mut InMemDicomObject, tag, vr, s: &str| {
            obj.put(DataElement::new(tag, vr, PrimitiveValue::from(s)));
        };
        let put_ds = |obj: &mut InMemDicomObject, tag, v: &[f64]| {
            let s: Vec<String> = v.iter().map(|x| format!("{x}")).collect();
            obj.put(DataElement::new(
                tag,
                VR::DS,
                PrimitiveValue::Strs(s.into()),
            ));
        };
        let put_us = |obj: &mut InMemDicomObject, tag, v: u16| {
            obj.put(DataElement::new(tag, VR::US, PrimitiveValue::from(v)));
        };
        put_str(
            &mut obj,
            tags::SOP_CLASS_UID,
            VR::UI,
            uids::CT_IMAGE_STORAGE,
        );
        put_str(&mut obj, tags::SOP_INSTANCE_UID, VR::UI, &instance);
        put_str(&mut obj, tags::MODALITY, VR::CS, "CT");
        put_str(
            &mut obj,
            tags::SERIES_INSTANCE_UID,
            VR::UI,
            &opts.series_uid,
        );
        put_str(
            &mut obj,
            tags::INSTANCE_NUMBER,
            VR::IS,
            &(z + 1).to_string(),
        );
        let o = opts.origin;
        put_ds(
            &mut obj,
            tags::IMAGE_POSITION_PATIENT,
            &[o[0], o[1], o[2] + z as f64 * f64::from(sp[2])],
        );
        put_ds(
            &mut obj,
            tags::IMAGE_ORIENTATION_PATIENT,
            &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
        );
        put_ds(
            &mut obj,
            tags::PIXEL_SPACING,
            &[f64::from(sp[1]), f64::from(sp[0])],
        );
        put_ds(&mut obj, tags::SLICE_THICKNESS, &[f64::from(sp[2]) * 2.0]);
        put_ds(&mut obj, tags::RESCALE_SLOPE, &[1.0]);
        put_ds(
            &mut obj,
            tags::RESCALE_INTERCEPT,
            &[f64::from(opts.intercept)],
        );
        put_us(&mut obj, tags::ROWS, ny as u16);
        put_us(&mut obj, tags::COLUMNS, nx as u16);
        put_us(&mut obj, tags::SAMPLES_PER_PIXEL, 1);
        put_str(
            &mut obj,
            tags::PHOTOMETRIC_INTERPRETATION,
            VR::CS,
            "MONOCHROME2",
        );
        put_us(&mut obj, tags::BITS_ALLOCATED, 16);
        put_us(&mut obj, tags::BITS_STORED, bits_stored);
        put_us(&mut obj, tags::HIGH_BIT, bits_stored - 1);
        put_us(&mut obj, tags::PIXEL_REPRESENTATION, u16::from(signed));
        let ts = if opts.rle {
            let frag = rle_encode_16(&bytes, nx * ny);
            obj.put(DataElement::new(
                tags::PIXEL_DATA,
                VR::OB,
                PixelFragmentSequence::new(Vec::<u32>::new(), vec![frag]),
            ));
            uids::RLE_LOSSLESS
        } else {
            obj.put(DataElement::new(
                tags::PIXEL_DATA,
                VR::OW,
                PrimitiveValue::U8(bytes.into()),
            ));
            uids::EXPLICIT_VR_LITTLE_ENDIAN
        };
        let path = dir.join(format!("slice_{:04}.dcm", z + 1));
        let file = obj
            .with_meta(
                FileMetaTableBuilder::new()
                    .transfer_syntax(ts)
                    .media_storage_sop_class_uid(uids::CT_IMAGE_STORAGE)
                    .media_storage_sop_instance_uid(&instance),
            )
            .map_err(|e| VolumeError::header(&path, "file meta", e.to_string()))?;
        file.write_to_file(&path)
            .map_err(|e| VolumeError::io(&path, std::io::Error::other(e.to_string())))?;
    }
    Ok(())
}

/// RLE Lossless (DICOM PS3.5 annex G) of one 16-bit frame: two segments, the high bytes
/// then the low bytes, each PackBits-coded and padded to even length.
fn rle_encode_16(le_bytes: &[u8], pixels: usize) -> Vec<u8> {
    let hi: Vec<u8> = (0..pixels).map(|i| le_bytes[2 * i + 1]).collect();
    let lo: Vec<u8> = (0..pixels).map(|i| le_bytes[2 * i]).collect();
    let segs = [packbits(&hi), packbits(&lo)];
    let mut out = vec![0u8; 64];
    out[0..4].copy_from_slice(&2u32.to_le_bytes());
    let mut offset = 64u32;
    for (i, s) in segs.iter().enumerate() {
        out[4 + 4 * i..8 + 4 * i].copy_from_slice(&offset.to_le_bytes());
        offset += s.len() as u32;
    }
    for s in segs {
        out.extend_from_slice(&s);
    }
    out
}

fn packbits(src: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < src.len() {
        let mut run = 1;
        while i + run < src.len() && run < 128 && src[i + run] == src[i] {
            run += 1;
        }
        if run >= 2 {
            out.push((257 - run) as u8);
            out.push(src[i]);
            i += run;
        } else {
            let start = i;
            while i < src.len() && i - start < 128 && !(i + 1 < src.len() && src[i + 1] == src[i]) {
                i += 1;
            }
            if i == start {
                i += 1;
            }
            out.push((i - start - 1) as u8);
            out.extend_from_slice(&src[start..i]);
        }
    }
    if out.len() % 2 == 1 {
        out.push(0x80);
    }
    out
}
