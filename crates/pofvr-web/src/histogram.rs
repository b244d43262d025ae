//! The volume's value histogram that the page's transfer-function panel draws under the
//! opacity curves: counted once, over the bricks' value range, in parallel.

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
    /// value range, splitting the voxels among the machine's cores.
    #[must_use]
    pub fn of(scene: &Scene) -> Histogram {
        let range = scene.grid().value_range();
        let (lo, hi) = (range.min, range.max);
        let counts = match scene.volume().data() {
            VoxelData::U8(x) => count(x.as_slice(), lo, hi),
            VoxelData::U16(x) => count(x.as_slice(), lo, hi),
            VoxelData::I16(x) => count(x.as_slice(), lo, hi),
            VoxelData::F32(x) => count(x.as_slice(), lo, hi),
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
}
