//! The VTK peer: the same frame rendered by VTK's CPU ray caster through the peer script
//! (`vtk_render.py`), given pofvr's own camera JSON and family, in the same run.
//!
//! The script is an outside program: every way it can fail (no interpreter, no VTK, a
//! crash, output it did not write) is reported as the reason the frame was not measured,
//! never as a number.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde::Serialize;

use crate::render::{Camera, Image, TransferFunction};
use crate::volume::{Volume, VoxelData};

use super::npy;

/// How to run the peer.
#[derive(Clone, Debug)]
pub struct VtkPeer {
    /// The Python interpreter that has vtk, numpy and pillow.
    pub python: PathBuf,
    /// `vtk_render.py`.
    pub script: PathBuf,
    /// The mapper's threads.
    pub threads: usize,
    /// Timed re-renders (the median is reported); the first render builds VTK's tables and
    /// is reported apart.
    pub repeat: usize,
}

/// One frame as VTK rendered it.
#[derive(Clone, Debug, Serialize)]
pub struct VtkFrame {
    /// The VTK version the script reported.
    pub vtk: Option<String>,
    /// Median re-render time.
    pub median_ms: f64,
    /// The first render (includes building the mapper's tables).
    pub first_render_ms: Option<f64>,
    /// VTK's own float ray-cast image (premultiplied RGBA, rows top first).
    #[serde(skip)]
    pub image: Image,
}

/// A volume written once as the raw file the script reads, removed on drop.
pub struct PeerVolume {
    dir: PathBuf,
    raw: PathBuf,
    dims: [usize; 3],
    dtype: &'static str,
    spacing: [f32; 3],
}

impl Drop for PeerVolume {
    fn drop(&mut self) {
        // A leftover temporary folder is harmless; nothing to report.
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

impl PeerVolume {
    /// Writes `volume`'s voxels (x fastest, little-endian) into a fresh temporary folder.
    ///
    /// # Errors
    /// A message when the folder or the file cannot be written.
    pub fn write(volume: &Volume, tag: usize) -> Result<Self, String> {
        let dir =
            std::env::temp_dir().join(format!("pofvr-bench-frame-{}-{tag}", std::process::id()));
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let raw = dir.join("volume.raw");
        let bytes: Vec<u8> = match volume.data() {
            VoxelData::U8(v) => v.as_slice().to_vec(),
            VoxelData::U16(v) => v.as_slice().iter().flat_map(|x| x.to_le_bytes()).collect(),
            VoxelData::I16(v) => v.as_slice().iter().flat_map(|x| x.to_le_bytes()).collect(),
            VoxelData::F32(v) => v.as_slice().iter().flat_map(|x| x.to_le_bytes()).collect(),
        };
        let pv = PeerVolume {
            dir,
            raw,
            dims: volume.dims(),
            dtype: volume.data_type().name(),
            spacing: volume.spacing(),
        };
        std::fs::write(&pv.raw, bytes).map_err(|e| format!("{}: {e}", pv.raw.display()))?;
        Ok(pv)
    }
}

impl VtkPeer {
    /// Renders `camera`'s frame of `vol` with `family` at `weights`, shaded or not.
    ///
    /// # Errors
    /// Why the frame was not measured: the script's own message where it printed one.
    pub fn render(
        &self,
        vol: &PeerVolume,
        family: &TransferFunction,
        weights: &[f32],
        camera: &Camera,
        shade: bool,
    ) -> Result<VtkFrame, String> {
        let d = &vol.dir;
        let (tf, cam, npy_path, json, png) = (
            d.join("tf.json"),
            d.join("camera.json"),
            d.join("vtk.npy"),
            d.join("vtk.json"),
            d.join("vtk.png"),
        );
        for p in [&npy_path, &json] {
            let _ = std::fs::remove_file(p);
        }
        let mut family = family.clone();
        family.weights = weights.to_vec();
        let tf_text = serde_json::to_string(&family).map_err(|e| e.to_string())?;
        std::fs::write(&tf, tf_text).map_err(|e| format!("{}: {e}", tf.display()))?;
        std::fs::write(&cam, camera.to_json()).map_err(|e| format!("{}: {e}", cam.display()))?;
        let mut cmd = Command::new(&self.python);
        cmd.arg(&self.script)
            .arg("--raw")
            .arg(&vol.raw)
            .arg("--dims")
            .args(vol.dims.map(|x| x.to_string()))
            .args(["--dtype", vol.dtype, "--spacing"])
            .args(vol.spacing.map(|x| x.to_string()))
            .arg("--tf")
            .arg(&tf)
            .arg("--camera")
            .arg(&cam)
            .args(["--threads", &self.threads.to_string()])
            .args(["--repeat", &self.repeat.max(1).to_string()])
            .arg("--out")
            .arg(&png)
            .arg("--out-npy")
            .arg(&npy_path)
            .arg("--json")
            .arg(&json)
            .arg("--quiet");
        if shade {
            cmd.arg("--shade");
        }
        let out = cmd
            .output()
            .map_err(|e| format!("cannot run {}: {e}", self.python.display()))?;
        if !out.status.success() {
            let err = String::from_utf8_lossy(&out.stderr);
            let last = err
                .lines()
                .rev()
                .find(|l| !l.trim().is_empty())
                .unwrap_or("");
            return Err(format!(
                "{} failed ({}): {last}",
                self.script.display(),
                out.status
            ));
        }
        let info: serde_json::Value = read(&json).and_then(|b| {
            serde_json::from_slice(&b).map_err(|e| format!("{}: {e}", json.display()))
        })?;
        let median = info["median_rerender_s"]
            .as_f64()
            .ok_or_else(|| format!("{}: no median_rerender_s", json.display()))?;
        let image = npy::read_rgba_f32(&read(&npy_path)?)
            .map_err(|e| format!("{}: {e}", npy_path.display()))?;
        Ok(VtkFrame {
            vtk: info["vtk"].as_str().map(str::to_owned),
            median_ms: median * 1e3,
            first_render_ms: info["first_render_s"].as_f64().map(|s| s * 1e3),
            image,
        })
    }
}

fn read(p: &Path) -> Result<Vec<u8>, String> {
    std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()))
}
