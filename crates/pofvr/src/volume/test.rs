//! Unit tests of the volume readers: round trips of small hand-written files, and every
//! kind of bad input with the text of its message.

use std::io::Write;
use std::path::{Path, PathBuf};

use flate2::write::{GzEncoder, ZlibEncoder};
use flate2::Compression;

use super::{nifti, nrrd, raw, DataType, Endian, RawSpec, Volume, VolumeError, VoxelData};

const DIMS: [usize; 3] = [5, 4, 3];
const N: usize = 60;

fn u16_values() -> Vec<u16> {
    (0..N).map(|i| (i as u16) * 1013 + 7).collect()
}
fn i16_values() -> Vec<i16> {
    (0..N).map(|i| (i as i16) * 37 - 1000).collect()
}
fn u8_values() -> Vec<u8> {
    (0..N).map(|i| (i * 7 % 256) as u8).collect()
}
fn f32_values() -> Vec<f32> {
    (0..N).map(|i| i as f32 * 0.25 - 3.5).collect()
}

fn le<T: bytemuck::Pod>(v: &[T]) -> Vec<u8> {
    bytemuck::cast_slice(v).to_vec()
}
fn be16(v: &[u16]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_be_bytes()).collect()
}
fn be_f32(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_be_bytes()).collect()
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

fn write(dir: &Path, name: &str, parts: &[&[u8]]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, parts.concat()).unwrap();
    p
}

fn as_u8(v: &Volume) -> Vec<u8> {
    match v.data() {
        VoxelData::U8(x) => x.as_slice().to_vec(),
        other => panic!("expected u8, got {}", other.data_type()),
    }
}
fn as_u16(v: &Volume) -> Vec<u16> {
    match v.data() {
        VoxelData::U16(x) => x.as_slice().to_vec(),
        other => panic!("expected u16, got {}", other.data_type()),
    }
}
fn as_i16(v: &Volume) -> Vec<i16> {
    match v.data() {
        VoxelData::I16(x) => x.as_slice().to_vec(),
        other => panic!("expected i16, got {}", other.data_type()),
    }
}
fn as_f32(v: &Volume) -> Vec<f32> {
    match v.data() {
        VoxelData::F32(x) => x.as_slice().to_vec(),
        other => panic!("expected f32, got {}", other.data_type()),
    }
}

/// The error's message, checked to name `file`.
fn err_text(r: Result<Volume, VolumeError>, file: &Path) -> String {
    let e = r.expect_err("expected an error");
    let msg = e.to_string();
    let name = file.file_name().unwrap().to_string_lossy();
    assert!(msg.contains(&*name), "message {msg:?} does not name {name}");
    msg
}

fn assert_contains(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "message {msg:?} lacks {p:?}");
    }
}

// ---------------------------------------------------------------- raw

#[test]
fn raw_shorter_and_longer_than_dims_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let spec = RawSpec::new(DIMS, DataType::U16);
    let bytes = le(&u16_values());
    let short = write(dir.path(), "short.raw", &[&bytes[..bytes.len() - 1]]);
    let msg = err_text(raw::open(&short, &spec), &short);
    assert_contains(&msg, &["size mismatch", "expected 120", "got 119"]);
    let long = write(dir.path(), "long.raw", &[&bytes, &[0]]);
    let msg = err_text(raw::open(&long, &spec), &long);
    assert_contains(&msg, &["size mismatch", "expected 120", "got 121"]);
    let ok = write(dir.path(), "ok.raw", &[&bytes]);
    let v = raw::open(&ok, &spec).unwrap();
    assert!(v.data().is_mapped());
    assert_eq!(as_u16(&v), u16_values());
}

#[test]
fn raw_zero_and_overflowing_dims_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "v.raw", &[&[0u8; 8]]);
    let msg = err_text(raw::open(&p, &RawSpec::new([2, 0, 4], DataType::U8)), &p);
    assert_contains(&msg, &["bad dimensions", "at least 1"]);
    let big = 1usize << 40;
    let msg = err_text(
        raw::open(&p, &RawSpec::new([big, big, big], DataType::U8)),
        &p,
    );
    assert_contains(&msg, &["bad dimensions"]);
    let msg = err_text(
        raw::open(&p, &RawSpec::new([1 << 25, 1, 1], DataType::U8)),
        &p,
    );
    assert_contains(&msg, &["larger than 16777216"]);
}

#[test]
fn unknown_dtype_string_is_rejected() {
    let e = "u12".parse::<DataType>().unwrap_err();
    assert_contains(&e, &["unknown data type \"u12\"", "u8, u16, i16, f32"]);
    assert_eq!("UShort".parse::<DataType>().unwrap(), DataType::U16);
}

#[test]
fn raw_nan_and_inf_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    for (name, bad, shown) in [
        ("nan.raw", f32::NAN, "NaN"),
        ("inf.raw", f32::INFINITY, "inf"),
    ] {
        let mut v = f32_values();
        v[17] = bad;
        let p = write(dir.path(), name, &[&le(&v)]);
        let msg = err_text(raw::open(&p, &RawSpec::new(DIMS, DataType::F32)), &p);
        assert_contains(&msg, &["non-finite value", shown, "index 17"]);
    }
}

#[test]
fn raw_from_reader_rejects_short_and_long_streams() {
    let p = Path::new("stream.gz");
    let spec = RawSpec::new(DIMS, DataType::U8);
    let msg = err_text(raw::from_reader(p, &[0u8; 59][..], &spec), p);
    assert_contains(&msg, &["after 59 of 60 bytes", "truncated"]);
    let msg = err_text(raw::from_reader(p, &[0u8; 64][..], &spec), p);
    assert_contains(&msg, &["expected 60", "got 64"]);
}

// ---------------------------------------------------------------- NRRD

fn nrrd_header(fields: &str) -> Vec<u8> {
    format!("NRRD0004\n{fields}\n").into_bytes()
}

