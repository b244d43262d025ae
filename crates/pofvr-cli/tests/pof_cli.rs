//! End-to-end: `pofvr pof build`, `info` and `check` on a small phantom.

use std::process::Command;

fn pofvr() -> Command {
    Command::new(env!("CARGO_BIN_EXE_pofvr"))
}

#[test]
fn pof_build_info_check_round_trip_and_rejects_corruption() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("head.pof");
    let out = pofvr()
        .args([
            "pof",
            "build",
            "phantom:head:64",
            "--views",
            "8,8",
            "--encoding",
            "u16",
            "--sets",
            "-o",
        ])
        .arg(&file)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        !dir.path().join("head.pof.partial").exists(),
        "the resume file is removed once saved"
    );

    let out = pofvr()
        .args(["pof", "info", "--json"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(out.status.success());
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(info["encoding"], "u16");
    assert_eq!(info["sets"], true);
    assert_eq!(info["views"], serde_json::json!([8, 8]));
    assert_eq!(info["core_length"], 8.0);

    let out = pofvr()
        .args(["pof", "check", "phantom:head:64", "--views", "40", "--pof"])
        .arg(&file)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains(" 0 where the lookup exceeds"), "{text}");

    // A different volume is refused, naming the file and what differs.
    let out = pofvr()
        .args(["pof", "check", "phantom:head:48", "--views", "4", "--pof"])
        .arg(&file)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("head.pof") && err.contains("volume size"),
        "{err}"
    );

    let mut bytes = std::fs::read(&file).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0xff;
    std::fs::write(&file, &bytes).unwrap();
    let out = pofvr().args(["pof", "info"]).arg(&file).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("head.pof") && err.contains("corrupted"),
        "{err}"
    );
}

#[test]
fn pof_build_method_sampled_passes_check() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("head-sampled.pof");
    let out = pofvr()
        .args([
            "pof",
            "build",
            "phantom:head:64",
            "--views",
            "12,12",
            "--method",
            "sampled",
            "-o",
        ])
        .arg(&file)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("sampled method"), "{err}");

    let out = pofvr()
        .args(["pof", "info", "--json"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(out.status.success());
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(info["method"], "sampled");
    assert_eq!(info["phases"], 2);
    let out = pofvr().args(["pof", "info"]).arg(&file).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("empirical bound"), "{text}");

    let out = pofvr()
        .args(["pof", "check", "phantom:head:64", "--views", "60", "--pof"])
        .arg(&file)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains(" 0 where the lookup exceeds"), "{text}");

    // --phases means nothing to the bound.
    let out = pofvr()
        .args([
            "pof",
            "build",
            "phantom:head:32",
            "--method",
            "bound",
            "--phases",
            "4",
            "-o",
        ])
        .arg(dir.path().join("x.pof"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--phases"));
}

/// Builds `name` in `d`: POFs of the 48³ phantom head for bricks of `brick`, 6×6 views,
/// core length `core`.
fn build_phantom_pof(d: &std::path::Path, name: &str, brick: &str, core: &str) {
    let out = pofvr()
        .current_dir(d)
        .args([
            "pof",
            "build",
            "phantom:head:48",
            "--brick",
            brick,
            "--views",
            "6,6",
            "--core-length",
            core,
            "--quiet",
            "-o",
            name,
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `pofvr render` of the 48³ phantom in `d` with `extra` arguments, the first of `pofs` as
/// `--pof` and the others as `--pof-level`, into `o.png` and `s.json`.
fn render_with_pofs(d: &std::path::Path, extra: &[&str], pofs: &[&str]) -> std::process::Output {
    let mut c = pofvr();
    c.current_dir(d).args([
        "render",
        "phantom:head:48",
        "--size",
        "48x48",
        "--view",
        "30,20",
        "--weights",
        "3,1",
        "--quiet",
        "--stats",
        "s.json",
        "--out",
        "o.png",
        "--pof",
        pofs[0],
    ]);
    c.args(extra);
    for l in &pofs[1..] {
        c.args(["--pof-level", l]);
    }
    c.output().unwrap()
}

#[test]
fn render_takes_pof_levels_and_refuses_two_of_one_core_length() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let build = |name: &str, core: &str| build_phantom_pof(d, name, "8", core);
    build("l4.pof", "4");
    build("l7.pof", "7");
    build("l4b.pof", "4");
    let render = |level: &str| render_with_pofs(d, &["--brick", "8"], &["l4.pof", level]);
    let out = render("l7.pof");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("s.json")).unwrap()).unwrap();
    assert_eq!(stats["cull"], "pof");
    std::fs::remove_file(d.join("o.png")).unwrap();
    let out = render("l4b.pof");
    assert_eq!(out.status.code(), Some(2));
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(
        e.contains("--pof-level") && e.contains("core length 4"),
        "{e}"
    );
    assert!(!d.join("o.png").exists(), "a refused render writes nothing");
}

#[test]
fn render_takes_sub_brick_pofs_beside_its_own_and_refuses_two_sub_brick_sizes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let build = |name: &str, brick: &str, core: &str| build_phantom_pof(d, name, brick, core);
    build("b16.pof", "16", "8");
    build("b8.pof", "8", "4");
    build("b8l7.pof", "8", "7");
    build("b4.pof", "4", "2");
    let render = |pofs: &[&str]| render_with_pofs(d, &[], pofs);
    for pofs in [
        &["b8.pof"][..],
        &["b8.pof", "b8l7.pof"],
        &["b16.pof", "b8.pof", "b8l7.pof"],
    ] {
        let out = render(pofs);
        assert!(
            out.status.success(),
            "{pofs:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let stats: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.join("s.json")).unwrap()).unwrap();
        assert_eq!(stats["cull"], "pof", "{pofs:?}");
        std::fs::remove_file(d.join("o.png")).unwrap();
    }
    let out = render(&["b16.pof", "b8.pof", "b4.pof"]);
    assert_eq!(out.status.code(), Some(2));
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.contains("b4.pof") && e.contains("sub-brick size"), "{e}");
    assert!(!d.join("o.png").exists(), "a refused render writes nothing");
}

