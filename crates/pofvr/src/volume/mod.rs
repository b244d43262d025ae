//! Stage 1: the scalar volume, kept in its stored type.
//!
//! A [`Volume`] is a dense 3D grid of scalars, x fastest, then y, then z. Data stay in
//! their stored type (a 16-bit CT stays 16-bit in memory) and are memory-mapped where the
//! file layout allows, so opening a volume never copies or reads it twice.
//!
//! Coordinates: voxel `(i, j, k)` sits at index-space point `(i, j, k)` and at world point
//! `(i·sx, j·sy, k·sz)`. The sampled domain is the box `[0, dims-1]` in index space.

mod body;
pub mod dicom;
mod dicom_rle;
mod dicom_scan;
pub mod dicom_write;
mod error;
mod header;
pub mod metaimage;
pub mod nifti;
pub mod nrrd;
pub mod phantom;
pub mod raw;
mod storage;
#[cfg(test)]
mod test;
#[cfg(test)]
mod test_body;
#[cfg(test)]
mod test_dicom;
#[cfg(test)]
mod test_zarr;
pub mod zarr;

use std::path::Path;

pub use error::VolumeError;
pub use raw::{Endian, RawSpec};
pub use storage::Voxels;

/// The stored scalar type of a volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DataType {
    /// Unsigned 8-bit.
    U8,
    /// Unsigned 16-bit.
    U16,
    /// Signed 16-bit.
    I16,
    /// 32-bit IEEE float.
    F32,
}

impl DataType {
    /// Bytes per voxel.
    #[must_use]
    pub fn size(self) -> usize {
        match self {
            DataType::U8 => 1,
            DataType::U16 | DataType::I16 => 2,
            DataType::F32 => 4,
        }
    }

    /// The lowercase name used on the command line and in file headers.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            DataType::U8 => "u8",
            DataType::U16 => "u16",
            DataType::I16 => "i16",
            DataType::F32 => "f32",
        }
    }
}

impl std::fmt::Display for DataType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for DataType {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "u8" | "uint8" | "uchar" => Ok(DataType::U8),
            "u16" | "uint16" | "ushort" => Ok(DataType::U16),
            "i16" | "int16" | "short" => Ok(DataType::I16),
            "f32" | "float32" | "float" => Ok(DataType::F32),
            other => Err(format!(
                "unknown data type {other:?}, expected one of u8, u16, i16, f32"
            )),
        }
    }
}

/// A scalar type a volume may be stored in; the hot loops are generic over it.
pub trait Voxel: bytemuck::Pod + Send + Sync + 'static {
    /// The stored type tag.
    const TYPE: DataType;
    /// Converts to the float the sampler interpolates.
    fn to_f32(self) -> f32;
    /// Reverses the byte order (for big-endian files).
    #[must_use]
    fn swap_bytes(self) -> Self;
    /// The nearest stored value to `v` (rounded and clamped for integers).
    fn from_f32(v: f32) -> Self;
    /// The lesser of two voxels (in the order of [`Voxel::to_f32`], which is monotone), in
    /// the stored type: the range passes reduce whole rows of them, which vectorises.
    #[must_use]
    fn min_of(self, o: Self) -> Self;
    /// The greater of two voxels (see [`Voxel::min_of`]).
    #[must_use]
    fn max_of(self, o: Self) -> Self;
    /// `[min, max]` of `v` as floats; `[∞, −∞]` when `v` is empty. Reduced in the stored
    /// type and converted once: the conversion is monotone, so the result is the same.
    #[inline]
    fn range_f32(v: &[Self]) -> [f32; 2] {
        let Some((&first, rest)) = v.split_first() else {
            return [f32::INFINITY, f32::NEG_INFINITY];
        };
        let (lo, hi) = rest
            .iter()
            .fold((first, first), |(lo, hi), &x| (lo.min_of(x), hi.max_of(x)));
        [lo.to_f32(), hi.to_f32()]
    }
}

macro_rules! voxel_int {
    ($t:ty, $tag:expr) => {
        impl Voxel for $t {
            const TYPE: DataType = $tag;
            #[inline(always)]
            fn to_f32(self) -> f32 {
                self as f32
            }
            #[inline]
            fn swap_bytes(self) -> Self {
                <$t>::swap_bytes(self)
            }
            #[inline]
            fn from_f32(v: f32) -> Self {
                v.round().clamp(<$t>::MIN as f32, <$t>::MAX as f32) as $t
            }
            #[inline(always)]
            fn min_of(self, o: Self) -> Self {
                Ord::min(self, o)
            }
            #[inline(always)]
            fn max_of(self, o: Self) -> Self {
                Ord::max(self, o)
            }
        }
    };
}
voxel_int!(u8, DataType::U8);
voxel_int!(u16, DataType::U16);
voxel_int!(i16, DataType::I16);

