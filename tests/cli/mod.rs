//! The built `vidslam` binary run from the integration tests, and its output as text.

#![allow(dead_code)] // each test binary uses the helpers it needs

use std::process::{Command, Output};

/// `vidslam ARGS…` run to completion (the binary Cargo built for this test run).
pub fn vidslam(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_vidslam"))
        .args(args)
        .output()
        .expect("run vidslam")
}

/// Standard output followed by standard error, for assertions on messages and for failure text.
pub fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}
