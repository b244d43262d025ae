//! `--memory-budget SIZE` on `render`, `serve`, `experiment` and `pof build`: one parser and
//! one message, the same images, figures and POF files as without a budget, and what each
//! frame read.

mod common;

use common::{pofvr, stderr};
use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;
use std::process::{Command, Output, Stdio};

/// The test volume: 96×80×88 u8, a ball (200) in a shell (100) in air (0), off centre, so
/// that only some of its 16³ bricks are non-empty.
const DIMS: [usize; 3] = [96, 80, 88];

/// A budget under the volume's 675,840 bytes that holds every non-empty brick of a view.
const ROOMY: &str = "400K";

/// A budget that holds a few bricks only: every frame reads its bricks again.
const TIGHT: &str = "16K";

/// Writes the volume (`v.raw`) and a one-basis family (`tf.json`) into `dir`.
fn write_volume(dir: &Path) {
    let [nx, ny, nz] = DIMS;
    let mut v = vec![0u8; nx * ny * nz];
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let d = [x as f64 - 40.0, y as f64 - 44.0, z as f64 - 50.0];
                let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                v[x + nx * (y + ny * z)] = if r < 9.0 {
                    200
                } else if r < 15.0 {
                    100
                } else {
                    0
                };
            }
        }
    }
    std::fs::write(dir.join("v.raw"), v).unwrap();
    std::fs::write(
        dir.join("tf.json"),
        r#"{"bases": [{"name": "all", "opacity": [[50, 0.0], [100, 0.08], [200, 0.4]]}],
            "weights": [1.0], "color": [[0, 1, 0.5, 0.2], [255, 1, 1, 1]]}"#,
    )
    .unwrap();
}

/// The volume flags.
const VOL: [&str; 7] = [
    "v.raw", "--dims", "96,80,88", "--dtype", "u8", "--tf", "tf.json",
];

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

fn u64s(v: &serde_json::Value) -> Vec<u64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_u64().unwrap())
        .collect()
}

/// Renders a 3-frame orbit with the brick engine, with `extra` flags, writing
/// `{name}-000N.raw` and `{name}.json`.
fn orbit(dir: &Path, name: &str, orbit: &str, extra: &[&str]) -> Output {
    let raw = format!("{name}.raw");
    let stats = format!("{name}.json");
    let mut args = vec!["render"];
    args.extend(VOL);
    args.extend([
        "--size",
        "64x56",
        "--view",
        "30,20",
        "--frames",
        "3",
        "--orbit",
        orbit,
        "--engine",
        "bricks",
        "--out",
        "o.png",
        "--out-raw",
        &raw,
        "--stats",
        &stats,
    ]);
    args.extend(extra);
    let o = pofvr(&args, dir);
    assert!(o.status.success(), "{name}: {}", stderr(&o));
    o
}

#[test]
fn an_orbit_under_a_budget_is_the_same_images_and_reports_the_bytes_each_frame_read() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_volume(d);
    for turn in ["0", "25"] {
        orbit(d, "whole", turn, &[]);
        let roomy = orbit(d, "roomy", turn, &["--memory-budget", ROOMY]);
        orbit(d, "tight", turn, &["--memory-budget", TIGHT]);
        for i in 0..3 {
            let w = std::fs::read(d.join(format!("whole-{i:04}.raw"))).unwrap();
            for b in ["roomy", "tight"] {
                let img = std::fs::read(d.join(format!("{b}-{i:04}.raw"))).unwrap();
                assert!(img == w, "{b} frame {i} (orbit {turn}) differs");
            }
        }
        let (r, t) = (json(&d.join("roomy.json")), json(&d.join("tight.json")));
        let (rr, tr) = (u64s(&r["bytes_read"]), u64s(&t["bytes_read"]));
        assert_eq!(rr.len(), 3);
        // Every frame of a sequence says what it read; the first reads its bricks.
        for (k, f) in r["frames"].as_array().unwrap().iter().enumerate() {
            assert_eq!(f["bytes_read"].as_u64(), Some(rr[k]));
        }
        assert!(rr[0] > 0 && tr[0] > 0, "{rr:?} {tr:?}");
        if turn == "0" {
            // The same view again: a cache that holds it reads nothing, a tight one all.
            assert_eq!(rr[1..], [0, 0], "{rr:?}");
            assert_eq!(r["median_bytes_read_after_first"].as_u64(), Some(0));
            assert!(tr[1] > 0 && tr[2] > 0, "{tr:?}");
            let cache = &r["memory_budget"]["cache"];
            assert!(cache["cache_hits"].as_u64().unwrap() > 0, "{cache}");
            assert_eq!(cache["bytes_read"].as_u64(), Some(rr[0]));
            assert_eq!(cache["evictions"].as_u64(), Some(0));
        } else {
            // Turning, the roomy cache reads only the bricks that come into view.
            assert!(rr[1] < rr[0] && rr[2] < rr[0], "{rr:?}");
        }
        let line = stderr(&roomy);
        assert!(line.contains("bytes read: first frame"), "{line}");
        assert!(line.contains("MB read per frame ["), "{line}");
    }
}

