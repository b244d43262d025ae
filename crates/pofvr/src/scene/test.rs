use std::path::Path;
use std::sync::Arc;

use super::*;
use crate::error::{OutOfRange, Setting, Value};
use crate::frame::{render_frame, render_reference};
use crate::pof::PofError;
use crate::render::{families, Camera, Projection, RenderSettings};
use crate::volume::phantom::Phantom;

fn head(n: usize) -> (Volume, TransferFunction) {
    (
        Phantom::SheppLogan.generate(n),
        families::for_phantom(Phantom::SheppLogan),
    )
}

fn scene(n: usize) -> Scene {
    let (v, tf) = head(n);
    Scene::builder(v, tf).build().unwrap()
}

/// The job the legacy entry points render, with `weights` and `shade` as its own.
fn job(n: usize, weights: &[f32], shade: bool) -> RenderJob {
    let (v, mut tf) = head(n);
    tf.weights = weights.to_vec();
    let settings = RenderSettings {
        shade,
        ..RenderSettings::default()
    };
    RenderJob::new(v, tf, 16, settings).unwrap()
}

fn camera(s: &Scene, az: f64) -> Camera {
    Camera::orbit(s.volume(), az, 20.0, 40, 32, Projection::Orthographic)
}

fn small_build() -> PofBuild {
    PofBuild {
        views: [4, 4],
        ..PofBuild::default()
    }
}

#[test]
fn scene_is_send_and_sync() {
    fn shared<T: Send + Sync>() {}
    shared::<Scene>();
    shared::<Pofs>();
    shared::<Frame>();
}

#[test]
fn one_arc_scene_renders_from_many_threads_with_each_threads_look() {
    let s = Arc::new(scene(32).with_range_bound(4.0));
    let looks: Vec<(Vec<f32>, bool)> = vec![
        (vec![1.0, 1.0], false),
        (vec![0.0, 1.0], true),
        (vec![2.0, 0.5], false),
        (vec![1.0, 1.0], true),
    ];
    let frames: Vec<Frame> = std::thread::scope(|scope| {
        let workers: Vec<_> = looks
            .iter()
            .map(|(w, shade)| {
                let s = Arc::clone(&s);
                scope.spawn(move || {
                    let cam = camera(&s, 30.0);
                    let cull = s.default_cull();
                    let req = FrameRequest::new(&cam).weights(w).shade(*shade).cull(cull);
                    s.render(&req).unwrap()
                })
            })
            .collect();
        workers.into_iter().map(|w| w.join().unwrap()).collect()
    });
    for ((w, shade), frame) in looks.iter().zip(&frames) {
        // Each frame is the one a job with that look renders by itself, bit for bit.
        let j = job(32, w, *shade);
        let bound = RangeBound::new(&j.grid, &j.sampled, j.settings.step, j.settings.ert, 4.0);
        let cam = Camera::orbit(&j.volume, 30.0, 20.0, 40, 32, Projection::Orthographic);
        let opts = FrameOptions {
            cull: CullMode::Pof,
            ..FrameOptions::default()
        };
        let (alone, st) = render_frame(&j, Some(&bound), &cam, &opts).unwrap();
        assert_eq!(frame.image.pixels(), alone.pixels(), "{w:?} shade {shade}");
        assert_eq!(frame.stats.bricks, st.bricks);
        assert_eq!(frame.stats.cull, Some(CullMode::Pof));
    }
    assert_ne!(frames[0].image.pixels(), frames[1].image.pixels());
}

