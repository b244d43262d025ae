//! Where the real-data tests find the catalogue's volumes.
//!
//! Those tests are `#[ignore = "needs ../shared/data (real volumes)"]`: a plain `cargo test`
//! counts them as ignored, and `cargo test -- --ignored` runs them. Run that way without the
//! data, they fail with the reason instead of passing without having checked anything.

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
