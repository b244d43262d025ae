//! Boxes of a Zarr level assembled from its chunks, decoded on demand and kept in an LRU of
//! decoded chunks within a byte budget: what a brick store reads a volume from when the
//! level does not fit the memory budget (`Volume::is_resident` is false).
//!
//! A brick's apron box meets up to eight chunks and a 64³ chunk holds 64 bricks of 16³, so
//! without the chunk cache every brick would decode its chunks again; with it, a chunk is
//! decoded once while the bricks in it are read (and again only after it was evicted).

use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use crate::volume::zarr::ZarrLevel;
use crate::volume::{DataType, VolumeError, Voxel, VoxelData, Voxels};
use crate::with_voxels;

/// Chunk indices, x, y, z.
type ChunkId = [usize; 3];

/// The decoded chunks held and their recency.
#[derive(Debug, Default)]
struct ChunkLru {
    held: HashMap<ChunkId, (Arc<VoxelData>, u64)>,
    order: BTreeMap<u64, ChunkId>,
    clock: u64,
    bytes: u64,
}

impl ChunkLru {
    fn touch(&mut self, id: ChunkId) -> Option<Arc<VoxelData>> {
        self.clock += 1;
        let now = self.clock;
        let (data, used) = self.held.get_mut(&id)?;
        self.order.remove(used);
        *used = now;
        self.order.insert(now, id);
        Some(Arc::clone(data))
    }

    fn insert(&mut self, id: ChunkId, data: &Arc<VoxelData>, budget: u64) -> u64 {
        let size = bytes_of(data);
        let mut evicted = 0;
        if size > budget {
            return 0;
        }
        while self.bytes + size > budget {
            let Some((_, old)) = self.order.pop_first() else {
                break;
            };
            if let Some((d, _)) = self.held.remove(&old) {
                self.bytes -= bytes_of(&d);
                evicted += 1;
            }
        }
        self.clock += 1;
        self.held.insert(id, (Arc::clone(data), self.clock));
        self.order.insert(self.clock, id);
        self.bytes += size;
        evicted
    }
}

fn bytes_of(d: &VoxelData) -> u64 {
    d.len() as u64 * d.data_type().size() as u64
}

/// A Zarr level read box by box from its chunks, decoded chunks cached within a budget.
#[derive(Debug)]
pub struct ZarrSource {
    level: Arc<ZarrLevel>,
    budget: AtomicU64,
    lru: Mutex<ChunkLru>,
    decoded: AtomicU64,
    evictions: AtomicU64,
}

impl ZarrSource {
    /// Reads of `level` keeping at most `chunk_budget` bytes of decoded chunks.
    #[must_use]
    pub fn new(level: Arc<ZarrLevel>, chunk_budget: u64) -> Self {
        ZarrSource {
            level,
            budget: AtomicU64::new(chunk_budget),
            lru: Mutex::default(),
            decoded: AtomicU64::new(0),
            evictions: AtomicU64::new(0),
        }
    }

    /// The level read.
    #[must_use]
    pub fn level(&self) -> &ZarrLevel {
        &self.level
    }

    /// The decoded-chunk budget in bytes.
    #[must_use]
    pub fn chunk_budget(&self) -> u64 {
        self.budget.load(Ordering::Relaxed)
    }

    /// Sets the decoded-chunk budget (the brick store's share of the memory budget).
    pub fn set_chunk_budget(&self, bytes: u64) {
        self.budget.store(bytes, Ordering::Relaxed);
    }

    /// Chunks decoded so far (misses of the chunk cache).
    #[must_use]
    pub fn chunks_decoded(&self) -> u64 {
        self.decoded.load(Ordering::Relaxed)
    }

    /// Chunks evicted from the chunk cache so far.
    #[must_use]
    pub fn chunk_evictions(&self) -> u64 {
        self.evictions.load(Ordering::Relaxed)
    }

    /// The voxels of the box at `origin` with `n` voxels per axis (inside the level), x
    /// fastest, in the stored type; with the encoded bytes read from the store for it
    /// (0 when every chunk it meets was cached).
    ///
    /// # Errors
    /// [`VolumeError::Decode`] naming the chunk's file when a chunk is missing or corrupt.
    pub fn read_box(
        &self,
        origin: [usize; 3],
        n: [usize; 3],
    ) -> Result<(VoxelData, u64), VolumeError> {
        let (data, bytes, _) = self.read_box_decoding(origin, n)?;
        Ok((data, bytes))
    }

