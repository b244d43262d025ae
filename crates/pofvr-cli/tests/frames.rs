//! `pofvr render --frames N --orbit DEG` in one process: an orbit about Y, one stats entry
//! per frame, and each process's memory in `--stats`.

mod common;

use common::pofvr;
use std::path::Path;

fn floats(path: &Path) -> Vec<f32> {
    std::fs::read(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn max_diff(a: &Path, b: &Path) -> f32 {
    let (a, b) = (floats(a), floats(b));
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(&b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn an_orbit_is_the_views_it_passes_and_stats_have_one_entry_per_frame() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = pofvr(
        &[
            "render",
            "phantom:head:48",
            "--size",
            "48x40",
            "--view",
            "30,20",
            "--frames",
            "3",
            "--orbit",
            "40",
            "--ranks",
            "2",
            "--out",
            "o.png",
            "--out-raw",
            "o.raw",
            "--stats",
            "s.json",
        ],
        d,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for v in ["30,20", "70,20", "110,20"] {
        let raw = format!("v{}.raw", v.replace(',', "_"));
        let o = pofvr(
            &[
                "render",
                "phantom:head:48",
                "--size",
                "48x40",
                "--view",
                v,
                // The orbit is rendered by the brick engine (--ranks 2): so are the views.
                "--engine",
                "bricks",
                "--out",
                "v.png",
                "--out-raw",
                &raw,
            ],
            d,
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    assert!(max_diff(&d.join("o-0000.raw"), &d.join("v30_20.raw")) <= 1e-6);
    assert!(max_diff(&d.join("o-0001.raw"), &d.join("v70_20.raw")) <= 1e-6);
    assert!(max_diff(&d.join("o-0002.raw"), &d.join("v110_20.raw")) <= 1e-6);
    assert!(max_diff(&d.join("o-0000.raw"), &d.join("o-0002.raw")) > 1e-3);
    assert!(d.join("o-0002.png").exists() && !d.join("o.png").exists());
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("s.json")).unwrap()).unwrap();
    assert_eq!(s["frames"].as_array().unwrap().len(), 3, "{s}");
    assert_eq!(s["frame_ms"].as_array().unwrap().len(), 3, "{s}");
    assert_eq!(s["bytes_sent"].as_array().unwrap().len(), 3, "{s}");
    assert!(s["bytes_sent"][0].as_u64().unwrap() > 0, "{s}");
    assert_eq!(s["frames"][2]["ranks"].as_array().unwrap().len(), 2, "{s}");
    assert!(s["memory"][0]["vm_hwm_bytes"].as_u64().unwrap() > 0, "{s}");
}

#[test]
fn zero_frames_and_a_reference_with_a_sequence_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    for args in [
        vec!["render", "phantom:head:32", "--frames", "0"],
        vec![
            "render",
            "phantom:head:32",
            "--frames",
            "2",
            "--reference",
            "x.raw",
        ],
    ] {
        let o = pofvr(&args, dir.path());
        assert!(!o.status.success(), "{args:?} must fail");
        assert!(
            String::from_utf8_lossy(&o.stderr).contains("--frames")
                || String::from_utf8_lossy(&o.stderr).contains("--reference"),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    assert!(std::fs::read_dir(dir.path()).unwrap().next().is_none());
}

#[test]
fn replicas_give_the_same_frame_and_more_replicas_than_ranks_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let render = |ranks: &str, replicas: &str, raw: &str| {
        pofvr(
            &[
                "render",
                "phantom:head:48",
                "--size",
                "64x56",
                "--view",
                "30,20",
                "--cull",
                "none",
                "--ranks",
                ranks,
                "--replicas",
                replicas,
                "--out",
                "o.png",
                "--out-raw",
                raw,
                "--stats",
                &format!("{raw}.json"),
            ],
            d,
        )
    };
    let o = render("1", "1", "one.raw");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = render("5", "2", "five.raw");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(max_diff(&d.join("one.raw"), &d.join("five.raw")), 0.0);
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("five.raw.json")).unwrap()).unwrap();
    let rendered: u64 = s["ranks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["bricks_rendered"].as_u64().unwrap())
        .sum();
    assert_eq!(rendered, s["bricks"]["visible"].as_u64().unwrap(), "{s}");
    let o = render("3", "4", "bad.raw");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--replicas") && err.contains("got 4"), "{err}");
    assert!(!d.join("bad.raw").exists());
}

#[test]
fn jitter_is_off_unless_asked_reproducible_per_seed_and_the_same_for_bricks_and_whole() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let render = |out: &str, extra: &[&str]| {
        let mut args = vec![
            "render",
            "phantom:head:40",
            "--size",
            "48x40",
            "--view",
            "25,15",
            "-o",
            "o.png",
            "--out-raw",
            out,
        ];
        args.extend_from_slice(extra);
        let o = pofvr(&args, d);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    render("plain.raw", &[]);
    render("plain-whole.raw", &["--whole"]);
    render("j0.raw", &["--jitter"]);
    render("j0-again.raw", &["--jitter", "0"]);
    render("j5.raw", &["--jitter", "5"]);
    render("j5-whole.raw", &["--jitter", "5", "--whole"]);
    let diff = |a: &str, b: &str| max_diff(&d.join(a), &d.join(b));
    // The brick and whole frames differ by early termination inside bricks only
    // (at most 1 − ert); the jitter adds nothing to that.
    let unjittered_gap = diff("plain.raw", "plain-whole.raw");
    assert!(unjittered_gap <= 0.01 + 1e-6, "{unjittered_gap}");
    assert!(diff("j5.raw", "j5-whole.raw") <= 0.01 + 1e-6);
    assert_eq!(
        diff("j0.raw", "j0-again.raw"),
        0.0,
        "--jitter alone is seed 0"
    );
    assert!(diff("j0.raw", "j5.raw") > 1e-3, "seeds differ");
    assert!(
        diff("plain.raw", "j5.raw") > 1e-3,
        "jitter is off without the flag"
    );
    // One process renders with the march engine by default: the reference's image.
    assert_eq!(diff("j5.raw", "j5-whole.raw"), 0.0);
    // The brick engine gives the same frame for any rank count.
    render("j5-bricks.raw", &["--jitter", "5", "--engine", "bricks"]);
    render("j5-ranks.raw", &["--jitter", "5", "--ranks", "3"]);
    assert!(diff("j5-bricks.raw", "j5-ranks.raw") <= 1e-6);
    assert!(diff("j5-bricks.raw", "j5-whole.raw") <= 0.01 + 1e-6);
}

#[test]
fn a_verified_orbit_repairs_what_its_predictor_misses_and_reports_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let common = [
        "render",
        "phantom:head:48",
        "--size",
        "48x40",
        "--view",
        "30,20",
    ];
    let o = pofvr(
        &[
            &common[..],
            &["--whole", "--out", "w.png", "--out-raw", "w.raw"],
        ]
        .concat(),
        d,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for predictor in ["proxy", "previous", "everything", "random:3"] {
        let o = pofvr(
            &[
                &common[..],
                &[
                    "--cull",
                    "verified",
                    "--predictor",
                    predictor,
                    "--frames",
                    "3",
                    "--orbit",
                    "0",
                    "--ranks",
                    "2",
                    "--out",
                    "v.png",
                    "--out-raw",
                    "v.raw",
                    "--stats",
                    "s.json",
                ],
            ]
            .concat(),
            d,
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let name = predictor.split(':').next().unwrap();
        assert!(
            String::from_utf8_lossy(&o.stderr).contains(&format!("predicted by {name}")),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
        let s: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.join("s.json")).unwrap()).unwrap();
        for k in 0..3 {
            let f = &s["frames"][k];
            assert_eq!(f["cull"], "verified", "{f}");
            assert_eq!(f["predictor"], name, "{f}");
            assert_eq!(f["verified"], true, "{f}");
            assert!(f["bricks"]["repaired"].as_u64().is_some(), "{f}");
            for r in f["ranks"].as_array().unwrap() {
                assert!(r["verify_ms"].as_f64().is_some(), "{r}");
                assert!(r["repair_ms"].as_f64().is_some(), "{r}");
            }
            // The threshold rule's bound on any pixel (0.95 by default).
            let raw = format!("v-{k:04}.raw");
            assert!(max_diff(&d.join(raw), &d.join("w.raw")) <= 0.05 + 1e-5);
        }
        let repaired = |k: usize| s["frames"][k]["bricks"]["repaired"].as_u64().unwrap();
        match name {
            "everything" => assert!(repaired(0) > 0),
            // The same view again: last frame's set needs (next to) no repair.
            "previous" => {
                let visible = s["frames"][1]["bricks"]["visible"].as_u64().unwrap();
                assert!(repaired(1) * 20 <= visible, "{s}");
            }
            _ => {}
        }
    }
    // Flags that do not apply are refused.
    for (args, what) in [
        (
            &["--cull", "exact", "--predictor", "proxy"][..],
            "--predictor",
        ),
        (&["--cull", "none", "--verify"][..], "--verify"),
        (
            &["--cull", "verified", "--predictor", "bogus"][..],
            "unknown predictor",
        ),
        (
            &["--cull", "verified", "--predictor", "pof"][..],
            "needs precomputed POFs",
        ),
    ] {
        let o = pofvr(&[&common[..], args, &["--out", "x.png"]].concat(), d);
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(what), "{args:?}: {err}");
    }
}
