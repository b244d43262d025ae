//! Hostile input to the `pofvr` binary: non-finite and out-of-range numbers on every flag and
//! in every JSON field that takes one, and outputs that cannot be written. Each must fail
//! with exit status 2, a message naming the flag or field, and no output file.

use std::path::Path;
use std::process::{Command, Output};

fn pofvr_cmd(args: &[&str], dir: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_pofvr"));
    c.args(args).current_dir(dir);
    c
}

fn pofvr(args: &[&str], dir: &Path) -> Output {
    pofvr_cmd(args, dir).output().expect("run pofvr")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn repo() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A render of the small phantom with `extra` flags must fail naming `needle`, and write
/// nothing.
fn rejected(extra: &[&str], needle: &str) {
    let dir = tempfile::tempdir().unwrap();
    let mut args = vec![
        "render",
        "phantom:head:16",
        "--size",
        "8x8",
        "--out",
        "o.png",
        "--quiet",
    ];
    args.extend_from_slice(extra);
    let o = pofvr(&args, dir.path());
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{extra:?}: {err}");
    assert!(
        err.contains(needle),
        "{extra:?}: expected {needle:?} in {err}"
    );
    assert!(!err.contains("panicked"), "{extra:?}: {err}");
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        0,
        "{extra:?} left a file"
    );
}

#[test]
fn non_finite_views_are_rejected_naming_the_flag() {
    for v in ["nan,0", "0,nan", "inf,0", "0,-inf", "1e400,0", "NaN,NaN"] {
        rejected(&[&format!("--view={v}")], "--view: ");
    }
    rejected(&["--view=30"], "--view: expected 2");
    rejected(&["--orbit=nan", "--frames", "2"], "--orbit");
}

#[test]
fn non_finite_and_out_of_range_settings_are_rejected_naming_the_flag() {
    for s in ["nan", "inf", "-1", "0", "1e-9", "65"] {
        rejected(&[&format!("--step={s}")], "--step: ");
    }
    for s in ["nan", "inf", "-1", "0"] {
        rejected(&[&format!("--ert={s}")], "--ert: ");
    }
    for s in ["nan", "inf", "-1", "0", "1.5"] {
        rejected(&[&format!("--cull-threshold={s}")], "--cull-threshold: ");
    }
    for w in ["nan,1", "inf,1", "-1,1", "1e40,1", "1"] {
        rejected(&[&format!("--weights={w}")], "--weights: ");
    }
}

#[test]
fn non_finite_bench_and_experiment_views_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    for args in [
        vec!["bench", "cull", "phantom:head:16", "--view=nan,0"],
        vec!["bench", "frame", "--view=0,inf"],
    ] {
        let o = pofvr(&args, dir.path());
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains("--view: "), "{args:?}: {}", stderr(&o));
    }
}

#[test]
fn bench_frame_rounds_out_of_range_are_rejected_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    for r in ["0", "101", "-1", "x"] {
        let flag = format!("--rounds={r}");
        let args = ["bench", "frame", flag.as_str()];
        let o = pofvr(&args, dir.path());
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains("--rounds"), "{args:?}: {}", stderr(&o));
    }
}

#[test]
fn bad_raw_spacing_is_rejected_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("v.raw"), [0u8; 8]).unwrap();
    let tf = repo().join("tfs/sim-isobands.json");
    for s in ["nan,1,1", "1,inf,1", "1,1,0", "-1,1,1"] {
        let o = pofvr(
            &[
                "render",
                "v.raw",
                "--dims",
                "2,2,2",
                "--dtype",
                "u8",
                &format!("--spacing={s}"),
                "--tf",
                tf.to_str().unwrap(),
                "--out",
                "o.png",
            ],
            dir.path(),
        );
        assert_eq!(o.status.code(), Some(2), "{s}: {}", stderr(&o));
        assert!(stderr(&o).contains("--spacing: "), "{s}: {}", stderr(&o));
        assert!(!dir.path().join("o.png").exists());
    }
}

const GOOD_CAMERA: &str = r#"{"projection":"orthographic","position":[8,8,40],"focal_point":[8,8,8],"view_up":[0,1,0],"parallel_scale":12,"view_angle":30,"width":8,"height":8}"#;

/// `GOOD_CAMERA` with `key` set to `value`.
fn camera_with(key: &str, value: &str) -> String {
    let mut cam: serde_json::Value = serde_json::from_str(GOOD_CAMERA).unwrap();
    cam[key] = serde_json::from_str(value).unwrap();
    cam.to_string()
}

