use super::range_bound::RangeBound;
use super::spans::PixelSpans;
use super::strip::{all_at_least, strips_of, STRIP_ROWS};
use super::*;
use crate::brick::{BrickGrid, BrickId};
use crate::frame::{render_frame, render_reference, FrameOptions, RenderJob};
use crate::render::{families, Image, RenderSettings, TransferFunction};
use crate::render::{Camera, IndexRay, PixelRect, Projection, RayCaster};
use crate::volume::phantom::Phantom;

/// The threshold rule ([`crate::check::rule`]), asserted.
pub(crate) fn assert_conservative(reference: &Image, culled: &Image, threshold: f32, what: &str) {
    let r = crate::check::check_threshold_rule(reference, culled, threshold);
    assert!(r.holds(), "{what}: {r}");
}

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

#[test]
fn visibility_order_is_front_to_back_along_every_ray() {
    let j = job(40, &[1.0, 1.0]);
    for (az, el, p) in [
        (0.0, 0.0, Projection::Orthographic),
        (37.0, -25.0, Projection::Orthographic),
        (200.0, 60.0, Projection::Perspective),
    ] {
        let c = cam(&j, az, el, p);
        let fb = FrameBricks::new(&j.volume, &j.grid, &j.sampled, &j.tf.weights, &c);
        let rank: std::collections::HashMap<BrickId, usize> =
            fb.order.iter().enumerate().map(|(i, b)| (*b, i)).collect();
        let frame = c.frame();
        for y in (0..c.height).step_by(5) {
            for x in (0..c.width).step_by(5) {
                let ray = IndexRay::new(
                    &c.ray(&frame, f64::from(x) + 0.5, f64::from(y) + 0.5),
                    j.volume.spacing(),
                    j.volume.unit(),
                );
                let mut hits: Vec<(f32, usize)> = fb
                    .order
                    .iter()
                    .filter_map(|b| ray.span(&j.grid.index_box(*b)).map(|s| (s.0, rank[b])))
                    .collect();
                hits.sort_by(|a, b| a.0.total_cmp(&b.0));
                assert!(
                    hits.windows(2).all(|w| w[0].1 < w[1].1),
                    "view {az},{el} pixel {x},{y}: {hits:?}"
                );
            }
        }
    }
}

#[test]
fn cull_none_matches_the_reference_within_float_rounding() {
    let j = job(40, &[1.0, 1.0]);
    let opts = FrameOptions {
        cull: CullMode::None,
        ..FrameOptions::default()
    };
    for (az, el, p) in [
        (0.0, 0.0, Projection::Orthographic),
        (33.0, 21.0, Projection::Perspective),
    ] {
        let c = cam(&j, az, el, p);
        let (reference, _) = render_reference(&j, &c);
        let (img, st) = render_frame(&j, None, &c, &opts).unwrap();
        assert_eq!(st.bricks.culled, 0);
        // Brick fragments terminate early per brick, the reference per ray: where the
        // reference is below the termination threshold the two agree to rounding.
        assert_conservative(&reference, &img, 0.99, "cull none");
    }
}

#[test]
fn range_bound_and_exact_culling_are_conservative_and_cull() {
    for weights in [[1.0, 1.0], [0.3, 2.0], [3.0, 0.0]] {
        let j = job(48, &weights);
        let bound = RangeBound::new(&j.grid, &j.sampled, j.settings.step, j.settings.ert, 4.0);
        for (az, el, p) in [
            (0.0, 0.0, Projection::Orthographic),
            (41.0, 17.0, Projection::Orthographic),
            (-70.0, 30.0, Projection::Perspective),
        ] {
            let c = cam(&j, az, el, p);
            let (reference, _) = render_reference(&j, &c);
            let mut culled = Vec::new();
            for mode in [CullMode::Pof, CullMode::Exact] {
                let opts = FrameOptions {
                    cull: mode,
                    cull_threshold: 0.95,
                    ..FrameOptions::default()
                };
                let (img, st) = render_frame(&j, Some(&bound), &c, &opts).unwrap();
                assert_conservative(
                    &reference,
                    &img,
                    0.95,
                    &format!("{mode:?} {weights:?} {az},{el}"),
                );
                assert!(st.bricks.culled + st.bricks.visible + st.bricks.empty <= st.bricks.total);
                culled.push(st.bricks.culled);
            }
            eprintln!("weights {weights:?} view {az},{el}: culled by bound/exact {culled:?}");
            assert!(
                culled[1] >= culled[0],
                "exact culls at least as much as the bound: {culled:?}"
            );
            if weights[0] > 1.0 {
                assert!(
                    culled[1] > 0,
                    "the skull shell occludes the inside: {culled:?}"
                );
            }
        }
    }
}

