//! `pofvr.Scene` and `pofvr.open`: one volume with its bricks, family and sampling, shared
//! by every thread that renders it.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use pofvr::pof::{Encoding, PofMethod};
use pofvr::volume::RawSpec;
use pofvr::{Camera, CullMode, FrameRequest, PofBuild, Scene, TransferFunction, Volume};
use pyo3::prelude::*;

use crate::build::{self, Progress};
use crate::error::{input_error, OrPy};
use crate::frame::PyFrame;
use crate::{array, memory, options};

/// The sampling settings every scene is built with.
struct Sampling {
    brick: usize,
    step: f32,
    ert: f32,
    jitter: Option<u32>,
}

fn build_scene(volume: Volume, family: TransferFunction, s: &Sampling) -> PyResult<Scene> {
    Scene::builder(volume, family)
        .brick_size(s.brick)
        .step(s.step)
        .early_termination(s.ert)
        .jitter(s.jitter)
        .build()
        .or_py()
}

/// A volume ready to render: its bricks, transfer-function family and sampling settings,
/// and POFs once built or loaded.
///
/// ``Scene(volume, spacing=(1, 1, 1), *, tf, ...)`` borrows ``volume``, a C-contiguous
/// numpy array of shape ``(z, y, x)`` (x varies fastest, as in a raw file the command line
/// reads with ``--dims X,Y,Z``) and dtype uint8, uint16, int16 or float32 in native byte
/// order. ``spacing`` is ``(sx, sy, sz)``, the order of ``--spacing``: the reverse of the
/// array's axes. The voxels are **not copied**: the scene keeps a reference to the array
/// and marks it read-only (``volume.flags.writeable`` becomes False), since bricks, value
/// ranges and POFs are measured on its values; do not write to other views of the same
/// memory while the scene lives. Float voxels must be finite.
///
/// ``tf`` is a family JSON file's path or a dict of the same content (``bases``,
/// ``weights``, ``color``); ``weights`` overrides its default weights. ``brick``, ``step``,
/// ``ert`` and ``jitter`` are the command line's ``--brick``, ``--step``, ``--ert`` and
/// ``--jitter``.
///
/// One scene may be rendered from many threads at once: ``render`` releases the GIL.
#[pyclass(module = "pofvr", name = "Scene", frozen)]
pub(crate) struct PyScene {
    /// `None` only when attaching POFs failed after the scene was handed over (see
    /// [`PyScene::attach`]). Held only while an `Arc` is cloned or swapped, never while
    /// waiting for the GIL.
    scene: Mutex<Option<Arc<Scene>>>,
}

impl PyScene {
    fn new_from(scene: Scene) -> Self {
        PyScene {
            scene: Mutex::new(Some(Arc::new(scene))),
        }
    }

    fn get(&self) -> PyResult<Arc<Scene>> {
        self.scene
            .lock()
            .map_err(|_| input_error("the scene is unusable: a thread panicked holding it"))?
            .clone()
            .ok_or_else(|| input_error("the scene is unusable: attaching POFs to it failed"))
    }

    /// Replaces the scene with `with(scene)` once no frame holds it (frames in flight keep
    /// their own reference; this waits for them without the GIL).
    fn attach(
        &self,
        py: Python<'_>,
        with: impl FnOnce(Scene) -> pofvr::Result<Scene> + Send,
    ) -> PyResult<()> {
        let owned = py.allow_threads(|| loop {
            let mut slot = match self.scene.lock() {
                Ok(s) => s,
                Err(_) => return Err("a thread panicked holding the scene"),
            };
            let Some(arc) = slot.take() else {
                return Err("attaching POFs to it failed before");
            };
            match Arc::try_unwrap(arc) {
                Ok(scene) => return Ok(scene),
                Err(arc) => *slot = Some(arc),
            }
            drop(slot);
            std::thread::sleep(std::time::Duration::from_millis(2));
        });
        let owned = owned.map_err(|why| input_error(format!("the scene is unusable: {why}")))?;
        let scene = py.allow_threads(|| with(owned)).or_py()?;
        *self
            .scene
            .lock()
            .map_err(|_| input_error("the scene is unusable: a thread panicked holding it"))? =
            Some(Arc::new(scene));
        Ok(())
    }
}