#[test]
fn pof_upgrade_rewrites_an_older_layout_with_the_same_frames() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    build_phantom_pof(d, "new.pof", "16", "8");
    // An older pofvr's file: the same values, function-major, format version 3.
    let new = pofvr::pof::PofTable::open(&d.join("new.pof")).unwrap();
    let old = new.relayout(false);
    old.save(&d.join("old.pof")).unwrap();
    let mut bytes = std::fs::read(d.join("old.pof")).unwrap();
    bytes[8..12].copy_from_slice(&3u32.to_le_bytes());
    let crc = crc32fast::hash(&bytes[..252]);
    bytes[252..256].copy_from_slice(&crc.to_le_bytes());
    std::fs::write(d.join("old.pof"), &bytes).unwrap();
    let info = |f: &str| {
        let out = pofvr()
            .current_dir(d)
            .args(["pof", "info", f, "--json"])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()
    };
    assert_eq!(info("old.pof")["layout"], "function-major");
    let out = pofvr()
        .current_dir(d)
        .args(["pof", "upgrade", "old.pof", "-o", "up.pof"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(info("up.pof")["layout"], "cell-major");
    // The upgraded file is the one a fresh build writes, byte for byte.
    assert_eq!(
        std::fs::read(d.join("up.pof")).unwrap(),
        std::fs::read(d.join("new.pof")).unwrap()
    );
    let frame = |pof: &str| {
        let png = format!("{pof}.png");
        let out = pofvr()
            .current_dir(d)
            .args([
                "render",
                "phantom:head:48",
                "--cull",
                "pof",
                "--pof",
                pof,
                "--size",
                "96x96",
                "--view",
                "30,20",
                "--stats",
                &format!("{pof}.json"),
                "-o",
                &png,
            ])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let st: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.join(format!("{pof}.json"))).unwrap()).unwrap();
        (
            std::fs::read(d.join(png)).unwrap(),
            st["bricks"]["culled"].clone(),
        )
    };
    let (a, ca) = frame("old.pof");
    let (b, cb) = frame("up.pof");
    assert_eq!(ca, cb);
    assert!(a == b, "frames differ");
    // A file that is not a POF file: an error naming it, nothing written.
    std::fs::write(d.join("bad.pof"), b"not a pof file").unwrap();
    let out = pofvr()
        .current_dir(d)
        .args(["pof", "upgrade", "bad.pof", "-o", "bad-up.pof"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("bad.pof"));
    assert!(!d.join("bad-up.pof").exists());
}

/// The threshold rule of `culled` against `unculled` (raw RGBA f32 frames of `w`×`h`).
fn rule_holds(unculled: &std::path::Path, culled: &std::path::Path, w: u32, h: u32) {
    let read = |p: &std::path::Path| pofvr::Image::read_raw(p, w, h).unwrap();
    let r = pofvr::check::check_threshold_rule(&read(unculled), &read(culled), 0.95);
    assert!(r.holds(), "{}: {r}", culled.display());
}

/// `pofvr render phantom:head:48 --brick 8` at 64×56 from 30,20 with `look` (family,
/// weights) and `extra`, writing OUT.png, OUT.raw and OUT.json in `d`.
fn render_head48(
    d: &std::path::Path,
    look: &[&str],
    extra: &[&str],
    out: &str,
) -> std::process::Output {
    pofvr()
        .current_dir(d)
        .args(["render", "phantom:head:48", "--brick", "8"])
        .args(look)
        .args(["--size", "64x56", "--view", "30,20", "--quiet"])
        .args(["--out", &format!("{out}.png")])
        .args(["--out-raw", &format!("{out}.raw")])
        .args(["--stats", &format!("{out}.json")])
        .args(extra)
        .output()
        .unwrap()
}

