//! The march engine on the catalogue's real volumes: the image of the whole-volume
//! reference bit for bit, in orthographic and perspective views, shaded and unshaded, with
//! fewer samples per ray. Ignored unless run with `--ignored` (they need `../shared/data`).

mod common;

use pofvr::render::{Camera, Projection};
use pofvr::{Engine, FrameRequest, Scene};

#[test]
#[ignore = "needs ../shared/data (real volumes)"]
fn march_equals_the_reference_on_every_real_volume() {
    for (vol, tf, volume, family) in common::open_catalogue() {
        let bases = family.bases.len();
        // The eight-ray packets over the volume's blocked copy too (these volumes are
        // below the size that gets one by default).
        let scenes = [None, Some(true)].map(|blocks| {
            Scene::builder(volume.share(), family.clone())
                .march_blocks(blocks)
                .build()
                .unwrap()
        });
        let scene = &scenes[0];
        // The family's own weights, and the first basis alone (more of the volume empty).
        let alone: Vec<f32> = (0..bases).map(|i| f32::from(i == 0)).collect();
        let weight_sets = [scene.default_weights().to_vec(), alone];
        for weights in &weight_sets {
            for (az, el, projection, shade) in [
                (0.0, 0.0, Projection::Orthographic, false),
                (30.0, 20.0, Projection::Perspective, true),
                (0.0, 90.0, Projection::Orthographic, true),
                (-117.0, -33.0, Projection::Perspective, false),
                // Along an axis in perspective: lockstep packets whose rays fan out, so
                // that no axis is fixed (the orthographic views above fix two).
                (0.0, 90.0, Projection::Perspective, false),
            ] {
                let cam = Camera::orbit(scene.volume(), az, el, 96, 96, projection);
                let req = FrameRequest::new(&cam)
                    .weights(weights)
                    .shade(shade)
                    .engine(Engine::March);
                let whole = scene.render_reference(&req).unwrap();
                for (blocks, scene) in [false, true].into_iter().zip(&scenes) {
                    let march = scene.render(&req).unwrap();
                    let what = format!(
                        "{vol} {tf} {weights:?} view {az},{el} {projection:?} shade {shade} blocks {blocks}"
                    );
                    for (i, (m, w)) in march
                        .image
                        .pixels()
                        .iter()
                        .zip(whole.image.pixels())
                        .enumerate()
                    {
                        assert_eq!(
                            m.map(f32::to_bits),
                            w.map(f32::to_bits),
                            "{what}: pixel {i}"
                        );
                    }
                    assert_eq!(march.stats.rays, whole.stats.rays, "{what}");
                    assert!(march.stats.samples <= whole.stats.samples, "{what}");
                    // The copy serves the eight-ray packets, where they run.
                    let eights = march.stats.march_simd == Some("avx2");
                    assert_eq!(march.stats.march_blocks, blocks && eights, "{what}");
                }
            }
        }
    }
}

#[test]
#[ignore = "needs ../shared/data (real volumes)"]
fn the_floor_of_exact_skipping_lies_between_the_visible_samples_and_the_march_engines() {
    use pofvr::experiment::bench_frame::minimum_samples;
    for (vol, _, volume, family) in common::open_catalogue() {
        let scene = Scene::builder(volume, family).build().unwrap();
        for (az, el) in [(30.0, 20.0), (0.0, 90.0)] {
            let cam = Camera::orbit(scene.volume(), az, el, 96, 96, Projection::Orthographic);
            let b = minimum_samples(&scene, scene.default_weights(), &cam);
            let req = FrameRequest::new(&cam).engine(Engine::March);
            let march = scene.render(&req).unwrap();
            // Real boundaries put samples of zero alpha into cells that can hold opacity,
            // and 4³ cells hold more of them than single trilinear cells do.
            assert!(
                b.visible < b.cell_floor && b.cell_floor < march.stats.samples,
                "{vol} view {az},{el}: {b:?}, march {}",
                march.stats.samples
            );
            assert_eq!(b.rays, march.stats.rays, "{vol} view {az},{el}");
        }
    }
}
