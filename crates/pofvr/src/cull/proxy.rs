//! The low-resolution proxy predictor: per cell of [`PROXY_CELL`]³ voxels
//! ([`COARSE_PROXY_CELL`]³ on large volumes, [`proxy_cell`]), a few value
//! groups (the cell's voxels sorted by value, split in [`PROXY_GROUPS`] equal shares) with
//! each group's mean extinction per basis. At frame time each cell gets an *effective*
//! extinction from its groups, sample rays are marched through the cells to predict where
//! their opacity reaches the cull threshold, and a brick is predicted hidden when every
//! sample ray that meets it enters it beyond that depth.
//!
//! Why groups and not the cell's mean: a ray crossing a cell half air, half bone meets
//! either the air or the bone over a stretch, not their average. With a material that
//! holds over a correlation length ℓ ([`CORRELATION_LENGTH`]), a ray's transmittance over
//! ℓ is the mean of the groups' transmittances, `Σ fᵍ e^(−eᵍℓ)`, which exceeds the
//! transmittance of the mean extinction (Jensen); the cell's effective extinction is
//! `−ln(Σ fᵍ e^(−eᵍℓ)) / ℓ`. The mean overstates opacity at every surface, which made the
//! mean proxy guess hidden too early there and forced a safety factor that then
//! under-predicted everywhere else; the effective extinction needs none.
//!
//! Why a distribution and not a bound: air in the lungs or around the body zeroes the
//! minimum of almost every cell of a CT, so a bound predicts nothing. The prediction may be
//! wrong either way, which is what verification is for ([`super::verify`]): a wrong guess
//! costs a repair, never a pixel.

use std::sync::{Arc, Mutex, OnceLock};

use rayon::prelude::*;

use crate::brick::{BrickGrid, BrickId};
use crate::render::transfer_function::TF_BINS;
use crate::render::{Camera, IndexRay, PixelRect, SampledTf};
use crate::volume::{Volume, Voxel};
use crate::with_voxels;

use super::proxy_march::Extinction;
use super::FrameBricks;

/// Edge of a proxy cell in voxels, for volumes of at most [`FINE_PROXY_VOXELS`] voxels: fine
/// enough to resolve the cortex's sulci, which let single rays deep between 4³ cells
/// (measured on `ch2better_mri`, docs/culling.md: the opaque family renders 1.5 points over
/// the oracle instead of 2.2, at fewer repairs; the CTs predict the same).
pub const PROXY_CELL: usize = 2;

/// Edge of a proxy cell in voxels for larger volumes ([`proxy_cell`]): 2³ cells cost about
/// half a byte of slots per voxel plus their groups (four bytes per voxel and basis where
/// some basis sees the cell), more than an i16 volume; 4³ cells an eighth of that.
pub const COARSE_PROXY_CELL: usize = 4;

/// The most voxels (64 Mi, e.g. 400³) whose proxy has [`PROXY_CELL`]-voxel cells: its slots
/// then take at most 32 MiB.
pub const FINE_PROXY_VOXELS: usize = 1 << 26;

/// The cell edge of the proxy of a volume of `dims` voxels: [`PROXY_CELL`] up to
/// [`FINE_PROXY_VOXELS`] voxels, [`COARSE_PROXY_CELL`] above, so that a proxy costs a small
/// share of a large volume's memory. Depends on the dimensions only, so a streamed and a
/// mapped proxy of one volume agree.
#[must_use]
pub fn proxy_cell(dims: [usize; 3]) -> usize {
    let voxels = dims.iter().fold(1usize, |a, &n| a.saturating_mul(n));
    if voxels <= FINE_PROXY_VOXELS {
        PROXY_CELL
    } else {
        COARSE_PROXY_CELL
    }
}

/// Value groups per cell: enough to tell air, soft tissue and bone apart in one cell.
pub const PROXY_GROUPS: usize = 4;

/// The length (in ray `t`, about a voxel) over which a ray is taken to stay in one value
/// group of a cell: 16 voxels, four coarse cells. Longer than a cell because tissue is correlated beyond
/// it: a ray that enters the air of a sulcus or between ribs stays in it for a while.
/// Measured against 4, 8 and 32 on the sweep targets (docs/culling.md): 16 repairs least
/// for what it renders.
pub const CORRELATION_LENGTH: f32 = 16.0;

/// The optical depth a ray must reach in the proxy, in multiples of the threshold's
/// (`−ln(1 − threshold)`), before the bricks behind are predicted hidden (after
/// [`PROXY_MARGIN`] more): the threshold's own, the margin being a length.
pub const PROXY_DEPTH_FACTOR: f32 = 1.0;

