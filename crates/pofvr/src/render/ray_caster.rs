//! The software ray caster: front-to-back emission–absorption with trilinear samples, over
//! the whole volume or one box of it, on the one sample lattice (see [`first_sample`]).

use std::sync::OnceLock;

use rayon::prelude::*;

use super::arch::{self, Gather, MarchParams};
use super::camera::{Camera, PixelRect, ViewFrame};
use super::image::Image;
use super::jitter;
use super::sampler::TrilinearSampler;
use super::transfer_function::Classifier;
use crate::brick::IndexBox;
use crate::volume::Volume;
use crate::with_voxels;

pub use super::lattice::{first_sample, sample_range, IndexRay};

/// Per-frame knobs of the ray caster.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Sample distance in units of the smallest spacing. Default 1.
    pub step: f32,
    /// Early ray termination: stop a ray once its opacity reaches this. Default 0.99;
    /// 1.0 (or more) disables it.
    pub ert: f32,
    /// Lambertian gradient shading with a headlight.
    pub shade: bool,
    /// Jittered ray starts with this seed ([`super::jitter`]): each pixel's first sample
    /// moves forward by its own fraction of a step. Default `None` (every ray on the
    /// unshifted lattice).
    pub jitter: Option<u32>,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            step: 1.0,
            ert: 0.99,
            shade: false,
            jitter: None,
        }
    }
}

/// Rays and samples a render performed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct RayStats {
    /// Rays that met the rendered box.
    pub rays: u64,
    /// Samples taken (after early termination).
    pub samples: u64,
}

impl std::ops::AddAssign for RayStats {
    fn add_assign(&mut self, o: Self) {
        self.rays += o.rays;
        self.samples += o.samples;
    }
}

/// The ray caster: renders a box of the volume over a pixel rectangle, or the whole volume.
pub struct RayCaster<'a> {
    volume: &'a Volume,
    settings: RenderSettings,
    /// What the sample loops need, AVX2 on where the CPU has it.
    params: MarchParams<'a>,
    /// The pixel rays of the first camera a box is rendered for (see [`PixelRays`]).
    rays: OnceLock<PixelRays>,
}

/// Every pixel's index ray for one camera, computed a row at a time when a box first needs
/// that row, and shared by every box rendered after: a frame renders each pixel through
/// several bricks, and the ray (a camera ray in f64, its conversion to index space with
/// three divisions, the jitter) is the same for each, so a brick's set-up per pixel is a
/// load rather than that computation. The rays are the very values
/// [`RayCaster::pixel_ray`] returns, so the images do not change by a bit.
struct PixelRays {
    camera: Camera,
    frame: ViewFrame,
    rows: Vec<OnceLock<Box<[IndexRay]>>>,
}

impl PixelRays {
    fn new(camera: &Camera, frame: &ViewFrame) -> Self {
        PixelRays {
            camera: camera.clone(),
            frame: *frame,
            rows: (0..camera.height).map(|_| OnceLock::new()).collect(),
        }
    }

    /// Whether these are the rays of `camera` seen through `frame`.
    fn are_for(&self, camera: &Camera, frame: &ViewFrame) -> bool {
        // The frame is derived from the camera; compared too, as callers pass both.
        self.camera == *camera && frame_bits(&self.frame) == frame_bits(frame)
    }
}

/// A view frame's exact bits, for comparing frames.
fn frame_bits(f: &ViewFrame) -> [u64; 9] {
    let v = [f.forward, f.right, f.up];
    std::array::from_fn(|i| v[i / 3][i % 3].to_bits())
}

/// Rows per parallel work item of a full-frame render.
const TILE_ROWS: usize = 8;

/// Columns of the pixel tiles a band is traversed in.
const TILE_COLS: usize = 8;

impl<'a> RayCaster<'a> {
    /// A caster for `volume` with the classification `cls` (built for `settings.step`).
    #[must_use]
    pub fn new(volume: &'a Volume, cls: &'a Classifier, settings: RenderSettings) -> Self {
        RayCaster {
            volume,
            settings,
            params: MarchParams {
                cls: cls.view(),
                step: settings.step,
                ert: settings.ert,
                shade: settings.shade.then(|| volume.spacing()),
                avx2: arch::avx2_available(),
                avx512: arch::avx512_available(),
                scalar: false,
                prefetch: arch::prefetch_pays(
                    volume.data().len() * volume.data().data_type().size(),
                ),
                gather: arch::gather_pays(arch::avx512_available()),
            },
            rays: OnceLock::new(),
        }
    }

    /// The same caster with the AVX2 loops on or off (on only where the CPU has it), and
    /// with them the march engine's AVX-512 packets (on where the CPU has them too): every
    /// loop gives the same image, bit for bit; this is for comparing them. The packet loop
    /// that then runs loads by gathers where they measured faster in it
    /// ([`RayCaster::with_gather`] chooses otherwise).
    #[must_use]
    pub fn with_avx2(mut self, on: bool) -> Self {
        self.params.avx2 = on && arch::avx2_available();
        self.params.avx512 = self.params.avx2 && arch::avx512_available();
        self.params.gather = self.params.avx2 && arch::gather_pays(self.params.avx512);
        self
    }