/// Unverified `pof` and `pof-set` culls with the table `file` are refused (exit 2, the
/// file and `why` named) and write nothing.
fn assert_plain_pof_refused(
    d: &std::path::Path,
    render: &dyn Fn(&[&str], &str) -> std::process::Output,
    file: &str,
    why: &str,
) {
    for plain in [&["--pof", file][..], &["--pof", file, "--cull", "pof-set"]] {
        let o = render(plain, "plain");
        assert_eq!(o.status.code(), Some(2), "{plain:?}");
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(file) && e.contains(why), "{e}");
        assert!(!d.join("plain.png").exists() && !d.join("plain.raw").exists());
    }
}

#[test]
fn pofs_of_edited_bases_predict_verified_frames_and_plain_pof_refuses_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The phantom's family, and the same family with its bases' control points edited:
    // every opacity at 0.3×, the skin ramp moved up by 20.
    let original =
        pofvr::render::families::for_phantom(pofvr::volume::phantom::Phantom::SheppLogan);
    let mut edited = original.clone();
    for (i, b) in edited.bases.iter_mut().enumerate() {
        for p in &mut b.opacity {
            p[1] *= 0.3;
            if i == 0 {
                p[0] += 20.0;
            }
        }
    }
    std::fs::write(d.join("tf.json"), serde_json::to_string(&original).unwrap()).unwrap();
    std::fs::write(
        d.join("edited.json"),
        serde_json::to_string(&edited).unwrap(),
    )
    .unwrap();
    let out = pofvr()
        .current_dir(d)
        .args([
            "pof",
            "build",
            "phantom:head:48",
            "--tf",
            "tf.json",
            "--brick",
            "8",
        ])
        .args([
            "--views",
            "6,6",
            "--core-length",
            "4",
            "--sets",
            "--quiet",
            "-o",
            "p.pof",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let render = |extra: &[&str], out: &str| {
        render_head48(d, &["--tf", "edited.json", "--weights", "3,1"], extra, out)
    };
    let o = render(&["--whole"], "w");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Plain POF culling bounds with the table: refused, nothing written.
    assert_plain_pof_refused(d, &render, "p.pof", "bases");
    // Verified, the stale table only predicts: a warning, and the rule holds.
    for (name, args) in [
        ("pof-verify", &["--cull", "pof", "--verify"][..]),
        ("pof-set-verify", &["--cull", "pof-set", "--verify"]),
        (
            "verified-pof",
            &["--cull", "verified", "--predictor", "pof"],
        ),
        (
            "verified-pof-set",
            &["--cull", "verified", "--predictor", "pof-set"],
        ),
    ] {
        let o = render(&[&["--pof", "p.pof"][..], args].concat(), name);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{name}: {e}");
        assert!(e.contains("warning") && e.contains("bases"), "{name}: {e}");
        rule_holds(&d.join("w.raw"), &d.join(format!("{name}.raw")), 64, 56);
        let s: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.join(format!("{name}.json"))).unwrap())
                .unwrap();
        assert_eq!(s["verified"], true, "{name}: {s}");
    }
    // Any verified frame takes the table with the warning, even one whose predictor does
    // not read it (the proxy, --cull verified's own).
    let o = render(&["--pof", "p.pof", "--cull", "verified"], "proxy");
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && e.contains("warning"), "{e}");
    rule_holds(&d.join("w.raw"), &d.join("proxy.raw"), 64, 56);
}

#[test]
fn typical_pofs_predict_verified_frames_and_plain_pof_refuses_them() {
    // Typical values (a quantile, not a minimum) bound nothing: an unverified POF cull
    // with them is refused, naming the file; a verified frame takes them as its
    // predictor, without the edited-bases warning, and keeps the threshold rule.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = pofvr()
        .current_dir(d)
        .args(["pof", "build", "phantom:head:48", "--brick", "8"])
        .args([
            "--method",
            "typical",
            "--views",
            "6,6",
            "--core-length",
            "4",
        ])
        .args(["--sets", "--quiet", "-o", "t.pof"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let render = |extra: &[&str], out: &str| render_head48(d, &[], extra, out);
    let o = render(&["--whole"], "w");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_plain_pof_refused(d, &render, "t.pof", "typical");
    for (name, args) in [
        ("pof-verify", &["--cull", "pof", "--verify"][..]),
        (
            "verified-pof-set",
            &["--cull", "verified", "--predictor", "pof-set"],
        ),
    ] {
        let o = render(&[&["--pof", "t.pof"][..], args].concat(), name);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{name}: {e}");
        assert!(!e.contains("warning"), "{name}: {e}");
        rule_holds(&d.join("w.raw"), &d.join(format!("{name}.raw")), 64, 56);
    }
}