/// How far (in world units: millimetres for medical volumes) beyond the depth where the
/// proxy says a ray reaches the threshold the bricks are still taken as visible
/// ([`margin_length`] turns it into ray `t`).
///
/// Why a length and not a factor on the optical depth: a brick is hidden only if *every*
/// ray over it is opaque in front of it, and what the proxy gets wrong is *where* a ray
/// meets the surface that stops it (a surface placed within a cell, a single ray slipping
/// down a sulcus), a matter of distance whatever the material. A factor on the depth gave an
/// opaque tissue (the MRI's grey matter, 0.7 per voxel) a margin of 2 voxels and a faint
/// one (the CTs' soft tissue, 0.13 per voxel) of 12: the MRI needed more, the CTs were
/// over-cautious.
///
/// Why in world units and not voxels: the gaps a ray slips through (sulci, skin folds, the
/// spaces between ribs) have an anatomical size, not a size in voxels. Counted in voxels of
/// the smallest spacing (4, before), the margin was 2 mm on the 0.5 mm MRI, 6 mm on the head
/// CT's 1.5 mm slices and 0.8 mm on a CT of 0.19 mm slices: the coarse CT over-cautious, the
/// fine one hardly protected. Measured (docs/culling.md, round 3, 24 views): 2 mm renders
/// ≤ 1.9 points over the oracle with ≤ 3.9 % repairs on all four catalogue families (the
/// head CT 1.42 points instead of 2.01; the MRI, at 0.5 mm, as before); 1.5 mm repairs
/// 4.7–5.1 % on the MRI, 3 mm renders 2.35 points over on it. The CTs barely change between
/// 1.5 and 4 mm.
pub const PROXY_MARGIN: f32 = 2.0;

/// [`PROXY_MARGIN`] in ray `t` (units of the smallest voxel spacing `unit`), kept between 1
/// and 16 voxels: below one the proxy cannot place a surface at all, and a volume whose
/// spacing is not in millimetres (metres, or 1 for unknown) must not make the margin a
/// brick deep or vanish.
#[must_use]
pub fn margin_length(unit: f32) -> f32 {
    let t = PROXY_MARGIN / unit;
    if t.is_finite() {
        t.clamp(1.0, 16.0)
    } else {
        16.0
    }
}

/// Pixels between the sample rays of the prediction, in x and in y: a quarter of the rays
/// predicts within a few bricks of every ray (docs/culling.md) at a quarter of the cost.
pub const PREDICT_STRIDE: u32 = 2;

/// Weights and the effective extinction of every cell at them.
type Cached = (Vec<f32>, Arc<Extinction>);

/// A cell's slot when every basis is transparent over its voxels (air, or tissue outside
/// the family): it has no groups stored, every group's extinction is zero.
const NO_SLOT: u32 = u32::MAX;

/// The proxy of a volume for one family: per basis, per cell and value group, the mean
/// extinction, and each group's share of the cell's voxels. It depends on the bases, not on
/// the weights, so a job builds it once.
///
/// Why sparse: a dense table holds `4 × (bases + 1)` floats per 4³ cell, 37 % of an i16
/// volume's bytes for two bases, which alone broke a 256 MB memory budget on a
/// 512×512×1728 CT. Most cells of a CT are transparent for any family (air), so only the
/// others keep their groups; the shares are not stored at all, since a cell's group shares
/// follow from its voxel count, which follows from where it is.
#[derive(Clone, Debug)]
pub struct Proxy {
    /// Voxels per axis.
    dims: [usize; 3],
    /// Edge of a cell in voxels ([`proxy_cell`]).
    edge: usize,
    /// Cells per axis.
    cells: [usize; 3],
    /// Per cell (x fastest), the index of its groups in `tau`, or [`NO_SLOT`].
    slot: Vec<u32>,
    /// Per basis, the mean extinction per unit length of the value groups of the cells with
    /// a slot ([`PROXY_GROUPS`] per slot, lowest values first).
    tau: Vec<Vec<f32>>,
    /// Cells with a slot so far.
    stored: usize,
    /// The effective extinction of the last weights asked for: every rank of a job and
    /// every frame at the same weights shares it (shared by clones, keyed by the weights).
    cache: Arc<Mutex<Option<Cached>>>,
}

impl Proxy {
    /// Measures `volume` with the family tabulated in `sampled`: one pass over the voxels,
    /// parallel over slabs of cells.
    #[must_use]
    pub fn new(volume: &Volume, sampled: &SampledTf) -> Self {
        Proxy::with_cell(volume, sampled, proxy_cell(volume.dims()))
    }

