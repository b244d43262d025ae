//! `pofvr experiment`: the paper's §5 experiments on a user's volume, written as a report
//! (`index.html`, SVG charts, PNG images, and the numbers behind each as CSV and JSON).
//!
//! Every number comes from a frame rendered here with [`render_frame`]; nothing is
//! estimated. Experiments whose inputs this build cannot produce (POF tables) are reported
//! as not available, with the reason, instead of being left out silently.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;
use pofvr::cull::range_bound::RangeBound;
use pofvr::cull::{CullMode, OpacityBound};
use pofvr::distribute::Curve;
use pofvr::frame::{render_frame, FrameOptions, FrameStats, RenderJob};
use pofvr::pof::{Encoding, PofSettings, PofTable};
use pofvr::render::{Camera, Image, Projection, RenderSettings};
use serde::Serialize;
use serde_json::json;

use crate::args::{TfArgs, VolumeArgs};
use crate::progress::Ui;
use crate::report::plot::{line_chart, stacked_bars, Legend, Line, Stack};
use crate::report::{esc, Cell, Csv, Html, ReportDir};
use crate::resolve;

#[derive(Args, Debug)]
pub(crate) struct ExperimentArgs {
    #[command(flatten)]
    pub(crate) volume: VolumeArgs,
    #[command(flatten)]
    pub(crate) tf: TfArgs,
    /// Report directory (created; the report's files in it are replaced).
    /// > default: report
    #[arg(long, short, default_value = "report")]
    pub(crate) out: PathBuf,
    /// A CI-sized run: 128x128 images, 12 audit views, a 3x3 weight grid, up to 4 ranks,
    /// one repetition per timed frame.
    #[arg(long)]
    pub(crate) quick: bool,
    /// Largest rank count of the speedup figure (1, 2, 4, … up to it).
    /// > default: 8 (4 with --quick)
    #[arg(long)]
    pub(crate) max_ranks: Option<usize>,
    /// Rank count of the per-rank time breakdown.
    /// > default: --max-ranks
    #[arg(long)]
    pub(crate) breakdown_ranks: Option<usize>,
    /// Image size.
    /// > default: 512x512 (128x128 with --quick)
    #[arg(long, value_name = "WxH")]
    pub(crate) size: Option<String>,
    /// POFs (table encoding) for the pof modes: read when the file exists, otherwise built
    /// and saved there for the next run. The u8, u16 and cubic encodings are always built
    /// (their construction is figure 1).
    /// > default: built in memory, not saved
    #[arg(long, value_name = "FILE.pof")]
    pub(crate) pof: Option<PathBuf>,
    /// POF view grid (θ rows × φ columns); the paper uses 36,36 (1296 views).
    /// > default: 36,36 (18,18 with --quick)
    #[arg(long, value_name = "N,M")]
    pub(crate) pof_views: Option<String>,
    /// Also build POF sets (the aggressive pof-set mode). They cost far more than the
    /// tables to build (about 20× on the phantom).
    /// > default: on, off with --quick
    #[arg(long, value_name = "BOOL", num_args = 0..=1, default_missing_value = "true")]
    pub(crate) pof_sets: Option<bool>,
    /// Random views of the conservativeness audit.
    /// > default: 100 (12 with --quick)
    #[arg(long)]
    pub(crate) audit_views: Option<usize>,
    /// View of the per-rank, speedup and transfer-function figures: azimuth about +y and
    /// elevation, degrees.
    /// > default: 0,0
    #[arg(
        long,
        value_name = "AZ,EL",
        default_value = "0,0",
        allow_hyphen_values = true
    )]
    pub(crate) view: String,
    /// Opacity at or above which a pixel hides what lies behind it.
    /// > default: 0.95
    #[arg(long, default_value_t = 0.95)]
    pub(crate) cull_threshold: f32,
    /// Repetitions of each timed frame (the median is reported).
    /// > default: 3 (1 with --quick)
    #[arg(long)]
    pub(crate) reps: Option<usize>,
    /// Internal: render one timed point of figures 5 and 6 in this process and print its
    /// statistics as JSON. The experiment runs itself so with `--threads RANKS`, giving each
    /// in-process rank one core as in the paper.
    #[arg(long, hide = true, value_name = "RANKS,CURVE,METHOD")]
    pub(crate) point: Option<String>,
    /// Seed of the audit's random views.
    /// > default: 1
    #[arg(long, default_value_t = 1)]
    pub(crate) seed: u64,
}

/// A way of culling, as the figures name it.
struct Method<'a> {
    name: &'static str,
    mode: CullMode,
    bound: Option<&'a dyn OpacityBound>,
    /// `Some(reason)` when this build cannot run it.
    missing: Option<String>,
    /// Guaranteed to follow the threshold rule (audited); false for the aggressive POF sets.
    conservative: bool,
    about: &'static str,
}

impl Method<'_> {
    fn available(&self) -> bool {
        self.missing.is_none()
    }
}

/// Resolved settings of a run.
#[derive(Serialize, Clone)]
struct Plan {
    width: u32,
    height: u32,
    quick: bool,
    max_ranks: usize,
    breakdown_ranks: usize,
    rank_counts: Vec<usize>,
    audit_views: usize,
    view: [f64; 2],
    cull_threshold: f32,
    reps: usize,
    seed: u64,
    step: f32,
    ert: f32,
    brick: usize,
    projection: &'static str,
    pof_views: [usize; 2],
}

/// A deterministic generator for the audit's views (SplitMix64).
struct SplitMix(u64);

impl SplitMix {
    fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        #[allow(clippy::cast_precision_loss)]
        let v = (z >> 11) as f64 / (1u64 << 53) as f64;
        v
    }
}

// `..default()` keeps this compiling when FrameOptions gains fields (MPI).
#[allow(clippy::needless_update)]
fn opts(mode: CullMode, threshold: f32, ranks: usize, curve: Curve) -> FrameOptions {
    FrameOptions {
        cull: mode,
        cull_threshold: threshold,
        ranks,
        curve,
        ..FrameOptions::default()
    }
}