#[test]
fn nrrd_attached_raw_u8_is_mapped() {
    let dir = tempfile::tempdir().unwrap();
    let fields = "type: uchar\ndimension: 3\nsizes: 5 4 3\nspacings: 0.5 1 2\nencoding: raw\nsome key:=some: value\n";
    let pad = (8 - (fields.len() + 12) % 8) % 8;
    let h = nrrd_header(&format!("#{}\n{fields}", " ".repeat(pad)));
    assert_eq!(
        h.len() % 8,
        0,
        "keep the offset aligned so the data can be mapped"
    );
    let p = write(dir.path(), "a.nrrd", &[&h, &u8_values()]);
    let v = nrrd::open(&p).unwrap();
    assert_eq!(v.dims(), DIMS);
    assert_eq!(v.spacing(), [0.5, 1.0, 2.0]);
    assert_eq!(as_u8(&v), u8_values());
    assert!(v.data().is_mapped());
    assert_eq!(v.source(), p.display().to_string());
}

#[test]
fn nrrd_attached_raw_at_odd_offset_and_crlf() {
    let dir = tempfile::tempdir().unwrap();
    let h = b"NRRD0005\r\ntype: unsigned short\r\ndimension: 3\r\nsizes: 5 4 3\r\nendian: little\r\nencoding: raw\r\n\r\n";
    let p = write(dir.path(), "odd.nrrd", &[h, &le(&u16_values())]);
    let v = nrrd::open(&p).unwrap();
    assert_eq!(as_u16(&v), u16_values());
    assert_eq!(v.spacing(), [1.0; 3]);
}

#[test]
fn nrrd_detached_big_endian_u16_with_space_directions() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("sub")).unwrap();
    write(&dir.path().join("sub"), "d.raw", &[&be16(&u16_values())]);
    let h = nrrd_header(
        "Type: uint16\nDimension: 3\nspace: left-posterior-superior\nSizes: 5 4 3\nspace directions: (0,0.5,0) (3,4,0) (0,0,-2.5)\nEndian: BIG\nEncoding: raw\ndata file: sub/d.raw",
    );
    let p = write(dir.path(), "d.nhdr", &[&h]);
    let v = nrrd::open(&p).unwrap();
    assert_eq!(v.spacing(), [0.5, 5.0, 2.5]);
    assert_eq!(as_u16(&v), u16_values());
    assert_eq!(v.source(), p.display().to_string());
}

#[test]
fn nrrd_gzip_attached_and_detached() {
    let dir = tempfile::tempdir().unwrap();
    let h =
        nrrd_header("type: short\ndimension: 3\nsizes: 5 4 3\nendian: little\nencoding: gzip\n");
    let p = write(dir.path(), "g.nrrd", &[&h, &gzip(&le(&i16_values()))]);
    let v = nrrd::open(&p).unwrap();
    assert_eq!(as_i16(&v), i16_values());
    assert!(!v.data().is_mapped());

    write(dir.path(), "g.raw.gz", &[&gzip(&be_f32(&f32_values()))]);
    let h = nrrd_header(
        "type: float\ndimension: 3\nsizes: 5 4 3\nendian: big\nencoding: gz\ndatafile: g.raw.gz",
    );
    let p = write(dir.path(), "g.nhdr", &[&h]);
    assert_eq!(as_f32(&nrrd::open(&p).unwrap()), f32_values());
}

#[test]
fn nrrd_gzip_of_several_members_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let b = le(&u16_values());
    let h =
        nrrd_header("type: ushort\ndimension: 3\nsizes: 5 4 3\nendian: little\nencoding: gzip\n");
    let p = write(
        dir.path(),
        "m.nrrd",
        &[&h, &gzip(&b[..50]), &gzip(&b[50..])],
    );
    assert_eq!(as_u16(&nrrd::open(&p).unwrap()), u16_values());
}

#[test]
fn nrrd_byte_skip_and_line_skip() {
    let dir = tempfile::tempdir().unwrap();
    let data = le(&u16_values());
    write(
        dir.path(),
        "s.raw",
        &[b"first line\nsecond\n", b"XYZ", &data],
    );
    let h = nrrd_header(
        "type: uint16\ndimension: 3\nsizes: 5 4 3\nendian: little\nencoding: raw\nline skip: 2\nbyte skip: 3\ndata file: s.raw",
    );
    let p = write(dir.path(), "s.nhdr", &[&h]);
    assert_eq!(as_u16(&nrrd::open(&p).unwrap()), u16_values());

    write(dir.path(), "e.raw", &[b"any junk of any length", &data]);
    let h = nrrd_header("type: uint16\ndimension: 3\nsizes: 5 4 3\nendian: little\nencoding: raw\nbyte skip: -1\ndata file: e.raw");
    let p = write(dir.path(), "e.nhdr", &[&h]);
    assert_eq!(as_u16(&nrrd::open(&p).unwrap()), u16_values());

    // With gzip, the byte skip applies to the decompressed bytes.
    write(
        dir.path(),
        "z.gz",
        &[&gzip(&[b"1234567".as_slice(), &data].concat())],
    );
    let h = nrrd_header("type: uint16\ndimension: 3\nsizes: 5 4 3\nendian: little\nencoding: gzip\nbyte skip: 7\ndata file: z.gz");
    let p = write(dir.path(), "z.nhdr", &[&h]);
    assert_eq!(as_u16(&nrrd::open(&p).unwrap()), u16_values());

    let h = nrrd_header("type: uint16\ndimension: 3\nsizes: 5 4 3\nendian: little\nencoding: gzip\nbyte skip: -1\ndata file: z.gz");
    let p = write(dir.path(), "zbad.nhdr", &[&h]);
    let msg = err_text(nrrd::open(&p), &p);
    assert_contains(&msg, &["byte skip", "only allowed for uncompressed"]);

    write(
        dir.path(),
        "few_lines.raw",
        &[b"one\ntwo\nno newline after this"],
    );
    let h = nrrd_header("type: uint16\ndimension: 3\nsizes: 5 4 3\nendian: little\nencoding: raw\nline skip: 5\ndata file: few_lines.raw");
    let p = write(dir.path(), "ls.nhdr", &[&h]);
    let msg = err_text(nrrd::open(&p), &p);
    assert_contains(&msg, &["line skip", "found only 2 of 5 lines"]);
}