#[test]
fn pof_modes_without_pofs_are_an_error() {
    let j = job(16, &[1.0, 1.0]);
    let c = cam(&j, 0.0, 0.0, Projection::Orthographic);
    let e = render_frame(&j, None, &c, &FrameOptions::default()).unwrap_err();
    assert!(e.to_string().contains("pof build"), "{e}");
    let _ = TransferFunction::from_json(families::SHEPP_LOGAN_JSON, "x").unwrap();
}

#[test]
fn frame_is_identical_for_any_rank_count_and_curve() {
    use crate::distribute::Curve;
    let j = job(40, &[2.0, 1.0]);
    let bound = RangeBound::new(&j.grid, &j.sampled, j.settings.step, j.settings.ert, 4.0);
    for (az, el, p, mode) in [
        (30.0, 20.0, Projection::Orthographic, CullMode::Exact),
        (-60.0, 10.0, Projection::Perspective, CullMode::Pof),
        (0.0, 0.0, Projection::Orthographic, CullMode::None),
    ] {
        let c = cam(&j, az, el, p);
        let one = FrameOptions {
            cull: mode,
            ranks: 1,
            ..FrameOptions::default()
        };
        let (base, base_stats) = render_frame(&j, Some(&bound), &c, &one).unwrap();
        for (curve, replicas) in [(Curve::Hilbert, 1), (Curve::Z, 1), (Curve::Hilbert, 2)] {
            for ranks in [1, 2, 3, 4, 7, 32] {
                if replicas > ranks {
                    continue;
                }
                let opts = FrameOptions {
                    cull: mode,
                    ranks,
                    curve,
                    replicas,
                    ..FrameOptions::default()
                };
                let (img, st) = render_frame(&j, Some(&bound), &c, &opts).unwrap();
                assert_eq!(
                    img.max_abs_diff(&base),
                    Some(0.0),
                    "{mode:?} {curve:?} {ranks} ranks, {replicas} replicas"
                );
                assert_eq!(
                    st.bricks, base_stats.bricks,
                    "{mode:?} {curve:?} {ranks} ranks, {replicas} replicas"
                );
                assert_eq!(st.ranks.len(), ranks);
                let rendered: usize = st.ranks.iter().map(|r| r.bricks_rendered).sum();
                assert_eq!(
                    rendered, st.bricks.visible,
                    "each visible brick is rendered once"
                );
            }
        }
    }
}

#[test]
fn each_row_of_a_core_footprint_is_one_run() {
    // The POF composite fills each row between the first and last core pixel; that is
    // exact only because a ray's length inside a box is concave in the pixel position.
    let j = job(40, &[1.0, 1.0]);
    for (az, el) in [(0.0, 0.0), (37.0, -25.0), (200.0, 60.0), (91.0, 3.0)] {
        let c = cam(&j, az, el, Projection::Orthographic);
        let frame = c.frame();
        let spans = PixelSpans::new(&c, &frame, &j.volume);
        let fb = FrameBricks::new(&j.volume, &j.grid, &j.sampled, &j.tf.weights, &c);
        let mut runs = 0;
        for id in j.grid.ids() {
            let Some(rect) = fb.footprints[id.index()] else {
                continue;
            };
            let ibox = j.grid.index_box(id);
            for core in [2.0f32, 4.0, 6.0] {
                for y in rect.y0..rect.y1 {
                    let flags: Vec<bool> = (rect.x0..rect.x1)
                        .map(|x| spans.in_core(x, y, &ibox, core))
                        .collect();
                    let starts = flags
                        .iter()
                        .enumerate()
                        .filter(|(i, f)| **f && (*i == 0 || !flags[i - 1]))
                        .count();
                    assert!(
                        starts <= 1,
                        "view {az},{el} brick {id:?} row {y}: {flags:?}"
                    );
                    runs += starts;
                }
            }
        }
        assert!(runs > 100, "view {az},{el}: only {runs} core runs");
    }
}

