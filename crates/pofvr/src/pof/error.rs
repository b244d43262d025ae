//! Errors building, reading or writing POF tables.

/// Errors building, reading or writing POF tables.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PofError {
    /// A setting is out of range.
    #[error("POF setting {field}: {why}")]
    Setting {
        /// The setting.
        field: &'static str,
        /// What is wrong.
        why: String,
    },
    /// The file could not be read.
    #[error("{file}: {err}")]
    Io {
        /// The file.
        file: String,
        /// The cause.
        #[source]
        err: std::io::Error,
    },
    /// The file could not be written.
    #[error(transparent)]
    Write(#[from] crate::io::WriteError),
    /// The volume's voxels could not be read (a build that reads them from the file,
    /// [`crate::pof::build_streamed`]).
    #[error(transparent)]
    Volume(#[from] crate::volume::VolumeError),
    /// Not a POF file, or a structurally invalid one.
    #[error("{file}: not a valid POF file: {why}")]
    Format {
        /// The file.
        file: String,
        /// What is wrong.
        why: String,
    },
    /// A section's bytes do not match its checksum.
    #[error("{file}: {section} section is corrupted: CRC32 {got:08x}, expected {expected:08x}")]
    Crc {
        /// The file.
        file: String,
        /// Which section.
        section: &'static str,
        /// Stored checksum.
        expected: u32,
        /// Checksum of the bytes read.
        got: u32,
    },
    /// The file was built for another volume, brick size or family.
    #[error("{file}: built for a different {what}: file has {in_file}, expected {expected} (rebuild it with `pofvr pof build`)")]
    Mismatch {
        /// The file.
        file: String,
        /// What differs.
        what: &'static str,
        /// The file's value.
        in_file: String,
        /// The value of the volume/family given.
        expected: String,
    },
    /// POF sets were asked for but the table has none.
    #[error("{file}: the table has no POF sets (they are built only when asked for)")]
    NoSets {
        /// The file.
        file: String,
    },
    /// A build stopped because its caller asked it to ([`crate::pof::PofTable::build_cancellable`]).
    #[error("POF build cancelled after {done} of {total} bricks")]
    Cancelled {
        /// Bricks finished.
        done: u64,
        /// Bricks to build.
        total: u64,
    },
}
