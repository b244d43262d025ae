//! Zarr v3 arrays and OME-Zarr multiscale images, through zarrs.
//!
//! Zarr arrays are C-ordered, so a `[z, y, x]` array has the volume's memory layout (x
//! fastest). A path may name the array itself (`store.zarr/path/to/array`) or an OME-Zarr
//! image group whose `multiscales` list the levels (finest first); leading axes of length 1
//! (OME's `t`, `c`) are dropped. Every chunk must be present: the Zarr default of filling
//! absent chunks with the fill value would silently render a hole in a damaged store.

use std::path::Path;
use std::sync::Arc;

use zarrs::array::codec::ZstdCodec;
use zarrs::array::{
    data_type, Array, ArrayBuilder, ArrayToBytesCodecTraits, Element, ElementOwned,
};
use zarrs::filesystem::FilesystemStore;
use zarrs::group::GroupBuilder;

use super::{DataType, Volume, VolumeError, Voxel, VoxelData, Voxels};

/// Chunk edge of the arrays `pofvr convert` writes: a whole number of 16³ bricks.
pub const CHUNK: usize = 64;

/// True when `path` is a Zarr v3 node (a folder with a `zarr.json`).
#[must_use]
pub fn is_zarr(path: &Path) -> bool {
    path.join("zarr.json").is_file()
}

fn decode(file: &Path, why: impl std::fmt::Display) -> VolumeError {
    VolumeError::Decode {
        file: file.display().to_string(),
        why: why.to_string(),
    }
}

fn read_json(path: &Path) -> Result<serde_json::Value, VolumeError> {
    let file = path.join("zarr.json");
    let text = std::fs::read_to_string(&file).map_err(|e| VolumeError::io(&file, e))?;
    serde_json::from_str(&text)
        .map_err(|e| VolumeError::header(&file, "zarr.json", format!("not JSON: {e}")))
}

/// One level of a multiscale image: its array path (relative) and voxel scale (x, y, z).
struct Level {
    path: String,
    scale: [f32; 3],
}

/// The levels of an OME-Zarr image group (0.4: `multiscales` in the attributes, 0.5: under
/// `ome`).
fn levels(group: &Path, meta: &serde_json::Value) -> Result<Vec<Level>, VolumeError> {
    let file = group.join("zarr.json");
    let attrs = &meta["attributes"];
    let ms = attrs["ome"]["multiscales"]
        .as_array()
        .or_else(|| attrs["multiscales"].as_array())
        .ok_or_else(|| {
            VolumeError::header(
                &file,
                "attributes.ome.multiscales",
                "a group without OME-Zarr multiscales: name one of its arrays",
            )
        })?;
    let datasets = ms
        .first()
        .and_then(|m| m["datasets"].as_array())
        .filter(|d| !d.is_empty())
        .ok_or_else(|| VolumeError::header(&file, "multiscales[0].datasets", "missing or empty"))?;
    datasets
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let path = d["path"].as_str().ok_or_else(|| {
                VolumeError::header(&file, &format!("datasets[{i}].path"), "missing")
            })?;
            let scale = d["coordinateTransformations"]
                .as_array()
                .and_then(|t| t.iter().find(|t| t["type"] == "scale"))
                .and_then(|t| t["scale"].as_array())
                .map(|s| {
                    s.iter()
                        .filter_map(serde_json::Value::as_f64)
                        .collect::<Vec<_>>()
                })
                .unwrap_or_default();
            let scale = if scale.len() >= 3 && scale.iter().all(|s| s.is_finite() && *s > 0.0) {
                let n = scale.len();
                [
                    scale[n - 1] as f32,
                    scale[n - 2] as f32,
                    scale[n - 3] as f32,
                ]
            } else {
                [1.0; 3]
            };
            Ok(Level {
                path: path.to_string(),
                scale,
            })
        })
        .collect()
}

/// Opens a Zarr array or OME-Zarr image at `path`. For an image, `level` picks the level
/// (0 the finest); without it the finest level whose largest dimension is at most
/// `max_dim` (when given) is read, else the finest.
///
/// # Errors
/// A [`VolumeError`] naming the file for a bad `zarr.json`, a level that does not exist, an
/// array that is not 3-D (after dropping axes of length 1), an unsupported data type and a
/// missing or corrupt chunk.
pub fn open(
    path: &Path,
    level: Option<usize>,
    max_dim: Option<usize>,
) -> Result<Volume, VolumeError> {
    open_deferring(path, level, max_dim, None)
}

