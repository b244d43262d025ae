//! `pofvr experiment`: the paper's §5 experiments on a user's volume, written as a report
//! (`index.html`, SVG charts, PNG images, and the numbers behind each as CSV and JSON).
//!
//! The measurements are [`pofvr::experiment`]'s; this command resolves the flags, runs
//! them in figure order and hands each result to [`crate::report::experiment`].
//! Experiments whose inputs this run cannot produce (POF sets) are reported as not
//! available, with the reason, instead of being left out silently.

use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{anyhow, bail, Result};
use clap::Args;
use indicatif::ProgressBar;
use pofvr::cull::CullMode;
use pofvr::experiment::{self as exp, Method, PofSource, Progress};
use pofvr::frame::RenderJob;
use pofvr::pof::Encoding;
use pofvr::render::{Camera, Projection, RenderSettings};
use serde::Serialize;
use serde_json::json;

use crate::args::{TfArgs, VolumeArgs};
use crate::progress::Ui;
use crate::report::experiment::{self as report, shortest, Page};
use crate::report::{esc, ReportDir};
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
    /// Seed of the audit's random views.
    /// > default: 1
    #[arg(long, default_value_t = 1)]
    pub(crate) seed: u64,
    /// At most this much memory for the volume's voxels (e.g. 256M, 4G), as `render
    /// --memory-budget`: a volume larger than that has its bricks' value ranges measured by
    /// streaming the file, and every brick-engine frame of the figures reads the bricks it
    /// renders on demand into one LRU cache within the budget. The POF builds (figure 1)
    /// stream the volume slab by slab from the store (the same tables), the unculled frames
    /// the threshold rule is checked against are brick-engine frames read through the store,
    /// and the exact oracle, which samples the whole lattice, is not measured (said on
    /// stderr, in `report.json` and on the page). `report.json` gains a `memory_budget`
    /// entry (bytes and bricks read, cache hits, cache peak, peak RSS, what was streamed and
    /// what was left out).
    /// > default: none (the whole volume is mapped)
    #[arg(long, value_name = "SIZE")]
    pub(crate) memory_budget: Option<String>,
}

/// Resolved settings of a run (`plan` in `report.json`).
#[derive(Serialize, Clone)]
pub(crate) struct Plan {
    pub(crate) width: u32,
    pub(crate) height: u32,
    pub(crate) quick: bool,
    pub(crate) max_ranks: usize,
    pub(crate) breakdown_ranks: usize,
    pub(crate) rank_counts: Vec<usize>,
    pub(crate) audit_views: usize,
    pub(crate) view: [f64; 2],
    pub(crate) cull_threshold: f32,
    pub(crate) reps: usize,
    pub(crate) seed: u64,
    pub(crate) step: f32,
    pub(crate) ert: f32,
    pub(crate) brick: usize,
    pub(crate) projection: &'static str,
    pub(crate) pof_views: [usize; 2],
}

impl Plan {
    /// The flags resolved, with the `--quick` defaults where they differ.
    fn of(a: &ExperimentArgs) -> Result<Self> {
        let (width, height) = resolve::size(a.size.as_deref().unwrap_or(if a.quick {
            "128x128"
        } else {
            "512x512"
        }))?;
        let max_ranks = a.max_ranks.unwrap_or(if a.quick { 4 } else { 8 });
        if !(1..=256).contains(&max_ranks) {
            bail!("--max-ranks {max_ranks} must be in 1..=256");
        }
        let breakdown_ranks = a.breakdown_ranks.unwrap_or(max_ranks);
        if !(1..=256).contains(&breakdown_ranks) {
            bail!("--breakdown-ranks {breakdown_ranks} must be in 1..=256");
        }
        let view = resolve::view(&a.view)?;
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
        Ok(Plan {
            width,
            height,
            quick: a.quick,
            max_ranks,
            breakdown_ranks,
            rank_counts: exp::rank_counts(max_ranks),
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
        })
    }
}

/// The library's progress drawn as one indicatif bar per stage.
pub(crate) struct Bars<'a> {
    ui: &'a Ui,
    bar: Mutex<Option<ProgressBar>>,
}

impl<'a> Bars<'a> {
    pub(crate) fn new(ui: &'a Ui) -> Self {
        Bars {
            ui,
            bar: Mutex::new(None),
        }
    }

    fn with(&self, f: impl FnOnce(&ProgressBar)) {
        if let Some(b) = self.bar.lock().unwrap_or_else(|e| e.into_inner()).as_ref() {
            f(b);
        }
    }
}