#[test]
fn row_candidates_hold_every_pixel_the_exact_tests_pass_and_runs_only_such_pixels() {
    // The culler only tests the candidates of a row; a pixel outside them that passes the
    // exact test would be a brick wrongly culled. It fills runs without a test per pixel;
    // a pixel in a run that fails the exact test would be opacity wrongly added.
    let j = job(40, &[1.0, 1.0]);
    let (mut tight, mut rows, mut passing) = (0usize, 0usize, 0usize);
    let mut exact_runs = 0usize;
    for (az, el) in [
        (0.0, 0.0),
        (37.0, -25.0),
        (200.0, 60.0),
        (91.0, 3.0),
        (90.0, 0.0),
    ] {
        let c = cam(&j, az, el, Projection::Orthographic);
        let frame = c.frame();
        let spans = PixelSpans::new(&c, &frame, &j.volume);
        let fb = FrameBricks::new(&j.volume, &j.grid, &j.sampled, &j.tf.weights, &c);
        for id in j.grid.ids() {
            let Some(rect) = fb.footprints[id.index()] else {
                continue;
            };
            let ibox = j.grid.index_box(id);
            for core in [None, Some(2.0f32), Some(4.0), Some(6.0)] {
                for y in rect.y0..rect.y1 {
                    let xs = spans
                        .row_candidates(y, &ibox, core, (rect.x0, rect.x1))
                        .expect("orthographic");
                    let box_rows = spans.rows_of(&ibox).expect("orthographic");
                    for x in rect.x0..rect.x1 {
                        let pass = match core {
                            None => spans.hits(x, y, &ibox),
                            Some(l) => spans.in_core(x, y, &ibox, l),
                        };
                        passing += usize::from(pass);
                        assert!(
                            !pass || (box_rows.0..box_rows.1).contains(&y),
                            "view {az},{el} brick {id:?}: row {y} outside {box_rows:?}"
                        );
                        assert!(
                            !pass || xs.contains(&x),
                            "view {az},{el} brick {id:?} core {core:?} row {y}: {x} outside {xs:?}"
                        );
                    }
                    // Candidates are the passing pixels and at most two more at each end.
                    let n = (rect.x0..rect.x1)
                        .filter(|x| match core {
                            None => spans.hits(*x, y, &ibox),
                            Some(l) => spans.in_core(*x, y, &ibox, l),
                        })
                        .count();
                    tight += usize::from(xs.len() <= n + 4);
                    rows += 1;
                    // The runs the culler fills: only pixels the exact test passes, and
                    // all of them but where a pixel centre sits on the region's edge.
                    let run = spans
                        .region(&ibox, core)
                        .expect("orthographic")
                        .run(y, (rect.x0, rect.x1));
                    for x in run.clone() {
                        let pass = match core {
                            None => spans.hits(x, y, &ibox),
                            Some(l) => spans.in_core(x, y, &ibox, l),
                        };
                        assert!(
                            pass,
                            "view {az},{el} brick {id:?} core {core:?} row {y}: {x} in run {run:?} fails"
                        );
                    }
                    exact_runs += usize::from(run.len() == n);
                    // Clipped to any window (a tile's edge cuts a brick's footprint), a run
                    // keeps only passing pixels of the window, even where the region lies
                    // wholly on one side of it.
                    let region = spans.region(&ibox, core).expect("orthographic");
                    for (w0, w1) in [
                        (rect.x0, rect.x0 + 1),
                        (rect.x1 - 1, rect.x1),
                        (rect.x0 + rect.width() / 2, rect.x1),
                        (rect.x0, rect.x0 + rect.width() / 3),
                    ] {
                        let clipped = region.run(y, (w0, w1));
                        assert!(
                            clipped.is_empty() || (w0 <= clipped.start && clipped.end <= w1),
                            "{clipped:?} outside {w0}..{w1}"
                        );
                        assert_eq!(
                            clipped.len(),
                            run.clone().filter(|x| (w0..w1).contains(x)).count(),
                            "view {az},{el} brick {id:?} core {core:?} row {y}: window {w0}..{w1}"
                        );
                    }
                }
            }
        }
    }
    assert!(passing > 10_000, "only {passing} passing pixels");
    assert!(tight * 100 >= rows * 99, "{tight} of {rows} rows tight");
    assert!(
        exact_runs * 1000 >= rows * 999,
        "{exact_runs} of {rows} runs hold every passing pixel"
    );
    // Perspective views have no candidates: the culler tests every pixel.
    let c = cam(&j, 30.0, 20.0, Projection::Perspective);
    let frame = c.frame();
    let spans = PixelSpans::new(&c, &frame, &j.volume);
    assert!(spans
        .row_candidates(0, &j.grid.index_box(BrickId(0)), None, (0, 10))
        .is_none());
}

