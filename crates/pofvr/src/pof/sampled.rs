//! The sampled POF builder: measures, per direction, the optical depth the ray caster's
//! own samples give on a grid of parallel rays, instead of bounding it.
//!
//! ## What is measured
//!
//! For an index direction `d`, rays are laid on a square grid of pitch `pitch` voxels on
//! the plane through the brick's centre perpendicular to `d`, and sampled at
//! `t = (k + φ)·step` from that plane for `phases` evenly spread phases `φ`: the renderer's
//! lattice seen from one ray, since a camera's lattice is some phase of it. Samples are
//! trilinear over the brick's voxels including its far ghost layer (what the renderer
//! reads inside the box) and classified through the same bins as [`SampledTf`]. A basis's
//! value is the least optical depth over the rays whose span is at least `L − step`.
//!
//! The grid's lines and an evenly spread phase set are the same for `−d`, so one
//! hemisphere is measured and mirrored, as for the bound.
//!
//! ## Why it is not a rigorous bound
//!
//! Rays between the grid's, phases between the measured ones and directions between the
//! measured ones can see less: trilinear fields vary within a voxel, and a ray grazing a
//! thin shell can slip between samples. The table keeps `margin` of the measured depth for
//! that, a share chosen by measurement with `pofvr pof check` (see [`super::SAMPLED_MARGIN`]).

use super::build::Ctx;
use crate::brick::BrickId;
use crate::render::sampler::TrilinearSampler;
use crate::render::transfer_function::TF_BINS;
use crate::render::SampledTf;

/// Per-basis extinction per step, `lanes` floats per bin (bases padded with zeros): the
/// hot loop adds a whole bin's row at once.
pub(super) struct TauRows {
    pub(super) lanes: usize,
    pub(super) rows: Vec<f32>,
    lo: f32,
    scale: f32,
}

impl TauRows {
    pub(super) fn new(sampled: &SampledTf, step: f32) -> Self {
        Self::with_extra(sampled, None, step)
    }

    /// The bases of `sampled`, then `extra`'s one basis as lane p (the typical method
    /// measures the joint POF in the same pass: its extinction is linear in the bases').
    pub(super) fn with_extra(sampled: &SampledTf, extra: Option<&SampledTf>, step: f32) -> Self {
        let p = sampled.basis_count();
        let used = p + usize::from(extra.is_some());
        let lanes = used.next_multiple_of(4).max(4);
        let mut rows = vec![0f32; TF_BINS * lanes];
        for i in 0..p {
            for (b, t) in sampled.tau_table(i).iter().enumerate() {
                rows[b * lanes + i] = t * step;
            }
        }
        if let Some(x) = extra {
            for (b, t) in x.tau_table(0).iter().enumerate() {
                rows[b * lanes + p] = t * step;
            }
        }
        let (lo, scale) = sampled.bin_params();
        TauRows {
            lanes,
            rows,
            lo,
            scale,
        }
    }

    /// The bin of value `v`, as the classifier computes it.
    #[inline(always)]
    pub(super) fn bin(&self, v: f32) -> usize {
        #[allow(clippy::manual_clamp)]
        let b = ((v - self.lo) * self.scale)
            .max(0.0)
            .min((TF_BINS - 1) as f32);
        // SAFETY: b is in [0, TF_BINS−1]; `max` maps NaN to 0.
        unsafe { b.to_int_unchecked::<u32>() as usize }
    }
}

/// Per-ray accumulators: a fixed-width array for the common few-basis families, a vector
/// otherwise.
pub(super) trait Acc {
    fn zero(&mut self);
    /// Adds bin `b`'s row.
    fn add(&mut self, rows: &[f32], b: usize);
    /// True when every lane is at least its limit: the ray can improve no basis.
    fn all_ge(&self, lim: &[f32]) -> bool;
    fn sums(&self) -> &[f32];
}

impl<const S: usize> Acc for [f32; S] {
    #[inline(always)]
    fn zero(&mut self) {
        *self = [0.0; S];
    }
    #[inline(always)]
    fn add(&mut self, rows: &[f32], b: usize) {
        debug_assert!((b + 1) * S <= rows.len());
        // SAFETY: `b < TF_BINS` (clamped by the caller) and `rows` holds TF_BINS rows of S.
        let r = unsafe { rows.get_unchecked(b * S..(b + 1) * S) };
        for (a, t) in self.iter_mut().zip(r) {
            *a += t;
        }
    }
    #[inline(always)]
    fn all_ge(&self, lim: &[f32]) -> bool {
        let lim: &[f32; S] = lim.try_into().expect("S limits");
        let mut ok = true;
        for (a, l) in self.iter().zip(lim) {
            ok &= a >= l;
        }
        ok
    }
    fn sums(&self) -> &[f32] {
        self
    }
}

