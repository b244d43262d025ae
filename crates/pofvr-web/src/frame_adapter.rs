//! The one file that knows how the library renders a frame.
//!
//! The library's culling frame path (`pofvr::frame::render_frame` with `CullMode`,
//! `FrameOptions`, `BrickCounts`, `RankStats`, POF tables) is being written in parallel. Until
//! it lands, this module mirrors its types and renders through the reference ray caster,
//! the same two calls as `pofvr::frame::render_reference`, with no culling: every cull mode
//! gives the unculled image and `culled == 0`. The rest of the crate uses only what this
//! module exports, so switching to the real frame path changes this file alone.
//!
//! Weights and shading are per frame, while `render_reference` reads them from the job:
//! building the classifier per frame keeps one shared, immutable `RenderJob` per volume, so
//! clients with different weights render concurrently without cloning the volume.

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Instant;

use pofvr::brick::BrickId;
use pofvr::frame::RenderJob;
use pofvr::render::{Camera, Image, RayCaster, RenderSettings};
use serde::Serialize;

/// Whether this build culls bricks; `false` while frames go through the reference path.
pub const CULLING_AVAILABLE: bool = false;

/// How bricks are culled before ray casting (mirrors the library's coming `CullMode`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum CullMode {
    /// Render every non-empty brick.
    None,
    /// Cull with per-brick plenoptic opacity functions.
    Pof,
    /// Cull with POFs of brick sets.
    PofSet,
    /// Cull with exact (brute-force) occlusion: the slow reference.
    Exact,
}

impl CullMode {
    /// Every mode, in the order the page lists them.
    pub const ALL: [CullMode; 4] = [
        CullMode::None,
        CullMode::Pof,
        CullMode::PofSet,
        CullMode::Exact,
    ];

    /// The name used in URLs and on the command line.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            CullMode::None => "none",
            CullMode::Pof => "pof",
            CullMode::PofSet => "pof-set",
            CullMode::Exact => "exact",
        }
    }
}

impl fmt::Display for CullMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for CullMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        CullMode::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!("unknown cull mode {s:?}, expected none, pof, pof-set or exact"))
    }
}

/// Per-frame options of the frame path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameOptions {
    /// Culling strategy.
    pub cull: CullMode,
    /// Accumulated opacity above which what lies behind counts as occluded.
    pub cull_threshold: f32,
    /// In-process ranks.
    pub ranks: usize,
}

impl Default for FrameOptions {
    fn default() -> Self {
        FrameOptions {
            cull: CullMode::None,
            cull_threshold: 0.95,
            ranks: 1,
        }
    }
}

/// What changes per frame besides the camera and the options: the look of the volume.
#[derive(Clone, Debug, PartialEq)]
pub struct Look {
    /// One weight per basis, already validated against the family.
    pub weights: Vec<f32>,
    /// Gradient shading.
    pub shade: bool,
}

/// Brick counts of one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct BrickCounts {
    /// Bricks in the grid.
    pub total: usize,
    /// Bricks empty under the frame's weights.
    pub empty: usize,
    /// `total - empty`.
    pub non_empty: usize,
    /// Non-empty bricks culled as occluded.
    pub culled: usize,
    /// Bricks ray cast: `non_empty - culled`.
    pub visible: usize,
}

/// Figures of one rank in one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct RankStats {
    /// The rank.
    pub rank: usize,
    /// Bricks it ray cast.
    pub bricks_rendered: usize,
    /// Samples it took.
    pub samples: u64,
    /// Milliseconds spent culling.
    pub cull_ms: f64,
    /// Milliseconds spent ray casting.
    pub raycast_ms: f64,
    /// Milliseconds spent compositing.
    pub composite_ms: f64,
    /// Milliseconds spent in communication.
    pub comm_ms: f64,
    /// Bytes it sent to other ranks.
    pub bytes_sent: u64,
}

