use glam::DVec3;

use super::*;
use crate::brick::BrickGrid;
use crate::render::families;
use crate::volume::phantom::Phantom;
use crate::volume::{Volume, Voxel, VoxelData, Voxels};
use crate::with_voxels;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use sampler::TrilinearSampler;

fn constant_tf(alpha: f32) -> TransferFunction {
    TransferFunction::from_json(
        &format!(r#"{{"bases":[{{"name":"c","opacity":[[0,{alpha}],[255,{alpha}]]}}],"color":[[0,1,1,1]]}}"#),
        "t",
    )
    .unwrap()
}

#[test]
fn constant_slab_head_on_gives_beer_lambert() {
    // 20 units thick along z, wide in x and y; viewed down the z axis.
    let dims = [40, 40, 21];
    let vol = Volume::new(
        dims,
        [1.0; 3],
        VoxelData::U8(Voxels::owned(vec![100; 40 * 40 * 21])),
        "slab",
    )
    .unwrap();
    let tf = constant_tf(0.05);
    let grid = BrickGrid::from_volume(&vol, 16).unwrap();
    let s = SampledTf::new(&tf, grid.value_range());
    let settings = RenderSettings {
        step: 0.5,
        ert: 2.0,
        shade: false,
        jitter: None,
    };
    let cls = s.classify(&[1.0], settings.step);
    let cam = Camera::orbit(&vol, 0.0, 0.0, 64, 64, Projection::Orthographic);
    let (img, st) = RayCaster::new(&vol, &cls, settings).render(&cam);
    let tau = -(1.0f32 - 0.05).ln();
    let expected = 1.0 - (-tau * 20.0).exp();
    let one_sample = 1.0 - (-tau * settings.step).exp();
    // Pixels over the slab's interior see exactly the slab thickness.
    let frame = cam.frame();
    let (cx, cy, _) = cam.project(&frame, DVec3::new(19.5, 19.5, 10.0)).unwrap();
    let a = img.pixel(cx as u32, cy as u32)[3];
    assert!(
        (a - expected).abs() <= one_sample * (1.0 - expected) + 1e-5,
        "alpha {a}, expected {expected}"
    );
    assert!(st.samples > 0 && st.rays > 0);
}

#[test]
fn fully_transparent_tf_gives_a_transparent_image() {
    let vol = Phantom::SheppLogan.generate(32);
    let tf = constant_tf(0.0);
    let grid = BrickGrid::from_volume(&vol, 8).unwrap();
    let s = SampledTf::new(&tf, grid.value_range());
    let cls = s.classify(&[1.0], 1.0);
    let cam = Camera::orbit(&vol, 20.0, 30.0, 48, 40, Projection::Perspective);
    let (img, _) = RayCaster::new(&vol, &cls, RenderSettings::default()).render(&cam);
    assert!(img.pixels().iter().all(|p| *p == [0.0; 4]));
    assert!(grid.ranges().iter().all(|r| s.is_empty(*r, &[1.0])));
}

/// Renders brick by brick along each ray, carrying the accumulator across bricks.
fn render_by_bricks(grid: &BrickGrid, caster: &RayCaster<'_>, cam: &Camera) -> Image {
    let frame = cam.frame();
    let mut img = Image::new(cam.width, cam.height);
    let w = cam.width;
    for (i, px) in img.pixels_mut().iter_mut().enumerate() {
        let (x, y) = (i as u32 % w, i as u32 / w);
        let ray = caster.pixel_ray(cam, &frame, x, y);
        let mut hits: Vec<_> = grid
            .ids()
            .filter_map(|b| ray.span(&grid.index_box(b)).map(|s| (s.0, b)))
            .collect();
        hits.sort_by(|a, b| a.0.total_cmp(&b.0));
        let rect = PixelRect {
            x0: x,
            y0: y,
            x1: x + 1,
            y1: y + 1,
        };
        for (_, b) in hits {
            caster.render_box_into(
                cam,
                &frame,
                rect,
                &grid.index_box(b),
                std::slice::from_mut(px),
            );
        }
    }
    img
}

#[test]
fn brick_by_brick_equals_whole_volume_bit_for_bit() {
    // Anisotropic spacing and a size that is not a multiple of the brick size.
    let base = Phantom::SheppLogan.generate(37);
    let VoxelData::U8(v) = base.data() else {
        unreachable!()
    };
    let vol = Volume::new(
        [37; 3],
        [1.0, 0.8, 1.3],
        VoxelData::U8(Voxels::owned(v.as_slice().to_vec())),
        "aniso",
    )
    .unwrap();
    let grid = BrickGrid::from_volume(&vol, 8).unwrap();
    let tf = families::for_phantom(Phantom::SheppLogan);
    let s = SampledTf::new(&tf, grid.value_range());
    for (settings, az, el, projection) in [
        (
            RenderSettings {
                step: 1.0,
                ert: 2.0,
                shade: false,
                jitter: None,
            },
            0.0,
            0.0,
            Projection::Orthographic,
        ),
        (
            RenderSettings {
                step: 1.0,
                ert: 2.0,
                shade: false,
                jitter: None,
            },
            90.0,
            0.0,
            Projection::Orthographic,
        ),
        (
            RenderSettings {
                step: 0.7,
                ert: 0.99,
                shade: true,
                jitter: None,
            },
            33.0,
            21.0,
            Projection::Orthographic,
        ),
        (
            RenderSettings {
                step: 0.5,
                ert: 0.9,
                shade: false,
                jitter: None,
            },
            -120.0,
            -40.0,
            Projection::Perspective,
        ),
        (
            RenderSettings {
                step: 0.6,
                ert: 0.95,
                shade: true,
                jitter: None,
            },
            150.0,
            -35.0,
            Projection::Perspective,
        ),
    ] {
        let cls = s.classify(&tf.weights, settings.step);
        let caster = RayCaster::new(&vol, &cls, settings);
        let cam = Camera::orbit(&vol, az, el, 41, 37, projection);
        let (whole, _) = caster.render(&cam);
        let bricks = render_by_bricks(&grid, &caster, &cam);
        assert!(whole.mean_alpha() > 0.05, "view {az},{el} shows something");
        assert_eq!(
            whole.max_abs_diff(&bricks),
            Some(0.0),
            "view {az},{el} {projection:?}"
        );
    }
}

#[test]
fn ray_spans_of_bricks_partition_the_volume_span() {
    let vol = Phantom::SheppLogan.generate(50);
    let grid = BrickGrid::from_volume(&vol, 16).unwrap();
    let tf = families::for_phantom(Phantom::SheppLogan);
    let s = SampledTf::new(&tf, grid.value_range());
    let cls = s.classify(&tf.weights, 1.0);
    let caster = RayCaster::new(&vol, &cls, RenderSettings::default());
    let cam = Camera::orbit(&vol, 47.0, 13.0, 31, 29, Projection::Perspective);
    let frame = cam.frame();
    for y in 0..29 {
        for x in 0..31 {
            let ray = caster.pixel_ray(&cam, &frame, x, y);
            let Some(whole) = ray.span(&caster.volume_box()) else {
                continue;
            };
            let (k0, k1) = ray_caster::sample_range(whole, 1.0);
            let mut count = 0;
            for b in grid.ids() {
                if let Some(sp) = ray.span(&grid.index_box(b)) {
                    let (a, c) = ray_caster::sample_range(sp, 1.0);
                    count += (c - a).max(0);
                }
            }
            assert_eq!(count, k1 - k0, "pixel {x},{y}");
        }
    }
}

#[test]
fn early_termination_stops_at_the_threshold() {
    let vol = Phantom::SheppLogan.generate(48);
    let grid = BrickGrid::from_volume(&vol, 16).unwrap();
    let tf = families::for_phantom(Phantom::SheppLogan);
    let s = SampledTf::new(&tf, grid.value_range());
    let cls = s.classify(&tf.weights, 1.0);
    let cam = Camera::orbit(&vol, 0.0, 0.0, 32, 32, Projection::Orthographic);
    let (full, st_full) = RayCaster::new(
        &vol,
        &cls,
        RenderSettings {
            ert: 2.0,
            ..RenderSettings::default()
        },
    )
    .render(&cam);
    let (ert, st_ert) = RayCaster::new(
        &vol,
        &cls,
        RenderSettings {
            ert: 0.9,
            ..RenderSettings::default()
        },
    )
    .render(&cam);
    assert!(st_ert.samples < st_full.samples);
    for (a, b) in full.pixels().iter().zip(ert.pixels()) {
        if a[3] < 0.9 {
            assert_eq!(a, b);
        } else {
            assert!(b[3] >= 0.9 && a[3] - b[3] <= 0.1 + 1e-6);
        }
    }
}

/// The scalar sample loop as it was before the SIMD paths (unshaded): the definition every
/// path of `RayCaster::march` must reproduce bit for bit.
fn march_reference<T: Voxel>(
    tri: &TrilinearSampler<'_, T>,
    cls: &Classifier,
    settings: RenderSettings,
    ray: &IndexRay,
    (k0, k1): (i32, i32),
    acc: &mut [f32; 4],
) -> u64 {
    let mut n = 0u64;
    for k in k0..k1 {
        if acc[3] >= settings.ert {
            break;
        }
        let t = k as f32 * settings.step;
        let p = [
            ray.o[0] + t * ray.d[0],
            ray.o[1] + t * ray.d[1],
            ray.o[2] + t * ray.d[2],
        ];
        let s = cls.sample(tri.sample(p));
        n += 1;
        if s[3] == 0.0 {
            continue;
        }
        let w = 1.0 - acc[3];
        acc[0] += w * s[0];
        acc[1] += w * s[1];
        acc[2] += w * s[2];
        acc[3] += w * s[3];
    }
    n
}

fn random_volume(rng: &mut StdRng, dtype: usize) -> Volume {
    let dims: [usize; 3] = std::array::from_fn(|_| {
        if rng.gen_bool(0.1) {
            1
        } else if rng.gen_bool(0.8) {
            rng.gen_range(2..=13)
        } else {
            // Long enough for whole runs of eight samples well inside the data.
            rng.gen_range(14..=40)
        }
    });
    let spacing: [f32; 3] = std::array::from_fn(|_| rng.gen_range(0.4..2.0));
    let n = dims.iter().product();
    let data = match dtype {
        0 => VoxelData::U8(Voxels::owned((0..n).map(|_| rng.gen()).collect())),
        1 => VoxelData::U16(Voxels::owned((0..n).map(|_| rng.gen()).collect())),
        2 => VoxelData::I16(Voxels::owned((0..n).map(|_| rng.gen()).collect())),
        _ => VoxelData::F32(Voxels::owned(
            (0..n).map(|_| rng.gen_range(-1000.0..1000.0)).collect(),
        )),
    };
    Volume::new(dims, spacing, data, "random").unwrap()
}

#[test]
fn fast_march_equals_scalar_reference_bit_for_bit() {
    let mut rng = StdRng::seed_from_u64(0x5eed);
    let mut shaded_differs = false;
    for case in 0..96 {
        let vol = random_volume(&mut rng, case % 4);
        let (min, max) = with_voxels!(vol.data(), v => v.iter().fold(
            (f32::INFINITY, f32::NEG_INFINITY),
            |(a, b), x| (a.min(x.to_f32()), b.max(x.to_f32()))
        ));
        let r = max - min;
        // Zero-opacity stretches exercise the skipped composite.
        let tf = TransferFunction::from_json(
            &format!(
                r#"{{"bases":[{{"name":"a","opacity":[[{},0],[{},0],[{},0.4],[{},0.1]]}}],
                    "color":[[{},1,0.5,0.2],[{},0.1,0.9,1]]}}"#,
                min,
                min + 0.3 * r,
                min + 0.5 * r,
                max,
                min,
                max
            ),
            "t",
        )
        .unwrap();
        let s = SampledTf::new(&tf, crate::brick::ValueRange { min, max });
        let settings = RenderSettings {
            step: [0.3, 0.7, 1.0, 1.6][rng.gen_range(0..4)],
            ert: [0.5, 0.95, 2.0][rng.gen_range(0..3)],
            shade: false,
            jitter: None,
        };
        let cls = s.classify(&[rng.gen_range(0.5..3.0)], settings.step);
        let caster = RayCaster::new(&vol, &cls, settings);
        // The one-sample SSE2 loop as well where the CPU runs the AVX2 one by default.
        let one = RayCaster::new(&vol, &cls, settings).with_avx2(false);
        assert_ne!(one.simd(), "avx2");
        // The same loops shaded, against the scalar loop shaded (the shading reference).
        let shaded = RenderSettings {
            shade: true,
            ..settings
        };
        let shaded_loops = [
            RayCaster::new(&vol, &cls, shaded),
            RayCaster::new(&vol, &cls, shaded).with_avx2(false),
        ];
        let shaded_reference = RayCaster::new(&vol, &cls, shaded).with_scalar_loop(true);
        assert_eq!(shaded_reference.simd(), "scalar");
        let vbox = caster.volume_box();
        let dims = vol.dims();
        with_voxels!(vol.data(), v => {
            let tri = TrilinearSampler::new(v, dims);
            for _ in 0..200 {
                let ray = if rng.gen_bool(0.5) {
                    // A world ray through the anisotropic spacing.
                    let o = DVec3::from(std::array::from_fn::<f64, 3, _>(|a| {
                        rng.gen_range(-4.0..(dims[a] as f64 + 4.0)) * f64::from(vol.spacing()[a])
                    }));
                    let mut dir = DVec3::from(std::array::from_fn::<f64, 3, _>(|_| {
                        if rng.gen_bool(0.15) { 0.0 } else { rng.gen_range(-1.0..1.0) }
                    }));
                    if dir.length() < 1e-3 {
                        dir = DVec3::X;
                    }
                    IndexRay::new(&Ray { origin: o, dir: dir.normalize() }, vol.spacing(), vol.unit())
                } else {
                    IndexRay {
                        o: std::array::from_fn(|a| rng.gen_range(-3.0..(dims[a] as f32 + 3.0))),
                        d: std::array::from_fn(|_| rng.gen_range(-1.5..1.5)),
                        dir: [0.0, 0.0, 1.0],
                    }
                };
                // The volume's own sample range, or any range (positions outside get clamped).
                let range = match ray.span(&vbox) {
                    Some(span) if rng.gen_bool(0.7) => ray_caster::sample_range(span, settings.step),
                    _ => {
                        let k0 = rng.gen_range(0..40);
                        (k0, k0 + rng.gen_range(0..90))
                    }
                };
                let start = if rng.gen_bool(0.5) { [0.0; 4] } else { [0.1, 0.05, 0.2, 0.3] };
                let (mut fast, mut slow, mut single) = (start, start, start);
                let nf = caster.march(&tri, &ray, range, &mut fast);
                let ns = march_reference(&tri, &cls, settings, &ray, range, &mut slow);
                let n1 = one.march(&tri, &ray, range, &mut single);
                assert_eq!((n1, single.map(f32::to_bits)), (ns, slow.map(f32::to_bits)));
                // The scalar reference loop itself (the one `with_scalar_loop` runs).
                let mut generic = start;
                let ng = arch::generic::march(&caster.params(), &tri, &ray, range, &mut generic);
                assert_eq!((ng, generic.map(f32::to_bits)), (ns, slow.map(f32::to_bits)));
                assert_eq!(nf, ns, "case {case}: {ray:?} {range:?}");
                assert_eq!(
                    fast.map(f32::to_bits),
                    slow.map(f32::to_bits),
                    "case {case} ({:?}): {ray:?} {range:?}",
                    vol.data().data_type()
                );
                let mut reference = start;
                let nr = shaded_reference.march(&tri, &ray, range, &mut reference);
                assert_eq!(nr, ns, "shading changes no opacity, so no sample count");
                assert_eq!(reference[3].to_bits(), slow[3].to_bits());
                shaded_differs |= reference != slow;
                for (i, c) in shaded_loops.iter().enumerate() {
                    let mut acc = start;
                    let n = c.march(&tri, &ray, range, &mut acc);
                    assert_eq!(
                        (n, acc.map(f32::to_bits)),
                        (nr, reference.map(f32::to_bits)),
                        "shaded, loop {} ({i}), case {case} ({:?}): {ray:?} {range:?}",
                        c.simd(),
                        vol.data().data_type()
                    );
                }
            }
        });
    }
    assert!(shaded_differs, "shading changed some colour");
}

