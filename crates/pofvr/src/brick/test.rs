use super::*;
use crate::volume::phantom::Phantom;
use crate::volume::{VoxelData, Voxels};

#[test]
fn bricks_tile_the_sampled_box() {
    let vol = Phantom::SheppLogan.generate(40);
    let grid = BrickGrid::from_volume(&vol, 16).unwrap();
    assert_eq!(grid.counts(), [3, 3, 3]); // (40-1)/16 rounded up
    let last = grid.id([2, 2, 2]);
    assert_eq!(grid.index_box(last).hi, [39.0; 3]);
    assert_eq!(grid.index_box(grid.id([1, 0, 0])).lo[0], 16.0);
    assert_eq!(grid.index_box(grid.id([0, 0, 0])).hi[0], 16.0); // shared face
}

#[test]
fn brick_range_matches_brute_force_over_its_ghosted_box() {
    let vol = Phantom::SheppLogan.generate(37);
    let grid = BrickGrid::from_volume(&vol, 8).unwrap();
    for id in grid.ids() {
        let (lo, hi) = grid.voxel_bounds(id);
        let (mut mn, mut mx) = (f32::MAX, f32::MIN);
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    mn = mn.min(vol.value(x, y, z));
                    mx = mx.max(vol.value(x, y, z));
                }
            }
        }
        assert_eq!(
            grid.range(id),
            ValueRange { min: mn, max: mx },
            "brick {id:?}"
        );
    }
}

#[test]
fn single_voxel_thick_volume_has_one_degenerate_layer() {
    let vol = crate::volume::Volume::new(
        [5, 5, 1],
        [1.0; 3],
        VoxelData::U8(Voxels::owned(vec![7; 25])),
        "flat",
    )
    .unwrap();
    let grid = BrickGrid::from_volume(&vol, 16).unwrap();
    assert_eq!(grid.counts(), [1, 1, 1]);
    assert_eq!(grid.range(BrickId(0)), ValueRange { min: 7.0, max: 7.0 });
}

#[test]
fn bad_brick_size_is_rejected() {
    let vol = Phantom::SheppLogan.generate(8);
    assert!(BrickGrid::from_volume(&vol, 1).is_err());
}

#[test]
fn ranges_measured_in_pieces_and_merged_equal_the_whole_grid() {
    let vol = Phantom::SheppLogan.generate(40);
    let whole = BrickGrid::from_volume(&vol, 8).unwrap();
    // Two "ranks" measure the even and the odd bricks; each fills in the other's ranges.
    let mut even = BrickGrid::from_volume_where(&vol, 8, &|id| id.0 % 2 == 0).unwrap();
    let odd = BrickGrid::from_volume_where(&vol, 8, &|id| id.0 % 2 == 1).unwrap();
    assert!(even.range(BrickId(1)).min > even.range(BrickId(1)).max);
    for id in odd.ids().filter(|id| id.0 % 2 == 1) {
        even.set_range(id, odd.range(id)).unwrap();
    }
    assert_eq!(even.ranges(), whole.ranges());
    let n = whole.len() as u32;
    assert!(matches!(
        even.set_range(BrickId(n), ValueRange { min: 0.0, max: 1.0 }),
        Err(BrickError::UnknownBrick { .. })
    ));
}

#[test]
fn frames_from_private_brick_copies_equal_frames_from_the_volume_bit_for_bit() {
    use crate::frame::{render_frame, FrameOptions, RenderJob};
    use crate::render::{families, Camera, Projection, RenderSettings};
    // Odd sizes put partial bricks at the far faces; f32 and u8 take different gathers.
    for (phantom, n) in [(Phantom::SheppLogan, 37), (Phantom::MarschnerLobb, 29)] {
        for shade in [false, true] {
            let settings = RenderSettings {
                shade,
                ..RenderSettings::default()
            };
            let tf = families::for_phantom(phantom);
            let mut job = RenderJob::new(phantom.generate(n), tf, 8, settings).unwrap();
            // Only every other brick copied: the rest still come from the volume.
            let ids: Vec<BrickId> = job.grid.ids().filter(|id| id.0 % 2 == 0).collect();
            let store = BrickStore::new(&job.volume, &job.grid, &ids);
            assert_eq!(store.len(), ids.len());
            for id in &ids {
                let c = store.get(*id).unwrap();
                let [x, y, z] = c.origin();
                assert_eq!(c.value(x, y, z), Some(job.volume.value(x, y, z)));
            }
            for (az, el, p) in [
                (0.0, 0.0, Projection::Orthographic),
                (33.0, -21.0, Projection::Orthographic),
                (145.0, 50.0, Projection::Perspective),
            ] {
                let cam = Camera::orbit(&job.volume, az, el, 61, 47, p);
                let opts = FrameOptions {
                    ranks: 2,
                    cull: crate::cull::CullMode::None,
                    ..FrameOptions::default()
                };
                job.bricks = None;
                let (a, _) = render_frame(&job, None, &cam, &opts).unwrap();
                job.bricks = Some(BrickStore::new(&job.volume, &job.grid, &ids));
                let (b, _) = render_frame(&job, None, &cam, &opts).unwrap();
                let bits = |i: &crate::render::Image| -> Vec<u32> {
                    i.pixels().iter().flatten().map(|v| v.to_bits()).collect()
                };
                assert!(
                    bits(&a) == bits(&b),
                    "{phantom:?} {n} shade {shade} view {az},{el} {p:?}"
                );
            }
        }
    }
}

#[test]
fn sub_bricks_tile_their_brick() {
    use crate::volume::phantom::Phantom;
    // 37 voxels: bricks of 8 end in a partial one, as do their sub-bricks of 4 and 2.
    let v = Phantom::SheppLogan.generate(37);
    let coarse = BrickGrid::from_volume(&v, 8).unwrap();
    for size in [2, 4, 8] {
        let fine = BrickGrid::from_volume(&v, size).unwrap();
        let mut seen = vec![0u32; fine.len()];
        for id in coarse.ids() {
            let b = coarse.index_box(id);
            let mut volume = 0f32;
            for (f, fb) in coarse.sub_bricks(id, &fine) {
                seen[f.index()] += 1;
                assert_eq!(fb, fine.index_box(f));
                for a in 0..3 {
                    assert!(
                        fb.lo[a] >= b.lo[a] && fb.hi[a] <= b.hi[a],
                        "{size}: {fb:?} in {b:?}"
                    );
                }
                volume += (0..3).map(|a| fb.hi[a] - fb.lo[a]).product::<f32>();
            }
            let whole: f32 = (0..3).map(|a| b.hi[a] - b.lo[a]).product();
            assert_eq!(volume, whole, "{size}: sub-bricks of {id:?} fill it");
        }
        assert!(
            seen.iter().all(|n| *n == 1),
            "{size}: each sub-brick in one brick"
        );
    }
}
