//! `bench frame`: per volume and view, the frame time of each engine shaded and unshaded,
//! samples per ray against the minimum ([`min_samples`]), and the same frame rendered by
//! VTK in the same run ([`vtk_peer`]) with the time ratio and the image PSNR.

mod min_samples;
pub mod npy;
pub mod vtk_peer;

use std::time::Instant;

use serde::Serialize;

use crate::render::{Camera, Image, Projection};
use crate::{Engine, Frame, FrameRequest, Scene};

pub use min_samples::{minimum_samples, SampleBounds};
pub use vtk_peer::{PeerVolume, VtkFrame, VtkPeer};

use super::{ExperimentError, Progress};

/// A way of rendering a frame of a [`Scene`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FrameEngine {
    /// The whole volume in one pass, no bricks ([`Scene::render_reference`]).
    Whole,
    /// Brick by brick, one rank, no culling ([`Engine::Bricks`]).
    Bricks,
    /// Whole rays with empty-space skipping ([`Engine::March`]).
    March,
}

/// The engines measured, in report order; the first is the reference the others' images
/// are compared with.
pub const FRAME_ENGINES: [FrameEngine; 3] =
    [FrameEngine::Whole, FrameEngine::Bricks, FrameEngine::March];

impl FrameEngine {
    /// The name the report uses.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            FrameEngine::Whole => "whole",
            FrameEngine::Bricks => "bricks",
            FrameEngine::March => "march",
        }
    }

    fn render(self, scene: &Scene, req: &FrameRequest<'_>) -> crate::Result<Frame> {
        match self {
            FrameEngine::Whole => scene.render_reference(req),
            FrameEngine::Bricks => scene.render(&req.clone().engine(Engine::Bricks)),
            FrameEngine::March => scene.render(&req.clone().engine(Engine::March)),
        }
    }
}

/// A volume to measure.
pub struct FrameVolume {
    /// The name as given.
    pub name: String,
    /// The scene (volume, bricks, family at its default weights).
    pub scene: Scene,
}

/// One engine's frame.
#[derive(Clone, Debug, Serialize)]
pub struct EngineFrame {
    /// The engine.
    pub engine: FrameEngine,
    /// Median frame time: the median of `round_ms`.
    pub median_ms: f64,
    /// The median frame time of each round ([`FrameBench::rounds`]), in order.
    pub round_ms: Vec<f64>,
    /// Samples taken.
    pub samples: u64,
    /// Samples per ray that meets the volume.
    pub samples_per_ray: f64,
    /// `samples_per_ray` over the minimum.
    pub samples_over_minimum: f64,
    /// `samples_per_ray` over the floor of an exact empty-space skip
    /// ([`FrameCase::cell_floor_samples_per_ray`]).
    pub samples_over_cell_floor: f64,
    /// Largest per-channel difference from the first engine's image.
    pub max_abs_diff_vs_whole: f32,
    /// VTK's frame time over this engine's, when VTK was measured: the median over rounds
    /// of each round's ratio, so that a machine that speeds up or slows down between
    /// rounds moves both sides of a ratio together.
    pub vtk_over_pofvr: Option<f64>,
    /// Samples taken per second of the median frame and per worker thread: what one core
    /// gets through, set-up and empty-space walk included.
    pub samples_per_s_per_core: f64,
    /// The march engine's packet-loop steps (`--stats`' `march_steps`; 0 for the other
    /// engines and where no packet loop runs).
    pub march_steps: u64,
    /// Core time per packet-loop step: the median frame times the worker threads over
    /// `march_steps` (`None` where there are none). With `march_steps` it splits a frame
    /// into how many steps and what each costs.
    pub core_ns_per_step: Option<f64>,
}

/// VTK's side of one frame: measured, or the reason it was not.
#[derive(Clone, Debug, Serialize)]
pub struct VtkCase {
    /// Whether VTK rendered the frame.
    pub measured: bool,
    /// Why not, when not.
    pub reason: Option<String>,
    /// The VTK version.
    pub version: Option<String>,
    /// Median re-render time: the median of `round_ms`.
    pub median_ms: Option<f64>,
    /// The median re-render time of each round's VTK process, in order. VTK's times move
    /// by up to half from one process to the next on the same frame (`docs/results.md`,
    /// stop 34), more than they move within one.
    pub round_ms: Vec<f64>,
    /// The first render.
    pub first_render_ms: Option<f64>,
    /// PSNR of VTK's float image against the whole-volume image (dB, peak 1).
    pub psnr_db: Option<f64>,
}