#[test]
fn all_at_least_agrees_with_the_plain_test_at_every_length_and_position() {
    for len in 0..40 {
        let row = vec![0.96f32; len];
        assert!(all_at_least(&row, 0.95), "len {len}");
        for low in 0..len {
            let mut r = row.clone();
            r[low] = 0.2;
            assert!(!all_at_least(&r, 0.95), "len {len}, low pixel at {low}");
            r[low] = 0.95;
            assert!(all_at_least(&r, 0.95), "len {len}, equal at {low}");
        }
    }
}

#[test]
fn occupied_layers_peel_the_occupied_region_from_its_surface() {
    // Weights do not matter: the layers are the family's, not the frame's.
    let j = job(96, &[0.0, 1.0]);
    let layers = j.occupied_layers();
    let every = vec![1.0; j.sampled.basis_count()];
    let counts = j.grid.counts();
    let mut deepest = 0;
    for id in j.grid.ids() {
        let l = layers[id.index()];
        assert_eq!(
            l == 0,
            j.sampled.is_empty(j.grid.range(id), &every),
            "{id:?}"
        );
        if l == 0 {
            continue;
        }
        deepest = deepest.max(l);
        let c = j.grid.coords(id);
        let mut near = Vec::new();
        for a in 0..3 {
            for s in [-1i64, 1] {
                let x = c[a] as i64 + s;
                if x < 0 || x >= counts[a] as i64 {
                    near.push(0); // outside the volume counts as empty
                    continue;
                }
                let mut n = c;
                {
                    n[a] = x as usize;
                }
                near.push(layers[j.grid.id(n).index()]);
            }
        }
        // One more than the nearest neighbour layer (a distance field in bricks).
        assert_eq!(
            l,
            near.iter().min().unwrap() + 1,
            "{id:?}: {l} beside {near:?}"
        );
    }
    assert!(
        deepest >= 3,
        "the phantom's head is several bricks deep: {deepest}"
    );
    // The deal gives every rank its share of each layer.
    let a = j
        .assignment(crate::distribute::Curve::Hilbert, 7, 1)
        .unwrap();
    for l in 1..=deepest {
        let per: Vec<usize> = (0..7)
            .map(|r| {
                a.of(crate::distribute::Rank(r))
                    .iter()
                    .filter(|b| layers[b.index()] == l)
                    .count()
            })
            .collect();
        assert!(
            per.iter().max().unwrap() - per.iter().min().unwrap() <= 1,
            "layer {l}: {per:?}"
        );
    }
}

/// The views the POF-level tests render: axis-aligned, two oblique, one perspective.
const LEVEL_VIEWS: [(f64, f64, Projection); 4] = [
    (0.0, 0.0, Projection::Orthographic),
    (41.0, 17.0, Projection::Orthographic),
    (130.0, -35.0, Projection::Orthographic),
    (-70.0, 30.0, Projection::Perspective),
];

/// A POF table of `j`'s family for the bricks of `grid` (8×8 views), with core length
/// `core` (`None`: half a brick).
fn pof_table(j: &RenderJob, grid: &BrickGrid, core: Option<f32>) -> crate::pof::PofTable {
    let settings = crate::pof::PofSettings {
        views: [8, 8],
        core_length: core,
        step: j.settings.step,
        ert: j.settings.ert,
        ..crate::pof::PofSettings::default()
    };
    crate::pof::PofTable::build(&j.volume, grid, &j.tf, &j.sampled, &settings, &|_, _| {}).unwrap()
}

