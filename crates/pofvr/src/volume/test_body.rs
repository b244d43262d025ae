//! The body phantom: grid, determinism and the Hounsfield units of its tissues.

use super::body::{hu, landmark, position, spacing};
use super::phantom::Phantom;
use super::{DataType, Volume};

/// The voxel nearest to the patient-frame point `p` (mm).
fn voxel_at(dims: [usize; 3], p: [f64; 3]) -> [usize; 3] {
    let s = spacing(dims);
    let i = (p[0] / s[0] + (dims[0] as f64 - 1.0) * 0.5).round() as usize;
    let j = (p[1] / s[1] + (dims[1] as f64 - 1.0) * 0.5).round() as usize;
    let k = (p[2] / s[2] - 0.5).round() as usize;
    [i, j, k]
}

/// The median of the 3×3×3 voxels around `p`: the tissue there, without the noise.
fn median_at(v: &Volume, p: [f64; 3]) -> f32 {
    let [i, j, k] = voxel_at(v.dims(), p);
    let mut vals = Vec::new();
    for dk in 0..3 {
        for dj in 0..3 {
            for di in 0..3 {
                vals.push(v.value(i + di - 1, j + dj - 1, k + dk - 1));
            }
        }
    }
    vals.sort_by(f32::total_cmp);
    vals[13]
}

#[test]
fn body_takes_any_grid_in_millimetres() {
    let v = Phantom::Body.generate_dims([40, 32, 70]);
    assert_eq!(v.dims(), [40, 32, 70]);
    assert_eq!(v.data_type(), DataType::I16);
    assert_eq!(v.spacing(), [10.0, 10.0, 10.0]);
    let w = Phantom::Body.generate_dims([64, 64, 350]);
    assert_eq!(w.spacing(), [6.25, 6.25, 2.0]);
    // The grid's centre is the patient frame's x = y = 0 and the slices tile 0..700 mm.
    assert_eq!(position([64, 64, 350], [0, 0, 0])[2], 1.0);
    let c = position([65, 65, 350], [32, 32, 349]);
    assert_eq!([c[0], c[1], c[2]], [0.0, 0.0, 699.0]);
    // A cube request gives a cube grid.
    assert_eq!(Phantom::Body.generate(24).dims(), [24; 3]);
}

#[test]
fn body_is_deterministic_and_independent_of_threads() {
    let dims = [48, 40, 84];
    let a = Phantom::Body.generate_dims(dims);
    let b = Phantom::Body.generate_dims(dims);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| Phantom::Body.generate_dims(dims));
    let (a, b, one) = (a.data(), b.data(), one.data());
    let slice = |d: &super::VoxelData| match d {
        super::VoxelData::I16(x) => x.as_slice().to_vec(),
        _ => panic!("body phantom must be i16"),
    };
    assert_eq!(slice(a), slice(b));
    assert_eq!(slice(a), slice(one));
    // Seeded noise: neighbouring air voxels differ, but only by a few HU.
    let s = slice(a);
    assert_ne!(s[0], s[1]);
    assert!(s[..40].iter().all(|x| (*x as f64 - hu::AIR).abs() < 25.0));
}

#[test]
fn body_tissues_have_their_hounsfield_units() {
    let v = Phantom::Body.generate_dims([128, 128, 224]);
    let within = |name: &str, p: [f64; 3], lo: f64, hi: f64| {
        let m = f64::from(median_at(&v, p));
        assert!(
            (lo..=hi).contains(&m),
            "{name} at {p:?} mm: median {m} HU, expected {lo}..={hi}"
        );
    };
    within("air", landmark::AIR, -1010.0, -990.0);
    within("lung", landmark::LUNG, -900.0, -700.0);
    within("fat", landmark::FAT, -130.0, -40.0);
    within("liver", landmark::LIVER, 40.0, 80.0);
    within("heart", landmark::HEART, 30.0, 60.0);
    within("vertebral body", landmark::VERTEBRA, 200.0, 1200.0);
    // The value range spans air to cortical bone, and bone is a small share of the voxels.
    let (mut lo, mut hi, mut bone, mut air) = (f32::MAX, f32::MIN, 0usize, 0usize);
    let n = v.dims().iter().product::<usize>();
    for k in 0..v.dims()[2] {
        for j in 0..v.dims()[1] {
            for i in 0..v.dims()[0] {
                let x = v.value(i, j, k);
                lo = lo.min(x);
                hi = hi.max(x);
                bone += usize::from(x > 300.0);
                air += usize::from(x < -950.0);
            }
        }
    }
    assert!((-1024.0..-990.0).contains(&lo), "min {lo}");
    assert!(hi > 600.0 && hi <= 3071.0, "max {hi}");
    let (bone, air) = (bone as f64 / n as f64, air as f64 / n as f64);
    assert!((0.002..0.05).contains(&bone), "bone share {bone}");
    assert!((0.3..0.8).contains(&air), "air share {air}");
}
