use anyhow::Result;
use pofvr::frame::{render_reference, RenderJob};
use pofvr::render::{families, Camera, Projection, RenderSettings};
use pofvr::volume::phantom::Phantom;

use crate::args::DemoArgs;
use crate::progress::Ui;

pub(crate) fn run(a: &DemoArgs, ui: &Ui) -> Result<()> {
    let sp = ui.spinner("generating the head phantom");
    let vol = Phantom::SheppLogan.generate(a.n);
    let cam = Camera::orbit(&vol, 30.0, 20.0, 512, 512, Projection::Orthographic);
    let settings = RenderSettings {
        shade: true,
        ..RenderSettings::default()
    };
    let job = RenderJob::new(
        vol,
        families::for_phantom(Phantom::SheppLogan),
        16,
        settings,
    )?;
    sp.set_message("rendering");
    let (image, stats) = render_reference(&job, &cam);
    sp.finish_and_clear();
    image.write_png(&a.out)?;
    println!(
        "wrote {} ({}³ Shepp–Logan head phantom, 512×512, {:.1} ms, {:.1} M samples)",
        a.out.display(),
        a.n,
        stats.frame_ms,
        stats.samples as f64 / 1e6
    );
    Ok(())
}
