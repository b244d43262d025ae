//! Predict, verify, repair: the threshold rule for every predictor, good or deliberately
//! bad; one round of repair; the same frame for any rank count.

use super::proxy_march::Extinction;
use super::range_bound::RangeBound;
use super::test::assert_conservative;
use super::*;
use crate::brick::BrickId;
use crate::composite::TileFragment;
use crate::distribute::Curve;
use crate::frame::{render_frame, render_reference, FrameOptions, FrameStats, RenderJob};
use crate::render::{families, Camera, Projection, RayCaster, RenderSettings};
use crate::volume::phantom::Phantom;

fn job(n: usize, weights: &[f32]) -> RenderJob {
    let mut tf = families::for_phantom(Phantom::SheppLogan);
    tf.set_weights(weights.to_vec()).unwrap();
    RenderJob::new(
        Phantom::SheppLogan.generate(n),
        tf,
        8,
        RenderSettings::default(),
    )
    .unwrap()
}

fn cam(job: &RenderJob, az: f64, el: f64, p: Projection) -> Camera {
    Camera::orbit(&job.volume, az, el, 72, 64, p)
}

fn verified(predictor: Predictor, ranks: usize) -> FrameOptions {
    FrameOptions {
        cull: CullMode::Verified,
        predictor,
        ranks,
        ..FrameOptions::default()
    }
}

const PREDICTORS: [Predictor; 8] = [
    Predictor::Proxy,
    Predictor::Pof,
    Predictor::PofSet,
    Predictor::Previous,
    Predictor::Nothing,
    Predictor::Everything,
    Predictor::Random(1),
    Predictor::Random(0xdead_beef),
];

/// Renders the bricks `st` did not cull and verifies the culled ones against them: what
/// a second round of verification would find.
fn second_round(j: &RenderJob, c: &Camera, st: &FrameStats, threshold: f32) -> Verdict {
    let bricks = FrameBricks::new(&j.volume, &j.grid, &j.sampled, &j.tf.weights, c);
    let cls = j.sampled.classify(&j.tf.weights, j.settings.step);
    let caster = RayCaster::new(&j.volume, &cls, j.settings);
    let frame = c.frame();
    let culled: std::collections::HashSet<BrickId> = st.culled_bricks.iter().copied().collect();
    let fragments: Vec<TileFragment> = bricks
        .order
        .iter()
        .filter(|b| !culled.contains(b))
        .map(|&b| {
            let rect = bricks.footprints[b.index()].unwrap();
            let (pixels, _) = caster.render_box(c, &frame, rect, &j.grid.index_box(b));
            TileFragment {
                brick: b,
                depth_key: bricks.depth_key[b.index()],
                rect,
                pixels,
            }
        })
        .collect();
    let view = VerifyView {
        camera: c,
        volume: &j.volume,
        grid: &j.grid,
        bricks: &bricks,
    };
    verify_tile(
        &view,
        bricks.bounds.unwrap(),
        &fragments,
        &st.culled_bricks,
        threshold,
    )
}

#[test]
fn every_predictor_obeys_the_threshold_rule_and_one_repair_round_suffices() {
    for weights in [[3.0, 1.0], [1.0, 1.0]] {
        let j = job(48, &weights);
        let bound = RangeBound::new(&j.grid, &j.sampled, j.settings.step, j.settings.ert, 4.0);
        for (az, el, p) in [
            (0.0, 0.0, Projection::Orthographic),
            (41.0, 17.0, Projection::Orthographic),
            (-70.0, 30.0, Projection::Perspective),
        ] {
            let c = cam(&j, az, el, p);
            let (reference, _) = render_reference(&j, &c);
            for predictor in PREDICTORS {
                j.forget_previous();
                for threshold in [0.95, 0.6] {
                    let opts = FrameOptions {
                        cull_threshold: threshold,
                        ..verified(predictor, 1)
                    };
                    let what = format!("{predictor:?} {weights:?} {az},{el} at {threshold}");
                    let (img, st) = render_frame(&j, Some(&bound), &c, &opts).unwrap();
                    assert_conservative(&reference, &img, threshold, &what);
                    let b = st.bricks;
                    assert!(b.repaired <= b.visible, "{what}: {b:?}");
                    assert_eq!(
                        b.culled + b.visible,
                        b.non_empty - off_screen(&j, &c),
                        "{what}"
                    );
                    assert!(st.verified, "{what}");
                    assert_eq!(st.predictor, Some(predictor.name()), "{what}");
                    match predictor {
                        Predictor::Nothing => assert_eq!(b.repaired, 0, "{what}"),
                        // Everything that is rendered was culled first, then repaired.
                        Predictor::Everything => assert_eq!(b.repaired, b.visible, "{what}"),
                        _ => {}
                    }
                    let again = second_round(&j, &c, &st, threshold);
                    assert!(again.failing.is_empty(), "{what}: {again:?}");
                }
            }
        }
    }
}

