//! `pofvr experiment --quick` on the phantom: every file is written, every SVG parses, the
//! CSV numbers agree with what `pofvr render --stats` reports for the same view and mode,
//! and the conservativeness audit finds no pixel breaking the rule.

mod common;

use common::{pofvr, stderr};
use std::collections::HashMap;
use std::path::Path;

const VOLUME: &str = "phantom:head:64";
const SIZE: &str = "96x96";

/// A CSV file as rows of column → cell.
fn read_csv(path: &Path) -> Vec<HashMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            assert_eq!(cells.len(), header.len(), "{}: {l}", path.display());
            header
                .iter()
                .cloned()
                .zip(cells.iter().map(|c| (*c).to_string()))
                .collect()
        })
        .collect()
}

fn num(row: &HashMap<String, String>, col: &str) -> f64 {
    row[col]
        .parse()
        .unwrap_or_else(|_| panic!("{col} = {:?} is not a number", row[col]))
}

/// `pofvr render --stats` for one view, mode and weights (POF modes read `head.pof`).
fn render_stats(dir: &Path, view: &str, cull: &str, weights: Option<&str>) -> serde_json::Value {
    let mut args = vec![
        "render", VOLUME, "--view", view, "--size", SIZE, "--cull", cull, "--out", "r.png",
        "--stats", "r.json",
    ];
    if cull.starts_with("pof") {
        args.extend(["--pof", "head.pof"]);
    }
    if let Some(w) = weights {
        args.extend(["--weights", w]);
    }
    let o = pofvr(&args, dir);
    assert!(o.status.success(), "{}", stderr(&o));
    serde_json::from_slice(&std::fs::read(dir.join("r.json")).unwrap()).unwrap()
}

