//! POFs of a family stay usable when the user edits the bases' shapes: a verified frame
//! predicts with the stale table, verification repairs what it culls wrongly, and the image
//! obeys the threshold rule against the unculled frame of the *edited* family. An
//! unverified POF cull must refuse such a table, since it bounds nothing any more.

use super::test::assert_conservative;
use crate::error::Error;
use crate::pof::PofError;
use crate::render::{families, Camera, Projection, TransferFunction};
use crate::scene::{Cull, FrameRequest, PofBuild, Predict, Scene};
use crate::volume::phantom::Phantom;

fn family() -> TransferFunction {
    let mut tf = families::for_phantom(Phantom::SheppLogan);
    // The skull shell (bone) hides the inside: POFs then cull a lot.
    tf.set_weights(vec![3.0, 1.0]).unwrap();
    tf
}

/// The family with its bases' control points moved: `scale` multiplies every opacity,
/// and the skin's ramp is shifted by `shift` in value.
fn edited(scale: f32, shift: f32) -> TransferFunction {
    let mut tf = family();
    for (i, b) in tf.bases.iter_mut().enumerate() {
        for p in &mut b.opacity {
            p[1] *= scale;
            if i == 0 {
                p[0] += shift;
            }
        }
    }
    tf
}

/// A scene of the phantom with `tf`, and the POF file of the *original* family in `dir`.
fn scenes(dir: &std::path::Path) -> (Scene, std::path::PathBuf) {
    let original = Scene::builder(Phantom::SheppLogan.generate(64), family())
        .brick_size(8)
        .build()
        .unwrap();
    // Half-brick cores, as the cull tests use: they cull the phantom's inside.
    let build = PofBuild {
        views: [8, 8],
        core_length: Some(4.0),
        sets: true,
        ..PofBuild::default()
    };
    let path = dir.join("original.pof");
    original.build_pofs(&build).unwrap().save(&path).unwrap();
    (original, path)
}

fn cameras(s: &Scene) -> Vec<Camera> {
    [
        (0.0, 0.0, Projection::Orthographic),
        (35.0, 20.0, Projection::Orthographic),
        (-110.0, 40.0, Projection::Perspective),
    ]
    .into_iter()
    .map(|(az, el, p)| Camera::orbit(s.volume(), az, el, 160, 144, p))
    .collect()
}

#[test]
fn stale_pofs_predict_verified_frames_that_obey_the_rule() {
    let dir = tempfile::tempdir().unwrap();
    let (original, path) = scenes(dir.path());
    let mut repaired_when_thinner = 0;
    // Thinner (predictions cull too much), thicker (cull too little), moved.
    for (scale, shift) in [(0.3, 0.0), (2.0, 0.0), (1.0, 25.0)] {
        let what = format!("bases scaled {scale}, skin moved {shift}");
        let family = edited(scale, shift);
        let scene = original.with_family(family).unwrap();
        // Dropped by `with_family`, since they bound the old bases' opacity.
        assert!(scene.pofs().is_none(), "{what}");
        // A plain load refuses the table, naming the bases.
        let e = original
            .with_family(edited(scale, shift))
            .unwrap()
            .load_pof_levels(&path, &[])
            .unwrap_err();
        assert!(
            matches!(&e, Error::Pof(PofError::Mismatch { what, .. }) if what.contains("bases")),
            "{e}"
        );
        let scene = scene.load_pof_predictions(&path, &[]).unwrap();
        let pofs = scene.pofs().unwrap();
        let why = pofs.stale_reason().expect("other bases are stale");
        assert!(
            why.contains("original.pof") && why.contains("bases"),
            "{why}"
        );
        for cam in cameras(&scene) {
            let base = || FrameRequest::new(&cam);
            let reference = scene.render_reference(&base()).unwrap().image;
            // An unverified POF cull bounds nothing with these POFs: refused.
            for cull in [Cull::Pof(pofs), Cull::PofSet(pofs)] {
                let e = scene.render(&base().cull(cull)).unwrap_err();
                assert!(matches!(e, Error::StalePofs { .. }), "{what}: {e}");
                assert!(e.to_string().contains("verify"), "{e}");
            }
            for (name, req) in [
                ("pof --verify", base().cull(Cull::Pof(pofs)).verify(true)),
                (
                    "pof-set --verify",
                    base().cull(Cull::PofSet(pofs)).verify(true),
                ),
                (
                    "verified pof",
                    base().cull(Cull::Verified(Predict::Pof(pofs))),
                ),
                (
                    "verified pof-set",
                    base().cull(Cull::Verified(Predict::PofSet(pofs))),
                ),
            ] {
                for threshold in [0.95, 0.7] {
                    let req = req.clone().threshold(threshold).ranks(3);
                    let frame = scene.render(&req).unwrap();
                    let what = format!("{what}, {name} at {threshold}");
                    assert_conservative(&reference, &frame.image, threshold, &what);
                    let b = frame.stats.bricks;
                    assert!(frame.stats.verified, "{what}");
                    assert!(b.repaired <= b.visible, "{what}: {b:?}");
                    if scale < 1.0 {
                        repaired_when_thinner += b.repaired;
                    }
                }
            }
        }
    }
    // Thinner bases than the table was built for: the stale POFs claim more opacity than
    // there is, the prediction culls visible bricks, and verification had to repair them.
    eprintln!("repaired with bases 0.3× as opaque as the table's: {repaired_when_thinner}");
    assert!(repaired_when_thinner > 0);
}

#[test]
fn pofs_of_the_same_bases_are_not_stale() {
    let dir = tempfile::tempdir().unwrap();
    let (original, path) = scenes(dir.path());
    let scene = original.load_pof_predictions(&path, &[]).unwrap();
    let pofs = scene.pofs().unwrap();
    assert_eq!(pofs.stale_reason(), None);
    // Their bound holds: the plain cull is allowed and obeys the rule.
    let mut culled = 0;
    for cam in &cameras(&scene) {
        let reference = scene
            .render_reference(&FrameRequest::new(cam))
            .unwrap()
            .image;
        for cull in [Cull::Pof(pofs), Cull::Verified(Predict::PofSet(pofs))] {
            let frame = scene.render(&FrameRequest::new(cam).cull(cull)).unwrap();
            assert_conservative(&reference, &frame.image, 0.95, "same bases");
            culled += frame.stats.bricks.culled;
        }
    }
    assert!(
        culled > 0,
        "POFs of the family's own bases cull the phantom's inside"
    );
}

#[test]
fn another_basis_count_is_refused_even_for_predictions() {
    let dir = tempfile::tempdir().unwrap();
    let (original, path) = scenes(dir.path());
    let mut three = family();
    three.bases.push(three.bases[1].clone());
    three.bases[2].name = "bone again".into();
    three.weights.push(1.0);
    let e = original
        .with_family(three)
        .unwrap()
        .load_pof_predictions(&path, &[])
        .unwrap_err();
    assert!(
        matches!(&e, Error::Pof(PofError::Mismatch { what, .. }) if what.contains("basis count")),
        "{e}"
    );
}
