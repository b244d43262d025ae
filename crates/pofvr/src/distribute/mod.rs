//! Static data distribution along a space-filling curve (paper §4.1).
//!
//! Bricks are listed in the order of a Hilbert or Z curve and dealt to ranks round-robin
//! along that order. The curves are defined on the power-of-two cube enclosing the brick
//! grid; cells outside the grid are skipped, so any `[nx, ny, nz]` works. Because a curve
//! finishes a neighbourhood before leaving it, consecutive bricks are close together and the
//! visible bricks of any view end up spread evenly over the ranks. A volume read chunk by
//! chunk from a store is dealt by chunks instead ([`chunks`]), so that each rank decodes
//! only its own part of the store.

pub mod chunks;
pub mod hilbert;
pub mod morton;
pub mod setup;
#[cfg(test)]
mod test;
#[cfg(test)]
mod test_chunks;

use std::fmt;
use std::str::FromStr;

use crate::brick::BrickId;
pub use crate::comm::Rank;
pub use chunks::Deal;

/// A space-filling curve.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Curve {
    /// The 3D Hilbert curve: consecutive cells are face neighbours.
    Hilbert,
    /// The Z (Morton) curve: bit interleaving, cheaper but with jumps.
    Z,
}

impl FromStr for Curve {
    type Err = DistributeError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "hilbert" => Ok(Curve::Hilbert),
            "z" => Ok(Curve::Z),
            _ => Err(DistributeError::UnknownCurve(s.to_owned())),
        }
    }
}

impl fmt::Display for Curve {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Curve::Hilbert => "hilbert",
            Curve::Z => "z",
        })
    }
}

/// Errors setting up a distribution.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DistributeError {
    /// The curve name is not known.
    #[error("unknown curve {0:?}, expected \"hilbert\" or \"z\"")]
    UnknownCurve(String),
    /// A brick count is zero, or the grid is too large for the curves or for [`BrickId`].
    #[error(
        "brick counts {counts:?} are unusable: expected each in 1..={max_side} and at most \
         {max_bricks} bricks in all"
    )]
    BadCounts {
        /// The counts given.
        counts: [usize; 3],
        /// The largest count per axis.
        max_side: usize,
        /// The largest number of bricks.
        max_bricks: u64,
    },
    /// The deal name is not known.
    #[error("unknown deal {0:?}, expected \"auto\", \"curve\" or \"chunks\"")]
    UnknownDeal(String),
    /// A deal by chunks asked of a volume that is not read chunk by chunk.
    #[error(
        "{0}: a deal by chunks needs a Zarr level read chunk by chunk (one larger than \
         the memory budget); this volume is not"
    )]
    NoChunks(String),
    /// The number of ranks is zero or does not fit a [`Rank`].
    #[error("got {0} ranks, expected 1..={max}", max = u32::MAX)]
    BadRanks(usize),
    /// More owners per brick than ranks, or none.
    #[error("owners per brick: got {replicas}, expected 1..={ranks} (the number of ranks)")]
    BadReplicas {
        /// Owners per brick asked for.
        replicas: usize,
        /// Ranks.
        ranks: usize,
    },
}

/// All bricks of a grid in the order of a space-filling curve.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SfcOrder {
    counts: [usize; 3],
    curve: Curve,
    bricks: Vec<BrickId>,
}

impl SfcOrder {
    /// Orders the bricks of a grid with `counts` bricks along x, y, z (ids x fastest, as
    /// [`crate::brick::BrickGrid::id`]).
    ///
    /// # Errors
    /// [`DistributeError::BadCounts`] when a count is zero, above `2^21`, or the grid has
    /// more bricks than [`BrickId`] can number.
    pub fn new(counts: [usize; 3], curve: Curve) -> Result<Self, DistributeError> {
        const MAX_SIDE: usize = 1 << morton::MAX_BITS;
        let max_bricks = u64::from(u32::MAX) + 1;
        let bad = || DistributeError::BadCounts {
            counts,
            max_side: MAX_SIDE,
            max_bricks,
        };
        if counts.iter().any(|&c| c == 0 || c > MAX_SIDE) {
            return Err(bad());
        }
        let total = counts
            .iter()
            .try_fold(1u64, |a, &c| a.checked_mul(c as u64))
            .ok_or_else(bad)?;
        if total > max_bricks {
            return Err(bad());
        }
        let side = counts.iter().copied().max().unwrap_or(1);
        let bits = side.next_power_of_two().trailing_zeros();
        // Sorting the in-range cells by their key on the enclosing cube equals walking the
        // whole cube and skipping the outside cells, without visiting up to 8× (or, for flat
        // grids, far more) empty cells.
        let mut keyed: Vec<(u64, BrickId)> = Vec::with_capacity(total as usize);
        let mut id = 0u32;
        for z in 0..counts[2] {
            for y in 0..counts[1] {
                for x in 0..counts[0] {
                    let c = [x as u32, y as u32, z as u32];
                    let key = match curve {
                        Curve::Hilbert => hilbert::index(c, bits),
                        Curve::Z => morton::encode(c),
                    }
                    .ok_or_else(bad)?;
                    keyed.push((key, BrickId(id)));
                    id = id.wrapping_add(1);
                }
            }
        }
        keyed.sort_unstable();
        Ok(SfcOrder {
            counts,
            curve,
            bricks: keyed.into_iter().map(|(_, b)| b).collect(),
        })
    }