/// [`open`], except that a level of more than `defer_above` bytes is not decoded: the
/// volume's voxels are then not resident ([`Volume::is_resident`]) and a brick store
/// decodes its chunks on demand ([`Volume::zarr_level`]).
///
/// # Errors
/// As [`open`].
pub fn open_deferring(
    path: &Path,
    level: Option<usize>,
    max_dim: Option<usize>,
    defer_above: Option<u64>,
) -> Result<Volume, VolumeError> {
    let meta = read_json(path)?;
    let file = path.join("zarr.json");
    match meta["node_type"].as_str() {
        Some("array") => open_array(path, [1.0; 3], defer_above),
        Some("group") => {
            let levels = levels(path, &meta)?;
            let pick = match level {
                Some(l) if l < levels.len() => l,
                Some(l) => {
                    return Err(VolumeError::header(
                        &file,
                        "multiscales",
                        format!(
                            "no level {l}: the image has levels 0..={}",
                            levels.len() - 1
                        ),
                    ))
                }
                None => {
                    let mut pick = levels.len() - 1;
                    if let Some(m) = max_dim {
                        for (i, l) in levels.iter().enumerate() {
                            let p = path.join(&l.path);
                            let shape = read_json(&p)?["shape"].clone();
                            let fits = shape.as_array().is_some_and(|s| {
                                s.iter().all(|d| d.as_u64().unwrap_or(0) <= m as u64)
                            });
                            if fits {
                                pick = i;
                                break;
                            }
                        }
                    } else {
                        pick = 0;
                    }
                    pick
                }
            };
            let l = &levels[pick];
            open_array(&path.join(&l.path), l.scale, defer_above)
        }
        other => Err(VolumeError::header(
            &file,
            "node_type",
            format!("expected \"array\" or \"group\", got {other:?}"),
        )),
    }
}

fn open_array(
    path: &Path,
    spacing: [f32; 3],
    defer_above: Option<u64>,
) -> Result<Volume, VolumeError> {
    let level = ZarrLevel::open(path)?;
    let source = path.display().to_string();
    let bytes = level.dims.iter().product::<usize>() as u64 * level.dtype.size() as u64;
    if defer_above.is_some_and(|b| bytes > b) {
        // Larger than the budget: the chunks are decoded on demand by the brick store.
        return Volume::deferred(level.dims, spacing, level.dtype, source, Arc::new(level));
    }
    let data = match level.dtype {
        DataType::U8 => VoxelData::U8(Voxels::owned(read_chunks::<u8>(&level)?)),
        DataType::U16 => VoxelData::U16(Voxels::owned(read_chunks::<u16>(&level)?)),
        DataType::I16 => VoxelData::I16(Voxels::owned(read_chunks::<i16>(&level)?)),
        DataType::F32 => VoxelData::F32(Voxels::owned(read_chunks::<f32>(&level)?)),
    };
    Volume::new(level.dims, spacing, data, source)
}

/// One 3-D Zarr array opened for chunk reads: what the whole-level decode reads, and what
/// a brick store decodes chunks from on demand when the level does not fit its memory
/// budget (`crate::store`). Chunk indices and shapes are given x, y, z.
pub struct ZarrLevel {
    array: Array<FilesystemStore>,
    path: std::path::PathBuf,
    dims: [usize; 3],
    dtype: DataType,
    /// Chunk shape, x, y, z (every chunk has it: edge chunks overhang the array).
    chunk: [usize; 3],
    /// Chunks per axis, x, y, z.
    counts: [usize; 3],
    /// Leading axes of length 1 (OME's `t`, `c`).
    lead: usize,
    /// True when a codec other than `bytes` and `transpose` is listed: the encoded size
    /// of a chunk then says nothing about its decoded size.
    compressed: bool,
    /// True when the one compressor is zstd: each chunk is one zstd frame of the chunk.
    zstd_only: bool,
}

