//! `pofvr pof build|info|check` and `pofvr bench pof`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use clap::{Args, Subcommand};
use pofvr::brick::BrickGrid;
use pofvr::check::{audit_table, AuditSummary};
use pofvr::pof::{build_streamed, Encoding, PofMethod, PofSettings, PofTable};
use pofvr::pof_measure::{build_timed, cell_opacities, process_cpu_seconds, TimedBuild};
use pofvr::render::{families, SampledTf, TransferFunction};
use pofvr::volume::{DataType, RawSpec, Volume};
use serde::Serialize;

use crate::args::{TfArgs, VolumeArgs};
use crate::progress::Ui;
use crate::resolve;

/// `pofvr pof …`
#[derive(Subcommand, Debug)]
pub(crate) enum PofCommand {
    /// Precompute the POFs of every brick for a transfer-function family into a .pof file.
    Build(PofBuildArgs),
    /// Print what a .pof file holds.
    Info(PofInfoArgs),
    /// Render random views of random bricks by brute force and count views where the POF
    /// lookup exceeds the true core-footprint minimum; exits non-zero if there is any.
    Check(PofCheckArgs),
    /// Rewrite a .pof file of an older format (version 3 or before) with cell-major records,
    /// which culling reads faster (one cache line per lookup); the values are unchanged.
    Upgrade(PofUpgradeArgs),
}

/// Knobs of the precompute shared by `pof build` and `bench pof`.
#[derive(Args, Debug, Clone)]
pub(crate) struct PofKnobs {
    /// How cell values are obtained: `bound` (a rigorous lower bound, fast, loose),
    /// `sampled` (the ray caster's samples measured on a ray grid and kept at --margin: an
    /// empirical bound, verified with `pofvr pof check`) or `typical` (a low quantile of the
    /// non-empty core rays' depths at each cell's centre: a predictor for `--cull verified`,
    /// not a bound; the cheapest build).
    /// > default: bound
    #[arg(long, default_value = "bound")]
    pub(crate) method: String,
    /// Sample views over (θ, φ), rows × columns.
    /// > default: 36,36
    #[arg(long, value_name = "N,M", default_value = "36,36")]
    pub(crate) views: String,
    /// Sample distance the POFs bound, in units of the smallest voxel spacing (must match
    /// the renderer's --step).
    /// > default: 1
    #[arg(long, default_value_t = 1.0)]
    pub(crate) step: f32,
    /// Early ray termination threshold lookups are capped at (the renderer's --ert).
    /// > default: 0.99
    #[arg(long, default_value_t = 0.99)]
    pub(crate) ert: f32,
    /// Core length L in units of the smallest spacing: the POF bounds rays running at least
    /// this far inside a brick. Files built with longer cores (e.g. 14 for 16³ bricks) add
    /// tighter bounds for long rays as `render --pof-level`.
    /// > default: half the brick size
    #[arg(long, value_name = "L")]
    pub(crate) core_length: Option<f32>,
    /// Entry-face patch size of the bound, or spacing of the sampled and typical methods'
    /// rays, in voxels.
    /// > default: 0.5 (bound), 1 (sampled), 3 (typical)
    #[arg(long)]
    pub(crate) pitch: Option<f32>,
    /// Lattice phases per ray of the sampled and typical methods, evenly spread over a step.
    /// > default: 2 (sampled), 1 (typical)
    #[arg(long)]
    pub(crate) phases: Option<usize>,
    /// Measured directions per view-cell edge.
    /// > default: 2 (bound, sampled), 1 (typical: the cell's centre)
    #[arg(long)]
    pub(crate) subdiv: Option<usize>,
    /// Share of the measured optical depth kept for directions (and, sampled, ray positions
    /// and phases) between the measured ones.
    /// > default: 0.9 (bound), 0.7 (sampled), 1 (typical)
    #[arg(long)]
    pub(crate) margin: Option<f32>,
    /// Leave out the joint POF (the whole family at the file's weights, which lifts the
    /// bound where bases take turns along a ray; stored for 2 to 16 bases).
    #[arg(long)]
    pub(crate) no_joint: bool,
}

