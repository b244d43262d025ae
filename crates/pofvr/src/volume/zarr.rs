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
use zarrs::array::{data_type, Array, ArrayBuilder, Element, ElementOwned};
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
    let meta = read_json(path)?;
    let file = path.join("zarr.json");
    match meta["node_type"].as_str() {
        Some("array") => open_array(path, [1.0; 3]),
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
            open_array(&path.join(&l.path), l.scale)
        }
        other => Err(VolumeError::header(
            &file,
            "node_type",
            format!("expected \"array\" or \"group\", got {other:?}"),
        )),
    }
}

fn open_array(path: &Path, spacing: [f32; 3]) -> Result<Volume, VolumeError> {
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
    let dims = [
        shape[n - 1] as usize,
        shape[n - 2] as usize,
        shape[n - 3] as usize,
    ];
    let source = path.display().to_string();
    super::checked_voxel_count(&source, dims)?;
    let data = match dtype {
        DataType::U8 => VoxelData::U8(Voxels::owned(read_chunks::<u8>(&array, path, dims)?)),
        DataType::U16 => VoxelData::U16(Voxels::owned(read_chunks::<u16>(&array, path, dims)?)),
        DataType::I16 => VoxelData::I16(Voxels::owned(read_chunks::<i16>(&array, path, dims)?)),
        DataType::F32 => VoxelData::F32(Voxels::owned(read_chunks::<f32>(&array, path, dims)?)),
    };
    Volume::new(dims, spacing, data, source)
}

/// Decodes every chunk (in parallel) into one x-fastest buffer, failing on an absent one.
fn read_chunks<T: Voxel + ElementOwned + Default>(
    array: &Array<FilesystemStore>,
    path: &Path,
    dims: [usize; 3],
) -> Result<Vec<T>, VolumeError> {
    use rayon::prelude::*;
    let n = array.shape().len();
    let grid = array.chunk_grid_shape().to_vec();
    let lead = vec![0u64; n - 3];
    let chunk = array
        .chunk_shape_usize(&vec![0u64; n])
        .map_err(|e| decode(path, e))?;
    let (cz, cy, cx) = (chunk[n - 3], chunk[n - 2], chunk[n - 1]);
    let plane = dims[0] * dims[1];
    let mut out = vec![T::default(); plane * dims[2]];
    // One z-row of chunks at a time, so each task owns a disjoint slab of the output.
    let per_row = cz * plane;
    out.par_chunks_mut(per_row)
        .enumerate()
        .try_for_each(|(kz, slab)| {
            for ky in 0..grid[n - 2] as usize {
                for kx in 0..grid[n - 1] as usize {
                    let mut idx = lead.clone();
                    idx.extend([kz as u64, ky as u64, kx as u64]);
                    let key = array.chunk_key(&idx);
                    let data: Vec<T> = array
                        .retrieve_chunk_if_exists(&idx)
                        .map_err(|e| decode(&path.join(key.as_str()), e))?
                        .ok_or_else(|| {
                            decode(
                                &path.join(key.as_str()),
                                format!("chunk {idx:?} is missing from the store"),
                            )
                        })?;
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
