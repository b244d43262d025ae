//! The transfer-function panel's routes: histogram, family swap, POF state and rebuild,
//! and the camera of a frame.

use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::body::Body;
use axum::http::{Request, StatusCode};
use pofvr::render::{families, Camera, Projection, TransferFunction};
use pofvr::volume::phantom::Phantom;
use pofvr::Scene;
use pofvr_web::{router, Viewer, ViewerOptions, STATS_HEADER};
use serde_json::Value;
use tower::ServiceExt;

fn scene(n: usize) -> Scene {
    scene_with(n, family())
}

fn scene_with(n: usize, tf: TransferFunction) -> Scene {
    Scene::builder(Phantom::SheppLogan.generate(n), tf)
        .brick_size(16)
        .build()
        .unwrap()
}

fn family() -> TransferFunction {
    families::for_phantom(Phantom::SheppLogan)
}

fn viewer_of(scene: Scene) -> Arc<Viewer> {
    Arc::new(Viewer::new(
        Arc::new(scene),
        "phantom:head",
        &ViewerOptions::default(),
    ))
}

/// The skin basis made more opaque: other bases, so POFs for the built-in ones go stale.
fn reshaped() -> TransferFunction {
    let mut tf = family();
    tf.bases[0].opacity[1][1] = 0.9;
    tf.bases[0].opacity[2][1] = 0.9;
    tf
}

struct Answer {
    status: StatusCode,
    stats: Option<Value>,
    body: Vec<u8>,
}

impl Answer {
    fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
    fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| panic!("{e}: {}", self.text()))
    }
}

async fn call(v: &Arc<Viewer>, req: Request<Body>) -> Answer {
    let resp = router(Arc::clone(v)).oneshot(req).await.unwrap();
    let status = resp.status();
    let stats = resp
        .headers()
        .get(STATS_HEADER)
        .map(|x| serde_json::from_str(x.to_str().unwrap()).unwrap());
    let body = axum::body::to_bytes(resp.into_body(), 1 << 26)
        .await
        .unwrap()
        .to_vec();
    Answer {
        status,
        stats,
        body,
    }
}

async fn get(v: &Arc<Viewer>, uri: &str) -> Answer {
    call(v, Request::get(uri).body(Body::empty()).unwrap()).await
}

async fn post(v: &Arc<Viewer>, uri: &str, body: impl Into<String>) -> Answer {
    let body: String = body.into();
    let req = Request::post(uri)
        .header("content-type", "application/json")
        .header("content-length", body.len().to_string())
        .body(Body::from(body))
        .unwrap();
    call(v, req).await
}

async fn post_tf(v: &Arc<Viewer>, tf: &TransferFunction) -> Answer {
    post(v, "/api/tf", serde_json::to_string(tf).unwrap()).await
}

async fn frame(v: &Arc<Viewer>, query: &str) -> Answer {
    let a = get(v, &format!("/api/frame?w=40&h=32&{query}")).await;
    assert_eq!(a.status, StatusCode::OK, "{query}: {}", a.text());
    a
}

#[tokio::test]
async fn the_histogram_counts_every_voxel_over_the_value_range() {
    let v = viewer_of(scene(32));
    let h = get(&v, "/api/histogram").await.json();
    let info = get(&v, "/api/info").await.json();
    assert_eq!(h["value_range"], info["volume"]["value_range"]);
    assert_eq!(h["lo"], h["value_range"][0]);
    assert_eq!(h["hi"], h["value_range"][1]);
    let counts: Vec<u64> = serde_json::from_value(h["counts"].clone()).unwrap();
    assert_eq!(counts.len(), pofvr_web::histogram::HISTOGRAM_BINS);
    assert_eq!(counts.iter().sum::<u64>(), 32 * 32 * 32);
    assert_eq!(h["total"], 32 * 32 * 32);
    // The phantom's air fills the lowest bin and its shell the highest.
    assert!(counts[0] > 0 && counts[counts.len() - 1] > 0, "{counts:?}");
    // Counted once: a second answer is the same.
    assert_eq!(get(&v, "/api/histogram").await.json(), h);
}