/// The decoded size a zstd frame's header claims (`Frame_Content_Size`, RFC 8878 3.1.1.1),
/// when `data` starts with a zstd frame that states it.
pub(crate) fn zstd_content_size(data: &[u8]) -> Option<u64> {
    if data.len() < 5 || data[..4] != [0x28, 0xB5, 0x2F, 0xFD] {
        return None;
    }
    let fhd = data[4];
    let single = fhd & 0x20 != 0;
    let fcs_len = match fhd >> 6 {
        0 if single => 1,
        0 => return None,
        1 => 2,
        2 => 4,
        _ => 8,
    };
    let dict_len = [0, 1, 2, 4][usize::from(fhd & 3)];
    let at = 5 + usize::from(!single) + dict_len;
    let field = data.get(at..at + fcs_len)?;
    let mut v = [0u8; 8];
    v[..fcs_len].copy_from_slice(field);
    let n = u64::from_le_bytes(v);
    Some(if fcs_len == 2 { n + 256 } else { n })
}

impl std::fmt::Debug for ZarrLevel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ZarrLevel")
            .field("path", &self.path)
            .field("dims", &self.dims)
            .field("dtype", &self.dtype)
            .field("chunk", &self.chunk)
            .finish_non_exhaustive()
    }
}

impl ZarrLevel {
    /// Opens the array at `path`, checking its metadata: a supported data type, 3-D after
    /// dropping leading axes of length 1, a regular chunk grid.
    ///
    /// # Errors
    /// A [`VolumeError`] naming the `zarr.json` and the field.
    pub fn open(path: &Path) -> Result<Self, VolumeError> {
        let file = path.join("zarr.json");
        let meta = read_json(path)?;
        let dtype = match meta["data_type"].as_str() {
            Some("uint8") => DataType::U8,
            Some("uint16") => DataType::U16,
            Some("int16") => DataType::I16,
            Some("float32") => DataType::F32,
            other => {
                return Err(VolumeError::header(
                    &file,
                    "data_type",
                    format!("{other:?}: uint8, uint16, int16 and float32 are read"),
                ))
            }
        };
        let store = Arc::new(FilesystemStore::new(path).map_err(|e| decode(path, e))?);
        let array = Array::open(store, "/").map_err(|e| {
            VolumeError::header(
                &file,
                "zarr.json",
                format!("not a readable Zarr v3 array: {e}"),
            )
        })?;
        let shape = array.shape().to_vec();
        let n = shape.len();
        if n < 3 || (0..n - 3).any(|a| shape[a] != 1) {
            return Err(VolumeError::header(
                &file,
                "shape",
                format!("{shape:?}: a 3-D array (leading axes of length 1 allowed) is read"),
            ));
        }
        let to_usize = |v: u64| usize::try_from(v).unwrap_or(usize::MAX);
        let dims = [
            to_usize(shape[n - 1]),
            to_usize(shape[n - 2]),
            to_usize(shape[n - 3]),
        ];
        super::checked_voxel_count(&path.display().to_string(), dims)?;
        let grid = array.chunk_grid_shape().to_vec();
        let bad_grid = |why: String| VolumeError::header(&file, "chunk_grid", why);
        let first = array
            .chunk_shape_usize(&vec![0u64; n])
            .map_err(|e| bad_grid(e.to_string()))?;
        let last_idx: Vec<u64> = grid.iter().map(|g| g.saturating_sub(1)).collect();
        let last = array
            .chunk_shape_usize(&last_idx)
            .map_err(|e| bad_grid(e.to_string()))?;
        if first != last {
            return Err(bad_grid(format!(
                "chunks of shape {first:?} and {last:?}: a regular chunk grid is read"
            )));
        }
        let chunk = [first[n - 1], first[n - 2], first[n - 3]];
        let counts = [
            to_usize(grid[n - 1]),
            to_usize(grid[n - 2]),
            to_usize(grid[n - 3]),
        ];
        // The grid must cover the array with chunks that are not absurdly large: a chunk is
        // decoded whole, so its size is an allocation the file chooses.
        let covers = (0..3).all(|a| chunk[a] > 0 && chunk[a].saturating_mul(counts[a]) >= dims[a]);
        let chunk_bytes = chunk
            .iter()
            .try_fold(dtype.size(), |acc, c| acc.checked_mul(*c))
            .unwrap_or(usize::MAX);
        if !covers || chunk_bytes > MAX_CHUNK_BYTES {
            return Err(bad_grid(format!(
                "chunk shape {first:?} for an array of shape {shape:?}: chunks must cover the array and hold at most {MAX_CHUNK_BYTES} bytes"
            )));
        }
        let compressed = meta["codecs"].as_array().is_none_or(|c| {
            c.iter()
                .any(|c| !matches!(c["name"].as_str(), Some("bytes" | "transpose")))
        });
        let zstd_only = meta["codecs"].as_array().is_some_and(|c| {
            let names: Vec<_> = c.iter().filter_map(|c| c["name"].as_str()).collect();
            names.contains(&"zstd")
                && names
                    .iter()
                    .all(|n| matches!(*n, "bytes" | "transpose" | "zstd"))
                && names.iter().filter(|n| **n == "zstd").count() == 1
        });
        let level = ZarrLevel {
            array,
            path: path.to_path_buf(),
            dims,
            dtype,
            chunk,
            counts,
            lead: n - 3,
            compressed,
            zstd_only,
        };
        level.check_chunk_files()?;
        Ok(level)
    }