/// Figures of one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct FrameStats {
    /// Wall time of the frame in milliseconds.
    pub frame_ms: f64,
    /// Rays that met the volume.
    pub rays: u64,
    /// Samples taken.
    pub samples: u64,
    /// `samples / frame time`.
    pub samples_per_second: f64,
    /// Brick counts.
    pub bricks: BrickCounts,
    /// Per-rank figures.
    pub ranks: Vec<RankStats>,
    /// The bricks culled, for the footprint overlay.
    #[serde(skip)]
    pub culled_bricks: Vec<BrickId>,
}

/// A frame could not be rendered.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FrameError {
    /// The camera does not define a view.
    #[error("camera: {0}")]
    Camera(String),
}

/// Precomputed plenoptic opacity functions, as the frame path will read them.
///
/// Until the library's POF table lands this only records a checked, readable file, so
/// that `--pof` fails at start-up rather than at the first frame.
#[derive(Debug)]
pub struct Pofs {
    path: PathBuf,
}

impl Pofs {
    /// The file the table came from.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Opens a POF file for `job`.
///
/// # Errors
/// A message naming the file when it cannot be read.
pub fn load_pofs(path: &Path, _job: &RenderJob) -> Result<Pofs, String> {
    let meta = std::fs::metadata(path).map_err(|e| format!("--pof {}: {e}", path.display()))?;
    if !meta.is_file() {
        return Err(format!("--pof {}: not a regular file", path.display()));
    }
    std::fs::File::open(path).map_err(|e| format!("--pof {}: {e}", path.display()))?;
    Ok(Pofs {
        path: path.to_path_buf(),
    })
}

/// Renders one frame of `job` seen by `camera` with the per-frame `look` and `opts`.
///
/// # Errors
/// [`FrameError`] when the camera is unusable.
pub fn render_frame(
    job: &RenderJob,
    _pofs: Option<&Pofs>,
    camera: &Camera,
    _opts: &FrameOptions,
    look: &Look,
) -> Result<(Image, FrameStats), FrameError> {
    // The reference path neither culls nor splits work into ranks, so `opts` has no
    // effect until the library's frame path replaces it.
    camera
        .validate("camera")
        .map_err(|e| FrameError::Camera(e.to_string()))?;
    let start = Instant::now();
    let total = job.grid.len();
    let empty = job
        .grid
        .ranges()
        .iter()
        .filter(|r| job.sampled.is_empty(**r, &look.weights))
        .count();
    let settings = RenderSettings {
        shade: look.shade,
        ..job.settings
    };
    let cls = job.sampled.classify(&look.weights, settings.step);
    let t_cast = Instant::now();
    let (image, st) = RayCaster::new(&job.volume, &cls, settings).render(camera);
    let raycast_ms = t_cast.elapsed().as_secs_f64() * 1e3;
    let seconds = start.elapsed().as_secs_f64();
    #[allow(clippy::cast_precision_loss)]
    let samples_per_second = if seconds > 0.0 {
        st.samples as f64 / seconds
    } else {
        0.0
    };
    let non_empty = total - empty;
    let stats = FrameStats {
        frame_ms: seconds * 1e3,
        rays: st.rays,
        samples: st.samples,
        samples_per_second,
        bricks: BrickCounts {
            total,
            empty,
            non_empty,
            culled: 0,
            visible: non_empty,
        },
        ranks: vec![RankStats {
            rank: 0,
            bricks_rendered: non_empty,
            samples: st.samples,
            raycast_ms,
            ..RankStats::default()
        }],
        culled_bricks: Vec::new(),
    };
    Ok((image, stats))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cull_mode_names_round_trip_and_unknown_is_an_error() {
        for m in CullMode::ALL {
            assert_eq!(m.name().parse::<CullMode>(), Ok(m));
        }
        let e = "pofset".parse::<CullMode>().unwrap_err();
        assert!(e.contains("pof-set"), "{e}");
    }
}
