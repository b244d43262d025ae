//! `pofvr bench …`: performance reports measured in one run.

use anyhow::{Context, Result};
use pofvr::cull::ideal::IdealPofs;
use pofvr::cull::OpacityBound;
use pofvr::experiment::bench_cull::{self as bench, SweepSummary, SweepView, TargetSpec};
use pofvr::frame::RenderJob;
use pofvr::render::{families, Camera, Projection, RenderSettings};
use pofvr::volume::phantom::Phantom;
use pofvr::volume::Volume;

use crate::args::{BenchCullArgs, BenchFrameArgs, BenchRenderArgs};
use crate::cmd::experiment::Bars;
use crate::progress::Ui;
use crate::resolve;

pub(crate) fn render(a: &BenchRenderArgs, ui: &Ui) -> Result<()> {
    let (w, h) = resolve::size(&a.size)?;
    let mut jobs: Vec<(String, RenderJob)> = Vec::new();
    let ph = Phantom::SheppLogan.generate(a.phantom);
    let tf = families::for_phantom(Phantom::SheppLogan);
    jobs.push((
        format!("phantom:head:{}", a.phantom),
        RenderJob::new(ph, tf, 16, RenderSettings::default())?,
    ));
    for v in &a.volumes {
        let vol = Volume::open(std::path::Path::new(v), None)?;
        let grid = pofvr::brick::BrickGrid::from_volume(&vol, 16)?;
        let tf = match &a.tf {
            Some(p) => pofvr::render::TransferFunction::from_file(p)?,
            None => families::auto_ramp(grid.value_range()),
        };
        jobs.push((
            v.clone(),
            RenderJob::new(vol, tf, 16, RenderSettings::default())?,
        ));
    }
    let bars = Bars::new(ui);
    let cases = pofvr::experiment::bench_render(&jobs, (w, h), a.reps, &bars)?;
    let threads = rayon::current_num_threads();
    println!(
        "{:<40} {:<13} {:>4} {:>10} {:>12} {:>16} {:>6} {:>12}",
        "volume", "view", "ert", "ms", "Msamples", "Msamples/s/core", "loop", "vs 1-sample"
    );
    for c in &cases {
        let ms = c.samples as f64 / 1e6;
        println!(
            "{:<40} {:<13} {:>4} {:>10.1} {:>12.2} {:>16.1} {:>6} {:>12}",
            c.volume,
            c.view,
            if c.early_termination { "on" } else { "off" },
            c.median_ms,
            ms,
            c.samples_per_second_per_core / 1e6,
            c.simd,
            c.speedup_over_one_sample_loop
                .map_or_else(|| "-".to_owned(), |r| format!("{r:.2}x"))
        );
    }
    let report = serde_json::json!({ "threads": threads, "image": [w, h], "cases": cases });
    pofvr::io::write_bytes_atomic(&a.out, serde_json::to_string_pretty(&report)?.as_bytes())?;
    println!("report: {}", a.out.display());
    Ok(())
}

