use super::*;
use crate::render::families;
use crate::volume::phantom::Phantom;

/// A `.npy` file of `(h, w, 4)` f32 values as numpy writes it (version 1).
fn npy_bytes(h: usize, w: usize, values: &[f32]) -> Vec<u8> {
    let mut header =
        format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({h}, {w}, 4), }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend_from_slice(&(header.len() as u16).to_le_bytes());
    b.extend_from_slice(header.as_bytes());
    for v in values {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b
}

#[test]
fn npy_images_read_back_rows_top_first_and_bad_files_are_named() {
    let values: Vec<f32> = (0..2 * 3 * 4).map(|i| i as f32 / 32.0).collect();
    let img = npy::read_rgba_f32(&npy_bytes(2, 3, &values)).unwrap();
    assert_eq!((img.width(), img.height()), (3, 2));
    assert_eq!(
        img.pixel(1, 0),
        [4.0 / 32.0, 5.0 / 32.0, 6.0 / 32.0, 7.0 / 32.0]
    );
    assert_eq!(img.pixel(0, 1)[0], 12.0 / 32.0);
    assert_eq!(npy::psnr(&img, &img), Some(f64::INFINITY));
    let mut other = img.clone();
    other.pixels_mut()[0][0] += 0.1;
    let p = npy::psnr(&img, &other).unwrap();
    // MSE = 0.01 / 24 values.
    assert!((p - 10.0 * (24.0f64 / 0.01).log10()).abs() < 1e-3, "{p}");
    assert!(npy::read_rgba_f32(b"PK\x03\x04")
        .unwrap_err()
        .contains("magic"));
    let full = npy_bytes(2, 3, &values);
    let short = &full[..full.len() - 16];
    assert!(npy::read_rgba_f32(short)
        .unwrap_err()
        .contains("data bytes"));
    assert!(npy::read_rgba_f32(&full[..40])
        .unwrap_err()
        .contains("header"));
    let f8 = npy_bytes(2, 3, &values);
    let f8 = String::from_utf8_lossy(&f8).replace("<f4", "<f8");
    assert!(npy::read_rgba_f32(f8.as_bytes()).is_err());
}

#[test]
fn the_minimum_counts_only_visible_samples_before_termination() {
    let scene = Scene::builder(
        Phantom::SheppLogan.generate(32),
        families::for_phantom(Phantom::SheppLogan),
    )
    .build()
    .unwrap();
    let cam = Camera::orbit(scene.volume(), 30.0, 20.0, 48, 40, Projection::Orthographic);
    let whole = scene.render_reference(&FrameRequest::new(&cam)).unwrap();
    let b = minimum_samples(&scene, scene.default_weights(), &cam);
    assert_eq!(b.rays, whole.stats.rays);
    assert!(
        b.visible > 0 && b.visible < whole.stats.samples,
        "{b:?} of {}",
        whole.stats.samples
    );
    // The floor lies between the visible samples and what the march engine's 4³ cells
    // take, which skip only what they know to be empty; strictly, since the phantom's step
    // edges put samples of zero alpha into cells that can hold opacity.
    let march = scene
        .render(&FrameRequest::new(&cam).engine(crate::Engine::March))
        .unwrap();
    assert!(
        b.visible < b.cell_floor && b.cell_floor < march.stats.samples,
        "{b:?}, march {}",
        march.stats.samples
    );
    // With every basis off, no sample is visible, and no cell can hold opacity.
    let none = minimum_samples(&scene, &[0.0, 0.0], &cam);
    assert_eq!((none.visible, none.cell_floor), (0, 0));
}

/// A stand-in for the VTK peer, run as `sh SCRIPT ARGS…`: it writes `img` as its image and,
/// round after round, 10, 30 and 20 ms as its median re-render time.
#[cfg(unix)]
fn fake_peer(dir: &std::path::Path, img: &[u8]) -> VtkPeer {
    std::fs::write(dir.join("img.npy"), img).unwrap();
    let d = dir.display();
    let script = format!(
        r#"while [ $# -gt 0 ]; do
  case "$1" in --out-npy) npy=$2; shift;; --json) json=$2; shift;; esac; shift
done
n=$(cat "{d}/count" 2>/dev/null || echo 0); echo $((n + 1)) > "{d}/count"
case $((n % 3)) in 0) t=0.010;; 1) t=0.030;; *) t=0.020;; esac
cp "{d}/img.npy" "$npy"
printf '{{"vtk": "fake", "median_rerender_s": %s, "first_render_s": 0.5}}' $t > "$json"
"#
    );
    let path = dir.join("peer.sh");
    std::fs::write(&path, script).unwrap();
    VtkPeer {
        python: "/bin/sh".into(),
        script: path,
        threads: 1,
        repeat: 1,
    }
}

#[cfg(unix)]
#[test]
fn rounds_run_a_vtk_process_each_and_report_medians_and_the_median_ratio() {
    let dir = std::env::temp_dir().join(format!("pofvr-rounds-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (w, h) = (24, 20);
    let img = npy_bytes(h, w, &vec![0.25; h * w * 4]);
    let scene = Scene::builder(
        Phantom::SheppLogan.generate(24),
        families::for_phantom(Phantom::SheppLogan),
    )
    .build()
    .unwrap();
    let volumes = [FrameVolume {
        name: "phantom".into(),
        scene,
    }];
    let bench = FrameBench {
        views: vec![[30.0, 20.0]],
        size: (w as u32, h as u32),
        reps: 1,
        rounds: 3,
        peer: Ok(fake_peer(&dir, &img)),
    };
    let cases = bench_frame(&volumes, &bench, &super::super::NoProgress).unwrap();
    // One view, unshaded and shaded: six VTK processes in all.
    assert_eq!(cases.len(), 2);
    let count = std::fs::read_to_string(dir.join("count")).unwrap();
    assert_eq!(count.trim(), "6");
    for c in &cases {
        assert!(c.vtk.measured, "{:?}", c.vtk.reason);
        assert_eq!(c.vtk.version.as_deref(), Some("fake"));
        let r: Vec<f64> = c.vtk.round_ms.iter().map(|x| x.round()).collect();
        assert_eq!(r, [10.0, 30.0, 20.0]);
        assert!((c.vtk.median_ms.unwrap() - 20.0).abs() < 1e-9);
        assert!(c.vtk.psnr_db.is_some());
        for e in &c.engines {
            assert_eq!(e.round_ms.len(), 3);
            assert_eq!(e.median_ms, median(e.round_ms.clone()));
            let ratios: Vec<f64> = c
                .vtk
                .round_ms
                .iter()
                .zip(&e.round_ms)
                .map(|(v, p)| v / p)
                .collect();
            assert_eq!(e.vtk_over_pofvr, Some(median(ratios)));
        }
    }
    // A peer that fails in a round leaves VTK unmeasured, with the reason.
    let bench = FrameBench {
        rounds: 2,
        peer: Ok(VtkPeer {
            script: dir.join("missing.sh"),
            ..fake_peer(&dir, &img)
        }),
        ..bench
    };
    let cases = bench_frame(&volumes, &bench, &super::super::NoProgress).unwrap();
    for c in &cases {
        assert!(!c.vtk.measured);
        assert!(
            c.vtk.reason.as_deref().unwrap().contains("missing.sh"),
            "{:?}",
            c.vtk.reason
        );
        assert!(c.vtk.round_ms.is_empty());
        assert!(c
            .engines
            .iter()
            .all(|e| e.vtk_over_pofvr.is_none() && e.round_ms.len() == 2));
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
