//! The low-resolution proxy predictor: the volume's mean extinction per basis over cells
//! of [`PROXY_CELL`]³ voxels, marched per pixel at frame time to predict where each ray's
//! opacity reaches the cull threshold; a brick is predicted hidden when every ray that
//! meets it enters it beyond that depth.
//!
//! Why a mean and not a bound: air in the lungs or around the body zeroes the minimum of
//! almost every cell of a CT, so a bound predicts nothing; the mean extinction is what a
//! ray crossing the cell meets on average. It may be wrong either way, which is what
//! verification is for ([`super::verify`]): a wrong guess costs a repair, never a pixel.

use rayon::prelude::*;

use crate::brick::{BrickGrid, BrickId};
use crate::render::{Camera, IndexRay, PixelRect, SampledTf};
use crate::volume::{Volume, Voxel};
use crate::with_voxels;

use super::FrameBricks;

/// Edge of a proxy cell in voxels: fine enough to place a surface within a quarter of a
/// 16³ brick, coarse enough that a 512-cell ray crosses a few hundred cells.
pub const PROXY_CELL: usize = 4;

/// The optical depth a ray must reach in the proxy, in multiples of the threshold's
/// (`−ln(1 − threshold)`), before the bricks behind are predicted hidden.
///
/// Why more than one: a cell's mean extinction overstates what a ray crossing it meets
/// (the mean of the transmittances exceeds the transmittance of the mean), most where
/// opaque voxels share a cell with empty ones, at every surface; a wrong hidden guess costs
/// a repair, a brick rendered for nothing only its ray casting.
pub const PROXY_DEPTH_FACTOR: f32 = 3.0;

/// The proxy of a volume for one family: per basis, the mean extinction of each cell's
/// voxels. It depends on the bases, not on the weights, so a job builds it once.
#[derive(Clone, Debug)]
pub struct Proxy {
    /// Cells per axis.
    cells: [usize; 3],
    /// Per basis, the mean extinction per unit length of each cell (x fastest).
    tau: Vec<Vec<f32>>,
}

impl Proxy {
    /// Measures `volume` with the family tabulated in `sampled`: one pass over the voxels,
    /// parallel over slabs of cells.
    #[must_use]
    pub fn new(volume: &Volume, sampled: &SampledTf) -> Self {
        let dims = volume.dims();
        let cells = dims.map(|n| n.div_ceil(PROXY_CELL));
        let [cx, cy, cz] = cells;
        let bases = sampled.basis_count();
        // Per slab of cells along z, per basis, the slab's cells.
        let slabs: Vec<Vec<Vec<f32>>> = with_voxels!(volume.data(), v => {
            (0..cz).into_par_iter().map(|z| slab(v, dims, cells, z, sampled)).collect()
        });
        let mut tau = vec![Vec::with_capacity(cx * cy * cz); bases];
        for s in slabs {
            for (t, b) in tau.iter_mut().zip(s) {
                t.extend(b);
            }
        }
        Proxy { cells, tau }
    }

    /// As [`Proxy::new`] (the same proxy), for a volume of `dims` voxels read slab by slab
    /// with `read(z0, planes)`, which gives the voxels of planes `z0..z0 + planes`, x
    /// fastest: a volume larger than memory is streamed once, about `slab_planes` planes
    /// at a time.
    ///
    /// # Errors
    /// The first error of `read`.
    pub fn from_slabs<E>(
        dims: [usize; 3],
        sampled: &SampledTf,
        slab_planes: usize,
        read: &dyn Fn(usize, usize) -> Result<crate::volume::VoxelData, E>,
    ) -> Result<Self, E> {
        let cells = dims.map(|n| n.div_ceil(PROXY_CELL));
        let [cx, cy, cz] = cells;
        let per_read = (slab_planes / PROXY_CELL).max(1);
        let mut tau = vec![Vec::with_capacity(cx * cy * cz); sampled.basis_count()];
        for first in (0..cz).step_by(per_read) {
            let layers = per_read.min(cz - first);
            let z0 = first * PROXY_CELL;
            let planes = (layers * PROXY_CELL).min(dims[2] - z0);
            let data = read(z0, planes)?;
            let sdims = [dims[0], dims[1], planes];
            let slabs: Vec<Vec<Vec<f32>>> = with_voxels!(&data, v => {
                (0..layers).into_par_iter().map(|z| slab(v, sdims, cells, z, sampled)).collect()
            });
            for s in slabs {
                for (t, b) in tau.iter_mut().zip(s) {
                    t.extend(b);
                }
            }
        }
        Ok(Proxy { cells, tau })
    }

