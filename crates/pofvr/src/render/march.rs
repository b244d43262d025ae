//! The march engine: every pixel's ray walks the one sample lattice front to back across
//! the whole volume, as the reference [`RayCaster::render`] does, but jumps over the runs of
//! samples that lie in empty space ([`Occupancy`]: 32³ blocks, then 4³ cells), and stops
//! once its own opacity reaches the termination threshold.
//!
//! The jumps are exact, not geometric estimates. A sample's position along each axis,
//! `o + (k·step)·d` in f32, is monotone in the lattice index `k` (every float operation in
//! it is monotone), and so is its trilinear cell (the sampler's clamp and floor). So along
//! each axis the samples of one cell form one run of consecutive `k`, and the first `k` of
//! the next run is found by evaluating that very expression: a float estimate from the
//! plane crossing, settled by a galloping search. The runs the walk marches are therefore
//! exactly the samples whose cells are occupied, every skipped sample classifies to zero
//! opacity (which composites to nothing), and the samples marched go through the same
//! sample loops ([`super::arch::march`], AVX2 or SSE2, scalar when shading) with the same
//! accumulator: the image equals the reference bit for bit. Marching a sample of zero
//! opacity changes nothing either, so blocks whose cells are mostly occupied are marched
//! through whole, without walking their cells.

use rayon::prelude::*;

use super::arch::Gather;
use super::camera::Camera;
use super::image::Image;
use super::lattice::{sample_range, IndexRay};
use super::occupancy::{Occupancy, BLOCK_SHIFT, CELL_SHIFT};
use super::ray_caster::{RayCaster, RayStats};
use super::sampler::TrilinearSampler;
use crate::with_voxels;

/// Rows per parallel work item, as the reference.
const TILE_ROWS: usize = 8;
/// Columns of the pixel tiles a band is traversed in, as the reference.
const TILE_COLS: usize = 8;
/// The longest occupied run marched before the ray's opacity is checked again: past that,
/// walking on through occupied cells would be wasted on a ray about to terminate.
const RUN_MAX: i32 = 64;

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
    /// `1 / (d·step)`: lattice indices per unit of index space along this axis, for the
    /// estimate of a plane crossing (the search settles it exactly).
    per_unit: f64,
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

    /// The first sample after `k` (and before `end`; `end` when none) whose cell `>> shift`
    /// differs from sample `k`'s, which is `b`.
    #[inline(always)]
    fn next(&self, k: i32, end: i32, shift: u32, b: u32) -> i32 {
        if self.d == 0.0 || k + 1 >= end {
            return end;
        }
        // The plane the ray leaves the cell by, in index space.
        let plane = if self.d > 0.0 {
            let p = (b + 1) << shift;
            if p as f32 > self.last {
                return end;
            }
            p
        } else {
            if b == 0 {
                return end;
            }
            b << shift
        };
        // Truncated, plus one: a ceiling for the estimate without a libm call.
        let guess = (f64::from(plane) - f64::from(self.o)) * self.per_unit;
        let guess = (guess.clamp(f64::from(k), f64::from(end - 1)) as i32 + 1).clamp(k + 1, end);
        first_true(k, end, guess, |j| self.cell(j) >> shift != b)
    }
}

/// The least `j` in `(lo, hi)` with `pred(j)`, `hi` when none, for `pred` false at `lo` and
/// monotone on `(lo, hi)`: gallops from `guess`, then bisects.
#[inline(always)]
fn first_true(mut lo: i32, mut hi: i32, guess: i32, pred: impl Fn(i32) -> bool) -> i32 {
    if guess < hi {
        if pred(guess) {
            hi = guess;
            let mut s = 1;
            while hi - s > lo {
                if pred(hi - s) {
                    hi -= s;
                    s *= 2;
                } else {
                    lo = hi - s;
                    break;
                }
            }
        } else {
            lo = guess;
            let mut s = 1;
            while lo + s < hi {
                if pred(lo + s) {
                    hi = lo + s;
                    break;
                }
                lo += s;
                s *= 2;
            }
        }
    }
    while hi - lo > 1 {
        let m = lo + (hi - lo) / 2;
        if pred(m) {
            hi = m;
        } else {
            lo = m;
        }
    }
    hi
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

    /// Walks samples `k0..k1` of `ray` through the occupancy cells, marching the occupied
    /// runs into `acc`.
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
        let axes: [Axis; 3] = std::array::from_fn(|a| Axis {
            o: ray.o[a],
            d: ray.d[a],
            step,
            max: tri.max[a],
            last: tri.last_cell[a] as f32,
            per_unit: 1.0 / (f64::from(ray.d[a]) * f64::from(step)),
        });
        let mut k = k0;
        // Per axis: the sample's occupancy cell, and the first sample in the next one.
        let mut cell = [0u32; 3];
        let mut next = [k1; 3];
        let enter = |k: i32, cell: &mut [u32; 3], next: &mut [i32; 3]| {
            for a in 0..3 {
                cell[a] = axes[a].cell(k) >> CELL_SHIFT;
                next[a] = axes[a].next(k, k1, CELL_SHIFT, cell[a]);
            }
        };
        enter(k, &mut cell, &mut next);
        // The occupied run being gathered: samples run..k.
        let mut run: Option<i32> = None;
        let march = |from: i32, to: i32, acc: &mut [f32; 4], st: &mut MarchStats| {
            st.rays.samples += self.march(tri, ray, (from, to), acc);
            acc[3] >= ert
        };
        while k < k1 {
            let shift = BLOCK_SHIFT - CELL_SHIFT;
            if !occ.block(cell.map(|c| c >> shift)) {
                if let Some(r) = run.take() {
                    if march(r, k, acc, st) {
                        return;
                    }
                }
                // Jump to the first sample in another block.
                let to = (0..3)
                    .map(|a| axes[a].next(k, k1, BLOCK_SHIFT, cell[a] >> shift))
                    .min()
                    .unwrap_or(k1);
                st.skipped_samples += (to - k) as u64;
                k = to;
                if k < k1 {
                    enter(k, &mut cell, &mut next);
                }
                continue;
            }
            let b = cell.map(|c| c >> shift);
            let dense = occ.dense(b);
            let to = if dense {
                // Through the whole block: the first sample in another.
                (0..3)
                    .map(|a| axes[a].next(k, k1, BLOCK_SHIFT, b[a]))
                    .min()
                    .unwrap_or(k1)
            } else {
                next[0].min(next[1]).min(next[2])
            };
            if dense || occ.cell(cell) {
                let r = *run.get_or_insert(k);
                if to - r >= RUN_MAX {
                    run = None;
                    if march(r, to, acc, st) {
                        return;
                    }
                }
            } else {
                if let Some(r) = run.take() {
                    if march(r, k, acc, st) {
                        return;
                    }
                }
                st.skipped_samples += (to - k) as u64;
            }
            k = to;
            if dense {
                if k < k1 {
                    enter(k, &mut cell, &mut next);
                }
                continue;
            }
            if k < k1 {
                for a in 0..3 {
                    if next[a] == k {
                        cell[a] = axes[a].cell(k) >> CELL_SHIFT;
                        next[a] = axes[a].next(k, k1, CELL_SHIFT, cell[a]);
                    }
                }
            }
        }
        if let Some(r) = run {
            march(r, k1, acc, st);
        }
    }
}
