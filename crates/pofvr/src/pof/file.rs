//! The `.pof` file: a fixed 256-byte little-endian header, a brick index and the records,
//! laid out so that the file is used in place through a memory map.
//!
//! ```text
//!   0  magic "POFVRTBL", version u32, header length u32
//!  16  dims [u64; 3]
//!  40  dtype u8, encoding u8, sets u8, method u8, brick size u32, brick count u32, basis count u32
//!  56  range hash u64, bases fingerprint u64
//!  72  views [u32; 2], step f32, ert f32, L f32, margin f32, pitch f32, subdiv u32
//! 104  index offset u64, index length u64, data offset u64, data length u64, record length u64
//! 144  index CRC32 u32, data CRC32 u32, phases u32, joint basis count u32 (0: none)
//! 160  joint anchor weights [f32; 16], zeros …
//! 224  record layout u8: 0 function-major, 1 cell-major (version 4), zeros …
//! 252  header CRC32 u32 (of bytes 0..252)
//! 256  index: one u32 per brick, the record slot or u32::MAX for a brick empty for every basis
//!      data: slot × record length; a record is p encoded POFs, then (with sets) for each
//!      basis s the p−1 other bases' POFs at s's q_min, then (with a joint anchor) the
//!      joint POF, padded to 8 bytes; cell-major records hold the same values ordered by
//!      view cell first, then function
//! ```
//!
//! Version 2 added the method and phases; version 1 files (zeros there) are read as the
//! bound method. The version was bumped, although the layout is unchanged, so that an older
//! pofvr refuses a sampled table rather than report it as a rigorous bound. Version 3 added
//! the joint POF (an older pofvr would misread its records). Version 4 added cell-major
//! records for the table encodings: a lookup reads every function's value of a view cell
//! from one cache line instead of one line (and often one page) per function.

use std::path::Path;

use memmap2::Mmap;

use super::{Encoding, PofError, PofMeta, PofMethod, PofTable};
use crate::volume::DataType;

pub(crate) const MAGIC: &[u8; 8] = b"POFVRTBL";
pub(crate) const VERSION: u32 = 4;
/// Oldest version still read.
const MIN_VERSION: u32 = 1;
pub(crate) const HEADER_LEN: usize = 256;
/// Header byte of the record layout (version 4): 0 function-major, 1 cell-major.
const LAYOUT_AT: usize = 224;

/// The file's bytes: built in memory or mapped from disk.
pub(crate) enum Bytes {
    Owned(Vec<u8>),
    Mapped(Mmap),
}

impl Bytes {
    pub(crate) fn as_slice(&self) -> &[u8] {
        match self {
            Bytes::Owned(v) => v,
            Bytes::Mapped(m) => m,
        }
    }
}

fn dtype_code(t: DataType) -> u8 {
    match t {
        DataType::U8 => 0,
        DataType::U16 => 1,
        DataType::I16 => 2,
        DataType::F32 => 3,
    }
}

fn dtype_from(c: u8) -> Option<DataType> {
    Some(match c {
        0 => DataType::U8,
        1 => DataType::U16,
        2 => DataType::I16,
        3 => DataType::F32,
        _ => return None,
    })
}

/// Assembles a complete file image from the meta, the slot index and the records.
pub(crate) fn assemble(meta: &PofMeta, index: &[u32], data: &[u8], record_len: usize) -> Vec<u8> {
    let mut out = head(meta, index, data.len(), crc32fast::hash(data), record_len);
    out.extend_from_slice(data);
    out
}

/// Where the records start in a file of `bricks` bricks.
pub(crate) fn data_offset(bricks: usize) -> usize {
    (HEADER_LEN + bricks * 4).next_multiple_of(8)
}