pub(crate) fn frame(a: &BenchFrameArgs, ui: &Ui) -> Result<()> {
    use pofvr::experiment::bench_frame::VtkPeer;
    use pofvr::experiment::{FrameBench, FrameVolume};
    let (w, h) = resolve::size(&a.size)?;
    let specs = if a.volume.is_empty() {
        vec!["phantom:head:128".to_owned()]
    } else {
        a.volume.clone()
    };
    if a.tf.len() > specs.len() {
        anyhow::bail!(
            "--tf: {} families for {} volumes (the i-th --tf goes with the i-th --volume)",
            a.tf.len(),
            specs.len()
        );
    }
    let views = if a.view.is_empty() {
        vec![[30.0, 20.0], [0.0, 90.0]]
    } else {
        a.view
            .iter()
            .map(|v| resolve::view(v))
            .collect::<Result<_>>()?
    };
    let mut volumes = Vec::new();
    for (i, spec) in specs.iter().enumerate() {
        let sp = ui.spinner(&format!("opening and bricking {spec}"));
        let vol = self_describing_volume(spec)?;
        let tf_args = crate::args::TfArgs {
            tf: a.tf.get(i).cloned(),
            weights: None,
        };
        let tf = resolve::required_tf(&tf_args, spec)?;
        let scene = pofvr::Scene::builder(vol, tf).build()?;
        sp.finish_and_clear();
        volumes.push(FrameVolume {
            name: spec.clone(),
            scene,
        });
    }
    let peer = match (&a.peer_python, &a.peer_script) {
        (Some(python), Some(script)) => Ok(VtkPeer {
            python: python.clone(),
            script: script.clone(),
            threads: rayon::current_num_threads(),
            repeat: a.peer_repeat,
        }),
        _ => Err("no peer: --peer-python and --peer-script not given".to_owned()),
    };
    let bench = FrameBench {
        views,
        size: (w, h),
        reps: a.reps,
        rounds: usize::from(a.rounds),
        peer,
    };
    let bars = Bars::new(ui);
    let cases = pofvr::experiment::bench_frame(&volumes, &bench, &bars)?;
    let threads = rayon::current_num_threads();
    let rounds = a.rounds;
    println!(
        "{w}x{h}, {threads} threads (pofvr and VTK), orthographic; medians of {} rep(s) per round, {rounds} round(s)",
        a.reps.max(1)
    );
    println!(
        "{:<28} {:>9} {:>5} {:>8} {:>9} {:>9} {:>10} {:>10} {:>8} {:>8} {:>8} {:>8} {:>12} {:>9} {:>8}",
        "volume",
        "view",
        "shade",
        "engine",
        "ms",
        "VTK ms",
        "VTK/pofvr",
        "samp/ray",
        "min",
        "x min",
        "x floor",
        "PSNR dB",
        "Msamp/s/core",
        "k steps",
        "ns/step"
    );
    let opt = |x: Option<f64>, p: usize| x.map_or_else(|| "-".to_owned(), |v| format!("{v:.p$}"));
    for c in &cases {
        for e in &c.engines {
            println!(
                "{:<28} {:>9} {:>5} {:>8} {:>9.1} {:>9} {:>10} {:>10.1} {:>8.1} {:>8.2} {:>8.2} {:>8} {:>12.1} {:>9} {:>8}",
                short(&c.volume, 28),
                format!("{},{}", c.view[0], c.view[1]),
                if c.shade { "on" } else { "off" },
                e.engine.name(),
                e.median_ms,
                opt(c.vtk.median_ms, 1),
                opt(e.vtk_over_pofvr, 2),
                e.samples_per_ray,
                c.min_samples_per_ray,
                e.samples_over_minimum,
                e.samples_over_cell_floor,
                opt(c.vtk.psnr_db, 1),
                e.samples_per_s_per_core * 1e-6,
                opt((e.march_steps > 0).then_some(e.march_steps as f64 * 1e-3), 1),
                opt(e.core_ns_per_step, 0),
            );
        }
    }
    let mut reasons: Vec<&str> = cases
        .iter()
        .filter_map(|c| c.vtk.reason.as_deref())
        .collect();
    reasons.dedup();
    for r in reasons {
        println!("VTK not measured: {r}");
    }
    let report = serde_json::json!({
        "threads": threads,
        "image": [w, h],
        "projection": "orthographic",
        "reps": a.reps.max(1),
        "rounds": rounds,
        "engines": pofvr::experiment::FRAME_ENGINES.map(|e| e.name()),
        "cases": cases,
    });
    pofvr::io::write_bytes_atomic(&a.json, serde_json::to_string_pretty(&report)?.as_bytes())?;
    println!("report: {}", a.json.display());
    Ok(())
}

/// The last `n` characters of `s` (paths keep their distinctive end).
fn short(s: &str, n: usize) -> String {
    let count = s.chars().count();
    if count <= n {
        return s.to_owned();
    }
    let tail: String = s.chars().skip(count - (n - 1)).collect();
    format!("…{tail}")
}

/// The targets of `--targets`: a JSON list of {what, target, at_most}.
fn read_targets(path: &std::path::Path) -> Result<Vec<TargetSpec>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("--targets {}: cannot read", path.display()))?;
    serde_json::from_str(&text).with_context(|| {
        format!(
            "--targets {}: not a JSON list of {{\"what\", \"target\", \"at_most\"}}",
            path.display()
        )
    })
}

/// A volume the benches name by its spec alone (a header file or a phantom: no raw layout
/// flags), with the default 16³ bricks.
fn self_describing_volume(spec: &str) -> Result<pofvr::Volume> {
    resolve::volume(&crate::args::VolumeArgs {
        volume: spec.to_string(),
        dims: None,
        dtype: None,
        endian: "little".into(),
        spacing: None,
        header_bytes: 0,
        brick: 16,
        series: None,
        level: None,
    })
}