impl Voxel for f32 {
    const TYPE: DataType = DataType::F32;
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
    #[inline]
    fn swap_bytes(self) -> Self {
        f32::from_bits(self.to_bits().swap_bytes())
    }
    #[inline]
    fn from_f32(v: f32) -> Self {
        v
    }
    #[inline(always)]
    fn min_of(self, o: Self) -> Self {
        self.min(o)
    }
    #[inline(always)]
    fn max_of(self, o: Self) -> Self {
        self.max(o)
    }
}

/// The voxels of a volume in their stored type.
#[derive(Debug)]
pub enum VoxelData {
    /// Unsigned 8-bit voxels.
    U8(Voxels<u8>),
    /// Unsigned 16-bit voxels.
    U16(Voxels<u16>),
    /// Signed 16-bit voxels.
    I16(Voxels<i16>),
    /// Float voxels (finite: NaN/Inf are rejected when the volume is opened).
    F32(Voxels<f32>),
}

/// Calls `$body` with `$v` bound to the typed voxel slice, whatever the stored type.
#[macro_export]
macro_rules! with_voxels {
    ($data:expr, $v:ident => $body:expr) => {
        match $data {
            $crate::volume::VoxelData::U8(x) => {
                let $v: &[u8] = x.as_slice();
                $body
            }
            $crate::volume::VoxelData::U16(x) => {
                let $v: &[u16] = x.as_slice();
                $body
            }
            $crate::volume::VoxelData::I16(x) => {
                let $v: &[i16] = x.as_slice();
                $body
            }
            $crate::volume::VoxelData::F32(x) => {
                let $v: &[f32] = x.as_slice();
                $body
            }
        }
    };
}

impl VoxelData {
    /// The stored type.
    #[must_use]
    pub fn data_type(&self) -> DataType {
        match self {
            VoxelData::U8(_) => DataType::U8,
            VoxelData::U16(_) => DataType::U16,
            VoxelData::I16(_) => DataType::I16,
            VoxelData::F32(_) => DataType::F32,
        }
    }

    /// Number of voxels.
    #[must_use]
    pub fn len(&self) -> usize {
        match self {
            VoxelData::U8(x) => x.len(),
            VoxelData::U16(x) => x.len(),
            VoxelData::I16(x) => x.len(),
            VoxelData::F32(x) => x.len(),
        }
    }

    /// True when there are no voxels.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// True when the voxels are served from a memory map rather than an owned buffer.
    #[must_use]
    pub fn is_mapped(&self) -> bool {
        match self {
            VoxelData::U8(x) => x.is_mapped(),
            VoxelData::U16(x) => x.is_mapped(),
            VoxelData::I16(x) => x.is_mapped(),
            VoxelData::F32(x) => x.is_mapped(),
        }
    }
}

/// How to open a volume beyond its path (see [`Volume::open_with`]).
#[derive(Clone, Debug, Default)]
pub struct OpenOptions {
    /// The layout of a headerless file; `None` chooses the reader by extension.
    pub raw: Option<RawSpec>,
    /// The SeriesInstanceUID to read from a DICOM folder holding several.
    pub series: Option<String>,
    /// The level of an OME-Zarr multiscale image (0 the finest).
    pub level: Option<usize>,
    /// Without a level: the finest OME-Zarr level whose largest dimension is at most this.
    pub max_dim: Option<usize>,
    /// A Zarr level of more voxel bytes than this is not decoded when opened: its chunks
    /// are decoded on demand by a brick store under a memory budget (`--memory-budget`;
    /// see [`Volume::is_resident`]). `None`: every level is decoded whole.
    pub defer_above: Option<u64>,
}

/// A dense scalar volume.
#[derive(Debug)]
pub struct Volume {
    dims: [usize; 3],
    spacing: [f32; 3],
    data: VoxelData,
    source: String,
    /// The file and layout the voxels are stored at uncompressed, when they are (raw,
    /// NRRD and MetaImage raw data): what a brick store reads bricks from on demand.
    raw_file: Option<(std::path::PathBuf, RawSpec)>,
    /// The Zarr array whose chunks hold the voxels when they are not resident: what a
    /// brick store decodes on demand.
    zarr: Option<std::sync::Arc<zarr::ZarrLevel>>,
}

