//! [`DirectSend`]: every fragment goes straight to the owner of each tile it overlaps.

use std::time::Duration;

use rayon::prelude::*;

use crate::comm::{CommError, Communicator, Deadline, Rank};
use crate::render::{Image, PixelRect};

use super::{
    sort_front_to_back, CompositeError, Compositor, SparseTile, TileFragment, TileId, TileLayout,
};

/// The tag of every direct-send message; per (sender, tag) order is what lets a count
/// precede its fragments.
pub(crate) const TAG_FRAGMENTS: u32 = 0x4453_0001;
pub(crate) const KIND_COUNT: u8 = 0;
pub(crate) const KIND_FRAGMENT: u8 = 1;

/// Direct-send compositing (the paper's §4.2.2): each rank sends each fragment, clipped
/// and sparse, to the owner of every tile it overlaps; owners blend in depth order; rank 0
/// gathers the tiles.
///
/// Before its fragments, every rank tells every owner how many to expect (possibly zero),
/// so an owner never waits for a fragment that was never sent and reports a lost one.
/// Owners wait for fragments for at most ¾ of the timeout; the rest is for the gather.
///
/// # Examples
/// ```
/// use std::time::Duration;
/// use pofvr::brick::BrickId;
/// use pofvr::comm::{Communicator, LocalCommunicator};
/// use pofvr::composite::{composite_local, Compositor, DirectSend, TileFragment, TileLayout};
/// use pofvr::render::PixelRect;
///
/// let rect = |x0, y0, x1, y1| PixelRect { x0, y0, x1, y1 };
/// let fragments = vec![
///     TileFragment { brick: BrickId(0), depth_key: 1, rect: rect(2, 2, 10, 6), pixels: vec![[0.2, 0.0, 0.0, 0.4]; 32] },
///     TileFragment { brick: BrickId(1), depth_key: 0, rect: rect(6, 4, 12, 8), pixels: vec![[0.0, 0.5, 0.0, 0.5]; 24] },
/// ];
/// let layout = TileLayout::new(16, 10, rect(2, 2, 12, 8), 3).unwrap();
/// let frames = LocalCommunicator::run(3, |comm| {
///     // Each rank holds the fragments of the bricks it rendered.
///     let mine = fragments.iter().skip(comm.rank().index()).step_by(3).cloned().collect();
///     DirectSend::new(Duration::from_secs(10)).composite(comm, &layout, mine).unwrap()
/// });
/// let reference = composite_local(&fragments, 16, 10).unwrap();
/// assert_eq!(frames[0].as_ref(), Some(&reference));
/// assert!(frames[1].is_none() && frames[2].is_none());
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DirectSend {
    timeout: Duration,
}

impl DirectSend {
    /// Bound on one whole [`Compositor::composite`] call.
    /// > default: 60 s
    pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(60);

    /// A compositor whose [`Compositor::composite`] gives up after `timeout` in all.
    #[must_use]
    pub fn new(timeout: Duration) -> Self {
        DirectSend { timeout }
    }

    /// The bound on one composite call.
    #[must_use]
    pub fn timeout(&self) -> Duration {
        self.timeout
    }
}

impl Default for DirectSend {
    fn default() -> Self {
        DirectSend::new(Self::DEFAULT_TIMEOUT)
    }
}

impl Compositor for DirectSend {
    fn composite(
        &self,
        comm: &dyn Communicator,
        layout: &TileLayout,
        fragments: Vec<TileFragment>,
    ) -> Result<Option<Image>, CompositeError> {
        let result = self.run(comm, layout, &fragments);
        if let Err(e) = &result {
            if !matches!(e, CompositeError::Comm(CommError::Aborted { .. })) {
                comm.abort(&e.to_string());
            }
        }
        result
    }
}

