//! What several test modules share: the `volrad` binary, the repository root, path text.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs the `volrad` binary built for these tests.
pub fn volrad(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_volrad"))
        .args(args)
        .output()
        .expect("the volrad binary runs")
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A path as an argument.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The repository's root (the root crate's manifest directory).
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}