/// Non-empty bricks whose footprint misses the image.
fn off_screen(j: &RenderJob, c: &Camera) -> usize {
    let b = FrameBricks::new(&j.volume, &j.grid, &j.sampled, &j.tf.weights, c);
    j.grid.len() - b.empty - b.order.len()
}

#[test]
fn bad_predictors_are_repaired_and_good_ones_cull() {
    // The skull shell hides the inside at weights (3, 1).
    let j = job(48, &[3.0, 1.0]);
    let c = cam(&j, 30.0, 20.0, Projection::Orthographic);
    let (reference, _) = render_reference(&j, &c);
    let run = |p| render_frame(&j, None, &c, &verified(p, 1)).unwrap();
    let (_, everything) = run(Predictor::Everything);
    assert!(everything.bricks.repaired > 0);
    let (img, random) = run(Predictor::Random(5));
    assert_conservative(&reference, &img, 0.95, "random");
    assert!(random.bricks.repaired > 0, "{:?}", random.bricks);
    let (_, proxy) = run(Predictor::Proxy);
    assert!(proxy.bricks.culled > 0, "{:?}", proxy.bricks);
    // What a predictor renders and repairs, the verification keeps honest: nothing a
    // predictor culls correctly is rendered, so none renders more than all there is.
    let (_, exact) = render_frame(
        &j,
        None,
        &c,
        &FrameOptions {
            cull: CullMode::Exact,
            ..FrameOptions::default()
        },
    )
    .unwrap();
    assert!(exact.bricks.culled > 0);
    eprintln!(
        "rendered: exact {}, proxy {} ({} repaired), random {} ({} repaired)",
        exact.bricks.visible,
        proxy.bricks.visible,
        proxy.bricks.repaired,
        random.bricks.visible,
        random.bricks.repaired
    );
}

#[test]
fn verified_frame_is_identical_for_any_rank_count() {
    let j = job(40, &[2.0, 1.0]);
    for (az, el, p) in [
        (30.0, 20.0, Projection::Orthographic),
        (-60.0, 10.0, Projection::Perspective),
    ] {
        let c = cam(&j, az, el, p);
        for predictor in [
            Predictor::Proxy,
            Predictor::Everything,
            Predictor::Random(3),
        ] {
            let (base, base_st) = render_frame(&j, None, &c, &verified(predictor, 1)).unwrap();
            for (ranks, replicas, curve) in [
                (2, 1, Curve::Hilbert),
                (3, 1, Curve::Z),
                (7, 1, Curve::Hilbert),
                (4, 2, Curve::Hilbert),
            ] {
                let opts = FrameOptions {
                    replicas,
                    curve,
                    ..verified(predictor, ranks)
                };
                let what = format!("{predictor:?} {az},{el} {ranks} ranks {replicas} replicas");
                let (img, st) = render_frame(&j, None, &c, &opts).unwrap();
                assert_eq!(img.max_abs_diff(&base), Some(0.0), "{what}");
                assert_eq!(st.bricks, base_st.bricks, "{what}");
                let rendered: usize = st.ranks.iter().map(|r| r.bricks_rendered).sum();
                assert_eq!(
                    rendered, st.bricks.visible,
                    "{what}: each brick rendered once"
                );
            }
        }
    }
}

