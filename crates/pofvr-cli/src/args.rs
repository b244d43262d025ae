//! Command-line flags: plain clap data (syntax only), resolved into library types in
//! `resolve.rs`.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

/// pofvr: volume rendering that knows, before it renders, which bricks can't be seen.
#[derive(Parser, Debug)]
#[command(name = "pofvr", version, about, long_about = None, propagate_version = true)]
pub(crate) struct Cli {
    #[command(subcommand)]
    pub(crate) command: Command,
    /// Worker threads (0 = one per core).
    /// > default: 0
    #[arg(long, global = true, default_value_t = 0)]
    pub(crate) threads: usize,
    /// Hide progress bars (they are hidden anyway when stderr is not a terminal).
    #[arg(long, global = true)]
    pub(crate) quiet: bool,
}

#[derive(Subcommand, Debug)]
pub(crate) enum Command {
    /// Describe a volume: dims, type, spacing, value range, histogram, bricks.
    Info(InfoArgs),
    /// Render one frame of a volume to PNG (and optionally raw float RGBA).
    Render(Box<RenderArgs>),
    /// Render the built-in smooth head phantom, shaded and coloured, to demo.png; needs no
    /// input.
    Demo(DemoArgs),
    /// Serve the interactive viewer on http://127.0.0.1:8080/.
    Serve(crate::cmd::serve::ServeArgs),
    /// Reproduce the paper's experiments on a volume: a report with plots (index.html).
    Experiment(Box<crate::cmd::experiment::ExperimentArgs>),
    /// Measure performance and write a report.
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Plenoptic Opacity Functions: build, inspect and check .pof files.
    #[command(subcommand)]
    Pof(crate::cmd::pof::PofCommand),
    /// Write any input as an OME-Zarr (Zarr v3) multiscale image, slab by slab.
    Convert(crate::cmd::convert::ConvertArgs),
}

/// Where the volume comes from.
#[derive(Args, Debug, Clone)]
pub(crate) struct VolumeArgs {
    /// Volume file (.nrrd, .nhdr, .mhd, .mha, .nii, .nii.gz, or raw with --dims/--dtype),
    /// a folder of DICOM slices (one series, see --series), a Zarr v3 array or OME-Zarr
    /// image (store.zarr, store.zarr/path/to/array; see --level), or a generated phantom: `phantom:head:N` (Shepp–Logan, u8), `phantom:smooth-head:N`
    /// (its edges blended over a few voxels, f32, a coloured family), `phantom:ml:N`
    /// (Marschner–Lobb, f32) or `phantom:body:XxYxZ` (a CT torso in HU, i16, any grid).
    pub(crate) volume: String,
    /// Raw files: voxel counts X,Y,Z.
    #[arg(long, value_name = "X,Y,Z")]
    pub(crate) dims: Option<String>,
    /// Raw files: stored type, one of u8, u16, i16, f32.
    #[arg(long)]
    pub(crate) dtype: Option<String>,
    /// Raw files: byte order, little or big.
    /// > default: little
    #[arg(long, default_value = "little")]
    pub(crate) endian: String,
    /// Raw files: voxel spacing in world units.
    /// > default: 1,1,1
    #[arg(long, value_name = "SX,SY,SZ")]
    pub(crate) spacing: Option<String>,
    /// Raw files: bytes to skip before the voxels.
    /// > default: 0
    #[arg(long, default_value_t = 0)]
    pub(crate) header_bytes: u64,
    /// Brick edge in voxels.
    /// > default: 16
    #[arg(long, default_value_t = 16)]
    pub(crate) brick: usize,
    /// DICOM folders: the SeriesInstanceUID to read when the folder holds several.
    #[arg(long, value_name = "UID")]
    pub(crate) series: Option<String>,
    /// OME-Zarr images: the level to read (0 the finest).
    /// > default: the finest level (render: the finest no larger than twice the image)
    #[arg(long, value_name = "N")]
    pub(crate) level: Option<usize>,
}

