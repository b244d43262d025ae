//! The volume's value histogram that the page's transfer-function panel draws under the
//! opacity curves: counted once, over the bricks' value range, in parallel.

use pofvr::store::BrickCache;
use pofvr::volume::{Voxel, VoxelData};
use pofvr::Scene;
use serde::Serialize;

/// Bins of [`Histogram::of`]: fine enough to place control points by eye at 512 pixels.
pub const HISTOGRAM_BINS: usize = 256;

/// Voxel counts in equal bins over `[lo, hi]`, the value range the family is tabulated over.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Histogram {
    /// `[lo, hi]`, the bricks' value range.
    pub value_range: [f32; 2],
    /// Lower edge of the first bin.
    pub lo: f32,
    /// Upper edge of the last bin (its values included).
    pub hi: f32,
    /// Voxels per bin; bin `i` covers `[lo + i·w, lo + (i+1)·w)` with `w = (hi − lo) / bins`.
    pub counts: Vec<u64>,
    /// Voxels counted: every voxel of the volume.
    pub total: u64,
}

impl Histogram {
    /// Counts every voxel of `scene`'s volume into [`HISTOGRAM_BINS`] bins over its bricks'
    /// value range, splitting the voxels among the machine's cores. A scene under a memory
    /// budget its volume does not fit reads its file slab by slab instead of through the
    /// mapping, so that counting does not bring the whole volume into memory; a failed read
    /// (the file changed since it was opened) gives an empty histogram, with the reason on
    /// stderr, rather than a wrong one.
    #[must_use]
    pub fn of(scene: &Scene) -> Histogram {
        let range = scene.grid().value_range();
        let (lo, hi) = (range.min, range.max);
        let counts = match scene.store().filter(|s| s.source().is_file()) {
            Some(store) => streamed(scene, store, lo, hi).unwrap_or_else(|e| {
                eprintln!("pofvr serve: histogram not counted: {e}");
                vec![0; HISTOGRAM_BINS]
            }),
            None => count_data(scene.volume().data(), lo, hi),
        };
        Histogram {
            value_range: [lo, hi],
            lo,
            hi,
            total: counts.iter().sum(),
            counts,
        }
    }
}

fn count_data(data: &VoxelData, lo: f32, hi: f32) -> Vec<u64> {
    match data {
        VoxelData::U8(x) => count(x.as_slice(), lo, hi),
        VoxelData::U16(x) => count(x.as_slice(), lo, hi),
        VoxelData::I16(x) => count(x.as_slice(), lo, hi),
        VoxelData::F32(x) => count(x.as_slice(), lo, hi),
    }
}

/// The counts of a budgeted scene's volume, read from its store's file in slabs of whole
/// planes of at most an eighth of the budget (at least one plane).
fn streamed(
    scene: &Scene,
    store: &BrickCache,
    lo: f32,
    hi: f32,
) -> Result<Vec<u64>, pofvr::volume::VolumeError> {
    let vol = scene.volume();
    let d = vol.dims();
    let plane = (d[0] * d[1] * vol.data_type().size()) as u64;
    let planes = (store.budget() / 8 / plane.max(1)).max(1) as usize;
    let mut acc = vec![0u64; HISTOGRAM_BINS];
    for z0 in (0..d[2]).step_by(planes) {
        let n = planes.min(d[2] - z0);
        let slab = store.source().read_box(vol, [0, 0, z0], [d[0], d[1], n])?;
        for (a, b) in acc.iter_mut().zip(count_data(&slab, lo, hi)) {
            *a += b;
        }
    }
    Ok(acc)
}

fn count<T: Voxel>(voxels: &[T], lo: f32, hi: f32) -> Vec<u64> {
    let threads = std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get);
    let chunk = voxels.len().div_ceil(threads).max(1 << 16);
    // A flat volume has one value: every voxel lands in the first bin.
    let scale = if hi > lo {
        HISTOGRAM_BINS as f32 / (hi - lo)
    } else {
        0.0
    };
    let bin = |v: T| (((v.to_f32() - lo) * scale) as usize).min(HISTOGRAM_BINS - 1);
    std::thread::scope(|s| {
        let parts: Vec<_> = voxels
            .chunks(chunk)
            .map(|part| {
                s.spawn(move || {
                    let mut c = vec![0u64; HISTOGRAM_BINS];
                    for &v in part {
                        c[bin(v)] += 1;
                    }
                    c
                })
            })
            .collect();
        parts
            .into_iter()
            .fold(vec![0u64; HISTOGRAM_BINS], |mut acc, h| {
                // A counting thread cannot panic: its indices are clamped.
                for (a, b) in acc.iter_mut().zip(h.join().unwrap_or_default()) {
                    *a += b;
                }
                acc
            })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use pofvr::render::families;
    use pofvr::volume::phantom::Phantom;

    #[test]
    fn every_voxel_is_counted_once_in_the_bin_of_its_value_whatever_the_split() {
        let vol = Phantom::SheppLogan.generate(48);
        let expected: Vec<u64> = {
            let VoxelData::U8(x) = vol.data() else {
                panic!("the phantom is u8")
            };
            let mut c = vec![0u64; HISTOGRAM_BINS];
            let (lo, hi) = x
                .as_slice()
                .iter()
                .fold((255u8, 0u8), |(a, b), &v| (a.min(v), b.max(v)));
            for &v in x.as_slice() {
                let scale = HISTOGRAM_BINS as f32 / (f32::from(hi) - f32::from(lo));
                let i = ((f32::from(v) - f32::from(lo)) * scale) as usize;
                c[i.min(HISTOGRAM_BINS - 1)] += 1;
            }
            c
        };
        let scene = Scene::builder(vol, families::for_phantom(Phantom::SheppLogan))
            .build()
            .unwrap();
        let h = Histogram::of(&scene);
        assert_eq!(h.total, 48 * 48 * 48);
        assert_eq!(h.counts, expected);
        let r = scene.grid().value_range();
        assert_eq!(h.value_range, [r.min, r.max]);
    }

    #[test]
    fn a_budgeted_volume_is_counted_from_its_file_as_from_the_mapping() {
        let vol = Phantom::SheppLogan.generate_dims([40, 36, 50]);
        let dir = std::env::temp_dir().join(format!("pofvr-hist-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("v.raw");
        let VoxelData::U8(x) = vol.data() else {
            panic!("the phantom is u8")
        };
        std::fs::write(&path, x.as_slice()).unwrap();
        let mut spec = pofvr::volume::RawSpec::new(vol.dims(), pofvr::volume::DataType::U8);
        spec.spacing = vol.spacing();
        let tf = families::for_phantom(Phantom::SheppLogan);
        let open = || pofvr::volume::raw::open(&path, &spec).unwrap();
        let whole = Scene::builder(open(), tf.clone()).build().unwrap();
        // 8 KiB: slabs of a plane at a time.
        let budgeted = Scene::builder(open(), tf)
            .memory_budget(Some(8 << 10))
            .build()
            .unwrap();
        assert!(budgeted.store().is_some_and(|s| s.source().is_file()));
        let (a, b) = (Histogram::of(&whole), Histogram::of(&budgeted));
        assert_eq!(b.total, vol.dims().iter().product::<usize>() as u64);
        assert_eq!(a, b);
        // The file cut short: no counts, not wrong ones.
        std::fs::write(&path, [0u8; 10]).unwrap();
        assert_eq!(Histogram::of(&budgeted).total, 0);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
