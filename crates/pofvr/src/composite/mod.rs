//! Stage 6: compositing brick fragments into the frame, on one rank or many (paper §4.2.2).
//!
//! Each rendered brick (or run of bricks along the view) yields a [`TileFragment`]: its
//! premultiplied colour over its footprint rectangle, with a depth key. Fragments are blended
//! per pixel front to back with [`over`], in ascending `(depth_key, brick)` order.
//!
//! For parallel frames the image bounding box of the volume is cut into one tile per rank
//! ([`TileLayout`]); a [`Compositor`] sends each fragment, clipped and sparse-packed
//! ([`pack`]), to the owners of the tiles it overlaps, and gathers the tiles into the frame on
//! rank 0. [`composite_local`] is the single-process twin and gives bit-identical frames.
//! The wire protocol is described in `composite/README.md`.

mod direct;
mod sparse;
#[cfg(test)]
mod test;

use std::fmt;

use rayon::prelude::*;

pub use direct::{DirectSend, ReceivedTile};
pub use sparse::{pack, unpack, SparseTile, MAX_FRAGMENT_PIXELS};

use crate::brick::BrickId;
use crate::comm::{CommError, Communicator, Rank};
use crate::render::{Image, PixelRect};

/// Index of a tile in a [`TileLayout`], row-major; tile `i` is owned by rank `i`.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
pub struct TileId(pub u32);

impl TileId {
    /// As a `usize` index.
    #[inline]
    #[must_use]
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

impl fmt::Display for TileId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// Errors compositing fragments.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CompositeError {
    /// A layout was asked for no tiles, or more than `u32::MAX`.
    #[error("got {0} tiles, expected 1..={max}", max = u32::MAX)]
    BadTileCount(usize),
    /// The layout bounds are empty or not inside the frame.
    #[error("layout bounds {bounds:?} are empty or not inside the {width}×{height} frame")]
    BadBounds {
        /// The bounds given.
        bounds: PixelRect,
        /// Frame width.
        width: u32,
        /// Frame height.
        height: u32,
    },
    /// A fragment's pixel count does not match its rectangle.
    #[error("fragment of brick {} over {rect:?} has {got} pixels, expected {expected}", .brick.0)]
    PixelCount {
        /// The fragment's brick.
        brick: BrickId,
        /// Its rectangle.
        rect: PixelRect,
        /// The number of pixels it has.
        got: usize,
        /// The rectangle's area.
        expected: usize,
    },
    /// A fragment was clipped to a rectangle it does not overlap.
    #[error("fragment of brick {} over {rect:?} does not overlap the clip rectangle {clip:?}", .brick.0)]
    NoOverlap {
        /// The fragment's brick.
        brick: BrickId,
        /// Its rectangle.
        rect: PixelRect,
        /// The clip rectangle.
        clip: PixelRect,
    },
    /// A packed fragment would cover more pixels than [`MAX_FRAGMENT_PIXELS`].
    #[error("fragment covers {got} pixels, expected at most {max}", max = MAX_FRAGMENT_PIXELS)]
    TooLarge {
        /// Its pixel count.
        got: u64,
    },
    /// Packed bytes that do not decode.
    #[error("malformed fragment bytes at offset {offset}: {what}")]
    Malformed {
        /// Byte offset of the problem.
        offset: usize,
        /// What was got and what was expected.
        what: String,
    },
    /// Two fragments share a `(depth_key, brick)` key, so their order would be arbitrary.
    #[error("two fragments have depth key {depth_key} and brick {}, expected unique keys", .brick.0)]
    DuplicateKey {
        /// The brick.
        brick: BrickId,
        /// The depth key.
        depth_key: i64,
    },
    /// The layout has a different number of tiles than the communicator has ranks.
    #[error("rank {rank}: layout has {tiles} tiles, expected one per rank ({ranks})")]
    LayoutRanks {
        /// The rank that noticed.
        rank: Rank,
        /// Tiles in the layout.
        tiles: usize,
        /// Ranks in the communicator.
        ranks: usize,
    },
    /// A tile owner got a different number of fragments from a sender than announced.
    #[error("rank {rank}: tile {tile} got {got} fragments from rank {from}, expected {expected}")]
    FragmentCount {
        /// The tile.
        tile: TileId,
        /// The tile's owner, which noticed.
        rank: Rank,
        /// The sender.
        from: Rank,
        /// Fragments the sender announced.
        expected: usize,
        /// Fragments that arrived.
        got: usize,
    },
    /// A tile owner did not get a sender's fragment count in time.
    #[error(
        "rank {rank}: tile {tile} got no fragment count from rank {from}, expected one per rank"
    )]
    CountMissing {
        /// The tile.
        tile: TileId,
        /// The tile's owner, which noticed.
        rank: Rank,
        /// The silent sender.
        from: Rank,
    },
    /// A tile owner got a message that breaks the protocol.
    #[error("rank {rank}: tile {tile}: bad message from rank {from}: {what}")]
    Protocol {
        /// The tile.
        tile: TileId,
        /// The tile's owner, which noticed.
        rank: Rank,
        /// The sender.
        from: Rank,
        /// What was got and what was expected.
        what: String,
    },
    /// A composited tile arrived on rank 0 with the wrong size.
    #[error("rank {rank}: tile {tile} arrived with {got} bytes, expected {expected}")]
    TileSize {
        /// The tile.
        tile: TileId,
        /// The receiving rank.
        rank: Rank,
        /// Bytes that arrived.
        got: usize,
        /// Bytes expected for the tile's area.
        expected: usize,
    },
    /// The communicator failed.
    #[error(transparent)]
    Comm(#[from] CommError),
}