impl PofKnobs {
    fn settings(&self, encoding: Encoding, sets: bool) -> Result<PofSettings> {
        let v = resolve::parse_list::<usize>("--views", &self.views, Some(2))?;
        let method: PofMethod = self
            .method
            .parse()
            .map_err(|e: String| anyhow!("--method: {e}"))?;
        if method == PofMethod::Bound && self.phases.is_some() {
            bail!("--phases applies to --method sampled only (the bound covers every phase)");
        }
        let d = PofSettings::for_method(method);
        Ok(PofSettings {
            method,
            views: [v[0], v[1]],
            encoding,
            sets,
            step: self.step,
            ert: self.ert,
            core_length: self.core_length,
            pitch: self.pitch.unwrap_or(d.pitch),
            phases: self.phases.unwrap_or(d.phases),
            subdiv: self.subdiv.unwrap_or(d.subdiv),
            margin: self.margin.unwrap_or(d.margin),
            joint: !self.no_joint,
        })
    }
}

#[derive(Args, Debug)]
pub(crate) struct PofBuildArgs {
    #[command(flatten)]
    pub(crate) volume: VolumeArgs,
    #[command(flatten)]
    pub(crate) tf: TfArgs,
    /// Output .pof file.
    #[arg(long, short, value_name = "FILE.pof")]
    pub(crate) out: PathBuf,
    /// Storage: table (f32), u8, u16 (rounded down) or cubic (10 coefficients).
    /// > default: table
    #[arg(long, default_value = "table")]
    pub(crate) encoding: String,
    /// Also store POF sets (aggressive multi-basis mode).
    #[arg(long)]
    pub(crate) sets: bool,
    #[command(flatten)]
    pub(crate) knobs: PofKnobs,
    /// Start afresh instead of resuming from FILE.pof.partial.
    #[arg(long)]
    pub(crate) no_resume: bool,
    /// At most this much memory for the volume's voxels and the table (e.g. 256M, 4G): the
    /// volume is read once, one slab of bricks at a time (raw, NRRD and MetaImage raw data
    /// by positioned reads, Zarr by its chunks, half the budget for decoded chunks), and
    /// the records are written to the file as each slab finishes instead of held. The file
    /// is the same byte for byte. A budgeted build keeps no FILE.pof.partial: interrupted,
    /// it starts afresh.
    /// > default: none (the whole volume is mapped and the table built in memory)
    #[arg(long, value_name = "SIZE")]
    pub(crate) memory_budget: Option<String>,
}

#[derive(Args, Debug)]
pub(crate) struct PofInfoArgs {
    /// The .pof file.
    pub(crate) file: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub(crate) json: bool,
}

#[derive(Args, Debug)]
pub(crate) struct PofUpgradeArgs {
    /// The .pof file to read.
    pub(crate) file: PathBuf,
    /// Where to write the upgraded file (may be FILE itself: written to a temp file, then
    /// renamed).
    #[arg(short, long)]
    pub(crate) output: PathBuf,
}

#[derive(Args, Debug)]
pub(crate) struct PofCheckArgs {
    #[command(flatten)]
    pub(crate) volume: VolumeArgs,
    #[command(flatten)]
    pub(crate) tf: TfArgs,
    /// The .pof file to check.
    #[arg(long, value_name = "FILE.pof")]
    pub(crate) pof: PathBuf,
    /// Number of random brute-force views.
    /// > default: 200
    #[arg(long, default_value_t = 200)]
    pub(crate) views: usize,
    /// Random seed.
    /// > default: 1
    #[arg(long, default_value_t = 1)]
    pub(crate) seed: u64,
}

#[derive(Args, Debug)]
pub(crate) struct BenchPofArgs {
    /// Extra volumes: files the volume readers open, or catalogue raw files named
    /// `NAME_XxYxZ_TYPE.raw` (dims and type read from the name).
    pub(crate) volumes: Vec<String>,
    /// Transfer-function family for the extra volumes (an automatic ramp otherwise).
    #[arg(long, value_name = "TF.json")]
    pub(crate) tf: Option<PathBuf>,
    /// Phantom size (Shepp–Logan head with its built-in family).
    /// > default: 128
    #[arg(long, default_value_t = 128)]
    pub(crate) phantom: usize,
    #[command(flatten)]
    pub(crate) knobs: PofKnobs,
    /// Report file (JSON); a table is printed too.
    /// > default: bench-pof.json
    #[arg(long, default_value = "bench-pof.json")]
    pub(crate) out: PathBuf,
}

pub(crate) fn run(cmd: &PofCommand, ui: &Ui) -> Result<()> {
    match cmd {
        PofCommand::Build(a) => build(a, ui),
        PofCommand::Info(a) => info(a),
        PofCommand::Check(a) => check(a, ui),
        PofCommand::Upgrade(a) => upgrade(a),
    }
}

