//! A POF build with what it cost.

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use crate::brick::BrickGrid;
use crate::pof::{PofError, PofSettings, PofTable};
use crate::render::{SampledTf, TransferFunction};
use crate::volume::Volume;

/// A built table and what building it cost.
pub struct TimedBuild {
    /// The table.
    pub table: PofTable,
    /// Wall-clock seconds of the build.
    pub seconds: f64,
    /// CPU seconds of the process during the build, where the OS tells them.
    pub cpu_seconds: Option<f64>,
    /// Bricks computed in this build (the non-empty ones not resumed from a partial file).
    pub computed_bricks: u64,
    /// View cells per brick (θ rows × φ columns).
    pub views: usize,
    /// Worker threads the build could use.
    pub threads: usize,
}

impl TimedBuild {
    /// Brick-views per core-second: per CPU second used when known, else per wall second
    /// and worker thread. On a shared machine wall time × threads overstates the cores the
    /// build actually had, so the CPU time is preferred.
    #[must_use]
    pub fn brick_views_per_core_second(&self) -> f64 {
        let core_seconds = self
            .cpu_seconds
            .filter(|c| *c > 0.0)
            .unwrap_or(self.seconds * self.threads as f64);
        self.computed_bricks as f64 * self.views as f64 / core_seconds.max(1e-9)
    }
}

/// User + system CPU seconds of this process so far (Linux `/proc/self/stat`, in
/// USER_HZ = 100 ticks); `None` where the OS does not tell.
#[must_use]
pub fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// Builds the POFs of `grid`'s bricks for `tf`'s bases with `settings`, timed, resuming from
/// and saving to `partial` when given (see [`PofTable::build_resumable`]).
/// `progress(done, bricks)` is called as bricks finish, from the worker threads.
///
/// # Errors
/// [`PofError`] for bad settings or a partial file that cannot be read or written.
pub fn build_timed(
    volume: &Volume,
    grid: &BrickGrid,
    tf: &TransferFunction,
    settings: &PofSettings,
    partial: Option<&Path>,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<TimedBuild, PofError> {
    let sampled = SampledTf::new(tf, grid.value_range());
    let total = AtomicU64::new(0);
    let start = Instant::now();
    let cpu0 = process_cpu_seconds();
    let table =
        PofTable::build_resumable(volume, grid, tf, &sampled, settings, partial, &|done, n| {
            total.store(n, Ordering::Relaxed);
            progress(done, n);
        })?;
    Ok(TimedBuild {
        table,
        seconds: start.elapsed().as_secs_f64(),
        cpu_seconds: process_cpu_seconds().zip(cpu0).map(|(b, a)| b - a),
        computed_bricks: total.load(Ordering::Relaxed),
        views: settings.views[0] * settings.views[1],
        threads: rayon::current_num_threads(),
    })
}

#[cfg(test)]
mod test {
    use super::*;
    use crate::render::families;
    use crate::volume::phantom::Phantom;

    #[test]
    fn a_timed_build_counts_the_bricks_it_computed_and_its_rate() {
        let vol = Phantom::SheppLogan.generate(32);
        let grid = BrickGrid::from_volume(&vol, 16).unwrap();
        let tf = families::for_phantom(Phantom::SheppLogan);
        let settings = PofSettings {
            views: [4, 6],
            ..PofSettings::default()
        };
        let seen = AtomicU64::new(0);
        let b = build_timed(&vol, &grid, &tf, &settings, None, &|done, n| {
            assert!(done <= n);
            seen.fetch_max(n, Ordering::Relaxed);
        })
        .unwrap();
        assert_eq!(b.computed_bricks, seen.load(Ordering::Relaxed));
        assert!(b.computed_bricks > 0 && b.computed_bricks <= grid.len() as u64);
        assert_eq!(b.views, 24);
        assert!(b.seconds >= 0.0);
        let rate = b.brick_views_per_core_second();
        assert!(rate.is_finite() && rate > 0.0, "{rate}");

        // The rate divides brick-views by the CPU time, else by wall time × threads.
        let fixed = TimedBuild {
            seconds: 2.0,
            cpu_seconds: Some(4.0),
            computed_bricks: 10,
            threads: 8,
            ..b
        };
        assert_eq!(fixed.brick_views_per_core_second(), 10.0 * 24.0 / 4.0);
        let no_cpu = TimedBuild {
            cpu_seconds: None,
            ..fixed
        };
        assert_eq!(no_cpu.brick_views_per_core_second(), 10.0 * 24.0 / 16.0);
    }
}
