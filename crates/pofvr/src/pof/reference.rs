//! The slow twin of the builder: a brick's core-footprint minimum opacity measured by
//! rendering it alone with the real [`RayCaster::render_box`], as the renderer would.
//!
//! Used by the tests (the fast table must never exceed it) and by `pofvr pof check`.

use glam::DVec3;

use crate::brick::{BrickGrid, BrickId};
use crate::render::{Camera, PixelRect, Projection, RayCaster, RenderSettings, SampledTf};
use crate::volume::Volume;

/// One brute-force view of a brick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceView {
    /// Least composited opacity over pixels whose span is at least the core length;
    /// `None` when no pixel is in the core.
    pub core_min: Option<f32>,
    /// Pixels in the core.
    pub core_pixels: usize,
    /// Pixels whose ray met the brick at all.
    pub footprint_pixels: usize,
}

/// How a brute-force view is placed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceProbe {
    /// Unit world view direction (eye to scene).
    pub dir: DVec3,
    /// Shift of the sample lattice along the ray, as a fraction of a step (0..1).
    pub phase: f64,
    /// Sub-pixel shift of the image plane, in pixels, along its x and y.
    pub jitter: [f64; 2],
    /// Pixel size in units of the smallest spacing (≤ 0.5 puts ≥ 2 rays per voxel).
    pub pixel: f64,
}

/// Renders brick `id` alone, orthographically along `probe.dir`, with `weights`, `step`
/// and `ert`, and returns the least opacity over the pixels whose ray spans at least
/// `core_length` (in `t` units) of the brick.
#[must_use]
#[allow(clippy::too_many_arguments)]
pub fn core_min(
    volume: &Volume,
    grid: &BrickGrid,
    sampled: &SampledTf,
    id: BrickId,
    weights: &[f32],
    step: f32,
    ert: f32,
    core_length: f32,
    probe: &ReferenceProbe,
) -> ReferenceView {
    let cls = sampled.classify(weights, step);
    let settings = RenderSettings {
        step,
        ert,
        shade: false,
        jitter: None,
    };
    let rc = RayCaster::new(volume, &cls, settings);
    let b = grid.index_box(id);
    let sp = volume.spacing().map(f64::from);
    let unit = f64::from(volume.unit());
    let lo = DVec3::new(
        f64::from(b.lo[0]) * sp[0],
        f64::from(b.lo[1]) * sp[1],
        f64::from(b.lo[2]) * sp[2],
    );
    let hi = DVec3::new(
        f64::from(b.hi[0]) * sp[0],
        f64::from(b.hi[1]) * sp[1],
        f64::from(b.hi[2]) * sp[2],
    );
    let centre = (lo + hi) * 0.5;
    let radius = (hi - lo).length() * 0.5;
    let dir = probe.dir.normalize();
    let pix = probe.pixel * unit;
    let half = radius + 2.0 * pix;
    let size = ((2.0 * half / pix).ceil() as u32).clamp(1, 16384);
    let half = f64::from(size) * pix * 0.5;
    // An up vector far from the view direction.
    let up = [DVec3::X, DVec3::Y, DVec3::Z]
        .into_iter()
        .min_by(|a, b| a.dot(dir).abs().total_cmp(&b.dot(dir).abs()))
        .expect("three axes");
    let mut cam = Camera {
        projection: Projection::Orthographic,
        position: [0.0; 3],
        focal_point: centre.to_array(),
        view_up: up.to_array(),
        parallel_scale: half,
        view_angle: 30.0,
        width: size,
        height: size,
    };
    // The eye plane sits before the brick; moving it along the ray moves the sample
    // lattice relative to the brick (the phase), moving it sideways shifts the pixels.
    let back = 2.0 * radius + 4.0 * f64::from(step) * unit + probe.phase * f64::from(step) * unit;
    cam.position = (centre - dir * back).to_array();
    let frame = cam.frame();
    let shift = frame.right * probe.jitter[0] * pix + frame.up * probe.jitter[1] * pix;
    cam.position = (DVec3::from(cam.position) + shift).to_array();
    cam.focal_point = (centre + shift).to_array();
    let frame = cam.frame();
    let rect = PixelRect {
        x0: 0,
        y0: 0,
        x1: size,
        y1: size,
    };
    let (px, _) = rc.render_box(&cam, &frame, rect, &b);
    let mut view = ReferenceView {
        core_min: None,
        core_pixels: 0,
        footprint_pixels: 0,
    };
    for y in 0..size {
        for x in 0..size {
            let ray = rc.pixel_ray(&cam, &frame, x, y);
            let Some((t0, t1)) = ray.span(&b) else {
                continue;
            };
            view.footprint_pixels += 1;
            if t1 - t0 >= core_length {
                view.core_pixels += 1;
                let a = px[(y * size + x) as usize][3];
                view.core_min = Some(view.core_min.map_or(a, |m: f32| m.min(a)));
            }
        }
    }
    view
}
