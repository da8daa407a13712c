//! "S-V101": the simulator on the shared EuRoC V1_01 files — the real IMU passed through and images
//! rendered along the real ground-truth path. Skips with a message when the shared data is absent.

mod scratch;

use vidslam::camera::CameraModel;
use vidslam::dataset::{AslDataset, shared_data_or_skip};
use vidslam::sim::{ImuSource, SimConfig, TrajectorySource, generate};
use vidslam::time::TimeNs;

fn v101() -> Option<std::path::PathBuf> {
    shared_data_or_skip("euroc/V1_01_easy_micro/mav0")
}

fn data_lines(text: &str) -> Vec<&str> {
    text.split('\n')
        .filter(|l| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
        .collect()
}

fn t_of(line: &str) -> TimeNs {
    TimeNs(line.split(',').next().unwrap().trim().parse().unwrap())
}

#[test]
fn s_v101_uses_the_real_imu_byte_identically_and_frames_lie_inside_both_spans() {
    let Some(mav0) = v101() else { return };
    let gt_in = mav0.join("state_groundtruth_estimate0/data.csv");
    let imu_in = mav0.join("imu0/data.csv");
    let dir = scratch::dir("sim-v101");
    let mut cfg = SimConfig::new(
        dir.clone(),
        TrajectorySource::File(gt_in.clone()),
        ImuSource::File(imu_in.clone()),
    );
    cfg.force = true;
    // The whole 143 s flight; a 94x60 camera keeps this test to seconds (images are not the point).
    cfg.camera.model = CameraModel::euroc_cam0().scaled_to_level(3);
    let report = generate(&cfg).unwrap();
    eprintln!(
        "S-V101: {} frames, {} IMU rows, {:.1} s, {:.2} m; spline fit RMS {:.3} mm / {:.4} deg (max {:.2} mm)",
        report.frames,
        report.imu_samples,
        report.duration_s,
        report.path_length_m,
        report.fit.position_rms_m * 1e3,
        report.fit.rotation_rms_rad.to_degrees(),
        report.fit.position_max_m * 1e3
    );
    eprintln!("notes: {:?}", report.notes);

    let imu_text = std::fs::read_to_string(&imu_in).unwrap();
    let gt_text = std::fs::read_to_string(&gt_in).unwrap();
    let imu_rows = data_lines(&imu_text);
    let gt_rows = data_lines(&gt_text);
    let (gt0, gt1) = (t_of(gt_rows[0]), t_of(gt_rows[gt_rows.len() - 1]));
    let (imu0, imu1) = (t_of(imu_rows[0]), t_of(imu_rows[imu_rows.len() - 1]));
    let (lo, hi) = (gt0.max(imu0), gt1.min(imu1));
    let expected: Vec<&str> = imu_rows
        .iter()
        .copied()
        .filter(|l| (lo..=hi).contains(&t_of(l)))
        .collect();
    let out_text = std::fs::read_to_string(dir.join("mav0/imu0/data.csv")).unwrap();
    let out_rows = data_lines(&out_text);
    assert_eq!(out_rows.len(), expected.len());
    assert!(out_rows == expected, "IMU rows must be byte-identical");
    assert!(expected.len() > 28_000);

    let ds = AslDataset::open(&dir).unwrap();
    let imu_times: std::collections::HashSet<TimeNs> = expected.iter().map(|l| t_of(l)).collect();
    let frames: Vec<TimeNs> = ds.frames().unwrap().map(|f| f.unwrap().t).collect();
    assert!(frames.len() > 2800, "{} frames", frames.len());
    for w in frames.windows(2) {
        let dt_ns = w[1].ns_since(w[0]);
        assert!(
            (dt_ns - 50_000_000).abs() <= 5_000_000,
            "frame spacing {dt_ns} ns"
        );
    }
    for t in &frames {
        assert!(*t >= lo && *t <= hi && *t >= gt0 && *t <= gt1 && *t >= imu0 && *t <= imu1);
        assert!(imu_times.contains(t), "frame {t} is not an IMU sample time");
    }
    // Ground truth at every IMU sample, with velocity and biases.
    let gt = ds.ground_truth().unwrap().unwrap();
    assert_eq!(gt.states.len(), expected.len());
    let max_bg = gt
        .states
        .iter()
        .map(|s| s.gyro_bias_rad_s.unwrap().norm())
        .fold(0.0, f64::max);
    let s0 = &gt.states[gt.states.len() / 2];
    eprintln!(
        "estimated biases mid-flight: gyro {:?} rad/s, accel {:?} m/s^2",
        s0.gyro_bias_rad_s.unwrap().as_slice(),
        s0.accel_bias_m_s2.unwrap().as_slice()
    );
    assert!(
        max_bg < 0.2,
        "gyro bias estimate {max_bg} rad/s is implausible"
    );
    // The spline follows 200 Hz Vicon ground truth (mm noise) closely.
    assert!(report.fit.position_rms_m < 3e-3, "{:?}", report.fit);
    assert!(
        report.fit.rotation_rms_rad.to_degrees() < 0.2,
        "{:?}",
        report.fit
    );
    assert!(
        (report.path_length_m - 58.6).abs() < 1.5,
        "{} m",
        report.path_length_m
    );
    std::fs::remove_dir_all(&dir).ok();
}