    /// As [`Proxy::new`], with cells of `edge` voxels (≥ 1) instead of [`proxy_cell`]'s.
    #[must_use]
    pub fn with_cell(volume: &Volume, sampled: &SampledTf, edge: usize) -> Self {
        let dims = volume.dims();
        let edge = edge.max(1);
        let cells = dims.map(|n| n.div_ceil(edge));
        let slabs: Vec<Slab> = with_voxels!(volume.data(), v => {
            (0..cells[2])
                .into_par_iter()
                .map(|z| slab(v, (dims, edge, cells), z, sampled))
                .collect()
        });
        let mut proxy = Proxy::empty(dims, edge, sampled.basis_count());
        for s in slabs {
            proxy.append(s);
        }
        proxy.finish()
    }

    /// A proxy of no cells yet, filled slab by slab with [`Proxy::append`].
    fn empty(dims: [usize; 3], edge: usize, bases: usize) -> Self {
        let cells = dims.map(|n| n.div_ceil(edge));
        Proxy {
            dims,
            edge,
            cells,
            slot: Vec::with_capacity(cells.iter().product()),
            tau: vec![Vec::new(); bases],
            stored: 0,
            cache: Arc::default(),
        }
    }

    /// Adds the next slab of cells along z.
    fn append(&mut self, s: Slab) {
        let base = self.stored;
        self.stored += s.stored;
        // Past 2³² − 1 stored cells (a volume of 2⁴⁰ voxels) a cell is taken as transparent:
        // the proxy only predicts, and verification repairs what it gets wrong.
        self.slot.extend(s.slot.iter().map(|&l| {
            if l == NO_SLOT {
                NO_SLOT
            } else {
                u32::try_from(base + l as usize).unwrap_or(NO_SLOT)
            }
        }));
        for (t, b) in self.tau.iter_mut().zip(s.tau) {
            t.extend(b);
        }
    }

    /// Gives back the spare capacity of the growing tables.
    fn finish(mut self) -> Self {
        for t in &mut self.tau {
            t.shrink_to_fit();
        }
        self
    }

    /// Heap bytes of the proxy's tables (not counting the cached extinction, one `f32` per
    /// cell): what it costs a memory budget.
    #[must_use]
    pub fn heap_bytes(&self) -> u64 {
        let f = std::mem::size_of::<f32>();
        let tau: usize = self.tau.iter().map(|t| t.capacity() * f).sum();
        (self.slot.capacity() * std::mem::size_of::<u32>() + tau) as u64
    }

    /// The share of cell `c`'s voxels in each of its groups: the sizes of the group split
    /// of [`slab`] over the voxel count of a cell at its place (edge cells are cut short).
    fn shares(&self, c: usize) -> [f32; PROXY_GROUPS] {
        let [cx, cy, _] = self.cells;
        let at = [c % cx, (c / cx) % cy, c / (cx * cy)];
        let n: usize = (0..3)
            .map(|a| ((at[a] + 1) * self.edge).min(self.dims[a]) - at[a] * self.edge)
            .product();
        std::array::from_fn(|g| {
            let len = (g + 1) * n / PROXY_GROUPS - g * n / PROXY_GROUPS;
            if len == 0 {
                0.0
            } else {
                len as f32 / n as f32
            }
        })
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
        let mut proxy = Proxy::empty(dims, proxy_cell(dims), sampled.basis_count());
        let (cz, edge) = (proxy.cells[2], proxy.edge);
        let per_read = (slab_planes / edge).max(1);
        for first in (0..cz).step_by(per_read) {
            let layers = per_read.min(cz - first);
            let z0 = first * edge;
            let planes = (layers * edge).min(dims[2] - z0);
            let data = read(z0, planes)?;
            let sdims = [dims[0], dims[1], planes];
            let cells = proxy.cells;
            let slabs: Vec<Slab> = with_voxels!(&data, v => {
                (0..layers)
                    .into_par_iter()
                    .map(|z| slab(v, (sdims, edge, cells), z, sampled))
                    .collect()
            });
            for s in slabs {
                proxy.append(s);
            }
        }
        Ok(proxy.finish())
    }

    /// Cells per axis.
    #[must_use]
    pub fn cells(&self) -> [usize; 3] {
        self.cells
    }

    /// Edge of a cell in voxels ([`proxy_cell`]).
    #[must_use]
    pub fn cell_edge(&self) -> usize {
        self.edge
    }

