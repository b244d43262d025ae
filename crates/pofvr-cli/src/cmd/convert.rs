//! `pofvr convert IN OUT.zarr`: any input as an OME-Zarr (Zarr v3) multiscale image.

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;

use crate::args::VolumeArgs;
use crate::progress::Ui;
use crate::resolve;

#[derive(Args, Debug)]
pub(crate) struct ConvertArgs {
    #[command(flatten)]
    pub(crate) volume: VolumeArgs,
    /// The OME-Zarr store to write (a folder, conventionally OUT.zarr); it must not exist.
    /// Level 0 is the volume, each further level half the one before, in 64³ chunks
    /// (whole bricks) compressed with zstd.
    pub(crate) out: PathBuf,
}

pub(crate) fn run(a: &ConvertArgs, ui: &Ui) -> Result<()> {
    if a.out.exists() {
        bail!(
            "{}: already exists (convert does not overwrite)",
            a.out.display()
        );
    }
    let sp = ui.spinner("opening the volume");
    let vol = resolve::volume(&a.volume)?;
    sp.finish_and_clear();
    let mut bar = None;
    pofvr::volume::zarr::write_ome_zarr(&vol, &a.out, &mut |done, total| {
        let pb = bar.get_or_insert_with(|| ui.bar(total, "writing slabs"));
        pb.set_position(done);
    })?;
    if let Some(pb) = bar {
        pb.finish_and_clear();
    }
    let [x, y, z] = vol.dims();
    eprintln!(
        "{}: {x}×{y}×{z} {} written as OME-Zarr",
        a.out.display(),
        vol.data_type()
    );
    Ok(())
}
