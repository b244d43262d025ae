//! The conservativeness audit of a POF table: random views of random non-empty bricks are
//! rendered by brute force ([`core_min`]), and each view's lookup must not exceed the least
//! opacity the ray caster composites over the brick's core footprint. A lookup above it
//! would let culling hide a brick that shows through.
//!
//! The views are drawn from a seeded generator, so an audit is reproducible; every fourth
//! looks along a coordinate axis, because those directions lie on the borders of view cells
//! where lookups take the best of the cells that meet there.

use std::sync::atomic::{AtomicU64, Ordering};

use glam::DVec3;
use rayon::prelude::*;

use crate::brick::{BrickGrid, BrickId};
use crate::pof::reference::{core_min, ReferenceProbe};
use crate::pof::{PofMode, PofTable};
use crate::render::{SampledTf, TransferFunction};
use crate::volume::Volume;

/// The lookups an audit checks and the sampling they claim to bound.
///
/// [`PofTable`] is the one implementation in the library; the trait lets a test audit a
/// deliberately corrupted table.
pub trait AuditedTable: Sync {
    /// The sample distance the lookups bound, in units of the smallest spacing.
    fn step(&self) -> f32;
    /// The early-termination threshold the lookups are capped at.
    fn ert(&self) -> f32;
    /// The least span of a ray inside a brick for the lookups to hold on it.
    fn core_length(&self) -> f32;
    /// The conservative lookup for brick `id` seen along the unit direction `dir`.
    fn lookup(&self, id: BrickId, dir: DVec3, weights: &[f32]) -> f32;
}

impl AuditedTable for PofTable {
    fn step(&self) -> f32 {
        PofTable::step(self)
    }

    fn ert(&self) -> f32 {
        PofTable::ert(self)
    }

    fn core_length(&self) -> f32 {
        PofTable::core_length(self)
    }

    fn lookup(&self, id: BrickId, dir: DVec3, weights: &[f32]) -> f32 {
        self.opacity(id, dir, weights, PofMode::Conservative)
    }
}

/// What [`audit_table`] found.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AuditSummary {
    /// Brute-force views rendered.
    pub views: usize,
    /// Views with at least one pixel in the core (the others bound nothing).
    pub with_core: usize,
    /// Views whose lookup exceeds the brute-force core minimum.
    pub violations: usize,
    /// The largest such excess (0 when there is none).
    pub worst_excess: f32,
    /// Mean lookup over the views with a core.
    pub mean_lookup: f64,
    /// Mean brute-force core minimum over the views with a core.
    pub mean_true_min: f64,
    /// Share of footprint pixels whose ray spans at least L: where the POF is composited.
    pub core_share: f64,
}

impl AuditSummary {
    /// True when no view's lookup exceeds its brute-force minimum.
    #[must_use]
    pub fn holds(&self) -> bool {
        self.violations == 0
    }
}

/// Why an audit could not run.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum AuditError {
    /// Every brick is empty for the weights: there is nothing to look up.
    #[error("no non-empty brick to check for these weights")]
    NoBricks,
}

/// Audits `table` against brute force over `views` views (drawn from `seed`) of the bricks
/// that are non-empty for `tf`'s weights. `progress(done, views)` is called after each view,
/// from the worker threads.
///
/// The table must be the one for `volume`, `grid` and `tf`'s bases (as
/// [`PofTable::load`] checks).
///
/// # Errors
/// [`AuditError::NoBricks`] when every brick is empty for the weights.
pub fn audit_table(
    volume: &Volume,
    grid: &BrickGrid,
    tf: &TransferFunction,
    table: &dyn AuditedTable,
    views: usize,
    seed: u64,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<AuditSummary, AuditError> {
    let sampled = SampledTf::new(tf, grid.value_range());
    let stored: Vec<BrickId> = grid
        .ids()
        .filter(|id| !sampled.is_empty(grid.range(*id), &tf.weights))
        .collect();
    if stored.is_empty() {
        return Err(AuditError::NoBricks);
    }
    let probes = probes(&stored, views, seed);
    let done = AtomicU64::new(0);
    let total = views as u64;
    let results: Vec<(f32, Option<f32>, usize, usize)> = probes
        .par_iter()
        .map(|(id, p)| {
            let r = core_min(
                volume,
                grid,
                &sampled,
                *id,
                &tf.weights,
                table.step(),
                table.ert(),
                table.core_length(),
                p,
            );
            let a = table.lookup(*id, p.dir, &tf.weights);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            (a, r.core_min, r.core_pixels, r.footprint_pixels)
        })
        .collect();
    let mut s = AuditSummary {
        views,
        ..AuditSummary::default()
    };
    let (mut core_px, mut foot_px) = (0usize, 0usize);
    for (a, m, c, f) in results {
        core_px += c;
        foot_px += f;
        let Some(m) = m else { continue };
        s.with_core += 1;
        s.mean_lookup += f64::from(a);
        s.mean_true_min += f64::from(m);
        if a > m {
            s.violations += 1;
            s.worst_excess = s.worst_excess.max(a - m);
        }
    }
    let k = s.with_core.max(1) as f64;
    s.mean_lookup /= k;
    s.mean_true_min /= k;
    s.core_share = core_px as f64 / foot_px.max(1) as f64;
    Ok(s)
}

/// The audit's views: `n` (brick, placement) pairs drawn from `seed`.
fn probes(stored: &[BrickId], n: usize, seed: u64) -> Vec<(BrickId, ReferenceProbe)> {
    const AXES: [DVec3; 6] = [
        DVec3::X,
        DVec3::NEG_X,
        DVec3::Y,
        DVec3::NEG_Y,
        DVec3::Z,
        DVec3::NEG_Z,
    ];
    let mut rng = Rng(seed);
    (0..n)
        .map(|k| {
            let id = stored[(rng.next() % stored.len() as u64) as usize];
            let dir = if k % 4 == 3 {
                AXES[(k / 4) % AXES.len()]
            } else {
                rng.dir()
            };
            (
                id,
                ReferenceProbe {
                    dir,
                    phase: rng.unit(),
                    jitter: [rng.unit(), rng.unit()],
                    pixel: 0.5,
                },
            )
        })
        .collect()
}

/// A small deterministic generator (SplitMix64), so that an audit's seed fixes its views on
/// every platform.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1), from the top 53 bits.
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform on the unit sphere.
    fn dir(&mut self) -> DVec3 {
        let z = self.unit() * 2.0 - 1.0;
        let phi = self.unit() * std::f64::consts::TAU;
        let r = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(r * phi.cos(), r * phi.sin(), z)
    }
}

