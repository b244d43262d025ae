//! `pofvr bench …`: performance reports measured in one run.

use std::time::Instant;

use anyhow::Result;
use pofvr::frame::RenderJob;
use pofvr::render::{families, Camera, Projection, RayCaster, RenderSettings};
use pofvr::volume::phantom::Phantom;
use pofvr::volume::Volume;
use serde::Serialize;

use crate::args::BenchRenderArgs;
use crate::progress::Ui;
use crate::resolve;

#[derive(Serialize)]
struct RenderCase {
    volume: String,
    view: &'static str,
    early_termination: bool,
    median_ms: f64,
    samples: u64,
    samples_per_second_per_core: f64,
}

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
    let views: [(&str, f64, f64); 2] = [("axis-aligned", 0.0, 0.0), ("oblique", 33.0, 27.0)];
    let total = (jobs.len() * views.len() * 2 * a.reps) as u64;
    let pb = ui.bar(total, "bench render");
    let threads = rayon::current_num_threads();
    let mut cases = Vec::new();
    for (name, job) in &jobs {
        for (view, az, el) in views {
            for ert in [true, false] {
                let settings = RenderSettings {
                    ert: if ert { 0.99 } else { 2.0 },
                    ..job.settings
                };
                let cls = job.sampled.classify(&job.tf.weights, settings.step);
                let cam = Camera::orbit(&job.volume, az, el, w, h, Projection::Orthographic);
                let caster = RayCaster::new(&job.volume, &cls, settings);
                let mut times = Vec::new();
                let mut samples = 0;
                for _ in 0..a.reps.max(1) {
                    let t = Instant::now();
                    let (_, st) = caster.render(&cam);
                    times.push(t.elapsed().as_secs_f64());
                    samples = st.samples;
                    pb.inc(1);
                }
                times.sort_by(f64::total_cmp);
                let med = times[times.len() / 2];
                #[allow(clippy::cast_precision_loss)]
                let per_core = samples as f64 / med / threads as f64;
                cases.push(RenderCase {
                    volume: name.clone(),
                    view,
                    early_termination: ert,
                    median_ms: med * 1e3,
                    samples,
                    samples_per_second_per_core: per_core,
                });
            }
        }
    }
    pb.finish_and_clear();
    println!(
        "{:<40} {:<13} {:>4} {:>10} {:>12} {:>16}",
        "volume", "view", "ert", "ms", "Msamples", "Msamples/s/core"
    );
    for c in &cases {
        #[allow(clippy::cast_precision_loss)]
        let ms = c.samples as f64 / 1e6;
        println!(
            "{:<40} {:<13} {:>4} {:>10.1} {:>12.2} {:>16.1}",
            c.volume,
            c.view,
            if c.early_termination { "on" } else { "off" },
            c.median_ms,
            ms,
            c.samples_per_second_per_core / 1e6
        );
    }
    let report = serde_json::json!({ "threads": threads, "image": [w, h], "cases": cases });
    pofvr::io::write_bytes_atomic(&a.out, serde_json::to_string_pretty(&report)?.as_bytes())?;
    println!("report: {}", a.out.display());
    Ok(())
}
