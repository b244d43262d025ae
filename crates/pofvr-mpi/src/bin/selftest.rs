//! `pofvr-mpi-selftest SCENARIO`: checks of [`MpiCommunicator`] meant to run under
//! `mpirun -np N`. Each rank prints `ok RANK SCENARIO` when its checks pass and exits 1 with
//! the failed check otherwise; the `abort` and `panic` scenarios end the job on purpose.
//! The integration tests in `tests/` run it.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use pofvr::comm::{CommError, Communicator, Rank};
use pofvr_mpi::MpiCommunicator;

const T: Duration = Duration::from_secs(30);

fn main() -> ExitCode {
    let scenario = std::env::args().nth(1).unwrap_or_default();
    let comm = match MpiCommunicator::init() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("selftest: {e}");
            return ExitCode::FAILURE;
        }
    };
    comm.install_panic_abort();
    let result = match scenario.as_str() {
        "pingpong" => pingpong(&comm),
        "gather" => gather(&comm),
        "timeout" => timeout(&comm),
        "exchange" => exchange(&comm),
        "abort" => abort(&comm),
        "panic" => panic(&comm),
        "flood" => flood(&comm),
        other => Err(format!(
            "unknown scenario {other:?} (pingpong, gather, timeout, exchange, flood, abort, panic)"
        )),
    };
    match result {
        Ok(()) => {
            println!("ok {} {scenario}", comm.rank());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("selftest rank {}: {scenario}: FAILED: {e}", comm.rank());
            ExitCode::FAILURE
        }
    }
}

fn rank(r: usize) -> Rank {
    Rank(u32::try_from(r).expect("small world"))
}

fn payload(from: usize, to: usize, i: usize, len: usize) -> Vec<u8> {
    (0..len)
        .map(|k| u8::try_from((from * 31 + to * 17 + i * 7 + k) % 251).expect("< 256"))
        .collect()
}

fn expect_eq<T: PartialEq + std::fmt::Debug>(what: &str, got: T, want: T) -> Result<(), String> {
    if got == want {
        Ok(())
    } else {
        Err(format!("{what}: got {got:?}, want {want:?}"))
    }
}

/// Rank 0 sends messages of several sizes (empty to 4 MiB, past the eager limit) and tags
/// (a reserved one included) to every rank, which echoes them back; 50 messages under one
/// tag arrive in order; a message to oneself; any-source receive; byte counts.
fn pingpong(comm: &MpiCommunicator) -> Result<(), String> {
    let (me, n) = (comm.rank().index(), comm.size());
    let sizes = [0usize, 1, 1000, 65_536, 4 << 20];
    let tags = [0u32, 1, 0x4453_0001, 0xFFFF_0007];
    let mut expected_bytes = 0u64;
    if me == 0 {
        for to in 1..n {
            for (i, (&len, &tag)) in sizes.iter().zip(tags.iter().cycle()).enumerate() {
                comm.send(rank(to), tag, payload(0, to, i, len))
                    .map_err(|e| e.to_string())?;
                expected_bytes += len as u64;
            }
        }
        for to in 1..n {
            for (i, (&len, &tag)) in sizes.iter().zip(tags.iter().cycle()).enumerate() {
                let (from, back) = comm
                    .recv(Some(rank(to)), tag, T)
                    .map_err(|e| e.to_string())?;
                expect_eq("echo sender", from, rank(to))?;
                expect_eq(
                    &format!("echo {i} from {to}"),
                    back == payload(to, 0, i, len),
                    true,
                )?;
            }
        }
    } else {
        for (i, (&len, &tag)) in sizes.iter().zip(tags.iter().cycle()).enumerate() {
            let (from, got) = comm
                .recv(Some(Rank(0)), tag, T)
                .map_err(|e| e.to_string())?;
            expect_eq("sender", from, Rank(0))?;
            expect_eq(&format!("message {i}"), got == payload(0, me, i, len), true)?;
            comm.send(Rank(0), tag, payload(me, 0, i, len))
                .map_err(|e| e.to_string())?;
            expected_bytes += len as u64;
        }
    }
    // Order within one (sender, tag) stream, to the next rank round the ring.
    let next = rank((me + 1) % n);
    for i in 0..50u32 {
        comm.send(next, 42, i.to_le_bytes().to_vec())
            .map_err(|e| e.to_string())?;
        expected_bytes += 4;
    }
    let prev = rank((me + n - 1) % n);
    for i in 0..50u32 {
        let (_, b) = comm.recv(Some(prev), 42, T).map_err(|e| e.to_string())?;
        expect_eq("ordered stream", b, i.to_le_bytes().to_vec())?;
    }
    // To oneself, and from any rank.
    comm.send(comm.rank(), 9, vec![1, 2, 3])
        .map_err(|e| e.to_string())?;
    expected_bytes += 3;
    let (from, b) = comm.recv(None, 9, T).map_err(|e| e.to_string())?;
    expect_eq("self message", (from, b), (comm.rank(), vec![1, 2, 3]))?;
    expect_eq("bytes_sent", comm.bytes_sent(), expected_bytes)?;
    // Bad ranks are errors, not hangs.
    let bad = rank(n);
    match comm.send(bad, 0, Vec::new()) {
        Err(CommError::NoSuchRank { got, .. }) if got == bad => {}
        other => return Err(format!("send to rank {n}: {other:?}")),
    }
    comm.barrier(T).map_err(|e| e.to_string())
}

