//! The viewer under load and hostile requests, over real loopback sockets (no URI
//! normalisation by a test client): clients dragging at once, path traversal, malformed,
//! repeated and oversized parameters, and clients that hang up mid-frame.

mod common;

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use pofvr_web::{router, Viewer};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

fn viewer(n: usize) -> Arc<Viewer> {
    common::head_viewer(n, 16)
}

async fn spawn_server(v: Arc<Viewer>) -> SocketAddr {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, router(v)).await.unwrap() });
    addr
}

/// Sends `raw` (a whole request) on a fresh connection: the status and the body.
async fn raw_request(addr: SocketAddr, raw: &[u8]) -> (u16, Vec<u8>) {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(raw).await.unwrap();
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).await.unwrap();
    let head_end = buf
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .unwrap_or_else(|| panic!("no response head in {:?}", String::from_utf8_lossy(&buf)));
    let head = String::from_utf8_lossy(&buf[..head_end]);
    let status = head
        .split(' ')
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or_else(|| panic!("no status in {head}"));
    (status, buf[head_end + 4..].to_vec())
}

async fn get(addr: SocketAddr, path: &str) -> (u16, Vec<u8>) {
    let req = format!("GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n");
    raw_request(addr, req.as_bytes()).await
}

/// Peak resident memory of this process (the server runs in it), in MiB.
fn peak_rss_mib() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(0.0, |kb| kb / 1024.0)
}

#[tokio::test]
async fn static_files_cannot_be_escaped() {
    let v = viewer(16);
    let addr = spawn_server(Arc::clone(&v)).await;
    for path in [
        "/../../../../etc/passwd",
        "/%2e%2e/%2e%2e/%2e%2e/etc/passwd",
        "/%2e%2e%2f%2e%2e%2fetc%2fpasswd",
        "/..%5c..%5cCargo.toml",
        "/viewer.js/../../Cargo.toml",
        "/static/../Cargo.toml",
        "//etc/passwd",
        "/./viewer.js/..",
        "/viewer.js%00.html",
        "/index.html",
        "/static/viewer.js",
        "/src/lib.rs",
        "/Cargo.toml",
    ] {
        let (status, body) = get(addr, path).await;
        let text = String::from_utf8_lossy(&body);
        assert!(
            status == 404 || status == 400,
            "{path}: {status} {}",
            &text[..text.len().min(200)]
        );
        assert!(
            !text.contains("root:") && !text.contains("[package]") && !text.contains("pub fn"),
            "{path} served a file"
        );
    }
    // An absolute-form request target names no file either.
    let (status, _) = raw_request(
        addr,
        b"GET http://127.0.0.1/../../etc/passwd HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n",
    )
    .await;
    assert!(status == 404 || status == 400, "{status}");
    assert_eq!(v.renders(), 0);
}

