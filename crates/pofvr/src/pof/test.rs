use glam::DVec3;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::reference::{core_min, ReferenceProbe};
use super::view_grid::{border_cells, cell_of};
use super::*;
use crate::brick::{BrickGrid, BrickId};
use crate::render::families;
use crate::render::{SampledTf, TransferFunction};
use crate::volume::phantom::Phantom;
use crate::volume::{Volume, VoxelData, Voxels};

fn seeded_rng() -> StdRng {
    StdRng::seed_from_u64(0x0b0f_5eed)
}

fn random_dir(rng: &mut StdRng) -> DVec3 {
    loop {
        let v = DVec3::new(
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
        );
        let l = v.length();
        if l > 0.1 && l <= 1.0 {
            return v / l;
        }
    }
}

fn no_progress(_: u64, _: u64) {}

struct Scene {
    volume: Volume,
    grid: BrickGrid,
    tf: TransferFunction,
    sampled: SampledTf,
}

fn scene(volume: Volume, tf: TransferFunction) -> Scene {
    let grid = BrickGrid::from_volume(&volume, 16).unwrap();
    let sampled = SampledTf::new(&tf, grid.value_range());
    Scene {
        volume,
        grid,
        tf,
        sampled,
    }
}

fn phantom(n: usize) -> Scene {
    scene(
        Phantom::SheppLogan.generate(n),
        families::for_phantom(Phantom::SheppLogan),
    )
}

fn table(s: &Scene, settings: &PofSettings) -> PofTable {
    PofTable::build(
        &s.volume,
        &s.grid,
        &s.tf,
        &s.sampled,
        settings,
        &no_progress,
    )
    .unwrap()
}

fn small_views() -> PofSettings {
    small_views_for(PofMethod::Bound)
}

fn small_views_for(method: PofMethod) -> PofSettings {
    PofSettings {
        views: [12, 12],
        ..PofSettings::for_method(method)
    }
}

fn probe(rng: &mut StdRng, dir: DVec3) -> ReferenceProbe {
    ReferenceProbe {
        dir,
        phase: rng.gen_range(0.0..1.0),
        jitter: [rng.gen_range(0.0..1.0), rng.gen_range(0.0..1.0)],
        pixel: 0.5,
    }
}

fn od(a: f32) -> f64 {
    -(1.0 - f64::from(a)).ln()
}

