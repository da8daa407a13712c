//! The pymavlink test peers (`tests/peers/*.py`): a check that python3 can import pymavlink.
//!
//! pymavlink is a test requirement (`.ci/requirements.txt`, installed by `.ci/run`): without it
//! the tests that need it fail, they do not skip.

#![allow(dead_code)] // each test binary uses the helpers it needs

use std::path::PathBuf;
use std::process::Command;

/// The script `tests/peers/NAME`.
pub fn peer_script(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/peers")
        .join(name)
}

/// Panics, saying how to install it, unless python3 imports pymavlink (MAVLink 2).
pub fn require_pymavlink() {
    let out = Command::new("python3")
        .args([
            "-c",
            "import os; os.environ['MAVLINK20']='1'; from pymavlink import mavutil",
        ])
        .output();
    match out {
        Ok(o) if o.status.success() => {}
        Ok(o) => panic!(
            "pymavlink is not importable by python3 ({}): run `bash .ci/run` (CI installs the \
             Python test peers from .ci/requirements.txt)",
            String::from_utf8_lossy(&o.stderr).trim()
        ),
        Err(e) => panic!("cannot run python3 ({e}): run `bash .ci/run` to install the test peers"),
    }
}