    /// The effective extinction of every cell at `weights` ([`Proxy::extinction`]) with
    /// its blocks for the march, computed once per weights.
    #[must_use]
    pub fn extinction_at(&self, weights: &[f32]) -> Arc<Extinction> {
        let mut cache = self
            .cache
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some((w, ext)) = cache.as_ref() {
            if w.as_slice() == weights {
                return Arc::clone(ext);
            }
        }
        // Computed under the lock: the other ranks of the frame wait for it rather than
        // compute it again.
        let ext = Arc::new(Extinction::new(self.extinction(weights), self.cells));
        *cache = Some((weights.to_vec(), Arc::clone(&ext)));
        ext
    }

    /// The effective extinction of every cell at `weights`: with each group's extinction
    /// `eᵍ = Σ kᵢ τᵢᵍ`, `−ln(Σ fᵍ e^(−eᵍℓ)) / ℓ` for the correlation length ℓ (see the
    /// module's comment).
    #[must_use]
    pub fn extinction(&self, weights: &[f32]) -> Vec<f32> {
        let n: usize = self.cells.iter().product();
        let l = CORRELATION_LENGTH;
        (0..n)
            .into_par_iter()
            .with_min_len(4096)
            .map(|c| {
                let slot = self.slot[c];
                let group = |g: usize| -> f32 {
                    if slot == NO_SLOT {
                        return 0.0;
                    }
                    self.tau
                        .iter()
                        .zip(weights)
                        .filter(|(_, k)| **k > 0.0)
                        .map(|(t, k)| k * t[slot as usize * PROXY_GROUPS + g])
                        .sum()
                };
                let shares = self.shares(c);
                let transmit: f32 = (0..PROXY_GROUPS)
                    .map(|g| shares[g] * (-group(g) * l).exp())
                    .sum();
                // All groups opaque: as opaque as f32 says.
                -transmit.max(f32::MIN_POSITIVE).ln() / l
            })
            .collect()
    }

    /// The `t` at which `ray`'s optical depth through the cells of `ext` reaches `depth`;
    /// infinite when it never does ([`Extinction::termination`], which skips the blocks
    /// of transparent cells).
    #[must_use]
    pub fn termination(&self, ext: &Extinction, ray: &IndexRay, depth: f32) -> f32 {
        ext.termination(self.edge, ray, depth)
    }

    /// Where the prediction takes `ray` to end at `threshold` in a volume of smallest spacing
    /// `unit`: where its optical depth through the cells of `ext` reaches
    /// [`PROXY_DEPTH_FACTOR`] times the threshold's, plus [`margin_length`]; infinite when
    /// it never does.
    #[must_use]
    pub fn predicted_end(
        &self,
        ext: &Extinction,
        ray: &IndexRay,
        threshold: f32,
        unit: f32,
    ) -> f32 {
        let depth = -(1.0 - threshold.min(0.999_999)).ln() * PROXY_DEPTH_FACTOR;
        self.termination(ext, ray, depth) + margin_length(unit)
    }