    /// Every chunk's file is present and, uncompressed, exactly one chunk long: checked
    /// before anything is sized by the array's shape (a `zarr.json` claiming a huge array
    /// over a few chunks fails here, not in an allocation).
    fn check_chunk_files(&self) -> Result<(), VolumeError> {
        let bytes = self.chunk_bytes();
        for kz in 0..self.counts[2] {
            for ky in 0..self.counts[1] {
                for kx in 0..self.counts[0] {
                    let (idx, file) = self.chunk_file([kx, ky, kz]);
                    let len = match std::fs::metadata(&file) {
                        Ok(m) if m.is_file() => m.len(),
                        _ => {
                            return Err(decode(
                                &file,
                                format!("chunk {idx:?} is missing from the store"),
                            ))
                        }
                    };
                    self.check_encoded_len(&file, len)?;
                }
            }
        }
        debug_assert!(bytes > 0);
        Ok(())
    }

    /// An uncompressed chunk holds exactly its voxels.
    fn check_encoded_len(&self, file: &Path, len: u64) -> Result<(), VolumeError> {
        let bytes = self.chunk_bytes() as u64;
        if !self.compressed && len != bytes {
            return Err(decode(
                file,
                format!(
                    "an uncompressed chunk of {:?} {} voxels is {bytes} bytes, the file has {len}",
                    self.chunk, self.dtype
                ),
            ));
        }
        Ok(())
    }

    fn chunk_bytes(&self) -> usize {
        self.chunk.iter().product::<usize>() * self.dtype.size()
    }

    /// The zarrs indices (leading axes, z, y, x) of chunk `c` and its file.
    fn chunk_file(&self, c: [usize; 3]) -> (Vec<u64>, std::path::PathBuf) {
        let mut idx = vec![0u64; self.lead];
        idx.extend([c[2] as u64, c[1] as u64, c[0] as u64]);
        let key = self.array.chunk_key(&idx);
        let file = self.path.join(key.as_str());
        (idx, file)
    }

    /// The array's folder.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Voxels along x, y, z.
    #[must_use]
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// The stored type.
    #[must_use]
    pub fn data_type(&self) -> DataType {
        self.dtype
    }

    /// The chunk shape along x, y, z.
    #[must_use]
    pub fn chunk_shape(&self) -> [usize; 3] {
        self.chunk
    }

    /// Chunks along x, y, z.
    #[must_use]
    pub fn chunk_counts(&self) -> [usize; 3] {
        self.counts
    }

    /// Decodes chunk `c` (x, y, z chunk indices) into its voxels, x fastest, in the
    /// chunk's full shape; with the bytes read from the store for it (compressed).
    ///
    /// # Errors
    /// [`VolumeError::Decode`] naming the chunk's file when it is missing, cannot be
    /// decoded, or (float data) holds a NaN or Inf.
    pub fn read_chunk(&self, c: [usize; 3]) -> Result<(VoxelData, u64), VolumeError> {
        Ok(match self.dtype {
            DataType::U8 => {
                let (v, b) = self.chunk::<u8>(c)?;
                (VoxelData::U8(Voxels::owned(v)), b)
            }
            DataType::U16 => {
                let (v, b) = self.chunk::<u16>(c)?;
                (VoxelData::U16(Voxels::owned(v)), b)
            }
            DataType::I16 => {
                let (v, b) = self.chunk::<i16>(c)?;
                (VoxelData::I16(Voxels::owned(v)), b)
            }
            DataType::F32 => {
                let (v, b) = self.chunk::<f32>(c)?;
                (VoxelData::F32(Voxels::owned(v)), b)
            }
        })
    }

