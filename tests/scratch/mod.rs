//! Scratch space for the integration tests: one directory per test (or per shared fixture) under
//! Cargo's `CARGO_TARGET_TMPDIR` (`target/tmp/`), named after it and emptied before use.
//!
//! A rerun reuses the same directory instead of leaving another one in `/tmp` (the renders are
//! 45–90 MB each and fixtures shared through a `OnceLock` have no end-of-run hook to delete them),
//! and `cargo clean` or deleting the clone removes them all. Names are unique within a test binary;
//! Cargo runs the binaries one after the other.

#![allow(dead_code)] // each test binary uses the helpers it needs

use std::path::PathBuf;

/// An empty directory `target/tmp/NAME`, created (and emptied if a previous run left it).
pub fn dir(name: &str) -> PathBuf {
    let dir = path(name);
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    dir
}

/// The path `target/tmp/NAME` with nothing at it (a previous run's file or directory removed).
pub fn path(name: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    if p.is_dir() {
        let _ = std::fs::remove_dir_all(&p);
    } else {
        let _ = std::fs::remove_file(&p);
    }
    p
}
