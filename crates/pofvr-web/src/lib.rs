//! # pofvr-web: the interactive browser viewer
//!
//! ## Brief overview
//!
//! [`Viewer`] holds one [`pofvr::Scene`] (the opened volume, its bricks, the
//! transfer-function family and optional POFs), shared by `Arc` and rendered per request
//! with that request's weights, shading and cull mode, and answers HTTP through [`router`];
//! [`serve`] binds it to a socket. The page is one HTML file with plain JS and CSS, compiled
//! into the binary. Its transfer-function panel (`static/tf-editor.js`) edits the family:
//! [`tf_api`] swaps the scene for one with the posted family without holding up frames in
//! flight, and [`histogram`] counts the values the panel draws the curves over.
//!
//! ## HTTP interface
//!
//! | route | answer |
//! |---|---|
//! | `GET /` , `/viewer.js`, `/tf-editor.js`, `/viewer.css` | the page |
//! | `GET /api/info` | JSON: volume, basis names and the family's weights, brick count, cull modes, `pofs`, `family_version`, limits |
//! | `GET /api/frame?…` | `image/png`; the frame's figures as JSON in the `X-Pofvr-Stats` header |
//! | `GET /api/status` | JSON: frames rendered, requests superseded, clients, renders running |
//! | `GET /api/histogram` | JSON: the volume's voxel counts in 256 bins over `value_range` (`lo`, `hi`, `counts`, `total`) |
//! | `GET /api/tf` | the family frames render with, as the JSON `--tf` reads |
//! | `POST /api/tf` | a family JSON (`Content-Type: application/json`, at most 1 MiB), checked as `--tf` checks it: `400` naming the field, the old family kept; otherwise later frames use it and the answer is JSON: `version`, `pofs`, `pof_renders_as`, `bases`, `weights` |
//! | `GET /api/pofs` | JSON: `state` (`match`, `stale`: built for other bases, `none`), `pof_renders_as`, `version`, `build` progress |
//! | `POST /api/pofs/rebuild` | `202`: builds POFs for the current family in the background and swaps them in when done; `409` while one runs |
//! | `GET /api/camera?…` | the camera of `/api/frame` with the same parameters, as the JSON `pofvr render --camera` reads |
//!
//! `/api/frame` parameters, all optional: `az`, `el` (degrees; `el` in [-90, 90]), `zoom`
//! (1 fits the volume, in [0.1, 20]), `w`, `h` (1..=2048), `proj` (`ortho` | `persp`),
//! `weights` (comma-separated, one per basis, each in [0, 100]), `threshold` (in
//! [0.01, 1]), `cull` (`none` | `pof` | `pof-set` | `exact` | `verified`), `shade` and `overlay` (`0` |
//! `1`), `client` (1–64 of `A-Za-z0-9-_`) and `seq` (echoed back). An invalid, unknown or
//! repeated parameter is answered `400` with a plain-text message. While the POFs are
//! `stale` the POF modes render as `verified` ([`tf_api::cull_for`]), and the stats header
//! says so: `cull` as rendered, `cull_requested`, `pofs`, and `family_version`. A
//! `verified` frame names its `predictor`: `previous` (the client's last verified set, see
//! `drag.rs`) after the client's first frame, `proxy` on it; `bricks.repaired` counts what
//! verification found culled wrongly. Under a
//! memory budget its `bytes_read`, `bricks_read` and `cache_hits` say what the frame read
//! from the brick store. Unless
//! [`ViewerOptions::loopback_hosts_only`] is off, a `Host` other than a loopback name gets
//! `403`.
//!
//! A request supersedes every older request of the same `client` that has not started
//! rendering; those are answered `204 No Content` with an `X-Pofvr-Superseded: 1` header,
//! without rendering. A client renders at most one frame at a time, and at most
//! [`ViewerOptions::render_slots`] frames render at once.

#![warn(missing_docs)]

mod drag;
pub mod encode;
pub mod frame_adapter;
pub mod histogram;
pub mod params;
mod scheduler;
pub mod tf_api;

use std::borrow::Cow;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Instant;

