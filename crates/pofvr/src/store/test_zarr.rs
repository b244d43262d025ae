//! Zarr levels under a memory budget: boxes assembled from chunks equal the volume's, the
//! streamed grid equals the measured one, compressed bytes are counted, and budgeted frames
//! equal the frames of the decoded level bit for bit, chunks aligned with bricks or not.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use zarrs::array::codec::ZstdCodec;
use zarrs::array::ArrayBuilder;
use zarrs::filesystem::FilesystemStore;

use super::*;
use crate::brick::{BrickCopy, BrickGrid};
use crate::render::{families, Camera, Projection};
use crate::scene::{Cull, Engine, FrameRequest, Predict, Scene};
use crate::volume::phantom::Phantom;
use crate::volume::{OpenOptions, Volume, VoxelData};
use crate::with_voxels;

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("pofvr-zstore-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `volume` (i16) written as one Zarr v3 array at `dir/name` with chunks of `chunk` (x, y, z)
/// voxels, zstd-compressed.
fn write_array(volume: &Volume, dir: &Path, name: &str, chunk: [u64; 3]) -> PathBuf {
    let path = dir.join(name);
    std::fs::create_dir_all(&path).unwrap();
    let store = Arc::new(FilesystemStore::new(&path).unwrap());
    let d = volume.dims();
    let array = ArrayBuilder::new(
        vec![d[2] as u64, d[1] as u64, d[0] as u64],
        vec![chunk[2], chunk[1], chunk[0]],
        zarrs::array::data_type::int16(),
        zarrs::array::FillValue::new(vec![0u8; 2]),
    )
    .bytes_to_bytes_codecs(vec![Arc::new(ZstdCodec::new(1, false))])
    .build(store, "/")
    .unwrap();
    array.store_metadata().unwrap();
    let VoxelData::I16(v) = volume.data() else {
        panic!("an i16 volume")
    };
    let all = zarrs::array::CodecOptions::default().with_store_empty_chunks(true);
    array
        .store_array_subset_opt(
            &[0..d[2] as u64, 0..d[1] as u64, 0..d[0] as u64],
            v.as_slice(),
            &all,
        )
        .unwrap();
    path
}

fn deferred(path: &Path) -> Volume {
    let v = Volume::open_with(
        path,
        &OpenOptions {
            defer_above: Some(1),
            ..OpenOptions::default()
        },
    )
    .unwrap();
    assert!(!v.is_resident());
    v
}

fn values(d: &VoxelData) -> Vec<f32> {
    with_voxels!(d, v => v.iter().map(|x| crate::volume::Voxel::to_f32(*x)).collect())
}

/// Bytes of every file under `dir` but the metadata.
fn chunk_file_bytes(dir: &Path) -> u64 {
    let mut total = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            total += chunk_file_bytes(&p);
        } else if p.file_name().is_some_and(|n| n != "zarr.json") {
            total += std::fs::metadata(&p).unwrap().len();
        }
    }
    total
}

fn body() -> Volume {
    Phantom::Body.generate_dims([45, 38, 52])
}

