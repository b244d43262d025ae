//! What the viewer's integration tests share: a phantom viewer, one frame through the
//! router, and the threshold rule on its PNG.

// Each test crate that includes this module uses part of it.
#![allow(dead_code)]

use std::sync::Arc;

use pofvr::render::families;
use pofvr::volume::phantom::Phantom;
use pofvr::Scene;
use pofvr_web::ViewerOptions;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use pofvr_web::{router, Viewer, STATS_HEADER};
use tower::ServiceExt;

/// A viewer of the `n`³ Shepp–Logan head with its family, bricks of `brick`, default
/// options.
pub(crate) fn head_viewer(n: usize, brick: usize) -> Arc<Viewer> {
    let vol = Phantom::SheppLogan.generate(n);
    let scene = Scene::builder(vol, families::for_phantom(Phantom::SheppLogan))
        .brick_size(brick)
        .build()
        .unwrap();
    Arc::new(Viewer::new(
        Arc::new(scene),
        "phantom:head",
        &ViewerOptions::default(),
    ))
}

/// One frame: its stats and RGBA8 pixels.
pub(crate) async fn frame(v: &Arc<Viewer>, query: &str) -> (serde_json::Value, Vec<u8>) {
    let req = Request::get(format!("/api/frame?{query}"))
        .body(Body::empty())
        .unwrap();
    let resp = router(Arc::clone(v)).oneshot(req).await.unwrap();
    let status = resp.status();
    let stats = resp
        .headers()
        .get(STATS_HEADER)
        .map(|x| serde_json::from_str(x.to_str().unwrap()).unwrap());
    let body = axum::body::to_bytes(resp.into_body(), 1 << 26)
        .await
        .unwrap();
    assert_eq!(
        status,
        StatusCode::OK,
        "{query}: {}",
        String::from_utf8_lossy(&body)
    );
    let dec = png::Decoder::new(std::io::Cursor::new(body.to_vec()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    (stats.expect("stats header"), buf)
}

/// The threshold rule in 8 bits: where the unculled frame's alpha is below the threshold
/// the culled frame is the same (one level for rounding), elsewhere within 1 − threshold.
pub(crate) fn assert_rule(unculled: &[u8], culled: &[u8], threshold: f32, what: &str) {
    assert_eq!(unculled.len(), culled.len(), "{what}: sizes");
    let below = (threshold * 255.0).floor() as u8;
    let slack = ((1.0 - threshold) * 255.0).ceil() as i32 + 1;
    let mut checked_below = 0;
    for (i, (u, c)) in unculled
        .chunks_exact(4)
        .zip(culled.chunks_exact(4))
        .enumerate()
    {
        let allowed = if u[3] < below {
            checked_below += 1;
            1
        } else {
            slack
        };
        for k in 0..4 {
            let d = (i32::from(u[k]) - i32::from(c[k])).abs();
            assert!(
                d <= allowed,
                "{what}: pixel {i} channel {k}: {} vs {} (alpha {})",
                u[k],
                c[k],
                u[3]
            );
        }
    }
    assert!(checked_below > 0, "{what}: no pixel below the threshold");
}