use axum::extract::{Query, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use glam::DVec3;
use pofvr::render::{Camera, Projection};
use pofvr::Scene;
use serde::Serialize;

use frame_adapter::{CullMode, FrameOptions, FrameStats};
use params::FrameParams;
pub use scheduler::SchedulerStats;
use scheduler::{Refusal, Scheduler};

/// Largest request body accepted, in bytes, except by `POST /api/tf`
/// ([`tf_api::TF_BODY_BYTES`]).
pub const MAX_BODY_BYTES: u64 = 16 * 1024;
/// Longest query string accepted, in bytes.
pub const MAX_QUERY_BYTES: usize = 4096;
/// Name of the response header marking a `204` answer to a superseded request.
pub const SUPERSEDED_HEADER: &str = "x-pofvr-superseded";
/// Name of the response header carrying a frame's figures as JSON.
pub const STATS_HEADER: &str = "x-pofvr-stats";

const INDEX_HTML: &str = include_str!("../static/index.html");
const VIEWER_JS: &str = include_str!("../static/viewer.js");
const VIEWER_CSS: &str = include_str!("../static/viewer.css");
const TF_EDITOR_JS: &str = include_str!("../static/tf-editor.js");

/// Tunables of a [`Viewer`].
#[derive(Clone, Debug)]
pub struct ViewerOptions {
    /// Frames that may render at once, across all clients.
    /// > default: the number of cores
    pub render_slots: usize,
    /// Clients remembered at once; beyond it a new client gets `503` while every known one
    /// has a request in flight.
    /// > default: 256
    pub max_clients: usize,
    /// Answer only requests whose `Host` is a loopback name (`localhost`, `127.x.x.x`,
    /// `[::1]`), which defeats DNS rebinding; turn off when binding another address.
    /// > default: true
    pub loopback_hosts_only: bool,
    /// In-process ranks per frame, as `pofvr render --ranks`.
    /// > default: 1
    pub ranks: usize,
}

impl Default for ViewerOptions {
    fn default() -> Self {
        ViewerOptions {
            render_slots: std::thread::available_parallelism()
                .map_or(1, std::num::NonZeroUsize::get),
            max_clients: 256,
            loopback_hosts_only: true,
            ranks: 1,
        }
    }
}

/// The state behind the server: one scene and the scheduler.
pub struct Viewer {
    slot: tf_api::SceneSlot,
    source: String,
    scheduler: Scheduler,
    /// Each client's last verified set, for its next frame's `previous` predictor.
    drag: drag::DragMemory,
    defaults: FrameParams,
    loopback_hosts_only: bool,
}

impl Viewer {
    /// A viewer of `scene`; `source` names the volume on the page.
    #[must_use]
    pub fn new(scene: Arc<Scene>, source: &str, options: &ViewerOptions) -> Self {
        // As `pofvr render`: POF culling when POFs are given, otherwise none.
        let mut defaults = FrameParams::new(
            scene.default_weights().to_vec(),
            scene.default_cull().mode(),
        );
        defaults.options.ranks = options.ranks.max(1);
        Viewer {
            slot: tf_api::SceneSlot::new(scene),
            source: source.to_string(),
            scheduler: Scheduler::new(options.render_slots, options.max_clients),
            drag: drag::DragMemory::new(options.max_clients),
            defaults,
            loopback_hosts_only: options.loopback_hosts_only,
        }
    }

    /// Frames rendered so far (superseded requests are not rendered, so not counted).
    #[must_use]
    pub fn renders(&self) -> u64 {
        self.scheduler.stats().renders
    }

    /// Holds every render slot until the returned guard is dropped: requests keep arriving
    /// and superseding each other, but none starts rendering. Lets tests line up a burst
    /// deterministically, and an operator pause rendering.
    pub async fn hold_renders(&self) -> RenderHold {
        RenderHold {
            _permits: self.scheduler.hold_all().await,
        }
    }

    /// The cull modes this viewer can render: the POF modes only with POFs.
    #[must_use]
    pub fn cull_modes(&self) -> Vec<CullMode> {
        frame_adapter::CULL_MODES
            .into_iter()
            .filter(|m| self.pof_state() != tf_api::PofState::None || !m.needs_pofs())
            .collect()
    }

    /// The scene frames render now (the panel may swap it for one with another family).
    #[must_use]
    pub fn scene(&self) -> Arc<Scene> {
        self.slot.current().scene
    }

    /// Whether the current scene's POFs match its family.
    #[must_use]
    pub fn pof_state(&self) -> tf_api::PofState {
        self.slot.pof_state(&self.scene())
    }

    /// The defaults of a request to `scene`: its family's weights, the rest as at start.
    fn defaults_for(&self, scene: &Scene) -> Cow<'_, FrameParams> {
        if scene.default_weights() == self.defaults.look.weights.as_slice() {
            Cow::Borrowed(&self.defaults)
        } else {
            let mut d = self.defaults.clone();
            d.look.weights = scene.default_weights().to_vec();
            Cow::Owned(d)
        }
    }

    /// The scheduler's counters.
    #[must_use]
    pub fn status(&self) -> SchedulerStats {
        self.scheduler.stats()
    }

    /// The camera of a request: the orbit camera with the whole volume fitted, zoomed.
    fn camera(&self, scene: &Scene, p: &FrameParams) -> Camera {
        let mut cam = Camera::orbit(
            scene.volume(),
            p.azimuth,
            p.elevation,
            p.width,
            p.height,
            p.projection,
        );
        match p.projection {
            Projection::Orthographic => cam.parallel_scale /= p.zoom,
            Projection::Perspective => {
                let focal = DVec3::from(cam.focal_point);
                cam.position = (focal + (DVec3::from(cam.position) - focal) / p.zoom).to_array();
            }
        }
        cam
    }
}