/// One frame: a volume, a view, shaded or not.
#[derive(Clone, Debug, Serialize)]
pub struct FrameCase {
    /// The volume's name as given.
    pub volume: String,
    /// Azimuth and elevation, degrees.
    pub view: [f64; 2],
    /// Gradient shading.
    pub shade: bool,
    /// Rays that meet the volume.
    pub rays: u64,
    /// The fewest samples per ray: those of nonzero alpha ([`minimum_samples`]).
    pub min_samples_per_ray: f64,
    /// The fewest samples per ray an engine that skips only what it knows to be empty can
    /// take: those whose trilinear cell can hold opacity ([`SampleBounds::cell_floor`]).
    pub cell_floor_samples_per_ray: f64,
    /// Each engine's frame.
    pub engines: Vec<EngineFrame>,
    /// VTK's frame.
    pub vtk: VtkCase,
}

/// What `bench frame` measures with.
#[derive(Clone, Debug)]
pub struct FrameBench {
    /// Views (azimuth, elevation in degrees), orthographic.
    pub views: Vec<[f64; 2]>,
    /// Image size.
    pub size: (u32, u32),
    /// Repetitions per engine and round (at least one; the median is reported).
    pub reps: usize,
    /// Rounds (at least one): each frame is measured this many times over, every engine's
    /// repetitions then a VTK process of its own, and the rounds' medians and ratios are
    /// reported with their median.
    pub rounds: usize,
    /// The VTK peer, or why there is none.
    pub peer: Result<VtkPeer, String>,
}

