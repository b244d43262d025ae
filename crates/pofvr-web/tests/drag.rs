//! Verified frames while a client drags: each frame after a client's first predicts from
//! that client's last verified set (`previous`), never another client's, and the image is
//! the one the proxy's prediction gives (verification makes it predictor-independent).

mod common;

use std::sync::Arc;

use common::{assert_rule, frame};
use pofvr_web::Viewer;

fn viewer(n: usize) -> Arc<Viewer> {
    common::head_viewer(n, 8)
}

// A heavy skin weight makes the outer bricks opaque: the prediction culls, so it matters.
const LOOK: &str = "w=64&h=64&el=10&weights=40,40&threshold=0.9";

#[tokio::test]
async fn a_drag_predicts_from_the_clients_last_verified_frame() {
    let v = viewer(64);
    let (first, _) = frame(&v, &format!("{LOOK}&az=0&cull=verified&client=a")).await;
    assert_eq!(first["predictor"], "proxy", "{first}");
    let (second, dragged) = frame(&v, &format!("{LOOK}&az=5&cull=verified&client=a")).await;
    assert_eq!(second["predictor"], "previous", "{second}");
    let b = &second["bricks"];
    assert!(
        b["culled"].as_u64().unwrap() > 0,
        "nothing culled: {second}"
    );
    assert!(
        b["repaired"].as_u64().unwrap() <= b["visible"].as_u64().unwrap(),
        "{second}"
    );

    // Another client's first frame, at the same view: the proxy, not a's set.
    let (other, proxied) = frame(&v, &format!("{LOOK}&az=5&cull=verified&client=b")).await;
    assert_eq!(other["predictor"], "proxy", "{other}");
    // Both obey the threshold rule against the unculled frame, so they agree below the
    // threshold whichever predictor culled.
    let (none, unculled) = frame(&v, &format!("{LOOK}&az=5&cull=none&client=c")).await;
    assert!(none["predictor"].is_null(), "{none}");
    assert_rule(&unculled, &dragged, 0.9, "previous");
    assert_rule(&unculled, &proxied, 0.9, "proxy");
    let below = (0.9f32 * 255.0).floor() as u8;
    for (i, (p, q)) in dragged
        .chunks_exact(4)
        .zip(proxied.chunks_exact(4))
        .enumerate()
    {
        if unculled[4 * i + 3] < below {
            for k in 0..4 {
                assert!(
                    p[k].abs_diff(q[k]) <= 1,
                    "pixel {i}: previous {p:?} vs proxy {q:?}"
                );
            }
        }
    }

    // a goes on dragging from its own set; b's frame did not replace it.
    let (third, _) = frame(&v, &format!("{LOOK}&az=10&cull=verified&client=a")).await;
    assert_eq!(third["predictor"], "previous", "{third}");
}

#[tokio::test]
async fn new_weights_or_threshold_start_again_from_the_proxy() {
    let v = viewer(32);
    let q = |az: u32, rest: &str| format!("w=32&h=32&el=10&az={az}&cull=verified&client=a{rest}");
    let (s, _) = frame(&v, &q(0, "&weights=40,40")).await;
    assert_eq!(s["predictor"], "proxy");
    let (s, _) = frame(&v, &q(5, "&weights=40,40")).await;
    assert_eq!(s["predictor"], "previous");
    let (s, _) = frame(&v, &q(10, "&weights=40,10")).await;
    assert_eq!(s["predictor"], "proxy", "the weights changed: {s}");
    let (s, _) = frame(&v, &q(15, "&weights=40,10&threshold=0.5")).await;
    assert_eq!(s["predictor"], "proxy", "the threshold changed: {s}");
    let (s, _) = frame(&v, &q(20, "&weights=40,10&threshold=0.5")).await;
    assert_eq!(s["predictor"], "previous", "{s}");
}
