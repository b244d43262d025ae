use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use pofvr::brick::BrickGrid;
use pofvr::cull::Predictor;
use pofvr::distribute::{Curve, Deal};
use pofvr::frame::{FrameStats, RenderJob};
use pofvr::render::{Camera, Image};
use pofvr::volume::Volume;
use pofvr::{CullMode, Engine, Frame, FrameRequest, Pofs, Scene};

use crate::args::{FrameArgs, RenderArgs};
use crate::progress::Ui;
use crate::resolve;

/// Where the frames of `pofvr render` are made: in-process ranks (threads), or this
/// process's part of an MPI job (`mpi_frame.rs`).
pub(crate) trait Backend {
    /// True on the rank that writes the outputs and prints the summary.
    fn is_root(&self) -> bool;

    /// One frame; `Some` on the root only.
    fn frame(&self, scene: &Scene, request: &FrameRequest<'_>) -> Result<Option<Frame>>;

    /// The volume's brick grid with every brick's value range. A distributed backend
    /// measures each rank's own bricks and exchanges the ranges, so that no rank reads
    /// bricks it does not own.
    fn grid(&self, volume: &Volume, brick_size: usize, _curve: Curve) -> Result<BrickGrid> {
        Ok(BrickGrid::from_volume(volume, brick_size)?)
    }

    /// Called once the job is made, before it becomes the scene: a distributed backend
    /// keeps private copies of its own bricks and lets the volume's mapped pages go.
    fn prepare(&self, _job: &mut RenderJob, _curve: Curve, _replicas: usize) -> Result<()> {
        Ok(())
    }

    /// True when the frame is shared by the processes of an MPI job (the brick engine only).
    fn distributed(&self) -> bool {
        false
    }

    /// Called on every rank after the last frame; the root returns extra `--stats` fields.
    fn finish(&self) -> Result<Option<serde_json::Map<String, serde_json::Value>>>;
}

/// `--ranks N` threads of this process.
struct InProcess;

impl Backend for InProcess {
    fn is_root(&self) -> bool {
        true
    }

    fn frame(&self, scene: &Scene, request: &FrameRequest<'_>) -> Result<Option<Frame>> {
        Ok(Some(scene.render(request)?))
    }

    fn finish(&self) -> Result<Option<serde_json::Map<String, serde_json::Value>>> {
        let mut m = serde_json::Map::new();
        m.insert(
            "memory".into(),
            serde_json::to_value([MemoryStatus::now(0)])?,
        );
        Ok(Some(m))
    }
}

/// One process's memory, from `/proc/self/status` (Linux; zeros elsewhere), and its host.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct MemoryStatus {
    /// The rank (0 for in-process ranks, which share the process).
    pub(crate) rank: usize,
    /// Host name.
    pub(crate) host: String,
    /// Resident set now (`VmRSS`).
    pub(crate) vm_rss_bytes: u64,
    /// Peak resident set (`VmHWM`).
    pub(crate) vm_hwm_bytes: u64,
    /// Resident anonymous memory (`RssAnon`): heap, images, fragments.
    pub(crate) rss_anon_bytes: u64,
    /// Resident file-backed pages (`RssFile`): the memory-mapped volume pages touched.
    pub(crate) rss_file_bytes: u64,
    /// Voxel bytes of the private copies of this rank's own bricks (MPI ranks).
    #[serde(default)]
    pub(crate) brick_copy_bytes: u64,
    /// Bytes the process read by `read` calls so far (`rchar` of `/proc/self/io`): the
    /// store's chunks and files while measuring the ranges and rendering, which the
    /// frames' `bytes_read` count only in part (not the measuring).
    #[serde(default)]
    pub(crate) io_read_bytes: u64,
}

