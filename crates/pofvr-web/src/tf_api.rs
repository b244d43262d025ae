//! Editing the transfer function from the page: the family swapped under running frames,
//! whether the POFs still match it, and POFs rebuilt in the background.
//!
//! The scene is held as an `Arc` behind a lock that is only taken to clone or replace it:
//! a frame takes the scene once when it starts and renders with it to the end, so a swap
//! never waits for a frame nor a frame for a swap. A POF table bounds the opacity of the
//! bases it was built for, so a family with other bases cannot use it; what the POF cull
//! modes do then is decided in one place, [`cull_for`].

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, RwLock};
use std::time::Instant;

use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, Query, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use pofvr::cull::CullMode;
use pofvr::render::TransferFunction;
use pofvr::{PofBuild, Scene};
use serde::Serialize;

use crate::histogram::Histogram;
use crate::{json, params, text, Viewer};

/// Largest family JSON `POST /api/tf` accepts, in bytes; every other route keeps
/// [`crate::MAX_BODY_BYTES`].
pub const TF_BODY_BYTES: u64 = 1 << 20;

/// How errors in a posted family name their source.
pub const POSTED_FAMILY: &str = "the posted family";

/// The body limit of the route at `path`.
#[must_use]
pub fn body_limit(path: &str) -> u64 {
    if path == "/api/tf" {
        TF_BODY_BYTES
    } else {
        crate::MAX_BODY_BYTES
    }
}

/// Whether the scene's POFs bound its family.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PofState {
    /// The scene has POFs for its bases.
    Match,
    /// POFs were loaded or built, but for other bases than the family's.
    Stale,
    /// No POFs were ever loaded or built.
    None,
}

/// The cull mode a frame asking for `asked` renders with. POFs for other bases bound the
/// wrong opacity and would cull visible bricks, so with [`PofState::Stale`] the POF modes
/// render as `verified`: its proxy predictor needs no POFs, and verifying the prediction
/// while compositing (and repairing what it got wrong) keeps the threshold rule whatever
/// the family.
#[must_use]
pub fn cull_for(asked: CullMode, pofs: PofState) -> CullMode {
    if asked.needs_pofs() && pofs == PofState::Stale {
        CullMode::Verified
    } else {
        asked
    }
}

/// The scene frames render now and the version of its family (0 for the one served at
/// start, one more for each swap).
#[derive(Clone)]
pub struct Current {
    /// The scene.
    pub scene: Arc<Scene>,
    /// Its family's version.
    pub version: u64,
}

/// The swappable scene of a [`Viewer`], with what editing its family needs.
pub struct SceneSlot {
    current: RwLock<Current>,
    /// The newest scene with POFs. New families are made from it, so that every family with
    /// the bases its POFs were built for gets them back (an undone reshape culls again).
    pof_home: Mutex<Option<Arc<Scene>>>,
    /// Swaps one at a time, so that a finished build cannot undo a family posted meanwhile.
    edits: Mutex<()>,
    histogram: OnceLock<Histogram>,
    build: BuildProgress,
}