/// The file's bytes before its records (header, index, padding) for records of `data_len`
/// bytes with CRC32 `data_crc`: what a build that streams its records out writes last.
pub(crate) fn head(
    meta: &PofMeta,
    index: &[u32],
    data_len: usize,
    data_crc: u32,
    record_len: usize,
) -> Vec<u8> {
    let index_len = index.len() * 4;
    let index_offset = HEADER_LEN;
    let data_offset = data_offset(index.len());
    let mut out = Vec::with_capacity(data_offset);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&(HEADER_LEN as u32).to_le_bytes());
    for d in meta.dims {
        out.extend_from_slice(&d.to_le_bytes());
    }
    out.extend_from_slice(&[
        dtype_code(meta.dtype),
        meta.encoding.code(),
        u8::from(meta.sets),
        meta.method.code(),
    ]);
    out.extend_from_slice(&meta.brick_size.to_le_bytes());
    out.extend_from_slice(&meta.brick_count.to_le_bytes());
    out.extend_from_slice(&meta.basis_count.to_le_bytes());
    out.extend_from_slice(&meta.range_hash.to_le_bytes());
    out.extend_from_slice(&meta.bases_fingerprint.to_le_bytes());
    out.extend_from_slice(&meta.views[0].to_le_bytes());
    out.extend_from_slice(&meta.views[1].to_le_bytes());
    for f in [
        meta.step,
        meta.ert,
        meta.core_length,
        meta.margin,
        meta.pitch,
    ] {
        out.extend_from_slice(&f.to_le_bytes());
    }
    out.extend_from_slice(&meta.subdiv.to_le_bytes());
    for v in [index_offset, index_len, data_offset, data_len, record_len] {
        out.extend_from_slice(&(v as u64).to_le_bytes());
    }
    let index_bytes: Vec<u8> = index.iter().flat_map(|s| s.to_le_bytes()).collect();
    out.extend_from_slice(&crc32fast::hash(&index_bytes).to_le_bytes());
    out.extend_from_slice(&data_crc.to_le_bytes());
    out.extend_from_slice(&meta.phases.to_le_bytes());
    debug_assert_eq!(out.len(), 156);
    let anchor = meta.joint.as_deref().unwrap_or(&[]);
    debug_assert!(anchor.len() <= super::JOINT_MAX_BASES);
    out.extend_from_slice(&(anchor.len() as u32).to_le_bytes());
    for w in anchor {
        out.extend_from_slice(&w.to_le_bytes());
    }
    out.resize(HEADER_LEN - 4, 0);
    out[LAYOUT_AT] = u8::from(meta.cell_major);
    let hcrc = crc32fast::hash(&out);
    out.extend_from_slice(&hcrc.to_le_bytes());
    out.extend_from_slice(&index_bytes);
    out.resize(data_offset, 0);
    out
}