#[test]
fn verify_repairs_pof_set_and_keeps_pof_images() {
    let j = job(48, &[3.0, 1.0]);
    let bound = RangeBound::new(&j.grid, &j.sampled, j.settings.step, j.settings.ert, 4.0);
    let c = cam(&j, 10.0, 35.0, Projection::Orthographic);
    let (reference, _) = render_reference(&j, &c);
    for mode in [CullMode::Pof, CullMode::PofSet] {
        let plain = FrameOptions {
            cull: mode,
            ..FrameOptions::default()
        };
        let (a, sa) = render_frame(&j, Some(&bound), &c, &plain).unwrap();
        let (b, sb) = render_frame(
            &j,
            Some(&bound),
            &c,
            &FrameOptions {
                verify: true,
                ..plain
            },
        )
        .unwrap();
        assert_conservative(&reference, &b, 0.95, &format!("{mode:?} verified"));
        assert_eq!(sb.cull, Some(mode));
        assert!(sb.verified && !sa.verified);
        assert_eq!(sa.bricks.repaired, 0);
        // A bound culls nothing that shows: verification repairs nothing, the same image.
        if mode == CullMode::Pof {
            assert_eq!(sb.bricks.repaired, 0);
            assert_eq!(a.max_abs_diff(&b), Some(0.0));
        }
    }
}

#[test]
fn previous_predictor_follows_an_orbit() {
    let j = job(48, &[3.0, 1.0]);
    j.forget_previous();
    let mut last: Option<FrameStats> = None;
    for k in 0..4 {
        let c = cam(
            &j,
            20.0 + 3.0 * f64::from(k),
            15.0,
            Projection::Orthographic,
        );
        let (reference, _) = render_reference(&j, &c);
        let (img, st) = render_frame(&j, None, &c, &verified(Predictor::Previous, 2)).unwrap();
        assert_conservative(&reference, &img, 0.95, &format!("orbit frame {k}"));
        // The first frame has no set yet: the proxy predicts it, and the stats say so.
        assert_eq!(st.predictor, Some("previous"));
        let by = if k == 0 { "proxy" } else { "previous" };
        assert_eq!(st.predicted_by, Some(by), "frame {k}");
        if let Some(prev) = &last {
            // A few degrees on, last frame's set is nearly right.
            assert!(
                st.bricks.repaired * 4 <= st.bricks.visible,
                "frame {k}: {:?} after {:?}",
                st.bricks,
                prev.bricks
            );
        }
        last = Some(st);
    }
}

#[test]
fn pof_predictor_without_pofs_is_an_error() {
    let j = job(16, &[1.0, 1.0]);
    let c = cam(&j, 0.0, 0.0, Projection::Orthographic);
    let e = render_frame(&j, None, &c, &verified(Predictor::Pof, 1)).unwrap_err();
    assert!(e.to_string().contains("predictor pof"), "{e}");
    assert!(!e.to_string().contains("--"), "{e}");
}

#[test]
fn predictor_names_round_trip() {
    for p in PREDICTORS {
        let text = match p {
            Predictor::Random(s) => format!("random:{s}"),
            _ => p.name().to_owned(),
        };
        assert_eq!(text.parse::<Predictor>(), Ok(p));
    }
    assert!("bogus".parse::<Predictor>().unwrap_err().contains("proxy"));
    assert!("random:x".parse::<Predictor>().is_err());
}