/// One basis with a constant alpha per unit step over every value.
fn constant_tf(alpha: f32) -> TransferFunction {
    TransferFunction::from_json(
        &format!(r#"{{"bases":[{{"name":"c","opacity":[[0,{alpha}],[255,{alpha}]]}}],"color":[[0,1,1,1]]}}"#),
        "test",
    )
    .unwrap()
}

#[test]
fn dense_uniform_brick_matches_the_analytic_shortest_core_chord() {
    let n = 33;
    let volume = Volume::new(
        [n; 3],
        [1.0; 3],
        VoxelData::U8(Voxels::owned(vec![100u8; n * n * n])),
        "uniform",
    )
    .unwrap();
    let s = scene(volume, constant_tf(0.05));
    let t = table(
        &s,
        &PofSettings {
            views: [8, 8],
            ..PofSettings::default()
        },
    );
    let tau = -(0.95f64).ln();
    let l = f64::from(t.core_length());
    assert!((l - 8.0).abs() < 1e-6, "L defaults to half a brick");
    // The shortest core chord is L = 8 long and holds 8 samples (7 when the f32 span lands
    // a hair short): analytic 1 − exp(−τ·ℓ).
    let analytic_hi = 1.0 - (-tau * l).exp();
    let analytic_lo_od = tau * (l - 1.0);
    let mut rng = seeded_rng();
    for id in s.grid.ids() {
        for i in 0..8 {
            for j in 0..8 {
                let theta = (f64::from(i) + 0.5) / 8.0 * std::f64::consts::PI;
                let phi = (f64::from(j) + 0.5) / 8.0 * std::f64::consts::TAU;
                let a = t.opacity(id, direction(theta, phi), &[1.0], PofMode::Conservative);
                assert!(
                    f64::from(a) <= analytic_hi + 1e-6,
                    "brick {id:?} cell {i},{j}: {a} above analytic {analytic_hi}"
                );
                assert!(
                    od(a) >= 0.9 * analytic_lo_od - 1e-4,
                    "brick {id:?} cell {i},{j}: {a} too far below (od {})",
                    od(a)
                );
            }
        }
    }
    // And the brute force sees the same shortest chord.
    for _ in 0..6 {
        let id = BrickId(rng.gen_range(0..8));
        let dir = random_dir(&mut rng);
        let r = core_min(
            &s.volume,
            &s.grid,
            &s.sampled,
            id,
            &[1.0],
            1.0,
            0.99,
            t.core_length(),
            &probe(&mut rng, dir),
        );
        let m = r.core_min.unwrap();
        let a = t.opacity(id, dir, &[1.0], PofMode::Conservative);
        assert!(a <= m, "lookup {a} above brute force {m}");
        assert!(
            od(m) >= tau * (l - 1.0) - 1e-4 && od(m) <= tau * (l + 8.0),
            "brute force {m}"
        );
    }
}

/// The brute-force core minimum of brick `id` with weights `w`, at the table's step,
/// early-termination threshold and core length.
fn brute_force(
    s: &Scene,
    t: &PofTable,
    id: BrickId,
    w: &[f32],
    pr: &ReferenceProbe,
) -> super::reference::ReferenceView {
    core_min(
        &s.volume,
        &s.grid,
        &s.sampled,
        id,
        w,
        t.step(),
        t.ert(),
        t.core_length(),
        pr,
    )
}

fn check_conservative(
    s: &Scene,
    t: &PofTable,
    cases: usize,
    rng: &mut StdRng,
    weights: &dyn Fn(&mut StdRng) -> Vec<f32>,
) -> (usize, f64) {
    let stored: Vec<BrickId> = s.grid.ids().filter(|id| t.slot(*id).is_some()).collect();
    assert!(!stored.is_empty());
    let (mut compared, mut ratio) = (0, 0.0);
    for _ in 0..cases {
        let id = stored[rng.gen_range(0..stored.len())];
        let dir = random_dir(rng);
        let w = weights(rng);
        let pr = probe(rng, dir);
        let r = brute_force(s, t, id, &w, &pr);
        let Some(m) = r.core_min else { continue };
        let a = t.opacity(id, dir, &w, PofMode::Conservative);
        assert!(
            a <= m + 1e-6,
            "{:?}: brick {id:?} dir {dir:?} weights {w:?}: lookup {a} > brute force {m}",
            t.meta().encoding
        );
        compared += 1;
        if m > 0.0 {
            ratio += od(a) / od(m);
        }
    }
    (compared, ratio / compared.max(1) as f64)
}

#[test]
fn lookup_never_exceeds_brute_force_for_random_directions_in_every_encoding() {
    let s = phantom(64);
    let mut rng = seeded_rng();
    for enc in Encoding::ALL {
        let t = table(
            &s,
            &PofSettings {
                encoding: enc,
                ..small_views()
            },
        );
        for basis in 0..2 {
            let (n, ratio) = check_conservative(&s, &t, 25, &mut rng, &|_| {
                if basis == 0 {
                    vec![1.0, 0.0]
                } else {
                    vec![0.0, 1.0]
                }
            });
            eprintln!("{enc}: basis {basis}: {n} views compared, mean lookup/brute-force optical depth {ratio:.3}");
            assert!(n > 5);
        }
    }
}

#[test]
fn conservative_mode_never_exceeds_brute_force_for_random_weights() {
    let s = phantom(64);
    let t = table(&s, &small_views());
    let mut rng = seeded_rng();
    let (n, ratio) = check_conservative(&s, &t, 60, &mut rng, &|r| {
        vec![r.gen_range(0.0..3.0), r.gen_range(0.0..3.0)]
    });
    eprintln!("random weights: {n} views, mean lookup/brute-force optical depth {ratio:.3}");
    assert!(n > 20);
    // The bound must be useful, not just ≤: on average it keeps a share of the depth
    // (thin shells and ventricle edges erode to 0, so the share is well below 1).
    assert!(ratio > 0.15, "mean ratio {ratio}");
}

#[test]
fn eq3_is_exact_for_one_basis() {
    eq3_is_exact_for_one_basis_with(PofMethod::Bound);
}

#[test]
fn eq3_is_exact_for_one_basis_sampled() {
    eq3_is_exact_for_one_basis_with(PofMethod::Sampled);
}

fn eq3_is_exact_for_one_basis_with(method: PofMethod) {
    let settings = small_views_for(method);
    // Step-shaped bases make the tabulated extinction exactly −ln(1−α) per level, so a
    // family built for k·τ is the same family as τ with weight k.
    let fam = |a: f64, b: f64| {
        TransferFunction::from_json(
            &format!(r#"{{"bases":[{{"name":"b","opacity":[[0,0],[40,0],[40,{a}],[90,{a}],[90,{b}],[255,{b}]]}}],"color":[[0,1,1,1]]}}"#),
            "test",
        )
        .unwrap()
    };
    // Every voxel is non-empty and the field varies, so the POFs differ from brick to brick.
    let n = 49;
    let vol = || {
        let v: Vec<u8> = (0..n * n * n)
            .map(|i| {
                let (x, y, z) = (i % n, (i / n) % n, i / (n * n));
                u8::try_from(41 + (x * 7 + y * 13 + z * 5 + (x * y) % 11) % 80).unwrap()
            })
            .collect();
        Volume::new([n; 3], [1.0; 3], VoxelData::U8(Voxels::owned(v)), "varied").unwrap()
    };
    let (a, b) = (0.03f64, 0.08f64);
    let base = scene(vol(), fam(a, b));
    let t1 = table(&base, &settings);
    for k in [0.5f32, 2.0, 3.5] {
        let kf = f64::from(k);
        let scaled = scene(
            vol(),
            fam(1.0 - (1.0 - a).powf(kf), 1.0 - (1.0 - b).powf(kf)),
        );
        let tk = table(&scaled, &settings);
        let mut rng = seeded_rng();
        let mut nonzero = 0;
        for _ in 0..300 {
            let id = BrickId(rng.gen_range(0..base.grid.len() as u32));
            let dir = random_dir(&mut rng);
            let a = t1.opacity(id, dir, &[k], PofMode::Conservative);
            let b = tk.opacity(id, dir, &[1.0], PofMode::Conservative);
            assert!(
                (a - b).abs() <= 2e-4 * b.max(1e-3),
                "{method}: k={k}: τ with weight k gives {a}, kτ gives {b}"
            );
            if b > 0.0 {
                nonzero += 1;
            }
        }
        assert!(
            nonzero > 250,
            "too few non-zero POFs ({nonzero}) to test anything"
        );
    }
}

#[test]
fn sets_are_never_below_conservative_mode() {
    sets_are_never_below_conservative_mode_with(PofMethod::Bound);
}

#[test]
fn sampled_sets_are_never_below_conservative_mode() {
    sets_are_never_below_conservative_mode_with(PofMethod::Sampled);
}

fn sets_are_never_below_conservative_mode_with(method: PofMethod) {
    let s = phantom(64);
    for enc in [Encoding::Table, Encoding::Cubic, Encoding::U8] {
        let t = table(
            &s,
            &PofSettings {
                sets: true,
                encoding: enc,
                ..small_views_for(method)
            },
        );
        assert!(t.has_sets());
        let mut rng = seeded_rng();
        let mut higher = 0;
        for _ in 0..400 {
            let id = BrickId(rng.gen_range(0..s.grid.len() as u32));
            let dir = random_dir(&mut rng);
            let w = [rng.gen_range(0.0..2.0), rng.gen_range(0.0..2.0)];
            let c = t.opacity(id, dir, &w, PofMode::Conservative);
            let a = t.opacity(id, dir, &w, PofMode::Sets);
            assert!(a >= c, "{method} {enc}: sets {a} below conservative {c}");
            if a > c {
                higher += 1;
            }
            let axis = random_dir(&mut rng);
            let cc = t.opacity_cone(id, axis, 0.2, &w, PofMode::Conservative);
            let ca = t.opacity_cone(id, axis, 0.2, &w, PofMode::Sets);
            assert!(ca >= cc);
        }
        eprintln!("{method} {enc}: sets above conservative in {higher}/400 lookups");
    }
}

#[test]
fn cone_lookup_is_the_minimum_over_the_cone() {
    let s = phantom(64);
    let t = table(&s, &small_views());
    let mut rng = seeded_rng();
    for _ in 0..300 {
        let id = BrickId(rng.gen_range(0..s.grid.len() as u32));
        let axis = random_dir(&mut rng);
        let w = [1.0, 1.0];
        let cone = t.opacity_cone(id, axis, 0.15, &w, PofMode::Conservative);
        assert!(cone <= t.opacity(id, axis, &w, PofMode::Conservative));
        assert_eq!(
            t.opacity_cone(id, axis, 0.0, &w, PofMode::Conservative),
            t.opacity(id, axis, &w, PofMode::Conservative)
        );
        // Any direction inside the cone is looked up at least as high as the cone.
        let off = (axis + random_dir(&mut rng) * 0.1).normalize();
        if off.angle_between(axis) < 0.15 {
            assert!(t.opacity(id, off, &w, PofMode::Conservative) >= cone);
        }
    }
}

#[test]
fn encodings_never_exceed_the_table() {
    let s = phantom(48);
    let t = table(&s, &small_views());
    for enc in [Encoding::U8, Encoding::U16, Encoding::Cubic] {
        let e = table(
            &s,
            &PofSettings {
                encoding: enc,
                ..small_views()
            },
        );
        let mut worst = 0f32;
        for id in s.grid.ids() {
            for i in 0..12 {
                for j in 0..12 {
                    let a = t.basis_opacities(id, (i, j));
                    let b = e.basis_opacities(id, (i, j));
                    for (x, y) in a.iter().zip(&b) {
                        assert!(y <= x, "{enc}: {y} above table {x}");
                        worst = worst.max(x - y);
                    }
                }
            }
        }
        eprintln!(
            "{enc}: largest loss against the f32 table {worst:.4}, {} bytes per brick per basis",
            e.bytes_per_brick_per_basis()
        );
    }
}

#[test]
fn file_round_trip_keeps_every_value() {
    let s = phantom(48);
    let t = table(
        &s,
        &PofSettings {
            sets: true,
            encoding: Encoding::U16,
            ..small_views()
        },
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("head.pof");
    t.save(&path).unwrap();
    let back = PofTable::load(&path, &s.volume, &s.grid, &s.tf).unwrap();
    assert_eq!(back.meta(), t.meta());
    let mut rng = seeded_rng();
    for _ in 0..500 {
        let id = BrickId(rng.gen_range(0..s.grid.len() as u32));
        let d = random_dir(&mut rng);
        for mode in [PofMode::Conservative, PofMode::Sets] {
            assert_eq!(
                back.opacity(id, d, &[0.7, 1.3], mode),
                t.opacity(id, d, &[0.7, 1.3], mode)
            );
        }
    }
}

#[test]
fn corrupted_or_mismatched_files_are_rejected_with_a_clear_message() {
    let s = phantom(48);
    // Version 1 had no joint POF.
    let t = table(
        &s,
        &PofSettings {
            joint: false,
            ..small_views()
        },
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("head.pof");
    t.save(&path).unwrap();
    let good = std::fs::read(&path).unwrap();
    let data_at = usize::try_from(u64::from_le_bytes(good[120..128].try_into().unwrap())).unwrap();
    let cases: [(&str, usize, &str); 5] = [
        ("header field", 20, "header section is corrupted"),
        ("stored index CRC", 145, "header section is corrupted"),
        (
            "brick index",
            file::HEADER_LEN + 1,
            "brick index section is corrupted",
        ),
        ("POF data", data_at + 3, "POF data section is corrupted"),
        ("magic", 0, "not a .pof file"),
    ];
    for (what, at, msg) in cases {
        let mut bad = good.clone();
        bad[at] ^= 0x5a;
        let p = dir.path().join(format!("bad-{at}.pof"));
        std::fs::write(&p, &bad).unwrap();
        let e = PofTable::load(&p, &s.volume, &s.grid, &s.tf)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(msg) && e.contains(&p.display().to_string()),
            "{what}: {e}"
        );
    }
    let p = dir.path().join("short.pof");
    std::fs::write(&p, &good[..good.len() - 9]).unwrap();
    let e = PofTable::load(&p, &s.volume, &s.grid, &s.tf)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("short.pof") && e.contains("not a valid POF file"),
        "{e}"
    );

    let other = phantom(40);
    let e = PofTable::load(&path, &other.volume, &other.grid, &other.tf)
        .unwrap_err()
        .to_string();
    assert!(e.contains("head.pof") && e.contains("volume size"), "{e}");
    let mut tf = s.tf.clone();
    tf.bases[1].opacity[1][1] = 0.5;
    let e = PofTable::load(&path, &s.volume, &s.grid, &tf)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("head.pof") && e.contains("transfer-function family"),
        "{e}"
    );
    // Weights are free at run time.
    tf = s.tf.clone();
    tf.weights = vec![3.0, 0.1];
    PofTable::load(&path, &s.volume, &s.grid, &tf).unwrap();
    let grid8 = BrickGrid::from_volume(&s.volume, 8).unwrap();
    let e = PofTable::load(&path, &s.volume, &grid8, &s.tf)
        .unwrap_err()
        .to_string();
    assert!(e.contains("brick size"), "{e}");
}

#[test]
fn interrupted_build_resumes_from_the_partial_file() {
    let s = phantom(48);
    let dir = tempfile::tempdir().unwrap();
    let partial = dir.path().join("head.pof.partial");
    let settings = small_views();
    let first = PofTable::build_resumable(
        &s.volume,
        &s.grid,
        &s.tf,
        &s.sampled,
        &settings,
        Some(&partial),
        &no_progress,
    )
    .unwrap();
    // Tear the last entry, as a kill during a write would.
    let len = std::fs::metadata(&partial).unwrap().len();
    let f = std::fs::OpenOptions::new()
        .write(true)
        .open(&partial)
        .unwrap();
    f.set_len(len - 7).unwrap();
    drop(f);
    let starts = std::sync::Mutex::new(Vec::new());
    let second = PofTable::build_resumable(
        &s.volume,
        &s.grid,
        &s.tf,
        &s.sampled,
        &settings,
        Some(&partial),
        &|d, t| {
            starts.lock().unwrap().push((d, t));
        },
    )
    .unwrap();
    let starts = starts.into_inner().unwrap();
    let (d0, total) = starts[0];
    assert_eq!(d0 + 1, total, "all but the torn brick were resumed");
    assert_eq!(first.bytes.as_slice(), second.bytes.as_slice());
    // A partial file from a different build is ignored, not trusted.
    let other = PofSettings {
        views: [10, 10],
        ..small_views()
    };
    let third = PofTable::build_resumable(
        &s.volume,
        &s.grid,
        &s.tf,
        &s.sampled,
        &other,
        Some(&partial),
        &no_progress,
    )
    .unwrap();
    assert_eq!(third.meta().views, [10, 10]);
}

/// The folder of real volumes: `$POFVR_DATA` if set, else `../shared/data` beside the
/// workspace.
fn data_dir() -> std::path::PathBuf {
    std::env::var_os("POFVR_DATA").map_or_else(
        || std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
        std::path::PathBuf::from,
    )
}

#[test]
#[ignore = "needs ../shared/data (real volumes)"]
fn real_anisotropic_ct_lookups_never_exceed_brute_force() {
    // The catalogue's quarter-resolution CT head (i16, spacing 3.2×3.2×1.5 mm), the case
    // where index and world directions differ.
    let path = data_dir().join("headsq_quarter/headsq_quarter_64x64x93_int16.raw");
    assert!(
        path.exists(),
        "needs real data: {} is not present (set POFVR_DATA to the folder of real volumes, \
         or leave this test ignored)",
        path.display()
    );
    let mut spec = crate::volume::RawSpec::new([64, 64, 93], crate::volume::DataType::I16);
    spec.spacing = [3.2, 3.2, 1.5];
    let volume = crate::volume::raw::open(&path, &spec).unwrap();
    let tf = TransferFunction::from_json(
        r#"{"bases":[{"name":"head","opacity":[[300,0],[500,0.05],[4000,0.05]]},
                     {"name":"bone","opacity":[[1400,0],[1800,0.3],[4000,0.3]]}],
            "color":[[0,0,0,0],[4000,1,1,1]]}"#,
        "test",
    )
    .unwrap();
    let s = scene(volume, tf);
    let t = table(&s, &small_views());
    assert!(
        t.stored_bricks() > 5,
        "{} bricks with a POF",
        t.stored_bricks()
    );
    let mut rng = seeded_rng();
    let (n, ratio) = check_conservative(&s, &t, 60, &mut rng, &|r| {
        vec![r.gen_range(0.0..2.0), r.gen_range(0.0..2.0)]
    });
    eprintln!("headsq: {n} views, mean lookup/brute-force optical depth {ratio:.3}");
    assert!(n > 40);
}

