//! Per-frame brick geometry: which bricks are empty, their footprints and a front-to-back
//! order valid for every ray.

use glam::DVec3;

use crate::brick::{BrickGrid, BrickId};
use crate::render::{Camera, PixelRect, Projection, SampledTf};
use crate::volume::Volume;

/// Per-frame geometry of the bricks: which are empty, their footprints and a visibility
/// order. Shared by every rank of a frame.
pub struct FrameBricks {
    /// Non-empty bricks in a front-to-back order valid for every ray.
    pub order: Vec<BrickId>,
    /// Footprint (clipped to the image) of each brick by id; `None` when empty or off-screen.
    pub footprints: Vec<Option<PixelRect>>,
    /// Number of bricks empty for the current weights.
    pub empty: usize,
    /// Depth key of each brick by id (its position in `order`).
    pub depth_key: Vec<i64>,
    /// The union of the footprints: the image bounding box of what can be drawn.
    pub bounds: Option<PixelRect>,
}

impl FrameBricks {
    /// Finds the non-empty bricks, their footprints and a visibility order.
    ///
    /// The order key is a brick-grid distance that grows by one at every face a ray
    /// crosses: Σₐ sₐ·iₐ for parallel rays (sₐ the sign of the direction) and
    /// Σₐ |iₐ − eₐ| from the eye's brick cell for perspective. Along any ray the key is
    /// strictly increasing, so sorting by it is front to back for every ray at once.
    #[must_use]
    pub fn new(
        volume: &Volume,
        grid: &BrickGrid,
        sampled: &SampledTf,
        weights: &[f32],
        camera: &Camera,
    ) -> Self {
        let frame = camera.frame();
        let spacing = DVec3::from(volume.spacing().map(f64::from));
        let b = grid.brick_size() as f64;
        let eye_cell = (DVec3::from(camera.position) / spacing / b).floor();
        let mut keyed = Vec::new();
        let mut footprints = vec![None; grid.len()];
        let mut empty = 0;
        for id in grid.ids() {
            if sampled.is_empty(grid.range(id), weights) {
                empty += 1;
                continue;
            }
            let ib = grid.index_box(id);
            let lo = DVec3::from(ib.lo.map(f64::from)) * spacing;
            let hi = DVec3::from(ib.hi.map(f64::from)) * spacing;
            let Some(rect) = camera.footprint(&frame, lo, hi) else {
                continue;
            };
            footprints[id.index()] = Some(rect);
            let c = grid.coords(id).map(|x| x as i64);
            let key = match camera.projection {
                Projection::Orthographic => {
                    let s = [frame.forward.x, frame.forward.y, frame.forward.z].map(|x| {
                        if x > 0.0 {
                            1
                        } else if x < 0.0 {
                            -1
                        } else {
                            0
                        }
                    });
                    s[0] * c[0] + s[1] * c[1] + s[2] * c[2]
                }
                Projection::Perspective => {
                    let e = [eye_cell.x as i64, eye_cell.y as i64, eye_cell.z as i64];
                    (c[0] - e[0]).abs() + (c[1] - e[1]).abs() + (c[2] - e[2]).abs()
                }
            };
            keyed.push((key, id));
        }
        keyed.sort_unstable();
        let order: Vec<BrickId> = keyed.into_iter().map(|(_, id)| id).collect();
        let mut depth_key = vec![i64::MAX; grid.len()];
        for (i, id) in order.iter().enumerate() {
            {
                depth_key[id.index()] = i as i64;
            }
        }
        let bounds = footprints
            .iter()
            .flatten()
            .copied()
            .reduce(|a: PixelRect, b| PixelRect {
                x0: a.x0.min(b.x0),
                y0: a.y0.min(b.y0),
                x1: a.x1.max(b.x1),
                y1: a.y1.max(b.y1),
            });
        FrameBricks {
            order,
            footprints,
            empty,
            depth_key,
            bounds,
        }
    }
}
