//! `pofvr render` under `mpirun` (built with `--features mpi`): the frame of 1 to 4 MPI ranks
//! is the in-process frame, for both curves; sequences; a failing rank ends the job fast with
//! a message naming it. Each test is `#[ignore = "needs MPI (mpirun)"]`: `.ci/run`, which
//! installs OpenMPI, runs them with `--ignored`; run so without `mpirun`, they fail saying so.
//!
//! These live in the CLI crate rather than in `pofvr-mpi` because they run the `pofvr` binary
//! itself, which cargo builds (with the feature) only for this crate's tests.
#![cfg(feature = "mpi")]

mod common;

use common::pofvr;
use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

const PHANTOM: &str = "phantom:head:64";

/// `pofvr ARGS` as `np` MPI ranks.
fn mpirun(np: usize, args: &[&str], dir: &Path) -> (Output, Duration) {
    // OpenMPI's launcher can, rarely, hang after every rank has exited (the ranks left as
    // zombies, `mpirun` deaf to SIGTERM): a launcher fault, not pofvr's. A run that outlives
    // the deadline is killed and tried once more, so that such a hang fails loudly at worst
    // instead of stalling the suite.
    const DEADLINE: Duration = Duration::from_secs(20);
    for attempt in 1..=2 {
        let t = Instant::now();
        if let Some(out) = run_with_deadline(np, args, dir, DEADLINE) {
            return (out, t.elapsed());
        }
        eprintln!(
            "mpirun -np {np} {args:?}: no exit after {DEADLINE:?} (attempt {attempt}), killed"
        );
    }
    panic!("mpirun -np {np} {args:?} hung twice");
}

/// `pofvr ARGS` under `mpirun -np NP`, its output, or `None` (the launcher killed) when it
/// has not exited after `deadline`.
fn run_with_deadline(np: usize, args: &[&str], dir: &Path, deadline: Duration) -> Option<Output> {
    use std::io::Read;
    use std::process::Stdio;
    let mut child = Command::new("mpirun")
        .args([
            "--allow-run-as-root",
            "--oversubscribe",
            "--bind-to",
            "none",
        ])
        .args(["-np", &np.to_string()])
        .arg(env!("CARGO_BIN_EXE_pofvr"))
        .args(args)
        .current_dir(dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| {
            panic!("this test needs MPI: cannot run mpirun ({e}); install openmpi-bin")
        });
    // Both pipes drained as the job runs, so that a chatty job cannot block on a full pipe.
    let drain = |mut r: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut v = Vec::new();
            let _ = r.read_to_end(&mut v);
            v
        })
    };
    let out = drain(Box::new(child.stdout.take().expect("piped")));
    let err = drain(Box::new(child.stderr.take().expect("piped")));
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait for mpirun") {
            break status;
        }
        if start.elapsed() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            // (The readers are left behind: a rank still alive may hold the pipes open.)
            return None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Some(Output {
        status,
        stdout: out.join().unwrap_or_default(),
        stderr: err.join().unwrap_or_default(),
    })
}

