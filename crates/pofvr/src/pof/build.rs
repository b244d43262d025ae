//! The fast POF builder: a lower bound on every core ray's optical depth, per direction,
//! without rendering.
//!
//! ## The bound
//!
//! Every ray entering the brick's index box enters through a point `e` of an *entry face*
//! (a face whose inward normal has a positive component along `d`). Along the ray the
//! renderer takes the samples `t_k = k·step` inside its span; any half-open window of
//! length `step` contains exactly one of them, whatever the lattice phase, and the same
//! holds for the reversed ray. So a chord of length `ℓ` holds `n = ⌊ℓ/step⌋` disjoint
//! windows `e + [j·step, (j+1)·step)·d`, and the ray's optical depth for basis `i` is at
//! least `step · Σⱼ min τᵢ` over the voxel cells window `j` can touch.
//!
//! Entry faces are cut into patches of `pitch × pitch` voxels. For a patch, window `j`
//! of *every* ray entering through it lies in one axis-aligned box, so one lookup of a
//! precomputed box-minimum field bounds all of them at once; the patch's value bounds every
//! ray through it with span ≥ `L` (rays shorter than `L` are outside the core and exempt).
//! A cell's minimum extinction is the minimum of the family's bins over the range of its
//! eight corners (trilinear samples never leave it), widened by a hair for float rounding.
//!
//! The bound is independent of the lattice phase and of the ray's sense, so one hemisphere
//! of directions is computed and mirrored. A table cell holds the minimum over a grid of
//! directions covering the cell and its borders, times the optical-depth margin.

use std::collections::HashMap;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Mutex;

use rayon::prelude::*;

use super::file::{self, Bytes};
use super::sampled::{SampledBrick, TauRows};
use super::stream_build::BrickVoxels;
use super::{encoding, PofError, PofMeta, PofMethod, PofSettings, PofTable, ALPHA_MAX};
use crate::brick::{BrickGrid, BrickId};
use crate::render::transfer_function::TF_BINS;
use crate::render::{SampledTf, TransferFunction};
use crate::volume::Volume;

/// Range-minimum over the bins of one basis (sparse table).
struct BinMin {
    levels: Vec<Vec<f32>>,
}

impl BinMin {
    fn new(tau: &[f32]) -> Self {
        let mut levels = vec![tau.to_vec()];
        let mut w = 1;
        while 2 * w <= tau.len() {
            let prev = levels.last().expect("level 0 exists");
            let next: Vec<f32> = (0..=tau.len() - 2 * w)
                .map(|b| prev[b].min(prev[b + w]))
                .collect();
            levels.push(next);
            w *= 2;
        }
        BinMin { levels }
    }

    fn min(&self, b0: usize, b1: usize) -> f32 {
        let len = b1 - b0 + 1;
        let k = (usize::BITS - 1 - len.leading_zeros()) as usize;
        self.levels[k][b0].min(self.levels[k][b1 + 1 - (1 << k)])
    }

    fn max_is_zero(&self, b0: usize, b1: usize, tau: &[f32]) -> bool {
        tau[b0..=b1].iter().all(|t| *t == 0.0)
    }
}

/// What the whole build shares.
pub(super) struct Ctx<'a> {
    pub(super) volume: &'a Volume,
    /// Where bricks' voxels are read: the volume itself, or the slab a streamed build holds.
    pub(super) voxels: &'a dyn BrickVoxels,
    pub(super) grid: &'a BrickGrid,
    sampled: &'a SampledTf,
    bins: Vec<BinMin>,
    /// Value widening so that float rounding of a trilinear sample never leaves the range.
    widen: f32,
    pub(super) p: usize,
    pub(super) views: [usize; 2],
    pub(super) subdiv: usize,
    pub(super) step: f64,
    pub(super) core: f64,
    pub(super) pitch: f64,
    pub(super) margin: f64,
    pub(super) sets: bool,
    encoding: super::Encoding,
    record_len: usize,
    pub(super) phases: usize,
    /// The sampled and typical methods' per-bin extinction rows (the typical method's with
    /// the joint family as one more lane).
    tau: Option<TauRows>,
    method: PofMethod,
    /// `Typical`: the joint POF is measured as the last lane of `tau`, not by `joint`.
    typical_joint: bool,
    /// `Typical`: the quantile kept.
    quantile: f64,
    /// The joint POF's one-basis context (the family at the build's weights).
    joint: Option<Box<Ctx<'a>>>,
}

fn setting(field: &'static str, why: String) -> PofError {
    PofError::Setting { field, why }
}