/// The routes, with the size limits and response headers applied.
pub fn router(viewer: Arc<Viewer>) -> Router {
    Router::new()
        .route(
            "/",
            get(|| async { page("text/html; charset=utf-8", INDEX_HTML) }),
        )
        .route(
            "/viewer.js",
            get(|| async { page("text/javascript; charset=utf-8", VIEWER_JS) }),
        )
        .route(
            "/viewer.css",
            get(|| async { page("text/css; charset=utf-8", VIEWER_CSS) }),
        )
        // Browsers ask for an icon; an empty answer keeps their consoles free of 404s.
        .route("/favicon.ico", get(|| async { StatusCode::NO_CONTENT }))
        .route("/api/info", get(info))
        .route("/api/status", get(status))
        .route("/api/frame", get(frame))
        .route(
            "/tf-editor.js",
            get(|| async { page("text/javascript; charset=utf-8", TF_EDITOR_JS) }),
        )
        .merge(tf_api::routes())
        .fallback(|| async { (StatusCode::NOT_FOUND, "no such page\n") })
        .layer(middleware::from_fn_with_state(Arc::clone(&viewer), guard))
        .with_state(viewer)
}

/// Rejects oversized requests (bodies over [`tf_api::body_limit`]) and foreign host names before routing, and marks every
/// answer as not to be sniffed or framed by another site.
async fn guard(State(v): State<Arc<Viewer>>, req: Request, next: Next) -> Response {
    let limit = tf_api::body_limit(req.uri().path());
    let too_long = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.parse::<u64>().map_or(true, |n| n > limit));
    let chunked = req.headers().contains_key(header::TRANSFER_ENCODING);
    let foreign_host = v.loopback_hosts_only
        && req
            .headers()
            .get(header::HOST)
            .is_some_and(|h| !h.to_str().is_ok_and(is_loopback_host));
    let mut resp = if foreign_host {
        // A page on another site can point its own host name at 127.0.0.1 (DNS rebinding)
        // and would then pass the browser's same-origin checks; its Host header gives it
        // away.
        text(
            StatusCode::FORBIDDEN,
            "this viewer answers only to localhost, 127.x.x.x and [::1] host names",
        )
    } else if too_long || chunked {
        (
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("request bodies are limited to {limit} bytes\n"),
        )
            .into_response()
    } else if req.uri().query().is_some_and(|q| q.len() > MAX_QUERY_BYTES) {
        (
            StatusCode::URI_TOO_LONG,
            format!("query strings are limited to {MAX_QUERY_BYTES} bytes\n"),
        )
            .into_response()
    } else {
        next.run(req).await
    };
    let h = resp.headers_mut();
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(
            "default-src 'self'; img-src 'self' blob:; style-src 'self'; script-src 'self'",
        ),
    );
    resp
}

