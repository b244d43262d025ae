//! Turns parsed flags into library values, with errors that name the flag or file.

use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};
use pofvr::render::families;
use pofvr::render::{Camera, Projection, RenderSettings, TransferFunction};
use pofvr::volume::phantom::Phantom;
use pofvr::volume::{OpenOptions, RawSpec, Volume};

use crate::args::{TfArgs, ViewArgs, VolumeArgs};

/// Parses `a,b,c` into numbers, naming the flag on error.
pub(crate) fn parse_list<T: std::str::FromStr>(
    flag: &str,
    s: &str,
    n: Option<usize>,
) -> Result<Vec<T>> {
    let v: Vec<T> = s
        .split(',')
        .map(|x| {
            x.trim()
                .parse::<T>()
                .map_err(|_| anyhow!("{flag}: {x:?} is not a number (in {s:?})"))
        })
        .collect::<Result<_>>()?;
    if let Some(n) = n {
        if v.len() != n {
            bail!(
                "{flag}: expected {n} comma-separated values, got {} in {s:?}",
                v.len()
            );
        }
    }
    Ok(v)
}

/// A phantom named `phantom:KIND:N` (or `phantom:body:XxYxZ`), if `spec` is one: its kind
/// and grid.
pub(crate) fn phantom_spec(spec: &str) -> Result<Option<(Phantom, [usize; 3])>> {
    let Some(rest) = spec.strip_prefix("phantom:") else {
        return Ok(None);
    };
    let mut parts = rest.split(':');
    let kind: Phantom = parts
        .next()
        .unwrap_or("head")
        .parse()
        .map_err(|e: String| anyhow!("{spec}: {e}"))?;
    let dims = match parts.next() {
        Some(n) if n.contains(['x', 'X']) => {
            if !kind.any_grid() {
                bail!("{spec}: this phantom is a cube: give one size N (only phantom:body takes XxYxZ)");
            }
            let d: Vec<usize> = n
                .split(['x', 'X'])
                .map(|d| d.parse::<usize>())
                .collect::<Result<_, _>>()
                .map_err(|_| anyhow!("{spec}: size {n:?} is not XxYxZ"))?;
            if d.len() != 3 {
                bail!("{spec}: size {n:?} is not XxYxZ");
            }
            [d[0], d[1], d[2]]
        }
        Some(n) => {
            [n.parse::<usize>()
                .map_err(|_| anyhow!("{spec}: size {n:?} is not a number"))?; 3]
        }
        None => [128; 3],
    };
    if dims.iter().any(|n| !(2..=2048).contains(n)) {
        bail!("{spec}: phantom size must be 2..=2048");
    }
    Ok(Some((kind, dims)))
}

/// Opens the volume named by the flags.
pub(crate) fn volume(a: &VolumeArgs) -> Result<Volume> {
    volume_for(a, None)
}

/// Opens the volume named by the flags; an OME-Zarr image without `--level` is read at the
/// finest level no larger than `max_dim` voxels on any axis, when given.
pub(crate) fn volume_for(a: &VolumeArgs, max_dim: Option<usize>) -> Result<Volume> {
    volume_deferring(a, max_dim, None)
}

/// [`volume_for`], except that a Zarr level of more than `defer_above` bytes (the memory
/// budget) is not decoded: a brick store decodes its chunks on demand.
pub(crate) fn volume_deferring(
    a: &VolumeArgs,
    max_dim: Option<usize>,
    defer_above: Option<u64>,
) -> Result<Volume> {
    if let Some((kind, dims)) = phantom_spec(&a.volume)? {
        return Ok(kind.generate_dims(dims));
    }
    let path = Path::new(&a.volume);
    let raw = match (&a.dims, &a.dtype) {
        (None, None) => None,
        (Some(d), Some(t)) => {
            let dims = parse_list::<usize>("--dims", d, Some(3))?;
            let mut spec = RawSpec::new(
                [dims[0], dims[1], dims[2]],
                t.parse().map_err(|e: String| anyhow!("--dtype: {e}"))?,
            );
            spec.endian = a
                .endian
                .parse()
                .map_err(|e: String| anyhow!("--endian: {e}"))?;
            if let Some(s) = &a.spacing {
                let s = parse_list::<f32>("--spacing", s, Some(3))?;
                spec.spacing = [s[0], s[1], s[2]];
            }
            spec.offset = a.header_bytes;
            Some(spec)
        }
        _ => bail!("raw volumes need both --dims X,Y,Z and --dtype u8|u16|i16|f32"),
    };
    let is_raw = raw.is_some();
    let opts = OpenOptions {
        raw,
        series: a.series.clone(),
        level: a.level,
        max_dim,
        defer_above,
    };
    match Volume::open_with(path, &opts) {
        // Raw spacing comes from the flag; a header's spacing is the file's own fault.
        Err(e @ pofvr::volume::VolumeError::BadSpacing { .. }) if is_raw => {
            Err(anyhow::Error::new(e).context("--spacing"))
        }
        r => Ok(r?),
    }
}

