use super::*;

#[test]
fn raw_round_trip_is_memory_mapped_and_exact() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("v.raw");
    let data: Vec<u16> = (0..4 * 3 * 2).map(|i| i * 1000).collect();
    std::fs::write(&p, bytemuck::cast_slice(&data)).unwrap();
    let vol = Volume::open(&p, Some(&RawSpec::new([4, 3, 2], DataType::U16))).unwrap();
    assert!(vol.data().is_mapped());
    assert_eq!(vol.value(3, 2, 1), 23000.0);
}

#[test]
fn raw_size_mismatch_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("short.raw");
    std::fs::write(&p, [0u8; 10]).unwrap();
    let e = Volume::open(&p, Some(&RawSpec::new([2, 2, 2], DataType::U16)))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("short.raw") && e.contains("expected 16") && e.contains("got 10"),
        "{e}"
    );
}
