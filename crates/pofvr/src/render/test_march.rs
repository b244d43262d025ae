//! The march engine against the reference: the same image bit for bit, and fewer samples.

use super::frame_rays::FrameRays;
use super::*;
use crate::brick::BrickGrid;
use crate::volume::phantom::Phantom;
use crate::volume::{Volume, VoxelData, Voxels};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// Renders `vol` with the reference and the march engine; asserts the images are equal
/// bit for bit and returns the reference's and the march's figures.
fn compare(
    vol: &Volume,
    tf: &TransferFunction,
    weights: &[f32],
    settings: RenderSettings,
    cam: &Camera,
) -> (RayStats, MarchStats) {
    let grid = BrickGrid::from_volume(vol, 16).unwrap();
    let s = SampledTf::new(tf, grid.value_range());
    let cls = s.classify(weights, settings.step);
    let caster = RayCaster::new(vol, &cls, settings);
    let (want, ref_st) = caster.render(cam);
    let occ = Occupancy::new(&CellRanges::new(vol), &cls);
    let mut first = None;
    // The eights' other layout: these volumes are far below the size that gets it by
    // itself.
    let copy = MarchBlocks::new(vol).expect("a resident volume");
    // The packets of sixteen on AVX-512 and of eight on AVX2 (where the CPU has them),
    // and the walk around the one-sample loop; the packets with and without prefetching
    // (these volumes are far below the size that turns it on by itself), the sixteen
    // with loads lane by lane and by gathers, the eights over the volume's own layout and
    // over its blocked copy.
    for (avx2, avx512, prefetch, gather, blocks) in [
        (true, true, false, false, false),
        (true, true, false, true, false),
        (true, true, true, false, false),
        (true, true, true, true, false),
        (true, false, false, false, false),
        (true, false, false, true, false),
        (true, false, true, false, false),
        (true, false, true, true, false),
        (true, false, false, false, true),
        (true, false, true, false, true),
        (true, false, true, true, true),
        (false, false, false, false, false),
    ] {
        let caster = RayCaster::new(vol, &cls, settings)
            .with_avx2(avx2)
            .with_avx512(avx512)
            .with_prefetch(prefetch)
            .with_gather(gather);
        let want_packets = match (avx2, avx512) {
            (true, true) if arch::avx512_available() => "avx512",
            (true, _) if arch::avx2_available() => "avx2",
            _ => "none",
        };
        if caster.packet_simd() != want_packets {
            println!(
                "skipped: the {want_packets} packets (this CPU runs {})",
                caster.packet_simd()
            );
        }
        let (got, st) = caster.render_march_with(cam, &occ, blocks.then_some(&copy));
        assert_eq!(st.blocks, blocks && st.simd == "avx2", "{st:?}");
        for (i, (g, w)) in got.pixels().iter().zip(want.pixels()).enumerate() {
            assert_eq!(
                g.map(f32::to_bits),
                w.map(f32::to_bits),
                "pixel {i} ({}, {}): march ({}, packets {}, prefetch {prefetch}, gather {gather}, blocks {blocks}) {g:?}, reference {w:?} ({weights:?}, {settings:?}, {:?})",
                i as u32 % cam.width,
                i as u32 / cam.width,
                caster.simd(),
                caster.packet_simd(),
                cam.projection
            );
        }
        assert_eq!(st.rays.rays, ref_st.rays, "rays that met the volume");
        // The stats name the loop that ran: the packets asked for (or the walk around the
        // AVX2 loop, on a volume too small for the packets' wide reads), else the walk,
        // which runs the SSE2 loop where AVX2 is off.
        match want_packets {
            "none" if cfg!(target_arch = "x86_64") => assert_eq!(st.simd, "sse2"),
            "none" => assert_eq!(st.simd, "scalar"),
            p => assert!(st.simd == p || st.simd == "walk-avx2", "{p}: {st:?}"),
        }
        if settings.ert > 1.0 {
            // Without termination every lattice sample is either taken or skipped.
            assert_eq!(
                st.rays.samples + st.skipped_samples,
                ref_st.samples,
                "{st:?}"
            );
        }
        // Every packet step samples at most one sample per lane, and samples or leaps over
        // at least one; the walk takes no packet steps.
        let lanes = match st.simd {
            "avx512" => 16,
            "avx2" => 8,
            _ => 0,
        };
        if lanes == 0 {
            assert_eq!(st.packet_steps, 0, "{st:?}");
        } else {
            assert!(st.packet_steps * lanes >= st.rays.samples, "{st:?}");
            assert!(
                st.packet_steps <= st.rays.samples + st.skipped_samples,
                "{st:?}"
            );
            assert_eq!(
                st.packet_steps > 0,
                st.rays.samples + st.skipped_samples > 0,
                "{st:?}"
            );
        }
        first.get_or_insert(st);
    }
    (ref_st, first.unwrap())
}

