//! The facade: a [`Scene`] (what every frame shares) rendered per [`FrameRequest`] (what
//! changes from frame to frame) into a [`Frame`].
//!
//! A scene is immutable once built: the volume, its bricks, the transfer-function family
//! (its weights are only the default), the sampling settings, optional POFs and the brick
//! deal cache. It is `Send + Sync`, so one `Arc<Scene>` serves any number of threads, each
//! rendering with its own camera, weights, shading and cull mode.

mod builder;
mod engine;
mod output;
pub(crate) mod pofs;
mod request;
#[cfg(test)]
mod test;

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, OnceLock};

pub use builder::SceneBuilder;
pub use engine::Engine;
pub use output::Frame;
pub use pofs::{PofBuild, Pofs};
pub use request::{Cull, FrameRequest, Predict};

use crate::brick::BrickGrid;
use crate::comm::Communicator;
use crate::cull::range_bound::RangeBound;
use crate::cull::{CullMode, OpacityBound};
use crate::distribute::{BrickAssignment, Curve};
use crate::error::{Error, Result};
use crate::frame::{self, FrameOptions, Look, RenderJob};
use crate::pof::PofTable;
use crate::render::camera::GIVEN_CAMERA;
use crate::render::{CellRanges, SampledTf, TransferFunction};
use crate::volume::Volume;

/// One volume ready to render: see the [module](self) and [`Scene::builder`].
pub struct Scene {
    /// The volume, bricks, family (default weights), tabulated family, step and threshold,
    /// brick copies and the deal cache. Its shading flag is unused: shading is per frame.
    job: RenderJob,
    pofs: Option<Pofs>,
    /// The value ranges of the volume's 4³ cells, which the march engine's occupancy is
    /// rebuilt from for each frame's weights: measured once, on the first march frame.
    cells: OnceLock<CellRanges>,
    /// The volume in blocks for the march engine where it pays ([`crate::render::blocks`]):
    /// decided, and copied, on the first march frame.
    blocks: OnceLock<Option<std::sync::Arc<crate::render::MarchBlocks>>>,
    /// [`SceneBuilder::march_blocks`].
    blocks_policy: Option<bool>,
}

impl std::fmt::Debug for Scene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scene")
            .field("volume", &self.job.volume.source())
            .field("dims", &self.job.volume.dims())
            .field("bricks", &self.job.grid.len())
            .field("bases", &self.job.sampled.names())
            .field("step", &self.job.settings.step)
            .field("ert", &self.job.settings.ert)
            .field("pofs", &self.pofs)
            .finish_non_exhaustive()
    }
}

/// `weights` must give every basis of `family` a finite weight ≥ 0.
fn check_weights(family: &TransferFunction, weights: &[f32]) -> Result<()> {
    if weights.len() != family.bases.len() {
        return Err(Error::WeightCount {
            got: weights.len(),
            expected: family.bases.len(),
        });
    }
    if let Some((index, got)) = weights
        .iter()
        .enumerate()
        .find(|(_, k)| !k.is_finite() || **k < 0.0)
    {
        return Err(Error::Weight { index, got: *got });
    }
    Ok(())
}

impl Scene {
    /// Starts a scene of `volume` rendered with `family` (bases, default weights, colour).
    pub fn builder(volume: Volume, family: TransferFunction) -> SceneBuilder {
        SceneBuilder::new(volume, family)
    }

    /// A scene of a job set up by hand, e.g. a distributed rank's with private copies of
    /// its bricks ([`RenderJob::bricks`]); the job's weights become the defaults and its
    /// shading flag is dropped.
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for a bad step or threshold, [`Error::WeightCount`] or
    /// [`Error::Weight`] for bad weights.
    pub fn from_job(job: RenderJob) -> Result<Scene> {
        frame::check_settings(&job.settings)?;
        check_weights(&job.tf, &job.tf.weights)?;
        if job.grid.volume_dims() != job.volume.dims() {
            return Err(Error::GridMismatch {
                got: job.grid.volume_dims(),
                expected: job.volume.dims(),
            });
        }
        Ok(Scene::adopt(job))
    }

