//! `vidslam replay --depth gt` through the binary: the files it promises, the report's keys (the
//! accelerometer bias against the one the ground truth implies among them), clear errors for a
//! bad configuration and for a dataset without depth.

mod cli;
mod scratch;

use cli::{text, vidslam};
use std::path::Path;

/// `vidslam replay DATA --depth gt --out OUT --quiet` plus `extra`.
fn replay_gt(data: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "replay",
        data.to_str().unwrap(),
        "--depth",
        "gt",
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ];
    args.extend_from_slice(extra);
    vidslam(&args)
}

#[test]
fn replay_writes_trajectory_report_csv_and_plot() {
    let tmp = scratch::dir("replay-cli");
    let data = tmp.join("data");
    let o = vidslam(&[
        "sim",
        "--out",
        data.to_str().unwrap(),
        "--start-s",
        "12",
        "--seconds",
        "4.5",
        "--force",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let out = tmp.join("out");
    let o = replay_gt(&data, &out, &[]);
    assert!(o.status.success(), "{}", text(&o));
    let t = text(&o);
    assert!(
        t.contains("ATE RMSE") && t.contains("frames tracked"),
        "{t}"
    );
    for f in [
        "trajectory.tum",
        "report.json",
        "frames.csv",
        "trajectory.png",
    ] {
        assert!(out.join(f).is_file(), "missing {f}");
    }
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    for k in [
        "frames_in",
        "frames_tracked",
        "frames_flagged",
        "tracking_ms_p50",
        "tracking_ms_p99",
        "tracking_ms_max",
        "ate_rmse_m",
        "scale_error_pct",
    ] {
        assert!(
            rep.get(k).is_some_and(|v| !v.is_null()),
            "report.json lacks {k}"
        );
    }
    assert_eq!(rep["frames_in"], 90);
    assert_eq!(rep["frames_flagged"], 0);
    assert!(rep["ate_rmse_m"].as_f64().unwrap() < 0.02, "{rep}");
    // 4.5 s of flight is one 10 s segment of the same alignment: its ATE is the whole run's.
    let segs = rep["error_per_10s"].as_array().expect("error_per_10s");
    assert_eq!(segs.len(), 1, "{rep}");
    assert_eq!(segs[0]["poses"], rep["matched_poses"]);
    let seg_ate = segs[0]["ate_rmse_m"].as_f64().unwrap();
    assert!((seg_ate - rep["ate_rmse_m"].as_f64().unwrap()).abs() < 1e-12);
    let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    assert_eq!(csv.lines().count(), 91);
    // The accelerometer bias: estimated, implied by the ground truth (two 2 s windows of the
    // simulator's IMU), and close on tracking against true depth.
    let bias = |k: &str| -> Vec<f64> {
        rep[k]
            .as_array()
            .unwrap_or_else(|| panic!("report.json lacks {k}: {rep}"))
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect()
    };
    assert_eq!(bias("accel_bias_est_m_s2").len(), 3);
    assert_eq!(bias("accel_bias_gt_m_s2").len(), 3);
    let off = rep["accel_bias_error_m_s2"].as_f64().unwrap();
    assert!(off < 0.05, "{rep}");
    assert!(t.contains("implied by gt"), "{t}");

    // A config key that does not exist: the error names the file, the line and the key.
    let cfg = tmp.join("bad.toml");
    std::fs::write(&cfg, "[tracking]\nhuber_gray = 9.0\nhubber_gray = 3.0\n").unwrap();
    let o = replay_gt(&data, &out, &["--config", cfg.to_str().unwrap()]);
    let t = text(&o);
    assert!(!o.status.success());
    assert!(
        t.contains("bad.toml") && t.contains("line 3") && t.contains("hubber_gray"),
        "{t}"
    );

    // No ground-truth depth for a keyframe: named.
    std::fs::remove_dir_all(data.join("mav0/depth0")).unwrap();
    let o = replay_gt(&data, &out, &[]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains("depth0"), "{t}");
    let _ = std::fs::remove_dir_all(Path::new(&tmp));
}

#[test]
fn config_prints_every_table_and_checks_files() {
    let o = vidslam(&["config"]);
    assert!(o.status.success(), "{}", text(&o));
    let t = String::from_utf8_lossy(&o.stdout).to_string();
    for table in [
        "[tracking]",
        "[mapping]",
        "[static_detector]",
        "[bootstrap]",
    ] {
        assert!(t.contains(table), "missing {table} in\n{t}");
    }
    let bad = scratch::path("bad-config.toml");
    std::fs::write(&bad, "[bootstrap]\nmin_initial_points = -3\n").unwrap();
    let o = vidslam(&["config", "--config", bad.to_str().unwrap()]);
    let t = text(&o);
    assert!(!o.status.success() && t.contains("line 2"), "{t}");
    let _ = std::fs::remove_file(&bad);
    for cmd in ["demo", "replay", "config"] {
        let o = vidslam(&[cmd, "--help"]);
        assert!(o.status.success(), "{cmd} --help");
    }
}

/// `vidslam demo --seeds 1,2 --seconds 3`: one simulated dataset and replay per seed, and the
/// summary with one row per seed in OUT/seeds.json.
#[test]
fn demo_over_several_seeds_writes_the_distribution() {
    let out = scratch::dir("demo-seeds");
    let o = vidslam(&[
        "demo",
        "--seeds",
        "1,2",
        "--seconds",
        "3",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("ATE over 2 seeds"), "{t}");
    for s in [1, 2] {
        assert!(out.join(format!("seed-{s}/replay/report.json")).exists());
    }
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("seeds.json")).unwrap()).unwrap();
    let rows = v["seeds"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    assert_eq!(
        (rows[0]["seed"].as_u64(), rows[1]["seed"].as_u64()),
        (Some(1), Some(2))
    );
    for r in rows {
        assert!(
            r["ate_rmse_m"]
                .as_f64()
                .is_some_and(|a| a.is_finite() && a > 0.0),
            "{r}"
        );
        // Null only if no window of the 3 s flight could be solved.
        let off = &r["accel_bias_error_m_s2"];
        assert!(
            off.is_null() || off.as_f64().is_some_and(|b| b.is_finite() && b >= 0.0),
            "{r}"
        );
    }
    assert!(
        t.contains("accel bias off") && t.contains("body offset"),
        "{t}"
    );
    for r in rows {
        // 3 s of the built-in flight is the pad and the start of the climb: the body does not
        // turn, so no body-frame offset can be told from a world rotation.
        assert!(r["rot_body_offset_deg"].is_null(), "{r}");
    }
    assert!(v["ate_rmse_m_median"].as_f64().is_some());
    assert_eq!(v["realtime"].as_bool(), Some(false));
    assert!(!t.contains("views skipped"), "{t}");
    // Paced as on the vehicle: the same summary plus the real-time columns.
    let rt = out.join("rt");
    let o = vidslam(&[
        "demo",
        "--realtime",
        "--seeds",
        "2",
        "--seconds",
        "3",
        "--quiet",
        "--out",
        rt.to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("adjusted / discarded   views skipped"), "{t}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(rt.join("seeds.json")).unwrap()).unwrap();
    assert_eq!(v["realtime"].as_bool(), Some(true));
    let row = &v["seeds"][0];
    assert!(row["mapping_views_skipped"].as_u64().is_some(), "{row}");
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(rt.join("seed-2/replay/report.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        report["realtime"].as_bool(),
        Some(true),
        "replayed in real time"
    );
    let o = vidslam(&["demo", "--seeds", "3-1", "--out", out.to_str().unwrap()]);
    assert!(
        !o.status.success() && text(&o).contains("ascending"),
        "{}",
        text(&o)
    );
    let _ = std::fs::remove_dir_all(&out);
}
