//! Rays in voxel index space and the one sample lattice `t_k = k·step` every box of a ray
//! is sampled on.
//!
//! Samples of a ray lie on one lattice (t in units of the volume's smallest spacing,
//! measured from the camera), whatever box is being rendered. A box claims the samples in
//! its half-open interval `[t_near, t_far)`, computed from its face planes, and
//! neighbouring boxes compute the shared plane's `t` with the same float operations. So the
//! bricks of a grid partition every ray's samples exactly, and rendering brick by brick
//! (carrying the accumulator) performs the very operations of the whole-volume render.

use glam::DVec3;

use super::camera::Ray;
use crate::brick::IndexBox;

/// A ray in index space with `t` in units: `p(t) = o + t·d`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexRay {
    /// Origin in voxel index coordinates.
    pub o: [f32; 3],
    /// Index-space displacement per unit of `t`.
    pub d: [f32; 3],
    /// Unit world direction (for shading).
    pub dir: [f32; 3],
}

impl IndexRay {
    /// Converts a world ray for a volume with `spacing` and smallest spacing `unit`.
    #[must_use]
    pub fn new(ray: &Ray, spacing: [f32; 3], unit: f32) -> Self {
        let s = DVec3::from(spacing.map(f64::from));
        let o = ray.origin / s;
        let d = ray.dir * f64::from(unit) / s;
        IndexRay {
            o: o.to_array().map(|x| x as f32),
            d: d.to_array().map(|x| x as f32),
            dir: ray.dir.to_array().map(|x| x as f32),
        }
    }

    /// The half-open `t` interval `[t_near, t_far)` inside `b`, or `None` when it misses.
    #[inline]
    #[must_use]
    pub fn span(&self, b: &IndexBox) -> Option<(f32, f32)> {
        let (mut t0, mut t1) = (f32::NEG_INFINITY, f32::INFINITY);
        for a in 0..3 {
            let d = self.d[a];
            if d == 0.0 {
                if !(b.lo[a] <= self.o[a] && self.o[a] < b.hi[a]) {
                    return None;
                }
                continue;
            }
            // Same expression for every box sharing the plane: the partition is exact.
            let ta = (b.lo[a] - self.o[a]) / d;
            let tb = (b.hi[a] - self.o[a]) / d;
            let (near, far) = if d > 0.0 { (ta, tb) } else { (tb, ta) };
            t0 = t0.max(near);
            t1 = t1.min(far);
        }
        (t0 < t1).then_some((t0, t1))
    }
}

/// First lattice index `k ≥ 0` with `k·step ≥ t`.
#[inline]
#[must_use]
pub fn first_sample(t: f32, step: f32) -> i32 {
    if t <= 0.0 {
        return 0;
    }
    // A ceiling by hand: `f32::ceil` is a libm call on the x86_64 baseline (no SSE4.1),
    // once per box and ray. The loops below settle the exact boundary either way.
    let q = (t / step).min(i32::MAX as f32 - 2.0);
    let mut k = q as i32;
    k += i32::from((k as f32) < q);
    // The division rounds; settle on the exact boundary under the multiplication we sample with.
    while k > 0 && (k - 1) as f32 * step >= t {
        k -= 1;
    }
    while (k as f32) * step < t {
        k += 1;
    }
    k
}

/// The lattice indices `[k0, k1)` a box claims on a ray, given its span.
#[inline]
#[must_use]
pub fn sample_range(span: (f32, f32), step: f32) -> (i32, i32) {
    (first_sample(span.0, step), first_sample(span.1, step))
}
