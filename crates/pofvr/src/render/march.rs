//! The march engine: every pixel's ray walks the one sample lattice front to back across
//! the whole volume, as the reference [`RayCaster::render`] does, but leaps over the runs
//! of samples that lie in empty space ([`Occupancy`]: 4³ cells and each empty cell's
//! chessboard distance to an occupied one), and stops once its own opacity reaches the
//! termination threshold.
//!
//! The leaps are exact, not geometric estimates. A sample's position along each axis,
//! `o + (k·step)·d` in f32, is monotone in the lattice index `k` (every float operation in
//! it is monotone), and so is its trilinear cell (the sampler's clamp and floor). An empty
//! cell at distance `D` from every occupied one is the centre of a cube of `2D − 1` empty
//! cells per axis; the walk estimates in float where the ray leaves that cube, and leaps
//! only once the last sample of the leap is found, by the sampler's own cell, inside the
//! cube: then every sample between is inside too, and classifies to zero opacity, which
//! composites to nothing. Everything else goes, in order and with the same accumulator,
//! through the same sample loops ([`super::arch::march`], AVX2 or SSE2, scalar on request),
//! so the image equals the reference bit for bit. Marching a sample of zero opacity changes
//! nothing either, so the walk marches through occupied cells, and the empty cells next to
//! them, in chunks of samples without looking at each cell: the estimates cost a cell
//! lookup and a few float operations per leap, and the exact test two sample cells.

use rayon::prelude::*;

use super::arch::Gather;
use super::camera::Camera;
use super::image::Image;
use super::lattice::{sample_range, IndexRay};
use super::occupancy::{Occupancy, CELL_SHIFT, OCCUPIED};
use super::ray_caster::{RayCaster, RayStats};
use super::sampler::TrilinearSampler;
use crate::with_voxels;

/// Rows per parallel work item, as the reference.
const TILE_ROWS: usize = 8;
/// Columns of the pixel tiles a band is traversed in, as the reference.
const TILE_COLS: usize = 8;
/// The longest run of samples gathered for the sample loop before it is marched and the
/// ray's opacity checked: past that, walking on through occupied cells would be wasted on
/// a ray about to terminate.
const RUN_MAX: i32 = 64;
/// The samples the walk moves on by in an occupied cell, or in an empty one next to an
/// occupied one, before it looks at the occupancy again: the sample loop takes such
/// samples for less than a cell lookup per few samples would cost.
const CHUNK: i32 = 16;
/// The least chessboard distance to an occupied cell at which an empty cell is leapt
/// over, with the cube of empty cells around it; closer to occupied ones, leaps are too
/// short to pay for themselves.
const LEAP_MIN: i32 = 2;
/// The shortest run of empty samples worth a skip: a shorter one costs more in the split of
/// the sample loop than marching its samples of zero opacity does.
const MIN_SKIP: i32 = 2;

/// What a march frame took: the rays and samples, and the samples jumped over.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MarchStats {
    /// Rays that met the volume and samples taken.
    pub rays: RayStats,
    /// Lattice samples in empty cells the rays jumped over before terminating.
    pub skipped_samples: u64,
}

impl std::ops::AddAssign for MarchStats {
    fn add_assign(&mut self, o: Self) {
        self.rays += o.rays;
        self.skipped_samples += o.skipped_samples;
    }
}

/// One axis of a ray's samples: the sampler's position, clamp and cell, per lattice index.
#[derive(Clone, Copy)]
struct Axis {
    o: f32,
    d: f32,
    step: f32,
    /// The volume's last index (the position clamp).
    max: f32,
    /// The last trilinear cell.
    last: f32,
}

impl Axis {
    /// The trilinear cell of sample `k` on this axis, as [`TrilinearSampler::sample`] finds it.
    #[inline(always)]
    fn cell(&self, k: i32) -> u32 {
        let t = k as f32 * self.step;
        let p = self.o + t * self.d;
        let c = p.max(0.0).min(self.max).min(self.last);
        // SAFETY: c is finite and in [0, last] (rays and positions are finite).
        unsafe { c.to_int_unchecked::<u32>() }
    }
}

/// The trilinear cell of sample `k` on every axis.
#[inline(always)]
fn cell3(axes: &[Axis; 3], k: i32) -> [u32; 3] {
    [axes[0].cell(k), axes[1].cell(k), axes[2].cell(k)]
}

