//! `render_frame`: the one place where the stages are chained.
//!
//! [`RenderJob`] bundles a scene with the weights and shading of its frames; the
//! [`crate::Scene`] facade keeps the scene alone and passes those per frame. Both render
//! through the same functions here, which take the weights and shading as a `Look`.

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use rayon::prelude::*;
use serde::Serialize;

use crate::brick::{BrickError, BrickGrid, BrickId, BrickStore};
use crate::comm::{CommError, Communicator, LocalCommunicator, Rank};
use crate::composite::{CompositeError, Compositor, DirectSend, TileFragment, TileLayout};
use crate::cull::predict::{bricks_over_tile, random_culls, split};
use crate::cull::{
    verify_tile, CoreLevels, CullMode, CullResult, CullScratch, Culler, FrameBricks, OpacityBound,
    Predictor, Proxy, VerifyView,
};
use crate::distribute::{BrickAssignment, Curve, Deal, DistributeError};
use crate::error::{OutOfRange, Setting, Value};
use crate::pof::{PofError, PofTable};
use crate::render::{
    Camera, CellRanges, Image, IndexRay, MarchBlocks, PixelRect, RayCaster, RayStats,
    RenderSettings, SampledTf, TfError, TransferFunction,
};
use crate::volume::Volume;

/// The face neighbours of brick cell `c` in a grid of `counts` cells.
fn neighbours(c: [usize; 3], counts: [usize; 3]) -> impl Iterator<Item = [usize; 3]> {
    (0..3).flat_map(move |a| {
        let down = (c[a] > 0).then(|| {
            let mut n = c;
            n[a] -= 1;
            n
        });
        let up = (c[a] + 1 < counts[a]).then(|| {
            let mut n = c;
            n[a] += 1;
            n
        });
        down.into_iter().chain(up)
    })
}

/// A brick assignment and the (curve, deal, ranks, replicas) it was dealt for.
type CachedAssignment = ((Curve, Deal, usize, usize), std::sync::Arc<BrickAssignment>);

/// Everything a frame needs that does not change with the camera: the opened volume, its
/// bricks and the tabulated transfer-function family.
pub struct RenderJob {
    /// The volume.
    pub volume: Volume,
    /// Its bricks.
    pub grid: BrickGrid,
    /// The family with its current weights.
    pub tf: TransferFunction,
    /// The family tabulated over the volume's value range.
    pub sampled: SampledTf,
    /// Ray-caster settings.
    pub settings: RenderSettings,
    /// Private copies of the bricks this process ray-casts (a distributed rank's own):
    /// when a brick is here it is sampled from its copy, not from the volume. The frame is
    /// the same either way.
    pub bricks: Option<BrickStore>,
    /// Under a memory budget, the cache the brick engine reads each brick it renders from
    /// (see [`crate::store`]); `None` samples the volume.
    pub store: Option<std::sync::Arc<crate::store::BrickCache>>,
    /// How bricks are dealt to ranks ([`RenderJob::assignment`]); every rank of a job must
    /// use the same.
    pub deal: Deal,
    /// The last [`RenderJob::assignment`], by curve and rank count: every frame asks for
    /// it, and it only changes with the bricks and bases, which a job keeps.
    assignment_cache: std::sync::Mutex<Option<CachedAssignment>>,
    /// The culler's opacity buffers, kept from frame to frame.
    cull_scratch: CullScratch,
    /// The low-resolution proxy the [`Predictor::Proxy`] marches, measured on first use
    /// (it depends on the volume and the bases, which a job keeps).
    proxy: std::sync::OnceLock<Proxy>,
    /// The bricks the last verified frame needed, by id: what [`Predictor::Previous`]
    /// predicts from.
    previous: std::sync::Mutex<Option<Vec<bool>>>,
}

/// Validated before the volume is scanned, so a bad setting fails fast.
pub(crate) fn check_settings(settings: &RenderSettings) -> Result<(), OutOfRange> {
    if !(settings.step.is_finite() && settings.step > 1e-3 && settings.step <= 64.0) {
        return Err(OutOfRange {
            setting: Setting::Step,
            got: Value::Real(settings.step),
            expected: "a value in (0.001, 64]",
        });
    }
    if !(settings.ert > 0.0 && settings.ert.is_finite()) {
        return Err(OutOfRange {
            setting: Setting::EarlyTermination,
            got: Value::Real(settings.ert),
            expected: "a value > 0 (≥ 1 disables it)",
        });
    }
    Ok(())
}

