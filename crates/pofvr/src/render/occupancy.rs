//! The occupancy the march engine skips empty space with: per 4³ trilinear cells, the value
//! range of the voxels their samples interpolate from (built once per volume), and, per
//! weights, which of those cells can hold a sample of nonzero opacity, with each cell's
//! chessboard distance to the nearest cell of the other kind (so that a ray can leap over
//! a whole cube of empty cells, or march through a cube of occupied ones, at one lookup).
//!
//! A sample at index position `x` interpolates the eight corners of trilinear cell
//! `i = min(⌊x⌋, dims − 2)` per axis (the sampler's clamp), so the voxels `i` and `i + 1`.
//! Occupancy cell `c` holds trilinear cells `4c .. 4c + 4`, so its samples read voxels
//! `4c ..= 4c + 4`: the range below is over that span, one-voxel apron included. A
//! trilinear value lies within its corners' range up to the rounding of three lerps (a few
//! ulps of the largest corner), which the test widens the range by; the classification bin
//! is monotone in the value, so a cell whose widened range falls only on bins of zero
//! opacity holds only samples of zero opacity, and the engine may skip them without
//! changing a bit of the image.

use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use super::transfer_function::{Classifier, ClassifierView, BIN_MAX, TF_BINS};
use crate::volume::{Volume, Voxel};
use crate::with_voxels;

/// Trilinear cells per occupancy cell along each axis.
pub const CELL: usize = 4;
/// log₂ of [`CELL`].
pub(crate) const CELL_SHIFT: u32 = 2;
/// The largest chessboard distance kept for an empty cell: a leap crosses at most
/// `2·EMPTY_CAP − 1` cells along an axis. Each unit costs one pass of the rebuild.
const EMPTY_CAP: u8 = 8;
/// [`EMPTY_CAP`] of the tables toward one octant: each unit costs half a pass.
pub(crate) const AHEAD_CAP: u8 = 16;
/// Zero bytes after the last of [`Occupancy::leaps`]' entries: a 32-bit gather at any
/// cell's entry (the sixteen-lane loop's, `arch::x86_64::gather16`) stays inside it.
pub(crate) const LEAP_PAD: usize = 3;
/// The bit of an [`Occupancy::leaps`] entry that marks an occupied cell.
pub(crate) const OCCUPIED: u8 = 0x80;

/// Trilinear cells per axis of a volume of `dims` voxels: `dims − 1`, and one cell (which
/// reads voxel 0 only) on a one-voxel axis — the sampler's `last_cell + 1`.
fn trilinear_cells(dims: [usize; 3]) -> [usize; 3] {
    dims.map(|d| d.saturating_sub(2) + 1)
}

/// The value range of every occupancy cell's voxels (see the [module](self)): what the
/// per-weights occupancy is rebuilt from. Built once per volume.
#[derive(Debug)]
pub struct CellRanges {
    /// Occupancy cells per axis.
    cells: [usize; 3],
    /// `[min, max]` per cell, x fastest.
    range: Vec<[f32; 2]>,
    /// The occupancy last built by [`CellRanges::occupancy`], with what it depends on: a
    /// viewer's frames while the camera moves keep their weights, and need no rebuild.
    last: Mutex<Option<(OccupancyKey, Arc<Occupancy>)>>,
}

impl Clone for CellRanges {
    fn clone(&self) -> Self {
        CellRanges {
            cells: self.cells,
            range: self.range.clone(),
            last: Mutex::new(None),
        }
    }
}

/// All of a classification that its [`Occupancy`] depends on: the value-to-bin map and
/// which bins have nonzero opacity.
#[derive(Debug, PartialEq)]
struct OccupancyKey {
    lo: u32,
    scale: u32,
    opaque: Vec<bool>,
}

impl OccupancyKey {
    fn of(cls: &Classifier) -> Self {
        let v = cls.view();
        OccupancyKey {
            lo: v.lo.to_bits(),
            scale: v.scale.to_bits(),
            opaque: v.rgba.iter().map(|s| s[3] != 0.0).collect(),
        }
    }
}

/// The voxels occupancy cell `c` reads along an axis of `n` voxels.
fn span(c: usize, n: usize) -> std::ops::RangeInclusive<usize> {
    let lo = c * CELL;
    lo..=(lo + CELL).min(n - 1)
}

impl CellRanges {
    /// Measures `volume`: separable passes, parallel over layers of cells: per layer, the
    /// voxel-wise range over its slices (z), then per cell row over its rows (y), then per
    /// cell over its columns (x). The first two are whole rows of minima and maxima in the
    /// stored type, which vectorise; each voxel is read once, the slice two layers share
    /// twice.
    #[must_use]
    pub fn new(volume: &Volume) -> Self {
        let dims = volume.dims();
        let cells = trilinear_cells(dims).map(|n| n.div_ceil(CELL));
        let [cx, cy, cz] = cells;
        let mut range = vec![[0f32; 2]; cx * cy * cz];
        with_voxels!(volume.data(), v => measure_layers(v, dims, cells, &mut range));
        CellRanges {
            cells,
            range,
            last: Mutex::new(None),
        }
    }

