//! HTTP behaviour of the viewer: validation, frames, and bursts from many clients.

use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::body::Body;
use axum::http::{Request, StatusCode};
use pofvr::render::families;
use pofvr::volume::phantom::Phantom;
use pofvr::Scene;
use pofvr_web::{router, Viewer, ViewerOptions, STATS_HEADER, SUPERSEDED_HEADER};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tower::ServiceExt;

fn scene(n: usize) -> Scene {
    let vol = Phantom::SheppLogan.generate(n);
    Scene::builder(vol, families::for_phantom(Phantom::SheppLogan))
        .brick_size(16)
        .build()
        .unwrap()
}

fn viewer(n: usize, render_slots: usize) -> Arc<Viewer> {
    let opts = ViewerOptions {
        render_slots,
        ..ViewerOptions::default()
    };
    Arc::new(Viewer::new(Arc::new(scene(n)), "phantom:head", &opts))
}

/// A viewer whose POF modes read the library's range bound, which needs no POF file.
fn viewer_with_bounds(n: usize) -> Arc<Viewer> {
    Arc::new(Viewer::new(
        Arc::new(scene(n).with_range_bound(4.0)),
        "phantom:head",
        &ViewerOptions::default(),
    ))
}

struct Answer {
    status: StatusCode,
    content_type: String,
    stats: Option<serde_json::Value>,
    body: Vec<u8>,
}

impl Answer {
    fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
}

async fn get(v: &Arc<Viewer>, uri: &str) -> Answer {
    call(v, Request::get(uri).body(Body::empty()).unwrap()).await
}

async fn call(v: &Arc<Viewer>, req: Request<Body>) -> Answer {
    let resp = router(Arc::clone(v)).oneshot(req).await.unwrap();
    let status = resp.status();
    let h = resp.headers();
    let content_type = h
        .get("content-type")
        .map(|x| x.to_str().unwrap().to_string())
        .unwrap_or_default();
    let stats = h
        .get(STATS_HEADER)
        .map(|x| serde_json::from_str(x.to_str().unwrap()).unwrap());
    let body = axum::body::to_bytes(resp.into_body(), 1 << 26)
        .await
        .unwrap()
        .to_vec();
    Answer {
        status,
        content_type,
        stats,
        body,
    }
}

