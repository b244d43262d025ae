//! The exact oracle: a visible brick is rendered, and the opacity it really composites is
//! added to the buffer, so that later bricks are tested against what lies in front of
//! them. Sequential and as slow as rendering; it exists to measure how close the POF
//! modes get.

use crate::brick::IndexBox;
use crate::render::{Camera, PixelRect, RayCaster, ViewFrame};

/// Renders the box `ibox` over `rect` and composites its opacity into `buffer`, the
/// opacity of the pixels of `tile` (row-major).
pub(super) fn add_rendered(
    caster: &RayCaster<'_>,
    (camera, frame): (&Camera, &ViewFrame),
    ibox: &IndexBox,
    rect: PixelRect,
    (buffer, tile): (&mut [f32], PixelRect),
) {
    let (frag, _) = caster.render_box(camera, frame, rect, ibox);
    let (rw, tw) = (rect.width() as usize, tile.width() as usize);
    for (i, p) in frag.iter().enumerate() {
        let (x, y) = (rect.x0 + (i % rw) as u32, rect.y0 + (i / rw) as u32);
        let b = &mut buffer[(y - tile.y0) as usize * tw + (x - tile.x0) as usize];
        *b += (1.0 - *b) * p[3];
    }
}
