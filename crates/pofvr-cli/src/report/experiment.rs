//! The files of `pofvr experiment`: each figure's measurements (from
//! [`pofvr::experiment`]) as CSV, JSON, SVG charts and PNG images, and the `index.html`
//! that shows them.

use anyhow::Result;
use pofvr::experiment::{Audit, Method, PofBuildRow, RankBreakdown, Speedup, TfFamily, ViewSweep};
use pofvr::render::Image;
use serde_json::{json, Value};

use super::plot::{line_chart, stacked_bars, Legend, Line, Stack};
use super::{Cell, Csv, Html, ReportDir};
use crate::cmd::experiment::Plan;

/// Figure 1: `fig1_pof_construction.{csv,json}` and `fig1_pof_storage.svg`; returns the
/// JSON for the summary.
pub(crate) fn fig1(
    out: &mut ReportDir,
    plan: &Plan,
    rows: &[PofBuildRow],
    bases: usize,
) -> Result<Value> {
    let mut csv = Csv::new(&[
        "encoding",
        "sets",
        "source",
        "views",
        "seconds",
        "computed_bricks",
        "brick_views_per_second_per_core",
        "bytes_per_brick_per_basis",
        "stored_bricks",
        "file_bytes",
        "file_mb",
    ]);
    for r in rows {
        csv.push(vec![
            r.encoding.into(),
            yes_no(r.sets),
            r.source.clone().into(),
            r.views.clone().into(),
            r.seconds.into(),
            r.computed_bricks.into(),
            r.rate.into(),
            r.bytes_per_brick_per_basis.into(),
            r.stored_bricks.into(),
            r.file_bytes.into(),
            r.file_mb().into(),
        ]);
    }
    out.csv("fig1_pof_construction.csv", &csv)?;
    let svg = stacked_bars(
        &format!(
            "POF storage per encoding ({}×{} views, {bases} bases)",
            plan.pof_views[0], plan.pof_views[1]
        ),
        &rows.iter().map(PofBuildRow::label).collect::<Vec<_>>(),
        "encoding",
        "megabytes",
        &[Stack {
            name: "file size".into(),
            values: rows.iter().map(PofBuildRow::file_mb).collect(),
        }],
    )?;
    out.write("fig1_pof_storage.svg", svg.as_bytes())?;
    let json = json!({
        "views": plan.pof_views,
        "threads": rayon::current_num_threads(),
        "builds": rows,
    });
    out.json("fig1_pof_construction.json", &json)?;
    Ok(json)
}

/// Figure 4: `fig4_culling_vs_view.{csv,svg}`.
pub(crate) fn fig4(out: &mut ReportDir, f: &ViewSweep) -> Result<()> {
    let mut csv = Csv::new(&[
        "azimuth_deg",
        "elevation_deg",
        "method",
        "non_empty",
        "visible",
        "culled",
        "frame_ms",
        "samples",
        "repaired",
    ]);
    for r in &f.rows {
        csv.push(vec![
            r.azimuth_deg.into(),
            r.elevation_deg.into(),
            r.method.into(),
            r.non_empty.into(),
            r.visible.into(),
            r.culled.into(),
            r.frame_ms.into(),
            r.samples.into(),
            r.repaired.into(),
        ]);
    }
    out.csv("fig4_culling_vs_view.csv", &csv)?;
    let series = |method: &str, y: fn(&pofvr::experiment::ViewRow) -> usize| {
        f.rows
            .iter()
            .filter(|r| r.method == method)
            .map(|r| (r.azimuth_deg, y(r) as f64))
            .collect()
    };
    let mut lines: Vec<Line> = f
        .means
        .iter()
        .map(|m| Line {
            name: m.method.to_string(),
            points: series(m.method, |r| r.visible),
            dashed: false,
        })
        .collect();
    // What verification repaired, dashed under the method's rendered bricks (which
    // include them).
    lines.extend(
        f.means
            .iter()
            .filter(|m| m.mean_repaired > 0.0)
            .map(|m| Line {
                name: format!("{}: repaired", m.method),
                points: series(m.method, |r| r.repaired),
                dashed: true,
            }),
    );
    let svg = line_chart(
        "Visible bricks while rotating about the Y axis (elevation 0)",
        "azimuth (degrees)",
        "visible bricks",
        &lines,
        true,
        Legend::LowerLeft,
    )?;
    out.write("fig4_culling_vs_view.svg", svg.as_bytes())
}

