//! How the `dicom` and `zarr` seed inputs in `corpus/` were made (run with `--ignored` to
//! write them again): small valid inputs for the mutations to start from.

use std::path::Path;

use pofvr::volume::dicom_write::{write_series, SeriesOptions};
use pofvr::volume::phantom::Phantom;
use pofvr_fuzz::target::ZARR_FILE_MARK;

fn corpus(target: &str) -> std::path::PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("corpus")
        .join(target);
    std::fs::create_dir_all(&p).unwrap();
    p
}

/// Every file under `root`, packed as the `zarr` target reads them.
fn pack(root: &Path) -> Vec<u8> {
    fn walk(dir: &Path, root: &Path, out: &mut Vec<(String, Vec<u8>)>) {
        let mut entries: Vec<_> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        entries.sort();
        for p in entries {
            if p.is_dir() {
                walk(&p, root, out);
            } else {
                let name = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                out.push((name, std::fs::read(&p).unwrap()));
            }
        }
    }
    let mut files = Vec::new();
    walk(root, root, &mut files);
    let mut v = Vec::new();
    for (i, (name, bytes)) in files.into_iter().enumerate() {
        if i > 0 {
            v.extend_from_slice(ZARR_FILE_MARK);
        }
        v.extend_from_slice(name.as_bytes());
        v.push(b'\n');
        v.extend_from_slice(&bytes);
    }
    v
}

#[test]
#[ignore = "writes the seed corpus"]
fn write_dicom_and_zarr_seeds() {
    let v = Phantom::Body.generate_dims([8, 8, 3]);
    for (name, rle) in [("ct-explicit-le.dcm", false), ("ct-rle.dcm", true)] {
        let dir = tempfile::tempdir().unwrap();
        let opts = SeriesOptions {
            intercept: -1024,
            rle,
            ..SeriesOptions::default()
        };
        write_series(&v, dir.path(), &opts).unwrap();
        std::fs::copy(
            dir.path().join("slice_0001.dcm"),
            corpus("dicom").join(name),
        )
        .unwrap();
    }
    // An OME-Zarr image as `pofvr convert` writes it (zstd, two levels).
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s.zarr");
    let img = Phantom::Body.generate_dims([70, 6, 5]);
    pofvr::volume::zarr::write_ome_zarr(&img, &out, &mut |_, _| {}).unwrap();
    std::fs::write(corpus("zarr").join("ome-zstd.bin"), pack(&out)).unwrap();
    // A bare array with uncompressed chunks not aligned with the shape (2×4×3 of 4×4×4).
    let dir = tempfile::tempdir().unwrap();
    let meta = r#"{"zarr_format":3,"node_type":"array","shape":[4,4,4],"data_type":"int16","chunk_grid":{"name":"regular","configuration":{"chunk_shape":[2,4,3]}},"chunk_key_encoding":{"name":"default","configuration":{"separator":"/"}},"fill_value":0,"codecs":[{"name":"bytes","configuration":{"endian":"little"}}]}"#;
    std::fs::write(dir.path().join("zarr.json"), meta).unwrap();
    for (z, x) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
        let p = dir.path().join(format!("c/{z}/0/{x}"));
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        let bytes: Vec<u8> = (0..2 * 4 * 3)
            .flat_map(|i: i16| (i * 37 - 300 + 100 * (z * 2 + x) as i16).to_le_bytes())
            .collect();
        std::fs::write(&p, bytes).unwrap();
    }
    std::fs::write(corpus("zarr").join("array-raw.bin"), pack(dir.path())).unwrap();
}

/// The `dicom` target's neighbour slices written to `$POFVR_DICOM_FIXTURE` (for replaying a
/// finding with `pofvr info`: copy it there as `slice_0001.dcm`).
#[test]
#[ignore = "writes the dicom target's fixture for replays"]
fn write_dicom_fixture() {
    let Ok(dir) = std::env::var("POFVR_DICOM_FIXTURE") else {
        println!("skipped: POFVR_DICOM_FIXTURE is not set");
        return;
    };
    let v = Phantom::Body.generate_dims([8, 8, 3]);
    let opts = SeriesOptions {
        intercept: -1024,
        ..SeriesOptions::default()
    };
    write_series(&v, Path::new(&dir), &opts).unwrap();
}
