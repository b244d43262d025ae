//! The scalar sample loop: the reference every other loop equals bit for bit, and the
//! one that shades.

use super::MarchParams;
use crate::render::lattice::IndexRay;
use crate::render::sampler::TrilinearSampler;
use crate::volume::Voxel;

/// Composites samples `k0..k1` of `ray` behind `acc` (premultiplied RGBA); returns the
/// samples taken. A ray stops once its opacity reaches `p.ert`.
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
        let mut s = p.cls.sample(tri.sample(x));
        n += 1;
        if s[3] == 0.0 {
            continue;
        }
        if let Some(spacing) = p.shade {
            let l = lambert(tri, spacing, x, ray.dir);
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

/// Ambient + diffuse factor with a headlight at index position `x` of a volume with voxel
/// `spacing`; the gradient uses central differences at ±½ voxel so that it reads only the
/// brick's ghost layer.
fn lambert<T: Voxel, const COPY: bool>(
    tri: &TrilinearSampler<'_, T, COPY>,
    spacing: [f32; 3],
    x: [f32; 3],
    dir: [f32; 3],
) -> f32 {
    let mut g = [0f32; 3];
    for a in 0..3 {
        let (mut lo, mut hi) = (x, x);
        lo[a] -= 0.5;
        hi[a] += 0.5;
        g[a] = (tri.sample(hi) - tri.sample(lo)) / spacing[a];
    }
    let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    if len <= f32::EPSILON {
        return 1.0;
    }
    let ndotl = ((g[0] * dir[0] + g[1] * dir[1] + g[2] * dir[2]) / len).abs();
    0.3 + 0.7 * ndotl
}