#[test]
fn facade_frames_are_the_legacy_frames_bit_for_bit() {
    let w = [0.5, 2.0];
    let s = scene(40);
    let j = job(40, &w, true);
    let cam = camera(&s, -50.0);
    for mode in [CullMode::None, CullMode::Exact] {
        for ranks in [1, 3] {
            let req = FrameRequest::new(&cam)
                .weights(&w)
                .shade(true)
                .cull(s.cull(mode).unwrap())
                .ranks(ranks)
                .threshold(0.9)
                .engine(Engine::Bricks);
            let frame = s.render(&req).unwrap();
            let opts = FrameOptions {
                cull: mode,
                cull_threshold: 0.9,
                ranks,
                ..FrameOptions::default()
            };
            let (image, stats) = render_frame(&j, None, &cam, &opts).unwrap();
            assert_eq!(frame.image.pixels(), image.pixels(), "{mode:?} {ranks}");
            assert_eq!(frame.stats.bricks, stats.bricks);
            assert_eq!(frame.culled_bricks(), stats.bricks.culled);
        }
    }
    let reference = s
        .render_reference(&FrameRequest::new(&cam).weights(&w).shade(true))
        .unwrap();
    assert_eq!(
        reference.image.pixels(),
        render_reference(&j, &cam).0.pixels()
    );
    // Without weights, a request renders with the family's.
    let (plain, _) = render_reference(&job(40, &[1.0, 1.0], false), &cam);
    let default = s.render_reference(&FrameRequest::new(&cam)).unwrap();
    assert_eq!(s.default_weights(), &[1.0, 1.0]);
    assert_eq!(default.image.pixels(), plain.pixels());
}

#[test]
fn pofs_built_from_a_scene_take_its_step_and_threshold() {
    let (v, tf) = head(32);
    let s = Scene::builder(v, tf)
        .step(0.5)
        .early_termination(0.9)
        .build()
        .unwrap();
    let table = s.build_pofs(&small_build()).unwrap();
    assert_eq!((table.step(), table.ert()), (0.5, 0.9));
    let s = s.with_pofs(table).unwrap();
    let pofs = s.pofs().expect("attached");
    assert!(!pofs.has_sets());
    let cam = camera(&s, 10.0);
    let culled = s
        .render(&FrameRequest::new(&cam).cull(Cull::Pof(pofs)))
        .unwrap();
    // The threshold rule compares with the brick path's unculled frame.
    let none = s
        .render(&FrameRequest::new(&cam).engine(Engine::Bricks))
        .unwrap();
    assert_eq!(culled.stats.cull, Some(CullMode::Pof));
    assert_eq!(none.stats.cull, Some(CullMode::None));
    let rule = crate::check::rule::check_threshold_rule(&none.image, &culled.image, 0.95);
    assert!(rule.holds(), "{rule}");

    // A table built for another step is refused, naming what differs.
    let other = scene(32);
    let table = other.build_pofs(&small_build()).unwrap();
    let (v, tf) = head(32);
    let half = Scene::builder(v, tf).step(0.5).build().unwrap();
    let e = half.with_pofs(table).unwrap_err();
    assert!(
        matches!(&e, Error::Pof(PofError::Mismatch { what, .. }) if *what == Setting::Step.name()),
        "{e}"
    );
    assert!(e.to_string().contains("sample step"), "{e}");
}

#[test]
fn a_request_with_another_scenes_pofs_is_refused() {
    let a = scene(16).with_range_bound(4.0);
    let b = scene(16).with_range_bound(4.0);
    let cam = camera(&a, 0.0);
    let pofs = b.pofs().unwrap();
    let e = a
        .render(&FrameRequest::new(&cam).cull(Cull::Pof(pofs)))
        .unwrap_err();
    assert!(matches!(e, Error::ForeignPofs), "{e}");
    assert!(a
        .render(&FrameRequest::new(&cam).cull(a.default_cull()))
        .is_ok());
    // A POF mode needs POFs: a scene without them has no such cull.
    assert!(scene(16).cull(CullMode::Pof).is_none());
    assert!(matches!(scene(16).cull(CullMode::Exact), Some(Cull::Exact)));
}