#[test]
fn nrrd_every_type_spelling_is_understood() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        ("uchar", DataType::U8),
        ("unsigned char", DataType::U8),
        ("uint8", DataType::U8),
        ("uint8_t", DataType::U8),
        ("short", DataType::I16),
        ("short int", DataType::I16),
        ("signed short", DataType::I16),
        ("signed  short int", DataType::I16),
        ("int16", DataType::I16),
        ("int16_t", DataType::I16),
        ("ushort", DataType::U16),
        ("unsigned short", DataType::U16),
        ("unsigned short int", DataType::U16),
        ("uint16", DataType::U16),
        ("uint16_t", DataType::U16),
        ("float", DataType::F32),
        ("FLOAT32", DataType::F32),
    ];
    for (spelling, want) in cases {
        let h = nrrd_header(&format!(
            "type: {spelling}\ndimension: 3\nsizes: 1 1 1\nendian: little\nencoding: raw\ndata file: x.raw"
        ));
        let p = write(dir.path(), "t.nhdr", &[&h]);
        assert_eq!(nrrd::read_header(&p).unwrap().dtype, want, "{spelling}");
    }
}

#[test]
fn nrrd_missing_required_fields_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let full = [
        "type: uint16",
        "dimension: 3",
        "sizes: 5 4 3",
        "endian: little",
        "encoding: raw",
    ];
    for (i, field) in ["type", "dimension", "sizes", "endian", "encoding"]
        .into_iter()
        .enumerate()
    {
        let mut lines: Vec<&str> = full.to_vec();
        lines.remove(i);
        lines.push("data file: x.raw");
        let p = write(
            dir.path(),
            &format!("no_{field}.nhdr"),
            &[&nrrd_header(&lines.join("\n"))],
        );
        let msg = err_text(nrrd::open(&p), &p);
        assert_contains(
            &msg,
            &[
                &format!("header field {field:?}"),
                "required field is missing",
            ],
        );
    }
    // One-byte types need no endian.
    let h = nrrd_header("type: uint8\ndimension: 3\nsizes: 5 4 3\nencoding: raw\n");
    let p = write(dir.path(), "u8.nrrd", &[&h, &u8_values()]);
    assert_eq!(as_u8(&nrrd::open(&p).unwrap()), u8_values());
}

#[test]
fn nrrd_unsupported_fields_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let base = |ty: &str, dim: &str, enc: &str, extra: &str| {
        nrrd_header(&format!(
            "type: {ty}\ndimension: {dim}\nsizes: 5 4 3\nendian: little\nencoding: {enc}\n{extra}data file: x.raw"
        ))
    };
    let cases: Vec<(&str, Vec<u8>, Vec<&str>)> = vec![
        ("double", base("double", "3", "raw", ""), vec!["\"type\"", "unsupported type \"double\""]),
        ("int32", base("int", "3", "raw", ""), vec!["\"type\"", "unsupported type \"int\""]),
        ("ascii", base("uint8", "3", "ascii", ""), vec!["\"encoding\"", "unsupported encoding \"ascii\""]),
        ("bzip2", base("uint8", "3", "bzip2", ""), vec!["\"encoding\"", "unsupported encoding \"bzip2\""]),
        ("dim4", base("uint8", "4", "raw", ""), vec!["\"dimension\"", "unsupported dimension \"4\""]),
        ("sizes2", nrrd_header("type: uint8\ndimension: 3\nsizes: 5 4\nencoding: raw\ndata file: x.raw"), vec!["\"sizes\"", "expected 3 values, got 2"]),
        ("sizesneg", nrrd_header("type: uint8\ndimension: 3\nsizes: 5 -4 3\nencoding: raw\ndata file: x.raw"), vec!["\"sizes\"", "cannot parse \"-4\""]),
        ("none", base("uint8", "3", "raw", "space directions: none (1,0,0) (0,1,0)\n"), vec!["\"space directions\"", "\"none\" entry"]),
        ("twodirs", base("uint8", "3", "raw", "space directions: (1,0,0) (0,1,0)\n"), vec!["\"space directions\"", "expected 3 vectors, got 2"]),
        ("nanspacing", base("uint8", "3", "raw", "spacings: 1 NaN 1\n"), vec!["\"spacings\"", "NaN entries"]),
        ("disagree", base("uint8", "3", "raw", "spacings: 1 1 1\nspace directions: (2,0,0) (0,1,0) (0,0,1)\n"), vec!["\"spacings\"", "disagree"]),
        ("dup", base("uint8", "3", "raw", "type: uint8\n"), vec!["\"type\"", "more than once"]),
        ("badskip", base("uint8", "3", "raw", "byte skip: -2\n"), vec!["\"byte skip\"", "expected -1 or a byte count"]),
        ("badendian", nrrd_header("type: uint16\ndimension: 3\nsizes: 5 4 3\nendian: middle\nencoding: raw\ndata file: x.raw"), vec!["\"endian\"", "unknown value \"middle\""]),
        ("noline", nrrd_header("type: uint8\ndimension: 3\nsizes: 5 4 3\nencoding: raw\nthis is not a field\ndata file: x.raw"), vec!["line 6 is neither a field nor a comment"]),
    ];
    for (name, header, want) in cases {
        let p = write(dir.path(), &format!("{name}.nhdr"), &[&header]);
        let msg = err_text(nrrd::open(&p), &p);
        assert_contains(&msg, &want);
    }
    let h = nrrd_header(
        "type: uint8\ndimension: 3\nsizes: 5 4 3\nencoding: raw\ndata file: LIST\na.raw\nb.raw",
    );
    let p = write(dir.path(), "multi.nhdr", &[&h]);
    assert_contains(
        &err_text(nrrd::open(&p), &p),
        &["\"data file\"", "multi-file data"],
    );
    let h = nrrd_header(
        "type: uint8\ndimension: 3\nsizes: 5 4 3\nencoding: raw\ndata file: slice%03d.raw 1 3 1 2",
    );
    let p = write(dir.path(), "pattern.nhdr", &[&h]);
    assert_contains(
        &err_text(nrrd::open(&p), &p),
        &["\"data file\"", "multi-file data"],
    );
}