/// Figure 5: `fig5_rank_breakdown_{method}.svg` per method and `fig5_rank_breakdown.csv`.
pub(crate) fn fig5(out: &mut ReportDir, f: &RankBreakdown) -> Result<()> {
    let mut csv = Csv::new(&[
        "method",
        "rank",
        "bricks_rendered",
        "samples",
        "cull_ms",
        "raycast_ms",
        "composite_ms",
        "comm_ms",
        "bytes_sent",
        "frame_ms",
        "verify_ms",
        "repair_ms",
        "frame_repaired",
    ]);
    for fr in &f.frames {
        let ranks = &fr.stats.ranks;
        for r in ranks {
            csv.push(vec![
                fr.method.into(),
                r.rank.into(),
                r.bricks_rendered.into(),
                r.samples.into(),
                r.cull_ms.into(),
                r.raycast_ms.into(),
                r.composite_ms.into(),
                r.comm_ms.into(),
                r.bytes_sent.into(),
                fr.frame_ms.into(),
                r.verify_ms.into(),
                r.repair_ms.into(),
                fr.repaired.into(),
            ]);
        }
        let stack = |name: &str, v: fn(&pofvr::frame::RankStats) -> f64| Stack {
            name: name.into(),
            values: ranks.iter().map(v).collect(),
        };
        let svg = stacked_bars(
            &format!(
                "Time per rank, {} ranks, cull {} (frame {:.1} ms)",
                fr.ranks, fr.method, fr.frame_ms
            ),
            &ranks.iter().map(|r| r.rank.to_string()).collect::<Vec<_>>(),
            "rank",
            "milliseconds",
            &[
                stack("culling", |r| r.cull_ms),
                stack("ray casting", |r| r.raycast_ms),
                stack("compositing", |r| r.composite_ms),
                stack("id exchange + gather", |r| r.comm_ms),
            ],
        )?;
        out.write(
            &format!("fig5_rank_breakdown_{}.svg", fr.method),
            svg.as_bytes(),
        )?;
    }
    out.csv("fig5_rank_breakdown.csv", &csv)
}

/// Figure 6: `fig6_speedup.csv` and the frame time, speedup and load balance charts.
pub(crate) fn fig6(out: &mut ReportDir, f: &Speedup) -> Result<()> {
    let mut csv = Csv::new(&[
        "curve",
        "method",
        "ranks",
        "frame_ms",
        "speedup",
        "efficiency",
        "load_balance_max_over_mean_samples",
        "samples",
        "visible",
    ]);
    let (mut times, mut speeds, mut balances): (Vec<Line>, Vec<Line>, Vec<Line>) =
        (Vec::new(), Vec::new(), Vec::new());
    for r in &f.rows {
        csv.push(vec![
            r.curve.to_string().into(),
            r.method.into(),
            r.ranks.into(),
            r.frame_ms.into(),
            r.speedup.into(),
            r.efficiency.into(),
            r.load_balance_max_over_mean_samples.into(),
            r.samples.into(),
            r.visible.into(),
        ]);
        let name = format!("{}, cull {}", r.curve, r.method);
        let x = r.ranks as f64;
        for (lines, y) in [
            (&mut times, r.frame_ms),
            (&mut speeds, r.speedup),
            (&mut balances, r.load_balance_max_over_mean_samples),
        ] {
            match lines.last_mut() {
                Some(l) if l.name == name => l.points.push((x, y)),
                _ => lines.push(Line {
                    name: name.clone(),
                    points: vec![(x, y)],
                    dashed: false,
                }),
            }
        }
    }
    speeds.push(Line {
        name: "ideal".into(),
        points: f
            .rank_counts
            .iter()
            .map(|&r| (r as f64, r as f64))
            .collect(),
        dashed: true,
    });
    out.csv("fig6_speedup.csv", &csv)?;
    for (file, title, y, lines, from_zero, legend) in [
        (
            "fig6_frame_time.svg",
            "Frame time vs ranks",
            "frame time (ms)",
            &times,
            true,
            Legend::LowerLeft,
        ),
        (
            "fig6_speedup.svg",
            "Speedup vs ranks (relative to 1 rank)",
            "speedup",
            &speeds,
            true,
            Legend::UpperLeft,
        ),
        (
            "fig6_load_balance.svg",
            "Load balance: max / mean samples per rank",
            "max / mean samples",
            &balances,
            false,
            Legend::UpperLeft,
        ),
    ] {
        let svg = line_chart(title, "ranks", y, lines, from_zero, legend)?;
        out.write(file, svg.as_bytes())?;
    }
    Ok(())
}

