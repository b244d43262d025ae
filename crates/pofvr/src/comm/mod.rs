//! Message passing between ranks, behind a small [`Communicator`] trait.
//!
//! The parallel renderer talks only to this trait, so the same code runs on ranks that are
//! threads of one process ([`LocalCommunicator`]) or MPI processes (a separate crate). The
//! collectives have default implementations on top of [`Communicator::send`] and
//! [`Communicator::recv`] using the tags in [`RESERVED_TAGS`]; an implementation with native
//! collectives may override them.
//!
//! Every wait takes a timeout and every error names the rank that saw it, so a lost
//! message or a dead peer becomes an error instead of a hang. A rank that fails calls
//! [`Communicator::abort`], which makes every pending and later operation on every rank fail
//! with [`CommError::Aborted`].

mod local;
#[cfg(test)]
mod test;

use std::fmt;
use std::time::{Duration, Instant};

pub use local::LocalCommunicator;

/// The index of a process (or thread) taking part in a parallel frame.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
pub struct Rank(pub u32);

impl Rank {
    /// As a `usize` index.
    #[inline]
    #[must_use]
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

impl fmt::Display for Rank {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// Tags at or above this value belong to the collectives; user messages use lower tags.
pub const RESERVED_TAGS: std::ops::RangeFrom<u32> = 0xFFFF_0000..;
const TAG_GATHER: u32 = 0xFFFF_0001;
const TAG_ALL_GATHER: u32 = 0xFFFF_0002;
const TAG_BARRIER: u32 = 0xFFFF_0003;

/// Errors of a communicator; each names the rank it happened on.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CommError {
    /// No matching message arrived in time.
    #[error("rank {rank}: timed out after {waited:?} waiting for a message with tag {tag:#x} from {}", from_text(*.from))]
    Timeout {
        /// The rank that waited.
        rank: Rank,
        /// The sender waited for (`None`: any).
        from: Option<Rank>,
        /// The tag waited for.
        tag: u32,
        /// How long it waited.
        waited: Duration,
    },
    /// A rank outside the communicator was named.
    #[error("rank {rank}: got rank {got} as a peer, expected a rank below {size}")]
    NoSuchRank {
        /// The rank that made the call.
        rank: Rank,
        /// The rank it named.
        got: Rank,
        /// The communicator size.
        size: usize,
    },
    /// Some rank called [`Communicator::abort`].
    #[error("rank {rank}: communicator aborted by rank {by}: {reason}")]
    Aborted {
        /// The rank that saw the abort.
        rank: Rank,
        /// The rank that aborted.
        by: Rank,
        /// Why it aborted.
        reason: String,
    },
}

fn from_text(from: Option<Rank>) -> String {
    from.map_or_else(|| "any rank".to_owned(), |r| format!("rank {r}"))
}

/// Point-to-point messages and a few collectives among `size()` ranks.
///
/// Messages from one sender with one tag arrive in the order sent; [`Communicator::send`]
/// never waits for the receiver, so sending to oneself is allowed.
pub trait Communicator: Send + Sync {
    /// This rank.
    fn rank(&self) -> Rank;

    /// Number of ranks.
    fn size(&self) -> usize;

    /// Queues `bytes` for rank `to` under `tag`, without waiting for it to be received.
    ///
    /// # Errors
    /// [`CommError::NoSuchRank`] for a bad `to`, [`CommError::Aborted`] after an abort.
    fn send(&self, to: Rank, tag: u32, bytes: Vec<u8>) -> Result<(), CommError>;

    /// Takes the oldest message with `tag` from `from` (or from any rank when `None`),
    /// waiting at most `timeout`. Returns the sender and the bytes.
    ///
    /// # Errors
    /// [`CommError::Timeout`] when nothing matching arrives in time,
    /// [`CommError::NoSuchRank`] for a bad `from`, [`CommError::Aborted`] after an abort.
    fn recv(
        &self,
        from: Option<Rank>,
        tag: u32,
        timeout: Duration,
    ) -> Result<(Rank, Vec<u8>), CommError>;