/// Shaded and unshaded frames of the phantoms (u8 and f32 gathers, anisotropic voxels),
/// orthographic and perspective: the AVX2 and SSE2 loops equal the scalar reference loop
/// bit for bit, whole-volume and brick by brick.
#[test]
fn shaded_frames_of_every_loop_equal_the_scalar_reference_bit_for_bit() {
    for (phantom, n, spacing) in [
        (Phantom::SheppLogan, 45, [1.0, 0.8, 1.3]),
        (Phantom::MarschnerLobb, 33, [1.0; 3]),
    ] {
        let base = phantom.generate(n);
        let data = match base.data() {
            VoxelData::U8(v) => VoxelData::U8(Voxels::owned(v.as_slice().to_vec())),
            VoxelData::F32(v) => VoxelData::F32(Voxels::owned(v.as_slice().to_vec())),
            _ => unreachable!("the phantoms are u8 and f32"),
        };
        let vol = Volume::new(base.dims(), spacing, data, "phantom").unwrap();
        let grid = BrickGrid::from_volume(&vol, 8).unwrap();
        let tf = families::for_phantom(phantom);
        let s = SampledTf::new(&tf, grid.value_range());
        for shade in [true, false] {
            for (step, az, el, projection) in [
                (1.0, 30.0, 20.0, Projection::Orthographic),
                (0.5, -70.0, 45.0, Projection::Perspective),
                (0.8, 180.0, -10.0, Projection::Perspective),
            ] {
                let settings = RenderSettings {
                    step,
                    ert: 0.99,
                    shade,
                    jitter: None,
                };
                let cls = s.classify(&tf.weights, step);
                let cam = Camera::orbit(&vol, az, el, 53, 47, projection);
                let what = format!("{phantom:?} shade {shade} view {az},{el} {projection:?}");
                let (reference, _) = RayCaster::new(&vol, &cls, settings)
                    .with_scalar_loop(true)
                    .render(&cam);
                assert!(reference.mean_alpha() > 0.05, "{what} shows something");
                for avx2 in [true, false] {
                    let caster = RayCaster::new(&vol, &cls, settings).with_avx2(avx2);
                    let (img, _) = caster.render(&cam);
                    assert_eq!(
                        img.max_abs_diff(&reference),
                        Some(0.0),
                        "{what} {}",
                        caster.simd()
                    );
                    let bricks = render_by_bricks(&grid, &caster, &cam);
                    assert_eq!(bricks.max_abs_diff(&reference), Some(0.0), "{what} bricks");
                }
            }
        }
    }
}

