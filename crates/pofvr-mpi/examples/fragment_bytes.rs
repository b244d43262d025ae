//! Bytes of the fragment exchange of one frame, sparse (as sent) against dense fragments and
//! against full tiles: `cargo run --release -p pofvr-mpi --example fragment_bytes -- VOLUME
//! [--dims X,Y,Z --dtype T --spacing SX,SY,SZ] --tf TF.json [--view AZ,EL] [--size WxH]
//! [--ranks 1,2,4]`. Cull mode none; the in-process frame's own steps (bricks dealt along the
//! Hilbert curve, a tile per rank, each rank's fragments clipped to the tiles they overlap).
//! Needs no MPI: the counts are the same as under mpirun.

use std::collections::BTreeSet;
use std::path::Path;

use pofvr::comm::Rank;
use pofvr::composite::{SparseTile, TileFragment, TileLayout};
use pofvr::cull::FrameBricks;
use pofvr::distribute::{BrickAssignment, Curve};
use pofvr::frame::RenderJob;
use pofvr::render::{Camera, Projection, RayCaster, RenderSettings, TransferFunction};
use pofvr::volume::{RawSpec, Volume};
use rayon::prelude::*;

fn flag<'a>(args: &'a [String], name: &str) -> Option<&'a str> {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .map(String::as_str)
}

fn list<T: std::str::FromStr>(s: &str) -> Vec<T> {
    s.split(',')
        .map(|x| {
            x.trim()
                .parse()
                .unwrap_or_else(|_| panic!("bad number in {s:?}"))
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args
        .first()
        .expect("usage: fragment_bytes VOLUME --tf TF.json …");
    let raw = flag(&args, "--dims").map(|d| {
        let d: Vec<usize> = list(d);
        let mut spec = RawSpec::new(
            [d[0], d[1], d[2]],
            flag(&args, "--dtype")
                .expect("--dtype")
                .parse()
                .expect("dtype"),
        );
        if let Some(s) = flag(&args, "--spacing") {
            let s: Vec<f32> = list(s);
            spec.spacing = [s[0], s[1], s[2]];
        }
        spec
    });
    let volume = Volume::open(Path::new(path), raw.as_ref()).expect("open volume");
    let tf = TransferFunction::from_file(Path::new(flag(&args, "--tf").expect("--tf")))
        .expect("read TF");
    let view: Vec<f64> = list(flag(&args, "--view").unwrap_or("30,20"));
    let (w, h) = flag(&args, "--size")
        .unwrap_or("512x512")
        .split_once('x')
        .map(|(w, h)| (w.parse().expect("width"), h.parse().expect("height")))
        .expect("--size WxH");
    let ranks: Vec<usize> = list(flag(&args, "--ranks").unwrap_or("1,2,4"));
    let camera = Camera::orbit(&volume, view[0], view[1], w, h, Projection::Orthographic);
    let job = RenderJob::new(volume, tf, 16, RenderSettings::default()).expect("job");
    let weights = &job.tf.weights;
    let cls = job.sampled.classify(weights, job.settings.step);
    let caster = RayCaster::new(&job.volume, &cls, job.settings);
    let bricks = FrameBricks::new(&job.volume, &job.grid, &job.sampled, weights, &camera);
    let frame = camera.frame();
    // Every visible brick's fragment, rendered once (the counts below only regroup them).
    let fragments: Vec<TileFragment> = bricks
        .order
        .par_iter()
        .filter_map(|id| {
            let rect = bricks.footprints[id.index()]?;
            let (pixels, _) = caster.render_box(&camera, &frame, rect, &job.grid.index_box(*id));
            Some(TileFragment {
                brick: *id,
                depth_key: bricks.depth_key[id.index()],
                rect,
                pixels,
            })
        })
        .collect();
    let by_brick: std::collections::HashMap<u32, &TileFragment> =
        fragments.iter().map(|f| (f.brick.0, f)).collect();
    println!(
        "{} visible bricks, image {w}x{h}, view {},{}",
        fragments.len(),
        view[0],
        view[1]
    );
    println!("ranks  sparse_sent  dense_fragments  one_tile_per_pair  saved_vs_dense  saved_vs_pair_tiles  gather_bytes");
    for n in ranks {
        let assignment = BrickAssignment::new(job.grid.counts(), Curve::Hilbert, n).expect("deal");
        let layout =
            TileLayout::new(w, h, bricks.bounds.expect("volume on screen"), n).expect("tiles");
        let (mut sparse, mut dense) = (0u64, 0u64);
        let mut pairs = BTreeSet::new();
        for r in 0..n {
            let me = Rank(u32::try_from(r).expect("small"));
            for id in assignment.of(me) {
                let Some(f) = by_brick.get(&id.0) else {
                    continue;
                };
                for t in layout.tiles_overlapping(&f.rect) {
                    let owner = layout.owner(t);
                    if owner == me {
                        continue;
                    }
                    let clip = layout.tile(t).expect("tile");
                    let s = SparseTile::new(f, clip).expect("clip");
                    // 1 kind byte + the encoded fragment, as DirectSend sends it.
                    sparse += 1 + s.encode().len() as u64;
                    let area = f.rect.intersect(&clip).map_or(0, |c| c.area());
                    dense += 1 + 36 + 12 + 16 * area as u64;
                    pairs.insert((r, t.index()));
                }
            }
        }
        let full: u64 = pairs
            .iter()
            .map(|&(_, t)| {
                16 * layout
                    .tile(pofvr::composite::TileId(u32::try_from(t).expect("small")))
                    .map_or(0, |c| c.area()) as u64
            })
            .sum();
        let gather: u64 = (1..n)
            .map(|t| {
                16 * layout
                    .tile(pofvr::composite::TileId(u32::try_from(t).expect("small")))
                    .map_or(0, |c| c.area()) as u64
            })
            .sum();
        let pct = |x: u64, of: u64| 100.0 * (1.0 - x as f64 / of.max(1) as f64);
        println!(
            "{n:>5}  {sparse:>11}  {dense:>15}  {full:>17}  {:>13.1}%  {:>18.1}%  {gather:>12}",
            pct(sparse, dense),
            pct(sparse, full)
        );
    }
}
