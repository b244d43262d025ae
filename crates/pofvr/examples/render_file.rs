//! Renders one culled frame of a volume file to a PNG through the [`pofvr::Scene`] facade.
//!
//! ```text
//! cargo run --release --example render_file -- [VOLUME TF.json] [--pof FILE.pof] [--out OUT.png]
//! ```
//!
//! Without a volume it renders the built-in head phantom with its family, skin weighted
//! up. POFs are loaded
//! from `--pof` when given, otherwise built for the scene on the spot (a coarse view grid,
//! to stay quick). Raw volumes need a header (NRRD, MetaImage, NIfTI).

use std::path::PathBuf;
use std::process::ExitCode;

use pofvr::render::families;
use pofvr::volume::phantom::Phantom;
use pofvr::{Camera, Cull, FrameRequest, PofBuild, Projection, Scene, TransferFunction, Volume};

struct Args {
    input: Option<(PathBuf, PathBuf)>,
    pof: Option<PathBuf>,
    out: PathBuf,
}

fn args() -> Result<Args, String> {
    let mut positional = Vec::new();
    let (mut pof, mut out) = (None, PathBuf::from("render_file.png"));
    let mut it = std::env::args_os().skip(1);
    while let Some(a) = it.next() {
        match a.to_str() {
            Some("--pof") => pof = Some(it.next().ok_or("--pof needs a file")?.into()),
            Some("--out") => out = it.next().ok_or("--out needs a file")?.into(),
            Some("-h" | "--help") => return Err(String::new()),
            _ => positional.push(PathBuf::from(a)),
        }
    }
    let input = match <[PathBuf; 2]>::try_from(positional) {
        Ok([volume, tf]) => Some((volume, tf)),
        Err(p) if p.is_empty() => None,
        Err(_) => return Err("expected a volume and its TF.json, or nothing".into()),
    };
    Ok(Args { input, pof, out })
}

fn run(a: &Args) -> pofvr::Result<()> {
    let (volume, family) = match &a.input {
        Some((v, tf)) => (Volume::open(v, None)?, TransferFunction::from_file(tf)?),
        None => {
            // Skin weighted up, so that the brain hides much of what is behind it.
            let mut family = families::for_phantom(Phantom::SheppLogan);
            family.weights = vec![3.0, 1.0];
            (Phantom::SheppLogan.generate(96), family)
        }
    };
    let scene = Scene::builder(volume, family).brick_size(8).build()?;
    let scene = match &a.pof {
        Some(p) => scene.load_pofs(p)?,
        None => {
            let pofs = scene.build_pofs(&PofBuild {
                views: [12, 12],
                ..PofBuild::default()
            })?;
            scene.with_pofs(pofs)?
        }
    };
    let camera = Camera::orbit(scene.volume(), 0.0, 0.0, 384, 384, Projection::Orthographic);
    let pofs = scene.pofs().expect("the scene was given POFs above");
    let request = FrameRequest::new(&camera).cull(Cull::Pof(pofs));
    let frame = scene.render(&request)?;
    frame.write_png(&a.out)?;
    let b = frame.stats.bricks;
    println!(
        "{}: {}×{} in {:.1} ms; {} of {} non-empty bricks culled, {} rendered",
        a.out.display(),
        camera.width,
        camera.height,
        frame.stats.frame_ms,
        b.culled,
        b.non_empty,
        b.visible
    );
    Ok(())
}

fn main() -> ExitCode {
    let a = match args() {
        Ok(a) => a,
        Err(e) => {
            if !e.is_empty() {
                eprintln!("render_file: {e}");
            }
            eprintln!("usage: render_file [VOLUME TF.json] [--pof FILE.pof] [--out OUT.png]");
            return ExitCode::from(2);
        }
    };
    match run(&a) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("render_file: {e}");
            ExitCode::FAILURE
        }
    }
}
