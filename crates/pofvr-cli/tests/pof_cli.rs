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
