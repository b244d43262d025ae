//! The communicator under `mpirun`: ping-pong, collectives, timeouts, non-blocking sends,
//! abort and panic, at 1 to 4 ranks. Skipped, with the reason printed, where `mpirun` is
//! absent.

use std::process::{Command, Output};
use std::time::{Duration, Instant};

/// `mpirun` with the flags CI needs (root, more ranks than cores, no core binding), or
/// `None` when it is not installed.
fn mpirun(np: usize) -> Option<Command> {
    let found = Command::new("mpirun").arg("--version").output().is_ok();
    if !found {
        eprintln!("SKIPPED: mpirun not found on PATH (install openmpi-bin to run MPI tests)");
        return None;
    }
    let mut c = Command::new("mpirun");
    c.args([
        "--allow-run-as-root",
        "--oversubscribe",
        "--bind-to",
        "none",
    ])
    .arg("-np")
    .arg(np.to_string());
    Some(c)
}

fn selftest(np: usize, scenario: &str) -> Option<(Output, Duration)> {
    let mut c = mpirun(np)?;
    c.arg(env!("CARGO_BIN_EXE_pofvr-mpi-selftest"))
        .arg(scenario);
    let t = Instant::now();
    let out = c.output().expect("run mpirun");
    Some((out, t.elapsed()))
}

fn text(out: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

fn passes(scenario: &str) {
    for np in 1..=4 {
        let Some((out, _)) = selftest(np, scenario) else {
            return;
        };
        assert!(
            out.status.success(),
            "{scenario} at {np} ranks: {}",
            text(&out)
        );
        let stdout = String::from_utf8_lossy(&out.stdout);
        for r in 0..np {
            assert!(
                stdout.lines().any(|l| l == format!("ok {r} {scenario}")),
                "{scenario}: rank {r} of {np} did not report ok: {}",
                text(&out)
            );
        }
    }
}

#[test]
fn ping_pong_sizes_tags_order_self_and_byte_counts() {
    passes("pingpong");
}

#[test]
fn gather_all_gather_barrier() {
    passes("gather");
}

#[test]
fn recv_times_out_naming_rank_peer_and_tag() {
    passes("timeout");
}

#[test]
fn sends_do_not_wait_for_the_receiver() {
    passes("exchange");
}

fn fails_fast(scenario: &str, cause: &str) {
    let Some((out, took)) = selftest(3, scenario) else {
        return;
    };
    assert!(
        !out.status.success(),
        "{scenario}: the job must fail: {}",
        text(&out)
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(&format!("pofvr: rank 2 aborted: {cause}")),
        "{scenario}: no message naming rank 2 and the cause: {}",
        text(&out)
    );
    assert!(
        took < Duration::from_secs(30),
        "{scenario}: took {took:?} (peers wait up to 600 s unless killed)"
    );
}

#[test]
fn abort_ends_every_rank_non_zero() {
    fails_fast("abort", "deliberate abort from the selftest");
}

#[test]
fn panic_on_a_worker_thread_aborts_the_job() {
    fails_fast("panic", "panic: deliberate panic from the selftest");
}

#[test]
fn thousands_of_fragment_sized_messages_arrive_in_order() {
    passes("flood");
}
