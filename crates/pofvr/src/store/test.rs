//! The brick store: positioned reads equal the volume, the streamed grid equals the mapped
//! one, and budgeted frames equal unbudgeted ones bit for bit while evicting.

use std::path::{Path, PathBuf};

use super::*;
use crate::brick::{BrickCopy, BrickGrid, BrickId};
use crate::render::{families, Camera, Projection};
use crate::scene::{Cull, Engine, FrameRequest, PofBuild, Predict, Scene};
use crate::volume::phantom::Phantom;
use crate::volume::{raw, Endian, RawSpec, Volume, VoxelData};
use crate::with_voxels;

pub(super) fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("pofvr-store-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `volume` written as a raw file with `offset` bytes of header, in `endian` order.
pub(super) fn write_raw(
    volume: &Volume,
    dir: &Path,
    offset: usize,
    endian: Endian,
) -> (PathBuf, RawSpec) {
    let mut bytes = vec![0xAB; offset];
    with_voxels!(volume.data(), v => {
        for x in v {
            let b = bytemuck::bytes_of(x);
            if endian == Endian::Big {
                bytes.extend(b.iter().rev());
            } else {
                bytes.extend_from_slice(b);
            }
        }
    });
    let path = dir.join("vol.raw");
    std::fs::write(&path, bytes).unwrap();
    let mut spec = RawSpec::new(volume.dims(), volume.data_type());
    spec.offset = offset as u64;
    spec.endian = endian;
    spec.spacing = volume.spacing();
    (path, spec)
}

fn values(d: &VoxelData) -> Vec<f32> {
    with_voxels!(d, v => v.iter().map(|x| crate::volume::Voxel::to_f32(*x)).collect())
}

/// A phantom of odd dimensions (bricks clipped on every high face) as i16.
fn head_i16() -> Volume {
    let v = Phantom::SheppLogan.generate_dims([37, 30, 41]);
    let data = with_voxels!(v.data(), x => x.iter().map(|a| (crate::volume::Voxel::to_f32(*a) * 1000.0) as i16).collect::<Vec<i16>>());
    Volume::new(
        v.dims(),
        v.spacing(),
        VoxelData::I16(crate::volume::Voxels::owned(data)),
        "head",
    )
    .unwrap()
}

#[test]
fn positioned_reads_give_the_volumes_boxes_in_either_byte_order() {
    let vol = head_i16();
    let grid = BrickGrid::from_volume(&vol, 8).unwrap();
    for (endian, offset) in [(Endian::Little, 0), (Endian::Big, 7)] {
        let dir = tmp(&format!("reads-{offset}"));
        let (path, spec) = write_raw(&vol, &dir, offset, endian);
        let opened = raw::open(&path, &spec).unwrap();
        assert_eq!(opened.raw_file().map(|(p, _)| p), Some(path.as_path()));
        let src = BrickSource::of(&opened).unwrap();
        assert!(src.is_file());
        for id in grid.ids() {
            let (o, n) = BrickCopy::apron_box(&grid, id);
            let read = src.read_box(&opened, o, n).unwrap();
            let mem = BrickSource::Memory.read_box(&vol, o, n).unwrap();
            assert_eq!(values(&read), values(&mem), "brick {id:?}");
        }
        // Whole planes and a whole slab, read in one call each.
        let d = vol.dims();
        for (o, n) in [([0, 3, 5], [d[0], 9, 4]), ([0, 0, 2], [d[0], d[1], 6])] {
            let read = src.read_box(&opened, o, n).unwrap();
            let mem = BrickSource::Memory.read_box(&vol, o, n).unwrap();
            assert_eq!(values(&read), values(&mem));
        }
        std::fs::remove_dir_all(dir).unwrap();
    }
}

#[test]
fn the_streamed_grid_has_the_mapped_grids_ranges() {
    let vol = head_i16();
    let dir = tmp("grid");
    let (path, spec) = write_raw(&vol, &dir, 3, Endian::Little);
    let opened = raw::open(&path, &spec).unwrap();
    let src = BrickSource::of(&opened).unwrap();
    for (b, slab) in [(8, 1), (8, 1 << 20), (16, 4000), (5, 1)] {
        let mapped = BrickGrid::from_volume(&vol, b).unwrap();
        let streamed = measure_grid(&opened, &src, b, slab).unwrap();
        assert_eq!(mapped.ranges(), streamed.ranges(), "brick {b}, slab {slab}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn the_cache_keeps_its_budget_evicting_the_least_recently_used() {
    let vol = head_i16();
    let grid = BrickGrid::from_volume(&vol, 8).unwrap();
    let one = (0..3)
        .map(|i| {
            BrickCopy::apron_box(&grid, BrickId(i))
                .1
                .iter()
                .product::<usize>() as u64
                * 2
        })
        .max()
        .unwrap();
    // Room for two interior bricks.
    let cache = BrickCache::new(BrickSource::Memory, 2 * one);
    let (a, b, c) = (
        ReadCounts::default(),
        ReadCounts::default(),
        ReadCounts::default(),
    );
    let get = |i: u32, r: &ReadCounts| cache.get(&vol, &grid, BrickId(i), r).unwrap();
    let first = get(0, &a);
    assert_eq!(
        values(first.data()),
        values(BrickCopy::new(&vol, &grid, BrickId(0)).data())
    );
    get(1, &a);
    get(0, &b); // hit
    get(2, &b); // read, not cached: 0 is this frame's, 1 the frame before's
    get(2, &c); // read again; evicts 1, last used two frames ago
    get(2, &c); // hit
    get(1, &c); // read, not cached: 0 is the frame before's, 2 this one's
    assert_eq!((a.cache_hits(), a.bricks_read()), (0, 2));
    assert_eq!((b.cache_hits(), b.bricks_read()), (1, 1));
    assert_eq!((c.cache_hits(), c.bricks_read()), (1, 2));
    let s = cache.summary();
    assert!(s.cache_peak_bytes <= 2 * one, "{s:?}");
    assert_eq!((s.evictions, s.not_cached), (1, 2), "{s:?}");
    assert_eq!(s.bricks_read, 5);
    assert_eq!(
        a.bytes_read() + b.bytes_read() + c.bytes_read(),
        s.bytes_read
    );
}

#[test]
fn bytes_reserved_elsewhere_come_out_of_the_caches_budget() {
    let vol = head_i16();
    let grid = BrickGrid::from_volume(&vol, 8).unwrap();
    let one = (0..3)
        .map(|i| {
            BrickCopy::apron_box(&grid, BrickId(i))
                .1
                .iter()
                .product::<usize>() as u64
                * 2
        })
        .max()
        .unwrap();
    // Room for three bricks, one of which is reserved (the proxy's share).
    let cache = BrickCache::new(BrickSource::Memory, 3 * one);
    cache.reserve(one);
    assert_eq!(cache.brick_budget(), 2 * one);
    let frame = ReadCounts::default();
    for i in 0..3 {
        cache.get(&vol, &grid, BrickId(i), &frame).unwrap();
    }
    let s = cache.summary();
    assert_eq!(s.reserved_bytes, one);
    assert!(s.cache_peak_bytes <= 2 * one, "{s:?}");
    assert_eq!(s.not_cached, 1, "{s:?}");
    // Reserving the whole budget leaves the cache nothing: bricks are read and passed on.
    cache.reserve(2 * one);
    assert_eq!(cache.brick_budget(), 0);
    let next = ReadCounts::default();
    cache.get(&vol, &grid, BrickId(3), &next).unwrap();
    cache.get(&vol, &grid, BrickId(3), &next).unwrap();
    assert_eq!((next.bricks_read(), next.cache_hits()), (2, 0));
}

#[test]
fn frames_that_need_more_than_the_budget_find_a_budgets_worth_of_bricks_next_time() {
    let vol = head_i16();
    let grid = BrickGrid::from_volume(&vol, 8).unwrap();
    let ids: Vec<BrickId> = (0..grid.len() as u32).map(BrickId).collect();
    let bytes =
        |id: &BrickId| BrickCopy::apron_box(&grid, *id).1.iter().product::<usize>() as u64 * 2;
    let all: u64 = ids.iter().map(bytes).sum();
    let cache = BrickCache::new(BrickSource::Memory, all / 2);
    // The same bricks in the same order every frame, as a still or slowly turning view.
    let frame = || {
        let c = ReadCounts::default();
        for id in &ids {
            cache.get(&vol, &grid, *id, &c).unwrap();
        }
        c
    };
    let one = frame();
    assert_eq!(one.bytes_read(), all);
    for _ in 0..3 {
        let next = frame();
        // Plain LRU would evict each brick just before it is asked for: no hit at all.
        assert!(
            next.bytes_read() <= all - all / 2 + all / 8,
            "{} of {all}",
            next.bytes_read()
        );
        assert!(next.cache_hits() > 0);
    }
    assert!(cache.summary().cache_peak_bytes <= all / 2);
}

fn camera(v: &Volume, az: f64, size: u32) -> Camera {
    Camera::orbit(v, az, 25.0, size, size, Projection::Perspective)
}

#[test]
fn budgeted_frames_equal_unbudgeted_ones_in_every_cull_mode_and_rank_count() {
    let vol = Phantom::SheppLogan.generate(40);
    let tf = families::for_phantom(Phantom::SheppLogan);
    let dir = tmp("frames");
    let (path, spec) = write_raw(&vol, &dir, 0, Endian::Little);
    let build = PofBuild {
        views: [4, 4],
        ..PofBuild::default()
    };
    let plain = Scene::builder(raw::open(&path, &spec).unwrap(), tf.clone())
        .brick_size(8)
        .build()
        .unwrap();
    let table = plain.build_pofs(&build).unwrap();
    let plain = plain.with_pofs(table).unwrap();
    // A budget of a tenth of the volume: the bricks of one frame do not fit.
    let budget = super::volume_bytes(&vol) / 10;
    let held = Scene::builder(raw::open(&path, &spec).unwrap(), tf)
        .brick_size(8)
        .memory_budget(Some(budget))
        .build()
        .unwrap();
    assert_eq!(held.grid().ranges(), plain.grid().ranges());
    let table = held.build_pofs(&build).unwrap();
    // Built from the store's slabs, not the mapping: the same table, byte for byte.
    let (a, b) = (dir.join("plain.pof"), dir.join("held.pof"));
    plain.build_pofs(&build).unwrap().save(&a).unwrap();
    table.save(&b).unwrap();
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap());
    let held = held.with_pofs(table).unwrap();
    assert!(held.store().is_some_and(|s| s.source().is_file()));
    let cam = camera(&vol, 30.0, 48);
    let base = FrameRequest::new(&cam);
    for ranks in [1, 3] {
        let modes: [(Cull<'_>, Cull<'_>); 5] = [
            (Cull::None, Cull::None),
            (plain.default_cull(), held.default_cull()),
            (
                Cull::PofSet(plain.pofs().unwrap()),
                Cull::PofSet(held.pofs().unwrap()),
            ),
            (
                Cull::Verified(Predict::Proxy),
                Cull::Verified(Predict::Proxy),
            ),
            (
                Cull::Verified(Predict::Nothing),
                Cull::Verified(Predict::Nothing),
            ),
        ];
        for (p, h) in modes {
            // The brick engine on both sides: its blend order is not the march engine's.
            let want = plain
                .render(
                    &base
                        .clone()
                        .engine(Engine::Bricks)
                        .cull(p)
                        .ranks(ranks)
                        .threshold(0.9),
                )
                .unwrap();
            let got = held
                .render(&base.clone().cull(h).ranks(ranks).threshold(0.9))
                .unwrap();
            let what = format!("{:?} with {ranks} ranks", h.mode());
            let differ = got
                .image
                .pixels()
                .iter()
                .zip(want.image.pixels())
                .filter(|(a, b)| a != b)
                .count();
            assert_eq!(
                differ, 0,
                "pixels differ: {what}, {:?} vs {:?}",
                got.stats.bricks, want.stats.bricks
            );
            assert_eq!(got.stats.engine, "bricks", "{what}");
            let rendered: usize = got.stats.ranks.iter().map(|r| r.bricks_rendered).sum();
            assert_eq!(
                (got.stats.bricks_read + got.stats.cache_hits) as usize,
                rendered,
                "every rendered brick comes from the store: {what}"
            );
            assert!(got.stats.bricks_read > 0, "{what}");
            assert!(got.stats.cache_peak_bytes <= budget, "{what}");
            assert_eq!(got.stats.memory_budget, Some(budget));
            assert_eq!(want.stats.bytes_read, 0);
        }
    }
    // What samples the whole lattice would map the whole file: refused, naming it.
    for (what, e) in [
        (
            "exact",
            held.render(&base.clone().cull(Cull::Exact)).unwrap_err(),
        ),
        ("whole", held.render_reference(&base).unwrap_err()),
    ] {
        let e = e.to_string();
        assert!(e.contains(&path.display().to_string()), "{what}: {e}");
        assert!(e.contains("does not fit the memory budget"), "{what}: {e}");
    }
    assert!(plain.render(&base.clone().cull(Cull::Exact)).is_ok());
    // Without an engine named, a budgeted scene renders with the brick engine.
    let none = held.render(&base).unwrap();
    assert_eq!(none.stats.engine, "bricks");
    let want = plain.render(&base.clone().engine(Engine::Bricks)).unwrap();
    assert_eq!(none.image.pixels(), want.image.pixels());
    assert_eq!(plain.render(&base).unwrap().stats.engine, "march");
    let summary = held.store().unwrap().summary();
    assert!(summary.evictions + summary.not_cached > 0, "{summary:?}");
    // The verified frames' proxy, and the extinction it caches, are charged to the budget.
    let cells: usize = vol.dims().iter().map(|n| n.div_ceil(4)).product();
    assert!(
        summary.reserved_bytes >= 4 * cells as u64 * 2,
        "{summary:?}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_budget_the_volume_fits_keeps_the_whole_volume() {
    let vol = Phantom::SheppLogan.generate(24);
    let tf = families::for_phantom(Phantom::SheppLogan);
    let bytes = super::volume_bytes(&vol);
    let s = Scene::builder(vol, tf)
        .memory_budget(Some(bytes))
        .build()
        .unwrap();
    assert!(s.store().is_none());
    let cam = camera(s.volume(), 0.0, 16);
    assert_eq!(
        s.render(&FrameRequest::new(&cam)).unwrap().stats.engine,
        "march"
    );
}

#[test]
fn a_second_frame_of_the_same_view_reads_nothing_when_its_bricks_fit() {
    // A cube of 1.0 in empty space: only the 8 bricks around it are not empty.
    let n = 64;
    let data: Vec<f32> = (0..n * n * n)
        .map(|i| {
            let inside = [i % n, (i / n) % n, i / (n * n)]
                .iter()
                .all(|c| (20..44).contains(c));
            if inside {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    let data = VoxelData::F32(crate::volume::Voxels::owned(data));
    let vol = Volume::new([n; 3], [1.0; 3], data, "cube").unwrap();
    let tf = families::auto_ramp(crate::brick::ValueRange { min: 0.0, max: 1.0 });
    // Just under the volume: a store (over the in-memory volume), with room for the
    // bricks a view renders, apron included.
    let budget = super::volume_bytes(&vol) - 1;
    let s = Scene::builder(vol, tf)
        .memory_budget(Some(budget))
        .build()
        .unwrap();
    assert_eq!(s.store().map(|c| c.source().kind()), Some("memory"));
    let cam = camera(s.volume(), 10.0, 32);
    let req = FrameRequest::new(&cam).cull(Cull::Exact);
    let first = s.render(&req).unwrap();
    assert!(first.stats.bricks_read > 0);
    assert!(
        first.stats.bytes_read <= budget,
        "{} bytes",
        first.stats.bytes_read
    );
    let second = s.render(&req).unwrap();
    assert_eq!(first.image.pixels(), second.image.pixels());
    assert_eq!(second.stats.bytes_read, 0);
    assert_eq!(second.stats.cache_hits, first.stats.bricks_read);
    assert_eq!(first.stats.bricks.visible as u64, first.stats.bricks_read);
}

#[test]
fn a_file_cut_short_after_opening_is_an_error_naming_it() {
    let vol = head_i16();
    let dir = tmp("short");
    let (path, spec) = write_raw(&vol, &dir, 0, Endian::Little);
    let opened = raw::open(&path, &spec).unwrap();
    let src = BrickSource::of(&opened).unwrap();
    drop(opened);
    std::fs::write(&path, [0u8; 100]).unwrap();
    let e = src
        .read_box(&vol, [0, 0, 30], [37, 30, 5])
        .expect_err("read past the end");
    assert!(e.to_string().contains(&path.display().to_string()), "{e}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn the_streamed_proxy_is_the_mapped_proxy() {
    use crate::cull::proxy::Proxy;
    let vol = head_i16();
    let tf = families::auto_ramp(BrickGrid::from_volume(&vol, 8).unwrap().value_range());
    let grid = BrickGrid::from_volume(&vol, 8).unwrap();
    let sampled = crate::render::SampledTf::new(&tf, grid.value_range());
    let mapped = Proxy::new(&vol, &sampled);
    let d = vol.dims();
    for planes in [1, 4, 9, 64] {
        let read =
            |z0: usize, n: usize| BrickSource::Memory.read_box(&vol, [0, 0, z0], [d[0], d[1], n]);
        let streamed = Proxy::from_slabs(d, &sampled, planes, &read).unwrap();
        assert_eq!(streamed.cells(), mapped.cells());
        assert_eq!(
            streamed.extinction(&[1.0]),
            mapped.extinction(&[1.0]),
            "{planes} planes"
        );
    }
}

/// The proxy's effective extinction of every cell, computed densely and directly from the
/// definition (cell voxels sorted by bin, four near-equal groups, each group's mean
/// extinction per basis, shares from the groups' sizes): what the sparse proxy must equal.
/// Also the number of cells where some basis is not transparent.
fn dense_extinction(
    vol: &Volume,
    sampled: &crate::render::SampledTf,
    w: &[f32],
) -> (Vec<f32>, usize) {
    use crate::cull::proxy::{CORRELATION_LENGTH as L, PROXY_CELL as C, PROXY_GROUPS as G};
    let d = vol.dims();
    let cells = d.map(|n| n.div_ceil(C));
    let v = values(vol.data());
    let mut out = Vec::new();
    let mut seen = 0;
    for z in 0..cells[2] {
        for y in 0..cells[1] {
            for x in 0..cells[0] {
                let mut bins = Vec::new();
                for zz in z * C..((z + 1) * C).min(d[2]) {
                    for yy in y * C..((y + 1) * C).min(d[1]) {
                        for xx in x * C..((x + 1) * C).min(d[0]) {
                            bins.push(sampled.bin(v[xx + d[0] * (yy + d[1] * zz)]));
                        }
                    }
                }
                bins.sort_unstable();
                let opaque =
                    |i: &usize| (0..sampled.basis_count()).any(|b| sampled.tau_table(b)[*i] > 0.0);
                seen += usize::from(bins.iter().any(opaque));
                let n = bins.len();
                let transmit: f32 = (0..G)
                    .map(|g| {
                        let part = &bins[g * n / G..(g + 1) * n / G];
                        if part.is_empty() {
                            return 0.0;
                        }
                        let e: f32 = (0..sampled.basis_count())
                            .zip(w)
                            .filter(|(_, k)| **k > 0.0)
                            .map(|(b, k)| {
                                let t = sampled.tau_table(b);
                                let s: f64 = part.iter().map(|&i| f64::from(t[i])).sum();
                                k * (s / part.len() as f64) as f32
                            })
                            .sum();
                        part.len() as f32 / n as f32 * (-e * L).exp()
                    })
                    .sum();
                out.push(-transmit.max(f32::MIN_POSITIVE).ln() / L);
            }
        }
    }
    (out, seen)
}

#[test]
fn the_proxy_stores_only_cells_some_basis_sees_and_equals_the_dense_definition() {
    use crate::cull::proxy::{Proxy, PROXY_CELL, PROXY_GROUPS};
    // Odd dimensions: the cells on every high face are cut short, so their shares differ.
    let vol = Phantom::Body.generate_dims([45, 38, 29]);
    let tf = families::for_phantom(Phantom::Body);
    let grid = BrickGrid::from_volume(&vol, 8).unwrap();
    let sampled = crate::render::SampledTf::new(&tf, grid.value_range());
    let proxy = Proxy::new(&vol, &sampled);
    for w in [[1.0, 1.0], [0.0, 2.5], [0.3, 0.0]] {
        assert_eq!(
            proxy.extinction(&w),
            dense_extinction(&vol, &sampled, &w).0,
            "{w:?}"
        );
    }
    // Cells where either basis is opaque somewhere: the only ones with stored groups.
    let cells: usize = vol.dims().map(|n| n.div_ceil(PROXY_CELL)).iter().product();
    let seen = dense_extinction(&vol, &sampled, &[1.0, 1.0]).1;
    assert!(seen > 0 && seen < cells, "{seen} of {cells} cells seen");
    let f = std::mem::size_of::<f32>() as u64;
    let dense = cells as u64 * PROXY_GROUPS as u64 * f * 3;
    let sparse = cells as u64 * f + (seen * PROXY_GROUPS * 2) as u64 * f;
    assert!(
        proxy.heap_bytes() <= sparse && proxy.heap_bytes() < dense,
        "{} heap bytes; {sparse} sparse, {dense} dense",
        proxy.heap_bytes()
    );
}

#[test]
fn the_library_frame_refuses_the_exact_cull_on_a_job_reading_through_a_store() {
    use crate::frame::{render_frame, FrameError, FrameOptions, RenderJob};
    use crate::render::RenderSettings;
    let vol = Phantom::SheppLogan.generate(40);
    let tf = families::for_phantom(Phantom::SheppLogan);
    let dir = tmp("exact");
    let (path, spec) = write_raw(&vol, &dir, 0, Endian::Little);
    let budget = super::volume_bytes(&vol) / 10;
    let opened = raw::open(&path, &spec).unwrap();
    let grid = super::grid_for(&opened, 8, Some(budget)).unwrap();
    let store = super::cache_for(&opened, Some(budget)).unwrap();
    let mut job = RenderJob::with_grid(opened, tf, grid, RenderSettings::default()).unwrap();
    job.store = store;
    assert!(job.store.is_some());
    let cam = camera(&vol, 30.0, 32);
    for ranks in [1, 3] {
        let exact = FrameOptions {
            cull: crate::cull::CullMode::Exact,
            ranks,
            ..FrameOptions::default()
        };
        let read = || job.store.as_ref().unwrap().summary().bricks_read;
        let before = read();
        let e = render_frame(&job, None, &cam, &exact).unwrap_err();
        assert!(
            matches!(e, FrameError::WholeLattice(_)),
            "{ranks} ranks: {e}"
        );
        let e = e.to_string();
        assert!(e.contains("the exact cull"), "{e}");
        assert!(e.contains(&path.display().to_string()), "{e}");
        assert!(e.contains("does not fit the memory budget"), "{e}");
        // Nothing was read for it; a frame without the oracle reads through the store.
        assert_eq!(read(), before);
        let none = FrameOptions {
            cull: crate::cull::CullMode::None,
            ..exact
        };
        let (_, stats) = render_frame(&job, None, &cam, &none).unwrap();
        assert!(stats.bricks_read + stats.cache_hits > 0);
    }
    // Without a store the oracle samples the mapped volume, as before.
    job.store = None;
    let exact = FrameOptions {
        cull: crate::cull::CullMode::Exact,
        ..FrameOptions::default()
    };
    assert!(render_frame(&job, None, &cam, &exact).is_ok());
    std::fs::remove_dir_all(dir).unwrap();
}