#[test]
fn every_command_reads_memory_budget_alike_and_refuses_bad_sizes_before_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_volume(d);
    for (size, why) in [
        ("12X", "unknown unit"),
        ("0", "out of range"),
        ("M", "no number"),
    ] {
        let expected = format!("--memory-budget: bad size {size:?}: {why}");
        for cmd in ["render", "serve", "experiment", "pof build"] {
            let mut args: Vec<&str> = cmd.split(' ').collect();
            args.extend(VOL);
            args.extend(["--memory-budget", size, "--out", "out"]);
            if cmd == "serve" {
                // `serve` has no --out; a bad size must stop it before it listens.
                args.truncate(args.len() - 2);
                args.extend(["--port", "0"]);
            }
            let o = pofvr(&args, d);
            assert!(!o.status.success(), "{cmd} {size} succeeded");
            assert!(stderr(&o).contains(&expected), "{cmd}: {}", stderr(&o));
            assert!(!d.join("out").exists(), "{cmd} {size} left an output");
        }
    }
}

#[test]
fn pof_build_under_a_budget_streams_the_volume_and_writes_the_same_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_volume(d);
    for method in ["bound", "sampled", "typical"] {
        let build = |out: &str, extra: &[&str]| {
            let mut args = vec!["pof", "build"];
            args.extend(VOL);
            args.extend(["--method", method, "--views", "4,6", "--sets", "-o", out]);
            args.extend(extra);
            let o = pofvr(&args, d);
            assert!(o.status.success(), "{method} {extra:?}: {}", stderr(&o));
            (std::fs::read(d.join(out)).unwrap(), stderr(&o))
        };
        let (whole, _) = build("whole.pof", &[]);
        let (roomy, line) = build("roomy.pof", &["--memory-budget", ROOMY]);
        // 16K: a row of bricks per slab.
        let (tight, tline) = build("tight.pof", &["--memory-budget", TIGHT]);
        assert!(roomy == whole, "{method}: the roomy budget's file differs");
        assert!(tight == whole, "{method}: the tight budget's file differs");
        assert!(
            line.contains("slabs read") && line.contains("raw file"),
            "{line}"
        );
        let slabs = |l: &str| -> u64 {
            let at = l.find(" slabs read").expect("slab count");
            l[..at].rsplit(' ').next().unwrap().parse().unwrap()
        };
        // The roomy budget reads a layer of bricks per slab, the tight one a row.
        assert!(slabs(&tline) > slabs(&line), "{line}\n{tline}");
        assert!(!d.join("tight.pof.partial").exists());
    }
    // Every temp file was renamed into place.
    let left: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

#[test]
fn pof_build_under_a_budget_reads_a_zarr_level_by_its_chunks_and_writes_the_same_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_volume(d);
    let mut args = vec!["convert"];
    args.extend(&VOL[..5]);
    args.push("v.zarr");
    let o = pofvr(&args, d);
    assert!(o.status.success(), "convert: {}", stderr(&o));
    let build = |out: &str, extra: &[&str]| {
        let mut args = vec!["pof", "build", "v.zarr", "--level", "0", "--tf", "tf.json"];
        args.extend(["--method", "typical", "--views", "4,6", "-o", out]);
        args.extend(extra);
        let o = pofvr(&args, d);
        assert!(o.status.success(), "{extra:?}: {}", stderr(&o));
        (std::fs::read(d.join(out)).unwrap(), stderr(&o))
    };
    let (whole, _) = build("whole.pof", &[]);
    let (held, line) = build("held.pof", &["--memory-budget", ROOMY]);
    assert!(held == whole, "the budgeted build's file differs");
    assert!(
        line.contains("zarr chunks") && line.contains("slabs read"),
        "{line}"
    );
    // The budgeted table is the raw file's too: the same voxels.
    let mut args = vec!["pof", "build"];
    args.extend(VOL);
    args.extend(["--method", "typical", "--views", "4,6", "-o", "raw.pof"]);
    assert!(pofvr(&args, d).status.success());
    assert!(std::fs::read(d.join("raw.pof")).unwrap() == held);
}

