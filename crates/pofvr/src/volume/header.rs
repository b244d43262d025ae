//! What the text-header readers (NRRD, MetaImage) share: reading header lines with a byte
//! count, and fetching the voxel bytes a header points at through the raw back end.

use std::fs::File;
use std::io::{BufRead, BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use flate2::read::{MultiGzDecoder, ZlibDecoder};

use super::{checked_voxel_count, raw, RawSpec, Volume, VolumeError};

/// A header longer than this is taken to be a file without a header end (binary data read
/// as text), rather than read on to the end of a possibly huge file.
pub(crate) const MAX_HEADER_BYTES: u64 = 1 << 20;

/// Reads a text header line by line, counting the bytes consumed so that attached data
/// can be found right after the last header line.
pub(crate) struct HeaderLines<'a> {
    path: &'a Path,
    reader: BufReader<File>,
    consumed: u64,
    line_no: usize,
}

impl<'a> HeaderLines<'a> {
    /// Opens `path` for reading its header.
    pub(crate) fn open(path: &'a Path) -> Result<Self, VolumeError> {
        let file = File::open(path).map_err(|e| VolumeError::io(path, e))?;
        Ok(HeaderLines {
            path,
            reader: BufReader::new(file),
            consumed: 0,
            line_no: 0,
        })
    }

    /// Bytes consumed so far: the offset of whatever follows the last line returned.
    pub(crate) fn consumed(&self) -> u64 {
        self.consumed
    }

    /// Number of the last line returned, from 1.
    pub(crate) fn line_no(&self) -> usize {
        self.line_no
    }

    /// The next line without its line ending, or `None` at the end of the file.
    pub(crate) fn next_line(&mut self) -> Result<Option<String>, VolumeError> {
        let mut buf = Vec::new();
        let room = MAX_HEADER_BYTES.saturating_sub(self.consumed);
        let k = (&mut self.reader)
            .take(room + 1)
            .read_until(b'\n', &mut buf)
            .map_err(|e| VolumeError::io(self.path, e))?;
        if k == 0 {
            return Ok(None);
        }
        self.consumed += k as u64;
        self.line_no += 1;
        if self.consumed > MAX_HEADER_BYTES {
            return Err(VolumeError::header(
                self.path,
                "header",
                format!("no end of the header within the first {MAX_HEADER_BYTES} bytes"),
            ));
        }
        if buf.last() == Some(&b'\n') {
            buf.pop();
            if buf.last() == Some(&b'\r') {
                buf.pop();
            }
        }
        String::from_utf8(buf).map(Some).map_err(|_| {
            VolumeError::header(
                self.path,
                "header",
                format!(
                    "line {} is not text (binary data where a header line should be)",
                    self.line_no
                ),
            )
        })
    }
}

/// How the voxel bytes are encoded in the data file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Compression {
    /// Plain bytes, memory-mapped.
    None,
    /// gzip (one or more members), streamed.
    Gzip,
    /// zlib, streamed.
    Zlib,
}

/// Bytes between the start of the data and the voxels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Skip {
    /// This many bytes (after decompression for compressed data).
    Bytes(u64),
    /// The voxels are the last bytes of the file (NRRD `byte skip: -1`, MetaImage
    /// `HeaderSize = -1`); raw data only.
    FromEnd,
}

/// Where a header says the voxel bytes are.
#[derive(Debug)]
pub(crate) struct DataSource {
    /// The file holding the data (the header itself for attached data).
    pub(crate) file: PathBuf,
    /// Byte offset in `file` where the data (compressed or not) begin.
    pub(crate) start: u64,
    /// Lines to skip from `start` before the data, counted in the file as stored.
    pub(crate) skip_lines: u64,
    /// Bytes to skip before the voxels.
    pub(crate) skip: Skip,
    /// The header field `skip` came from, for messages.
    pub(crate) skip_field: &'static str,
    /// The encoding.
    pub(crate) compression: Compression,
}