/// Errors setting up a job.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum JobError {
    /// Bad brick size.
    #[error(transparent)]
    Brick(#[from] BrickError),
    /// Bad transfer function or weights.
    #[error(transparent)]
    Tf(#[from] TfError),
    /// A step or early-termination threshold out of range.
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
}

impl RenderJob {
    /// Which rank renders which brick: each of [`RenderJob::occupied_layers`] (the bricks
    /// the family cannot show, its surface, the layer under it, …) dealt round-robin along
    /// `curve` apart from the others ([`BrickAssignment::from_order_classes`]). It depends
    /// on the family's bases and the data only, not on the weights or the view, so a
    /// distributed rank's bricks stay put.
    ///
    /// A volume read chunk by chunk from a store ([`RenderJob::deal`],
    /// [`crate::distribute::chunks::chunk_shape_for`]) is dealt by chunks instead: one run
    /// of chunks along `curve` per rank, balanced by the bricks the family can show
    /// ([`BrickAssignment::by_chunks`]), so that each rank decodes only its part.
    ///
    /// `replicas` owners per brick (1: the paper's deal).
    ///
    /// # Errors
    /// [`DistributeError`] for a rank count of zero or one past `u32::MAX`, replicas
    /// outside `1..=ranks`, or [`Deal::Chunks`] on a volume not read by chunks.
    pub fn assignment(
        &self,
        curve: Curve,
        ranks: usize,
        replicas: usize,
    ) -> Result<std::sync::Arc<BrickAssignment>, DistributeError> {
        let mut cache = self
            .assignment_cache
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some((key, a)) = cache.as_ref() {
            if *key == (curve, self.deal, ranks, replicas) {
                return Ok(a.clone());
            }
        }
        let brick_size = self.grid.brick_size();
        let layers = self.occupied_layers();
        let dealt = match crate::distribute::chunks::chunk_shape_for(
            &self.volume,
            brick_size,
            self.deal,
        )? {
            Some(chunk) => BrickAssignment::by_chunks(
                self.grid.counts(),
                brick_size,
                chunk,
                curve,
                ranks,
                &|id| u64::from(layers[id.index()] > 0),
            )?,
            None => {
                let order = crate::distribute::SfcOrder::new(self.grid.counts(), curve)?;
                BrickAssignment::from_order_classes(&order, ranks, &|id| layers[id.index()])?
            }
        };
        let a = std::sync::Arc::new(dealt.with_replicas(replicas)?);
        *cache = Some(((curve, self.deal, ranks, replicas), a.clone()));
        Ok(a)
    }

    /// Each brick's layer: 0 for a brick the family cannot show (empty for every basis),
    /// and for the others 1 + their distance, in bricks across faces, from the nearest
    /// such brick or the volume's boundary: 1 for the occupied region's surface, 2 for the
    /// bricks under it, and so on.
    ///
    /// Why: whatever the view, what survives culling is mostly the outer layers; dealing
    /// each layer apart ([`BrickAssignment::from_order_classes`]) gives every rank its
    /// share of each, so the bricks left to render after culling stay balanced too.
    #[must_use]
    pub fn occupied_layers(&self) -> Vec<usize> {
        let every = vec![1.0; self.sampled.basis_count()];
        let counts = self.grid.counts();
        let mut layer: Vec<usize> = self
            .grid
            .ids()
            .map(|id| {
                if self.sampled.is_empty(self.grid.range(id), &every) {
                    0
                } else {
                    usize::MAX
                }
            })
            .collect();
        // Breadth-first from the empty bricks and the boundary.
        let mut front = std::collections::VecDeque::new();
        for id in self.grid.ids() {
            if layer[id.index()] == 0 {
                continue;
            }
            let c = self.grid.coords(id);
            let on_boundary = (0..3).any(|a| c[a] == 0 || c[a] + 1 == counts[a]);
            let by_empty = neighbours(c, counts).any(|n| layer[self.grid.id(n).index()] == 0);
            if on_boundary || by_empty {
                layer[id.index()] = 1;
                front.push_back(id);
            }
        }
        while let Some(id) = front.pop_front() {
            let next = layer[id.index()] + 1;
            for n in neighbours(self.grid.coords(id), counts) {
                let n = self.grid.id(n);
                if layer[n.index()] == usize::MAX {
                    layer[n.index()] = next;
                    front.push_back(n);
                }
            }
        }
        layer
    }

    /// Bricks the volume and tabulates the family over its value range.
    ///
    /// # Errors
    /// [`JobError`] for a bad brick size, step or early-termination threshold.
    pub fn new(
        volume: Volume,
        tf: TransferFunction,
        brick_size: usize,
        settings: RenderSettings,
    ) -> Result<Self, JobError> {
        check_settings(&settings)?;
        let grid = BrickGrid::from_volume(&volume, brick_size)?;
        Self::with_grid(volume, tf, grid, settings)
    }

    /// As [`RenderJob::new`] with the brick grid (and its ranges) already made, e.g. measured
    /// in pieces by several ranks.
    ///
    /// # Errors
    /// [`JobError::OutOfRange`] for a bad step or threshold, [`JobError::GridMismatch`] for a
    /// grid cut from other dims.
    pub fn with_grid(
        volume: Volume,
        tf: TransferFunction,
        grid: BrickGrid,
        settings: RenderSettings,
    ) -> Result<Self, JobError> {
        check_settings(&settings)?;
        if grid.volume_dims() != volume.dims() {
            return Err(JobError::GridMismatch {
                got: grid.volume_dims(),
                expected: volume.dims(),
            });
        }
        let sampled = SampledTf::new(&tf, grid.value_range());
        Ok(RenderJob {
            volume,
            grid,
            tf,
            sampled,
            settings,
            bricks: None,
            store: None,
            deal: Deal::Auto,
            assignment_cache: std::sync::Mutex::default(),
            cull_scratch: CullScratch::new(),
            proxy: std::sync::OnceLock::new(),
            previous: std::sync::Mutex::default(),
        })
    }

    /// Loads precomputed POFs for this job: the file must match the volume, the bases (the
    /// weights are free) and the ray caster's step and early-termination threshold, since a
    /// POF bounds what the ray caster composites with those.
    ///
    /// # Errors
    /// [`PofError`] naming the file and what differs.
    pub fn load_pofs(&self, path: &std::path::Path) -> Result<PofTable, PofError> {
        crate::scene::pofs::load_table(self, path)
    }

    /// Loads `first` and further levels of it built with other core lengths
    /// ([`CoreLevels`]), each checked as [`RenderJob::load_pofs`] does.
    ///
    /// Tables may also be built for sub-bricks of the render bricks (brick size 8 for
    /// render bricks of 16), all of one brick size: each visible brick then gets the bounds
    /// of its sub-bricks, and where there are tables for the render bricks too, the higher
    /// of the two at each pixel.
    ///
    /// # Errors
    /// [`PofError`] naming the file and what differs, two levels of one core length, or
    /// sub-brick tables of two brick sizes.
    ///
    /// The levels carry no mark of typical-value tables (`pof build --method typical`),
    /// which bound nothing: [`crate::Scene::load_pof_levels`] refuses unverified culls
    /// with those; a job's caller (the benchmarks, which count rule violations) must
    /// verify them itself.
    pub fn load_pof_levels(
        &self,
        first: &std::path::Path,
        more: &[std::path::PathBuf],
    ) -> Result<CoreLevels, PofError> {
        crate::scene::pofs::load_levels(self, first, more).map(|l| l.levels)
    }

    /// The low-resolution proxy of the volume for this job's family
    /// ([`Predictor::Proxy`]), measured on first use.
    #[must_use]
    pub fn proxy(&self) -> &Proxy {
        self.proxy
            .get_or_init(|| Proxy::new(&self.volume, &self.sampled))
    }

    /// [`RenderJob::proxy`], measured by streaming the brick store's file when there is one
    /// (a budgeted volume is never mapped whole).
    fn stream_proxy(&self) -> Result<&Proxy, FrameError> {
        let Some(store) = self.store.as_ref().filter(|s| s.source().is_file()) else {
            return Ok(self.proxy());
        };
        if let Some(p) = self.proxy.get() {
            return Ok(p);
        }
        let d = self.volume.dims();
        // Slabs of at most an eighth of the budget, so that they fit beside the cache.
        let plane = (d[0] * d[1] * self.volume.data_type().size()) as u64;
        let planes = (store.budget() / 8 / plane.max(1)).max(1) as usize;
        let read = |z0: usize, n: usize| {
            store
                .source()
                .read_box(&self.volume, [0, 0, z0], [d[0], d[1], n])
        };
        let p = Proxy::from_slabs(d, &self.sampled, planes, &read)?;
        let mut first = false;
        let p = self.proxy.get_or_init(|| {
            first = true;
            p
        });
        if first {
            // The proxy and the extinction it caches (a float per cell) come out of the
            // budget: the cache keeps the rest.
            let cells: usize = p.cells().iter().product();
            store.reserve(p.heap_bytes() + 4 * cells as u64);
        }
        Ok(p)
    }

    /// Forgets the bricks the last verified frame needed, so that the next
    /// [`Predictor::Previous`] frame starts from the proxy's guess.
    pub fn forget_previous(&self) {
        *self
            .previous
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = None;
    }

    /// The bricks the last verified frame needed, by brick index (`None` before the first
    /// verified frame or after [`RenderJob::forget_previous`]).
    #[must_use]
    pub fn previous_needed(&self) -> Option<Vec<bool>> {
        self.previous
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// Whether a [`Predictor::Previous`] frame has a set to predict from (one of this
    /// job's bricks: a set of another length is ignored, as the predictor does).
    #[must_use]
    pub fn has_previous(&self) -> bool {
        self.previous
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .as_ref()
            .is_some_and(|p| p.len() == self.grid.len())
    }

    /// Sets what the next [`Predictor::Previous`] frame predicts from: a caller that keeps
    /// several sequences of frames (the viewer, one per client) swaps each one's set in.
    /// A set of the wrong length is ignored by the predictor (it falls back to the proxy).
    pub fn set_previous_needed(&self, needed: Option<Vec<bool>>) {
        *self
            .previous
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = needed;
    }

    /// Number of bricks that are empty for the current weights.
    #[must_use]
    pub fn empty_bricks(&self) -> usize {
        self.grid
            .ranges()
            .iter()
            .filter(|r| self.sampled.is_empty(**r, &self.tf.weights))
            .count()
    }
}

/// Figures of one frame, written by `--stats`.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FrameStats {
    /// Wall time of the frame in milliseconds.
    pub frame_ms: f64,
    /// Rays cast: for the whole-volume and march engines one per pixel whose ray meets the
    /// volume; for the brick engine one per brick fragment (a pixel's ray counts once for
    /// every rendered brick it crosses), so more than the pixels. See
    /// [`FrameStats::pixel_rays`].
    pub rays: u64,
    /// Pixels whose ray meets the volume, whatever the engine: what `samples_per_ray` is
    /// counted over.
    pub pixel_rays: u64,
    /// Samples taken.
    pub samples: u64,
    /// `samples / frame time`.
    pub samples_per_second: f64,
    /// Worker threads used.
    pub threads: usize,
    /// Cull mode used.
    pub cull: Option<CullMode>,
    /// Brick counts for the mode used.
    pub bricks: BrickCounts,
    /// Per-rank breakdown.
    pub ranks: Vec<RankStats>,
    /// Ids of the culled bricks (for overlays and experiments).
    #[serde(skip)]
    pub culled_bricks: Vec<BrickId>,
    /// The renderer: "march", "bricks", or "whole" (the whole-volume reference).
    pub engine: &'static str,
    /// Samples per ray that met the volume (`samples` over those rays, whatever the
    /// engine; the brick path's `rays` count a ray once per brick).
    pub samples_per_ray: f64,
    /// Lattice samples in empty space the march engine jumped over (0 for the others).
    pub skipped_samples: u64,
    /// Steps of the march engine's packet loops ([`crate::render::MarchStats::packet_steps`]:
    /// iterations in which a packet's rays sampled or leapt; 0 for the other engines and
    /// where no packet loop runs).
    pub march_steps: u64,
    /// The march engine's rebuild of the occupancy for the frame's weights, in
    /// milliseconds, inside `frame_ms` (0 for the others).
    pub occupancy_ms: f64,
    /// The loop the march engine ran ([`crate::render::MarchStats::simd`]: "avx512",
    /// "avx2", "walk-avx2", "sse2" or "scalar"); `None` for the other engines.
    pub march_simd: Option<&'static str>,
    /// Whether the march engine's packet loops prefetched the voxels ahead of their rays
    /// (by default where the voxels exceed the last-level cache; `POFVR_PREFETCH=on|off`
    /// overrides it); false for the other engines. The image is the same either way.
    pub march_prefetch: bool,
    /// Whether the march engine's packet loop (sixteen lanes or eight) loaded its corners
    /// and table entries by gathers (by default where they measured faster in it on this CPU;
    /// `POFVR_GATHER=on|off` overrides it); false for the other engines and loops. The
    /// image is the same either way.
    pub march_gather: bool,
    /// Whether the march engine's eight-ray packet loop read the voxels from the volume's
    /// blocked copy ([`crate::render::MarchBlocks`]: by default for volumes of 256 MiB and
    /// more where memory allows; `POFVR_BLOCKS=on|off` overrides it); false for the other
    /// engines and loops. The image is the same either way.
    pub march_blocks: bool,
    /// The time this frame spent copying the volume into blocks, in milliseconds, inside
    /// `frame_ms`: the first march frame of a volume that gets them; 0 for the others.
    pub blocks_ms: f64,
    /// Whether the culling was verified (and repaired) while compositing.
    pub verified: bool,
    /// The predictor of a verified frame (`None` otherwise).
    pub predictor: Option<&'static str>,
    /// What actually predicted a verified frame: the predictor, except `proxy` where
    /// `previous` had no last frame's set to predict from (a job's first verified frame).
    pub predicted_by: Option<&'static str>,
    /// Bytes the frame read from the brick store's source, all ranks (0 without a store).
    pub bytes_read: u64,
    /// Bricks it read from the store's source, all ranks (cache misses).
    pub bricks_read: u64,
    /// Bricks the store served from its cache, all ranks.
    pub cache_hits: u64,
    /// This process's peak resident set (`VmHWM`) at the end of the frame.
    pub peak_rss_bytes: u64,
    /// The most voxel bytes the brick store has cached at once (0 without a store).
    pub cache_peak_bytes: u64,
    /// The store's memory budget in bytes (`None` without a store).
    pub memory_budget: Option<u64>,
    /// How the brick engine dealt bricks to ranks: `"curve"` (the paper's, round-robin
    /// along the curve) or `"chunks"` (one run of store chunks per rank); `None` for the
    /// engines without ranks.
    pub deal: Option<&'static str>,
}

/// Brick counts of a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct BrickCounts {
    /// All bricks.
    pub total: usize,
    /// Bricks empty for the current weights (skipped in every mode).
    pub empty: usize,
    /// `total − empty`.
    pub non_empty: usize,
    /// Non-empty bricks culled (never loaded, sampled or sent).
    pub culled: usize,
    /// Non-empty bricks rendered (`non_empty − culled`, less bricks off-screen), the
    /// repaired ones included.
    pub visible: usize,
    /// Of the rendered bricks, those a verified frame's prediction culled and verification
    /// found showing: rendered and blended in afterwards (0 unless verified).
    pub repaired: usize,
}