#[test]
fn core_levels_cull_more_and_keep_the_threshold_rule() {
    // The skull shell occludes the inside.
    let j = job(64, &[3.0, 1.0]);
    let table = |core: f32| pof_table(&j, &j.grid, Some(core));
    // Out of order on purpose: levels sort by core length.
    let levels = CoreLevels::new(vec![table(7.0), table(4.0)])
        .unwrap()
        .unwrap();
    assert_eq!(levels.core_lengths(), vec![4.0, 7.0]);
    assert!(CoreLevels::new(vec![table(4.0), table(4.0)]).is_err());
    assert!(CoreLevels::new(Vec::new()).unwrap().is_none());
    let single = table(4.0);
    let mut more = 0;
    for (az, el, p) in LEVEL_VIEWS {
        let c = cam(&j, az, el, p);
        let (reference, _) = render_reference(&j, &c);
        let opts = FrameOptions {
            cull: CullMode::Pof,
            cull_threshold: 0.95,
            ..FrameOptions::default()
        };
        let (one, st1) = render_frame(&j, Some(&single), &c, &opts).unwrap();
        let (two, st2) = render_frame(&j, Some(&levels), &c, &opts).unwrap();
        assert_conservative(&reference, &one, 0.95, &format!("one level {az},{el}"));
        assert_conservative(&reference, &two, 0.95, &format!("two levels {az},{el}"));
        eprintln!(
            "view {az},{el}: culled with one / two levels {} / {}",
            st1.bricks.culled, st2.bricks.culled
        );
        assert!(st2.bricks.culled >= st1.bricks.culled, "{az},{el}");
        more += st2.bricks.culled - st1.bricks.culled;
    }
    assert!(more > 0, "a longer core lifts culling somewhere");
}

#[test]
fn sub_brick_bounds_keep_the_threshold_rule_and_cull() {
    // An occluding skull, and a see-through one where over-culling would show.
    let culled = sub_brick_case(&[3.0, 1.0]);
    assert!(culled > 0, "sub-brick bounds cull the phantom's inside");
    sub_brick_case(&[0.6, 1.0]);
}

/// Renders the phantom with sub-brick bounds (alone, two levels, beside the render bricks'
/// own) at several views and rank counts, checks the threshold rule and that the frame
/// does not depend on the rank count, and returns how many bricks were culled.
fn sub_brick_case(weights: &[f32]) -> usize {
    // Render bricks of 8, POFs for bricks of 4.
    let j = job(64, weights);
    let fine = BrickGrid::from_volume(&j.volume, 4).unwrap();
    let table = |core: f32| pof_table(&j, &fine, Some(core));
    let one = CoreLevels::from(table(2.0)).with_grid(fine.clone());
    let two = CoreLevels::new(vec![table(2.0), table(3.5)])
        .unwrap()
        .unwrap()
        .with_grid(fine.clone());
    assert!(two.grid().is_some());
    // Bounds for the render bricks and for their sub-bricks: each pixel takes the higher.
    let own = pof_table(&j, &j.grid, None);
    let both =
        CoreLevels::from(own).with_sub_bricks(CoreLevels::from(table(2.0)).with_grid(fine.clone()));
    assert!(both.grid().is_none() && both.sub_bricks().is_some());
    let own_only = CoreLevels::from(pof_table(&j, &j.grid, None));
    let mut culled = 0;
    for (az, el, p) in LEVEL_VIEWS {
        let c = cam(&j, az, el, p);
        let (reference, _) = render_reference(&j, &c);
        let mut by_name = std::collections::HashMap::new();
        for (levels, name) in [
            (&one, "one level"),
            (&two, "two levels"),
            (&own_only, "own level"),
            (&both, "own and sub-brick levels"),
        ] {
            let mut frames = Vec::new();
            for ranks in [1, 3] {
                let opts = FrameOptions {
                    cull: CullMode::Pof,
                    cull_threshold: 0.95,
                    ranks,
                    ..FrameOptions::default()
                };
                let (img, st) = render_frame(&j, Some(levels), &c, &opts).unwrap();
                assert_conservative(&reference, &img, 0.95, &format!("{name} {az},{el}"));
                culled += st.bricks.culled;
                if ranks == 1 {
                    by_name.insert(name, st.bricks.culled);
                }
                frames.push(img);
            }
            assert_eq!(
                frames[0].pixels(),
                frames[1].pixels(),
                "{name} {az},{el}: 1 vs 3 ranks"
            );
        }
        // Each pixel takes the higher of the two bounds, so together they cull what either
        // culls alone (skipping the sub-bricks where the brick's own bound suffices must
        // keep that).
        let both = by_name["own and sub-brick levels"];
        assert!(
            both >= by_name["own level"] && both >= by_name["one level"],
            "{az},{el}: {by_name:?}"
        );
    }
    culled
}