/// Measures every volume at every view, unshaded then shaded, with every engine of
/// [`FRAME_ENGINES`] and VTK.
///
/// # Errors
/// A frame's error; [`ExperimentError::Check`] when an engine's image differs from the
/// reference's by more than early termination and float rounding allow.
pub fn bench_frame(
    volumes: &[FrameVolume],
    bench: &FrameBench,
    progress: &dyn Progress,
) -> Result<Vec<FrameCase>, ExperimentError> {
    let rounds = bench.rounds.max(1);
    let per_frame = ((FRAME_ENGINES.len() * bench.reps.max(1) + 1) * rounds) as u64;
    progress.begin(
        "bench frame",
        volumes.len() as u64 * bench.views.len() as u64 * 2 * per_frame,
    );
    let mut cases = Vec::new();
    for (i, fv) in volumes.iter().enumerate() {
        let scene = &fv.scene;
        let weights = scene.default_weights();
        let peer_volume = match &bench.peer {
            Ok(_) => PeerVolume::write(scene.volume(), i)
                .map_err(|e| format!("cannot write the raw volume for VTK: {e}")),
            Err(e) => Err(e.clone()),
        };
        for &[az, el] in &bench.views {
            let (w, h) = bench.size;
            let cam = Camera::orbit(scene.volume(), az, el, w, h, Projection::Orthographic);
            let bounds = minimum_samples(scene, weights, &cam);
            let rays = bounds.rays;
            let min_per_ray = bounds.visible as f64 / rays.max(1) as f64;
            let floor_per_ray = bounds.cell_floor as f64 / rays.max(1) as f64;
            for shade in [false, true] {
                let req = FrameRequest::new(&cam).shade(shade);
                // Per engine, the median of each round.
                let mut round_ms = vec![Vec::new(); FRAME_ENGINES.len()];
                let mut frames: Vec<Option<Frame>> = vec![None; FRAME_ENGINES.len()];
                let mut vtk_rounds = Vec::new();
                for _ in 0..rounds {
                    let mut times = vec![Vec::new(); FRAME_ENGINES.len()];
                    for _ in 0..bench.reps.max(1) {
                        // Interleaved, so that every engine sees the same machine.
                        for (k, engine) in FRAME_ENGINES.iter().enumerate() {
                            let t = Instant::now();
                            let f = engine.render(scene, &req)?;
                            times[k].push(t.elapsed().as_secs_f64() * 1e3);
                            frames[k] = Some(f);
                            progress.inc();
                        }
                    }
                    for (r, t) in round_ms.iter_mut().zip(times) {
                        r.push(median(t));
                    }
                    vtk_rounds.push(match (&bench.peer, &peer_volume) {
                        (Ok(peer), Ok(pv)) => peer.render(pv, scene.family(), weights, &cam, shade),
                        (_, Err(e)) => Err(e.clone()),
                        (Err(e), _) => Err(e.clone()),
                    });
                    progress.inc();
                }
                let frames: Vec<Frame> = frames.into_iter().flatten().collect();
                let reference = &frames[0].image;
                // A brick stops its part of a ray at the termination opacity without knowing
                // what lies in front, so a pixel may take up to `1 − ert` more than the whole
                // ray, which stops once: that, plus float rounding, is what engines may differ by.
                let tolerance = (1.0 - scene.early_termination()).max(0.0) + 1e-5;
                // Every round's VTK frame, or the first reason one failed.
                let vtk = vtk_case(vtk_rounds.into_iter().collect(), reference);
                let vtk_ms = vtk.measured.then_some(&vtk.round_ms);
                let mut engines = Vec::new();
                let threads = rayon::current_num_threads() as f64;
                for ((engine, rt), f) in FRAME_ENGINES.iter().zip(round_ms).zip(&frames) {
                    let median_ms = median(rt.clone());
                    let diff = reference.max_abs_diff(&f.image).unwrap_or(f32::INFINITY);
                    if diff > tolerance {
                        return Err(ExperimentError::Check(format!(
                            "{}: the {} engine's image differs from the whole frame by {diff}",
                            fv.name,
                            engine.name()
                        )));
                    }
                    let per_ray = f.stats.samples as f64 / rays.max(1) as f64;
                    engines.push(EngineFrame {
                        engine: *engine,
                        median_ms,
                        vtk_over_pofvr: vtk_ms
                            .map(|v| median(v.iter().zip(&rt).map(|(v, p)| v / p).collect())),
                        round_ms: rt,
                        samples: f.stats.samples,
                        samples_per_ray: per_ray,
                        samples_over_minimum: per_ray / min_per_ray,
                        samples_over_cell_floor: per_ray / floor_per_ray,
                        max_abs_diff_vs_whole: diff,
                        samples_per_s_per_core: f.stats.samples as f64
                            / (median_ms * 1e-3)
                            / threads,
                        march_steps: f.stats.march_steps,
                        core_ns_per_step: (f.stats.march_steps > 0)
                            .then(|| median_ms * 1e6 * threads / f.stats.march_steps as f64),
                    });
                }
                cases.push(FrameCase {
                    volume: fv.name.clone(),
                    view: [az, el],
                    shade,
                    rays,
                    min_samples_per_ray: min_per_ray,
                    cell_floor_samples_per_ray: floor_per_ray,
                    engines,
                    vtk,
                });
            }
        }
    }
    progress.end();
    Ok(cases)
}

/// VTK's side of a frame from its rounds (at least one): times over all of them, the
/// version, first render and image of the first.
fn vtk_case(vtk: Result<Vec<VtkFrame>, String>, reference: &Image) -> VtkCase {
    // `bench_frame` runs at least one round; an empty list would be a reason, not a number.
    let vtk = vtk.and_then(|v| {
        (!v.is_empty())
            .then_some(v)
            .ok_or("no VTK rounds".to_owned())
    });
    match vtk {
        Ok(v) => {
            let round_ms: Vec<f64> = v.iter().map(|f| f.median_ms).collect();
            VtkCase {
                measured: true,
                reason: None,
                version: v[0].vtk.clone(),
                median_ms: Some(median(round_ms.clone())),
                round_ms,
                first_render_ms: v[0].first_render_ms,
                psnr_db: npy::psnr(&v[0].image, reference),
            }
        }
        Err(reason) => VtkCase {
            measured: false,
            reason: Some(reason),
            version: None,
            median_ms: None,
            round_ms: Vec::new(),
            first_render_ms: None,
            psnr_db: None,
        },
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

#[cfg(test)]
mod test;