#[test]
fn bad_settings_are_typed_errors_that_name_no_flag() {
    let (v, tf) = head(16);
    let e = Scene::builder(v, tf).step(0.0).build().unwrap_err();
    assert_eq!(
        e.out_of_range(),
        Some(&OutOfRange {
            setting: Setting::Step,
            got: Value::Real(0.0),
            expected: "a value in (0.001, 64]"
        })
    );
    let (v, tf) = head(16);
    let e = Scene::builder(v, tf)
        .early_termination(-1.0)
        .build()
        .unwrap_err();
    assert_eq!(
        e.out_of_range().map(|r| r.setting),
        Some(Setting::EarlyTermination)
    );
    let (v, tf) = head(16);
    let e = Scene::builder(v, tf).brick_size(1).build().unwrap_err();
    assert!(matches!(e, Error::Brick(_)), "{e}");

    let s = scene(16);
    let cam = camera(&s, 0.0);
    assert!(!e.to_string().contains("--"), "{e}");
    let mut messages = Vec::new();
    let e = s
        .render(&FrameRequest::new(&cam).threshold(1.5))
        .unwrap_err();
    assert_eq!(
        e.out_of_range().map(|r| (r.setting, r.got)),
        Some((Setting::CullThreshold, Value::Real(1.5)))
    );
    messages.push(e.to_string());
    let e = s.render(&FrameRequest::new(&cam).ranks(0)).unwrap_err();
    assert_eq!(
        e.out_of_range().map(|r| (r.setting, r.got)),
        Some((Setting::Ranks, Value::Count(0)))
    );
    messages.push(e.to_string());
    let e = s
        .render(&FrameRequest::new(&cam).weights(&[1.0]))
        .unwrap_err();
    assert!(
        matches!(
            e,
            Error::WeightCount {
                got: 1,
                expected: 2
            }
        ),
        "{e}"
    );
    messages.push(e.to_string());
    let e = s
        .render_reference(&FrameRequest::new(&cam).weights(&[1.0, -1.0]))
        .unwrap_err();
    assert!(
        matches!(e, Error::Weight { index: 1, got } if got == -1.0),
        "{e}"
    );
    messages.push(e.to_string());
    assert_eq!(s.empty_bricks(&[1.0]).unwrap_err().to_string(), messages[2]);
    for m in &messages {
        assert!(!m.contains("--"), "{m}");
        assert!(m.contains("got"), "{m}");
    }
    assert!(messages[0].contains("cull threshold: got 1.5, expected a value in (0, 1]"));
}

#[test]
fn pof_files_load_checked_and_name_a_bad_file() {
    let dir = tempfile::tempdir().unwrap();
    let s = scene(32);
    let save = |core: f32, name: &str| {
        let build = PofBuild {
            core_length: Some(core),
            ..small_build()
        };
        let p = dir.path().join(name);
        s.build_pofs(&build).unwrap().save(&p).unwrap();
        p
    };
    let (a, b) = (save(8.0, "a.pof"), save(12.0, "b.pof"));
    let s = s.load_pof_levels(&b, std::slice::from_ref(&a)).unwrap();
    // The shortest core comes first, the longer one as the deeper level.
    let bound = s.pofs().unwrap().bound();
    assert_eq!(bound.core_length(), 8.0);
    assert_eq!(bound.deeper(0).map(OpacityBound::core_length), Some(12.0));
    let e = scene(32)
        .load_pof_levels(&a, std::slice::from_ref(&a))
        .unwrap_err();
    assert!(e.to_string().contains("core length 8"), "{e}");
    let e = scene(32)
        .load_pof_levels(&a, &[dir.path().join("missing.pof")])
        .unwrap_err();
    assert!(e.to_string().contains("missing.pof"), "{e}");
    let e = scene(32).load_pofs(Path::new("missing.pof")).unwrap_err();
    assert!(e.to_string().contains("missing.pof"), "{e}");
    // A file for a scene of another step names the step.
    let (v, tf) = head(32);
    let half = Scene::builder(v, tf).step(0.5).build().unwrap();
    let e = half.load_pofs(&a).unwrap_err();
    assert!(e.to_string().contains("sample step"), "{e}");
    assert!(e.to_string().contains("a.pof"), "{e}");
    let s = scene(32).load_pofs(&a).unwrap();
    assert_eq!(s.pofs().unwrap().core_length(), 8.0);
}

#[test]
fn a_scene_adopts_a_job_with_its_weights_as_defaults() {
    let j = job(16, &[0.5, 1.5], true);
    let s = Scene::from_job(j).unwrap();
    assert_eq!(s.default_weights(), &[0.5, 1.5]);
    let cam = camera(&s, 0.0);
    // The job's shading is dropped: shading is per frame.
    let f = s.render_reference(&FrameRequest::new(&cam)).unwrap();
    let (unshaded, _) = render_reference(&job(16, &[0.5, 1.5], false), &cam);
    assert_eq!(f.image.pixels(), unshaded.pixels());
    let mut bad = job(16, &[1.0, 1.0], false);
    bad.tf.weights = vec![1.0];
    assert!(matches!(
        Scene::from_job(bad),
        Err(Error::WeightCount {
            got: 1,
            expected: 2
        })
    ));
}

