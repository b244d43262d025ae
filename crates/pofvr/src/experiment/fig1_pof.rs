//! Figure 1: POF construction, the build time and storage of each encoding.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use serde::Serialize;

use crate::frame::RenderJob;
use crate::pof::{Encoding, PofSettings, PofTable};

use super::{ExperimentError, Progress};

/// Where the table encoding comes from.
pub enum PofSource {
    /// Read beforehand (from the file named), not timed.
    Read {
        /// The table (boxed: a table is large beside the other variant).
        table: Box<PofTable>,
        /// Where it came from, as the figure's `source` column says it.
        from: String,
    },
    /// Built here, timed.
    Build,
}

/// One POF build (or read) of figure 1.
#[derive(Clone, Debug, Serialize)]
pub struct PofBuildRow {
    /// Encoding name.
    pub encoding: &'static str,
    /// Whether the table holds POF sets.
    pub sets: bool,
    /// The view grid, `NxM`.
    pub views: String,
    /// `built` (`built, streamed from the …` when read through the brick store), or where
    /// the table was read from.
    pub source: String,
    /// Build time (absent when read).
    pub seconds: Option<f64>,
    /// Bricks whose POFs were computed (absent when read).
    pub computed_bricks: Option<u64>,
    /// Brick-views per second per worker thread.
    pub rate: Option<f64>,
    /// Storage per brick and basis.
    pub bytes_per_brick_per_basis: f64,
    /// Bricks with stored POFs.
    pub stored_bricks: usize,
    /// Size of the file the table saves to.
    pub file_bytes: usize,
    /// Bytes the build read from the brick store (built from the store under a memory
    /// budget the volume does not fit; absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bytes_read: Option<u64>,
}

impl PofBuildRow {
    /// The row of table `t`, timed when `built` (seconds, computed bricks).
    #[must_use]
    pub fn of(t: &PofTable, encoding: Encoding, source: &str, built: Option<(f64, u64)>) -> Self {
        let views = t.meta().views;
        let rate = built.map(|(s, n)| {
            n as f64 * f64::from(views[0]) * f64::from(views[1])
                / s.max(1e-9)
                / rayon::current_num_threads() as f64
        });
        PofBuildRow {
            encoding: encoding.name(),
            sets: t.has_sets(),
            views: format!("{}x{}", views[0], views[1]),
            source: source.to_string(),
            seconds: built.map(|b| b.0),
            computed_bricks: built.map(|b| b.1),
            rate,
            bytes_per_brick_per_basis: t.bytes_per_brick_per_basis(),
            stored_bricks: t.stored_bricks(),
            file_bytes: t.file_len(),
            bytes_read: None,
        }
    }

    /// The file size in megabytes.
    #[must_use]
    pub fn file_mb(&self) -> f64 {
        self.file_bytes as f64 / 1e6
    }

    /// The row's label: the encoding, `+ sets` when it has them.
    #[must_use]
    pub fn label(&self) -> String {
        if self.sets {
            format!("{} + sets", self.encoding)
        } else {
            self.encoding.to_string()
        }
    }
}

/// Figure 1's rows and the tables built, which the culling figures then use.
#[derive(Serialize)]
pub struct PofBuild {
    /// One row per table, the table encoding first.
    pub rows: Vec<PofBuildRow>,
    /// The table encoding.
    #[serde(skip)]
    pub table: PofTable,
    /// Whether `table` was built here (not read).
    pub table_built: bool,
    /// The cubic encoding.
    #[serde(skip)]
    pub cubic: PofTable,
    /// Tables with POF sets, when built here (`table` may hold sets itself).
    #[serde(skip)]
    pub sets_table: Option<PofTable>,
}

impl PofBuild {
    /// The table with POF sets for the aggressive mode, if any.
    #[must_use]
    pub fn sets(&self) -> Option<&PofTable> {
        if self.table.has_sets() {
            Some(&self.table)
        } else {
            self.sets_table.as_ref()
        }
    }
}