/// A `dims` volume of zeros holding `blob` (value 200) in the voxels `lo..hi`.
fn blob_volume(dims: [usize; 3], lo: [usize; 3], hi: [usize; 3]) -> Volume {
    let mut v = vec![0u8; dims.iter().product()];
    for z in lo[2]..hi[2] {
        for y in lo[1]..hi[1] {
            for x in lo[0]..hi[0] {
                v[(z * dims[1] + y) * dims[0] + x] = 200;
            }
        }
    }
    Volume::new(dims, [1.0; 3], VoxelData::U8(Voxels::owned(v)), "blob").unwrap()
}

/// A one-basis family opaque from `from` up.
fn opaque_above(from: f32) -> TransferFunction {
    TransferFunction::from_json(
        &format!(
            r#"{{"bases":[{{"name":"b","opacity":[[0,0],[{from},0],[{},0.4],[255,0.4]]}}],"color":[[0,1,0.5,0.2],[255,0.2,0.5,1]]}}"#,
            from + 1.0
        ),
        "above",
    )
    .unwrap()
}

#[test]
fn march_leaps_through_long_empty_space_exactly() {
    // A small blob at one end of a long empty volume: rays along x cross up to 40 empty
    // cells, more than one cube of the distance cap, so leaps follow each other, land in
    // the cells next to the blob, and go on past it.
    let vol = blob_volume([160, 36, 36], [120, 12, 14], [131, 23, 22]);
    let tf = opaque_above(50.0);
    for (az, el) in [
        (90.0, 0.0),
        (-90.0, 0.0),
        (75.0, 8.0),
        (100.0, -12.0),
        (0.0, 0.0),
    ] {
        for projection in [Projection::Orthographic, Projection::Perspective] {
            for shade in [false, true] {
                let settings = RenderSettings {
                    ert: 2.0,
                    shade,
                    ..RenderSettings::default()
                };
                let cam = Camera::orbit(&vol, az, el, 40, 24, projection);
                let (reference, march) = compare(&vol, &tf, &[1.0], settings, &cam);
                assert!(
                    march.rays.samples * 4 < reference.samples,
                    "view {az},{el} {projection:?}: {march:?} vs {reference:?}"
                );
            }
        }
    }
}