    /// Predicts which bricks over `tile` are hidden at `threshold`: the sample rays (every
    /// [`PREDICT_STRIDE`]-th pixel of the image in x and y) are marched through the proxy to where
    /// their opacity would reach the threshold, and a brick is predicted hidden when every
    /// sample ray of the tile that meets it enters it at or beyond that depth. Returns
    /// (visible, culled), each in visibility order.
    ///
    /// Why sample rays: a prediction needs no pixel exactness (verification tests every
    /// pixel), and a brick's footprint holds tens of them at any size that matters, so a
    /// quarter of the rays predicts about as well at a quarter of the cost. Why lazily: a
    /// brick in front fails at its first sample ray that meets it; a ray is marched only
    /// when a brick asks for it, once.
    ///
    /// The samples sit on the image's grid, not the tile's, so every tiling asks the same
    /// rays and the union of the tiles' visible sets does not depend on the rank count.
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
        let ext = self.extinction_at(weights);
        let s = PREDICT_STRIDE;
        let off = s / 2;
        // The sample columns and rows of the tile: the first at or after its corner.
        let first = |lo: u32| lo + (off + s - lo % s) % s;
        let (sx0, sy0) = (first(tile.x0), first(tile.y0));
        let nx = (tile.x1.saturating_sub(sx0)).div_ceil(s) as usize;
        let ny = (tile.y1.saturating_sub(sy0)).div_ceil(s) as usize;
        // The sample rays (cheap), and where each ends (a march), on demand.
        let rays: Vec<IndexRay> = (0..nx * ny)
            .into_par_iter()
            .with_min_len(1024)
            .map(|k| {
                let (x, y) = (sx0 + (k % nx) as u32 * s, sy0 + (k / nx) as u32 * s);
                IndexRay::new(
                    &camera.ray(&frame, f64::from(x) + 0.5, f64::from(y) + 0.5),
                    volume.spacing(),
                    volume.unit(),
                )
            })
            .collect();
        let ends: Vec<OnceLock<f32>> = (0..nx * ny).map(|_| OnceLock::new()).collect();
        let unit = volume.unit();
        let end_of =
            |k: usize| *ends[k].get_or_init(|| self.predicted_end(&ext, &rays[k], threshold, unit));
        // The sample indices inside [lo, hi) of an axis starting at `s0`.
        let range = |lo: u32, hi: u32, s0: u32, n: usize| -> std::ops::Range<usize> {
            let a = (lo.max(s0) - s0).div_ceil(s) as usize;
            let b = (hi.max(s0) - s0).div_ceil(s) as usize;
            a.min(n)..b.min(n)
        };
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
                let (is, js) = (
                    range(rect.x0, rect.x1, sx0, nx),
                    range(rect.y0, rect.y1, sy0, ny),
                );
                js.into_iter().all(|j| {
                    is.clone().all(|i| {
                        // Where the ray meets the brick, from the ray alone (cheap); the
                        // march only for rays that do.
                        let k = j * nx + i;
                        match rays[k].span(&ib) {
                            None => true,
                            Some((t0, t1)) if t1 <= t0 => true,
                            Some((t0, _)) => {
                                let end = end_of(k);
                                end.is_finite() && t0 >= end
                            }
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

// A cell's bins are sorted as u16.
const _: () = assert!(TF_BINS <= 1 << 16);

/// One slab of cells: per cell its slot among the slab's stored cells (or [`NO_SLOT`]),
/// and per basis the mean extinction of each stored cell's value groups.
struct Slab {
    slot: Vec<u32>,
    tau: Vec<Vec<f32>>,
    /// Cells stored.
    stored: usize,
}

/// One slab of cells of `edge` voxels (cell row `z`): each cell's voxels sorted by bin and
/// split into [`PROXY_GROUPS`] near-equal shares, each group's mean extinction per basis; a
/// cell where every basis is transparent is not stored.
fn slab<T: Voxel>(
    v: &[T],
    ([nx, ny, nz], edge, [cx, cy, _]): ([usize; 3], usize, [usize; 3]),
    z: usize,
    sampled: &SampledTf,
) -> Slab {
    let bases = sampled.basis_count();
    let tables: Vec<&[f32]> = (0..bases).map(|b| sampled.tau_table(b)).collect();
    let mut tau = vec![Vec::new(); bases];
    let mut slot = Vec::with_capacity(cx * cy);
    let mut stored = 0usize;
    let zs = z * edge..((z + 1) * edge).min(nz);
    // Bins where some basis is not transparent: a cell with none (air, or tissue outside
    // the family) has every group at zero and needs no sort. Most cells of a CT are such.
    let opaque: Vec<bool> = (0..TF_BINS)
        .map(|b| tables.iter().any(|t| t[b] > 0.0))
        .collect();
    let mut bins: Vec<u16> = Vec::with_capacity(edge.pow(3));
    for ycell in 0..cy {
        let ys = ycell * edge..((ycell + 1) * edge).min(ny);
        for xcell in 0..cx {
            let xs = xcell * edge..((xcell + 1) * edge).min(nx);
            bins.clear();
            let mut any = false;
            for zz in zs.clone() {
                for y in ys.clone() {
                    let row = &v[(zz * ny + y) * nx..][xs.clone()];
                    bins.extend(row.iter().map(|x| {
                        let b = sampled.bin(x.to_f32());
                        any |= opaque[b];
                        b as u16
                    }));
                }
            }
            if !any {
                slot.push(NO_SLOT);
                continue;
            }
            // A slab of more than 2³² − 1 cells (a plane of 2³⁶ voxels) keeps the rest
            // transparent, as [`Proxy::append`] does.
            slot.push(u32::try_from(stored).unwrap_or(NO_SLOT));
            stored += 1;
            let n = bins.len();
            bins.sort_unstable();
            for g in 0..PROXY_GROUPS {
                let part = &bins[g * n / PROXY_GROUPS..(g + 1) * n / PROXY_GROUPS];
                for (t, table) in tau.iter_mut().zip(&tables) {
                    if part.is_empty() {
                        t.push(0.0);
                        continue;
                    }
                    let sum: f64 = part.iter().map(|b| f64::from(table[usize::from(*b)])).sum();
                    t.push((sum / part.len() as f64) as f32);
                }
            }
        }
    }
    Slab { slot, tau, stored }
}
