//! What lookups remember: where the lookups of a view direction read (per thread, for the
//! last few directions) and, for directions on the borders of view cells, the per-function
//! maxima over the cells that meet there (per table).

use glam::DVec3;

use std::sync::{Arc, Mutex, PoisonError, Weak};

use super::{view_grid, Encoding, PofTable};

/// The cells meeting at a border direction, and per record each function's largest value
/// over them.
type BorderValues = (Vec<(usize, usize)>, Arc<[f32]>);

/// What a table's lookups remember.
#[derive(Default)]
pub(super) struct Caches {
    /// Tells this table from every other in the per-thread lookup cache
    /// ([`PofTable::with_lookup`]): its address, held by a weak reference in each cache
    /// entry so that no later table can get the same one while an entry may name it.
    identity: Arc<()>,
    /// Per record, each function's largest value over the cells that meet at a border
    /// direction ([`PofTable::border_values`]), by the cells' list: made on first use.
    borders: Mutex<Vec<BorderValues>>,
}

/// Where the lookups of one view direction read: one cell, or (a direction on the border
/// of several cells) the per-function maxima over them.
pub(super) enum Lookup {
    Cell((usize, usize)),
    Border(Arc<[f32]>),
}

impl PofTable {
    /// Runs `f` with where the lookups along `dir` read, remembered per thread for the
    /// last directions: a frame asks for one direction thousands of times (orthographic
    /// views), and the angles cost an `acos` and an `atan2`. A few entries, not one: tables
    /// of different view grids (core levels, sub-brick tables) are looked up in turn, and
    /// one entry would miss every time.
    ///
    /// Why per thread and not a field of the table: the culler's strips look the same
    /// direction up from several threads at once, thousands of times a frame, and a shared
    /// cache would take a lock (or bounce a cache line between cores) on every lookup. What
    /// is cached is a pure function of the table and the direction, so the cache changes
    /// no result, only how often it is computed.
    pub(super) fn with_lookup<R>(&self, dir: DVec3, f: impl FnOnce(&Lookup) -> R) -> R {
        /// The direction's bits and the table's [`Caches::identity`].
        type Key = ([u64; 3], *const ());
        type Entry = Option<(Key, Weak<()>, Lookup)>;
        const WAYS: usize = 4;
        thread_local! {
            // The entries and the next one to replace (borrowed in place, not copied out).
            static LAST: std::cell::RefCell<([Entry; WAYS], usize)> =
                const { std::cell::RefCell::new(([None, None, None, None], 0)) };
        }
        let key = (
            dir.to_array().map(f64::to_bits),
            Arc::as_ptr(&self.caches.identity),
        );
        LAST.with_borrow_mut(|(ways, next)| {
            if let Some((_, _, at)) = ways.iter().flatten().find(|(k, _, _)| *k == key) {
                return f(at);
            }
            let cells = view_grid::border_cells(self.meta.views, dir);
            let at = match cells.as_slice() {
                [one] => Lookup::Cell(*one),
                // Cubic POFs are smooth across cells: nothing to gain on a border.
                _ if self.meta.encoding == Encoding::Cubic => Lookup::Cell(self.cell_of(dir)),
                _ => Lookup::Border(self.border_values(cells)),
            };
            let r = f(&at);
            ways[*next] = Some((key, Arc::downgrade(&self.caches.identity), at));
            *next = (*next + 1) % WAYS;
            r
        })
    }

    /// [`PofTable::cell_of`], through the per-thread cache of [`PofTable::with_lookup`].
    #[cfg(test)]
    pub(super) fn cell_of_cached(&self, dir: DVec3) -> (usize, usize) {
        self.with_lookup(dir, |at| match at {
            Lookup::Cell(c) => *c,
            Lookup::Border(_) => self.cell_of(dir),
        })
    }

    /// Per record, each function's largest value over `cells`, the cells whose borders
    /// meet at one direction (the poles, where a whole row of cells meets, and the axes and
    /// grid lines between two or four).
    ///
    /// Why: every cell's value bounds every direction of the cell *and its border*, so a
    /// direction on the border is bounded by each of them, per basis and for the joint POF:
    /// by the largest. Axis-aligned views, the commonest of all, look along such directions;
    /// with one cell chosen by rounding, a brick read as transparent there when a
    /// neighbouring cell knew better.
    pub(super) fn border_values(&self, cells: Vec<(usize, usize)>) -> Arc<[f32]> {
        let mut made = self
            .caches
            .borders
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if let Some((_, v)) = made.iter().find(|(c, _)| *c == cells) {
            return v.clone();
        }
        let funcs = self.meta.functions();
        let slots =
            self.bytes.as_slice().len().saturating_sub(self.data_offset) / self.record_len.max(1);
        let mut values = vec![0f32; slots * funcs];
        for (s, out) in values.chunks_exact_mut(funcs).enumerate() {
            let rec = self.record(s);
            for (f, o) in out.iter_mut().enumerate() {
                *o = cells
                    .iter()
                    .map(|c| self.function_value(rec, f, *c))
                    .fold(0.0, f32::max);
            }
        }
        let values: Arc<[f32]> = values.into();
        made.push((cells, values.clone()));
        values
    }
}