fn png_size(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

#[tokio::test]
async fn bad_parameters_get_400_with_a_message_and_render_nothing() {
    let v = viewer(32, 2);
    for (query, needle) in [
        ("el=91", "el: 91 is outside [-90, 90]"),
        ("az=NaN", "az: \"NaN\" is not a finite number"),
        ("zoom=1e400", "zoom:"),
        ("w=4096&h=16", "w: 4096 is outside [1, 2048]"),
        ("h=0", "h: 0 is outside"),
        (
            "weights=1",
            "weights: got 1 values in \"1\", expected one per basis (2)",
        ),
        ("weights=1,2,3", "expected one per basis (2)"),
        ("weights=1,-0.5", "weights[1]: -0.5 is outside"),
        ("threshold=0", "threshold: 0 is outside"),
        ("cull=everything", "cull: unknown cull mode"),
        ("cull=pof", "cull: pof needs precomputed POFs"),
        ("cull=pof-set", "cull: pof-set needs precomputed POFs"),
        ("proj=fisheye", "proj: \"fisheye\""),
        ("shade=2", "shade: \"2\" is not 0 or 1"),
        ("client=a/b", "client: expected"),
        ("file=/etc/passwd", "unknown parameter \"file\""),
        ("az=1&az=2", "az: given more than once"),
        ("az=%FF%FE", "is not a number"),
    ] {
        let a = get(&v, &format!("/api/frame?{query}")).await;
        assert_eq!(a.status, StatusCode::BAD_REQUEST, "{query}: {}", a.text());
        assert!(
            a.content_type.starts_with("text/plain"),
            "{query}: {}",
            a.content_type
        );
        assert!(
            a.text().contains(needle),
            "{query}: {:?} lacks {needle:?}",
            a.text()
        );
    }
    assert_eq!(v.renders(), 0);
}

#[tokio::test]
async fn oversized_requests_are_refused_before_routing() {
    let v = viewer(16, 1);
    let long = format!("/api/frame?client={}", "a".repeat(5000));
    assert_eq!(get(&v, &long).await.status, StatusCode::URI_TOO_LONG);
    let big = Request::post("/api/frame")
        .header("content-length", "100000")
        .body(Body::from(vec![0u8; 100_000]))
        .unwrap();
    let a = call(&v, big).await;
    assert_eq!(a.status, StatusCode::PAYLOAD_TOO_LARGE, "{}", a.text());
    let small_post = Request::post("/api/frame")
        .header("content-length", "2")
        .body(Body::from("{}"))
        .unwrap();
    assert_eq!(
        call(&v, small_post).await.status,
        StatusCode::METHOD_NOT_ALLOWED
    );
    assert_eq!(
        get(&v, "/../../etc/passwd").await.status,
        StatusCode::NOT_FOUND
    );
    assert_eq!(v.renders(), 0);
}

#[tokio::test]
async fn only_loopback_host_names_are_answered() {
    let v = viewer(16, 1);
    for host in [
        "localhost:8080",
        "127.0.0.1",
        "127.0.0.2:9",
        "[::1]:8080",
        "LOCALHOST",
    ] {
        let req = Request::get("/api/info")
            .header("host", host)
            .body(Body::empty())
            .unwrap();
        assert_eq!(call(&v, req).await.status, StatusCode::OK, "{host}");
    }
    for host in [
        "evil.example:8080",
        "localhost.evil.example",
        "10.0.0.1",
        "[::2]",
    ] {
        let req = Request::get("/api/info")
            .header("host", host)
            .body(Body::empty())
            .unwrap();
        let a = call(&v, req).await;
        assert_eq!(a.status, StatusCode::FORBIDDEN, "{host}");
        assert!(a.text().contains("localhost"), "{host}: {}", a.text());
    }
    let opts = ViewerOptions {
        loopback_hosts_only: false,
        ..ViewerOptions::default()
    };
    let open = Arc::new(Viewer::new(Arc::new(scene(16)), "phantom:head", &opts));
    let req = Request::get("/api/info")
        .header("host", "viewer.lan")
        .body(Body::empty())
        .unwrap();
    assert_eq!(call(&open, req).await.status, StatusCode::OK);
}

#[tokio::test]
async fn a_valid_frame_is_a_png_of_the_asked_size_with_its_figures() {
    let v = viewer(32, 2);
    let a = get(
        &v,
        "/api/frame?az=10&el=-20&zoom=1.5&w=40&h=24&proj=persp&weights=1,0.5&shade=1&seq=9",
    )
    .await;
    assert_eq!(a.status, StatusCode::OK, "{}", a.text());
    assert_eq!(a.content_type, "image/png");
    let (w, h, rgba) = png_size(&a.body);
    assert_eq!((w, h), (40, 24));
    assert!(
        rgba.chunks_exact(4).any(|p| p[3] > 0),
        "the phantom is visible"
    );
    let s = a.stats.expect("stats header");
    assert_eq!(
        (s["width"].as_u64(), s["height"].as_u64(), s["seq"].as_u64()),
        (Some(40), Some(24), Some(9))
    );
    let b = &s["bricks"];
    assert_eq!(b["total"].as_u64(), Some(8));
    assert_eq!(
        b["non_empty"].as_u64().unwrap() + b["empty"].as_u64().unwrap(),
        8
    );
    assert!(s["times"]["raycast_ms"].as_f64().unwrap() > 0.0);
    assert_eq!(v.renders(), 1);
}

#[tokio::test]
async fn weights_change_the_frame_and_exact_culling_is_counted_and_tinted() {
    let v = viewer(64, 2);
    let base = "/api/frame?w=64&h=64&az=0&el=0";
    let a = get(&v, base).await;
    let b = get(&v, &format!("{base}&weights=1,0")).await;
    assert_ne!(
        png_size(&a.body).2,
        png_size(&b.body).2,
        "removing bone changes the image"
    );

    // A heavy skin weight makes the outer bricks opaque, so the exact oracle culls the
    // bricks behind them.
    let q = format!("{base}&weights=40,40&cull=exact&threshold=0.9");
    let plain = get(&v, &q).await;
    assert_eq!(plain.status, StatusCode::OK, "{}", plain.text());
    let s = plain.stats.unwrap();
    let culled = s["bricks"]["culled"].as_u64().unwrap();
    assert!(culled > 0, "exact culling culled nothing: {s}");
    assert_eq!(
        s["bricks"]["visible"].as_u64().unwrap() + culled,
        s["bricks"]["non_empty"].as_u64().unwrap(),
        "{s}"
    );
    let tinted = get(&v, &format!("{q}&overlay=1")).await;
    let (p, t) = (png_size(&plain.body).2, png_size(&tinted.body).2);
    let changed = p
        .chunks_exact(4)
        .zip(t.chunks_exact(4))
        .filter(|(x, y)| x != y)
        .count();
    assert!(
        changed > 0,
        "the overlay tinted no pixel although {culled} bricks were culled"
    );
}

#[tokio::test]
async fn ranks_split_the_frame_without_changing_it() {
    let one = viewer(32, 2);
    let opts = ViewerOptions {
        ranks: 3,
        ..ViewerOptions::default()
    };
    let three = Arc::new(Viewer::new(Arc::new(scene(32)), "phantom:head", &opts));
    let q = "/api/frame?w=48&h=40&az=20&el=10&cull=exact";
    let (a, b) = (get(&one, q).await, get(&three, q).await);
    assert_eq!(
        (a.status, b.status),
        (StatusCode::OK, StatusCode::OK),
        "{}",
        b.text()
    );
    assert_eq!(png_size(&a.body).2, png_size(&b.body).2);
    assert_eq!(a.stats.unwrap()["ranks"], 1);
    assert_eq!(b.stats.unwrap()["ranks"], 3);
}

#[tokio::test]
async fn pof_modes_render_when_the_viewer_has_bounds() {
    let v = viewer_with_bounds(32);
    let info: serde_json::Value = serde_json::from_slice(&get(&v, "/api/info").await.body).unwrap();
    assert_eq!(
        info["cull_modes_available"],
        serde_json::json!(["none", "pof", "pof-set", "exact", "verified"])
    );
    for mode in ["pof", "pof-set"] {
        let a = get(&v, &format!("/api/frame?w=32&h=32&cull={mode}")).await;
        assert_eq!(a.status, StatusCode::OK, "{mode}: {}", a.text());
        assert_eq!(a.stats.unwrap()["cull"], mode);
    }
}

#[tokio::test]
async fn info_names_the_bases_and_the_page_is_served() {
    let v = viewer(16, 1);
    let info: serde_json::Value = serde_json::from_slice(&get(&v, "/api/info").await.body).unwrap();
    assert_eq!(info["bases"][0]["name"], "skin");
    assert_eq!(info["bases"][1]["name"], "bone");
    assert_eq!(
        info["cull_modes_available"],
        serde_json::json!(["none", "exact", "verified"])
    );
    let page = get(&v, "/").await;
    assert!(page.content_type.starts_with("text/html") && page.text().contains("/viewer.js"));
    assert!(get(&v, "/viewer.js").await.text().contains("pofvr:frame"));
}

// ---- bursts over a real socket ----------------------------------------------------------

async fn spawn_server(v: Arc<Viewer>) -> std::net::SocketAddr {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, router(v)).await.unwrap() });
    addr
}

