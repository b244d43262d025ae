//! The march engine's pixel rays: [`RayCaster::pixel_ray`] value for value, with what
//! depends only on a pixel's column or only on its row computed once per frame.
//!
//! A pixel's ray is `Camera::ray` of its centre converted to index space (and jittered).
//! In that expression the screen coordinate `u` depends on the column alone, `v` on the row
//! alone, the orthographic direction (and the perspective origin) on neither. Hoisting
//! those terms keeps every float operation and its order: `eye + right·u` (or
//! `forward + right·u`) is the left operand of the sum whatever the row, and `up·v` the
//! right one. So the rays are bit for bit those of the reference, and a pixel's ray costs
//! three additions and three divisions (the conversion of the varying part to index
//! space) rather than the whole camera computation: a few percent of a frame whose rays
//! mostly leap through empty space.

use glam::DVec3;

use super::camera::{Camera, Projection, ViewFrame};
use super::jitter;
use super::lattice::IndexRay;

/// Per-frame terms of every pixel ray of one camera.
pub(crate) struct FrameRays {
    perspective: bool,
    /// Per column: `eye + right·u` (orthographic) or `forward + right·u` (perspective).
    cols: Vec<DVec3>,
    /// Per row: `up·v`.
    rows: Vec<DVec3>,
    /// The volume's voxel spacing (the conversion to index space).
    s: DVec3,
    /// `unit` as f64.
    unit: f64,
    /// The part of the index ray that is the same for every pixel: the direction
    /// (orthographic) or the origin (perspective).
    fixed: [f32; 3],
    /// The world direction of every ray (orthographic).
    dir: [f32; 3],
    /// The jitter's seed and the step it shifts by.
    jitter: Option<(u32, f32)>,
}

impl FrameRays {
    /// The rays of `camera` seen through `frame`, for a volume of `spacing` with smallest
    /// spacing `unit`, jittered by `jitter` (seed, step) as the caster does.
    pub(crate) fn new(
        camera: &Camera,
        frame: &ViewFrame,
        spacing: [f32; 3],
        unit: f32,
        jitter: Option<(u32, f32)>,
    ) -> Self {
        // `Camera::ray`'s terms, in its order of operations.
        let perspective = camera.projection == Projection::Perspective;
        let h = match camera.projection {
            Projection::Orthographic => camera.parallel_scale,
            Projection::Perspective => (camera.view_angle * 0.5).to_radians().tan(),
        };
        let aspect = f64::from(camera.width) / f64::from(camera.height);
        let eye = DVec3::from(camera.position);
        let base = if perspective { frame.forward } else { eye };
        let cols = (0..camera.width)
            .map(|x| {
                let u = ((f64::from(x) + 0.5) / f64::from(camera.width) * 2.0 - 1.0) * h * aspect;
                base + frame.right * u
            })
            .collect();
        let rows = (0..camera.height)
            .map(|y| {
                let v = (1.0 - (f64::from(y) + 0.5) / f64::from(camera.height) * 2.0) * h;
                frame.up * v
            })
            .collect();
        let s = DVec3::from(spacing.map(f64::from));
        let unit = f64::from(unit);
        // `IndexRay::new`'s conversions of the fixed part.
        let fixed = if perspective {
            eye / s
        } else {
            frame.forward * unit / s
        };
        FrameRays {
            perspective,
            cols,
            rows,
            s,
            unit,
            fixed: fixed.to_array().map(|x| x as f32),
            dir: frame.forward.to_array().map(|x| x as f32),
            jitter,
        }
    }

    /// The index ray of pixel `(x, y)`, as [`super::RayCaster::pixel_ray`] gives it.
    ///
    /// Always inlined: the packet loop's set-up calls it sixteen times per packet, and as
    /// a call (which an unrelated edit elsewhere in the crate once made it) it took 3 % of
    /// a 512² frame (`docs/results.md`, stop 39).
    #[inline(always)]
    pub(crate) fn ray(&self, x: u32, y: u32) -> IndexRay {
        let p = self.cols[x as usize] + self.rows[y as usize];
        let ray = if self.perspective {
            let dir = p.normalize();
            IndexRay {
                o: self.fixed,
                d: (dir * self.unit / self.s).to_array().map(|x| x as f32),
                dir: dir.to_array().map(|x| x as f32),
            }
        } else {
            IndexRay {
                o: (p / self.s).to_array().map(|x| x as f32),
                d: self.fixed,
                dir: self.dir,
            }
        };
        match self.jitter {
            None => ray,
            Some((seed, step)) => jitter::shifted(ray, jitter::offset(seed, x, y), step),
        }
    }
}
