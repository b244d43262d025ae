//! Zarr v3 / OME-Zarr: round trips through the writer, level choice, and bad stores.

use std::path::Path;

use super::phantom::Phantom;
use super::zarr::{open, write_ome_zarr, CHUNK};
use super::{DataType, Endian, OpenOptions, RawSpec, Volume};

fn same_voxels(a: &Volume, b: &Volume) {
    assert_eq!(a.dims(), b.dims());
    assert_eq!(a.data_type(), b.data_type());
    let [nx, ny, nz] = a.dims();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                assert_eq!(
                    a.value(x, y, z).to_bits(),
                    b.value(x, y, z).to_bits(),
                    "voxel {x},{y},{z}"
                );
            }
        }
    }
}

fn write(v: &Volume, out: &Path) -> Vec<(u64, u64)> {
    let mut calls = Vec::new();
    write_ome_zarr(v, out, &mut |d, t| calls.push((d, t))).unwrap();
    calls
}

#[test]
fn a_raw_file_round_trips_through_zarr_bit_exact() {
    let dir = tempfile::tempdir().unwrap();
    // Not a multiple of the chunk on any axis, and more than one chunk on each.
    let body = Phantom::Body.generate_dims([CHUNK + 13, CHUNK + 3, 2 * CHUNK + 7]);
    let raw = dir.path().join("body.raw");
    let bytes: Vec<u8> = match body.data() {
        super::VoxelData::I16(v) => v.as_slice().iter().flat_map(|x| x.to_le_bytes()).collect(),
        _ => unreachable!("the body phantom is i16"),
    };
    std::fs::write(&raw, bytes).unwrap();
    let mut spec = RawSpec::new(body.dims(), DataType::I16);
    spec.endian = Endian::Little;
    spec.spacing = body.spacing();
    let mapped = Volume::open(&raw, Some(&spec)).unwrap();
    assert!(mapped.data().is_mapped());
    let out = dir.path().join("body.zarr");
    let calls = write(&mapped, &out);
    // One call per slab of every level, the last one complete.
    let (done, total) = *calls.last().unwrap();
    assert_eq!(done, total);
    assert_eq!(calls.len() as u64, total);
    let back = Volume::open(&out, None).unwrap();
    same_voxels(&mapped, &back);
    assert_eq!(back.spacing(), body.spacing());
    // The array itself opens too (store.zarr/path/to/array).
    same_voxels(&mapped, &Volume::open(&out.join("0"), None).unwrap());
    // No temporary folder is left beside the store.
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");
}

#[test]
fn every_type_round_trips_and_levels_halve() {
    let dir = tempfile::tempdir().unwrap();
    for (i, v) in [
        Phantom::SheppLogan.generate(70),
        Phantom::MarschnerLobb.generate(66),
        Phantom::Body.generate_dims([130, 96, 140]),
    ]
    .into_iter()
    .enumerate()
    {
        let out = dir.path().join(format!("v{i}.zarr"));
        write(&v, &out);
        same_voxels(&v, &open(&out, Some(0), None).unwrap());
        let l1 = open(&out, Some(1), None).unwrap();
        assert_eq!(l1.dims(), v.dims().map(|d| d.div_ceil(2)));
        assert_eq!(l1.spacing(), v.spacing().map(|s| s * 2.0));
        // A level is the 2×2×2 mean of the one above.
        let want = (0..8)
            .map(|c| v.value(2 + (c & 1), 4 + ((c >> 1) & 1), 6 + (c >> 2)))
            .sum::<f32>()
            / 8.0;
        let got = l1.value(1, 2, 3);
        let tol = if v.data_type() == DataType::F32 {
            1e-5
        } else {
            0.5
        };
        assert!((got - want).abs() <= tol, "{got} vs {want}");
        // The size chooses the finest level that fits.
        let fit = open(
            &out,
            None,
            Some(v.dims().iter().copied().max().unwrap().div_ceil(2)),
        )
        .unwrap();
        assert_eq!(fit.dims(), l1.dims());
        let e = open(&out, Some(9), None).unwrap_err().to_string();
        assert!(e.contains("no level 9"), "{e}");
        let via_opts = Volume::open_with(
            &out,
            &OpenOptions {
                level: Some(1),
                ..OpenOptions::default()
            },
        )
        .unwrap();
        assert_eq!(via_opts.dims(), l1.dims());
    }
}

