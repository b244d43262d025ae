//! # pofvr-mpi: the parallel frame over MPI
//!
//! [`MpiCommunicator`] implements [`pofvr::comm::Communicator`] on top of MPI (through
//! rsmpi 0.8), so that `pofvr::frame::render_frame_on` runs across processes started by
//! `mpirun` exactly as it runs across the threads of a `LocalCommunicator`. This is the only
//! crate of the workspace that links MPI; the `pofvr` binary uses it behind its `mpi` feature.
//!
//! ## Design
//!
//! - **Threading.** MPI is initialised with `MPI_THREAD_MULTIPLE` requested and at least
//!   `MPI_THREAD_SERIALIZED` required. The trait is `Send + Sync` and the frame code may call
//!   it from any thread, so every MPI call except `MPI_Abort` is made while holding one mutex:
//!   calls are serialised, which is all `SERIALIZED` promises. `MPI_Abort` is made without the
//!   lock so that a rank can die even while another of its threads is inside a poll; with
//!   `MULTIPLE` provided (OpenMPI and MPICH both provide it) that is allowed.
//! - **Messages.** Every message travels under one MPI tag with the pofvr tag (a full `u32`,
//!   which MPI tags, bounded by `MPI_TAG_UB`, cannot always hold) in a 4-byte header. A
//!   receive drains everything that has arrived into a local mailbox and takes the oldest match
//!   from it, so the order of each (sender, tag) stream is MPI's non-overtaking order.
//! - **Sends never block on the receiver.** [`Communicator::send`] starts an `MPI_Isend` and
//!   keeps the buffer and the request until `MPI_Test` reports completion, which is checked on
//!   every later call and, at drop, waited for with a deadline while still receiving (so two
//!   ranks finishing with rendezvous sends to each other cannot deadlock).
//! - **Timeouts.** MPI has no timed receive, so [`Communicator::recv`] polls with
//!   `MPI_Improbe` (rsmpi's `immediate_matched_probe`) until its deadline: without sleeping
//!   while traffic flows (rendezvous transfers progress only when both sides call MPI), then
//!   with sleeps growing to 250 µs, then returns [`CommError::Timeout`] naming rank and tag.
//! - **Faults.** [`Communicator::abort`] prints `pofvr: rank R aborted: REASON` to stderr and
//!   calls `MPI_Abort` with [`ABORT_CODE`], which ends every process of the job with a
//!   non-zero exit status; [`install_panic_abort`] makes a panic on any thread do the same.
//! - The collectives are the trait's defaults: they are built on `send`/`recv` and so keep the
//!   timeouts that native blocking collectives would lack.

use std::collections::VecDeque;
use std::fmt;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use mpi::environment::Universe;
use mpi::ffi;
use mpi::point_to_point::MatchedReceiveVec;
use mpi::raw::AsRaw;
use mpi::topology::{Communicator as _, SimpleCommunicator};
use mpi::traits::Source as _;
use mpi::Threading;
use pofvr::comm::{CommError, Communicator, Rank};

/// Exit code passed to `MPI_Abort`; `mpirun` exits non-zero when a rank aborts.
pub const ABORT_CODE: i32 = 3;

/// The one MPI tag all pofvr messages travel under (the pofvr tag is in the payload).
const DATA_TAG: i32 = 7;

/// Bytes of the header in front of every payload: the pofvr tag, little-endian.
const HEADER: usize = 4;

/// How long [`Drop`] waits for outstanding sends to be received before giving up.
const DRAIN_TIMEOUT: Duration = Duration::from_secs(60);

/// Rank recorded for the panic hook (`u32::MAX`: MPI not initialised by this crate).
static HOOK_RANK: AtomicU32 = AtomicU32::new(u32::MAX);

/// Errors starting MPI.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum MpiInitError {
    /// MPI was already initialised in this process (one communicator per process).
    AlreadyInitialized,
    /// The library cannot be called from several threads, even serialised.
    Threading(String),
    /// More ranks than a [`Rank`] can number.
    TooManyRanks(usize),
}

impl fmt::Display for MpiInitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MpiInitError::AlreadyInitialized => {
                write!(f, "MPI is already initialised in this process")
            }
            MpiInitError::Threading(got) => write!(
                f,
                "the MPI library provides thread level {got}; pofvr needs at least \
                 MPI_THREAD_SERIALIZED"
            ),
            MpiInitError::TooManyRanks(n) => write!(f, "{n} MPI ranks is more than pofvr supports"),
        }
    }
}