#[test]
fn proxy_termination_is_where_a_uniform_slab_reaches_the_depth() {
    let j = job(32, &[1.0, 1.0]);
    let proxy = Proxy::new(&j.volume, &j.sampled);
    let n: usize = proxy.cells().iter().product();
    let ext = Extinction::new(vec![0.5f32; n], proxy.cells());
    let air = Extinction::new(vec![0.0f32; n], proxy.cells());
    // Along +x from outside: enters at t = 2, reaches depth 1 after 2 more.
    let ray = crate::render::IndexRay {
        o: [-2.0, 5.0, 5.0],
        d: [1.0, 0.0, 0.0],
        dir: [1.0, 0.0, 0.0],
    };
    let t = proxy.termination(&ext, &ray, 1.0);
    assert!((t - 4.0).abs() < 1e-4, "{t}");
    assert!(proxy.termination(&air, &ray, 1.0).is_infinite());
    // The prediction: where the threshold's depth is reached, then the margin's length.
    let th = 0.95f32;
    let d = -(1.0 - th).ln() * proxy::PROXY_DEPTH_FACTOR;
    let end = proxy.predicted_end(&ext, &ray, th, 0.5);
    // The margin, 2 mm, is 4 voxels of 0.5 mm.
    let want = 2.0 + d / 0.5 + 4.0;
    assert!((end - want).abs() < 1e-3, "{end}, want {want}");
    assert!(proxy.predicted_end(&air, &ray, th, 0.5).is_infinite());
    // In world units: 2 mm is 1.5 voxels of 4/3 mm; a spacing in metres or of unknown
    // units keeps the margin between one voxel and a brick.
    assert!((proxy::margin_length(4.0 / 3.0) - 1.5).abs() < 1e-6);
    assert_eq!(proxy::margin_length(0.000_5), 16.0);
    assert_eq!(proxy::margin_length(0.0), 16.0);
    assert_eq!(proxy::margin_length(1000.0), 1.0);
}

/// A volume of two proxy cells of `c` voxels along x: the first half air (x < c/2), half
/// value 200; the second all 200. The family is opaque (α 0.5 per unit) above 100 only.
fn two_cells(c: usize) -> (crate::volume::Volume, crate::render::SampledTf) {
    use crate::volume::{VoxelData, Voxels};
    let (nx, ny, nz) = (2 * c, c, c);
    let v: Vec<u8> = (0..nx * ny * nz)
        .map(|i| if i % nx < c / 2 { 0 } else { 200 })
        .collect();
    let vol = crate::volume::Volume::new(
        [nx, ny, nz],
        [1.0; 3],
        VoxelData::U8(Voxels::owned(v)),
        "cells",
    )
    .unwrap();
    let tf = crate::render::TransferFunction::from_json(
        r#"{"bases":[{"name":"b","opacity":[[0,0],[100,0],[101,0.5],[255,0.5]]}],"color":[[0,1,1,1]]}"#,
        "t",
    )
    .unwrap();
    let s = crate::render::SampledTf::new(
        &tf,
        crate::brick::ValueRange {
            min: 0.0,
            max: 255.0,
        },
    );
    (vol, s)
}

#[test]
fn proxy_cell_half_air_has_the_effective_extinction_of_its_groups() {
    // Both cell sizes a proxy uses (fine on small volumes, coarse on large ones).
    for c in [proxy::PROXY_CELL, proxy::COARSE_PROXY_CELL] {
        let (vol, s) = two_cells(c);
        let proxy = Proxy::with_cell(&vol, &s, c);
        assert_eq!((proxy.cells(), proxy.cell_edge()), ([2, 1, 1], c));
        let e = -(0.5f32).ln();
        let ext = proxy.extinction(&[1.0]);
        // The uniform cell: its extinction. The half-air one: half the rays cross air over a
        // correlation length, so −ln(½ + ½e^(−eℓ))/ℓ, far below the mean e/2 (which would
        // hide what lies behind a surface too early).
        assert!((ext[1] - e).abs() < 1e-5, "{c}: {ext:?}");
        let l = proxy::CORRELATION_LENGTH;
        let want = -(0.5 + 0.5 * (-e * l).exp()).ln() / l;
        assert!((ext[0] - want).abs() < 1e-5, "{c}: {ext:?}, want {want}");
        assert!(ext[0] < e / 2.0);
        // Weights scale each group's extinction before the groups combine.
        let ext2 = proxy.extinction(&[2.0]);
        assert!((ext2[1] - 2.0 * e).abs() < 1e-5);
        assert!(ext2[0] > ext[0] && ext2[0] < 2.0 * ext[0]);
        // The cached extinction is the same, and follows the weights.
        assert_eq!(proxy.extinction_at(&[1.0]).cells(), ext);
        assert_eq!(proxy.extinction_at(&[2.0]).cells(), ext2);
        assert_eq!(proxy.extinction_at(&[1.0]).cells(), ext);
        // A ray along x through both cells: the half-air cell adds its effective depth over
        // its c voxels, the uniform one reaches the rest at e per unit.
        let ray = crate::render::IndexRay {
            o: [-1.0, 0.5, 0.5],
            d: [1.0, 0.0, 0.0],
            dir: [1.0, 0.0, 0.0],
        };
        let depth = want * c as f32 + 0.5 * e;
        let t = proxy.termination(&Extinction::new(ext, proxy.cells()), &ray, depth);
        assert!((t - (1.0 + c as f32 + 0.5)).abs() < 1e-3, "{c}: {t}");
    }
}