    /// The occupancy under `cls` ([`Occupancy::new`]), reused while the classification's
    /// opaque bins stay the same.
    #[must_use]
    pub fn occupancy(&self, cls: &Classifier) -> Arc<Occupancy> {
        let key = OccupancyKey::of(cls);
        let mut last = self
            .last
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some((k, occ)) = last.as_ref() {
            if *k == key {
                return Arc::clone(occ);
            }
        }
        let occ = Arc::new(Occupancy::new(self, cls));
        *last = Some((key, Arc::clone(&occ)));
        occ
    }

    /// Occupancy cells per axis.
    #[must_use]
    pub fn cells(&self) -> [usize; 3] {
        self.cells
    }

    /// `[min, max]` of the voxels the samples of cell `c` interpolate from.
    #[must_use]
    pub fn range(&self, c: [usize; 3]) -> [f32; 2] {
        self.range[(c[2] * self.cells[1] + c[1]) * self.cells[0] + c[0]]
    }
}

/// [`CellRanges::new`] for voxels of type `T`: `range` takes the cells x fastest.
fn measure_layers<T: Voxel>(v: &[T], dims: [usize; 3], cells: [usize; 3], range: &mut [[f32; 2]]) {
    let [nx, ny, nz] = dims;
    let [cx, cy, _] = cells;
    let slice = nx * ny;
    range.par_chunks_mut(cx * cy).enumerate().for_each_init(
        || (Vec::with_capacity(slice), Vec::with_capacity(slice)),
        |(lo, hi): &mut (Vec<T>, Vec<T>), (z, out)| {
            // z: the layer's slices, voxel by voxel.
            let mut slices = span(z, nz).map(|s| &v[s * slice..][..slice]);
            let first = slices.next().expect("a cell spans at least one slice");
            lo.clear();
            lo.extend_from_slice(first);
            hi.clear();
            hi.extend_from_slice(first);
            for s in slices {
                fold_rows(lo, hi, s, s);
            }
            for (c, out) in out.chunks_exact_mut(cx).enumerate() {
                // y: the cell row's rows, folded into its first. Row `y0` is the last
                // row of the cell row before, which has already read it.
                let y0 = c * CELL;
                for y in span(c, ny).skip(1) {
                    let (ld, ls) = lo.split_at_mut(y * nx);
                    let (hd, hs) = hi.split_at_mut(y * nx);
                    let (ld, hd) = (&mut ld[y0 * nx..][..nx], &mut hd[y0 * nx..][..nx]);
                    fold_rows(ld, hd, &ls[..nx], &hs[..nx]);
                }
                // x: each cell's columns.
                let (l, h) = (&lo[y0 * nx..][..nx], &hi[y0 * nx..][..nx]);
                for (x, o) in out.iter_mut().enumerate() {
                    let s = span(x, nx);
                    let a = l[s.clone()].iter().copied().reduce(T::min_of);
                    let b = h[s].iter().copied().reduce(T::max_of);
                    *o = [a, b].map(|q| q.expect("a cell spans a voxel").to_f32());
                }
            }
        },
    );
}

/// `lo[i] = min(lo[i], slo[i])` and `hi[i] = max(hi[i], shi[i])`.
fn fold_rows<T: Voxel>(lo: &mut [T], hi: &mut [T], slo: &[T], shi: &[T]) {
    for (l, &x) in lo.iter_mut().zip(slo) {
        *l = l.min_of(x);
    }
    for (h, &x) in hi.iter_mut().zip(shi) {
        *h = h.max_of(x);
    }
}

/// Which value ranges can hold a sample of nonzero opacity under one classification: the
/// one test behind [`Occupancy`] and `bench frame`'s floor of samples per ray.
pub(crate) struct OpaqueBins<'c> {
    view: ClassifierView<'c>,
    /// Bins of nonzero opacity below each bin.
    below: Vec<u32>,
}

impl<'c> OpaqueBins<'c> {
    pub(crate) fn new(cls: &'c Classifier) -> Self {
        let view = cls.view();
        let mut below = vec![0u32; TF_BINS + 1];
        for (b, s) in view.rgba.iter().enumerate() {
            below[b + 1] = below[b] + u32::from(s[3] != 0.0);
        }
        OpaqueBins { view, below }
    }

