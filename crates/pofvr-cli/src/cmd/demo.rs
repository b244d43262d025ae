use anyhow::Result;
use pofvr::render::families;
use pofvr::volume::phantom::Phantom;
use pofvr::{Camera, FrameRequest, Projection, Scene};

use crate::args::DemoArgs;
use crate::progress::Ui;

pub(crate) fn run(a: &DemoArgs, ui: &Ui) -> Result<()> {
    let sp = ui.spinner("generating the head phantom");
    let vol = Phantom::SheppLogan.generate(a.n);
    let scene = Scene::builder(vol, families::for_phantom(Phantom::SheppLogan)).build()?;
    let cam = Camera::orbit(
        scene.volume(),
        30.0,
        20.0,
        512,
        512,
        Projection::Orthographic,
    );
    sp.set_message("rendering");
    let frame = scene.render_reference(&FrameRequest::new(&cam).shade(true))?;
    sp.finish_and_clear();
    frame.write_png(&a.out)?;
    println!(
        "wrote {} ({}³ Shepp–Logan head phantom, 512×512, {:.1} ms, {:.1} M samples)",
        a.out.display(),
        a.n,
        frame.stats.frame_ms,
        frame.stats.samples as f64 / 1e6
    );
    Ok(())
}