#[tokio::test]
async fn a_posted_family_renders_later_frames_as_a_scene_built_with_it() {
    let v = viewer_of(scene(64));
    let before = frame(&v, "cull=exact").await;
    assert_eq!(before.stats.as_ref().unwrap()["family_version"], 0);
    let served: TransferFunction = serde_json::from_slice(&get(&v, "/api/tf").await.body).unwrap();
    assert_eq!(served, family());

    let a = post_tf(&v, &reshaped()).await;
    assert_eq!(a.status, StatusCode::OK, "{}", a.text());
    let answer = a.json();
    assert_eq!(answer["version"], 1);
    assert_eq!(answer["pofs"], "none");
    assert_eq!(answer["bases"], serde_json::json!(["skin", "bone"]));
    let served: TransferFunction = serde_json::from_slice(&get(&v, "/api/tf").await.body).unwrap();
    assert_eq!(served, reshaped());

    for cull in ["none", "exact"] {
        let after = frame(&v, &format!("cull={cull}")).await;
        let stats = after.stats.as_ref().unwrap();
        assert_eq!(stats["family_version"], 1);
        let fresh = viewer_of(scene_with(64, reshaped()));
        let expected = frame(&fresh, &format!("cull={cull}")).await;
        assert_eq!(after.body, expected.body, "cull {cull}: as a fresh scene");
        if cull == "exact" {
            assert_ne!(after.body, before.body, "the new family changes the frame");
            assert_ne!(
                stats["bricks"]["culled"],
                before.stats.as_ref().unwrap()["bricks"]["culled"],
                "and the culled count"
            );
        }
    }
}

