//! Exact leaps over empty space for one ray: which occupancy cell the sampler puts a
//! lattice sample in, and how far past a cube of empty cells the ray may jump without
//! dropping a sample of nonzero opacity. The march engine's walk ([`super::march`]) leaps by
//! it, and the AVX2 packet loop (`arch/x86_64/packet.rs`) by the same rule, lane-wise.
//!
//! A sample's position along each axis, `o + (k·step)·d` in f32, is monotone in the lattice
//! index `k` (every float operation in it is monotone), and so is its trilinear cell (the
//! sampler's clamp and floor). An empty cell at distance `D` from every occupied one is the
//! centre of a cube of `2D − 1` empty cells per axis; the leap estimates in float where the
//! ray leaves that cube, and is taken only once the last sample of the leap is found, by the
//! sampler's own cell, inside the cube: then every sample between is inside too, and
//! classifies to zero opacity, which composites to nothing.

use super::lattice::IndexRay;
use super::occupancy::{Occupancy, CELL_SHIFT, OCCUPIED};
use super::sampler::TrilinearSampler;

/// The least chessboard distance to an occupied cell at which an empty cell is leapt
/// over, with the cube of empty cells around it; closer to occupied ones, leaps are too
/// short to pay for themselves.
pub(crate) const LEAP_MIN: i32 = 2;

/// One axis of a ray's samples: the sampler's position, clamp and cell, per lattice index.
#[derive(Clone, Copy)]
struct Axis {
    o: f32,
    d: f32,
    /// `1 / d`, or 0 where `d` is 0 (the estimates only).
    inv: f32,
    /// The volume's last index (the position clamp).
    max: f32,
    /// The last trilinear cell.
    last: f32,
}

/// A ray's samples against one [`Occupancy`]: cells and leaps.
pub(crate) struct Skip<'o> {
    /// [`Occupancy::leaps`] of every cell, x fastest.
    pub(crate) leap: &'o [u8],
    /// Occupancy cells per axis.
    pub(crate) n: [i32; 3],
    axes: [Axis; 3],
    step: f32,
    inv_step: f32,
    /// Lattice samples leapt over (or left out as a group of empty cells) so far.
    pub(crate) skipped: u64,
}

/// `max(a, b)` for numbers that are not NaN: one `maxss`, where `f32::max` also handles
/// NaN (positions and estimates here never are, and the sampler's own vector clamp agrees
/// with this one on everything else, up to the sign of a zero the cell's floor drops).
#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// `min(a, b)` for numbers that are not NaN (see [`max`]).
#[inline(always)]
fn min(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

impl<'o> Skip<'o> {
    /// For rays sampled by `tri` (the whole volume's sampler) every `step`, against `occ`
    /// (built for that volume); [`Skip::aim`] sets the ray.
    pub(crate) fn new<T>(occ: &'o Occupancy, tri: &TrilinearSampler<'_, T>, step: f32) -> Self {
        let axis = |a: usize| Axis {
            o: 0.0,
            d: 0.0,
            inv: 0.0,
            max: tri.max[a],
            last: tri.last_cell[a] as f32,
        };
        Skip {
            leap: occ.leaps(),
            n: occ.dims().map(|n| n as i32),
            axes: [axis(0), axis(1), axis(2)],
            step,
            inv_step: 1.0 / step,
            skipped: 0,
        }
    }

    /// Follows `ray` from now on.
    #[inline(always)]
    pub(crate) fn aim(&mut self, ray: &IndexRay) {
        for (a, x) in self.axes.iter_mut().enumerate() {
            x.o = ray.o[a];
            x.d = ray.d[a];
            x.inv = if ray.d[a] == 0.0 { 0.0 } else { 1.0 / ray.d[a] };
        }
    }

    /// The occupancy cell of sample `k` per axis, from its trilinear cell as
    /// [`TrilinearSampler::sample`] finds it.
    #[inline(always)]
    pub(crate) fn cell(&self, k: i32) -> [i32; 3] {
        let t = k as f32 * self.step;
        self.axes.map(|a| {
            let p = a.o + t * a.d;
            let c = min(min(max(p, 0.0), a.max), a.last);
            // SAFETY: c is finite and in [0, last] (rays and positions are finite).
            (unsafe { c.to_int_unchecked::<u32>() } >> CELL_SHIFT) as i32
        })
    }

    /// The leap entry ([`Occupancy::leaps`]) of cell `c`.
    #[inline(always)]
    pub(crate) fn leap_of(&self, c: [i32; 3]) -> u8 {
        self.leap[((c[2] * self.n[1] + c[1]) * self.n[0] + c[0]) as usize]
    }

    /// Whether `leap` (an [`Occupancy::leaps`] entry) marks an empty cell far enough from
    /// every occupied one to leap from.
    #[inline(always)]
    pub(crate) fn leaps(leap: u8) -> bool {
        leap & OCCUPIED == 0 && i32::from(leap) >= LEAP_MIN
    }

    /// Sample `k` lies in the empty cell `c`, whose entry `leap` passes [`Skip::leaps`]:
    /// the first sample, in `k + 1 ..= k1`, past the cube of empty cells around `c` — every
    /// sample before it from `k` on is in the cube, checked by the sampler's own cells.
    #[inline(always)]
    pub(crate) fn leap_end(&self, k: i32, c: [i32; 3], leap: u8, k1: i32) -> i32 {
        let r = i32::from(leap) - 1;
        let mut lo = [0i32; 3];
        let mut hi = [0i32; 3];
        // The `t` at which the ray leaves cells `lo..=hi`: the least over the axes, each
        // infinite where the ray would leave the grid (clamped samples stay in its last
        // cell). Only an estimate.
        let mut te = f32::INFINITY;
        for (a, x) in self.axes.iter().enumerate() {
            lo[a] = (c[a] - r).max(0);
            hi[a] = (c[a] + r).min(self.n[a] - 1);
            let face = if x.d > 0.0 && hi[a] < self.n[a] - 1 {
                (hi[a] + 1) << CELL_SHIFT
            } else if x.d < 0.0 && lo[a] > 0 {
                lo[a] << CELL_SHIFT
            } else {
                continue;
            };
            te = min(te, (face as f32 - x.o) * x.inv);
        }
        // The first sample at or past `te`, and at least the next one.
        let q = max(min(te * self.inv_step, k1 as f32), 0.0);
        // SAFETY: q is finite (te is a finite product or infinite, then k1) and in [0, k1].
        let kq = unsafe { q.to_int_unchecked::<i32>() };
        let mut kb = (kq + i32::from((kq as f32) < q)).max(k + 1).min(k1);
        let inside = |k: i32| {
            let c = self.cell(k);
            (0..3).all(|a| lo[a] <= c[a] && c[a] <= hi[a])
        };
        // Settled by one sample where a rounding put the estimate past a face.
        if !inside(kb - 1) {
            kb -= 1;
            if !inside(kb - 1) {
                kb = k + 1;
            }
        }
        kb
    }
}