/// Builds the table with a progress bar labelled `label`, timed.
pub(crate) fn build_table(
    vol: &Volume,
    grid: &BrickGrid,
    tf: &TransferFunction,
    settings: &PofSettings,
    partial: Option<&Path>,
    ui: &Ui,
    label: &str,
) -> Result<TimedBuild> {
    let bar = ui.bar(0, label);
    let built = build_timed(vol, grid, tf, settings, partial, &|done, n| {
        bar.set_length(n);
        bar.set_position(done);
    })?;
    bar.finish_and_clear();
    Ok(built)
}

/// The audit of `table` over `views` brute-force views from `seed`, with a progress bar.
fn check_table(
    vol: &Volume,
    grid: &BrickGrid,
    tf: &TransferFunction,
    table: &PofTable,
    views: usize,
    seed: u64,
    ui: &Ui,
) -> Result<AuditSummary> {
    let bar = ui.bar(views as u64, "brute-force views");
    let s = audit_table(vol, grid, tf, table, views, seed, &|_, _| bar.inc(1))?;
    bar.finish_and_clear();
    Ok(s)
}

fn build(a: &PofBuildArgs, ui: &Ui) -> Result<()> {
    let budget = super::render::memory_budget(a.memory_budget.as_deref())?;
    let encoding: Encoding = a
        .encoding
        .parse()
        .map_err(|e: String| anyhow!("--encoding: {e}"))?;
    let settings = a.knobs.settings(encoding, a.sets)?;
    let sp = ui.spinner("opening and bricking the volume");
    // Under a budget a Zarr level is not decoded, and the ranges are streamed from the file.
    let vol = resolve::volume_deferring(&a.volume, None, budget)?;
    let tf = resolve::required_tf(&a.tf, &a.volume.volume)?;
    let grid = pofvr::store::grid_for(&vol, a.volume.brick, budget)?;
    sp.finish_and_clear();
    if let Some(b) = budget {
        return build_within(a, ui, &vol, &grid, &tf, &settings, b);
    }
    let partial = PathBuf::from(format!("{}.partial", a.out.display()));
    if a.no_resume {
        let _ = std::fs::remove_file(&partial);
    }
    let built = build_table(&vol, &grid, &tf, &settings, Some(&partial), ui, "POFs")?;
    built.table.save(&a.out)?;
    // The table is safely on disk: the resume file has served its purpose.
    let _ = std::fs::remove_file(&partial);
    eprintln!(
        "{}: {} method, {} of {} bricks stored ({} non-empty computed), {} views, {} encoding, {:.0} bytes per brick per basis, {} bytes; {:.2} s, {:.0} brick-views/s per core",
        a.out.display(),
        settings.method,
        built.table.stored_bricks(),
        grid.len(),
        built.computed_bricks,
        settings.views[0] * settings.views[1],
        encoding,
        built.table.bytes_per_brick_per_basis(),
        built.table.file_len(),
        built.seconds,
        built.brick_views_per_core_second()
    );
    method_note(settings.method, &a.out);
    Ok(())
}

