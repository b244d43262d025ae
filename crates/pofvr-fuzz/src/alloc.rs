//! A global allocator that records, per input, the largest single allocation asked for, and
//! refuses one past a hard ceiling so that a header claiming 10¹² voxels shows up as a
//! finding instead of taking the machine's memory.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Wraps [`System`]; install it with `#[global_allocator]` in the runner.
pub struct Capped;

/// The largest allocation the current input justifies; `usize::MAX` between inputs.
static LIMIT: AtomicUsize = AtomicUsize::new(usize::MAX);
/// The largest single allocation above [`LIMIT`] seen since [`arm`].
static WORST: AtomicUsize = AtomicUsize::new(0);
/// Never granted while armed: far past any justified size, well below the machine's memory.
pub const HARD_CEILING: usize = 1 << 31;

/// Starts watching allocations for one input allowed `limit` bytes in one allocation.
pub fn arm(limit: usize) {
    WORST.store(0, Ordering::SeqCst);
    LIMIT.store(limit, Ordering::SeqCst);
}

/// Stops watching; returns the largest allocation over the limit, if any.
pub fn disarm() -> Option<usize> {
    LIMIT.store(usize::MAX, Ordering::SeqCst);
    match WORST.swap(0, Ordering::SeqCst) {
        0 => None,
        n => Some(n),
    }
}

fn check(size: usize) -> bool {
    let limit = LIMIT.load(Ordering::Relaxed);
    if size > limit {
        WORST.fetch_max(size, Ordering::Relaxed);
        return size <= HARD_CEILING;
    }
    true
}

// SAFETY: every call is forwarded to `System` unchanged, or answered with null (a failed
// allocation, which the caller must handle) when the size is past the hard ceiling.
unsafe impl GlobalAlloc for Capped {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if !check(layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: the caller's contract is passed on unchanged.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if !check(layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: as for `alloc`.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System` through this allocator.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if !check(new_size) {
            return std::ptr::null_mut();
        }
        // SAFETY: as for `dealloc`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}