    /// Wraps a job whose settings are checked.
    fn adopt(mut job: RenderJob) -> Scene {
        job.settings.shade = false;
        Scene {
            job,
            pofs: None,
            cells: OnceLock::new(),
            blocks: OnceLock::new(),
            blocks_policy: None,
        }
    }

    /// The brick store the brick engine reads from under a memory budget
    /// ([`SceneBuilder::memory_budget`]); `None` when the scene samples the whole volume.
    #[must_use]
    pub fn store(&self) -> Option<&crate::store::BrickCache> {
        self.job.store.as_deref()
    }

    /// The volume.
    #[must_use]
    pub fn volume(&self) -> &Volume {
        &self.job.volume
    }

    /// Its bricks, with their value ranges.
    #[must_use]
    pub fn grid(&self) -> &BrickGrid {
        &self.job.grid
    }

    /// The family: bases, default weights, colour.
    #[must_use]
    pub fn family(&self) -> &TransferFunction {
        &self.job.tf
    }

    /// The family's own weights, which a [`FrameRequest`] without weights renders with.
    #[must_use]
    pub fn default_weights(&self) -> &[f32] {
        &self.job.tf.weights
    }

    /// The family tabulated over the volume's value range.
    #[must_use]
    pub fn sampled(&self) -> &SampledTf {
        &self.job.sampled
    }

    /// Sample distance in units of the smallest voxel spacing.
    #[must_use]
    pub fn step(&self) -> f32 {
        self.job.settings.step
    }

    /// Early-termination threshold.
    #[must_use]
    pub fn early_termination(&self) -> f32 {
        self.job.settings.ert
    }

    /// The POFs, when the scene has them: what [`Cull::Pof`] and [`Cull::PofSet`] carry.
    #[must_use]
    pub fn pofs(&self) -> Option<&Pofs> {
        self.pofs.as_ref()
    }

