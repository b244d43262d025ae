//! The brick cache: decoded bricks, with their apron, kept within a byte budget and evicted
//! least recently used first, but never for a brick of the same frame or the one before.
//!
//! Why not plain LRU: a frame visits its bricks in the same order every time (front to
//! back), so when a view needs more than the budget, plain LRU evicts each brick just
//! before the next frame asks for it again and an orbit re-reads everything every frame
//! (measured: 5.7 GB per frame at 1024² on the 2048³ volume under 4G, no hit at all). Keeping
//! what the frame has already used, and reading the overflow past the cache, lets the next
//! frame find a budget's worth of its bricks. Why the frame before too: a frame that misses
//! would otherwise evict the previous frame's bricks it has not reached yet, the oldest
//! first, which it then misses in turn (measured on the 1728-slice CT under 256M with the
//! proxy charged, a cache of 174 MB for a 265 MB view: 188 MB read per later frame).

use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, PoisonError};

use super::BrickSource;
use crate::brick::{BrickCopy, BrickGrid, BrickId};
use crate::volume::{Volume, VolumeError};

/// What one reader (a rank's frame) asked of a cache: counted by the caller, so that ranks
/// sharing one cache (in-process ranks) each report their own reads. A reader is also a
/// frame to the cache: what it has used is not evicted for what it reads later, so make one
/// per frame.
#[derive(Debug, Default)]
pub struct ReadCounts {
    bytes_read: AtomicU64,
    bricks_read: AtomicU64,
    cache_hits: AtomicU64,
    chunks_decoded: AtomicU64,
    /// The cache's clock when this reader first asked: bricks used after it are its own.
    start: OnceLock<u64>,
}

impl ReadCounts {
    /// Bytes read from the source.
    #[must_use]
    pub fn bytes_read(&self) -> u64 {
        self.bytes_read.load(Ordering::Relaxed)
    }

    /// Bricks read from the source (misses).
    #[must_use]
    pub fn bricks_read(&self) -> u64 {
        self.bricks_read.load(Ordering::Relaxed)
    }

    /// Bricks served from the cache.
    #[must_use]
    pub fn cache_hits(&self) -> u64 {
        self.cache_hits.load(Ordering::Relaxed)
    }

    /// Zarr chunks decoded for the bricks read (0 for other sources).
    #[must_use]
    pub fn chunks_decoded(&self) -> u64 {
        self.chunks_decoded.load(Ordering::Relaxed)
    }

    fn add(&self, bytes: u64, read: u64, hits: u64) {
        self.bytes_read.fetch_add(bytes, Ordering::Relaxed);
        self.bricks_read.fetch_add(read, Ordering::Relaxed);
        self.cache_hits.fetch_add(hits, Ordering::Relaxed);
    }
}

/// The cached bricks and their recency.
#[derive(Debug, Default)]
struct Lru {
    /// Brick → (copy, last use).
    held: HashMap<BrickId, (Arc<BrickCopy>, u64)>,
    /// Last use → brick: the oldest first.
    order: BTreeMap<u64, BrickId>,
    clock: u64,
    bytes: u64,
    peak: u64,
    evictions: u64,
    /// Bricks read but not kept: the cache was full of the reading frame's own bricks and
    /// those of the frame before it.
    passed: u64,
    /// The clocks at which the last two readers (frames) started, the older first.
    starts: [u64; 2],
}

impl Lru {
    fn touch(&mut self, id: BrickId) -> Option<Arc<BrickCopy>> {
        self.clock += 1;
        let now = self.clock;
        let (copy, used) = self.held.get_mut(&id)?;
        self.order.remove(used);
        *used = now;
        self.order.insert(now, id);
        Some(Arc::clone(copy))
    }

    /// A reader (frame) starts at clock `start`.
    fn begin(&mut self, start: u64) {
        if start > self.starts[1] {
            self.starts = [self.starts[1], start];
        }
    }

    /// Caches `copy`, evicting the least recently used bricks last used before the frame
    /// before the reading one started (`start` is the reading frame's start) to make room;
    /// when the oldest left was used by either frame, the copy is passed on uncached
    /// instead.
    fn insert(&mut self, id: BrickId, copy: &Arc<BrickCopy>, budget: u64, start: u64) {
        let size = copy.bytes() as u64;
        if size > budget {
            self.passed += 1;
            return;
        }
        let keep_after = start.min(self.starts[0]);
        while self.bytes + size > budget {
            let Some((&used, &old)) = self.order.first_key_value() else {
                break;
            };
            if used > keep_after {
                self.passed += 1;
                return;
            }
            self.order.pop_first();
            if let Some((c, _)) = self.held.remove(&old) {
                self.bytes -= c.bytes() as u64;
                self.evictions += 1;
            }
        }
        self.clock += 1;
        self.held.insert(id, (Arc::clone(copy), self.clock));
        self.order.insert(self.clock, id);
        self.bytes += size;
        self.peak = self.peak.max(self.bytes);
    }
}

