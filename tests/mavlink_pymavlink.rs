//! End to end against a real MAVLink peer: `vidslam mavlink play` (the real binary) streams a
//! generated trajectory to `tests/peers/mavlink_listener.py`, a pymavlink listener on a free
//! loopback port that plays the flight controller and checks every message it decodes against
//! the trajectory (its own implementation of the frame conventions). See the script's docstring.
//!
//! pymavlink is a test requirement (`.ci/requirements.txt`, installed by `.ci/run`): without it
//! these tests fail, they do not skip.

mod pymavlink;
mod scratch;

use pymavlink::{Peer, require_pymavlink};

use std::path::{Path, PathBuf};
use std::process::Command;

/// 2 s at 100 Hz of smooth 6-DoF motion (positions within 2 m so f32 keeps 1e-6), EuRoC CSV.
fn write_trajectory(dir: &Path) -> PathBuf {
    let mut text = String::from("#timestamp [ns],px,py,pz,qw,qx,qy,qz\n");
    for i in 0..=200i64 {
        let t = i as f64 * 0.01;
        let p = [1.5 * (0.8 * t).sin(), (0.6 * t).cos() - 1.0, 1.0 + 0.2 * t];
        let q = nalgebra::UnitQuaternion::from_euler_angles(
            0.2 * t.sin(),
            0.15 * (1.3 * t).cos(),
            0.8 * t,
        );
        text.push_str(&format!(
            "{},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}\n",
            1_403_715_274_302_140_000 + i * 10_000_000,
            p[0],
            p[1],
            p[2],
            q.w,
            q.i,
            q.j,
            q.k
        ));
    }
    let path = dir.join("trajectory.csv");
    std::fs::write(&path, text).unwrap();
    path
}

/// Runs the listener with `listener_args` and vidslam with `play_args` (+ `--to`), returns the
/// listener's JSON report after asserting both succeeded.
fn run_pair(name: &str, listener_args: &[&str], play_args: &[&str]) -> serde_json::Value {
    require_pymavlink();
    let dir = scratch::dir(&format!("mavlink-{name}"));
    std::fs::create_dir_all(&dir).unwrap();
    let traj = write_trajectory(&dir);
    let mut args: Vec<std::ffi::OsString> = vec!["--trajectory".into(), traj.clone().into()];
    args.extend(listener_args.iter().map(|a| a.into()));
    let listener = Peer::start("mavlink_listener.py", &args);
    let port = listener.port;

    let play = Command::new(env!("CARGO_BIN_EXE_vidslam"))
        .args(["mavlink", "play"])
        .arg(&traj)
        .arg("--to")
        .arg(format!("udpout:127.0.0.1:{port}"))
        .args(play_args)
        .output()
        .expect("running vidslam");
    let play_log = String::from_utf8_lossy(&play.stderr).to_string();
    eprintln!("{play_log}");
    assert!(
        play.status.success(),
        "vidslam mavlink play failed: {play_log}"
    );

    let (status, report) = listener.stop();
    std::fs::remove_dir_all(&dir).ok();
    eprintln!("listener report ({name}): {report}");
    let failures = report["failures"].as_array().unwrap();
    assert!(
        status.success() && failures.is_empty(),
        "pymavlink listener found problems:\n{}\nreport: {report}",
        failures
            .iter()
            .map(|f| format!("  - {f}"))
            .collect::<Vec<_>>()
            .join("\n")
    );
    report
}

#[test]
fn odometry_stream_decodes_and_matches_the_trajectory_in_frd() {
    let report = run_pair(
        "odometry",
        &[
            "--rate-hz",
            "25",
            "--mount-rpy-deg",
            "180,0,90",
            "--pose-std",
            "0.05,0.02",
            "--velocity-std",
            "0.1,0.01",
            "--discontinuity-at",
            "20",
            "--inject-nan-at",
            "30",
        ],
        &[
            "--rate-hz",
            "25",
            "--realtime",
            "--mount-rpy-deg",
            "180,0,90",
            "--position-std-m",
            "0.05",
            "--attitude-std-rad",
            "0.02",
            "--velocity-std-m-s",
            "0.1",
            "--angular-rate-std-rad-s",
            "0.01",
            "--discontinuity-at",
            "20",
            "--inject-nan-at",
            "30",
        ],
    );
    // The listener checked each item; these confirm it had something to check.
    assert_eq!(
        report["pose_messages"], 50,
        "2 s at 25 Hz = 51 samples, one NaN dropped"
    );
    assert_eq!(report["counts"]["ODOMETRY"], 50);
    assert!(report["heartbeats"].as_u64().unwrap() >= 3, "{report}");
    assert_eq!(report["timesync_reply_ok"], true);
    assert_eq!(report["reset_counters"], serde_json::json!([0, 1]));
}

#[test]
fn legacy_vision_messages_in_the_fc_time_base() {
    let report = run_pair(
        "legacy",
        &[
            "--rate-hz",
            "25",
            "--messages",
            "legacy",
            "--frame",
            "ned",
            "--discontinuity-at",
            "10",
            "--fc-clock-offset-s",
            "1000",
        ],
        &[
            "--rate-hz",
            "25",
            "--realtime",
            "--messages",
            "legacy",
            "--frame",
            "ned",
            "--discontinuity-at",
            "10",
            "--time-base",
            "fc",
            "--timesync-max-rtt-ms",
            "200",
        ],
    );
    assert_eq!(report["pose_messages"], 51);
    assert_eq!(report["counts"]["VISION_SPEED_ESTIMATE"], 51);
    assert!(report["time_bases"]["fc"].as_u64().unwrap() > 0, "{report}");
    assert!(
        report["timesync_requests_answered"].as_u64().unwrap() >= 5,
        "{report}"
    );
    assert_eq!(report["reset_counters"], serde_json::json!([0, 1]));
}
