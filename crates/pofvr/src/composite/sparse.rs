//! [`SparseTile`]: a fragment clipped to a tile with its transparent runs left out, and its
//! byte form ([`pack`], [`unpack`]): the one boundary where fragments become bytes.

use crate::brick::BrickId;
use crate::render::PixelRect;

use super::{over, CompositeError, TileFragment};

/// The most pixels a packed fragment's rectangle may cover (8192²), which bounds what
/// decoding untrusted bytes can allocate.
pub const MAX_FRAGMENT_PIXELS: usize = 1 << 26;

const MAGIC: [u8; 4] = *b"PTF1";
const SPAN_BYTES: usize = 12;
const PIXEL_BYTES: usize = 16;

/// A run of stored pixels: row `dy`, columns `dx..dx + len`, relative to the rectangle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Span {
    dy: u32,
    dx: u32,
    len: u32,
}

/// A fragment clipped to a rectangle, storing only runs of non-transparent pixels.
///
/// A pixel is transparent when all four components are zero; leaving it out changes no
/// composite, since blending it adds `(1 - a) · 0` to each channel.
#[derive(Clone, Debug, PartialEq)]
pub struct SparseTile {
    brick: BrickId,
    depth_key: i64,
    rect: PixelRect,
    spans: Vec<Span>,
    pixels: Vec<[f32; 4]>,
}

fn transparent(p: &[f32; 4]) -> bool {
    p.iter().all(|&c| c == 0.0)
}

fn too_large(rect: &PixelRect) -> Option<CompositeError> {
    (rect.area() > MAX_FRAGMENT_PIXELS).then(|| CompositeError::TooLarge {
        got: rect.area() as u64,
    })
}

impl SparseTile {
    /// The part of `fragment` inside `clip`, its transparent runs left out.
    ///
    /// # Errors
    /// [`CompositeError::PixelCount`] for an inconsistent fragment,
    /// [`CompositeError::NoOverlap`] when `clip` misses it, [`CompositeError::TooLarge`] when
    /// the clipped rectangle exceeds [`MAX_FRAGMENT_PIXELS`].
    pub fn new(fragment: &TileFragment, clip: PixelRect) -> Result<Self, CompositeError> {
        fragment.check()?;
        let rect = fragment
            .rect
            .intersect(&clip)
            .ok_or(CompositeError::NoOverlap {
                brick: fragment.brick,
                rect: fragment.rect,
                clip,
            })?;
        if let Some(e) = too_large(&rect) {
            return Err(e);
        }
        let fw = fragment.rect.width() as usize;
        let (mut spans, mut pixels) = (Vec::new(), Vec::new());
        for y in rect.y0..rect.y1 {
            let row = &fragment.pixels[(y - fragment.rect.y0) as usize * fw..]
                [(rect.x0 - fragment.rect.x0) as usize..][..rect.width() as usize];
            let mut x = 0;
            while x < row.len() {
                if transparent(&row[x]) {
                    x += 1;
                    continue;
                }
                let start = x;
                while x < row.len() && !transparent(&row[x]) {
                    x += 1;
                }
                pixels.extend_from_slice(&row[start..x]);
                spans.push(Span {
                    dy: y - rect.y0,
                    dx: start as u32,
                    len: (x - start) as u32,
                });
            }
        }
        Ok(SparseTile {
            brick: fragment.brick,
            depth_key: fragment.depth_key,
            rect,
            spans,
            pixels,
        })
    }

    /// The brick.
    #[must_use]
    pub fn brick(&self) -> BrickId {
        self.brick
    }

    /// The depth key.
    #[must_use]
    pub fn depth_key(&self) -> i64 {
        self.depth_key
    }

    /// The clipped rectangle.
    #[must_use]
    pub fn rect(&self) -> PixelRect {
        self.rect
    }

    /// Number of non-transparent pixels stored.
    #[must_use]
    pub fn stored_pixels(&self) -> usize {
        self.pixels.len()
    }