#[test]
fn what_samples_the_whole_volume_is_refused_under_a_budget_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_volume(d);
    for extra in [&["--whole"][..], &["--cull", "exact"][..]] {
        let mut args = vec!["render"];
        args.extend(VOL);
        args.extend([
            "--size",
            "32x32",
            "--out",
            "o.png",
            "--memory-budget",
            ROOMY,
        ]);
        args.extend(extra);
        let o = pofvr(&args, d);
        assert!(!o.status.success(), "{extra:?} succeeded");
        let e = stderr(&o);
        assert!(
            e.contains("v.raw") && e.contains("does not fit the memory budget"),
            "{extra:?}: {e}"
        );
        assert!(!d.join("o.png").exists(), "{extra:?} left an image");
        // Without the budget the same frame renders.
        let mut args = vec!["render"];
        args.extend(VOL);
        args.extend(["--size", "32x32", "--out", "o.png"]);
        args.extend(extra);
        let o = pofvr(&args, d);
        assert!(o.status.success(), "{extra:?}: {}", stderr(&o));
        std::fs::remove_file(d.join("o.png")).unwrap();
    }
}

#[test]
fn the_experiment_under_a_budget_gives_the_same_figures_and_reports_its_reads() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_volume(d);
    let run = |out: &str, budget: Option<&str>| {
        let mut args = vec!["experiment"];
        args.extend(VOL);
        args.extend([
            "--quick",
            "--size",
            "48x40",
            "--audit-views",
            "4",
            "--max-ranks",
            "2",
            "--out",
            out,
            "--quiet",
        ]);
        if let Some(b) = budget {
            args.extend(["--memory-budget", b]);
        }
        let o = pofvr(&args, d);
        assert!(o.status.success(), "{out}: {}", stderr(&o));
        (json(&d.join(out).join("report.json")), stderr(&o))
    };
    let (whole, _) = run("whole", None);
    let (budgeted, line) = run("budgeted", Some(ROOMY));
    assert!(whole.get("memory_budget").is_none());
    let mb = &budgeted["memory_budget"];
    assert_eq!(mb["budget_bytes"].as_u64(), Some(400 << 10));
    assert_eq!(mb["volume_bytes"].as_u64(), Some(96 * 80 * 88));
    assert_eq!(mb["source"].as_str(), Some("raw file"));
    assert!(mb["cache"]["bytes_read"].as_u64().unwrap() > 0, "{mb}");
    assert!(mb["cache"]["cache_hits"].as_u64().unwrap() > 0, "{mb}");
    assert!(line.contains("read on demand from the raw file"), "{line}");
    // The same bricks rendered, culled and repaired, view by view.
    let means = |r: &serde_json::Value| {
        r["summary"]["culling_vs_view"]
            .as_array()
            .unwrap()
            .iter()
            .map(|m| {
                (
                    m["method"].to_string(),
                    m["mean_visible"].as_f64(),
                    m["mean_culled_fraction_of_non_empty"].as_f64(),
                    m["mean_repaired"].as_f64(),
                )
            })
            .collect::<Vec<_>>()
    };
    // The exact oracle samples the whole lattice: under the budget it is left out, said so.
    let exact = "\"exact\"".to_string();
    let whole_means: Vec<_> = means(&whole).into_iter().filter(|m| m.0 != exact).collect();
    assert!(!whole_means.is_empty());
    assert!(means(&whole).iter().any(|m| m.0 == exact));
    assert_eq!(whole_means, means(&budgeted));
    assert_eq!(
        whole["summary"]["audit"]["conservative_violations"],
        budgeted["summary"]["audit"]["conservative_violations"]
    );
    assert_budgeted_experiment_says_what_it_did(d, "budgeted", &budgeted, &line);
    // The POF tables are the same, built from the store slab by slab.
    let cols = |r: &str| {
        let csv = std::fs::read_to_string(d.join(r).join("fig1_pof_construction.csv")).unwrap();
        csv.lines()
            .map(|l| {
                // Counted from the end (the source column may hold commas): views, computed
                // bricks, bytes per brick and basis, stored bricks, file bytes.
                let c: Vec<&str> = l.split(',').collect();
                let n = c.len();
                [c[0], c[1], c[n - 8], c[n - 6], c[n - 4], c[n - 3], c[n - 2]].map(str::to_string)
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(cols("whole"), cols("budgeted"));
}

/// What a budgeted run's report and stderr must say: the POF builds streamed from the raw
/// file (with their bytes), the reference frames read through the store, the exact oracle
/// not measured and why, in report.json, index.html and on stderr.
fn assert_budgeted_experiment_says_what_it_did(
    d: &Path,
    out: &str,
    report: &serde_json::Value,
    stderr: &str,
) {
    let e = &report["memory_budget"]["experiment"];
    assert_eq!(
        e["pof_build"].as_str(),
        Some("streamed slab by slab from the raw file"),
        "{e}"
    );
    assert!(e["pof_build_bytes_read"].as_u64().unwrap() > 0, "{e}");
    assert!(
        e["reference"]
            .as_str()
            .is_some_and(|r| r.contains("through the brick store")),
        "{e}"
    );
    let left = e["methods_not_measured"].as_array().unwrap();
    assert_eq!(left.len(), 1, "{e}");
    assert_eq!(left[0]["method"].as_str(), Some("exact"));
    assert!(left[0]["reason"]
        .as_str()
        .unwrap()
        .contains("--memory-budget"));
    assert!(
        stderr.contains("note: exact not measured") && stderr.contains("--memory-budget"),
        "{stderr}"
    );
    let html = std::fs::read_to_string(d.join(out).join("index.html")).unwrap();
    assert!(
        html.contains("larger than --memory-budget"),
        "no note in index.html"
    );
    let csv = std::fs::read_to_string(d.join(out).join("fig1_pof_construction.csv")).unwrap();
    assert!(csv.contains("streamed from the raw file"), "{csv}");
}

/// Runs `pofvr ARGS` in `dir` and returns whether it succeeded, its stderr and its peak
/// resident set size in bytes (`ru_maxrss` of the child, from `wait4`): file pages it
/// maps and touches count, pages it reads with `pread` do not.
fn pofvr_peak_rss(args: &[&str], dir: &Path) -> (bool, String, u64) {
    let err = dir.join("stderr.txt");
    let child = Command::new(env!("CARGO_BIN_EXE_pofvr"))
        .args(args)
        .current_dir(dir)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&err).unwrap())
        .spawn()
        .expect("run pofvr");
    let pid = libc::pid_t::try_from(child.id()).unwrap();
    let mut status = 0;
    // SAFETY: `rusage` is plain data, zeroed is a valid value; `wait4` fills it for our own
    // child, which nothing else waits for (the `Child` is dropped without waiting).
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let got = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    assert_eq!(got, pid, "wait4");
    drop(child);
    let ok = libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0;
    let kib = u64::try_from(usage.ru_maxrss).unwrap();
    (ok, std::fs::read_to_string(&err).unwrap(), kib * 1024)
}