/// `Cell::gradient` is the derivative of `Cell::value`: the interpolant is linear along
/// each axis inside a cell, so a difference quotient along an axis gives it up to rounding.
#[test]
fn cell_gradient_is_the_derivative_of_the_trilinear_value() {
    let mut rng = StdRng::seed_from_u64(0x9e5d);
    for _ in 0..2000 {
        let c: [f32; 8] = std::array::from_fn(|_| rng.gen_range(-100.0..100.0));
        let f: [f32; 3] = std::array::from_fn(|_| rng.gen_range(0.0..0.75));
        let cell = sampler::Cell { c, f };
        let g = cell.gradient();
        for a in 0..3 {
            let h = 0.25;
            let mut f1 = f;
            f1[a] += h;
            let q = (sampler::Cell { c, f: f1 }.value() - cell.value()) / h;
            assert!((q - g[a]).abs() <= 1e-3, "axis {a}: {q} vs {}", g[a]);
        }
    }
}

#[test]
fn jitter_offsets_are_reproducible_in_range_and_depend_on_the_seed() {
    let (mut same_as_other_seed, mut sum) = (0, 0.0f64);
    for y in 0..64 {
        for x in 0..64 {
            let a = jitter::offset(7, x, y);
            assert_eq!(a, jitter::offset(7, x, y));
            assert!((0.0..1.0).contains(&a), "offset {a} at {x},{y}");
            same_as_other_seed += usize::from(a == jitter::offset(8, x, y));
            sum += f64::from(a);
        }
    }
    assert!(
        same_as_other_seed < 4,
        "{same_as_other_seed} pixels ignore the seed"
    );
    // Spread over the step, not clustered: the mean of 4096 uniform draws is 0.5 ± 0.005.
    let mean = sum / 4096.0;
    assert!((mean - 0.5).abs() < 0.03, "mean offset {mean}");
    // Neighbouring pixels are not ordered like the lattice phase they replace.
    let row: Vec<f32> = (0..64).map(|x| jitter::offset(7, x, 3)).collect();
    let rising = row.windows(2).filter(|w| w[1] > w[0]).count();
    assert!((16..48).contains(&rising), "{rising} of 63 steps rise");
}

