//! One rank's part of a distributed job whose communicator lives for the whole run (MPI
//! processes, or threads sharing a [`crate::comm::LocalCommunicator`] group).
//!
//! No rank reads the whole volume: each measures the value ranges of the bricks dealt to it
//! and the ranges are exchanged, since culling needs every brick's; then each keeps private
//! copies of the bricks it ray-casts and lets the volume's mapped pages go. Frames are
//! rendered with [`render_frame_on`], and their statistics report each frame's own bytes
//! sent, as a frame on a fresh communicator would.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, PoisonError};
use std::time::Duration;

use crate::brick::{BrickError, BrickGrid, BrickId, BrickStore, ValueRange};
use crate::comm::{CommError, Communicator};
use crate::cull::OpacityBound;
use crate::distribute::{BrickAssignment, Curve, Deal, DistributeError};
use crate::frame::{render_frame_on, FrameError, FrameOptions, FrameStats, RenderJob};
use crate::render::{Camera, Image};
use crate::volume::Volume;
use crate::{Frame, FrameRequest, Scene};

/// Bound on the exchange of brick ranges: generous, it only turns a lost rank into an error.
const EXCHANGE_TIMEOUT: Duration = Duration::from_secs(120);

/// Bytes of one brick's entry in the range exchange: id, min, max, little-endian.
const RANGE_ENTRY: usize = 12;

