//! Prefetching the cache lines lookups are about to read.

use glam::DVec3;

use super::cache::Lookup;
use super::{encoding, PofTable};
use crate::brick::BrickId;

impl PofTable {
    /// Starts loading the cache lines [`PofTable::opacity`] reads for each of `bricks`
    /// along `view_dir` (each function's value in the direction's cell), without waiting.
    pub fn prefetch(&self, bricks: &[BrickId], view_dir: DVec3) {
        // Border directions read a small array of their own, not the records.
        let Some(cell) = self.with_lookup(view_dir, |at| match at {
            Lookup::Cell(c) => Some(*c),
            Lookup::Border(_) => None,
        }) else {
            return;
        };
        let funcs = self.meta.functions();
        let range = |f: usize| {
            encoding::value_range(
                self.meta.encoding,
                funcs,
                f,
                self.meta.views,
                cell,
                self.meta.cell_major,
            )
        };
        // The first byte of each function's value in the cell; in a cell-major record they
        // are side by side, so the first and last byte cover them (across a line boundary).
        // Culling calls this per visible brick: no allocation.
        let (first, last) = (range(0).start, range(funcs - 1).end - 1);
        let step = if self.meta.cell_major {
            0
        } else {
            range(1.min(funcs - 1)).start - first
        };
        let data = self.bytes.as_slice();
        for &b in bricks {
            if let Some(s) = self.slot(b) {
                let rec = self.data_offset + s * self.record_len;
                if self.meta.cell_major {
                    for i in [first, last] {
                        if let Some(x) = data.get(rec + i) {
                            prefetch_line(x);
                        }
                    }
                } else {
                    for f in 0..funcs {
                        if let Some(x) = data.get(rec + first + f * step) {
                            prefetch_line(x);
                        }
                    }
                }
            }
        }
    }
}

/// Asks the CPU to bring the cache line holding `b` closer: a hint, with no effect on
/// results.
#[inline]
fn prefetch_line(b: &u8) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch reads nothing architecturally and cannot fault; SSE is part of the
    // x86_64 baseline.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
            std::ptr::from_ref(b).cast::<i8>(),
        );
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = b;
}