    /// The byte form (little-endian, layout in `composite/README.md`).
    #[must_use]
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::new();
        self.encode_into(&mut out);
        out
    }

    /// Appends the byte form to `out`.
    pub(crate) fn encode_into(&self, out: &mut Vec<u8>) {
        out.reserve(36 + self.spans.len() * SPAN_BYTES + self.pixels.len() * PIXEL_BYTES);
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&self.brick.0.to_le_bytes());
        out.extend_from_slice(&self.depth_key.to_le_bytes());
        for v in [self.rect.x0, self.rect.y0, self.rect.x1, self.rect.y1] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&(self.spans.len() as u32).to_le_bytes());
        let mut pixels = self.pixels.iter();
        for s in &self.spans {
            for v in [s.dy, s.dx, s.len] {
                out.extend_from_slice(&v.to_le_bytes());
            }
            for p in pixels.by_ref().take(s.len as usize) {
                for c in p {
                    out.extend_from_slice(&c.to_le_bytes());
                }
            }
        }
    }

    /// Decodes the byte form, checking every length and bound.
    ///
    /// # Errors
    /// [`CompositeError::Malformed`] for bytes that are cut short, have trailing data, a bad
    /// magic, an empty rectangle, or spans that leave the rectangle, are empty or out of
    /// order; [`CompositeError::TooLarge`] for a rectangle above [`MAX_FRAGMENT_PIXELS`].
    pub fn decode(bytes: &[u8]) -> Result<Self, CompositeError> {
        let mut r = Reader { bytes, at: 0 };
        let magic = r.take(4, "magic")?;
        if magic != MAGIC {
            return Err(r.malformed(0, format!("got magic {magic:?}, expected {MAGIC:?}")));
        }
        let brick = BrickId(r.u32("brick")?);
        let depth_key = i64::from_le_bytes(r.array("depth key")?);
        let rect_at = r.at;
        let rect = PixelRect {
            x0: r.u32("rect")?,
            y0: r.u32("rect")?,
            x1: r.u32("rect")?,
            y1: r.u32("rect")?,
        };
        if rect.x0 >= rect.x1 || rect.y0 >= rect.y1 {
            return Err(r.malformed(
                rect_at,
                format!("got rectangle {rect:?}, expected a non-empty one"),
            ));
        }
        if let Some(e) = too_large(&rect) {
            return Err(e);
        }
        let count = r.u32("span count")? as usize;
        let mut spans = Vec::with_capacity(count.min(r.left() / SPAN_BYTES));
        let mut pixels = Vec::new();
        // The end of the previous span, as (row, column): spans must move strictly forward.
        let mut end = (0u32, 0u32);
        for _ in 0..count {
            let at = r.at;
            let s = Span {
                dy: r.u32("span")?,
                dx: r.u32("span")?,
                len: r.u32("span")?,
            };
            let fits = s.len > 0
                && s.dy < rect.height()
                && u64::from(s.dx) + u64::from(s.len) <= u64::from(rect.width());
            if !fits || (s.dy, s.dx) < end {
                return Err(r.malformed(
                    at,
                    format!(
                        "got span {s:?}, expected a non-empty run inside {}×{} starting at or after {end:?}",
                        rect.width(),
                        rect.height()
                    ),
                ));
            }
            end = (s.dy, s.dx + s.len);
            let data = r.take(s.len as usize * PIXEL_BYTES, "span pixels")?;
            pixels.extend(data.chunks_exact(PIXEL_BYTES).map(|p| {
                std::array::from_fn(|c| {
                    f32::from_le_bytes([p[4 * c], p[4 * c + 1], p[4 * c + 2], p[4 * c + 3]])
                })
            }));
            spans.push(s);
        }
        if r.left() != 0 {
            return Err(r.malformed(
                r.at,
                format!("got {} trailing bytes, expected none", r.left()),
            ));
        }
        Ok(SparseTile {
            brick,
            depth_key,
            rect,
            spans,
            pixels,
        })
    }

    /// The dense fragment over the clipped rectangle, transparent where nothing is stored.
    #[must_use]
    pub fn to_fragment(&self) -> TileFragment {
        let mut pixels = vec![[0.0; 4]; self.rect.area()];
        self.blend_into(&mut pixels, self.rect);
        TileFragment {
            brick: self.brick,
            depth_key: self.depth_key,
            rect: self.rect,
            pixels,
        }
    }

    /// Blends the stored pixels behind what `target` (the pixels of `target_rect`) holds.
    /// Returns false, touching nothing, when the fragment is not inside `target_rect` or
    /// `target` does not fill it.
    pub(crate) fn blend_into(&self, target: &mut [[f32; 4]], target_rect: PixelRect) -> bool {
        let inside = self.rect.x0 >= target_rect.x0
            && self.rect.y0 >= target_rect.y0
            && self.rect.x1 <= target_rect.x1
            && self.rect.y1 <= target_rect.y1;
        if !inside || target.len() != target_rect.area() {
            return false;
        }
        let tw = target_rect.width() as usize;
        let (ox, oy) = (
            (self.rect.x0 - target_rect.x0) as usize,
            (self.rect.y0 - target_rect.y0) as usize,
        );
        let mut pixels = self.pixels.as_slice();
        for s in &self.spans {
            let (src, rest) = pixels.split_at(s.len as usize);
            pixels = rest;
            let dst = &mut target[(oy + s.dy as usize) * tw + ox + s.dx as usize..][..src.len()];
            for (d, p) in dst.iter_mut().zip(src) {
                *d = over(*d, *p);
            }
        }
        true
    }
}