impl MemoryStatus {
    pub(crate) fn now(rank: usize) -> Self {
        let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
        let kib = |key: &str| {
            status
                .lines()
                .find_map(|l| l.strip_prefix(key)?.strip_prefix(':'))
                .and_then(|v| v.split_whitespace().next()?.parse::<u64>().ok())
                .map_or(0, |k| k * 1024)
        };
        MemoryStatus {
            rank,
            host: std::fs::read_to_string("/proc/sys/kernel/hostname")
                .map(|h| h.trim().to_owned())
                .unwrap_or_default(),
            vm_rss_bytes: kib("VmRSS"),
            vm_hwm_bytes: kib("VmHWM"),
            rss_anon_bytes: kib("RssAnon"),
            rss_file_bytes: kib("RssFile"),
            brick_copy_bytes: 0,
            io_read_bytes: std::fs::read_to_string("/proc/self/io")
                .ok()
                .and_then(|io| {
                    io.lines()
                        .find_map(|l| l.strip_prefix("rchar:"))
                        .and_then(|v| v.trim().parse().ok())
                })
                .unwrap_or(0),
        }
    }
}

pub(crate) fn run(a: &RenderArgs, ui: &Ui) -> Result<()> {
    #[cfg(feature = "mpi")]
    if pofvr_mpi::launched_by_mpi() {
        return super::mpi_frame::run(a, ui);
    }
    run_with(a, ui, &InProcess)
}

