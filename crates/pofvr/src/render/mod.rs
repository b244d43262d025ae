//! Stage 5: cameras, transfer functions and the ray caster.
//!
//! - `camera`, `image`, `transfer_function` (and `families`, the built-in ones).
//! - `lattice`: index rays and the one sample lattice every box of a ray is sampled on.
//! - `jitter`: seeded per-pixel offsets of the first sample (reproducible, off by default).
//! - `sampler`: the trilinear sampler, the one definition of a sample's value.
//! - `ray_caster`: whole-volume and per-box renders ([`RayCaster`]).
//! - `occupancy`, `skip` and `march`: the cells that can hold opacity for a
//!   classification, the exact leaps over the others, and the whole-volume render that
//!   skips them ([`RayCaster::render_march`]).
//! - `blocks`: a copy of the volume in blocks, for the march engine on volumes far
//!   larger than the caches.
//! - `arch`: the sample loops, `arch/generic.rs` the scalar reference (and shading),
//!   `arch/x86_64/{sse2,avx2}.rs` the vector loops that equal it bit for bit.

mod arch;
pub mod blocks;
pub mod camera;
pub mod families;
mod frame_rays;
pub mod image;
pub mod jitter;
mod lattice;
pub mod march;
pub mod occupancy;
pub mod ray_caster;
pub(crate) mod sampler;
mod skip;
#[cfg(test)]
mod test;
#[cfg(test)]
mod test_march;
pub mod transfer_function;

pub use blocks::MarchBlocks;
pub use camera::{Camera, PixelRect, Projection, Ray, ViewFrame};
pub use image::Image;
pub use march::MarchStats;
pub use occupancy::{CellRanges, Occupancy};
pub use ray_caster::{IndexRay, RayCaster, RayStats, RenderSettings};
pub use transfer_function::{Classifier, SampledTf, TfError, TransferFunction};