impl Volume {
    /// Builds a volume from its parts, checking that the sizes agree and that float data
    /// are finite.
    ///
    /// # Errors
    /// [`VolumeError::BadDims`] when a dimension is zero or the product overflows,
    /// [`VolumeError::SizeMismatch`] when `data` has the wrong length,
    /// [`VolumeError::BadSpacing`] for a non-positive spacing or one that makes the world
    /// extent overflow, and
    /// [`VolumeError::NonFinite`] for NaN or Inf in float data.
    pub fn new(
        dims: [usize; 3],
        spacing: [f32; 3],
        data: VoxelData,
        source: impl Into<String>,
    ) -> Result<Self, VolumeError> {
        let source = source.into();
        let n = checked_voxel_count(&source, dims)?;
        check_spacing(&source, dims, spacing)?;
        if data.len() != n {
            return Err(VolumeError::SizeMismatch {
                file: source,
                expected: n as u64 * data.data_type().size() as u64,
                got: data.len() as u64 * data.data_type().size() as u64,
            });
        }
        if let VoxelData::F32(v) = &data {
            // NaN/Inf would poison every sample that touches them and every value range;
            // rejecting at open time is the documented policy.
            if let Some(i) = v.as_slice().iter().position(|x| !x.is_finite()) {
                return Err(VolumeError::NonFinite {
                    file: source,
                    index: i as u64,
                    value: v.as_slice()[i],
                });
            }
        }
        Ok(Volume {
            dims,
            spacing,
            data,
            source,
            raw_file: None,
            zarr: None,
        })
    }

    /// A volume whose voxels stay in the Zarr array `level` (not decoded): its samplers
    /// cannot run over the whole lattice, a brick store reads its bricks.
    ///
    /// # Errors
    /// As [`Volume::new`] for the dims and spacing.
    pub(crate) fn deferred(
        dims: [usize; 3],
        spacing: [f32; 3],
        dtype: DataType,
        source: String,
        level: std::sync::Arc<zarr::ZarrLevel>,
    ) -> Result<Self, VolumeError> {
        let n = checked_voxel_count(&source, dims)?;
        let data = match dtype {
            DataType::U8 => VoxelData::U8(Voxels::deferred(n)),
            DataType::U16 => VoxelData::U16(Voxels::deferred(n)),
            DataType::I16 => VoxelData::I16(Voxels::deferred(n)),
            DataType::F32 => VoxelData::F32(Voxels::deferred(n)),
        };
        check_spacing(&source, dims, spacing)?;
        Ok(Volume {
            dims,
            spacing,
            data,
            source,
            raw_file: None,
            zarr: Some(level),
        })
    }

    /// Opens a volume file, choosing the reader by extension: `.nrrd`/`.nhdr`,
    /// `.mhd`/`.mha`, `.nii`/`.nii.gz`; anything else needs a [`RawSpec`].
    ///
    /// # Errors
    /// Any [`VolumeError`] of the reader, each naming the file.
    pub fn open(path: &Path, raw: Option<&RawSpec>) -> Result<Self, VolumeError> {
        Self::open_with(
            path,
            &OpenOptions {
                raw: raw.cloned(),
                ..OpenOptions::default()
            },
        )
    }

    /// Opens a volume as [`Volume::open`] does, and also a Zarr v3 array or OME-Zarr image
    /// (a folder with a `zarr.json`) and a folder of DICOM slices (one series:
    /// [`OpenOptions::series`] picks it when there are several).
    ///
    /// # Errors
    /// Any [`VolumeError`] of the reader, each naming the file.
    pub fn open_with(path: &Path, opts: &OpenOptions) -> Result<Self, VolumeError> {
        let name = path.to_string_lossy().to_ascii_lowercase();
        if let Some(spec) = &opts.raw {
            return raw::open(path, spec);
        }
        if zarr::is_zarr(path) {
            return zarr::open_deferring(path, opts.level, opts.max_dim, opts.defer_above);
        }
        if path.is_dir() && dicom::is_series_dir(path) {
            return dicom::open(path, opts.series.as_deref());
        }
        if name.ends_with(".nrrd") || name.ends_with(".nhdr") {
            nrrd::open(path)
        } else if name.ends_with(".mhd") || name.ends_with(".mha") {
            metaimage::open(path)
        } else if name.ends_with(".nii") || name.ends_with(".nii.gz") {
            nifti::open(path)
        } else {
            Err(VolumeError::UnknownFormat {
                file: path.display().to_string(),
            })
        }
    }

    /// Voxel counts along x, y, z.
    #[must_use]
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// World size of a voxel step along x, y, z.
    #[must_use]
    pub fn spacing(&self) -> [f32; 3] {
        self.spacing
    }

    /// Lets go of the resident pages of a memory-mapped volume (see
    /// [`Voxels::release_pages`]); they come back on the next access.
    pub fn release_pages(&self) {
        match self.data() {
            VoxelData::U8(x) => x.release_pages(),
            VoxelData::U16(x) => x.release_pages(),
            VoxelData::I16(x) => x.release_pages(),
            VoxelData::F32(x) => x.release_pages(),
        }
    }

