//! Integration tests of the volume readers through `Volume::open`: the same voxels written
//! as raw, NRRD, MetaImage and NIfTI read back identically, and the real volumes of
//! `shared/data` match their catalogue (ignored unless run with `--ignored`).

mod common;

use std::io::Write;
use std::path::PathBuf;

use flate2::write::{GzEncoder, ZlibEncoder};
use flate2::Compression;
use pofvr::volume::{DataType, Endian, RawSpec, Volume, VoxelData};

const DIMS: [usize; 3] = [17, 9, 6];

fn values() -> Vec<u16> {
    (0..DIMS.iter().product::<usize>())
        .map(|i| ((i * 7919) % 65536) as u16)
        .collect()
}

fn u16s(v: &Volume) -> Vec<u16> {
    match v.data() {
        VoxelData::U16(x) => x.as_slice().to_vec(),
        other => panic!("{}: expected u16, got {}", v.source(), other.data_type()),
    }
}

fn gzip(b: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::default());
    e.write_all(b).unwrap();
    e.finish().unwrap()
}

fn zlib(b: &[u8]) -> Vec<u8> {
    let mut e = ZlibEncoder::new(Vec::new(), Compression::default());
    e.write_all(b).unwrap();
    e.finish().unwrap()
}

/// A NIfTI-1 header (348 bytes) plus an empty extension flag, for uint16 data.
fn nifti_header(dims: [usize; 3], spacing: [f32; 3], big: bool) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    let i16b = |v: i16| {
        if big {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        }
    };
    let f32b = |v: f32| {
        if big {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        }
    };
    let i32b = if big {
        348i32.to_be_bytes()
    } else {
        348i32.to_le_bytes()
    };
    h[0..4].copy_from_slice(&i32b);
    let dim = [3, dims[0], dims[1], dims[2], 1, 1, 1, 1];
    for (i, d) in dim.iter().enumerate() {
        h[40 + 2 * i..42 + 2 * i].copy_from_slice(&i16b(i16::try_from(*d).unwrap()));
    }
    h[70..72].copy_from_slice(&i16b(512));
    h[72..74].copy_from_slice(&i16b(16));
    let pixdim = [1.0, spacing[0], spacing[1], spacing[2], 1.0, 1.0, 1.0, 1.0];
    for (i, d) in pixdim.iter().enumerate() {
        h[76 + 4 * i..80 + 4 * i].copy_from_slice(&f32b(*d));
    }
    h[108..112].copy_from_slice(&f32b(352.0));
    h[344..348].copy_from_slice(b"n+1\0");
    h
}

#[test]
fn every_format_gives_the_same_voxels() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let v = values();
    let le: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    let be: Vec<u8> = v.iter().flat_map(|x| x.to_be_bytes()).collect();
    let spacing = [0.5f32, 0.75, 1.5];
    let w = |name: &str, parts: &[&[u8]]| -> PathBuf {
        let p = d.join(name);
        std::fs::write(&p, parts.concat()).unwrap();
        p
    };
    let sizes = "sizes: 17 9 6\nspacings: 0.5 0.75 1.5\n";
    let raw_le = w("v_le.raw", &[&le]);
    w("v_be.raw", &[&be]);
    w("v.raw.gz", &[&gzip(&le)]);
    w("v.zraw", &[&zlib(&be)]);
    let files = vec![
        w(
            "attached.nrrd",
            &[
                format!("NRRD0004\ntype: ushort\ndimension: 3\n{sizes}endian: little\nencoding: raw\n\n").as_bytes(),
                &le,
            ],
        ),
        w(
            "attached_gz.nrrd",
            &[
                format!("NRRD0004\ntype: uint16\ndimension: 3\n{sizes}endian: big\nencoding: gzip\n\n").as_bytes(),
                &gzip(&be),
            ],
        ),
        w(
            "detached.nhdr",
            &[b"NRRD0004\ntype: unsigned short\ndimension: 3\nsizes: 17 9 6\nspace directions: (0.5,0,0) (0,0.75,0) (0,0,1.5)\nendian: big\nencoding: raw\ndata file: v_be.raw\n"],
        ),
        w(
            "detached_gz.nhdr",
            &[format!("NRRD0004\ntype: uint16_t\ndimension: 3\n{sizes}endian: little\nencoding: gz\ndatafile: v.raw.gz\n").as_bytes()],
        ),
        w(
            "v.mhd",
            &[b"ObjectType = Image\nNDims = 3\nDimSize = 17 9 6\nElementSpacing = 0.5 0.75 1.5\nElementType = MET_USHORT\nElementByteOrderMSB = False\nElementDataFile = v_le.raw\n"],
        ),
        w(
            "z.mhd",
            &[b"ObjectType = Image\nNDims = 3\nDimSize = 17 9 6\nElementSpacing = 0.5 0.75 1.5\nElementType = MET_USHORT\nBinaryDataByteOrderMSB = True\nCompressedData = True\nElementDataFile = v.zraw\n"],
        ),
        w(
            "v.mha",
            &[
                b"ObjectType = Image\nNDims = 3\nDimSize = 17 9 6\nElementSpacing = 0.5 0.75 1.5\nElementType = MET_USHORT\nElementDataFile = LOCAL\n",
                &le,
            ],
        ),
        w("v.nii", &[&nifti_header(DIMS, spacing, false), &le]),
        w("be.nii", &[&nifti_header(DIMS, spacing, true), &be]),
        w("v.nii.gz", &[&gzip(&[nifti_header(DIMS, spacing, false), le.clone()].concat())]),
    ];
    let spec = RawSpec {
        spacing,
        ..RawSpec::new(DIMS, DataType::U16)
    };
    let reference = Volume::open(&raw_le, Some(&spec)).unwrap();
    assert_eq!(u16s(&reference), v);
    let big = RawSpec {
        endian: Endian::Big,
        ..spec.clone()
    };
    assert_eq!(
        u16s(&Volume::open(&d.join("v_be.raw"), Some(&big)).unwrap()),
        v
    );
    for f in &files {
        let vol = Volume::open(f, None).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(vol.dims(), DIMS, "{}", f.display());
        assert_eq!(vol.spacing(), spacing, "{}", f.display());
        assert_eq!(vol.data_type(), DataType::U16, "{}", f.display());
        assert!(
            u16s(&vol) == v,
            "{}: voxels differ from the raw file",
            f.display()
        );
        assert_eq!(vol.source(), f.display().to_string());
    }
    // Little-endian data at an aligned offset are served from the map, not copied.
    for name in ["v_le.raw", "v.mhd", "v.nii"] {
        let vol = Volume::open(&d.join(name), (name == "v_le.raw").then_some(&spec)).unwrap();
        assert!(vol.data().is_mapped(), "{name} should be memory-mapped");
    }
}