impl Progress for Bars<'_> {
    fn begin(&self, what: &str, len: u64) {
        *self.bar.lock().unwrap_or_else(|e| e.into_inner()) = Some(self.ui.bar(len, what));
    }
    fn set(&self, done: u64, len: u64) {
        self.with(|b| {
            b.set_length(len);
            b.set_position(done);
        });
    }
    fn inc(&self) {
        self.with(|b| b.inc(1));
    }
    fn end(&self) {
        if let Some(b) = self.bar.lock().unwrap_or_else(|e| e.into_inner()).take() {
            b.finish_and_clear();
        }
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

/// The table encoding from `--pof` when the file exists.
fn read_table(a: &ExperimentArgs, job: &RenderJob, ui: &Ui) -> Result<PofSource> {
    let Some(p) = a.pof.as_ref().filter(|p| p.exists()) else {
        return Ok(PofSource::Build);
    };
    let sp = ui.spinner(&format!("reading {}", p.display()));
    let table = job.load_pofs(p)?;
    sp.finish_and_clear();
    if table.meta().encoding != Encoding::Table {
        bail!(
            "--pof {}: holds {} POFs; the experiment reads the table encoding \
             (build it with `pofvr pof build --encoding table`)",
            p.display(),
            table.meta().encoding
        );
    }
    Ok(PofSource::Read {
        table: Box::new(table),
        from: p.display().to_string(),
    })
}

/// Why the POF-set method is not measured when the sets were not built.
const NO_SETS: &str = "not measured: POF sets were not built (they are skipped with --quick for \
                       their build cost; pass --pof-sets)";

pub(crate) fn run(a: &ExperimentArgs, ui: &Ui) -> Result<()> {
    let t_start = Instant::now();
    let plan = Plan::of(a)?;
    let budget = super::render::memory_budget(a.memory_budget.as_deref())?;
    let (width, height, thr) = (plan.width, plan.height, plan.cull_threshold);
    let mach = machine();
    let sp = ui.spinner("opening and bricking the volume");
    let vol = resolve::volume(&a.volume)?;
    let tf = resolve::required_tf(&a.tf, &a.volume.volume)?;
    let grid = pofvr::store::grid_for(&vol, a.volume.brick, budget)?;
    let store = pofvr::store::cache_for(&vol, budget)?;
    let mut job = RenderJob::with_grid(vol, tf, grid, RenderSettings::default())?;
    job.store = store;
    sp.finish_and_clear();
    let mut out = ReportDir::create(&a.out)?;
    let bars = Bars::new(ui);
    let base_weights = job.tf.weights.clone();
    let names: Vec<String> = job.tf.bases.iter().map(|b| b.name.clone()).collect();
    let mut summary = serde_json::Map::new();

    // Figure 1 first: the culling methods below read its tables.
    let source = read_table(a, &job, ui)?;
    let want_sets = a.pof_sets.unwrap_or(!a.quick);
    let pofs = exp::pof_construction(&job, plan.pof_views, source, want_sets, &bars)?;
    if let (true, Some(p)) = (pofs.table_built, &a.pof) {
        pofs.table.save(p)?;
    }
    let fig1 = report::fig1(&mut out, &plan, &pofs.rows, names.len())?;
    summary.insert("pof_construction".into(), fig1);

    let range = exp::range_bound(&job);
    let mut methods = exp::methods(&pofs, &range, NO_SETS);
    // Under a budget the volume does not fit, what would sample the whole lattice is left
    // out, said here, in report.json (`methods_not_measured`) and on the page.
    let left_out = exp::honour_budget(&mut methods, &job);
    for name in &left_out {
        eprintln!("note: {name} {}", exp::NO_EXACT_UNDER_BUDGET);
    }
    let primary = *exp::primary(&methods)?;
    let avail: Vec<Method<'_>> = methods.iter().copied().filter(Method::available).collect();
    let culling: Vec<Method<'_>> = avail
        .iter()
        .copied()
        .filter(|m| m.mode != CullMode::None)
        .collect();
    let timed = [Method::none(), primary];
    // The view of figures 5, 6 and 8.
    let cam = Camera::orbit(
        &job.volume,
        plan.view[0],
        plan.view[1],
        width,
        height,
        Projection::Orthographic,
    );

    let fig4 = exp::culling_vs_view(&job, &avail, thr, (width, height), &bars)?;
    report::fig4(&mut out, &fig4)?;
    summary.insert("culling_vs_view".into(), serde_json::to_value(&fig4.means)?);

    // Fig. 5 also shows verified culling's verify and repair time per rank.
    let fig5_methods = [Method::none(), primary, Method::verified()];
    let fig5 = exp::rank_breakdown(
        &job,
        &fig5_methods,
        &cam,
        thr,
        plan.breakdown_ranks,
        plan.reps,
        &bars,
    )?;
    report::fig5(&mut out, &fig5)?;
    summary.insert("rank_breakdown".into(), serde_json::to_value(&fig5.frames)?);

    let fig6 = exp::speedup(&job, &timed, &cam, thr, &plan.rank_counts, plan.reps, &bars)?;
    report::fig6(&mut out, &fig6)?;
    summary.insert("speedup".into(), serde_json::to_value(&fig6.best)?);

    let grid = exp::weight_grid(a.quick);
    let fig8 = exp::tf_family(
        &mut job,
        &culling,
        &primary,
        &cam,
        thr,
        (&grid.0, &grid.1),
        &bars,
    )?;
    let fig8_methods: Vec<&str> = culling.iter().map(|m| m.name).collect();
    let fig8_images = report::fig8(&mut out, &fig8, &fig8_methods, &names)?;
    summary.insert("tf_family_images".into(), fig8_images.clone());

    let audit = exp::audit(
        &job,
        &culling,
        thr,
        plan.audit_views,
        plan.seed,
        (width, height),
        &bars,
    )?;
    summary.insert("audit".into(), report::audit(&mut out, &audit, &methods)?);

    let b = job.grid.counts();
    let dims = job.volume.dims();
    let intro = format!(
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
    );
    let html = report::page(
        &Page {
            intro,
            plan: &plan,
            methods: &methods,
            primary: primary.name,
            machine: &mach,
            pof_rows: &pofs.rows,
            fig4: &fig4,
            fig5: &fig5,
            fig6: &fig6,
            fig8_methods: &fig8_methods,
            fig8_images: &fig8_images,
            k_names: report::k_names(&names),
            audit: &audit,
        },
        &format!("pofvr experiment: {}", a.volume.volume),
    );
    out.record("index.html");
    out.record("report.json");
    let mut report = json!({
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
    if let (Some(b), Some(m)) = (budget, report.as_object_mut()) {
        let mut entry = super::render::budget_json(&job.volume, job.store.as_deref(), b)?;
        if let (Some(e), Some(store)) = (entry.as_object_mut(), job.store.as_deref()) {
            let kind = store.source().kind();
            e.insert(
                "experiment".into(),
                json!({
                    "pof_build": format!("streamed slab by slab from the {kind}"),
                    "pof_build_bytes_read": pofs
                        .rows
                        .iter()
                        .filter_map(|r| r.bytes_read)
                        .sum::<u64>(),
                    "reference": format!(
                        "unculled brick-engine frames (cull none), bricks read through the \
                         brick store from the {kind}"
                    ),
                    "methods_not_measured": left_out
                        .iter()
                        .map(|n| json!({"method": n, "reason": exp::NO_EXACT_UNDER_BUDGET}))
                        .collect::<Vec<_>>(),
                }),
            );
        }
        m.insert("memory_budget".into(), entry);
    }
    out.write("index.html", html.as_bytes())?;
    out.json("report.json", &report)?;

    eprintln!(
        "report: {} ({} files, {:.1} s)",
        out.path("index.html").display(),
        out.files().len(),
        t_start.elapsed().as_secs_f64()
    );
    for m in &fig4.means {
        eprintln!(
            "  {:<12} mean visible {:9.1}   culled {:5.1} % of non-empty",
            m.method,
            m.mean_visible,
            100.0 * m.mean_culled_fraction_of_non_empty
        );
    }
    if let Some(b) = &fig6.best {
        eprintln!(
            "  best speedup {:.2}x at {} ranks ({})",
            b.speedup, b.ranks, b.best
        );
    }
    if let Some(store) = job.store.as_deref() {
        let c = store.summary();
        eprintln!(
            "  memory budget {:.1} MB: {} bricks ({:.1} MB) read on demand from the {}, {} cache hits, cache peak {:.1} MB, peak RSS {:.1} MB",
            c.budget_bytes as f64 / 1e6,
            c.bricks_read,
            c.bytes_read as f64 / 1e6,
            store.source().kind(),
            c.cache_hits,
            c.cache_peak_bytes as f64 / 1e6,
            pofvr::store::peak_rss_bytes() as f64 / 1e6
        );
    }
    let violations = audit.conservative_violations;
    eprintln!(
        "  audit: {violations} pixels break the rule over {} views",
        plan.audit_views
    );
    if !audit.passed() {
        return Err(anyhow!(
            "conservativeness audit failed: {violations} pixels break the rule (see {})",
            out.path("audit.csv").display()
        ));
    }
    Ok(())
}