/// One rank's share of a frame.
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
pub struct RankStats {
    /// The rank.
    pub rank: usize,
    /// Bricks it ray-cast.
    pub bricks_rendered: usize,
    /// Samples it took.
    pub samples: u64,
    /// Culling time for its tile.
    pub cull_ms: f64,
    /// Ray-casting time.
    pub raycast_ms: f64,
    /// Compositing time.
    pub composite_ms: f64,
    /// Time in communication (exchanges and waits).
    pub comm_ms: f64,
    /// Bytes it sent.
    pub bytes_sent: u64,
    /// Rays it cast (one per brick a pixel's ray meets).
    pub rays: u64,
    /// Its resident memory at the end of the frame (bytes; threads of one process share it).
    pub resident_bytes: u64,
    /// Verifying the prediction over its tile (0 unless verified).
    #[serde(default)]
    pub verify_ms: f64,
    /// Repairing: learning every tile's failures, rendering its share of them and sending
    /// their fragments (0 unless verified).
    #[serde(default)]
    pub repair_ms: f64,
    /// Bytes it read from the brick store's source.
    #[serde(default)]
    pub bytes_read: u64,
    /// Bricks it read from the store's source.
    #[serde(default)]
    pub bricks_read: u64,
    /// Bricks the store served it from its cache.
    #[serde(default)]
    pub cache_hits: u64,
    /// Zarr chunks decoded for the bricks it read (ranks of one process share the chunk
    /// cache: a chunk counts for the rank that decoded it).
    #[serde(default)]
    pub chunks_decoded: u64,
}