pub(crate) fn cull(a: &BenchCullArgs, ui: &Ui) -> Result<()> {
    let spec = a.volume.as_deref().unwrap_or("phantom:head:256");
    let specs = a.targets.as_deref().map(read_targets).transpose()?;
    let sp = ui.spinner("opening and bricking the volume");
    let vol = self_describing_volume(spec)?;
    let tf_args = crate::args::TfArgs {
        tf: a.tf.clone(),
        weights: None,
    };
    let tf = resolve::required_tf(&tf_args, spec)?;
    let job = RenderJob::new(vol, tf, 16, RenderSettings::default())?;
    sp.finish_and_clear();
    let view = resolve::view(&a.view)?;
    let (w, h) = resolve::size(&a.size)?;
    let cam = Camera::orbit(
        &job.volume,
        view[0],
        view[1],
        w,
        h,
        Projection::Orthographic,
    );
    let pofs = match &a.pof {
        Some(p) => job.load_pof_levels(p, &a.pof_level)?,
        None => {
            let settings = pofvr::pof::PofSettings {
                sets: true,
                step: job.settings.step,
                ert: job.settings.ert,
                ..Default::default()
            };
            crate::cmd::pof::build_table(
                &job.volume,
                &job.grid,
                &job.tf,
                &settings,
                None,
                ui,
                "building POFs (with sets)",
            )?
            .table
            .into()
        }
    };
    let bars = Bars::new(ui);
    let result = bench::bench_cull(&job, &pofs, &cam, a.reps, &bars)?;
    let speedup = result.speedup_pof_vs_none;
    println!(
        "volume {spec}, {w}x{h}, view {},{}; {} threads",
        view[0],
        view[1],
        rayon::current_num_threads()
    );
    let m = pofs.first().meta();
    println!(
        "POFs: {:?} method, {}x{} views, sets {}, joint {}, core lengths {:?}",
        m.method,
        m.views[0],
        m.views[1],
        m.sets,
        m.joint.is_some(),
        pofs.core_lengths()
    );
    println!(
        "{:<8} {:>5} {:>8} {:>10} {:>9} {:>8} {:>8} {:>9} {:>8} {:>9} {:>9} {:>8} {:>10}",
        "mode",
        "ranks",
        "replicas",
        "frame ms",
        "cull ms",
        "cull %",
        "culled",
        "culled %",
        "balance",
        "verify ms",
        "repair ms",
        "repaired",
        "samples"
    );
    for c in &result.cases {
        println!(
            "{:<8} {:>5} {:>8} {:>10.1} {:>9.2} {:>8.2} {:>8} {:>9.1} {:>8.3} {:>9.2} {:>9.2} {:>8} {:>10}",
            c.mode,
            c.ranks,
            c.replicas,
            c.median_frame_ms,
            c.max_cull_ms,
            100.0 * c.cull_share_of_frame,
            c.culled,
            100.0 * c.culled_fraction,
            c.load_balance_max_over_mean_samples,
            c.max_verify_ms,
            c.max_repair_ms,
            c.repaired,
            c.samples
        );
    }
    if let Some(x) = speedup {
        println!("frame time none/pof at 1 rank: {x:.2}x");
    }
    let targets = match (&specs, &a.targets) {
        (Some(s), Some(file)) => bench::evaluate_targets(s, &result.measures())
            .with_context(|| format!("--targets {}", file.display()))?,
        _ => Vec::new(),
    };
    for t in &targets {
        println!(
            "target {:<48} {:>8.3} {} {:<6} {}",
            t.what,
            t.measured,
            if t.at_most { "<=" } else { ">=" },
            t.target,
            if t.met { "met" } else { "MISSED" }
        );
    }
    // The tables' own levels (not sub-brick tables: one measured number per render brick).
    let ideal = if a.ideal {
        IdealPofs::new(
            &job.volume,
            &job.grid,
            &job.sampled,
            (job.settings.step, job.settings.ert),
            &pofs.core_lengths(),
        )
    } else {
        None
    };
    let ideal_case = match &ideal {
        Some(i) => {
            let sp = ui.spinner("culling with ideal POFs (a brick render per brick and level)");
            let st = bench::cull_once(&job, i, &cam)?;
            sp.finish_and_clear();
            let fraction = pofvr::experiment::culled_fraction(&st);
            println!(
                "ideal POFs (core minima measured at this view, core lengths {:?}): culled {} ({:.1} %)",
                pofs.core_lengths(),
                st.bricks.culled,
                100.0 * fraction
            );
            Some(serde_json::json!({
                "core_lengths": pofs.core_lengths(),
                "culled": st.bricks.culled,
                "culled_fraction": fraction,
            }))
        }
        None => None,
    };
    let sweep_report = if a.sweep > 0 {
        let ideal = ideal.as_ref().map(|i| i as &dyn OpacityBound);
        let views = bench::sweep_views(a.sweep);
        let predictor: pofvr::cull::Predictor = a
            .predictor
            .parse()
            .map_err(|e: String| anyhow::anyhow!("--predictor: {e}"))?;
        let rows = bench::sweep_with(&job, &pofs, ideal, &views, (w, h), predictor, &bars)?;
        println!("sweep: verified frames predicted by {}", predictor.name());
        let summary = SweepSummary::of(&rows);
        print_sweep(&rows, &summary);
        let mut report = serde_json::to_value(&summary)?;
        report["views"] = serde_json::to_value(&rows)?;
        Some(report)
    } else {
        None
    };
    let report = serde_json::json!({
        "volume": spec,
        "image": [w, h],
        "view": view,
        "sweep": sweep_report,
        "ideal": ideal_case,
        "threads": rayon::current_num_threads(),
        "speedup_pof_vs_none": speedup,
        "speedup_verified_vs_none": result.speedup_verified_vs_none,
        "speedup_verified_vs_none_8": result.speedup_verified_vs_none_8,
        "targets": targets,
        "pof": {
            "core_lengths": pofs.core_lengths(),
            "method": format!("{:?}", pofs.first().meta().method).to_lowercase(),
            "views": pofs.first().meta().views,
            "sets": pofs.first().meta().sets,
            "joint": pofs.first().meta().joint.is_some(),
            "margin": pofs.first().meta().margin,
        },
        "cases": result.cases,
    });
    pofvr::io::write_bytes_atomic(&a.out, serde_json::to_string_pretty(&report)?.as_bytes())?;
    println!("report: {}", a.out.display());
    Ok(())
}

