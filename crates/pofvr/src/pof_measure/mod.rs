//! Measurements of POF tables that `pof build` and `bench pof` report.
//!
//! - [`timed`]: a build with its wall and CPU time, the bricks it computed and its rate.
//! - [`strength`]: how opaque a table's lookups are over its view cells, which is how much
//!   it can cull.
//!
//! Whether a table is conservative is [`crate::check::audit`]'s question.

pub mod strength;
pub mod timed;

pub use strength::{cell_opacities, CellOpacities};
pub use timed::{build_timed, process_cpu_seconds, TimedBuild};
