//! Sweeps one basis weight over one `Arc<Scene>`: worker threads share the scene and each
//! renders its own weights, which the frame request carries, with no lock and no copy.
//!
//! ```text
//! cargo run --release --example weights_sweep -- [BASIS] [STEPS]
//! ```
//!
//! On the built-in head phantom with POFs built for it, prints per weight of basis `BASIS`
//! (default 0, "skin") the bricks culled and the frame time.

use std::sync::{Arc, Mutex};

use pofvr::render::families;
use pofvr::volume::phantom::Phantom;
use pofvr::{Camera, Cull, Frame, FrameRequest, PofBuild, Projection, Scene};

fn main() -> pofvr::Result<()> {
    let mut args = std::env::args().skip(1);
    let basis: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(0);
    let steps: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(9);

    let volume = Phantom::SheppLogan.generate(96);
    let scene = Scene::builder(volume, families::for_phantom(Phantom::SheppLogan))
        .brick_size(8)
        .build()?;
    let pofs = scene.build_pofs(&PofBuild {
        views: [12, 12],
        ..PofBuild::default()
    })?;
    let scene = Arc::new(scene.with_pofs(pofs)?);
    let bases = scene.family().bases.len();
    if basis >= bases {
        eprintln!("weights_sweep: basis {basis} of a family of {bases}");
        std::process::exit(2);
    }
    let camera = Camera::orbit(scene.volume(), 0.0, 0.0, 384, 384, Projection::Orthographic);

    // The weights of each step: the family's, with basis `basis` swept over [0, 4].
    let sweep: Vec<Vec<f32>> = (0..steps)
        .map(|i| {
            let mut w = scene.default_weights().to_vec();
            w[basis] = 4.0 * i as f32 / (steps.max(2) - 1) as f32;
            w
        })
        .collect();
    let next = Mutex::new(0..sweep.len());
    let results: Mutex<Vec<Option<Frame>>> = Mutex::new(vec![None; sweep.len()]);
    let outcomes: Vec<pofvr::Result<()>> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..2)
            .map(|_| {
                let scene = Arc::clone(&scene);
                let (sweep, next, results, camera) = (&sweep, &next, &results, &camera);
                s.spawn(move || -> pofvr::Result<()> {
                    while let Some(i) = next.lock().expect("no worker panics").next() {
                        let pofs = scene.pofs().expect("the scene has POFs");
                        let request = FrameRequest::new(camera)
                            .weights(&sweep[i])
                            .cull(Cull::Pof(pofs));
                        let frame = scene.render(&request)?;
                        results.lock().expect("no worker panics")[i] = Some(frame);
                    }
                    Ok(())
                })
            })
            .collect();
        workers
            .into_iter()
            .map(|w| w.join().expect("no worker panics"))
            .collect()
    });
    for outcome in outcomes {
        outcome?;
    }
    let name = &scene.family().bases[basis].name;
    println!("weight of {name:>8}  culled / non-empty  frame ms");
    for (w, frame) in sweep
        .iter()
        .zip(results.into_inner().expect("no worker panics"))
    {
        let frame = frame.expect("every weight was rendered");
        let b = frame.stats.bricks;
        println!(
            "{:>17.2}  {:>7} / {:<9}  {:>8.1}",
            w[basis], b.culled, b.non_empty, frame.stats.frame_ms
        );
    }
    Ok(())
}
