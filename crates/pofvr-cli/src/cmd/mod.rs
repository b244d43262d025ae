pub(crate) mod bench;
pub(crate) mod demo;
pub(crate) mod experiment;
pub(crate) mod info;
pub(crate) mod pof;
pub(crate) mod render;
pub(crate) mod serve;