#[test]
fn quick_report_on_the_phantom_is_complete_consistent_and_conservative() {
    let dir = tempfile::tempdir().unwrap();
    let t = std::time::Instant::now();
    let o = pofvr(
        &[
            "experiment",
            VOLUME,
            "--quick",
            "--size",
            SIZE,
            "--out",
            "report",
            "--pof",
            "head.pof",
            "--quiet",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    eprintln!("quick report in {:.1} s", t.elapsed().as_secs_f64());
    let rep = dir.path().join("report");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(rep.join("report.json")).unwrap()).unwrap();
    let primary = report["primary_culling_method"]
        .as_str()
        .unwrap()
        .to_string();

    // Every file: the fixed ones, the ones named after the culling method, and nothing else
    // (no temp files left behind).
    let listed: Vec<String> = report["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap().to_string())
        .collect();
    let mut expected: Vec<String> = [
        "index.html",
        "report.json",
        "fig1_pof_construction.json",
        "fig1_pof_construction.csv",
        "fig1_pof_storage.svg",
        "fig4_culling_vs_view.csv",
        "fig4_culling_vs_view.svg",
        "fig5_rank_breakdown.csv",
        "fig5_rank_breakdown_none.svg",
        "fig6_speedup.csv",
        "fig6_frame_time.svg",
        "fig6_speedup.svg",
        "fig6_load_balance.svg",
        "fig8_tf_family.csv",
        "fig8_tf_family_exact.svg",
        "fig8_tf_family_verified.svg",
        "fig5_rank_breakdown_verified.svg",
        "fig8_k0_0.05_k1_1.png",
        "fig8_k0_0.25_k1_0.9.png",
        "fig8_k0_0.8_k1_0.5.png",
        "fig8_side_by_side.png",
        "audit.csv",
        "audit.json",
    ]
    .iter()
    .map(|s| (*s).to_string())
    .collect();
    expected.push(format!("fig5_rank_breakdown_{primary}.svg"));
    expected.push(format!("fig8_tf_family_{primary}.svg"));
    for f in &expected {
        assert!(listed.contains(f), "{f} not listed in report.json");
    }
    let mut on_disk: Vec<String> = std::fs::read_dir(&rep)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    on_disk.sort();
    let mut listed_sorted = listed.clone();
    listed_sorted.sort();
    assert_eq!(on_disk, listed_sorted, "files on disk = files listed");

    // Every SVG parses as XML, is an <svg>, and carries text labels; every image is on the page.
    let html = std::fs::read_to_string(rep.join("index.html")).unwrap();
    for f in &listed {
        let bytes = std::fs::read(rep.join(f)).unwrap();
        assert!(!bytes.is_empty(), "{f} is empty");
        if f.ends_with(".svg") {
            let text = String::from_utf8(bytes).unwrap();
            let doc =
                roxmltree::Document::parse(&text).unwrap_or_else(|e| panic!("{f} is not XML: {e}"));
            assert_eq!(doc.root_element().tag_name().name(), "svg", "{f}");
            let labels = doc
                .descendants()
                .filter(|n| n.has_tag_name("text"))
                .filter(|n| n.text().is_some_and(|t| !t.trim().is_empty()))
                .count();
            assert!(labels >= 5, "{f}: only {labels} text labels");
            assert!(html.contains(f.as_str()), "index.html does not show {f}");
        }
        if f.ends_with(".png") {
            assert_eq!(&std::fs::read(rep.join(f)).unwrap()[1..4], b"PNG", "{f}");
            assert!(html.contains(f.as_str()), "index.html does not show {f}");
        }
    }

    // Fig. 4: 18 views per measured method; the numbers are those `render --stats` gives.
    let fig4 = read_csv(&rep.join("fig4_culling_vs_view.csv"));
    for m in [
        "none",
        "pof-table",
        "pof-cubic",
        "exact",
        "range-bound",
        "verified",
    ] {
        let rows: Vec<_> = fig4.iter().filter(|r| r["method"] == m).collect();
        assert_eq!(rows.len(), 18, "{m}");
        let az: Vec<f64> = rows.iter().map(|r| num(r, "azimuth_deg")).collect();
        assert_eq!(az, (0..18).map(|i| f64::from(i) * 20.0).collect::<Vec<_>>());
    }
    let mut culled_somewhere = false;
    for (az, method) in [
        (20.0, "none"),
        (20.0, "exact"),
        (140.0, "exact"),
        (60.0, "pof-table"),
        (100.0, "verified"),
    ] {
        let row = fig4
            .iter()
            .find(|r| r["method"] == method && num(r, "azimuth_deg") == az)
            .unwrap();
        let mode = method.strip_suffix("-table").unwrap_or(method);
        let st = render_stats(dir.path(), &format!("{az},0"), mode, None);
        for (col, key) in [
            ("visible", "visible"),
            ("culled", "culled"),
            ("non_empty", "non_empty"),
            ("repaired", "repaired"),
        ] {
            assert_eq!(
                num(row, col),
                st["bricks"][key].as_f64().unwrap(),
                "fig 4 {mode} at {az}: {col}"
            );
        }
        assert_eq!(num(row, "samples"), st["samples"].as_f64().unwrap());
        culled_somewhere |= num(row, "culled") > 0.0;
    }
    assert!(
        culled_somewhere,
        "exact culling culls something on the phantom"
    );
    // Culling never renders more than no culling.
    for r in fig4.iter().filter(|r| r["method"] != "none") {
        let none = fig4
            .iter()
            .find(|n| n["method"] == "none" && n["azimuth_deg"] == r["azimuth_deg"])
            .unwrap();
        assert!(num(r, "visible") <= num(none, "visible"));
        assert_eq!(num(r, "visible") + num(r, "culled"), num(none, "visible"));
    }

    // Fig. 5: one row per rank for each method, at --max-ranks (4 with --quick).
    let fig5 = read_csv(&rep.join("fig5_rank_breakdown.csv"));
    assert_eq!(fig5.iter().filter(|r| r["method"] == "none").count(), 4);
    assert_eq!(fig5.iter().filter(|r| r["method"] == primary).count(), 4);
    // Verified culling's ranks report their verification; the others verify nothing.
    let verified: Vec<_> = fig5.iter().filter(|r| r["method"] == "verified").collect();
    assert_eq!(verified.len(), 4);
    assert!(verified.iter().all(|r| num(r, "verify_ms") >= 0.0));
    assert!(verified.iter().any(|r| num(r, "verify_ms") > 0.0));
    assert!(fig5
        .iter()
        .filter(|r| r["method"] != "verified")
        .all(|r| num(r, "verify_ms") == 0.0 && num(r, "frame_repaired") == 0.0));
    let none_samples: f64 = fig5
        .iter()
        .filter(|r| r["method"] == "none")
        .map(|r| num(r, "samples"))
        .sum();
    let st = render_stats(dir.path(), "0,0", "none", None);
    assert_eq!(none_samples, st["samples"].as_f64().unwrap());

    // Fig. 6: 1, 2, 4 ranks for both curves and both methods; speedup 1 at one rank.
    let fig6 = read_csv(&rep.join("fig6_speedup.csv"));
    assert_eq!(fig6.len(), 2 * 2 * 3);
    for r in &fig6 {
        assert!(["hilbert", "z"].contains(&r["curve"].as_str()));
        if num(r, "ranks") == 1.0 {
            assert!((num(r, "speedup") - 1.0).abs() < 1e-12);
        }
        assert!(num(r, "load_balance_max_over_mean_samples") >= 1.0 - 1e-12);
        assert!(num(r, "frame_ms") > 0.0);
    }

    // Fig. 8: 3×3 weights; the paper's middle weighting agrees with `render --weights`.
    let fig8 = read_csv(&rep.join("fig8_tf_family.csv"));
    assert_eq!(fig8.iter().filter(|r| r["method"] == "none").count(), 9);
    let row = fig8
        .iter()
        .find(|r| r["method"] == "exact" && r["k0"] == "0.25" && r["k1"] == "0.9")
        .unwrap();
    let st = render_stats(dir.path(), "0,0", "exact", Some("0.25,0.9"));
    assert_eq!(
        num(row, "visible"),
        st["bricks"]["visible"].as_f64().unwrap()
    );
    assert_eq!(num(row, "culled"), st["bricks"]["culled"].as_f64().unwrap());
    let row = fig8
        .iter()
        .find(|r| r["method"] == "verified" && r["k0"] == "0.25" && r["k1"] == "0.9")
        .unwrap();
    let st = render_stats(dir.path(), "0,0", "verified", Some("0.25,0.9"));
    for col in ["visible", "culled", "repaired"] {
        assert_eq!(
            num(row, col),
            st["bricks"][col].as_f64().unwrap(),
            "fig 8 {col}"
        );
    }

    // The audit: 12 views × every measured culling method, zero pixels breaking the rule.
    let audit: serde_json::Value =
        serde_json::from_slice(&std::fs::read(rep.join("audit.json")).unwrap()).unwrap();
    assert_eq!(audit["conservative_violations"], 0, "{audit:#}");
    let rows = read_csv(&rep.join("audit.csv"));
    assert_eq!(
        rows.len(),
        12 * 5,
        "12 views × (pof-table, pof-cubic, exact, range-bound, verified)"
    );
    assert!(rows.iter().all(|r| num(r, "violations") == 0.0));
    assert!(
        rows.iter().map(|r| num(r, "culled")).sum::<f64>() > 0.0,
        "the audit checked frames where something was culled"
    );
    assert!(html.contains("PASS"), "the audit verdict is on the page");

    // Fig. 1: every encoding built, sized as the encoding says (18×18 views with --quick:
    // 4, 1 and 2 bytes per view, the cubic's 10 coefficients in 40 bytes), and the table
    // saved to --pof as `pof info` reads it.
    let fig1 = read_csv(&rep.join("fig1_pof_construction.csv"));
    let per_basis = |enc: &str| {
        let r = fig1.iter().find(|r| r["encoding"] == enc).unwrap();
        assert_eq!(r["views"], "18x18");
        assert!(num(r, "seconds") > 0.0 && num(r, "brick_views_per_second_per_core") > 0.0);
        num(r, "bytes_per_brick_per_basis")
    };
    assert_eq!(per_basis("table"), 4.0 * 324.0);
    assert_eq!(per_basis("u8"), 324.0);
    assert_eq!(per_basis("u16"), 2.0 * 324.0);
    assert_eq!(per_basis("cubic"), 40.0);
    let o = pofvr(&["pof", "info", "head.pof", "--json"], dir.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let info: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(info["encoding"], "table");
    assert_eq!(info["views"], serde_json::json!([18, 18]));
    let table = fig1.iter().find(|r| r["encoding"] == "table").unwrap();
    assert_eq!(
        num(table, "file_bytes"),
        info["file_bytes"].as_f64().unwrap()
    );
}

#[test]
fn bad_options_fail_before_writing_a_report() {
    let dir = tempfile::tempdir().unwrap();
    for args in [
        vec!["experiment", VOLUME, "--quick", "--max-ranks", "0"],
        vec!["experiment", VOLUME, "--quick", "--size", "0x10"],
        vec!["experiment", VOLUME, "--quick", "--cull-threshold", "1.5"],
        vec!["experiment", "no-such-volume.nhdr", "--quick"],
    ] {
        let mut a = args.clone();
        a.extend(["--out", "report"]);
        let o = pofvr(&a, dir.path());
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(stderr(&o).contains("error"), "{args:?}: {}", stderr(&o));
        assert!(
            !dir.path().join("report").exists(),
            "{args:?} left a report"
        );
    }
}
