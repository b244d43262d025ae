//! NRRD reader: `.nrrd` (data attached after the header's blank line) and `.nhdr` (data in
//! the file named by `data file`).
//!
//! Supported: `dimension: 3`; `type` uint8, int16, uint16 and float in all their NRRD
//! spellings; encodings `raw` (memory-mapped at its offset) and `gzip`/`gz` (streamed once
//! through the decoder); `endian`; `sizes`; `spacings` or `space directions` (spacing = the
//! length of each direction vector; unit spacing when neither is given); `byte skip`
//! (including -1 for raw data) and `line skip`; a single detached data file. Field names are
//! matched case-insensitively and with or without their inner spaces (`data file` and
//! `datafile`); comments and `key:=value` pairs are ignored. Anything else that would
//! change how the voxels are read (other types, encodings, dimensions, multi-file data) is
//! rejected with an error that names the file and the field.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::header::{dims3, load, parse_list, Compression, DataSource, HeaderLines, Skip};
use super::{DataType, Endian, RawSpec, Volume, VolumeError};

/// A parsed NRRD header: the fields that decide how the voxels are read.
#[derive(Clone, Debug, PartialEq)]
pub struct NrrdHeader {
    /// Voxel counts along x, y, z.
    pub dims: [usize; 3],
    /// Stored type.
    pub dtype: DataType,
    /// Byte order (little when the type is one byte wide and no `endian` is given).
    pub endian: Endian,
    /// World spacing along x, y, z.
    pub spacing: [f32; 3],
    /// True for `gzip`/`gz` encoding, false for `raw`.
    pub gzip: bool,
    /// The detached data file, resolved against the header's directory; `None` when the
    /// data are attached.
    pub data_file: Option<PathBuf>,
    /// `byte skip`; `None` for -1 (the voxels are the last bytes of the file).
    pub byte_skip: Option<u64>,
    /// `line skip`.
    pub line_skip: u64,
    /// Offset of the first byte after the header (attached data start here).
    pub header_len: u64,
}

