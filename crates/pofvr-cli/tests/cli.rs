//! End-to-end tests of the `pofvr` binary: outputs, contracts and bad input.

mod common;

use common::{pofvr, stderr};
use std::path::{Path, PathBuf};
use std::process::Output;

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

#[test]
fn demo_needs_no_input() {
    let dir = tempfile::tempdir().unwrap();
    let o = pofvr(&["demo", "--n", "48"], dir.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let png = std::fs::read(dir.path().join("demo.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
}

/// Decodes an 8-bit RGBA PNG: (width, height, pixels).
fn rgba(path: &Path) -> (u32, u32, Vec<[u8; 4]>) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba);
    let px = buf[..info.buffer_size()]
        .chunks_exact(4)
        .map(|c| [c[0], c[1], c[2], c[3]])
        .collect();
    (info.width, info.height, px)
}

#[test]
fn the_demo_is_a_coloured_shaded_image_the_same_on_every_run() {
    let dir = tempfile::tempdir().unwrap();
    for out in ["a.png", "b.png"] {
        let o = pofvr(&["demo", "--n", "64", "-o", out], dir.path());
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let (w, h, px) = rgba(&dir.path().join("a.png"));
    assert_eq!((w, h), (512, 512));
    assert_eq!(
        std::fs::read(dir.path().join("a.png")).unwrap(),
        std::fs::read(dir.path().join("b.png")).unwrap(),
        "seeded jitter: reproducible"
    );
    let seen: Vec<&[u8; 4]> = px.iter().filter(|p| p[3] > 64).collect();
    assert!(
        seen.len() > px.len() / 10,
        "the head covers the frame: {} pixels",
        seen.len()
    );
    // Coloured: red and blue channels differ on most of the head.
    let coloured = seen.iter().filter(|p| p[0].abs_diff(p[2]) > 40).count();
    assert!(
        coloured > seen.len() / 2,
        "{coloured} of {} pixels coloured",
        seen.len()
    );
    // Not flat: shading and the features spread the brightness.
    let lum: Vec<f64> = seen
        .iter()
        .map(|p| f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2]))
        .collect();
    let mean = lum.iter().sum::<f64>() / lum.len() as f64;
    let sd = (lum.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / lum.len() as f64).sqrt();
    assert!(sd > 10.0, "brightness spread {sd}");
}

#[test]
fn stats_camera_and_raw_outputs_follow_the_contract() {
    let dir = tempfile::tempdir().unwrap();
    let o = pofvr(
        &[
            "render",
            "phantom:head:40",
            "--view",
            "30,-20",
            "--size",
            "40x30",
            "--out",
            "a.png",
            "--out-raw",
            "a.f32",
            "--stats",
            "s.json",
            "--camera-out",
            "cam.json",
            "--cull",
            "exact",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("s.json")).unwrap()).unwrap();
    for key in [
        "frame_ms",
        "rays",
        "pixel_rays",
        "samples",
        "samples_per_second",
    ] {
        assert!(stats[key].is_number(), "{key} missing: {stats}");
    }
    // The brick engine's rays are per brick fragment; the pixels' rays are counted apart.
    let n = |k: &str| stats[k].as_u64().unwrap();
    assert!(n("pixel_rays") > 0 && n("pixel_rays") <= 40 * 30, "{stats}");
    assert!(n("rays") > n("pixel_rays"), "{stats}");
    let e = stderr(&o);
    assert!(
        e.contains(&format!(
            "{} pixel rays ({} rays cast, one per brick fragment)",
            n("pixel_rays"),
            n("rays")
        )),
        "{e}"
    );
    for key in ["total", "empty", "non_empty", "culled", "visible"] {
        assert!(
            stats["bricks"][key].is_number(),
            "bricks.{key} missing: {stats}"
        );
    }
    for key in [
        "rank",
        "bricks_rendered",
        "samples",
        "cull_ms",
        "raycast_ms",
        "composite_ms",
        "comm_ms",
        "bytes_sent",
    ] {
        assert!(
            stats["ranks"][0][key].is_number(),
            "ranks[0].{key} missing: {stats}"
        );
    }
    assert_eq!(
        std::fs::metadata(dir.path().join("a.f32")).unwrap().len(),
        40 * 30 * 16
    );
    let cam: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("cam.json")).unwrap()).unwrap();
    assert_eq!(cam["projection"], "orthographic");
    assert_eq!(cam["width"], 40);
    // The written camera reproduces the frame exactly.
    let o = pofvr(
        &[
            "render",
            "phantom:head:40",
            "--camera",
            "cam.json",
            "--out",
            "b.png",
            "--out-raw",
            "b.f32",
            "--cull",
            "exact",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read(dir.path().join("a.f32")).unwrap(),
        std::fs::read(dir.path().join("b.f32")).unwrap()
    );
}