/// The premultiplied colour of one brick (or run of bricks) over its footprint.
#[derive(Clone, Debug, PartialEq)]
pub struct TileFragment {
    /// The brick the fragment comes from; breaks ties between equal depth keys.
    pub brick: BrickId,
    /// Front-to-back position: smaller keys are nearer the eye.
    pub depth_key: i64,
    /// The pixels covered.
    pub rect: PixelRect,
    /// Premultiplied RGBA, row-major over `rect`.
    pub pixels: Vec<[f32; 4]>,
}

impl TileFragment {
    /// Checks that the pixels fill the rectangle.
    ///
    /// # Errors
    /// [`CompositeError::PixelCount`] when they do not.
    pub fn check(&self) -> Result<(), CompositeError> {
        if self.pixels.len() == self.rect.area() {
            Ok(())
        } else {
            Err(CompositeError::PixelCount {
                brick: self.brick,
                rect: self.rect,
                got: self.pixels.len(),
                expected: self.rect.area(),
            })
        }
    }

    /// The sort key: ascending is front to back.
    #[must_use]
    pub fn key(&self) -> (i64, BrickId) {
        (self.depth_key, self.brick)
    }
}

/// `front` over `back` for premultiplied RGBA: `front + (1 - front.a) · back`.
///
/// Both composite paths blend through this one function, so they round identically.
#[inline]
#[must_use]
pub fn over(front: [f32; 4], back: [f32; 4]) -> [f32; 4] {
    let t = 1.0 - front[3];
    [
        front[0] + t * back[0],
        front[1] + t * back[1],
        front[2] + t * back[2],
        front[3] + t * back[3],
    ]
}

/// The image bounding box of the volume's projection cut into one tile per rank.
///
/// The box is cut into `cols × rows == n` tiles, the factorisation whose tiles are closest to
/// square (ties go to fewer columns, whose tile rows are longer); column widths (row heights)
/// differ by at most one pixel. When the box has fewer
/// columns or rows of pixels than needed, some tiles are empty.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TileLayout {
    width: u32,
    height: u32,
    bounds: PixelRect,
    col_edges: Vec<u32>,
    row_edges: Vec<u32>,
}