/// True for `localhost`, an IPv4 loopback address or `[::1]`, with or without a port.
fn is_loopback_host(host: &str) -> bool {
    let name = if let Some(rest) = host.strip_prefix('[') {
        rest.split(']').next().unwrap_or("")
    } else {
        host.rsplit_once(':').map_or(host, |(n, _)| n)
    };
    name.eq_ignore_ascii_case("localhost")
        || name
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

fn page(content_type: &'static str, body: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, content_type),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
        .into_response()
}

fn text(status: StatusCode, msg: impl Into<String>) -> Response {
    let mut m = msg.into();
    m.push('\n');
    (
        status,
        [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
        m,
    )
        .into_response()
}

#[derive(Serialize)]
struct Info<'a> {
    volume: VolumeInfo<'a>,
    bases: Vec<BasisInfo<'a>>,
    bricks: BrickInfo,
    cull_modes: Vec<&'static str>,
    cull_modes_available: Vec<&'static str>,
    pofs_loaded: bool,
    pofs: tf_api::PofState,
    family_version: u64,
    defaults: Defaults,
    limits: Limits,
}

#[derive(Serialize)]
struct VolumeInfo<'a> {
    source: &'a str,
    dims: [usize; 3],
    spacing: [f32; 3],
    data_type: &'static str,
    value_range: [f32; 2],
}

#[derive(Serialize)]
struct BasisInfo<'a> {
    name: &'a str,
    weight: f32,
}

#[derive(Serialize)]
struct BrickInfo {
    size: usize,
    counts: [usize; 3],
    total: usize,
}

#[derive(Serialize)]
struct Defaults {
    az: f64,
    el: f64,
    w: u32,
    h: u32,
    threshold: f32,
    shade: bool,
    cull: CullMode,
}

#[derive(Serialize)]
struct Limits {
    max_side: u32,
    max_weight: f32,
    zoom: [f64; 2],
    threshold: [f32; 2],
}

async fn info(State(v): State<Arc<Viewer>>) -> Response {
    let cur = v.slot.current();
    let scene = &cur.scene;
    let pofs = v.slot.pof_state(scene);
    let range = scene.grid().value_range();
    let info = Info {
        volume: VolumeInfo {
            source: &v.source,
            dims: scene.volume().dims(),
            spacing: scene.volume().spacing(),
            data_type: scene.volume().data_type().name(),
            value_range: [range.min, range.max],
        },
        bases: scene
            .family()
            .bases
            .iter()
            .zip(scene.default_weights())
            .map(|(b, w)| BasisInfo {
                name: &b.name,
                weight: *w,
            })
            .collect(),
        bricks: BrickInfo {
            size: scene.grid().brick_size(),
            counts: scene.grid().counts(),
            total: scene.grid().len(),
        },
        cull_modes: frame_adapter::CULL_MODES.iter().map(|m| m.name()).collect(),
        cull_modes_available: v.cull_modes().iter().map(|m| m.name()).collect(),
        pofs_loaded: pofs != tf_api::PofState::None,
        pofs,
        family_version: cur.version,
        defaults: Defaults {
            az: v.defaults.azimuth,
            el: v.defaults.elevation,
            w: v.defaults.width,
            h: v.defaults.height,
            threshold: v.defaults.options.cull_threshold,
            shade: v.defaults.look.shade,
            cull: v.defaults.options.cull,
        },
        limits: Limits {
            max_side: params::MAX_SIDE,
            max_weight: params::MAX_WEIGHT,
            zoom: [params::ZOOM_RANGE.0, params::ZOOM_RANGE.1],
            threshold: [0.01, 1.0],
        },
    };
    json(&info)
}

async fn status(State(v): State<Arc<Viewer>>) -> Response {
    json(&v.status())
}

fn json<T: Serialize>(value: &T) -> Response {
    match serde_json::to_string(value) {
        Ok(s) => (
            [
                (header::CONTENT_TYPE, "application/json"),
                (header::CACHE_CONTROL, "no-store"),
            ],
            s,
        )
            .into_response(),
        Err(e) => text(StatusCode::INTERNAL_SERVER_ERROR, format!("JSON: {e}")),
    }
}

/// Stage times of a frame in milliseconds: the slowest rank's, since ranks run at once.
#[derive(Serialize)]
struct Times {
    cull_ms: f64,
    raycast_ms: f64,
    composite_ms: f64,
    comm_ms: f64,
    encode_ms: f64,
    wait_ms: f64,
    server_ms: f64,
}

