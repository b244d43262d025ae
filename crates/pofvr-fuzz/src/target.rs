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
        // Zarr chunks are compressed (zstd): a 30-byte frame of a valid store decodes to a
        // 512 KB chunk of zeros, so the decoded size of a valid input is not bounded by 64
        // times its length. Its reader checks what the data can bound (every chunk present,
        // uncompressed chunks exactly one chunk long) before sizing anything by the shape.
        let per_byte = if self.name == "zarr" { 1 << 14 } else { 64 };
        (16 << 20) + per_byte * (len + FIXTURE.len())
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
        name: "dicom",
        what: "one slice of a three-slice DICOM series (the middle one)",
        run: dicom,
    },
    Target {
        name: "zarr",
        what: "a Zarr v3 store (array or OME-Zarr group) packed as files, decoded whole and chunk by chunk",
        run: zarr,
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
    volume_checks(&v);
    true
}

/// The invariants of an accepted volume.
fn volume_checks(v: &Volume) {
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
    use pofvr_web::frame_adapter::CullMode;
    use pofvr_web::params::{self, FrameParams};
    // As the server decodes it (axum's Query is serde_urlencoded).
    let Ok(pairs) = serde_urlencoded::from_bytes::<Vec<(String, String)>>(d) else {
        return false;
    };
    // The server's own defaults (a two-basis family), so that the target cannot drift
    // from them.
    let defaults = FrameParams::new(vec![1.0, 1.0], CullMode::None);
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

/// The series the `dicom` target's input joins: slices 0 and 2 of an 8×8×3 body phantom in
/// HU, written once per scratch directory; the input is slice 1.
fn dicom(s: &Scratch, d: &[u8]) -> bool {
    use pofvr::volume::dicom_write::{write_series, SeriesOptions};
    let dir = s.path().join("dicom");
    if !dir.join("slice_0000.dcm").is_file() {
        let v = pofvr::volume::phantom::Phantom::Body.generate_dims([8, 8, 3]);
        let opts = SeriesOptions {
            intercept: -1024,
            ..SeriesOptions::default()
        };
        write_series(&v, &dir, &opts).expect("the DICOM fixture");
    }
    std::fs::write(dir.join("slice_0001.dcm"), d).expect("write the input");
    let Ok(v) = Volume::open_with(&dir, &pofvr::volume::OpenOptions::default()) else {
        return false;
    };
    // Slice 1 may be skipped as not DICOM: then slices 0 and 2 are a series too.
    let [x, y, z] = v.dims();
    assert!(
        [x, y] == [8, 8] && (z == 2 || z == 3),
        "8×8 slices: {:?}",
        v.dims()
    );
    volume_checks(&v);
    true
}

/// Separates the files of a `zarr` target input: each file is `PATH\n` then its bytes.
pub const ZARR_FILE_MARK: &[u8] = b"\n\x00@@file ";

/// Unpacks a `zarr` input into a fresh store folder: files separated by [`ZARR_FILE_MARK`],
/// each named by its first line (relative, plain components only). Opens the store
/// decoded whole and, under a budget of 1 byte, not decoded: then every voxel is read from
/// the chunks box by box, and both must agree.
fn zarr(s: &Scratch, d: &[u8]) -> bool {
    let root = s.path().join("store.zarr");
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).expect("store folder");
    for part in split(d, ZARR_FILE_MARK) {
        let (name, bytes) = match part.iter().position(|b| *b == b'\n') {
            Some(i) => (&part[..i], &part[i + 1..]),
            None => continue,
        };
        let Ok(name) = std::str::from_utf8(name) else {
            continue;
        };
        let plain = |c: &str| {
            !c.is_empty()
                && c != "."
                && c != ".."
                && c.bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b"._-".contains(&b))
        };
        let comps: Vec<&str> = name.split('/').collect();
        if comps.len() > 8 || !comps.iter().all(|c| plain(c)) {
            continue;
        }
        let path = root.join(name);
        if let Some(p) = path.parent() {
            if std::fs::create_dir_all(p).is_err() {
                continue;
            }
        }
        let _ = std::fs::write(&path, bytes);
    }
    let whole = Volume::open(&root, None);
    let opts = pofvr::volume::OpenOptions {
        defer_above: Some(1),
        ..pofvr::volume::OpenOptions::default()
    };
    let lazy = Volume::open_with(&root, &opts);
    let (whole, lazy) = match (whole, lazy) {
        (Ok(w), Ok(l)) => (w, l),
        // Opening checks only the metadata; a bad chunk shows when it is decoded.
        (Err(_), Ok(l)) => {
            let _ = read_all(&l);
            return false;
        }
        (Ok(_), Err(e)) => panic!("decoded whole, but not opened deferred: {e}"),
        (Err(_), Err(_)) => return false,
    };
    volume_checks(&whole);
    assert!(!lazy.is_resident());
    assert_eq!(lazy.dims(), whole.dims());
    let read = read_all(&lazy).expect("every chunk decoded whole decodes on demand");
    let same = pofvr::with_voxels!(whole.data(), v => {
        v.iter().zip(&read).all(|(a, b)| pofvr::volume::Voxel::to_f32(*a).to_bits() == b.to_bits())
    });
    assert!(
        same && read.len() == whole.data().len(),
        "chunk reads differ from the decode"
    );
    true
}

/// Every voxel of a non-resident volume, read from its chunks in bricks of 5³.
fn read_all(v: &Volume) -> Result<Vec<f32>, pofvr::volume::VolumeError> {
    let src = pofvr::store::BrickSource::of(v)?;
    if let Some(z) = src.zarr() {
        z.set_chunk_budget(1 << 20);
    }
    let d = v.dims();
    let mut out = vec![0f32; d.iter().product()];
    let b = 5;
    for z0 in (0..d[2]).step_by(b) {
        for y0 in (0..d[1]).step_by(b) {
            for x0 in (0..d[0]).step_by(b) {
                let n = [b.min(d[0] - x0), b.min(d[1] - y0), b.min(d[2] - z0)];
                let data = src.read_box(v, [x0, y0, z0], n)?;
                pofvr::with_voxels!(&data, vals => {
                    for (i, val) in vals.iter().enumerate() {
                        let (x, y, z) = (x0 + i % n[0], y0 + (i / n[0]) % n[1], z0 + i / (n[0] * n[1]));
                        out[x + d[0] * (y + d[1] * z)] = pofvr::volume::Voxel::to_f32(*val);
                    }
                });
            }
        }
    }
    Ok(out)
}

fn split<'a>(d: &'a [u8], mark: &[u8]) -> Vec<&'a [u8]> {
    let mut parts = Vec::new();
    let mut rest = d;
    while let Some(i) = rest.windows(mark.len()).position(|w| w == mark) {
        parts.push(&rest[..i]);
        rest = &rest[i + mark.len()..];
    }
    parts.push(rest);
    parts
}