/// A tile owner's fragments, received and not yet blended: what verification reads
/// before the tile is blended ([`DirectSend::exchange`], [`DirectSend::finish`]).
#[derive(Clone, Debug)]
pub struct ReceivedTile {
    tile: TileId,
    rect: PixelRect,
    fragments: Vec<SparseTile>,
}

impl ReceivedTile {
    /// The owner's tile.
    #[must_use]
    pub fn tile(&self) -> TileId {
        self.tile
    }

    /// Its pixels.
    #[must_use]
    pub fn rect(&self) -> PixelRect {
        self.rect
    }

    /// The fragments received so far (the owner's own included), in arrival order.
    #[must_use]
    pub fn fragments(&self) -> &[SparseTile] {
        &self.fragments
    }
}

impl DirectSend {
    /// The first half of [`Compositor::composite`]: sends this rank's `fragments` to the
    /// owners of the tiles they overlap and receives those of this rank's tile, unblended.
    /// Every rank calls it together; it may be called again with more fragments
    /// ([`DirectSend::exchange_more`]) before [`DirectSend::finish`].
    ///
    /// # Errors
    /// As [`Compositor::composite`]; a failing rank aborts `comm`.
    pub fn exchange(
        &self,
        comm: &dyn Communicator,
        layout: &TileLayout,
        fragments: &[TileFragment],
    ) -> Result<ReceivedTile, CompositeError> {
        let mut received = ReceivedTile {
            tile: TileId(0),
            rect: empty_rect(),
            fragments: Vec::new(),
        };
        aborting(
            comm,
            self.exchange_into(comm, layout, fragments, &mut received),
        )?;
        Ok(received)
    }

    /// Another round of [`DirectSend::exchange`] into `received`: more fragments (a
    /// repair's) go to their owners, which keep them with the earlier ones; the blend
    /// sorts all of them, so they land in visibility order whatever the round.
    ///
    /// # Errors
    /// As [`DirectSend::exchange`].
    pub fn exchange_more(
        &self,
        comm: &dyn Communicator,
        layout: &TileLayout,
        received: &mut ReceivedTile,
        fragments: &[TileFragment],
    ) -> Result<(), CompositeError> {
        aborting(comm, self.exchange_into(comm, layout, fragments, received))
    }

    /// The second half of [`Compositor::composite`]: blends the owner's fragments front to
    /// back and gathers the tiles into the frame on rank 0 (`None` elsewhere).
    ///
    /// # Errors
    /// As [`Compositor::composite`]; a failing rank aborts `comm`.
    pub fn finish(
        &self,
        comm: &dyn Communicator,
        layout: &TileLayout,
        received: ReceivedTile,
    ) -> Result<Option<Image>, CompositeError> {
        aborting(comm, self.finish_inner(comm, layout, received))
    }

    fn run(
        &self,
        comm: &dyn Communicator,
        layout: &TileLayout,
        fragments: &[TileFragment],
    ) -> Result<Option<Image>, CompositeError> {
        let mut received = ReceivedTile {
            tile: TileId(0),
            rect: empty_rect(),
            fragments: Vec::new(),
        };
        self.exchange_into(comm, layout, fragments, &mut received)?;
        self.finish_inner(comm, layout, received)
    }