#[tokio::test]
async fn malformed_repeated_and_oversized_parameters_get_4xx() {
    let v = viewer(16);
    let addr = spawn_server(Arc::clone(&v)).await;
    let long_value = format!("/api/frame?az={}", "9".repeat(3000));
    let many = format!("/api/frame?{}", "zz=1&".repeat(800));
    let too_long = format!("/api/frame?client={}", "a".repeat(5000));
    for path in [
        "/api/frame?az=1&az=2",
        "/api/frame?w=64&w=64",
        "/api/frame?az=%zz",
        "/api/frame?az=%ff%fe",
        "/api/frame?%ff=1",
        "/api/frame?az=1e400",
        "/api/frame?az=NaN",
        "/api/frame?el=-inf",
        "/api/frame?w=0",
        "/api/frame?w=99999999999999999999",
        "/api/frame?h=-1",
        "/api/frame?zoom=0",
        "/api/frame?weights=1",
        "/api/frame?weights=1,nan",
        "/api/frame?weights=1,-1",
        "/api/frame?threshold=2",
        "/api/frame?cull=everything",
        "/api/frame?proj=fisheye",
        "/api/frame?seq=-1",
        "/api/frame?client=",
        "/api/frame?client=%3Cscript%3E",
        "/api/frame?shade=maybe",
        "/api/frame?bogus=1",
        "/api/frame?=",
        &long_value,
        &many,
        &too_long,
    ] {
        let (status, body) = get(addr, path).await;
        assert!(
            (400..500).contains(&status),
            "{}: {status} {}",
            &path[..path.len().min(80)],
            String::from_utf8_lossy(&body)
        );
    }
    // A request head far larger than any browser sends is refused by the HTTP layer.
    let huge_header = format!(
        "GET /api/frame HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Junk: {}\r\nConnection: close\r\n\r\n",
        "j".repeat(1 << 20)
    );
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    // The server may close before reading it all: the write can fail, the answer cannot be
    // a frame.
    let _ = s.write_all(huge_header.as_bytes()).await;
    let mut buf = Vec::new();
    let _ = s.read_to_end(&mut buf).await;
    let head = String::from_utf8_lossy(&buf[..buf.len().min(64)]).into_owned();
    assert!(
        buf.is_empty() || head.starts_with("HTTP/1.1 4"),
        "huge header: {head}"
    );
    assert_eq!(v.renders(), 0, "no malformed request renders");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_client_that_hangs_up_mid_frame_costs_nothing_after() {
    let v = viewer(48);
    let addr = spawn_server(Arc::clone(&v)).await;
    for i in 0..8u64 {
        let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
        let req = format!(
            "GET /api/frame?w=1024&h=1024&shade=1&az={i}&client=gone{i} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
        );
        s.write_all(req.as_bytes()).await.unwrap();
        // Hang up once the frame has been admitted, mid-render.
        let start = Instant::now();
        while v.status().requests <= i {
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "{:?}",
                v.status()
            );
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        drop(s);
    }
    // Every started render runs out and frees its slot; none is left rendering or queued.
    let start = Instant::now();
    while v.status().rendering > 0 || v.status().requests < 8 {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "{:?}",
            v.status()
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    let s = v.status();
    assert_eq!(s.rendering, 0, "{s:?}");
    assert!(s.renders <= 8, "{s:?}");
    // The server answers at once afterwards.
    let t = Instant::now();
    let (status, _) = get(addr, "/api/frame?w=32&h=32&client=after").await;
    assert_eq!(status, 200);
    assert!(t.elapsed() < Duration::from_secs(10), "{:?}", t.elapsed());
}

/// Load figures of one run.
#[derive(Debug)]
struct Load {
    requests: usize,
    rendered: usize,
    superseded: usize,
    p50_ms: f64,
    p99_ms: f64,
    peak_rss_mib: f64,
}

/// `clients` clients each dragging for `duration`: a new request with the next azimuth
/// every `interval`, over its own connection, without waiting for the previous answer (as
/// the page does while a slider moves).
async fn drag(
    v: &Arc<Viewer>,
    clients: usize,
    duration: Duration,
    interval: Duration,
    side: u32,
) -> Load {
    let addr = spawn_server(Arc::clone(v)).await;
    let rss_before = peak_rss_mib();
    let mut tasks = Vec::new();
    for c in 0..clients {
        tasks.push(tokio::spawn(async move {
            let mut answers = Vec::new();
            let start = Instant::now();
            let mut seq = 0u64;
            while start.elapsed() < duration {
                let path = format!(
                    "/api/frame?w={side}&h={side}&az={}&el=20&client=drag{c}&seq={seq}",
                    (seq * 3 + c as u64) % 360
                );
                answers.push(tokio::spawn(async move {
                    let t = Instant::now();
                    let (status, _) = get(addr, &path).await;
                    (seq, status, t.elapsed().as_secs_f64() * 1e3)
                }));
                seq += 1;
                tokio::time::sleep(interval).await;
            }
            let mut out = Vec::new();
            for a in answers {
                out.push(a.await.unwrap());
            }
            out
        }));
    }
    let mut latencies = Vec::new();
    let (mut requests, mut rendered, mut superseded) = (0, 0, 0);
    for t in tasks {
        let answers = t.await.unwrap();
        // The newest request to arrive is never superseded, so every client sees a frame.
        assert!(
            answers.iter().any(|a| a.1 == 200),
            "a client got no frame: {answers:?}"
        );
        for (_, status, ms) in answers {
            requests += 1;
            assert!(status < 500, "a {status} under load");
            match status {
                200 => {
                    rendered += 1;
                    latencies.push(ms);
                }
                204 => superseded += 1,
                other => panic!("status {other} under load"),
            }
        }
    }
    latencies.sort_by(f64::total_cmp);
    let q = |p: f64| latencies[((latencies.len() - 1) as f64 * p).round() as usize];
    let load = Load {
        requests,
        rendered,
        superseded,
        p50_ms: q(0.5),
        p99_ms: q(0.99),
        peak_rss_mib: peak_rss_mib().max(rss_before),
    };
    eprintln!(
        "load: {clients} clients, {duration:?}, {side}x{side}: {load:?} (peak RSS before {rss_before:.0} MiB)"
    );
    load
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn clients_dragging_at_once_get_no_5xx_and_stale_frames_are_superseded() {
    let v = viewer(32);
    let load = drag(
        &v,
        10,
        Duration::from_secs(2),
        Duration::from_millis(10),
        96,
    )
    .await;
    assert!(load.rendered >= 10, "{load:?}");
    assert!(
        load.p50_ms <= load.p99_ms && load.p99_ms < 10_000.0,
        "{load:?}"
    );
    assert_eq!(load.rendered + load.superseded, load.requests);
    assert!(load.peak_rss_mib < 1024.0, "{load:?}");
    assert_eq!(v.status().rendering, 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
#[ignore = "long: 50 clients dragging for 30 s (run with --ignored --nocapture for the figures)"]
async fn fifty_clients_dragging_for_thirty_seconds() {
    let v = viewer(128);
    let load = drag(
        &v,
        50,
        Duration::from_secs(30),
        Duration::from_millis(16),
        256,
    )
    .await;
    assert!(load.rendered >= 50, "{load:?}");
    assert!(
        load.p50_ms <= load.p99_ms && load.p99_ms < 30_000.0,
        "{load:?}"
    );
    assert!(load.superseded > 0, "{load:?}");
    assert!(load.peak_rss_mib < 2048.0, "{load:?}");
    assert_eq!(v.status().rendering, 0);
}