#[test]
fn bad_stores_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let v = Phantom::Body.generate_dims([80, 70, 72]);
    let out = dir.path().join("b.zarr");
    write(&v, &out);
    // Writing over an existing store is refused and leaves it as it was.
    let e = write_ome_zarr(&v, &out, &mut |_, _| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("b.zarr") && e.contains("exists"), "{e}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    // A missing chunk.
    let chunk = out.join("0/c/1/0/1");
    assert!(chunk.is_file());
    std::fs::remove_file(&chunk).unwrap();
    let e = Volume::open(&out, None).unwrap_err().to_string();
    assert!(e.contains("0/c/1/0/1") && e.contains("missing"), "{e}");
    // A corrupt chunk.
    std::fs::write(&chunk, b"not zstd").unwrap();
    let e = Volume::open(&out, None).unwrap_err().to_string();
    assert!(e.contains("0/c/1/0/1"), "{e}");
    // A bad zarr.json, at the group and at an array.
    std::fs::write(
        out.join("1/zarr.json"),
        "{\"zarr_format\": 3, \"node_type\": \"array\"",
    )
    .unwrap();
    let e = open(&out, Some(1), None).unwrap_err().to_string();
    assert!(e.contains("1/zarr.json") && e.contains("not JSON"), "{e}");
    std::fs::write(
        out.join("1/zarr.json"),
        "{\"zarr_format\": 3, \"node_type\": \"array\", \"data_type\": \"int16\"}",
    )
    .unwrap();
    let e = open(&out, Some(1), None).unwrap_err().to_string();
    assert!(
        e.contains("1/zarr.json") && e.contains("Zarr v3 array"),
        "{e}"
    );
    std::fs::write(
        out.join("zarr.json"),
        "{\"zarr_format\": 3, \"node_type\": \"group\", \"attributes\": {}}",
    )
    .unwrap();
    let e = Volume::open(&out, None).unwrap_err().to_string();
    assert!(e.contains("zarr.json") && e.contains("multiscales"), "{e}");
    std::fs::write(out.join("zarr.json"), "[1, 2").unwrap();
    let e = Volume::open(&out, None).unwrap_err().to_string();
    assert!(
        e.contains("b.zarr/zarr.json") && e.contains("not JSON"),
        "{e}"
    );
}

#[test]
fn chunk_sizes_are_checked_before_anything_is_sized_by_them() {
    let dir = tempfile::tempdir().unwrap();
    let v = Phantom::Body.generate_dims([70, 20, 10]);
    let out = dir.path().join("z.zarr");
    write(&v, &out);
    // A zstd frame claiming another size than the chunk's.
    let chunk = out.join("0/c/0/0/1");
    let mut bytes = std::fs::read(&chunk).unwrap();
    let want = (CHUNK * CHUNK * CHUNK * 2) as u64;
    assert_eq!(super::zarr::zstd_content_size(&bytes), Some(want));
    let at = bytes
        .windows(4)
        .position(|w| w == (want as u32).to_le_bytes())
        .expect("the frame content size");
    bytes[at + 2] ^= 0x40;
    std::fs::write(&chunk, &bytes).unwrap();
    let e = Volume::open(&out, None).unwrap_err().to_string();
    assert!(
        e.contains("0/c/0/0/1") && e.contains("zstd frame claims"),
        "{e}"
    );
    // An uncompressed array whose chunk file is not one chunk long, and one without its
    // chunks at all (a shape of a billion voxels over no data is refused, not allocated).
    let raw = dir.path().join("raw.zarr");
    std::fs::create_dir_all(raw.join("c/0/0")).unwrap();
    let meta = |shape: &str| {
        format!(
            r#"{{"zarr_format":3,"node_type":"array","shape":{shape},"data_type":"uint8","chunk_grid":{{"name":"regular","configuration":{{"chunk_shape":[2,2,2]}}}},"chunk_key_encoding":{{"name":"default","configuration":{{"separator":"/"}}}},"fill_value":0,"codecs":[{{"name":"bytes"}}]}}"#
        )
    };
    std::fs::write(raw.join("zarr.json"), meta("[2,2,2]")).unwrap();
    std::fs::write(raw.join("c/0/0/0"), [1u8; 7]).unwrap();
    let e = Volume::open(&raw, None).unwrap_err().to_string();
    assert!(e.contains("c/0/0/0") && e.contains("the file has 7"), "{e}");
    std::fs::write(raw.join("c/0/0/0"), [1u8; 8]).unwrap();
    assert_eq!(Volume::open(&raw, None).unwrap().value(1, 1, 1), 1.0);
    std::fs::write(raw.join("zarr.json"), meta("[1000,1000,1000]")).unwrap();
    let e = Volume::open(&raw, None).unwrap_err().to_string();
    assert!(e.contains("missing"), "{e}");
}
