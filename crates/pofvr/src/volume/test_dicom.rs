//! DICOM series: round trips through the writer and every bad case the reader names.

use std::path::Path;

use dicom_core::value::PrimitiveValue;
use dicom_core::{DataElement, VR};
use dicom_dictionary_std::tags;

use super::dicom_write::{write_series, SeriesOptions};
use super::phantom::Phantom;
use super::{DataType, OpenOptions, Volume};

fn body() -> Volume {
    Phantom::Body.generate_dims([24, 20, 12])
}

fn same_voxels(a: &Volume, b: &Volume) {
    assert_eq!(a.dims(), b.dims());
    let [nx, ny, nz] = a.dims();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                assert_eq!(a.value(x, y, z), b.value(x, y, z), "voxel {x},{y},{z}");
            }
        }
    }
}

fn open(dir: &Path) -> Result<Volume, String> {
    Volume::open(dir, None).map_err(|e| e.to_string())
}

/// Rewrites one slice file with `tag` set to `value`.
fn edit(file: &Path, tag: dicom_core::Tag, vr: VR, value: PrimitiveValue) {
    let mut obj = dicom_object::open_file(file).unwrap();
    obj.put(DataElement::new(tag, vr, value));
    obj.write_to_file(file).unwrap();
}

fn ds(v: &[f64]) -> PrimitiveValue {
    let s: Vec<String> = v.iter().map(|x| format!("{x}")).collect();
    PrimitiveValue::Strs(s.into())
}

fn expect(err: Result<Volume, String>, parts: &[&str]) {
    let e = err.expect_err("should fail");
    for p in parts {
        assert!(e.contains(p), "error {e:?} lacks {p:?}");
    }
}

#[test]
fn a_ct_series_reads_back_in_hounsfield_units() {
    let v = body();
    for rle in [false, true] {
        let dir = tempfile::tempdir().unwrap();
        let opts = SeriesOptions {
            rle,
            intercept: -1024,
            origin: [-90.0, -75.0, 12.5],
            ..SeriesOptions::default()
        };
        write_series(&v, dir.path(), &opts).unwrap();
        let back = open(dir.path()).unwrap();
        assert_eq!(back.data_type(), DataType::I16, "rle {rle}");
        same_voxels(&v, &back);
        for (a, b) in v.spacing().iter().zip(back.spacing()) {
            assert!(
                (a - b).abs() < 1e-4,
                "{:?} vs {:?}",
                v.spacing(),
                back.spacing()
            );
        }
    }
}

#[test]
fn slices_sort_by_position_not_by_file_name() {
    let v = body();
    let dir = tempfile::tempdir().unwrap();
    write_series(&v, dir.path(), &SeriesOptions::default()).unwrap();
    // Reverse the file names: the positions still give the order.
    let n = v.dims()[2];
    for z in 1..=n {
        let from = dir.path().join(format!("slice_{z:04}.dcm"));
        std::fs::rename(from, dir.path().join(format!("r_{:04}.dcm", n + 1 - z))).unwrap();
    }
    std::fs::write(dir.path().join("README.txt"), "not a slice").unwrap();
    same_voxels(&v, &open(dir.path()).unwrap());
}

#[test]
fn several_series_need_one_picked() {
    let v = body();
    let (a, b, both) = (
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
    );
    let uid_a = "1.2.3.4.1";
    let uid_b = "1.2.3.4.2";
    for (d, uid) in [(&a, uid_a), (&b, uid_b)] {
        let opts = SeriesOptions {
            series_uid: uid.into(),
            ..SeriesOptions::default()
        };
        write_series(&v, d.path(), &opts).unwrap();
        for e in std::fs::read_dir(d.path()).unwrap() {
            let p = e.unwrap().path();
            let name = format!("{uid}_{}", p.file_name().unwrap().to_string_lossy());
            std::fs::copy(&p, both.path().join(name)).unwrap();
        }
    }
    expect(
        open(both.path()),
        &["SeriesInstanceUID", uid_a, uid_b, "2 series"],
    );
    let picked = Volume::open_with(
        both.path(),
        &OpenOptions {
            series: Some(uid_b.into()),
            ..OpenOptions::default()
        },
    )
    .unwrap();
    same_voxels(&v, &picked);
    let none = Volume::open_with(
        both.path(),
        &OpenOptions {
            series: Some("9.9".into()),
            ..OpenOptions::default()
        },
    );
    expect(none.map_err(|e| e.to_string()), &["\"9.9\"", uid_a]);
}

