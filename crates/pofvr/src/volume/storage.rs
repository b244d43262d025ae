use std::sync::Arc;

use memmap2::Mmap;

use super::Voxel;

/// Typed voxels served from a memory map (no copy), from an owned buffer (decompressed,
/// byte-swapped, misaligned or generated data), or from memory borrowed from another owner
/// (e.g. a numpy array; no copy).
pub struct Voxels<T: Voxel> {
    repr: Repr<T>,
}

enum Repr<T: 'static> {
    /// Shared, so that a second handle ([`Voxels::share`]) costs no copy.
    Owned(Arc<Vec<T>>),
    Mapped {
        map: Arc<Mmap>,
        offset: usize,
        len: usize,
    },
    /// Voxels that are not in memory: a Zarr level larger than the memory budget, whose
    /// chunks a brick store decodes on demand ([`Voxels::deferred`]).
    Deferred { len: usize },
    /// Memory someone else owns, valid while `_owner` lives ([`Voxels::borrowed`]).
    Borrowed {
        _owner: Arc<dyn Send + Sync>,
        data: &'static [T],
    },
}

impl<T: Voxel> std::fmt::Debug for Voxels<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Voxels")
            .field("type", &T::TYPE)
            .field("len", &self.len())
            .field("mapped", &self.is_mapped())
            .finish()
    }
}

impl<T: Voxel> Voxels<T> {
    /// Owns `v`.
    #[must_use]
    pub fn owned(v: Vec<T>) -> Self {
        Voxels {
            repr: Repr::Owned(Arc::new(v)),
        }
    }

    /// `len` voxels that are not held in memory: every path that samples the whole lattice
    /// must check [`Voxels::is_resident`] first (the volume's brick store reads them).
    #[must_use]
    pub fn deferred(len: usize) -> Self {
        Voxels {
            repr: Repr::Deferred { len },
        }
    }

    /// False for [`Voxels::deferred`] voxels.
    #[must_use]
    pub fn is_resident(&self) -> bool {
        !matches!(self.repr, Repr::Deferred { .. })
    }

    /// Serves `len` voxels at byte `offset` of `map`, without copying when the offset is
    /// aligned for `T` and the file is little-endian; otherwise copies once (and swaps).
    #[must_use]
    pub fn from_map(map: Arc<Mmap>, offset: usize, len: usize, big_endian: bool) -> Self {
        let bytes = &map[offset..offset + len * std::mem::size_of::<T>()];
        let aligned = bytes.as_ptr().align_offset(std::mem::align_of::<T>()) == 0;
        if aligned && !(big_endian && std::mem::size_of::<T>() > 1) {
            return Voxels {
                repr: Repr::Mapped { map, offset, len },
            };
        }
        Self::from_bytes(bytes, big_endian)
    }

    /// Serves the `len` voxels at `ptr` without copying them: memory that another owner
    /// (e.g. a handle on a numpy array) manages and `owner` keeps alive.
    ///
    /// # Safety
    /// `ptr` must be non-null, aligned for `T` and point to `len` initialised voxels that
    /// stay valid, and that nothing writes, for as long as `owner` is alive (the returned
    /// value holds it).
    #[must_use]
    pub unsafe fn borrowed(owner: Arc<dyn Send + Sync>, ptr: *const T, len: usize) -> Self {
        // SAFETY: the caller's contract: valid, unwritten and alive as long as `owner`, which
        // the value holds for as long as the slice can be reached.
        let data: &'static [T] = unsafe { std::slice::from_raw_parts(ptr, len) };
        Voxels {
            repr: Repr::Borrowed {
                _owner: owner,
                data,
            },
        }
    }

    /// Copies little- or big-endian bytes into an owned buffer.
    #[must_use]
    pub fn from_bytes(bytes: &[u8], big_endian: bool) -> Self {
        let mut v: Vec<T> = bytes
            .chunks_exact(std::mem::size_of::<T>())
            .map(bytemuck::pod_read_unaligned::<T>)
            .collect();
        if big_endian && std::mem::size_of::<T>() > 1 {
            for x in &mut v {
                *x = x.swap_bytes();
            }
        }
        Voxels::owned(v)
    }

    /// The voxels.
    ///
    /// # Panics
    /// For [`Voxels::deferred`] voxels: a caller that samples the whole lattice must check
    /// [`Voxels::is_resident`] and report an error (silent zeros would be a wrong image).
    #[inline]
    #[must_use]
    pub fn as_slice(&self) -> &[T] {
        match &self.repr {
            Repr::Owned(v) => v.as_slice(),
            Repr::Deferred { len } => deferred_access(*len),
            Repr::Borrowed { data, .. } => data,
            Repr::Mapped { map, offset, len } => {
                bytemuck::cast_slice(&map[*offset..*offset + *len * std::mem::size_of::<T>()])
            }
        }
    }

    /// Number of voxels.
    #[must_use]
    pub fn len(&self) -> usize {
        match &self.repr {
            Repr::Owned(v) => v.len(),
            Repr::Borrowed { data, .. } => data.len(),
            Repr::Mapped { len, .. } | Repr::Deferred { len } => *len,
        }
    }

    /// True when empty.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// A second handle on the same voxels, without copying them: owned voxels and a memory
    /// map are shared, borrowed memory keeps its owner alive once more.
    #[must_use]
    pub fn share(&self) -> Self {
        let repr = match &self.repr {
            Repr::Owned(v) => Repr::Owned(Arc::clone(v)),
            Repr::Deferred { len } => Repr::Deferred { len: *len },
            Repr::Mapped { map, offset, len } => Repr::Mapped {
                map: Arc::clone(map),
                offset: *offset,
                len: *len,
            },
            Repr::Borrowed {
                _owner: owner,
                data,
            } => Repr::Borrowed {
                _owner: Arc::clone(owner),
                data,
            },
        };
        Voxels { repr }
    }

    /// True when served from a memory map.
    #[must_use]
    pub fn is_mapped(&self) -> bool {
        matches!(self.repr, Repr::Mapped { .. })
    }

    /// Unmaps the resident pages of a memory-mapped file from this process (they are read
    /// again from the file, or the page cache, on the next access); a no-op for owned
    /// voxels. For a process that has copied what it needs.
    pub fn release_pages(&self) {
        #[cfg(unix)]
        if let Repr::Mapped { map, .. } = &self.repr {
            // SAFETY: the map is a read-only, file-backed mapping: MADV_DONTNEED only drops
            // clean pages, and later reads fault them back in from the file unchanged.
            let _ = unsafe { map.unchecked_advise(memmap2::UncheckedAdvice::DontNeed) };
        }
    }
}

#[cold]
#[inline(never)]
fn deferred_access(len: usize) -> ! {
    panic!(
        "internal error: the whole lattice of a volume whose {len} voxels are decoded on demand (a Zarr level under --memory-budget) was sampled; this path must check Volume::is_resident"
    )
}
