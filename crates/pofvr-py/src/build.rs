//! POF builds that Python can watch and stop: the build runs on its own thread (and the
//! library's worker pool) while the calling thread, without the GIL between checks,
//! reports progress and checks for signals, so that Ctrl-C (`KeyboardInterrupt`) stops it
//! between bricks.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use pofvr::{PofBuild, PofTable, Scene};
use pyo3::prelude::*;

use crate::error::OrPy;

/// How a build shows its progress.
pub(crate) enum Progress<'py> {
    /// Not at all.
    Quiet,
    /// A line on `sys.stderr`, rewritten in place on a terminal; elsewhere (a log, a
    /// notebook's captured stream) one line per tenth of the bricks.
    Line,
    /// `callback(done, total)` in the calling thread.
    Call(Bound<'py, PyAny>),
}

/// How often the calling thread wakes to report progress and check for signals.
const TICK: Duration = Duration::from_millis(50);

/// `scene`'s POFs built with `build`, showing `progress`.
///
/// # Errors
/// The library's error, or the `KeyboardInterrupt` (or other signal handler's exception)
/// that stopped it.
pub(crate) fn build_pofs(
    py: Python<'_>,
    scene: &Scene,
    build: &PofBuild,
    progress: &Progress<'_>,
) -> PyResult<PofTable> {
    let cancel = AtomicBool::new(false);
    let (done, total) = (AtomicU64::new(0), AtomicU64::new(u64::MAX));
    let record = |d: u64, t: u64| {
        done.fetch_max(d, Ordering::Relaxed);
        total.store(t, Ordering::Relaxed);
    };
    let mut shown = None;
    let tty = matches!(progress, Progress::Line)
        && py
            .import("sys")?
            .getattr("stderr")?
            .call_method0("isatty")
            .and_then(|t| t.is_truthy())
            .unwrap_or(false);
    let mut tenth = None;
    let result = std::thread::scope(|s| {
        let worker = s.spawn(|| scene.build_pofs_cancellable(build, &record, &cancel));
        loop {
            let finished = py.allow_threads(|| {
                std::thread::sleep(TICK);
                worker.is_finished()
            });
            let now = (done.load(Ordering::Relaxed), total.load(Ordering::Relaxed));
            let mut checked = Ok(());
            if now.1 != u64::MAX && shown != Some(now) {
                shown = Some(now);
                // A signal arriving while the callback runs Python code is raised there.
                checked = show(py, progress, tty, &mut tenth, now);
            }
            if let Err(e) = checked.and_then(|()| py.check_signals()) {
                cancel.store(true, Ordering::Relaxed);
                // Bricks in flight finish (one per worker); none start after the flag. The
                // scope would wait for the worker anyway: it must stop first.
                let _ = py.allow_threads(|| worker.join());
                return Err(e);
            }
            if finished {
                return Ok(worker.join());
            }
        }
    });
    if tty && shown.is_some() {
        py.import("sys")?
            .getattr("stderr")?
            .call_method1("write", ("\n",))?;
    }
    match result? {
        Ok(table) => table.or_py(),
        Err(_) => Err(pyo3::exceptions::PyRuntimeError::new_err(
            "the POF build panicked",
        )),
    }
}

fn show(
    py: Python<'_>,
    progress: &Progress<'_>,
    tty: bool,
    tenth: &mut Option<u64>,
    (done, total): (u64, u64),
) -> PyResult<()> {
    match progress {
        Progress::Quiet => Ok(()),
        Progress::Line => {
            let line = format!("building POFs: {done}/{total} bricks");
            let text = if tty {
                format!("\r{line}")
            } else {
                let t = (done * 10).checked_div(total).unwrap_or(10);
                if *tenth == Some(t) {
                    return Ok(());
                }
                *tenth = Some(t);
                format!("{line}\n")
            };
            let err = py.import("sys")?.getattr("stderr")?;
            err.call_method1("write", (text,))?;
            err.call_method0("flush")?;
            Ok(())
        }
        Progress::Call(f) => f.call1((done, total)).map(drop),
    }
}
