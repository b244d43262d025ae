//! MetaImage reader: `.mhd` (data in the file named by `ElementDataFile`, `.raw` or
//! zlib-compressed `.zraw`) and `.mha` (`ElementDataFile = LOCAL`: data right after the
//! header line that names it).
//!
//! Supported: `NDims = 3`; `DimSize`; `ElementType` MET_UCHAR, MET_USHORT, MET_SHORT and
//! MET_FLOAT; `ElementSpacing` (or `ElementSize` when no spacing is given; unit spacing when
//! neither is); `BinaryDataByteOrderMSB` / `ElementByteOrderMSB` (little-endian when absent,
//! as in MetaIO); `CompressedData` (zlib, streamed); `HeaderSize` (bytes from the start of
//! the data file, -1 for "the voxels are the last bytes of the file", as MetaIO reads it);
//! `ElementNumberOfChannels = 1`; `BinaryData = True` (ASCII data are rejected). Keys are
//! matched case-insensitively. Anything else that would change how the voxels are read is
//! rejected with an error naming the file and field.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::header::{dims3, load, parse_list, Compression, DataSource, HeaderLines, Skip};
use super::{DataType, Endian, RawSpec, Volume, VolumeError};

/// A parsed MetaImage header: the fields that decide how the voxels are read.
#[derive(Clone, Debug, PartialEq)]
pub struct MetaHeader {
    /// Voxel counts along x, y, z.
    pub dims: [usize; 3],
    /// Stored type.
    pub dtype: DataType,
    /// Byte order.
    pub endian: Endian,
    /// World spacing along x, y, z.
    pub spacing: [f32; 3],
    /// True when `CompressedData = True` (zlib).
    pub compressed: bool,
    /// The data file, resolved against the header's directory; the header itself for LOCAL.
    pub data_file: PathBuf,
    /// True for `ElementDataFile = LOCAL`.
    pub local: bool,
    /// `HeaderSize`: `Some(n)` skips n bytes from the start of the data file, `None` is -1.
    /// Absent means 0 for a separate file and "right after the header" for LOCAL.
    pub header_size: Option<u64>,
    /// Offset of the first byte after the `ElementDataFile` line.
    pub header_len: u64,
}

/// Opens a `.mhd` or `.mha` file.
///
/// # Errors
/// [`VolumeError::Header`] for a missing, malformed or unsupported field,
/// [`VolumeError::SizeMismatch`] when raw data are shorter or longer than dims × type,
/// [`VolumeError::Decode`] for truncated or corrupt compressed data, and the errors of
/// [`Volume::new`].
pub fn open(path: &Path) -> Result<Volume, VolumeError> {
    let h = read_header(path)?;
    let (start, skip) = match (h.local, h.header_size) {
        (true, None) => (h.header_len, Skip::FromEnd),
        (false, None) => (0, Skip::FromEnd),
        (_, Some(n)) if n > 0 => (n, Skip::Bytes(0)),
        (true, Some(_)) => (h.header_len, Skip::Bytes(0)),
        (false, Some(_)) => (0, Skip::Bytes(0)),
    };
    let src = DataSource {
        file: h.data_file.clone(),
        start,
        skip_lines: 0,
        skip,
        skip_field: "HeaderSize",
        compression: if h.compressed {
            Compression::Zlib
        } else {
            Compression::None
        },
    };
    let spec = RawSpec {
        dims: h.dims,
        dtype: h.dtype,
        endian: h.endian,
        spacing: h.spacing,
        offset: 0,
    };
    load(path, &src, spec)
}

