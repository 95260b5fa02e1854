//! Helpers shared by the workspace-level tests.

#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

/// `../shared/data/<name>` beside the repository, or `None` (with a one-line note) when it is absent on a
/// user's clone. Under CI (`CI=true`) a missing folder fails the test.
pub fn shared_data(name: &str) -> Option<PathBuf> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data").join(name);
    if path.is_dir() {
        return Some(path);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("{} is missing, and CI always has ../shared/data", path.display());
    }
    eprintln!("skipped: {} not found (../shared/data is only beside CI and developer checkouts)", path.display());
    None
}

/// Runs the `m2smap` binary.
pub fn m2smap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_m2smap")).args(args).output().expect("run m2smap")
}
