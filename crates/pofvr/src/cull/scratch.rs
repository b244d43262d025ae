//! The opacity buffers culling draws on, kept from frame to frame by their owner.

use std::sync::{Mutex, PoisonError};

/// A pool of opacity buffers for [`super::Culler`], owned by whatever outlives the frames
/// (a render job) and lent to each frame's culler.
///
/// Why: a frame's buffer is megabytes, and a fresh allocation each frame would be fresh
/// pages, each faulted in on first touch. Buffers are kept instead, one per culler that
/// ran at once (ranks may be threads that live for one frame, and strips of a tile are
/// culled in parallel), and cleared before use.
#[derive(Default)]
pub struct CullScratch {
    buffers: Mutex<Vec<Vec<f32>>>,
}

/// Buffers kept at most: as many as cullers run at once, within reason.
const MAX_KEPT: usize = 64;

impl CullScratch {
    /// An empty pool.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// A buffer of `len` zeros, reusing a kept one when there is one.
    pub(super) fn take(&self, len: usize) -> Vec<f32> {
        let mut buffer = self
            .buffers
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .pop()
            .unwrap_or_default();
        buffer.clear();
        buffer.resize(len, 0.0);
        buffer
    }

    /// Keeps `buffer` for a later [`CullScratch::take`].
    pub(super) fn give(&self, buffer: Vec<f32>) {
        let mut pool = self.buffers.lock().unwrap_or_else(PoisonError::into_inner);
        if pool.len() < MAX_KEPT {
            pool.push(buffer);
        }
    }
}

impl std::fmt::Debug for CullScratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let kept = self
            .buffers
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .len();
        f.debug_struct("CullScratch").field("kept", &kept).finish()
    }
}