/// `pofvr ARGS` in this process's ranks (no MPI launcher in the environment).
fn text(out: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// The ranks of a frame's `--stats` rendered as many bricks as were visible.
fn refs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

fn assert_each_visible_brick_rendered_once(s: &serde_json::Value) {
    let rendered: u64 = s["ranks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["bricks_rendered"].as_u64().unwrap())
        .sum();
    assert_eq!(rendered, s["bricks"]["visible"].as_u64().unwrap(), "{s}");
}

fn floats(path: &Path) -> Vec<f32> {
    std::fs::read(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn max_diff(a: &Path, b: &Path) -> f32 {
    let (a, b) = (floats(a), floats(b));
    assert_eq!(a.len(), b.len(), "image sizes differ");
    assert!(!a.is_empty(), "empty image");
    a.iter()
        .zip(&b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

fn render_args<'a>(curve: &'a str, cull: &'a str, out: &'a str) -> Vec<&'a str> {
    vec![
        "render",
        PHANTOM,
        "--size",
        "96x80",
        "--view",
        "35,25",
        "--curve",
        curve,
        "--cull",
        cull,
        "--out",
        "x.png",
        "--out-raw",
        out,
    ]
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn one_to_four_mpi_ranks_give_the_in_process_frame_for_both_curves() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (curve, cull) in [("hilbert", "none"), ("z", "none"), ("hilbert", "exact")] {
        let one = format!("local-{curve}-{cull}-1.raw");
        let o = pofvr(
            &[render_args(curve, cull, &one), vec!["--ranks", "1"]].concat(),
            d,
        );
        assert!(o.status.success(), "{}", text(&o));
        let mut copy_total: Option<u64> = None;
        for np in 1..=4 {
            let local = format!("local-{curve}-{cull}-{np}.raw");
            let npstr = np.to_string();
            let o = pofvr(
                &[render_args(curve, cull, &local), vec!["--ranks", &npstr]].concat(),
                d,
            );
            assert!(o.status.success(), "{}", text(&o));
            let mpi = format!("mpi-{curve}-{cull}-{np}.raw");
            let stats = format!("mpi-{curve}-{cull}-{np}.json");
            let (o, _) = mpirun(
                np,
                &[render_args(curve, cull, &mpi), vec!["--stats", &stats]].concat(),
                d,
            );
            assert!(o.status.success(), "{curve} {cull} -np {np}: {}", text(&o));
            let vs_local = max_diff(&d.join(&mpi), &d.join(&local));
            let vs_one = max_diff(&d.join(&mpi), &d.join(&one));
            assert!(
                vs_local <= 1e-6 && vs_one <= 1e-6,
                "{curve} {cull} -np {np}: max diff {vs_local:e} vs --ranks {np}, \
                 {vs_one:e} vs --ranks 1"
            );
            let s: serde_json::Value =
                serde_json::from_slice(&std::fs::read(d.join(&stats)).unwrap()).unwrap();
            assert_eq!(s["mpi_ranks"], np, "{s}");
            assert_eq!(s["ranks"].as_array().unwrap().len(), np, "{s}");
            let memory = s["memory"].as_array().unwrap();
            assert_eq!(memory.len(), np, "{s}");
            for (r, m) in memory.iter().enumerate() {
                assert_eq!(m["rank"], r, "{s}");
                assert!(m["vm_hwm_bytes"].as_u64().unwrap() > 0, "{s}");
                assert!(m["vm_rss_bytes"].as_u64().unwrap() <= m["vm_hwm_bytes"].as_u64().unwrap());
            }
            // Each rank keeps copies of its own bricks only: together they are the same
            // bricks whatever the rank count, and none holds much more than its share.
            let copies: Vec<u64> = memory
                .iter()
                .map(|m| m["brick_copy_bytes"].as_u64().unwrap())
                .collect();
            let total: u64 = copies.iter().sum();
            let first = *copy_total.get_or_insert(total);
            assert_eq!(total, first, "{curve} -np {np}: brick copies {copies:?}");
            for c in &copies {
                assert!(
                    *c * np as u64 <= total * 5 / 4,
                    "{curve} -np {np}: a rank holds {c} of {total} bytes: {copies:?}"
                );
            }
            assert_each_visible_brick_rendered_once(&s);
            if np > 1 {
                assert!(
                    s["ranks"][1]["bytes_sent"].as_u64().unwrap() > 0,
                    "rank 1 sent nothing: {s}"
                );
            }
        }
    }
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn two_replicas_under_mpi_hold_every_brick_twice_and_give_the_same_frame() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = pofvr(&render_args("hilbert", "none", "one.raw"), d);
    assert!(o.status.success(), "{}", text(&o));
    let copies = |stats: &str| -> Vec<u64> {
        let s: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.join(stats)).unwrap()).unwrap();
        assert_each_visible_brick_rendered_once(&s);
        s["memory"]
            .as_array()
            .unwrap()
            .iter()
            .map(|m| m["brick_copy_bytes"].as_u64().unwrap())
            .collect()
    };
    for np in [2usize, 3] {
        let mut totals = Vec::new();
        for replicas in ["1", "2"] {
            let raw = format!("r{replicas}-{np}.raw");
            let stats = format!("r{replicas}-{np}.json");
            let (o, _) = mpirun(
                np,
                &[
                    render_args("hilbert", "none", &raw),
                    vec!["--replicas", replicas, "--stats", &stats],
                ]
                .concat(),
                d,
            );
            assert!(
                o.status.success(),
                "-np {np} --replicas {replicas}: {}",
                text(&o)
            );
            let diff = max_diff(&d.join(&raw), &d.join("one.raw"));
            assert!(
                diff <= 1e-6,
                "-np {np} --replicas {replicas}: max diff {diff:e}"
            );
            totals.push(copies(&stats).iter().sum::<u64>());
        }
        assert_eq!(
            totals[1],
            2 * totals[0],
            "-np {np}: brick copies {totals:?}"
        );
    }
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn an_orbit_sequence_under_mpi_has_one_stats_entry_per_frame() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (o, _) = mpirun(
        3,
        &[
            "render",
            PHANTOM,
            "--size",
            "64x64",
            "--view",
            "30,20",
            "--frames",
            "3",
            "--orbit",
            "40",
            "--out",
            "seq.png",
            "--out-raw",
            "seq.raw",
            "--stats",
            "seq.json",
        ],
        d,
    );
    assert!(o.status.success(), "{}", text(&o));
    let o = pofvr(
        &[
            "render",
            PHANTOM,
            "--size",
            "64x64",
            "--view",
            "110,20",
            // The brick engine, as every MPI frame uses.
            "--engine",
            "bricks",
            "--out",
            "one.png",
            "--out-raw",
            "one.raw",
        ],
        d,
    );
    assert!(o.status.success(), "{}", text(&o));
    let diff = max_diff(&d.join("seq-0002.raw"), &d.join("one.raw"));
    assert!(
        diff <= 1e-6,
        "frame 2 of a 40° orbit from 30° is not --view 110,20: {diff:e}"
    );
    assert!(max_diff(&d.join("seq-0000.raw"), &d.join("seq-0001.raw")) > 1e-3);
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("seq.json")).unwrap()).unwrap();
    assert_eq!(s["frames"].as_array().unwrap().len(), 3, "{s}");
    assert_eq!(s["frame_ms"].as_array().unwrap().len(), 3, "{s}");
    assert_eq!(s["bytes_sent"].as_array().unwrap().len(), 3, "{s}");
    // Per-frame bytes, not a running total: no frame sends several times another's bytes.
    let b: Vec<u64> = s["bytes_sent"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    assert!(
        b.iter().all(|&x| x > 0 && x < 2 * b[0]),
        "bytes per frame {b:?}"
    );
    assert!(s["median_frame_ms"].as_f64().unwrap() > 0.0, "{s}");
}

fn assert_aborts_fast(o: &Output, took: Duration, cause: &str) {
    assert!(!o.status.success(), "the job must fail: {}", text(o));
    let err = String::from_utf8_lossy(&o.stderr);
    let named = err
        .lines()
        .any(|l| l.starts_with("pofvr: rank ") && l.contains(" aborted: ") && l.contains(cause));
    assert!(named, "no line naming a rank and {cause:?}: {}", text(o));
    assert!(took < Duration::from_secs(30), "took {took:?}");
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn a_missing_volume_file_aborts_the_job_within_seconds() {
    let dir = tempfile::tempdir().unwrap();
    let (o, took) = mpirun(
        3,
        &[
            "render",
            "no-such-volume.raw",
            "--dims",
            "8,8,8",
            "--dtype",
            "u8",
            "--tf",
            "none.json",
        ],
        dir.path(),
    );
    assert_aborts_fast(&o, took, "no-such-volume.raw");
    assert!(!dir.path().join("out.png").exists());
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn rank_zero_failing_while_the_others_wait_aborts_the_job() {
    // Rank 0 fails writing the image after the frame, while ranks 1..3 already wait for the
    // end-of-run gather: the job must end at once, naming rank 0.
    let dir = tempfile::tempdir().unwrap();
    let (o, took) = mpirun(
        4,
        &[
            "render",
            PHANTOM,
            "--size",
            "64x64",
            "--out",
            "no-such-dir/x.png",
        ],
        dir.path(),
    );
    assert_aborts_fast(&o, took, "no-such-dir");
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("pofvr: rank 0 aborted"),
        "{}",
        text(&o)
    );
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn ranks_flag_under_mpirun_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (o, took) = mpirun(
        2,
        &["render", PHANTOM, "--size", "32x32", "--ranks", "3"],
        dir.path(),
    );
    assert_aborts_fast(&o, took, "--ranks 3");
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn verified_culling_under_mpi_repairs_and_gives_the_in_process_frame() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for predictor in ["proxy", "random:7", "everything"] {
        let tag = predictor.replace(':', "-");
        let args = |out: &str| -> Vec<String> {
            let mut a: Vec<String> = render_args("hilbert", "verified", out)
                .into_iter()
                .map(str::to_owned)
                .collect();
            a.extend(["--predictor".to_owned(), predictor.to_owned()]);
            a
        };
        let one = format!("local-{tag}.raw");
        let mut local = args(&one);
        local.extend(["--ranks".to_owned(), "1".to_owned()]);
        let o = pofvr(&local.iter().map(String::as_str).collect::<Vec<_>>(), d);
        assert!(o.status.success(), "{}", text(&o));
        for np in 2..=3 {
            let mpi = format!("mpi-{tag}-{np}.raw");
            let stats = format!("mpi-{tag}-{np}.json");
            let mut a = args(&mpi);
            a.extend(["--stats".to_owned(), stats.clone()]);
            let (o, _) = mpirun(np, &a.iter().map(String::as_str).collect::<Vec<_>>(), d);
            assert!(o.status.success(), "{predictor} -np {np}: {}", text(&o));
            let diff = max_diff(&d.join(&mpi), &d.join(&one));
            assert!(diff == 0.0, "{predictor} -np {np}: max diff {diff:e}");
            let s: serde_json::Value =
                serde_json::from_slice(&std::fs::read(d.join(&stats)).unwrap()).unwrap();
            assert_eq!(s["predictor"], predictor.split(':').next().unwrap(), "{s}");
            assert_each_visible_brick_rendered_once(&s);
            let repaired = s["bricks"]["repaired"].as_u64().unwrap();
            if predictor != "proxy" {
                assert!(repaired > 0, "{predictor} -np {np}: nothing repaired: {s}");
            }
            for r in s["ranks"].as_array().unwrap() {
                assert!(r["verify_ms"].as_f64().is_some() && r["repair_ms"].as_f64().is_some());
            }
        }
    }
}

#[test]
#[ignore = "needs MPI (mpirun)"]
fn mpi_ranks_under_a_budget_read_only_their_own_bricks_from_zarr_chunks() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = pofvr(
        &["convert", "phantom:body:160x128x200", "b.zarr", "--quiet"],
        d,
    );
    assert!(o.status.success(), "{}", text(&o));
    let tf = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tfs/ct-chest-skin-bone.json");
    let tf = tf.to_str().unwrap();
    let args = |cull: &'static str, raw: &str, stats: &str| -> Vec<String> {
        [
            "render",
            "b.zarr",
            "--level",
            "0",
            "--tf",
            tf,
            "--size",
            "64x64",
            "--view",
            "0,-90",
            "--cull",
            cull,
            "-o",
            "x.png",
            "--out-raw",
            raw,
            "--stats",
            stats,
        ]
        .iter()
        .map(|s| s.to_string())
        .collect()
    };
    let strs = |a: &[String], extra: &[&'static str]| -> Vec<String> {
        a.iter()
            .cloned()
            .chain(extra.iter().map(|s| s.to_string()))
            .collect()
    };
    for cull in ["none", "verified"] {
        let want = format!("one-{cull}.raw");
        let a = args(cull, &want, "one.json");
        let o = pofvr(&refs(&strs(&a, &["--engine", "bricks"])), d);
        assert!(o.status.success(), "{}", text(&o));
        for np in [1, 3] {
            let got = format!("mpi-{cull}-{np}.raw");
            let stats = format!("mpi-{cull}-{np}.json");
            let a = args(cull, &got, &stats);
            // 8.2 MB of voxels: 4 MB holds neither the chunks nor the bricks of a frame.
            let (o, _) = mpirun(np, &refs(&strs(&a, &["--memory-budget", "4M"])), d);
            assert!(o.status.success(), "{cull} -np {np}: {}", text(&o));
            let diff = max_diff(&d.join(&got), &d.join(&want));
            assert!(diff <= 1e-6, "{cull} -np {np}: max diff {diff:e}");
            let s: serde_json::Value =
                serde_json::from_slice(&std::fs::read(d.join(&stats)).unwrap()).unwrap();
            assert_each_visible_brick_rendered_once(&s);
            assert_eq!(s["memory_budget"]["source"], "zarr chunks", "{s}");
            // Read chunk by chunk: dealt by chunks, so that each rank decodes its part.
            assert_eq!(s["deal"], "chunks", "{s}");
            for r in s["ranks"].as_array().unwrap() {
                let n = |k: &str| r[k].as_u64().unwrap();
                // Every brick a rank renders comes from its own store: none is copied.
                assert_eq!(
                    n("bricks_read") + n("cache_hits"),
                    n("bricks_rendered"),
                    "{s}"
                );
                assert!(
                    n("bytes_read") > 0,
                    "{cull} -np {np}: a rank read nothing: {s}"
                );
            }
            for m in s["memory"].as_array().unwrap() {
                assert_eq!(m["brick_copy_bytes"], 0, "{s}");
                assert!(m["io_read_bytes"].as_u64().unwrap() > 0, "{s}");
            }
        }
        // The paper's deal, asked for: the same frame.
        let got = format!("mpi-{cull}-curve.raw");
        let a = args(cull, &got, "curve.json");
        let extra = ["--memory-budget", "4M", "--deal", "curve"];
        let (o, _) = mpirun(3, &refs(&strs(&a, &extra)), d);
        assert!(o.status.success(), "{cull} --deal curve: {}", text(&o));
        let diff = max_diff(&d.join(&got), &d.join(&want));
        assert!(diff <= 1e-6, "{cull} --deal curve: max diff {diff:e}");
        let s: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.join("curve.json")).unwrap()).unwrap();
        assert_eq!(s["deal"], "curve", "{s}");
        assert_each_visible_brick_rendered_once(&s);
    }
}
