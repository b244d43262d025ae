use std::time::Instant;

use anyhow::{Context, Result};
use pofvr::cull::CullMode;
use pofvr::frame::{render_frame, render_reference, FrameOptions, RenderJob};
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
    let (image, stats) = if a.frame.whole {
        render_reference(&job, &cam)
    } else {
        let cull: CullMode = match (&a.frame.cull, &a.frame.pof) {
            (Some(c), _) => c
                .parse()
                .map_err(|e: String| anyhow::anyhow!("--cull: {e}"))?,
            (None, Some(_)) => CullMode::Pof,
            (None, None) => CullMode::None,
        };
        let pofs = match &a.frame.pof {
            Some(p) => Some(job.load_pofs(p)?),
            None => None,
        };
        if cull == CullMode::PofSet && !pofs.as_ref().is_some_and(pofvr::pof::PofTable::has_sets) {
            anyhow::bail!("--cull pof-set needs a POF file built with --sets");
        }
        let bounds = pofs.as_ref().map(|t| t as &dyn pofvr::cull::OpacityBound);
        let opts = FrameOptions {
            cull,
            cull_threshold: a.frame.cull_threshold,
            ranks: a.frame.ranks,
            curve: a
                .frame
                .curve
                .parse()
                .map_err(|e| anyhow::anyhow!("--curve: {e}"))?,
        };
        render_frame(&job, bounds, &cam, &opts)?
    };
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
    if let Some(mode) = stats.cull {
        let b = stats.bricks;
        eprintln!(
            "bricks: {} total, {} empty, {} non-empty, {} culled ({:.1}% of non-empty) by {}, {} visible",
            b.total,
            b.empty,
            b.non_empty,
            b.culled,
            100.0 * b.culled as f64 / b.non_empty.max(1) as f64,
            mode.name(),
            b.visible
        );
    }
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
