//! [`Pofs`]: the per-brick opacity bounds a scene culls with, and how they are loaded,
//! checked against the scene, or built from it ([`PofBuild`]).
//!
//! A POF bounds what the ray caster composites with one sample step and one
//! early-termination threshold, so a table is only valid for a scene with both; tables
//! built through [`crate::Scene::build_pofs`] take them from the scene, and tables loaded
//! from files are checked.

use std::path::{Path, PathBuf};

use crate::brick::BrickGrid;
use crate::cull::{CoreLevels, OpacityBound};
use crate::error::Setting;
use crate::frame::RenderJob;
use crate::pof::{Encoding, PofError, PofMethod, PofSettings, PofTable};

/// Per-brick opacity bounds that the POF cull modes read: a POF table, levels of tables
/// ([`CoreLevels`]) or a bound computed from the bricks' value ranges
/// ([`crate::cull::range_bound::RangeBound`]).
///
/// Only a [`crate::Scene`] makes them (they are checked against it there), and a
/// [`crate::Cull`] takes them from the scene by reference, so a POF cull mode always has
/// its bounds.
///
/// Cloning shares the bounds: [`crate::Scene::with_family`] hands them to a scene whose
/// bases are the same.
#[derive(Clone)]
pub struct Pofs {
    bound: std::sync::Arc<dyn OpacityBound + Send>,
    sets: bool,
    /// Why the POFs bound nothing (built for other basis shapes), when they don't: they
    /// then only predict, for verified frames ([`crate::Scene::load_pof_predictions`]).
    stale: Option<String>,
    /// Why the POFs are predictions rather than bounds by construction, when they are
    /// (tables of typical values, `pof build --method typical`): they too may cull a frame
    /// only when it verifies the cull.
    typical: Option<String>,
}

impl std::fmt::Debug for Pofs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pofs")
            .field("core_length", &self.bound.core_length())
            .field("sets", &self.sets)
            .field("stale", &self.stale)
            .field("typical", &self.typical)
            .finish_non_exhaustive()
    }
}

impl Pofs {
    pub(crate) fn new(bound: Box<dyn OpacityBound + Send>, sets: bool) -> Self {
        Pofs {
            bound: bound.into(),
            sets,
            stale: None,
            typical: None,
        }
    }

    /// These POFs marked as built for other basis shapes (`why` says which): predictions
    /// only, which a frame may cull with only when it verifies the cull.
    pub(crate) fn stale(mut self, why: Option<String>) -> Self {
        self.stale = why;
        self
    }

    /// These POFs marked as typical values (`why` names the file): predictions only.
    pub(crate) fn typical(mut self, why: Option<String>) -> Self {
        self.typical = why;
        self
    }

    /// Why these POFs are predictions and not bounds, when a table holds typical values
    /// (`pof build --method typical`); `None` for bounds.
    #[must_use]
    pub fn typical_reason(&self) -> Option<&str> {
        self.typical.as_deref()
    }

    /// Why these POFs bound nothing, when they were built for other basis shapes than the
    /// scene's ([`crate::Scene::load_pof_predictions`]); `None` for POFs of its bases.
    #[must_use]
    pub fn stale_reason(&self) -> Option<&str> {
        self.stale.as_deref()
    }

    /// The bounds, as the culler reads them.
    #[must_use]
    pub fn bound(&self) -> &dyn OpacityBound {
        self.bound.as_ref()
    }

    /// Whether the bounds hold POF sets, which [`crate::Cull::PofSet`] reads (without them
    /// it culls as [`crate::Cull::Pof`] does).
    #[must_use]
    pub fn has_sets(&self) -> bool {
        self.sets
    }

    /// The shortest core length the bounds hold for.
    #[must_use]
    pub fn core_length(&self) -> f32 {
        self.bound.core_length()
    }
}

/// How to build POFs for a scene: every knob of [`PofSettings`] but the sample step and the
/// early-termination threshold, which [`crate::Scene::build_pofs`] takes from the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct PofBuild {
    /// As [`PofSettings::method`].
    pub method: PofMethod,
    /// As [`PofSettings::views`].
    pub views: [usize; 2],
    /// As [`PofSettings::encoding`].
    pub encoding: Encoding,
    /// As [`PofSettings::sets`].
    pub sets: bool,
    /// As [`PofSettings::core_length`].
    pub core_length: Option<f32>,
    /// As [`PofSettings::pitch`].
    pub pitch: f32,
    /// As [`PofSettings::phases`].
    pub phases: usize,
    /// As [`PofSettings::subdiv`].
    pub subdiv: usize,
    /// As [`PofSettings::margin`].
    pub margin: f32,
    /// As [`PofSettings::joint`].
    pub joint: bool,
}

impl Default for PofBuild {
    fn default() -> Self {
        PofBuild::from(&PofSettings::default())
    }
}

impl PofBuild {
    /// The defaults of `method` ([`PofSettings::for_method`]).
    #[must_use]
    pub fn for_method(method: PofMethod) -> Self {
        PofBuild::from(&PofSettings::for_method(method))
    }

    /// The settings of a build for a ray caster with `step` and `ert`.
    #[must_use]
    pub fn settings(&self, step: f32, ert: f32) -> PofSettings {
        PofSettings {
            method: self.method,
            views: self.views,
            encoding: self.encoding,
            sets: self.sets,
            step,
            ert,
            core_length: self.core_length,
            pitch: self.pitch,
            phases: self.phases,
            subdiv: self.subdiv,
            margin: self.margin,
            joint: self.joint,
        }
    }
}

