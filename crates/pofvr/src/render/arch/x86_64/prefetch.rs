//! Software prefetch for the march engine's packet loops, on volumes larger than the
//! last-level cache.
//!
//! A packet step waits on its corners' cache lines. A ray that moves mostly along y or z
//! crosses into a new row or slice every sample or two, a stride of a whole row or slice
//! (512 KB on a 512² i16 slice) that no hardware prefetcher follows; and the loop cannot
//! run ahead by itself, since whether a lane samples again depends on the opacity the
//! step's loads give. So where the voxels come from DRAM, each step's misses are the
//! step's latency. The loops therefore ask, every step, for the two cache lines their
//! sampling lanes will read [`AHEAD_VOXELS`] further along the ray: the word at that
//! corner and the one across the cell in the other axis than the ray's. Where the voxels
//! fit the cache the loads hit anyway and the prefetches are only instructions, so they
//! are issued only above the cache's size ([`pays`]). Measured in
//! `docs/results.md` ("Stop 37").

use std::sync::OnceLock;

use crate::render::lattice::IndexRay;

/// How far ahead of a lane's sample, in voxels along the ray's main axis, its lines are
/// asked for. One voxel is too close on oblique views (the lines arrive after the
/// sample), four too far (they are gone again from L1 or never used).
pub(crate) const AHEAD_VOXELS: f32 = 2.0;

/// Whether the packet loops prefetch for a volume of `voxel_bytes`: above the cache one
/// core can count on ([`core_cache_bytes`]), or as `POFVR_PREFETCH` says (`on`, `off`;
/// anything else: by size).
pub(crate) fn pays(voxel_bytes: usize) -> bool {
    match std::env::var("POFVR_PREFETCH").as_deref() {
        Ok(s) if s.eq_ignore_ascii_case("on") => true,
        Ok(s) if s.eq_ignore_ascii_case("off") => false,
        _ => voxel_bytes > core_cache_bytes(),
    }
}

/// The cache one core can count on holding the voxels, in bytes: the highest-level cache
/// Linux lists for CPU 0, at most [`DIE_CACHE_CAP`], or that cap where none is listed.
pub(crate) fn core_cache_bytes() -> usize {
    static BYTES: OnceLock<usize> = OnceLock::new();
    *BYTES.get_or_init(|| {
        read_llc("/sys/devices/system/cpu/cpu0/cache")
            .map_or(DIE_CACHE_CAP, |b| b.min(DIE_CACHE_CAP))
    })
}

/// 32 MiB, one die's L3 on current server parts. The capped figure matters: on
/// multi-die CPUs and under hypervisors Linux may list the L3 of every die together
/// (480 MiB on the development VM, whose cores each reach 32 MiB), while a volume of
/// 35 MB (`ch2better_mri`) or 151 MB already gains from prefetching there, and one of
/// 8.7 MB (`lidc2_ct_chest`, in cache) loses 3–5 % (`docs/results.md`, stop 37).
pub(crate) const DIE_CACHE_CAP: usize = 32 << 20;

/// The size of the highest-level data or unified cache under `dir` (sysfs `index*`
/// folders with `level`, `type` and `size` such as `32768K`).
fn read_llc(dir: &str) -> Option<usize> {
    let mut best: Option<(u32, usize)> = None;
    for e in std::fs::read_dir(dir).ok()?.flatten() {
        let p = e.path();
        let read = |f: &str| std::fs::read_to_string(p.join(f)).ok();
        let (Some(level), Some(kind), Some(size)) = (read("level"), read("type"), read("size"))
        else {
            continue;
        };
        if kind.trim() == "Instruction" {
            continue;
        }
        let (Ok(level), Some(bytes)) = (level.trim().parse::<u32>(), parse_size(size.trim()))
        else {
            continue;
        };
        if best.is_none_or(|(l, _)| level > l) {
            best = Some((level, bytes));
        }
    }
    best.map(|(_, b)| b)
}

/// `32768K`, `1M`, `512` (bytes) as bytes.
fn parse_size(s: &str) -> Option<usize> {
    let (num, unit) = match s.as_bytes().last()? {
        b'K' | b'k' => (&s[..s.len() - 1], 1 << 10),
        b'M' | b'm' => (&s[..s.len() - 1], 1 << 20),
        b'G' | b'g' => (&s[..s.len() - 1], 1 << 30),
        _ => (s, 1),
    };
    num.parse::<usize>().ok()?.checked_mul(unit)
}