/// The sweep's table and its mean and worst lines.
fn print_sweep(rows: &[SweepView], summary: &SweepSummary) {
    println!(
        "sweep over {} views (culled % of non-empty at 1 rank; balance at 32 ranks):",
        rows.len()
    );
    let ideal = |v: &SweepView| {
        v.culled_fraction_ideal
            .map_or_else(|| "-".to_owned(), |f| format!("{:.1}", 100.0 * f))
    };
    println!(
        "{:>8} {:>8} {:>7} {:>8} {:>7} {:>7} {:>11} {:>12}",
        "azimuth", "elev", "pof %", "pof-set", "ideal", "exact", "balance 32", "2 replicas"
    );
    for v in rows {
        println!(
            "{:>8.1} {:>8.1} {:>7.1} {:>8.1} {:>7} {:>7.1} {:>11.3} {:>12.3}",
            v.azimuth,
            v.elevation,
            100.0 * v.culled_fraction_pof,
            100.0 * v.culled_fraction_pof_set,
            ideal(v),
            100.0 * v.culled_fraction_exact,
            v.balance_32,
            v.balance_32_replicas_2
        );
    }
    let line = |what: &str, s: &Option<bench::Spread>| {
        if let Some(s) = s {
            println!(
                "sweep {what:<40} mean {:>7.3}  worst {:>7.3} at {:.1},{:.1}",
                s.mean, s.worst, s.worst_view[0], s.worst_view[1]
            );
        }
    };
    line(
        "points culled below exact (pof)",
        &summary.points_below_exact_pof,
    );
    line(
        "points culled below exact (pof-set)",
        &summary.points_below_exact_pof_set,
    );
    line(
        "points culled below exact (ideal POFs)",
        &summary.points_below_exact_ideal,
    );
    line(
        "points rendered over exact (verified)",
        &summary.points_rendered_over_exact_verified,
    );
    line(
        "repaired % of rendered (verified)",
        &summary.repaired_percent_verified,
    );
    line(
        "rule violations (verified, pixels)",
        &summary.rule_violations_verified,
    );
    line("load balance at 32 ranks (1 replica)", &summary.balance_32);
    line(
        "load balance at 32 ranks (2 replicas)",
        &summary.balance_32_replicas_2,
    );
}