/// `pofvr render` over any backend: every rank runs this; only the root writes.
pub(crate) fn run_with(a: &RenderArgs, ui: &Ui, backend: &dyn Backend) -> Result<()> {
    let t0 = Instant::now();
    if a.frames == 0 {
        bail!("--frames must be at least 1");
    }
    if !a.orbit.is_finite() {
        bail!("--orbit {} is not a finite number of degrees", a.orbit);
    }
    if a.frames > 1 && a.reference.is_some() {
        bail!("--reference compares one frame; leave out --frames");
    }
    let budget = memory_budget(a.memory_budget.as_deref())?;
    let sp = ui.spinner("opening and bricking the volume");
    // A multiscale image is read at the finest level that still has about two voxels per
    // pixel across the image: finer levels only add samples the pixels average away.
    let max_dim = resolve::size(&a.view.size)
        .ok()
        .map(|(w, h)| 2 * w.max(h) as usize);
    // A Zarr level larger than the budget is not decoded: the store decodes its chunks.
    let vol = resolve::volume_deferring(&a.volume, max_dim, budget)?;
    let tf = resolve::required_tf(&a.tf, &a.volume.volume)?;
    let cam = resolve::camera(&a.view, &vol)?;
    let curve: Curve = a
        .frame
        .curve
        .parse()
        .map_err(|e| anyhow::anyhow!("--curve: {e}"))?;
    let deal = deal(&a.frame)?;
    // An MPI rank measures only its own bricks (the backend's grid) and keeps copies of
    // them; one process under a budget streams the file once instead.
    let grid = match budget {
        Some(_) if !backend.distributed() => pofvr::store::grid_for(&vol, a.volume.brick, budget)?,
        _ => backend.grid(&vol, a.volume.brick, curve)?,
    };
    let store = if backend.distributed() {
        None
    } else {
        pofvr::store::cache_for(&vol, budget)?
    };
    let mut job = RenderJob::with_grid(vol, tf, grid, resolve::settings(&a.view))?;
    job.store = store;
    job.deal = deal;
    // A deal by chunks on a volume without them fails here, before any frame.
    if deal == Deal::Chunks {
        pofvr::distribute::chunks::chunk_shape_for(&job.volume, a.volume.brick, deal)
            .map_err(|e| anyhow!("--deal chunks: {e}"))?;
    }
    backend.prepare(&mut job, curve, a.frame.replicas)?;
    let mut scene = Scene::from_job(job)?;
    sp.set_message("rendering");
    // `None`: the whole volume in one pass (--whole).
    let mode = if a.frame.whole {
        None
    } else {
        let cull: CullMode = match (&a.frame.cull, &a.frame.pof) {
            (Some(c), _) => c
                .parse()
                .map_err(|e: String| anyhow::anyhow!("--cull: {e}"))?,
            (None, Some(_)) => CullMode::Pof,
            (None, None) => CullMode::None,
        };
        if let Some(p) = &a.frame.pof {
            scene = load_pofs(scene, &a.frame, cull, p)?;
        }
        if cull == CullMode::PofSet && !scene.pofs().is_some_and(Pofs::has_sets) {
            bail!("--cull pof-set needs a POF file built with --sets");
        }
        Some(cull)
    };
    let scene = scene;
    let budgeted = scene.store().is_some();
    let engine = engine(&a.frame, backend.distributed(), budgeted)?;
    let cull = match mode {
        Some(m) => Some(verified_cull(&a.frame, m, &scene)?),
        None => None,
    };
    let mut all = Vec::with_capacity(a.frames);
    for i in 0..a.frames {
        let cam_i = orbited(&cam, a.orbit * i as f64);
        let request = FrameRequest::new(&cam_i).shade(a.view.shade);
        let frame = match cull {
            None if backend.is_root() => Some(scene.render_reference(&request)?),
            None => None,
            Some(cull) => backend.frame(
                &scene,
                &request
                    .engine(engine)
                    .cull(cull)
                    .verify(a.frame.verify)
                    .threshold(a.frame.cull_threshold)
                    .ranks(a.frame.ranks)
                    .curve(curve)
                    .replicas(a.frame.replicas),
            )?,
        };
        let Some(Frame { image, stats }) = frame else {
            continue;
        };
        let name = |p: &Path| frame_path(p, i, a.frames);
        image.write_png(&name(&a.out))?;
        if let Some(p) = &a.out_raw {
            image.write_raw(&name(p))?;
        }
        if let Some(r) = &a.reference {
            let reference = Image::read_raw(r, cam.width, cam.height)
                .with_context(|| format!("--reference {}", r.display()))?;
            println!(
                "reference {}: rmse {:.3e}, max abs diff {:.3e}",
                r.display(),
                image.rmse(&reference).unwrap_or(f64::NAN),
                image.max_abs_diff(&reference).unwrap_or(f32::NAN)
            );
        }
        all.push(stats);
    }
    let mut extra = backend.finish()?;
    if let (Some(b), Some(m)) = (budget, extra.as_mut()) {
        m.insert(
            "memory_budget".into(),
            budget_json(scene.volume(), scene.store(), b)?,
        );
    }
    sp.finish_and_clear();
    if !backend.is_root() {
        return Ok(());
    }
    resolve::write_camera(&a.view, &cam)?;
    if let Some(p) = &a.stats {
        let json = stats_json(&all, extra)?;
        pofvr::io::write_bytes_atomic(p, serde_json::to_string_pretty(&json)?.as_bytes())?;
    }
    let Some(stats) = all.first() else {
        bail!("the root rendered no frame");
    };
    eprintln!(
        "{}: {}×{} in {:.1} ms, {}, {:.1} M samples ({:.0} M samples/s), total {:.2} s",
        frame_path(&a.out, 0, a.frames).display(),
        cam.width,
        cam.height,
        stats.frame_ms,
        rays_text(stats),
        stats.samples as f64 / 1e6,
        stats.samples_per_second / 1e6,
        t0.elapsed().as_secs_f64()
    );
    if let Some(mode) = stats.cull {
        let b = stats.bricks;
        eprintln!(
            "bricks: {} total, {} empty, {} non-empty, {} culled ({:.1}% of non-empty) by {}, {} visible",
            b.total,
            b.empty,
            b.non_empty,
            b.culled,
            100.0 * b.culled as f64 / b.non_empty.max(1) as f64,
            mode.name(),
            b.visible
        );
        if let (Some(deal), [_, _, ..]) = (stats.deal, stats.ranks.as_slice()) {
            let per: Vec<String> = stats
                .ranks
                .iter()
                .map(|r| r.bricks_rendered.to_string())
                .collect();
            eprintln!(
                "ranks: {} (bricks dealt by {deal}), bricks rendered per rank {}",
                stats.ranks.len(),
                per.join(" / ")
            );
        }
        if let Some(p) = stats.predictor {
            eprintln!(
                "verified: predicted by {p}, {} repaired ({:.1}% of the rendered)",
                b.repaired,
                100.0 * b.repaired as f64 / b.visible.max(1) as f64
            );
        }
    }
    if let Some(store) = scene.store() {
        let per: Vec<u64> = all.iter().map(|s| s.bytes_read).collect();
        eprintln!("{}", budget_line(store, &per));
        if let [first, rest @ ..] = per.as_slice() {
            if !rest.is_empty() {
                let mut r = rest.to_vec();
                r.sort_unstable();
                eprintln!(
                    "bytes read: first frame {:.1} MB, median of the rest {:.1} MB, most {:.1} MB",
                    *first as f64 / 1e6,
                    r[r.len() / 2] as f64 / 1e6,
                    r[r.len() - 1] as f64 / 1e6
                );
            }
        }
    }
    if all.len() > 1 {
        let ms: Vec<f64> = all.iter().map(|s| s.frame_ms).collect();
        eprintln!(
            "{} frames, {:.1}° apart: first {:.1} ms, median of the rest {:.1} ms",
            all.len(),
            a.orbit,
            ms[0],
            median(&ms[1..])
        );
    }
    Ok(())
}