/// For a packet's `rays` through voxels of element strides `step`: each lane's [`ahead`]
/// offset, and the packet's [`across`] offset, from the direction of its ray `lead` (a
/// lane with a ray; a packet's rays are nearly parallel).
pub(crate) fn offsets<const N: usize>(
    rays: &[IndexRay; N],
    lead: usize,
    step: [usize; 3],
) -> ([i32; N], usize) {
    let off = std::array::from_fn(|j| ahead(rays[j].d, step));
    (off, across(rays[lead].d, step[1], step[2]))
}

/// The element offset, for a ray of index-space direction `d` through voxels of element
/// strides `strides`, from a sample's corner to the corner [`AHEAD_VOXELS`] along the ray's
/// main axis (each axis rounded to whole voxels); 0 for a ray with no direction.
fn ahead(d: [f32; 3], strides: [usize; 3]) -> i32 {
    let m = d.iter().fold(0f32, |m, x| m.max(x.abs()));
    // `f32::max` drops NaN, so `m` is at least 0.
    if m == 0.0 || !m.is_finite() {
        return 0;
    }
    let off: i64 = (0..3)
        .map(|a| (d[a] / m * AHEAD_VOXELS).round() as i64 * strides[a] as i64)
        .sum();
    off.clamp(i32::MIN.into(), i32::MAX.into()) as i32
}

/// The second line a cell's corners lie on, as an element offset from the first, for
/// a ray of direction `d`: the cell's next row (`sy`) unless the ray moves mostly along y,
/// whose rows it walks anyway, then its next slice (`sz`).
fn across(d: [f32; 3], sy: usize, sz: usize) -> usize {
    let [x, y, z] = d.map(f32::abs);
    if y > x && y > z {
        sz
    } else {
        sy
    }
}

/// Asks for the lines at elements `at[j]` and `at[j] + across` of `v`, every lane.
///
/// Prefetches do not fault, so no offset needs to be inside `v`; the callers clamp them
/// anyway, so that the lines asked for are the volume's.
#[inline(always)]
pub(crate) fn lines<T, const N: usize>(v: &[T], at: &[i32; N], across: usize) {
    use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
    let p = v.as_ptr();
    for &x in at {
        let q = p.wrapping_add(x as u32 as usize);
        // SAFETY: `prefetcht0` reads nothing architecturally and never faults (SSE, part
        // of the x86_64 baseline).
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(q.cast());
            _mm_prefetch::<_MM_HINT_T0>(q.wrapping_add(across).cast());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_as_sysfs_writes_them() {
        assert_eq!(parse_size("32768K"), Some(32 << 20));
        assert_eq!(parse_size("1M"), Some(1 << 20));
        assert_eq!(parse_size("512"), Some(512));
        assert_eq!(parse_size("K"), None);
        assert_eq!(parse_size("x1K"), None);
        assert_eq!(parse_size(""), None);
    }

    #[test]
    fn the_last_level_is_the_highest_data_cache() {
        let dir = std::env::temp_dir().join(format!("pofvr-llc-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        for (i, (level, kind, size)) in [
            (1, "Data", "32K"),
            (1, "Instruction", "32K"),
            (2, "Unified", "1024K"),
            (3, "Unified", "32768K"),
            (4, "Instruction", "64M"),
        ]
        .into_iter()
        .enumerate()
        {
            let d = dir.join(format!("index{i}"));
            std::fs::create_dir_all(&d).unwrap();
            std::fs::write(d.join("level"), format!("{level}\n")).unwrap();
            std::fs::write(d.join("type"), format!("{kind}\n")).unwrap();
            std::fs::write(d.join("size"), format!("{size}\n")).unwrap();
        }
        assert_eq!(read_llc(dir.to_str().unwrap()), Some(32 << 20));
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(read_llc("/nonexistent/pofvr"), None);
        assert!(core_cache_bytes() > 0 && core_cache_bytes() <= DIE_CACHE_CAP);
    }

    #[test]
    fn ahead_follows_the_main_axis() {
        let s = [1, 512, 512 * 512];
        // Along z, two slices on; backwards, two back.
        assert_eq!(ahead([0.0, 0.0, 0.8], s), 2 * 512 * 512);
        assert_eq!(ahead([0.0, 0.0, -0.8], s), -2 * 512 * 512);
        // Oblique: z the main axis, x a quarter of it (half a voxel in two rounds up).
        assert_eq!(ahead([0.25, -0.1, 1.0], s), 1 + 2 * 512 * 512);
        assert_eq!(ahead([0.0; 3], s), 0);
        assert_eq!(ahead([f32::NAN, 0.0, 0.0], s), 0);
        assert_eq!(across([0.1, 0.9, 0.2], 512, 512 * 512), 512 * 512);
        assert_eq!(across([0.1, 0.2, 0.9], 512, 512 * 512), 512);
        assert_eq!(across([0.9, 0.2, 0.1], 512, 512 * 512), 512);
    }
}