    /// The file and layout of the voxels when they are stored there uncompressed (raw,
    /// NRRD and MetaImage raw data): positioned reads of it give any brick without touching
    /// the rest ([`crate::store`]).
    #[must_use]
    pub fn raw_file(&self) -> Option<(&Path, &RawSpec)> {
        self.raw_file.as_ref().map(|(p, s)| (p.as_path(), s))
    }

    /// False when the voxels are not in memory: a Zarr level larger than the memory budget
    /// it was opened with ([`OpenOptions::defer_above`]), whose chunks a brick store decodes
    /// on demand. Such a volume renders only with the brick engine through its store; what
    /// samples the whole lattice (the march engine, `--whole`, the exact cull) refuses it.
    #[must_use]
    pub fn is_resident(&self) -> bool {
        self.zarr.is_none()
    }

    /// The Zarr array a non-resident volume's chunks are decoded from.
    #[must_use]
    pub fn zarr_level(&self) -> Option<&std::sync::Arc<zarr::ZarrLevel>> {
        self.zarr.as_ref()
    }

    /// A second handle on the volume, sharing its voxels (owned, mapped or borrowed: no
    /// copy), its file and its Zarr level.
    #[must_use]
    pub fn share(&self) -> Volume {
        let data = match &self.data {
            VoxelData::U8(x) => VoxelData::U8(x.share()),
            VoxelData::U16(x) => VoxelData::U16(x.share()),
            VoxelData::I16(x) => VoxelData::I16(x.share()),
            VoxelData::F32(x) => VoxelData::F32(x.share()),
        };
        Volume {
            dims: self.dims,
            spacing: self.spacing,
            data,
            source: self.source.clone(),
            raw_file: self.raw_file.clone(),
            zarr: self.zarr.clone(),
        }
    }

    /// The stored voxels.
    #[must_use]
    pub fn data(&self) -> &VoxelData {
        &self.data
    }

    /// The stored type.
    #[must_use]
    pub fn data_type(&self) -> DataType {
        self.data.data_type()
    }

    /// Where the volume came from (a path or a generator name), for messages.
    #[must_use]
    pub fn source(&self) -> &str {
        &self.source
    }

    /// The unit length of transfer functions and `--step`: the smallest spacing component.
    #[must_use]
    pub fn unit(&self) -> f32 {
        self.spacing[0].min(self.spacing[1]).min(self.spacing[2])
    }

    /// World-space extent of the sampled box `[0, dims-1]·spacing`.
    #[must_use]
    pub fn world_extent(&self) -> [f32; 3] {
        std::array::from_fn(|a| (self.dims[a].saturating_sub(1)) as f32 * self.spacing[a])
    }

    /// Linear index of voxel `(x, y, z)`.
    #[inline]
    #[must_use]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        x + self.dims[0] * (y + self.dims[1] * z)
    }

    /// The value of one voxel as f32 (slow path, for tests and tools).
    #[must_use]
    pub fn value(&self, x: usize, y: usize, z: usize) -> f32 {
        let i = self.index(x, y, z);
        with_voxels!(&self.data, v => v[i].to_f32())
    }
}

/// Rejects a spacing that is not finite and positive, or whose world extent overflows.
fn check_spacing(source: &str, dims: [usize; 3], spacing: [f32; 3]) -> Result<(), VolumeError> {
    // A finite spacing times the voxel count can still overflow f32: every camera and
    // ray built on that extent would be NaN.
    let extent_ok = (0..3).all(|a| ((dims[a].saturating_sub(1)) as f32 * spacing[a]).is_finite());
    if !extent_ok || spacing.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(VolumeError::BadSpacing {
            file: source.to_string(),
            spacing,
        });
    }
    Ok(())
}

/// Multiplies out `dims`, rejecting zeros and overflow.
pub(crate) fn checked_voxel_count(source: &str, dims: [usize; 3]) -> Result<usize, VolumeError> {
    let bad = |why: &str| VolumeError::BadDims {
        file: source.to_string(),
        dims,
        why: why.to_string(),
    };
    if dims.contains(&0) {
        return Err(bad("every dimension must be at least 1"));
    }
    let n = dims
        .iter()
        .try_fold(1usize, |acc, d| acc.checked_mul(*d))
        .ok_or_else(|| bad("the voxel count overflows"))?;
    // Index arithmetic in the samplers is done in i32 lanes on each axis and in usize overall.
    if dims.iter().any(|d| *d > (1 << 24)) || n.checked_mul(4).is_none() {
        return Err(bad(
            "a dimension is larger than 16777216 or the byte size overflows",
        ));
    }
    Ok(n)
}
