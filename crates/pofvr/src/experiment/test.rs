//! Phantom-sized runs of each experiment: the rows' counts, the relations between them,
//! and the threshold rule on the conservative methods.

use super::audit::SplitMix;
use super::bench_cull::{self, TargetSpec, CASES};
use super::*;
use crate::cull::CullMode;
use crate::frame::{render_frame, FrameOptions, RenderJob};
use crate::render::{families, Camera, Projection, RenderSettings};
use crate::volume::phantom::Phantom;

const SIZE: (u32, u32) = (48, 40);

fn job() -> RenderJob {
    let mut tf = families::for_phantom(Phantom::SheppLogan);
    tf.set_weights(vec![1.0, 1.0]).unwrap();
    RenderJob::new(
        Phantom::SheppLogan.generate(40),
        tf,
        8,
        RenderSettings::default(),
    )
    .unwrap()
}

fn pofs(job: &RenderJob, sets: bool) -> PofBuild {
    pof_construction(job, [6, 6], PofSource::Build, sets, &NoProgress).unwrap()
}

fn pof_method<'a>(name: &'static str, bound: &'a dyn crate::cull::OpacityBound) -> Method<'a> {
    Method {
        name,
        mode: CullMode::Pof,
        bound: Some(bound),
        missing: None,
        conservative: true,
        about: "",
    }
}

fn camera(job: &RenderJob) -> Camera {
    Camera::orbit(
        &job.volume,
        0.0,
        0.0,
        SIZE.0,
        SIZE.1,
        Projection::Orthographic,
    )
}

#[test]
fn pof_construction_builds_every_encoding_and_the_sets_when_asked() {
    let j = job();
    let p = pofs(&j, true);
    let names: Vec<(&str, bool)> = p.rows.iter().map(|r| (r.encoding, r.sets)).collect();
    assert_eq!(
        names,
        [
            ("table", false),
            ("u8", false),
            ("u16", false),
            ("cubic", false),
            ("table", true)
        ]
    );
    assert!(p.table_built);
    assert!(p.sets().is_some_and(crate::pof::PofTable::has_sets));
    for r in &p.rows {
        assert_eq!(r.views, "6x6");
        assert_eq!(r.source, "built");
        assert!(r.computed_bricks.is_some_and(|n| n > 0), "{r:?}");
        assert!(r.file_bytes > 0 && r.stored_bricks > 0, "{r:?}");
    }
    let bytes = |k: usize| p.rows[k].bytes_per_brick_per_basis;
    // u8 < u16 < f32 tables; the cubic encoding stores 4 coefficients per cell row.
    assert!(bytes(1) < bytes(2) && bytes(2) < bytes(0), "{:?}", p.rows);
    assert!(bytes(3) < bytes(0), "{:?}", p.rows);
    let read = pof_construction(
        &j,
        [6, 6],
        PofSource::Read {
            table: Box::new(p.table),
            from: "memory".into(),
        },
        false,
        &NoProgress,
    )
    .unwrap();
    assert!(!read.table_built);
    assert_eq!(read.rows[0].source, "read from memory");
    assert_eq!(read.rows[0].seconds, None);
    assert_eq!(read.rows.len(), 4, "no sets asked for");
}