#[test]
fn sampled_lookup_never_exceeds_brute_force_in_every_encoding() {
    let s = phantom(64);
    let mut rng = seeded_rng();
    for enc in Encoding::ALL {
        let t = table(
            &s,
            &PofSettings {
                encoding: enc,
                ..small_views_for(PofMethod::Sampled)
            },
        );
        assert_eq!(t.meta().method, PofMethod::Sampled);
        for basis in 0..2 {
            let (n, ratio) = check_conservative(&s, &t, 40, &mut rng, &|_| {
                if basis == 0 {
                    vec![1.0, 0.0]
                } else {
                    vec![0.0, 1.0]
                }
            });
            eprintln!("sampled {enc}: basis {basis}: {n} views compared, mean lookup/brute-force optical depth {ratio:.3}");
            assert!(n > 10);
        }
    }
    let t = table(&s, &small_views_for(PofMethod::Sampled));
    let (n, ratio) = check_conservative(&s, &t, 80, &mut rng, &|r| {
        vec![r.gen_range(0.0..3.0), r.gen_range(0.0..3.0)]
    });
    eprintln!(
        "sampled, random weights: {n} views, mean lookup/brute-force optical depth {ratio:.3}"
    );
    assert!(n > 30);
    // Measured, not bounded: it keeps well over the bound's share of the true depth (the
    // bound's test above asks for 0.15).
    assert!(ratio > 0.35, "mean ratio {ratio}");
}