impl std::error::Error for MpiInitError {}

/// True when this process was started by an MPI launcher (`mpirun`/`mpiexec` of OpenMPI or
/// MPICH/Hydra, or a PMIx launcher such as `srun --mpi=pmix`), judged from the environment
/// before MPI is initialised. A plain `pofvr` run answers false and never touches MPI.
#[must_use]
pub fn launched_by_mpi() -> bool {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"]
        .iter()
        .any(|k| std::env::var_os(k).is_some())
}

struct Envelope {
    from: Rank,
    tag: u32,
    bytes: Vec<u8>,
}

/// Everything that needs MPI; only touched under the mutex.
struct Inner {
    world: SimpleCommunicator,
    /// Requests of `MPI_Isend`s in flight, contiguous for `MPI_Testsome`.
    requests: Vec<ffi::MPI_Request>,
    /// `buffers[i]` is read by MPI until `requests[i]` completes; Rust never touches it
    /// meanwhile.
    buffers: Vec<Vec<u8>>,
    /// Scratch for `MPI_Testsome`'s completed indices.
    done: Vec<i32>,
    mailbox: VecDeque<Envelope>,
}

// SAFETY: `Inner` holds MPI handles (a communicator and requests), which are plain
// identifiers that any thread may pass to MPI once the library was initialised with at least
// MPI_THREAD_SERIALIZED (checked in `MpiCommunicator::init`); every use is under the mutex in
// `MpiCommunicator`, so no two MPI calls that use them overlap.
unsafe impl Send for Inner {}

impl Inner {
    /// Frees the requests of completed sends (and their buffers), with one `MPI_Testsome`
    /// over all of them: testing each with `MPI_Test` would run MPI's progress engine once
    /// per request, and a frame sends thousands of fragments.
    fn reap(&mut self) {
        if self.requests.is_empty() {
            return;
        }
        let n = self.requests.len();
        self.done.resize(n, 0);
        let count = i32::try_from(n).expect("fewer than 2³¹ sends in flight");
        let mut completed: i32 = 0;
        // SAFETY: `requests` holds `count` active requests from MPI_Isend (completed ones are
        // removed below before the next call, so none is MPI_REQUEST_NULL), `done` has room
        // for `count` indices, `completed` is a valid out-pointer and the statuses are
        // ignored; MPI calls are serialised by the lock that guards `self`.
        unsafe {
            ffi::MPI_Testsome(
                count,
                self.requests.as_mut_ptr(),
                &mut completed,
                self.done.as_mut_ptr(),
                ffi::RSMPI_STATUSES_IGNORE,
            );
        }
        let Ok(completed) = usize::try_from(completed) else {
            return; // MPI_UNDEFINED: no active requests.
        };
        if completed == 0 {
            return;
        }
        let mut finished = vec![false; n];
        for &i in &self.done[..completed] {
            if let Some(f) = usize::try_from(i).ok().and_then(|i| finished.get_mut(i)) {
                *f = true;
            }
        }
        let mut k = 0;
        self.requests.retain(|_| {
            k += 1;
            !finished[k - 1]
        });
        let mut k = 0;
        self.buffers.retain(|_| {
            k += 1;
            !finished[k - 1]
        });
    }

    /// Moves every message that has arrived into the mailbox, in arrival order; returns how
    /// many arrived.
    fn pump(&mut self) -> usize {
        let mut arrived = 0;
        while let Some(probed) = self
            .world
            .any_process()
            .immediate_matched_probe_with_tag(DATA_TAG)
        {
            let (data, status) = probed.matched_receive_vec::<u8>();
            let from = Rank(u32::try_from(status.source_rank()).unwrap_or(u32::MAX));
            // Every message of this tag comes from `send`, which always writes the header.
            let (head, body) = data.split_at(HEADER.min(data.len()));
            let mut tag = [0u8; HEADER];
            tag[..head.len()].copy_from_slice(head);
            self.mailbox.push_back(Envelope {
                from,
                tag: u32::from_le_bytes(tag),
                bytes: body.to_vec(),
            });
            arrived += 1;
        }
        arrived
    }

