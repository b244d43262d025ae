//! The chunk-aligned deal: every brick of one store chunk goes to one rank.
//!
//! Why: a Zarr level larger than the memory budget is decoded chunk by chunk, a whole chunk
//! at a time, and a 64³ chunk holds 64 bricks of 16³. The paper's deal (bricks round-robin
//! along the curve) gives every chunk bricks of every rank, so every rank decodes almost
//! every chunk (measured: `mpirun -np 2` on a 906 MB store, each rank 291 MB read).
//!
//! Why runs and not chunks round-robin: a brick also reads the one-voxel apron around it
//! (and its shared upper face), so a chunk's bricks touch all 26 neighbouring chunks. Chunks
//! dealt one by one would give each rank the neighbours of its chunks, that is every chunk
//! again. So the chunks, in the order of the curve over the chunk grid, are cut into one
//! contiguous run per rank, the runs balanced by a weight per brick (the non-empty bricks,
//! which are the ones a frame can render): each rank decodes its run and a skin of chunks
//! around it.

use std::fmt;
use std::str::FromStr;

use super::{BrickAssignment, Curve, DistributeError, Rank, SfcOrder};
use crate::brick::BrickId;
use crate::volume::Volume;

/// How bricks are dealt to ranks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Deal {
    /// [`Deal::Chunks`] when the volume is read chunk by chunk from a store whose chunks
    /// are larger than a brick ([`chunk_shape_for`]), [`Deal::Curve`] otherwise.
    #[default]
    Auto,
    /// The paper's: bricks round-robin along the curve.
    Curve,
    /// One contiguous run of store chunks per rank ([`BrickAssignment::by_chunks`]).
    Chunks,
}

impl Deal {
    /// The name `--deal` takes and `--stats` reports.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Deal::Auto => "auto",
            Deal::Curve => "curve",
            Deal::Chunks => "chunks",
        }
    }
}

impl FromStr for Deal {
    type Err = DistributeError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "auto" => Ok(Deal::Auto),
            "curve" => Ok(Deal::Curve),
            "chunks" => Ok(Deal::Chunks),
            _ => Err(DistributeError::UnknownDeal(s.to_owned())),
        }
    }
}

impl fmt::Display for Deal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The chunk shape bricks of `brick_size` are dealt by under `deal`: `Some` for
/// [`Deal::Chunks`], and for [`Deal::Auto`] when `volume` is read chunk by chunk (a Zarr
/// level not resident, [`Volume::zarr_level`]) and a chunk holds more voxels than a brick.
///
/// # Errors
/// [`DistributeError::NoChunks`] for [`Deal::Chunks`] on a volume not read by chunks.
pub fn chunk_shape_for(
    volume: &Volume,
    brick_size: usize,
    deal: Deal,
) -> Result<Option<[usize; 3]>, DistributeError> {
    let chunk = volume.zarr_level().map(|z| z.chunk_shape());
    match (deal, chunk) {
        (Deal::Curve, _) => Ok(None),
        (Deal::Chunks, None) => Err(DistributeError::NoChunks(volume.source().to_owned())),
        (Deal::Chunks, Some(c)) => Ok(Some(c)),
        (Deal::Auto, c) => Ok(c.filter(|c| c.iter().product::<usize>() > brick_size.pow(3))),
    }
}

impl BrickAssignment {
    /// Deals the bricks of a grid with `counts` bricks of `brick_size` voxels by the store
    /// chunks of `chunk` voxels they start in: the chunks, ordered along `curve` over the
    /// chunk grid, are cut into `ranks` contiguous runs of about equal total `weight` (of
    /// their bricks), and every brick goes to its chunk's run. A run may be empty (more
    /// ranks than weighted chunks). [`BrickAssignment::of`] lists a rank's bricks in the
    /// order of `curve` over the bricks.
    ///
    /// # Errors
    /// [`DistributeError::BadCounts`] as for [`SfcOrder::new`] (bricks or chunks),
    /// [`DistributeError::BadRanks`] when `ranks` is zero or above `u32::MAX`.
    pub fn by_chunks(
        counts: [usize; 3],
        brick_size: usize,
        chunk: [usize; 3],
        curve: Curve,
        ranks: usize,
        weight: &dyn Fn(BrickId) -> u64,
    ) -> Result<Self, DistributeError> {
        if ranks == 0 || u32::try_from(ranks).is_err() {
            return Err(DistributeError::BadRanks(ranks));
        }
        // Checked first: the counts must be usable before anything is sized by them.
        let bricks = SfcOrder::new(counts, curve)?;
        let chunk = chunk.map(|c| c.max(1));
        // The chunk a brick starts in, by brick coordinates.
        let chunk_of = |c: [usize; 3]| -> [usize; 3] {
            std::array::from_fn(|a| c[a].saturating_mul(brick_size) / chunk[a])
        };
        let last = chunk_of(counts.map(|c| c - 1));
        let chunk_counts = last.map(|c| c.saturating_add(1));
        let chunk_id = |k: [usize; 3]| k[0] + chunk_counts[0] * (k[1] + chunk_counts[1] * k[2]);
        let brick_coords = |i: usize| {
            [
                i % counts[0],
                (i / counts[0]) % counts[1],
                i / (counts[0] * counts[1]),
            ]
        };
        let chunks = SfcOrder::new(chunk_counts, curve)?;
        let brick_chunk: Vec<usize> = (0..bricks.len())
            .map(|i| chunk_id(chunk_of(brick_coords(i))))
            .collect();
        let mut chunk_weight = vec![0u64; chunks.len()];
        for (i, &k) in brick_chunk.iter().enumerate() {
            chunk_weight[k] = chunk_weight[k].saturating_add(weight(BrickId(i as u32)));
        }
        let total: u128 = chunk_weight.iter().map(|&w| u128::from(w)).sum();
        // Each chunk joins the run its weight's midpoint falls in: runs of about total/ranks
        // each, contiguous along the curve. Without any weight, runs of equal chunk counts.
        let n = ranks as u128;
        let mut run_of = vec![0usize; chunks.len()];
        let mut before = 0u128;
        for (pos, k) in chunks.bricks().iter().enumerate() {
            let w = u128::from(chunk_weight[k.index()]);
            let r = if total == 0 {
                pos as u128 * n / chunks.len() as u128
            } else {
                (2 * before + w) * n / (2 * total)
            };
            run_of[k.index()] = (r as usize).min(ranks - 1);
            before += w;
        }
        let owners: Vec<Rank> = brick_chunk
            .iter()
            .map(|&k| Rank(run_of[k] as u32))
            .collect();
        Ok(Self::from_owners(&bricks, owners, ranks, Deal::Chunks))
    }
}