#[test]
fn sampled_table_is_tighter_than_the_bound() {
    let s = phantom(64);
    let bound = table(&s, &small_views());
    let sampled = table(&s, &small_views_for(PofMethod::Sampled));
    let (mut sum_b, mut sum_s, mut cells, mut at_least, mut above) = (0f64, 0f64, 0, 0, 0);
    for id in s.grid.ids() {
        for i in 0..12 {
            for j in 0..12 {
                let b = bound.basis_opacities(id, (i, j));
                let a = sampled.basis_opacities(id, (i, j));
                for (x, y) in b.iter().zip(&a) {
                    if *x <= 0.0 && *y <= 0.0 {
                        continue;
                    }
                    sum_b += f64::from(*x);
                    sum_s += f64::from(*y);
                    cells += 1;
                    at_least += usize::from(y >= x);
                    above += usize::from(*y > 1.5 * *x);
                }
            }
        }
    }
    let share = at_least as f64 / cells as f64;
    eprintln!(
        "{cells} non-zero cells: mean bound {:.4}, mean sampled {:.4}; sampled ≥ bound in {:.1}%, > 1.5× in {above}",
        sum_b / f64::from(cells),
        sum_s / f64::from(cells),
        100.0 * share
    );
    // The sampled values are well above the bound on average (12×12 views: coarse cells
    // cost the sampled method more than the bound). Where the bound is already tight
    // (uniform material) the sampled method's smaller margin leaves it a little below, so
    // only most cells, not all, are at least the bound.
    assert!(cells > 500);
    assert!(sum_s >= 1.7 * sum_b, "sampled {sum_s} vs bound {sum_b}");
    assert!(share > 0.7, "sampled ≥ bound in only {share}");
}

