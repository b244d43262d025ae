//! What culling needs of precomputed POFs: a lower bound of a brick's composited opacity
//! over its core footprint ([`OpacityBound`]), and POF tables of several core lengths
//! used together ([`CoreLevels`]).

use glam::DVec3;

use crate::brick::{BrickGrid, BrickId};
use crate::pof::{PofMode, PofTable};

/// A lower bound of a brick's composited opacity over its core footprint: what culling
/// needs of precomputed POFs.
pub trait OpacityBound: Sync {
    /// Minimum `t`-span (in units of the smallest spacing) of a ray inside a brick for the
    /// bound to hold on that ray.
    fn core_length(&self) -> f32;
    /// Bound for parallel rays of unit world direction `dir`.
    fn opacity(&self, brick: BrickId, dir: DVec3, weights: &[f32], aggressive: bool) -> f32;
    /// Bound for every ray whose direction lies within `half_angle` of `axis`.
    fn opacity_cone(
        &self,
        brick: BrickId,
        axis: DVec3,
        half_angle: f64,
        weights: &[f32],
        aggressive: bool,
    ) -> f32;
    /// A hint that [`OpacityBound::opacity`] will soon be asked for each of `bricks` along
    /// `dir`: an implementation may start loading what those lookups read.
    fn prefetch(&self, _bricks: &[BrickId], _dir: DVec3) {}
    /// Bounds for rays that run further inside each brick (longer
    /// [`OpacityBound::core_length`]s, increasing with `k`), tighter where they apply:
    /// `deeper(0)` is the next longer core; `None` past the last (at once when there is
    /// none).
    fn deeper(&self, _k: usize) -> Option<&dyn OpacityBound> {
        None
    }
    /// The grid of the bricks the bounds are for, when finer than the render bricks (each
    /// render brick then gets the bounds of its sub-bricks); `None` when they are the render
    /// bricks.
    fn grid(&self) -> Option<&BrickGrid> {
        None
    }
    /// Bounds for the sub-bricks of the render bricks (their [`OpacityBound::grid`] says
    /// which), used together with these: each pixel gets the higher of the two.
    fn sub_bricks(&self) -> Option<&dyn OpacityBound> {
        None
    }
    /// The early-termination threshold of the renderer the bounds are for: a render brick
    /// stops compositing there, so what its sub-bricks' bounds add up to is capped at it.
    fn ert(&self) -> f32 {
        1.0
    }
}

/// POF tables of one family built with different core lengths, shortest first: each pixel
/// of a brick's footprint gets the bound of the longest core its ray runs through.
///
/// Why: a POF holds for every ray running at least `L` inside the brick, so its value is
/// that of the shortest such rays; in oblique views most rays run much longer, and a table
/// built for a longer `L` bounds them far more tightly, over a smaller core.
pub struct CoreLevels {
    /// The tables by core length, shortest first; never empty.
    tables: Vec<PofTable>,
    /// The tables' brick grid when finer than the render bricks ([`OpacityBound::grid`]).
    fine: Option<BrickGrid>,
    /// Levels for sub-bricks, beside these ([`OpacityBound::sub_bricks`]).
    sub: Option<Box<CoreLevels>>,
}

impl CoreLevels {
    /// Orders `tables` by core length; `None` when there is none.
    ///
    /// # Errors
    /// A message naming two tables with the same core length.
    pub fn new(mut tables: Vec<PofTable>) -> Result<Option<Self>, String> {
        tables.sort_by(|a, b| a.core_length().total_cmp(&b.core_length()));
        if let Some(w) = tables
            .windows(2)
            .find(|w| w[0].core_length() == w[1].core_length())
        {
            return Err(format!(
                "two POF tables with core length {}: each level needs its own core length",
                w[0].core_length()
            ));
        }
        Ok((!tables.is_empty()).then_some(CoreLevels {
            tables,
            fine: None,
            sub: None,
        }))
    }

    /// Declares the tables to be for `fine`, a grid of sub-bricks of the render bricks
    /// (built with a brick size dividing theirs): culling then composites, over each
    /// visible brick, the bounds of its sub-bricks.
    ///
    /// Why: a POF is a minimum over a brick's footprint, so one transparent corner of a
    /// brick (the edge of a skull-stripping mask) zeroes it; sub-bricks confine that loss
    /// to the corner, while rendering keeps the larger bricks.
    #[must_use]
    pub fn with_grid(mut self, fine: BrickGrid) -> Self {
        self.fine = Some(fine);
        self
    }

