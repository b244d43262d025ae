//! End-to-end tests of the data inputs: the body phantom, DICOM series, Zarr stores and
//! `pofvr convert`.

mod common;

use common::{pofvr, stderr};
use std::path::Path;
use std::process::Output;

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Runs `args`, expects a failure whose message has every one of `parts`, and no file left
/// in `dir` other than those in `keep`.
fn expect_error(dir: &Path, args: &[&str], parts: &[&str], keep: &[&str]) {
    let o = pofvr(args, dir);
    assert!(!o.status.success(), "{args:?} should fail");
    let e = stderr(&o);
    for p in parts {
        assert!(e.contains(p), "{args:?}: error {e:?} lacks {p:?}");
    }
    assert!(!e.contains("panicked"), "{args:?} panicked: {e}");
    let mut left: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| !keep.contains(&n.as_str()))
        .collect();
    left.sort();
    assert!(left.is_empty(), "{args:?} left {left:?}");
}

#[test]
fn the_body_phantom_takes_any_grid_and_renders_with_its_family() {
    let dir = tempfile::tempdir().unwrap();
    let o = pofvr(&["info", "phantom:body:40x32x72"], dir.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let out = stdout(&o);
    assert!(out.contains("40 × 32 × 72"), "{out}");
    assert!(out.contains("i16"), "{out}");
    let o = pofvr(
        &[
            "render",
            "phantom:body:40x40x72",
            "--size",
            "48x48",
            "--shade",
            "-o",
            "b.png",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(dir.path().join("b.png").exists());
    expect_error(
        dir.path(),
        &["info", "phantom:head:8x8x8"],
        &["phantom:head:8x8x8", "cube"],
        &["b.png"],
    );
    expect_error(
        dir.path(),
        &["info", "phantom:body:8x8"],
        &["phantom:body:8x8", "XxYxZ"],
        &["b.png"],
    );
}

#[test]
fn a_dicom_folder_renders_and_several_series_need_series() {
    use pofvr::volume::dicom_write::{write_series, SeriesOptions};
    let dir = tempfile::tempdir().unwrap();
    let vol = pofvr::volume::phantom::Phantom::Body.generate_dims([32, 32, 40]);
    let ct = dir.path().join("ct");
    let opts = SeriesOptions {
        intercept: -1024,
        ..SeriesOptions::default()
    };
    write_series(&vol, &ct, &opts).unwrap();
    let o = pofvr(&["info", "ct"], dir.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let out = stdout(&o);
    assert!(out.contains("32 × 32 × 40") && out.contains("i16"), "{out}");
    let tf = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tfs/ct-chest-skin-bone.json");
    let tf = tf.to_str().unwrap();
    let o = pofvr(
        &[
            "render", "ct", "--tf", tf, "--size", "32x32", "-o", "ct.png",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    // A second series in the same folder: an error listing both, then --series picks one.
    let other = SeriesOptions {
        series_uid: "1.2.3.99".into(),
        ..SeriesOptions::default()
    };
    let tmp = dir.path().join("tmp");
    write_series(&vol, &tmp, &other).unwrap();
    for e in std::fs::read_dir(&tmp).unwrap() {
        let p = e.unwrap().path();
        let name = format!("b_{}", p.file_name().unwrap().to_string_lossy());
        std::fs::rename(&p, ct.join(name)).unwrap();
    }
    std::fs::remove_dir(&tmp).unwrap();
    expect_error(
        dir.path(),
        &["info", "ct"],
        &["ct", "SeriesInstanceUID", "1.2.3.99", "2 series"],
        &["ct", "ct.png"],
    );
    let o = pofvr(&["info", "ct", "--series", "1.2.3.99"], dir.path());
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn convert_writes_ome_zarr_that_every_command_opens() {
    let dir = tempfile::tempdir().unwrap();
    let o = pofvr(
        &["convert", "phantom:body:80x72x150", "body.zarr", "--quiet"],
        dir.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(dir.path().join("body.zarr/zarr.json").is_file());
    assert!(dir.path().join("body.zarr/1/zarr.json").is_file());
    let info = |args: &[&str]| {
        let o = pofvr(args, dir.path());
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        stdout(&o)
    };
    let full = info(&["info", "body.zarr"]);
    assert!(
        full.contains("80 × 72 × 150") && full.contains("i16"),
        "{full}"
    );
    // The same voxels as the phantom: the same histogram lines.
    let phantom = info(&["info", "phantom:body:80x72x150"]);
    let hist = |s: &str| {
        s.lines()
            .filter(|l| l.contains('%'))
            .map(str::to_string)
            .collect::<Vec<_>>()
    };
    assert_eq!(hist(&full), hist(&phantom));
    let half = info(&["info", "body.zarr", "--level", "1"]);
    assert!(half.contains("40 × 36 × 75"), "{half}");
    let arr = info(&["info", "body.zarr/1"]);
    assert!(arr.contains("40 × 36 × 75"), "{arr}");
    // render picks the level from the image size: a 32² image needs no more than 64 voxels.
    let tf = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tfs/ct-chest-skin-bone.json");
    let o = pofvr(
        &[
            "render",
            "body.zarr",
            "--tf",
            tf.to_str().unwrap(),
            "--size",
            "32x32",
            "-o",
            "z.png",
            "--stats",
            "s.json",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    // Level 2 (20×18×38) is the finest with every axis ≤ 64: 2×2×3 bricks of 16³.
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("s.json")).unwrap()).unwrap();
    assert_eq!(stats["bricks"]["total"], 12, "{stats}");
    // An existing output is refused; a bad store is a clear error.
    expect_error(
        dir.path(),
        &["convert", "phantom:body:8x8x8", "body.zarr"],
        &["body.zarr", "exists"],
        &["body.zarr", "z.png", "s.json"],
    );
    std::fs::remove_file(dir.path().join("body.zarr/0/c/0/0/0")).unwrap();
    expect_error(
        dir.path(),
        &["info", "body.zarr"],
        &["body.zarr/0/c/0/0/0", "missing"],
        &["body.zarr", "z.png", "s.json"],
    );
    expect_error(
        dir.path(),
        &["convert", "phantom:body:8x8x8", "nodir/x.zarr"],
        &["nodir"],
        &["body.zarr", "z.png", "s.json"],
    );
}

#[test]
fn a_zarr_level_larger_than_the_budget_renders_from_chunks_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let o = pofvr(
        &["convert", "phantom:body:160x128x200", "b.zarr", "--quiet"],
        dir.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let tf = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tfs/ct-chest-skin-bone.json");
    let tf = tf.to_str().unwrap();
    let render = |extra: &[&str], raw: &str, stats: &str| {
        let mut args = vec![
            "render",
            "b.zarr",
            "--level",
            "0",
            "--tf",
            tf,
            "--size",
            "48x48",
            "-o",
            "f.png",
            "--out-raw",
            raw,
            "--stats",
            stats,
            "--cull",
            "verified",
        ];
        args.extend_from_slice(extra);
        let o = pofvr(&args, dir.path());
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        let s: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join(stats)).unwrap())
                .unwrap();
        (std::fs::read(dir.path().join(raw)).unwrap(), s)
    };
    // The level is 8.2 MB in 24 chunks of 64³ (512 KB decoded): a 4 MB budget holds four
    // decoded chunks and 2 MB of bricks, so neither fits.
    let (want, _) = render(&["--engine", "bricks"], "a.raw", "a.json");
    for ranks in ["1", "3"] {
        let (got, s) = render(
            &["--memory-budget", "4M", "--ranks", ranks],
            &format!("b{ranks}.raw"),
            &format!("b{ranks}.json"),
        );
        assert!(got == want, "{ranks} ranks: the budgeted frame differs");
        let m = &s["memory_budget"];
        assert_eq!(m["source"], "zarr chunks", "{s}");
        assert!(
            m["zarr_chunks"]["chunk_evictions"].as_u64().unwrap() > 0,
            "{s}"
        );
        // Bricks that do not fit are evicted or, once the frame's own fill the cache,
        // read past it.
        let c = &m["cache"];
        let evicted = c["evictions"].as_u64().unwrap() + c["not_cached"].as_u64().unwrap();
        assert!(evicted > 0, "{s}");
        assert!(c["bytes_read"].as_u64().unwrap() > 0, "{s}");
        // Read chunk by chunk, the bricks are dealt by chunks; asked, along the curve: the
        // same frame either way.
        assert_eq!(s["deal"], "chunks", "{s}");
        let (curve, s) = render(
            &["--memory-budget", "4M", "--ranks", ranks, "--deal", "curve"],
            &format!("c{ranks}.raw"),
            &format!("c{ranks}.json"),
        );
        assert!(
            curve == want,
            "{ranks} ranks dealt along the curve: the frame differs"
        );
        assert_eq!(s["deal"], "curve", "{s}");
    }
    // Without a budget the level is decoded whole: no chunks to deal by.
    let (_, s) = render(&["--ranks", "2"], "d.raw", "d.json");
    assert_eq!(s["deal"], "curve", "{s}");
    let o = pofvr(
        &[
            "render", "b.zarr", "--level", "0", "--tf", tf, "--size", "48x48", "-o", "e.png",
            "--ranks", "2", "--deal", "chunks",
        ],
        dir.path(),
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("--deal chunks") && e.contains("b.zarr"), "{e}");
    assert!(!dir.path().join("e.png").exists());
    // The whole-volume pass cannot run from chunks: a clear error, exit code 2, no image.
    let o = pofvr(
        &[
            "render",
            "b.zarr",
            "--level",
            "0",
            "--tf",
            tf,
            "--size",
            "48x48",
            "-o",
            "w.png",
            "--memory-budget",
            "4M",
            "--whole",
        ],
        dir.path(),
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("b.zarr") && e.contains("memory budget"), "{e}");
    assert!(!dir.path().join("w.png").exists());
}

/// `pofvr ARGS` must fail with exit status 2, a message holding every one of `parts`, no
/// panic, and leave nothing in `dir` but `keep`.
fn expect_exit_2(dir: &Path, args: &[&str], parts: &[&str], keep: &[&str]) {
    let o = pofvr(args, dir);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
    expect_error(dir, args, parts, keep);
}

#[test]
fn damaged_dicom_slices_are_errors_naming_the_file_and_tag() {
    use pofvr::volume::dicom_write::{write_series, SeriesOptions};
    let vol = pofvr::volume::phantom::Phantom::Body.generate_dims([24, 20, 12]);
    let tf = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tfs/ct-chest-skin-bone.json");
    let tf = tf.to_str().unwrap();
    let render = ["render", "ct", "--tf", tf, "--size", "16x16", "-o", "o.png"];
    // Truncated pixel data.
    let dir = tempfile::tempdir().unwrap();
    let ct = dir.path().join("ct");
    write_series(&vol, &ct, &SeriesOptions::default()).unwrap();
    let slice = ct.join("slice_0005.dcm");
    let bytes = std::fs::read(&slice).unwrap();
    std::fs::write(&slice, &bytes[..bytes.len() - 100]).unwrap();
    expect_exit_2(
        dir.path(),
        &render,
        &["slice_0005.dcm", "PixelData"],
        &["ct"],
    );
    // BitsAllocated 32 (explicit VR little endian: tag, "US", length 2, value).
    let dir = tempfile::tempdir().unwrap();
    let ct = dir.path().join("ct");
    write_series(&vol, &ct, &SeriesOptions::default()).unwrap();
    let slice = ct.join("slice_0003.dcm");
    let mut bytes = std::fs::read(&slice).unwrap();
    let tag = [0x28, 0x00, 0x00, 0x01, b'U', b'S', 0x02, 0x00, 0x10, 0x00];
    let at = bytes
        .windows(tag.len())
        .position(|w| w == tag)
        .expect("BitsAllocated 16 in the slice");
    bytes[at + 8] = 0x20;
    std::fs::write(&slice, &bytes).unwrap();
    expect_exit_2(
        dir.path(),
        &render,
        &["slice_0003.dcm", "BitsAllocated", "32"],
        &["ct"],
    );
}

#[test]
fn damaged_zarr_stores_are_errors_naming_the_file_with_or_without_a_budget() {
    let dir = tempfile::tempdir().unwrap();
    let o = pofvr(
        &["convert", "phantom:body:80x72x150", "b.zarr", "--quiet"],
        dir.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let tf = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tfs/ct-chest-skin-bone.json");
    let tf = tf.to_str().unwrap();
    let render = |budget: &'static str| -> Vec<&str> {
        let mut v = vec![
            "render", "b.zarr", "--level", "0", "--tf", tf, "--size", "16x16", "-o", "o.png",
        ];
        if !budget.is_empty() {
            v.extend(["--memory-budget", budget]);
        }
        v
    };
    let keep = ["b.zarr"];
    // A missing chunk: decoded whole, or on demand under a budget.
    let chunk = dir.path().join("b.zarr/0/c/1/0/1");
    let saved = std::fs::read(&chunk).unwrap();
    std::fs::remove_file(&chunk).unwrap();
    for budget in ["", "256K"] {
        expect_exit_2(
            dir.path(),
            &render(budget),
            &["b.zarr/0/c/1/0/1", "missing"],
            &keep,
        );
    }
    // A corrupt chunk.
    std::fs::write(&chunk, &saved[..saved.len() / 2]).unwrap();
    for budget in ["", "256K"] {
        expect_exit_2(dir.path(), &render(budget), &["b.zarr/0/c/1/0/1"], &keep);
    }
    std::fs::write(&chunk, &saved).unwrap();
    // A bad zarr.json, at the array and at the group.
    let meta = dir.path().join("b.zarr/0/zarr.json");
    let good = std::fs::read_to_string(&meta).unwrap();
    std::fs::write(&meta, &good[..good.len() / 2]).unwrap();
    for budget in ["", "256K"] {
        expect_exit_2(
            dir.path(),
            &render(budget),
            &["b.zarr/0/zarr.json", "not JSON"],
            &keep,
        );
    }
    std::fs::write(&meta, good.replace("int16", "int64")).unwrap();
    expect_exit_2(
        dir.path(),
        &render("256K"),
        &["b.zarr/0/zarr.json", "data_type"],
        &keep,
    );
    std::fs::write(&meta, &good).unwrap();
    std::fs::write(dir.path().join("b.zarr/zarr.json"), "{\"node_type\": 7}").unwrap();
    expect_exit_2(
        dir.path(),
        &render(""),
        &["b.zarr/zarr.json", "node_type"],
        &keep,
    );
}
