//! The one file that knows how the library renders a frame.
//!
//! Every request renders on the viewer's one [`Scene`], shared by `Arc` and never changed:
//! the request's weights, shading, cull mode and threshold travel in its
//! [`pofvr::FrameRequest`], so frames of different clients and looks render side by side
//! with no lock. Modes `pof` and `pof-set` need the scene's POFs (a POF file, or in tests
//! the library's range bound).

use pofvr::render::Camera;
use pofvr::{Cull, Frame, FrameRequest, Predict, Scene};

pub use pofvr::cull::CullMode;
pub use pofvr::frame::{BrickCounts, FrameOptions, FrameStats, RankStats};

/// Every cull mode, in the order the page lists them.
pub const CULL_MODES: [CullMode; 5] = [
    CullMode::None,
    CullMode::Pof,
    CullMode::PofSet,
    CullMode::Exact,
    CullMode::Verified,
];

/// What changes per frame besides the camera and the options: the look of the volume.
#[derive(Clone, Debug, PartialEq)]
pub struct Look {
    /// One weight per basis, already validated against the family.
    pub weights: Vec<f32>,
    /// Gradient shading.
    pub shade: bool,
}

/// Renders one frame of `scene` seen by `camera` with `look` and `opts` (its cull mode,
/// threshold, ranks, curve, replicas and, for `verified`, predictor), with the scene's engine for them: the march
/// engine for one rank without culling (the frames while dragging), the brick engine
/// otherwise.
///
/// # Errors
/// [`pofvr::Error::NoPofs`] for a POF mode on a scene without POFs, or the frame's error
/// (bad weights or threshold, a failed rank).
pub fn render(
    scene: &Scene,
    camera: &Camera,
    opts: &FrameOptions,
    look: &Look,
) -> Result<Frame, pofvr::Error> {
    // A verified frame predicts with the options' predictor (the viewer picks `previous`
    // while a client drags); the other modes are the scene's.
    let cull = match opts.cull {
        CullMode::Verified => {
            Predict::from_predictor(opts.predictor, scene.pofs()).map(Cull::Verified)
        }
        mode => scene.cull(mode),
    }
    .ok_or(pofvr::Error::NoPofs { mode: opts.cull })?;
    let request = FrameRequest::new(camera)
        .weights(&look.weights)
        .shade(look.shade)
        .cull(cull)
        .threshold(opts.cull_threshold)
        .ranks(opts.ranks)
        .curve(opts.curve)
        .replicas(opts.replicas);
    scene.render(&request)
}

#[cfg(test)]
mod tests {
    use super::*;
    use pofvr::frame::{render_reference, RenderJob};
    use pofvr::render::{families, Projection, RenderSettings};
    use pofvr::volume::phantom::Phantom;

    fn scene() -> Scene {
        let vol = Phantom::SheppLogan.generate(32);
        let tf = families::for_phantom(Phantom::SheppLogan);
        Scene::builder(vol, tf).build().unwrap()
    }

    #[test]
    fn the_look_of_each_frame_is_the_one_asked_for() {
        let shared = std::sync::Arc::new(scene());
        let cam = Camera::orbit(
            shared.volume(),
            30.0,
            20.0,
            24,
            24,
            Projection::Orthographic,
        );
        let opts = FrameOptions {
            cull: CullMode::None,
            ..FrameOptions::default()
        };
        let a = Look {
            weights: vec![1.0, 1.0],
            shade: false,
        };
        let b = Look {
            weights: vec![0.0, 1.0],
            shade: true,
        };
        // Two looks at once on the one scene, then the first again.
        let (ia, ib) = std::thread::scope(|s| {
            let ta = s.spawn(|| render(&shared, &cam, &opts, &a).unwrap());
            let tb = s.spawn(|| render(&shared, &cam, &opts, &b).unwrap());
            (ta.join().unwrap(), tb.join().unwrap())
        });
        let ia2 = render(&shared, &cam, &opts, &a).unwrap();
        assert_eq!(ia.image.pixels(), ia2.image.pixels());
        assert_ne!(ia.image.pixels(), ib.image.pixels());
        let mut tf = families::for_phantom(Phantom::SheppLogan);
        tf.weights = b.weights.clone();
        let settings = RenderSettings {
            shade: true,
            ..RenderSettings::default()
        };
        let direct = RenderJob::new(Phantom::SheppLogan.generate(32), tf, 16, settings).unwrap();
        // One rank, no culling: the march engine, which gives the reference's image.
        let (ib_direct, _) = render_reference(&direct, &cam);
        assert_eq!(ib.image.pixels(), ib_direct.pixels());
    }

    #[test]
    fn pof_modes_without_pofs_are_an_error() {
        let s = scene();
        let cam = Camera::orbit(s.volume(), 0.0, 0.0, 8, 8, Projection::Orthographic);
        let look = Look {
            weights: vec![1.0, 1.0],
            shade: false,
        };
        for cull in [CullMode::Pof, CullMode::PofSet] {
            let opts = FrameOptions {
                cull,
                ..FrameOptions::default()
            };
            let e = render(&s, &cam, &opts, &look).unwrap_err();
            assert!(
                matches!(e, pofvr::Error::NoPofs { mode } if mode == cull),
                "{e}"
            );
            let with = scene().with_range_bound(4.0);
            assert!(render(&with, &cam, &opts, &look).is_ok());
        }
    }
}