#[test]
fn nrrd_bad_magic_and_missing_data_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "m.nrrd", &[b"P6\n3 3\n255\n"]);
    assert_contains(
        &err_text(nrrd::open(&p), &p),
        &["\"magic\"", "not a NRRD file"],
    );
    let p = write(dir.path(), "bin.nrrd", &[&[0xff, 0xfe, 0x00, b'\n']]);
    assert_contains(&err_text(nrrd::open(&p), &p), &["not text"]);
    let p = write(
        dir.path(),
        "nodata.nrrd",
        &[b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw"],
    );
    assert_contains(&err_text(nrrd::open(&p), &p), &["\"data file\"", "no data"]);
    let p = dir.path().join("absent.nhdr");
    assert_contains(&err_text(nrrd::open(&p), &p), &["No such file"]);
    let h =
        nrrd_header("type: uint8\ndimension: 3\nsizes: 5 4 3\nencoding: raw\ndata file: gone.raw");
    let p = write(dir.path(), "gone.nhdr", &[&h]);
    let e = nrrd::open(&p).unwrap_err().to_string();
    assert_contains(&e, &["gone.raw", "No such file"]);
}

#[test]
fn nrrd_raw_size_and_dims_errors() {
    let dir = tempfile::tempdir().unwrap();
    let h =
        nrrd_header("type: uint16\ndimension: 3\nsizes: 5 4 3\nendian: little\nencoding: raw\n");
    let data = le(&u16_values());
    let p = write(dir.path(), "short.nrrd", &[&h, &data[..100]]);
    let msg = err_text(nrrd::open(&p), &p);
    assert_contains(
        &msg,
        &[
            "size mismatch",
            &format!("expected {}", h.len() + 120),
            &format!("got {}", h.len() + 100),
        ],
    );
    let p = write(dir.path(), "long.nrrd", &[&h, &data, b"\n"]);
    assert_contains(
        &err_text(nrrd::open(&p), &p),
        &["size mismatch", &format!("got {}", h.len() + 121)],
    );

    let h = nrrd_header("type: uint8\ndimension: 3\nsizes: 5 0 3\nencoding: raw\n");
    let p = write(dir.path(), "zero.nrrd", &[&h]);
    assert_contains(
        &err_text(nrrd::open(&p), &p),
        &["bad dimensions [5, 0, 3]", "at least 1"],
    );
    let h = nrrd_header(
        "type: uint8\ndimension: 3\nsizes: 4294967296 4294967296 4294967296\nencoding: raw\n",
    );
    let p = write(dir.path(), "huge.nrrd", &[&h]);
    assert_contains(
        &err_text(nrrd::open(&p), &p),
        &["bad dimensions", "overflows"],
    );
}

#[test]
fn nrrd_truncated_and_corrupt_gzip_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let h =
        nrrd_header("type: uint16\ndimension: 3\nsizes: 5 4 3\nendian: little\nencoding: gzip\n");
    let z = gzip(&le(&u16_values()));
    for cut in [z.len() / 2, z.len() - 4, z.len() - 1] {
        let p = write(dir.path(), &format!("cut{cut}.nrrd"), &[&h, &z[..cut]]);
        let msg = err_text(nrrd::open(&p), &p);
        assert_contains(&msg, &["compressed data"]);
    }
    // Valid gzip of too few voxels says how many bytes it found.
    let b = le(&u16_values());
    let p = write(dir.path(), "few.nrrd", &[&h, &gzip(&b[..90])]);
    assert_contains(
        &err_text(nrrd::open(&p), &p),
        &["compressed data", "after 90 of 120 bytes", "truncated"],
    );
    let p = write(
        dir.path(),
        "many.nrrd",
        &[&h, &gzip(&[b.as_slice(), &[1, 2]].concat())],
    );
    assert_contains(
        &err_text(nrrd::open(&p), &p),
        &["size mismatch", "expected 120", "got 122"],
    );
    let mut bad = z.clone();
    let mid = bad.len() / 2;
    bad[mid] ^= 0xff;
    bad[mid + 1] ^= 0x55;
    let p = write(dir.path(), "corrupt.nrrd", &[&h, &bad]);
    assert!(nrrd::open(&p).is_err());
}

#[test]
fn nrrd_nan_in_float_data_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let mut v = f32_values();
    v[3] = f32::NEG_INFINITY;
    let h =
        nrrd_header("type: float\ndimension: 3\nsizes: 5 4 3\nendian: little\nencoding: gzip\n");
    let p = write(dir.path(), "inf.nrrd", &[&h, &gzip(&le(&v))]);
    assert_contains(
        &err_text(nrrd::open(&p), &p),
        &["non-finite value -inf at voxel index 3"],
    );
}

// ---------------------------------------------------------------- MetaImage

fn mhd(fields: &str) -> Vec<u8> {
    format!("ObjectType = Image\nNDims = 3\n{fields}\n").into_bytes()
}

#[test]
fn mhd_detached_raw_is_mapped() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "v.raw", &[&le(&u16_values())]);
    let p = write(
        dir.path(),
        "v.mhd",
        &[&mhd("DimSize = 5 4 3\nElementSpacing = 0.5 0.25 2\nElementType = MET_USHORT\nBinaryDataByteOrderMSB = False\nElementDataFile = v.raw")],
    );
    let v = super::metaimage::open(&p).unwrap();
    assert_eq!(v.dims(), DIMS);
    assert_eq!(v.spacing(), [0.5, 0.25, 2.0]);
    assert_eq!(as_u16(&v), u16_values());
    assert!(v.data().is_mapped());
    assert_eq!(v.source(), p.display().to_string());
}