#[test]
fn files_of_format_version_1_are_read_as_bound_and_unknown_versions_refused() {
    let s = phantom(48);
    // Version 1 had no joint POF.
    let t = table(
        &s,
        &PofSettings {
            joint: false,
            ..small_views()
        },
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("head.pof");
    // Versions before 4 laid records out function by function.
    let old = t.relayout(false);
    assert!(t.meta().cell_major && !old.meta().cell_major);
    old.save(&path).unwrap();
    let good = std::fs::read(&path).unwrap();
    let with = |version: u32| {
        let mut b = good.clone();
        b[8..12].copy_from_slice(&version.to_le_bytes());
        // Version 1 had zeros where the method and phases now are.
        b[43] = 0;
        b[152..156].copy_from_slice(&[0; 4]);
        let crc = crc32fast::hash(&b[..file::HEADER_LEN - 4]);
        b[file::HEADER_LEN - 4..file::HEADER_LEN].copy_from_slice(&crc.to_le_bytes());
        let p = dir.path().join(format!("v{version}.pof"));
        std::fs::write(&p, &b).unwrap();
        p
    };
    let v1 = PofTable::load(&with(1), &s.volume, &s.grid, &s.tf).unwrap();
    assert_eq!(v1.meta().method, PofMethod::Bound);
    let mut rng = seeded_rng();
    for _ in 0..100 {
        let id = BrickId(rng.gen_range(0..s.grid.len() as u32));
        let d = random_dir(&mut rng);
        assert_eq!(
            v1.opacity(id, d, &[1.0, 1.0], PofMode::Conservative),
            t.opacity(id, d, &[1.0, 1.0], PofMode::Conservative)
        );
    }
    let e = PofTable::open(&with(5)).unwrap_err().to_string();
    assert!(
        e.contains("v5.pof") && e.contains("format version 5"),
        "{e}"
    );
}

#[test]
fn joint_pof_lifts_lookups_and_stays_below_brute_force_for_any_weights() {
    // Two bands that overlap and take turns along the smooth Marschner–Lobb signal, as grey
    // and white matter do in an MRI (the head phantom's skin and bone bases leave a gap of
    // values between them, where no joint POF can help).
    let tf = TransferFunction::from_json(
        r#"{"bases": [
            {"name": "low", "opacity": [[0.2, 0.0], [0.35, 0.15], [0.6, 0.15], [0.7, 0.0]]},
            {"name": "high", "opacity": [[0.55, 0.0], [0.7, 0.3], [1.0, 0.3]]}],
          "weights": [1.0, 1.0], "color": [[0, 1, 1, 1], [1, 1, 1, 1]]}"#,
        "bands",
    )
    .unwrap();
    let s = scene(Phantom::MarschnerLobb.generate(48), tf);
    let anchor = s.tf.weights.clone();
    let with = table(&s, &small_views());
    let without = table(
        &s,
        &PofSettings {
            joint: false,
            ..small_views()
        },
    );
    assert_eq!(with.meta().joint.as_deref(), Some(anchor.as_slice()));
    assert_eq!(without.meta().joint, None);
    let mut rng = seeded_rng();
    let (mut lifted, mut n) = (0, 0);
    for _ in 0..400 {
        let id = BrickId(rng.gen_range(0..s.grid.len() as u32));
        let d = random_dir(&mut rng);
        let a = with.opacity(id, d, &anchor, PofMode::Conservative);
        let b = without.opacity(id, d, &anchor, PofMode::Conservative);
        assert!(
            a >= b,
            "brick {id:?}: joint lookup {a} below Eq. 3 alone {b}"
        );
        n += 1;
        lifted += usize::from(a > b + 1e-4);
    }
    eprintln!("joint POF lifted {lifted} of {n} lookups at the anchor weights");
    assert!(
        lifted * 10 > n,
        "the joint POF lifted only {lifted} of {n} lookups"
    );
    // Weights below, along and above the anchor, and lopsided ones (c < 1).
    let (cases, _) = check_conservative(&s, &with, 80, &mut rng, &|r| match r.gen_range(0..3) {
        0 => {
            let c = r.gen_range(0.2..3.0);
            anchor.iter().map(|a| a * c).collect()
        }
        1 => vec![r.gen_range(0.0..0.5), r.gen_range(1.0..4.0)],
        _ => vec![r.gen_range(0.0..3.0), r.gen_range(0.0..3.0)],
    });
    assert!(cases > 30);
    // The file keeps the anchor.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("joint.pof");
    with.save(&path).unwrap();
    let back = PofTable::load(&path, &s.volume, &s.grid, &s.tf).unwrap();
    assert_eq!(back.meta().joint, with.meta().joint);
    let d = random_dir(&mut rng);
    for id in s.grid.ids() {
        assert_eq!(
            back.opacity(id, d, &[0.7, 2.0], PofMode::Conservative),
            with.opacity(id, d, &[0.7, 2.0], PofMode::Conservative)
        );
    }
}

