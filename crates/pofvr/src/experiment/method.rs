//! A way of culling, as the figures name it.

use crate::cull::{CullMode, OpacityBound};

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