#[test]
fn mhd_big_endian_and_element_size() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "b.raw", &[&be16(&u16_values())]);
    let p = write(
        dir.path(),
        "b.mhd",
        &[&mhd("dimsize = 5 4 3\nElementSize = 3 2 1\nElementType = MET_USHORT\nElementByteOrderMSB = True\nElementDataFile = b.raw")],
    );
    let v = super::metaimage::open(&p).unwrap();
    assert_eq!(v.spacing(), [3.0, 2.0, 1.0]);
    assert_eq!(as_u16(&v), u16_values());
    let p = write(
        dir.path(),
        "c.mhd",
        &[&mhd("DimSize = 5 4 3\nElementType = MET_USHORT\nElementByteOrderMSB = True\nBinaryDataByteOrderMSB = False\nElementDataFile = b.raw")],
    );
    assert_contains(
        &err_text(super::metaimage::open(&p), &p),
        &["\"ElementByteOrderMSB\"", "disagrees"],
    );
}

#[test]
fn mhd_zraw_and_mha_local() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "z.zraw", &[&zlib(&le(&f32_values()))]);
    let p = write(
        dir.path(),
        "z.mhd",
        &[&mhd("DimSize = 5 4 3\nElementType = MET_FLOAT\nCompressedData = True\nElementDataFile = z.zraw")],
    );
    assert_eq!(as_f32(&super::metaimage::open(&p).unwrap()), f32_values());

    let h = mhd("DimSize = 5 4 3\nElementSpacing = 1 1 1.5\nElementType = MET_SHORT\nElementDataFile = LOCAL");
    let p = write(dir.path(), "l.mha", &[&h, &le(&i16_values())]);
    let v = super::metaimage::open(&p).unwrap();
    assert_eq!(as_i16(&v), i16_values());
    assert_eq!(v.spacing(), [1.0, 1.0, 1.5]);

    let h = mhd("DimSize = 5 4 3\nElementType = MET_UCHAR\nCompressedData = True\nCompressedDataSize = 99\nElementDataFile = LOCAL");
    let p = write(dir.path(), "lz.mha", &[&h, &zlib(&u8_values())]);
    assert_eq!(as_u8(&super::metaimage::open(&p).unwrap()), u8_values());
}

#[test]
fn mhd_header_size() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "h.raw", &[&[9u8; 11], &u8_values()]);
    let p = write(
        dir.path(),
        "h.mhd",
        &[&mhd(
            "DimSize = 5 4 3\nElementType = MET_UCHAR\nHeaderSize = 11\nElementDataFile = h.raw",
        )],
    );
    assert_eq!(as_u8(&super::metaimage::open(&p).unwrap()), u8_values());
    let p = write(
        dir.path(),
        "e.mhd",
        &[&mhd(
            "DimSize = 5 4 3\nElementType = MET_UCHAR\nHeaderSize = -1\nElementDataFile = h.raw",
        )],
    );
    assert_eq!(as_u8(&super::metaimage::open(&p).unwrap()), u8_values());
    let h =
        mhd("DimSize = 5 4 3\nElementType = MET_UCHAR\nHeaderSize = -1\nElementDataFile = LOCAL");
    let p = write(dir.path(), "e.mha", &[&h, b"padding", &u8_values()]);
    assert_eq!(as_u8(&super::metaimage::open(&p).unwrap()), u8_values());
    // The voxels cannot overlap the header.
    let p = write(dir.path(), "o.mha", &[&h, &u8_values()[..50]]);
    assert_contains(
        &err_text(super::metaimage::open(&p), &p),
        &["size mismatch"],
    );
}

#[test]
fn mha_truncated_data_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let h = mhd("DimSize = 5 4 3\nElementType = MET_USHORT\nElementDataFile = LOCAL");
    let data = le(&u16_values());
    let p = write(dir.path(), "t.mha", &[&h, &data[..119]]);
    let msg = err_text(super::metaimage::open(&p), &p);
    assert_contains(
        &msg,
        &[
            "size mismatch",
            &format!("expected {}", h.len() + 120),
            &format!("got {}", h.len() + 119),
        ],
    );
    let h = mhd(
        "DimSize = 5 4 3\nElementType = MET_USHORT\nCompressedData = True\nElementDataFile = LOCAL",
    );
    let z = zlib(&data);
    let p = write(dir.path(), "tz.mha", &[&h, &z[..z.len() - 3]]);
    assert_contains(
        &err_text(super::metaimage::open(&p), &p),
        &["compressed data"],
    );
}

#[test]
fn mhd_bad_headers_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let cases: Vec<(&str, String, Vec<&str>)> = vec![
        ("double", "NDims = 3\nDimSize = 5 4 3\nElementType = MET_DOUBLE\nElementDataFile = x.raw".into(), vec!["\"ElementType\"", "unsupported type \"MET_DOUBLE\""]),
        ("ndims", "NDims = 2\nDimSize = 5 4\nElementType = MET_UCHAR\nElementDataFile = x.raw".into(), vec!["\"NDims\"", "unsupported NDims \"2\""]),
        ("nondims", "DimSize = 5 4 3\nElementType = MET_UCHAR\nElementDataFile = x.raw".into(), vec!["\"NDims\"", "required field is missing"]),
        ("notype", "NDims = 3\nDimSize = 5 4 3\nElementDataFile = x.raw".into(), vec!["\"ElementType\"", "required field is missing"]),
        ("nosize", "NDims = 3\nElementType = MET_UCHAR\nElementDataFile = x.raw".into(), vec!["\"DimSize\"", "required field is missing"]),
        ("nofile", "NDims = 3\nDimSize = 5 4 3\nElementType = MET_UCHAR\n".into(), vec!["\"ElementDataFile\"", "required field is missing"]),
        ("channels", "NDims = 3\nDimSize = 5 4 3\nElementNumberOfChannels = 3\nElementType = MET_UCHAR\nElementDataFile = x.raw".into(), vec!["\"ElementNumberOfChannels\"", "unsupported value \"3\""]),
        ("list", "NDims = 3\nDimSize = 5 4 3\nElementType = MET_UCHAR\nElementDataFile = LIST".into(), vec!["\"ElementDataFile\"", "multi-file data"]),
        ("bool", "NDims = 3\nDimSize = 5 4 3\nElementType = MET_UCHAR\nCompressedData = maybe\nElementDataFile = x.raw".into(), vec!["\"CompressedData\"", "expected True or False"]),
        ("ascii", "NDims = 3\nDimSize = 5 4 3\nBinaryData = False\nElementType = MET_UCHAR\nElementDataFile = x.raw".into(), vec!["\"BinaryData\"", "ASCII"]),
        ("nokv", "NDims 3\nElementDataFile = x.raw".into(), vec!["line 1 is not a \"Key = Value\" field"]),
        ("zero", "NDims = 3\nDimSize = 5 4 0\nElementType = MET_UCHAR\nElementDataFile = x.raw".into(), vec!["bad dimensions [5, 4, 0]"]),
        ("zneg", "NDims = 3\nDimSize = 5 4 3\nElementType = MET_UCHAR\nCompressedData = True\nHeaderSize = -1\nElementDataFile = x.raw".into(), vec!["\"HeaderSize\"", "only allowed for uncompressed"]),
    ];
    write(dir.path(), "x.raw", &[&u8_values()]);
    for (name, text, want) in cases {
        let p = write(dir.path(), &format!("{name}.mhd"), &[text.as_bytes()]);
        assert_contains(&err_text(super::metaimage::open(&p), &p), &want);
    }
}

