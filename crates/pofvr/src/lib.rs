//! # pofvr: volume rendering with Plenoptic Opacity Function culling
//!
//! ## Brief overview
//!
//! Most programs need only the facade: a [`Scene`] (built once, shared by `Arc`) rendered
//! per [`FrameRequest`] into a [`Frame`]. From a file to a culled PNG:
//!
//! ```
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! # let dir = tempfile::tempdir()?;
//! # std::env::set_current_dir(dir.path())?;
//! # let phantom = pofvr::volume::phantom::Phantom::SheppLogan.generate(64);
//! # let pofvr::volume::VoxelData::U8(voxels) = phantom.data() else { unreachable!() };
//! # let mut nrrd = b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 64 64 64\nencoding: raw\n\n".to_vec();
//! # nrrd.extend_from_slice(voxels.as_slice());
//! # std::fs::write("head.nrrd", nrrd)?;
//! # std::fs::write("head.json", pofvr::render::families::SHEPP_LOGAN_JSON)?;
//! use pofvr::{Camera, Cull, FrameRequest, PofBuild, Projection, Scene, TransferFunction, Volume};
//!
//! let volume = Volume::open("head.nrrd".as_ref(), None)?;
//! let family = TransferFunction::from_file("head.json".as_ref())?;
//! let scene = Scene::builder(volume, family).brick_size(8).build()?;
//! let pofs = scene.build_pofs(&PofBuild { views: [8, 8], ..PofBuild::default() })?;
//! let scene = scene.with_pofs(pofs)?; // or scene.load_pofs("head.pof")?
//! let camera = Camera::orbit(scene.volume(), 0.0, 0.0, 256, 256, Projection::Orthographic);
//! let cull = Cull::Pof(scene.pofs().ok_or("no POFs")?);
//! let frame = scene.render(&FrameRequest::new(&camera).weights(&[3.0, 1.0]).cull(cull))?;
//! frame.write_png("head.png")?;
//! println!("{} of {} bricks culled", frame.culled_bricks(), frame.stats.bricks.non_empty);
//! # assert!(std::path::Path::new("head.png").exists() && frame.culled_bricks() > 0);
//! # Ok(())
//! # }
//! ```
//!
//! Every fallible call returns [`Result`], whose [`Error`] carries the values at fault
//! ("got X, expected Y") and names the file where a file is at fault.
//!
//! The stages behind it, in order:
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
//! 6. [`frame`]: the one place where stages are chained into a frame; [`scene`] is the
//!    facade over it ([`frame::RenderJob`] is the same with the weights and shading of
//!    its frames inside, for code that sets up a job by hand).
//!
//! For parallel frames (paper §4):
//!
//! - [`distribute::BrickAssignment`]: bricks dealt round-robin to ranks along a Hilbert or
//!   Z curve ([`distribute::SfcOrder`]).
//! - [`comm::Communicator`]: messages between ranks; [`comm::LocalCommunicator`] runs the
//!   ranks as threads ([`FrameRequest::ranks`]), [`Scene::render_on`] takes any other.
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
pub mod experiment;
pub mod frame;
pub mod io;
pub mod pof;
pub mod pof_measure;
pub mod render;
pub mod scene;
pub mod store;
pub mod volume;

pub use cull::CullMode;
pub use distribute::Curve;
pub use error::{Error, Result};
pub use frame::FrameStats;
pub use pof::PofTable;
pub use render::{Camera, Image, Projection, TransferFunction};
pub use scene::{Cull, Engine, Frame, FrameRequest, PofBuild, Pofs, Predict, Scene, SceneBuilder};
pub use volume::Volume;