/// A poisoned lock only means another request panicked; the value is still whole.
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl SceneSlot {
    /// A slot serving `scene`, whose POFs (if any) are the ones loaded.
    #[must_use]
    pub fn new(scene: Arc<Scene>) -> Self {
        let home = scene.pofs().is_some().then(|| Arc::clone(&scene));
        SceneSlot {
            current: RwLock::new(Current { scene, version: 0 }),
            pof_home: Mutex::new(home),
            edits: Mutex::new(()),
            histogram: OnceLock::new(),
            build: BuildProgress::default(),
        }
    }

    /// The scene frames render now, with its version.
    #[must_use]
    pub fn current(&self) -> Current {
        self.current
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// Whether `scene`'s POFs match its family.
    #[must_use]
    pub fn pof_state(&self, scene: &Scene) -> PofState {
        if scene.pofs().is_some() {
            PofState::Match
        } else if lock(&self.pof_home).is_some() {
            PofState::Stale
        } else {
            PofState::None
        }
    }

    /// Makes `family` the one frames render with from now on, keeping the POFs when its
    /// bases are the ones they were built for.
    ///
    /// # Errors
    /// [`pofvr::Error`] for default weights that do not fit the bases.
    pub fn set_family(&self, family: TransferFunction) -> pofvr::Result<Current> {
        let _edit = lock(&self.edits);
        let home = lock(&self.pof_home).clone();
        let base = match home {
            Some(h) => {
                // Measured once on the home scene; every scene made from it copies them.
                let _ = h.cell_ranges();
                h
            }
            None => self.current().scene,
        };
        let next = base.with_family(family)?;
        Ok(self.install(Arc::new(next)))
    }

    /// Makes `built` (a scene with POFs) the home of POFs, and renders the current family
    /// with them when its bases are theirs.
    fn adopt_pofs(&self, built: Arc<Scene>) -> pofvr::Result<Current> {
        let _edit = lock(&self.edits);
        *lock(&self.pof_home) = Some(Arc::clone(&built));
        let now = self.current().scene;
        let next = if now.family() == built.family() {
            built
        } else {
            Arc::new(built.with_family(now.family().clone())?)
        };
        Ok(self.install(next))
    }

    fn install(&self, scene: Arc<Scene>) -> Current {
        let mut cur = self
            .current
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        *cur = Current {
            scene,
            version: cur.version + 1,
        };
        cur.clone()
    }

    /// The volume's histogram, counted on first use.
    pub fn histogram(&self) -> &Histogram {
        self.histogram
            .get_or_init(|| Histogram::of(&self.current().scene))
    }
}

/// Where the background POF build stands.
#[derive(Default)]
struct BuildProgress {
    running: AtomicBool,
    done: AtomicU64,
    total: AtomicU64,
    finished: AtomicU64,
    last: Mutex<BuildEnd>,
}

/// How the last build ended.
#[derive(Clone, Default, Serialize)]
struct BuildEnd {
    error: Option<String>,
    seconds: Option<f64>,
    version: Option<u64>,
}

/// What `GET /api/pofs` answers.
#[derive(Serialize)]
struct PofReport {
    state: PofState,
    /// What `pof` renders as now; `null` without POFs.
    pof_renders_as: Option<CullMode>,
    version: u64,
    build: BuildReport,
}

#[derive(Serialize)]
struct BuildReport {
    running: bool,
    /// Bricks done and to do in the running (or last) build.
    done: u64,
    total: u64,
    /// Builds finished, successful or not.
    finished: u64,
    /// The last finished build's error, seconds and the family version it installed.
    last: BuildEnd,
}

/// The viewer's routes for the transfer-function panel.
pub(crate) fn routes() -> Router<Arc<Viewer>> {
    Router::new()
        .route("/api/histogram", get(histogram))
        .route(
            "/api/tf",
            get(family)
                .post(post_family)
                .layer(DefaultBodyLimit::max(TF_BODY_BYTES as usize)),
        )
        .route("/api/pofs", get(pofs))
        .route("/api/pofs/rebuild", post(rebuild))
        .route("/api/camera", get(camera))
}

/// A POST must say its body is JSON: a page of another site can only send that with a
/// CORS preflight, which this server does not grant, so it cannot change the family.
fn refuse_non_json(headers: &HeaderMap) -> Option<Response> {
    let is_json = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| {
            v.split(';')
                .next()
                .is_some_and(|t| t.trim().eq_ignore_ascii_case("application/json"))
        });
    (!is_json).then(|| {
        text(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "POST bodies must be sent as Content-Type: application/json",
        )
    })
}

async fn histogram(State(v): State<Arc<Viewer>>) -> Response {
    let viewer = Arc::clone(&v);
    match tokio::task::spawn_blocking(move || viewer.slot.histogram().clone()).await {
        Ok(h) => json(&h),
        Err(e) => text(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("histogram task failed: {e}"),
        ),
    }
}

async fn family(State(v): State<Arc<Viewer>>) -> Response {
    let cur = v.slot.current();
    json(cur.scene.family())
}

/// What `POST /api/tf` answers.
#[derive(Serialize)]
struct Posted {
    version: u64,
    pofs: PofState,
    pof_renders_as: Option<CullMode>,
    bases: Vec<String>,
    weights: Vec<f32>,
}

async fn post_family(State(v): State<Arc<Viewer>>, headers: HeaderMap, body: Bytes) -> Response {
    if let Some(r) = refuse_non_json(&headers) {
        return r;
    }
    let Ok(body) = std::str::from_utf8(&body) else {
        return text(
            StatusCode::BAD_REQUEST,
            format!("{POSTED_FAMILY}: not UTF-8 text"),
        );
    };
    // The very checks `--tf` makes, so that the page can save what `pofvr render` reads.
    let family = match TransferFunction::from_json(body, POSTED_FAMILY) {
        Ok(f) => f,
        Err(e) => return text(StatusCode::BAD_REQUEST, e.to_string()),
    };
    let viewer = Arc::clone(&v);
    let swapped = tokio::task::spawn_blocking(move || viewer.slot.set_family(family)).await;
    match swapped {
        Ok(Ok(cur)) => {
            let state = v.slot.pof_state(&cur.scene);
            json(&Posted {
                version: cur.version,
                pofs: state,
                pof_renders_as: pof_renders_as(state),
                bases: cur
                    .scene
                    .family()
                    .bases
                    .iter()
                    .map(|b| b.name.clone())
                    .collect(),
                weights: cur.scene.default_weights().to_vec(),
            })
        }
        Ok(Err(e)) => text(StatusCode::BAD_REQUEST, format!("{POSTED_FAMILY}: {e}")),
        Err(e) => text(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("family swap failed: {e}"),
        ),
    }
}