/// The frame with the median time of `reps` renders.
fn timed(
    job: &RenderJob,
    m: &Method<'_>,
    cam: &Camera,
    o: &FrameOptions,
    reps: usize,
) -> Result<(Image, FrameStats)> {
    let mut runs = Vec::new();
    for _ in 0..reps.max(1) {
        runs.push(render_frame(job, m.bound, cam, o)?);
    }
    runs.sort_by(|a, b| a.1.frame_ms.total_cmp(&b.1.frame_ms));
    let mid = runs.len() / 2;
    Ok(runs.swap_remove(mid))
}

fn rank_counts(max: usize) -> Vec<usize> {
    let mut v = Vec::new();
    let mut r = 1;
    while r <= max {
        v.push(r);
        r *= 2;
    }
    if v.last() != Some(&max) {
        v.push(max);
    }
    v
}

#[allow(clippy::cast_precision_loss)]
fn load_balance(st: &FrameStats) -> f64 {
    let n = st.ranks.len().max(1) as f64;
    let mean = st.ranks.iter().map(|r| r.samples as f64).sum::<f64>() / n;
    let max = st.ranks.iter().map(|r| r.samples).max().unwrap_or(0) as f64;
    if mean > 0.0 {
        max / mean
    } else {
        1.0
    }
}

fn machine() -> serde_json::Value {
    let cores = std::thread::available_parallelism().map_or(0, std::num::NonZeroUsize::get);
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into());
    json!({
        "cores": cores,
        "threads": rayon::current_num_threads(),
        "cpu": cpu,
        "os": std::env::consts::OS,
        "load_average_at_start": load_average(),
    })
}

/// The 1, 5 and 15 minute load averages (Linux), for judging the timings.
fn load_average() -> Option<String> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
}

