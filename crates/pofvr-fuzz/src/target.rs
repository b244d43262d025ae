//! The fuzz targets: one per parser of outside input, each taking `&[u8]`.
//!
//! A target returns normally whether the parser accepts or rejects the input; a panic
//! (including a broken invariant of an accepted input, checked here) is a finding.

use std::path::{Path, PathBuf};

use pofvr::brick::ValueRange;
use pofvr::pof::PofTable;
use pofvr::render::{Camera, SampledTf, TransferFunction};
use pofvr::volume::Volume;

/// The voxels detached headers in the corpus name (`d.raw`, and gzipped as `d.raw.gz`):
/// 4³ bytes.
const FIXTURE: [u8; 64] = {
    let mut a = [0u8; 64];
    let mut i = 0;
    while i < 64 {
        a[i] = i as u8;
        i += 1;
    }
    a
};

/// A directory holding the fixture data files and the current input.
pub struct Scratch {
    dir: tempfile::TempDir,
}

impl Scratch {
    /// A fresh directory with `d.raw` and `d.raw.gz`, in memory (`/dev/shm`) where there is
    /// one: every file-format input is written to a file.
    ///
    /// # Panics
    /// When the directory or its files cannot be made.
    #[must_use]
    pub fn new() -> Self {
        let shm = Path::new("/dev/shm");
        let dir = if shm.is_dir() {
            tempfile::tempdir_in(shm)
        } else {
            tempfile::tempdir()
        }
        .expect("scratch directory");
        std::fs::write(dir.path().join("d.raw"), FIXTURE).expect("fixture");
        std::fs::write(dir.path().join("d.raw.gz"), gzip(&FIXTURE)).expect("fixture");
        Scratch { dir }
    }

    /// The directory.
    #[must_use]
    pub fn path(&self) -> &Path {
        self.dir.path()
    }

    fn write(&self, name: &str, data: &[u8]) -> PathBuf {
        let p = self.dir.path().join(name);
        std::fs::write(&p, data).expect("write the input");
        p
    }
}

impl Default for Scratch {
    fn default() -> Self {
        Self::new()
    }
}

fn gzip(data: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(data).expect("gzip in memory");
    e.finish().expect("gzip in memory")
}

/// One fuzz target.
pub struct Target {
    /// Its name: the corpus folder and the runner's argument.
    pub name: &'static str,
    /// What it feeds.
    pub what: &'static str,
    run: fn(&Scratch, &[u8]) -> bool,
}

impl Target {
    /// Feeds one input; true when the parser accepted it.
    pub fn run(&self, scratch: &Scratch, data: &[u8]) -> bool {
        (self.run)(scratch, data)
    }

    /// The seed corpus folder of this target under `root`.
    #[must_use]
    pub fn corpus(&self, root: &Path) -> PathBuf {
        root.join(self.name)
    }

    /// The largest single allocation an input of `len` bytes justifies: its own size many
    /// times over (decoded voxels widen to f32, tables per value bin) plus a floor for the
    /// fixed-size tables every parse builds. A header that claims more voxels than its
    /// data can hold must fail before allocating for them.
    #[must_use]
    pub fn allocation_limit(&self, len: usize) -> usize {
        (16 << 20) + 64 * (len + FIXTURE.len())
    }
}

/// Every target.
pub const TARGETS: &[Target] = &[
    Target {
        name: "nrrd",
        what: "NRRD with attached data (raw, gzip, byte/line skip, endian)",
        run: |s, d| volume(&s.write("in.nrrd", d)),
    },
    Target {
        name: "nhdr",
        what: "detached NRRD headers (data file, gzip data file, LIST)",
        run: |s, d| volume(&s.write("in.nhdr", d)),
    },
    Target {
        name: "mha",
        what: "MetaImage with LOCAL data (raw and compressed)",
        run: |s, d| volume(&s.write("in.mha", d)),
    },
    Target {
        name: "mhd",
        what: "detached MetaImage headers",
        run: |s, d| volume(&s.write("in.mhd", d)),
    },
    Target {
        name: "nifti",
        what: "NIfTI-1 single files (.nii, and .nii.gz when the input is gzip)",
        run: |s, d| {
            let name = if d.starts_with(&[0x1f, 0x8b]) {
                "in.nii.gz"
            } else {
                "in.nii"
            };
            volume(&s.write(name, d))
        },
    },
    Target {
        name: "pof",
        what: "the .pof file",
        run: |s, d| {
            let Ok(t) = PofTable::open(&s.write("in.pof", d)) else {
                return false;
            };
            assert!(t.core_length().is_finite() && t.step().is_finite());
            let _ = t.meta();
            true
        },
    },
    Target {
        name: "tf",
        what: "the transfer-function family JSON",
        run: |_, d| tf(d),
    },
    Target {
        name: "camera",
        what: "the camera JSON",
        run: |_, d| camera(d),
    },
    Target {
        name: "query",
        what: "the viewer's /api/frame query string",
        run: |_, d| query(d),
    },
];