#[test]
fn a_jittered_scene_renders_its_brick_frames_equal_to_its_whole_frame() {
    let (v, tf) = head(36);
    let s = Scene::builder(v, tf).jitter(Some(11)).build().unwrap();
    let (plain_v, plain_tf) = head(36);
    let plain = Scene::builder(plain_v, plain_tf).build().unwrap();
    for shade in [false, true] {
        let cam = camera(&s, 40.0);
        let req = FrameRequest::new(&cam).shade(shade);
        let whole = s.render_reference(&req).unwrap();
        assert!(whole.image.mean_alpha() > 0.05);
        for ranks in [1, 3] {
            // The ranks' partial images are composited, not carried along each ray: the
            // order of the additions differs, so the frames agree to float rounding.
            let bricks = s.render(&req.clone().ranks(ranks)).unwrap();
            let diff = whole.image.max_abs_diff(&bricks.image).unwrap();
            assert!(diff <= 1e-6, "ranks {ranks}: {diff}");
        }
        let unjittered = plain.render_reference(&req).unwrap();
        assert!(whole.image.max_abs_diff(&unjittered.image).unwrap() > 1e-3);
    }
}

#[test]
fn a_jittered_scene_refuses_pof_culling_but_culls_exactly() {
    let (v, tf) = (
        Phantom::SheppLogan.generate(32),
        families::for_phantom(Phantom::SheppLogan),
    );
    let s = Scene::builder(v, tf)
        .brick_size(8)
        .jitter(Some(3))
        .build()
        .unwrap();
    let pofs = s
        .build_pofs(&PofBuild {
            views: [4, 4],
            ..PofBuild::default()
        })
        .unwrap();
    let s = s.with_pofs(pofs).unwrap();
    let cam = Camera::orbit(s.volume(), 30.0, 20.0, 24, 24, Projection::Orthographic);
    for cull in [
        Cull::Pof(s.pofs().unwrap()),
        Cull::PofSet(s.pofs().unwrap()),
    ] {
        let mode = cull.mode();
        let e = s.render(&FrameRequest::new(&cam).cull(cull)).unwrap_err();
        assert!(
            matches!(e, Error::JitteredPofs { mode: m } if m == mode),
            "{e}"
        );
        assert!(!e.to_string().contains("--"), "{e}");
    }
    assert!(s.render(&FrameRequest::new(&cam).cull(Cull::Exact)).is_ok());
}

#[test]
fn one_process_frames_default_to_the_march_engine_which_equals_the_reference() {
    let s = scene(40);
    let cam = camera(&s, 35.0);
    for (weights, shade) in [([1.0, 1.0], false), ([1.0, 0.0], true), ([0.5, 2.0], false)] {
        let req = FrameRequest::new(&cam).weights(&weights).shade(shade);
        assert_eq!(s.engine(&req).unwrap(), Engine::March);
        let march = s.render(&req).unwrap();
        let whole = s.render_reference(&req).unwrap();
        let bits = |f: &Frame| -> Vec<[u32; 4]> {
            f.image
                .pixels()
                .iter()
                .map(|p| p.map(f32::to_bits))
                .collect()
        };
        assert_eq!(bits(&march), bits(&whole), "{weights:?} shade {shade}");
        assert_eq!((march.stats.engine, whole.stats.engine), ("march", "whole"));
        assert_eq!(march.stats.rays, whole.stats.rays);
        assert!(march.stats.samples <= whole.stats.samples);
        assert!(march.stats.samples_per_ray <= whole.stats.samples_per_ray);
        assert_eq!(march.stats.cull, Some(CullMode::None));
        let bricks = s.render(&req.clone().engine(Engine::Bricks)).unwrap();
        assert_eq!(bricks.stats.engine, "bricks");
        assert_eq!(march.stats.bricks.empty, bricks.stats.bricks.empty);
        // Samples per ray count the rays that met the volume, whatever the engine.
        let per_ray = bricks.stats.samples as f64 / whole.stats.rays as f64;
        assert_eq!(bricks.stats.samples_per_ray, per_ray);
    }
    // Skin only: empty space to skip.
    let req = FrameRequest::new(&cam).weights(&[1.0, 0.0]);
    let march = s.render(&req).unwrap();
    assert!(march.stats.skipped_samples > 0, "{:?}", march.stats);
}