/// The label of the weights axis of figure 8.
pub(crate) fn k_names(names: &[String]) -> String {
    if names.len() >= 2 {
        format!("k0 ({}) / k1 ({})", names[0], names[1])
    } else {
        format!("k0 ({})", names[0])
    }
}

/// Figure 8: `fig8_tf_family.csv`, a chart per culling method, the paper's three images
/// and them side by side; returns the images' JSON for the summary.
pub(crate) fn fig8(
    out: &mut ReportDir,
    f: &TfFamily,
    methods: &[&str],
    names: &[String],
) -> Result<Value> {
    let mut csv = Csv::new(&[
        "k0",
        "k1",
        "method",
        "non_empty",
        "visible",
        "culled",
        "frame_ms",
        "repaired",
    ]);
    for r in &f.rows {
        csv.push(vec![
            format!("{}", r.k0).into(),
            r.k1.map_or(Cell::Na, |k| format!("{k}").into()),
            r.method.into(),
            r.non_empty.into(),
            r.visible.into(),
            r.culled.into(),
            r.frame_ms.into(),
            r.repaired.into(),
        ]);
    }
    out.csv("fig8_tf_family.csv", &csv)?;
    for name in methods {
        let rows: Vec<_> = f.rows.iter().filter(|r| r.method == *name).collect();
        let cats: Vec<String> = rows
            .iter()
            .map(|r| match r.k1 {
                Some(k1) => format!("{}/{k1}", r.k0),
                None => format!("{}", r.k0),
            })
            .collect();
        let stack = |name: &str, v: fn(&pofvr::experiment::TfFamilyRow) -> usize| Stack {
            name: name.into(),
            values: rows.iter().map(|r| v(r) as f64).collect(),
        };
        // Verified culling's rendered bricks split into those predicted visible and those
        // repaired; the other methods repair nothing.
        let stacks = if rows.iter().any(|r| r.repaired > 0) {
            vec![
                stack("visible as predicted", |r| r.visible - r.repaired),
                stack("repaired", |r| r.repaired),
                stack("culled", |r| r.culled),
            ]
        } else {
            vec![
                stack("visible", |r| r.visible),
                stack("culled", |r| r.culled),
            ]
        };
        let svg = stacked_bars(
            &format!("Visible and culled bricks per weights, cull {name}"),
            &cats,
            &k_names(names),
            "non-empty bricks",
            &stacks,
        )?;
        out.write(&format!("fig8_tf_family_{name}.svg"), svg.as_bytes())?;
    }
    let mut images = Vec::new();
    for im in &f.images {
        let file = match im.k1 {
            Some(k1) => format!("fig8_k0_{}_k1_{k1}.png", im.k0),
            None => format!("fig8_k0_{}.png", im.k0),
        };
        im.image.write_png(&out.path(&file))?;
        out.record(&file);
        images.push(json!({
            "file": file, "k0": shortest(im.k0), "k1": im.k1.map(shortest),
            "method": im.method, "visible": im.visible, "culled": im.culled,
            "non_empty": im.non_empty, "repaired": im.repaired,
        }));
    }
    let all: Vec<Image> = f.images.iter().map(|i| i.image.clone()).collect();
    side_by_side(&all, 8).write_png(&out.path("fig8_side_by_side.png"))?;
    out.record("fig8_side_by_side.png");
    Ok(Value::Array(images))
}

/// The threshold rule as the audit states it.
const RULE: &str = "pixels whose unculled opacity is below the threshold are identical within \
                    1e-6, and no pixel differs by more than 1 - threshold";