#[test]
fn culling_vs_view_counts_every_view_and_pof_culls_within_the_oracle() {
    let j = job();
    let p = pofs(&j, false);
    let methods = [
        Method::none(),
        pof_method("pof-table", &p.table),
        Method::exact(),
        Method::verified(),
    ];
    let f = culling_vs_view(&j, &methods, 0.95, SIZE, &NoProgress).unwrap();
    assert_eq!(f.azimuths.len(), 18);
    assert_eq!(f.rows.len(), 18 * methods.len());
    let mut verified_culled = 0;
    for views in f.rows.chunks(methods.len()) {
        let (none, pof, exact, verified) = (&views[0], &views[1], &views[2], &views[3]);
        assert_eq!(none.culled, 0, "{none:?}");
        // A conservative bound culls only bricks that are hidden.
        assert!(pof.culled <= exact.culled, "{pof:?} vs {exact:?}");
        // Verified culling renders what it predicted and what it repaired: the bricks
        // on screen, as every method.
        assert_eq!(
            verified.visible + verified.culled,
            none.visible,
            "{verified:?}"
        );
        assert!(verified.repaired <= verified.visible, "{verified:?}");
        verified_culled += verified.culled;
        for r in views {
            assert_eq!(r.non_empty, none.non_empty);
            assert!(r.visible + r.culled <= r.non_empty, "{r:?}");
            if r.method != "verified" {
                assert_eq!(r.repaired, 0, "{r:?}");
            }
        }
    }
    // What the proxy culls here is measured, not asserted: on this small phantom it
    // predicts nothing hidden, and verification keeps the frame right either way.
    eprintln!("verified culled {verified_culled} bricks over 18 views");
    let exact_culled: usize = f
        .rows
        .iter()
        .filter(|r| r.method == "exact")
        .map(|r| r.culled)
        .sum();
    assert!(
        exact_culled > 0,
        "the family occludes nothing: the test says nothing"
    );
    for (m, mean) in methods.iter().zip(&f.means) {
        assert_eq!(mean.method, m.name);
        let rows: Vec<_> = f.rows.iter().filter(|r| r.method == m.name).collect();
        let v = rows.iter().map(|r| r.visible as f64).sum::<f64>() / 18.0;
        assert!((mean.mean_visible - v).abs() < 1e-9);
        assert!((0.0..=1.0).contains(&mean.mean_culled_fraction_of_non_empty));
        let repaired = rows.iter().map(|r| r.repaired as f64).sum::<f64>() / 18.0;
        assert!((mean.mean_repaired - repaired).abs() < 1e-9);
    }
}

#[test]
fn a_frame_with_one_core_per_rank_is_the_frame() {
    let j = job();
    let p = pofs(&j, false);
    let m = pof_method("pof-table", &p.table);
    let cam = camera(&j);
    let opts = FrameOptions {
        ranks: 3,
        ..FrameOptions::default()
    };
    let (want, st0) = render_frame(&j, m.bound, &cam, &opts).unwrap();
    let (got, st) = one_core_per_rank(&j, &m, &cam, &opts).unwrap();
    assert_eq!(got, want);
    assert_eq!(st.bricks, st0.bricks);
    assert_eq!(st.samples, st0.samples);
    assert_eq!((st.threads, st.ranks.len()), (3, 3));
}

#[test]
fn rank_breakdown_has_every_rank_and_they_render_the_visible_bricks() {
    let j = job();
    let r = range_bound(&j);
    let methods = [
        Method::none(),
        pof_method("range-bound", &r),
        Method::verified(),
    ];
    let f = rank_breakdown(&j, &methods, &camera(&j), 0.95, 3, 1, &NoProgress).unwrap();
    assert_eq!(f.frames.len(), 3);
    for fr in &f.frames {
        assert_eq!(fr.ranks, 3);
        assert_eq!(fr.stats.ranks.len(), 3);
        // Repaired bricks are rendered once, by their owners, as the predicted ones.
        let rendered: usize = fr.stats.ranks.iter().map(|r| r.bricks_rendered).sum();
        assert_eq!(rendered, fr.visible, "{}", fr.method);
        assert_eq!(fr.repaired, fr.stats.bricks.repaired, "{}", fr.method);
        assert!(fr.load_balance_max_over_mean_samples >= 1.0);
        let verified = fr.method == "verified";
        assert_eq!(fr.stats.verified, verified, "{}", fr.method);
        if !verified {
            assert!(
                fr.stats.ranks.iter().all(|r| r.verify_ms == 0.0),
                "{}",
                fr.method
            );
        }
    }
}