#[test]
fn the_march_engine_refuses_culling_ranks_and_communicators() {
    let s = scene(16);
    let cam = camera(&s, 0.0);
    let march = FrameRequest::new(&cam).engine(Engine::March);
    for (req, what) in [
        (march.clone().cull(Cull::Exact), "cull mode exact"),
        (march.clone().ranks(2), "2 ranks"),
    ] {
        let e = s.render(&req).unwrap_err();
        assert!(matches!(e, Error::Engine { .. }), "{e}");
        assert!(e.to_string().contains(what), "{e}");
        assert!(!e.to_string().contains("--"), "{e}");
    }
    // Without a choice, culling and ranks take the brick engine.
    let culled = FrameRequest::new(&cam).cull(Cull::Exact);
    assert_eq!(s.engine(&culled).unwrap(), Engine::Bricks);
    assert_eq!(
        s.engine(&FrameRequest::new(&cam).ranks(3)).unwrap(),
        Engine::Bricks
    );
    let comm = crate::comm::LocalCommunicator::run(1, |c| s.render_on(c, &march).map(|_| ()));
    assert!(matches!(comm[0], Err(Error::Engine { .. })));
    assert_eq!(Engine::March.name(), "march");
    assert_eq!("Bricks".parse::<Engine>(), Ok(Engine::Bricks));
    assert!("vtk".parse::<Engine>().is_err());
}

#[test]
fn a_scene_with_another_family_renders_as_one_built_with_it_and_keeps_matching_pofs() {
    let (v, tf) = head(24);
    let s = Scene::builder(v, tf.clone())
        .build()
        .unwrap()
        .with_range_bound(4.0);
    let cam = camera(&s, 30.0);
    // New colours and weights, same bases: the POFs still bound the opacity.
    let mut recoloured = tf.clone();
    recoloured.color = vec![[0.0, 0.1, 0.9, 0.2], [255.0, 0.9, 0.1, 0.1]];
    recoloured.weights = vec![2.0, 0.5];
    let r = s.with_family(recoloured.clone()).unwrap();
    assert!(r.pofs().is_some(), "same bases keep the POFs");
    assert_eq!(r.family(), &recoloured);
    // Reshaped bases: the POFs no longer bound them.
    let mut reshaped = tf.clone();
    reshaped.bases[0].opacity[1][1] = 0.5;
    let q = s.with_family(reshaped.clone()).unwrap();
    assert!(q.pofs().is_none(), "other bases drop the POFs");
    for (scene, family) in [(&r, recoloured), (&q, reshaped)] {
        let (v, _) = head(24);
        let fresh = Scene::builder(v, family).build().unwrap();
        for cull in [Cull::None, Cull::Exact] {
            let req = FrameRequest::new(&cam).cull(cull);
            let got = scene.render(&req).unwrap().image;
            assert_eq!(got.pixels(), fresh.render(&req).unwrap().image.pixels());
        }
    }
    // The generated (owned) voxels are shared with the new scenes, not copied.
    let voxels = |s: &Scene| crate::with_voxels!(s.volume().data(), v => v.as_ptr().cast::<u8>());
    assert!(!s.volume().data().is_mapped());
    assert!(std::ptr::eq(voxels(&s), voxels(&r)));
    assert!(std::ptr::eq(voxels(&s), voxels(&q)));
    let mut bad = tf;
    bad.weights = vec![1.0];
    assert!(matches!(s.with_family(bad), Err(Error::WeightCount { .. })));
}

