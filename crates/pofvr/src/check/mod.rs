//! Checks of correctness that the library, its tests, `pof check` and the experiments share.
//!
//! - [`rule`]: the threshold rule a culled frame obeys against the unculled frame.
//! - [`audit`]: the conservativeness audit of a POF table against brute-force views.

pub mod audit;
pub mod rule;

pub use audit::{audit_table, AuditError, AuditSummary, AuditedTable};
pub use rule::{check_threshold_rule, RuleReport, IDENTICAL};