/// Runs a command expected to fail; checks exit code 2, the message parts, and that no
/// output file was created.
fn expect_error(dir: &Path, args: &[&str], parts: &[&str]) {
    let before = files_in(dir);
    let o = pofvr(args, dir);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
    let e = stderr(&o);
    for p in parts {
        assert!(e.contains(p), "{args:?}: message lacks {p:?}: {e}");
    }
    assert!(!e.contains("panicked"), "{e}");
    assert_eq!(files_in(dir), before, "{args:?} left files behind");
}

#[test]
fn bad_input_is_a_clear_error_and_leaves_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("short.raw"), [0u8; 100]).unwrap();
    expect_error(
        d,
        &[
            "render",
            "short.raw",
            "--dims",
            "8,8,8",
            "--dtype",
            "u8",
            "--tf",
            "x.json",
            "--out",
            "o.png",
        ],
        &["short.raw", "expected 512", "got 100"],
    );
    expect_error(
        d,
        &[
            "render",
            "short.raw",
            "--dims",
            "5,5,5",
            "--dtype",
            "u8",
            "--out",
            "o.png",
        ],
        &["short.raw", "expected 125", "got 100"],
    );
    expect_error(
        d,
        &["info", "short.raw", "--dims", "0,5,5", "--dtype", "u8"],
        &["short.raw", "at least 1"],
    );
    expect_error(
        d,
        &[
            "info",
            "short.raw",
            "--dims",
            "4000000000,4000000000,4000000000",
            "--dtype",
            "u8",
        ],
        &["short.raw", "overflow"],
    );
    expect_error(
        d,
        &["info", "short.raw", "--dims", "10,10,1", "--dtype", "u12"],
        &["--dtype", "u12"],
    );
    std::fs::write(
        d.join("tf.json"),
        r#"{"bases":[{"name":"a","opacity":[[10,0.1],[5,0.2]]}],"color":[[0,1,1,1]]}"#,
    )
    .unwrap();
    expect_error(
        d,
        &[
            "render",
            "phantom:head:16",
            "--tf",
            "tf.json",
            "--out",
            "o.png",
        ],
        &["tf.json", "bases[0].opacity[1]", "sorted"],
    );
    std::fs::write(
        d.join("tf.json"),
        r#"{"bases":[{"name":"a","opacity":[[0,1.2]]}],"color":[[0,1,1,1]]}"#,
    )
    .unwrap();
    expect_error(
        d,
        &[
            "render",
            "phantom:head:16",
            "--tf",
            "tf.json",
            "--out",
            "o.png",
        ],
        &["tf.json", "outside [0, 1]"],
    );
    expect_error(
        d,
        &[
            "render",
            "phantom:head:16",
            "--weights",
            "1,-1",
            "--out",
            "o.png",
        ],
        &["--weights", "weights[1]"],
    );
    expect_error(
        d,
        &[
            "render",
            "phantom:head:16",
            "--weights",
            "1",
            "--out",
            "o.png",
        ],
        &["--weights", "expected one per basis"],
    );
    std::fs::write(
        d.join("v.nhdr"),
        "NRRD0004\ntype: uint8\ndimension: 3\nencoding: raw\ndata file: short.raw\n",
    )
    .unwrap();
    expect_error(d, &["info", "v.nhdr"], &["v.nhdr", "sizes"]);
    let o = pofvr(
        &[
            "render",
            "phantom:head:16",
            "--out",
            "/nonexistent-dir/o.png",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("/nonexistent-dir/o.png"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn f32_data_with_nan_is_rejected_naming_the_voxel() {
    let dir = tempfile::tempdir().unwrap();
    let mut v = [0.5f32; 27];
    v[13] = f32::NAN;
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    std::fs::write(dir.path().join("nan.raw"), bytes).unwrap();
    expect_error(
        dir.path(),
        &["info", "nan.raw", "--dims", "3,3,3", "--dtype", "f32"],
        &["nan.raw", "NaN", "index 13"],
    );
}

/// The catalogue's directory: `$POFVR_DATA` when set, else `shared/data` beside the
/// repository. The tests that call it are `#[ignore]`d; run with `--ignored` without the
/// data, they fail naming the directory instead of passing without having checked anything.
fn shared_data() -> PathBuf {
    let dir = match std::env::var_os("POFVR_DATA") {
        Some(d) => PathBuf::from(d),
        None => repo().join("../shared/data"),
    };
    assert!(
        dir.join("CATALOG.md").is_file(),
        "this test needs the real volumes: {} has no CATALOG.md (set POFVR_DATA to the \
         catalogue's directory, or run the tests without --ignored)",
        dir.display()
    );
    dir
}

/// One render of each catalogued real volume with its family.
#[test]
#[ignore = "needs ../shared/data (real volumes)"]
fn every_real_volume_renders() {
    let data = shared_data();
    let cases = [
        ("neghip/neghip.nhdr", "sim-isobands.json"),
        ("ironprot/ironprot.nhdr", "sim-isobands.json"),
        ("hydrogen/hydrogen.nhdr", "sim-hydrogen.json"),
        (
            "headsq_quarter/headsq_quarter.mhd",
            "ct-head-skin-bone.json",
        ),
        (
            "lidc2_ct_chest/lidc2_ct_chest.nhdr",
            "ct-chest-skin-bone.json",
        ),
        ("ch2better_mri/source/ch2better.nii.gz", "mri-brain.json"),
    ];
    let dir = tempfile::tempdir().unwrap();
    for (vol, tf) in cases {
        let v = data.join(vol);
        let t = repo().join("tfs").join(tf);
        let o = pofvr(
            &[
                "render",
                v.to_str().unwrap(),
                "--tf",
                t.to_str().unwrap(),
                "--size",
                "96x96",
                "--out",
                "r.png",
                "--stats",
                "s.json",
            ],
            dir.path(),
        );
        assert!(o.status.success(), "{vol}: {}", stderr(&o));
        let stats: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.path().join("s.json")).unwrap()).unwrap();
        assert!(
            stats["samples"].as_u64().unwrap() > 0,
            "{vol} rendered nothing"
        );
    }
}

#[test]
fn an_error_names_its_cause_once() {
    let dir = tempfile::tempdir().unwrap();
    let o = pofvr(&["info", "no-such-volume.nhdr"], dir.path());
    assert_eq!(o.status.code(), Some(2));
    let e = stderr(&o);
    assert!(e.contains("no-such-volume.nhdr"), "{e}");
    let cause = "No such file or directory";
    assert_eq!(e.matches(cause).count(), 1, "{e}");
}

/// `bench cull` on a small phantom, one repetition, with `extra` arguments: its output and
/// its report.
fn bench_cull(d: &Path, extra: &[&str]) -> (Output, serde_json::Value) {
    let mut args = vec![
        "bench",
        "cull",
        "phantom:head:48",
        "--size",
        "64x64",
        "--reps",
        "1",
        "--quiet",
        "--out",
        "b.json",
    ];
    args.extend_from_slice(extra);
    let o = pofvr(&args, d);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = serde_json::from_slice(&std::fs::read(d.join("b.json")).unwrap()).unwrap();
    (o, r)
}

#[test]
fn bench_cull_sweep_and_ideal_report_each_view_and_their_mean_and_worst() {
    let dir = tempfile::tempdir().unwrap();
    let (o, r) = bench_cull(dir.path(), &["--sweep", "3", "--ideal"]);
    let views = r["sweep"]["views"].as_array().unwrap();
    assert_eq!(views.len(), 3, "{r}");
    let f = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap_or_else(|| panic!("{k} in {v}"));
    let gaps: Vec<f64> = views
        .iter()
        .map(|v| {
            for k in [
                "culled_fraction_pof",
                "culled_fraction_pof_set",
                "culled_fraction_exact",
            ] {
                assert!((0.0..=1.0).contains(&f(v, k)), "{k} in {v}");
            }
            for k in ["balance_32", "balance_32_replicas_2"] {
                assert!(f(v, k) >= 1.0, "{k} in {v}");
            }
            100.0 * (f(v, "culled_fraction_exact") - f(v, "culled_fraction_pof"))
        })
        .collect();
    let s = &r["sweep"]["points_below_exact_pof"];
    let mean = gaps.iter().sum::<f64>() / 3.0;
    let worst = gaps.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    assert!((f(s, "mean") - mean).abs() < 1e-9, "{s} vs {gaps:?}");
    assert!((f(s, "worst") - worst).abs() < 1e-9, "{s} vs {gaps:?}");
    assert!(
        f(&r["sweep"]["points_below_exact_ideal"], "mean").is_finite(),
        "{r}"
    );
    assert!(r["ideal"]["culled"].as_u64().is_some(), "{r}");
    let b = &r["sweep"]["balance_32"];
    assert!(f(b, "worst") >= f(b, "mean"), "{b}");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("sweep load balance at 32 ranks (1 replica)"),
        "{text}"
    );
}