#[test]
fn leaving_out_sub_bricks_where_the_bricks_own_bound_suffices_changes_nothing() {
    // The skull left out (bone weight 0), the brain opaque: bricks at the brain's edge are partly empty,
    // where only sub-bricks bound anything, and bricks inside are opaque on their own.
    let j = job(64, &[3.0, 0.0]);
    let fine = BrickGrid::from_volume(&j.volume, 4).unwrap();
    let both = CoreLevels::from(pof_table(&j, &j.grid, None))
        .with_sub_bricks(CoreLevels::from(pof_table(&j, &fine, Some(2.0))).with_grid(fine));
    let own = CoreLevels::from(pof_table(&j, &j.grid, None));
    let opts = FrameOptions {
        cull: CullMode::Pof,
        cull_threshold: 0.95,
        ..FrameOptions::default()
    };
    let mut gained = 0;
    for (az, el, p) in LEVEL_VIEWS {
        let c = cam(&j, az, el, p);
        let (_, st_own) = render_frame(&j, Some(&own), &c, &opts).unwrap();
        let (_, st_with) = render_frame(&j, Some(&both), &c, &opts).unwrap();
        // The frame's culling, by hand, with the shortcut and without: the same bricks
        // culled and visible, so the same frame.
        let weights = &j.tf.weights;
        let cls = j.sampled.classify(weights, j.settings.step);
        let caster = RayCaster::new(&j.volume, &cls, j.settings);
        let bricks = FrameBricks::new(&j.volume, &j.grid, &j.sampled, weights, &c);
        let tile = bricks.bounds.expect("the phantom is on screen");
        let scratch = CullScratch::new();
        let runs: Vec<CullResult> = [true, false]
            .into_iter()
            .map(|skip_sub_bricks| {
                let culler = Culler {
                    volume: &j.volume,
                    grid: &j.grid,
                    mode: CullMode::Pof,
                    threshold: opts.cull_threshold,
                    weights,
                    bounds: Some(&both),
                    caster: &caster,
                    scratch: &scratch,
                    skip_sub_bricks,
                };
                culler.cull(&c, &bricks, tile)
            })
            .collect();
        let (with, without) = (&runs[0], &runs[1]);
        assert_eq!(with.visible, without.visible, "{az},{el}: visible bricks");
        assert_eq!(with.culled, without.culled, "{az},{el}: culled bricks");
        assert_eq!(
            with.culled.len(),
            st_with.bricks.culled,
            "{az},{el}: as the frame"
        );
        eprintln!(
            "view {az},{el}: culled by the own bound / with sub-bricks {} / {}",
            st_own.bricks.culled, st_with.bricks.culled
        );
        gained += st_with.bricks.culled.saturating_sub(st_own.bricks.culled);
    }
    assert!(
        gained > 0,
        "sub-bricks cull more somewhere, or the case tests nothing"
    );
}