#[test]
fn march_rays_grazing_cell_faces_equal_the_reference() {
    // Orthographic views along the axes whose pixel centres fall on whole voxel
    // positions, multiples of the cell size among them: rays run inside the faces between
    // occupancy cells (and between empty and occupied ones), where the sampler's floor and
    // the cells' bounds meet exactly.
    let vol = blob_volume([33, 33, 33], [8, 8, 8], [13, 17, 12]);
    let tf = opaque_above(20.0);
    let c = 16.0;
    for (dir, up) in [
        ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        ([0.0, -1.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]),
        ([1.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
    ] {
        for shade in [false, true] {
            let cam = Camera {
                projection: Projection::Orthographic,
                position: std::array::from_fn(|a| c - 40.0 * dir[a]),
                focal_point: [c; 3],
                view_up: up,
                // One world unit per pixel, with pixel centres on whole positions: the
                // image's centre line is at 16, and pixel i's centre at i + 0.5 − 16.5.
                parallel_scale: 16.5,
                view_angle: 30.0,
                width: 33,
                height: 33,
            };
            let settings = RenderSettings {
                ert: 0.95,
                shade,
                ..RenderSettings::default()
            };
            compare(&vol, &tf, &[1.0], settings, &cam);
        }
    }
}

#[test]
fn march_equals_reference_on_the_phantoms() {
    let head = Phantom::SheppLogan.generate(48);
    let ml = Phantom::MarschnerLobb.generate(33);
    let cases: [(&Volume, TransferFunction, Vec<Vec<f32>>); 2] = [
        (
            &head,
            families::for_phantom(Phantom::SheppLogan),
            // Both bases; skin only (most of the volume empty); brain only; heavy.
            vec![
                vec![1.0, 1.0],
                vec![1.0, 0.0],
                vec![0.0, 1.0],
                vec![6.0, 3.0],
            ],
        ),
        (
            &ml,
            families::for_phantom(Phantom::MarschnerLobb),
            vec![vec![1.0; 1], vec![0.3; 1]],
        ),
    ];
    let views = [
        (0.0, 0.0),
        (90.0, 0.0),
        (0.0, 90.0),
        (30.0, 20.0),
        (-127.0, -41.0),
    ];
    for (vol, tf, weight_sets) in &cases {
        let bases = tf.bases.len();
        for weights in weight_sets {
            let weights: Vec<f32> = weights.iter().copied().cycle().take(bases).collect();
            for (i, &(az, el)) in views.iter().enumerate() {
                for projection in [Projection::Orthographic, Projection::Perspective] {
                    // Shading and termination vary with the view, so that every
                    // combination appears without multiplying the cases.
                    let settings = RenderSettings {
                        step: [1.0, 0.5, 0.7][i % 3],
                        ert: [0.99, 2.0, 0.6]
                            [(i + usize::from(projection == Projection::Perspective)) % 3],
                        shade: (i + weights.len()).is_multiple_of(2),
                        // Jittered ray starts in some cases: the march engine must start
                        // each ray where the reference does.
                        jitter: (i % 4 == 3).then_some(u32::try_from(i).unwrap()),
                    };
                    let cam = Camera::orbit(vol, az, el, 40, 36, projection);
                    compare(vol, tf, &weights, settings, &cam);
                }
            }
        }
    }
}

/// Images whose sides are not multiples of the 4 × 2 or 4 × 4 packets, nor of the 8-row bands: the
/// packets at the right and bottom edges hold lanes without a pixel, which must neither
/// be written nor hold back the others.
#[test]
fn march_packets_at_the_image_edges_equal_the_reference() {
    let head = Phantom::SheppLogan.generate(36);
    let tf = families::for_phantom(Phantom::SheppLogan);
    for (i, (w, h)) in [(37, 23), (1, 1), (5, 3), (3, 17), (6, 9)]
        .into_iter()
        .enumerate()
    {
        for projection in [Projection::Orthographic, Projection::Perspective] {
            for shade in [false, true] {
                let settings = RenderSettings {
                    step: 1.0,
                    ert: 0.95,
                    shade,
                    jitter: (i % 2 == 1).then_some(11),
                };
                let cam = Camera::orbit(&head, 25.0 + 40.0 * i as f64, 15.0, w, h, projection);
                compare(&head, &tf, &[1.0, 1.0], settings, &cam);
            }
        }
    }
}

#[test]
fn march_shaded_and_unshaded_on_every_axis_view() {
    let head = Phantom::SheppLogan.generate(40);
    let tf = families::for_phantom(Phantom::SheppLogan);
    for (az, el) in [
        (0.0, 0.0),
        (180.0, 0.0),
        (90.0, 0.0),
        (270.0, 0.0),
        (0.0, 90.0),
        (0.0, -90.0),
    ] {
        for shade in [false, true] {
            // Steps under a voxel too: then consecutive samples of a packet in lockstep
            // share their cell's corners, which the eight-lane loop reads once.
            for (ert, step) in [(0.95, 1.0), (1.0, 1.0), (0.95, 0.3), (1.0, 0.45)] {
                let settings = RenderSettings {
                    step,
                    ert,
                    shade,
                    jitter: None,
                };
                let cam = Camera::orbit(&head, az, el, 32, 32, Projection::Orthographic);
                compare(&head, &tf, &[1.0, 1.0], settings, &cam);
            }
        }
    }
}

/// A volume of zeros with a few random boxes of random values, of any voxel type.
fn sparse_volume(rng: &mut StdRng, dtype: usize) -> Volume {
    let dims: [usize; 3] = std::array::from_fn(|_| {
        if rng.gen_bool(0.1) {
            1
        } else {
            rng.gen_range(2..=45)
        }
    });
    let spacing: [f32; 3] = std::array::from_fn(|_| rng.gen_range(0.4..2.0));
    let n: usize = dims.iter().product();
    let mut v = vec![0f32; n];
    for _ in 0..rng.gen_range(1..4) {
        let lo: [usize; 3] = std::array::from_fn(|a| rng.gen_range(0..dims[a]));
        let hi: [usize; 3] = std::array::from_fn(|a| rng.gen_range(lo[a]..dims[a]).min(lo[a] + 6));
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    v[(z * dims[1] + y) * dims[0] + x] = rng.gen_range(0.0..250.0);
                }
            }
        }
    }
    let data = match dtype {
        0 => VoxelData::U8(Voxels::owned(v.iter().map(|x| *x as u8).collect())),
        1 => VoxelData::U16(Voxels::owned(
            v.iter().map(|x| (*x * 100.0) as u16).collect(),
        )),
        2 => VoxelData::I16(Voxels::owned(
            v.iter().map(|x| (*x * 50.0) as i16 - 3000).collect(),
        )),
        _ => VoxelData::F32(Voxels::owned(v.iter().map(|x| x * 0.37 - 2.0).collect())),
    };
    Volume::new(dims, spacing, data, "sparse").unwrap()
}