    /// Whether a trilinear value interpolated from corners within `[lo, hi]` can have
    /// nonzero opacity: some bin of the widened range is opaque.
    #[inline(always)]
    pub(crate) fn any(&self, lo: f32, hi: f32) -> bool {
        // The classifier's bin of `v` (`ClassifierView::sample`), monotone in `v`; not
        // clamp, as there: `max` maps NaN to bin 0.
        #[allow(clippy::manual_clamp)]
        let bin = |v: f32| {
            let b = ((v - self.view.lo) * self.view.scale).max(0.0).min(BIN_MAX);
            // SAFETY: `b` is in [0, BIN_MAX] (NaN became 0), so it converts exactly; the
            // checked conversion kept the loop from vectorising.
            unsafe { b.to_int_unchecked::<u32>() as usize }
        };
        // The rounding of the trilinear lerps stays within a few ulps of the largest
        // corner; widen by more than that.
        let m = lo.abs().max(hi.abs()) * (8.0 * f32::EPSILON) + f32::MIN_POSITIVE;
        self.below[bin(hi + m) + 1] > self.below[bin(lo - m)]
    }
}

/// Which cells can hold a sample of nonzero opacity under one classification, and how far
/// each cell is from one of the other kind: rebuilt from [`CellRanges`] whenever the
/// weights (or the step) change.
#[derive(Clone, Debug)]
pub struct Occupancy {
    cells: [usize; 3],
    cell: Vec<bool>,
    /// Per cell: [`OCCUPIED`] when occupied, or'ed with the chessboard distance (in cells,
    /// at least 1, capped) to the nearest cell of the other kind; an empty cell's distance
    /// to the nearest occupied one is capped at [`EMPTY_CAP`], an occupied cell's to the
    /// nearest empty one at [`OCCUPIED_CAP`]. Every cell within `distance − 1` of a cell
    /// (on every axis) is of its kind. Followed by [`LEAP_PAD`] zero bytes.
    leap: Vec<u8>,
    /// The leap tables toward each octant asked for so far ([`Occupancy::leaps_toward`]),
    /// by octant (bit `a` set where the sign along axis `a` is negative).
    toward: Arc<[std::sync::OnceLock<Vec<u8>>; 8]>,
}

impl Occupancy {
    /// The occupancy of `ranges` under `cls`: a cell is occupied when some bin its widened
    /// range falls on has nonzero opacity.
    #[must_use]
    pub fn new(ranges: &CellRanges, cls: &Classifier) -> Self {
        let opaque = OpaqueBins::new(cls);
        let mut cell = vec![false; ranges.range.len()];
        // In runs of plain loops: one iterator step per cell took 1.6 times as long.
        cell.par_chunks_mut(1 << 14)
            .zip(ranges.range.par_chunks(1 << 14))
            .for_each(|(out, range)| {
                for (o, &[lo, hi]) in out.iter_mut().zip(range) {
                    *o = opaque.any(lo, hi);
                }
            });
        let cells = ranges.cells;
        let leap = leap_table(&cell, cells);
        Occupancy {
            cells,
            cell,
            leap,
            toward: Arc::new(Default::default()),
        }
    }

    /// Occupancy cells per axis.
    #[must_use]
    pub(crate) fn dims(&self) -> [usize; 3] {
        self.cells
    }

    /// Whether occupancy cell `c` can hold a sample of nonzero opacity.
    #[inline(always)]
    #[must_use]
    pub fn cell(&self, c: [u32; 3]) -> bool {
        let [cx, cy, _] = self.cells;
        self.cell[(c[2] as usize * cy + c[1] as usize) * cx + c[0] as usize]
    }

    /// Every cell's leap entry (see the field), x fastest, and [`LEAP_PAD`] bytes after
    /// the last.
    #[must_use]
    pub(crate) fn leaps(&self) -> &[u8] {
        &self.leap
    }

    /// The leap entries toward `sign` (each ±1): for rays whose direction along each axis
    /// is 0 or of that sign, an empty cell's distance `D` is to the nearest occupied cell
    /// ahead, so every cell of `c + sign·[0, D − 1]` is empty. Built on first use.
    #[must_use]
    pub(crate) fn leaps_toward(&self, sign: [i8; 3]) -> &[u8] {
        let o = (0..3).map(|a| usize::from(sign[a] < 0) << a).sum::<usize>();
        self.toward[o].get_or_init(|| leap_table_toward(&self.cell, self.cells, sign))
    }

    /// Occupied cells, and all cells.
    #[must_use]
    pub fn occupied_cells(&self) -> (usize, usize) {
        (self.cell.iter().filter(|c| **c).count(), self.cell.len())
    }
}