/// Opens a `.nrrd` or `.nhdr` file.
///
/// # Errors
/// [`VolumeError::Header`] for a missing, malformed or unsupported field,
/// [`VolumeError::SizeMismatch`] when raw data are shorter or longer than dims × type,
/// [`VolumeError::Decode`] for truncated or corrupt gzip data, and the errors of
/// [`Volume::new`].
pub fn open(path: &Path) -> Result<Volume, VolumeError> {
    let h = read_header(path)?;
    let src = DataSource {
        file: h.data_file.clone().unwrap_or_else(|| path.to_path_buf()),
        start: if h.data_file.is_some() {
            0
        } else {
            h.header_len
        },
        skip_lines: h.line_skip,
        skip: h.byte_skip.map_or(Skip::FromEnd, Skip::Bytes),
        skip_field: "byte skip",
        compression: if h.gzip {
            Compression::Gzip
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

/// Reads and checks the header of a `.nrrd` or `.nhdr` file without touching the data.
///
/// # Errors
/// [`VolumeError::Header`] for a missing, malformed or unsupported field; I/O errors.
pub fn read_header(path: &Path) -> Result<NrrdHeader, VolumeError> {
    let mut lines = HeaderLines::open(path)?;
    let magic = lines.next_line()?.unwrap_or_default();
    if !(magic.starts_with("NRRD")
        && magic.len() == 8
        && magic[4..].bytes().all(|b| b.is_ascii_digit()))
    {
        return Err(VolumeError::header(
            path,
            "magic",
            format!(
                "not a NRRD file: first line is {:?}, expected NRRD000n",
                truncate(&magic)
            ),
        ));
    }
    // Canonical (lowercase, no spaces) field name → (name as written, value).
    let mut fields: HashMap<String, (String, String)> = HashMap::new();
    let mut ended = false;
    while let Some(line) = lines.next_line()? {
        if line.is_empty() {
            ended = true;
            break;
        }
        if line.starts_with('#') {
            continue;
        }
        let Some(colon) = line.find(':') else {
            return Err(VolumeError::header(
                path,
                "header",
                format!(
                    "line {} is neither a field nor a comment: {:?}",
                    lines.line_no(),
                    truncate(&line)
                ),
            ));
        };
        if line[colon..].starts_with(":=") {
            continue;
        }
        let name = line[..colon].trim();
        let value = line[colon + 1..].trim();
        let key: String = name
            .chars()
            .filter(|c| !c.is_whitespace())
            .collect::<String>()
            .to_ascii_lowercase();
        // With "data file: LIST" the rest of the header is the list of file names.
        let list = key == "datafile" && value.split_whitespace().next() == Some("LIST");
        if fields
            .insert(key, (name.to_string(), value.to_string()))
            .is_some()
        {
            return Err(VolumeError::header(path, name, "given more than once"));
        }
        if list {
            ended = true;
            break;
        }
    }
    let get = |key: &str| fields.get(key).map(|(_, v)| v.as_str());
    let require = |key: &str, field: &str| {
        get(key).ok_or_else(|| VolumeError::header(path, field, "required field is missing"))
    };

    let dimension = require("dimension", "dimension")?;
    if dimension != "3" {
        return Err(VolumeError::header(
            path,
            "dimension",
            format!("unsupported dimension {dimension:?}: only 3D scalar volumes are read"),
        ));
    }
    let dtype = parse_type(path, require("type", "type")?)?;
    let sizes: Vec<usize> = parse_list(path, "sizes", require("sizes", "sizes")?, 3)?;
    let dims = dims3(&sizes);

    let encoding = require("encoding", "encoding")?.to_ascii_lowercase();
    let gzip = match encoding.as_str() {
        "raw" => false,
        "gzip" | "gz" => true,
        other => {
            return Err(VolumeError::header(
                path,
                "encoding",
                format!("unsupported encoding {other:?}: pofvr reads raw and gzip"),
            ))
        }
    };
    let endian = match get("endian") {
        Some(e) => match e.to_ascii_lowercase().as_str() {
            "little" => Endian::Little,
            "big" => Endian::Big,
            other => {
                return Err(VolumeError::header(
                    path,
                    "endian",
                    format!("unknown value {other:?}, expected little or big"),
                ))
            }
        },
        None if dtype.size() > 1 => {
            return Err(VolumeError::header(
                path,
                "endian",
                format!("required field is missing (type {dtype} is more than one byte wide)"),
            ))
        }
        None => Endian::Little,
    };
    let spacing = parse_spacing(path, get("spacings"), get("spacedirections"))?;

    let byte_skip = match get("byteskip") {
        None => Some(0),
        Some("-1") => None,
        Some(v) => Some(v.parse::<u64>().map_err(|_| {
            VolumeError::header(
                path,
                "byte skip",
                format!("expected -1 or a byte count, got {v:?}"),
            )
        })?),
    };
    let line_skip = match get("lineskip") {
        None => 0,
        Some(v) => v.parse::<u64>().map_err(|_| {
            VolumeError::header(
                path,
                "line skip",
                format!("expected a line count, got {v:?}"),
            )
        })?,
    };
    let data_file = match get("datafile") {
        None => None,
        Some(v) => Some(resolve_data_file(path, v)?),
    };
    if data_file.is_none() && !ended {
        return Err(VolumeError::header(
            path,
            "data file",
            "no data: the header has neither a data file nor a blank line followed by attached data",
        ));
    }
    Ok(NrrdHeader {
        dims,
        dtype,
        endian,
        spacing,
        gzip,
        data_file,
        byte_skip,
        line_skip,
        header_len: lines.consumed(),
    })
}

/// Maps every NRRD spelling of the four supported types.
fn parse_type(path: &Path, value: &str) -> Result<DataType, VolumeError> {
    let norm = value
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .to_ascii_lowercase();
    match norm.as_str() {
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => Ok(DataType::U8),
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => Ok(DataType::I16),
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => Ok(DataType::U16),
        "float" | "float32" => Ok(DataType::F32),
        _ => Err(VolumeError::header(
            path,
            "type",
            format!("unsupported type {value:?}: pofvr reads uint8 (uchar), int16 (short), uint16 (ushort) and float"),
        )),
    }
}

/// Spacing from `spacings` or from the lengths of the `space directions` vectors; when both
/// are given they must agree. Unit spacing when neither is.
fn parse_spacing(
    path: &Path,
    spacings: Option<&str>,
    directions: Option<&str>,
) -> Result<[f32; 3], VolumeError> {
    let from_spacings = match spacings {
        None => None,
        Some(v) => {
            let items: Vec<&str> = v.split_whitespace().collect();
            if items.iter().any(|s| s.eq_ignore_ascii_case("nan")) {
                return Err(VolumeError::header(
                    path,
                    "spacings",
                    format!("NaN entries ({v:?}) are not allowed: every axis of a 3D volume needs a spacing"),
                ));
            }
            let s: Vec<f32> = parse_list(path, "spacings", v, 3)?;
            Some([s[0], s[1], s[2]])
        }
    };
    let from_directions = match directions {
        None => None,
        Some(v) => Some(parse_directions(path, v)?),
    };
    match (from_spacings, from_directions) {
        (Some(s), Some(d)) => {
            let agree = s
                .iter()
                .zip(&d)
                .all(|(a, b)| (a - b).abs() <= 1e-4 * a.abs().max(b.abs()));
            if !agree {
                return Err(VolumeError::header(
                    path,
                    "spacings",
                    format!(
                        "spacings {s:?} disagree with the lengths {d:?} of the space directions"
                    ),
                ));
            }
            Ok(d)
        }
        (Some(s), None) => Ok(s),
        (None, Some(d)) => Ok(d),
        (None, None) => Ok([1.0; 3]),
    }
}

/// Lengths of the three `(x,y,z)` vectors of `space directions`.
fn parse_directions(path: &Path, value: &str) -> Result<[f32; 3], VolumeError> {
    let field = "space directions";
    let mut out = Vec::new();
    let mut rest = value.trim();
    while !rest.is_empty() {
        if rest
            .get(..4)
            .is_some_and(|s| s.eq_ignore_ascii_case("none"))
        {
            return Err(VolumeError::header(
                path,
                field,
                "a \"none\" entry is not allowed: every axis of a 3D volume needs a direction",
            ));
        }
        if !rest.starts_with('(') {
            return Err(VolumeError::header(
                path,
                field,
                format!("expected (x,y,z) vectors, got {value:?}"),
            ));
        }
        let Some(close) = rest.find(')') else {
            return Err(VolumeError::header(
                path,
                field,
                format!("unclosed parenthesis in {value:?}"),
            ));
        };
        let comps: Result<Vec<f64>, _> = rest[1..close]
            .split(',')
            .map(|c| c.trim().parse::<f64>())
            .collect();
        let comps = comps.map_err(|_| {
            VolumeError::header(
                path,
                field,
                format!("cannot parse vector {:?}", &rest[..=close]),
            )
        })?;
        if comps.is_empty() || comps.iter().any(|c| !c.is_finite()) {
            return Err(VolumeError::header(
                path,
                field,
                format!("bad vector {:?}", &rest[..=close]),
            ));
        }
        out.push(comps.iter().map(|c| c * c).sum::<f64>().sqrt() as f32);
        rest = rest[close + 1..].trim_start();
    }
    if out.len() != 3 {
        return Err(VolumeError::header(
            path,
            field,
            format!("expected 3 vectors, got {}", out.len()),
        ));
    }
    Ok([out[0], out[1], out[2]])
}

/// Resolves a single detached data file against the header's directory.
fn resolve_data_file(path: &Path, value: &str) -> Result<PathBuf, VolumeError> {
    let tokens: Vec<&str> = value.split_whitespace().collect();
    let multi =
        tokens.first().is_some_and(|t| *t == "LIST") || (value.contains('%') && tokens.len() >= 4);
    if multi {
        return Err(VolumeError::header(
            path,
            "data file",
            format!(
                "multi-file data ({:?}) is not supported: give a single data file",
                truncate(value)
            ),
        ));
    }
    if value.is_empty() {
        return Err(VolumeError::header(path, "data file", "empty file name"));
    }
    let p = Path::new(value);
    Ok(if p.is_absolute() {
        p.to_path_buf()
    } else {
        path.parent().unwrap_or(Path::new("")).join(p)
    })
}

/// Shortens a string quoted in a message (a binary file's first "line" can be long).
fn truncate(s: &str) -> &str {
    match s.char_indices().nth(60) {
        Some((i, _)) => &s[..i],
        None => s,
    }
}