#[test]
fn strips_tile_the_tile_and_strip_culling_keeps_the_threshold_rule() {
    let tile = PixelRect {
        x0: 3,
        y0: 5,
        x1: 203,
        y1: 205,
    };
    let strips = strips_of(tile, CullMode::Pof);
    assert_eq!(strips.len(), 4);
    assert_eq!(strips[0].y0, tile.y0);
    assert_eq!(strips[3].y1, tile.y1);
    for w in strips.windows(2) {
        assert_eq!(w[0].y1, w[1].y0);
    }
    assert!(strips.iter().all(|s| s.x0 == tile.x0 && s.x1 == tile.x1));
    assert!(strips.iter().all(|s| s.height() <= STRIP_ROWS));
    // The oracle stays sequential; small tiles stay whole.
    assert_eq!(strips_of(tile, CullMode::Exact), vec![tile]);
    let small = PixelRect { y1: 100, ..tile };
    assert_eq!(strips_of(small, CullMode::PofSet), vec![small]);

    // A frame tall enough to be culled in strips, against the reference.
    let j = job(64, &[3.0, 1.0]);
    let table = pof_table(&j, &j.grid, None);
    let mut culled = 0;
    for (az, el, p) in LEVEL_VIEWS {
        let c = Camera::orbit(&j.volume, az, el, 200, 200, p);
        let (reference, _) = render_reference(&j, &c);
        for mode in [CullMode::Pof, CullMode::PofSet] {
            let opts = FrameOptions {
                cull: mode,
                cull_threshold: 0.95,
                ..FrameOptions::default()
            };
            let (img, st) = render_frame(&j, Some(&table), &c, &opts).unwrap();
            assert_conservative(&reference, &img, 0.95, &format!("{mode:?} {az},{el}"));
            culled += st.bricks.culled;
        }
    }
    assert!(culled > 0, "strip culling culls the phantom's inside");
}

#[test]
fn ideal_pofs_sit_between_the_tables_and_the_oracle() {
    let j = job(64, &[3.0, 1.0]);
    let levels = CoreLevels::new(vec![
        pof_table(&j, &j.grid, Some(4.0)),
        pof_table(&j, &j.grid, Some(7.0)),
    ])
    .unwrap()
    .unwrap();
    let ideal = ideal::IdealPofs::new(
        &j.volume,
        &j.grid,
        &j.sampled,
        (j.settings.step, j.settings.ert),
        &levels.core_lengths(),
    )
    .unwrap();
    assert_eq!(ideal.core_length(), 4.0);
    assert_eq!(ideal.deeper(0).map(OpacityBound::core_length), Some(7.0));
    assert!(ideal.deeper(1).is_none());
    assert_eq!(levels.deeper(0).map(OpacityBound::core_length), Some(7.0));
    assert!(levels.deeper(1).is_none());
    assert!(ideal::IdealPofs::new(&j.volume, &j.grid, &j.sampled, (1.0, 0.99), &[]).is_none());
    let mut above = 0;
    for (az, el) in [(0.0, 0.0), (37.0, 23.0), (150.0, -30.0)] {
        let c = cam(&j, az, el, Projection::Orthographic);
        let d = c.frame().forward;
        // Per brick and level: the table is a rigorous bound of the measured minimum.
        let mut level: Option<(&dyn OpacityBound, &dyn OpacityBound)> = Some((&levels, &ideal));
        let mut deeper = 0;
        while let Some((t, i)) = level {
            for id in j.grid.ids() {
                let (tv, iv) = (
                    t.opacity(id, d, &j.tf.weights, false),
                    i.opacity(id, d, &j.tf.weights, false),
                );
                assert!(
                    tv <= iv + 1e-6,
                    "view {az},{el} brick {id:?} core {}: table {tv} above measured {iv}",
                    t.core_length()
                );
                above += usize::from(iv > tv + 1e-3);
            }
            level = levels.deeper(deeper).zip(ideal.deeper(deeper));
            deeper += 1;
        }
        // So culling with the measurements culls at least as much; the oracle (the real
        // composited opacity over every pixel, rims included) culls more still here.
        let run = |mode, b: &dyn OpacityBound| {
            let opts = FrameOptions {
                cull: mode,
                ..FrameOptions::default()
            };
            render_frame(&j, Some(b), &c, &opts)
                .unwrap()
                .1
                .bricks
                .culled
        };
        let (pof, ideal_culled, exact) = (
            run(CullMode::Pof, &levels),
            run(CullMode::Pof, &ideal),
            run(CullMode::Exact, &levels),
        );
        eprintln!("view {az},{el}: culled pof {pof}, ideal {ideal_culled}, exact {exact}");
        assert!(
            pof <= ideal_culled && ideal_culled <= exact,
            "view {az},{el}: {pof} {ideal_culled} {exact}"
        );
    }
    assert!(
        above > 0,
        "the measured minima are above the bound somewhere"
    );
}
