//! Helpers shared by the workspace-level tests.

#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

/// The file where tests record what they skipped; `make test` prints it at the end (cargo hides a passing
/// test's stderr, so a note there alone is never seen).
pub fn skip_list() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/skipped-tests.txt")
}

/// `../shared/data/<name>` beside the repository, or `None` when it is absent on a user's clone: the calling
/// test is then recorded in [`skip_list`] and returns early. Under CI (`CI=true`) a missing folder fails the
/// test.
pub fn shared_data(name: &str) -> Option<PathBuf> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data").join(name);
    if path.is_dir() {
        return Some(path);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("{} is missing, and CI always has ../shared/data", path.display());
    }
    record_skip(&skip_list(), &format!("{} not found", path.display()));
    None
}

/// Appends "<test name>: <why>" to `list` (and says it on stderr).
pub fn record_skip(list: &std::path::Path, why: &str) {
    use std::io::Write;
    let test = std::thread::current().name().unwrap_or("a test").to_owned();
    eprintln!("skipped: {test}: {why}");
    if let Some(dir) = list.parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    if let Ok(mut f) = std::fs::OpenOptions::new().create(true).append(true).open(list) {
        let _ = writeln!(f, "{test}: {why}");
    }
}

/// Runs the `m2smap` binary.
pub fn m2smap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_m2smap")).args(args).output().expect("run m2smap")
}

/// The map-level metric keys of `m2smap run`'s summary.json and frames.jsonl, in the column order of the eval
/// report's "Map-level metrics" table.
pub const MAP_LEVEL_KEYS: [&str; 11] = [
    "free_space_violation",
    "free_space_violation_sq",
    "sq_behind_support",
    "adhesion_map",
    "adhesion_map_sq",
    "g2r_true_rmse_m",
    "g2r_true_sq_rmse_m",
    "penetration_p95_m",
    "penetration_max_m",
    "penetration_sq_p95_m",
    "penetration_sq_max_m",
];

/// Runs `m2smap run DATASET --out OUT EXTRA…`, asserts it succeeded and returns the summary.json it wrote.
pub fn run_ok(dataset: &std::path::Path, out: &std::path::Path, extra: &[&str]) -> serde_json::Value {
    let mut args = vec!["run", dataset.to_str().unwrap(), "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    let o = m2smap(&args);
    assert!(o.status.success(), "m2smap run failed: {}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

/// Runs `m2smap args` and checks it fails with one `error: ` line that contains every one of `needles`.
pub fn expect_failure(args: &[&str], needles: &[&str]) {
    let o = m2smap(args);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "expected failure for {needles:?}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "one line: {stderr}");
    assert!(
        stderr.starts_with("error: ") && needles.iter().all(|n| stderr.contains(n)),
        "{stderr:?} should name {needles:?}"
    );
    assert!(!stderr.contains("panicked"));
}