impl TileLayout {
    /// Cuts `bounds`, inside a `width × height` frame, into exactly `tiles` tiles.
    ///
    /// # Errors
    /// [`CompositeError::BadTileCount`] when `tiles` is zero or above `u32::MAX`,
    /// [`CompositeError::BadBounds`] when `bounds` is empty or leaves the frame.
    pub fn new(
        width: u32,
        height: u32,
        bounds: PixelRect,
        tiles: usize,
    ) -> Result<Self, CompositeError> {
        if tiles == 0 || u32::try_from(tiles).is_err() {
            return Err(CompositeError::BadTileCount(tiles));
        }
        if bounds.x0 >= bounds.x1
            || bounds.y0 >= bounds.y1
            || bounds.x1 > width
            || bounds.y1 > height
        {
            return Err(CompositeError::BadBounds {
                bounds,
                width,
                height,
            });
        }
        let (bw, bh) = (bounds.width(), bounds.height());
        let score = |cols: usize| {
            let rows = tiles / cols;
            // Layouts without empty tiles first, then the squarest tiles.
            let empty = cols > bw as usize || rows > bh as usize;
            let aspect = (f64::from(bw) / cols as f64) / (f64::from(bh) / rows as f64);
            (empty, aspect.ln().abs())
        };
        let mut best = 1;
        let mut d = 1;
        while d * d <= tiles {
            // Written out rather than `is_multiple_of`, which is newer than the MSRV.
            if (tiles / d) * d == tiles {
                for cols in [d, tiles / d] {
                    let (a, b) = (score(cols), score(best));
                    if (!a.0 && b.0) || (a.0 == b.0 && a.1 < b.1) {
                        best = cols;
                    }
                }
            }
            d += 1;
        }
        let edges = |lo: u32, len: u32, parts: usize| -> Vec<u32> {
            (0..=parts as u64)
                .map(|i| lo + (i * u64::from(len) / parts as u64) as u32)
                .collect()
        };
        Ok(TileLayout {
            width,
            height,
            bounds,
            col_edges: edges(bounds.x0, bw, best),
            row_edges: edges(bounds.y0, bh, tiles / best),
        })
    }

    /// Number of tiles (and of ranks).
    #[must_use]
    pub fn len(&self) -> usize {
        self.cols() * self.rows()
    }

    /// Always false: a layout has at least one tile.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Tile columns.
    #[must_use]
    pub fn cols(&self) -> usize {
        self.col_edges.len() - 1
    }

    /// Tile rows.
    #[must_use]
    pub fn rows(&self) -> usize {
        self.row_edges.len() - 1
    }

    /// Frame width.
    #[must_use]
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Frame height.
    #[must_use]
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The box that the tiles cut up.
    #[must_use]
    pub fn bounds(&self) -> PixelRect {
        self.bounds
    }

    /// The pixels of tile `id` (possibly zero-sized); `None` for an unknown tile.
    #[must_use]
    pub fn tile(&self, id: TileId) -> Option<PixelRect> {
        let (col, row) = (id.index() % self.cols(), id.index() / self.cols());
        (row < self.rows()).then(|| PixelRect {
            x0: self.col_edges[col],
            y0: self.row_edges[row],
            x1: self.col_edges[col + 1],
            y1: self.row_edges[row + 1],
        })
    }

    /// The rank that composites tile `id`.
    #[must_use]
    pub fn owner(&self, id: TileId) -> Rank {
        Rank(id.0)
    }

    /// The tile that `rank` composites; `None` for a rank outside the layout.
    #[must_use]
    pub fn tile_of(&self, rank: Rank) -> Option<TileId> {
        (rank.index() < self.len()).then_some(TileId(rank.0))
    }

    /// The tiles sharing at least one pixel with `rect`, in id order.
    #[must_use]
    pub fn tiles_overlapping(&self, rect: &PixelRect) -> Vec<TileId> {
        let overlaps = |edges: &[u32], lo: u32, hi: u32| -> Vec<usize> {
            (0..edges.len() - 1)
                .filter(|&i| edges[i].max(lo) < edges[i + 1].min(hi))
                .collect()
        };
        let cols = overlaps(&self.col_edges, rect.x0, rect.x1);
        let rows = overlaps(&self.row_edges, rect.y0, rect.y1);
        rows.iter()
            .flat_map(|&r| {
                cols.iter()
                    .map(move |&c| TileId((r * (self.col_edges.len() - 1) + c) as u32))
            })
            .collect()
    }
}

