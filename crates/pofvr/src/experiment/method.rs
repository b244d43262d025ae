//! A way of culling, as the figures name it.

use crate::cull::range_bound::RangeBound;
use crate::cull::{CullMode, OpacityBound};
use crate::frame::RenderJob;

use super::PofBuild;

/// The paper's three weightings (k0, k1) of figure 8's images.
pub const PAPER_WEIGHTS: [(f32, f32); 3] = [(0.05, 1.0), (0.25, 0.9), (0.8, 0.5)];

/// A culling method of the experiments: a mode and the bound it culls with.
#[derive(Clone, Copy)]
pub struct Method<'a> {
    /// The name figures and files use (`none`, `pof-table`, `range-bound`, …).
    pub name: &'static str,
    /// The cull mode.
    pub mode: CullMode,
    /// The bound of the POF modes.
    pub bound: Option<&'a dyn OpacityBound>,
    /// `Some(reason)` when this run cannot measure it.
    pub missing: Option<&'a str>,
    /// Guaranteed to follow the threshold rule; false for the aggressive POF sets, which
    /// are audited for information only.
    pub conservative: bool,
    /// One line saying what it is.
    pub about: &'static str,
}

impl Method<'_> {
    /// True when it can be measured.
    #[must_use]
    pub fn available(&self) -> bool {
        self.missing.is_none()
    }

    /// No culling: every non-empty brick on screen is rendered.
    #[must_use]
    pub fn none() -> Method<'static> {
        Method {
            name: "none",
            mode: CullMode::None,
            bound: None,
            missing: None,
            conservative: true,
            about: "no culling: every non-empty brick on screen is rendered",
        }
    }

    /// Predict, verify, repair with the best predictor ([`crate::cull::Predictor::BEST`],
    /// which needs no POFs): exact by construction, so the figures show what it renders
    /// and repairs against the oracle.
    #[must_use]
    pub fn verified() -> Method<'static> {
        Method {
            name: "verified",
            mode: CullMode::Verified,
            bound: None,
            missing: None,
            conservative: true,
            about: "predict (the low-resolution proxy), verify while compositing, repair the \
                    wrongly culled bricks in one round",
        }
    }

    /// The sequential oracle.
    #[must_use]
    pub fn exact() -> Method<'static> {
        Method {
            name: "exact",
            mode: CullMode::Exact,
            bound: None,
            missing: None,
            conservative: true,
            about: "the sequential oracle: bricks tested against the opacity actually composited",
        }
    }
}

/// The bound from each brick's value range alone, over half a brick's core: the baseline
/// POFs must beat, needing no precompute.
#[must_use]
pub fn range_bound(job: &RenderJob) -> RangeBound {
    RangeBound::new(
        &job.grid,
        &job.sampled,
        job.settings.step,
        job.settings.ert,
        job.grid.brick_size() as f32 / 2.0,
    )
}

/// The methods the figures compare, in their order: none, POF tables, cubic POFs, POF
/// sets (missing for `no_sets` when `pofs` has none), the oracle, the range bound and
/// verified culling.
#[must_use]
pub fn methods<'a>(pofs: &'a PofBuild, range: &'a RangeBound, no_sets: &'a str) -> Vec<Method<'a>> {
    let sets = pofs.sets();
    vec![
        Method::none(),
        Method {
            name: "pof-table",
            mode: CullMode::Pof,
            bound: Some(&pofs.table),
            missing: None,
            conservative: true,
            about: "conservative POF culling, POFs stored as f32 tables",
        },
        Method {
            name: "pof-cubic",
            mode: CullMode::Pof,
            bound: Some(&pofs.cubic),
            missing: None,
            conservative: true,
            about: "conservative POF culling, POFs stored as cubic polynomials",
        },
        Method {
            name: "pof-set",
            mode: CullMode::PofSet,
            bound: sets.map(|t| t as &dyn OpacityBound),
            missing: sets.is_none().then_some(no_sets),
            conservative: false,
            about: "aggressive POF-set culling (not guaranteed; audited for information)",
        },
        Method::exact(),
        Method {
            name: "range-bound",
            mode: CullMode::Pof,
            bound: Some(range),
            missing: None,
            conservative: true,
            about: "the POF culling path with a bound from each brick's value range alone \
                    (no precompute; the baseline POFs must beat)",
        },
        Method::verified(),
    ]
}

/// Why the oracle is not measured under a memory budget the volume does not fit.
pub const NO_EXACT_UNDER_BUDGET: &str =
    "not measured: the volume is read through its brick store (larger than --memory-budget) \
     and the exact oracle composites every brick from the whole lattice, which would map the \
     whole file";

/// Marks as missing, with [`NO_EXACT_UNDER_BUDGET`], the methods that sample the whole
/// lattice (the exact oracle) when `job` reads its volume through a brick store, so that a
/// budgeted run never maps the file whole and the report says why they are absent. Returns
/// the names marked.
pub fn honour_budget(methods: &mut [Method<'_>], job: &RenderJob) -> Vec<&'static str> {
    if !job.store.as_ref().is_some_and(|s| s.source().is_file()) {
        return Vec::new();
    }
    let mut marked = Vec::new();
    for m in methods.iter_mut().filter(|m| m.mode == CullMode::Exact) {
        m.missing = Some(NO_EXACT_UNDER_BUDGET);
        marked.push(m.name);
    }
    marked
}

impl std::fmt::Debug for Method<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Method")
            .field("name", &self.name)
            .field("mode", &self.mode)
            .field("bound", &self.bound.is_some())
            .field("missing", &self.missing)
            .field("conservative", &self.conservative)
            .finish_non_exhaustive()
    }
}