#[test]
fn bench_cull_reports_every_case_and_each_target_in_one_run() {
    let dir = tempfile::tempdir().unwrap();
    let targets = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../benches/targets/cull.json"
    );
    let (o, r) = bench_cull(dir.path(), &["--targets", targets]);
    let cases = r["cases"].as_array().unwrap();
    for (mode, ranks, replicas) in [
        ("none", 1, 1),
        ("pof", 1, 1),
        ("pof-set", 1, 1),
        ("exact", 1, 1),
        ("pof", 2, 1),
        ("pof", 8, 1),
        ("pof", 8, 2),
        ("pof", 32, 1),
        ("pof", 32, 2),
    ] {
        let c = cases
            .iter()
            .find(|c| c["mode"] == mode && c["ranks"] == ranks && c["replicas"] == replicas)
            .unwrap_or_else(|| panic!("no case {mode} {ranks} {replicas}: {r}"));
        for key in [
            "median_frame_ms",
            "max_cull_ms",
            "cull_share_of_frame",
            "culled_fraction",
            "load_balance_max_over_mean_samples",
            "max_verify_ms",
            "max_repair_ms",
        ] {
            assert!(c[key].as_f64().is_some(), "{key} in {c}");
        }
        for key in ["repaired", "samples"] {
            assert!(c[key].as_u64().is_some(), "{key} in {c}");
        }
    }
    let targets = r["targets"].as_array().unwrap();
    assert_eq!(targets.len(), 6, "{r}");
    for t in targets {
        let (m, goal) = (
            t["measured"].as_f64().unwrap(),
            t["target"].as_f64().unwrap(),
        );
        let at_most = t["at_most"].as_bool().unwrap();
        assert_eq!(
            t["met"].as_bool().unwrap(),
            if at_most { m <= goal } else { m >= goal },
            "{t}"
        );
    }
    let speedup = r["speedup_pof_vs_none"].as_f64().unwrap();
    let t = targets
        .iter()
        .find(|t| t["what"].as_str().unwrap().contains("speed-up"))
        .unwrap();
    assert_eq!(t["measured"].as_f64().unwrap(), speedup);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("target load balance at 32 ranks (2 replicas)"),
        "{text}"
    );
}