    /// Every brick id once, in curve order.
    #[must_use]
    pub fn bricks(&self) -> &[BrickId] {
        &self.bricks
    }

    /// The brick counts along x, y, z.
    #[must_use]
    pub fn counts(&self) -> [usize; 3] {
        self.counts
    }

    /// The curve.
    #[must_use]
    pub fn curve(&self) -> Curve {
        self.curve
    }

    /// Number of bricks.
    #[must_use]
    pub fn len(&self) -> usize {
        self.bricks.len()
    }

    /// Always false: a grid has at least one brick.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.bricks.is_empty()
    }
}

/// Which rank owns which brick: bricks dealt round-robin along a curve (the paper's deal),
/// or by store chunks ([`BrickAssignment::by_chunks`], [`Deal`]).
///
/// With `r` replicas (beyond the paper) every brick has `r` owners: its dealt rank and the
/// ranks `k·ranks/r` further on. Which bricks are visible depends on the view, so with one
/// owner and a few dozen visible bricks per rank, the busiest rank's share is left to
/// chance; with two, each frame gives each visible brick to the less loaded of its owners
/// ([`BrickAssignment::renderers`]), at the cost of holding twice the bricks.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BrickAssignment {
    owners: Vec<Rank>,
    by_rank: Vec<Vec<BrickId>>,
    replicas: usize,
    deal: Deal,
}

impl BrickAssignment {
    /// Deals the bricks of a grid with `counts` bricks to `ranks` ranks along `curve`.
    ///
    /// # Errors
    /// [`DistributeError::BadCounts`] as for [`SfcOrder::new`], and
    /// [`DistributeError::BadRanks`] when `ranks` is zero or above `u32::MAX`.
    pub fn new(counts: [usize; 3], curve: Curve, ranks: usize) -> Result<Self, DistributeError> {
        Self::from_order(&SfcOrder::new(counts, curve)?, ranks)
    }

    /// Deals the bricks of `order` to `ranks` ranks: the `i`-th brick goes to rank
    /// `i mod ranks`.
    ///
    /// # Errors
    /// [`DistributeError::BadRanks`] when `ranks` is zero or above `u32::MAX`.
    pub fn from_order(order: &SfcOrder, ranks: usize) -> Result<Self, DistributeError> {
        Self::from_order_classes(order, ranks, &|_| 0)
    }

    /// Deals each class of bricks (`class(b)`, small integers) round-robin along the curve
    /// apart from the others, each deal starting again at rank 0: every rank holds as many
    /// bricks of each class as any other, give or take one.
    ///
    /// # Errors
    /// [`DistributeError::BadRanks`] when `ranks` is zero or above `u32::MAX`.
    pub fn from_order_classes(
        order: &SfcOrder,
        ranks: usize,
        class: &dyn Fn(BrickId) -> usize,
    ) -> Result<Self, DistributeError> {
        if ranks == 0 || u32::try_from(ranks).is_err() {
            return Err(DistributeError::BadRanks(ranks));
        }
        let mut owners = vec![Rank(0); order.len()];
        let mut by_rank = vec![Vec::with_capacity(order.len() / ranks + 1); ranks];
        let mut next: Vec<usize> = Vec::new();
        for &b in order.bricks() {
            let c = class(b);
            if c >= next.len() {
                next.resize(c + 1, 0);
            }
            let r = next[c] % ranks;
            next[c] += 1;
            let rank = Rank(r as u32);
            owners[b.index()] = rank;
            by_rank[r].push(b);
        }
        Ok(BrickAssignment {
            owners,
            by_rank,
            replicas: 1,
            deal: Deal::Curve,
        })
    }