    /// Makes every pending and later operation on every rank fail with
    /// [`CommError::Aborted`] carrying `reason`; the first abort's reason is kept.
    fn abort(&self, reason: &str);

    /// Bytes this rank has passed to `send` so far, collectives included.
    fn bytes_sent(&self) -> u64;

    /// Collects every rank's `bytes` on `root`: `Some(v)` there, with `v[r]` from rank `r`,
    /// and `None` on the other ranks.
    ///
    /// # Errors
    /// As [`Communicator::send`] and [`Communicator::recv`]; `timeout` bounds the whole call.
    fn gather(
        &self,
        root: Rank,
        bytes: Vec<u8>,
        timeout: Duration,
    ) -> Result<Option<Vec<Vec<u8>>>, CommError> {
        check_rank(self, root)?;
        if self.rank() != root {
            self.send(root, TAG_GATHER, bytes)?;
            return Ok(None);
        }
        let deadline = Deadline::new(timeout);
        let mut mine = Some(bytes);
        let mut all = Vec::with_capacity(self.size());
        for r in 0..self.size() {
            all.push(match mine.take_if(|_| r == root.index()) {
                Some(bytes) => bytes,
                None => self.recv(Some(rank_of(r)), TAG_GATHER, deadline.left())?.1,
            });
        }
        Ok(Some(all))
    }

    /// Gives every rank every rank's `bytes`, indexed by rank.
    ///
    /// # Errors
    /// As [`Communicator::send`] and [`Communicator::recv`]; `timeout` bounds the whole call.
    fn all_gather(&self, bytes: Vec<u8>, timeout: Duration) -> Result<Vec<Vec<u8>>, CommError> {
        let me = self.rank();
        for r in (0..self.size()).filter(|&r| r != me.index()) {
            self.send(rank_of(r), TAG_ALL_GATHER, bytes.clone())?;
        }
        let deadline = Deadline::new(timeout);
        let mut mine = Some(bytes);
        let mut all = Vec::with_capacity(self.size());
        for r in 0..self.size() {
            all.push(match mine.take_if(|_| r == me.index()) {
                Some(bytes) => bytes,
                None => {
                    self.recv(Some(rank_of(r)), TAG_ALL_GATHER, deadline.left())?
                        .1
                }
            });
        }
        Ok(all)
    }

    /// Returns once every rank has entered the barrier.
    ///
    /// # Errors
    /// As [`Communicator::send`] and [`Communicator::recv`]; `timeout` bounds the whole call.
    fn barrier(&self, timeout: Duration) -> Result<(), CommError> {
        let me = self.rank();
        for r in (0..self.size()).filter(|&r| r != me.index()) {
            self.send(rank_of(r), TAG_BARRIER, Vec::new())?;
        }
        let deadline = Deadline::new(timeout);
        for r in (0..self.size()).filter(|&r| r != me.index()) {
            self.recv(Some(rank_of(r)), TAG_BARRIER, deadline.left())?;
        }
        Ok(())
    }
}

fn rank_of(r: usize) -> Rank {
    // Sizes are bounded by `u32` when a communicator is built.
    Rank(r as u32)
}

fn check_rank<C: Communicator + ?Sized>(comm: &C, got: Rank) -> Result<(), CommError> {
    if got.index() < comm.size() {
        Ok(())
    } else {
        Err(CommError::NoSuchRank {
            rank: comm.rank(),
            got,
            size: comm.size(),
        })
    }
}

/// A point in time that several waits share, so a multi-step call keeps to one timeout.
#[derive(Clone, Copy, Debug)]
pub struct Deadline(Option<Instant>);

impl Deadline {
    /// `timeout` from now; a timeout too large to represent never expires.
    #[must_use]
    pub fn new(timeout: Duration) -> Self {
        Deadline(Instant::now().checked_add(timeout))
    }

    /// The time left, zero once passed.
    #[must_use]
    pub fn left(&self) -> Duration {
        self.0.map_or(Duration::MAX, |d| {
            d.saturating_duration_since(Instant::now())
        })
    }
}