/// The transfer-function family.
#[derive(Args, Debug, Clone)]
pub(crate) struct TfArgs {
    /// Transfer-function family JSON (bases, weights, color). Phantoms have a built-in one.
    #[arg(long, value_name = "TF.json")]
    pub(crate) tf: Option<PathBuf>,
    /// Basis weights k1,k2,…, overriding the file's "weights".
    #[arg(long, value_name = "K1,K2,…")]
    pub(crate) weights: Option<String>,
}

#[derive(Args, Debug)]
pub(crate) struct InfoArgs {
    #[command(flatten)]
    pub(crate) volume: VolumeArgs,
    #[command(flatten)]
    pub(crate) tf: TfArgs,
    /// Print JSON instead of text.
    #[arg(long)]
    pub(crate) json: bool,
}

/// View and image.
#[derive(Args, Debug, Clone)]
pub(crate) struct ViewArgs {
    /// View direction around the volume centre: azimuth about +y and elevation, degrees.
    /// > default: 30,20
    #[arg(
        long,
        value_name = "AZ,EL",
        default_value = "30,20",
        allow_hyphen_values = true
    )]
    pub(crate) view: String,
    /// Camera JSON (as written by --camera-out); overrides --view, --size, --projection.
    #[arg(long, value_name = "camera.json")]
    pub(crate) camera: Option<PathBuf>,
    /// Write the exact camera used to this JSON file.
    #[arg(long, value_name = "camera.json")]
    pub(crate) camera_out: Option<PathBuf>,
    /// Image size.
    /// > default: 512x512
    #[arg(long, value_name = "WxH", default_value = "512x512")]
    pub(crate) size: String,
    /// orthographic (the paper's case) or perspective.
    /// > default: orthographic
    #[arg(long, default_value = "orthographic")]
    pub(crate) projection: String,
    /// Sample distance in units of the smallest voxel spacing.
    /// > default: 1
    #[arg(long, default_value_t = 1.0)]
    pub(crate) step: f32,
    /// Early ray termination opacity (1 disables it).
    /// > default: 0.99
    #[arg(long, default_value_t = 0.99)]
    pub(crate) ert: f32,
    /// Gradient (Lambertian, headlight) shading.
    #[arg(long)]
    pub(crate) shade: bool,
    /// Jittered ray starts: each pixel's first sample moves forward by its own fraction of
    /// a step, drawn from the pixel and SEED (the same seed gives the same image). Trades
    /// the wood-grain rings of step-edged volumes for fine noise.
    /// > default: off; SEED 0 when the flag is given alone
    #[arg(long, value_name = "SEED", num_args = 0..=1, default_missing_value = "0")]
    pub(crate) jitter: Option<u32>,
}

#[derive(Args, Debug)]
pub(crate) struct RenderArgs {
    #[command(flatten)]
    pub(crate) volume: VolumeArgs,
    #[command(flatten)]
    pub(crate) tf: TfArgs,
    #[command(flatten)]
    pub(crate) view: ViewArgs,
    /// Output PNG (8-bit RGBA, straight alpha).
    /// > default: out.png
    #[arg(long, short, default_value = "out.png")]
    pub(crate) out: PathBuf,
    /// Also write the float image: little-endian f32, W×H×4, premultiplied RGBA.
    #[arg(long, value_name = "FILE")]
    pub(crate) out_raw: Option<PathBuf>,
    /// Write frame statistics as JSON.
    #[arg(long, value_name = "FILE")]
    pub(crate) stats: Option<PathBuf>,
    /// Compare with a raw float image of the same size and print RMSE and max difference.
    #[arg(long, value_name = "FILE")]
    pub(crate) reference: Option<PathBuf>,
    #[command(flatten)]
    pub(crate) frame: FrameArgs,
    /// At most this much memory for the volume's voxels (e.g. 256M, 4G): a volume larger
    /// than that is rendered by the brick engine (the default engine then, whatever
    /// --cull), each brick it renders read on demand (raw, NRRD and MetaImage raw data:
    /// positioned reads of the file) into an LRU cache within the budget, and the bricks'
    /// value ranges measured by streaming the file once. --stats adds bytes_read,
    /// bricks_read, cache_hits, cache_peak_bytes and peak_rss_bytes. A volume that fits
    /// gets the march engine's blocked copy (1.2 × its voxels) only where both fit
    /// together. The image is the same.
    /// > default: none (the whole volume is mapped)
    #[arg(long, value_name = "SIZE")]
    pub(crate) memory_budget: Option<String>,
    /// Frames to render: an orbit about the volume's Y axis (see --orbit), so that per-frame
    /// time can be measured after start-up. With more than one frame, outputs get a
    /// `-NNNN` frame suffix and --stats holds one entry per frame.
    /// > default: 1
    #[arg(long, default_value_t = 1)]
    pub(crate) frames: usize,
    /// Azimuth step between frames in degrees (rotation about the Y axis through the focal
    /// point).
    /// > default: 0
    #[arg(
        long,
        default_value_t = 0.0,
        allow_hyphen_values = true,
        value_name = "DEG"
    )]
    pub(crate) orbit: f64,
}

