//! Verified culling on the catalogue's real volumes: the threshold rule holds for every
//! predictor, deliberately bad ones included (cull everything, cull at random), at one rank
//! and several. Ignored unless run with `--ignored` (they need `../shared/data`).

mod common;

use pofvr::cull::range_bound::RangeBound;
use pofvr::cull::{CullMode, OpacityBound, Predictor};
use pofvr::frame::{render_frame, render_reference, FrameOptions, RenderJob};
use pofvr::render::{Camera, Projection, RenderSettings};

#[test]
#[ignore = "needs ../shared/data (real volumes)"]
fn every_predictor_obeys_the_threshold_rule_on_every_real_volume() {
    for (vol, _, volume, tf) in common::open_catalogue() {
        let job = RenderJob::new(volume, tf, 16, RenderSettings::default()).unwrap();
        let bound = RangeBound::new(
            &job.grid,
            &job.sampled,
            job.settings.step,
            job.settings.ert,
            8.0,
        );
        let bounds: Option<&dyn OpacityBound> = Some(&bound);
        for (az, el, p) in [
            (0.0, 0.0, Projection::Orthographic),
            (37.0, 23.0, Projection::Orthographic),
            (-110.0, -30.0, Projection::Perspective),
        ] {
            let cam = Camera::orbit(&job.volume, az, el, 96, 80, p);
            let (reference, _) = render_reference(&job, &cam);
            for predictor in [
                Predictor::Proxy,
                Predictor::PofSet,
                Predictor::Previous,
                Predictor::Everything,
                Predictor::Random(11),
                Predictor::Random(12345),
            ] {
                let mut one_rank = None;
                for ranks in [1, 3] {
                    let opts = FrameOptions {
                        cull: CullMode::Verified,
                        predictor,
                        ranks,
                        ..FrameOptions::default()
                    };
                    let (img, st) = render_frame(&job, bounds, &cam, &opts).unwrap();
                    let what = format!("{vol} {predictor:?} {az},{el} {p:?} {ranks} ranks");
                    let r =
                        pofvr::check::check_threshold_rule(&reference, &img, opts.cull_threshold);
                    assert!(r.holds(), "{what}: {r}");
                    assert!(st.bricks.repaired <= st.bricks.visible, "{what}");
                    if predictor == Predictor::Everything {
                        assert_eq!(st.bricks.repaired, st.bricks.visible, "{what}");
                    }
                    // Predictions made per pixel (the proxy's sample rays on the image's
                    // grid) or per brick give the same frame for any tiling.
                    if !matches!(predictor, Predictor::PofSet | Predictor::Previous) {
                        match &one_rank {
                            None => one_rank = Some((img, st.culled_bricks)),
                            Some((img1, culled1)) => {
                                assert_eq!(culled1, &st.culled_bricks, "{what}");
                                assert!(img1 == &img, "{what}");
                            }
                        }
                    }
                }
            }
        }
    }
}
