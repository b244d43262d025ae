//! What the CLI's integration tests share: running the built `pofvr` binary.

// Each test crate that includes this module uses part of it.
#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output};

/// `pofvr ARGS` run in `dir`, its output collected.
pub(crate) fn pofvr(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pofvr"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run pofvr")
}

/// A run's standard error, as text.
pub(crate) fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}
