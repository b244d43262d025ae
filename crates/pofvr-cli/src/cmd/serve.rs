//! `pofvr serve`: the interactive browser viewer.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{anyhow, Result};
use clap::Args;
use pofvr::Scene;
use pofvr_web::{ServeConfig, Viewer, ViewerOptions};

use crate::args::{TfArgs, VolumeArgs};
use crate::progress::Ui;
use crate::resolve;

/// Flags of `pofvr serve`.
#[derive(Args, Debug)]
pub(crate) struct ServeArgs {
    #[command(flatten)]
    pub(crate) volume: VolumeArgs,
    #[command(flatten)]
    pub(crate) tf: TfArgs,
    /// Precomputed plenoptic opacity functions for the volume and family.
    #[arg(long, value_name = "FILE.pof")]
    pub(crate) pof: Option<PathBuf>,
    /// More POFs built with other --core-length values (repeatable; see `render --pof-level`).
    #[arg(long, value_name = "FILE.pof", requires = "pof")]
    pub(crate) pof_level: Vec<PathBuf>,
    /// TCP port; 0 picks a free one (the address is printed on stdout).
    /// > default: 8080
    #[arg(long, default_value_t = 8080)]
    pub(crate) port: u16,
    /// Address to listen on. Anything but loopback exposes the viewer to the network.
    /// > default: 127.0.0.1
    #[arg(long, default_value_t = IpAddr::V4(Ipv4Addr::LOCALHOST))]
    pub(crate) bind: IpAddr,
    /// In-process ranks per frame (bricks dealt along a Hilbert curve, as `pofvr render`).
    /// > default: 1
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub(crate) ranks: u16,
}

pub(crate) fn run(a: &ServeArgs, ui: &Ui) -> Result<()> {
    let sp = ui.spinner("opening and bricking the volume");
    let vol = resolve::volume(&a.volume)?;
    let tf = resolve::required_tf(&a.tf, &a.volume.volume)?;
    let mut scene = Scene::builder(vol, tf).brick_size(a.volume.brick).build()?;
    if let Some(p) = &a.pof {
        scene = scene.load_pof_levels(p, &a.pof_level)?;
    }
    sp.finish_and_clear();
    if !a.bind.is_loopback() {
        eprintln!(
            "pofvr serve: warning: listening on {}, reachable from other machines",
            a.bind
        );
    }
    let opts = ViewerOptions {
        loopback_hosts_only: a.bind.is_loopback(),
        ranks: usize::from(a.ranks),
        ..ViewerOptions::default()
    };
    let viewer = Viewer::new(Arc::new(scene), &a.volume.volume, &opts);
    pofvr_web::serve_blocking(ServeConfig {
        viewer,
        addr: SocketAddr::new(a.bind, a.port),
    })
    .map_err(|e| anyhow!("serving on {}:{}: {e}", a.bind, a.port))
}
