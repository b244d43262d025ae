//! The one file that knows how the library renders a frame.
//!
//! Frames go through `pofvr::frame::render_frame`, the same path as `pofvr render`. That
//! function reads the weights and shading from the `RenderJob`, while the viewer changes
//! them per frame and per client; [`SharedJob`] bridges the two. Frames whose look matches
//! the job's render concurrently under a read lock; a frame with another look takes the
//! write lock, re-weights the job (cheap: the weights and one flag) and renders while
//! holding it, so it can never see weights changed under it. When `render_frame` takes the
//! weights per call, [`SharedJob::render`] becomes a plain call and the lock goes away.
//!
//! Modes `pof` and `pof-set` need a [`Pofs`]: a POF file ([`load_pofs`]) or, in tests, the
//! library's range bound.

use std::path::Path;
use std::sync::{PoisonError, RwLock, RwLockReadGuard};

use pofvr::frame::{render_frame, RenderJob};
use pofvr::render::{Camera, Image};

pub use pofvr::cull::{CullMode, OpacityBound};
pub use pofvr::frame::{BrickCounts, FrameError, FrameOptions, FrameStats, RankStats};

/// Every cull mode, in the order the page lists them.
pub const CULL_MODES: [CullMode; 4] = [
    CullMode::None,
    CullMode::Pof,
    CullMode::PofSet,
    CullMode::Exact,
];

/// Per-brick opacity bounds that the POF cull modes read.
pub type Pofs = Box<dyn OpacityBound + Send>;

/// Opens a POF file for `job`, checked against its volume, bases, step and early
/// termination.
///
/// # Errors
/// A message naming the file and what does not match.
pub fn load_pofs(path: &Path, job: &RenderJob) -> Result<Pofs, String> {
    job.load_pofs(path)
        .map(|t| Box::new(t) as Pofs)
        .map_err(|e| e.to_string())
}

/// Loads a POF file and further levels of it built with other core lengths
/// ([`pofvr::cull::CoreLevels`]).
///
/// # Errors
/// A message naming the file and what does not match, or two levels of one core length.
pub fn load_pof_levels(
    path: &Path,
    levels: &[std::path::PathBuf],
    job: &RenderJob,
) -> Result<Pofs, String> {
    job.load_pof_levels(path, levels)
        .map(|l| Box::new(l) as Pofs)
        .map_err(|e| e.to_string())
}

/// What changes per frame besides the camera and the options: the look of the volume.
#[derive(Clone, Debug, PartialEq)]
pub struct Look {
    /// One weight per basis, already validated against the family.
    pub weights: Vec<f32>,
    /// Gradient shading.
    pub shade: bool,
}

/// A render job shared by every request, re-weighted per frame as needed.
pub struct SharedJob {
    job: RwLock<RenderJob>,
}

impl SharedJob {
    /// Shares `job`.
    #[must_use]
    pub fn new(job: RenderJob) -> Self {
        SharedJob {
            job: RwLock::new(job),
        }
    }