// ---------------------------------------------------------------- NIfTI

/// Fields of a hand-built NIfTI-1 header.
struct Nii {
    dim: [i16; 8],
    datatype: i16,
    bitpix: i16,
    pixdim: [f32; 8],
    vox_offset: f32,
    slope: f32,
    inter: f32,
    big: bool,
    magic: &'static [u8; 4],
}

impl Nii {
    fn new(datatype: i16, bitpix: i16) -> Self {
        Nii {
            dim: [3, 5, 4, 3, 1, 1, 1, 1],
            datatype,
            bitpix,
            pixdim: [1.0, 0.75, 1.25, 2.0, 1.0, 1.0, 1.0, 1.0],
            vox_offset: 352.0,
            slope: 0.0,
            inter: 0.0,
            big: false,
            magic: b"n+1\0",
        }
    }

    /// The 348-byte header and the 4-byte extension flag (no extensions).
    fn bytes(&self) -> Vec<u8> {
        let mut h = vec![0u8; 352];
        let big = self.big;
        let put = |h: &mut Vec<u8>, at: usize, b: &[u8]| h[at..at + b.len()].copy_from_slice(b);
        let i32b = |v: i32| {
            if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        };
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
        put(&mut h, 0, &i32b(348));
        for (i, d) in self.dim.iter().enumerate() {
            put(&mut h, 40 + 2 * i, &i16b(*d));
        }
        put(&mut h, 70, &i16b(self.datatype));
        put(&mut h, 72, &i16b(self.bitpix));
        for (i, d) in self.pixdim.iter().enumerate() {
            put(&mut h, 76 + 4 * i, &f32b(*d));
        }
        put(&mut h, 108, &f32b(self.vox_offset));
        put(&mut h, 112, &f32b(self.slope));
        put(&mut h, 116, &f32b(self.inter));
        put(&mut h, 344, self.magic);
        h
    }
}

#[test]
fn nifti_u16_is_mapped_and_gz_is_streamed() {
    let dir = tempfile::tempdir().unwrap();
    let h = Nii::new(512, 16).bytes();
    let data = le(&u16_values());
    let p = write(dir.path(), "a.nii", &[&h, &data]);
    let v = nifti::open(&p).unwrap();
    assert_eq!(v.dims(), DIMS);
    assert_eq!(v.spacing(), [0.75, 1.25, 2.0]);
    assert_eq!(as_u16(&v), u16_values());
    assert!(v.data().is_mapped());
    let p = write(
        dir.path(),
        "a.nii.gz",
        &[&gzip(&[h.as_slice(), &data].concat())],
    );
    let v = nifti::open(&p).unwrap();
    assert_eq!(as_u16(&v), u16_values());
    assert!(!v.data().is_mapped());
}

#[test]
fn nifti_types_endianness_extensions_and_4d() {
    let dir = tempfile::tempdir().unwrap();
    let mut n = Nii::new(16, 32);
    n.big = true;
    let p = write(dir.path(), "be.nii", &[&n.bytes(), &be_f32(&f32_values())]);
    assert_eq!(as_f32(&nifti::open(&p).unwrap()), f32_values());

    let mut n = Nii::new(4, 16);
    n.dim = [4, 5, 4, 3, 1, 1, 1, 1];
    n.vox_offset = 368.0;
    let body = [n.bytes().as_slice(), &[0u8; 16], &le(&i16_values())].concat();
    let p = write(dir.path(), "ext.nii.gz", &[&gzip(&body)]);
    assert_eq!(as_i16(&nifti::open(&p).unwrap()), i16_values());
    let p = write(dir.path(), "ext.nii", &[&body]);
    assert_eq!(as_i16(&nifti::open(&p).unwrap()), i16_values());

    let mut n = Nii::new(2, 8);
    n.slope = f32::NAN;
    n.inter = 5.0;
    let p = write(dir.path(), "nan_slope.nii", &[&n.bytes(), &u8_values()]);
    assert_eq!(as_u8(&nifti::open(&p).unwrap()), u8_values());
    n.slope = 1.0;
    n.inter = 0.0;
    let p = write(dir.path(), "unit_slope.nii", &[&n.bytes(), &u8_values()]);
    assert_eq!(as_u8(&nifti::open(&p).unwrap()), u8_values());
}