fn validate(s: &PofSettings) -> Result<(), PofError> {
    if s.views.iter().any(|v| !(1..=1024).contains(v)) {
        return Err(setting(
            "views",
            format!("{:?}: each must be 1..=1024", s.views),
        ));
    }
    if !(s.step.is_finite() && s.step > 1e-3 && s.step <= 64.0) {
        return Err(setting(
            "step",
            format!("{} must be in (0.001, 64]", s.step),
        ));
    }
    if !(s.ert.is_finite() && s.ert > 0.0) {
        return Err(setting("ert", format!("{} must be > 0", s.ert)));
    }
    if let Some(l) = s.core_length {
        if !(l.is_finite() && l > 0.0) {
            return Err(setting("core_length", format!("{l} must be > 0")));
        }
    }
    if !(s.pitch.is_finite() && s.pitch >= 0.05 && s.pitch <= 16.0) {
        return Err(setting(
            "pitch",
            format!("{} must be in [0.05, 16]", s.pitch),
        ));
    }
    if !(1..=16).contains(&s.subdiv) {
        return Err(setting("subdiv", format!("{} must be 1..=16", s.subdiv)));
    }
    if !(s.margin.is_finite() && s.margin > 0.0 && s.margin <= 1.0) {
        return Err(setting("margin", format!("{} must be in (0, 1]", s.margin)));
    }
    if !(1..=64).contains(&s.phases) {
        return Err(setting("phases", format!("{} must be 1..=64", s.phases)));
    }
    Ok(())
}

/// What a build reports to, and what stops it.
pub(super) struct Hooks<'a> {
    /// Called with `(done, total)` as bricks complete.
    pub(super) progress: &'a (dyn Fn(u64, u64) + Sync),
    /// Once set, no further brick is started and the build ends with
    /// [`PofError::Cancelled`].
    pub(super) cancel: Option<&'a AtomicBool>,
}

/// What a build computes before its first brick: the shared context, the file's meta and
/// the bricks to compute (those whose value range touches a non-zero bin), in id order.
pub(super) struct Plan<'a> {
    pub(super) ctx: Ctx<'a>,
    pub(super) meta: PofMeta,
    pub(super) todo: Vec<BrickId>,
    pub(super) record_len: usize,
}

