//! The communicator under `mpirun`: ping-pong, collectives, timeouts, non-blocking sends,
//! abort and panic, at 1 to 4 ranks. Each test is `#[ignore = "needs MPI (mpirun)"]`:
//! `.ci/run`, which installs OpenMPI, runs them with `--ignored`; run so without `mpirun`,
//! they fail saying so.

use std::process::{Command, Output};
use std::time::{Duration, Instant};

/// `mpirun` with the flags CI needs (root, more ranks than cores, no core binding).
fn mpirun(np: usize) -> Command {
    let mut c = Command::new("mpirun");
    c.args([
        "--allow-run-as-root",
        "--oversubscribe",
        "--bind-to",
        "none",
    ])
    .arg("-np")
    .arg(np.to_string());
    c
}

fn selftest(np: usize, scenario: &str) -> (Output, Duration) {
    let mut c = mpirun(np);
    c.arg(env!("CARGO_BIN_EXE_pofvr-mpi-selftest"))
        .arg(scenario);
    let t = Instant::now();
    let out = c.output().unwrap_or_else(|e| {
        panic!("this test needs MPI: cannot run mpirun ({e}); install openmpi-bin")
    });
    (out, t.elapsed())
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
        let (out, _) = selftest(np, scenario);
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
#[ignore = "needs MPI (mpirun)"]
fn ping_pong_sizes_tags_order_self_and_byte_counts() {
    passes("pingpong");
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn gather_all_gather_barrier() {
    passes("gather");
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn recv_times_out_naming_rank_peer_and_tag() {
    passes("timeout");
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn sends_do_not_wait_for_the_receiver() {
    passes("exchange");
}

fn fails_fast(scenario: &str, cause: &str) {
    let (out, took) = selftest(3, scenario);
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
#[ignore = "needs MPI (mpirun)"]
fn abort_ends_every_rank_non_zero() {
    fails_fast("abort", "deliberate abort from the selftest");
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn panic_on_a_worker_thread_aborts_the_job() {
    fails_fast("panic", "panic: deliberate panic from the selftest");
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn thousands_of_fragment_sized_messages_arrive_in_order() {
    passes("flood");
}