/// The family: the file, the phantom's built-in one, or `None` when neither applies.
pub(crate) fn tf(a: &TfArgs, volume_spec: &str) -> Result<Option<TransferFunction>> {
    let mut tf = match (&a.tf, phantom_spec(volume_spec)?) {
        (Some(p), _) => TransferFunction::from_file(p)?,
        (None, Some((kind, _))) => families::for_phantom(kind),
        (None, None) => return Ok(None),
    };
    if let Some(w) = &a.weights {
        tf.set_weights(parse_list::<f32>("--weights", w, None)?)?;
    }
    Ok(Some(tf))
}

/// Like [`tf`] but a family is required.
pub(crate) fn required_tf(a: &TfArgs, volume_spec: &str) -> Result<TransferFunction> {
    tf(a, volume_spec)?.ok_or_else(|| anyhow!("--tf TF.json is required for {volume_spec} (phantoms have a built-in family; see tfs/ for examples)"))
}

/// `WxH`.
pub(crate) fn size(s: &str) -> Result<(u32, u32)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| anyhow!("--size: expected WxH, got {s:?}"))?;
    let w: u32 = w
        .parse()
        .map_err(|_| anyhow!("--size: width {w:?} is not a number"))?;
    let h: u32 = h
        .parse()
        .map_err(|_| anyhow!("--size: height {h:?} is not a number"))?;
    if !(1..=16384).contains(&w) || !(1..=16384).contains(&h) {
        bail!("--size: {w}x{h} is out of range 1..=16384");
    }
    Ok((w, h))
}

/// The camera from `--camera` or from `--view/--size/--projection`.
pub(crate) fn camera(v: &ViewArgs, volume: &Volume) -> Result<Camera> {
    if let Some(p) = &v.camera {
        return Ok(Camera::from_file(p)?);
    }
    let view = parse_list::<f64>("--view", &v.view, Some(2))?;
    let (w, h) = size(&v.size)?;
    let projection: Projection = v
        .projection
        .parse()
        .map_err(|e: String| anyhow!("--projection: {e}"))?;
    Ok(Camera::try_orbit(
        volume, view[0], view[1], w, h, projection,
    )?)
}

/// `AZ,EL` in degrees, both finite (a NaN angle would put every ray at NaN).
pub(crate) fn view(s: &str) -> Result<[f64; 2]> {
    let v = parse_list::<f64>("--view", s, Some(2))?;
    if let Some(x) = v.iter().find(|x| !x.is_finite()) {
        bail!("--view: {x} is not a finite angle in degrees (in {s:?})");
    }
    Ok([v[0], v[1]])
}

/// Ray-caster settings.
pub(crate) fn settings(v: &ViewArgs) -> RenderSettings {
    RenderSettings {
        step: v.step,
        ert: v.ert,
        shade: v.shade,
        jitter: v.jitter,
    }
}

/// Writes the camera JSON if asked.
pub(crate) fn write_camera(v: &ViewArgs, cam: &Camera) -> Result<()> {
    if let Some(p) = &v.camera_out {
        pofvr::io::write_bytes_atomic(p, cam.to_json().as_bytes())
            .with_context(|| "--camera-out")?;
    }
    Ok(())
}
