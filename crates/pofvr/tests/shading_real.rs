//! Shading on the catalogue's real volumes: every sample loop gives the scalar reference's
//! shaded frame bit for bit, the brick engine gives it within the rounding the unshaded
//! frames allow, and shading changes colours but no opacity. Ignored unless run with
//! `--ignored` (they need `../shared/data`).

mod common;

use pofvr::check::check_threshold_rule;
use pofvr::cull::CullMode;
use pofvr::frame::{render_frame, FrameOptions, RenderJob};
use pofvr::render::{Camera, Image, Projection, RayCaster, RenderSettings};

fn bits(i: &Image) -> Vec<u32> {
    i.pixels().iter().flatten().map(|v| v.to_bits()).collect()
}

#[test]
#[ignore = "needs ../shared/data (real volumes)"]
fn shaded_frames_equal_the_scalar_reference_on_every_real_volume() {
    for (vol, _, volume, tf) in common::open_catalogue() {
        let settings = RenderSettings {
            shade: true,
            ..RenderSettings::default()
        };
        let job = RenderJob::new(volume, tf, 16, settings).unwrap();
        let cls = job.sampled.classify(&job.tf.weights, settings.step);
        for (az, el, p) in [
            (30.0, 20.0, Projection::Orthographic),
            (0.0, 90.0, Projection::Orthographic),
            (-110.0, -30.0, Projection::Perspective),
        ] {
            let what = format!("{vol} view {az},{el} {p:?}");
            let cam = Camera::orbit(&job.volume, az, el, 96, 80, p);
            let caster = |s: RenderSettings| RayCaster::new(&job.volume, &cls, s);
            let (reference, _) = caster(settings).with_scalar_loop(true).render(&cam);
            assert!(reference.mean_alpha() > 0.01, "{what} shows something");
            for avx2 in [true, false] {
                let c = caster(settings).with_avx2(avx2);
                let (img, _) = c.render(&cam);
                assert!(bits(&img) == bits(&reference), "{what}: loop {}", c.simd());
            }
            // Shading scales colours only.
            let (unshaded, _) = caster(RenderSettings {
                shade: false,
                ..settings
            })
            .render(&cam);
            let alpha =
                |i: &Image| -> Vec<u32> { i.pixels().iter().map(|p| p[3].to_bits()).collect() };
            assert!(alpha(&unshaded) == alpha(&reference), "{what}: opacities");
            assert!(bits(&unshaded) != bits(&reference), "{what}: shading shows");
            // The brick engine: fragments terminate early per brick and are composited
            // brick by brick, so it agrees to rounding (`check::IDENTICAL`) where the
            // reference is below the termination opacity, as unshaded frames do.
            for ranks in [1, 2] {
                let opts = FrameOptions {
                    cull: CullMode::None,
                    ranks,
                    ..FrameOptions::default()
                };
                let (bricks, _) = render_frame(&job, None, &cam, &opts).unwrap();
                let r = check_threshold_rule(&reference, &bricks, settings.ert);
                assert!(r.holds(), "{what}, bricks on {ranks} ranks: {r}");
            }
        }
    }
}