    /// The assignment giving brick `i` to `owners[i]` (one per brick of `order`, each below
    /// `ranks`), each rank's bricks listed in `order`, recorded as dealt by `deal`.
    pub(crate) fn from_owners(
        order: &SfcOrder,
        owners: Vec<Rank>,
        ranks: usize,
        deal: Deal,
    ) -> Self {
        debug_assert_eq!(owners.len(), order.len());
        let mut by_rank = vec![Vec::new(); ranks];
        for &b in order.bricks() {
            by_rank[owners[b.index()].index()].push(b);
        }
        BrickAssignment {
            owners,
            by_rank,
            replicas: 1,
            deal,
        }
    }

    /// How the bricks were dealt: [`Deal::Curve`] or [`Deal::Chunks`].
    #[must_use]
    pub fn deal(&self) -> Deal {
        self.deal
    }

    /// The same deal with `replicas` owners per brick (1 is the paper's).
    ///
    /// # Errors
    /// [`DistributeError::BadReplicas`] unless `replicas` is in `1..=ranks`.
    pub fn with_replicas(mut self, replicas: usize) -> Result<Self, DistributeError> {
        if !(1..=self.ranks()).contains(&replicas) {
            return Err(DistributeError::BadReplicas {
                replicas,
                ranks: self.ranks(),
            });
        }
        self.replicas = replicas;
        Ok(self)
    }

    /// Owners per brick.
    #[must_use]
    pub fn replicas(&self) -> usize {
        self.replicas
    }

    /// Every owner of brick `id`, its dealt rank first; empty when `id` is not a brick.
    pub fn owners_of(&self, id: BrickId) -> impl Iterator<Item = Rank> + '_ {
        let n = self.ranks();
        let first = self.owners.get(id.index()).map(|r| r.index());
        (0..self.replicas)
            .filter_map(move |k| first.map(|f| Rank(((f + k * n / self.replicas) % n) as u32)))
    }

    /// Every brick `rank` holds (as any of the owners), in id order.
    #[must_use]
    pub fn held_by(&self, rank: Rank) -> Vec<BrickId> {
        (0..self.owners.len())
            .map(|i| BrickId(i as u32))
            .filter(|id| self.owners_of(*id).any(|r| r == rank))
            .collect()
    }

    /// The rank that renders each of `visible` this frame: its only owner, or with
    /// replicas the least loaded of its owners, by `cost` (an estimate every rank computes
    /// alike, such as the footprint area), the costliest bricks placed first. The same on
    /// every rank: it depends only on its arguments.
    #[must_use]
    pub fn renderers(&self, visible: &[BrickId], cost: &dyn Fn(BrickId) -> u64) -> Vec<Rank> {
        if self.replicas == 1 {
            return visible
                .iter()
                .map(|id| self.owner(*id).unwrap_or(Rank(0)))
                .collect();
        }
        let mut by_cost: Vec<(u64, usize)> = visible
            .iter()
            .enumerate()
            .map(|(i, id)| (cost(*id), i))
            .collect();
        by_cost.sort_unstable_by(|a, b| b.0.cmp(&a.0).then(visible[a.1].cmp(&visible[b.1])));
        let mut load = vec![0u64; self.ranks()];
        let mut out = vec![Rank(0); visible.len()];
        for (c, i) in by_cost {
            let Some(r) = self
                .owners_of(visible[i])
                .min_by_key(|r| (load[r.index()], r.index()))
            else {
                continue;
            };
            load[r.index()] += c;
            out[i] = r;
        }
        out
    }

    /// The rank owning brick `id`; `None` when `id` is not a brick of the grid.
    #[must_use]
    pub fn owner(&self, id: BrickId) -> Option<Rank> {
        self.owners.get(id.index()).copied()
    }

    /// The bricks of `rank`, in curve order; empty for a rank outside `0..ranks()`.
    #[must_use]
    pub fn of(&self, rank: Rank) -> &[BrickId] {
        self.by_rank.get(rank.index()).map_or(&[], Vec::as_slice)
    }

    /// Number of ranks.
    #[must_use]
    pub fn ranks(&self) -> usize {
        self.by_rank.len()
    }

    /// Number of bricks.
    #[must_use]
    pub fn len(&self) -> usize {
        self.owners.len()
    }

    /// Always false: a grid has at least one brick.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.owners.is_empty()
    }
}