    /// Cells per axis.
    #[must_use]
    pub fn cells(&self) -> [usize; 3] {
        self.cells
    }

    /// The extinction of every cell at `weights`: `Σ kᵢ τᵢ`.
    #[must_use]
    pub fn extinction(&self, weights: &[f32]) -> Vec<f32> {
        let n = self.cells.iter().product();
        let mut sum = vec![0f32; n];
        for (t, k) in self.tau.iter().zip(weights) {
            if *k > 0.0 {
                for (s, x) in sum.iter_mut().zip(t) {
                    *s += k * x;
                }
            }
        }
        sum
    }

    /// The `t` at which `ray`'s optical depth through the cells of `ext` reaches `depth`;
    /// infinite when it never does.
    #[must_use]
    pub fn termination(&self, ext: &[f32], ray: &IndexRay, depth: f32) -> f32 {
        let hi = self.cells.map(|c| (c * PROXY_CELL) as f32);
        let (mut t0, mut t1) = (0f32, f32::INFINITY);
        for ((&o, &d), &hi) in ray.o.iter().zip(&ray.d).zip(&hi) {
            if d == 0.0 {
                if o < 0.0 || o >= hi {
                    return f32::INFINITY;
                }
                continue;
            }
            let (ta, tb) = ((0.0 - o) / d, (hi - o) / d);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        if t0 >= t1 {
            return f32::INFINITY;
        }
        let edge = PROXY_CELL as f32;
        let p = |a: usize, t: f32| ray.o[a] + t * ray.d[a];
        let mut cell: [i64; 3] = std::array::from_fn(|a| {
            let x = (p(a, t0 + (t1 - t0) * 1e-6) / edge).floor() as i64;
            x.clamp(0, self.cells[a] as i64 - 1)
        });
        let step: [i64; 3] = std::array::from_fn(|a| {
            if ray.d[a] > 0.0 {
                1
            } else if ray.d[a] < 0.0 {
                -1
            } else {
                0
            }
        });
        // The t of the next cell face crossed along each axis.
        let next = |a: usize, c: i64| -> f32 {
            if step[a] == 0 {
                return f32::INFINITY;
            }
            let face = if step[a] > 0 { c + 1 } else { c } as f32 * edge;
            (face - ray.o[a]) / ray.d[a]
        };
        let mut t_next: [f32; 3] = std::array::from_fn(|a| next(a, cell[a]));
        let (mut t, mut acc) = (t0, 0f32);
        let [nx, ny, _] = self.cells;
        loop {
            let i = (cell[2] as usize * ny + cell[1] as usize) * nx + cell[0] as usize;
            let a = (0..3)
                .min_by(|&x, &y| t_next[x].total_cmp(&t_next[y]))
                .unwrap_or(0);
            let out = t_next[a].min(t1);
            let e = ext[i];
            let add = e * (out - t).max(0.0);
            if acc + add >= depth && e > 0.0 {
                return t + (depth - acc) / e;
            }
            acc += add;
            t = out;
            if t >= t1 {
                return f32::INFINITY;
            }
            cell[a] += step[a];
            if cell[a] < 0 || cell[a] >= self.cells[a] as i64 {
                return f32::INFINITY;
            }
            t_next[a] = next(a, cell[a]);
        }
    }

    /// Predicts which bricks over `tile` are hidden at `threshold`: each pixel's ray is
    /// marched through the proxy to where its opacity would reach the threshold, and a
    /// brick is predicted hidden when every ray of the tile that meets it enters it at or
    /// beyond that depth. Returns (visible, culled), each in visibility order.
    #[must_use]
    pub fn predict(
        &self,
        (volume, grid): (&Volume, &BrickGrid),
        (camera, bricks): (&Camera, &FrameBricks),
        weights: &[f32],
        tile: PixelRect,
        threshold: f32,
    ) -> (Vec<BrickId>, Vec<BrickId>) {
        if tile.area() == 0 {
            return (Vec::new(), Vec::new());
        }
        let frame = camera.frame();
        let ext = self.extinction(weights);
        let depth = -(1.0 - threshold.min(0.999_999)).ln() * PROXY_DEPTH_FACTOR;
        let tw = tile.width() as usize;
        let ray_at = |x: u32, y: u32| {
            IndexRay::new(
                &camera.ray(&frame, f64::from(x) + 0.5, f64::from(y) + 0.5),
                volume.spacing(),
                volume.unit(),
            )
        };
        // Each pixel's ray and where it is predicted to end; rays are kept, since every
        // brick over a pixel asks for its span along it.
        let ends: Vec<(IndexRay, f32)> = (0..tile.area())
            .into_par_iter()
            .with_min_len(256)
            .map(|i| {
                let (x, y) = (tile.x0 + (i % tw) as u32, tile.y0 + (i / tw) as u32);
                let ray = ray_at(x, y);
                let end = self.termination(&ext, &ray, depth);
                (ray, end)
            })
            .collect();
        let over: Vec<(BrickId, PixelRect)> = bricks
            .order
            .iter()
            .filter_map(|&id| {
                bricks.footprints[id.index()]
                    .and_then(|r| r.intersect(&tile))
                    .map(|r| (id, r))
            })
            .collect();
        let hidden: Vec<bool> = over
            .par_iter()
            .map(|&(id, rect)| {
                let ib = grid.index_box(id);
                (rect.y0..rect.y1).all(|y| {
                    (rect.x0..rect.x1).all(|x| {
                        let (ray, end) =
                            &ends[(y - tile.y0) as usize * tw + (x - tile.x0) as usize];
                        let end = *end;
                        end.is_finite()
                            && match ray.span(&ib) {
                                None => true,
                                Some((t0, t1)) => t1 <= t0 || t0 >= end,
                            }
                    })
                })
            })
            .collect();
        let (mut visible, mut culled) = (Vec::new(), Vec::new());
        for ((id, _), h) in over.iter().zip(hidden) {
            if h {
                culled.push(*id);
            } else {
                visible.push(*id);
            }
        }
        (visible, culled)
    }
}

/// One slab of cells (cell row `z`), per basis: the mean extinction of each cell's voxels.
fn slab<T: Voxel>(
    v: &[T],
    [nx, ny, nz]: [usize; 3],
    [cx, cy, _]: [usize; 3],
    z: usize,
    sampled: &SampledTf,
) -> Vec<Vec<f32>> {
    let bases = sampled.basis_count();
    let tables: Vec<&[f32]> = (0..bases).map(|b| sampled.tau_table(b)).collect();
    let mut sums = vec![vec![0f64; cx * cy]; bases];
    let mut counts = vec![0u32; cx * cy];
    for zz in z * PROXY_CELL..((z + 1) * PROXY_CELL).min(nz) {
        for y in 0..ny {
            let row = &v[(zz * ny + y) * nx..][..nx];
            let base = (y / PROXY_CELL) * cx;
            for (x, voxel) in row.iter().enumerate() {
                let c = base + x / PROXY_CELL;
                let bin = sampled.bin(voxel.to_f32());
                for (s, t) in sums.iter_mut().zip(&tables) {
                    s[c] += f64::from(t[bin]);
                }
                counts[c] += 1;
            }
        }
    }
    sums.into_iter()
        .map(|s| {
            s.into_iter()
                .zip(&counts)
                .map(|(x, n)| (x / f64::from((*n).max(1))) as f32)
                .collect()
        })
        .collect()
}