/// Errors setting up a rank.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SetupError {
    /// Bad brick size, or a brick id outside the grid.
    #[error(transparent)]
    Brick(#[from] BrickError),
    /// Bricks could not be dealt to the ranks.
    #[error(transparent)]
    Distribute(#[from] DistributeError),
    /// The exchange between ranks failed.
    #[error(transparent)]
    Comm(#[from] CommError),
    /// A rank's ranges are not whole entries of 12 bytes.
    #[error("rank {rank} sent {bytes} bytes of brick ranges")]
    Ranges {
        /// The rank that sent them.
        rank: usize,
        /// How many bytes it sent.
        bytes: usize,
    },
    /// A rank's own bricks could not be read from the volume's storage (a Zarr level
    /// under a memory budget).
    #[error(transparent)]
    Store(Box<crate::Error>),
    /// A brick whose range no rank sent.
    #[error("brick {0}: no rank measured its value range")]
    Unmeasured(usize),
}

impl SetupError {
    fn is_abort(&self) -> bool {
        matches!(self, SetupError::Comm(CommError::Aborted { .. }))
    }
}

/// This rank of a distributed job: the set-up of its grid and bricks, and its frames.
pub struct DistributedRank<'c> {
    comm: &'c dyn Communicator,
    /// Root only: every rank's cumulative bytes sent after the previous frame.
    sent_before: Mutex<Vec<u64>>,
    /// Voxel bytes of this rank's private brick copies.
    copy_bytes: AtomicU64,
    /// How the bricks whose ranges this rank measures are dealt.
    deal: Deal,
}

impl<'c> DistributedRank<'c> {
    /// This rank of `comm`'s group.
    #[must_use]
    pub fn new(comm: &'c dyn Communicator) -> Self {
        DistributedRank {
            comm,
            sent_before: Mutex::new(Vec::new()),
            copy_bytes: AtomicU64::new(0),
            deal: Deal::Auto,
        }
    }

    /// The same rank measuring the bricks dealt by `deal` ([`Deal::Auto`] by default; give
    /// the job's frames the same [`crate::frame::RenderJob::deal`]).
    #[must_use]
    pub fn with_deal(mut self, deal: Deal) -> Self {
        self.deal = deal;
        self
    }

    /// The communicator.
    #[must_use]
    pub fn comm(&self) -> &'c dyn Communicator {
        self.comm
    }

    /// `volume`'s brick grid with every brick's value range: this rank measures the bricks
    /// dealt to it round-robin along `curve` and learns the others' from their ranks. Every
    /// rank must call it; the grid is the one [`BrickGrid::from_volume`] measures alone.
    /// A volume read chunk by chunk (see [`DistributedRank::with_deal`]) is dealt by runs of
    /// chunks of equal brick counts instead, so that each rank decodes only its part.
    ///
    /// # Errors
    /// [`SetupError`] for a bad brick size, a failed exchange, or ranges missing or garbled;
    /// a failing rank aborts the communicator so that no peer waits for it.
    pub fn measure_grid(
        &self,
        volume: &Volume,
        brick_size: usize,
        curve: Curve,
    ) -> Result<BrickGrid, SetupError> {
        self.measure_grid_within(volume, brick_size, curve, None)
    }

    /// [`DistributedRank::measure_grid`] under a memory budget: a volume that does not fit
    /// it has this rank's bricks read from storage ([`crate::store::measure_own`]: positioned
    /// reads of a raw file, or a Zarr level's chunks), not through the memory map.
    ///
    /// # Errors
    /// As [`DistributedRank::measure_grid`], and [`SetupError::Store`] for a missing or
    /// corrupt chunk.
    pub fn measure_grid_within(
        &self,
        volume: &Volume,
        brick_size: usize,
        curve: Curve,
        budget: Option<u64>,
    ) -> Result<BrickGrid, SetupError> {
        let result = self.measure_grid_inner(volume, brick_size, curve, budget);
        if let Err(e) = &result {
            if !e.is_abort() {
                self.comm.abort(&e.to_string());
            }
        }
        result
    }

    fn measure_grid_inner(
        &self,
        volume: &Volume,
        brick_size: usize,
        curve: Curve,
        budget: Option<u64>,
    ) -> Result<BrickGrid, SetupError> {
        let counts = BrickGrid::counts_for(volume.dims(), brick_size)?;
        let ranks = self.comm.size();
        // Every brick costs the same to measure, and no range is known yet to weigh by.
        let owners =
            match crate::distribute::chunks::chunk_shape_for(volume, brick_size, self.deal)? {
                Some(chunk) => {
                    BrickAssignment::by_chunks(counts, brick_size, chunk, curve, ranks, &|_| 1)?
                }
                None => BrickAssignment::new(counts, curve, ranks)?,
            };
        let me = self.comm.rank();
        let mut grid = crate::store::measure_own(volume, brick_size, budget, &|id| {
            owners.owner(id) == Some(me)
        })
        .map_err(|e| match e {
            crate::Error::Brick(b) => SetupError::Brick(b),
            e => SetupError::Store(Box::new(e)),
        })?;
        let mine = encode_ranges(&grid, owners.of(me));
        let all = self.comm.all_gather(mine, EXCHANGE_TIMEOUT)?;
        apply_ranges(&mut grid, &all)?;
        Ok(grid)
    }

    /// Keeps in `job.bricks` private copies of the bricks this rank holds in `job`'s
    /// assignment along `curve` with `replicas` owners per brick, and releases the volume's
    /// mapped pages: from then on frames sample the copies, and only the exact culling
    /// oracle (which renders bricks this rank does not own) reads the volume again.
    ///
    /// # Errors
    /// [`SetupError::Distribute`] for replicas outside `1..=ranks`.
    pub fn keep_own_bricks(
        &self,
        job: &mut RenderJob,
        curve: Curve,
        replicas: usize,
    ) -> Result<(), SetupError> {
        let owners = job.assignment(curve, self.comm.size(), replicas)?;
        if !job.volume.is_resident() {
            // No voxels to copy from: such a job reads its bricks through a store.
            return Err(SetupError::Store(Box::new(crate::Error::Engine {
                engine: "bricks",
                why: format!(
                    "{} is a Zarr level larger than the memory budget: its ranks read their bricks on demand (DistributedRank::read_own_bricks) rather than copy them",
                    job.volume.source()
                ),
            })));
        }
        let store = BrickStore::new(&job.volume, &job.grid, &owners.held_by(self.comm.rank()));
        job.volume.release_pages();
        self.copy_bytes
            .store(store.bytes() as u64, Ordering::Relaxed);
        job.bricks = Some(store);
        Ok(())
    }

    /// Under a memory budget the volume does not fit: instead of copies of all its bricks
    /// ([`DistributedRank::keep_own_bricks`]), this rank reads the bricks it renders (its
    /// own, and the repairs it owns) on demand into a brick cache within `budget`
    /// ([`crate::store::cache_for`]), from the raw file or the Zarr chunks. A volume that
    /// fits the budget keeps its copies.
    ///
    /// # Errors
    /// As [`DistributedRank::keep_own_bricks`], and [`SetupError::Store`] when the file
    /// cannot be opened again.
    pub fn read_own_bricks(
        &self,
        job: &mut RenderJob,
        curve: Curve,
        replicas: usize,
        budget: u64,
    ) -> Result<(), SetupError> {
        match crate::store::cache_for(&job.volume, Some(budget)) {
            Ok(Some(store)) => {
                job.store = Some(store);
                self.copy_bytes.store(0, Ordering::Relaxed);
                Ok(())
            }
            Ok(None) => self.keep_own_bricks(job, curve, replicas),
            Err(e) => Err(SetupError::Store(Box::new(e))),
        }
    }

    /// Voxel bytes of the copies [`DistributedRank::keep_own_bricks`] made (0 before).
    #[must_use]
    pub fn copy_bytes(&self) -> u64 {
        self.copy_bytes.load(Ordering::Relaxed)
    }

    /// This rank's part of one frame (see [`render_frame_on`]; `opts.ranks` is ignored:
    /// the group is the communicator's). The root returns the frame; the others return
    /// `None`. Each rank's `bytes_sent` counts what it sent since its count in the previous
    /// frame's statistics rather than since the communicator began: this frame's messages,
    /// after the previous frame's statistics message (or, for the first frame, the set-up's
    /// exchange).
    ///
    /// # Errors
    /// [`FrameError`] as [`render_frame_on`].
    pub fn frame(
        &self,
        job: &RenderJob,
        bounds: Option<&dyn OpacityBound>,
        camera: &Camera,
        opts: &FrameOptions,
    ) -> Result<Option<(Image, FrameStats)>, FrameError> {
        let opts = FrameOptions {
            ranks: 1,
            ..opts.clone()
        };
        let Some((image, mut stats)) = render_frame_on(self.comm, job, bounds, camera, &opts)?
        else {
            return Ok(None);
        };
        self.per_frame_bytes(&mut stats);
        Ok(Some((image, stats)))
    }

    /// [`DistributedRank::frame`] for a [`Scene`]: this rank's part of `request`'s frame
    /// (its rank count is the communicator's), the root returning the frame, with each
    /// rank's `bytes_sent` counted per frame.
    ///
    /// # Errors
    /// [`crate::Error`] as [`Scene::render_on`].
    pub fn render(
        &self,
        scene: &Scene,
        request: &FrameRequest<'_>,
    ) -> crate::Result<Option<Frame>> {
        let Some(mut frame) = scene.render_on(self.comm, request)? else {
            return Ok(None);
        };
        self.per_frame_bytes(&mut frame.stats);
        Ok(Some(frame))
    }

    /// Turns the communicator's cumulative byte counts into this frame's: what each rank
    /// sent since its count in the previous frame's statistics.
    fn per_frame_bytes(&self, stats: &mut FrameStats) {
        let mut before = self
            .sent_before
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        before.resize(stats.ranks.len(), 0);
        for (r, prev) in stats.ranks.iter_mut().zip(before.iter_mut()) {
            let total = r.bytes_sent;
            r.bytes_sent = total.saturating_sub(*prev);
            *prev = total;
        }
    }
}

