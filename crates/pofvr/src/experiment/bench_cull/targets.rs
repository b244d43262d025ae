//! Targets of the culling bench: a goal for a named measure, met or not.

use serde::{Deserialize, Serialize};

use crate::experiment::ExperimentError;

/// A goal for one of [`CullBench::measures`](super::CullBench::measures), as a targets
/// file lists it.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TargetSpec {
    /// The measure's name.
    pub what: String,
    /// The goal.
    pub target: f64,
    /// The measure must be at most (true) or at least (false) the goal.
    pub at_most: bool,
}

/// A target as measured in one run.
#[derive(Clone, Debug, Serialize)]
pub struct Target {
    /// The measure's name.
    pub what: String,
    /// Its value in this run.
    pub measured: f64,
    /// The goal.
    pub target: f64,
    /// The measure must be at most (true) or at least (false) the goal.
    pub at_most: bool,
    /// Whether the goal was met.
    pub met: bool,
}

/// Each of `specs` against the measure of its name in `measures`, in the order of `specs`.
///
/// # Errors
/// [`ExperimentError::Setting`] for a target whose measure is not in `measures`, listing
/// the measures there are.
pub fn evaluate_targets(
    specs: &[TargetSpec],
    measures: &[(String, f64)],
) -> Result<Vec<Target>, ExperimentError> {
    specs
        .iter()
        .map(|s| {
            let (_, measured) = measures.iter().find(|(n, _)| *n == s.what).ok_or_else(|| {
                ExperimentError::Setting(format!(
                    "no measure named {:?}; the measures are: {}",
                    s.what,
                    measures
                        .iter()
                        .map(|(n, _)| format!("{n:?}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ))
            })?;
            let met = if s.at_most {
                *measured <= s.target
            } else {
                *measured >= s.target
            };
            Ok(Target {
                what: s.what.clone(),
                measured: *measured,
                target: s.target,
                at_most: s.at_most,
                met,
            })
        })
        .collect()
}