/// What the `X-Pofvr-Stats` header carries.
#[derive(Serialize)]
struct FrameReport<'a> {
    client: &'a str,
    seq: u64,
    generation: u64,
    width: u32,
    height: u32,
    cull: CullMode,
    cull_requested: CullMode,
    pofs: tf_api::PofState,
    family_version: u64,
    threshold: f32,
    /// What predicted a `verified` frame's cull: `proxy` for a client's first frame (or its
    /// first with new weights, threshold or family), `previous` (its last frame's verified
    /// set) while it drags; `null` for the other modes.
    predictor: Option<&'static str>,
    frame_ms: f64,
    rays: u64,
    samples: u64,
    samples_per_second: f64,
    bricks: frame_adapter::BrickCounts,
    ranks: usize,
    times: Times,
    /// What the frame read from a memory-budgeted store (`pofvr serve --memory-budget`):
    /// bytes and bricks read from the file, bricks found in the cache; zeros otherwise.
    bytes_read: u64,
    bricks_read: u64,
    cache_hits: u64,
}

async fn frame(
    State(v): State<Arc<Viewer>>,
    query: Result<Query<Vec<(String, String)>>, axum::extract::rejection::QueryRejection>,
) -> Response {
    let received = Instant::now();
    let Ok(Query(pairs)) = query else {
        return text(
            StatusCode::BAD_REQUEST,
            "the query string is not valid URL encoding",
        );
    };
    // One scene from start to end, whatever the panel swaps in meanwhile.
    let cur = v.slot.current();
    let mut p = match params::parse(&pairs, &v.defaults_for(&cur.scene)) {
        Ok(p) => p,
        Err(msg) => return text(StatusCode::BAD_REQUEST, msg),
    };
    let pofs = v.slot.pof_state(&cur.scene);
    let cull_requested = p.options.cull;
    if p.options.cull.needs_pofs() && pofs == tf_api::PofState::None {
        return text(
            StatusCode::BAD_REQUEST,
            format!(
                "cull: {} needs precomputed POFs, which this server was started without; use none or exact",
                p.options.cull.name()
            ),
        );
    }
    p.options.cull = tf_api::cull_for(cull_requested, pofs);
    let ticket = match v.scheduler.ticket(&p.client) {
        Ok(t) => t,
        Err(_) => {
            return text(
                StatusCode::SERVICE_UNAVAILABLE,
                "too many clients with frames in flight; try again",
            )
        }
    };
    let grant = match v.scheduler.admit(&ticket).await {
        Ok(g) => g,
        Err(Refusal::Superseded) => {
            // 204 rather than an error status: being overtaken is the normal fate of most
            // requests while a slider moves, and browsers log every 4xx as an error.
            return (StatusCode::NO_CONTENT, [(SUPERSEDED_HEADER, "1")]).into_response();
        }
        Err(Refusal::TooManyClients) => {
            return text(StatusCode::SERVICE_UNAVAILABLE, "too many clients")
        }
    };
    let wait_ms = received.elapsed().as_secs_f64() * 1e3;
    let generation = ticket.generation();
    let viewer = Arc::clone(&v);
    let scene = Arc::clone(&cur.scene);
    let family_version = cur.version;
    // The grant moves into the blocking task, so a client that hangs up does not free the
    // render slot before the render it started is finished.
    let rendered = tokio::task::spawn_blocking(move || {
        let _grant = grant;
        viewer.scheduler.count_render();
        render_png(&viewer, &scene, &p, family_version)
            .map(|(png, stats, encode_ms)| (png, stats, encode_ms, p))
    })
    .await;
    let (png, stats, encode_ms, p) = match rendered {
        Ok(Ok(r)) => r,
        Ok(Err(msg)) => return text(StatusCode::INTERNAL_SERVER_ERROR, msg),
        Err(e) => {
            return text(
                StatusCode::INTERNAL_SERVER_ERROR,
                format!("render task failed: {e}"),
            )
        }
    };
    let slowest =
        |f: fn(&frame_adapter::RankStats) -> f64| stats.ranks.iter().map(f).fold(0.0, f64::max);
    let report = FrameReport {
        client: &p.client,
        seq: p.seq,
        generation,
        width: p.width,
        height: p.height,
        cull: p.options.cull,
        cull_requested,
        pofs,
        family_version: cur.version,
        threshold: p.options.cull_threshold,
        predictor: stats.predictor,
        frame_ms: stats.frame_ms,
        rays: stats.rays,
        samples: stats.samples,
        samples_per_second: stats.samples_per_second,
        bricks: stats.bricks,
        ranks: stats.ranks.len(),
        times: Times {
            cull_ms: slowest(|r| r.cull_ms),
            raycast_ms: slowest(|r| r.raycast_ms),
            composite_ms: slowest(|r| r.composite_ms),
            comm_ms: slowest(|r| r.comm_ms),
            encode_ms,
            wait_ms,
            server_ms: received.elapsed().as_secs_f64() * 1e3,
        },
        bytes_read: stats.bytes_read,
        bricks_read: stats.bricks_read,
        cache_hits: stats.cache_hits,
    };
    let mut headers = HeaderMap::new();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static("image/png"));
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    // serde_json escapes control characters and every string here is ASCII, so the JSON
    // is a valid header value; if that ever breaks, the frame still goes out.
    if let Ok(h) = serde_json::to_string(&report)
        .map_err(|_| ())
        .and_then(|s| HeaderValue::from_str(&s).map_err(|_| ()))
    {
        headers.insert(STATS_HEADER, h);
    }
    (headers, png).into_response()
}