    /// Read access to the job (its volume, grid and family do not change).
    pub fn read(&self) -> RwLockReadGuard<'_, RenderJob> {
        // A panic inside a render leaves the job whole: weights and shading are replaced
        // in one assignment each, before rendering starts.
        self.job.read().unwrap_or_else(PoisonError::into_inner)
    }

    /// Renders one frame seen by `camera` with `look` and `opts`.
    ///
    /// # Errors
    /// [`FrameError`] from the frame path (a POF mode without `pofs`, a bad threshold).
    pub fn render(
        &self,
        pofs: Option<&Pofs>,
        camera: &Camera,
        opts: &FrameOptions,
        look: &Look,
    ) -> Result<(Image, FrameStats), FrameError> {
        let bounds = pofs.map(|p| p.as_ref() as &dyn OpacityBound);
        {
            let job = self.read();
            if job.tf.weights == look.weights && job.settings.shade == look.shade {
                return render_frame(&job, bounds, camera, opts);
            }
        }
        let mut job = self.job.write().unwrap_or_else(PoisonError::into_inner);
        job.tf.weights.clone_from(&look.weights);
        job.settings.shade = look.shade;
        render_frame(&job, bounds, camera, opts)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pofvr::render::{families, Projection, RenderSettings};
    use pofvr::volume::phantom::Phantom;

    fn job() -> RenderJob {
        let vol = Phantom::SheppLogan.generate(32);
        let tf = families::for_phantom(Phantom::SheppLogan);
        RenderJob::new(vol, tf, 16, RenderSettings::default()).unwrap()
    }

    #[test]
    fn the_look_of_each_frame_is_the_one_asked_for() {
        let shared = SharedJob::new(job());
        let cam = Camera::orbit(
            &shared.read().volume,
            30.0,
            20.0,
            24,
            24,
            Projection::Orthographic,
        );
        let opts = FrameOptions {
            cull: CullMode::None,
            ..FrameOptions::default()
        };
        let a = Look {
            weights: vec![1.0, 1.0],
            shade: false,
        };
        let b = Look {
            weights: vec![0.0, 1.0],
            shade: true,
        };
        let (ia, _) = shared.render(None, &cam, &opts, &a).unwrap();
        let (ib, _) = shared.render(None, &cam, &opts, &b).unwrap();
        let (ia2, _) = shared.render(None, &cam, &opts, &a).unwrap();
        assert_eq!(ia.pixels(), ia2.pixels());
        assert_ne!(ia.pixels(), ib.pixels());
        let mut direct = job();
        direct.tf.weights = b.weights.clone();
        direct.settings.shade = true;
        let (ib_direct, _) = render_frame(&direct, None, &cam, &opts).unwrap();
        assert_eq!(ib.pixels(), ib_direct.pixels());
    }

    #[test]
    fn pof_modes_without_pofs_are_an_error() {
        let shared = SharedJob::new(job());
        let cam = Camera::orbit(
            &shared.read().volume,
            0.0,
            0.0,
            8,
            8,
            Projection::Orthographic,
        );
        let look = Look {
            weights: vec![1.0, 1.0],
            shade: false,
        };
        let opts = FrameOptions {
            cull: CullMode::Pof,
            ..FrameOptions::default()
        };
        assert!(shared.render(None, &cam, &opts, &look).is_err());
        let Err(e) = load_pofs(Path::new("missing.pof"), &shared.read()) else {
            panic!("a missing POF file must be an error");
        };
        assert!(e.contains("missing.pof"), "{e}");
    }

    #[test]
    fn pof_levels_load_in_order_and_name_a_bad_file() {
        use pofvr::pof::{PofSettings, PofTable};
        let j = job();
        let dir = std::env::temp_dir().join(format!("pofvr-web-levels-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let save = |core: f32, name: &str| {
            let settings = PofSettings {
                views: [4, 4],
                core_length: Some(core),
                ..PofSettings::default()
            };
            let t = PofTable::build(&j.volume, &j.grid, &j.tf, &j.sampled, &settings, &|_, _| {})
                .unwrap();
            let p = dir.join(name);
            t.save(&p).unwrap();
            p
        };
        let (a, b) = (save(8.0, "a.pof"), save(12.0, "b.pof"));
        let levels = load_pof_levels(&b, std::slice::from_ref(&a), &j).unwrap();
        // The shortest core comes first, the longer one as the deeper level.
        assert_eq!(levels.core_length(), 8.0);
        assert_eq!(levels.deeper(0).map(OpacityBound::core_length), Some(12.0));
        let Err(e) = load_pof_levels(&a, std::slice::from_ref(&a), &j) else {
            panic!("two levels of one core length must be an error");
        };
        assert!(e.contains("core length 8"), "{e}");
        let Err(e) = load_pof_levels(&a, &[dir.join("missing.pof")], &j) else {
            panic!("a missing level must be an error");
        };
        assert!(e.contains("missing.pof"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