#[test]
fn bad_inputs_through_open_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("missing.nrrd", b"NRRD0004\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n\0\0\0\0\0\0\0\0".to_vec(), "header field \"type\": required field is missing"),
        ("double.nrrd", b"NRRD0004\ntype: double\ndimension: 3\nsizes: 1 1 1\nendian: little\nencoding: raw\n\n\0\0\0\0\0\0\0\0".to_vec(), "unsupported type \"double\""),
        ("hex.nrrd", b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: hex\n\n00".to_vec(), "unsupported encoding \"hex\""),
        ("dim2.nrrd", b"NRRD0004\ntype: uint8\ndimension: 2\nsizes: 1 1\nencoding: raw\n\n0".to_vec(), "unsupported dimension \"2\""),
        ("trunc.mha", b"NDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n1234567".to_vec(), "size mismatch"),
        ("trunc_gz.nrrd", [b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 8 8 8\nencoding: gzip\n\n".as_slice(), &gzip(&[7u8; 512])[..20]].concat(), "compressed data"),
    ];
    for (name, bytes, want) in cases {
        let p = d.join(name);
        std::fs::write(&p, bytes).unwrap();
        let msg = Volume::open(&p, None).unwrap_err().to_string();
        assert!(
            msg.contains(&p.display().to_string()),
            "{msg:?} does not name {}",
            p.display()
        );
        assert!(msg.contains(want), "{msg:?} lacks {want:?}");
    }
}

const REAL: [&str; 6] = [
    "neghip",
    "ironprot",
    "hydrogen",
    "headsq_quarter",
    "lidc2_ct_chest",
    "ch2better_mri",
];

#[test]
#[ignore = "needs ../shared/data (real volumes)"]
fn real_volumes_nrrd_and_mhd_match_the_catalogue() {
    let data = common::shared_data();
    for name in REAL {
        let dir = data.join(name);
        let stats: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("stats.json")).unwrap())
                .unwrap();
        let dims: Vec<usize> = stats["dims"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_u64().unwrap() as usize)
            .collect();
        let spacing: Vec<f32> = stats["spacing"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap() as f32)
            .collect();
        let dtype: DataType = stats["dtype"].as_str().unwrap().parse().unwrap();
        let nrrd =
            Volume::open(&dir.join(format!("{name}.nhdr")), None).unwrap_or_else(|e| panic!("{e}"));
        let mhd =
            Volume::open(&dir.join(format!("{name}.mhd")), None).unwrap_or_else(|e| panic!("{e}"));
        for vol in [&nrrd, &mhd] {
            assert_eq!(vol.dims().to_vec(), dims, "{}", vol.source());
            assert_eq!(vol.spacing().to_vec(), spacing, "{}", vol.source());
            assert_eq!(vol.data_type(), dtype, "{}", vol.source());
            assert!(vol.data().is_mapped(), "{}", vol.source());
        }
        let same = pofvr::with_voxels!(nrrd.data(), a => {
            let b: Vec<u8> = pofvr::with_voxels!(mhd.data(), b => bytemuck::cast_slice(b).to_vec());
            bytemuck::cast_slice::<_, u8>(a) == b.as_slice()
        });
        assert!(same, "{name}: NRRD and MHD voxels differ");
        let (min, max) = pofvr::with_voxels!(nrrd.data(), v => v.iter().fold((f32::MAX, f32::MIN), |(lo, hi), x| {
            use pofvr::volume::Voxel;
            (lo.min(x.to_f32()), hi.max(x.to_f32()))
        }));
        assert_eq!(f64::from(min), stats["min"].as_f64().unwrap(), "{name} min");
        assert_eq!(f64::from(max), stats["max"].as_f64().unwrap(), "{name} max");
        println!("{name}: {dims:?} {dtype} {spacing:?}, NRRD = MHD, range {min}..{max}");
    }
}

#[test]
#[ignore = "needs ../shared/data (real volumes)"]
fn real_nifti_equals_its_raw_file() {
    let data = common::shared_data();
    let dir = data.join("ch2better_mri");
    let nii =
        Volume::open(&dir.join("source/ch2better.nii.gz"), None).unwrap_or_else(|e| panic!("{e}"));
    let raw = Volume::open(&dir.join("ch2better_mri.nhdr"), None).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(nii.dims(), raw.dims());
    assert_eq!(nii.spacing(), raw.spacing());
    assert_eq!(
        nii.data_type(),
        DataType::U8,
        "scl_slope NaN must keep the stored type"
    );
    let (VoxelData::U8(a), VoxelData::U8(b)) = (nii.data(), raw.data()) else {
        panic!("expected u8 data");
    };
    assert!(
        a.as_slice() == b.as_slice(),
        "NIfTI voxels differ from the raw file"
    );
}