#[test]
fn proxy_cells_are_fine_on_small_volumes_and_coarse_on_large_ones() {
    use proxy::{proxy_cell, COARSE_PROXY_CELL, FINE_PROXY_VOXELS, PROXY_CELL};
    const { assert!(PROXY_CELL < COARSE_PROXY_CELL) };
    // The catalogue's MRI and CTs get fine cells; the 512×512×1728 CT coarse ones.
    for small in [
        [301, 370, 316],
        [256, 256, 133],
        [64, 64, 93],
        [400, 400, 400],
    ] {
        assert_eq!(proxy_cell(small), PROXY_CELL, "{small:?}");
    }
    assert_eq!(proxy_cell([FINE_PROXY_VOXELS, 1, 1]), PROXY_CELL);
    assert_eq!(proxy_cell([FINE_PROXY_VOXELS + 1, 1, 1]), COARSE_PROXY_CELL);
    assert_eq!(proxy_cell([512, 512, 1728]), COARSE_PROXY_CELL);
    // No overflow on absurd dimensions.
    assert_eq!(proxy_cell([usize::MAX, 3, 3]), COARSE_PROXY_CELL);
    // A job's proxy has the cells of its volume's size.
    let j = job(32, &[1.0, 1.0]);
    let p = j.proxy();
    assert_eq!(p.cell_edge(), proxy_cell(j.volume.dims()));
    assert_eq!(
        p.cells(),
        j.volume.dims().map(|n| n.div_ceil(p.cell_edge()))
    );
}

#[test]
fn proxy_sample_rays_predict_the_same_set_for_any_tiling() {
    // The sample rays sit on the image's grid: the union of the tiles' visible sets is the
    // one-tile set, whatever the cut (the culled sets may differ only by bricks another
    // tile finds visible).
    let j = job(48, &[3.0, 1.0]);
    let c = Camera::orbit(&j.volume, 30.0, 20.0, 97, 83, Projection::Orthographic);
    let bricks = FrameBricks::new(&j.volume, &j.grid, &j.sampled, &j.tf.weights, &c);
    let whole = bricks.bounds.unwrap();
    let proxy = j.proxy();
    let predict = |t| proxy.predict((&j.volume, &j.grid), (&c, &bricks), &j.tf.weights, t, 0.95);
    let (vis, culled) = predict(whole);
    assert!(!culled.is_empty(), "the skull hides the inside");
    for cut in [1u32, 2, 3, 7] {
        let xm = whole.x0 + (whole.width() * cut / 8).max(1);
        let ym = whole.y0 + (whole.height() * (8 - cut) / 8).max(1);
        let mut union = std::collections::BTreeSet::new();
        for t in [
            crate::render::PixelRect {
                x0: whole.x0,
                y0: whole.y0,
                x1: xm,
                y1: ym,
            },
            crate::render::PixelRect {
                x0: xm,
                y0: whole.y0,
                x1: whole.x1,
                y1: ym,
            },
            crate::render::PixelRect {
                x0: whole.x0,
                y0: ym,
                x1: xm,
                y1: whole.y1,
            },
            crate::render::PixelRect {
                x0: xm,
                y0: ym,
                x1: whole.x1,
                y1: whole.y1,
            },
        ] {
            union.extend(predict(t).0);
        }
        let want: std::collections::BTreeSet<_> = vis.iter().copied().collect();
        assert_eq!(union, want, "cut {cut}");
    }
}