/// The audit: `audit.csv` and `audit.json`; returns the JSON for the summary.
pub(crate) fn audit(out: &mut ReportDir, a: &Audit, methods: &[Method<'_>]) -> Result<Value> {
    let mut csv = Csv::new(&[
        "view",
        "azimuth_deg",
        "elevation_deg",
        "projection",
        "method",
        "conservative",
        "culled",
        "pixels_below_threshold_changed",
        "pixels_over_max_diff",
        "violations",
        "max_abs_diff",
    ]);
    for r in &a.rows {
        csv.push(vec![
            r.view.into(),
            r.azimuth_deg.into(),
            r.elevation_deg.into(),
            r.projection.into(),
            r.method.into(),
            yes_no(r.conservative),
            r.culled.into(),
            r.pixels_below_threshold_changed.into(),
            r.pixels_over_max_diff.into(),
            r.violations.into(),
            r.max_abs_diff.into(),
        ]);
    }
    out.csv("audit.csv", &csv)?;
    let mut json = serde_json::to_value(a)?;
    json["rule"] = RULE.into();
    json["not_audited"] = methods
        .iter()
        .filter(|m| !m.available())
        .map(|m| json!({"method": m.name, "reason": m.missing}))
        .collect();
    out.json("audit.json", &json)?;
    Ok(json)
}

/// What the page says besides the figures' own data.
pub(crate) struct Page<'a> {
    /// The intro paragraph (HTML, parts escaped).
    pub(crate) intro: String,
    pub(crate) plan: &'a Plan,
    pub(crate) methods: &'a [Method<'a>],
    pub(crate) primary: &'a str,
    pub(crate) machine: &'a Value,
    pub(crate) pof_rows: &'a [PofBuildRow],
    pub(crate) fig4: &'a ViewSweep,
    pub(crate) fig5: &'a RankBreakdown,
    pub(crate) fig6: &'a Speedup,
    pub(crate) fig8_methods: &'a [&'a str],
    pub(crate) fig8_images: &'a Value,
    pub(crate) k_names: String,
    pub(crate) audit: &'a Audit,
}

