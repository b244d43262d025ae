//! A rank that dies mid-frame under `mpirun` (the CLI built with `--features mpi`): the job
//! ends within seconds instead of leaving its peers waiting, and says which rank died.
//! `#[ignore = "needs MPI (mpirun)"]` like tests/mpi.rs; `.ci/run` runs them with `--ignored`.
#![cfg(feature = "mpi")]

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A long orbit under `mpirun -np 3`, so that a rank can be killed while frames render.
fn long_job(dir: &Path) -> Child {
    Command::new("mpirun")
        .args([
            "--allow-run-as-root",
            "--oversubscribe",
            "--bind-to",
            "none",
        ])
        .args(["-np", "3"])
        .arg(env!("CARGO_BIN_EXE_pofvr"))
        .args([
            "render",
            "phantom:head:96",
            "--size",
            "512x512",
            "--frames",
            "400",
            "--orbit",
            "1",
            "--out",
            "o.png",
            "--quiet",
        ])
        .current_dir(dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("this test needs MPI: cannot run mpirun ({e})"))
}

/// The pid of MPI rank `rank` of the job running in `dir`, once it is up.
fn rank_pid(dir: &Path, rank: u32) -> libc::pid_t {
    let want = format!("OMPI_COMM_WORLD_RANK={rank}");
    let start = Instant::now();
    loop {
        for e in std::fs::read_dir("/proc").unwrap().flatten() {
            let Ok(pid) = e.file_name().to_string_lossy().parse::<libc::pid_t>() else {
                continue;
            };
            let p = e.path();
            let in_dir = std::fs::read_link(p.join("cwd")).is_ok_and(|c| c == dir);
            let ours = std::fs::read(p.join("cmdline"))
                .is_ok_and(|c| String::from_utf8_lossy(&c).contains("render"));
            let is_rank = std::fs::read(p.join("environ"))
                .is_ok_and(|env| env.split(|&b| b == 0).any(|kv| kv == want.as_bytes()));
            if in_dir && ours && is_rank {
                return pid;
            }
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "rank {rank} never started"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Kills rank 1 with `sig` after the job has rendered for a while; returns the job's exit
/// status, its stderr and how long it took to end after the kill.
fn kill_rank_mid_frame(sig: libc::c_int) -> (std::process::ExitStatus, String, Duration) {
    let dir = tempfile::tempdir().unwrap();
    let dir_path = dir.path().canonicalize().unwrap();
    let mut job = long_job(&dir_path);
    let pid = rank_pid(&dir_path, 1);
    // Into the frames: the volume generated, the orbit under way.
    std::thread::sleep(Duration::from_millis(1500));
    assert!(
        job.try_wait().unwrap().is_none(),
        "the job ended before the kill"
    );
    // SAFETY: kill(2) on a pid this test found; no memory is involved.
    assert_eq!(unsafe { libc::kill(pid, sig) }, 0);
    let killed = Instant::now();
    let deadline = Duration::from_secs(20);
    let status = loop {
        if let Some(s) = job.try_wait().unwrap() {
            break s;
        }
        if killed.elapsed() > deadline {
            let _ = job.kill();
            panic!("the job outlived rank 1 by {deadline:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let took = killed.elapsed();
    let mut err = String::new();
    use std::io::Read;
    job.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    (status, err, took)
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn a_rank_terminated_mid_frame_ends_the_job_within_seconds_naming_it() {
    let (status, err, took) = kill_rank_mid_frame(libc::SIGTERM);
    assert!(!status.success(), "{err}");
    assert!(
        err.contains("pofvr: rank 1 aborted: signal SIGTERM"),
        "{err}"
    );
    assert!(took < Duration::from_secs(10), "{took:?}: {err}");
    eprintln!("SIGTERM to rank 1: job ended {took:?} later");
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn a_rank_killed_mid_frame_ends_the_job_within_seconds() {
    // SIGKILL cannot be caught: the rank says nothing, and mpirun, seeing it gone, ends
    // its peers and names it.
    let (status, err, took) = kill_rank_mid_frame(libc::SIGKILL);
    assert!(!status.success(), "{err}");
    assert!(err.contains("rank 1"), "{err}");
    assert!(took < Duration::from_secs(10), "{took:?}: {err}");
    eprintln!("SIGKILL to rank 1: job ended {took:?} later");
}