/// Culling and the parallel frame.
#[derive(Args, Debug, Clone)]
pub(crate) struct FrameArgs {
    /// Culling mode: none, pof (conservative POFs), pof-set (the paper's aggressive POF
    /// sets: culls more, but an estimate, not a bound: a few pixels may break the threshold
    /// rule), exact (the sequential oracle, to measure how close POFs get) or verified
    /// (predict, verify, repair: the proxy predictor, a low-resolution copy of the volume
    /// marched per pixel, guesses; tile owners verify the guess while compositing and
    /// render what it culled wrongly, so the threshold rule always holds; no POFs needed).
    /// > default: pof when --pof is given, otherwise none
    #[arg(long)]
    pub(crate) cull: Option<String>,
    /// The predictor of --cull verified: proxy, pof, pof-set (both need --pof), previous
    /// (the bricks the previous frame needed, for --frames orbits), nothing, everything or
    /// random[:SEED] (the last three for tests).
    /// > default: proxy
    #[arg(long, value_name = "NAME")]
    pub(crate) predictor: Option<String>,
    /// Verify --cull pof or pof-set while compositing and repair what was culled wrongly
    /// (as --cull verified --predictor pof or pof-set does): the threshold rule then holds
    /// for pof-set too.
    #[arg(long)]
    pub(crate) verify: bool,
    /// Opacity at or above which a pixel hides what lies behind it.
    /// > default: 0.95
    #[arg(long, default_value_t = 0.95)]
    pub(crate) cull_threshold: f32,
    /// Ray-cast the whole volume in one pass with no bricks and no culling (the reference
    /// renderer that culled frames are checked against).
    #[arg(long, conflicts_with = "cull")]
    pub(crate) whole: bool,
    /// Renderer: march (one process, no culling: each ray walks the whole volume, skips
    /// empty space and stops at --ert; the --whole image) or bricks (the brick path that
    /// --cull, --ranks and MPI use).
    /// > default: march for one process without --cull, --pof or --ranks above 1, otherwise bricks
    #[arg(long, conflicts_with = "whole")]
    pub(crate) engine: Option<String>,
    /// Precomputed POFs (`pofvr pof build`) for --cull pof and pof-set.
    #[arg(long, value_name = "FILE.pof")]
    pub(crate) pof: Option<PathBuf>,
    /// More POFs of the same family built with other --core-length values (repeatable):
    /// each pixel of a brick gets the bound of the longest core its ray runs through, which
    /// lifts culling in oblique views, where most rays run far longer than the shortest.
    #[arg(long, value_name = "FILE.pof", requires = "pof")]
    pub(crate) pof_level: Vec<PathBuf>,
    /// Ranks to render with, as threads of this process (the paper's parallel algorithm;
    /// the frame is identical for any count).
    /// > default: 1
    #[arg(long, default_value_t = 1)]
    pub(crate) ranks: usize,
    /// Space-filling curve along which bricks are dealt to ranks: hilbert or z.
    /// > default: hilbert
    #[arg(long, default_value = "hilbert")]
    pub(crate) curve: String,
    /// How bricks are dealt to ranks: curve (the paper's: round-robin along --curve), chunks
    /// (one run of store chunks along the curve per rank, balanced by non-empty bricks, so
    /// each rank decodes only its part of a Zarr store) or auto (chunks for a Zarr level read
    /// chunk by chunk under --memory-budget whose chunks are larger than a brick, curve
    /// otherwise). The frame is the same; `--stats` says which was used (`deal`).
    /// > default: auto
    #[arg(long, default_value = "auto")]
    pub(crate) deal: String,
    /// Owners per brick: 1 (the paper) renders each visible brick on the rank it was dealt
    /// to; 2 holds every brick on two ranks and gives it, each frame, to the less loaded
    /// one (better balance for twice the brick memory). The frame is the same.
    /// > default: 1
    #[arg(long, default_value_t = 1)]
    pub(crate) replicas: usize,
}