    /// Chunk `c` as `T` (the array's own type) and its encoded size.
    fn chunk<T: Voxel + ElementOwned>(&self, c: [usize; 3]) -> Result<(Vec<T>, u64), VolumeError> {
        let (idx, file) = self.chunk_file(c);
        let encoded = self
            .array
            .retrieve_encoded_chunk(&idx)
            .map_err(|e| decode(&file, e))?
            .ok_or_else(|| decode(&file, format!("chunk {idx:?} is missing from the store")))?;
        let bytes = encoded.len() as u64;
        // The file may have changed since the store was opened.
        self.check_encoded_len(&file, bytes)?;
        // zstd sizes its output by the frame's own claim: a damaged one must not decide an
        // allocation. A chunk decodes to exactly its voxels.
        if let Some(claim) = zstd_content_size(&encoded) {
            let want = self.chunk_bytes() as u64;
            if self.zstd_only && claim != want {
                return Err(decode(
                    &file,
                    format!("the zstd frame claims {claim} bytes, the chunk holds {want}"),
                ));
            }
        }
        let shape = self.array.chunk_shape(&idx).map_err(|e| decode(&file, e))?;
        let decoded = self
            .array
            .codecs()
            .decode(
                std::borrow::Cow::Owned(encoded),
                &shape,
                self.array.data_type(),
                self.array.fill_value(),
                &zarrs::array::CodecOptions::default(),
            )
            .map_err(|e| decode(&file, e))?;
        let shape_u64: Vec<u64> = shape.iter().map(|s| s.get()).collect();
        let v = <Vec<T> as zarrs::array::FromArrayBytes>::from_array_bytes(
            decoded.into_owned(),
            &shape_u64,
            self.array.data_type(),
        )
        .map_err(|e| decode(&file, e))?;
        if v.len() != self.chunk.iter().product::<usize>() {
            return Err(decode(
                &file,
                format!(
                    "decoded {} voxels, the chunk holds {:?}",
                    v.len(),
                    self.chunk
                ),
            ));
        }
        if T::TYPE == DataType::F32 {
            self.check_finite(&v, c, &file)?;
        }
        Ok((v, bytes))
    }