/// The ranges of `ids` as (id, min, max) little-endian entries.
fn encode_ranges(grid: &BrickGrid, ids: &[BrickId]) -> Vec<u8> {
    let mut out = Vec::with_capacity(ids.len() * RANGE_ENTRY);
    for id in ids {
        let r = grid.range(*id);
        out.extend_from_slice(&id.0.to_le_bytes());
        out.extend_from_slice(&r.min.to_le_bytes());
        out.extend_from_slice(&r.max.to_le_bytes());
    }
    out
}

/// Sets the ranges every rank sent (`all[r]` from rank `r`); every brick must end up with
/// one.
fn apply_ranges(grid: &mut BrickGrid, all: &[Vec<u8>]) -> Result<(), SetupError> {
    let word = |c: &[u8]| [c[0], c[1], c[2], c[3]];
    for (rank, bytes) in all.iter().enumerate() {
        if bytes.len() % RANGE_ENTRY != 0 {
            return Err(SetupError::Ranges {
                rank,
                bytes: bytes.len(),
            });
        }
        for t in bytes.chunks_exact(RANGE_ENTRY) {
            let id = BrickId(u32::from_le_bytes(word(&t[0..4])));
            let range = ValueRange {
                min: f32::from_le_bytes(word(&t[4..8])),
                max: f32::from_le_bytes(word(&t[8..12])),
            };
            grid.set_range(id, range)?;
        }
    }
    match grid.ranges().iter().position(|r| r.min > r.max) {
        Some(b) => Err(SetupError::Unmeasured(b)),
        None => Ok(()),
    }
}