#[test]
fn speedup_measures_each_curve_method_and_count_from_one() {
    assert_eq!(rank_counts(1), vec![1]);
    assert_eq!(rank_counts(8), vec![1, 2, 4, 8]);
    assert_eq!(rank_counts(6), vec![1, 2, 4, 6]);
    let j = job();
    let methods = [Method::none(), Method::exact()];
    let f = speedup(&j, &methods, &camera(&j), 0.95, &[1, 2, 3], 1, &NoProgress).unwrap();
    assert_eq!(f.rows.len(), 2 * 2 * 3);
    for line in f.rows.chunks(3) {
        assert_eq!(line.iter().map(|r| r.ranks).collect::<Vec<_>>(), [1, 2, 3]);
        assert!(line
            .iter()
            .all(|r| r.method == line[0].method && r.curve == line[0].curve));
        assert_eq!(line[0].speedup, 1.0);
        for r in line {
            assert!(r.load_balance_max_over_mean_samples >= 1.0, "{r:?}");
            assert!((r.efficiency - r.speedup / r.ranks as f64).abs() < 1e-12);
            // The same frame, however many ranks draw it.
            assert_eq!(r.visible, line[0].visible, "{r:?}");
        }
    }
    let best = f.best.unwrap();
    assert!(f.rows.iter().all(|r| r.speedup <= best.speedup));
}

#[test]
fn tf_family_measures_each_weighting_and_restores_the_weights() {
    let mut j = job();
    let p = pofs(&j, false);
    let m = pof_method("pof-table", &p.table);
    let cam = camera(&j);
    let before = j.tf.weights.clone();
    let (k0s, k1s) = weight_grid(true);
    let f = tf_family(
        &mut j,
        &[m, Method::exact(), Method::verified()],
        &m,
        &cam,
        0.95,
        (&k0s, &k1s),
        &NoProgress,
    )
    .unwrap();
    assert_eq!(j.tf.weights, before);
    assert_eq!(f.rows.len(), k0s.len() * k1s.len() * 4);
    for w in f.rows.chunks(4) {
        assert_eq!(
            w.iter().map(|r| r.method).collect::<Vec<_>>(),
            ["none", "pof-table", "exact", "verified"]
        );
        assert!(w[1].culled <= w[2].culled, "{w:?}");
        assert_eq!(w[3].visible + w[3].culled, w[0].visible, "{w:?}");
        assert!(w[3].repaired <= w[3].visible, "{w:?}");
        assert!(w.iter().all(|r| r.k0 == w[0].k0 && r.k1 == w[0].k1));
    }
    assert_eq!(f.images.len(), PAPER_WEIGHTS.len());
    for (im, (k0, k1)) in f.images.iter().zip(PAPER_WEIGHTS) {
        assert_eq!((im.k0, im.k1), (k0, Some(k1)));
        assert_eq!(im.method, "pof-table");
        assert_eq!((im.image.width(), im.image.height()), SIZE);
    }
}

#[test]
fn the_audit_finds_no_conservative_method_breaking_the_rule() {
    let j = job();
    let p = pofs(&j, true);
    let r = range_bound(&j);
    let all = methods(&p, &r, "no sets");
    let names: Vec<&str> = all.iter().map(|m| m.name).collect();
    assert_eq!(
        names,
        [
            "none",
            "pof-table",
            "pof-cubic",
            "pof-set",
            "exact",
            "range-bound",
            "verified"
        ]
    );
    assert!(all.iter().all(Method::available));
    assert_eq!(primary(&all).unwrap().name, "pof-table");
    let methods: Vec<Method<'_>> = all
        .into_iter()
        .filter(|m| m.mode != CullMode::None)
        .collect();
    assert!(
        methods.iter().any(|m| !m.conservative),
        "pof-set is audited too"
    );
    let a = audit(&j, &methods, 0.95, 6, 1, SIZE, &NoProgress).unwrap();
    assert_eq!(a.rows.len(), 6 * methods.len());
    assert_eq!(a.pixels_per_view, u64::from(SIZE.0 * SIZE.1));
    assert!(a.passed(), "{:?}", a.methods);
    for t in a.methods.iter().filter(|t| t.conservative) {
        assert_eq!(t.violations, 0, "{t:?}");
        assert!(t.max_abs_diff <= 0.05 + 1e-6, "{t:?}");
    }
    let exact = a.methods.iter().find(|t| t.method == "exact").unwrap();
    assert!(
        exact.bricks_culled_over_all_views > 0,
        "nothing culled: nothing audited"
    );
    let projections: Vec<&str> = a
        .rows
        .iter()
        .step_by(methods.len())
        .map(|r| r.projection)
        .collect();
    assert_eq!(
        projections,
        ["orthographic", "orthographic", "perspective"].repeat(2)
    );
}