/// `pof build --memory-budget`: the volume streamed slab by slab, the table streamed out.
fn build_within(
    a: &PofBuildArgs,
    ui: &Ui,
    vol: &Volume,
    grid: &BrickGrid,
    tf: &TransferFunction,
    settings: &PofSettings,
    budget: u64,
) -> Result<()> {
    let source = pofvr::store::BrickSource::of(vol)?;
    // A Zarr level's decoded chunks take half the budget, the slabs and records the rest.
    let slabs = match source.zarr() {
        Some(z) => {
            z.set_chunk_budget(budget / 2);
            budget - budget / 2
        }
        None => budget,
    };
    let sampled = SampledTf::new(tf, grid.value_range());
    let bar = ui.bar(0, "POFs (streamed)");
    let t0 = Instant::now();
    let cpu0 = process_cpu_seconds();
    let r = build_streamed(
        vol,
        &source,
        grid,
        tf,
        &sampled,
        settings,
        slabs,
        &a.out,
        &|done, n| {
            bar.set_length(n);
            bar.set_position(done);
        },
    )?;
    bar.finish_and_clear();
    let seconds = t0.elapsed().as_secs_f64();
    let cpu = process_cpu_seconds().zip(cpu0).map(|(b, a)| b - a);
    let views = settings.views[0] * settings.views[1];
    let core_seconds = cpu
        .filter(|c| *c > 0.0)
        .unwrap_or(seconds * rayon::current_num_threads() as f64);
    eprintln!(
        "{}: {} method, {} of {} bricks stored ({} non-empty computed), {} views, {} encoding, {:.0} bytes per brick per basis, {} bytes; {:.2} s ({:.1} s CPU), {:.0} brick-views/s per core",
        a.out.display(),
        settings.method,
        r.stored_bricks,
        grid.len(),
        r.computed_bricks,
        views,
        settings.encoding,
        settings
            .encoding
            .function_bytes(settings.views.map(|v| v as u32)),
        r.file_bytes,
        seconds,
        cpu.unwrap_or(f64::NAN),
        r.computed_bricks as f64 * views as f64 / core_seconds.max(1e-9),
    );
    eprintln!(
        "memory budget {:.1} MB ({}): {} slabs read, {:.1} MB read ({:.0} % of the volume's {:.1} MB), largest slab with its records {:.1} MB, peak RSS {:.1} MB",
        budget as f64 / 1e6,
        source.kind(),
        r.slabs_read,
        r.bytes_read as f64 / 1e6,
        100.0 * r.bytes_read as f64 / pofvr::store::volume_bytes(vol).max(1) as f64,
        pofvr::store::volume_bytes(vol) as f64 / 1e6,
        r.slab_peak_bytes as f64 / 1e6,
        pofvr::store::peak_rss_bytes() as f64 / 1e6,
    );
    method_note(settings.method, &a.out);
    Ok(())
}

/// What to do with a table that measures rather than bounds.
fn method_note(method: PofMethod, out: &Path) {
    if method == PofMethod::Sampled {
        eprintln!(
            "note: the sampled method measures rather than bounds; before culling with {}, \
             run `pofvr pof check` on this volume (it exits non-zero if a lookup exceeds \
             the brute-force minimum)",
            out.display()
        );
    }
    if method == PofMethod::Typical {
        eprintln!(
            "note: typical POFs predict rather than bound; cull with them as \
             `--cull verified --predictor pof --pof {}` (or `--cull pof --verify`)",
            out.display()
        );
    }
}

#[derive(Serialize)]
struct InfoJson {
    file: String,
    dims: [u64; 3],
    dtype: String,
    brick_size: u32,
    bricks: u32,
    stored_bricks: usize,
    bases: u32,
    bases_fingerprint: String,
    range_hash: String,
    views: [u32; 2],
    encoding: String,
    sets: bool,
    step: f32,
    ert: f32,
    core_length: f32,
    margin: f32,
    pitch: f32,
    subdiv: u32,
    method: String,
    phases: u32,
    /// Anchor weights of the joint POF (null when the file has none).
    joint: Option<Vec<f32>>,
    bytes_per_brick_per_basis: f64,
    /// Everything stored per non-empty brick (POFs, sets, joint POF).
    bytes_per_brick: usize,
    file_bytes: usize,
    /// "cell-major" (format 4) or "function-major" (older formats, and the cubic).
    layout: &'static str,
}