/// Renders and encodes one frame: PNG bytes, the frame's figures and the encode time.
fn render_png(
    v: &Viewer,
    scene: &Scene,
    p: &FrameParams,
    family_version: u64,
) -> Result<(Vec<u8>, FrameStats, f64), String> {
    let cam = v.camera(scene, p);
    let render = |predictor| {
        let opts = FrameOptions {
            predictor,
            ..p.options.clone()
        };
        frame_adapter::render(scene, &cam, &opts, &p.look)
    };
    let frame = if p.options.cull == CullMode::Verified {
        let key = drag::SetKey {
            family_version,
            weights: p.look.weights.clone(),
            threshold: p.options.cull_threshold,
        };
        v.drag.render(scene, &p.client, key, render)
    } else {
        render(p.options.predictor)
    };
    let pofvr::Frame { image, stats } = frame.map_err(|e| e.to_string())?;
    let t = Instant::now();
    let tinted = if p.overlay {
        encode::footprints(
            scene.grid(),
            scene.volume().spacing(),
            &cam,
            &stats.culled_bricks,
        )
    } else {
        Vec::new()
    };
    let png = encode::png(
        &encode::rgba8_with_tint(&image, &tinted),
        image.width(),
        image.height(),
    )?;
    Ok((png, stats, t.elapsed().as_secs_f64() * 1e3))
}

/// While alive, no frame starts rendering (see [`Viewer::hold_renders`]).
#[must_use = "rendering resumes as soon as the hold is dropped"]
pub struct RenderHold {
    _permits: Option<tokio::sync::OwnedSemaphorePermit>,
}

/// Where and how to serve.
pub struct ServeConfig {
    /// The viewer to serve.
    pub viewer: Viewer,
    /// Address to bind; port 0 picks a free one.
    /// > default (CLI): 127.0.0.1:8080
    pub addr: SocketAddr,
}

/// Binds `config.addr`, prints `pofvr serve: listening on http://ADDR/` (the bound address,
/// so that port 0 can be used) on stdout and serves until Ctrl-C.
///
/// # Errors
/// The I/O error from binding or accepting.
pub async fn serve(config: ServeConfig) -> std::io::Result<()> {
    let listener = tokio::net::TcpListener::bind(config.addr).await?;
    let addr = listener.local_addr()?;
    {
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        writeln!(out, "pofvr serve: listening on http://{addr}/")?;
        out.flush()?;
    }
    serve_on(listener, Arc::new(config.viewer)).await
}

/// Serves `viewer` on an already bound listener until Ctrl-C.
///
/// # Errors
/// The I/O error from accepting.
pub async fn serve_on(
    listener: tokio::net::TcpListener,
    viewer: Arc<Viewer>,
) -> std::io::Result<()> {
    axum::serve(listener, router(viewer))
        .with_graceful_shutdown(async {
            // Without a signal handler the server simply runs until killed.
            if tokio::signal::ctrl_c().await.is_err() {
                std::future::pending::<()>().await;
            }
        })
        .await
}

/// [`serve`] on a multi-threaded Tokio runtime of its own, for callers without one.
///
/// # Errors
/// The I/O error from starting the runtime, binding or accepting.
pub fn serve_blocking(config: ServeConfig) -> std::io::Result<()> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?
        .block_on(serve(config))
}