/// The `index.html` page.
pub(crate) fn page(p: &Page<'_>, title: &str) -> String {
    let plan = p.plan;
    let mut html = Html::new();
    html.raw(&p.intro);
    let audited: Vec<&Method<'_>> = p
        .methods
        .iter()
        .filter(|m| m.available() && m.name != "none")
        .collect();
    let conservative: Vec<&str> = audited
        .iter()
        .filter(|m| m.conservative)
        .map(|m| m.name)
        .collect();
    let ok = p.audit.passed();
    html.note(
        if ok { "ok" } else { "fail" },
        &format!(
            "Conservativeness audit: {} pixels break the rule over {} random views × {} \
             conservative method(s) ({}) — {}.",
            p.audit.conservative_violations,
            plan.audit_views,
            conservative.len(),
            conservative.join(", "),
            if ok { "PASS" } else { "FAIL" }
        ),
    );
    html.h2("Culling methods");
    html.table(
        &["method", "what", "in this report"],
        &p.methods
            .iter()
            .map(|m| {
                vec![
                    m.name.to_string(),
                    m.about.to_string(),
                    m.missing.unwrap_or("measured").to_string(),
                ]
            })
            .collect::<Vec<_>>(),
    );

    html.h2("1. POF construction");
    html.p(&format!(
        "POFs of every non-empty brick over a {}×{} view grid ({} views), per basis, in each \
         encoding, and the table with POF sets (the aggressive mode) when built. Rates are \
         brick-views per second per worker thread ({} threads).",
        plan.pof_views[0],
        plan.pof_views[1],
        plan.pof_views[0] * plan.pof_views[1],
        rayon::current_num_threads()
    ));
    html.table(
        &[
            "encoding",
            "source",
            "seconds",
            "brick-views/s per core",
            "bytes per brick per basis",
            "file MB",
        ],
        &p.pof_rows
            .iter()
            .map(|r| {
                vec![
                    r.label(),
                    r.source.clone(),
                    r.seconds.map_or_else(|| "-".into(), |s| format!("{s:.2}")),
                    r.rate.map_or_else(|| "-".into(), |s| format!("{s:.0}")),
                    format!("{:.0}", r.bytes_per_brick_per_basis),
                    format!("{:.3}", r.file_mb()),
                ]
            })
            .collect::<Vec<_>>(),
    );
    if let (Some(t), Some(c)) = (
        p.pof_rows.iter().find(|r| r.encoding == "table" && !r.sets),
        p.pof_rows.iter().find(|r| r.encoding == "cubic"),
    ) {
        html.p(&format!(
            "Table vs cubic storage: {:.0} vs {:.0} bytes per brick per basis ({:.1}× smaller; \
             the paper: 55 MB vs 5 MB for one basis on the Visible Woman, 36×36 views).",
            t.bytes_per_brick_per_basis,
            c.bytes_per_brick_per_basis,
            t.bytes_per_brick_per_basis / c.bytes_per_brick_per_basis.max(1e-9)
        ));
    }
    html.img("fig1_pof_storage.svg", "POF storage per encoding");
    html.data(&["fig1_pof_construction.csv", "fig1_pof_construction.json"]);

    html.h2("2. Culling effectiveness vs view (paper Fig. 4)");
    html.img("fig4_culling_vs_view.svg", "visible bricks vs azimuth");
    html.table(
        &[
            "method",
            "mean visible bricks",
            "mean culled share of non-empty",
            "mean repaired bricks",
        ],
        &p.fig4
            .means
            .iter()
            .map(|m| {
                vec![
                    m.method.to_string(),
                    format!("{:.1}", m.mean_visible),
                    format!("{:.1} %", 100.0 * m.mean_culled_fraction_of_non_empty),
                    format!("{:.1}", m.mean_repaired),
                ]
            })
            .collect::<Vec<_>>(),
    );
    for m in p.methods.iter().filter(|m| !m.available()) {
        html.note("na", &format!("{}: {}", m.name, m.missing.unwrap_or("")));
    }
    html.data(&["fig4_culling_vs_view.csv"]);

    html.h2("3. Time per rank (paper Fig. 5)");
    html.p(&format!(
        "{} in-process ranks, view {},{}, Hilbert curve; without culling, \
         with culling by {} and verified (predicted, verified while compositing, repaired). \
         Median of {} frame(s).",
        plan.breakdown_ranks, plan.view[0], plan.view[1], p.primary, plan.reps
    ));
    html.table(
        &[
            "method",
            "frame ms",
            "visible bricks",
            "culled bricks",
            "repaired bricks",
            "max/mean samples",
        ],
        &p.fig5
            .frames
            .iter()
            .map(|f| {
                vec![
                    f.method.to_string(),
                    format!("{:.2}", f.frame_ms),
                    f.visible.to_string(),
                    f.culled.to_string(),
                    f.repaired.to_string(),
                    format!("{:.3}", f.load_balance_max_over_mean_samples),
                ]
            })
            .collect::<Vec<_>>(),
    );
    html.raw("<div class=\"side2\">");
    for f in &p.fig5.frames {
        html.img(
            &format!("fig5_rank_breakdown_{}.svg", f.method),
            &format!("time per rank, cull {}", f.method),
        );
    }
    html.raw("</div>");
    html.data(&["fig5_rank_breakdown.csv"]);

    html.h2("4. Speedup and load balance (paper Fig. 6)");
    html.p(&format!(
        "Ranks {:?}; each point runs its ranks on one worker thread each, as the paper's \
         one processor per rank, on a machine with {} cores \
         (load average {} when the run started), so rank counts above the core count share \
         cores and speedup flattens there. Hilbert and Z curves, without culling and with {}. \
         Median of {} frame(s) per point.",
        plan.rank_counts,
        p.machine["cores"],
        p.machine["load_average_at_start"]
            .as_str()
            .unwrap_or("unknown"),
        p.primary,
        plan.reps
    ));
    if let Some(b) = &p.fig6.best {
        html.p(&format!(
            "Best speedup: {:.2}× at {} ranks ({}).",
            b.speedup, b.ranks, b.best
        ));
    }
    html.img("fig6_frame_time.svg", "frame time vs ranks");
    html.img("fig6_speedup.svg", "speedup vs ranks");
    html.img("fig6_load_balance.svg", "load balance vs ranks");
    html.data(&["fig6_speedup.csv"]);

    html.h2("5. Transfer-function family (paper Fig. 8)");
    html.p(&format!(
        "One set of bricks, weights changed at run time: {}. Images: the paper's three \
         weightings (k0, k1) = (0.05, 1.0), (0.25, 0.9), (0.8, 0.5), culled by {}.",
        p.k_names, p.primary
    ));
    for name in p.fig8_methods {
        html.img(
            &format!("fig8_tf_family_{name}.svg"),
            &format!("visible and culled bricks per weights, {name}"),
        );
    }
    let images = p.fig8_images.as_array().map_or(&[][..], Vec::as_slice);
    html.raw("<div class=\"side\">");
    for im in images {
        html.img(im["file"].as_str().unwrap_or(""), "rendered image");
    }
    html.raw("</div>");
    html.table(
        &["image", "method", "visible", "culled", "non-empty"],
        &images
            .iter()
            .map(|im| {
                vec![
                    im["file"].as_str().unwrap_or("").to_string(),
                    im["method"].as_str().unwrap_or("").to_string(),
                    im["visible"].to_string(),
                    im["culled"].to_string(),
                    im["non_empty"].to_string(),
                ]
            })
            .collect::<Vec<_>>(),
    );
    html.data(&["fig8_tf_family.csv", "fig8_side_by_side.png"]);

    let thr = plan.cull_threshold;
    html.h2("6. Conservativeness audit");
    html.p(&format!(
        "{} random views (uniform over the sphere, every third one in perspective), 2 ranks. \
         Each culled frame is compared with the unculled frame (cull none) of the same view: \
         pixels whose unculled opacity is below {thr} must be identical within 1e-6, and no \
         pixel may differ by more than 1 − {thr}.",
        plan.audit_views
    ));
    html.table(
        &[
            "method",
            "guaranteed",
            "pixels breaking the rule",
            "bricks culled (all views)",
            "max |diff|",
        ],
        &p.audit
            .methods
            .iter()
            .map(|t| {
                vec![
                    t.method.to_string(),
                    if t.conservative { "yes" } else { "no" }.to_string(),
                    t.violations.to_string(),
                    t.bricks_culled_over_all_views.to_string(),
                    format!("{:.2e}", t.max_abs_diff),
                ]
            })
            .collect::<Vec<_>>(),
    );
    html.data(&["audit.csv", "audit.json"]);
    html.finish(title)
}

