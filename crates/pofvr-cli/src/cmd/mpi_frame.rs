//! `pofvr render` under `mpirun` (cargo feature `mpi`): one pofvr rank per MPI process,
//! through [`pofvr_mpi::MpiCommunicator`] and `pofvr::Scene::render_on`. Every rank
//! opens the volume memory-mapped and reads only the bricks it owns: it measures their value
//! ranges (exchanged with the other ranks: culling needs every brick's) and ray-casts them,
//! renders its share of each frame, and rank 0 writes the outputs and `--stats`, which gains
//! `mpi_ranks` and `memory` (every rank's resident memory and host).
//!
//! Any error on any rank (a missing file, a bad flag, a failed exchange) and any panic ends
//! the whole job through `MPI_Abort`, after printing `pofvr: rank R aborted: CAUSE`.

use std::cell::{Cell, RefCell};
use std::time::Duration;

use anyhow::{anyhow, bail, Result};
use pofvr::brick::{BrickGrid, BrickId, BrickStore, ValueRange};
use pofvr::comm::{Communicator, Rank};
use pofvr::distribute::{BrickAssignment, Curve};
use pofvr::frame::RenderJob;
use pofvr::volume::Volume;
use pofvr::{Frame, FrameRequest, Scene};
use pofvr_mpi::MpiCommunicator;

use super::render::{self, Backend, MemoryStatus};
use crate::args::RenderArgs;
use crate::progress::Ui;

/// Bound on the end-of-run memory gather (it only turns a lost rank into an error).
const GATHER_TIMEOUT: Duration = Duration::from_secs(120);

struct Mpi<'a> {
    comm: &'a MpiCommunicator,
    /// Root only: every rank's `bytes_sent` after the previous frame, to report per frame.
    sent_before: RefCell<Vec<u64>>,
    /// Bytes of this rank's private brick copies.
    copy_bytes: Cell<u64>,
}

impl Backend for Mpi<'_> {
    fn is_root(&self) -> bool {
        self.comm.rank() == Rank(0)
    }

    fn frame(&self, scene: &Scene, request: &FrameRequest<'_>) -> Result<Option<Frame>> {
        let Some(Frame { image, mut stats }) = scene.render_on(self.comm, request)? else {
            return Ok(None);
        };
        // The communicator lives for the whole run, so its counts are cumulative; report
        // each frame's own bytes like the in-process path (a fresh communicator per frame).
        let mut before = self.sent_before.borrow_mut();
        before.resize(stats.ranks.len(), 0);
        for (r, prev) in stats.ranks.iter_mut().zip(before.iter_mut()) {
            let total = r.bytes_sent;
            r.bytes_sent = total.saturating_sub(*prev);
            *prev = total;
        }
        Ok(Some(Frame { image, stats }))
    }

    fn grid(&self, volume: &Volume, brick_size: usize, curve: Curve) -> Result<BrickGrid> {
        let counts = BrickGrid::counts_for(volume.dims(), brick_size)?;
        let owners = BrickAssignment::new(counts, curve, self.comm.size())?;
        let me = self.comm.rank();
        let mut grid =
            BrickGrid::from_volume_where(volume, brick_size, &|id| owners.owner(id) == Some(me))?;
        // Each rank's measured ranges as (id, min, max) little-endian triples.
        let mut mine = Vec::new();
        for id in owners.of(me) {
            let r = grid.range(*id);
            mine.extend_from_slice(&id.0.to_le_bytes());
            mine.extend_from_slice(&r.min.to_le_bytes());
            mine.extend_from_slice(&r.max.to_le_bytes());
        }
        let all = self.comm.all_gather(mine, GATHER_TIMEOUT)?;
        let word = |c: &[u8]| [c[0], c[1], c[2], c[3]];
        for (rank, bytes) in all.iter().enumerate() {
            if bytes.len() % 12 != 0 {
                bail!("rank {rank} sent {} bytes of brick ranges", bytes.len());
            }
            for t in bytes.chunks_exact(12) {
                let id = BrickId(u32::from_le_bytes(word(&t[0..4])));
                let range = ValueRange {
                    min: f32::from_le_bytes(word(&t[4..8])),
                    max: f32::from_le_bytes(word(&t[8..12])),
                };
                grid.set_range(id, range)?;
            }
        }
        if let Some(r) = grid.ranges().iter().position(|r| r.min > r.max) {
            bail!("brick {r}: no rank measured its value range");
        }
        Ok(grid)
    }

    fn prepare(&self, job: &mut RenderJob, curve: Curve, replicas: usize) -> Result<()> {
        let owners = job.assignment(curve, self.comm.size(), replicas)?;
        let store = BrickStore::new(&job.volume, &job.grid, &owners.held_by(self.comm.rank()));
        // From here on only `--cull exact` (the oracle renders bricks it does not own) reads
        // the mapping again.
        job.volume.release_pages();
        self.copy_bytes.set(store.bytes() as u64);
        job.bricks = Some(store);
        Ok(())
    }

    fn finish(&self) -> Result<Option<serde_json::Map<String, serde_json::Value>>> {
        let mut me = MemoryStatus::now(self.comm.rank().index());
        me.brick_copy_bytes = self.copy_bytes.get();
        let gathered = self
            .comm
            .gather(Rank(0), serde_json::to_vec(&me)?, GATHER_TIMEOUT)?;
        let Some(all) = gathered else {
            return Ok(None);
        };
        let memory: Vec<MemoryStatus> = all
            .iter()
            .map(|b| serde_json::from_slice(b))
            .collect::<Result<_, _>>()
            .map_err(|e| anyhow!("rank memory report: {e}"))?;
        let mut m = serde_json::Map::new();
        m.insert("mpi_ranks".into(), self.comm.size().into());
        m.insert("memory".into(), serde_json::to_value(memory)?);
        Ok(Some(m))
    }
}

/// Runs `pofvr render` as this process's rank of the MPI job. Does not return on failure:
/// the job is aborted with the cause.
pub(crate) fn run(a: &RenderArgs, ui: &Ui) -> Result<()> {
    let comm = MpiCommunicator::init().map_err(|e| anyhow!("MPI: {e}"))?;
    comm.install_panic_abort();
    let result = (|| {
        if a.frame.ranks != 1 {
            bail!(
                "--ranks {} runs ranks as threads of one process; under mpirun the rank count \
                 is mpirun's -np ({} here)",
                a.frame.ranks,
                comm.size()
            );
        }
        if a.frame.whole {
            bail!("--whole is the single-process reference renderer; run it without mpirun");
        }
        let backend = Mpi {
            comm: &comm,
            sent_before: RefCell::new(Vec::new()),
            copy_bytes: Cell::new(0),
        };
        render::run_with(a, ui, &backend)
    })();
    if let Err(e) = result {
        comm.abort_job(&format!("{e:#}"));
    }
    Ok(())
}