/// Gather to rank 0 and to the last rank, all-gather, barrier, with per-rank payloads.
fn gather(comm: &MpiCommunicator) -> Result<(), String> {
    let (me, n) = (comm.rank().index(), comm.size());
    for root in [0, n - 1] {
        let got = comm
            .gather(rank(root), payload(me, root, 3, 100 + me), T)
            .map_err(|e| e.to_string())?;
        if me == root {
            let all = got.ok_or("root got no gather")?;
            expect_eq("gather count", all.len(), n)?;
            for (r, b) in all.iter().enumerate() {
                expect_eq(
                    &format!("gather from {r}"),
                    b,
                    &payload(r, root, 3, 100 + r),
                )?;
            }
        } else if got.is_some() {
            return Err("a non-root got the gather".into());
        }
    }
    let all = comm
        .all_gather(vec![u8::try_from(me).expect("small"); me + 1], T)
        .map_err(|e| e.to_string())?;
    for (r, b) in all.iter().enumerate() {
        expect_eq(
            &format!("all_gather from {r}"),
            b,
            &vec![u8::try_from(r).expect("small"); r + 1],
        )?;
    }
    for _ in 0..3 {
        comm.barrier(T).map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// A receive nobody answers times out on time, naming rank, peer and tag; the
/// communicator still works afterwards.
fn timeout(comm: &MpiCommunicator) -> Result<(), String> {
    let me = comm.rank();
    let from = Rank(u32::try_from(comm.size() - 1).expect("small"));
    let t0 = Instant::now();
    let wait = Duration::from_millis(300);
    match comm.recv(Some(from), 0xBEEF, wait) {
        Err(e @ CommError::Timeout { .. }) => {
            let text = e.to_string();
            let CommError::Timeout {
                rank,
                from: f,
                tag,
                waited,
            } = e
            else {
                unreachable!()
            };
            expect_eq("timeout rank", rank, me)?;
            expect_eq("timeout peer", f, Some(from))?;
            expect_eq("timeout tag", tag, 0xBEEF)?;
            if waited < wait || t0.elapsed() > Duration::from_secs(5) {
                return Err(format!(
                    "waited {waited:?} ({:?} wall) for a {wait:?} timeout",
                    t0.elapsed()
                ));
            }
            if !text.contains(&format!("rank {me}")) || !text.contains("0xbeef") {
                return Err(format!("timeout message lacks rank or tag: {text}"));
            }
        }
        other => return Err(format!("expected a timeout, got {other:?}")),
    }
    comm.barrier(T).map_err(|e| e.to_string())
}

/// Every rank sends 8 MiB to every other rank before receiving anything: with sends that
/// waited for the receiver this would deadlock.
fn exchange(comm: &MpiCommunicator) -> Result<(), String> {
    let (me, n) = (comm.rank().index(), comm.size());
    let len = 8 << 20;
    for to in (0..n).filter(|&r| r != me) {
        comm.send(rank(to), 5, payload(me, to, 0, len))
            .map_err(|e| e.to_string())?;
    }
    for from in (0..n).filter(|&r| r != me) {
        let (_, b) = comm
            .recv(Some(rank(from)), 5, T)
            .map_err(|e| e.to_string())?;
        expect_eq(
            &format!("8 MiB from {from}"),
            b == payload(from, me, 0, len),
            true,
        )?;
    }
    comm.barrier(T).map_err(|e| e.to_string())
}

/// The last rank aborts; the others wait (far longer than the test allows) for a message
/// that never comes. The job must end at once, non-zero.
fn abort(comm: &MpiCommunicator) -> Result<(), String> {
    if comm.rank().index() == comm.size() - 1 {
        std::thread::sleep(Duration::from_millis(200));
        comm.abort("deliberate abort from the selftest");
    }
    let r = comm.recv(None, 77, Duration::from_secs(600));
    Err(format!("survived the abort: {r:?}"))
}

/// The last rank panics on a worker thread; the others wait as in `abort`.
fn panic(comm: &MpiCommunicator) -> Result<(), String> {
    if comm.rank().index() == comm.size() - 1 {
        std::thread::sleep(Duration::from_millis(200));
        let h = std::thread::spawn(|| panic!("deliberate panic from the selftest"));
        let _ = h.join();
    }
    let r = comm.recv(None, 77, Duration::from_secs(600));
    Err(format!("survived the panic: {r:?}"))
}

/// Every other rank sends 2000 messages of 1 to 40 KiB to rank 0 (as fragments go to tile
/// owners), which takes them sender by sender; prints the rate.
fn flood(comm: &MpiCommunicator) -> Result<(), String> {
    let (me, n) = (comm.rank().index(), comm.size());
    let count = 2000;
    let len = |i: usize| 1024 + (i * 7919) % (40 << 10);
    comm.barrier(T).map_err(|e| e.to_string())?;
    let t = Instant::now();
    if me == 0 {
        for from in 1..n {
            for i in 0..count {
                let (_, b) = comm
                    .recv(Some(rank(from)), 3, T)
                    .map_err(|e| e.to_string())?;
                expect_eq("flood length", b.len(), len(i))?;
            }
        }
        let s = t.elapsed().as_secs_f64();
        let msgs = (count * (n - 1)) as f64;
        eprintln!(
            "flood: {msgs} messages in {:.1} ms, {:.1} µs each",
            s * 1e3,
            s * 1e6 / msgs.max(1.0)
        );
    } else {
        for i in 0..count {
            comm.send(Rank(0), 3, payload(me, 0, i, len(i)))
                .map_err(|e| e.to_string())?;
        }
    }
    comm.barrier(T).map_err(|e| e.to_string())
}