#[cfg(test)]
mod test {
    use super::*;
    use crate::comm::{LocalCommunicator, Rank};
    use crate::cull::CullMode;
    use crate::frame::render_frame;
    use crate::render::{families, Projection, RenderSettings};
    use crate::volume::phantom::Phantom;

    const SIZE: usize = 40;

    fn volume() -> Volume {
        Phantom::SheppLogan.generate(SIZE)
    }

    fn job(grid: BrickGrid) -> RenderJob {
        let tf = families::for_phantom(Phantom::SheppLogan);
        RenderJob::with_grid(volume(), tf, grid, RenderSettings::default()).unwrap()
    }

    #[test]
    fn ranks_measure_the_grid_of_one_process() {
        let whole = BrickGrid::from_volume(&volume(), 8).unwrap();
        for curve in [Curve::Hilbert, Curve::Z] {
            for n in [1, 2, 3, 5] {
                let grids = LocalCommunicator::run(n, |comm| {
                    let vol = volume();
                    DistributedRank::new(comm).measure_grid(&vol, 8, curve)
                });
                for (r, g) in grids.into_iter().enumerate() {
                    let g = g.unwrap();
                    assert_eq!(g.counts(), whole.counts(), "{curve:?} {n} ranks, rank {r}");
                    assert_eq!(g.ranges(), whole.ranges(), "{curve:?} {n} ranks, rank {r}");
                    assert_eq!(g.value_range(), whole.value_range());
                }
            }
        }
    }