    fn take(&mut self, from: Option<Rank>, tag: u32) -> Option<Envelope> {
        let at = self
            .mailbox
            .iter()
            .position(|e| e.tag == tag && (from.is_none() || from == Some(e.from)))?;
        self.mailbox.remove(at)
    }
}

/// A [`Communicator`] over `MPI_COMM_WORLD`: one pofvr rank per MPI process.
///
/// Create it once per process with [`MpiCommunicator::init`]; dropping it waits (bounded)
/// for outstanding sends and finalises MPI.
pub struct MpiCommunicator {
    rank: Rank,
    size: usize,
    provided: Threading,
    bytes_sent: AtomicU64,
    inner: Mutex<Inner>,
    /// Declared last: dropped (MPI_Finalize) after everything that uses MPI.
    _universe: Universe,
}

impl fmt::Debug for MpiCommunicator {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("MpiCommunicator")
            .field("rank", &self.rank)
            .field("size", &self.size)
            .field("provided", &self.provided)
            .finish_non_exhaustive()
    }
}

impl MpiCommunicator {
    /// Initialises MPI (`MPI_Init_thread`, `MULTIPLE` requested) and wraps `MPI_COMM_WORLD`.
    ///
    /// # Errors
    /// [`MpiInitError`] when MPI was already initialised, offers less than
    /// `MPI_THREAD_SERIALIZED`, or has more ranks than fit a [`Rank`].
    pub fn init() -> Result<Self, MpiInitError> {
        let (universe, provided) = mpi::initialize_with_threading(Threading::Multiple)
            .ok_or(MpiInitError::AlreadyInitialized)?;
        if matches!(provided, Threading::Single | Threading::Funneled) {
            return Err(MpiInitError::Threading(format!("{provided:?}")));
        }
        let world = universe.world();
        let size = usize::try_from(world.size()).unwrap_or(0);
        let rank = u32::try_from(world.rank()).map_err(|_| MpiInitError::TooManyRanks(size))?;
        if u32::try_from(size).is_err() {
            return Err(MpiInitError::TooManyRanks(size));
        }
        Ok(MpiCommunicator {
            rank: Rank(rank),
            size,
            provided,
            bytes_sent: AtomicU64::new(0),
            inner: Mutex::new(Inner {
                world,
                requests: Vec::new(),
                buffers: Vec::new(),
                done: Vec::new(),
                mailbox: VecDeque::new(),
            }),
            _universe: universe,
        })
    }

    /// The thread level the MPI library provided.
    #[must_use]
    pub fn threading(&self) -> Threading {
        self.provided
    }

    /// Sends started and not yet known to be complete.
    #[must_use]
    pub fn pending_sends(&self) -> usize {
        let mut inner = self.lock();
        inner.reap();
        inner.requests.len()
    }

    /// Makes a panic on any thread of this process abort the whole MPI job (after the usual
    /// panic message), naming this rank and the panic, so no peer waits for a dead rank; a
    /// fatal signal (SIGTERM, SIGINT, SIGHUP, SIGSEGV, SIGBUS) prints the same line naming
    /// the signal and exits with [`ABORT_CODE`], which makes `mpirun` end the job.
    pub fn install_panic_abort(&self) {
        HOOK_RANK.store(self.rank.0, Ordering::SeqCst);
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            previous(info);
            let rank = HOOK_RANK.load(Ordering::SeqCst);
            if rank == u32::MAX {
                return;
            }
            let what = info
                .payload()
                .downcast_ref::<&str>()
                .map(|s| (*s).to_owned())
                .or_else(|| info.payload().downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown payload".to_owned());
            let at = info
                .location()
                .map(|l| format!(" at {}:{}", l.file(), l.line()))
                .unwrap_or_default();
            abort_job(Rank(rank), &format!("panic: {what}{at}"));
        }));
        install_signal_abort(self.rank);
    }

    /// Prints `pofvr: rank R aborted: REASON` to stderr and ends every process of the job
    /// through `MPI_Abort` with [`ABORT_CODE`].
    pub fn abort_job(&self, reason: &str) -> ! {
        abort_job(self.rank, reason)
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn check(&self, got: Rank) -> Result<(), CommError> {
        if got.index() < self.size {
            Ok(())
        } else {
            Err(CommError::NoSuchRank {
                rank: self.rank,
                got,
                size: self.size,
            })
        }
    }
}

/// `pofvr: rank R aborted: signal ` for the signal handler, which must not allocate.
static SIGNAL_PREFIX: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();