#[test]
fn both_record_layouts_give_the_same_lookups_in_every_encoding() {
    // Cell-major records (format 4) and function-major ones (formats 1 to 3) hold the same
    // values; a layout mix-up would read another function's or another cell's value.
    let s = phantom(64);
    let mut rng = seeded_rng();
    for encoding in Encoding::ALL {
        let t = table(
            &s,
            &PofSettings {
                encoding,
                sets: true,
                ..small_views()
            },
        );
        let old = t.relayout(false);
        let back = old.relayout(true);
        assert_eq!(t.meta().cell_major, encoding != Encoding::Cubic);
        assert!(!old.meta().cell_major);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("old.pof");
        old.save(&path).unwrap();
        let reread = PofTable::open(&path).unwrap();
        assert!(!reread.meta().cell_major);
        let mut differ = 0;
        for _ in 0..300 {
            let id = BrickId(rng.gen_range(0..s.grid.len() as u32));
            let d = random_dir(&mut rng);
            let w = [rng.gen_range(0.0..2.0f32), rng.gen_range(0.0..2.0f32)];
            for mode in [PofMode::Conservative, PofMode::Sets] {
                let a = t.opacity(id, d, &w, mode);
                assert_eq!(
                    a,
                    reread.opacity(id, d, &w, mode),
                    "{encoding} {id:?} {w:?}"
                );
                assert_eq!(a, back.opacity(id, d, &w, mode), "{encoding} {id:?} {w:?}");
            }
        }
        let v = t.meta().views;
        for id in s.grid.ids() {
            for cell in (0..v[0] as usize).flat_map(|i| (0..v[1] as usize).map(move |j| (i, j))) {
                let per_basis = t.basis_opacities(id, cell);
                assert_eq!(per_basis, reread.basis_opacities(id, cell), "{encoding}");
                differ += usize::from(per_basis[0] != per_basis[1]);
            }
        }
        // Bases that differ: a swap of functions would show.
        assert!(
            differ > 50,
            "{encoding}: bases differ in only {differ} cells"
        );
    }
}