#[test]
fn degenerate_camera_json_fields_are_rejected_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("good.json"), GOOD_CAMERA).unwrap();
    let ok = pofvr(
        &[
            "render",
            "phantom:head:16",
            "--camera",
            "good.json",
            "--out",
            "ok.png",
            "--quiet",
        ],
        dir.path(),
    );
    assert!(ok.status.success(), "{}", stderr(&ok));
    std::fs::remove_file(dir.path().join("ok.png")).unwrap();
    let cases = [
        (
            "position",
            "[8,8,8]",
            "position: must differ from focal_point",
        ),
        ("view_up", "[0,0,0]", "view_up: must not be zero"),
        ("view_up", "[0,0,1]", "view_up: must not be parallel"),
        ("view_up", "[0,0,-3]", "view_up: must not be parallel"),
        ("parallel_scale", "0", "parallel_scale: must be > 0"),
        ("parallel_scale", "-2", "parallel_scale: must be > 0"),
        ("width", "0", "width: image size"),
        ("height", "20000", "width: image size"),
        ("projection", "\"perspective\"", "GOOD"),
    ];
    for (key, value, needle) in cases {
        let text = camera_with(key, value);
        if needle == "GOOD" {
            // Perspective with the same fields is a valid camera: the checks are per
            // projection.
            std::fs::write(dir.path().join("c.json"), &text).unwrap();
            let o = pofvr(
                &[
                    "render",
                    "phantom:head:16",
                    "--camera",
                    "c.json",
                    "--out",
                    "p.png",
                    "--quiet",
                ],
                dir.path(),
            );
            assert!(o.status.success(), "{}", stderr(&o));
            std::fs::remove_file(dir.path().join("p.png")).unwrap();
            continue;
        }
        camera_rejected(dir.path(), &text, needle);
    }
    // Perspective cameras check their angle; JSON has no NaN, and a number too large for
    // f64 is a parse error, not an infinity.
    camera_rejected(
        dir.path(),
        &camera_with("projection", "\"perspective\"")
            .replace("\"view_angle\":30", "\"view_angle\":180"),
        "view_angle: must be in (0, 180)",
    );
    camera_rejected(
        dir.path(),
        &GOOD_CAMERA.replace("[8,8,40]", "[8,8,1e400]"),
        "c.json: ",
    );
    camera_rejected(
        dir.path(),
        &GOOD_CAMERA
            .replace("[8,8,40]", "[8,8,-1.7e308]")
            .replace("[8,8,8]", "[8,8,1.7e308]"),
        "position: is too far from focal_point",
    );
}

fn camera_rejected(dir: &Path, text: &str, needle: &str) {
    std::fs::write(dir.join("c.json"), text).unwrap();
    let o = pofvr(
        &[
            "render",
            "phantom:head:16",
            "--camera",
            "c.json",
            "--out",
            "o.png",
            "--quiet",
        ],
        dir,
    );
    assert_eq!(o.status.code(), Some(2), "{text}: {}", stderr(&o));
    assert!(
        stderr(&o).contains(needle) && stderr(&o).contains("c.json"),
        "{text}: expected {needle:?} in {}",
        stderr(&o)
    );
    assert!(!dir.join("o.png").exists());
}

#[test]
fn bad_tf_family_points_are_rejected_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let good =
        r#"{"bases":[{"name":"a","opacity":[[0,0],[1,0.5]]}],"color":[[0,1,1,1],[1,1,1,1]]}"#;
    let cases = [
        (
            good.replace("[1,0.5]", "[1,1.5]"),
            "bases[0].opacity[1]: alpha 1.5",
        ),
        (
            good.replace("[1,0.5]", "[1,-0.5]"),
            "bases[0].opacity[1]: alpha -0.5",
        ),
        (
            good.replace("[[0,0],[1,0.5]]", "[[1,0],[0,0.5]]"),
            "bases[0].opacity[1]: values not sorted",
        ),
        (good.replace("[1,0.5]", "[1e400,0.5]"), "tf.json: "),
        (
            good.replace("[1,1,1,1]]", "[1,1,2,1]]"),
            "color[1]: colour components",
        ),
        (
            good.replace("\"color\"", "\"weights\":[-1],\"color\""),
            "weights[0]: weight -1",
        ),
        (
            good.replace("\"color\"", "\"weights\":[1,1],\"color\""),
            "weights: got 2 weights",
        ),
        (
            good.replace("[[0,0],[1,0.5]]", "[]"),
            "bases[0].opacity: no points",
        ),
    ];
    let vol = dir.path().join("v.raw");
    std::fs::write(&vol, [0u8, 1, 2, 3, 4, 5, 6, 7]).unwrap();
    for (text, needle) in cases {
        std::fs::write(dir.path().join("tf.json"), &text).unwrap();
        let o = pofvr(
            &[
                "render", "v.raw", "--dims", "2,2,2", "--dtype", "u8", "--tf", "tf.json", "--out",
                "o.png",
            ],
            dir.path(),
        );
        assert_eq!(o.status.code(), Some(2), "{text}: {}", stderr(&o));
        assert!(
            stderr(&o).contains(needle),
            "{text}: expected {needle:?} in {}",
            stderr(&o)
        );
        assert!(!dir.path().join("o.png").exists());
    }
}

