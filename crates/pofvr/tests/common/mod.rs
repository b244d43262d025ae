//! Where the real-data tests find the catalogue's volumes.
//!
//! Those tests are `#[ignore = "needs ../shared/data (real volumes)"]`: a plain `cargo test`
//! counts them as ignored, and `cargo test -- --ignored` runs them. Run that way without the
//! data, they fail with the reason instead of passing without having checked anything.
//!
//! Each test crate that includes this module uses part of it.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The catalogue's directory: `$POFVR_DATA` when set, else `shared/data` beside the
/// repository (`../shared/data` from its root). Panics, naming the directory, when it holds
/// no `CATALOG.md`.
pub(crate) fn shared_data() -> PathBuf {
    let dir = match std::env::var_os("POFVR_DATA") {
        Some(d) => PathBuf::from(d),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
    };
    assert!(
        dir.join("CATALOG.md").is_file(),
        "this test needs the real volumes: {} has no CATALOG.md (set POFVR_DATA to the \
         catalogue's directory, or run the tests without --ignored)",
        dir.display()
    );
    dir
}

/// Every catalogued volume (its path under [`shared_data`]) with its family in `tfs/`.
pub(crate) const CATALOGUE: [(&str, &str); 7] = [
    ("neghip/neghip.nhdr", "sim-isobands.json"),
    ("ironprot/ironprot.nhdr", "sim-isobands.json"),
    ("hydrogen/hydrogen.nhdr", "sim-hydrogen.json"),
    (
        "headsq_quarter/headsq_quarter.nhdr",
        "ct-head-skin-bone.json",
    ),
    (
        "lidc2_ct_chest/lidc2_ct_chest.nhdr",
        "ct-chest-skin-bone.json",
    ),
    ("ch2better_mri/ch2better_mri.nhdr", "mri-brain.json"),
    ("ch2better_mri/ch2better_mri.nhdr", "mri-brain-opaque.json"),
];

/// Every catalogued volume, opened from [`shared_data`] one at a time, with its path, its
/// family's file name and the family.
pub(crate) fn open_catalogue() -> impl Iterator<
    Item = (
        &'static str,
        &'static str,
        pofvr::Volume,
        pofvr::render::TransferFunction,
    ),
> {
    let data = shared_data();
    CATALOGUE.into_iter().map(move |(vol, tf)| {
        let volume = pofvr::Volume::open(&data.join(vol), None).unwrap();
        let family = pofvr::render::TransferFunction::from_file(&family_file(tf)).unwrap();
        (vol, tf, volume, family)
    })
}

/// A family file of the repository's `tfs/`.
pub(crate) fn family_file(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tfs")
        .join(name)
}
