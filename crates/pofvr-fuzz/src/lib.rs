//! Fuzzing of every parser of outside input on the stable toolchain.
//!
//! Each [`target::Target`] takes `&[u8]` and feeds it to one parser (through a file where
//! the parser reads files, so that detached data files and gzip streams are exercised too).
//! The runner (`src/bin/pofvr-fuzz.rs`) mutates the seed corpus in `corpus/TARGET/` with a
//! seeded RNG ([`mutate`]), catches panics, enforces a per-input time limit, and fails an
//! input whose single allocation exceeds what its length justifies ([`alloc`]).

pub mod alloc;
pub mod mutate;
pub mod target;