#[cfg(test)]
mod test {
    use super::*;
    use crate::pof::PofSettings;
    use crate::render::families;
    use crate::volume::phantom::Phantom;

    /// A table whose every lookup is raised by `by` (capped at 1): no longer a lower bound.
    struct Raised<'a>(&'a PofTable, f32);

    impl AuditedTable for Raised<'_> {
        fn step(&self) -> f32 {
            self.0.step()
        }
        fn ert(&self) -> f32 {
            self.0.ert()
        }
        fn core_length(&self) -> f32 {
            self.0.core_length()
        }
        fn lookup(&self, id: BrickId, dir: DVec3, weights: &[f32]) -> f32 {
            (self.0.lookup(id, dir, weights) + self.1).min(1.0)
        }
    }

    fn phantom() -> (Volume, BrickGrid, TransferFunction, PofTable) {
        let vol = Phantom::SheppLogan.generate(32);
        let grid = BrickGrid::from_volume(&vol, 16).unwrap();
        let tf = families::for_phantom(Phantom::SheppLogan);
        let sampled = SampledTf::new(&tf, grid.value_range());
        let settings = PofSettings {
            views: [8, 8],
            ..PofSettings::default()
        };
        let table = PofTable::build(&vol, &grid, &tf, &sampled, &settings, &|_, _| {}).unwrap();
        (vol, grid, tf, table)
    }

    #[test]
    fn a_built_table_passes_and_a_raised_one_fails() {
        let (vol, grid, tf, table) = phantom();
        let calls = AtomicU64::new(0);
        let count = |done: u64, total: u64| {
            assert!(done >= 1 && done <= total && total == 40);
            calls.fetch_add(1, Ordering::Relaxed);
        };
        let good = audit_table(&vol, &grid, &tf, &table, 40, 1, &count).unwrap();
        assert_eq!(calls.load(Ordering::Relaxed), 40);
        assert!(good.holds(), "{good:?}");
        assert_eq!(good.views, 40);
        assert!(good.with_core > 0, "{good:?}");
        assert!(good.mean_lookup <= good.mean_true_min, "{good:?}");
        assert!(good.core_share > 0.0 && good.core_share <= 1.0, "{good:?}");

        // Raised by more than the gap between lookup and minimum: each view with a core
        // whose minimum is below 1 − 0.5 now exceeds it.
        let bad = audit_table(&vol, &grid, &tf, &Raised(&table, 0.5), 40, 1, &|_, _| {}).unwrap();
        assert!(!bad.holds(), "{bad:?}");
        assert_eq!(bad.with_core, good.with_core);
        assert!(bad.violations > good.with_core / 2, "{bad:?}");
        assert!(
            bad.worst_excess > 0.0 && bad.worst_excess <= 0.5 + 1e-6,
            "{bad:?}"
        );
        assert!(bad.mean_lookup > good.mean_lookup, "{bad:?} vs {good:?}");
    }

    #[test]
    fn the_seed_fixes_the_views() {
        let (vol, grid, tf, table) = phantom();
        let a = audit_table(&vol, &grid, &tf, &table, 24, 5, &|_, _| {}).unwrap();
        let b = audit_table(&vol, &grid, &tf, &table, 24, 5, &|_, _| {}).unwrap();
        assert_eq!(a, b);
        let stored: Vec<BrickId> = grid.ids().collect();
        assert_eq!(probes(&stored, 24, 5), probes(&stored, 24, 5));
        assert_ne!(probes(&stored, 24, 5), probes(&stored, 24, 6));
        // Every fourth view looks along an axis, cycling through the six.
        let p = probes(&stored, 24, 5);
        assert_eq!(p[3].1.dir, DVec3::X);
        assert_eq!(p[7].1.dir, DVec3::NEG_X);
        assert_eq!(p[23].1.dir, DVec3::NEG_Z);
    }

    #[test]
    fn weights_that_empty_every_brick_are_an_error() {
        let (vol, grid, mut tf, table) = phantom();
        tf.weights.iter_mut().for_each(|w| *w = 0.0);
        let e = audit_table(&vol, &grid, &tf, &table, 10, 1, &|_, _| {}).unwrap_err();
        assert_eq!(e, AuditError::NoBricks);
        assert_eq!(
            e.to_string(),
            "no non-empty brick to check for these weights"
        );
    }

    #[test]
    fn the_generator_is_splitmix64() {
        // The first outputs of SplitMix64 from seed 0 (Vigna's reference implementation).
        let mut r = Rng(0);
        assert_eq!(r.next(), 0xe220_a839_7b1d_cdaf);
        assert_eq!(r.next(), 0x6e78_9e6a_a1b9_65f4);
        let mut r = Rng(9);
        for _ in 0..1000 {
            let u = r.unit();
            assert!((0.0..1.0).contains(&u));
            let d = r.dir();
            assert!((d.length() - 1.0).abs() < 1e-12);
        }
    }
}