/// The [`Occupancy::leaps`] of cells `cell` (occupied or not, x fastest) on a grid of
/// `cells`: [`OCCUPIED`] for an occupied cell, else its chessboard distance to the
/// nearest occupied one, capped; then [`LEAP_PAD`] zero bytes.
pub(crate) fn leap_table(cell: &[bool], cells: [usize; 3]) -> Vec<u8> {
    leaps_of(cell, cells, EMPTY_CAP, [0; 3])
}

/// [`leap_table`] with distances to occupied cells toward `sign` ([`chessboard_toward`]),
/// capped at `cap`.
fn leaps_of(cell: &[bool], cells: [usize; 3], cap: u8, sign: [i8; 3]) -> Vec<u8> {
    let to_occupied = chessboard_toward(cell, true, cells, cap, sign);
    let mut leap: Vec<u8> = cell
        .par_iter()
        .zip(&to_occupied)
        .map(|(&occ, &e)| if occ { OCCUPIED } else { e })
        .collect();
    leap.resize(leap.len() + LEAP_PAD, 0);
    leap
}

/// [`leap_table`] toward `sign` (each ±1): an empty cell's entry is the distance to the
/// nearest occupied cell ahead of it ([`chessboard_toward`]), capped at [`AHEAD_CAP`].
pub(crate) fn leap_table_toward(cell: &[bool], cells: [usize; 3], sign: [i8; 3]) -> Vec<u8> {
    leaps_of(cell, cells, AHEAD_CAP, sign)
}

/// Per cell of a grid of `dims`, the chessboard distance to the nearest cell whose `kind`
/// is `seed` (0 for those cells), capped at `cap` (also where there is none).
///
/// The distance is `min` over seeds of `max(|Δx|, |Δy|, |Δz|)`, and as `max(a, ·)` is
/// monotone the minimum separates: along x, `d(x) = min_j max(|j|, s(x + j))` from the seed
/// indicator (0 or `cap`), then the same along y of that, then along z. Capped, the window
/// is `|j| < cap`; each pass is `2·(cap − 1)` runs of byte minima and maxima over shifted
/// rows or slices, which the compiler vectorises.
#[cfg(test)]
pub(super) fn chessboard(kind: &[bool], seed: bool, dims: [usize; 3], cap: u8) -> Vec<u8> {
    chessboard_toward(kind, seed, dims, cap, [0; 3])
}

/// [`chessboard`] over the seeds on one side only along the axes of nonzero `sign`: the
/// distance to the nearest seed `c + Δ` with `Δ[a]·sign[a] ≥ 0` (both sides where
/// `sign[a]` is 0); the box `c + sign·[0, D − 1]` then holds no seed.
pub(super) fn chessboard_toward(
    kind: &[bool],
    seed: bool,
    dims: [usize; 3],
    cap: u8,
    sign: [i8; 3],
) -> Vec<u8> {
    let [nx, ny, _] = dims;
    let slice = nx * ny;
    let mut d: Vec<u8> = kind
        .par_iter()
        .map(|&k| if k == seed { 0 } else { cap })
        .collect();
    let w = usize::from(cap.saturating_sub(1));
    if d.is_empty() || w == 0 {
        return d;
    }
    // x, then y, within each slice.
    d.par_chunks_mut(slice).for_each(|s| {
        let mut src = s.to_vec();
        for (out, row) in s.chunks_exact_mut(nx).zip(src.chunks_exact(nx)) {
            for j in 1..=w.min(nx - 1) {
                let n = nx - j;
                if sign[0] >= 0 {
                    min_max_into(&mut out[..n], &row[j..], j as u8);
                }
                if sign[0] <= 0 {
                    min_max_into(&mut out[j..], &row[..n], j as u8);
                }
            }
        }
        src.copy_from_slice(s);
        for j in 1..=w.min(ny - 1) {
            let n = (ny - j) * nx;
            if sign[1] >= 0 {
                min_max_into(&mut s[..n], &src[j * nx..], j as u8);
            }
            if sign[1] <= 0 {
                min_max_into(&mut s[j * nx..], &src[..n], j as u8);
            }
        }
    });
    // z, across slices.
    let src = d.clone();
    let nz = d.len() / slice;
    d.par_chunks_mut(slice).enumerate().for_each(|(z, out)| {
        for j in 1..=w.min(nz - 1) {
            let back = z.checked_sub(j).filter(|_| sign[2] <= 0);
            let ahead = Some(z + j).filter(|&zz| zz < nz && sign[2] >= 0);
            for zz in [back, ahead].into_iter().flatten() {
                min_max_into(out, &src[zz * slice..][..slice], j as u8);
            }
        }
    });
    d
}

/// `a[i] = min(a[i], max(b[i], j))`.
fn min_max_into(a: &mut [u8], b: &[u8], j: u8) {
    for (x, y) in a.iter_mut().zip(b) {
        *x = (*x).min((*y).max(j));
    }
}