    fn exchange_into(
        &self,
        comm: &dyn Communicator,
        layout: &TileLayout,
        fragments: &[TileFragment],
        received: &mut ReceivedTile,
    ) -> Result<(), CompositeError> {
        // Owners stop waiting for fragments at ¾ of the timeout, before rank 0 gives up on
        // their tiles, so the owner's precise error is the one that aborts the frame.
        let fragments_deadline = Deadline::new(self.timeout.saturating_mul(3) / 4);
        let (me, n) = (comm.rank(), comm.size());
        let my_tile = match layout.tile_of(me) {
            Some(t) if layout.len() == n => t,
            _ => {
                return Err(CompositeError::LayoutRanks {
                    rank: me,
                    tiles: layout.len(),
                    ranks: n,
                })
            }
        };

        // Clip and pack every fragment for every tile it overlaps.
        let clipped: Vec<Vec<(TileId, SparseTile)>> = fragments
            .par_iter()
            .map(|f| {
                f.check()?;
                layout
                    .tiles_overlapping(&f.rect)
                    .into_iter()
                    .filter_map(|t| layout.tile(t).map(|clip| (t, clip)))
                    .map(|(t, clip)| Ok((t, SparseTile::new(f, clip)?)))
                    .collect()
            })
            .collect::<Result<_, CompositeError>>()?;
        let mut outgoing: Vec<Vec<SparseTile>> = vec![Vec::new(); n];
        for (t, s) in clipped.into_iter().flatten() {
            outgoing[t.index()].push(s);
        }

        // Send: a count to every other owner, then that many fragments.
        let mine = std::mem::take(&mut outgoing[me.index()]);
        for (owner, tiles) in outgoing
            .into_iter()
            .enumerate()
            .filter(|&(o, _)| o != me.index())
        {
            let to = layout.owner(tile_id(owner));
            let mut count = vec![KIND_COUNT];
            count.extend_from_slice(&(tiles.len() as u32).to_le_bytes());
            comm.send(to, TAG_FRAGMENTS, count)?;
            for s in tiles {
                let mut msg = vec![KIND_FRAGMENT];
                s.encode_into(&mut msg);
                comm.send(to, TAG_FRAGMENTS, msg)?;
            }
        }

        let got = receive(comm, layout, my_tile, mine, fragments_deadline)?;
        received.tile = my_tile;
        received.rect = layout.tile(my_tile).unwrap_or(empty_rect());
        received.fragments.extend(got);
        Ok(())
    }

    fn finish_inner(
        &self,
        comm: &dyn Communicator,
        layout: &TileLayout,
        received: ReceivedTile,
    ) -> Result<Option<Image>, CompositeError> {
        let deadline = Deadline::new(self.timeout);
        let me = comm.rank();
        let pixels = blend(comm.rank(), received)?;

        // Gather the tiles on rank 0.
        let bytes: Vec<u8> = pixels
            .iter()
            .flatten()
            .flat_map(|c| c.to_le_bytes())
            .collect();
        let Some(tiles) = comm.gather(Rank(0), bytes, deadline.left())? else {
            return Ok(None);
        };
        let mut image = Image::new(layout.width(), layout.height());
        let w = layout.width() as usize;
        for (r, bytes) in tiles.into_iter().enumerate() {
            let tile = tile_id(r);
            let Some(rect) = layout.tile(tile) else {
                continue;
            };
            if bytes.len() != rect.area() * 16 {
                return Err(CompositeError::TileSize {
                    tile,
                    rank: me,
                    got: bytes.len(),
                    expected: rect.area() * 16,
                });
            }
            let tw = rect.width() as usize;
            if tw == 0 {
                continue;
            }
            let frame = image.pixels_mut();
            for (dy, row) in bytes.chunks_exact(tw * 16).enumerate() {
                let dst = &mut frame[(rect.y0 as usize + dy) * w + rect.x0 as usize..][..tw];
                for (d, p) in dst.iter_mut().zip(row.chunks_exact(16)) {
                    *d = std::array::from_fn(|c| {
                        f32::from_le_bytes([p[4 * c], p[4 * c + 1], p[4 * c + 2], p[4 * c + 3]])
                    });
                }
            }
        }
        Ok(Some(image))
    }
}

/// Aborts `comm` on an error of this rank's (not on another's abort), so no peer waits.
fn aborting<T>(
    comm: &dyn Communicator,
    result: Result<T, CompositeError>,
) -> Result<T, CompositeError> {
    if let Err(e) = &result {
        if !matches!(e, CompositeError::Comm(CommError::Aborted { .. })) {
            comm.abort(&e.to_string());
        }
    }
    result
}