fn info(a: &PofInfoArgs) -> Result<()> {
    let t = PofTable::open(&a.file)?;
    let m = t.meta();
    let j = InfoJson {
        file: a.file.display().to_string(),
        dims: m.dims,
        dtype: m.dtype.to_string(),
        brick_size: m.brick_size,
        bricks: m.brick_count,
        stored_bricks: t.stored_bricks(),
        bases: m.basis_count,
        bases_fingerprint: format!("{:016x}", m.bases_fingerprint),
        range_hash: format!("{:016x}", m.range_hash),
        views: m.views,
        encoding: m.encoding.to_string(),
        sets: m.sets,
        step: m.step,
        ert: m.ert,
        core_length: m.core_length,
        margin: m.margin,
        pitch: m.pitch,
        subdiv: m.subdiv,
        method: m.method.to_string(),
        phases: m.phases,
        joint: m.joint.clone(),
        bytes_per_brick_per_basis: t.bytes_per_brick_per_basis(),
        bytes_per_brick: t.bytes_per_brick(),
        file_bytes: t.file_len(),
        layout: if m.cell_major {
            "cell-major"
        } else {
            "function-major"
        },
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&j)?);
        return Ok(());
    }
    println!("file        {}  ({} bytes, CRCs ok)", j.file, j.file_bytes);
    println!(
        "volume      {}×{}×{} {}, bricks of {} ({} bricks, {} stored), value-range hash {}",
        m.dims[0],
        m.dims[1],
        m.dims[2],
        j.dtype,
        j.brick_size,
        j.bricks,
        j.stored_bricks,
        j.range_hash
    );
    println!(
        "family      {} bases, fingerprint {}",
        j.bases, j.bases_fingerprint
    );
    if let Some(a) = &m.joint {
        println!("joint       the family at weights {a:?} (scaled to any weights at lookup)");
    }
    println!(
        "method      {}",
        match m.method {
            PofMethod::Bound => "bound (a rigorous lower bound)".to_string(),
            PofMethod::Sampled => format!(
                "sampled (measured on rays {} voxels apart at {} lattice phases: an empirical bound)",
                m.pitch, m.phases
            ),
            PofMethod::Typical => format!(
                "typical (a low quantile of the non-empty core rays' depths, rays {} voxels apart: \
                 a predictor for --cull verified, not a bound)",
                m.pitch
            ),
        }
    );
    println!(
        "views       {}×{} (θ × φ), {} measured directions per cell edge, margin {}",
        m.views[0], m.views[1], m.subdiv, m.margin
    );
    println!(
        "sampling    step {}, ert {}, core length L {}, {} {}",
        m.step,
        m.ert,
        m.core_length,
        match m.method {
            PofMethod::Bound => "patch pitch",
            PofMethod::Sampled | PofMethod::Typical => "ray pitch",
        },
        m.pitch
    );
    println!(
        "encoding    {}{}, {:.0} bytes per brick per basis, {} bytes per stored brick, {} records",
        j.encoding,
        if m.sets { " with POF sets" } else { "" },
        j.bytes_per_brick_per_basis,
        j.bytes_per_brick,
        j.layout
    );
    if !m.cell_major && m.encoding != pofvr::pof::Encoding::Cubic {
        println!(
            "            (an older format: `pofvr pof upgrade` rewrites it for faster culling)"
        );
    }
    Ok(())
}

fn upgrade(a: &PofUpgradeArgs) -> Result<()> {
    let t = PofTable::open(&a.file)?;
    let m = t.meta();
    let up = t.relayout(true);
    up.save(&a.output)?;
    println!(
        "{}: {} {} records, {} stored bricks -> {} ({})",
        a.file.display(),
        m.encoding,
        if m.cell_major {
            "cell-major"
        } else {
            "function-major"
        },
        t.stored_bricks(),
        a.output.display(),
        if up.meta().cell_major {
            "cell-major"
        } else {
            "function-major: the cubic keeps each function's coefficients together"
        }
    );
    Ok(())
}

fn check(a: &PofCheckArgs, ui: &Ui) -> Result<()> {
    let vol = resolve::volume(&a.volume)?;
    let tf = resolve::required_tf(&a.tf, &a.volume.volume)?;
    let grid = BrickGrid::from_volume(&vol, a.volume.brick)?;
    let table = PofTable::load(&a.pof, &vol, &grid, &tf)?;
    let s = check_table(&vol, &grid, &tf, &table, a.views, a.seed, ui)?;
    println!(
        "{}: {} views ({} with a core), {} where the lookup exceeds the brute-force core minimum (worst by {:.2e}); mean lookup {:.4}, mean true minimum {:.4}; core pixels {:.1}% of the footprint",
        a.pof.display(),
        s.views,
        s.with_core,
        s.violations,
        s.worst_excess,
        s.mean_lookup,
        s.mean_true_min,
        100.0 * s.core_share
    );
    if s.violations > 0 {
        bail!(
            "{}: {} of {} views are not conservative",
            a.pof.display(),
            s.violations,
            s.with_core
        );
    }
    Ok(())
}

/// Opens a volume for the benchmark: a reader's file, or a catalogue raw file whose name
/// carries its dims and type.
fn bench_volume(spec: &str) -> Result<Volume> {
    let path = Path::new(spec);
    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("");
    if path.extension().and_then(|e| e.to_str()) == Some("raw") {
        let parts: Vec<&str> = stem.rsplitn(3, '_').collect();
        if parts.len() == 3 {
            let dtype: DataType = match parts[0] {
                "uint8" => DataType::U8,
                "uint16" => DataType::U16,
                "int16" => DataType::I16,
                "float32" => DataType::F32,
                other => other.parse().map_err(|e: String| anyhow!("{spec}: {e}"))?,
            };
            let dims = resolve::parse_list::<usize>(
                "dims in the file name",
                &parts[1].replace('x', ","),
                Some(3),
            )?;
            return Ok(pofvr::volume::raw::open(
                path,
                &RawSpec::new([dims[0], dims[1], dims[2]], dtype),
            )?);
        }
    }
    Ok(Volume::open(path, None)?)
}

