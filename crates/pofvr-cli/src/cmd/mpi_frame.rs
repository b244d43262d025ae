//! `pofvr render` under `mpirun` (cargo feature `mpi`): one pofvr rank per MPI process,
//! [`pofvr_mpi::MpiCommunicator`] wired to the library's
//! [`pofvr::distribute::setup::DistributedRank`]. Every rank opens the volume memory-mapped
//! and reads only the bricks it owns (measuring their ranges, which the ranks exchange, and
//! ray-casting them; under a `--memory-budget` the volume does not fit, read on demand from
//! the file or a Zarr level's chunks into a brick cache rather than copied), renders its
//! share of each frame, and rank 0 writes the outputs and
//! `--stats`, which gains `mpi_ranks` and `memory` (every rank's resident memory and host).
//!
//! Any error on any rank (a missing file, a bad flag, a failed exchange) and any panic ends
//! the whole job through `MPI_Abort`, after printing `pofvr: rank R aborted: CAUSE`.

use std::time::Duration;

use anyhow::{anyhow, bail, Result};
use pofvr::brick::BrickGrid;
use pofvr::comm::{Communicator, Rank};
use pofvr::distribute::setup::DistributedRank;
use pofvr::distribute::Curve;
use pofvr::frame::RenderJob;
use pofvr::volume::Volume;
use pofvr::{Frame, FrameRequest, Scene};
use pofvr_mpi::MpiCommunicator;

use super::render::{self, Backend, MemoryStatus};
use crate::args::RenderArgs;
use crate::progress::Ui;

/// Bound on the end-of-run memory gather (it only turns a lost rank into an error).
const GATHER_TIMEOUT: Duration = Duration::from_secs(120);

/// This process's rank, through the library's distributed set-up, and the memory budget:
/// under one that the volume does not fit, the rank measures and renders its own bricks
/// read on demand from the file or the Zarr chunks instead of copying them.
struct Mpi<'a>(DistributedRank<'a>, Option<u64>);

impl Backend for Mpi<'_> {
    fn is_root(&self) -> bool {
        self.0.comm().rank() == Rank(0)
    }

    fn frame(&self, scene: &Scene, request: &FrameRequest<'_>) -> Result<Option<Frame>> {
        Ok(self.0.render(scene, request)?)
    }

    fn distributed(&self) -> bool {
        true
    }

    fn grid(&self, volume: &Volume, brick_size: usize, curve: Curve) -> Result<BrickGrid> {
        // Dealt as the rank was told when it was made (`run`: `--deal`).
        Ok(self
            .0
            .measure_grid_within(volume, brick_size, curve, self.1)?)
    }

    fn prepare(&self, job: &mut RenderJob, curve: Curve, replicas: usize) -> Result<()> {
        match self.1 {
            Some(b) => Ok(self.0.read_own_bricks(job, curve, replicas, b)?),
            None => Ok(self.0.keep_own_bricks(job, curve, replicas)?),
        }
    }

    fn finish(&self) -> Result<Option<serde_json::Map<String, serde_json::Value>>> {
        let comm = self.0.comm();
        let mut me = MemoryStatus::now(comm.rank().index());
        me.brick_copy_bytes = self.0.copy_bytes();
        let gathered = comm.gather(Rank(0), serde_json::to_vec(&me)?, GATHER_TIMEOUT)?;
        let Some(all) = gathered else {
            return Ok(None);
        };
        let memory: Vec<MemoryStatus> = all
            .iter()
            .map(|b| serde_json::from_slice(b))
            .collect::<Result<_, _>>()
            .map_err(|e| anyhow!("rank memory report: {e}"))?;
        let mut m = serde_json::Map::new();
        m.insert("mpi_ranks".into(), comm.size().into());
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
        let budget = render::memory_budget(a.memory_budget.as_deref())?;
        let deal = render::deal(&a.frame)?;
        let rank = DistributedRank::new(&comm).with_deal(deal);
        render::run_with(a, ui, &Mpi(rank, budget))
    })();
    if let Err(e) = result {
        comm.abort_job(&format!("{e:#}"));
    }
    Ok(())
}
