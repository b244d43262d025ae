//! The fewest samples a frame can take: per ray, the samples up to early termination whose
//! alpha is above zero; and the fewest an exact empty-space skip can take: those of them,
//! and the rest before termination, whose own trilinear cell can hold opacity.
//!
//! Why this minimum: a sample with zero alpha adds nothing to the pixel, so an engine that
//! skipped empty space perfectly would take only the others; and no engine may go on past
//! the sample where the ray's opacity reaches the termination threshold. Shading changes
//! colour, never alpha, so the minimum is the same shaded and unshaded.
//!
//! Why the floor: an engine that must give the reference image bit for bit may skip a
//! sample only once it knows, without interpolating it, that its alpha is zero. The finest
//! such knowledge short of the sample itself is its trilinear cell's eight corners: their
//! range, through the occupancy's own test ([`OpaqueBins`]), says "zero" or "maybe". A
//! sample whose cell says "maybe" but whose value lands on a bin of zero opacity (a ray
//! grazing a boundary, a cell whose corners straddle a thin opaque band) must be taken. So
//! no exact skip over cells, of any size, takes fewer samples than the floor; the march
//! engine's 4³ cells take more.

use rayon::prelude::*;

use crate::render::occupancy::OpaqueBins;
use crate::render::ray_caster::sample_range;
use crate::render::sampler::TrilinearSampler;
use crate::render::{Camera, RayCaster};
use crate::with_voxels;
use crate::Scene;

/// A frame's rays and its fewest samples ([`minimum_samples`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SampleBounds {
    /// Rays that meet the volume.
    pub rays: u64,
    /// Samples before termination whose alpha is above zero.
    pub visible: u64,
    /// Samples before termination whose trilinear cell can hold opacity: the fewest an
    /// exact empty-space skip can take (see the [module](self)). At least `visible`.
    pub cell_floor: u64,
}

/// The rays that meet the volume and their fewest samples, for `weights` seen by `camera`.
#[must_use]
pub fn minimum_samples(scene: &Scene, weights: &[f32], camera: &Camera) -> SampleBounds {
    let settings = crate::render::RenderSettings {
        step: scene.step(),
        ert: scene.early_termination(),
        shade: false,
        jitter: None,
    };
    let cls = scene.sampled().classify(weights, settings.step);
    let view = cls.view();
    let opaque = OpaqueBins::new(&cls);
    let volume = scene.volume();
    let caster = RayCaster::new(volume, &cls, settings);
    let (frame, vbox) = (camera.frame(), caster.volume_box());
    let (w, h) = (camera.width, camera.height);
    with_voxels!(volume.data(), v => {
        let tri = TrilinearSampler::new(v, volume.dims());
        (0..h)
            .into_par_iter()
            .map(|y| {
                let mut b = SampleBounds::default();
                for x in 0..w {
                    let ray = caster.pixel_ray(camera, &frame, x, y);
                    let Some(span) = ray.span(&vbox) else { continue };
                    b.rays += 1;
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
                        let cell = tri.cell(p);
                        let (lo, hi) = cell
                            .c
                            .iter()
                            .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &c| {
                                (l.min(c), h.max(c))
                            });
                        if opaque.any(lo, hi) {
                            b.cell_floor += 1;
                        }
                        let a = view.sample(cell.value())[3];
                        if a > 0.0 {
                            b.visible += 1;
                            alpha += (1.0 - alpha) * a;
                        }
                    }
                }
                b
            })
            .reduce(SampleBounds::default, |a, b| SampleBounds {
                rays: a.rays + b.rays,
                visible: a.visible + b.visible,
                cell_floor: a.cell_floor + b.cell_floor,
            })
    })
}