impl Acc for Vec<f32> {
    fn zero(&mut self) {
        self.iter_mut().for_each(|a| *a = 0.0);
    }
    #[inline(always)]
    fn add(&mut self, rows: &[f32], b: usize) {
        let s = self.len();
        for (a, t) in self.iter_mut().zip(&rows[b * s..(b + 1) * s]) {
            *a += t;
        }
    }
    fn all_ge(&self, lim: &[f32]) -> bool {
        self.iter().zip(lim).all(|(a, l)| a >= l)
    }
    fn sums(&self) -> &[f32] {
        self
    }
}

/// One brick's voxels (ghost layer included) as f32 in brick-local coordinates, and what
/// the previous direction learnt.
pub(super) struct SampledBrick {
    pub(super) n: [usize; 3],
    vox: Vec<f32>,
    /// Where each basis's minimising ray crossed the centre plane at the previous
    /// direction: marched first, it sets a tight limit early so the other rays stop sooner.
    hints: Vec<[f64; 3]>,
}

/// What one direction's sweep keeps.
struct Sweep {
    best: Vec<f32>,
    at_best: Vec<Vec<f32>>,
    best_at: Vec<[f64; 3]>,
    lim: Vec<f32>,
    any_core: bool,
}

impl SampledBrick {
    pub(super) fn new(ctx: &Ctx<'_>, id: BrickId) -> Option<Self> {
        let (lo, hi) = ctx.grid.voxel_bounds(id);
        let n: [usize; 3] = std::array::from_fn(|a| hi[a] - lo[a]);
        if n.contains(&0) {
            return None;
        }
        let vox = ctx.voxels.box_f32(lo, hi);
        Some(SampledBrick {
            n,
            vox,
            hints: Vec::new(),
        })
    }

    /// The least measured optical depth (per basis) over every core ray of index direction
    /// `d`, and with sets, every basis's depth on each basis's minimising ray: `funcs`
    /// values laid out as [`super::build`]'s bound writes them.
    pub(super) fn direction(&mut self, ctx: &Ctx<'_>, tau: &TauRows, d: [f64; 3], out: &mut [f64]) {
        match tau.lanes {
            4 => self.direction_with::<[f32; 4]>(ctx, tau, d, out, [0.0; 4]),
            8 => self.direction_with::<[f32; 8]>(ctx, tau, d, out, [0.0; 8]),
            l => self.direction_with::<Vec<f32>>(ctx, tau, d, out, vec![0.0; l]),
        }
    }