#[pymethods]
impl PyScene {
    #[new]
    #[pyo3(signature = (volume, spacing = (1.0, 1.0, 1.0), *, tf, weights = None, brick = 16, step = 1.0, ert = 0.99, jitter = None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        volume: &Bound<'_, PyAny>,
        spacing: (f32, f32, f32),
        tf: &Bound<'_, PyAny>,
        weights: Option<Vec<f32>>,
        brick: usize,
        step: f32,
        ert: f32,
        jitter: Option<u32>,
    ) -> PyResult<Self> {
        let family = options::with_weights(options::family(tf)?, weights)?;
        let volume = array::volume(volume, [spacing.0, spacing.1, spacing.2])?;
        let s = Sampling {
            brick,
            step,
            ert,
            jitter,
        };
        let scene = py.allow_threads(|| build_scene(volume, family, &s))?;
        Ok(PyScene::new_from(scene))
    }

    /// Voxel counts ``(x, y, z)``.
    #[getter]
    fn dims(&self) -> PyResult<(usize, usize, usize)> {
        let d = self.get()?.volume().dims();
        Ok((d[0], d[1], d[2]))
    }

    /// The array shape of the volume, ``(z, y, x)``.
    #[getter]
    fn shape(&self) -> PyResult<(usize, usize, usize)> {
        let d = self.get()?.volume().dims();
        Ok((d[2], d[1], d[0]))
    }

    /// Voxel spacing ``(sx, sy, sz)``.
    #[getter]
    fn spacing(&self) -> PyResult<(f32, f32, f32)> {
        let s = self.get()?.volume().spacing();
        Ok((s[0], s[1], s[2]))
    }

    /// The stored voxel type: ``"u8"``, ``"u16"``, ``"i16"`` or ``"f32"``.
    #[getter]
    fn dtype(&self) -> PyResult<&'static str> {
        Ok(self.get()?.volume().data_type().name())
    }

    /// The names of the family's bases.
    #[getter]
    fn bases(&self) -> PyResult<Vec<String>> {
        Ok(self
            .get()?
            .family()
            .bases
            .iter()
            .map(|b| b.name.clone())
            .collect())
    }

    /// The weights a frame renders with unless given others.
    #[getter]
    fn default_weights(&self) -> PyResult<Vec<f32>> {
        Ok(self.get()?.default_weights().to_vec())
    }

    /// The number of bricks.
    #[getter]
    fn bricks(&self) -> PyResult<usize> {
        Ok(self.get()?.grid().len())
    }

    /// Whether the scene has POFs (``build_pofs`` or ``load_pofs``).
    #[getter]
    fn has_pofs(&self) -> PyResult<bool> {
        Ok(self.get()?.pofs().is_some())
    }

    /// The address of the voxels the scene reads: for a scene of a numpy array, the
    /// array's ``ctypes.data`` (no copy was made).
    #[getter]
    fn _voxel_address(&self) -> PyResult<usize> {
        let scene = self.get()?;
        Ok(pofvr::with_voxels!(scene.volume().data(), v => v.as_ptr() as usize))
    }

    /// Precomputes POFs for the scene (``pofvr pof build``) and attaches them, so that
    /// ``render(cull="pof")`` (the default once built) and ``"pof-set"`` can cull.
    ///
    /// ``views`` is the view grid (rows, columns); ``method`` ``"bound"`` or
    /// ``"sampled"``; ``encoding`` ``"table"``, ``"cubic"``...; ``sets`` builds POF sets
    /// for ``"pof-set"``. ``progress``: True shows a line on stderr, a callable is called
    /// with ``(done, total)`` bricks, False shows nothing. Releases the GIL while it
    /// builds; Ctrl-C stops it (``KeyboardInterrupt``) between bricks, the scene as before.
    #[pyo3(signature = (views = (36, 36), *, method = None, encoding = None, sets = false, core_length = None, progress = None))]
    #[allow(clippy::too_many_arguments)]
    fn build_pofs(
        &self,
        py: Python<'_>,
        views: (usize, usize),
        method: Option<&str>,
        encoding: Option<&str>,
        sets: bool,
        core_length: Option<f32>,
        progress: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let method: PofMethod = match method {
            Some(m) => options::parse("method", m)?,
            None => PofMethod::default(),
        };
        let mut b = PofBuild::for_method(method);
        b.views = [views.0, views.1];
        if let Some(e) = encoding {
            b.encoding = options::parse::<Encoding>("encoding", e)?;
        }
        b.sets = sets;
        b.core_length = core_length;
        let progress = match progress {
            None => Progress::Line,
            Some(p) if p.is_callable() => Progress::Call(p.clone()),
            Some(p) if p.is_truthy()? => Progress::Line,
            Some(_) => Progress::Quiet,
        };
        let scene = self.get()?;
        let table = build::build_pofs(py, &scene, &b, &progress)?;
        drop(scene);
        self.attach(py, move |s| s.with_pofs(table))
    }

    /// Loads POFs from a ``.pof`` file (``pofvr pof build``), checked to be for this
    /// volume, bricks, family, step and threshold, and attaches them.
    fn load_pofs(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        // Every check `with_pofs` makes is made first, on the scene still shared: handing
        // the scene over to a check that fails would lose it.
        let scene = self.get()?;
        let table = py
            .allow_threads(|| pofvr::pof::PofTable::open(&path))
            .or_py()?;
        table
            .check_matches(scene.volume(), scene.grid(), scene.family())
            .or_py()?;
        for (what, in_file, own) in [
            ("sample step", table.step(), scene.step()),
            (
                "early-termination threshold",
                table.ert(),
                scene.early_termination(),
            ),
        ] {
            if in_file != own {
                return Err(input_error(format!(
                    "{}: built for a different {what}: file has {in_file}, expected {own}",
                    path.display()
                )));
            }
        }
        drop(scene);
        self.attach(py, move |s| s.with_pofs(table))
    }

    /// Renders one frame.
    ///
    /// The camera orbits the volume's centre at ``view`` = (azimuth, elevation) degrees
    /// with an image of ``size`` = (width, height) pixels, or is ``camera``, a dict as
    /// ``Frame.camera`` and ``--camera-out`` give (then ``view``, ``size`` and
    /// ``projection`` are not read). ``weights`` (one per basis) replace the defaults;
    /// ``shade`` lights gradients. ``cull`` is ``"none"``, ``"exact"``, ``"pof"`` or
    /// ``"pof-set"`` (default: ``"pof"`` when the scene has POFs, else ``"none"``);
    /// ``whole=True`` ray-casts the whole volume in one pass (``--whole``). ``threshold``,
    /// ``ranks``, ``curve``, ``replicas`` and ``engine`` are ``--cull-threshold``,
    /// ``--ranks``, ``--curve``, ``--replicas`` and ``--engine``. ``threads`` renders on a
    /// pool of that many threads of its own (default: the shared pool, one thread per
    /// core), e.g. 1 for one frame per Python thread. The GIL is released while rendering.
    #[pyo3(signature = (view = (30.0, 20.0), size = (512, 512), *, camera = None, projection = "orthographic", weights = None, shade = false, cull = None, whole = false, threshold = 0.95, ranks = 1, curve = "hilbert", replicas = 1, engine = None, threads = None))]
    #[allow(clippy::too_many_arguments)]
    fn render(
        &self,
        py: Python<'_>,
        view: (f64, f64),
        size: (u32, u32),
        camera: Option<&Bound<'_, PyAny>>,
        projection: &str,
        weights: Option<Vec<f32>>,
        shade: bool,
        cull: Option<&str>,
        whole: bool,
        threshold: f32,
        ranks: usize,
        curve: &str,
        replicas: usize,
        engine: Option<&str>,
        threads: Option<usize>,
    ) -> PyResult<PyFrame> {
        let scene = self.get()?;
        let cam = match camera {
            Some(c) => options::camera(c)?,
            None => {
                let (az, el) = options::view(view)?;
                let (w, h) = options::size(size)?;
                let projection = options::projection(projection)?;
                Camera::orbit(scene.volume(), az, el, w, h, projection)
            }
        };
        if whole && (cull.is_some() || engine.is_some()) {
            return Err(input_error(
                "whole: the whole-volume pass neither culls nor takes an engine; leave out cull and engine",
            ));
        }
        let mode = cull.map(options::cull).transpose()?;
        let engine = engine.map(options::engine).transpose()?;
        let curve = options::curve(curve)?;
        if threads == Some(0) {
            return Err(input_error("threads: got 0, expected at least 1"));
        }
        let frame = py.allow_threads(|| {
            let cull = match mode {
                None => scene.default_cull(),
                Some(m) => scene.cull(m).ok_or_else(|| {
                    format!(
                        "cull: {} needs POFs: call build_pofs() or load_pofs() first",
                        m.name()
                    )
                })?,
            };
            if mode == Some(CullMode::PofSet) && !scene.pofs().is_some_and(|p| p.has_sets()) {
                return Err("cull: pof-set needs POFs built with sets=True".to_owned());
            }
            let mut req = FrameRequest::new(&cam)
                .shade(shade)
                .cull(cull)
                .threshold(threshold)
                .ranks(ranks)
                .curve(curve)
                .replicas(replicas);
            if let Some(w) = &weights {
                req = req.weights(w);
            }
            if let Some(e) = engine {
                req = req.engine(e);
            }
            let go = || {
                if whole {
                    scene.render_reference(&req)
                } else {
                    scene.render(&req)
                }
            };
            let result = match threads {
                None => go(),
                Some(n) => rayon::ThreadPoolBuilder::new()
                    .num_threads(n)
                    .build()
                    .map_err(|e| format!("threads: {e}"))?
                    .install(go),
            };
            Ok(result)
        });
        let frame = frame.map_err(input_error)?.or_py()?;
        let (image, stats) = frame.into_parts();
        let mut json =
            serde_json::to_value(&stats).map_err(|e| input_error(format!("statistics: {e}")))?;
        if let serde_json::Value::Object(m) = &mut json {
            m.insert("memory".into(), memory::status_json());
        }
        Ok(PyFrame::new(image, json.to_string(), cam))
    }

    fn __repr__(&self) -> PyResult<String> {
        let s = self.get()?;
        let d = s.volume().dims();
        Ok(format!(
            "<pofvr.Scene {} ({}, {}, {}) {} from {}, {} bricks, bases {:?}{}>",
            s.volume().data_type(),
            d[2],
            d[1],
            d[0],
            "(z, y, x)",
            s.volume().source(),
            s.grid().len(),
            s.sampled().names(),
            if s.pofs().is_some() { ", POFs" } else { "" }
        ))
    }
}