/// Plans a build of `grid`'s bricks whose voxels are read from `voxels` (`volume` itself,
/// or a streamed build's slabs of it) and runs it with `run` (the plan borrows the joint
/// POF's family table, which lives here).
pub(super) fn with_plan<R>(
    volume: &Volume,
    voxels: &dyn BrickVoxels,
    grid: &BrickGrid,
    tf: &TransferFunction,
    sampled: &SampledTf,
    settings: &PofSettings,
    run: impl FnOnce(Plan<'_>) -> Result<R, PofError>,
) -> Result<R, PofError> {
    validate(settings)?;
    let p = sampled.basis_count();
    if tf.bases.len() != p {
        return Err(setting(
            "family",
            format!("{} bases, but the sampled table has {p}", tf.bases.len()),
        ));
    }
    let core = settings
        .core_length
        .unwrap_or(grid.brick_size() as f32 / 2.0);
    let views32 = settings.views.map(|v| v as u32);
    // One basis needs no joint POF: Eq. 3 is already exact.
    let anchor = (settings.joint && (2..=super::JOINT_MAX_BASES).contains(&p))
        .then(|| tf.weights.clone())
        .filter(|w| w.iter().any(|k| *k > 0.0));
    let funcs = p + if settings.sets { p * (p - 1) } else { 0 } + usize::from(anchor.is_some());
    let record_len = (funcs * settings.encoding.function_bytes(views32)).next_multiple_of(8);
    let range = grid.value_range();
    let joint_sampled = anchor.as_ref().map(|a| sampled.joint(a));
    let mut ctx = Ctx {
        volume,
        voxels,
        grid,
        sampled,
        bins: (0..p).map(|i| BinMin::new(sampled.tau_table(i))).collect(),
        widen: (range.max - range.min).abs() * 1e-5 + range.max.abs().max(range.min.abs()) * 1e-6,
        p,
        views: settings.views,
        subdiv: settings.subdiv,
        step: f64::from(settings.step),
        core: f64::from(core),
        pitch: f64::from(settings.pitch),
        margin: f64::from(settings.margin),
        sets: settings.sets,
        encoding: settings.encoding,
        record_len,
        phases: settings.phases,
        tau: match settings.method {
            PofMethod::Bound => None,
            PofMethod::Sampled => Some(TauRows::new(sampled, settings.step)),
            PofMethod::Typical => Some(TauRows::with_extra(
                sampled,
                joint_sampled.as_ref(),
                settings.step,
            )),
        },
        method: settings.method,
        typical_joint: settings.method == PofMethod::Typical && joint_sampled.is_some(),
        quantile: super::TYPICAL_QUANTILE,
        joint: None,
    };
    if settings.method != PofMethod::Typical {
        ctx.joint = joint_sampled
            .as_ref()
            .map(|js| Box::new(ctx.sibling(js, settings.step)));
    }
    let meta = PofMeta {
        dims: volume.dims().map(|d| d as u64),
        dtype: volume.data_type(),
        brick_size: grid.brick_size() as u32,
        brick_count: grid.len() as u32,
        range_hash: super::range_hash(grid),
        bases_fingerprint: tf.bases_fingerprint(),
        basis_count: p as u32,
        views: views32,
        encoding: settings.encoding,
        sets: settings.sets,
        step: settings.step,
        ert: settings.ert,
        core_length: core,
        margin: settings.margin,
        pitch: settings.pitch,
        subdiv: settings.subdiv as u32,
        method: settings.method,
        phases: match settings.method {
            PofMethod::Bound => 1,
            PofMethod::Sampled | PofMethod::Typical => settings.phases as u32,
        },
        joint: anchor,
        cell_major: settings.encoding != super::Encoding::Cubic,
    };

    // Bricks whose value range touches a non-zero bin of some basis.
    let todo: Vec<BrickId> = grid.ids().filter(|id| !ctx.brick_empty(*id)).collect();
    run(Plan {
        ctx,
        meta,
        todo,
        record_len,
    })
}

pub(super) fn build(
    volume: &Volume,
    grid: &BrickGrid,
    tf: &TransferFunction,
    sampled: &SampledTf,
    settings: &PofSettings,
    partial: Option<&Path>,
    hooks: Hooks<'_>,
) -> Result<PofTable, PofError> {
    with_plan(volume, volume, grid, tf, sampled, settings, |plan| {
        run(plan, partial, &hooks)
    })
}

fn run(plan: Plan<'_>, partial: Option<&Path>, hooks: &Hooks<'_>) -> Result<PofTable, PofError> {
    let Plan {
        ctx,
        meta,
        todo,
        record_len,
    } = plan;
    let progress = hooks.progress;
    let cancelled = || hooks.cancel.is_some_and(|c| c.load(Ordering::Relaxed));
    let grid = ctx.grid;
    let total = todo.len() as u64;
    let mut done: HashMap<u32, Option<Vec<u8>>> = HashMap::new();
    let mut part = match partial {
        Some(path) => Some(Partial::open(
            path,
            partial_key(&meta, record_len),
            record_len,
            &mut done,
        )?),
        None => None,
    };
    let counter = AtomicU64::new(done.len() as u64);
    progress(counter.load(Ordering::Relaxed), total);
    let remaining: Vec<BrickId> = todo
        .iter()
        .copied()
        .filter(|id| !done.contains_key(&id.0))
        .collect();
    // Chunks bound what an interruption can lose when a partial file is kept.
    let chunk = if part.is_some() {
        64
    } else {
        remaining.len().max(1)
    };
    for ids in remaining.chunks(chunk) {
        let results: Vec<(u32, Option<Vec<u8>>)> = ids
            .par_iter()
            .filter_map(|id| {
                if cancelled() {
                    return None;
                }
                let r = ctx.brick_record(*id);
                let n = counter.fetch_add(1, Ordering::Relaxed) + 1;
                progress(n, total);
                Some((id.0, r))
            })
            .collect();
        // Only finished bricks reach the partial file, so a cancelled build resumes.
        if let Some(pf) = part.as_mut() {
            pf.append(&results)?;
        }
        done.extend(results);
        if cancelled() {
            return Err(PofError::Cancelled {
                done: done.len() as u64,
                total,
            });
        }
    }

    let mut index = vec![u32::MAX; grid.len()];
    let mut data = Vec::new();
    let mut slot = 0u32;
    for id in &todo {
        if let Some(Some(rec)) = done.get(&id.0) {
            index[id.index()] = slot;
            data.extend_from_slice(rec);
            slot += 1;
        }
    }
    let image = file::assemble(&meta, &index, &data, record_len);
    let table = file::from_bytes(Bytes::Owned(image), "<built in memory>".to_string())?;
    drop(part);
    Ok(table)
}

/// Direction-independent state of one brick: the per-cell minimum extinction of every
/// basis and box-minimum fields of it, made on demand.
struct BrickField {
    n: [usize; 3],
    p: usize,
    base: Vec<f32>,
    /// Box sizes up to `SMALL` per axis, by `(sx−1) + SMALL·(sy−1) + SMALL²·(sz−1)`: the
    /// hot path indexes instead of hashing.
    small: Vec<Option<Vec<f32>>>,
    large: HashMap<[usize; 3], Vec<f32>>,
    /// The patches that gave each basis its minimum at the previous direction: tried first,
    /// they set a tight bound early and let the other patches stop after a few windows.
    hints: Vec<(usize, usize, usize)>,
}

const SMALL: usize = 4;

impl BrickField {
    fn new(n: [usize; 3], p: usize, base: Vec<f32>) -> Self {
        BrickField {
            n,
            p,
            base,
            small: vec![None; SMALL * SMALL * SMALL],
            large: HashMap::new(),
            hints: Vec::new(),
        }
    }

    fn small_index(size: [usize; 3]) -> Option<usize> {
        size.iter()
            .all(|s| *s <= SMALL)
            .then(|| (size[0] - 1) + SMALL * (size[1] - 1) + SMALL * SMALL * (size[2] - 1))
    }

    fn get(&self, size: [usize; 3]) -> Option<&[f32]> {
        match Self::small_index(size) {
            Some(k) => self.small[k].as_deref(),
            None => self.large.get(&size).map(Vec::as_slice),
        }
    }

    fn field(&mut self, size: [usize; 3]) -> &[f32] {
        if let Some(k) = Self::small_index(size) {
            if self.small[k].is_none() {
                self.ensure(size);
            }
            return self.small[k].as_deref().expect("just made");
        }
        self.ensure(size);
        &self.large[&size]
    }

    /// Makes the field of box size `size`: `out[c] = min` over the cells `c .. c + size`
    /// (clipped to the brick), per basis. One pass per field: the box is the box one
    /// shorter along its last long axis, plus the one-cell slab at its far end.
    fn ensure(&mut self, size: [usize; 3]) {
        if self.get(size).is_some() {
            return;
        }
        let made = match (0..3).rev().find(|a| size[*a] > 1) {
            None => self.base.clone(),
            Some(a) => {
                let (mut shorter, mut slab) = (size, size);
                shorter[a] -= 1;
                slab[a] = 1;
                self.ensure(shorter);
                self.ensure(slab);
                let (m1, m2) = (
                    self.get(shorter).expect("made"),
                    self.get(slab).expect("made"),
                );
                let [nx, ny, nz] = self.n;
                let p = self.p;
                let stride = [p, nx * p, nx * ny * p][a];
                let off = (size[a] - 1) * stride;
                let mut out = m1.to_vec();
                for z in 0..nz {
                    if a == 2 && z + size[2] > nz {
                        break;
                    }
                    for y in 0..ny {
                        if a == 1 && y + size[1] > ny {
                            break;
                        }
                        let xs = if a == 0 {
                            nx.saturating_sub(size[0] - 1)
                        } else {
                            nx
                        };
                        let at = (y + ny * z) * nx * p;
                        let row = &mut out[at..at + xs * p];
                        for (o, v) in row.iter_mut().zip(&m2[at + off..at + off + xs * p]) {
                            *o = o.min(*v);
                        }
                    }
                }
                out
            }
        };
        match Self::small_index(size) {
            Some(k) => self.small[k] = Some(made),
            None => {
                self.large.insert(size, made);
            }
        }
    }
}

impl<'a> Ctx<'a> {
    fn bin_range(&self, lo: f32, hi: f32) -> (usize, usize) {
        let b0 = self.sampled.bin(lo - self.widen);
        let b1 = self.sampled.bin(hi + self.widen).max(b0);
        (b0, b1.min(TF_BINS - 1))
    }

    fn brick_empty(&self, id: BrickId) -> bool {
        let r = self.grid.range(id);
        let (b0, b1) = self.bin_range(r.min, r.max);
        (0..self.p).all(|i| self.bins[i].max_is_zero(b0, b1, self.sampled.tau_table(i)))
    }

    fn brick_field(&self, id: BrickId) -> Option<BrickField> {
        let (lo, hi) = self.grid.voxel_bounds(id);
        let n: [usize; 3] = std::array::from_fn(|a| hi[a] - lo[a]);
        if n.contains(&0) {
            return None;
        }
        let p = self.p;
        let mut base = vec![0f32; n[0] * n[1] * n[2] * p];
        // The brick's voxels and its far ghost layer, (n + 1)³.
        let vox = self.voxels.box_f32(lo, hi);
        let at = |x: usize, y: usize, z: usize| vox[x + (n[0] + 1) * (y + (n[1] + 1) * z)];
        for z in 0..n[2] {
            for y in 0..n[1] {
                for x in 0..n[0] {
                    let (mut mn, mut mx) = (f32::INFINITY, f32::NEG_INFINITY);
                    for c in 0..8 {
                        let s = at(x + (c & 1), y + ((c >> 1) & 1), z + ((c >> 2) & 1));
                        mn = mn.min(s);
                        mx = mx.max(s);
                    }
                    let (b0, b1) = self.bin_range(mn, mx);
                    let cell = (x + n[0] * (y + n[1] * z)) * p;
                    for i in 0..p {
                        base[cell + i] = self.bins[i].min(b0, b1);
                    }
                }
            }
        }
        if base.iter().all(|t| *t == 0.0) {
            return None;
        }
        Some(BrickField::new(n, p, base))
    }

    /// The encoded record of a brick, or `None` when its POF is 0 for every basis.
    pub(super) fn brick_record(&self, id: BrickId) -> Option<Vec<u8>> {
        let zero = |t: &Vec<f32>| t.iter().all(|a| *a <= 0.0);
        let (own, joint) = match (self.method, &self.tau) {
            (PofMethod::Typical, Some(tau)) => {
                match super::typical::tables(self, tau, self.typical_joint, self.quantile, id) {
                    Some(mut t) => {
                        let j = if self.typical_joint { t.pop() } else { None };
                        (Some(t), j)
                    }
                    None => (None, None),
                }
            }
            _ => (
                self.tables_of(id),
                self.joint
                    .as_ref()
                    .and_then(|j| j.tables_of(id))
                    .and_then(|mut t| t.pop()),
            ),
        };
        let own = own.filter(|t| !t[..self.p].iter().all(zero));
        let joint = joint.filter(|t| !zero(t));
        if own.is_none() && joint.is_none() {
            return None;
        }
        let cells = self.views[0] * self.views[1];
        let funcs = self.p + if self.sets { self.p * (self.p - 1) } else { 0 };
        let mut tables = own.unwrap_or_else(|| vec![vec![0.0; cells]; funcs]);
        if self.joint.is_some() || self.typical_joint {
            tables.push(joint.unwrap_or_else(|| vec![0.0; cells]));
        }
        let views = self.views.map(|v| v as u32);
        let mut out = Vec::with_capacity(self.record_len);
        encoding::encode_record(self.encoding, &tables, views, true, &mut out);
        out.resize(self.record_len, 0);
        Some(out)
    }

    /// The same build over another family table, without sets (the joint POF's).
    fn sibling(&self, sampled: &'a SampledTf, step: f32) -> Ctx<'a> {
        Ctx {
            volume: self.volume,
            voxels: self.voxels,
            grid: self.grid,
            sampled,
            bins: (0..sampled.basis_count())
                .map(|i| BinMin::new(sampled.tau_table(i)))
                .collect(),
            widen: self.widen,
            p: sampled.basis_count(),
            views: self.views,
            subdiv: self.subdiv,
            step: self.step,
            core: self.core,
            pitch: self.pitch,
            margin: self.margin,
            sets: false,
            encoding: self.encoding,
            record_len: self.record_len,
            phases: self.phases,
            tau: self.tau.as_ref().map(|_| TauRows::new(sampled, step)),
            method: self.method,
            typical_joint: false,
            quantile: self.quantile,
            joint: None,
        }
    }

    /// The brick's tables, or `None` when it is empty for every basis of this context.
    fn tables_of(&self, id: BrickId) -> Option<Vec<Vec<f32>>> {
        Some(match &self.tau {
            None => {
                let mut bf = self.brick_field(id)?;
                self.brick_tables(&mut |d, out| self.direction_bound(&mut bf, d, out))
            }
            Some(tau) => {
                let mut sb = SampledBrick::new(self, id)?;
                self.brick_tables(&mut |d, out| sb.direction(self, tau, d, out))
            }
        })
    }

    /// Per-function opacity tables (`views[0] × views[1]`): p conservative POFs, then the
    /// sets (basis s's p−1 companions) when asked for.
    fn brick_tables(&self, measure: &mut dyn FnMut([f64; 3], &mut [f64])) -> Vec<Vec<f32>> {
        use std::f64::consts::{PI, TAU};
        let [n_rows, n_cols] = self.views;
        let s = self.subdiv;
        let p = self.p;
        let funcs = if self.sets { p + p * (p - 1) } else { p };
        let even = n_cols % 2 == 0;
        let half_cols = if even { n_cols / 2 } else { n_cols };
        let pr = n_rows * s + 1;
        let pc = if even { half_cols * s + 1 } else { n_cols * s };
        let spacing = self.volume.spacing();
        let unit = f64::from(self.volume.unit());
        // Optical depths at each measured direction.
        let mut pts = vec![0f64; pr * pc * funcs];
        for r in 0..pr {
            let theta = r as f64 / (n_rows * s) as f64 * PI;
            for c in 0..pc {
                let phi = c as f64 / (n_cols * s) as f64 * TAU;
                let dir = super::direction(theta, phi);
                let d = [0, 1, 2].map(|a| dir[a] * unit / f64::from(spacing[a]));
                let out = &mut pts[(r * pc + c) * funcs..(r * pc + c + 1) * funcs];
                measure(d, out);
            }
        }
        let mut tables = vec![vec![0f32; n_rows * n_cols]; funcs];
        for i in 0..n_rows {
            for j in 0..half_cols {
                let mut m = vec![f64::INFINITY; funcs];
                for r in i * s..=(i + 1) * s {
                    for c in j * s..=(j + 1) * s {
                        // Odd column counts measure the whole circle: wrap φ = 2π to 0.
                        let c = c % pc;
                        let v = &pts[(r * pc + c) * funcs..(r * pc + c + 1) * funcs];
                        for f in 0..funcs {
                            m[f] = m[f].min(v[f]);
                        }
                    }
                }
                for f in 0..funcs {
                    let a = ((1.0 - (-self.margin * m[f]).exp()) as f32).clamp(0.0, ALPHA_MAX);
                    tables[f][i * n_cols + j] = a;
                    if even {
                        // Both methods' values hold for a line whichever way it is traversed
                        // (the sampled one through its symmetric phase set).
                        tables[f][(n_rows - 1 - i) * n_cols + j + half_cols] = a;
                    }
                }
            }
        }
        tables
    }

    /// The least optical depth (per basis) over every core ray of index direction `d`, and
    /// with sets, every basis's depth at each basis's minimising patch. Writes `funcs`
    /// values: p minima, then for each s the p−1 others at s's argmin patch.
    fn direction_bound(&self, bf: &mut BrickField, d: [f64; 3], out: &mut [f64]) {
        let p = self.p;
        let mut best = vec![f64::INFINITY; p];
        let mut at_best: Vec<Vec<f64>> = vec![Vec::new(); if self.sets { p } else { 0 }];
        let mut best_patch = vec![(usize::MAX, 0, 0); p];
        let mut sums = vec![0f64; p];
        let n = bf.n.map(|x| x as f64);
        let counts: [usize; 3] = std::array::from_fn(|a| (n[a] / self.pitch).ceil() as usize);
        let hints = std::mem::take(&mut bf.hints);
        let mut visit =
            |bf: &mut BrickField, patch: (usize, usize, usize), best: &mut Vec<f64>| -> bool {
                if !self.patch_sums(bf, d, patch, best, &mut sums) {
                    return false;
                }
                for i in 0..p {
                    if sums[i] < best[i] {
                        best[i] = sums[i];
                        best_patch[i] = patch;
                        if self.sets {
                            at_best[i].clone_from(&sums);
                        }
                    }
                }
                // With sets too: every basis's minimising patch has been summed in full.
                best.iter().all(|b| *b <= 0.0)
            };
        let mut done = false;
        for h in &hints {
            if h.0 < 3 && visit(bf, *h, &mut best) {
                done = true;
                break;
            }
        }
        // Patches in groups of GROUP × GROUP: a group's bound is below each of its patches'
        // (bigger boxes, no more windows), so a group that cannot beat `best` is skipped.
        const GROUP: usize = 4;
        let mut group_sums = vec![0f64; p];
        if !done {
            'faces: for a in 0..3 {
                if d[a].abs() <= 1e-9 {
                    continue;
                }
                let (b, c) = ((a + 1) % 3, (a + 2) % 3);
                for gb in (0..counts[b]).step_by(GROUP) {
                    for gc in (0..counts[c]).step_by(GROUP) {
                        let (eb, ec) = ((gb + GROUP).min(counts[b]), (gc + GROUP).min(counts[c]));
                        {
                            let rect = self.rect(bf, a, (gb, eb), (gc, ec));
                            if !self.rect_sums(bf, d, a, rect, &best, &mut group_sums)
                                || group_sums.iter().zip(&best).all(|(g, b)| g >= b)
                            {
                                continue;
                            }
                        }
                        for ib in gb..eb {
                            for ic in gc..ec {
                                if visit(bf, (a, ib, ic), &mut best) {
                                    break 'faces;
                                }
                            }
                        }
                    }
                }
            }
        }
        bf.hints = best_patch;
        for i in 0..p {
            // No core ray at all in this direction (L longer than the brick): nothing to bound.
            out[i] = if best[i].is_finite() { best[i] } else { 0.0 };
        }
        if self.sets {
            let mut k = p;
            for (s, sums_at_s) in at_best.iter().enumerate() {
                for j in 0..p {
                    if j == s {
                        continue;
                    }
                    out[k] = sums_at_s.get(j).copied().unwrap_or(0.0).max(out[j]);
                    k += 1;
                }
            }
        }
    }

    /// The entry-face rectangle `[b0, b1] × [c0, c1]` of patches `ib0..ib1 × ic0..ic1` on
    /// face `a`.
    fn rect(
        &self,
        bf: &BrickField,
        a: usize,
        (ib0, ib1): (usize, usize),
        (ic0, ic1): (usize, usize),
    ) -> [f64; 4] {
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        let pitch = self.pitch;
        [
            ib0 as f64 * pitch,
            (ib1 as f64 * pitch).min(bf.n[b] as f64),
            ic0 as f64 * pitch,
            (ic1 as f64 * pitch).min(bf.n[c] as f64),
        ]
    }

    /// Optical-depth lower bounds (per basis) of every core ray entering through patch
    /// `(a, ib, ic)` of entry face `a`; false when the patch holds no core ray.
    fn patch_sums(
        &self,
        bf: &mut BrickField,
        d: [f64; 3],
        (a, ib, ic): (usize, usize, usize),
        best: &[f64],
        sums: &mut [f64],
    ) -> bool {
        let rect = self.rect(bf, a, (ib, ib + 1), (ic, ic + 1));
        self.rect_sums(bf, d, a, rect, best, sums)
    }

    /// Optical-depth lower bounds (per basis) of every core ray entering face `a` through
    /// `rect`; false when it holds no core ray. Stops early once no basis can improve on
    /// `best` (the sums are then partial but already ≥ `best`).
    fn rect_sums(
        &self,
        bf: &mut BrickField,
        d: [f64; 3],
        a: usize,
        [b0, b1, c0, c1]: [f64; 4],
        best: &[f64],
        sums: &mut [f64],
    ) -> bool {
        let p = self.p;
        let n = bf.n.map(|x| x as f64);
        let step = self.step;
        if d[a].abs() <= 1e-9 {
            return false;
        }
        let far = |ax: usize, e: f64| -> f64 {
            if d[ax] > 1e-12 {
                (n[ax] - e) / d[ax]
            } else if d[ax] < -1e-12 {
                e / -d[ax]
            } else {
                f64::INFINITY
            }
        };
        // Cell range along one axis of an interval: the cells it overlaps, a point on a
        // cell border counting for one of them (its value is in both cells' ranges).
        let cells = |lo: f64, hi: f64, n: usize| -> (usize, usize) {
            // Truncation of a shifted positive number is floor without a libm call; the
            // coordinates stay within a few bricks of the origin.
            const SHIFT: f64 = 1_048_576.0;
            let floor = |x: f64| (x + SHIFT) as i64 - SHIFT as i64;
            let i0 = floor(lo + 1e-4).max(0) as usize;
            // ceil(x) − 1 = −floor(−x) − 1
            let i1 = (-floor(-(hi - 1e-4)) - 1).max(0) as usize;
            let i0 = i0.min(n - 1);
            let i1 = i1.min(n - 1).max(i0);
            (i0, i1 - i0 + 1)
        };
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        let fa = if d[a] > 0.0 { 0.0 } else { n[a] };
        let far_a = n[a] / d[a].abs();
        let (fb0, fb1, fc0, fc1) = (far(b, b0), far(b, b1), far(c, c0), far(c, c1));
        // The exit distance is linear in the entry point on each axis, so its extremes over
        // the patch are at the patch's corners.
        let chord_max = far_a.min(fb0.max(fb1)).min(fc0.max(fc1));
        if chord_max < self.core {
            return false;
        }
        let chord_min = far_a.min(fb0.min(fb1)).min(fc0.min(fc1));
        // Every core ray of the patch is at least this long; a hair less guards the
        // renderer's f32 span arithmetic.
        let windows = ((self.core.max(chord_min) - 1e-3) / step).floor().max(0.0) as usize;
        sums.iter_mut().for_each(|x| *x = 0.0);
        let (nx, ny) = (bf.n[0], bf.n[1]);
        for j in 0..windows {
            let (t0, t1) = (j as f64 * step, (j + 1) as f64 * step);
            let lo_of = |ax: usize| (d[ax] * t0).min(d[ax] * t1);
            let hi_of = |ax: usize| (d[ax] * t0).max(d[ax] * t1);
            let mut lo = [0f64; 3];
            let mut hi = [0f64; 3];
            lo[a] = fa + lo_of(a);
            hi[a] = fa + hi_of(a);
            lo[b] = b0 + lo_of(b);
            hi[b] = b1 + hi_of(b);
            lo[c] = c0 + lo_of(c);
            hi[c] = c1 + hi_of(c);
            let (x0, sx) = cells(lo[0], hi[0], bf.n[0]);
            let (y0, sy) = cells(lo[1], hi[1], bf.n[1]);
            let (z0, sz) = cells(lo[2], hi[2], bf.n[2]);
            let f = bf.field([sx, sy, sz]);
            let at = (x0 + nx * (y0 + ny * z0)) * p;
            for i in 0..p {
                sums[i] += step * f64::from(f[at + i]);
            }
            // A patch stopped here improves no basis, so every patch that does (and whose
            // sums the sets keep) was summed in full.
            if sums.iter().zip(best).all(|(s, b)| s >= b) {
                break;
            }
        }
        true
    }
}

/// Key of a partial file: a resumed run must be the very same build.
fn partial_key(meta: &PofMeta, record_len: usize) -> u64 {
    let image = file::assemble(meta, &[], &[], record_len);
    let mut h = crate::render::transfer_function::Fnv::default();
    h.write(&image[..file::HEADER_LEN - 4]);
    h.0
}

/// `FILE.partial`: finished bricks appended as `(brick u32, present u8, record, crc u32)`,
/// so an interrupted build resumes where it stopped; a torn last entry is ignored.
struct Partial {
    path: PathBuf,
    file: Mutex<std::fs::File>,
    record_len: usize,
}

const PARTIAL_MAGIC: &[u8; 8] = b"POFPART1";

impl Partial {
    fn open(
        path: &Path,
        key: u64,
        record_len: usize,
        done: &mut HashMap<u32, Option<Vec<u8>>>,
    ) -> Result<Self, PofError> {
        let name = path.display().to_string();
        let io = |err| PofError::Io {
            file: name.clone(),
            err,
        };
        let mut resumed = false;
        if let Ok(mut f) = std::fs::File::open(path) {
            let mut bytes = Vec::new();
            f.read_to_end(&mut bytes).map_err(io)?;
            if bytes.len() >= 16
                && &bytes[..8] == PARTIAL_MAGIC
                && bytes[8..16] == key.to_le_bytes()
            {
                resumed = true;
                let entry = 4 + 1 + record_len + 4;
                let mut o = 16;
                let mut good = 16;
                while o + entry <= bytes.len() {
                    let e = &bytes[o..o + entry];
                    let crc = u32::from_le_bytes(e[entry - 4..].try_into().expect("4 bytes"));
                    if crc32fast::hash(&e[..entry - 4]) != crc {
                        break;
                    }
                    let id = u32::from_le_bytes(e[..4].try_into().expect("4 bytes"));
                    let rec = (e[4] != 0).then(|| e[5..5 + record_len].to_vec());
                    done.insert(id, rec);
                    o += entry;
                    good = o;
                }
                // Drop a torn tail so new entries append cleanly.
                let f = std::fs::OpenOptions::new()
                    .write(true)
                    .open(path)
                    .map_err(io)?;
                f.set_len(good as u64).map_err(io)?;
            }
        }
        let file = if resumed {
            std::fs::OpenOptions::new()
                .append(true)
                .open(path)
                .map_err(io)?
        } else {
            done.clear();
            let mut f = std::fs::File::create(path).map_err(io)?;
            f.write_all(PARTIAL_MAGIC).map_err(io)?;
            f.write_all(&key.to_le_bytes()).map_err(io)?;
            f
        };
        Ok(Partial {
            path: path.to_path_buf(),
            file: Mutex::new(file),
            record_len,
        })
    }

    fn append(&mut self, results: &[(u32, Option<Vec<u8>>)]) -> Result<(), PofError> {
        let mut buf = Vec::new();
        for (id, rec) in results {
            let start = buf.len();
            buf.extend_from_slice(&id.to_le_bytes());
            buf.push(u8::from(rec.is_some()));
            match rec {
                Some(r) => buf.extend_from_slice(r),
                None => buf.resize(buf.len() + self.record_len, 0),
            }
            let crc = crc32fast::hash(&buf[start..]);
            buf.extend_from_slice(&crc.to_le_bytes());
        }
        let f = self
            .file
            .get_mut()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        f.write_all(&buf)
            .and_then(|()| f.sync_data())
            .map_err(|err| PofError::Io {
                file: self.path.display().to_string(),
                err,
            })
    }
}