    /// [`ZarrSource::read_box`], with the number of chunks decoded for the box (the chunk
    /// cache's misses): what lets ranks sharing one source each count their own decodes.
    ///
    /// # Errors
    /// As [`ZarrSource::read_box`].
    pub fn read_box_decoding(
        &self,
        origin: [usize; 3],
        n: [usize; 3],
    ) -> Result<(VoxelData, u64, u64), VolumeError> {
        Ok(match self.level.data_type() {
            DataType::U8 => {
                let (v, b, k) = self.assemble::<u8>(origin, n)?;
                (VoxelData::U8(Voxels::owned(v)), b, k)
            }
            DataType::U16 => {
                let (v, b, k) = self.assemble::<u16>(origin, n)?;
                (VoxelData::U16(Voxels::owned(v)), b, k)
            }
            DataType::I16 => {
                let (v, b, k) = self.assemble::<i16>(origin, n)?;
                (VoxelData::I16(Voxels::owned(v)), b, k)
            }
            DataType::F32 => {
                let (v, b, k) = self.assemble::<f32>(origin, n)?;
                (VoxelData::F32(Voxels::owned(v)), b, k)
            }
        })
    }

    /// Copies the box's part of every chunk it meets into one buffer.
    fn assemble<T: Voxel>(
        &self,
        origin: [usize; 3],
        n: [usize; 3],
    ) -> Result<(Vec<T>, u64, u64), VolumeError> {
        let c = self.level.chunk_shape();
        let mut out = vec![T::zeroed(); n[0] * n[1] * n[2]];
        let mut bytes = 0;
        let mut decoded = 0;
        // Chunks along each axis that the box meets.
        let span = |a: usize| origin[a] / c[a]..=(origin[a] + n[a] - 1) / c[a];
        for kz in span(2) {
            for ky in span(1) {
                for kx in span(0) {
                    let k = [kx, ky, kz];
                    let (chunk, b, fresh) = self.chunk(k)?;
                    bytes += b;
                    decoded += u64::from(fresh);
                    let src: &[T] = typed(&chunk);
                    // The intersection of the box and the chunk, in volume coordinates.
                    let lo: [usize; 3] = std::array::from_fn(|a| origin[a].max(k[a] * c[a]));
                    let hi: [usize; 3] =
                        std::array::from_fn(|a| (origin[a] + n[a]).min((k[a] + 1) * c[a]));
                    let w = hi[0] - lo[0];
                    for z in lo[2]..hi[2] {
                        for y in lo[1]..hi[1] {
                            let s = (lo[0] - kx * c[0])
                                + c[0] * ((y - ky * c[1]) + c[1] * (z - kz * c[2]));
                            let d = (lo[0] - origin[0])
                                + n[0] * ((y - origin[1]) + n[1] * (z - origin[2]));
                            out[d..d + w].copy_from_slice(&src[s..s + w]);
                        }
                    }
                }
            }
        }
        Ok((out, bytes, decoded))
    }

    /// Chunk `k` from the cache, or decoded (outside the lock, so that other threads keep
    /// hitting meanwhile) and cached; with the encoded bytes read for it and whether it
    /// was decoded.
    fn chunk(&self, k: ChunkId) -> Result<(Arc<VoxelData>, u64, bool), VolumeError> {
        let lru = || self.lru.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(hit) = lru().touch(k) {
            return Ok((hit, 0, false));
        }
        let (data, bytes) = self.level.read_chunk(k)?;
        let data = Arc::new(data);
        self.decoded.fetch_add(1, Ordering::Relaxed);
        let mut l = lru();
        if let Some(held) = l.touch(k) {
            return Ok((held, bytes, true));
        }
        let evicted = l.insert(k, &data, self.chunk_budget());
        self.evictions.fetch_add(evicted, Ordering::Relaxed);
        Ok((data, bytes, true))
    }
}

/// The voxels of `d` as `T`, the type they were decoded in (one level, one type).
fn typed<T: Voxel>(d: &VoxelData) -> &[T] {
    debug_assert_eq!(d.data_type(), T::TYPE);
    with_voxels!(d, v => bytemuck::cast_slice(v))
}
