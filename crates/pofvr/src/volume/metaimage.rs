//! Reader for metaimage files (being written).
use std::path::Path;

use super::{Volume, VolumeError};

/// Opens a metaimage file.
///
/// # Errors
/// Always, until the reader lands.
pub fn open(path: &Path) -> Result<Volume, VolumeError> {
    Err(VolumeError::header(
        path,
        "format",
        "metaimage reader not built yet",
    ))
}