#[allow(clippy::too_many_lines)]
pub(crate) fn run(a: &ExperimentArgs, ui: &Ui) -> Result<()> {
    let t_start = Instant::now();
    let (width, height) =
        resolve::size(
            a.size
                .as_deref()
                .unwrap_or(if a.quick { "128x128" } else { "512x512" }),
        )?;
    let max_ranks = a.max_ranks.unwrap_or(if a.quick { 4 } else { 8 });
    if !(1..=256).contains(&max_ranks) {
        bail!("--max-ranks {max_ranks} must be in 1..=256");
    }
    let breakdown_ranks = a.breakdown_ranks.unwrap_or(max_ranks);
    if !(1..=256).contains(&breakdown_ranks) {
        bail!("--breakdown-ranks {breakdown_ranks} must be in 1..=256");
    }
    let view = resolve::parse_list::<f64>("--view", &a.view, Some(2))?;
    if !(a.cull_threshold > 0.0 && a.cull_threshold <= 1.0) {
        bail!("--cull-threshold {} must be in (0, 1]", a.cull_threshold);
    }
    let pv = resolve::parse_list::<usize>(
        "--pof-views",
        a.pof_views
            .as_deref()
            .unwrap_or(if a.quick { "18,18" } else { "36,36" }),
        Some(2),
    )?;
    if pv.iter().any(|v| !(2..=360).contains(v)) {
        bail!("--pof-views {pv:?}: each count must be in 2..=360");
    }
    let plan = Plan {
        width,
        height,
        quick: a.quick,
        max_ranks,
        breakdown_ranks,
        rank_counts: rank_counts(max_ranks),
        audit_views: a.audit_views.unwrap_or(if a.quick { 12 } else { 100 }),
        view: [view[0], view[1]],
        cull_threshold: a.cull_threshold,
        reps: a.reps.unwrap_or(if a.quick { 1 } else { 3 }).max(1),
        seed: a.seed,
        step: RenderSettings::default().step,
        ert: RenderSettings::default().ert,
        brick: a.volume.brick,
        projection: "orthographic",
        pof_views: [pv[0], pv[1]],
    };

    let mach = machine();
    let sp = ui.spinner("opening and bricking the volume");
    let vol = resolve::volume(&a.volume)?;
    let tf = resolve::required_tf(&a.tf, &a.volume.volume)?;
    let mut job = RenderJob::new(vol, tf, a.volume.brick, RenderSettings::default())?;
    sp.finish_and_clear();
    if let Some(p) = &a.point {
        return run_point(a, &job, &plan, p);
    }
    let mut out = ReportDir::create(&a.out)?;
    let base_weights = job.tf.weights.clone();
    let mut summary = serde_json::Map::new();

    // --- 1. POF construction ----------------------------------------------------------
    // Built first: the culling methods below read them.
    let mut pof_rows: Vec<PofBuildRow> = Vec::new();
    let want_sets = a.pof_sets.unwrap_or(!a.quick);
    let table = match &a.pof {
        Some(p) if p.exists() => {
            let sp = ui.spinner(&format!("reading {}", p.display()));
            let t = job.load_pofs(p)?;
            sp.finish_and_clear();
            if t.meta().encoding != Encoding::Table {
                bail!(
                    "--pof {}: holds {} POFs; the experiment reads the table encoding \
                     (build it with `pofvr pof build --encoding table`)",
                    p.display(),
                    t.meta().encoding
                );
            }
            pof_rows.push(PofBuildRow::of(
                &t,
                Encoding::Table,
                &format!("read from {}", p.display()),
                None,
            ));
            t
        }
        _ => {
            let (t, row) = build_pofs(&job, plan.pof_views, Encoding::Table, false, ui)?;
            if let Some(p) = &a.pof {
                t.save(p)?;
            }
            pof_rows.push(row);
            t
        }
    };
    let mut cubic = None;
    for enc in [Encoding::U8, Encoding::U16, Encoding::Cubic] {
        let (t, row) = build_pofs(&job, plan.pof_views, enc, false, ui)?;
        pof_rows.push(row);
        if enc == Encoding::Cubic {
            cubic = Some(t);
        }
    }
    let cubic = cubic.expect("the cubic encoding was built");
    // POF sets: read from --pof when it has them, else built when asked for.
    let sets_table = if table.has_sets() {
        None
    } else if want_sets {
        let (t, row) = build_pofs(&job, plan.pof_views, Encoding::Table, true, ui)?;
        pof_rows.push(row);
        Some(t)
    } else {
        None
    };
    let sets: Option<&PofTable> = if table.has_sets() {
        Some(&table)
    } else {
        sets_table.as_ref()
    };
    let mut fig1 = Csv::new(&[
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
    for r in &pof_rows {
        fig1.push(vec![
            r.encoding.into(),
            (if r.sets { "yes" } else { "no" }).into(),
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
    out.csv("fig1_pof_construction.csv", &fig1)?;
    out.write(
        "fig1_pof_storage.svg",
        stacked_bars(
            &format!(
                "POF storage per encoding ({}×{} views, {} bases)",
                plan.pof_views[0],
                plan.pof_views[1],
                job.tf.bases.len()
            ),
            &pof_rows
                .iter()
                .map(|r| {
                    if r.sets {
                        format!("{} + sets", r.encoding)
                    } else {
                        r.encoding.to_string()
                    }
                })
                .collect::<Vec<_>>(),
            "encoding",
            "megabytes",
            &[Stack {
                name: "file size".into(),
                values: pof_rows.iter().map(PofBuildRow::file_mb).collect(),
            }],
        )?
        .as_bytes(),
    )?;
    let pof_json = json!({
        "views": plan.pof_views,
        "threads": rayon::current_num_threads(),
        "builds": pof_rows,
    });
    out.json("fig1_pof_construction.json", &pof_json)?;
    summary.insert("pof_construction".into(), pof_json);

    #[allow(clippy::cast_precision_loss)]
    let range_bound = RangeBound::new(
        &job.grid,
        &job.sampled,
        job.settings.step,
        job.settings.ert,
        a.volume.brick as f32 / 2.0,
    );
    let methods: Vec<Method<'_>> = vec![
        Method {
            name: "none",
            mode: CullMode::None,
            bound: None,
            missing: None,
            conservative: true,
            about: "no culling: every non-empty brick on screen is rendered",
        },
        Method {
            name: "pof-table",
            mode: CullMode::Pof,
            bound: Some(&table),
            missing: None,
            conservative: true,
            about: "conservative POF culling, POFs stored as f32 tables",
        },
        Method {
            name: "pof-cubic",
            mode: CullMode::Pof,
            bound: Some(&cubic),
            missing: None,
            conservative: true,
            about: "conservative POF culling, POFs stored as cubic polynomials",
        },
        Method {
            name: "pof-set",
            mode: CullMode::PofSet,
            bound: sets.map(|t| t as &dyn OpacityBound),
            missing: sets.is_none().then(|| {
                "not measured: POF sets were not built (they are skipped with --quick for \
                 their build cost; pass --pof-sets)"
                    .into()
            }),
            conservative: false,
            about: "aggressive POF-set culling (not guaranteed; audited for information)",
        },
        Method {
            name: "exact",
            mode: CullMode::Exact,
            bound: None,
            missing: None,
            conservative: true,
            about: "the sequential oracle: bricks tested against the opacity actually composited",
        },
        Method {
            name: "range-bound",
            mode: CullMode::Pof,
            bound: Some(&range_bound),
            missing: None,
            conservative: true,
            about: "the POF culling path with a bound from each brick's value range alone \
                    (no precompute; the baseline POFs must beat)",
        },
    ];
    let method = |name: &str| {
        methods
            .iter()
            .find(|m| m.name == name)
            .expect("known method")
    };
    // The culling method of the timed figures: POF tables when built, else the range bound.
    let primary = if method("pof-table").available() {
        method("pof-table")
    } else {
        method("range-bound")
    };
    let none = method("none");
    let thr = plan.cull_threshold;
    let mut html = Html::new();

    // --- 2. Culling effectiveness vs view (Fig. 4) ----------------------------------------
    let avail: Vec<&Method<'_>> = methods.iter().filter(|m| m.available()).collect();
    let azimuths: Vec<f64> = (0..18).map(|i| f64::from(i) * 20.0).collect();
    let pb = ui.bar(
        (azimuths.len() * avail.len()) as u64,
        "fig 4: culling vs view",
    );
    let mut fig4 = Csv::new(&[
        "azimuth_deg",
        "elevation_deg",
        "method",
        "non_empty",
        "visible",
        "culled",
        "frame_ms",
        "samples",
    ]);
    let mut fig4_lines: Vec<Line> = avail
        .iter()
        .map(|m| Line {
            name: m.name.to_string(),
            points: Vec::new(),
            dashed: false,
        })
        .collect();
    let mut fig4_culled_frac: Vec<(f64, f64)> = vec![(0.0, 0.0); avail.len()];
    for &az in &azimuths {
        let cam = Camera::orbit(
            &job.volume,
            az,
            0.0,
            width,
            height,
            Projection::Orthographic,
        );
        for (k, m) in avail.iter().enumerate() {
            let (_, st) = render_frame(&job, m.bound, &cam, &opts(m.mode, thr, 1, Curve::Hilbert))?;
            let b = st.bricks;
            fig4.push(vec![
                az.into(),
                0.0.into(),
                m.name.into(),
                b.non_empty.into(),
                b.visible.into(),
                b.culled.into(),
                st.frame_ms.into(),
                st.samples.into(),
            ]);
            #[allow(clippy::cast_precision_loss)]
            {
                fig4_lines[k].points.push((az, b.visible as f64));
                fig4_culled_frac[k].0 += b.culled as f64 / b.non_empty.max(1) as f64;
                fig4_culled_frac[k].1 += b.visible as f64;
            }
            pb.inc(1);
        }
    }
    pb.finish_and_clear();
    out.csv("fig4_culling_vs_view.csv", &fig4)?;
    out.write(
        "fig4_culling_vs_view.svg",
        line_chart(
            "Visible bricks while rotating about the Y axis (elevation 0)",
            "azimuth (degrees)",
            "visible bricks",
            &fig4_lines,
            true,
            Legend::LowerLeft,
        )?
        .as_bytes(),
    )?;
    #[allow(clippy::cast_precision_loss)]
    let fig4_means: Vec<(String, f64, f64)> = avail
        .iter()
        .zip(&fig4_culled_frac)
        .map(|(m, (f, v))| {
            (
                m.name.to_string(),
                v / azimuths.len() as f64,
                f / azimuths.len() as f64,
            )
        })
        .collect();
    summary.insert(
        "culling_vs_view".into(),
        json!(fig4_means
            .iter()
            .map(|(n, v, f)| json!({"method": n, "mean_visible": v, "mean_culled_fraction_of_non_empty": f}))
            .collect::<Vec<_>>()),
    );

    // --- 3. Per-rank breakdown (Fig. 5) -------------------------------------------------
    // Timed points run in child processes with one worker thread per rank; they read the
    // table from disk.
    let scratch_pof = out.path(".experiment-table.pof.tmp");
    let pof_file: Option<PathBuf> = if primary.name == "pof-table" {
        match &a.pof {
            Some(p) if p.exists() => Some(p.clone()),
            _ => {
                table.save(&scratch_pof)?;
                Some(scratch_pof.clone())
            }
        }
    } else {
        None
    };
    let test_cam = Camera::orbit(
        &job.volume,
        plan.view[0],
        plan.view[1],
        width,
        height,
        Projection::Orthographic,
    );
    let pb = ui.bar(2, "fig 5: per-rank breakdown");
    let mut fig5 = Csv::new(&[
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
    ]);
    let mut fig5_frames = Vec::new();
    for m in [none, primary] {
        let st = point(
            a,
            &plan,
            pof_file.as_deref(),
            breakdown_ranks,
            Curve::Hilbert,
            m.name,
        )?;
        for r in &st.ranks {
            fig5.push(vec![
                m.name.into(),
                r.rank.into(),
                r.bricks_rendered.into(),
                r.samples.into(),
                r.cull_ms.into(),
                r.raycast_ms.into(),
                r.composite_ms.into(),
                r.comm_ms.into(),
                r.bytes_sent.into(),
                st.frame_ms.into(),
            ]);
        }
        let cats: Vec<String> = st.ranks.iter().map(|r| r.rank.to_string()).collect();
        let stacks = vec![
            Stack {
                name: "culling".into(),
                values: st.ranks.iter().map(|r| r.cull_ms).collect(),
            },
            Stack {
                name: "ray casting".into(),
                values: st.ranks.iter().map(|r| r.raycast_ms).collect(),
            },
            Stack {
                name: "compositing".into(),
                values: st.ranks.iter().map(|r| r.composite_ms).collect(),
            },
            Stack {
                name: "id exchange + gather".into(),
                values: st.ranks.iter().map(|r| r.comm_ms).collect(),
            },
        ];
        let file = format!("fig5_rank_breakdown_{}.svg", m.name);
        out.write(
            &file,
            stacked_bars(
                &format!(
                    "Time per rank, {} ranks, cull {} (frame {:.1} ms)",
                    breakdown_ranks, m.name, st.frame_ms
                ),
                &cats,
                "rank",
                "milliseconds",
                &stacks,
            )?
            .as_bytes(),
        )?;
        fig5_frames.push((m.name, st));
        pb.inc(1);
    }
    pb.finish_and_clear();
    out.csv("fig5_rank_breakdown.csv", &fig5)?;
    summary.insert(
        "rank_breakdown".into(),
        json!(fig5_frames
            .iter()
            .map(|(n, st)| json!({
                "method": n, "ranks": breakdown_ranks, "frame_ms": st.frame_ms,
                "culled": st.bricks.culled, "visible": st.bricks.visible,
                "load_balance_max_over_mean_samples": load_balance(st),
            }))
            .collect::<Vec<_>>()),
    );

    // --- 4. Speedup and load balance (Fig. 6) --------------------------------------------
    let curves = [Curve::Hilbert, Curve::Z];
    let pb = ui.bar(
        (curves.len() * 2 * plan.rank_counts.len()) as u64,
        "fig 6: speedup",
    );
    let mut fig6 = Csv::new(&[
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
    let mut time_lines = Vec::new();
    let mut speed_lines = Vec::new();
    let mut balance_lines = Vec::new();
    let mut best_speedup: Option<(String, usize, f64)> = None;
    for curve in curves {
        for m in [none, primary] {
            let name = format!("{curve}, cull {}", m.name);
            let (mut tl, mut sl, mut bl) = (Vec::new(), Vec::new(), Vec::new());
            let mut t1 = None;
            for &r in &plan.rank_counts {
                let st = point(a, &plan, pof_file.as_deref(), r, curve, m.name)?;
                let t1v = *t1.get_or_insert(st.frame_ms);
                let speedup = t1v / st.frame_ms;
                #[allow(clippy::cast_precision_loss)]
                let (rf, eff) = (r as f64, speedup / r as f64);
                let lb = load_balance(&st);
                fig6.push(vec![
                    curve.to_string().into(),
                    m.name.into(),
                    r.into(),
                    st.frame_ms.into(),
                    speedup.into(),
                    eff.into(),
                    lb.into(),
                    st.samples.into(),
                    st.bricks.visible.into(),
                ]);
                tl.push((rf, st.frame_ms));
                sl.push((rf, speedup));
                bl.push((rf, lb));
                match &best_speedup {
                    Some(b) if b.2 >= speedup => {}
                    _ => best_speedup = Some((name.clone(), r, speedup)),
                }
                pb.inc(1);
            }
            time_lines.push(Line {
                name: name.clone(),
                points: tl,
                dashed: false,
            });
            speed_lines.push(Line {
                name: name.clone(),
                points: sl,
                dashed: false,
            });
            balance_lines.push(Line {
                name,
                points: bl,
                dashed: false,
            });
        }
    }
    pb.finish_and_clear();
    #[allow(clippy::cast_precision_loss)]
    speed_lines.push(Line {
        name: "ideal".into(),
        points: plan
            .rank_counts
            .iter()
            .map(|&r| (r as f64, r as f64))
            .collect(),
        dashed: true,
    });
    out.csv("fig6_speedup.csv", &fig6)?;
    out.write(
        "fig6_frame_time.svg",
        line_chart(
            "Frame time vs ranks",
            "ranks",
            "frame time (ms)",
            &time_lines,
            true,
            Legend::LowerLeft,
        )?
        .as_bytes(),
    )?;
    out.write(
        "fig6_speedup.svg",
        line_chart(
            "Speedup vs ranks (relative to 1 rank)",
            "ranks",
            "speedup",
            &speed_lines,
            true,
            Legend::UpperLeft,
        )?
        .as_bytes(),
    )?;
    out.write(
        "fig6_load_balance.svg",
        line_chart(
            "Load balance: max / mean samples per rank",
            "ranks",
            "max / mean samples",
            &balance_lines,
            false,
            Legend::UpperLeft,
        )?
        .as_bytes(),
    )?;
    summary.insert(
        "speedup".into(),
        json!(best_speedup
            .as_ref()
            .map(|(n, r, s)| json!({"best": n, "ranks": r, "speedup": s}))),
    );

    if pof_file.as_deref() == Some(scratch_pof.as_path()) {
        let _ = std::fs::remove_file(&scratch_pof);
    }

    // --- 5. Transfer-function family (Fig. 8) --------------------------------------------
    let bases = job.tf.bases.len();
    let names: Vec<String> = job.tf.bases.iter().map(|b| b.name.clone()).collect();
    let k0s: &[f32] = if a.quick {
        &[0.05, 0.25, 0.8]
    } else {
        &[0.05, 0.25, 0.5, 0.8, 1.0]
    };
    let k1s: &[f32] = if bases < 2 {
        &[f32::NAN]
    } else if a.quick {
        &[0.5, 0.9, 1.0]
    } else {
        &[0.25, 0.5, 0.9, 1.0]
    };
    let weights_of = |k0: f32, k1: f32| {
        let mut w = base_weights.clone();
        w[0] = k0;
        if bases >= 2 {
            w[1] = k1;
        }
        w
    };
    let fig8_methods: Vec<&Method<'_>> = avail
        .iter()
        .copied()
        .filter(|m| m.mode != CullMode::None)
        .collect();
    let pb = ui.bar(
        (k0s.len() * k1s.len() * (1 + fig8_methods.len()) + 3) as u64,
        "fig 8: transfer-function family",
    );
    let mut fig8 = Csv::new(&[
        "k0",
        "k1",
        "method",
        "non_empty",
        "visible",
        "culled",
        "frame_ms",
    ]);
    // Per method: categories (weights), visible and culled counts.
    type Bars = (String, Vec<String>, Vec<f64>, Vec<f64>);
    let mut fig8_bars: Vec<Bars> = fig8_methods
        .iter()
        .map(|m| (m.name.to_string(), Vec::new(), Vec::new(), Vec::new()))
        .collect();
    for &k0 in k0s {
        for &k1 in k1s {
            job.tf.set_weights(weights_of(k0, k1))?;
            let label = if bases >= 2 {
                format!("{k0}/{k1}")
            } else {
                format!("{k0}")
            };
            for m in std::iter::once(none).chain(fig8_methods.iter().copied()) {
                let (_, st) = render_frame(
                    &job,
                    m.bound,
                    &test_cam,
                    &opts(m.mode, thr, 1, Curve::Hilbert),
                )?;
                fig8.push(vec![
                    format!("{k0}").into(),
                    if bases >= 2 {
                        format!("{k1}").into()
                    } else {
                        Cell::Na
                    },
                    m.name.into(),
                    st.bricks.non_empty.into(),
                    st.bricks.visible.into(),
                    st.bricks.culled.into(),
                    st.frame_ms.into(),
                ]);
                if let Some(bars) = fig8_bars.iter_mut().find(|b| b.0 == m.name) {
                    bars.1.push(label.clone());
                    #[allow(clippy::cast_precision_loss)]
                    {
                        bars.2.push(st.bricks.visible as f64);
                        bars.3.push(st.bricks.culled as f64);
                    }
                }
                pb.inc(1);
            }
        }
    }
    out.csv("fig8_tf_family.csv", &fig8)?;
    let k_names = if bases >= 2 {
        format!("k0 ({}) / k1 ({})", names[0], names[1])
    } else {
        format!("k0 ({})", names[0])
    };
    for (name, cats, vis, cul) in &fig8_bars {
        out.write(
            &format!("fig8_tf_family_{name}.svg"),
            stacked_bars(
                &format!("Visible and culled bricks per weights, cull {name}"),
                cats,
                &k_names,
                "non-empty bricks",
                &[
                    Stack {
                        name: "visible".into(),
                        values: vis.clone(),
                    },
                    Stack {
                        name: "culled".into(),
                        values: cul.clone(),
                    },
                ],
            )?
            .as_bytes(),
        )?;
    }
    // The paper's three weightings, rendered side by side with the primary method.
    let paper_weights: [(f32, f32); 3] = [(0.05, 1.0), (0.25, 0.9), (0.8, 0.5)];
    let mut images = Vec::new();
    let mut fig8_images = Vec::new();
    for (k0, k1) in paper_weights {
        job.tf.set_weights(weights_of(k0, k1))?;
        let (img, st) = render_frame(
            &job,
            primary.bound,
            &test_cam,
            &opts(primary.mode, thr, 1, Curve::Hilbert),
        )?;
        let file = if bases >= 2 {
            format!("fig8_k0_{k0}_k1_{k1}.png")
        } else {
            format!("fig8_k0_{k0}.png")
        };
        img.write_png(&out.path(&file))?;
        out.record(&file);
        fig8_images.push(json!({
            "file": file, "k0": shortest(k0), "k1": (bases >= 2).then(|| shortest(k1)),
            "method": primary.name, "visible": st.bricks.visible, "culled": st.bricks.culled,
            "non_empty": st.bricks.non_empty,
        }));
        images.push(img);
        pb.inc(1);
    }
    pb.finish_and_clear();
    let side = side_by_side(&images, 8);
    side.write_png(&out.path("fig8_side_by_side.png"))?;
    out.record("fig8_side_by_side.png");
    job.tf.set_weights(base_weights.clone())?;
    summary.insert("tf_family_images".into(), json!(fig8_images));

    // --- 6. Conservativeness audit ------------------------------------------------------
    let audited: Vec<&Method<'_>> = avail
        .iter()
        .copied()
        .filter(|m| m.mode != CullMode::None)
        .collect();
    let pb = ui.bar(
        (plan.audit_views * (1 + audited.len())) as u64,
        "audit: culled vs unculled",
    );
    let mut rng = SplitMix(plan.seed);
    let mut audit = Csv::new(&[
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
    let mut totals: Vec<(u64, u64, f32)> = vec![(0, 0, 0.0); audited.len()];
    for v in 0..plan.audit_views {
        let az = rng.next_f64() * 360.0;
        let el = (2.0 * rng.next_f64() - 1.0)
            .clamp(-1.0, 1.0)
            .asin()
            .to_degrees();
        // Every third view in perspective: the rule holds for any camera.
        let projection = if v % 3 == 2 {
            Projection::Perspective
        } else {
            Projection::Orthographic
        };
        let cam = Camera::orbit(&job.volume, az, el, width, height, projection);
        let (unculled, _) = render_frame(
            &job,
            None,
            &cam,
            &opts(CullMode::None, thr, 2, Curve::Hilbert),
        )?;
        pb.inc(1);
        for (k, m) in audited.iter().enumerate() {
            let (img, st) =
                render_frame(&job, m.bound, &cam, &opts(m.mode, thr, 2, Curve::Hilbert))?;
            let c = pofvr::check::check_threshold_rule(&unculled, &img, thr);
            audit.push(vec![
                v.into(),
                az.into(),
                el.into(),
                (if projection == Projection::Perspective {
                    "perspective"
                } else {
                    "orthographic"
                })
                .into(),
                m.name.into(),
                (if m.conservative { "yes" } else { "no" }).into(),
                st.bricks.culled.into(),
                c.below_changed.into(),
                c.over_bound.into(),
                c.violations.into(),
                f64::from(c.max_diff).into(),
            ]);
            totals[k].0 += c.violations;
            totals[k].1 += st.bricks.culled as u64;
            totals[k].2 = totals[k].2.max(c.max_diff);
            pb.inc(1);
        }
    }
    pb.finish_and_clear();
    out.csv("audit.csv", &audit)?;
    let conservative_violations: u64 = audited
        .iter()
        .zip(&totals)
        .filter(|(m, _)| m.conservative)
        .map(|(_, t)| t.0)
        .sum();
    let audit_json = json!({
        "views": plan.audit_views,
        "pixels_per_view": u64::from(width) * u64::from(height),
        "threshold": thr,
        "rule": "pixels whose unculled opacity is below the threshold are identical within 1e-6, \
                 and no pixel differs by more than 1 - threshold",
        "conservative_violations": conservative_violations,
        "methods": audited.iter().zip(&totals).map(|(m, t)| json!({
            "method": m.name, "conservative": m.conservative, "violations": t.0,
            "bricks_culled_over_all_views": t.1, "max_abs_diff": t.2,
        })).collect::<Vec<_>>(),
        "not_audited": methods.iter().filter(|m| !m.available()).map(|m| json!({
            "method": m.name, "reason": m.missing,
        })).collect::<Vec<_>>(),
    });
    out.json("audit.json", &audit_json)?;
    summary.insert("audit".into(), audit_json);

    // --- The page -----------------------------------------------------------------------
    let b = job.grid.counts();
    let dims = job.volume.dims();
    let ok = conservative_violations == 0;
    html.raw(&format!(
        "<p>Volume <b>{}</b>: {}×{}×{} {} voxels, spacing {:?}; {} bricks of {}³ ({}×{}×{}), \
         {} empty for the family's weights {:?}. Machine: {} cores ({}), {} worker threads, \
         load average {} at the start. \
         Images {}×{}, orthographic, step {}, early termination {}, culling threshold {}. \
         Produced by <code>pofvr experiment</code>{} in {:.1} s.</p>",
        esc(&a.volume.volume),
        dims[0],
        dims[1],
        dims[2],
        job.volume.data_type(),
        job.volume.spacing(),
        job.grid.len(),
        a.volume.brick,
        b[0],
        b[1],
        b[2],
        job.empty_bricks(),
        base_weights,
        mach["cores"],
        esc(mach["cpu"].as_str().unwrap_or("")),
        mach["threads"],
        mach["load_average_at_start"].as_str().unwrap_or("unknown"),
        width,
        height,
        plan.step,
        plan.ert,
        thr,
        if a.quick { " --quick" } else { "" },
        t_start.elapsed().as_secs_f64(),
    ));
    html.note(
        if ok { "ok" } else { "fail" },
        &format!(
            "Conservativeness audit: {} pixels break the rule over {} random views × {} \
             conservative method(s) ({}) — {}.",
            conservative_violations,
            plan.audit_views,
            audited.iter().filter(|m| m.conservative).count(),
            audited
                .iter()
                .filter(|m| m.conservative)
                .map(|m| m.name)
                .collect::<Vec<_>>()
                .join(", "),
            if ok { "PASS" } else { "FAIL" }
        ),
    );
    html.h2("Culling methods");
    html.table(
        &["method", "what", "in this report"],
        &methods
            .iter()
            .map(|m| {
                vec![
                    m.name.to_string(),
                    m.about.to_string(),
                    m.missing.clone().unwrap_or_else(|| "measured".into()),
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
        &pof_rows
            .iter()
            .map(|r| {
                vec![
                    if r.sets {
                        format!("{} + sets", r.encoding)
                    } else {
                        r.encoding.to_string()
                    },
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
        pof_rows.iter().find(|r| r.encoding == "table" && !r.sets),
        pof_rows.iter().find(|r| r.encoding == "cubic"),
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
        ],
        &fig4_means
            .iter()
            .map(|(n, v, f)| vec![n.clone(), format!("{v:.1}"), format!("{:.1} %", 100.0 * f)])
            .collect::<Vec<_>>(),
    );
    for m in methods.iter().filter(|m| !m.available()) {
        html.note(
            "na",
            &format!("{}: {}", m.name, m.missing.as_deref().unwrap_or("")),
        );
    }
    html.data(&["fig4_culling_vs_view.csv"]);

    html.h2("3. Time per rank (paper Fig. 5)");
    html.p(&format!(
        "{breakdown_ranks} in-process ranks, view {},{}, Hilbert curve; without culling and \
         with culling by {}. Median of {} frame(s).",
        plan.view[0], plan.view[1], primary.name, plan.reps
    ));
    html.table(
        &[
            "method",
            "frame ms",
            "visible bricks",
            "culled bricks",
            "max/mean samples",
        ],
        &fig5_frames
            .iter()
            .map(|(n, st)| {
                vec![
                    (*n).to_string(),
                    format!("{:.2}", st.frame_ms),
                    st.bricks.visible.to_string(),
                    st.bricks.culled.to_string(),
                    format!("{:.3}", load_balance(st)),
                ]
            })
            .collect::<Vec<_>>(),
    );
    html.raw("<div class=\"side2\">");
    for m in [none, primary] {
        html.img(
            &format!("fig5_rank_breakdown_{}.svg", m.name),
            &format!("time per rank, cull {}", m.name),
        );
    }
    html.raw("</div>");
    html.data(&["fig5_rank_breakdown.csv"]);

    html.h2("4. Speedup and load balance (paper Fig. 6)");
    html.p(&format!(
        "Ranks {:?}; each point runs in a child process with one worker thread per rank \
         (`--threads R`), as the paper's one processor per rank, on a machine with {} cores \
         (load average {} when the run started), so rank counts above the core count share \
         cores and speedup flattens there. Hilbert and Z curves, without culling and with {}. \
         Median of {} frame(s) per point.",
        plan.rank_counts,
        mach["cores"],
        mach["load_average_at_start"].as_str().unwrap_or("unknown"),
        primary.name,
        plan.reps
    ));
    if let Some((n, r, s)) = &best_speedup {
        html.p(&format!("Best speedup: {s:.2}× at {r} ranks ({n})."));
    }
    html.img("fig6_frame_time.svg", "frame time vs ranks");
    html.img("fig6_speedup.svg", "speedup vs ranks");
    html.img("fig6_load_balance.svg", "load balance vs ranks");
    html.data(&["fig6_speedup.csv"]);

    html.h2("5. Transfer-function family (paper Fig. 8)");
    html.p(&format!(
        "One set of bricks, weights changed at run time: {}. Images: the paper's three \
         weightings (k0, k1) = (0.05, 1.0), (0.25, 0.9), (0.8, 0.5), culled by {}.",
        k_names, primary.name
    ));
    for (name, _, _, _) in &fig8_bars {
        html.img(
            &format!("fig8_tf_family_{name}.svg"),
            &format!("visible and culled bricks per weights, {name}"),
        );
    }
    html.raw("<div class=\"side\">");
    for im in &fig8_images {
        html.img(im["file"].as_str().unwrap_or(""), "rendered image");
    }
    html.raw("</div>");
    html.table(
        &["image", "method", "visible", "culled", "non-empty"],
        &fig8_images
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
        &audited
            .iter()
            .zip(&totals)
            .map(|(m, t)| {
                vec![
                    m.name.to_string(),
                    if m.conservative { "yes" } else { "no" }.to_string(),
                    t.0.to_string(),
                    t.1.to_string(),
                    format!("{:.2e}", t.2),
                ]
            })
            .collect::<Vec<_>>(),
    );
    html.data(&["audit.csv", "audit.json"]);

    out.record("index.html");
    out.record("report.json");
    let report = json!({
        "volume": a.volume.volume,
        "dims": dims,
        "data_type": job.volume.data_type().to_string(),
        "spacing": job.volume.spacing(),
        "bricks": { "size": a.volume.brick, "counts": b, "total": job.grid.len(), "empty": job.empty_bricks() },
        "weights": base_weights.iter().map(|w| shortest(*w)).collect::<Vec<_>>(),
        "bases": names,
        "machine": mach,
        "plan": plan,
        "primary_culling_method": primary.name,
        "summary": summary,
        "files": out.files(),
        "seconds": t_start.elapsed().as_secs_f64(),
    });
    out.write(
        "index.html",
        html.finish(&format!("pofvr experiment: {}", a.volume.volume))
            .as_bytes(),
    )?;
    out.json("report.json", &report)?;

    eprintln!(
        "report: {} ({} files, {:.1} s)",
        out.path("index.html").display(),
        out.files().len(),
        t_start.elapsed().as_secs_f64()
    );
    for (n, v, f) in &fig4_means {
        eprintln!(
            "  {n:<12} mean visible {v:9.1}   culled {:5.1} % of non-empty",
            100.0 * f
        );
    }
    if let Some((n, r, s)) = &best_speedup {
        eprintln!("  best speedup {s:.2}x at {r} ranks ({n})");
    }
    eprintln!(
        "  audit: {conservative_violations} pixels break the rule over {} views",
        plan.audit_views
    );
    if !ok {
        return Err(anyhow!(
            "conservativeness audit failed: {conservative_violations} pixels break the rule \
             (see {})",
            out.path("audit.csv").display()
        ));
    }
    Ok(())
}

/// Statistics of a frame as `render --stats` and `--point` print them.
#[derive(serde::Deserialize)]
struct PointStats {
    frame_ms: f64,
    samples: u64,
    rays: u64,
    bricks: PointBricks,
    ranks: Vec<pofvr::frame::RankStats>,
}

#[derive(serde::Deserialize)]
struct PointBricks {
    total: usize,
    empty: usize,
    non_empty: usize,
    culled: usize,
    visible: usize,
}

/// Runs one timed point in a child process with `--threads ranks`.
fn point(
    a: &ExperimentArgs,
    plan: &Plan,
    pof: Option<&std::path::Path>,
    ranks: usize,
    curve: Curve,
    method: &str,
) -> Result<FrameStats> {
    let exe = std::env::current_exe().context("cannot find the pofvr executable")?;
    let mut cmd = std::process::Command::new(exe);
    let v = &a.volume;
    cmd.arg(format!("--threads={ranks}"))
        .arg("--quiet")
        .arg("experiment")
        .arg(&v.volume)
        .arg(format!("--endian={}", v.endian))
        .arg(format!("--header-bytes={}", v.header_bytes))
        .arg(format!("--brick={}", v.brick))
        .arg(format!("--size={}x{}", plan.width, plan.height))
        .arg(format!("--view={},{}", plan.view[0], plan.view[1]))
        .arg(format!("--cull-threshold={}", plan.cull_threshold))
        .arg(format!("--reps={}", plan.reps))
        .arg(format!("--point={ranks},{curve},{method}"));
    for (flag, val) in [
        ("dims", &v.dims),
        ("dtype", &v.dtype),
        ("spacing", &v.spacing),
    ] {
        if let Some(x) = val {
            cmd.arg(format!("--{flag}={x}"));
        }
    }
    if let Some(t) = &a.tf.tf {
        cmd.arg("--tf").arg(t);
    }
    if let Some(w) = &a.tf.weights {
        cmd.arg(format!("--weights={w}"));
    }
    if let Some(p) = pof {
        cmd.arg("--pof").arg(p);
    }
    let o = cmd.output().context("running a timed point")?;
    if !o.status.success() {
        bail!(
            "timed point ({ranks} ranks, {curve}, {method}) failed: {}",
            String::from_utf8_lossy(&o.stderr).trim()
        );
    }
    let p: PointStats = serde_json::from_slice(&o.stdout).context("timed point output")?;
    #[allow(clippy::cast_precision_loss)]
    let sps = if p.frame_ms > 0.0 {
        p.samples as f64 / (p.frame_ms / 1e3)
    } else {
        0.0
    };
    Ok(FrameStats {
        frame_ms: p.frame_ms,
        rays: p.rays,
        samples: p.samples,
        samples_per_second: sps,
        threads: ranks,
        cull: None,
        bricks: pofvr::frame::BrickCounts {
            total: p.bricks.total,
            empty: p.bricks.empty,
            non_empty: p.bricks.non_empty,
            culled: p.bricks.culled,
            visible: p.bricks.visible,
        },
        ranks: p.ranks,
        ..FrameStats::default()
    })
}

/// The child side of [`point`]: median of `reps` frames, statistics on stdout.
fn run_point(a: &ExperimentArgs, job: &RenderJob, plan: &Plan, spec: &str) -> Result<()> {
    let parts: Vec<&str> = spec.split(',').collect();
    let [ranks, curve, method] = parts[..] else {
        bail!("--point: expected RANKS,CURVE,METHOD, got {spec:?}");
    };
    let ranks: usize = ranks
        .parse()
        .map_err(|_| anyhow!("--point: bad rank count {ranks:?}"))?;
    let curve: Curve = curve.parse().map_err(|e| anyhow!("--point: {e}"))?;
    let loaded;
    #[allow(clippy::cast_precision_loss)]
    let range = RangeBound::new(
        &job.grid,
        &job.sampled,
        job.settings.step,
        job.settings.ert,
        job.grid.brick_size() as f32 / 2.0,
    );
    let (mode, bound): (CullMode, Option<&dyn OpacityBound>) = match method {
        "none" => (CullMode::None, None),
        "exact" => (CullMode::Exact, None),
        "range-bound" => (CullMode::Pof, Some(&range)),
        "pof-table" => {
            let p = a
                .pof
                .as_ref()
                .ok_or_else(|| anyhow!("--point pof-table needs --pof"))?;
            loaded = job.load_pofs(p)?;
            (CullMode::Pof, Some(&loaded))
        }
        other => bail!("--point: unknown method {other:?}"),
    };
    let cam = Camera::orbit(
        &job.volume,
        plan.view[0],
        plan.view[1],
        plan.width,
        plan.height,
        Projection::Orthographic,
    );
    let m = Method {
        name: "point",
        mode,
        bound,
        missing: None,
        conservative: true,
        about: "",
    };
    let (_, st) = timed(
        job,
        &m,
        &cam,
        &opts(mode, plan.cull_threshold, ranks, curve),
        plan.reps,
    )?;
    println!("{}", serde_json::to_string(&st)?);
    Ok(())
}

/// An f32 as the f64 with the same shortest decimal form (0.05, not 0.0500000007).
fn shortest(x: f32) -> f64 {
    format!("{x}").parse().unwrap_or(f64::from(x))
}

/// One POF build (or read) of figure 1.
#[derive(Serialize)]
struct PofBuildRow {
    encoding: &'static str,
    sets: bool,
    views: String,
    source: String,
    seconds: Option<f64>,
    computed_bricks: Option<u64>,
    /// Brick-views per second per worker thread.
    rate: Option<f64>,
    bytes_per_brick_per_basis: f64,
    stored_bricks: usize,
    file_bytes: usize,
}

impl PofBuildRow {
    fn of(t: &PofTable, encoding: Encoding, source: &str, built: Option<(f64, u64)>) -> Self {
        let views = t.meta().views;
        #[allow(clippy::cast_precision_loss)]
        let rate = built.map(|(s, n)| {
            n as f64 * f64::from(views[0]) * f64::from(views[1])
                / s.max(1e-9)
                / rayon::current_num_threads() as f64
        });
        PofBuildRow {
            encoding: encoding.name(),
            sets: t.has_sets(),
            views: format!("{}x{}", views[0], views[1]),
            source: source.to_string(),
            seconds: built.map(|b| b.0),
            computed_bricks: built.map(|b| b.1),
            rate,
            bytes_per_brick_per_basis: t.bytes_per_brick_per_basis(),
            stored_bricks: t.stored_bricks(),
            file_bytes: t.file_len(),
        }
    }

    #[allow(clippy::cast_precision_loss)]
    fn file_mb(&self) -> f64 {
        self.file_bytes as f64 / 1e6
    }
}

/// Builds the POFs of `job`'s volume and family in one encoding, timed, with a progress bar.
fn build_pofs(
    job: &RenderJob,
    views: [usize; 2],
    encoding: Encoding,
    sets: bool,
    ui: &Ui,
) -> Result<(PofTable, PofBuildRow)> {
    let settings = PofSettings {
        views,
        encoding,
        sets,
        step: job.settings.step,
        ert: job.settings.ert,
        ..PofSettings::default()
    };
    let bar = ui.bar(0, &format!("fig 1: POFs, {encoding}"));
    let total = AtomicU64::new(0);
    let t = Instant::now();
    let table = PofTable::build(
        &job.volume,
        &job.grid,
        &job.tf,
        &job.sampled,
        &settings,
        &|done, n| {
            total.store(n, Ordering::Relaxed);
            bar.set_length(n);
            bar.set_position(done);
        },
    )?;
    let seconds = t.elapsed().as_secs_f64();
    bar.finish_and_clear();
    let row = PofBuildRow::of(
        &table,
        encoding,
        "built",
        Some((seconds, total.load(Ordering::Relaxed))),
    );
    Ok((table, row))
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
    fn rank_counts_double_up_to_the_maximum() {
        assert_eq!(rank_counts(1), vec![1]);
        assert_eq!(rank_counts(8), vec![1, 2, 4, 8]);
        assert_eq!(rank_counts(6), vec![1, 2, 4, 6]);
    }

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

    #[test]
    fn views_are_deterministic_and_in_range() {
        let mut a = SplitMix(7);
        let mut b = SplitMix(7);
        for _ in 0..1000 {
            let x = a.next_f64();
            assert!((0.0..1.0).contains(&x));
            assert_eq!(x.to_bits(), b.next_f64().to_bits());
        }
    }
}
