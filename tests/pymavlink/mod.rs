//! The pymavlink test peers (`tests/peers/*.py`): a check that python3 can import pymavlink.
//!
//! pymavlink is a test requirement (`.ci/requirements.txt`, installed by `.ci/run`): without it
//! the tests that need it fail, they do not skip.

#![allow(dead_code)] // each test binary uses the helpers it needs

use std::ffi::OsStr;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::PathBuf;
use std::process::{Child, ChildStdout, Command, ExitStatus, Stdio};

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

/// A running peer script: it bound a loopback UDP port, announced as `PORT <n>`.
pub struct Peer {
    child: Child,
    out: BufReader<ChildStdout>,
    pub port: u16,
}

impl Peer {
    /// Starts `python3 tests/peers/NAME ARGS…` and reads the port it announces.
    pub fn start<S: AsRef<OsStr>>(name: &str, args: &[S]) -> Peer {
        let mut child = Command::new("python3")
            .arg(peer_script(name))
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap_or_else(|e| panic!("starting python3 tests/peers/{name}: {e}"));
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let mut first = String::new();
        out.read_line(&mut first).unwrap();
        let port: u16 = first
            .strip_prefix("PORT ")
            .and_then(|p| p.trim().parse().ok())
            .unwrap_or_else(|| panic!("tests/peers/{name} did not announce its port: {first:?}"));
        Peer { child, out, port }
    }

    /// Tells the peer to stop (`stop` on its stdin), and returns its exit status and its
    /// `REPORT <json>` line parsed.
    pub fn stop(mut self) -> (ExitStatus, serde_json::Value) {
        writeln!(self.child.stdin.take().unwrap(), "stop").unwrap();
        let mut rest = String::new();
        self.out.read_to_string(&mut rest).unwrap();
        let status = self.child.wait().unwrap();
        let line = rest
            .lines()
            .find_map(|l| l.strip_prefix("REPORT "))
            .unwrap_or_else(|| panic!("no REPORT from the peer: {rest}"));
        (status, serde_json::from_str(line).unwrap())
    }
}