#[test]
fn bench_frame_without_the_peer_reports_vtk_not_measured_and_every_engine() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = pofvr(
        &[
            "bench",
            "frame",
            "--volume",
            "phantom:head:24",
            "--volume",
            "phantom:smooth-head:20",
            "--view",
            "30,20",
            "--size",
            "40x32",
            "--reps",
            "1",
            "--rounds",
            "2",
            "--json",
            "f.json",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("VTK not measured: no peer"), "{out}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("f.json")).unwrap()).unwrap();
    assert_eq!(r["image"], serde_json::json!([40, 32]));
    assert_eq!(
        (r["reps"].as_u64(), r["rounds"].as_u64()),
        (Some(1), Some(2))
    );
    assert_eq!(
        r["engines"],
        serde_json::json!(["whole", "bricks", "march"])
    );
    let cases = r["cases"].as_array().unwrap();
    // Two volumes, one view, unshaded and shaded.
    assert_eq!(cases.len(), 4);
    for c in cases {
        for k in [
            "volume",
            "view",
            "shade",
            "rays",
            "min_samples_per_ray",
            "cell_floor_samples_per_ray",
            "engines",
            "vtk",
        ] {
            assert!(c.get(k).is_some(), "case lacks {k}: {c}");
        }
        assert_eq!(c["vtk"]["measured"], false);
        assert!(c["vtk"]["reason"]
            .as_str()
            .unwrap()
            .contains("--peer-python"));
        assert!(c["vtk"]["median_ms"].is_null() && c["vtk"]["psnr_db"].is_null());
        assert_eq!(c["vtk"]["round_ms"], serde_json::json!([]));
        let min = c["min_samples_per_ray"].as_f64().unwrap();
        assert!(min > 0.0);
        let floor = c["cell_floor_samples_per_ray"].as_f64().unwrap();
        assert!(floor >= min, "floor {floor} below the minimum {min}");
        let engines = c["engines"].as_array().unwrap();
        assert_eq!(engines.len(), 3);
        for e in engines {
            for k in [
                "engine",
                "median_ms",
                "round_ms",
                "samples",
                "samples_per_ray",
                "samples_over_minimum",
                "samples_over_cell_floor",
                "max_abs_diff_vs_whole",
                "vtk_over_pofvr",
                "samples_per_s_per_core",
                "march_steps",
                "core_ns_per_step",
            ] {
                assert!(e.get(k).is_some(), "engine lacks {k}: {e}");
            }
            // Only the march engine's packets take steps, and a step costs time.
            let steps = e["march_steps"].as_u64().unwrap();
            if e["engine"] != "march" {
                assert_eq!(steps, 0, "{e}");
            }
            assert_eq!(e["core_ns_per_step"].is_null(), steps == 0, "{e}");
            if steps > 0 {
                assert!(e["core_ns_per_step"].as_f64().unwrap() > 0.0, "{e}");
            }
            assert!(e["vtk_over_pofvr"].is_null());
            // One median per round, and the frame's median among them.
            let rounds: Vec<f64> = e["round_ms"]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            assert_eq!(rounds.len(), 2, "{e}");
            assert!(rounds.contains(&e["median_ms"].as_f64().unwrap()), "{e}");
            assert!(e["samples_per_s_per_core"].as_f64().unwrap() > 0.0, "{e}");
            // No engine takes fewer samples than the minimum.
            assert!(e["samples_per_ray"].as_f64().unwrap() >= min, "{e}");
        }
    }
    // A peer that cannot run is a reason, never a number.
    let o = pofvr(
        &[
            "bench",
            "frame",
            "--volume",
            "phantom:head:16",
            "--view",
            "0,0",
            "--size",
            "16x16",
            "--reps",
            "1",
            "--json",
            "g.json",
            "--peer-python",
            "/nonexistent/python",
            "--peer-script",
            "/nonexistent/vtk_render.py",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("g.json")).unwrap()).unwrap();
    let vtk = &r["cases"][0]["vtk"];
    assert_eq!(vtk["measured"], false);
    assert!(
        vtk["reason"]
            .as_str()
            .unwrap()
            .contains("/nonexistent/python"),
        "{vtk}"
    );
}

#[test]
fn the_engine_is_march_by_default_for_one_process_and_equals_whole() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let common = [
        "render",
        "phantom:head:40",
        "--size",
        "40x30",
        "--view",
        "30,20",
    ];
    let run = |extra: &[&str], name: &str| {
        let mut args = common.to_vec();
        let raw = format!("{name}.raw");
        let stats = format!("{name}.json");
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--out", "o.png", "--out-raw", &raw, "--stats", &stats]);
        let o = pofvr(&args, d);
        assert!(o.status.success(), "{extra:?}: {}", stderr(&o));
        let s: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.join(&stats)).unwrap()).unwrap();
        (std::fs::read(d.join(&raw)).unwrap(), s)
    };
    let (march, s) = run(&[], "march");
    assert_eq!(s["engine"], "march", "{s}");
    assert!(s["samples_per_ray"].as_f64().unwrap() > 0.0, "{s}");
    assert!(s["skipped_samples"].as_u64().unwrap() > 0, "{s}");
    assert!(s["occupancy_ms"].is_number(), "{s}");
    let simd = s["march_simd"].as_str().unwrap_or_default();
    let steps = s["march_steps"].as_u64().unwrap();
    assert_eq!(steps > 0, ["avx512", "avx2"].contains(&simd), "{s}");
    assert!(
        ["avx512", "avx2", "walk-avx2", "sse2", "scalar"].contains(&simd),
        "{s}"
    );
    let (whole, w) = run(&["--whole"], "whole");
    assert_eq!(w["engine"], "whole", "{w}");
    assert!(w["march_simd"].is_null(), "{w}");
    assert_eq!(march, whole, "the march image is the --whole image");
    assert!(s["samples_per_ray"].as_f64() < w["samples_per_ray"].as_f64());
    // Prefetching: off by itself for 64 KB of voxels, and no other engine's; forced on, the
    // packet loops run it and the image stays the same.
    assert_eq!(w["march_prefetch"], false, "{w}");
    if std::env::var_os("POFVR_PREFETCH").is_none() {
        assert_eq!(s["march_prefetch"], false, "{s}");
    }
    // The default march frame with one switch set in the environment.
    let run_env = |key: &str, value: &str| {
        let (raw, stats) = (format!("{key}-{value}.raw"), format!("{key}-{value}.json"));
        let mut args = common.to_vec();
        args.extend_from_slice(&["--out", "o.png", "--out-raw", &raw, "--stats", &stats]);
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_pofvr"))
            .args(&args)
            .current_dir(d)
            .env(key, value)
            .output()
            .unwrap();
        assert!(o.status.success(), "{key}={value}: {}", stderr(&o));
        let s: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.join(&stats)).unwrap()).unwrap();
        (std::fs::read(d.join(&raw)).unwrap(), s)
    };
    let (pf, p) = run_env("POFVR_PREFETCH", "on");
    assert_eq!(p["march_prefetch"], steps > 0, "{p}");
    assert_eq!(pf, march, "prefetching changes no pixel");
    // Gathers: on or off as asked, where a packet loop runs (sixteen lanes or eight: the
    // same `steps > 0` as above), and never another engine's; the image is the same
    // either way. (This read "the sixteen-lane loop" until stop 46, whose AVX2-only CI
    // core showed that the eight-lane loop's gathers, since stop 41, had been left out.)
    assert_eq!(w["march_gather"], false, "{w}");
    assert!(!s["march_gather"].as_bool().unwrap() || steps > 0, "{s}");
    for on in ["on", "off"] {
        let (g, gs) = run_env("POFVR_GATHER", on);
        assert_eq!(gs["march_gather"], on == "on" && steps > 0, "{gs}");
        assert_eq!(g, march, "POFVR_GATHER={on} changes no pixel");
    }
    // The blocked copy: off by itself for 64 KB of voxels; forced on, copied on the first
    // frame (timed) and read by the eight-ray packets where they run; never another
    // engine's; the image is the same either way.
    assert_eq!(w["march_blocks"], false, "{w}");
    assert_eq!(w["blocks_ms"], 0.0, "{w}");
    if std::env::var_os("POFVR_BLOCKS").is_none() {
        assert_eq!(s["march_blocks"], false, "{s}");
        assert_eq!(s["blocks_ms"], 0.0, "{s}");
    }
    for on in ["on", "off"] {
        let (g, gs) = run_env("POFVR_BLOCKS", on);
        let eights = gs["march_simd"] == "avx2";
        assert_eq!(gs["march_blocks"], on == "on" && eights, "{gs}");
        assert_eq!(gs["blocks_ms"].as_f64().unwrap() > 0.0, on == "on", "{gs}");
        assert_eq!(g, march, "POFVR_BLOCKS={on} changes no pixel");
    }
    let (_, b) = run(&["--engine", "bricks"], "bricks");
    assert_eq!(b["engine"], "bricks", "{b}");
    let (_, c) = run(&["--cull", "exact"], "culled");
    assert_eq!(c["engine"], "bricks", "{c}");
    for (extra, flag) in [
        (
            &["--engine", "march", "--cull", "exact"][..],
            "--cull exact",
        ),
        (&["--engine", "march", "--ranks", "2"][..], "--ranks 2"),
        (&["--engine", "vtk"][..], "--engine"),
    ] {
        let mut args = common.to_vec();
        args.extend_from_slice(extra);
        let o = pofvr(&args, d);
        assert!(!o.status.success(), "{extra:?}");
        assert!(stderr(&o).contains(flag), "{extra:?}: {}", stderr(&o));
    }
}
