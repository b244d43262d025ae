//! # pofvr: volume rendering with Plenoptic Opacity Function culling
//!
//! ## Brief overview
//!
//! The pipeline, in order:
//!
//! 1. [`volume::Volume`]: the scalar grid in its stored type, memory-mapped from raw,
//!    NRRD, MetaImage or NIfTI files, or generated ([`volume::phantom::Phantom`]).
//! 2. [`brick::BrickGrid`]: the volume cut into bricks (16³ by default) with their value
//!    ranges; empty bricks for a transfer function are known before rendering.
//! 3. [`pof::PofTable`]: per brick and basis, the least opacity from every view (paper §3),
//!    precomputed once and looked up by the culler.
//! 4. [`render::TransferFunction`]: a family of basis opacity functions with weights,
//!    tabulated as [`render::SampledTf`].
//! 5. [`render::Camera`] and [`render::RayCaster`]: front-to-back emission–absorption
//!    ray casting on one global sample lattice, so bricks render seamlessly.
//! 6. [`frame`]: the one place where stages are chained into a frame.
//!
//! For parallel frames (paper §4):
//!
//! - [`distribute::BrickAssignment`]: bricks dealt round-robin to ranks along a Hilbert or
//!   Z curve ([`distribute::SfcOrder`]).
//! - [`comm::Communicator`]: messages between ranks; [`comm::LocalCommunicator`] runs the
//!   ranks as threads.
//! - [`composite::DirectSend`]: brick fragments sent sparse to the owners of the image tiles
//!   they overlap, blended in depth order and gathered into the frame.

#![warn(missing_docs)]

pub mod brick;
pub mod check;
pub mod comm;
pub mod composite;
pub mod cull;
pub mod distribute;
pub mod error;
pub mod frame;
pub mod io;
pub mod pof;
pub mod render;
pub mod scene;
pub mod volume;

pub use cull::CullMode;
pub use distribute::Curve;
pub use error::{Error, Result};
pub use frame::FrameStats;
pub use pof::PofTable;
pub use render::{Camera, Image, Projection, TransferFunction};
pub use scene::{Cull, Frame, FrameRequest, PofBuild, Pofs, Scene, SceneBuilder};
pub use volume::Volume;