/// The temp-file names `pofvr::io` writes beside an output before renaming it.
fn leftovers(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".pofvr-") || n.ends_with(".png"))
        .collect()
}

#[test]
fn an_output_under_a_regular_file_or_in_proc_fails_naming_the_path() {
    // Tests run as root, where permission bits stop no write: a directory that cannot hold
    // files is one under a regular file (ENOTDIR) or in /proc.
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("plain"), b"x").unwrap();
    for out in ["plain/o.png", "/proc/pofvr-o.png"] {
        let o = pofvr(
            &["render", "phantom:head:16", "--size", "8x8", "--out", out],
            dir.path(),
        );
        assert_eq!(o.status.code(), Some(2), "{out}: {}", stderr(&o));
        assert!(
            stderr(&o).contains(&format!("cannot write {out}")),
            "{out}: {}",
            stderr(&o)
        );
    }
    assert_eq!(std::fs::read(dir.path().join("plain")).unwrap(), b"x");
}

#[cfg(unix)]
#[test]
fn a_write_cut_short_by_the_file_size_limit_leaves_no_partial_file() {
    use std::os::unix::process::CommandExt;
    // RLIMIT_FSIZE makes a write past the limit fail (EFBIG) as a full disk would
    // (ENOSPC), for any user and with no mount: the PNG is larger than the limit.
    let dir = tempfile::tempdir().unwrap();
    let mut cmd = pofvr_cmd(
        &[
            "render",
            "phantom:smooth-head:32",
            "--size",
            "256x256",
            "--out",
            "o.png",
            "--quiet",
        ],
        dir.path(),
    );
    // SAFETY: setrlimit and signal are async-signal-safe; nothing else runs in the child.
    unsafe {
        cmd.pre_exec(|| {
            // Without this the kernel ends the process with SIGXFSZ instead of failing the
            // write.
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            let lim = libc::rlimit {
                rlim_cur: 4096,
                rlim_max: 4096,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let o = cmd.output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("cannot write o.png") && stderr(&o).contains("large"),
        "{}",
        stderr(&o)
    );
    assert_eq!(leftovers(dir.path()), Vec::<String>::new());
}

#[cfg(unix)]
#[test]
fn a_killed_pof_build_leaves_no_pof_and_its_partial_resumes_or_is_rebuilt_to_the_same_file() {
    let dir = tempfile::tempdir().unwrap();
    let build = |out: &str, extra: &[&str]| {
        let mut args = vec![
            "pof",
            "build",
            "phantom:smooth-head:64",
            "--brick",
            "8",
            "--views",
            "12,12",
            "--quiet",
            "-o",
            out,
        ];
        args.extend_from_slice(extra);
        pofvr_cmd(&args, dir.path())
    };
    let o = build("fresh.pof", &["--no-resume"]).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let fresh = std::fs::read(dir.path().join("fresh.pof")).unwrap();

    // Killed (SIGKILL: no clean-up runs) once some bricks are in the partial file.
    let partial = dir.path().join("a.pof.partial");
    let mut child = build("a.pof", &[]).spawn().unwrap();
    let start = std::time::Instant::now();
    while std::fs::metadata(&partial).map_or(0, |m| m.len()) < 200 {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the build ended before it could be killed"
        );
        assert!(start.elapsed() < std::time::Duration::from_secs(60));
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(
        !dir.path().join("a.pof").exists(),
        "no .pof from a killed build"
    );
    let kept = std::fs::read(&partial).unwrap();
    assert!(kept.len() >= 200);

    // Resumed from the partial file: the same bytes as the uninterrupted build.
    let o = build("a.pof", &[]).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(dir.path().join("a.pof")).unwrap(), fresh);
    assert!(!partial.exists());

    // A partial file cut anywhere (inside its header, inside an entry) or overwritten is
    // rebuilt or resumed from its intact entries only, never trusted past them.
    let mut flipped = kept.clone();
    let last = flipped.len() - 3;
    flipped[last] ^= 0x55;
    for bad in [
        kept[..5].to_vec(),
        kept[..16].to_vec(),
        kept[..kept.len() - 3].to_vec(),
        flipped,
        vec![0xAB; kept.len()],
    ] {
        std::fs::remove_file(dir.path().join("a.pof")).unwrap();
        std::fs::write(&partial, &bad).unwrap();
        let o = build("a.pof", &[]).output().unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
        assert_eq!(std::fs::read(dir.path().join("a.pof")).unwrap(), fresh);
        assert!(!partial.exists());
    }
}