/// Opens a volume file as a scene (what ``pofvr render VOLUME`` reads): ``.nrrd``,
/// ``.nhdr``, ``.mhd``, ``.mha``, ``.nii``, ``.nii.gz``; a raw file with ``dims=(x, y, z)``
/// and ``dtype`` (and ``spacing=(sx, sy, sz)``, ``endian``, ``header_bytes``); or a
/// phantom ``"phantom:head:N"``, ``"phantom:smooth-head:N"``, ``"phantom:ml:N"``. The file
/// is memory-mapped where its layout allows. ``tf`` (a path or a dict) is required but for
/// phantoms, which have their own. The other arguments are as ``Scene``'s.
#[pyfunction]
#[pyo3(signature = (path, tf = None, *, weights = None, brick = 16, step = 1.0, ert = 0.99, jitter = None, dims = None, dtype = None, spacing = None, endian = "little", header_bytes = 0))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn open(
    py: Python<'_>,
    path: &Bound<'_, PyAny>,
    tf: Option<&Bound<'_, PyAny>>,
    weights: Option<Vec<f32>>,
    brick: usize,
    step: f32,
    ert: f32,
    jitter: Option<u32>,
    dims: Option<(usize, usize, usize)>,
    dtype: Option<&str>,
    spacing: Option<(f32, f32, f32)>,
    endian: &str,
    header_bytes: u64,
) -> PyResult<PyScene> {
    let spec: PathBuf = path.extract()?;
    let name = spec.to_string_lossy().into_owned();
    let phantom = options::phantom(&name)?;
    let family = match (tf, phantom) {
        (Some(t), _) => options::family(t)?,
        (None, Some((kind, _))) => options::phantom_family(kind),
        (None, None) => {
            return Err(input_error(format!(
                "tf: a family (a JSON file's path or a dict) is required for {name} (phantoms have a built-in one)"
            )))
        }
    };
    let family = options::with_weights(family, weights)?;
    let raw = match (dims, dtype) {
        (None, None) => None,
        (Some(d), Some(t)) => {
            let mut r = RawSpec::new([d.0, d.1, d.2], options::parse("dtype", t)?);
            r.endian = options::parse("endian", endian)?;
            if let Some(s) = spacing {
                r.spacing = [s.0, s.1, s.2];
            }
            r.offset = header_bytes;
            Some(r)
        }
        _ => {
            return Err(input_error(
                "raw volumes need both dims=(x, y, z) and dtype (u8, u16, i16 or f32)",
            ))
        }
    };
    if raw.is_none() && spacing.is_some() {
        return Err(input_error(
            "spacing: only raw volumes (dims and dtype given) take a spacing; headers carry their own",
        ));
    }
    let s = Sampling {
        brick,
        step,
        ert,
        jitter,
    };
    let scene = py.allow_threads(|| {
        let volume = match phantom {
            Some((kind, n)) => kind.generate(n),
            None => Volume::open(&spec, raw.as_ref()).map_err(pofvr::Error::from)?,
        };
        Ok::<_, pofvr::Error>(volume)
    });
    let volume = scene.or_py()?;
    let scene = py.allow_threads(|| build_scene(volume, family, &s))?;
    Ok(PyScene::new_from(scene))
}
