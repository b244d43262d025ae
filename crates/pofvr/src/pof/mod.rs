//! Stage 3: Plenoptic Opacity Functions (paper §3): per brick, per basis, the least opacity
//! the ray caster composites for the brick alone, tabulated over view directions.
//!
//! ## What a POF value guarantees
//!
//! With [`PofMethod::Bound`] (the default) the following holds rigorously for the measured
//! directions and, through `margin`, for the directions between them. A
//! [`PofMethod::Sampled`] table only aims at it: its values are measured on a finite grid
//! of rays, phases and directions, so it is an empirical bound whose margin is chosen so
//! that `pofvr pof check` finds no violation; it can be exceeded (anisotropic volumes, where
//! index and world directions differ, are the likeliest), so check a sampled table on the
//! volume it is for.
//!
//! For brick `b`, basis `i` and the angular cell `(θ, φ)` of a view direction `d`, the
//! stored opacity `α` satisfies, for *every* ray of a direction in that cell whose `t`-span
//! inside the brick's index box is at least [`PofTable::core_length`] (`L`), and for every
//! phase of the renderer's sample lattice: the opacity that
//! [`crate::render::RayCaster::render_box`] composites for basis `i` alone (weight 1) is
//! `≥ α`. Rays shorter than `L` (the footprint's rim) are exempt: they graze an edge and
//! carry almost nothing, so a minimum over them would be 0 and cull nothing.
//!
//! Weights enter through Eq. 3 ([`PofTable::opacity`]); the result is capped at the
//! early-termination threshold because a ray stops compositing there.
//!
//! ## How it is computed (see `build.rs`; the sampled method in `sampled.rs`)
//!
//! Not by rendering every view (that is `reference.rs`, the slow twin used by tests and
//! `pofvr pof check`), but from a lower bound that holds for all continuous ray positions
//! and lattice phases at once: a chord of length `ℓ` holds `⌊ℓ/step⌋` disjoint windows of
//! length `step`, each containing exactly one sample, and each sample's extinction is at
//! least the minimum extinction over the voxel cells the window can touch.
//!
//! ## Files
//!
//! - `settings`: the knobs of the precompute ([`PofSettings`], [`PofMethod`]).
//! - `build`, `sampled`: the two builders; `reference`: the brute-force twin;
//!   `stream_build`: a build within a memory budget, slab by slab, written as it goes.
//! - `table`: the table of records ([`PofTable`]); `meta`: what it was built for
//!   ([`PofMeta`]); `error`: [`PofError`]; `file`, `encoding`, `cubic`: how it is stored.
//! - `lookup`: run-time opacity along a direction or over a cone ([`PofMode`], Eq. 3);
//!   `cache`: what lookups remember; `prefetch`: loading ahead what they will read.
//! - `view_grid`: the angular grid of view cells ([`angles`], [`direction`]).

mod build;
mod cache;
mod cubic;
mod encoding;
mod error;
mod file;
mod lookup;
mod meta;
mod prefetch;
pub mod reference;
mod sampled;
mod settings;
mod stream_build;
mod table;
#[cfg(test)]
mod test;
mod typical;
mod view_grid;

pub use encoding::Encoding;
pub use error::PofError;
pub use lookup::{PofMode, ALPHA_MAX};
pub use meta::{range_hash, PofMeta};
pub use settings::{
    PofMethod, PofSettings, JOINT_MAX_BASES, SAMPLED_MARGIN, SAMPLED_PHASES, SAMPLED_PITCH,
    TYPICAL_PITCH, TYPICAL_QUANTILE,
};
pub use stream_build::{build_streamed, build_streamed_in_memory, StreamedBuild};
pub use table::PofTable;
pub use view_grid::{angles, direction};