/// The target called `name`.
#[must_use]
pub fn by_name(name: &str) -> Option<&'static Target> {
    TARGETS.iter().find(|t| t.name == name)
}

fn volume(path: &Path) -> bool {
    let Ok(v) = Volume::open(path, None) else {
        return false;
    };
    let [x, y, z] = v.dims();
    assert!(x > 0 && y > 0 && z > 0, "accepted dims {:?}", v.dims());
    assert_eq!(v.data().len(), x * y * z, "voxel count of {:?}", v.dims());
    assert!(
        v.spacing().iter().all(|s| s.is_finite() && *s > 0.0),
        "accepted spacing {:?}",
        v.spacing()
    );
    // Every voxel can be read where the renderer reads it.
    let _ = (v.value(0, 0, 0), v.value(x - 1, y - 1, z - 1));
    assert!(v.world_extent().iter().all(|e| e.is_finite()));
    true
}

fn tf(d: &[u8]) -> bool {
    let Ok(tf) = TransferFunction::from_json(&String::from_utf8_lossy(d), "fuzz") else {
        return false;
    };
    // An accepted family samples to finite extinctions over any finite domain.
    for (min, max) in [(0.0, 1.0), (-1e30, 1e30), (5.0, 5.0)] {
        let s = SampledTf::new(&tf, ValueRange { min, max });
        for b in 0..s.basis_count() {
            assert!(s.tau_table(b).iter().all(|t| t.is_finite() && *t >= 0.0));
        }
        let c = s.classify(&tf.weights, 1.0).sample(min);
        assert!(c.iter().all(|x| x.is_finite()), "{c:?}");
    }
    true
}

fn camera(d: &[u8]) -> bool {
    let Ok(cam) = Camera::from_json(&String::from_utf8_lossy(d), "fuzz") else {
        return false;
    };
    // An accepted camera gives finite unit rays through every pixel.
    let f = cam.frame();
    for (x, y) in [
        (0.5, 0.5),
        (f64::from(cam.width) - 0.5, f64::from(cam.height) - 0.5),
    ] {
        let r = cam.ray(&f, x, y);
        assert!(
            r.origin.is_finite() && r.dir.is_finite() && (r.dir.length() - 1.0).abs() < 1e-6,
            "{cam:?}: {r:?}"
        );
    }
    true
}

fn query(d: &[u8]) -> bool {
    use pofvr_web::frame_adapter::{CullMode, FrameOptions, Look};
    use pofvr_web::params::{self, FrameParams};
    // As the server decodes it (axum's Query is serde_urlencoded).
    let Ok(pairs) = serde_urlencoded::from_bytes::<Vec<(String, String)>>(d) else {
        return false;
    };
    let defaults = FrameParams {
        azimuth: 30.0,
        elevation: 20.0,
        zoom: 1.0,
        width: 512,
        height: 512,
        projection: pofvr::render::Projection::Orthographic,
        look: Look {
            weights: vec![1.0, 1.0],
            shade: false,
        },
        options: FrameOptions {
            cull: CullMode::None,
            ..FrameOptions::default()
        },
        overlay: false,
        client: "default".into(),
        seq: 0,
    };
    let Ok(p) = params::parse(&pairs, &defaults) else {
        return false;
    };
    assert!(p.azimuth.is_finite() && (-90.0..=90.0).contains(&p.elevation));
    assert!(p.zoom.is_finite() && p.zoom > 0.0);
    assert!(
        (1..=params::MAX_SIDE).contains(&p.width) && (1..=params::MAX_SIDE).contains(&p.height)
    );
    assert_eq!(p.look.weights.len(), 2);
    assert!(p.look.weights.iter().all(|w| w.is_finite() && *w >= 0.0));
    assert!(p.options.cull_threshold > 0.0 && p.options.cull_threshold <= 1.0);
    assert!(!p.client.is_empty() && p.client.len() <= params::MAX_CLIENT_ID);
    true
}