/// The handler of [`install_signal_abort`]: only async-signal-safe calls (`write`, `_exit`).
extern "C" fn signal_abort(sig: libc::c_int) {
    // mpirun also sends SIGTERM to the peers of a rank that aborted: the suffix tells
    // those lines from the first, which names the cause.
    let (name, why): (&[u8], &[u8]) = match sig {
        libc::SIGTERM => (
            b"SIGTERM",
            b" (sent to it: mpirun ending the job, or a kill)",
        ),
        libc::SIGINT => (b"SIGINT", b" (an interrupt)"),
        libc::SIGHUP => (b"SIGHUP", b" (its terminal closed)"),
        libc::SIGSEGV => (b"SIGSEGV", b" (a memory fault)"),
        libc::SIGBUS => (
            b"SIGBUS",
            b" (a bus error: a memory-mapped file that shrank?)",
        ),
        _ => (b"fatal signal", b""),
    };
    if let Some(prefix) = SIGNAL_PREFIX.get() {
        for part in [prefix.as_slice(), name, why, b"\n"] {
            // SAFETY: write(2) is async-signal-safe; the buffers outlive the call.
            unsafe { libc::write(2, part.as_ptr().cast(), part.len()) };
        }
    }
    // SAFETY: _exit(2) is async-signal-safe and ends the process at once; mpirun sees a rank
    // exit without MPI_Finalize and ends the job.
    unsafe { libc::_exit(ABORT_CODE) }
}

/// Routes the fatal signals a rank can get mid-frame (mpirun forwarding a Ctrl-C, a kill, a
/// fault in a memory-mapped volume whose file shrank) to [`signal_abort`].
fn install_signal_abort(rank: Rank) {
    let _ = SIGNAL_PREFIX.set(format!("pofvr: rank {rank} aborted: signal ").into_bytes());
    for sig in [
        libc::SIGTERM,
        libc::SIGINT,
        libc::SIGHUP,
        libc::SIGSEGV,
        libc::SIGBUS,
    ] {
        // SAFETY: the handler only calls async-signal-safe functions.
        unsafe {
            libc::signal(
                sig,
                signal_abort as extern "C" fn(libc::c_int) as libc::sighandler_t,
            )
        };
    }
}

/// Prints the reason and ends the whole job with `MPI_Abort` (if MPI is live), else exits.
fn abort_job(rank: Rank, reason: &str) -> ! {
    eprintln!("pofvr: rank {rank} aborted: {reason}");
    let (mut initialized, mut finalized) = (0, 0);
    // SAFETY: MPI_Initialized and MPI_Finalized may be called at any time, from any thread,
    // and only write the flags they are given.
    unsafe {
        ffi::MPI_Initialized(&mut initialized);
        ffi::MPI_Finalized(&mut finalized);
    }
    if initialized != 0 && finalized == 0 {
        // SAFETY: MPI is initialised and not finalised; RSMPI_COMM_WORLD is the predefined
        // world communicator. MPI_Abort is called without the communicator's lock (see the
        // crate docs on threading); it does not return in practice.
        unsafe {
            ffi::MPI_Abort(ffi::RSMPI_COMM_WORLD, ABORT_CODE);
        }
    }
    std::process::exit(ABORT_CODE);
}

/// Pause after the `idle`-th poll in a row that saw no traffic: none (yield) for the first
/// [`SPIN_POLLS`], then sleeps doubling from 16 µs to [`MAX_NAP`].
fn poll_nap(idle: u32) -> Option<Duration> {
    let past = idle.checked_sub(SPIN_POLLS)?;
    Some((Duration::from_micros(16) * 2u32.saturating_pow(past.min(8))).min(MAX_NAP))
}

/// Polls without sleeping while a wait is young.
const SPIN_POLLS: u32 = 200;

/// Longest sleep between polls: bounds the latency a rendezvous transfer or a late message
/// pays, while a long wait (for a peer still ray-casting) costs little CPU.
const MAX_NAP: Duration = Duration::from_micros(250);

impl Communicator for MpiCommunicator {
    fn rank(&self) -> Rank {
        self.rank
    }

    fn size(&self) -> usize {
        self.size
    }