fn empty_rect() -> PixelRect {
    PixelRect {
        x0: 0,
        y0: 0,
        x1: 0,
        y1: 0,
    }
}

fn tile_id(i: usize) -> TileId {
    // Layouts have at most `u32::MAX` tiles.
    TileId(i as u32)
}

fn rank_at(i: usize) -> Rank {
    Rank(tile_id(i).0)
}

/// Receives this owner's fragments, checking each sender against its announced count;
/// returns them with its own.
///
/// Senders are read one at a time, each stream by name: a fast peer may already be sending
/// the next frame's count, which must stay queued rather than be taken for this frame's.
fn receive(
    comm: &dyn Communicator,
    layout: &TileLayout,
    tile: TileId,
    mine: Vec<SparseTile>,
    deadline: Deadline,
) -> Result<Vec<SparseTile>, CompositeError> {
    let me = comm.rank();
    let rect = layout.tile(tile).unwrap_or(empty_rect());
    let mut received = mine;
    for from in (0..comm.size()).map(rank_at).filter(|&r| r != me) {
        let protocol = |what: String| CompositeError::Protocol {
            tile,
            rank: me,
            from,
            what,
        };
        let count = match comm.recv(Some(from), TAG_FRAGMENTS, deadline.left()) {
            Ok((_, bytes)) => match (
                bytes.first(),
                <[u8; 4]>::try_from(bytes.get(1..).unwrap_or(&[])),
            ) {
                (Some(&KIND_COUNT), Ok(count)) => u32::from_le_bytes(count) as usize,
                (Some(&KIND_COUNT), Err(_)) => {
                    return Err(protocol(format!(
                        "got a count message of {} bytes, expected 5",
                        bytes.len()
                    )));
                }
                (kind, _) => {
                    return Err(protocol(format!(
                        "got message kind {kind:?} first, expected the count (0)"
                    )));
                }
            },
            Err(CommError::Timeout { .. }) => {
                return Err(CompositeError::CountMissing {
                    tile,
                    rank: me,
                    from,
                })
            }
            Err(e) => return Err(e.into()),
        };
        for got in 0..count {
            let bytes = match comm.recv(Some(from), TAG_FRAGMENTS, deadline.left()) {
                Ok((_, bytes)) => bytes,
                Err(CommError::Timeout { .. }) => {
                    return Err(CompositeError::FragmentCount {
                        tile,
                        rank: me,
                        from,
                        expected: count,
                        got,
                    });
                }
                Err(e) => return Err(e.into()),
            };
            if bytes.first() != Some(&KIND_FRAGMENT) {
                return Err(protocol(format!(
                    "got message kind {:?} after {got} of {count} fragments, expected a fragment (1)",
                    bytes.first()
                )));
            }
            let sparse =
                SparseTile::decode(&bytes[1..]).map_err(|err| protocol(err.to_string()))?;
            if sparse.rect().intersect(&rect) != Some(sparse.rect()) {
                return Err(protocol(format!(
                    "got a fragment over {:?}, expected one inside {rect:?}",
                    sparse.rect()
                )));
            }
            received.push(sparse);
        }
    }
    Ok(received)
}

/// Blends an owner's fragments into its tile in depth order.
fn blend(me: Rank, received: ReceivedTile) -> Result<Vec<[f32; 4]>, CompositeError> {
    let ReceivedTile {
        tile,
        rect,
        fragments: mut received,
    } = received;
    sort_front_to_back(&mut received, |s| (s.depth_key(), s.brick()))?;
    let mut pixels = vec![[0.0f32; 4]; rect.area()];
    for s in &received {
        if !s.blend_into(&mut pixels, rect) {
            return Err(CompositeError::Protocol {
                tile,
                rank: me,
                from: me,
                what: format!(
                    "got a fragment over {:?}, expected one inside the tile {rect:?}",
                    s.rect()
                ),
            });
        }
    }
    Ok(pixels)
}