    fn direction_with<A: Acc>(
        &mut self,
        ctx: &Ctx<'_>,
        tau: &TauRows,
        d: [f64; 3],
        out: &mut [f64],
        mut acc: A,
    ) {
        let p = ctx.p;
        let lanes = tau.lanes;
        let (u, w) = ray_frame(d);
        let c = self.n.map(|x| x as f64 * 0.5);
        let radius = dot(c, c).sqrt();
        let pitch = ctx.pitch;
        let half = (radius / pitch).ceil() as i64;
        let cap = saturation_depth(ctx.margin);
        let mut sw = Sweep {
            best: vec![f32::INFINITY; p],
            at_best: vec![Vec::new(); if ctx.sets { p } else { 0 }],
            best_at: vec![c; p],
            lim: vec![f32::INFINITY; lanes],
            any_core: false,
        };
        for l in &mut sw.lim[..p] {
            *l = cap;
        }
        // Padding lanes never hold a ray back.
        for l in &mut sw.lim[p..] {
            *l = f32::NEG_INFINITY;
        }
        let step = ctx.step;
        // Rays one step shorter than L are measured too: where the span changes fast with
        // position (grazing directions, near an edge) the grid may hold no ray whose span
        // is just over L, and those shortest core rays are the lowest: leaving them out lets
        // a lookup exceed the brute-force minimum that `pof check` measures.
        let core = ctx.core - step;
        let phases: Vec<f64> = (0..ctx.phases)
            .map(|k| k as f64 / ctx.phases as f64)
            .collect();
        let df = d.map(|x| x as f32);
        let hints = std::mem::take(&mut self.hints);
        let this = &*self;
        let tri = this.sampler();
        let ray = |sw: &mut Sweep, acc: &mut A, i: i64, j: i64| -> bool {
            let (a, b) = (i as f64 * pitch, j as f64 * pitch);
            let q: [f64; 3] = std::array::from_fn(|k| c[k] + a * u[k] + b * w[k]);
            // Span in the box: t from the centre plane, the renderer's slab expression.
            let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
            for k in 0..3 {
                if d[k].abs() < 1e-12 {
                    if !(0.0..this.n[k] as f64).contains(&q[k]) {
                        return false;
                    }
                    continue;
                }
                let ta = -q[k] / d[k];
                let tb = (this.n[k] as f64 - q[k]) / d[k];
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
            if t1 - t0 < core {
                return false;
            }
            sw.any_core = true;
            let qf = q.map(|x| x as f32);
            for ph in &phases {
                let k0 = (t0 / step - ph).ceil() as i64;
                let k1 = (t1 / step - ph).ceil() as i64;
                acc.zero();
                let mut stopped = false;
                for k in k0..k1 {
                    let t = ((k as f64 + ph) * step) as f32;
                    let b = tau.bin(tri.sample([
                        qf[0] + t * df[0],
                        qf[1] + t * df[1],
                        qf[2] + t * df[2],
                    ]));
                    acc.add(&tau.rows, b);
                    if acc.all_ge(&sw.lim) {
                        stopped = true;
                        break;
                    }
                }
                if stopped {
                    continue;
                }
                let sums = acc.sums();
                for s in 0..p {
                    if sums[s] < sw.best[s] {
                        sw.best[s] = sums[s];
                        sw.lim[s] = sums[s].min(cap);
                        sw.best_at[s] = q;
                        if ctx.sets {
                            sw.at_best[s].clear();
                            sw.at_best[s].extend_from_slice(&sums[..p]);
                        }
                    }
                }
            }
            // Every basis at 0: no ray can go lower.
            sw.best.iter().all(|b| *b <= 0.0)
        };
        let mut done = false;
        for h in hints {
            let r = [h[0] - c[0], h[1] - c[1], h[2] - c[2]];
            let (i, j) = (
                (dot(r, u) / pitch).round() as i64,
                (dot(r, w) / pitch).round() as i64,
            );
            if ray(&mut sw, &mut acc, i, j) {
                done = true;
                break;
            }
        }
        if !done {
            'rays: for i in -half..=half {
                for j in -half..=half {
                    if ray(&mut sw, &mut acc, i, j) {
                        break 'rays;
                    }
                }
            }
        }
        self.hints.clone_from(&sw.best_at);
        for (o, b) in out[..p].iter_mut().zip(&sw.best) {
            *o = if sw.any_core {
                f64::from(b.min(cap))
            } else {
                // No core ray at all in this direction (L longer than the brick).
                0.0
            };
        }
        if ctx.sets {
            let mut k = p;
            for (s, sums) in sw.at_best.iter().enumerate() {
                for j in 0..p {
                    if j == s {
                        continue;
                    }
                    // A basis whose minimum was held back by the cap has no full sums: its
                    // companions keep their own minima.
                    out[k] = <[f32]>::get(sums, j)
                        .map_or(0.0, |v| f64::from(*v))
                        .max(out[j]);
                    k += 1;
                }
            }
        }
    }

    /// The trilinear sampler over the brick's voxels, in brick-local coordinates: the
    /// ray caster's own, so that a sample here is the renderer's sample, bit for bit.
    pub(super) fn sampler(&self) -> TrilinearSampler<'_, f32> {
        TrilinearSampler::new(&self.vox, self.n.map(|x| x + 1))
    }
}

/// An orthonormal basis `u`, `w` of the plane perpendicular to `d` (the plane the core
/// rays of a direction are spread over).
pub(super) fn ray_frame(d: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let len = dot(d, d).sqrt();
    let dh = d.map(|x| x / len);
    // Crossed with the axis least aligned with d, so that the cross product is well
    // conditioned.
    let e = (0..3)
        .min_by(|a, b| dh[*a].abs().total_cmp(&dh[*b].abs()))
        .expect("three axes");
    let mut ev = [0f64; 3];
    ev[e] = 1.0;
    let u = normalize(cross(dh, ev));
    let w = cross(dh, u);
    (u, w)
}

/// Depth beyond which a basis's stored opacity saturates at `ALPHA_MAX` (with the build's
/// `margin`): no ray need be summed further than that.
pub(super) fn saturation_depth(margin: f64) -> f32 {
    (-(1.0 - f64::from(super::ALPHA_MAX)).ln() / margin) as f32 * 1.001
}

pub(super) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub(super) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

pub(super) fn normalize(a: [f64; 3]) -> [f64; 3] {
    let l = dot(a, a).sqrt();
    a.map(|x| x / l)
}