/// A volume whose every 32³ brick is non-empty: 256³ i16 (32 MiB), smooth values.
fn write_dense_volume(dir: &Path) {
    let n = 256usize;
    let mut v = Vec::with_capacity(n * n * n * 2);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let s =
                    ((x as f64 * 0.11).sin() + (y as f64 * 0.07).cos() + (z as f64 * 0.05).sin())
                        * 300.0
                        + 1000.0;
                v.extend_from_slice(&(s as i16).to_le_bytes());
            }
        }
    }
    std::fs::write(dir.join("dense.raw"), v).unwrap();
    std::fs::write(
        dir.join("dense.json"),
        r#"{"bases": [{"name": "all", "opacity": [[100, 0.0], [1000, 0.01], [1900, 0.05]]}],
            "weights": [1.0], "color": [[0, 1, 0.5, 0.2], [2000, 1, 1, 1]]}"#,
    )
    .unwrap();
}

/// Measured (2-core VM, load 5–6): whole 115 MB, budgeted at 4M 77 MB, and 110 MB with the
/// POF builds sampling the mapping and the exact oracle measured (the code before this
/// test), which fails the bound. Ignored for its time: about 100 s for the two runs (every
/// frame of the figures re-reads the 32 MiB volume through a 4 MiB cache).
#[test]
#[ignore = "slow (about 100 s): cargo test --release -p pofvr-cli --test memory_budget -- --ignored"]
fn the_experiment_under_a_budget_does_not_map_the_volume_whole() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_dense_volume(d);
    let volume_bytes = 256u64 * 256 * 256 * 2;
    let run = |out: &str, budget: Option<&str>| {
        let mut args = vec![
            "experiment",
            "dense.raw",
            "--dims",
            "256,256,256",
            "--dtype",
            "i16",
            "--tf",
            "dense.json",
            "--brick",
            "32",
            "--quick",
            "--pof-views",
            "3,4",
            "--size",
            "24x24",
            "--audit-views",
            "2",
            "--max-ranks",
            "1",
            "--out",
            out,
            "--quiet",
        ];
        if let Some(b) = budget {
            args.extend(["--memory-budget", b]);
        }
        let (ok, err, rss) = pofvr_peak_rss(&args, d);
        assert!(ok, "{out}: {err}");
        (json(&d.join(out).join("report.json")), err, rss)
    };
    let (whole, _, whole_rss) = run("whole", None);
    let (budgeted, err, budgeted_rss) = run("budgeted", Some("4M"));
    assert!(
        whole["bricks"]["empty"].as_u64() == Some(0),
        "{}",
        whole["bricks"]
    );
    assert_budgeted_experiment_says_what_it_did(d, "budgeted", &budgeted, &err);
    // The unbudgeted run maps the 32 MiB volume and touches all of it; the budgeted one
    // reads it through the store and must stay well below (without the streamed POF build
    // and with the exact oracle, it touched every page too).
    eprintln!("peak RSS: whole {whole_rss}, budgeted {budgeted_rss}, volume {volume_bytes}");
    assert!(
        whole_rss > volume_bytes,
        "whole: peak RSS {whole_rss} not above the volume's {volume_bytes} bytes"
    );
    assert!(
        budgeted_rss + volume_bytes / 2 < whole_rss,
        "budgeted peak RSS {budgeted_rss} vs whole {whole_rss}: the volume was mapped"
    );
}

