//! [`LocalCommunicator`]: ranks as threads of one process, for tests and laptops.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use super::{check_rank, rank_of, CommError, Communicator, Rank};

/// One rank of a group of threads that exchange messages through shared mailboxes.
///
/// Dropping a rank while its thread panics aborts the group, so a panicking rank does not
/// leave its peers waiting.
///
/// # Examples
/// ```
/// use std::time::Duration;
/// use pofvr::comm::{Communicator, LocalCommunicator, Rank};
///
/// let sums = LocalCommunicator::run(3, |comm| {
///     let all = comm.all_gather(vec![comm.rank().0 as u8], Duration::from_secs(5)).unwrap();
///     all.iter().map(|b| u32::from(b[0])).sum::<u32>()
/// });
/// assert_eq!(sums, vec![3, 3, 3]);
/// ```
#[derive(Debug)]
pub struct LocalCommunicator {
    rank: Rank,
    shared: Arc<Shared>,
    bytes_sent: AtomicU64,
}

#[derive(Debug)]
struct Shared {
    // One lock for every mailbox and the abort flag, so that an abort can never slip in
    // between a receiver's check and its wait.
    state: Mutex<State>,
    arrived: Vec<Condvar>,
}

#[derive(Debug)]
struct State {
    mailboxes: Vec<VecDeque<Envelope>>,
    aborted: Option<(Rank, String)>,
}

#[derive(Debug)]
struct Envelope {
    from: Rank,
    tag: u32,
    bytes: Vec<u8>,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // No code panics while holding the lock, but a poisoned lock must not turn a peer's
        // panic into a second one here.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl LocalCommunicator {
    /// A group of `n` connected ranks, `0..n`, to be moved to `n` threads; empty when `n`
    /// is zero or above `u32::MAX`.
    #[must_use]
    pub fn group(n: usize) -> Vec<LocalCommunicator> {
        if u32::try_from(n).is_err() {
            return Vec::new();
        }
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                mailboxes: (0..n).map(|_| VecDeque::new()).collect(),
                aborted: None,
            }),
            arrived: (0..n).map(|_| Condvar::new()).collect(),
        });
        (0..n)
            .map(|r| LocalCommunicator {
                rank: rank_of(r),
                shared: Arc::clone(&shared),
                bytes_sent: AtomicU64::new(0),
            })
            .collect()
    }

    /// Runs `f` on `n` ranks, one scoped thread each, and returns the results by rank.
    ///
    /// # Panics
    /// Re-raises the panic of the first rank (by rank order) that panicked, after every
    /// rank has finished; the panicking rank aborts the group so the others do finish.
    pub fn run<T, F>(n: usize, f: F) -> Vec<T>
    where
        T: Send,
        F: Fn(&LocalCommunicator) -> T + Sync,
    {
        let f = &f;
        let results: Vec<std::thread::Result<T>> = std::thread::scope(|s| {
            let handles: Vec<_> = Self::group(n)
                .into_iter()
                .map(|comm| s.spawn(move || f(&comm)))
                .collect();
            handles
                .into_iter()
                .map(std::thread::ScopedJoinHandle::join)
                .collect()
        });
        results
            .into_iter()
            .map(|r| r.unwrap_or_else(|p| std::panic::resume_unwind(p)))
            .collect()
    }
}

impl Drop for LocalCommunicator {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.abort(&format!("rank {} panicked", self.rank));
        }
    }
}

impl Communicator for LocalCommunicator {
    fn rank(&self) -> Rank {
        self.rank
    }

    fn size(&self) -> usize {
        self.shared.arrived.len()
    }

    fn send(&self, to: Rank, tag: u32, bytes: Vec<u8>) -> Result<(), CommError> {
        check_rank(self, to)?;
        let mut state = self.shared.lock();
        if let Some((by, reason)) = &state.aborted {
            return Err(CommError::Aborted {
                rank: self.rank,
                by: *by,
                reason: reason.clone(),
            });
        }
        self.bytes_sent
            .fetch_add(bytes.len() as u64, Ordering::Relaxed);
        state.mailboxes[to.index()].push_back(Envelope {
            from: self.rank,
            tag,
            bytes,
        });
        drop(state);
        self.shared.arrived[to.index()].notify_all();
        Ok(())
    }

    fn recv(
        &self,
        from: Option<Rank>,
        tag: u32,
        timeout: Duration,
    ) -> Result<(Rank, Vec<u8>), CommError> {
        if let Some(f) = from {
            check_rank(self, f)?;
        }
        let deadline = Instant::now().checked_add(timeout);
        let me = self.rank.index();
        let mut state = self.shared.lock();
        loop {
            if let Some((by, reason)) = &state.aborted {
                return Err(CommError::Aborted {
                    rank: self.rank,
                    by: *by,
                    reason: reason.clone(),
                });
            }
            let mailbox = &mut state.mailboxes[me];
            // The oldest match first keeps each (sender, tag) stream in order.
            if let Some(at) = mailbox
                .iter()
                .position(|e| e.tag == tag && (from.is_none() || from == Some(e.from)))
            {
                if let Some(e) = mailbox.remove(at) {
                    return Ok((e.from, e.bytes));
                }
            }
            state = match deadline {
                None => self.shared.arrived[me]
                    .wait(state)
                    .unwrap_or_else(PoisonError::into_inner),
                Some(d) => {
                    let left = d.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        return Err(CommError::Timeout {
                            rank: self.rank,
                            from,
                            tag,
                            waited: timeout,
                        });
                    }
                    self.shared.arrived[me]
                        .wait_timeout(state, left)
                        .unwrap_or_else(PoisonError::into_inner)
                        .0
                }
            };
        }
    }

    fn abort(&self, reason: &str) {
        let mut state = self.shared.lock();
        if state.aborted.is_none() {
            state.aborted = Some((self.rank, reason.to_owned()));
        }
        drop(state);
        for c in &self.shared.arrived {
            c.notify_all();
        }
    }

    fn bytes_sent(&self) -> u64 {
        self.bytes_sent.load(Ordering::Relaxed)
    }
}