#[test]
fn march_equals_reference_on_sparse_random_volumes() {
    let mut rng = StdRng::seed_from_u64(16);
    for case in 0..120 {
        let vol = sparse_volume(&mut rng, case % 4);
        let grid = BrickGrid::from_volume(&vol, 8).unwrap();
        let r = grid.value_range();
        // Opacity only on a random band of values above the background.
        let a = rng.gen_range(0.05..0.6);
        let lo = r.min + (r.max - r.min) * rng.gen_range(0.01..0.5);
        let hi = lo + (r.max - lo) * rng.gen_range(0.1..1.0);
        let tf = TransferFunction::from_json(
            &format!(
                r#"{{"bases":[{{"name":"b","opacity":[[{},0],[{lo},0],[{hi},{a}],[{},{a}]]}}],"color":[[{},1,0.5,0.2],[{},0.2,0.5,1]]}}"#,
                r.min, r.max, r.min, r.max
            ),
            "band",
        )
        .unwrap();
        let settings = RenderSettings {
            step: rng.gen_range(0.3..1.5),
            ert: if rng.gen_bool(0.5) {
                rng.gen_range(0.3..0.99)
            } else {
                1.0
            },
            shade: rng.gen_bool(0.3),
            jitter: rng.gen_bool(0.3).then(|| rng.gen()),
        };
        let projection = if rng.gen_bool(0.5) {
            Projection::Orthographic
        } else {
            Projection::Perspective
        };
        let cam = Camera::orbit(
            &vol,
            rng.gen_range(-180.0..180.0),
            rng.gen_range(-89.0..89.0),
            24,
            20,
            projection,
        );
        compare(&vol, &tf, &[1.0], settings, &cam);
    }
}

#[test]
fn march_skips_empty_space_and_takes_fewer_samples() {
    // Skin only: the air around the head and the inside of the skull are empty.
    let head = Phantom::SheppLogan.generate(64);
    let tf = families::for_phantom(Phantom::SheppLogan);
    let cam = Camera::orbit(&head, 30.0, 20.0, 64, 64, Projection::Perspective);
    let settings = RenderSettings {
        ert: 2.0,
        ..RenderSettings::default()
    };
    let (reference, march) = compare(&head, &tf, &[1.0, 0.0], settings, &cam);
    assert!(march.skipped_samples > 0, "{march:?}");
    assert!(
        march.rays.samples < reference.samples,
        "{march:?} vs {reference:?}"
    );
    // Without termination every lattice sample is either taken or skipped.
    assert_eq!(
        march.rays.samples + march.skipped_samples,
        reference.samples
    );
}

