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
    /// At most this much memory for the volume's voxels (e.g. 256M, 4G), as `render
    /// --memory-budget`: a volume larger than that is rendered by the brick engine, each
    /// brick a frame renders read on demand into an LRU cache within the budget, shared by
    /// every client's frames; the histogram is counted by streaming the file. The frames'
    /// stats header gains bytes_read, bricks_read and cache_hits.
    /// > default: none (the whole volume is mapped)
    #[arg(long, value_name = "SIZE")]
    pub(crate) memory_budget: Option<String>,
}

pub(crate) fn run(a: &ServeArgs, ui: &Ui) -> Result<()> {
    let budget = super::render::memory_budget(a.memory_budget.as_deref())?;
    let sp = ui.spinner("opening and bricking the volume");
    let vol = resolve::volume(&a.volume)?;
    let tf = resolve::required_tf(&a.tf, &a.volume.volume)?;
    let mut scene = Scene::builder(vol, tf)
        .brick_size(a.volume.brick)
        .memory_budget(budget)
        .build()?;
    if let Some(p) = &a.pof {
        scene = scene.load_pof_levels(p, &a.pof_level)?;
    }
    sp.finish_and_clear();
    if let Some(b) = budget {
        let bytes = pofvr::store::volume_bytes(scene.volume());
        match scene.store() {
            Some(store) => eprintln!(
                "pofvr serve: the volume ({:.1} MB) does not fit the memory budget ({:.1} MB): the brick engine reads bricks on demand from the {}",
                bytes as f64 / 1e6,
                b as f64 / 1e6,
                store.source().kind()
            ),
            None => eprintln!(
                "pofvr serve: the volume ({:.1} MB) fits the memory budget ({:.1} MB): rendered whole",
                bytes as f64 / 1e6,
                b as f64 / 1e6
            ),
        }
    }
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
