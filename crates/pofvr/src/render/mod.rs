//! Stage 5: cameras, transfer functions and the ray caster.

mod arch;
pub mod camera;
pub mod families;
pub mod image;
mod lattice;
pub mod ray_caster;
pub(crate) mod sampler;
#[cfg(test)]
mod test;
pub mod transfer_function;

pub use camera::{Camera, PixelRect, Projection, Ray, ViewFrame};
pub use image::Image;
pub use ray_caster::{IndexRay, RayCaster, RayStats, RenderSettings};
pub use transfer_function::{Classifier, SampledTf, TfError, TransferFunction};
