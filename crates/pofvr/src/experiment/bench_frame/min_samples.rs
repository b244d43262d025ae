//! The fewest samples a frame can take: per ray, the samples up to early termination whose
//! alpha is above zero.
//!
//! Why this minimum: a sample with zero alpha adds nothing to the pixel, so an engine that
//! skipped empty space perfectly would take only the others; and no engine may go on past
//! the sample where the ray's opacity reaches the termination threshold. Shading changes
//! colour, never alpha, so the minimum is the same shaded and unshaded.

use rayon::prelude::*;

use crate::render::ray_caster::sample_range;
use crate::render::sampler::TrilinearSampler;
use crate::render::{Camera, RayCaster};
use crate::with_voxels;
use crate::Scene;

/// Rays that meet the volume and their minimum samples, for `weights` seen by `camera`.
#[must_use]
pub fn minimum_samples(scene: &Scene, weights: &[f32], camera: &Camera) -> (u64, u64) {
    let settings = crate::render::RenderSettings {
        step: scene.step(),
        ert: scene.early_termination(),
        shade: false,
        jitter: None,
    };
    let cls = scene.sampled().classify(weights, settings.step);
    let view = cls.view();
    let volume = scene.volume();
    let caster = RayCaster::new(volume, &cls, settings);
    let (frame, vbox) = (camera.frame(), caster.volume_box());
    let (w, h) = (camera.width, camera.height);
    with_voxels!(volume.data(), v => {
        let tri = TrilinearSampler::new(v, volume.dims());
        (0..h)
            .into_par_iter()
            .map(|y| {
                let (mut rays, mut samples) = (0u64, 0u64);
                for x in 0..w {
                    let ray = caster.pixel_ray(camera, &frame, x, y);
                    let Some(span) = ray.span(&vbox) else { continue };
                    rays += 1;
                    let (k0, k1) = sample_range(span, settings.step);
                    let mut alpha = 0f32;
                    for k in k0..k1 {
                        if alpha >= settings.ert {
                            break;
                        }
                        let t = k as f32 * settings.step;
                        let p = [
                            ray.o[0] + t * ray.d[0],
                            ray.o[1] + t * ray.d[1],
                            ray.o[2] + t * ray.d[2],
                        ];
                        let a = view.sample(tri.sample(p))[3];
                        if a > 0.0 {
                            samples += 1;
                            alpha += (1.0 - alpha) * a;
                        }
                    }
                }
                (rays, samples)
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
    })
}
