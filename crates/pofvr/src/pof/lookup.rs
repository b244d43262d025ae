//! Run-time lookups: a brick's opacity along a view direction, or over a cone of them, for
//! given basis weights (Eq. 3, POF sets and the joint POF).

use glam::DVec3;

use super::cache::Lookup;
use super::{view_grid, PofTable};
use crate::brick::BrickId;

/// Largest stored per-basis opacity: keeps `ln(1 − α)` finite so that Eq. 3 with small
/// weights never turns a saturated basis into full opacity.
pub const ALPHA_MAX: f32 = 1.0 - 1.0 / 1_048_576.0;

/// How several bases are combined at run time (paper §3.2.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PofMode {
    /// Eq. 3 on the per-basis POFs: a lower bound of every core ray's opacity.
    Conservative,
    /// The minimum over the POF-set estimates at each basis's `q_min`: closer to the truth,
    /// not guaranteed (never below `Conservative`). Needs a table built with `sets`.
    Sets,
}

impl PofTable {
    pub(super) fn cell_opacity(
        &self,
        rec: &[u8],
        cell: (usize, usize),
        weights: &[f32],
        mode: PofMode,
    ) -> f32 {
        self.combine(|f| self.function_value(rec, f, cell), weights, mode)
    }

    /// The run-time opacity from the values of one view cell's functions (`value(f)`: the
    /// `f`-th encoded function, in record order).
    #[inline]
    fn combine(&self, value: impl Fn(usize) -> f32, weights: &[f32], mode: PofMode) -> f32 {
        let p = self.meta.basis_count as usize;
        let combine = |set_of: Option<usize>| -> f32 {
            // Eq. 3: 1 − Π (1 − αᵢ)^kᵢ. A weight of 1 (the common case) needs no power:
            // culling asks this for every visible brick and sub-brick of every frame.
            let mut t = 1.0f64;
            for (i, k) in weights.iter().enumerate().take(p) {
                if *k > 0.0 {
                    let mut a = value(i);
                    if let Some(s) = set_of {
                        // Each set entry is at least the basis's own POF; separately fitted
                        // cubics could lose that, so it is restored here.
                        a = a.max(value(self.function_index(i, Some(s))));
                    }
                    if a <= 0.0 {
                        continue;
                    }
                    let a = f64::from(a.min(ALPHA_MAX));
                    t *= if *k == 1.0 {
                        1.0 - a
                    } else {
                        (1.0 - a).powf(f64::from(*k))
                    };
                }
            }
            (1.0 - t) as f32
        };
        let a = match mode {
            PofMode::Sets if self.meta.sets => (0..p)
                .map(|s| combine(Some(s)))
                .fold(f32::INFINITY, f32::min),
            _ => combine(None),
        };
        let joint = if self.meta.joint.is_some() {
            self.joint_opacity(value(self.meta.functions() - 1), weights)
        } else {
            0.0
        };
        a.max(joint).clamp(0.0, self.meta.ert)
    }

    /// The joint POF scaled to `weights`: with anchor `a`, every weight vector is at least
    /// `c·a` for `c = minᵢ wᵢ/aᵢ` over the bases with `aᵢ > 0`, and a ray's optical depth
    /// grows with every weight, so `1 − (1 − α_joint)^c` stays a lower bound.
    fn joint_opacity(&self, stored: f32, weights: &[f32]) -> f32 {
        let Some(anchor) = &self.meta.joint else {
            return 0.0;
        };
        let mut c = f64::INFINITY;
        for (i, a) in anchor.iter().enumerate() {
            if *a > 0.0 {
                let w = weights.get(i).copied().unwrap_or(0.0).max(0.0);
                c = c.min(f64::from(w) / f64::from(*a));
            }
        }
        if !(c.is_finite() && c > 0.0) {
            return 0.0;
        }
        let aj = stored.clamp(0.0, ALPHA_MAX);
        if c == 1.0 || aj <= 0.0 {
            // The anchor's own weights (the common case): the joint POF as stored.
            return aj;
        }
        (1.0 - (1.0 - f64::from(aj)).powf(c)) as f32
    }

    /// Run-time opacity of `brick` seen along `view_dir` (unit world direction, eye to
    /// scene) with basis weights `weights`: every ray of that direction whose span in the
    /// brick is at least [`PofTable::core_length`] composites at least this much
    /// (`Conservative`). `Sets` on a table without sets falls back to `Conservative`.
    #[must_use]
    pub fn opacity(&self, brick: BrickId, view_dir: DVec3, weights: &[f32], mode: PofMode) -> f32 {
        let Some(s) = self.slot(brick) else {
            return 0.0;
        };
        self.with_lookup(view_dir, |at| match at {
            Lookup::Cell(cell) => self.cell_opacity(self.record(s), *cell, weights, mode),
            Lookup::Border(values) => {
                let funcs = self.meta.functions();
                let v = &values[s * funcs..(s + 1) * funcs];
                self.combine(|f| v[f], weights, mode)
            }
        })
    }

    /// As [`PofTable::opacity`] for every direction within `half_angle` radians of `axis`
    /// (perspective views: the cone under which the eye sees the brick): the minimum over
    /// every view cell the cone touches.
    #[must_use]
    pub fn opacity_cone(
        &self,
        brick: BrickId,
        axis: DVec3,
        half_angle: f64,
        weights: &[f32],
        mode: PofMode,
    ) -> f32 {
        let Some(s) = self.slot(brick) else {
            return 0.0;
        };
        let rec = self.record(s);
        let mut m = f32::INFINITY;
        for cell in view_grid::cone_cells(self.meta.views, axis, half_angle) {
            m = m.min(self.cell_opacity(rec, cell, weights, mode));
            if m <= 0.0 {
                break;
            }
        }
        if m.is_finite() {
            m
        } else {
            0.0
        }
    }
}