/// Loads the voxels a header describes: raw data memory-mapped at their offset (the file
/// must end exactly where the voxels do), compressed data streamed through the decoder.
/// The volume's source is the header, which is what the user named.
pub(crate) fn load(header: &Path, src: &DataSource, spec: RawSpec) -> Result<Volume, VolumeError> {
    let data_name = src.file.display().to_string();
    let n = checked_voxel_count(&header.display().to_string(), spec.dims)?;
    let data_bytes = n as u64 * spec.dtype.size() as u64;
    let start = src.start.saturating_add(skip_lines(header, src)?);
    let mut vol = match src.compression {
        Compression::None => {
            let offset = match src.skip {
                Skip::Bytes(b) => start.saturating_add(b),
                Skip::FromEnd => {
                    let len = std::fs::metadata(&src.file)
                        .map_err(|e| VolumeError::io(&src.file, e))?
                        .len();
                    match len.checked_sub(data_bytes) {
                        Some(off) if off >= start => off,
                        _ => {
                            return Err(VolumeError::SizeMismatch {
                                file: data_name,
                                expected: start.saturating_add(data_bytes),
                                got: len,
                            })
                        }
                    }
                }
            };
            raw::open(&src.file, &RawSpec { offset, ..spec })?
        }
        Compression::Gzip | Compression::Zlib => {
            let Skip::Bytes(skip) = src.skip else {
                return Err(VolumeError::header(
                    header,
                    src.skip_field,
                    "-1 (data at the end of the file) is only allowed for uncompressed data",
                ));
            };
            let mut file = File::open(&src.file).map_err(|e| VolumeError::io(&src.file, e))?;
            file.seek(SeekFrom::Start(start))
                .map_err(|e| VolumeError::io(&src.file, e))?;
            let input = BufReader::new(file);
            let mut decoder: Box<dyn Read> = if src.compression == Compression::Gzip {
                Box::new(MultiGzDecoder::new(input))
            } else {
                Box::new(ZlibDecoder::new(input))
            };
            let skipped = std::io::copy(&mut (&mut decoder).take(skip), &mut std::io::sink())
                .map_err(|e| VolumeError::Decode {
                    file: data_name.clone(),
                    why: e.to_string(),
                })?;
            if skipped != skip {
                return Err(VolumeError::Decode {
                    file: data_name,
                    why: format!(
                        "data end after {skipped} bytes, before the {skip} bytes of {} (truncated?)",
                        src.skip_field
                    ),
                });
            }
            raw::from_reader(&src.file, decoder, &spec)?
        }
    };
    vol.source = header.display().to_string();
    Ok(vol)
}

/// Bytes taken by the first `src.skip_lines` lines at `src.start`.
fn skip_lines(header: &Path, src: &DataSource) -> Result<u64, VolumeError> {
    if src.skip_lines == 0 {
        return Ok(0);
    }
    let mut file = File::open(&src.file).map_err(|e| VolumeError::io(&src.file, e))?;
    file.seek(SeekFrom::Start(src.start))
        .map_err(|e| VolumeError::io(&src.file, e))?;
    let mut reader = BufReader::new(file);
    let mut total = 0u64;
    let mut line = Vec::new();
    for i in 0..src.skip_lines {
        line.clear();
        // Bounded so that a line skip over binary data without newlines cannot read the
        // whole file into memory.
        let k = (&mut reader)
            .take(MAX_HEADER_BYTES)
            .read_until(b'\n', &mut line)
            .map_err(|e| VolumeError::io(&src.file, e))?;
        if k == 0 || line.last() != Some(&b'\n') {
            return Err(VolumeError::header(
                header,
                "line skip",
                format!(
                    "{}: found only {i} of {} lines before the data",
                    src.file.display(),
                    src.skip_lines
                ),
            ));
        }
        total += k as u64;
    }
    Ok(total)
}

/// Parses `n` whitespace-separated values of one header field.
pub(crate) fn parse_list<T: std::str::FromStr>(
    path: &Path,
    field: &str,
    value: &str,
    n: usize,
) -> Result<Vec<T>, VolumeError> {
    let items: Vec<&str> = value.split_whitespace().collect();
    if items.len() != n {
        return Err(VolumeError::header(
            path,
            field,
            format!("expected {n} values, got {} ({value:?})", items.len()),
        ));
    }
    items
        .iter()
        .map(|s| {
            s.parse::<T>().map_err(|_| {
                VolumeError::header(path, field, format!("cannot parse {s:?} as a number"))
            })
        })
        .collect()
}

/// Dims from a parsed size list (already of length 3).
pub(crate) fn dims3(v: &[usize]) -> [usize; 3] {
    [v[0], v[1], v[2]]
}
