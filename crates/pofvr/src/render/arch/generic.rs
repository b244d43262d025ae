//! The scalar sample loop: the reference every other loop equals bit for bit, shaded or
//! not, and the one definition of shading ([`lambert`]).

use super::MarchParams;
use crate::render::lattice::IndexRay;
use crate::render::sampler::TrilinearSampler;
use crate::volume::Voxel;

/// Ambient share of the shaded colour.
pub(crate) const AMBIENT: f32 = 0.3;
/// Diffuse share of the shaded colour.
pub(crate) const DIFFUSE: f32 = 0.7;

/// Composites samples `k0..k1` of `ray` behind `acc` (premultiplied RGBA); returns the
/// samples taken. A ray stops once its opacity reaches `p.ert`. With shading, a sample's
/// colour (not its opacity) is scaled by [`lambert`] of its cell's gradient, which is
/// computed only for samples whose opacity is above zero.
#[inline(always)]
pub(crate) fn march<T: Voxel, const COPY: bool>(
    p: &MarchParams<'_>,
    tri: &TrilinearSampler<'_, T, COPY>,
    ray: &IndexRay,
    (k0, k1): (i32, i32),
    acc: &mut [f32; 4],
) -> u64 {
    let (step, ert) = (p.step, p.ert);
    let mut n = 0u64;
    for k in k0..k1 {
        if acc[3] >= ert {
            break;
        }
        let t = k as f32 * step;
        let x = [
            ray.o[0] + t * ray.d[0],
            ray.o[1] + t * ray.d[1],
            ray.o[2] + t * ray.d[2],
        ];
        let cell = tri.cell(x);
        let mut s = p.cls.sample(cell.value());
        n += 1;
        if s[3] == 0.0 {
            continue;
        }
        if let Some(spacing) = p.shade {
            let l = lambert(cell.gradient(), spacing, ray.dir);
            s[0] *= l;
            s[1] *= l;
            s[2] *= l;
        }
        let w = 1.0 - acc[3];
        acc[0] += w * s[0];
        acc[1] += w * s[1];
        acc[2] += w * s[2];
        acc[3] += w * s[3];
    }
    n
}

/// Ambient + diffuse factor of a headlight (light along the view ray `dir`, a unit world
/// vector; two-sided, no specular) for the index-space gradient `g` of a volume with voxel
/// `spacing`: the gradient is taken to world units per axis first, so that anisotropic
/// voxels tilt the normal as they tilt the surface. A gradient too short to give a normal
/// leaves the colour as it is. The vector loops evaluate these operations lane-wise, in
/// this order.
#[inline(always)]
pub(crate) fn lambert(g: [f32; 3], spacing: [f32; 3], dir: [f32; 3]) -> f32 {
    let g = [g[0] / spacing[0], g[1] / spacing[1], g[2] / spacing[2]];
    let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    if len <= f32::EPSILON {
        return 1.0;
    }
    let ndotl = ((g[0] * dir[0] + g[1] * dir[1] + g[2] * dir[2]) / len).abs();
    AMBIENT + DIFFUSE * ndotl
}
