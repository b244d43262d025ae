//! Reader for nifti files (being written).
use std::path::Path;

use super::{Volume, VolumeError};

/// Opens a nifti file.
///
/// # Errors
/// Always, until the reader lands.
pub fn open(path: &Path) -> Result<Volume, VolumeError> {
    Err(VolumeError::header(
        path,
        "format",
        "nifti reader not built yet",
    ))
}
