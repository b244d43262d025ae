//! Reader for nrrd files (being written).
use std::path::Path;

use super::{Volume, VolumeError};

/// Opens a nrrd file.
///
/// # Errors
/// Always, until the reader lands.
pub fn open(path: &Path) -> Result<Volume, VolumeError> {
    Err(VolumeError::header(
        path,
        "format",
        "nrrd reader not built yet",
    ))
}
