//! [`Error`]: the one error type of the [`crate::Scene`] facade, with every module's error
//! as a variant and typed variants for what the facade itself checks.
//!
//! Messages say what is wrong with a value ("got X, expected Y") and name files where a
//! file is at fault, but never a command-line flag: a program built on the library adds
//! that context (the `pofvr` binary maps [`Setting`] to its flags).

use crate::brick::BrickError;
use crate::comm::CommError;
use crate::composite::CompositeError;
use crate::cull::CullMode;
use crate::distribute::DistributeError;
use crate::frame::{FrameError, JobError};
use crate::io::WriteError;
use crate::pof::PofError;
use crate::render::camera::CameraError;
use crate::render::TfError;
use crate::volume::VolumeError;

/// `std::result::Result` with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// A numeric setting of a scene or a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Setting {
    /// The ray caster's sample distance, in units of the smallest voxel spacing.
    Step,
    /// The opacity at which a ray stops (early ray termination).
    EarlyTermination,
    /// The opacity at which culling treats a pixel as opaque.
    CullThreshold,
    /// The number of ranks a frame is rendered with.
    Ranks,
}

impl Setting {
    /// What the setting is, in words.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Setting::Step => "sample step",
            Setting::EarlyTermination => "early-termination threshold",
            Setting::CullThreshold => "cull threshold",
            Setting::Ranks => "rank count",
        }
    }
}

impl std::fmt::Display for Setting {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The value a setting was given.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Value {
    /// A real number.
    Real(f32),
    /// A count.
    Count(usize),
}

impl std::fmt::Display for Value {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Value::Real(x) => write!(f, "{x}"),
            Value::Count(n) => write!(f, "{n}"),
        }
    }
}

/// A setting outside its valid range.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{setting}: got {got}, expected {expected}")]
pub struct OutOfRange {
    /// Which setting.
    pub setting: Setting,
    /// The value given.
    pub got: Value,
    /// The valid range, in words.
    pub expected: &'static str,
}

/// Everything that can go wrong opening, setting up or rendering a [`crate::Scene`].
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A volume file could not be opened or is invalid.
    #[error(transparent)]
    Volume(#[from] VolumeError),
    /// A bad brick size or brick id.
    #[error(transparent)]
    Brick(#[from] BrickError),
    /// A transfer-function family file or value is invalid.
    #[error(transparent)]
    Tf(#[from] TfError),
    /// A camera file or value is invalid.
    #[error(transparent)]
    Camera(#[from] CameraError),
    /// A POF file could not be read, is invalid, or was built for something else.
    #[error(transparent)]
    Pof(#[from] PofError),
    /// An output file could not be written.
    #[error(transparent)]
    Write(#[from] WriteError),
    /// Bricks could not be dealt to ranks.
    #[error(transparent)]
    Distribute(#[from] DistributeError),
    /// Compositing failed.
    #[error(transparent)]
    Composite(#[from] CompositeError),
    /// An exchange between ranks failed.
    #[error(transparent)]
    Comm(#[from] CommError),
    /// A setting outside its range.
    #[error(transparent)]
    OutOfRange(#[from] OutOfRange),
    /// A brick grid measured on a volume of other dimensions.
    #[error("brick grid cut from a {got:?} volume, expected {expected:?}")]
    GridMismatch {
        /// The dimensions the grid was cut from.
        got: [usize; 3],
        /// The volume's dimensions.
        expected: [usize; 3],
    },
    /// A weight vector of the wrong length.
    #[error("weights: got {got} values, expected one per basis ({expected})")]
    WeightCount {
        /// Weights given.
        got: usize,
        /// Bases of the family.
        expected: usize,
    },
    /// A negative or non-finite weight.
    #[error("weights[{index}]: got {got}, expected a finite weight ≥ 0")]
    Weight {
        /// Which basis.
        index: usize,
        /// The weight given.
        got: f32,
    },
    /// A POF cull mode without POFs (only through [`crate::frame::render_frame`]: a
    /// [`crate::Cull`] cannot say it).
    #[error("cull mode {} needs precomputed POFs (built by `pofvr pof build`)", .mode.name())]
    NoPofs {
        /// The mode asked for.
        mode: CullMode,
    },
    /// A POF cull mode in a scene with jittered ray starts: POF tables bound what the
    /// unjittered sample lattice composites, and jitter moves every sample.
    #[error("cull mode {} with jittered ray starts: POF tables bound the unjittered sample lattice", .mode.name())]
    JitteredPofs {
        /// The mode asked for.
        mode: CullMode,
    },
    /// An unverified POF cull with POFs built for other basis shapes
    /// ([`crate::Scene::load_pof_predictions`]) or of typical values: they bound nothing.
    #[error("cull mode {} without verification needs POFs that bound the family's opacity, and {why}: verify the frame (--verify or --cull verified) or build bounds (pof build --method bound)", .mode.name())]
    StalePofs {
        /// The mode asked for.
        mode: CullMode,
        /// What differs.
        why: String,
    },
    /// A [`crate::Cull`] carrying another scene's POFs.
    #[error("the frame's POFs belong to another scene: take them from the scene rendered")]
    ForeignPofs,
    /// A frame asked of an engine that cannot render it (the march engine is one process,
    /// unculled, over the whole volume).
    #[error("the {engine} engine cannot render this frame: {why}")]
    Engine {
        /// The engine asked for.
        engine: &'static str,
        /// What the frame asks that the engine does not do.
        why: String,
    },
    /// The ranks of a frame disagreed on what they exchanged.
    #[error("frame gather: {why}")]
    Gather {
        /// What went wrong.
        why: String,
    },
}

impl Error {
    /// The setting out of range, if that is the error.
    #[must_use]
    pub fn out_of_range(&self) -> Option<&OutOfRange> {
        match self {
            Error::OutOfRange(r) => Some(r),
            _ => None,
        }
    }

    /// True when this rank only saw another rank's abort.
    #[must_use]
    pub fn is_abort(&self) -> bool {
        matches!(
            self,
            Error::Comm(CommError::Aborted { .. })
                | Error::Composite(CompositeError::Comm(CommError::Aborted { .. }))
        )
    }
}

impl From<JobError> for Error {
    fn from(e: JobError) -> Self {
        match e {
            JobError::Brick(e) => Error::Brick(e),
            JobError::Tf(e) => Error::Tf(e),
            JobError::OutOfRange(r) => Error::OutOfRange(r),
            JobError::GridMismatch { got, expected } => Error::GridMismatch { got, expected },
        }
    }
}

impl From<FrameError> for Error {
    fn from(e: FrameError) -> Self {
        match e {
            FrameError::NoPofs(mode) => Error::NoPofs { mode },
            FrameError::NoPofsPredictor(_) => Error::NoPofs {
                mode: crate::cull::CullMode::Verified,
            },
            FrameError::OutOfRange(r) => Error::OutOfRange(r),
            FrameError::Gather(why) => Error::Gather { why },
            FrameError::Distribute(e) => Error::Distribute(e),
            FrameError::Composite(e) => Error::Composite(e),
            FrameError::Comm(e) => Error::Comm(e),
            FrameError::Read(e) => Error::Volume(e),
            FrameError::WholeLattice(why) => Error::Engine {
                engine: "reference",
                why,
            },
        }
    }
}