impl RayCaster<'_> {
    /// Renders the whole volume as [`RayCaster::render`] does, bit for bit, skipping the
    /// samples in the cells `occ` says are empty (see the [module](self)). `occ` must be
    /// built for this volume and this caster's classification.
    #[must_use]
    pub fn render_march(&self, camera: &Camera, occ: &Occupancy) -> (Image, MarchStats) {
        let w = camera.width as usize;
        let mut image = Image::new(camera.width, camera.height);
        let frame = camera.frame();
        let vbox = self.volume_box();
        let stats = with_voxels!(self.volume().data(), v => {
            let tri = TrilinearSampler::new(v, self.volume().dims());
            image
                .pixels_mut()
                .par_chunks_mut(w * TILE_ROWS)
                .enumerate()
                .map(|(band, rows)| {
                    let mut st = MarchStats::default();
                    for x0 in (0..w).step_by(TILE_COLS) {
                        for r in 0..rows.len() / w {
                            for x in x0..(x0 + TILE_COLS).min(w) {
                                let y = (band * TILE_ROWS + r) as u32;
                                let ray = self.pixel_ray(camera, &frame, x as u32, y);
                                if let Some(span) = ray.span(&vbox) {
                                    st.rays.rays += 1;
                                    let range = sample_range(span, self.settings().step);
                                    self.walk(&tri, occ, &ray, range, &mut rows[r * w + x], &mut st);
                                }
                            }
                        }
                    }
                    st
                })
                .reduce(MarchStats::default, |mut a, b| {
                    a += b;
                    a
                })
        });
        (image, stats)
    }

    /// Walks samples `k0..k1` of `ray` through the cells of `occ`, from sample to sample:
    /// at sample `k`, its cell (the sampler's own) and that cell's [`Occupancy::leap_at`]
    /// give a cube of cells of one kind around it, and the walk goes on from the first
    /// sample estimated past the cube. Samples in cubes of empty cells are skipped once the
    /// last of them is found, by its own cell, inside the cube (every axis's cell is
    /// monotone in `k`, so then all of them are); everything else is marched into `acc`, in
    /// order, in as few calls of the sample loop as the skips allow.
    fn walk<T: Gather>(
        &self,
        tri: &TrilinearSampler<'_, T>,
        occ: &Occupancy,
        ray: &IndexRay,
        (k0, k1): (i32, i32),
        acc: &mut [f32; 4],
        st: &mut MarchStats,
    ) {
        let ert = self.settings().ert;
        let step = self.settings().step;
        let inv_step = 1.0 / step;
        let axes: [Axis; 3] = std::array::from_fn(|a| Axis {
            o: ray.o[a],
            d: ray.d[a],
            step,
            max: tri.max[a],
            last: tri.last_cell[a] as f32,
        });
        let inv: [f32; 3] = ray.d.map(|d| if d == 0.0 { 0.0 } else { 1.0 / d });
        let n = occ.dims().map(|n| n as i32);
        // The `t` at which the ray leaves the cells `lo..=hi` along axis `a`; infinite
        // where it would leave the grid (clamped samples stay in its last cell). Only an
        // estimate: skips verify their last sample.
        let leave = |a: usize, lo: i32, hi: i32| -> f32 {
            let d = axes[a].d;
            if d > 0.0 && hi < n[a] - 1 {
                (((hi + 1) << CELL_SHIFT) as f32 - axes[a].o) * inv[a]
            } else if d < 0.0 && lo > 0 {
                ((lo << CELL_SHIFT) as f32 - axes[a].o) * inv[a]
            } else {
                f32::INFINITY
            }
        };
        let march = |from: i32, to: i32, acc: &mut [f32; 4], st: &mut MarchStats| {
            st.rays.samples += self.march(tri, ray, (from, to), acc);
            acc[3] >= ert
        };
        let in_cube = |c: [u32; 3], lo: &[i32; 3], hi: &[i32; 3]| {
            (0..3).all(|a| {
                let x = (c[a] >> CELL_SHIFT) as i32;
                lo[a] <= x && x <= hi[a]
            })
        };
        // The first sample neither marched nor skipped: samples `pend..k` are marched
        // before any skip past them.
        let mut pend = k0;
        let mut k = k0;
        while k < k1 {
            let c = cell3(&axes, k).map(|x| (x >> CELL_SHIFT) as i32);
            let leap = occ.leap_at(((c[2] * n[1] + c[1]) * n[0] + c[0]) as usize);
            let mut kb;
            if leap & OCCUPIED == 0 && i32::from(leap) >= LEAP_MIN {
                let r = i32::from(leap) - 1;
                let lo = c.map(|x| (x - r).max(0));
                let hi: [i32; 3] = std::array::from_fn(|a| (c[a] + r).min(n[a] - 1));
                let te = leave(0, lo[0], hi[0])
                    .min(leave(1, lo[1], hi[1]))
                    .min(leave(2, lo[2], hi[2]));
                // The first sample at or past `te` (an estimate), and at least the next one.
                let q = (te * inv_step).min(k1 as f32);
                let kq = q as i32;
                kb = (kq + i32::from((kq as f32) < q)).clamp(k + 1, k1);
                // Samples `k..kb` are skipped once their last is in the cube (`k` is),
                // settled by one sample where a rounding put the estimate past a face.
                if !in_cube(cell3(&axes, kb - 1), &lo, &hi) {
                    kb -= 1;
                    if !in_cube(cell3(&axes, kb - 1), &lo, &hi) {
                        kb = k + 1;
                    }
                }
                if kb - k >= MIN_SKIP {
                    if k > pend && march(pend, k, acc, st) {
                        return;
                    }
                    st.skipped_samples += (kb - k) as u64;
                    pend = kb;
                }
            } else {
                kb = (k + CHUNK).min(k1);
                if kb - pend >= RUN_MAX {
                    // A long occupied stretch is marched before walking on: the ray may
                    // terminate in it.
                    if march(pend, kb, acc, st) {
                        return;
                    }
                    pend = kb;
                }
            }
            k = kb;
        }
        if pend < k1 {
            march(pend, k1, acc, st);
        }
    }
}