#[test]
fn a_cancelled_pof_build_stops_between_bricks() {
    let s = Scene::builder(head(48).0, head(48).1)
        .brick_size(8)
        .build()
        .unwrap();
    let cancel = std::sync::atomic::AtomicBool::new(false);
    let started = std::sync::atomic::AtomicU64::new(0);
    // Cancelled from the progress hook once the first brick is done.
    let progress = |done: u64, _total: u64| {
        started.fetch_max(done, std::sync::atomic::Ordering::Relaxed);
        if done >= 1 {
            cancel.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    };
    let err = s
        .build_pofs_cancellable(&small_build(), &progress, &cancel)
        .unwrap_err();
    let Error::Pof(PofError::Cancelled { done, total }) = err else {
        panic!("expected a cancelled build, got {err}");
    };
    // At most one brick in flight per worker when the flag was set.
    let workers = rayon::current_num_threads() as u64;
    assert!(done >= 1 && done <= 1 + workers, "{done} of {total}");
    assert!(total > 2 * (1 + workers), "{total} bricks");
    // Uncancelled, the same call builds the table.
    let quiet = std::sync::atomic::AtomicBool::new(false);
    assert!(s
        .build_pofs_cancellable(&small_build(), &|_, _| {}, &quiet)
        .is_ok());
}

#[test]
fn stats_count_pixel_rays_and_brick_fragment_rays_apart() {
    let s = Scene::builder(head(40).0, head(40).1)
        .brick_size(8)
        .build()
        .unwrap();
    let cam = camera(&s, 30.0);
    let base = FrameRequest::new(&cam);
    let march = s.render(&base.clone().engine(Engine::March)).unwrap().stats;
    let whole = s.render_reference(&base).unwrap().stats;
    // One ray per pixel that meets the volume, for the engines that walk the whole volume.
    assert!(march.pixel_rays > 0 && march.pixel_rays <= 40 * 32);
    assert_eq!(march.rays, march.pixel_rays);
    assert_eq!(
        (whole.rays, whole.pixel_rays),
        (march.rays, march.pixel_rays)
    );
    for ranks in [1, 3] {
        let bricks = s
            .render(&base.clone().engine(Engine::Bricks).ranks(ranks))
            .unwrap()
            .stats;
        // The same pixels; the brick engine casts one ray per brick fragment, more of them.
        assert_eq!(bricks.pixel_rays, march.pixel_rays, "{ranks} ranks");
        assert!(
            bricks.rays > 2 * bricks.pixel_rays,
            "{ranks} ranks: {bricks:?}"
        );
        let per_rank: u64 = bricks.ranks.iter().map(|r| r.rays).sum();
        assert_eq!(per_rank, bricks.rays);
        let spr = bricks.samples as f64 / bricks.pixel_rays as f64;
        assert!((bricks.samples_per_ray - spr).abs() < 1e-9);
    }
}

#[test]
fn march_blocks_follow_the_builder_and_a_memory_budget_and_change_no_pixel() {
    let (v, tf) = head(48);
    // 48³ u8: 110 592 bytes of voxels, and a copy of 3 × 3 × 3 blocks of 17³.
    let copy = crate::render::blocks::copy_bytes(&v);
    assert_eq!(copy, 27 * 17 * 17 * 17);
    let frame = |blocks: Option<bool>, budget: Option<u64>| {
        let s = Scene::builder(v.share(), tf.clone())
            .march_blocks(blocks)
            .memory_budget(budget)
            .build()
            .unwrap();
        let cam = camera(&s, 30.0);
        let first = s.render(&FrameRequest::new(&cam)).unwrap();
        let second = s.render(&FrameRequest::new(&cam)).unwrap();
        // Copied once, on the first frame.
        assert_eq!(second.stats.blocks_ms, 0.0);
        assert_eq!(first.stats.march_blocks, second.stats.march_blocks);
        assert_eq!(first.image, second.image);
        first
    };
    let plain = frame(Some(false), None);
    assert!(!plain.stats.march_blocks && plain.stats.blocks_ms == 0.0);
    let eights = plain.stats.march_simd == Some("avx2");
    let blocked = frame(Some(true), None);
    assert_eq!(blocked.stats.march_blocks, eights, "{:?}", blocked.stats);
    assert!(blocked.stats.blocks_ms > 0.0);
    assert_eq!(blocked.image, plain.image);
    // A budget the volume fits beside its copy keeps it; one it fits alone does not.
    let both = (110_592 + copy) as u64;
    assert_eq!(frame(Some(true), Some(both)).stats.march_blocks, eights);
    let alone = frame(Some(true), Some(both - 1));
    assert!(!alone.stats.march_blocks && alone.stats.blocks_ms == 0.0);
    assert_eq!(alone.image, plain.image);
    // By default, not for a volume this small.
    assert!(!frame(None, None).stats.march_blocks || std::env::var_os("POFVR_BLOCKS").is_some());
}