    fn send(&self, to: Rank, tag: u32, bytes: Vec<u8>) -> Result<(), CommError> {
        self.check(to)?;
        self.bytes_sent
            .fetch_add(bytes.len() as u64, Ordering::Relaxed);
        let mut inner = self.lock();
        inner.reap();
        if to == self.rank {
            inner.mailbox.push_back(Envelope {
                from: to,
                tag,
                bytes,
            });
            return Ok(());
        }
        let mut buffer = Vec::with_capacity(HEADER + bytes.len());
        buffer.extend_from_slice(&tag.to_le_bytes());
        buffer.extend_from_slice(&bytes);
        drop(bytes);
        let Ok(count) = i32::try_from(buffer.len()) else {
            drop(inner);
            abort_job(
                self.rank,
                &format!(
                    "message of {} bytes to rank {to} exceeds MPI's 2 GiB count limit",
                    buffer.len()
                ),
            );
        };
        let dest = i32::try_from(to.0).expect("checked against the world size");
        // SAFETY: MPI_REQUEST_NULL is a valid initial value for an out-parameter.
        let mut request = unsafe { ffi::RSMPI_REQUEST_NULL };
        // SAFETY: `buffer` holds `count` initialised bytes and is moved, unchanged, into
        // `inner.buffers` below, where it stays (its heap allocation does not move) until
        // MPI_Test reports the request complete or Drop waits for it; the datatype,
        // destination (checked < size), tag and communicator are valid, and MPI calls are
        // serialised by the lock held in `inner`.
        unsafe {
            ffi::MPI_Isend(
                buffer.as_ptr().cast(),
                count,
                ffi::RSMPI_UINT8_T,
                dest,
                DATA_TAG,
                inner.world.as_raw(),
                &mut request,
            );
        }
        inner.requests.push(request);
        inner.buffers.push(buffer);
        Ok(())
    }

    fn recv(
        &self,
        from: Option<Rank>,
        tag: u32,
        timeout: Duration,
    ) -> Result<(Rank, Vec<u8>), CommError> {
        if let Some(f) = from {
            self.check(f)?;
        }
        let start = Instant::now();
        let deadline = start.checked_add(timeout);
        let mut idle_polls = 0u32;
        loop {
            {
                let mut inner = self.lock();
                let pending = inner.requests.len();
                let arrived = inner.pump();
                inner.reap();
                if let Some(e) = inner.take(from, tag) {
                    return Ok((e.from, e.bytes));
                }
                // Traffic is flowing (a rendezvous transfer needs both sides to call MPI):
                // keep polling at full rate.
                if arrived > 0 || inner.requests.len() < pending {
                    idle_polls = 0;
                }
            }
            let left = deadline.map_or(Duration::MAX, |d| {
                d.saturating_duration_since(Instant::now())
            });
            if left.is_zero() {
                return Err(CommError::Timeout {
                    rank: self.rank,
                    from,
                    tag,
                    waited: start.elapsed(),
                });
            }
            idle_polls = idle_polls.saturating_add(1);
            match poll_nap(idle_polls) {
                None => std::thread::yield_now(),
                Some(nap) => std::thread::sleep(nap.min(left)),
            }
        }
    }

    /// Prints `pofvr: rank R aborted: REASON` and ends the whole job through `MPI_Abort`:
    /// stronger than the trait asks (every peer is killed rather than seeing
    /// [`CommError::Aborted`]), and the job's exit status is non-zero. Does not return.
    fn abort(&self, reason: &str) {
        abort_job(self.rank, reason);
    }

    fn bytes_sent(&self) -> u64 {
        self.bytes_sent.load(Ordering::Relaxed)
    }
}

impl Drop for MpiCommunicator {
    fn drop(&mut self) {
        let rank = self.rank;
        let inner = self.inner.get_mut().unwrap_or_else(PoisonError::into_inner);
        let deadline = Instant::now() + DRAIN_TIMEOUT;
        loop {
            inner.reap();
            if inner.requests.is_empty() {
                break;
            }
            if Instant::now() >= deadline {
                let n = inner.requests.len();
                abort_job(
                    rank,
                    &format!("{n} sends not received after {DRAIN_TIMEOUT:?} at shutdown"),
                );
            }
            // Keep receiving: a peer may be blocked sending to us in its own drop.
            inner.pump();
            std::thread::sleep(Duration::from_micros(200));
        }
        HOOK_RANK.store(u32::MAX, Ordering::SeqCst);
        // `_universe` drops after this: MPI_Finalize.
    }
}