#[test]
fn record_values_are_read_where_the_record_writer_put_them() {
    // Distinct values per function and cell: a reader that takes another function's or
    // another cell's value differs from the writer's.
    let views = [5u32, 7];
    let cells = 35;
    let funcs = 4;
    let tables: Vec<Vec<f32>> = (0..funcs)
        .map(|f| {
            (0..cells)
                .map(|c| (1 + f * cells + c) as f32 / 200.0)
                .collect()
        })
        .collect();
    for enc in Encoding::ALL {
        for cell_major in [false, true] {
            let mut rec = Vec::new();
            encoding::encode_record(enc, &tables, views, cell_major, &mut rec);
            assert_eq!(rec.len(), funcs * enc.function_bytes(views));
            for (f, t) in tables.iter().enumerate() {
                let mut alone = Vec::new();
                encoding::encode(enc, t, views, &mut alone);
                for (c, v) in t.iter().enumerate() {
                    let cell = (c / 7, c % 7);
                    let got = encoding::decode_in_record(
                        enc,
                        &rec,
                        funcs,
                        f,
                        views,
                        cell,
                        cell_major && enc != Encoding::Cubic,
                    );
                    let want = encoding::decode(enc, &alone, views, cell);
                    assert_eq!(got, want, "{enc} cell-major {cell_major} f {f} c {c}");
                    if enc != Encoding::Cubic {
                        assert!((got - v).abs() < 0.01, "{enc} f {f} c {c}: {got}");
                    }
                }
            }
        }
    }
}

#[test]
fn cached_view_cells_stay_right_when_tables_of_other_grids_take_turns() {
    // Core levels and sub-brick tables of other view grids are looked up in turn, on one
    // thread, for the same directions: each must get its own grid's cell.
    let s = phantom(32);
    let grids = [[4, 6], [5, 7], [3, 3], [6, 4], [7, 5]];
    let tables: Vec<PofTable> = grids
        .iter()
        .map(|v| {
            table(
                &s,
                &PofSettings {
                    views: *v,
                    ..small_views()
                },
            )
        })
        .collect();
    let mut rng = seeded_rng();
    let dirs: Vec<DVec3> = (0..6).map(|_| random_dir(&mut rng)).collect();
    for round in 0..3 {
        for (k, d) in dirs.iter().enumerate() {
            for t in tables.iter().cycle().skip(k + round).take(2 * tables.len()) {
                assert_eq!(
                    t.cell_of_cached(*d),
                    t.cell_of(*d),
                    "{:?} {d}",
                    t.meta.views
                );
            }
        }
    }
}

/// The six axis directions and a few more on the lines between view cells of a 12×12 grid
/// (θ on a row border, φ on a column border, or both).
fn border_dirs() -> Vec<DVec3> {
    use std::f64::consts::PI;
    let mut d = vec![
        DVec3::X,
        DVec3::NEG_X,
        DVec3::Y,
        DVec3::NEG_Y,
        DVec3::Z,
        DVec3::NEG_Z,
    ];
    for (t, p) in [(3.0, 1.3), (4.4, 2.0), (5.0, 7.0), (6.0, 5.5)] {
        d.push(direction(t / 12.0 * PI, p / 12.0 * 2.0 * PI));
    }
    d
}

#[test]
fn border_cells_are_the_cells_whose_closure_holds_the_direction() {
    let views = [12, 12];
    // A pole: the whole first or last row.
    assert_eq!(
        border_cells(views, DVec3::Z),
        (0..12).map(|j| (0, j)).collect::<Vec<_>>()
    );
    assert_eq!(
        border_cells(views, DVec3::NEG_Z),
        (0..12).map(|j| (11, j)).collect::<Vec<_>>()
    );
    // +x: θ = 90° (rows 5 and 6 meet), φ = 0 (columns 11 and 0 meet).
    assert_eq!(
        border_cells(views, DVec3::X),
        vec![(5, 0), (5, 11), (6, 0), (6, 11)]
    );
    // A hair off a line still counts as on it; a little more does not.
    let near = direction(std::f64::consts::FRAC_PI_2 + 1e-12, 1.0);
    assert_eq!(border_cells(views, near).len(), 2);
    let off = direction(std::f64::consts::FRAC_PI_2 + 1e-6, 1.0);
    assert_eq!(border_cells(views, off), vec![cell_of(views, off)]);
    // Anywhere else: the one cell of `cell_of`.
    let mut rng = seeded_rng();
    for _ in 0..200 {
        let d = random_dir(&mut rng);
        assert_eq!(border_cells(views, d), vec![cell_of(views, d)], "{d}");
    }
    for d in border_dirs() {
        let cells = border_cells(views, d);
        assert!(cells.len() >= 2, "{d}: {cells:?}");
        assert!(cells.contains(&cell_of(views, d)), "{d}: {cells:?}");
    }
}

