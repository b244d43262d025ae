use anyhow::Result;
use pofvr::brick::BrickGrid;
use pofvr::render::families;
use pofvr::volume::Voxel;
use pofvr::{with_voxels, Scene};

use crate::args::InfoArgs;
use crate::progress::Ui;
use crate::resolve;

pub(crate) fn run(a: &InfoArgs, ui: &Ui) -> Result<()> {
    let sp = ui.spinner("opening and bricking the volume");
    let vol = resolve::volume(&a.volume)?;
    let grid = BrickGrid::from_volume(&vol, a.volume.brick)?;
    let range = grid.value_range();
    // One pass over the voxels for the histogram.
    let mut hist = [0u64; 16];
    let width = (range.max - range.min).max(f32::MIN_POSITIVE);
    with_voxels!(vol.data(), v => {
        for x in v {
            let b = (((x.to_f32() - range.min) / width * 16.0) as usize).min(15);
            hist[b] += 1;
        }
    });
    sp.finish_and_clear();
    let tf = resolve::tf(&a.tf, &a.volume.volume)?;
    let (tf_name, tf) = match tf {
        Some(tf) => ("given", tf),
        None => ("automatic ramp", families::auto_ramp(range)),
    };
    let scene = Scene::builder(vol, tf).grid(grid).build()?;
    let (vol, grid, sampled, weights) = (
        scene.volume(),
        scene.grid(),
        scene.sampled(),
        scene.default_weights(),
    );
    let empty = scene.empty_bricks(weights)?;
    let total: u64 = hist.iter().sum();
    let hist_json: Vec<serde_json::Value> = hist
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let lo = range.min + width * i as f32 / 16.0;
            serde_json::json!({"from": lo, "to": lo + width / 16.0, "count": c})
        })
        .collect();
    let info = serde_json::json!({
        "source": vol.source(),
        "dims": vol.dims(),
        "dtype": vol.data_type(),
        "spacing": vol.spacing(),
        "memory_mapped": vol.data().is_mapped(),
        "value_range": [range.min, range.max],
        "histogram": hist_json,
        "brick_size": grid.brick_size(),
        "bricks": {"counts": grid.counts(), "total": grid.len(), "empty": empty, "non_empty": grid.len() - empty},
        "tf": {"kind": tf_name, "bases": sampled.names(), "weights": weights},
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&info)?);
        return Ok(());
    }
    let d = vol.dims();
    let s = vol.spacing();
    println!("volume     {}", vol.source());
    println!(
        "dims       {} × {} × {}  ({} voxels)",
        d[0],
        d[1],
        d[2],
        d[0] * d[1] * d[2]
    );
    println!(
        "type       {}{}",
        vol.data_type(),
        if vol.data().is_mapped() {
            "  (memory-mapped)"
        } else {
            ""
        }
    );
    println!("spacing    {} × {} × {}", s[0], s[1], s[2]);
    println!("range      {} .. {}", range.min, range.max);
    println!("histogram  (16 bins over the range, % of voxels)");
    for (i, c) in hist.iter().enumerate() {
        let lo = range.min + width * i as f32 / 16.0;
        let pct = 100.0 * *c as f64 / total.max(1) as f64;
        let bar = "#".repeat((pct / 2.0).ceil() as usize);
        println!("  {lo:>12.3}  {pct:>6.2}%  {bar}");
    }
    let c = grid.counts();
    println!(
        "bricks     {}³: {} × {} × {} = {}",
        grid.brick_size(),
        c[0],
        c[1],
        c[2],
        grid.len()
    );
    println!(
        "empty      {} of {} for the {} transfer function ({}; weights {:?})",
        empty,
        grid.len(),
        tf_name,
        sampled.names().join(", "),
        weights
    );
    Ok(())
}