    /// Adds `sub`, levels for sub-bricks (made [`CoreLevels::with_grid`]), to these levels
    /// of the render bricks: culling takes the higher of the two bounds at each pixel.
    #[must_use]
    pub fn with_sub_bricks(mut self, sub: CoreLevels) -> Self {
        self.sub = Some(Box::new(sub));
        self
    }

    /// The levels for sub-bricks, if any.
    #[must_use]
    pub fn sub_levels(&self) -> Option<&CoreLevels> {
        self.sub.as_deref()
    }

    /// The table with the shortest core (the others differ only in their core length).
    #[must_use]
    pub fn first(&self) -> &PofTable {
        &self.tables[0]
    }

    /// Whether every level holds POF sets (for `--cull pof-set`).
    #[must_use]
    pub fn has_sets(&self) -> bool {
        self.tables.iter().all(PofTable::has_sets)
    }

    /// The core lengths, shortest first.
    #[must_use]
    pub fn core_lengths(&self) -> Vec<f32> {
        self.tables.iter().map(PofTable::core_length).collect()
    }
}

/// One table is one level.
impl From<PofTable> for CoreLevels {
    fn from(first: PofTable) -> Self {
        CoreLevels {
            tables: vec![first],
            fine: None,
            sub: None,
        }
    }
}

/// The levels bound as their shortest core does; the longer ones are [`OpacityBound::deeper`].
impl OpacityBound for CoreLevels {
    fn core_length(&self) -> f32 {
        self.first().core_length()
    }
    fn opacity(&self, brick: BrickId, dir: DVec3, weights: &[f32], aggressive: bool) -> f32 {
        OpacityBound::opacity(self.first(), brick, dir, weights, aggressive)
    }
    fn opacity_cone(
        &self,
        brick: BrickId,
        axis: DVec3,
        half_angle: f64,
        weights: &[f32],
        aggressive: bool,
    ) -> f32 {
        OpacityBound::opacity_cone(self.first(), brick, axis, half_angle, weights, aggressive)
    }
    fn prefetch(&self, bricks: &[BrickId], dir: DVec3) {
        for t in &self.tables {
            OpacityBound::prefetch(t, bricks, dir);
        }
    }
    fn deeper(&self, k: usize) -> Option<&dyn OpacityBound> {
        self.tables.get(k + 1).map(|t| t as &dyn OpacityBound)
    }
    fn grid(&self) -> Option<&BrickGrid> {
        self.fine.as_ref()
    }
    fn sub_bricks(&self) -> Option<&dyn OpacityBound> {
        self.sub.as_deref().map(|s| s as &dyn OpacityBound)
    }
    fn ert(&self) -> f32 {
        self.first().ert()
    }
}

/// Culling reads POFs through [`OpacityBound`]; the POF module knows nothing of culling.
impl OpacityBound for PofTable {
    fn core_length(&self) -> f32 {
        PofTable::core_length(self)
    }
    fn opacity(&self, brick: BrickId, dir: DVec3, weights: &[f32], aggressive: bool) -> f32 {
        PofTable::opacity(self, brick, dir, weights, pof_mode(self, aggressive))
    }
    fn prefetch(&self, bricks: &[BrickId], dir: DVec3) {
        PofTable::prefetch(self, bricks, dir);
    }
    fn ert(&self) -> f32 {
        PofTable::ert(self)
    }
    fn opacity_cone(
        &self,
        brick: BrickId,
        axis: DVec3,
        half_angle: f64,
        weights: &[f32],
        aggressive: bool,
    ) -> f32 {
        PofTable::opacity_cone(
            self,
            brick,
            axis,
            half_angle,
            weights,
            pof_mode(self, aggressive),
        )
    }
}

/// The lookup mode for a cull: a table without sets answers the aggressive mode
/// conservatively.
fn pof_mode(table: &PofTable, aggressive: bool) -> PofMode {
    if aggressive && table.has_sets() {
        PofMode::Sets
    } else {
        PofMode::Conservative
    }
}