#[test]
fn audit_views_are_deterministic_and_in_range() {
    let mut a = SplitMix(7);
    let mut b = SplitMix(7);
    for _ in 0..1000 {
        let x = a.next_f64();
        assert!((0.0..1.0).contains(&x));
        assert_eq!(x.to_bits(), b.next_f64().to_bits());
    }
}

#[test]
fn bench_cull_measures_every_case_and_checks_named_targets() {
    let j = job();
    let p = pofs(&j, true);
    let levels: crate::cull::CoreLevels = p.sets_table.unwrap().into();
    let b = bench_cull(&j, &levels, &camera(&j), 2, &NoProgress).unwrap();
    assert_eq!(b.cases.len(), CASES.len());
    for (c, (mode, ranks, replicas)) in b.cases.iter().zip(CASES) {
        assert_eq!(
            (c.mode, c.ranks, c.replicas),
            (mode.name(), ranks, replicas)
        );
        assert!((0.0..=1.0).contains(&c.culled_fraction), "{c:?}");
        assert!(c.load_balance_max_over_mean_samples >= 1.0, "{c:?}");
    }
    let pof = b.case("pof", 1, 1).unwrap();
    assert!(pof.culled <= b.case("exact", 1, 1).unwrap().culled);
    assert_eq!(pof.culled, b.case("pof", 32, 1).unwrap().culled);
    let measures = b.measures();
    assert_eq!(measures.len(), 8, "{measures:?}");
    for what in [
        "frame speed-up, verified over none (1 rank)",
        "frame speed-up, verified over none (8 ranks)",
    ] {
        assert!(
            measures.iter().any(|(w, x)| w == what && *x > 0.0),
            "{measures:?}"
        );
    }
    let spec = |what: &str, target, at_most| TargetSpec {
        what: what.into(),
        target,
        at_most,
    };
    let speed = b.speedup_pof_vs_none.unwrap();
    let t = bench_cull::evaluate_targets(
        &[
            spec("frame speed-up, pof over none (1 rank)", speed, false),
            spec("load balance at 32 ranks (1 replica)", 0.5, true),
        ],
        &measures,
    )
    .unwrap();
    assert_eq!(t[0].measured, speed);
    assert!(t[0].met && !t[1].met, "{t:?}");
    let e = bench_cull::evaluate_targets(&[spec("no such measure", 1.0, true)], &measures)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("no such measure") && e.contains("load balance"),
        "{e}"
    );
    let rows = bench_cull::sweep(
        &j,
        &levels,
        None,
        &bench_cull::sweep_views(2),
        SIZE,
        &NoProgress,
    )
    .unwrap();
    assert_eq!(rows.len(), 2);
    let s = bench_cull::SweepSummary::of(&rows);
    assert!(s.points_below_exact_ideal.is_none());
    let pts = s.points_below_exact_pof.unwrap();
    assert!(pts.worst >= pts.mean && pts.mean >= 0.0, "{pts:?}");
}

#[test]
fn bench_render_measures_each_view_with_and_without_early_termination() {
    let jobs = [("head".to_string(), job())];
    let cases = bench_render(&jobs, SIZE, 1, &NoProgress).unwrap();
    let key: Vec<(&str, bool)> = cases
        .iter()
        .map(|c| (c.view, c.early_termination))
        .collect();
    assert_eq!(
        key,
        [
            ("axis-aligned", true),
            ("axis-aligned", false),
            ("oblique", true),
            ("oblique", false)
        ]
    );
    for pair in cases.chunks(2) {
        // Early termination only ever drops samples.
        assert!(pair[0].samples <= pair[1].samples, "{pair:?}");
        assert!(pair[0].samples > 0 && pair[0].samples_per_second_per_core > 0.0);
    }
}