    /// [`Cull::Pof`] when the scene has POFs, otherwise [`Cull::None`]: what `pofvr render`
    /// and the viewer cull with unless told otherwise.
    #[must_use]
    pub fn default_cull(&self) -> Cull<'_> {
        self.pofs.as_ref().map_or(Cull::None, Cull::Pof)
    }

    /// `mode` with this scene's POFs; `None` when `mode` reads POFs and the scene has none.
    #[must_use]
    pub fn cull(&self, mode: CullMode) -> Option<Cull<'_>> {
        Cull::from_mode(mode, self.pofs.as_ref())
    }

    /// Bricks empty for `weights` (skipped in every mode).
    ///
    /// # Errors
    /// [`Error::WeightCount`] or [`Error::Weight`] for bad weights.
    pub fn empty_bricks(&self, weights: &[f32]) -> Result<usize> {
        check_weights(&self.job.tf, weights)?;
        Ok(self
            .job
            .grid
            .ranges()
            .iter()
            .filter(|r| self.job.sampled.is_empty(**r, weights))
            .count())
    }

    /// Which rank renders which brick ([`RenderJob::assignment`]); cached per curve, rank
    /// count and replicas.
    ///
    /// # Errors
    /// [`Error::Distribute`] for a rank count or replicas out of range.
    pub fn assignment(
        &self,
        curve: Curve,
        ranks: usize,
        replicas: usize,
    ) -> Result<Arc<BrickAssignment>> {
        Ok(self.job.assignment(curve, ranks, replicas)?)
    }

    /// Each brick's layer under the occupied region's surface
    /// ([`RenderJob::occupied_layers`]).
    #[must_use]
    pub fn occupied_layers(&self) -> Vec<usize> {
        self.job.occupied_layers()
    }

    /// Precomputes POFs for this scene: its volume, bricks and bases, with its step and
    /// early-termination threshold. Attach them with [`Scene::with_pofs`], or save them.
    ///
    /// # Errors
    /// [`Error::Pof`] for a bad view grid, core length, pitch or margin.
    pub fn build_pofs(&self, build: &PofBuild) -> Result<PofTable> {
        self.build_pofs_with(build, None, &|_, _| {})
    }

    /// As [`Scene::build_pofs`], saving finished bricks to `partial` and resuming from it
    /// ([`PofTable::build_resumable`]), and calling `progress(done, total)` as bricks
    /// complete. A scene that reads its volume through a brick store builds from the
    /// store's slabs and keeps no partial file.
    ///
    /// # Errors
    /// As [`Scene::build_pofs`], plus I/O errors on `partial`.
    pub fn build_pofs_with(
        &self,
        build: &PofBuild,
        partial: Option<&Path>,
        progress: &(dyn Fn(u64, u64) + Sync),
    ) -> Result<PofTable> {
        if let Some(t) = self.build_pofs_streamed(build, progress, None)? {
            return Ok(t);
        }
        self.whole_lattice("a POF build")?;
        let settings = build.settings(self.step(), self.early_termination());
        let j = &self.job;
        Ok(PofTable::build_resumable(
            &j.volume, &j.grid, &j.tf, &j.sampled, &settings, partial, progress,
        )?)
    }

    /// A scene whose volume is read through its brick store (a file or Zarr level larger
    /// than the memory budget) builds its POFs from the store, slab by slab, instead of
    /// sampling the volume's mapping ([`crate::pof::build_streamed_in_memory`]); `None` for
    /// any other scene. Such a build keeps no partial file.
    fn build_pofs_streamed(
        &self,
        build: &PofBuild,
        progress: &(dyn Fn(u64, u64) + Sync),
        cancel: Option<&AtomicBool>,
    ) -> Result<Option<PofTable>> {
        let Some(store) = self.job.store.as_ref().filter(|s| s.source().is_file()) else {
            return Ok(None);
        };
        let settings = build.settings(self.step(), self.early_termination());
        let j = &self.job;
        let chunks = store
            .source()
            .zarr()
            .map_or(0, crate::store::ZarrSource::chunk_budget);
        let (table, _) = crate::pof::build_streamed_in_memory(
            &j.volume,
            store.source(),
            &j.grid,
            &j.tf,
            &j.sampled,
            &settings,
            store.budget().saturating_sub(chunks).max(1),
            progress,
            cancel,
        )?;
        Ok(Some(table))
    }

    /// As [`Scene::build_pofs`], calling `progress(done, total)` as bricks complete and
    /// stopping between bricks once `cancel` is set ([`PofTable::build_cancellable`]).
    ///
    /// # Errors
    /// As [`Scene::build_pofs`], plus [`crate::pof::PofError::Cancelled`] (as
    /// [`Error::Pof`]) when cancelled.
    pub fn build_pofs_cancellable(
        &self,
        build: &PofBuild,
        progress: &(dyn Fn(u64, u64) + Sync),
        cancel: &AtomicBool,
    ) -> Result<PofTable> {
        if let Some(t) = self.build_pofs_streamed(build, progress, Some(cancel))? {
            return Ok(t);
        }
        self.whole_lattice("a POF build")?;
        let settings = build.settings(self.step(), self.early_termination());
        let j = &self.job;
        Ok(PofTable::build_cancellable(
            &j.volume, &j.grid, &j.tf, &j.sampled, &settings, progress, cancel,
        )?)
    }

    /// This scene with `table` as its POFs, once checked to be for its volume, bricks,
    /// bases, step and threshold.
    ///
    /// # Errors
    /// [`Error::Pof`] naming what differs.
    pub fn with_pofs(mut self, table: PofTable) -> Result<Scene> {
        table.check_matches(&self.job.volume, &self.job.grid, &self.job.tf)?;
        let table = pofs::check_sampling(&self.job, "POF table", table)?;
        let sets = table.has_sets();
        self.pofs = Some(Pofs::new(Box::new(table), sets));
        Ok(self)
    }

    /// This scene with the POF file `path` as its POFs, checked as [`Scene::with_pofs`]
    /// does.
    ///
    /// # Errors
    /// [`Error::Pof`] naming the file and what is wrong with it.
    pub fn load_pofs(self, path: impl AsRef<Path>) -> Result<Scene> {
        self.load_pof_levels(path, &[])
    }

    /// This scene with `first` and further levels of it built with other core lengths (or
    /// for sub-bricks) as its POFs ([`RenderJob::load_pof_levels`]).
    ///
    /// # Errors
    /// [`Error::Pof`] naming the file and what differs, or two levels of one core length.
    pub fn load_pof_levels(mut self, first: impl AsRef<Path>, more: &[PathBuf]) -> Result<Scene> {
        let l = pofs::load_levels(&self.job, first.as_ref(), more)?;
        let sets = l.levels.has_sets();
        self.pofs = Some(Pofs::new(Box::new(l.levels), sets).typical(l.typical));
        Ok(self)
    }

    /// This scene with `first` (and `more` levels, as [`Scene::load_pof_levels`]) as POFs
    /// that may have been built for other basis shapes than the scene's, as when the user
    /// edited the family's bases after building them (the count must still agree). Such
    /// POFs bound nothing, but still predict: frames cull with them only when verified
    /// ([`Cull::Verified`] with a POF predictor, or [`FrameRequest::verify`]), and
    /// verification repairs what they cull wrongly, so images stay right while predictions
    /// get worse. [`Pofs::stale_reason`] says what differs.
    ///
    /// # Errors
    /// [`Error::Pof`] naming the file and what differs (volume, bricks, basis count, step,
    /// threshold).
    pub fn load_pof_predictions(
        mut self,
        first: impl AsRef<Path>,
        more: &[PathBuf],
    ) -> Result<Scene> {
        let l = pofs::load_levels_for(&self.job, first.as_ref(), more, true)?;
        let sets = l.levels.has_sets();
        self.pofs = Some(
            Pofs::new(Box::new(l.levels), sets)
                .stale(l.stale)
                .typical(l.typical),
        );
        Ok(self)
    }

    /// A scene of the same volume, bricks and settings rendered with `family`: its POFs
    /// are kept when `family` has the same bases (names and points; weights and colour are
    /// free), and dropped otherwise, since they bound the old bases' opacity. The bricks'
    /// value ranges and the measured cell ranges are reused, and the voxels shared, not
    /// copied ([`Volume::share`]). Private brick copies ([`RenderJob::bricks`]) are not
    /// carried over: the new scene samples the volume.
    ///
    /// # Errors
    /// [`Error::WeightCount`] or [`Error::Weight`] for bad default weights in `family`.
    pub fn with_family(&self, family: TransferFunction) -> Result<Scene> {
        check_weights(&family, &family.weights)?;
        let same_bases = family.bases.len() == self.job.tf.bases.len()
            && family.bases_fingerprint() == self.job.tf.bases_fingerprint();
        // Shared, not copied: a second copy of a large volume would double the memory, and
        // under a memory budget a copy of a mapped file would bring it all into memory.
        let volume = self.job.volume.share();
        let mut job =
            RenderJob::with_grid(volume, family, self.job.grid.clone(), self.job.settings)?;
        job.store = self.job.store.clone();
        let scene = Scene {
            job,
            pofs: self.pofs.clone().filter(|_| same_bases),
            cells: self.cells.clone(),
            blocks: self.blocks.clone(),
            blocks_policy: self.blocks_policy,
        };
        Ok(scene)
    }

    /// This scene with the bound of its bricks' value ranges as its POFs
    /// ([`RangeBound`]: weak but conservative, and needs no precomputation), claimed for
    /// rays running at least `core` inside a brick.
    #[must_use]
    pub fn with_range_bound(mut self, core: f32) -> Scene {
        let j = &self.job;
        let bound = RangeBound::new(&j.grid, &j.sampled, j.settings.step, j.settings.ert, core);
        self.pofs = Some(Pofs::new(Box::new(bound), false));
        self
    }

    /// The weights, shading and frame options of `req`, checked.
    fn resolve<'s>(&'s self, req: &FrameRequest<'s>) -> Result<(Look<'s>, FrameOptions)> {
        req.camera.validate(GIVEN_CAMERA)?;
        let weights = req.weights.unwrap_or(&self.job.tf.weights);
        check_weights(&self.job.tf, weights)?;
        let mode = req.cull.mode();
        if mode == CullMode::Exact {
            self.whole_lattice("the exact cull")?;
        }
        if self.job.store.is_none() {
            self.whole_lattice("a scene without a brick store")?;
        }
        if self.job.settings.jitter.is_some() && req.cull.pofs().is_some() {
            return Err(Error::JitteredPofs { mode });
        }
        if let Some(p) = req.cull.pofs() {
            if !self.pofs.as_ref().is_some_and(|own| std::ptr::eq(own, p)) {
                return Err(Error::ForeignPofs);
            }
            // POFs of other basis shapes, and typical values, bound nothing: only
            // verification keeps the rule.
            let why = p.stale_reason().or(p.typical_reason());
            if let (Some(why), false) = (why, req.verify || mode == CullMode::Verified) {
                return Err(Error::StalePofs {
                    mode,
                    why: why.to_owned(),
                });
            }
        }
        let look = Look {
            weights,
            shade: req.shade,
        };
        let opts = FrameOptions {
            cull: req.cull.mode(),
            cull_threshold: req.threshold,
            ranks: req.ranks,
            curve: req.curve,
            replicas: req.replicas,
            verify: req.verify,
            predictor: req.cull.predictor(),
        };
        Ok((look, opts))
    }

    /// An error when `what` would sample the whole lattice of a volume read brick by brick
    /// under a memory budget ([`RenderJob::whole_lattice_refusal`]).
    fn whole_lattice(&self, what: &str) -> Result<()> {
        match self.job.whole_lattice_refusal(what) {
            Some(why) => Err(Error::Engine {
                engine: "reference",
                why,
            }),
            None => Ok(()),
        }
    }

    /// The bounds every mode is given: the scene's POFs, whatever the mode (the POF modes
    /// cull with them; every mode's replicas use them to share out bricks).
    fn bound(&self) -> Option<&dyn OpacityBound> {
        self.pofs.as_ref().map(Pofs::bound)
    }

    /// The engine `req` is rendered with: its own, or by default [`Engine::March`] for one
    /// rank with no culling on a scene holding the whole volume, [`Engine::Bricks`]
    /// otherwise (a budgeted scene whose volume does not fit reads bricks on demand).
    ///
    /// # Errors
    /// [`Error::Engine`] when `req` asks the march engine for culling, more than one rank,
    /// a scene that holds private brick copies instead of the volume, or one whose volume
    /// does not fit its memory budget ([`SceneBuilder::memory_budget`]).
    pub fn engine(&self, req: &FrameRequest<'_>) -> Result<Engine> {
        let why = if req.ranks > 1 {
            Some(format!("it renders one process, got {} ranks", req.ranks))
        } else if req.cull.mode() != CullMode::None {
            Some(format!(
                "it does not cull, got cull mode {}",
                req.cull.mode().name()
            ))
        } else if self.job.bricks.is_some() {
            Some("it needs the whole volume, the scene holds brick copies".to_owned())
        } else {
            self.job.store.as_ref().map(|store| {
                format!(
                    "it needs the whole lattice, and the volume ({} bytes) does not fit the memory budget of {} bytes (the brick engine reads only the bricks it renders)",
                    crate::store::volume_bytes(&self.job.volume),
                    store.budget()
                )
            })
        };
        match (req.engine, why) {
            (Some(Engine::March), Some(why)) => Err(Error::Engine {
                engine: Engine::March.name(),
                why,
            }),
            (Some(e), _) => Ok(e),
            (None, None) => Ok(Engine::March),
            (None, Some(_)) => Ok(Engine::Bricks),
        }
    }

    /// The value ranges of the volume's 4³ cells, measured on first use.
    #[must_use]
    pub fn cell_ranges(&self) -> &CellRanges {
        self.cells.get_or_init(|| CellRanges::new(&self.job.volume))
    }

    /// Renders one frame with [`Scene::engine`]: the march engine, or the brick path with
    /// `req.ranks` in-process ranks (paper §3.3, §4). The same image for any engine, rank
    /// count, curve or replicas.
    ///
    /// # Errors
    /// [`Error::Camera`] for a camera that defines no view, [`Error::WeightCount`],
    /// [`Error::Weight`], [`Error::OutOfRange`] (threshold, ranks),
    /// [`Error::ForeignPofs`], [`Error::JitteredPofs`], [`Error::Engine`], or a failed rank's
    /// error.
    pub fn render(&self, req: &FrameRequest<'_>) -> Result<Frame> {
        let (look, opts) = self.resolve(req)?;
        if self.engine(req)? == Engine::March {
            frame::check_options(self.bound(), &opts)?;
            let cells = self.cell_ranges();
            let (image, stats) = frame::march_with(
                &self.job,
                look,
                cells,
                (&self.blocks, self.blocks_policy),
                req.camera,
            );
            return Ok(Frame { image, stats });
        }
        let (image, stats) = frame::frame_with(&self.job, look, self.bound(), req.camera, &opts)?;
        Ok(Frame { image, stats })
    }

    /// This process's part of a frame rendered by every rank of `comm` (its size is the
    /// rank count; `req.ranks` is not read) with the brick engine. Rank 0 gets the frame,
    /// the others `None`.
    ///
    /// # Errors
    /// As [`Scene::render`] ([`Error::Engine`] when `req` asks for the march engine); a
    /// failing rank aborts `comm` so that no peer waits forever.
    pub fn render_on(
        &self,
        comm: &dyn Communicator,
        req: &FrameRequest<'_>,
    ) -> Result<Option<Frame>> {
        let (look, opts) = self.resolve(req)?;
        if req.engine == Some(Engine::March) {
            return Err(Error::Engine {
                engine: Engine::March.name(),
                why: "it renders one process, not the ranks of a communicator".to_owned(),
            });
        }
        let opts = FrameOptions { ranks: 1, ..opts };
        let frame = frame::frame_on_with(comm, &self.job, look, self.bound(), req.camera, &opts)?;
        Ok(frame.map(|(image, stats)| Frame { image, stats }))
    }

    /// The bricks the scene's last verified frame needed ([`crate::cull::Predictor::Previous`]
    /// predicts from them), by brick index.
    #[must_use]
    pub fn previous_needed(&self) -> Option<Vec<bool>> {
        self.job.previous_needed()
    }

    /// Sets the set the next [`crate::cull::Predictor::Previous`] frame predicts from (`None`:
    /// it predicts with the proxy). The scene keeps one set; a caller rendering several
    /// sequences of frames at once must swap each one's set in and out under its own lock.
    pub fn set_previous_needed(&self, needed: Option<Vec<bool>>) {
        self.job.set_previous_needed(needed);
    }

    /// The whole volume ray-cast in one pass with `req`'s camera, weights and shading: no
    /// bricks, no culling (its cull mode, threshold and ranks are not read). Culled frames
    /// are checked against it.
    ///
    /// # Errors
    /// [`Error::Camera`] for a camera that defines no view, [`Error::WeightCount`] or
    /// [`Error::Weight`] for bad weights.
    pub fn render_reference(&self, req: &FrameRequest<'_>) -> Result<Frame> {
        self.whole_lattice("the whole-volume pass")?;
        req.camera.validate(GIVEN_CAMERA)?;
        let weights = req.weights.unwrap_or(&self.job.tf.weights);
        check_weights(&self.job.tf, weights)?;
        let look = Look {
            weights,
            shade: req.shade,
        };
        let (image, stats) = frame::reference_with(&self.job, look, req.camera);
        Ok(Frame { image, stats })
    }
}