fn pof_renders_as(state: PofState) -> Option<CullMode> {
    (state != PofState::None).then(|| cull_for(CullMode::Pof, state))
}

async fn pofs(State(v): State<Arc<Viewer>>) -> Response {
    let cur = v.slot.current();
    let state = v.slot.pof_state(&cur.scene);
    let b = &v.slot.build;
    json(&PofReport {
        state,
        pof_renders_as: pof_renders_as(state),
        version: cur.version,
        build: BuildReport {
            running: b.running.load(Ordering::Acquire),
            done: b.done.load(Ordering::Relaxed),
            total: b.total.load(Ordering::Relaxed),
            finished: b.finished.load(Ordering::Acquire),
            last: lock(&b.last).clone(),
        },
    })
}

/// Starts building POFs for the current family on a thread of its own (frames keep
/// rendering meanwhile) and answers `202` at once; `409` while a build runs.
async fn rebuild(State(v): State<Arc<Viewer>>, headers: HeaderMap) -> Response {
    if let Some(r) = refuse_non_json(&headers) {
        return r;
    }
    let b = &v.slot.build;
    if b.running.swap(true, Ordering::AcqRel) {
        return text(StatusCode::CONFLICT, "a POF build is already running");
    }
    b.done.store(0, Ordering::Relaxed);
    b.total.store(0, Ordering::Relaxed);
    let viewer = Arc::clone(&v);
    let spawned = std::thread::Builder::new()
        .name("pof-rebuild".into())
        .spawn(move || build_pofs(&viewer));
    if let Err(e) = spawned {
        b.running.store(false, Ordering::Release);
        return text(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("could not start the build: {e}"),
        );
    }
    text(StatusCode::ACCEPTED, "POF build started")
}

/// Builds POFs for the current scene with the library's default build settings and swaps
/// them in; the outcome lands in the build progress either way.
fn build_pofs(v: &Viewer) {
    /// Marks the build finished even if it panics, so that a later one can start.
    struct Finish<'a>(&'a BuildProgress);
    impl Drop for Finish<'_> {
        fn drop(&mut self) {
            self.0.finished.fetch_add(1, Ordering::AcqRel);
            self.0.running.store(false, Ordering::Release);
        }
    }
    let b = &v.slot.build;
    let _finish = Finish(b);
    let t = Instant::now();
    let scene = v.slot.current().scene;
    // Bricks finish on many threads, so counts may arrive out of order.
    let progress = |done: u64, total: u64| {
        b.done.fetch_max(done, Ordering::Relaxed);
        b.total.store(total, Ordering::Relaxed);
    };
    let outcome = scene
        .build_pofs_with(&PofBuild::default(), None, &progress)
        .and_then(|table| scene.with_family(scene.family().clone())?.with_pofs(table))
        .and_then(|built| v.slot.adopt_pofs(Arc::new(built)));
    *lock(&b.last) = match outcome {
        Ok(cur) => BuildEnd {
            error: None,
            seconds: Some(t.elapsed().as_secs_f64()),
            version: Some(cur.version),
        },
        Err(e) => BuildEnd {
            error: Some(e.to_string()),
            seconds: Some(t.elapsed().as_secs_f64()),
            version: None,
        },
    };
}

/// `GET /api/camera?…`: the camera of the frame with the same parameters, as the JSON that
/// `pofvr render --camera` reads.
async fn camera(
    State(v): State<Arc<Viewer>>,
    query: Result<Query<Vec<(String, String)>>, axum::extract::rejection::QueryRejection>,
) -> Response {
    let Ok(Query(pairs)) = query else {
        return text(
            StatusCode::BAD_REQUEST,
            "the query string is not valid URL encoding",
        );
    };
    let cur = v.slot.current();
    let defaults = v.defaults_for(&cur.scene);
    match params::parse(&pairs, &defaults) {
        Ok(p) => {
            let cam = v.camera(&cur.scene, &p);
            (
                [
                    (header::CONTENT_TYPE, "application/json"),
                    (header::CACHE_CONTROL, "no-store"),
                ],
                cam.to_json(),
            )
                .into_response()
        }
        Err(msg) => text(StatusCode::BAD_REQUEST, msg),
    }
}