#[derive(Serialize)]
struct EncodingReport {
    encoding: String,
    bytes_per_brick_per_basis: usize,
}

#[derive(Serialize)]
struct VolumeReport {
    volume: String,
    dims: [usize; 3],
    bricks: usize,
    computed_bricks: u64,
    stored_bricks: usize,
    views: [usize; 2],
    seconds: f64,
    cpu_seconds: Option<f64>,
    threads: usize,
    brick_views_per_core_second: f64,
    mean_pof: f64,
    share_of_brick_views_at_least_half: f64,
    encodings: Vec<EncodingReport>,
    check: AuditSummary,
}

pub(crate) fn bench(a: &BenchPofArgs, ui: &Ui) -> Result<()> {
    let mut cases: Vec<(String, Volume, TransferFunction)> = Vec::new();
    let ph = pofvr::volume::phantom::Phantom::SheppLogan;
    cases.push((
        format!("phantom:head:{}", a.phantom),
        ph.generate(a.phantom),
        families::for_phantom(ph),
    ));
    for v in &a.volumes {
        let vol = bench_volume(v).with_context(|| format!("bench pof: {v}"))?;
        let tf = match &a.tf {
            Some(p) => TransferFunction::from_file(p)?,
            None => {
                let g = BrickGrid::from_volume(&vol, 16)?;
                families::auto_ramp(g.value_range())
            }
        };
        cases.push((v.clone(), vol, tf));
    }
    let settings = a.knobs.settings(Encoding::Table, false)?;
    let mut reports = Vec::new();
    println!(
        "{:<48} {:>8} {:>9} {:>8} {:>14} {:>9}  bytes/brick/basis (table u8 u16 cubic)",
        "volume", "bricks", "computed", "secs", "brick-views/s", "mean POF"
    );
    for (name, vol, tf) in &cases {
        let grid = BrickGrid::from_volume(vol, 16)?;
        let built = build_table(vol, &grid, tf, &settings, None, ui, name)?;
        let t = &built.table;
        // How much the table can cull: its lookups over every non-empty brick and view cell.
        let cells = cell_opacities(t, &grid, tf);
        let views32 = settings.views.map(|v| u32::try_from(v).unwrap_or(u32::MAX));
        let encodings = Encoding::ALL
            .iter()
            .map(|e| EncodingReport {
                encoding: e.to_string(),
                bytes_per_brick_per_basis: e.function_bytes(views32),
            })
            .collect::<Vec<_>>();
        let check = check_table(vol, &grid, tf, t, 100, 7, ui)?;
        let r = VolumeReport {
            volume: name.clone(),
            dims: vol.dims(),
            bricks: grid.len(),
            computed_bricks: built.computed_bricks,
            stored_bricks: t.stored_bricks(),
            views: settings.views,
            seconds: built.seconds,
            cpu_seconds: built.cpu_seconds,
            threads: built.threads,
            brick_views_per_core_second: built.brick_views_per_core_second(),
            mean_pof: cells.mean,
            share_of_brick_views_at_least_half: cells.share_at_least_half,
            encodings,
            check,
        };
        println!(
            "{:<48} {:>8} {:>9} {:>8.2} {:>14.0} {:>9.3}  {}  (check: {} of {} views above the brute-force minimum)",
            r.volume,
            r.bricks,
            r.computed_bricks,
            r.seconds,
            r.brick_views_per_core_second,
            r.mean_pof,
            r.encodings.iter().map(|e| e.bytes_per_brick_per_basis.to_string()).collect::<Vec<_>>().join(" "),
            r.check.violations,
            r.check.with_core
        );
        reports.push(r);
    }
    let json = serde_json::to_string_pretty(
        &serde_json::json!({ "bench": "pof", "settings": format!("{settings:?}"), "volumes": reports }),
    )?;
    pofvr::io::write_bytes_atomic(&a.out, json.as_bytes())?;
    eprintln!("report: {}", a.out.display());
    Ok(())
}