/// A strategy that composites every rank's fragments into the frame on rank 0.
///
/// Every strategy has this one signature, so they are interchangeable in `frame.rs`.
pub trait Compositor {
    /// Composites `fragments` (this rank's) with those of all other ranks. Returns the frame
    /// on rank 0 and `None` elsewhere. A rank that fails aborts `comm`, so no peer is left
    /// waiting; only rank 0's result says whether the frame as a whole succeeded, as the
    /// other ranks may finish their part before a peer fails.
    ///
    /// # Errors
    /// Bad fragments, a layout that does not match `comm`, lost or extra messages
    /// ([`CompositeError::FragmentCount`]) and communicator failures.
    fn composite(
        &self,
        comm: &dyn Communicator,
        layout: &TileLayout,
        fragments: Vec<TileFragment>,
    ) -> Result<Option<Image>, CompositeError>;
}

/// Sorts front to back and rejects equal keys, whose relative order would be arbitrary.
fn sort_front_to_back<T>(
    items: &mut [T],
    key: impl Fn(&T) -> (i64, BrickId),
) -> Result<(), CompositeError> {
    items.sort_unstable_by_key(&key);
    match items.windows(2).find(|w| key(&w[0]) == key(&w[1])) {
        Some(w) => {
            let (depth_key, brick) = key(&w[0]);
            Err(CompositeError::DuplicateKey { brick, depth_key })
        }
        None => Ok(()),
    }
}

/// Rows per parallel work item of [`composite_local`].
const BAND_ROWS: usize = 8;

/// Composites all fragments of a frame in one process: the reference for every
/// [`Compositor`], with the same order and blend, so the frames are bit-identical (as long
/// as the fragments lie inside the layout bounds, outside which a compositor drops pixels).
///
/// # Errors
/// [`CompositeError::PixelCount`] for a fragment whose pixels do not fill its rectangle,
/// [`CompositeError::DuplicateKey`] for two fragments with the same key.
pub fn composite_local(
    fragments: &[TileFragment],
    width: u32,
    height: u32,
) -> Result<Image, CompositeError> {
    for f in fragments {
        f.check()?;
    }
    let mut order: Vec<&TileFragment> = fragments.iter().collect();
    sort_front_to_back(&mut order, |f| f.key())?;
    let mut image = Image::new(width, height);
    let frame = PixelRect {
        x0: 0,
        y0: 0,
        x1: width,
        y1: height,
    };
    let w = width as usize;
    if w == 0 {
        return Ok(image);
    }
    // Bands of rows in parallel: every pixel still takes its fragments in depth order, with
    // the one blend, so the bands change nothing but the time.
    let visible: Vec<(PixelRect, &TileFragment)> = order
        .into_iter()
        .filter_map(|f| f.rect.intersect(&frame).map(|r| (r, f)))
        .collect();
    image
        .pixels_mut()
        .par_chunks_mut(w * BAND_ROWS)
        .enumerate()
        .for_each(|(band, pixels)| {
            let (b0, b1) = (
                (band * BAND_ROWS) as u32,
                (band * BAND_ROWS + pixels.len() / w) as u32,
            );
            for (r, f) in &visible {
                let fw = f.rect.width() as usize;
                for y in r.y0.max(b0)..r.y1.min(b1) {
                    let src = &f.pixels[(y - f.rect.y0) as usize * fw..]
                        [(r.x0 - f.rect.x0) as usize..][..r.width() as usize];
                    let dst =
                        &mut pixels[(y - b0) as usize * w..][r.x0 as usize..][..r.width() as usize];
                    for (d, s) in dst.iter_mut().zip(src) {
                        *d = over(*d, *s);
                    }
                }
            }
        });
    Ok(image)
}