#[test]
fn lookups_on_cell_borders_take_the_best_cell_and_never_exceed_brute_force() {
    let s = phantom(64);
    let t = table(
        &s,
        &PofSettings {
            sets: true,
            ..small_views()
        },
    );
    let mut rng = seeded_rng();
    let stored: Vec<BrickId> = s.grid.ids().filter(|id| t.slot(*id).is_some()).collect();
    let (mut lifted, mut compared) = (0, 0);
    for d in border_dirs() {
        let cells = border_cells(t.meta().views, d);
        for &id in &stored {
            for w in [
                vec![1.0, 0.0],
                vec![0.0, 1.0],
                vec![1.0, 1.0],
                vec![3.0, 0.5],
            ] {
                let a = t.opacity(id, d, &w, PofMode::Conservative);
                // Every cell of the border bounds the direction, so the lookup is at least
                // what each alone gives, and more where the cells differ.
                let rec = t.record(t.slot(id).unwrap());
                let each = cells
                    .iter()
                    .map(|c| t.cell_opacity(rec, *c, &w, PofMode::Conservative))
                    .fold(0.0, f32::max);
                assert!(
                    a >= each - 1e-6,
                    "{d} brick {id:?}: {a} below a cell's {each}"
                );
                let one =
                    t.cell_opacity(rec, cell_of(t.meta().views, d), &w, PofMode::Conservative);
                lifted += usize::from(a > one + 1e-3);
                // Sets: never below the conservative lookup.
                assert!(t.opacity(id, d, &w, PofMode::Sets) >= a - 1e-6);
            }
            // And still a bound: the brute-force minimum along the very direction.
            let w = [1.0, 1.0];
            let r = brute_force(&s, &t, id, &w, &probe(&mut rng, d));
            if let Some(m) = r.core_min {
                let a = t.opacity(id, d, &w, PofMode::Conservative);
                assert!(
                    a <= m + 1e-6,
                    "{d} brick {id:?}: lookup {a} > brute force {m}"
                );
                compared += 1;
            }
        }
    }
    eprintln!("{compared} border views compared; {lifted} lookups lifted above the rounded cell's");
    assert!(compared > 50, "{compared}");
    assert!(lifted > 0, "a border lookup gains somewhere");
}

#[test]
fn typical_values_sit_above_the_sampled_minimum_and_keep_their_method() {
    // A low quantile of the non-empty core rays is at least their minimum: cells where the
    // sampled (minimum) table is positive are rarely lower in the typical table, and on the
    // whole the typical values are higher. The joint lane (measured in the same pass) and
    // the sets must be stored too.
    let s = phantom(64);
    let sampled = table(&s, &small_views_for(PofMethod::Sampled));
    let typical = table(
        &s,
        &PofSettings {
            sets: true,
            ..small_views_for(PofMethod::Typical)
        },
    );
    assert_eq!(typical.meta().method, PofMethod::Typical);
    assert!(typical.meta().joint.is_some());
    assert!(typical.has_sets());
    let (mut sum_s, mut sum_t, mut cells, mut lower) = (0f64, 0f64, 0usize, 0usize);
    for id in s.grid.ids() {
        for i in 0..12 {
            for j in 0..12 {
                let a = sampled.basis_opacities(id, (i, j));
                let t = typical.basis_opacities(id, (i, j));
                for (x, y) in a.iter().zip(&t) {
                    if *x <= 0.0 && *y <= 0.0 {
                        continue;
                    }
                    sum_s += f64::from(*x);
                    sum_t += f64::from(*y);
                    cells += 1;
                    lower += usize::from(*y < 0.9 * *x);
                }
            }
        }
    }
    eprintln!(
        "typical: {cells} cells, mean {:.4} against sampled {:.4}, {lower} lower",
        sum_t / cells as f64,
        sum_s / cells as f64
    );
    assert!(cells > 100, "{cells}");
    assert!(sum_t > sum_s, "typical {sum_t} sampled {sum_s}");
    assert!((lower as f64) < 0.05 * cells as f64, "{lower} of {cells}");
    // The file keeps the method: a reader sees a typical table, not a bound.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.pof");
    typical.save(&path).unwrap();
    let back = PofTable::open(&path).unwrap();
    assert_eq!(back.meta().method, PofMethod::Typical);
    assert_eq!(back.meta().pitch, TYPICAL_PITCH);
}