/// Per-frame choices.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameOptions {
    /// Cull mode.
    pub cull: CullMode,
    /// Opacity at which a pixel hides what is behind it.
    pub cull_threshold: f32,
    /// In-process ranks (threads) for [`render_frame`].
    pub ranks: usize,
    /// The curve bricks are dealt along.
    pub curve: Curve,
    /// Owners per brick (1, the paper's: each brick rendered by the rank it was dealt to;
    /// 2: by the less loaded of two, see [`BrickAssignment`]).
    pub replicas: usize,
    /// Whether tile owners verify the cull while compositing and the frame repairs what
    /// was culled wrongly (always for [`CullMode::Verified`]).
    pub verify: bool,
    /// What predicts the cull of a [`CullMode::Verified`] frame (other modes predict with
    /// their own cull).
    pub predictor: Predictor,
}

impl Default for FrameOptions {
    fn default() -> Self {
        FrameOptions {
            cull: CullMode::Pof,
            cull_threshold: 0.95,
            ranks: 1,
            curve: Curve::Hilbert,
            replicas: 1,
            verify: false,
            predictor: Predictor::BEST,
        }
    }
}

/// Errors of one frame.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FrameError {
    /// A POF mode without POFs.
    #[error("cull mode {} needs precomputed POFs (built by `pofvr pof build`)", .0.name())]
    NoPofs(CullMode),
    /// A POF predictor without POFs.
    #[error("predictor {} needs precomputed POFs (built by `pofvr pof build`)", .0.name())]
    NoPofsPredictor(Predictor),
    /// A threshold or rank count out of range.
    #[error(transparent)]
    OutOfRange(#[from] OutOfRange),
    /// The ranks' statistics could not be gathered into the frame.
    #[error("frame gather: {0}")]
    Gather(String),
    /// Bricks could not be dealt to ranks.
    #[error(transparent)]
    Distribute(#[from] DistributeError),
    /// Compositing failed (a lost fragment names its tile and rank).
    #[error(transparent)]
    Composite(#[from] CompositeError),
    /// An exchange between ranks failed.
    #[error(transparent)]
    Comm(#[from] CommError),
    /// A brick could not be read from the brick store's file.
    #[error(transparent)]
    Read(#[from] crate::volume::VolumeError),
    /// What samples the whole lattice (the exact cull) asked of a job whose volume is read
    /// brick by brick under a memory budget ([`RenderJob::store`]).
    #[error("{0}")]
    WholeLattice(String),
}

impl FrameError {
    /// True when this rank only saw another rank's abort.
    #[must_use]
    pub fn is_abort(&self) -> bool {
        matches!(
            self,
            FrameError::Comm(CommError::Aborted { .. })
                | FrameError::Composite(CompositeError::Comm(CommError::Aborted { .. }))
        )
    }
}

impl FrameStats {
    fn from_rays(st: RayStats, seconds: f64, engine: &'static str) -> Self {
        let sps = if seconds > 0.0 {
            st.samples as f64 / seconds
        } else {
            0.0
        };
        FrameStats {
            frame_ms: seconds * 1e3,
            rays: st.rays,
            pixel_rays: st.rays,
            samples: st.samples,
            samples_per_second: sps,
            threads: rayon::current_num_threads(),
            engine,
            samples_per_ray: st.samples as f64 / st.rays.max(1) as f64,
            peak_rss_bytes: crate::store::peak_rss_bytes(),
            ..FrameStats::default()
        }
    }
}

/// What a frame reads besides the scene and the camera: the basis weights and whether to
/// shade.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Look<'a> {
    /// One weight per basis, validated against the family.
    pub(crate) weights: &'a [f32],
    /// Gradient shading.
    pub(crate) shade: bool,
}

impl RenderJob {
    /// The job's own weights and shading, which [`render_frame`] renders with.
    fn look(&self) -> Look<'_> {
        Look {
            weights: &self.tf.weights,
            shade: self.settings.shade,
        }
    }
}

impl RenderJob {
    /// Why `what` must not sample the whole lattice of this job's volume, or `None` when it
    /// may: not when its voxels are not resident (a Zarr level larger than the memory
    /// budget, decoded chunk by chunk for the bricks rendered), where silent zeros would be
    /// a wrong image; nor when they are a file larger than the memory budget of
    /// [`RenderJob::store`], where sampling its mapping would bring every page it touches
    /// into memory (the whole file, for the exact cull and the whole-volume pass), past the
    /// budget the caller asked for.
    #[must_use]
    pub fn whole_lattice_refusal(&self, what: &str) -> Option<String> {
        if let Some(store) = &self.store {
            if let crate::store::BrickSource::File { path, .. } = store.source() {
                return Some(format!(
                    "{what} samples the whole volume, and {} ({:.1} MB of voxels in {}) does not fit the memory budget of {:.1} MB: it would map the whole file, where the brick engine reads only the bricks it renders. Render with --cull none or verified, or raise or leave out --memory-budget",
                    self.volume.source(),
                    crate::store::volume_bytes(&self.volume) as f64 / 1e6,
                    path.display(),
                    store.budget() as f64 / 1e6,
                ));
            }
        }
        (!self.volume.is_resident()).then(|| format!(
            "{what} samples the whole volume, and {} is a Zarr level larger than the memory budget whose chunks are decoded only for the bricks rendered: render with the brick engine and --cull none or verified, or raise --memory-budget",
            self.volume.source()
        ))
    }
}

/// Renders the whole volume with the reference ray caster (no bricks, no culling).
#[must_use]
pub fn render_reference(job: &RenderJob, camera: &Camera) -> (Image, FrameStats) {
    reference_with(job, job.look(), camera)
}

/// [`render_reference`] with `look` in place of the job's weights and shading.
pub(crate) fn reference_with(
    job: &RenderJob,
    look: Look<'_>,
    camera: &Camera,
) -> (Image, FrameStats) {
    let start = Instant::now();
    let cls = job.sampled.classify(look.weights, job.settings.step);
    let settings = RenderSettings {
        shade: look.shade,
        ..job.settings
    };
    let (image, st) = RayCaster::new(&job.volume, &cls, settings).render(camera);
    (
        image,
        FrameStats::from_rays(st, start.elapsed().as_secs_f64(), "whole"),
    )
}

/// Renders the whole volume with the march engine, the reference's image bit for bit:
/// the occupancy of `cells` is rebuilt for `look`'s weights when they changed (timed
/// inside the frame), and the volume copied into `blocks` on the first frame where
/// `policy` (`None`: [`crate::render::blocks::pays`]) asks for them.
pub(crate) fn march_with(
    job: &RenderJob,
    look: Look<'_>,
    cells: &CellRanges,
    (blocks, policy): (&OnceLock<Option<std::sync::Arc<MarchBlocks>>>, Option<bool>),
    camera: &Camera,
) -> (Image, FrameStats) {
    let start = Instant::now();
    // Built on the first frame that needs them, and kept: they depend on the volume only.
    let mut blocks_ms = 0.0;
    let blocks = blocks
        .get_or_init(|| {
            let t = Instant::now();
            let want = policy.unwrap_or_else(|| crate::render::blocks::pays(&job.volume));
            let b = (want && job.store.is_none())
                .then(|| MarchBlocks::new(&job.volume))
                .flatten()
                .map(std::sync::Arc::new);
            if b.is_some() {
                blocks_ms = t.elapsed().as_secs_f64() * 1e3;
            }
            b
        })
        .as_deref();
    let t = Instant::now();
    let cls = job.sampled.classify(look.weights, job.settings.step);
    let occ = cells.occupancy(&cls);
    let occupancy_ms = t.elapsed().as_secs_f64() * 1e3;
    let settings = RenderSettings {
        shade: look.shade,
        ..job.settings
    };
    let t = Instant::now();
    let caster = RayCaster::new(&job.volume, &cls, settings);
    let (image, st) = caster.render_march_with(camera, &occ, blocks);
    let raycast_ms = t.elapsed().as_secs_f64() * 1e3;
    let mut stats = FrameStats::from_rays(st.rays, start.elapsed().as_secs_f64(), "march");
    stats.skipped_samples = st.skipped_samples;
    stats.march_steps = st.packet_steps;
    stats.occupancy_ms = occupancy_ms;
    stats.march_simd = Some(st.simd);
    stats.march_prefetch = caster.prefetch() && st.packet_steps > 0;
    stats.march_gather = caster.gather() && matches!(st.simd, "avx512" | "avx2");
    stats.march_blocks = st.blocks;
    stats.blocks_ms = blocks_ms;
    // No brick is culled, and none is projected: every non-empty one counts as visible.
    let empty = job
        .grid
        .ranges()
        .iter()
        .filter(|r| job.sampled.is_empty(**r, look.weights))
        .count();
    stats.cull = Some(CullMode::None);
    stats.bricks = BrickCounts {
        total: job.grid.len(),
        empty,
        non_empty: job.grid.len() - empty,
        culled: 0,
        visible: job.grid.len() - empty,
        repaired: 0,
    };
    // One rank: this process, which ray-casts through every visible brick.
    stats.ranks = vec![RankStats {
        rank: 0,
        bricks_rendered: job.grid.len() - empty,
        samples: st.rays.samples,
        raycast_ms,
        rays: st.rays.rays,
        resident_bytes: resident_bytes(),
        ..RankStats::default()
    }];
    (image, stats)
}

/// Pixels of `camera` whose ray meets `volume`: what the brick path's samples per ray
/// are counted over.
fn rays_meeting(volume: &Volume, camera: &Camera) -> u64 {
    let frame = camera.frame();
    let vbox = crate::brick::IndexBox {
        lo: [0.0; 3],
        hi: volume.dims().map(|d| (d - 1) as f32),
    };
    (0..camera.height)
        .into_par_iter()
        .map(|y| {
            (0..camera.width)
                .filter(|&x| {
                    let r = camera.ray(&frame, f64::from(x) + 0.5, f64::from(y) + 0.5);
                    IndexRay::new(&r, volume.spacing(), volume.unit())
                        .span(&vbox)
                        .is_some()
                })
                .count() as u64
        })
        .sum()
}

/// Renders a frame the paper's way (§3.3, §4) with `opts.ranks` in-process ranks: the same
/// algorithm and the same image as any number of MPI ranks.
///
/// # Errors
/// [`FrameError`] when a POF mode has no bounds, an option is out of range, or a rank fails.
pub fn render_frame(
    job: &RenderJob,
    bounds: Option<&dyn OpacityBound>,
    camera: &Camera,
    opts: &FrameOptions,
) -> Result<(Image, FrameStats), FrameError> {
    frame_with(job, job.look(), bounds, camera, opts)
}

/// [`render_frame`] with `look` in place of the job's weights and shading.
pub(crate) fn frame_with(
    job: &RenderJob,
    look: Look<'_>,
    bounds: Option<&dyn OpacityBound>,
    camera: &Camera,
    opts: &FrameOptions,
) -> Result<(Image, FrameStats), FrameError> {
    check_options(bounds, opts)?;
    let mut results = LocalCommunicator::run(opts.ranks.max(1), |comm| {
        frame_on_with(comm, job, look, bounds, camera, opts)
    });
    // Report rank 0's error first: it holds the frame; others may only have seen the abort.
    let first = results.remove(0);
    match first {
        Ok(Some(frame)) => Ok(frame),
        Ok(None) => Err(FrameError::Gather("rank 0 returned no frame".into())),
        Err(e) => Err(results
            .into_iter()
            .find_map(|r| r.err().filter(|e| !e.is_abort()))
            .unwrap_or(e)),
    }
}

pub(crate) fn check_options(
    bounds: Option<&dyn OpacityBound>,
    opts: &FrameOptions,
) -> Result<(), FrameError> {
    if opts.cull.needs_pofs() && bounds.is_none() {
        return Err(FrameError::NoPofs(opts.cull));
    }
    if opts.cull == CullMode::Verified && opts.predictor.needs_pofs() && bounds.is_none() {
        return Err(FrameError::NoPofsPredictor(opts.predictor));
    }
    if !(opts.cull_threshold > 0.0 && opts.cull_threshold <= 1.0) {
        return Err(OutOfRange {
            setting: Setting::CullThreshold,
            got: Value::Real(opts.cull_threshold),
            expected: "a value in (0, 1]",
        }
        .into());
    }
    if !(1..=MAX_RANKS).contains(&opts.ranks) {
        return Err(OutOfRange {
            setting: Setting::Ranks,
            got: Value::Count(opts.ranks),
            expected: "a count in 1..=4096",
        }
        .into());
    }
    Ok(())
}

/// Most in-process ranks of a frame.
const MAX_RANKS: usize = 4096;

/// An estimate of the samples ray casting brick `b` takes, the same on every rank (it reads
/// only what every rank holds), by which replicas share the visible bricks: its voxels
/// (rays times the steps of a mean chord, whatever the view), times the share of a chord a
/// ray takes before early termination, at the rate of optical depth per unit length that
/// the brick's bound guarantees along `dir` (`−ln(1 − α)` over the core length `L`).
///
/// Why not the footprint's area: a dense brick stops its rays within a few samples, so
/// the area over-counts it, and the ranks given the dense bricks would be left short of
/// work.
fn render_cost(
    job: &RenderJob,
    bounds: Option<&dyn OpacityBound>,
    dir: glam::DVec3,
    weights: &[f32],
    b: BrickId,
) -> u64 {
    let ib = job.grid.index_box(b);
    let voxels: f64 = (0..3).map(|a| f64::from(ib.hi[a] - ib.lo[a])).product();
    let share = bounds.map_or(1.0, |bd| {
        let alpha = f64::from(bd.opacity(b, dir, weights, false)).clamp(0.0, 0.999_999);
        let rate = -(1.0 - alpha).ln() / f64::from(bd.core_length()).max(1e-6);
        if rate <= 0.0 {
            return 1.0;
        }
        let to_ert = -(1.0 - f64::from(job.settings.ert).min(0.999_999)).ln() / rate;
        let edge = job.grid.brick_size() as f64;
        (to_ert / edge).min(1.0)
    });
    (voxels * share * 64.0).round() as u64
}

/// Timeout of each exchange of a frame: generous, it only turns a lost peer into an error.
const EXCHANGE_TIMEOUT: Duration = Duration::from_secs(120);

/// One rank's part of a frame (paper §4.2): cull for its tile, exchange visible ids,
/// ray-cast its own visible bricks, send fragments to tile owners, gather on rank 0.
/// Rank 0 returns the frame and the statistics of every rank; the others return `None`.
///
/// # Errors
/// [`FrameError`] for bad options or a failed exchange; a failing rank aborts `comm` so that
/// no peer waits forever.
pub fn render_frame_on(
    comm: &dyn Communicator,
    job: &RenderJob,
    bounds: Option<&dyn OpacityBound>,
    camera: &Camera,
    opts: &FrameOptions,
) -> Result<Option<(Image, FrameStats)>, FrameError> {
    frame_on_with(comm, job, job.look(), bounds, camera, opts)
}

/// [`render_frame_on`] with `look` in place of the job's weights and shading.
pub(crate) fn frame_on_with(
    comm: &dyn Communicator,
    job: &RenderJob,
    look: Look<'_>,
    bounds: Option<&dyn OpacityBound>,
    camera: &Camera,
    opts: &FrameOptions,
) -> Result<Option<(Image, FrameStats)>, FrameError> {
    let result = rank_frame(comm, job, look, bounds, camera, opts);
    if let Err(e) = &result {
        if !e.is_abort() {
            comm.abort(&e.to_string());
        }
    }
    result
}

fn rank_frame(
    comm: &dyn Communicator,
    job: &RenderJob,
    look: Look<'_>,
    bounds: Option<&dyn OpacityBound>,
    camera: &Camera,
    opts: &FrameOptions,
) -> Result<Option<(Image, FrameStats)>, FrameError> {
    check_options(bounds, opts)?;
    if opts.cull == CullMode::Exact {
        if let Some(why) = job.whole_lattice_refusal("the exact cull") {
            return Err(FrameError::WholeLattice(why));
        }
    }
    let start = Instant::now();
    let me = comm.rank();
    let weights = look.weights;
    let verify = opts.verify || opts.cull == CullMode::Verified;
    // Read before this frame stores its own set (after verification, which every rank
    // reaches only once all have culled), so it says what the cull below predicts from.
    let predicted_by = verify.then(|| match predictor_of(opts) {
        Predictor::Previous if !job.has_previous() => Predictor::Proxy.name(),
        p => p.name(),
    });
    let cls = job.sampled.classify(weights, job.settings.step);
    let settings = RenderSettings {
        shade: look.shade,
        ..job.settings
    };
    let caster = RayCaster::new(&job.volume, &cls, settings);
    let bricks = FrameBricks::new(&job.volume, &job.grid, &job.sampled, weights, camera);
    let assignment = job.assignment(opts.curve, comm.size(), opts.replicas)?;
    if opts.cull == CullMode::Verified
        && matches!(opts.predictor, Predictor::Proxy | Predictor::Previous)
    {
        job.stream_proxy()?;
    }

    // Cull (or predict) for this rank's tile.
    let t = Instant::now();
    let layout = match bricks.bounds {
        Some(b) => Some(TileLayout::new(
            camera.width,
            camera.height,
            b,
            comm.size(),
        )?),
        None => None,
    };
    let my_tile = layout
        .as_ref()
        .and_then(|l| l.tile_of(me).and_then(|id| l.tile(id)));
    let culler = Culler {
        volume: &job.volume,
        grid: &job.grid,
        mode: opts.cull,
        threshold: opts.cull_threshold,
        weights,
        bounds,
        caster: &caster,
        scratch: &job.cull_scratch,
        skip_sub_bricks: true,
    };
    let culled = my_tile
        .map(|tile| cull_tile(job, &culler, (camera, &bricks), tile, opts))
        .unwrap_or_default();
    let cull_ms = t.elapsed().as_secs_f64() * 1e3;

    // Every rank learns the union of the visible sets: a brick is visible when it is visible
    // in any tile (the tiles' buffers agree wherever either is below the threshold).
    let t = Instant::now();
    let all = comm.all_gather(ids_to_bytes(&culled.visible), EXCHANGE_TIMEOUT)?;
    let mut visible = vec![false; job.grid.len()];
    for bytes in &all {
        mark(&mut visible, bytes);
    }
    let mut comm_ms = t.elapsed().as_secs_f64() * 1e3;

    // Ray-cast this rank's visible bricks, each over its own footprint.
    let t = Instant::now();
    let frame = camera.frame();
    let mine_of = |set: &[bool]| -> Vec<BrickId> {
        if assignment.replicas() == 1 {
            assignment
                .of(me)
                .iter()
                .copied()
                .filter(|b| set[b.index()])
                .collect()
        } else {
            // Every rank makes the same choice from the same set: no messages.
            let ids: Vec<BrickId> = job.grid.ids().filter(|b| set[b.index()]).collect();
            let cost = |b: BrickId| render_cost(job, bounds, frame.forward, weights, b);
            ids.iter()
                .zip(assignment.renderers(&ids, &cost))
                .filter(|(_, r)| *r == me)
                .map(|(b, _)| *b)
                .collect()
        }
    };
    // What this rank reads from the brick store (its own bricks only).
    let reads = crate::store::ReadCounts::default();
    let render_all = |ids: &[BrickId]| -> Result<(Vec<TileFragment>, RayStats), FrameError> {
        // From a store, bricks go in id order (z slowest): neighbours sharing a Zarr chunk
        // follow each other, so that each chunk is decoded about once while it is cached.
        // Fragments are composited by their (depth, brick) keys, whatever their order.
        let sorted: Vec<BrickId>;
        let ids = if job.store.is_some() {
            sorted = {
                let mut v = ids.to_vec();
                v.sort_unstable();
                v
            };
            &sorted[..]
        } else {
            ids
        };
        let done: Vec<(TileFragment, RayStats)> = ids
            .par_iter()
            .map(|id| {
                let rect = bricks.footprints[id.index()].expect("visible bricks are on screen");
                let ibox = job.grid.index_box(*id);
                let (pixels, st) = match (job.bricks.as_ref().and_then(|s| s.get(*id)), &job.store)
                {
                    (Some(copy), _) => caster.render_box_copy(camera, &frame, rect, &ibox, copy),
                    (None, Some(store)) => {
                        let copy = store.get(&job.volume, &job.grid, *id, &reads)?;
                        caster.render_box_copy(camera, &frame, rect, &ibox, &copy)
                    }
                    (None, None) => caster.render_box(camera, &frame, rect, &ibox),
                };
                Ok((
                    TileFragment {
                        brick: *id,
                        depth_key: bricks.depth_key[id.index()],
                        rect,
                        pixels,
                    },
                    st,
                ))
            })
            .collect::<Result<_, FrameError>>()?;
        let (fragments, rays): (Vec<TileFragment>, Vec<RayStats>) = done.into_iter().unzip();
        let mut total = RayStats::default();
        for r in rays {
            total += r;
        }
        Ok((fragments, total))
    };
    let mut mine = mine_of(&visible);
    let (mut fragments, mut mine_stats) = render_all(&mine)?;
    let raycast_ms = t.elapsed().as_secs_f64() * 1e3;

    // Fragments to tile owners, tiles to rank 0; a verified frame is checked and repaired
    // between the two.
    let t = Instant::now();
    let (mut verify_ms, mut repair_ms, mut repaired) = (0.0, 0.0, 0usize);
    let image = match &layout {
        Some(l) if verify => {
            let view = VerifyView {
                camera,
                volume: &job.volume,
                grid: &job.grid,
                bricks: &bricks,
            };
            // This tile's culled bricks that no other tile found visible: the ones whose
            // absence verification must justify here.
            let suspects: Vec<BrickId> = culled
                .culled
                .iter()
                .copied()
                .filter(|b| !visible[b.index()])
                .collect();
            let tile = my_tile.unwrap_or(l.bounds());
            let single = comm.size() == 1;
            let ds = DirectSend::new(EXCHANGE_TIMEOUT);
            let mut received = if single {
                None
            } else {
                Some(ds.exchange(comm, l, &fragments)?)
            };
            let tv = Instant::now();
            let verdict = match &received {
                None => verify_tile(&view, tile, &fragments, &suspects, opts.cull_threshold),
                Some(r) => verify_tile(
                    &view,
                    r.rect(),
                    r.fragments(),
                    &suspects,
                    opts.cull_threshold,
                ),
            };
            verify_ms = tv.elapsed().as_secs_f64() * 1e3;

            // Repair, in one round. Why one suffices: blended opacity only grows as more
            // fragments are blended, and a brick passed verification because the bricks in
            // front of it that were rendered — a subset of those rendered in the end —
            // already reach the threshold over its footprint. Adding the repaired bricks
            // can only raise that opacity, so every brick that passed still passes, and
            // every brick that failed is now rendered: nothing is left to repair. The
            // repaired fragments join the others before the blend sorts them, so they
            // land in visibility order, not on top.
            let tr = Instant::now();
            let all = comm.all_gather(
                verdict_to_bytes(&verdict.failing, &verdict.needed),
                EXCHANGE_TIMEOUT,
            )?;
            let mut failing = vec![false; job.grid.len()];
            let mut needed = vec![false; job.grid.len()];
            for bytes in &all {
                let (f, n) = bytes_to_verdict(bytes)
                    .ok_or_else(|| FrameError::Gather("malformed verification message".into()))?;
                mark(&mut failing, f);
                mark(&mut needed, n);
                mark(&mut needed, f);
            }
            // Only a rendered brick or a failing one can be needed.
            for (n, (v, f)) in needed.iter_mut().zip(visible.iter().zip(&failing)) {
                *n &= *v || *f;
            }
            repaired = failing.iter().filter(|f| **f).count();
            *job.previous
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(needed);
            if repaired > 0 {
                let fix = mine_of(&failing);
                let (more, st) = render_all(&fix)?;
                mine_stats += st;
                mine.extend(fix);
                match &mut received {
                    None => fragments.extend(more),
                    Some(r) => ds.exchange_more(comm, l, r, &more)?,
                }
                for (v, f) in visible.iter_mut().zip(&failing) {
                    *v |= *f;
                }
            }
            repair_ms = tr.elapsed().as_secs_f64() * 1e3;
            match received {
                None => Some(crate::composite::composite_local(
                    &fragments,
                    camera.width,
                    camera.height,
                )?),
                Some(r) => ds.finish(comm, l, r)?,
            }
        }
        // One rank has nothing to exchange: blend in place, the same frame bit for bit.
        Some(_) if comm.size() == 1 => Some(crate::composite::composite_local(
            &fragments,
            camera.width,
            camera.height,
        )?),
        Some(l) => DirectSend::new(EXCHANGE_TIMEOUT).composite(comm, l, fragments)?,
        None => (me.index() == 0).then(|| Image::new(camera.width, camera.height)),
    };
    let composite_ms = t.elapsed().as_secs_f64() * 1e3 - verify_ms - repair_ms;

    let t = Instant::now();
    let mut rank = RankStats {
        rank: me.index(),
        bricks_rendered: mine.len(),
        samples: mine_stats.samples,
        cull_ms,
        raycast_ms,
        composite_ms,
        comm_ms,
        bytes_sent: comm.bytes_sent(),
        rays: mine_stats.rays,
        resident_bytes: resident_bytes(),
        verify_ms,
        repair_ms,
        bytes_read: reads.bytes_read(),
        bricks_read: reads.bricks_read(),
        cache_hits: reads.cache_hits(),
        chunks_decoded: reads.chunks_decoded(),
    };
    let gathered = comm.gather(
        Rank(0),
        serde_json::to_vec(&rank).expect("stats serialise"),
        EXCHANGE_TIMEOUT,
    )?;
    comm_ms += t.elapsed().as_secs_f64() * 1e3;
    rank.comm_ms = comm_ms;
    let (Some(image), Some(gathered)) = (image, gathered) else {
        return Ok(None);
    };
    let mut ranks: Vec<RankStats> = gathered
        .iter()
        .map(|b| serde_json::from_slice(b))
        .collect::<Result<_, _>>()
        .map_err(|e| FrameError::Gather(format!("rank stats: {e}")))?;
    ranks[0] = rank;
    let total = RayStats {
        rays: ranks.iter().map(|r| r.rays).sum(),
        samples: ranks.iter().map(|r| r.samples).sum(),
    };
    let mut stats = FrameStats::from_rays(total, start.elapsed().as_secs_f64(), "bricks");
    // Counted after the frame's time is taken: the brick path never needs it.
    stats.pixel_rays = rays_meeting(&job.volume, camera);
    stats.samples_per_ray = total.samples as f64 / stats.pixel_rays.max(1) as f64;
    let n_visible = visible.iter().filter(|v| **v).count();
    stats.cull = Some(opts.cull);
    stats.verified = verify;
    stats.predictor = verify.then(|| predictor_of(opts).name());
    stats.predicted_by = predicted_by;
    stats.bricks = BrickCounts {
        total: job.grid.len(),
        empty: bricks.empty,
        non_empty: job.grid.len() - bricks.empty,
        culled: bricks.order.len() - n_visible,
        visible: n_visible,
        repaired,
    };
    stats.culled_bricks = bricks
        .order
        .iter()
        .copied()
        .filter(|b| !visible[b.index()])
        .collect();
    stats.bytes_read = ranks.iter().map(|r| r.bytes_read).sum();
    stats.bricks_read = ranks.iter().map(|r| r.bricks_read).sum();
    stats.cache_hits = ranks.iter().map(|r| r.cache_hits).sum();
    if let Some(store) = &job.store {
        stats.cache_peak_bytes = store.summary().cache_peak_bytes;
        stats.memory_budget = Some(store.budget());
    }
    stats.ranks = ranks;
    stats.deal = Some(assignment.deal().name());
    Ok(Some((image, stats)))
}

/// What predicts a frame's cull: a verified frame's predictor, or the mode's own cull.
fn predictor_of(opts: &FrameOptions) -> Predictor {
    match opts.cull {
        CullMode::Verified => opts.predictor,
        CullMode::Pof => Predictor::Pof,
        CullMode::PofSet => Predictor::PofSet,
        CullMode::None => Predictor::Nothing,
        // The oracle's cull is its own; verifying it finds nothing to repair.
        CullMode::Exact => Predictor::Nothing,
    }
}

/// This rank's cull of `tile`: the mode's, or for a verified frame its predictor's.
fn cull_tile(
    job: &RenderJob,
    culler: &Culler<'_>,
    (camera, bricks): (&Camera, &FrameBricks),
    tile: PixelRect,
    opts: &FrameOptions,
) -> CullResult {
    if opts.cull != CullMode::Verified {
        return culler.cull(camera, bricks, tile);
    }
    let start = Instant::now();
    let with_mode = |mode| Culler { mode, ..*culler }.cull(camera, bricks, tile);
    let proxy = || {
        job.proxy().predict(
            (&job.volume, &job.grid),
            (camera, bricks),
            culler.weights,
            tile,
            opts.cull_threshold,
        )
    };
    let (visible, culled) = match opts.predictor {
        Predictor::Pof => return with_mode(CullMode::Pof),
        Predictor::PofSet => return with_mode(CullMode::PofSet),
        Predictor::Proxy => proxy(),
        Predictor::Previous => {
            let previous = job
                .previous
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .clone();
            match previous.filter(|p| p.len() == job.grid.len()) {
                Some(p) => split(&bricks_over_tile(bricks, tile), |b| !p[b.index()]),
                None => proxy(),
            }
        }
        Predictor::Nothing => split(&bricks_over_tile(bricks, tile), |_| false),
        Predictor::Everything => split(&bricks_over_tile(bricks, tile), |_| true),
        Predictor::Random(seed) => {
            split(&bricks_over_tile(bricks, tile), |b| random_culls(seed, b))
        }
    };
    CullResult {
        visible,
        culled,
        cull_ms: start.elapsed().as_secs_f64() * 1e3,
    }
}

/// Brick ids as little-endian `u32`s.
fn ids_to_bytes(ids: &[BrickId]) -> Vec<u8> {
    ids.iter().flat_map(|b| b.0.to_le_bytes()).collect()
}

/// Sets `set[id]` for every id of `bytes` (little-endian `u32`s; ids past the end are
/// ignored).
fn mark(set: &mut [bool], bytes: &[u8]) {
    for c in bytes.chunks_exact(4) {
        let id = u32::from_le_bytes([c[0], c[1], c[2], c[3]]) as usize;
        if let Some(v) = set.get_mut(id) {
            *v = true;
        }
    }
}

/// A tile's verdict for the exchange: the count of failing ids, the failing ids, the
/// needed ids.
fn verdict_to_bytes(failing: &[BrickId], needed: &[BrickId]) -> Vec<u8> {
    let mut out = (failing.len() as u32).to_le_bytes().to_vec();
    out.extend(ids_to_bytes(failing));
    out.extend(ids_to_bytes(needed));
    out
}

/// The (failing, needed) id bytes of [`verdict_to_bytes`]; `None` when malformed.
fn bytes_to_verdict(bytes: &[u8]) -> Option<(&[u8], &[u8])> {
    let n = u32::from_le_bytes(bytes.get(..4)?.try_into().ok()?) as usize;
    let rest = &bytes[4..];
    let split = n.checked_mul(4).filter(|s| *s <= rest.len())?;
    Some(rest.split_at(split))
}

/// This process's resident set size in bytes (Linux), 0 where unknown.
#[must_use]
pub fn resident_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| {
            s.split_whitespace()
                .nth(1)
                .and_then(|p| p.parse::<u64>().ok())
        })
        .map_or(0, |pages| pages * 4096)
}