#[test]
fn boxes_from_chunks_equal_the_volumes_boxes_and_count_compressed_bytes() {
    let vol = body();
    let dir = tmp("boxes");
    for (i, chunk) in [[16, 16, 16], [13, 9, 11], [64, 64, 64]]
        .into_iter()
        .enumerate()
    {
        let path = write_array(&vol, &dir, &format!("a{i}"), chunk);
        let opened = deferred(&path);
        assert_eq!(opened.dims(), vol.dims());
        let src = BrickSource::of(&opened).unwrap();
        assert_eq!(src.kind(), "zarr chunks");
        assert!(src.is_file());
        // No chunk cached: each box reads every chunk it meets, so the whole volume as one
        // box reads every chunk file once.
        let d = vol.dims();
        let (whole, bytes) = src.read_box_counted(&opened, [0; 3], d).unwrap();
        assert_eq!(values(&whole), values(vol.data()));
        assert_eq!(bytes, chunk_file_bytes(&path), "chunks {chunk:?}");
        // Room for two chunks: boxes evict as they go.
        let z = src.zarr().unwrap();
        z.set_chunk_budget(2 * chunk.iter().product::<u64>() * 2);
        for b in [8, 5] {
            let grid = BrickGrid::from_volume(&vol, b).unwrap();
            for id in grid.ids() {
                let (o, n) = BrickCopy::apron_box(&grid, id);
                let read = src.read_box(&opened, o, n).unwrap();
                let mem = BrickSource::Memory.read_box(&vol, o, n).unwrap();
                assert_eq!(
                    values(&read),
                    values(&mem),
                    "brick {id:?}, chunks {chunk:?}"
                );
            }
        }
        assert!(z.chunks_decoded() > 0);
        if chunk != [64, 64, 64] {
            assert!(z.chunk_evictions() > 0, "chunks {chunk:?}");
        }
        // A read that meets only cached chunks reads no bytes.
        let src = BrickSource::of(&opened).unwrap();
        let z = src.zarr().unwrap();
        z.set_chunk_budget(1 << 30);
        let one = src
            .read_box_counted(&opened, [1, 2, 3], [4, 4, 4])
            .unwrap()
            .1;
        assert!(one > 0);
        assert_eq!(
            src.read_box_counted(&opened, [1, 2, 3], [4, 4, 4])
                .unwrap()
                .1,
            0
        );
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn the_streamed_grid_of_a_deferred_level_has_the_decoded_grids_ranges() {
    let vol = body();
    let dir = tmp("grid");
    let path = write_array(&vol, &dir, "a", [13, 9, 11]);
    let opened = deferred(&path);
    for b in [8, 16, 5] {
        let want = BrickGrid::from_volume(&vol, b).unwrap();
        for budget in [Some(4096), Some(1 << 20), None] {
            let got = grid_for(&opened, b, budget).unwrap();
            assert_eq!(want.ranges(), got.ranges(), "brick {b}, budget {budget:?}");
        }
    }
    std::fs::remove_dir_all(dir).unwrap();
}

fn camera(v: &Volume, az: f64, size: u32) -> Camera {
    Camera::orbit(v, az, 25.0, size, size, Projection::Perspective)
}

#[test]
fn budgeted_zarr_frames_equal_decoded_frames_bit_for_bit() {
    let vol = body();
    let tf = families::for_phantom(Phantom::Body);
    let dir = tmp("frames");
    // Chunks aligned with 8³ bricks (16³) and not aligned with them (13×9×11).
    for (i, chunk) in [[16, 16, 16], [13, 9, 11]].into_iter().enumerate() {
        let path = write_array(&vol, &dir, &format!("a{i}"), chunk);
        let plain = Scene::builder(Volume::open(&path, None).unwrap(), tf.clone())
            .brick_size(8)
            .build()
            .unwrap();
        assert!(plain.volume().is_resident());
        // A tenth of the volume: the bricks of one frame do not fit, nor its chunks.
        let budget = volume_bytes(&vol) / 10;
        let opened = Volume::open_with(
            &path,
            &OpenOptions {
                defer_above: Some(budget),
                ..OpenOptions::default()
            },
        )
        .unwrap();
        assert!(!opened.is_resident());
        let held = Scene::builder(opened, tf.clone())
            .brick_size(8)
            .memory_budget(Some(budget))
            .build()
            .unwrap();
        assert_eq!(held.grid().ranges(), plain.grid().ranges());
        assert_eq!(held.store().map(|s| s.source().kind()), Some("zarr chunks"));
        let cam = camera(&vol, 30.0, 48);
        let base = FrameRequest::new(&cam);
        for ranks in [1, 3] {
            for cull in [
                Cull::None,
                Cull::Verified(Predict::Proxy),
                Cull::Verified(Predict::Nothing),
            ] {
                let what = format!("{:?} with {ranks} ranks, chunks {chunk:?}", cull.mode());
                let want = plain
                    .render(
                        &base
                            .clone()
                            .engine(Engine::Bricks)
                            .cull(cull)
                            .ranks(ranks)
                            .threshold(0.9),
                    )
                    .unwrap();
                let got = held
                    .render(&base.clone().cull(cull).ranks(ranks).threshold(0.9))
                    .unwrap();
                assert!(
                    got.image.pixels() == want.image.pixels(),
                    "pixels differ: {what}"
                );
                assert_eq!(got.stats.engine, "bricks", "{what}");
                let rendered: usize = got.stats.ranks.iter().map(|r| r.bricks_rendered).sum();
                assert_eq!(
                    (got.stats.bricks_read + got.stats.cache_hits) as usize,
                    rendered,
                    "{what}"
                );
                assert!(got.stats.cache_peak_bytes <= budget, "{what}");
            }
        }
        let s = held.store().unwrap();
        // The verified frames' proxy is charged to the budget; here it leaves the bricks
        // little or nothing, so that they are evicted or passed on uncached.
        let summary = s.summary();
        assert!(summary.reserved_bytes > 0, "{summary:?}");
        assert!(summary.evictions + summary.not_cached > 0, "{summary:?}");
        let z = s.source().zarr().unwrap();
        assert_eq!(z.chunk_budget(), budget / 2);
        assert!(z.chunks_decoded() > 0);
        // The compressed bytes read are counted, not the decoded ones.
        assert!(s.summary().bytes_read > 0);
        assert!(s.summary().bytes_read <= chunk_file_bytes(&path) * 50);
        // What samples the whole lattice is refused with a message, not zeros.
        for e in [
            held.render(&base.clone().cull(Cull::Exact)).map(|_| ()),
            held.render_reference(&base).map(|_| ()),
            held.render(&base.clone().engine(Engine::March)).map(|_| ()),
        ] {
            let e = e.expect_err("needs the whole lattice").to_string();
            assert!(e.contains("whole") && e.contains("budget"), "{e}");
        }
        // A POF build reads the chunks slab by slab: the decoded level's table, byte for byte.
        let build = crate::scene::PofBuild {
            views: [4, 6],
            ..crate::scene::PofBuild::default()
        };
        let (a, b) = (dir.join("plain.pof"), dir.join("held.pof"));
        plain.build_pofs(&build).unwrap().save(&a).unwrap();
        held.build_pofs(&build).unwrap().save(&b).unwrap();
        assert!(
            std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(),
            "chunks {chunk:?}"
        );
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_chunk_removed_after_opening_is_an_error_naming_it() {
    let vol = body();
    let dir = tmp("gone");
    let path = write_array(&vol, &dir, "a", [16, 16, 16]);
    let opened = deferred(&path);
    let src = BrickSource::of(&opened).unwrap();
    let chunk = path.join("c/1/1/1");
    assert!(chunk.is_file());
    std::fs::remove_file(&chunk).unwrap();
    let e = src
        .read_box(&opened, [10, 10, 10], [10, 10, 10])
        .unwrap_err()
        .to_string();
    assert!(e.contains("c/1/1/1") && e.contains("missing"), "{e}");
    std::fs::write(&chunk, b"not zstd").unwrap();
    let e = src
        .read_box(&opened, [10, 10, 10], [10, 10, 10])
        .unwrap_err()
        .to_string();
    assert!(e.contains("c/1/1/1"), "{e}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn distributed_ranks_read_only_their_own_bricks_from_the_chunks() {
    use crate::comm::LocalCommunicator;
    use crate::distribute::setup::DistributedRank;
    use crate::distribute::Curve;
    use crate::frame::{FrameOptions, RenderJob};
    use crate::render::RenderSettings;
    let vol = body();
    let tf = families::for_phantom(Phantom::Body);
    let dir = tmp("ranks");
    let path = write_array(&vol, &dir, "a", [13, 9, 11]);
    let whole = BrickGrid::from_volume(&vol, 8).unwrap();
    let budget = volume_bytes(&vol) / 10;
    let cam = camera(&vol, 30.0, 40);
    let plain = RenderJob::with_grid(
        Volume::open(&path, None).unwrap(),
        tf.clone(),
        whole.clone(),
        RenderSettings::default(),
    )
    .unwrap();
    for cull in [crate::cull::CullMode::None, crate::cull::CullMode::Verified] {
        let opts = FrameOptions {
            cull,
            ..FrameOptions::default()
        };
        let (want, _) = crate::frame::render_frame(&plain, None, &cam, &opts).unwrap();
        for n in [1, 3] {
            let out = LocalCommunicator::run(n, |comm| {
                let opened = Volume::open_with(
                    &path,
                    &OpenOptions {
                        defer_above: Some(budget),
                        ..OpenOptions::default()
                    },
                )
                .unwrap();
                let rank = DistributedRank::new(comm);
                let grid = rank
                    .measure_grid_within(&opened, 8, Curve::Hilbert, Some(budget))
                    .unwrap();
                assert_eq!(grid.ranges(), whole.ranges());
                let mut job =
                    RenderJob::with_grid(opened, tf.clone(), grid, RenderSettings::default())
                        .unwrap();
                rank.read_own_bricks(&mut job, Curve::Hilbert, 1, budget)
                    .unwrap();
                assert!(job.bricks.is_none() && job.store.is_some());
                rank.frame(&job, None, &cam, &opts).unwrap()
            });
            let (image, stats) = out[0].clone().expect("rank 0 has the frame");
            let what = format!("{cull:?}, {n} ranks");
            assert!(image.pixels() == want.pixels(), "pixels differ: {what}");
            assert_eq!(stats.ranks.len(), n);
            for r in &stats.ranks {
                // Each rank read exactly the bricks it rendered, from its own store.
                assert_eq!(
                    r.bricks_read + r.cache_hits,
                    r.bricks_rendered as u64,
                    "{what}"
                );
                assert!(r.bytes_read > 0, "{what}: rank {} read nothing", r.rank);
            }
        }
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn ranks_dealt_by_chunks_give_the_same_frame_and_decode_fewer_chunks() {
    use crate::comm::LocalCommunicator;
    use crate::distribute::setup::DistributedRank;
    use crate::distribute::{Curve, Deal};
    use crate::frame::{FrameOptions, RenderJob};
    use crate::render::RenderSettings;
    let vol = Phantom::Body.generate_dims([96, 80, 112]);
    let tf = families::for_phantom(Phantom::Body);
    let dir = tmp("deal");
    // 16³ chunks of eight 8³ bricks: 6×5×7 chunks. So few chunks across that a run's skin
    // (the neighbours its bricks' aprons meet) is much of the grid: the gain here is small,
    // on the 8×8×27 chunks of docs/large-data.md it is half at 2 ranks.
    const C: usize = 16;
    let path = write_array(&vol, &dir, "a", [C as u64; 3]);
    // Under the volume (so the level is read by chunks) but room for every chunk: the
    // decodes counted are each rank's chunks, not evictions.
    let budget = volume_bytes(&vol) * 9 / 10;
    let cam = camera(&vol, 30.0, 40);
    let plain = RenderJob::new(
        Volume::open(&path, None).unwrap(),
        tf.clone(),
        8,
        RenderSettings::default(),
    )
    .unwrap();
    let opts = FrameOptions {
        cull: crate::cull::CullMode::None,
        ..FrameOptions::default()
    };
    let (want, _) = crate::frame::render_frame(&plain, None, &cam, &opts).unwrap();
    for n in [2, 3] {
        let mut most = Vec::new();
        for deal in [Deal::Curve, Deal::Auto, Deal::Chunks] {
            let out = LocalCommunicator::run(n, |comm| {
                let opened = Volume::open_with(
                    &path,
                    &OpenOptions {
                        defer_above: Some(budget),
                        ..OpenOptions::default()
                    },
                )
                .unwrap();
                let rank = DistributedRank::new(comm).with_deal(deal);
                let grid = rank
                    .measure_grid_within(&opened, 8, Curve::Hilbert, Some(budget))
                    .unwrap();
                let mut job =
                    RenderJob::with_grid(opened, tf.clone(), grid, RenderSettings::default())
                        .unwrap();
                job.deal = deal;
                rank.read_own_bricks(&mut job, Curve::Hilbert, 1, budget)
                    .unwrap();
                let dealt = job.assignment(Curve::Hilbert, n, 1).unwrap();
                // One thread per rank: threads of a rank missing one chunk at once would
                // both decode it, and the counts would vary from run to run.
                let one = rayon::ThreadPoolBuilder::new()
                    .num_threads(1)
                    .build()
                    .unwrap();
                let frame = one.install(|| rank.frame(&job, None, &cam, &opts).unwrap());
                (dealt, frame)
            });
            let what = format!("{deal} with {n} ranks");
            let (image, stats) = out[0].1.clone().expect("rank 0 has the frame");
            assert!(image.pixels() == want.pixels(), "pixels differ: {what}");
            let dealt = if deal == Deal::Curve {
                "curve"
            } else {
                "chunks"
            };
            assert_eq!(stats.deal, Some(dealt), "{what}");
            for r in &stats.ranks {
                assert_eq!(
                    r.bricks_read + r.cache_hits,
                    r.bricks_rendered as u64,
                    "{what}"
                );
            }
            let busiest = stats.ranks.iter().map(|r| r.chunks_decoded).max().unwrap();
            most.push((busiest, out[0].0.clone()));
        }
        let (curve, auto, chunks) = (&most[0], &most[1], &most[2]);
        assert_eq!(auto.1, chunks.1, "{n} ranks: auto deals by chunks");
        assert_ne!(curve.1, chunks.1, "{n} ranks");
        // The distinct chunks the busiest rank's non-empty bricks meet (apron included):
        // what the deal decides, whatever the chunk cache then evicts.
        let met = |dealt: &crate::distribute::BrickAssignment| {
            (0..n)
                .map(|r| {
                    let mut set = std::collections::HashSet::new();
                    for id in dealt.of(crate::comm::Rank(r as u32)) {
                        if plain
                            .sampled
                            .is_empty(plain.grid.range(*id), &plain.tf.weights)
                        {
                            continue;
                        }
                        let (o, d) = BrickCopy::apron_box(&plain.grid, *id);
                        for z in o[2] / C..=(o[2] + d[2] - 1) / C {
                            for y in o[1] / C..=(o[1] + d[1] - 1) / C {
                                for x in o[0] / C..=(o[0] + d[0] - 1) / C {
                                    set.insert([x, y, z]);
                                }
                            }
                        }
                    }
                    set.len()
                })
                .max()
                .unwrap()
        };
        let (c, k) = (met(&curve.1), met(&chunks.1));
        let (dc, dk) = (curve.0, chunks.0);
        eprintln!("{n} ranks, busiest: chunks met {c} (curve) vs {k}; decoded {dc} vs {dk}");
        assert!(k < c, "{n} ranks: {k} vs {c} chunks met");
        // Decoded (one thread per rank, so the same every run): fewer too.
        assert!(dk < dc, "{n} ranks: {dk} vs {dc} decoded");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn the_library_frame_refuses_the_exact_cull_on_a_level_decoded_by_chunks() {
    use crate::frame::{render_frame, FrameError, FrameOptions, RenderJob};
    use crate::render::RenderSettings;
    let vol = body();
    let dir = tmp("exact");
    let path = write_array(&vol, &dir, "a", [16, 16, 16]);
    let opened = deferred(&path);
    let grid = grid_for(&opened, 8, Some(4096)).unwrap();
    let mut job = RenderJob::with_grid(
        opened,
        families::for_phantom(Phantom::Body),
        grid,
        RenderSettings::default(),
    )
    .unwrap();
    job.store = cache_for(&job.volume, Some(4096)).unwrap();
    let exact = FrameOptions {
        cull: crate::cull::CullMode::Exact,
        ..FrameOptions::default()
    };
    // Without the check the oracle would sample a lattice that is not in memory.
    let e = render_frame(&job, None, &camera(&vol, 0.0, 24), &exact).unwrap_err();
    assert!(matches!(e, FrameError::WholeLattice(_)), "{e}");
    let e = e.to_string();
    assert!(
        e.contains("Zarr level") && e.contains("memory budget"),
        "{e}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}
