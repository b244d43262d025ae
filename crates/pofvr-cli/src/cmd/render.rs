use std::time::Instant;

use anyhow::{Context, Result};
use pofvr::frame::{render_reference, RenderJob};
use pofvr::render::Image;

use crate::args::RenderArgs;
use crate::progress::Ui;
use crate::resolve;

pub(crate) fn run(a: &RenderArgs, ui: &Ui) -> Result<()> {
    let t0 = Instant::now();
    let sp = ui.spinner("opening and bricking the volume");
    let vol = resolve::volume(&a.volume)?;
    let tf = resolve::required_tf(&a.tf, &a.volume.volume)?;
    let cam = resolve::camera(&a.view, &vol)?;
    let job = RenderJob::new(vol, tf, a.volume.brick, resolve::settings(&a.view))?;
    sp.set_message("rendering");
    let (image, stats) = render_reference(&job, &cam);
    sp.finish_and_clear();
    image.write_png(&a.out)?;
    if let Some(p) = &a.out_raw {
        image.write_raw(p)?;
    }
    resolve::write_camera(&a.view, &cam)?;
    if let Some(p) = &a.stats {
        let json = serde_json::to_string_pretty(&stats)?;
        pofvr::io::write_bytes_atomic(p, json.as_bytes())?;
    }
    eprintln!(
        "{}: {}×{} in {:.1} ms, {} rays, {:.1} M samples ({:.0} M samples/s), total {:.2} s",
        a.out.display(),
        cam.width,
        cam.height,
        stats.frame_ms,
        stats.rays,
        stats.samples as f64 / 1e6,
        stats.samples_per_second / 1e6,
        t0.elapsed().as_secs_f64()
    );
    if let Some(r) = &a.reference {
        let reference = Image::read_raw(r, cam.width, cam.height)
            .with_context(|| format!("--reference {}", r.display()))?;
        println!(
            "reference {}: rmse {:.3e}, max abs diff {:.3e}",
            r.display(),
            image.rmse(&reference).unwrap_or(f64::NAN),
            image.max_abs_diff(&reference).unwrap_or(f32::NAN)
        );
    }
    Ok(())
}
