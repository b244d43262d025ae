pub(crate) mod bench;
pub(crate) mod demo;
pub(crate) mod info;
#[cfg(feature = "mpi")]
pub(crate) mod mpi_frame;
pub(crate) mod pof;
pub(crate) mod render;
pub(crate) mod serve;