    #[test]
    fn ranks_give_the_frame_of_one_process_with_each_frames_own_bytes() {
        let single = job(BrickGrid::from_volume(&volume(), 16).unwrap());
        let cam = Camera::orbit(&single.volume, 30.0, 20.0, 48, 40, Projection::Orthographic);
        for (cull, replicas) in [
            (CullMode::None, 1),
            (CullMode::Exact, 1),
            (CullMode::None, 2),
        ] {
            for n in [2, 3] {
                let opts = FrameOptions {
                    cull,
                    ranks: n,
                    replicas,
                    ..FrameOptions::default()
                };
                let (want, want_stats) = render_frame(&single, None, &cam, &opts).unwrap();
                let (one, _) = render_frame(
                    &single,
                    None,
                    &cam,
                    &FrameOptions {
                        ranks: 1,
                        replicas: 1,
                        ..opts.clone()
                    },
                )
                .unwrap();
                let results = LocalCommunicator::run(n, |comm| {
                    let rank = DistributedRank::new(comm);
                    let vol = volume();
                    let grid = rank.measure_grid(&vol, 16, opts.curve).unwrap();
                    let mut job = job(grid);
                    rank.keep_own_bricks(&mut job, opts.curve, replicas)
                        .unwrap();
                    let held = job.bricks.as_ref().map_or(0, BrickStore::len);
                    let frames: Vec<_> = (0..2)
                        .map(|_| rank.frame(&job, None, &cam, &opts).unwrap())
                        .collect();
                    (held, rank.copy_bytes(), frames)
                });
                let label = format!("{cull:?}, {n} ranks, {replicas} replicas");
                let assignment = single.assignment(opts.curve, n, replicas).unwrap();
                let held: usize = results.iter().map(|r| r.0).sum();
                assert_eq!(held, single.grid.len() * replicas, "{label}");
                for (r, (h, bytes, frames)) in results.iter().enumerate() {
                    assert_eq!(*h, assignment.held_by(Rank(r as u32)).len(), "{label}");
                    assert!(*bytes > 0, "{label}: rank {r} copied nothing");
                    let some = frames.iter().filter(|f| f.is_some()).count();
                    assert_eq!(some, if r == 0 { 2 } else { 0 }, "{label}");
                }
                for (k, (image, stats)) in results[0].2.iter().flatten().enumerate() {
                    assert_eq!(*image, want, "{label}");
                    assert!(image.max_abs_diff(&one).unwrap() <= 1e-6, "{label}");
                    assert_eq!(stats.bricks.visible, want_stats.bricks.visible, "{label}");
                    // Each frame's own bytes, as a frame on a fresh communicator sends, plus
                    // what was sent after the last count: the range exchange before the first
                    // frame, and each other rank's statistics message of the frame before.
                    let sent: Vec<u64> = stats.ranks.iter().map(|r| r.bytes_sent).collect();
                    let fresh: Vec<u64> = want_stats.ranks.iter().map(|r| r.bytes_sent).collect();
                    if k == 0 {
                        assert!(sent.iter().zip(&fresh).all(|(s, f)| s > f), "{label}");
                    } else {
                        assert_eq!(sent[0], fresh[0], "{label}");
                        for (s, f) in sent.iter().zip(&fresh).skip(1) {
                            assert!(s > f && s - f < 512, "{label}: {sent:?} vs {fresh:?}");
                        }
                    }
                    assert!(sent[1] > 0, "{label}: rank 1 sent nothing");
                }
            }
        }
    }

    #[test]
    fn garbled_or_missing_ranges_are_errors() {
        let vol = volume();
        let whole = BrickGrid::from_volume(&vol, 16).unwrap();
        let ids: Vec<BrickId> = whole.ids().collect();
        let (a, b) = ids.split_at(ids.len() / 2);
        let fresh = || BrickGrid::from_volume_where(&vol, 16, &|_| false).unwrap();

        let mut g = fresh();
        apply_ranges(
            &mut g,
            &[encode_ranges(&whole, a), encode_ranges(&whole, b)],
        )
        .unwrap();
        assert_eq!(g.ranges(), whole.ranges());

        let mut short = encode_ranges(&whole, b);
        short.pop();
        let e = apply_ranges(&mut fresh(), &[encode_ranges(&whole, a), short]).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!("rank 1 sent {} bytes of brick ranges", b.len() * 12 - 1)
        );

        let e = apply_ranges(&mut fresh(), &[encode_ranges(&whole, a)]).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!("brick {}: no rank measured its value range", b[0].0)
        );

        let mut far = encode_ranges(&whole, &ids[..1]);
        far[..4].copy_from_slice(&9999u32.to_le_bytes());
        let e = apply_ranges(&mut fresh(), &[far]).unwrap_err();
        assert!(
            matches!(
                e,
                SetupError::Brick(BrickError::UnknownBrick { id: 9999, .. })
            ),
            "{e}"
        );
    }

    #[test]
    fn a_failing_rank_aborts_its_peers() {
        let results = LocalCommunicator::run(3, |comm| {
            let vol = volume();
            // Rank 1 asks for an unusable brick size and fails before the exchange; the
            // others must not wait for its ranges.
            let size = if comm.rank() == Rank(1) { 1 } else { 16 };
            DistributedRank::new(comm).measure_grid(&vol, size, Curve::Hilbert)
        });
        assert!(matches!(
            &results[1],
            Err(SetupError::Brick(BrickError::BadSize(1)))
        ));
        for r in [0, 2] {
            match &results[r] {
                Err(e) => assert!(e.is_abort(), "rank {r}: {e}"),
                Ok(_) => panic!("rank {r} finished without rank 1's ranges"),
            }
        }
    }
}