    /// Float voxels inside the array are finite (an edge chunk's overhang is not part of
    /// the volume and may hold a NaN fill value).
    fn check_finite<T: Voxel>(
        &self,
        v: &[T],
        c: [usize; 3],
        file: &Path,
    ) -> Result<(), VolumeError> {
        let [cx, cy, cz] = self.chunk;
        let n: [usize; 3] =
            std::array::from_fn(|a| self.chunk[a].min(self.dims[a] - c[a] * self.chunk[a]));
        for z in 0..n[2].min(cz) {
            for y in 0..n[1].min(cy) {
                let row = &v[(z * cy + y) * cx..][..n[0]];
                if let Some(x) = row.iter().position(|x| !x.to_f32().is_finite()) {
                    let at = [c[0] * cx + x, c[1] * cy + y, c[2] * cz + z];
                    return Err(decode(
                        file,
                        format!(
                            "non-finite value {} at voxel {at:?}: NaN/Inf are rejected",
                            row[x].to_f32()
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// The largest decoded chunk read (1 GiB): chunks are decoded whole.
const MAX_CHUNK_BYTES: usize = 1 << 30;

/// Decodes every chunk (in parallel) into one x-fastest buffer, failing on an absent one.
fn read_chunks<T: Voxel + ElementOwned + Default>(
    level: &ZarrLevel,
) -> Result<Vec<T>, VolumeError> {
    use rayon::prelude::*;
    let dims = level.dims;
    let [cx, cy, cz] = level.chunk;
    let plane = dims[0] * dims[1];
    let mut out = vec![T::default(); plane * dims[2]];
    // One z-row of chunks at a time, so each task owns a disjoint slab of the output.
    let per_row = cz * plane;
    out.par_chunks_mut(per_row)
        .enumerate()
        .try_for_each(|(kz, slab)| {
            for ky in 0..level.counts[1] {
                for kx in 0..level.counts[0] {
                    let (data, _) = level.chunk::<T>([kx, ky, kz])?;
                    for z in 0..cz.min(dims[2] - kz * cz) {
                        for y in 0..cy.min(dims[1] - ky * cy) {
                            let w = cx.min(dims[0] - kx * cx);
                            let src = &data[(z * cy + y) * cx..][..w];
                            let dst = z * plane + (ky * cy + y) * dims[0] + kx * cx;
                            slab[dst..dst + w].copy_from_slice(src);
                        }
                    }
                }
            }
            Ok(())
        })?;
    Ok(out)
}

/// Writes `volume` as an OME-Zarr (0.5, Zarr v3) image at `out`: level 0 the volume,
/// each further level half the previous (2×2×2 means) down to a chunk, every array in
/// [`CHUNK`]³ chunks compressed with zstd. Slabs one chunk deep go through memory at a
/// time, and a memory-mapped input has its pages released after each, so the resident
/// size stays near a slab of every level. The store is written to a temporary folder
/// beside `out` and renamed into place when complete; `progress(done, total)` is called
/// after each slab.
///
/// # Errors
/// [`VolumeError::Io`] when `out` exists or cannot be written, [`VolumeError::Decode`]
/// for a store error; nothing is left at `out` on error.
pub fn write_ome_zarr(
    volume: &Volume,
    out: &Path,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<(), VolumeError> {
    if out.exists() {
        return Err(VolumeError::io(
            out,
            std::io::Error::new(std::io::ErrorKind::AlreadyExists, "already exists"),
        ));
    }
    let parent = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = tempfile::Builder::new()
        .prefix(&format!(".{name}.tmp"))
        .tempdir_in(parent)
        .map_err(|e| VolumeError::io(parent, e))?;
    let r = match volume.data() {
        VoxelData::U8(v) => write_levels(volume, v, tmp.path(), data_type::uint8(), progress),
        VoxelData::U16(v) => write_levels(volume, v, tmp.path(), data_type::uint16(), progress),
        VoxelData::I16(v) => write_levels(volume, v, tmp.path(), data_type::int16(), progress),
        VoxelData::F32(v) => write_levels(volume, v, tmp.path(), data_type::float32(), progress),
    };
    r?;
    let tmp = tmp.keep();
    std::fs::rename(&tmp, out).map_err(|e| {
        let _ = std::fs::remove_dir_all(&tmp);
        VolumeError::io(out, e)
    })
}

fn level_dims(dims: [usize; 3]) -> Vec<[usize; 3]> {
    let mut v = vec![dims];
    while let Some(d) = v.last().copied() {
        if d.iter().all(|x| *x <= CHUNK) || d.iter().any(|x| *x < 4) {
            break;
        }
        v.push(d.map(|x| x.div_ceil(2)));
    }
    v
}

fn write_levels<T: Voxel + Element + ElementOwned + Default>(
    volume: &Volume,
    voxels: &Voxels<T>,
    root: &Path,
    dt: zarrs::array::DataType,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<(), VolumeError> {
    let err = |e: &dyn std::fmt::Display| decode(root, e);
    let store = Arc::new(FilesystemStore::new(root).map_err(|e| err(&e))?);
    let all = level_dims(volume.dims());
    let total: u64 = all.iter().map(|d| d[2].div_ceil(CHUNK) as u64).sum();
    let mut done = 0u64;
    let sp = volume.spacing();
    let mut datasets = Vec::new();
    let mut arrays: Vec<Array<FilesystemStore>> = Vec::new();
    for (l, d) in all.iter().enumerate() {
        let f = (1u32 << l) as f32;
        let array = ArrayBuilder::new(
            vec![d[2] as u64, d[1] as u64, d[0] as u64],
            vec![CHUNK as u64; 3],
            dt.clone(),
            // Zero bytes: the zero of every stored type.
            zarrs::array::FillValue::new(vec![0u8; std::mem::size_of::<T>()]),
        )
        .dimension_names(["z", "y", "x"].into())
        .bytes_to_bytes_codecs(vec![Arc::new(ZstdCodec::new(3, false))])
        .build(store.clone(), &format!("/{l}"))
        .map_err(|e| err(&e))?;
        array.store_metadata().map_err(|e| err(&e))?;
        datasets.push(serde_json::json!({
            "path": l.to_string(),
            "coordinateTransformations": [{"type": "scale", "scale": [sp[2] * f, sp[1] * f, sp[0] * f]}]
        }));
        arrays.push(array);
    }
    let mut group = GroupBuilder::new()
        .build(store.clone(), "/")
        .map_err(|e| err(&e))?;
    group.attributes_mut().insert(
        "ome".into(),
        serde_json::json!({
            "version": "0.5",
            "multiscales": [{
                "name": volume.source(),
                "axes": [
                    {"name": "z", "type": "space"},
                    {"name": "y", "type": "space"},
                    {"name": "x", "type": "space"}
                ],
                "datasets": datasets,
                "type": "mean"
            }]
        }),
    );
    group.store_metadata().map_err(|e| err(&e))?;
    // Every chunk is stored, even one all zero (Zarr's default skips those), so that a
    // reader can tell a damaged store from an empty region.
    let all_chunks = zarrs::array::CodecOptions::default().with_store_empty_chunks(true);
    let src = voxels.as_slice();
    let [nx, ny, nz] = volume.dims();
    let plane = nx * ny;
    for z0 in (0..nz).step_by(CHUNK) {
        let z1 = (z0 + CHUNK).min(nz);
        arrays[0]
            .store_array_subset_opt(
                &[z0 as u64..z1 as u64, 0..ny as u64, 0..nx as u64],
                &src[z0 * plane..z1 * plane],
                &all_chunks,
            )
            .map_err(|e| err(&e))?;
        // The slab is in the store: let the mapping's pages go so that a file larger than
        // memory streams through.
        voxels.release_pages();
        done += 1;
        progress(done, total);
    }
    for l in 1..all.len() {
        let (fine, coarse) = (all[l - 1], all[l]);
        for z0 in (0..coarse[2]).step_by(CHUNK) {
            let z1 = (z0 + CHUNK).min(coarse[2]);
            let (fz0, fz1) = (2 * z0, (2 * z1).min(fine[2]));
            let slab: Vec<T> = arrays[l - 1]
                .retrieve_array_subset(&[
                    fz0 as u64..fz1 as u64,
                    0..fine[1] as u64,
                    0..fine[0] as u64,
                ])
                .map_err(|e| err(&e))?;
            let half = downsample(
                &slab,
                [fine[0], fine[1], fz1 - fz0],
                [coarse[0], coarse[1], z1 - z0],
            );
            arrays[l]
                .store_array_subset_opt(
                    &[
                        z0 as u64..z1 as u64,
                        0..coarse[1] as u64,
                        0..coarse[0] as u64,
                    ],
                    &half,
                    &all_chunks,
                )
                .map_err(|e| err(&e))?;
            done += 1;
            progress(done, total);
        }
    }
    Ok(())
}

/// 2×2×2 means (the edge voxel repeated where an odd size has no pair), rounded back to
/// the stored type.
fn downsample<T: Voxel + Default>(src: &[T], fine: [usize; 3], coarse: [usize; 3]) -> Vec<T> {
    let mut out = Vec::with_capacity(coarse.iter().product());
    let at = |x: usize, y: usize, z: usize| src[x + fine[0] * (y + fine[1] * z)].to_f32();
    for z in 0..coarse[2] {
        for y in 0..coarse[1] {
            for x in 0..coarse[0] {
                let mut sum = 0.0f32;
                for dz in 0..2 {
                    for dy in 0..2 {
                        for dx in 0..2 {
                            let (i, j, k) = (
                                (2 * x + dx).min(fine[0] - 1),
                                (2 * y + dy).min(fine[1] - 1),
                                (2 * z + dz).min(fine[2] - 1),
                            );
                            sum += at(i, j, k);
                        }
                    }
                }
                out.push(T::from_f32(sum / 8.0));
            }
        }
    }
    out
}