#[test]
fn without_jitter_every_pixel_ray_is_the_camera_ray_and_with_it_rays_move_under_a_step() {
    let vol = Phantom::SheppLogan.generate(24);
    let tf = families::for_phantom(Phantom::SheppLogan);
    let s = SampledTf::new(
        &tf,
        crate::brick::ValueRange {
            min: 0.0,
            max: 255.0,
        },
    );
    let plain = RenderSettings::default();
    assert_eq!(plain.jitter, None, "jitter is off by default");
    let jittered = RenderSettings {
        step: 0.8,
        jitter: Some(3),
        ..plain
    };
    let cls = s.classify(&tf.weights, plain.step);
    let a = RayCaster::new(&vol, &cls, plain);
    let b = RayCaster::new(&vol, &cls, jittered);
    for projection in [Projection::Orthographic, Projection::Perspective] {
        let cam = Camera::orbit(&vol, 20.0, 10.0, 16, 12, projection);
        let frame = cam.frame();
        for (x, y) in [(0, 0), (5, 7), (15, 11)] {
            let camera_ray = IndexRay::new(
                &cam.ray(&frame, f64::from(x) + 0.5, f64::from(y) + 0.5),
                vol.spacing(),
                vol.unit(),
            );
            assert_eq!(a.pixel_ray(&cam, &frame, x, y), camera_ray);
            let r = b.pixel_ray(&cam, &frame, x, y);
            assert_eq!((r.d, r.dir), (camera_ray.d, camera_ray.dir));
            // The origin moved forward along d by offset · step.
            let moved = (0..3)
                .map(|k| (r.o[k] - camera_ray.o[k]) * camera_ray.d[k])
                .sum::<f32>()
                / (0..3)
                    .map(|k| camera_ray.d[k] * camera_ray.d[k])
                    .sum::<f32>();
            let want = jitter::offset(3, x, y) * 0.8;
            assert!((moved - want).abs() < 1e-3, "moved {moved}, want {want}");
        }
    }
}