/// The rays of a frame in words: pixels' rays, and for the brick engine the rays it cast,
/// one per brick fragment (`--stats` `pixel_rays` and `rays`).
fn rays_text(stats: &FrameStats) -> String {
    if stats.rays == stats.pixel_rays {
        format!("{} pixel rays", stats.pixel_rays)
    } else {
        format!(
            "{} pixel rays ({} rays cast, one per brick fragment)",
            stats.pixel_rays, stats.rays
        )
    }
}

/// The deal of `--deal`.
pub(crate) fn deal(a: &FrameArgs) -> Result<Deal> {
    a.deal.parse().map_err(|e| anyhow!("--deal: {e}"))
}

/// The bytes of `--memory-budget SIZE`, as `render`, `serve` and `experiment` read it: one
/// parser and one message for all of them.
pub(crate) fn memory_budget(flag: Option<&str>) -> Result<Option<u64>> {
    let budget = flag
        .map(pofvr::store::parse_size)
        .transpose()
        .map_err(|e| anyhow!("--memory-budget: {e}"))?;
    if budget.is_some() {
        // Freed chunks and slabs must leave the process for the budget to bound it.
        crate::alloc::return_large_blocks();
    }
    Ok(budget)
}

/// One line on what a budgeted scene read: the budget, where bricks come from, per-frame
/// MB read (`per_frame`, in frame order), the cache's totals and the peak RSS.
pub(crate) fn budget_line(store: &pofvr::store::BrickCache, per_frame: &[u64]) -> String {
    let per: Vec<String> = per_frame
        .iter()
        .map(|b| format!("{:.1}", *b as f64 / 1e6))
        .collect();
    let c = store.summary();
    format!(
        "memory budget {} MB: bricks read on demand from the {}, MB read per frame [{}], {} bricks read, {} cache hits, cache peak {:.1} MB (proxy charged {:.1} MB), peak RSS {:.1} MB",
        c.budget_bytes / 1_000_000,
        store.source().kind(),
        per.join(", "),
        c.bricks_read,
        c.cache_hits,
        c.cache_peak_bytes as f64 / 1e6,
        c.reserved_bytes as f64 / 1e6,
        pofvr::store::peak_rss_bytes() as f64 / 1e6
    )
}

/// `scene` with the POF file `p` (and `--pof-level`s). A frame that verifies its cull
/// (`--verify`, or `--cull verified`) accepts POFs built for other basis shapes, with a
/// warning: they only predict there, and verification keeps the image right. Plain
/// `--cull pof` and `pof-set` refuse them, since they bound nothing.
pub(crate) fn load_pofs(scene: Scene, a: &FrameArgs, cull: CullMode, p: &Path) -> Result<Scene> {
    if !(a.verify || cull == CullMode::Verified) {
        return Ok(scene.load_pof_levels(p, &a.pof_level)?);
    }
    let scene = scene.load_pof_predictions(p, &a.pof_level)?;
    if let Some(why) = scene.pofs().and_then(Pofs::stale_reason) {
        eprintln!(
            "warning: {why}; they only predict the cull, which verification repairs, so the \
             image stays right but more bricks are rendered and repaired"
        );
    }
    Ok(scene)
}