#[cfg(test)]
mod test {
    use super::*;
    use crate::volume::phantom::Phantom;

    /// A bound of one opacity for every brick.
    struct Flat(f32);

    impl OpacityBound for Flat {
        fn core_length(&self) -> f32 {
            8.0
        }
        fn opacity(&self, _: BrickId, _: glam::DVec3, _: &[f32], _: bool) -> f32 {
            self.0
        }
        fn opacity_cone(&self, _: BrickId, _: glam::DVec3, _: f64, _: &[f32], _: bool) -> f32 {
            self.0
        }
    }

    #[test]
    fn render_cost_counts_voxels_less_what_early_termination_saves() {
        // 40 = 16 + 16 + 8: the last brick along each axis is 8 voxels deep.
        let job = RenderJob::new(
            Phantom::SheppLogan.generate(40),
            crate::render::families::for_phantom(Phantom::SheppLogan),
            16,
            RenderSettings::default(),
        )
        .unwrap();
        let w = job.tf.weights.clone();
        let dir = glam::DVec3::Z;
        let (full, part) = (job.grid.id([0, 0, 0]), job.grid.id([2, 2, 2]));
        let cost = |b: Option<&dyn OpacityBound>, id| render_cost(&job, b, dir, &w, id);
        // Without a bound, or a bound of 0: every ray runs its whole chord.
        assert_eq!(cost(None, full), 16 * 16 * 16 * 64);
        assert_eq!(cost(Some(&Flat(0.0)), full), 16 * 16 * 16 * 64);
        // (Index boxes span cells between voxel centres: the last brick's 8 voxels, 7 cells.)
        assert_eq!(cost(None, part), 7 * 7 * 7 * 64);
        // A bound reaching the early-termination threshold over the core length L = 8 stops
        // rays after 8 of the brick's 16: half the samples.
        let ert = job.settings.ert;
        let half = cost(Some(&Flat(ert)), full);
        assert!(half.abs_diff(16 * 16 * 16 * 32) <= 64, "{half}");
        // Denser bricks cost less, never more (below 0.9 over L = 8, rays cross the whole
        // brick before terminating).
        let costs: Vec<u64> = [0.0, 0.3, 0.6, 0.9, ert, 0.9999]
            .iter()
            .map(|a| cost(Some(&Flat(*a)), full))
            .collect();
        assert!(costs.windows(2).all(|c| c[1] <= c[0]), "{costs:?}");
        assert!(costs[5] < costs[4] && costs[4] < costs[0], "{costs:?}");
    }
}
