/// Errors from opening or validating a volume. Every message names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum VolumeError {
    /// An I/O error on a named file.
    #[error("{file}: {err}")]
    Io {
        /// The file.
        file: String,
        /// The underlying error.
        #[source]
        err: std::io::Error,
    },
    /// The data are shorter or longer than the header says.
    #[error("{file}: data size mismatch: expected {expected} bytes from dims × type, got {got}")]
    SizeMismatch {
        /// The file.
        file: String,
        /// Bytes expected.
        expected: u64,
        /// Bytes found.
        got: u64,
    },
    /// Zero or overflowing dimensions.
    #[error("{file}: bad dimensions {dims:?}: {why}")]
    BadDims {
        /// The file.
        file: String,
        /// The dimensions given.
        dims: [usize; 3],
        /// Why they are rejected.
        why: String,
    },
    /// Spacing not finite and positive, or a world extent that overflows.
    #[error("{file}: bad spacing {spacing:?}: every component must be finite and > 0, and the world extent (spacing × voxels) finite")]
    BadSpacing {
        /// The file.
        file: String,
        /// The spacing given.
        spacing: [f32; 3],
    },
    /// NaN or Inf in float data (rejected, see the README).
    #[error("{file}: non-finite value {value} at voxel index {index}: NaN/Inf are rejected")]
    NonFinite {
        /// The file.
        file: String,
        /// Linear voxel index.
        index: u64,
        /// The value found.
        value: f32,
    },
    /// A header is malformed, lacks a field or uses an unsupported value.
    #[error("{file}: header field {field:?}: {why}")]
    Header {
        /// The file.
        file: String,
        /// The field concerned.
        field: String,
        /// What is wrong.
        why: String,
    },
    /// Compressed data could not be decoded (truncated or corrupt).
    #[error("{file}: compressed data: {why}")]
    Decode {
        /// The file.
        file: String,
        /// What failed.
        why: String,
    },
    /// Extension not recognised and no raw layout given.
    #[error("{file}: unknown volume format: use .nrrd, .nhdr, .mhd, .mha, .nii, .nii.gz, a folder of DICOM slices, a Zarr array or OME-Zarr image, or give a raw file's dimensions and voxel type")]
    UnknownFormat {
        /// The file.
        file: String,
    },
}

impl VolumeError {
    /// Wraps an I/O error with the file it concerns.
    pub(crate) fn io(path: &std::path::Path, err: std::io::Error) -> Self {
        VolumeError::Io {
            file: path.display().to_string(),
            err,
        }
    }
    /// A header problem.
    pub(crate) fn header(source: &std::path::Path, field: &str, why: impl Into<String>) -> Self {
        VolumeError::Header {
            file: source.display().to_string(),
            field: field.to_string(),
            why: why.into(),
        }
    }
}