impl From<&PofSettings> for PofBuild {
    /// The knobs of `s`, less its step and threshold.
    fn from(s: &PofSettings) -> Self {
        // Destructured in full, so that a new knob of `PofSettings` cannot be left out.
        let PofSettings {
            method,
            views,
            encoding,
            sets,
            step: _,
            ert: _,
            core_length,
            pitch,
            phases,
            subdiv,
            margin,
            joint,
        } = s.clone();
        PofBuild {
            method,
            views,
            encoding,
            sets,
            core_length,
            pitch,
            phases,
            subdiv,
            margin,
            joint,
        }
    }
}

/// Opens `path` and checks it against `job`'s volume, bricks, bases, step and threshold.
pub(crate) fn load_table(job: &RenderJob, path: &Path) -> Result<PofTable, PofError> {
    let table = PofTable::load(path, &job.volume, &job.grid, &job.tf)?;
    check_sampling(job, &path.display().to_string(), table)
}

/// The table's step and early-termination threshold must be the renderer's.
pub(crate) fn check_sampling(
    job: &RenderJob,
    file: &str,
    table: PofTable,
) -> Result<PofTable, PofError> {
    let mismatch = |what: Setting, in_file: f32, expected: f32| PofError::Mismatch {
        file: file.to_string(),
        what: what.name(),
        in_file: in_file.to_string(),
        expected: expected.to_string(),
    };
    if table.step() != job.settings.step {
        return Err(mismatch(Setting::Step, table.step(), job.settings.step));
    }
    if table.ert() != job.settings.ert {
        return Err(mismatch(
            Setting::EarlyTermination,
            table.ert(),
            job.settings.ert,
        ));
    }
    Ok(table)
}

/// Loads `first` and `more` as levels of one family ([`RenderJob::load_pof_levels`]).
pub(crate) fn load_levels(
    job: &RenderJob,
    first: &Path,
    more: &[PathBuf],
) -> Result<Loaded, PofError> {
    load_levels_for(job, first, more, false)
}

/// Tables loaded as levels, with why they bound nothing when they don't.
pub(crate) struct Loaded {
    /// The levels.
    pub(crate) levels: CoreLevels,
    /// The first mismatch of basis shapes, for tables of other bases.
    pub(crate) stale: Option<String>,
    /// The first table of typical values, named.
    pub(crate) typical: Option<String>,
}

/// Checks `table` against `grid` and `job`'s bases. With `any_shapes`, tables built for
/// other basis shapes (but as many bases) pass, and the mismatch is returned as text.
fn check_table(
    job: &RenderJob,
    grid: &BrickGrid,
    table: &PofTable,
    any_shapes: bool,
) -> Result<Option<String>, PofError> {
    table.check_grid(&job.volume, grid)?;
    match table.check_bases(&job.tf) {
        Ok(()) => Ok(None),
        Err(e) if any_shapes && table.meta().basis_count as usize == job.tf.bases.len() => {
            Ok(Some(e.to_string()))
        }
        Err(e) => Err(e),
    }
}

/// [`load_levels`], and with `any_shapes` accepting tables of other basis shapes: then
/// also the first table's mismatch ([`crate::Scene::load_pof_predictions`]).
pub(crate) fn load_levels_for(
    job: &RenderJob,
    first: &Path,
    more: &[PathBuf],
    any_shapes: bool,
) -> Result<Loaded, PofError> {
    let render = job.grid.brick_size();
    let mut stale: Option<String> = None;
    let mut typical: Option<String> = None;
    let mut own = Vec::new();
    let mut sub: Vec<PofTable> = Vec::new();
    let mut fine: Option<BrickGrid> = None;
    for path in std::iter::once(first).chain(more.iter().map(PathBuf::as_path)) {
        let file = path.display().to_string();
        // Opened (mapped and CRC-checked) once, then matched to the grid its size says.
        let table = PofTable::open(path)?;
        // A typical value is a quantile, not a minimum: it predicts and bounds nothing,
        // so an unverified cull with it could hide visible bricks (measured: the opaque
        // MRI family loses bricks the oracle keeps).
        if table.meta().method == PofMethod::Typical && typical.is_none() {
            typical = Some(format!(
                "{file} holds typical values (pof build --method typical), which predict a cull but bound nothing"
            ));
        }
        let size = table.meta().brick_size as usize;
        if size == render || size < 2 || !render.is_multiple_of(size) {
            // The render grid's own, or a mismatch that `check_grid` names.
            let why = check_table(job, &job.grid, &table, any_shapes)?;
            stale = stale.or(why);
            own.push(check_sampling(job, &file, table)?);
            continue;
        }
        if let Some(g) = &fine {
            if g.brick_size() != size {
                return Err(PofError::Mismatch {
                    file,
                    what: "sub-brick size (every sub-brick table needs the same)",
                    in_file: size.to_string(),
                    expected: g.brick_size().to_string(),
                });
            }
        } else {
            fine = Some(
                // Streamed from the store's chunks when the voxels are not resident.
                crate::store::grid_for(&job.volume, size, None).map_err(|e| PofError::Setting {
                    field: "brick_size",
                    why: e.to_string(),
                })?,
            );
        }
        let grid = fine.as_ref().expect("made above");
        let why = check_table(job, grid, &table, any_shapes)?;
        stale = stale.or(why);
        sub.push(check_sampling(job, &file, table)?);
    }
    let levels = |tables| {
        CoreLevels::new(tables).map_err(|why| PofError::Setting {
            field: "core_length",
            why,
        })
    };
    let sub = levels(sub)?.map(|l| l.with_grid(fine.expect("sub-brick tables have a grid")));
    let levels = match (levels(own)?, sub) {
        (Some(own), Some(sub)) => own.with_sub_bricks(sub),
        (Some(own), None) => own,
        (None, Some(sub)) => sub,
        (None, None) => unreachable!("at least the first table"),
    };
    Ok(Loaded {
        levels,
        stale,
        typical,
    })
}