#[tokio::test]
async fn a_bad_family_gets_400_naming_the_field_and_the_old_one_stays() {
    let v = viewer_of(scene(24));
    let before = frame(&v, "cull=exact").await;
    let good = serde_json::to_value(family()).unwrap();
    let with = |path: &[&str], value: Value| {
        let mut j = good.clone();
        let mut at = &mut j;
        for p in path {
            at = match p.parse::<usize>() {
                Ok(i) => &mut at[i],
                Err(_) => &mut at[*p],
            };
        }
        *at = value;
        j.to_string()
    };
    for (body, needle) in [
        (
            with(&["bases", "0", "opacity", "1", "1"], 2.0.into()),
            "bases[0].opacity[1]: alpha 2 is outside [0, 1]",
        ),
        (
            with(&["bases", "1", "opacity", "1", "0"], 10.0.into()),
            "bases[1].opacity[1]: values not sorted",
        ),
        (
            with(&["color", "2", "1"], 1.5.into()),
            "color[2]: colour components must be in [0, 1]",
        ),
        (
            with(&["weights"], serde_json::json!([1.0])),
            "weights: got 1 weights",
        ),
        (with(&["bases"], serde_json::json!([])), "bases: no bases"),
        (r#"{"bases": []}"#.to_string(), "missing field `color`"),
        ("not json".to_string(), "the posted family: expected"),
    ] {
        let a = post(&v, "/api/tf", body.clone()).await;
        assert_eq!(a.status, StatusCode::BAD_REQUEST, "{body}: {}", a.text());
        assert!(a.text().starts_with("the posted family: "), "{}", a.text());
        assert!(a.text().contains(needle), "{:?} lacks {needle:?}", a.text());
    }
    // Not declared as JSON: refused before it is read, as another site's form would be.
    let plain = Request::post("/api/tf")
        .header("content-type", "text/plain")
        .body(Body::from(good.to_string()))
        .unwrap();
    assert_eq!(
        call(&v, plain).await.status,
        StatusCode::UNSUPPORTED_MEDIA_TYPE
    );
    let served: TransferFunction = serde_json::from_slice(&get(&v, "/api/tf").await.body).unwrap();
    assert_eq!(served, family(), "the old family stays");
    let after = frame(&v, "cull=exact").await;
    assert_eq!(after.body, before.body, "and renders as before");
    assert_eq!(after.stats.unwrap()["family_version"], 0);
}

#[tokio::test]
async fn the_family_route_takes_a_mebibyte_and_the_others_keep_their_limit() {
    let v = viewer_of(scene(16));
    // A family of many points, beyond the 16 KiB every other route is held to.
    let mut tf = family();
    tf.bases[0].opacity = (0..4000).map(|i| [20.0 + i as f32 * 0.03, 0.1]).collect();
    let body = serde_json::to_string(&tf).unwrap();
    assert!(body.len() > 32 * 1024);
    let a = post(&v, "/api/tf", body).await;
    assert_eq!(a.status, StatusCode::OK, "{}", a.text());
    let huge = format!("{{\"pad\": \"{}\"}}", "x".repeat(1 << 20));
    assert_eq!(
        post(&v, "/api/tf", huge).await.status,
        StatusCode::PAYLOAD_TOO_LARGE
    );
    let a = post(&v, "/api/pofs/rebuild", "x".repeat(20_000)).await;
    assert_eq!(a.status, StatusCode::PAYLOAD_TOO_LARGE);
}

#[tokio::test]
async fn stale_pofs_render_the_pof_modes_as_verified_until_the_bases_come_back() {
    let v = viewer_of(scene(32).with_range_bound(4.0));
    assert_eq!(get(&v, "/api/pofs").await.json()["state"], "match");
    let pof = frame(&v, "cull=pof").await;
    assert_eq!(pof.stats.as_ref().unwrap()["cull"], "pof");
    assert_eq!(pof.stats.as_ref().unwrap()["pofs"], "match");

    let a = post_tf(&v, &reshaped()).await.json();
    assert_eq!(a["pofs"], "stale");
    assert_eq!(a["pof_renders_as"], "verified");
    let info = get(&v, "/api/info").await.json();
    assert_eq!(info["pofs"], "stale");
    assert!(info["cull_modes_available"]
        .as_array()
        .unwrap()
        .contains(&"pof".into()));
    let verified = frame(&v, "cull=verified").await;
    for mode in ["pof", "pof-set"] {
        let f = frame(&v, &format!("cull={mode}")).await;
        let s = f.stats.as_ref().unwrap();
        assert_eq!(s["cull"], "verified", "{mode}");
        assert_eq!(s["cull_requested"], mode);
        assert_eq!(s["pofs"], "stale");
        assert_eq!(f.body, verified.body, "{mode} renders as verified");
    }

    // New colours and weights on the old bases: the POFs bound them again.
    let mut recoloured = family();
    recoloured.color = vec![[0.0, 0.2, 0.2, 0.9], [255.0, 1.0, 0.9, 0.1]];
    recoloured.weights = vec![1.0, 0.5];
    let a = post_tf(&v, &recoloured).await.json();
    assert_eq!(a["pofs"], "match");
    assert_eq!(a["version"], 2);
    let f = frame(&v, "cull=pof").await;
    assert_eq!(f.stats.as_ref().unwrap()["cull"], "pof");
    assert_eq!(get(&v, "/api/pofs").await.json()["pof_renders_as"], "pof");
    // The family's weights are the default of a frame that gives none.
    let info = get(&v, "/api/info").await.json();
    assert_eq!(info["bases"][1]["weight"], 0.5);
    let unweighted = frame(&v, "cull=none").await;
    let weighted = frame(&v, "cull=none&weights=1,0.5").await;
    assert_eq!(unweighted.body, weighted.body);
}

#[tokio::test]
async fn rebuild_builds_pofs_for_the_current_family_in_the_background() {
    let v = viewer_of(scene(32));
    let a = get(&v, "/api/pofs").await.json();
    assert_eq!(a["state"], "none");
    assert_eq!(a["pof_renders_as"], Value::Null);
    assert_eq!(post_tf(&v, &reshaped()).await.status, StatusCode::OK);
    let plain = Request::post("/api/pofs/rebuild")
        .body(Body::empty())
        .unwrap();
    assert_eq!(
        call(&v, plain).await.status,
        StatusCode::UNSUPPORTED_MEDIA_TYPE
    );
    let a = post(&v, "/api/pofs/rebuild", "").await;
    assert_eq!(a.status, StatusCode::ACCEPTED, "{}", a.text());
    // Frames keep coming while it builds.
    frame(&v, "cull=exact").await;
    let start = Instant::now();
    let report = loop {
        let r = get(&v, "/api/pofs").await.json();
        if r["build"]["finished"] == 1 {
            break r;
        }
        assert!(start.elapsed() < Duration::from_secs(600), "{r}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert_eq!(report["build"]["running"], false);
    assert_eq!(report["build"]["last"]["error"], Value::Null, "{report}");
    let total = report["build"]["total"].as_u64().unwrap();
    // One step per brick that some basis can see, of the 8.
    assert!((1..=8).contains(&total), "{report}");
    assert_eq!(report["build"]["done"], total);
    assert_eq!(report["state"], "match");
    assert_eq!(report["version"], 2);
    let f = frame(&v, "cull=pof").await;
    let s = f.stats.as_ref().unwrap();
    assert_eq!(s["cull"], "pof");
    assert_eq!(s["family_version"], 2);
    // The built POFs are for the reshaped bases: the built-in ones find them stale.
    assert_eq!(post_tf(&v, &family()).await.json()["pofs"], "stale");
    assert_eq!(post_tf(&v, &reshaped()).await.json()["pofs"], "match");
}

#[tokio::test]
async fn the_camera_route_answers_the_camera_of_the_same_frame() {
    let v = viewer_of(scene(16));
    let a = get(&v, "/api/camera?az=10&el=-5&w=64&h=48&zoom=2&proj=ortho").await;
    assert_eq!(a.status, StatusCode::OK, "{}", a.text());
    let cam: Camera = serde_json::from_slice(&a.body).unwrap();
    let mut expected = Camera::orbit(
        v.scene().volume(),
        10.0,
        -5.0,
        64,
        48,
        Projection::Orthographic,
    );
    expected.parallel_scale /= 2.0;
    assert_eq!(cam.to_json(), expected.to_json());
    let bad = get(&v, "/api/camera?el=100").await;
    assert_eq!(bad.status, StatusCode::BAD_REQUEST);
    assert!(bad.text().contains("el: 100"), "{}", bad.text());
}

#[tokio::test]
async fn a_swap_waits_for_no_frame_and_a_frame_keeps_the_family_it_started_with() {
    let v = viewer_of(scene(32));
    let hold = v.hold_renders().await;
    let waiting = {
        let v = Arc::clone(&v);
        tokio::spawn(async move { frame(&v, "cull=none").await })
    };
    // The frame has taken its scene and its ticket, and waits for a render slot.
    let start = Instant::now();
    while v.status().requests == 0 {
        assert!(start.elapsed() < Duration::from_secs(30));
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let posted = tokio::time::timeout(Duration::from_secs(60), post_tf(&v, &reshaped()))
        .await
        .expect("a swap does not wait for the frames in flight");
    assert_eq!(posted.status, StatusCode::OK, "{}", posted.text());
    drop(hold);
    let old = waiting.await.unwrap();
    assert_eq!(old.stats.as_ref().unwrap()["family_version"], 0);
    let fresh_old = frame(&viewer_of(scene(32)), "cull=none").await;
    assert_eq!(
        old.body, fresh_old.body,
        "rendered with the family it started with"
    );
    let new = frame(&v, "cull=none").await;
    assert_eq!(new.stats.as_ref().unwrap()["family_version"], 1);
    assert_ne!(new.body, old.body);
}