#[test]
fn nifti_scaling_converts_to_f32() {
    let dir = tempfile::tempdir().unwrap();
    let mut n = Nii::new(4, 16);
    n.slope = 0.5;
    n.inter = -10.0;
    let p = write(dir.path(), "s.nii", &[&n.bytes(), &le(&i16_values())]);
    let v = nifti::open(&p).unwrap();
    let want: Vec<f32> = i16_values()
        .iter()
        .map(|x| f32::from(*x) * 0.5 - 10.0)
        .collect();
    assert_eq!(as_f32(&v), want);
    assert_eq!(nifti::scaling(0.0, 3.0), None);
    assert_eq!(nifti::scaling(f32::NAN, 3.0), None);
    assert_eq!(nifti::scaling(1.0, 0.0), None);
    assert_eq!(nifti::scaling(1.0, 2.0), Some((1.0, 2.0)));
    assert_eq!(nifti::scaling(2.0, f32::NAN), Some((2.0, 0.0)));
}

#[test]
fn nifti_bad_inputs_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let data = le(&u16_values());
    let ok = Nii::new(512, 16);

    let p = write(dir.path(), "short.nii", &[&ok.bytes(), &data[..100]]);
    assert_contains(
        &err_text(nifti::open(&p), &p),
        &["size mismatch", "expected 472", "got 452"],
    );
    let p = write(dir.path(), "long.nii", &[&ok.bytes(), &data, &[0]]);
    assert_contains(
        &err_text(nifti::open(&p), &p),
        &["size mismatch", "expected 472", "got 473"],
    );

    let z = gzip(&[ok.bytes().as_slice(), &data].concat());
    let p = write(dir.path(), "cut.nii.gz", &[&z[..z.len() - 30]]);
    assert_contains(&err_text(nifti::open(&p), &p), &["compressed data"]);
    let p = write(
        dir.path(),
        "few.nii.gz",
        &[&gzip(&[ok.bytes().as_slice(), &data[..60]].concat())],
    );
    assert_contains(&err_text(nifti::open(&p), &p), &["after 60 of 120 bytes"]);

    let p = write(dir.path(), "hdr.nii", &[&ok.bytes()[..200]]);
    assert_contains(
        &err_text(nifti::open(&p), &p),
        &["\"header\"", "ends inside"],
    );

    let mut n = Nii::new(64, 64);
    let p = write(dir.path(), "double.nii", &[&n.bytes(), &[0u8; 480]]);
    assert_contains(
        &err_text(nifti::open(&p), &p),
        &["\"datatype\"", "unsupported datatype 64", "Float64"],
    );

    n = Nii::new(512, 16);
    n.dim = [4, 5, 4, 3, 2, 1, 1, 1];
    let p = write(dir.path(), "4d.nii", &[&n.bytes(), &data, &data]);
    assert_contains(
        &err_text(nifti::open(&p), &p),
        &["\"dim\"", "[5, 4, 3, 2]", "only 3D"],
    );
    n.dim = [2, 5, 4, 1, 1, 1, 1, 1];
    let p = write(dir.path(), "2d.nii", &[&n.bytes(), &data]);
    assert_contains(&err_text(nifti::open(&p), &p), &["\"dim\"", "only 3D"]);
    n.dim = [3, 5, 0, 3, 1, 1, 1, 1];
    let p = write(dir.path(), "zero.nii", &[&n.bytes()]);
    assert!(nifti::open(&p).is_err());

    n = Nii::new(512, 16);
    n.vox_offset = 100.0;
    let p = write(dir.path(), "off.nii", &[&n.bytes(), &data]);
    assert_contains(&err_text(nifti::open(&p), &p), &["\"vox_offset\""]);

    n = Nii::new(512, 16);
    n.magic = b"ni1\0";
    let p = write(dir.path(), "pair.nii", &[&n.bytes(), &data]);
    assert_contains(
        &err_text(nifti::open(&p), &p),
        &["\"magic\"", "detached .hdr/.img"],
    );
    n.magic = b"abc\0";
    let p = write(dir.path(), "magic.nii", &[&n.bytes(), &data]);
    assert_contains(
        &err_text(nifti::open(&p), &p),
        &["\"magic\"", "not a NIfTI-1 file"],
    );

    let mut f = f32_values();
    f[59] = f32::NAN;
    let p = write(dir.path(), "nan.nii", &[&Nii::new(16, 32).bytes(), &le(&f)]);
    assert_contains(
        &err_text(nifti::open(&p), &p),
        &["non-finite value NaN at voxel index 59"],
    );
}

// ---------------------------------------------------------------- dispatch

#[test]
fn open_dispatches_by_extension() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "v.NRRD",
        &[
            &nrrd_header("type: uint8\ndimension: 3\nsizes: 5 4 3\nencoding: raw\n"),
            &u8_values(),
        ],
    );
    assert_eq!(as_u8(&Volume::open(&p, None).unwrap()), u8_values());
    let p = write(dir.path(), "v.dat", &[&u8_values()]);
    assert_contains(
        &err_text(Volume::open(&p, None), &p),
        &["unknown volume format"],
    );
    let spec = RawSpec {
        endian: Endian::Big,
        ..RawSpec::new(DIMS, DataType::U8)
    };
    assert_eq!(as_u8(&Volume::open(&p, Some(&spec)).unwrap()), u8_values());
}

// ---------------------------------------------------------------- robustness