/// Wraps a file image (built or mapped) after validating it.
pub(crate) fn from_bytes(bytes: Bytes, source: String) -> Result<PofTable, PofError> {
    let b = bytes.as_slice();
    let fmt = |why: String| PofError::Format {
        file: source.clone(),
        why,
    };
    if b.len() < HEADER_LEN {
        return Err(fmt(format!(
            "{} bytes, shorter than the {HEADER_LEN}-byte header",
            b.len()
        )));
    }
    if &b[0..8] != MAGIC {
        return Err(fmt("bad magic (not a .pof file)".into()));
    }
    let u32_at = |o: usize| u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().expect("8 bytes"));
    let f32_at = |o: usize| f32::from_bits(u32_at(o));
    let expected = u32_at(HEADER_LEN - 4);
    let got = crc32fast::hash(&b[..HEADER_LEN - 4]);
    if expected != got {
        return Err(PofError::Crc {
            file: source,
            section: "header",
            expected,
            got,
        });
    }
    let version = u32_at(8);
    if !(MIN_VERSION..=VERSION).contains(&version) {
        return Err(fmt(format!(
            "format version {version}, this pofvr reads versions {MIN_VERSION} to {VERSION} (rebuild it with `pofvr pof build`)"
        )));
    }
    let (method, phases) = if version >= 2 {
        let m = PofMethod::from_code(b[43])
            .ok_or_else(|| fmt(format!("unknown builder method code {}", b[43])))?;
        (m, u32_at(152))
    } else {
        (PofMethod::Bound, 1)
    };
    let dtype =
        dtype_from(b[40]).ok_or_else(|| fmt(format!("unknown voxel type code {}", b[40])))?;
    let encoding = Encoding::from_code(b[41])
        .ok_or_else(|| fmt(format!("unknown encoding code {}", b[41])))?;
    let meta = PofMeta {
        dims: [u64_at(16), u64_at(24), u64_at(32)],
        dtype,
        encoding,
        sets: b[42] != 0,
        brick_size: u32_at(44),
        brick_count: u32_at(48),
        basis_count: u32_at(52),
        range_hash: u64_at(56),
        bases_fingerprint: u64_at(64),
        views: [u32_at(72), u32_at(76)],
        step: f32_at(80),
        ert: f32_at(84),
        core_length: f32_at(88),
        margin: f32_at(92),
        pitch: f32_at(96),
        subdiv: u32_at(100),
        method,
        phases,
        joint: None,
        cell_major: version >= 4 && b[LAYOUT_AT] == 1,
    };
    let mut meta = meta;
    if version >= 4 && (b[LAYOUT_AT] > 1 || (meta.cell_major && encoding == Encoding::Cubic)) {
        return Err(fmt(format!(
            "record layout code {} for encoding {encoding}",
            b[LAYOUT_AT]
        )));
    }
    if version >= 3 {
        let n = u32_at(156) as usize;
        if n > super::JOINT_MAX_BASES || (n != 0 && n != meta.basis_count as usize) {
            return Err(fmt(format!(
                "joint anchor of {n} weights for {} bases",
                meta.basis_count
            )));
        }
        if n > 0 {
            let anchor: Vec<f32> = (0..n).map(|i| f32_at(160 + 4 * i)).collect();
            if anchor.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
                return Err(fmt(format!("joint anchor weights {anchor:?}")));
            }
            meta.joint = Some(anchor);
        }
    }
    let to_usize =
        |v: u64, what: &str| usize::try_from(v).map_err(|_| fmt(format!("{what} {v} too large")));
    let index_offset = to_usize(u64_at(104), "index offset")?;
    let index_len = to_usize(u64_at(112), "index length")?;
    let data_offset = to_usize(u64_at(120), "data offset")?;
    let data_len = to_usize(u64_at(128), "data length")?;
    let record_len = to_usize(u64_at(136), "record length")?;
    // Bounds keep every size computed below far from overflow, whatever the header says.
    if !(1..=4096).contains(&meta.views[0]) || !(1..=4096).contains(&meta.views[1]) {
        return Err(fmt(format!("view grid {:?} outside 1..=4096", meta.views)));
    }
    if !(1..=1024).contains(&meta.basis_count) {
        return Err(fmt(format!(
            "{} bases, expected 1..=1024",
            meta.basis_count
        )));
    }
    let funcs = meta.functions();
    let want_record = (funcs * encoding.function_bytes(meta.views)).next_multiple_of(8);
    if record_len != want_record {
        return Err(fmt(format!(
            "record length {record_len}, expected {want_record}"
        )));
    }
    if index_len != meta.brick_count as usize * 4
        || !matches!(index_offset.checked_add(index_len), Some(e) if e <= b.len())
        || !matches!(data_offset.checked_add(data_len), Some(e) if e == b.len())
        || (record_len > 0 && data_len % record_len != 0)
    {
        return Err(fmt(format!(
            "sections do not fit the file ({} bytes): index {index_offset}+{index_len}, data {data_offset}+{data_len}",
            b.len()
        )));
    }
    let (icrc, dcrc) = (u32_at(144), u32_at(148));
    let got = crc32fast::hash(&b[index_offset..index_offset + index_len]);
    if got != icrc {
        return Err(PofError::Crc {
            file: source,
            section: "brick index",
            expected: icrc,
            got,
        });
    }
    let got = crc32fast::hash(&b[data_offset..data_offset + data_len]);
    if got != dcrc {
        return Err(PofError::Crc {
            file: source,
            section: "POF data",
            expected: dcrc,
            got,
        });
    }
    let slots = data_len.checked_div(record_len).unwrap_or(0);
    for i in 0..meta.brick_count as usize {
        let s = u32_at(index_offset + 4 * i);
        if s != u32::MAX && s as usize >= slots {
            return Err(fmt(format!("brick {i} points at record {s} of {slots}")));
        }
    }
    Ok(PofTable {
        meta,
        bytes,
        index_offset,
        data_offset,
        record_len,
        source,
        caches: super::cache::Caches::default(),
    })
}

pub(crate) fn open(path: &Path) -> Result<PofTable, PofError> {
    let source = path.display().to_string();
    let io = |err| PofError::Io {
        file: source.clone(),
        err,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    // SAFETY: read-only map; a file changed underneath by another process is outside what
    // any mmap reader can defend against. The CRCs are checked right after mapping.
    let map = unsafe { Mmap::map(&file) }.map_err(io)?;
    from_bytes(Bytes::Mapped(map), source)
}
