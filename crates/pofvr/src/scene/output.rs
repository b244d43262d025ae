//! [`Frame`]: a rendered image and its figures.

use std::path::Path;

use crate::error::Result;
use crate::frame::FrameStats;
use crate::render::Image;

/// A rendered frame: the image (premultiplied RGBA floats) and what it took.
#[derive(Clone, Debug)]
pub struct Frame {
    /// The image.
    pub image: Image,
    /// Time, rays, samples, brick counts and the per-rank breakdown.
    pub stats: FrameStats,
}

impl Frame {
    /// Writes the image as an 8-bit RGBA PNG (straight alpha).
    ///
    /// # Errors
    /// [`crate::Error::Write`] naming the path.
    pub fn write_png(&self, path: impl AsRef<Path>) -> Result<()> {
        Ok(self.image.write_png(path.as_ref())?)
    }

    /// Writes the float image: little-endian f32, width × height × 4, premultiplied RGBA.
    ///
    /// # Errors
    /// [`crate::Error::Write`] naming the path.
    pub fn write_raw(&self, path: impl AsRef<Path>) -> Result<()> {
        Ok(self.image.write_raw(path.as_ref())?)
    }

    /// Non-empty bricks culled (never sampled).
    #[must_use]
    pub fn culled_bricks(&self) -> usize {
        self.stats.bricks.culled
    }

    /// The image and the figures, apart.
    #[must_use]
    pub fn into_parts(self) -> (Image, FrameStats) {
        (self.image, self.stats)
    }
}