#[test]
fn occupancy_is_empty_for_a_transparent_tf_and_full_for_an_opaque_one() {
    let head = Phantom::SheppLogan.generate(24);
    let ranges = CellRanges::new(&head);
    assert_eq!(ranges.cells(), [6, 6, 6]);
    let grid = BrickGrid::from_volume(&head, 8).unwrap();
    for (alpha, occupied) in [(0.0, 0), (0.3, 216)] {
        let tf = TransferFunction::from_json(
            &format!(r#"{{"bases":[{{"name":"c","opacity":[[0,{alpha}],[255,{alpha}]]}}],"color":[[0,1,1,1]]}}"#),
            "c",
        )
        .unwrap();
        let cls = SampledTf::new(&tf, grid.value_range()).classify(&[1.0], 1.0);
        assert_eq!(
            Occupancy::new(&ranges, &cls).occupied_cells(),
            (occupied, 216)
        );
    }
}

#[test]
fn cell_ranges_cover_the_one_voxel_apron() {
    // One nonzero voxel at x = 8 lies in cells 1 (voxels 4..=8) and 2 (voxels 8..=12).
    let dims = [17, 3, 2];
    let mut v = vec![0u8; 17 * 3 * 2];
    v[8] = 200;
    let vol = Volume::new(dims, [1.0; 3], VoxelData::U8(Voxels::owned(v)), "dot").unwrap();
    let r = CellRanges::new(&vol);
    assert_eq!(r.cells(), [4, 1, 1]);
    let maxes: Vec<f32> = (0..4).map(|x| r.range([x, 0, 0])[1]).collect();
    assert_eq!(maxes, [0.0, 200.0, 200.0, 0.0]);
}

#[test]
fn cell_ranges_match_brute_force_on_every_shape() {
    // Odd sizes (a last cell shorter than four), one-voxel axes, signed voxels.
    let mut rng = StdRng::seed_from_u64(31);
    for dims in [
        [9, 6, 11],
        [1, 7, 5],
        [13, 1, 1],
        [4, 5, 2],
        [2, 2, 2],
        [17, 9, 1],
    ] {
        let n = dims[0] * dims[1] * dims[2];
        let v: Vec<i16> = (0..n).map(|_| rng.gen_range(-900..900)).collect();
        let vol = Volume::new(
            dims,
            [1.0; 3],
            VoxelData::I16(Voxels::owned(v.clone())),
            "r",
        )
        .unwrap();
        let r = CellRanges::new(&vol);
        let cells = r.cells();
        let span = |c: usize, n: usize| 4 * c..=(4 * c + 4).min(n - 1);
        for z in 0..cells[2] {
            for y in 0..cells[1] {
                for x in 0..cells[0] {
                    let mut want = [f32::INFINITY, f32::NEG_INFINITY];
                    for k in span(z, dims[2]) {
                        for j in span(y, dims[1]) {
                            for i in span(x, dims[0]) {
                                let s = f32::from(v[(k * dims[1] + j) * dims[0] + i]);
                                want = [want[0].min(s), want[1].max(s)];
                            }
                        }
                    }
                    assert_eq!(r.range([x, y, z]), want, "{dims:?} cell {:?}", [x, y, z]);
                }
            }
        }
    }
}

#[test]
fn chessboard_distances_match_brute_force() {
    let mut rng = StdRng::seed_from_u64(16);
    for (dims, density) in [
        ([7, 5, 9], 0.05),
        ([1, 12, 3], 0.2),
        ([13, 1, 1], 0.1),
        ([6, 6, 6], 0.0),
    ] {
        let n = dims[0] * dims[1] * dims[2];
        let kind: Vec<bool> = (0..n).map(|_| rng.gen_bool(density)).collect();
        let at = |i: usize| [i % dims[0], i / dims[0] % dims[1], i / (dims[0] * dims[1])];
        for cap in [1u8, 3, 8] {
            let got = super::occupancy::chessboard(&kind, true, dims, cap);
            for (i, &d) in got.iter().enumerate() {
                let c = at(i);
                let want = (0..n)
                    .filter(|&j| kind[j])
                    .map(|j| {
                        let o = at(j);
                        (0..3).map(|a| c[a].abs_diff(o[a])).max().unwrap()
                    })
                    .min()
                    .map_or(cap, |d| d.min(usize::from(cap)) as u8);
                assert_eq!(d, want, "{dims:?} cap {cap} cell {c:?}");
            }
        }
    }
}

#[test]
fn chessboard_distances_toward_an_octant_match_brute_force() {
    let mut rng = StdRng::seed_from_u64(47);
    for (dims, density) in [([7, 5, 9], 0.05), ([1, 12, 3], 0.2), ([9, 8, 7], 0.02)] {
        let n = dims[0] * dims[1] * dims[2];
        let kind: Vec<bool> = (0..n).map(|_| rng.gen_bool(density)).collect();
        let at = |i: usize| [i % dims[0], i / dims[0] % dims[1], i / (dims[0] * dims[1])];
        for sign in [
            [1i8, 1, 1],
            [-1, 1, -1],
            [1, -1, 1],
            [-1, -1, -1],
            [0, 1, -1],
        ] {
            for cap in [1u8, 3, 16] {
                let got = super::occupancy::chessboard_toward(&kind, true, dims, cap, sign);
                for (i, &d) in got.iter().enumerate() {
                    let c = at(i);
                    // Seeds ahead of `c` along every signed axis only.
                    let want = (0..n)
                        .filter(|&j| kind[j])
                        .filter(|&j| {
                            let o = at(j);
                            (0..3).all(|a| match sign[a] {
                                1 => o[a] >= c[a],
                                -1 => o[a] <= c[a],
                                _ => true,
                            })
                        })
                        .map(|j| {
                            let o = at(j);
                            (0..3).map(|a| c[a].abs_diff(o[a])).max().unwrap()
                        })
                        .min()
                        .map_or(cap, |d| d.min(usize::from(cap)) as u8);
                    assert_eq!(d, want, "{dims:?} {sign:?} cap {cap} cell {c:?}");
                }
            }
        }
    }
}

#[test]
fn occupancy_is_reused_while_the_opaque_bins_stay_and_rebuilt_when_they_change() {
    let head = Phantom::SheppLogan.generate(24);
    let ranges = CellRanges::new(&head);
    let tf = families::for_phantom(Phantom::SheppLogan);
    let grid = BrickGrid::from_volume(&head, 8).unwrap();
    let s = SampledTf::new(&tf, grid.value_range());
    let (both, skin) = (s.classify(&[1.0, 1.0], 1.0), s.classify(&[1.0, 0.0], 1.0));
    let a = ranges.occupancy(&both);
    assert!(std::sync::Arc::ptr_eq(&a, &ranges.occupancy(&both)));
    let b = ranges.occupancy(&skin);
    assert!(!std::sync::Arc::ptr_eq(&a, &b));
    assert_eq!(
        b.occupied_cells(),
        Occupancy::new(&ranges, &skin).occupied_cells()
    );
    assert_eq!(
        ranges.occupancy(&both).occupied_cells(),
        Occupancy::new(&ranges, &both).occupied_cells()
    );
}

#[test]
fn frame_rays_equal_the_casters_pixel_rays_bit_for_bit() {
    let vol = Phantom::SheppLogan.generate(20);
    let anisotropic = Volume::new(
        [9, 7, 5],
        [0.7, 1.3, 2.1],
        VoxelData::U8(Voxels::owned(vec![0; 9 * 7 * 5])),
        "aniso",
    )
    .unwrap();
    let tf = families::for_phantom(Phantom::SheppLogan);
    for vol in [&vol, &anisotropic] {
        let grid = BrickGrid::from_volume(vol, 8).unwrap();
        let cls = SampledTf::new(&tf, grid.value_range()).classify(&[1.0, 1.0], 1.0);
        for jitter in [None, Some(7)] {
            let settings = RenderSettings {
                step: 0.7,
                jitter,
                ..RenderSettings::default()
            };
            let caster = RayCaster::new(vol, &cls, settings);
            for projection in [Projection::Orthographic, Projection::Perspective] {
                for (az, el, w, h) in [(30.0, 20.0, 17, 11), (-100.0, 65.0, 8, 13)] {
                    let cam = Camera::orbit(vol, az, el, w, h, projection);
                    let frame = cam.frame();
                    let rays = FrameRays::new(
                        &cam,
                        &frame,
                        vol.spacing(),
                        vol.unit(),
                        jitter.map(|s| (s, settings.step)),
                    );
                    for y in 0..h {
                        for x in 0..w {
                            let (got, want) =
                                (rays.ray(x, y), caster.pixel_ray(&cam, &frame, x, y));
                            let bits = |r: IndexRay| [r.o, r.d, r.dir].map(|v| v.map(f32::to_bits));
                            assert_eq!(
                                bits(got),
                                bits(want),
                                "pixel {x},{y} {projection:?} {jitter:?}"
                            );
                        }
                    }
                }
            }
        }
    }
}

/// The 48³ Shepp–Logan phantom (110 KB of u8 voxels) and its family's classification at
/// step 1.
fn classified_head() -> (Volume, Classifier) {
    let vol = Phantom::SheppLogan.generate(48);
    let tf = families::for_phantom(Phantom::SheppLogan);
    let grid = BrickGrid::from_volume(&vol, 16).unwrap();
    let cls = SampledTf::new(&tf, grid.value_range()).classify(&tf.weights, 1.0);
    (vol, cls)
}

#[test]
fn march_stats_name_the_packet_loop_that_ran() {
    let (vol, cls) = classified_head();
    let occ = Occupancy::new(&CellRanges::new(&vol), &cls);
    let cam = Camera::orbit(&vol, 30.0, 20.0, 32, 32, Projection::Orthographic);
    let caster = |avx2: bool, avx512: bool| {
        RayCaster::new(&vol, &cls, RenderSettings::default())
            .with_avx2(avx2)
            .with_avx512(avx512)
    };
    // A 48³ volume fits the packets' wide reads: where the CPU has them they run.
    for (avx2, avx512, want) in [(true, true, "avx512"), (true, false, "avx2")] {
        let c = caster(avx2, avx512);
        let (_, st) = c.render_march(&cam, &occ);
        if c.packet_simd() == want {
            assert_eq!(st.simd, want);
        } else {
            println!(
                "skipped: the {want} packets (this CPU runs {})",
                c.packet_simd()
            );
        }
    }
    let (_, st) = caster(false, false).render_march(&cam, &occ);
    let want = if cfg!(target_arch = "x86_64") {
        "sse2"
    } else {
        "scalar"
    };
    assert_eq!(st.simd, want);
}

#[test]
fn prefetching_is_on_only_for_volumes_larger_than_the_cache() {
    let (vol, cls) = classified_head();
    if std::env::var_os("POFVR_PREFETCH").is_some() {
        println!("skipped: POFVR_PREFETCH is set, and decides instead of the volume's size");
        return;
    }
    // 110 KB of voxels: below any last-level cache.
    assert!(!RayCaster::new(&vol, &cls, RenderSettings::default()).prefetch());
    assert!(!arch::prefetch_pays(64 << 10));
    let on = cfg!(target_arch = "x86_64");
    assert_eq!(arch::prefetch_pays(usize::MAX), on);
    let c = RayCaster::new(&vol, &cls, RenderSettings::default()).with_prefetch(true);
    assert!(c.prefetch());
}

#[test]
fn gathers_are_taken_only_where_a_packet_loop_runs() {
    let (vol, cls) = classified_head();
    let caster = || RayCaster::new(&vol, &cls, RenderSettings::default());
    // Asked for, they are on exactly where a packet loop can run; off, off everywhere.
    assert_eq!(caster().with_gather(true).gather(), arch::avx2_available());
    assert!(!caster().with_gather(false).gather());
    assert!(!caster().with_avx2(false).with_gather(true).gather());
    // By default, as measured for the loop that runs (or as POFVR_GATHER says), and never
    // without a packet loop.
    assert_eq!(
        caster().gather(),
        arch::gather_pays(arch::avx512_available())
    );
    assert_eq!(
        caster().with_avx512(false).gather(),
        arch::gather_pays(false)
    );
    assert!(!caster().with_avx2(false).gather());
    if !arch::avx2_available() {
        assert!(!caster().gather());
    }
}