    /// The same caster with the march engine's AVX-512 packets of sixteen rays on (only
    /// where the CPU has them and the AVX2 loops are on) or off (packets of eight on AVX2):
    /// the same image, bit for bit; this is for comparing them. The packet loop that then
    /// runs loads by gathers where they measured faster in it ([`RayCaster::with_gather`]
    /// chooses otherwise).
    #[must_use]
    pub fn with_avx512(mut self, on: bool) -> Self {
        self.params.avx512 = on && self.params.avx2 && arch::avx512_available();
        self.params.gather = self.params.avx2 && arch::gather_pays(self.params.avx512);
        self
    }

    /// The same caster with the march engine's packet loops prefetching the voxels ahead
    /// of their rays (`on`) or not: the same image, bit for bit. By default they do where
    /// the voxels exceed the last-level cache (or as `POFVR_PREFETCH=on|off` says); this is
    /// for comparing the two.
    #[must_use]
    pub fn with_prefetch(mut self, on: bool) -> Self {
        self.params.prefetch = on;
        self
    }

    /// The same caster with the march engine's packet loops (sixteen lanes or eight)
    /// loading their corners and table entries by gathers (`on`, where the CPU runs a
    /// packet loop) or lane by lane: the same image, bit for bit. By default the loop that
    /// runs gathers where gathers measured faster in it on this CPU (or as
    /// `POFVR_GATHER=on|off` says); this is for comparing the two.
    #[must_use]
    pub fn with_gather(mut self, on: bool) -> Self {
        self.params.gather = on && self.params.avx2;
        self
    }

    /// Whether the packet loop loads by gathers (see [`RayCaster::with_gather`]).
    #[must_use]
    pub fn gather(&self) -> bool {
        self.params.gather
    }

    /// Whether the march engine's packet loops prefetch (see [`RayCaster::with_prefetch`]).
    #[must_use]
    pub fn prefetch(&self) -> bool {
        self.params.prefetch
    }

