//! Stage 4: per-frame visibility culling of bricks (paper §3.3).
//!
//! Bricks are visited in a visibility order valid for every ray; an opacity buffer over the
//! tile accumulates a *lower bound* of what the bricks in front composite. A brick whose
//! footprint already reads ≥ the threshold at every pixel its rays reach is culled: the
//! pixels it could change are at least that opaque, so it changes them by at most
//! 1 − threshold. A visible brick adds its bound over its *core* footprint only (pixels whose
//! ray runs at least the bound's core length inside it), which is where the bound holds.
//!
//! - `mode`: the culling modes ([`CullMode`]).
//! - `bound`: what culling needs of POFs ([`OpacityBound`]) and POF levels of several core
//!   lengths ([`CoreLevels`]).
//! - `order`: the frame's bricks, their footprints and a front-to-back order
//!   ([`FrameBricks`]).
//! - `spans`: which pixels' rays meet a brick, or run a core length inside it.
//! - `strip`: the culling loop over strips of a tile ([`Culler`]); `fill` adds a visible
//!   brick's bounds to the buffer, `exact` its rendered opacity (the oracle); `scratch`
//!   keeps the buffers ([`CullScratch`]).
//! - [`ideal`] and [`range_bound`]: other bounds, for diagnostics and tests.
//! - Predict, verify, repair ([`CullMode::Verified`]): a [`Predictor`] guesses ([`proxy`]
//!   marches a low-resolution copy of the volume, [`proxy_march`] on two levels; [`predict`] holds the others) and
//!   [`verify`] tests the guess on the opacity tile owners blend, so a wrong guess costs a
//!   repair, never a pixel.

mod bound;
#[cfg(test)]
mod edited_bases_test;
mod exact;
mod fill;
pub mod ideal;
mod mode;
mod order;
pub mod predict;
pub mod proxy;
pub mod proxy_march;
#[cfg(test)]
mod proxy_march_test;
pub mod range_bound;
mod scratch;
mod spans;
mod strip;
#[cfg(test)]
mod test;
#[cfg(test)]
mod verified_test;
pub mod verify;

pub use bound::{CoreLevels, OpacityBound};
pub use mode::CullMode;
pub use order::FrameBricks;
pub use predict::Predictor;
pub use proxy::Proxy;
pub use scratch::CullScratch;
pub use strip::{CullResult, Culler};
pub use verify::{verify_tile, AlphaLayer, Verdict, VerifyView};