/// Mutated headers and truncated files give errors or volumes, never a panic.
#[test]
fn mutated_files_never_panic() {
    use rand::{Rng, SeedableRng};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let data = le(&u16_values());
    write(d, "m.raw", &[&data]);
    write(d, "m.zraw", &[&zlib(&data)]);
    let nrrd_fields = "type: uint16\ndimension: 3\nsizes: 5 4 3\nspace directions: (1,0,0) (0,2,0) (0,0,3)\nendian: little\n";
    let seeds: Vec<(&str, Vec<u8>, usize)> = vec![
        ("a.nrrd", [nrrd_header(&format!("{nrrd_fields}encoding: raw\nbyte skip: 0\n")), data.clone()].concat(), 0),
        ("g.nrrd", [nrrd_header(&format!("{nrrd_fields}encoding: gzip\n")), gzip(&data)].concat(), 0),
        ("d.nhdr", nrrd_header(&format!("{nrrd_fields}encoding: raw\nline skip: 0\ndata file: m.raw")), 0),
        ("l.mha", [mhd("DimSize = 5 4 3\nElementType = MET_USHORT\nHeaderSize = 0\nElementDataFile = LOCAL"), data.clone()].concat(), 0),
        ("z.mhd", mhd("DimSize = 5 4 3\nElementSpacing = 1 1 1\nElementType = MET_USHORT\nCompressedData = True\nElementDataFile = m.zraw"), 0),
        ("n.nii", [Nii::new(512, 16).bytes(), data.clone()].concat(), 352),
        ("n.nii.gz", gzip(&[Nii::new(512, 16).bytes(), data.clone()].concat()), 0),
    ];
    let alphabet = b"0123456789-+.eE:= \n\r()%,#LISTnone\xff\x00";
    let mut rng = rand::rngs::StdRng::seed_from_u64(2);
    for (name, seed, header_len) in &seeds {
        let p = d.join(name);
        std::fs::write(&p, seed).unwrap();
        Volume::open(&p, None).unwrap_or_else(|e| panic!("unmutated {name}: {e}"));
        let region = if *header_len > 0 {
            *header_len
        } else {
            seed.len()
        };
        for _ in 0..300 {
            let mut b = seed.clone();
            for _ in 0..rng.gen_range(1..4) {
                let i = rng.gen_range(0..region.min(b.len()));
                match rng.gen_range(0..4) {
                    0 => b[i] = alphabet[rng.gen_range(0..alphabet.len())],
                    1 => b[i] = rng.gen(),
                    2 => b.insert(i, alphabet[rng.gen_range(0..alphabet.len())]),
                    _ => b.truncate(i.max(1)),
                }
            }
            std::fs::write(&p, &b).unwrap();
            if let Err(e) = Volume::open(&p, None) {
                // Every message names a file; a mutated data-file name is still in `d`.
                let msg = e.to_string();
                assert!(msg.contains(&d.display().to_string()), "{msg}");
            }
        }
    }
}

/// The largest change between neighbouring voxels along x.
fn largest_x_step(v: &Volume) -> f32 {
    let n = v.dims()[0];
    let value = |i: usize| match v.data() {
        VoxelData::U8(d) => f32::from(d.as_slice()[i]),
        VoxelData::F32(d) => d.as_slice()[i],
        _ => unreachable!("phantoms are u8 or f32"),
    };
    (0..v.dims().iter().product::<usize>())
        .filter(|i| i % n + 1 < n)
        .map(|i| (value(i + 1) - value(i)).abs())
        .fold(0.0, f32::max)
}

#[test]
fn the_smooth_head_blends_the_heads_edges_over_several_voxels() {
    use super::phantom::Phantom;
    let (sharp, smooth) = (
        Phantom::SheppLogan.generate(64),
        Phantom::SmoothHead.generate(64),
    );
    assert_eq!(smooth.data_type(), DataType::F32);
    // The head's skull is one voxel step from air to 250; the smooth head ramps it.
    assert!(largest_x_step(&sharp) >= 200.0);
    let step = largest_x_step(&smooth);
    assert!(step < 80.0, "largest neighbour step {step}");
    // The same intensities where the head is flat: brain ≈ 50 at the centre, air outside.
    let at = |v: &Volume, x: usize, y: usize, z: usize| match v.data() {
        VoxelData::U8(d) => f32::from(d.as_slice()[x + 64 * (y + 64 * z)]),
        VoxelData::F32(d) => d.as_slice()[x + 64 * (y + 64 * z)],
        _ => unreachable!(),
    };
    assert_eq!(at(&sharp, 32, 20, 40), 50.0);
    assert!((at(&smooth, 32, 20, 40) - 50.0).abs() < 0.5);
    assert_eq!(at(&smooth, 0, 0, 0), 0.0);
    assert_eq!("smooth-head".parse::<Phantom>(), Ok(Phantom::SmoothHead));
}

#[test]
fn borrowed_voxels_read_the_owners_memory_and_keep_it_alive() {
    let owner: std::sync::Arc<Vec<u16>> = std::sync::Arc::new(u16_values());
    let (ptr, len) = (owner.as_ptr(), owner.len());
    let held = std::sync::Arc::clone(&owner);
    // SAFETY: `held` keeps the vector's buffer alive and nothing writes to it.
    let voxels = unsafe { super::Voxels::borrowed(held, ptr, len) };
    assert_eq!(voxels.as_slice().as_ptr(), ptr, "no copy");
    assert!(!voxels.is_mapped());
    assert_eq!(std::sync::Arc::strong_count(&owner), 2);
    let v = Volume::new([5, 4, 3], [1.0; 3], VoxelData::U16(voxels), "borrowed").unwrap();
    assert_eq!(std::sync::Arc::strong_count(&owner), 2);
    assert_eq!(v.value(1, 2, 1), owner[v.index(1, 2, 1)] as f32);
    drop(v);
    assert_eq!(
        std::sync::Arc::strong_count(&owner),
        1,
        "the owner is let go"
    );
}

#[test]
fn voxel_ranges_in_the_stored_type_equal_the_ranges_of_the_floats() {
    fn check<T: super::Voxel>(v: &[T]) {
        let want = v
            .iter()
            .fold([f32::INFINITY, f32::NEG_INFINITY], |[lo, hi], x| {
                [lo.min(x.to_f32()), hi.max(x.to_f32())]
            });
        assert_eq!(T::range_f32(v), want, "{} voxels", v.len());
    }
    check::<u8>(&[]);
    check::<u8>(&[7]);
    check::<u8>(&[3, 255, 0, 9]);
    check::<u16>(&[65535, 2, 40000]);
    check::<i16>(&[-1024, 3071, -3, 0, i16::MIN, i16::MAX]);
    check::<f32>(&[0.5, -2.25, 1e30, -1e-30]);
    let long: Vec<i16> = (0..1000)
        .map(|i| ((i * 7919) % 4001 - 2000) as i16)
        .collect();
    check(&long);
}