fn yes_no(b: bool) -> Cell {
    (if b { "yes" } else { "no" }).into()
}

/// An f32 as the f64 with the same shortest decimal form (0.05, not 0.0500000007).
pub(crate) fn shortest(x: f32) -> f64 {
    format!("{x}").parse().unwrap_or(f64::from(x))
}

/// Images side by side with `gap` transparent columns between them.
fn side_by_side(images: &[Image], gap: u32) -> Image {
    let h = images.iter().map(Image::height).max().unwrap_or(1).max(1);
    let n = u32::try_from(images.len()).unwrap_or(u32::MAX);
    let w = (images.iter().map(Image::width).sum::<u32>() + gap * n.saturating_sub(1)).max(1);
    let mut out = Image::new(w, h);
    let mut x0 = 0usize;
    for im in images {
        let (iw, ih) = (im.width() as usize, im.height() as usize);
        let px = out.pixels_mut();
        for y in 0..ih {
            for x in 0..iw {
                px[y * w as usize + x0 + x] = im.pixels()[y * iw + x];
            }
        }
        x0 += iw + gap as usize;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn side_by_side_places_images_left_to_right() {
        let mut a = Image::new(2, 2);
        a.pixels_mut()[3] = [1.0, 0.0, 0.0, 1.0];
        let mut b = Image::new(1, 1);
        b.pixels_mut()[0] = [0.0, 1.0, 0.0, 1.0];
        let s = side_by_side(&[a, b], 3);
        assert_eq!((s.width(), s.height()), (6, 2));
        assert_eq!(s.pixel(1, 1), [1.0, 0.0, 0.0, 1.0]);
        assert_eq!(s.pixel(5, 0), [0.0, 1.0, 0.0, 1.0]);
        assert_eq!(s.pixel(2, 0), [0.0; 4]);
    }

    #[test]
    fn weights_print_as_written() {
        assert_eq!(shortest(0.05), 0.05);
        assert_eq!(shortest(0.9), 0.9);
        assert_eq!(shortest(1.0), 1.0);
    }
}