#[test]
fn bad_series_are_clear_errors_naming_the_file_and_tag() {
    let v = body();
    let fresh = || {
        let d = tempfile::tempdir().unwrap();
        write_series(&v, d.path(), &SeriesOptions::default()).unwrap();
        d
    };
    let slice = |d: &tempfile::TempDir, z: usize| d.path().join(format!("slice_{z:04}.dcm"));

    let d = fresh();
    std::fs::remove_file(slice(&d, 5)).unwrap();
    expect(
        open(d.path()),
        &[
            "slice_0006.dcm",
            "ImagePositionPatient",
            "1 slice(s) missing",
            "slice_0004.dcm",
        ],
    );

    let d = fresh();
    let z = 5.0 * f64::from(v.spacing()[2]) + 1.3;
    edit(
        &slice(&d, 6),
        tags::IMAGE_POSITION_PATIENT,
        VR::DS,
        ds(&[0.0, 0.0, z]),
    );
    expect(
        open(d.path()),
        &["ImagePositionPatient", "uneven slice spacing"],
    );

    let d = fresh();
    edit(
        &slice(&d, 3),
        tags::IMAGE_POSITION_PATIENT,
        VR::DS,
        ds(&[0.0, 0.0, 0.0]),
    );
    expect(
        open(d.path()),
        &["ImagePositionPatient", "the same slice position"],
    );

    let d = fresh();
    edit(
        &slice(&d, 7),
        tags::IMAGE_ORIENTATION_PATIENT,
        VR::DS,
        ds(&[1.0, 0.0, 0.0, 0.0, 0.8, 0.6]),
    );
    expect(
        open(d.path()),
        &["slice_0007.dcm", "ImageOrientationPatient", "differs"],
    );

    let d = fresh();
    edit(
        &slice(&d, 2),
        tags::BITS_ALLOCATED,
        VR::US,
        PrimitiveValue::from(32u16),
    );
    expect(
        open(d.path()),
        &["slice_0002.dcm", "BitsAllocated (0028,0100)", "32"],
    );

    let d = fresh();
    let f = slice(&d, 4);
    let bytes = std::fs::read(&f).unwrap();
    std::fs::write(&f, &bytes[..bytes.len() - 300]).unwrap();
    expect(open(d.path()), &["slice_0004.dcm", "PixelData"]);

    let d = fresh();
    edit(
        &slice(&d, 8),
        tags::SERIES_INSTANCE_UID,
        VR::UI,
        PrimitiveValue::from("7.7"),
    );
    expect(open(d.path()), &["2 series", "7.7"]);
}

/// The byte offset of `tag`'s header in a little-endian file.
fn find_tag(bytes: &[u8], tag: dicom_core::Tag, vr: &[u8; 2]) -> usize {
    let mut pat = Vec::new();
    pat.extend(tag.group().to_le_bytes());
    pat.extend(tag.element().to_le_bytes());
    pat.extend(vr);
    bytes
        .windows(pat.len())
        .position(|w| w == pat)
        .expect("the tag in the file")
}

#[test]
fn lengths_past_the_end_and_damaged_rle_are_errors_not_allocations() {
    let v = body();
    // An element claiming 2 GB in a file of a few kilobytes: refused before dicom-rs
    // reserves the claim.
    let d = tempfile::tempdir().unwrap();
    write_series(&v, d.path(), &SeriesOptions::default()).unwrap();
    let f = d.path().join("slice_0003.dcm");
    let mut bytes = std::fs::read(&f).unwrap();
    let at = find_tag(&bytes, tags::PIXEL_DATA, b"OW");
    bytes[at + 8..at + 12].copy_from_slice(&0x7FFF_FFF0u32.to_le_bytes());
    std::fs::write(&f, &bytes).unwrap();
    expect(
        open(d.path()),
        &["slice_0003.dcm", "PixelData", "claims 2147483632 bytes"],
    );
    // Rows and columns claiming more pixels than the file holds.
    let d = tempfile::tempdir().unwrap();
    write_series(&v, d.path(), &SeriesOptions::default()).unwrap();
    edit(
        &d.path().join("slice_0002.dcm"),
        tags::ROWS,
        VR::US,
        PrimitiveValue::from(60000u16),
    );
    expect(
        open(d.path()),
        &["slice_0002.dcm", "PixelData", "do not fit"],
    );
    // RLE data cut short, and an RLE header naming segments past the data.
    let rle = SeriesOptions {
        rle: true,
        ..SeriesOptions::default()
    };
    let d = tempfile::tempdir().unwrap();
    write_series(&v, d.path(), &rle).unwrap();
    let f = d.path().join("slice_0004.dcm");
    let bytes = std::fs::read(&f).unwrap();
    std::fs::write(&f, &bytes[..bytes.len() - 200]).unwrap();
    expect(open(d.path()), &["slice_0004.dcm"]);
    let d = tempfile::tempdir().unwrap();
    write_series(&v, d.path(), &rle).unwrap();
    let f = d.path().join("slice_0005.dcm");
    let mut bytes = std::fs::read(&f).unwrap();
    // The first fragment: the item after the (empty) offset table item.
    let px = find_tag(&bytes, tags::PIXEL_DATA, b"OB");
    let frag = px + 12 + 8 + 8;
    assert_eq!(bytes[frag], 2, "two RLE segments");
    bytes[frag + 8..frag + 12].copy_from_slice(&60000u32.to_le_bytes());
    std::fs::write(&f, &bytes).unwrap();
    expect(
        open(d.path()),
        &[
            "slice_0005.dcm",
            "PixelData",
            "RLE data do not decode",
            "segment",
        ],
    );
}
