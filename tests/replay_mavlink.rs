//! The odometry's live output to a flight controller, end to end: `vidslam replay --mavlink`
//! (the real binary, the full odometry) streams a rendered take-off with a covered lens to
//! `tests/peers/mavlink_recorder.py`, a pymavlink peer on a free loopback port, and every
//! ODOMETRY message it decoded is compared with what the replay wrote itself (trajectory.tum,
//! frames.csv, report.json): one message per valid frame, the published pose in the flight
//! controller's FRD frames, the frames' spacing in `time_usec`, quality -1 exactly while lost,
//! and `reset_counter` ending at the re-initialisations plus the loop closer's jumps beyond
//! `[loop_closure] reset_min_jump_m`.
//!
//! pymavlink is a test requirement (`.ci/requirements.txt`, installed by `.ci/run`): without it
//! this test fails, it does not skip.

mod cli;
mod pymavlink;
mod scratch;

use cli::{text, vidslam};
use pymavlink::{Peer, require_pymavlink};
use std::path::Path;

/// `trajectory.tum` rows: `(t_s, [x, y, z])`.
fn read_tum(path: &Path) -> Vec<(f64, [f64; 3])> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            (v[0], [v[1], v[2], v[3]])
        })
        .collect()
}

/// `frames.csv`'s phase column, one per valid frame.
fn read_phases(path: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = header.iter().position(|h| *h == "phase").unwrap();
    lines
        .map(|l| l.split(',').nth(col).unwrap().to_string())
        .collect()
}

#[test]
fn the_replay_streams_every_valid_frame_with_its_resets_to_a_pymavlink_peer() {
    require_pymavlink();
    let tmp = scratch::dir("replay-mavlink");
    let data = tmp.join("data");
    let o = vidslam(&[
        "sim",
        "--out",
        data.to_str().unwrap(),
        "--seconds",
        "9",
        "--force",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    // Loop closure on (the default, written out so that the test does not depend on the
    // default), so its jumps (if any) are counted with the resets.
    let cfg = tmp.join("vidslam.toml");
    std::fs::write(&cfg, "[loop_closure]\nenabled = true\n").unwrap();

    let peer = Peer::start::<&str>("mavlink_recorder.py", &[]);
    let port = peer.port;

    let out = tmp.join("out");
    let cover_start_s = 5.5;
    let o = vidslam(&[
        "replay",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--config",
        cfg.to_str().unwrap(),
        "--quiet",
        "--cover-lens",
        &format!("{cover_start_s}:0.5"),
        "--mavlink",
        &format!("udpout:127.0.0.1:{port}"),
        "--rate-hz",
        "50",
    ]);
    let log = text(&o);
    eprintln!("{log}");
    assert!(o.status.success(), "vidslam replay --mavlink failed: {log}");
    assert!(log.contains("mavlink: "), "the sender's summary: {log}");

    let (status, report) = peer.stop();
    assert!(status.success(), "the peer failed: {report}");
    let msgs = report["odometry"].as_array().unwrap();

    let traj = read_tum(&out.join("trajectory.tum"));
    let phases = read_phases(&out.join("frames.csv"));
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["bad_bytes"], 0, "{}", report["counts"]);
    assert_eq!(phases.len(), traj.len());
    assert_eq!(
        msgs.len(),
        traj.len(),
        "one ODOMETRY per valid frame (50 Hz admits every 20 Hz frame)"
    );
    assert!(
        phases.iter().any(|p| p == "lost"),
        "the lens cover loses track"
    );

    let f = |m: &serde_json::Value, k: &str, i: usize| m[k][i].as_f64().unwrap();
    let t0_us = msgs[0]["time_usec"].as_i64().unwrap();
    let mut last_reset = 0;
    let mut first_reset_t_s = None;
    for (k, (m, ((t_s, p), phase))) in msgs.iter().zip(traj.iter().zip(&phases)).enumerate() {
        // FC local FRD = world (z up) turned 180° about x.
        let fc = [p[0], -p[1], -p[2]];
        for (i, want) in fc.iter().enumerate() {
            let got = f(m, "xyz", i);
            assert!(
                (got - want).abs() < 1e-4,
                "message {k} axis {i}: {got} vs {want}"
            );
        }
        let dt_us = m["time_usec"].as_i64().unwrap() - t0_us;
        let want_us = ((t_s - traj[0].0) * 1e6).round() as i64;
        assert!(
            (dt_us - want_us).abs() <= 2,
            "message {k}: {dt_us} µs vs {want_us}"
        );
        let q = m["quality"].as_i64().unwrap();
        match phase.as_str() {
            "lost" => assert_eq!(q, -1, "message {k} while lost"),
            "static" => assert_eq!(q, 100, "message {k} at rest"),
            _ => assert!((1..=100).contains(&q), "message {k}: quality {q}"),
        }
        if phase != "lost" {
            assert!(
                m["pose_covariance_0"].is_f64(),
                "message {k} ({phase}) has the tracker's covariance"
            );
        }
        assert_eq!(
            (m["sysid"].as_i64(), m["compid"].as_i64()),
            (Some(1), Some(197))
        );
        let r = m["reset_counter"].as_i64().unwrap();
        assert!(r >= last_reset, "message {k}: reset_counter went back");
        if r > 0 && first_reset_t_s.is_none() {
            first_reset_t_s = Some(t_s - traj[0].0);
        }
        last_reset = r;
    }
    let resets = rep["resets"].as_i64().unwrap();
    let jumps = rep["loop_closure"]["reset_jumps"].as_i64().unwrap();
    assert!(resets >= 1, "the covered lens is a reset: {rep}");
    assert_eq!(
        last_reset,
        (resets + jumps) % 256,
        "resets {resets} + jumps {jumps}"
    );
    if jumps == 0 {
        let t = first_reset_t_s.unwrap();
        assert!(
            t >= cover_start_s - 0.5,
            "the first reset at {t:.2} s, the lens covered from {cover_start_s} s after the first frame"
        );
    }
}
