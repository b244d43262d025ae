//! `pof build --memory-budget`: a POF build streamed slab by slab from the file is the
//! in-memory build's file byte for byte, for every method, however small the slabs; bad
//! reads and writes are errors naming the file, with nothing left under the output's name.

use std::path::{Path, PathBuf};

use super::test::{tmp, write_raw};
use super::*;
use crate::pof::{build_streamed, PofMethod, PofSettings, PofTable};
use crate::render::{families, SampledTf};
use crate::volume::phantom::Phantom;
use crate::volume::{raw, Endian};

/// Bricks of 8 over odd dimensions: clipped bricks on every high face.
fn setup(name: &str) -> (PathBuf, Volume, BrickGrid, PathBuf) {
    let vol = Phantom::SheppLogan.generate_dims([37, 30, 41]);
    let dir = tmp(name);
    let (path, spec) = write_raw(&vol, &dir, 5, Endian::Little);
    let opened = raw::open(&path, &spec).unwrap();
    let grid = BrickGrid::from_volume(&opened, 8).unwrap();
    (dir, opened, grid, path)
}

fn settings(method: PofMethod) -> PofSettings {
    PofSettings {
        views: [4, 6],
        sets: true,
        ..PofSettings::for_method(method)
    }
}

/// The streamed build of `vol` (the Shepp–Logan family) from `source` into `out` under
/// `budget`.
fn build_to(
    vol: &Volume,
    source: &BrickSource,
    grid: &BrickGrid,
    s: &PofSettings,
    budget: u64,
    out: &Path,
) -> Result<crate::pof::StreamedBuild, crate::pof::PofError> {
    let tf = families::for_phantom(Phantom::SheppLogan);
    let sampled = SampledTf::new(&tf, grid.value_range());
    build_streamed(vol, source, grid, &tf, &sampled, s, budget, out, &|_, _| {})
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn a_streamed_build_writes_the_in_memory_builds_file_for_every_method_and_slab_size() {
    let (dir, vol, grid, _) = setup("pof-same");
    let tf = families::for_phantom(Phantom::SheppLogan);
    let sampled = SampledTf::new(&tf, grid.value_range());
    let source = BrickSource::of(&vol).unwrap();
    assert!(source.is_file());
    let c = grid.counts();
    let vol_bytes = volume_bytes(&vol);
    for method in [PofMethod::Bound, PofMethod::Sampled, PofMethod::Typical] {
        let s = settings(method);
        let table = PofTable::build(&vol, &grid, &tf, &sampled, &s, &|_, _| {}).unwrap();
        let whole = dir.join("whole.pof");
        table.save(&whole).unwrap();
        let expected = std::fs::read(&whole).unwrap();
        // 1 byte: a row of bricks per slab; 40 kB: a few rows; 1 GiB: a layer per slab.
        for budget in [1, 40_000, 1 << 30] {
            let out = dir.join("streamed.pof");
            let r = build_to(&vol, &source, &grid, &s, budget, &out).unwrap();
            let got = std::fs::read(&out).unwrap();
            assert!(got == expected, "{method:?} at {budget}: files differ");
            assert_eq!(r.file_bytes, expected.len() as u64);
            assert_eq!(r.stored_bricks, table.stored_bricks() as u64);
            assert!(r.stored_bricks > 0 && r.computed_bricks >= r.stored_bricks);
            if budget == 1 {
                assert!(r.slabs_read > c[2] as u64, "{r:?}");
            } else if budget == 1 << 30 {
                assert!(r.slabs_read <= c[2] as u64, "{r:?}");
            }
            // Read about once: slabs share a face plane with the next along y and z.
            let b = grid.brick_size() as f64;
            let most = vol_bytes as f64 * ((b + 1.0) / b).powi(2);
            assert!(r.bytes_read > 0 && (r.bytes_read as f64) <= most, "{r:?}");
            PofTable::open(&out)
                .unwrap()
                .check_grid(&vol, &grid)
                .unwrap();
        }
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_volume_cut_short_during_a_streamed_build_is_an_error_naming_it_and_leaves_nothing() {
    let (dir, vol, grid, path) = setup("pof-short");
    let source = BrickSource::of(&vol).unwrap();
    let before = files_in(&dir);
    // Half the voxels are gone: the slabs past them cannot be read.
    let len = std::fs::metadata(&path).unwrap().len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&path)
        .unwrap()
        .set_len(len / 2)
        .unwrap();
    let out = dir.join("cut.pof");
    let e = build_to(
        &vol,
        &source,
        &grid,
        &settings(PofMethod::Typical),
        1 << 20,
        &out,
    )
    .expect_err("the file is short");
    assert!(e.to_string().contains(&path.display().to_string()), "{e}");
    assert_eq!(files_in(&dir), before, "nothing written");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn an_unwritable_output_is_an_error_naming_it() {
    let (dir, vol, grid, _) = setup("pof-unwritable");
    let source = BrickSource::of(&vol).unwrap();
    let out = dir.join("no-such-dir").join("x.pof");
    let e = build_to(
        &vol,
        &source,
        &grid,
        &settings(PofMethod::Typical),
        1 << 20,
        &out,
    )
    .expect_err("no such directory");
    assert!(e.to_string().contains(&out.display().to_string()), "{e}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn the_experiments_pofs_under_a_budget_are_built_from_the_store_and_the_oracle_is_left_out() {
    use crate::experiment::{self as exp, NoProgress, PofSource};
    use crate::frame::RenderJob;
    use crate::render::RenderSettings;
    let tf = families::for_phantom(Phantom::SheppLogan);
    let (dir, vol, grid, _) = setup("pof-experiment");
    let (other, vol2, grid2, _) = setup("pof-experiment-2");
    let bytes = volume_bytes(&vol);
    let store = cache_for(&vol2, Some(bytes / 3)).unwrap();
    assert!(store.is_some());
    let whole = RenderJob::with_grid(vol, tf.clone(), grid, RenderSettings::default()).unwrap();
    let mut budgeted = RenderJob::with_grid(vol2, tf, grid2, RenderSettings::default()).unwrap();
    budgeted.store = store;
    let a = exp::pof_construction(&whole, [4, 6], PofSource::Build, true, &NoProgress).unwrap();
    let b = exp::pof_construction(&budgeted, [4, 6], PofSource::Build, true, &NoProgress).unwrap();
    assert_eq!(a.rows.len(), b.rows.len());
    for (x, y) in a.rows.iter().zip(&b.rows) {
        assert_eq!(x.label(), y.label());
        assert_eq!(x.source, "built");
        assert!(x.bytes_read.is_none());
        assert!(
            y.source.starts_with("built, streamed from the raw file"),
            "{}",
            y.source
        );
        // Each build reads the volume once, ghost planes twice at most.
        let read = y.bytes_read.unwrap();
        assert!(read > 0 && read < 2 * bytes, "{read}");
        assert_eq!(
            (x.stored_bricks, x.file_bytes, x.computed_bricks),
            (y.stored_bricks, y.file_bytes, y.computed_bricks)
        );
    }
    // The same tables, so the same culling: compare the files.
    for (t, u, name) in [(&a.table, &b.table, "table"), (&a.cubic, &b.cubic, "cubic")] {
        let (p, q) = (
            dir.join(format!("a-{name}.pof")),
            dir.join(format!("b-{name}.pof")),
        );
        t.save(&p).unwrap();
        u.save(&q).unwrap();
        assert!(
            std::fs::read(&p).unwrap() == std::fs::read(&q).unwrap(),
            "{name}"
        );
    }
    let range = exp::range_bound(&budgeted);
    let mut all = exp::methods(&b, &range, "no sets");
    assert!(exp::honour_budget(&mut all.clone(), &whole).is_empty());
    assert_eq!(exp::honour_budget(&mut all, &budgeted), ["exact"]);
    for m in &all {
        assert_eq!(m.available(), m.name != "exact", "{}", m.name);
    }
    assert_eq!(
        all.iter().find(|m| m.name == "exact").unwrap().missing,
        Some(exp::NO_EXACT_UNDER_BUDGET)
    );
    std::fs::remove_dir_all(dir).unwrap();
    std::fs::remove_dir_all(other).unwrap();
}