/// One GET over its own connection: status code and the stats header, if any; a `204`
/// must say that it was superseded.
async fn http_get(addr: std::net::SocketAddr, path: &str) -> (u16, Option<serde_json::Value>) {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    let req = format!("GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n");
    s.write_all(req.as_bytes()).await.unwrap();
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).await.unwrap();
    let head_end = buf
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a complete response head");
    let head = String::from_utf8_lossy(&buf[..head_end]).into_owned();
    let status: u16 = head
        .split(' ')
        .nth(1)
        .and_then(|c| c.parse().ok())
        .expect("a status line");
    if status == 204 {
        assert!(head.contains(&format!("{SUPERSEDED_HEADER}: 1")), "{head}");
    }
    let stats = head.lines().find_map(|l| {
        l.strip_prefix(&format!("{STATS_HEADER}: "))
            .map(|j| serde_json::from_str(j).unwrap())
    });
    (status, stats)
}

async fn wait_for(what: &str, mut cond: impl FnMut() -> bool) {
    let start = Instant::now();
    while !cond() {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "timed out waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

type Burst = Vec<(
    usize,
    u64,
    tokio::task::JoinHandle<(u16, Option<serde_json::Value>)>,
)>;

/// 50 requests from 10 clients, 5 each, all in flight at once.
fn burst(addr: std::net::SocketAddr) -> Burst {
    let mut tasks = Vec::new();
    for round in 0..5u64 {
        for client in 0..10usize {
            let path = format!(
                "/api/frame?w=96&h=96&az={}&client=burst{client}&seq={round}",
                7 * round + client as u64
            );
            tasks.push((
                client,
                round,
                tokio::spawn(async move { http_get(addr, &path).await }),
            ));
        }
    }
    tasks
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_burst_renders_only_the_latest_request_of_each_client() {
    let v = viewer(32, 2);
    let addr = spawn_server(Arc::clone(&v)).await;
    // Hold rendering until all 50 requests have arrived, so that superseding is certain
    // rather than a matter of timing.
    let hold = v.hold_renders().await;
    let tasks = burst(addr);
    wait_for("all 50 requests to arrive", || v.status().requests == 50).await;

    // The server answers other requests while 50 frames wait.
    let t = Instant::now();
    let (code, _) = http_get(addr, "/api/status").await;
    assert_eq!(code, 200);
    assert!(
        t.elapsed() < Duration::from_secs(2),
        "status took {:?}",
        t.elapsed()
    );
    assert_eq!(v.renders(), 0);
    drop(hold);

    let mut per_client = vec![Vec::new(); 10];
    for (client, _, task) in tasks {
        let (code, stats) = tokio::time::timeout(Duration::from_secs(60), task)
            .await
            .expect("burst finished")
            .unwrap();
        per_client[client].push((code, stats));
    }
    for (client, answers) in per_client.iter().enumerate() {
        let ok: Vec<_> = answers.iter().filter(|(c, _)| *c == 200).collect();
        assert_eq!(ok.len(), 1, "client {client}: {answers:?}");
        assert_eq!(
            answers.iter().filter(|(c, _)| *c == 204).count(),
            4,
            "client {client}"
        );
        let generation = ok[0].1.as_ref().unwrap()["generation"].as_u64();
        assert_eq!(
            generation,
            Some(5),
            "client {client}: the rendered frame was not its latest request"
        );
    }
    assert_eq!(v.renders(), 10);
    assert_eq!(v.status().superseded, 40);
    assert_eq!(v.status().clients, 10);
    assert_eq!(v.status().rendering, 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_unheld_burst_completes_and_never_renders_a_superseded_request() {
    let v = viewer(32, 2);
    let addr = spawn_server(Arc::clone(&v)).await;
    let tasks = burst(addr);
    let mut ok = 0;
    let mut newest = [0u64; 10];
    for (client, _, task) in tasks {
        let (code, stats) = tokio::time::timeout(Duration::from_secs(60), task)
            .await
            .expect("burst finished")
            .unwrap();
        assert!(code == 200 || code == 204, "client {client}: HTTP {code}");
        if code == 200 {
            ok += 1;
            let g = stats.unwrap()["generation"].as_u64().unwrap();
            newest[client] = newest[client].max(g);
        }
    }
    assert_eq!(
        v.renders(),
        ok,
        "every render answered 200 and every 200 was rendered"
    );
    // Each client's last request is never superseded, so each client got ≥ 1 frame and its
    // newest rendered frame is generation 5.
    for (client, g) in newest.iter().enumerate() {
        assert_eq!(*g, 5, "client {client}");
    }
    let (code, _) = http_get(addr, "/api/info").await;
    assert_eq!(code, 200);
}