    /// The loop the march engine's packets take: "avx512" (sixteen rays), "avx2" (eight)
    /// or "none" (one ray at a time).
    #[must_use]
    pub fn packet_simd(&self) -> &'static str {
        arch::packet_name(&self.params)
    }

    /// The same caster on the scalar reference loop (`on`) or on the fastest loop this CPU
    /// runs: every loop gives the same image, bit for bit, shaded or not; this is for
    /// comparing them.
    #[must_use]
    pub fn with_scalar_loop(mut self, on: bool) -> Self {
        self.params.scalar = on;
        self
    }

    /// The sample loop this caster runs: "avx2", "sse2" or "scalar" (shaded or not).
    #[must_use]
    pub fn simd(&self) -> &'static str {
        arch::name(&self.params)
    }

    /// The volume.
    pub(super) fn volume(&self) -> &'a Volume {
        self.volume
    }

    /// The settings.
    #[must_use]
    pub fn settings(&self) -> RenderSettings {
        self.settings
    }

    /// The index-space box of the whole volume.
    #[must_use]
    pub fn volume_box(&self) -> IndexBox {
        IndexBox {
            lo: [0.0; 3],
            hi: self.volume.dims().map(|d| (d - 1) as f32),
        }
    }

    /// The index ray through the centre of pixel `(x, y)`, shifted by the pixel's jitter
    /// when the settings ask for it: every render of a box goes through here, so every
    /// partition of a ray samples the same lattice.
    #[must_use]
    pub fn pixel_ray(&self, camera: &Camera, frame: &ViewFrame, x: u32, y: u32) -> IndexRay {
        let r = camera.ray(frame, f64::from(x) + 0.5, f64::from(y) + 0.5);
        let ray = IndexRay::new(&r, self.volume.spacing(), self.volume.unit());
        match self.settings.jitter {
            None => ray,
            Some(seed) => jitter::shifted(ray, jitter::offset(seed, x, y), self.settings.step),
        }
    }

    /// Renders the whole volume (the reference, no bricks, no culling), in parallel over
    /// bands of rows.
    #[must_use]
    pub fn render(&self, camera: &Camera) -> (Image, RayStats) {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let mut image = Image::new(camera.width, camera.height);
        let frame = camera.frame();
        let vbox = self.volume_box();
        let stats = with_voxels!(self.volume.data(), v => {
            let tri = TrilinearSampler::new(v, self.volume.dims());
            image
                .pixels_mut()
                .par_chunks_mut(w * TILE_ROWS)
                .enumerate()
                .map(|(band, rows)| {
                    let mut st = RayStats::default();
                    // Tiles of TILE_ROWS × TILE_COLS pixels: neighbouring rays share cache lines.
                    for x0 in (0..w).step_by(TILE_COLS) {
                        for r in 0..rows.len() / w {
                            for x in x0..(x0 + TILE_COLS).min(w) {
                                let ray = self.pixel_ray(camera, &frame, x as u32, (band * TILE_ROWS + r) as u32);
                                if let Some(span) = ray.span(&vbox) {
                                    st.rays += 1;
                                    let range = sample_range(span, self.settings.step);
                                    st.samples += self.march(&tri, &ray, range, &mut rows[r * w + x]);
                                }
                            }
                        }
                    }
                    st
                })
                .reduce(RayStats::default, |mut a, b| {
                    a += b;
                    a
                })
        });
        debug_assert_eq!(image.pixels().len(), w * h);
        (image, stats)
    }

    /// Renders the index box `b` alone over `rect` (row-major premultiplied RGBA, starting
    /// from transparent), serially: callers parallelise over boxes.
    #[must_use]
    pub fn render_box(
        &self,
        camera: &Camera,
        frame: &ViewFrame,
        rect: PixelRect,
        b: &IndexBox,
    ) -> (Vec<[f32; 4]>, RayStats) {
        let mut out = vec![[0f32; 4]; rect.area()];
        let st = self.render_box_into(camera, frame, rect, b, &mut out);
        (out, st)
    }

    /// As [`RayCaster::render_box`], compositing behind what `out` already holds.
    pub fn render_box_into(
        &self,
        camera: &Camera,
        frame: &ViewFrame,
        rect: PixelRect,
        b: &IndexBox,
        out: &mut [[f32; 4]],
    ) -> RayStats {
        with_voxels!(self.volume.data(), v => {
            let tri = TrilinearSampler::new(v, self.volume.dims());
            self.march_rect(&tri, camera, frame, rect, b, out)
        })
    }

    /// As [`RayCaster::render_box`], sampling the private copy `copy` of the box's voxels
    /// instead of the volume: the same samples, bit for bit (see `TrilinearSampler`).
    #[must_use]
    pub fn render_box_copy(
        &self,
        camera: &Camera,
        frame: &ViewFrame,
        rect: PixelRect,
        b: &IndexBox,
        copy: &crate::brick::BrickCopy,
    ) -> (Vec<[f32; 4]>, RayStats) {
        let mut out = vec![[0f32; 4]; rect.area()];
        debug_assert_eq!(copy.data().data_type(), self.volume.data_type());
        let st = with_voxels!(copy.data(), v => {
            let tri = TrilinearSampler::local(v, copy.dims(), copy.origin(), self.volume.dims());
            self.march_rect(&tri, camera, frame, rect, b, &mut out)
        });
        (out, st)
    }

    /// Marches every pixel of `rect` through the box `b`, compositing behind `out`
    /// (row-major over `rect`).
    fn march_rect<T: Gather, const COPY: bool>(
        &self,
        tri: &TrilinearSampler<'_, T, COPY>,
        camera: &Camera,
        frame: &ViewFrame,
        rect: PixelRect,
        b: &IndexBox,
        out: &mut [[f32; 4]],
    ) -> RayStats {
        let mut st = RayStats::default();
        let w = rect.width() as usize;
        let rays = self.rays.get_or_init(|| PixelRays::new(camera, frame));
        let cached = rays.are_for(camera, frame);
        for (r, row) in out.chunks_mut(w).enumerate() {
            let y = rect.y0 + r as u32;
            let line = cached.then(|| {
                rays.rows[y as usize].get_or_init(|| {
                    (0..camera.width)
                        .map(|x| self.pixel_ray(camera, frame, x, y))
                        .collect()
                })
            });
            for (i, px) in row.iter_mut().enumerate() {
                let x = rect.x0 + i as u32;
                let ray = match line {
                    Some(line) => line[x as usize],
                    None => self.pixel_ray(camera, frame, x, y),
                };
                if let Some(span) = ray.span(b) {
                    st.rays += 1;
                    st.samples += self.march(tri, &ray, sample_range(span, self.settings.step), px);
                }
            }
        }
        st
    }

    /// Composites samples `range` of `ray` behind `acc` with whichever loop this caster
    /// runs ([`arch::march`]); returns the samples taken.
    #[inline(always)]
    pub(super) fn march<T: Gather, const COPY: bool>(
        &self,
        tri: &TrilinearSampler<'_, T, COPY>,
        ray: &IndexRay,
        range: (i32, i32),
        acc: &mut [f32; 4],
    ) -> u64 {
        arch::march(&self.params, tri, ray, range, acc)
    }

    /// What the sample loops need of this caster (the march engine's loop, and tests
    /// comparing the loops directly).
    pub(super) fn params(&self) -> MarchParams<'a> {
        self.params
    }
}