#[test]
fn jittered_frames_are_reproducible_differ_by_seed_and_equal_brick_by_brick() {
    let vol = Phantom::SheppLogan.generate(29);
    let grid = BrickGrid::from_volume(&vol, 8).unwrap();
    let tf = families::for_phantom(Phantom::SheppLogan);
    let s = SampledTf::new(&tf, grid.value_range());
    for (step, shade, projection) in [
        (1.0, false, Projection::Orthographic),
        (0.7, true, Projection::Orthographic),
        (0.6, false, Projection::Perspective),
    ] {
        let with_seed = |seed| RenderSettings {
            step,
            ert: 0.95,
            shade,
            jitter: seed,
        };
        let cls = s.classify(&tf.weights, step);
        let cam = Camera::orbit(&vol, 35.0, 25.0, 33, 31, projection);
        let one = RayCaster::new(&vol, &cls, with_seed(Some(1)));
        let (a, _) = one.render(&cam);
        let (again, _) = RayCaster::new(&vol, &cls, with_seed(Some(1))).render(&cam);
        let (other, _) = RayCaster::new(&vol, &cls, with_seed(Some(2))).render(&cam);
        let (plain, _) = RayCaster::new(&vol, &cls, with_seed(None)).render(&cam);
        assert!(a.mean_alpha() > 0.05);
        assert_eq!(a.max_abs_diff(&again), Some(0.0), "same seed, same frame");
        assert!(
            a.max_abs_diff(&other).unwrap() > 1e-3,
            "another seed moves samples"
        );
        assert!(
            a.max_abs_diff(&plain).unwrap() > 1e-3,
            "jitter moves samples"
        );
        assert_eq!(
            a.max_abs_diff(&render_by_bricks(&grid, &one, &cam)),
            Some(0.0),
            "{projection:?} step {step} shade {shade}"
        );
    }
}