#[derive(Args, Debug)]
pub(crate) struct DemoArgs {
    /// Phantom edge length in voxels.
    /// > default: 160
    #[arg(long, default_value_t = 160)]
    pub(crate) n: usize,
    /// Output PNG.
    /// > default: demo.png
    #[arg(long, short, default_value = "demo.png")]
    pub(crate) out: PathBuf,
}

#[derive(Subcommand, Debug)]
pub(crate) enum BenchCommand {
    /// Culling: frame time culled vs not, culling share of the frame, culled fractions per
    /// mode, per-rank load balance at 2, 8 and 32 ranks.
    Cull(BenchCullArgs),
    /// Samples per second per core of the ray caster, with and without early termination,
    /// axis-aligned and oblique, on the phantom and on given volumes.
    Render(BenchRenderArgs),
    /// Frame time of each engine, shaded and unshaded, samples per ray against the minimum,
    /// and the same frames rendered by VTK (through the peer script) in the same run.
    Frame(BenchFrameArgs),
    /// POF precompute: brick-views per second per core and bytes per brick per basis for
    /// each encoding, on the phantom and on given volumes.
    Pof(crate::cmd::pof::BenchPofArgs),
}

#[derive(Args, Debug)]
pub(crate) struct BenchRenderArgs {
    /// Extra volumes to measure (files; each needs --tf-for or uses an automatic ramp).
    pub(crate) volumes: Vec<String>,
    /// Transfer-function family for the extra volumes.
    #[arg(long, value_name = "TF.json")]
    pub(crate) tf: Option<PathBuf>,
    /// Phantom size.
    /// > default: 256
    #[arg(long, default_value_t = 256)]
    pub(crate) phantom: usize,
    /// Image size.
    /// > default: 512x512
    #[arg(long, default_value = "512x512")]
    pub(crate) size: String,
    /// Repetitions per case (the median is reported).
    /// > default: 3
    #[arg(long, default_value_t = 3)]
    pub(crate) reps: usize,
    /// Report file (JSON); a table is printed too.
    /// > default: bench-render.json
    #[arg(long, default_value = "bench-render.json")]
    pub(crate) out: PathBuf,
}

