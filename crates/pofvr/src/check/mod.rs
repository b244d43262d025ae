//! Checks of correctness that the library, its tests, `pof check` and the experiments share.
//!
//! - [`rule`]: the threshold rule a culled frame obeys against the unculled frame.

pub mod rule;

pub use rule::{check_threshold_rule, RuleReport, IDENTICAL};
