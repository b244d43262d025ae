//! The allocator's part of `--memory-budget`: under a budget the peak resident size is what
//! the user asked for, and glibc's malloc keeps freed blocks by default.
//!
//! glibc serves a block of at least `M_MMAP_THRESHOLD` bytes (128 KiB) by its own mapping and
//! unmaps it on free, but each such free raises the threshold (up to 32 MiB), after which
//! blocks of that size come from the per-thread heaps and stay resident once freed. The
//! budgeted paths allocate and free many such blocks (decoded 64³ Zarr chunks of 512 KiB,
//! slabs, brick copies) from several threads, so the retained heap grew past the budget:
//! measured on the 512×512×1728 body phantom as Zarr at `--memory-budget 256M`, a verified
//! frame peaked at 554 MB RSS, and 415 MB with the threshold fixed at 128 KiB (the same as
//! `MALLOC_MMAP_THRESHOLD_=131072`, `MALLOC_ARENA_MAX=1` or `MALLOC_TRIM_THRESHOLD_=0`).

/// Fixes glibc's mmap threshold at its default, so that large freed blocks go back to the
/// system instead of staying in the heap; elsewhere (musl, macOS) nothing to do.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
pub(crate) fn return_large_blocks() {
    // SAFETY: `mallopt` only sets an allocator parameter (under glibc's own arena lock);
    // it has no memory-safety preconditions. A rejected value leaves the default.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 128 * 1024);
    }
}

/// Fixes glibc's mmap threshold (see above); nothing to do on other C libraries.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub(crate) fn return_large_blocks() {}