/// Reads and checks the header of a `.mhd` or `.mha` file without touching the data.
///
/// # Errors
/// [`VolumeError::Header`] for a missing, malformed or unsupported field; I/O errors.
pub fn read_header(path: &Path) -> Result<MetaHeader, VolumeError> {
    let mut lines = HeaderLines::open(path)?;
    // Lowercase key → (key as written, value).
    let mut fields: HashMap<String, (String, String)> = HashMap::new();
    let mut data_file_seen = false;
    while let Some(line) = lines.next_line()? {
        let trimmed = line.trim();
        if trimmed.is_empty() {
            continue;
        }
        let Some(eq) = trimmed.find('=') else {
            return Err(VolumeError::header(
                path,
                "header",
                format!(
                    "line {} is not a \"Key = Value\" field: {:?} (is this a MetaImage file?)",
                    lines.line_no(),
                    trimmed.chars().take(60).collect::<String>()
                ),
            ));
        };
        let name = trimmed[..eq].trim();
        let value = trimmed[eq + 1..].trim();
        if fields
            .insert(
                name.to_ascii_lowercase(),
                (name.to_string(), value.to_string()),
            )
            .is_some()
        {
            return Err(VolumeError::header(path, name, "given more than once"));
        }
        // MetaIO ends the header at ElementDataFile; with LOCAL the data follow at once.
        if name.eq_ignore_ascii_case("ElementDataFile") {
            data_file_seen = true;
            break;
        }
    }
    let get = |key: &str| {
        fields
            .get(&key.to_ascii_lowercase())
            .map(|(_, v)| v.as_str())
    };
    let require = |key: &str| {
        get(key).ok_or_else(|| VolumeError::header(path, key, "required field is missing"))
    };

    let ndims = require("NDims")?;
    if ndims != "3" {
        return Err(VolumeError::header(
            path,
            "NDims",
            format!("unsupported NDims {ndims:?}: only 3D scalar volumes are read"),
        ));
    }
    if let Some(c) = get("ElementNumberOfChannels") {
        if c != "1" {
            return Err(VolumeError::header(
                path,
                "ElementNumberOfChannels",
                format!("unsupported value {c:?}: only scalar (1-channel) volumes are read"),
            ));
        }
    }
    let sizes: Vec<usize> = parse_list(path, "DimSize", require("DimSize")?, 3)?;
    let dims = dims3(&sizes);
    let et = require("ElementType")?;
    let dtype = match et.to_ascii_uppercase().as_str() {
        "MET_UCHAR" => DataType::U8,
        "MET_USHORT" => DataType::U16,
        "MET_SHORT" => DataType::I16,
        "MET_FLOAT" => DataType::F32,
        _ => {
            return Err(VolumeError::header(
                path,
                "ElementType",
                format!("unsupported type {et:?}: pofvr reads MET_UCHAR, MET_USHORT, MET_SHORT and MET_FLOAT"),
            ))
        }
    };
    let spacing = match (get("ElementSpacing"), get("ElementSize")) {
        (Some(v), _) => parse_list::<f32>(path, "ElementSpacing", v, 3)?,
        (None, Some(v)) => parse_list::<f32>(path, "ElementSize", v, 3)?,
        (None, None) => vec![1.0; 3],
    };
    let msb = ["BinaryDataByteOrderMSB", "ElementByteOrderMSB"]
        .into_iter()
        .filter_map(|k| get(k).map(|v| (k, v)))
        .map(|(k, v)| parse_bool(path, k, v))
        .collect::<Result<Vec<bool>, _>>()?;
    if msb.len() == 2 && msb[0] != msb[1] {
        return Err(VolumeError::header(
            path,
            "ElementByteOrderMSB",
            "disagrees with BinaryDataByteOrderMSB",
        ));
    }
    let endian = if msb.first() == Some(&true) {
        Endian::Big
    } else {
        Endian::Little
    };
    if let Some(v) = get("BinaryData") {
        if !parse_bool(path, "BinaryData", v)? {
            return Err(VolumeError::header(
                path,
                "BinaryData",
                "ASCII (BinaryData = False) MetaImage data are not supported",
            ));
        }
    }
    let compressed = match get("CompressedData") {
        None => false,
        Some(v) => parse_bool(path, "CompressedData", v)?,
    };
    let header_size = match get("HeaderSize") {
        None => Some(0),
        Some("-1") => None,
        Some(v) => Some(v.parse::<u64>().map_err(|_| {
            VolumeError::header(
                path,
                "HeaderSize",
                format!("expected -1 or a byte count, got {v:?}"),
            )
        })?),
    };
    if !data_file_seen {
        return Err(VolumeError::header(
            path,
            "ElementDataFile",
            "required field is missing",
        ));
    }
    let df = require("ElementDataFile")?;
    let tokens: Vec<&str> = df.split_whitespace().collect();
    let local = df.eq_ignore_ascii_case("LOCAL");
    if tokens
        .first()
        .is_some_and(|t| t.eq_ignore_ascii_case("LIST"))
        || (df.contains('%') && tokens.len() >= 4)
    {
        return Err(VolumeError::header(
            path,
            "ElementDataFile",
            format!("multi-file data ({df:?}) is not supported: give a single data file or LOCAL"),
        ));
    }
    if df.is_empty() {
        return Err(VolumeError::header(
            path,
            "ElementDataFile",
            "empty file name",
        ));
    }
    let data_file = if local {
        path.to_path_buf()
    } else {
        let p = Path::new(df);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            path.parent().unwrap_or(Path::new("")).join(p)
        }
    };
    Ok(MetaHeader {
        dims,
        dtype,
        endian,
        spacing: [spacing[0], spacing[1], spacing[2]],
        compressed,
        data_file,
        local,
        header_size,
        header_len: lines.consumed(),
    })
}

fn parse_bool(path: &Path, field: &str, v: &str) -> Result<bool, VolumeError> {
    match v.to_ascii_lowercase().as_str() {
        "true" | "1" => Ok(true),
        "false" | "0" => Ok(false),
        _ => Err(VolumeError::header(
            path,
            field,
            format!("expected True or False, got {v:?}"),
        )),
    }
}