/// The cull of `--cull` mode `m` with `--predictor` and `--verify`, checked.
pub(crate) fn verified_cull<'s>(
    a: &FrameArgs,
    m: CullMode,
    scene: &'s Scene,
) -> Result<pofvr::Cull<'s>> {
    let predictor: Option<Predictor> = a
        .predictor
        .as_deref()
        .map(str::parse)
        .transpose()
        .map_err(|e: String| anyhow!("--predictor: {e}"))?;
    if predictor.is_some() && m != CullMode::Verified {
        bail!(
            "--predictor picks the predictor of --cull verified, got --cull {}",
            m.name()
        );
    }
    if a.verify && !matches!(m, CullMode::Pof | CullMode::PofSet | CullMode::Verified) {
        bail!(
            "--verify adds verification to --cull pof and pof-set, got --cull {}",
            m.name()
        );
    }
    let no_pofs = |what: String| {
        anyhow!("{what} needs precomputed POFs (--pof FILE.pof, built by `pofvr pof build`)")
    };
    if m == CullMode::Verified {
        let p = predictor.unwrap_or(Predictor::BEST);
        return pofvr::Predict::from_predictor(p, scene.pofs())
            .map(pofvr::Cull::Verified)
            .ok_or_else(|| no_pofs(format!("--predictor {}", p.name())));
    }
    scene
        .cull(m)
        .ok_or_else(|| no_pofs(format!("--cull {}", m.name())))
}

/// The `memory_budget` entry of `--stats` (and of `experiment`'s `report.json`): the
/// budget, where bricks come from, why the engine is the brick engine, and the cache's
/// totals over the run.
pub(crate) fn budget_json(
    volume: &Volume,
    store: Option<&pofvr::store::BrickCache>,
    budget: u64,
) -> Result<serde_json::Value> {
    let volume_bytes = pofvr::store::volume_bytes(volume);
    let mut m = serde_json::Map::new();
    m.insert("budget_bytes".into(), budget.into());
    m.insert("volume_bytes".into(), volume_bytes.into());
    match store {
        Some(store) => {
            m.insert("source".into(), store.source().kind().into());
            m.insert(
                "engine".into(),
                "bricks: the volume does not fit the budget, so the brick engine reads the bricks it renders"
                    .into(),
            );
            m.insert("cache".into(), serde_json::to_value(store.summary())?);
            if let Some(z) = store.source().zarr() {
                m.insert(
                    "zarr_chunks".into(),
                    serde_json::json!({
                        "chunk_budget_bytes": z.chunk_budget(),
                        "chunk_shape": z.level().chunk_shape(),
                        "chunks_decoded": z.chunks_decoded(),
                        "chunk_evictions": z.chunk_evictions(),
                    }),
                );
            }
        }
        None => {
            m.insert(
                "source".into(),
                "the whole volume (it fits the budget)".into(),
            );
        }
    }
    m.insert(
        "peak_rss_bytes".into(),
        pofvr::store::peak_rss_bytes().into(),
    );
    Ok(serde_json::Value::Object(m))
}

