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
    let (rays, min) = minimum_samples(&scene, scene.default_weights(), &cam);
    assert_eq!(rays, whole.stats.rays);
    assert!(
        min > 0 && min < whole.stats.samples,
        "{min} of {}",
        whole.stats.samples
    );
    // With every basis off, no sample is visible.
    let (_, none) = minimum_samples(&scene, &[0.0, 0.0], &cam);
    assert_eq!(none, 0);
}
