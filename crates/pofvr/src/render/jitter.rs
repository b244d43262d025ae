//! Jittered ray starts: each pixel's ray samples the one lattice `t_k = k·step` shifted
//! by its own fraction of a step, drawn from a hash of the pixel and a seed.
//!
//! Why: sampling a surface at one fixed lattice for every pixel puts the samples at the
//! same depth phase on neighbouring rays, and the phase drifts slowly across the image —
//! wood-grain rings. A per-pixel offset in `[0, step)` turns that structured error into
//! fine noise. The offset is a pure function of `(seed, x, y)`, so a seeded frame is
//! reproducible, and it is applied to the ray itself (its origin moves forward along its
//! direction) before any box is intersected: every box of a ray — whole volume, brick or
//! any other partition — still claims its samples from the one (shifted) lattice, so a
//! frame rendered brick by brick equals the whole-volume frame bit for bit.

use super::lattice::IndexRay;

/// The offset of pixel `(x, y)`'s first sample, in `[0, 1)` steps, for `seed`.
#[must_use]
pub fn offset(seed: u32, x: u32, y: u32) -> f32 {
    // A murmur3-style finaliser over the three words: neighbouring pixels and seeds give
    // unrelated offsets.
    let mut h = seed ^ 0x9e37_79b9;
    for w in [x, y] {
        h ^= w
            .wrapping_mul(0xcc9e_2d51)
            .rotate_left(15)
            .wrapping_mul(0x1b87_3593);
        h = h.rotate_left(13).wrapping_mul(5).wrapping_add(0xe654_6b64);
    }
    h ^= h >> 16;
    h = h.wrapping_mul(0x85eb_ca6b);
    h ^= h >> 13;
    h = h.wrapping_mul(0xc2b2_ae35);
    h ^= h >> 16;
    // The top 24 bits: exactly representable, strictly below 1.
    (h >> 8) as f32 / (1u32 << 24) as f32
}

/// `ray` with its origin moved `frac · step` units forward, so that its lattice index `k`
/// samples the original ray at `t = (k + frac)·step`.
#[must_use]
pub fn shifted(ray: IndexRay, frac: f32, step: f32) -> IndexRay {
    let dt = frac * step;
    IndexRay {
        o: [
            ray.o[0] + dt * ray.d[0],
            ray.o[1] + dt * ray.d[1],
            ray.o[2] + dt * ray.d[2],
        ],
        ..ray
    }
}