/// One HTTP/1.1 GET of `path` from `addr`: the head and the body.
fn get(addr: &str, path: &str) -> (String, Vec<u8>) {
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut all = Vec::new();
    s.read_to_end(&mut all).unwrap();
    let at = all
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("an HTTP head");
    (
        String::from_utf8_lossy(&all[..at]).into_owned(),
        all[at + 4..].to_vec(),
    )
}

/// Kills the server when the test ends, passing or not.
struct Server(std::process::Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn serve_under_a_budget_renders_from_the_store_and_says_what_each_frame_read() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_volume(d);
    let mut args = vec!["serve"];
    args.extend(VOL);
    args.extend(["--port", "0", "--memory-budget", ROOMY]);
    let mut server = Server(
        Command::new(env!("CARGO_BIN_EXE_pofvr"))
            .args(&args)
            .current_dir(d)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut line = String::new();
    BufReader::new(server.0.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .trim()
        .strip_prefix("pofvr serve: listening on http://")
        .and_then(|a| a.strip_suffix('/'))
        .unwrap_or_else(|| panic!("no address in {line:?}"))
        .to_owned();
    let stats = |head: &str| -> serde_json::Value {
        let h = head
            .lines()
            .find_map(|l| {
                let (k, v) = l.split_once(':')?;
                k.eq_ignore_ascii_case("x-pofvr-stats")
                    .then(|| v.trim().to_owned())
            })
            .unwrap_or_else(|| panic!("no stats header in {head}"));
        serde_json::from_str(&h).unwrap()
    };
    let frame = "/api/frame?w=48&h=40&az=30&el=20&cull=none";
    let (h1, png) = get(&addr, frame);
    assert!(h1.starts_with("HTTP/1.1 200"), "{h1}");
    assert!(png.starts_with(b"\x89PNG"));
    let s1 = stats(&h1);
    assert!(s1["bytes_read"].as_u64().unwrap() > 0, "{s1}");
    assert!(s1["bricks_read"].as_u64().unwrap() > 0, "{s1}");
    // The same view again: every brick from the cache the frames share.
    let (h2, png2) = get(&addr, frame);
    let s2 = stats(&h2);
    assert_eq!(s2["bytes_read"].as_u64(), Some(0), "{s2}");
    assert_eq!(s2["cache_hits"], s1["bricks_read"], "{s1} {s2}");
    assert_eq!(png, png2);
    // The histogram, counted from the file: every voxel once.
    let (hh, body) = get(&addr, "/api/histogram");
    assert!(hh.starts_with("HTTP/1.1 200"), "{hh}");
    let hist: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(hist["total"].as_u64(), Some(96 * 80 * 88));
    drop(server);
}