/// The engine of `--engine`, or by default march for one process without `--cull`,
/// `--pof`, `--ranks` above 1 or a `--memory-budget` the volume does not fit, bricks
/// otherwise; march with any of those is an error.
pub(crate) fn engine(
    a: &crate::args::FrameArgs,
    distributed: bool,
    budgeted: bool,
) -> Result<Engine> {
    let conflict = if distributed {
        Some("an MPI job".to_owned())
    } else if budgeted {
        Some(
            "--memory-budget smaller than the volume (the march engine needs the whole lattice)"
                .to_owned(),
        )
    } else if let Some(c) = &a.cull {
        Some(format!("--cull {c}"))
    } else if a.pof.is_some() {
        Some("--pof (which culls with --cull pof)".to_owned())
    } else if a.ranks > 1 {
        Some(format!("--ranks {}", a.ranks))
    } else {
        None
    };
    match a.engine.as_deref() {
        None => Ok(if conflict.is_some() {
            Engine::Bricks
        } else {
            Engine::March
        }),
        Some(s) => {
            let e: Engine = s.parse().map_err(|e: String| anyhow!("--engine: {e}"))?;
            if let (Engine::March, Some(c)) = (e, conflict) {
                bail!(
                    "--engine march renders one process without culling; it cannot be used with {c} (use --engine bricks)"
                );
            }
            Ok(e)
        }
    }
}

/// The camera turned by `degrees` about the world Y axis through its focal point (the
/// azimuth of `--view` grows by `degrees`); exact for 0.
fn orbited(cam: &Camera, degrees: f64) -> Camera {
    let (s, c) = degrees.to_radians().sin_cos();
    let turn = |v: [f64; 3]| [c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]];
    let f = cam.focal_point;
    let rel = turn([
        cam.position[0] - f[0],
        cam.position[1] - f[1],
        cam.position[2] - f[2],
    ]);
    let mut out = cam.clone();
    out.position = [f[0] + rel[0], f[1] + rel[1], f[2] + rel[2]];
    out.view_up = turn(cam.view_up);
    out
}

/// `out.png` for one frame, `out-0003.png` for frame 3 of a sequence.
fn frame_path(p: &Path, i: usize, frames: usize) -> PathBuf {
    if frames <= 1 {
        return p.to_path_buf();
    }
    let stem = p
        .file_stem()
        .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
    let name = match p.extension() {
        Some(e) => format!("{stem}-{i:04}.{}", e.to_string_lossy()),
        None => format!("{stem}-{i:04}"),
    };
    p.with_file_name(name)
}

fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// One frame: its statistics (plus the backend's fields). A sequence: `frames` (one entry
/// per frame), `frame_ms` (per-frame times), `first_frame_ms`, `median_frame_ms` (of the
/// frames after the first), `bytes_sent` (per frame, all ranks), `bytes_read` (per frame,
/// from a budgeted store) and `median_bytes_read_after_first`, plus the backend's fields.
fn stats_json(
    all: &[FrameStats],
    extra: Option<serde_json::Map<String, serde_json::Value>>,
) -> Result<serde_json::Value> {
    use serde_json::Value;
    let mut map = if let [one] = all {
        match serde_json::to_value(one)? {
            Value::Object(m) => m,
            _ => bail!("frame statistics are not a JSON object"),
        }
    } else {
        let ms: Vec<f64> = all.iter().map(|s| s.frame_ms).collect();
        let bytes: Vec<u64> = all
            .iter()
            .map(|s| s.ranks.iter().map(|r| r.bytes_sent).sum())
            .collect();
        let mut m = serde_json::Map::new();
        m.insert("frames".into(), serde_json::to_value(all)?);
        m.insert("first_frame_ms".into(), ms.first().copied().into());
        m.insert(
            "median_frame_ms".into(),
            median(&ms[1.min(ms.len())..]).into(),
        );
        m.insert("frame_ms".into(), serde_json::to_value(&ms)?);
        m.insert("bytes_sent".into(), serde_json::to_value(&bytes)?);
        // What each frame read from a budgeted store: after the first, only the bricks
        // that came into view or fell out of the cache.
        let read: Vec<u64> = all.iter().map(|s| s.bytes_read).collect();
        let mut rest = read[1.min(read.len())..].to_vec();
        rest.sort_unstable();
        m.insert("bytes_read".into(), serde_json::to_value(&read)?);
        m.insert(
            "median_bytes_read_after_first".into(),
            rest.get(rest.len() / 2).copied().into(),
        );
        m
    };
    if let Some(extra) = extra {
        map.extend(extra);
    }
    Ok(Value::Object(map))
}