/// Builds (or takes) the table encoding, builds the u8, u16 and cubic encodings, and the
/// table with POF sets when `want_sets` and the table has none, over a `views` grid with
/// the job's step and early termination.
///
/// # Errors
/// [`ExperimentError::Pof`] when a build fails.
pub fn pof_construction(
    job: &RenderJob,
    views: [usize; 2],
    table: PofSource,
    want_sets: bool,
    progress: &dyn Progress,
) -> Result<PofBuild, ExperimentError> {
    let mut rows = Vec::new();
    let (table, table_built) = match table {
        PofSource::Read { table, from } => {
            rows.push(PofBuildRow::of(
                &table,
                Encoding::Table,
                &format!("read from {from}"),
                None,
            ));
            (*table, false)
        }
        PofSource::Build => {
            let (t, row) = build(job, views, Encoding::Table, false, progress)?;
            rows.push(row);
            (t, true)
        }
    };
    let mut cubic = None;
    for enc in [Encoding::U8, Encoding::U16, Encoding::Cubic] {
        let (t, row) = build(job, views, enc, false, progress)?;
        rows.push(row);
        if enc == Encoding::Cubic {
            cubic = Some(t);
        }
    }
    let sets_table = if !table.has_sets() && want_sets {
        let (t, row) = build(job, views, Encoding::Table, true, progress)?;
        rows.push(row);
        Some(t)
    } else {
        None
    };
    Ok(PofBuild {
        rows,
        table,
        table_built,
        cubic: cubic.expect("the loop builds the cubic encoding"),
        sets_table,
    })
}

/// Builds the POFs of the job's volume and family in one encoding, timed.
fn build(
    job: &RenderJob,
    views: [usize; 2],
    encoding: Encoding,
    sets: bool,
    progress: &dyn Progress,
) -> Result<(PofTable, PofBuildRow), ExperimentError> {
    let settings = PofSettings {
        views,
        encoding,
        sets,
        step: job.settings.step,
        ert: job.settings.ert,
        ..PofSettings::default()
    };
    progress.begin(&format!("fig 1: POFs, {encoding}"), 0);
    let total = AtomicU64::new(0);
    let on_progress = |done, n| {
        total.store(n, Ordering::Relaxed);
        progress.set(done, n);
    };
    let t = Instant::now();
    let (table, source, bytes_read) = match job.store.as_ref().filter(|s| s.source().is_file()) {
        // A volume read through its brick store (larger than the memory budget) is never
        // sampled through its mapping: the build reads it slab by slab from the store, the
        // same table bit for bit (`store/test_pof.rs`), its slabs within the budget less a
        // Zarr level's decoded-chunk share.
        Some(store) => {
            let chunks = store
                .source()
                .zarr()
                .map_or(0, crate::store::ZarrSource::chunk_budget);
            let (table, r) = crate::pof::build_streamed_in_memory(
                &job.volume,
                store.source(),
                &job.grid,
                &job.tf,
                &job.sampled,
                &settings,
                store.budget().saturating_sub(chunks).max(1),
                &on_progress,
                None,
            )?;
            let how = format!(
                "built, streamed from the {} ({} bytes read in {} slabs)",
                store.source().kind(),
                r.bytes_read,
                r.slabs_read
            );
            (table, how, Some(r.bytes_read))
        }
        None => (
            PofTable::build(
                &job.volume,
                &job.grid,
                &job.tf,
                &job.sampled,
                &settings,
                &on_progress,
            )?,
            "built".to_string(),
            None,
        ),
    };
    let seconds = t.elapsed().as_secs_f64();
    progress.end();
    let row = PofBuildRow {
        bytes_read,
        ..PofBuildRow::of(
            &table,
            encoding,
            &source,
            Some((seconds, total.load(Ordering::Relaxed))),
        )
    };
    Ok((table, row))
}