#[test]
fn one_caster_renders_boxes_for_several_cameras_as_fresh_casters_do() {
    // The caster keeps the pixel rays of the first camera it renders a box for; boxes
    // seen by another camera (or jittered) must still get that camera's own rays.
    let vol = Phantom::SheppLogan.generate(24);
    let tf = families::for_phantom(Phantom::SheppLogan);
    let grid = BrickGrid::from_volume(&vol, 8).unwrap();
    let s = SampledTf::new(&tf, grid.value_range());
    for jitter in [None, Some(7)] {
        let settings = RenderSettings {
            jitter,
            ..RenderSettings::default()
        };
        let cls = s.classify(&[1.0, 1.0], settings.step);
        let shared = RayCaster::new(&vol, &cls, settings);
        let cams = [
            Camera::orbit(&vol, 30.0, 20.0, 24, 20, Projection::Perspective),
            Camera::orbit(&vol, -60.0, 10.0, 24, 20, Projection::Orthographic),
        ];
        for _ in 0..2 {
            for cam in &cams {
                let frame = cam.frame();
                let rect = PixelRect {
                    x0: 3,
                    y0: 2,
                    x1: 21,
                    y1: 17,
                };
                for id in grid.ids() {
                    let b = grid.index_box(id);
                    let (got, st) = shared.render_box(cam, &frame, rect, &b);
                    let fresh = RayCaster::new(&vol, &cls, settings);
                    let (want, want_st) = fresh.render_box(cam, &frame, rect, &b);
                    assert_eq!(st, want_st);
                    for (g, w) in got.iter().zip(&want) {
                        assert_eq!(g.map(f32::to_bits), w.map(f32::to_bits));
                    }
                }
            }
        }
    }
}