/// Bricks read on demand from a [`BrickSource`] and kept, with their one-voxel apron, in
/// an LRU cache of at most `budget` bytes of voxels that does not evict a frame's own
/// bricks for it (see the [module](self)). A brick being rendered when it is
/// evicted lives until its renderer lets go, so the bricks resident at once exceed the
/// budget by at most one per rendering thread.
#[derive(Debug)]
pub struct BrickCache {
    source: BrickSource,
    budget: u64,
    /// Bytes of the budget held outside the cache ([`BrickCache::reserve`]).
    reserved: AtomicU64,
    lru: Mutex<Lru>,
    totals: ReadCounts,
}

/// What a cache has done since it was made, for `--stats`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct CacheSummary {
    /// The budget in bytes.
    pub budget_bytes: u64,
    /// Voxel bytes cached now.
    pub cached_bytes: u64,
    /// The most voxel bytes cached at once.
    pub cache_peak_bytes: u64,
    /// Bricks evicted.
    pub evictions: u64,
    /// Bricks read but not cached, because the cache was full of the reading frame's own
    /// bricks (see the [module](self)).
    pub not_cached: u64,
    /// Bytes of the budget held outside the cache (the verified cull's proxy), which the
    /// cache leaves free.
    pub reserved_bytes: u64,
    /// Bytes read from the source, over all frames.
    pub bytes_read: u64,
    /// Bricks read from the source, over all frames.
    pub bricks_read: u64,
    /// Bricks served from the cache, over all frames.
    pub cache_hits: u64,
}

impl BrickCache {
    /// A cache of at most `budget` bytes over `source`.
    #[must_use]
    pub fn new(source: BrickSource, budget: u64) -> Self {
        BrickCache {
            source,
            budget,
            reserved: AtomicU64::new(0),
            lru: Mutex::default(),
            totals: ReadCounts::default(),
        }
    }

    /// Charges `bytes` held elsewhere for the same volume (the verified cull's proxy: on a
    /// 2048³ volume about 2.8 GB) to the budget, in addition to what was charged before: the
    /// cache then keeps at most the rest, evicting down to it as it reads. Without this the
    /// process holds the budget's worth of bricks plus the proxy.
    pub fn reserve(&self, bytes: u64) {
        self.reserved.fetch_add(bytes, Ordering::Relaxed);
    }

    /// The bytes the cache may hold: the budget less what is reserved and, for a Zarr
    /// source, its decoded chunks' share.
    #[must_use]
    pub fn brick_budget(&self) -> u64 {
        let chunks = self
            .source
            .zarr()
            .map_or(0, super::ZarrSource::chunk_budget);
        self.budget
            .saturating_sub(chunks)
            .saturating_sub(self.reserved.load(Ordering::Relaxed))
    }

    /// The source.
    #[must_use]
    pub fn source(&self) -> &BrickSource {
        &self.source
    }

    /// The budget in bytes.
    #[must_use]
    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// Brick `id` of `grid` (cut from `volume`, the source's volume) with its apron: from
    /// the cache, or read from the source and cached. `counts` gets the read or the hit.
    ///
    /// # Errors
    /// [`VolumeError::Io`] naming the file when the read fails.
    pub fn get(
        &self,
        volume: &Volume,
        grid: &BrickGrid,
        id: BrickId,
        counts: &ReadCounts,
    ) -> Result<Arc<BrickCopy>, VolumeError> {
        let lru = || self.lru.lock().unwrap_or_else(PoisonError::into_inner);
        let hit = {
            let mut l = lru();
            let mut fresh = false;
            let start = *counts.start.get_or_init(|| {
                fresh = true;
                l.clock
            });
            if fresh {
                l.begin(start);
            }
            l.touch(id)
        };
        if let Some(copy) = hit {
            counts.add(0, 0, 1);
            self.totals.add(0, 0, 1);
            return Ok(copy);
        }
        // Read outside the lock: other threads keep hitting while this one waits on the
        // file. Two threads missing the same brick both read it (and both count it).
        let (origin, dims) = BrickCopy::apron_box(grid, id);
        let (data, bytes, chunks) = self.source.read_box_decoding(volume, origin, dims)?;
        let copy = Arc::new(BrickCopy::from_parts(origin, dims, data));
        counts.add(bytes, 1, 0);
        counts.chunks_decoded.fetch_add(chunks, Ordering::Relaxed);
        self.totals.add(bytes, 1, 0);
        let mut l = lru();
        if let Some(held) = l.touch(id) {
            return Ok(held);
        }
        let start = counts.start.get().copied().unwrap_or(0);
        l.insert(id, &copy, self.brick_budget(), start);
        Ok(copy)
    }

    /// Totals since the cache was made.
    #[must_use]
    pub fn summary(&self) -> CacheSummary {
        let l = self.lru.lock().unwrap_or_else(PoisonError::into_inner);
        CacheSummary {
            budget_bytes: self.budget,
            cached_bytes: l.bytes,
            cache_peak_bytes: l.peak,
            evictions: l.evictions,
            not_cached: l.passed,
            reserved_bytes: self.reserved.load(Ordering::Relaxed),
            bytes_read: self.totals.bytes_read(),
            bricks_read: self.totals.bricks_read(),
            cache_hits: self.totals.cache_hits(),
        }
    }
}