impl SparseTile {
    /// Blends the stored pixels' opacity behind `alpha`, the opacity of the pixels of
    /// `target_rect` (the alpha channel of [`SparseTile::blend_into`], what verification
    /// reads); the part outside `target_rect` is left out.
    pub(crate) fn blend_alpha_into(&self, alpha: &mut [f32], target_rect: PixelRect) {
        if alpha.len() != target_rect.area() {
            return;
        }
        let tw = target_rect.width() as usize;
        let mut pixels = self.pixels.as_slice();
        for s in &self.spans {
            let (src, rest) = pixels.split_at(s.len as usize);
            pixels = rest;
            let y = self.rect.y0 + s.dy;
            if y < target_rect.y0 || y >= target_rect.y1 {
                continue;
            }
            let x0 = self.rect.x0 + s.dx;
            for (k, p) in src.iter().enumerate() {
                let x = x0 + k as u32;
                if x >= target_rect.x0 && x < target_rect.x1 {
                    let d = &mut alpha
                        [(y - target_rect.y0) as usize * tw + (x - target_rect.x0) as usize];
                    *d += (1.0 - *d) * p[3];
                }
            }
        }
    }
}

/// Clips `fragment` to `clip` and packs it for sending, transparent runs left out.
///
/// # Errors
/// As [`SparseTile::new`].
pub fn pack(fragment: &TileFragment, clip: PixelRect) -> Result<Vec<u8>, CompositeError> {
    Ok(SparseTile::new(fragment, clip)?.encode())
}

/// Unpacks bytes from [`pack`] into a dense fragment over the clipped rectangle.
///
/// # Errors
/// As [`SparseTile::decode`]; never panics, whatever the bytes.
pub fn unpack(bytes: &[u8]) -> Result<TileFragment, CompositeError> {
    Ok(SparseTile::decode(bytes)?.to_fragment())
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn left(&self) -> usize {
        self.bytes.len() - self.at
    }

    fn malformed(&self, offset: usize, what: String) -> CompositeError {
        CompositeError::Malformed { offset, what }
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], CompositeError> {
        if n > self.left() {
            return Err(self.malformed(
                self.at,
                format!("got {} bytes for {what}, expected {n}", self.left()),
            ));
        }
        let out = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(out)
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], CompositeError> {
        let mut a = [0; N];
        a.copy_from_slice(self.take(N, what)?);
        Ok(a)
    }

    fn u32(&mut self, what: &str) -> Result<u32, CompositeError> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }
}