#[derive(Args, Debug)]
pub(crate) struct BenchFrameArgs {
    /// A volume to measure (repeatable): a file or a phantom spec. The i-th --tf is the
    /// i-th volume's family; volumes past the last --tf must be phantoms (built-in family).
    /// > default: phantom:head:128
    #[arg(long, value_name = "SPEC")]
    pub(crate) volume: Vec<String>,
    /// Transfer-function family of the volume in the same position (repeatable).
    #[arg(long, value_name = "TF.json")]
    pub(crate) tf: Vec<PathBuf>,
    /// A view (azimuth, elevation in degrees; repeatable).
    /// > default: 30,20 and 0,90
    #[arg(long, value_name = "AZ,EL", allow_hyphen_values = true)]
    pub(crate) view: Vec<String>,
    /// Image size.
    /// > default: 512x512
    #[arg(long, default_value = "512x512")]
    pub(crate) size: String,
    /// Repetitions per engine and frame (the median is reported).
    /// > default: 3
    #[arg(long, default_value_t = 3)]
    pub(crate) reps: usize,
    /// Python interpreter of the VTK peer (one with vtk, numpy and pillow). Without it and
    /// --peer-script, VTK is reported as not measured.
    #[arg(long, value_name = "PATH", requires = "peer_script")]
    pub(crate) peer_python: Option<PathBuf>,
    /// The VTK peer script (vtk_render.py).
    #[arg(long, value_name = "PATH", requires = "peer_python")]
    pub(crate) peer_script: Option<PathBuf>,
    /// VTK's timed re-renders per frame (the median is reported).
    /// > default: 5
    #[arg(long, default_value_t = 5)]
    pub(crate) peer_repeat: usize,
    /// Rounds per frame: every engine's --reps, then a VTK process of its own, this many
    /// times over; the table gives medians over rounds, the ratio the median of the rounds'
    /// ratios, and the JSON every round's median.
    /// > default: 1
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=100))]
    pub(crate) rounds: u16,
    /// Report file (JSON); a table is printed too.
    /// > default: bench-frame.json
    #[arg(long, default_value = "bench-frame.json")]
    pub(crate) json: PathBuf,
}

#[derive(Args, Debug)]
pub(crate) struct BenchCullArgs {
    /// Volume (culling is for occluding families: e.g. the catalogue's MRI with
    /// --tf tfs/mri-brain-opaque.json).
    /// > default: phantom:head:256
    pub(crate) volume: Option<String>,
    /// Transfer-function family.
    /// > default: the phantom's
    #[arg(long, value_name = "TF.json")]
    pub(crate) tf: Option<PathBuf>,
    /// Precomputed POFs for the pof and pof-set modes (built on the fly when absent).
    #[arg(long, value_name = "FILE.pof")]
    pub(crate) pof: Option<PathBuf>,
    /// More POFs built with other --core-length values (repeatable; see `render --pof-level`).
    #[arg(long, value_name = "FILE.pof", requires = "pof")]
    pub(crate) pof_level: Vec<PathBuf>,
    /// View (azimuth, elevation in degrees).
    /// > default: 0,0
    #[arg(long, default_value = "0,0", allow_hyphen_values = true)]
    pub(crate) view: String,
    /// Image size.
    /// > default: 512x512
    #[arg(long, default_value = "512x512")]
    pub(crate) size: String,
    /// Repetitions per case (the median is reported).
    /// > default: 3
    #[arg(long, default_value_t = 3)]
    pub(crate) reps: usize,
    /// Report file (JSON).
    /// > default: bench-cull.json
    #[arg(long, default_value = "bench-cull.json")]
    pub(crate) out: PathBuf,
    /// Also measure the culled fractions and the 32-rank balance (no timings: they are
    /// deterministic) at this many views spread evenly over the sphere, and report their
    /// mean and worst: one view can be lucky or unlucky.
    /// > default: 0 (none)
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub(crate) sweep: usize,
    /// Also cull with ideal POFs: each brick's core-footprint minimum measured by rendering
    /// it alone along the view (the tables' core lengths; slow). Between `pof` and
    /// `exact`, it tells the tables' slack from what one number per brick cannot say.
    #[arg(long)]
    pub(crate) ideal: bool,
    /// The predictor of the sweep's verified frames (see `render --predictor`): e.g. `pof`
    /// to measure the --pof tables (built with `pof build --method typical`) as predictors.
    /// > default: proxy
    #[arg(long, default_value = "proxy")]
    pub(crate) predictor: String,
    /// Goals to check the measures against and report under "targets": a JSON list of
    /// {"what", "target", "at_most"} (benches/targets/cull.json holds issue 4's).
    /// > default: none
    #[arg(long, value_name = "FILE.json")]
    pub(crate) targets: Option<PathBuf>,
}
