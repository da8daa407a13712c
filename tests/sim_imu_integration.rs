//! Integrating the noise-free synthetic IMU of a written sequence with the project's own
//! integrator (`imu::integration::propagate`) reproduces the ground-truth pose over 10 s of the
//! built-in demo flight (loops and turns) within 1 mm and 0.01°.

mod scratch;

use vidslam::camera::CameraModel;
use vidslam::dataset::{AslDataset, GroundTruthState};
use vidslam::imu::ImuSample;
use vidslam::imu::integration::{ImuBias, NavState, propagate};
use vidslam::sim::write::euroc_cam0_t_body_cam;
use vidslam::sim::{ImuSource, SimConfig, TrajectorySource, generate};

fn nav(s: &GroundTruthState) -> NavState {
    NavState {
        t: s.t,
        r_world_body: s.t_world_body.rotation,
        p_world_m: s.t_world_body.translation.vector,
        v_world_m_s: s.v_world_m_s.expect("17-column ground truth"),
    }
}

#[test]
fn noise_free_imu_integrates_to_the_ground_truth_pose_over_10_s() {
    let dir = scratch::dir("sim-imuint");
    let mut cfg = SimConfig::new(
        dir.clone(),
        TrajectorySource::Builtin("demo".into()),
        ImuSource::Synth,
    );
    cfg.realism = false;
    cfg.seconds = Some(20.0);
    cfg.force = true;
    // A tiny camera: this test is about the IMU and ground truth, not the images.
    cfg.camera.model = CameraModel::euroc_cam0().scaled_to_level(4);
    cfg.camera.t_body_cam = euroc_cam0_t_body_cam();
    generate(&cfg).unwrap();

    let ds = AslDataset::open(&dir).unwrap();
    let imu: Vec<ImuSample> = ds.imu_samples().unwrap().map(|s| s.unwrap()).collect();
    let gt = ds.ground_truth().unwrap().unwrap();
    assert_eq!(imu.len(), gt.states.len());
    // Window 8 s .. 18 s: figure-eight laps at up to 1.7 m/s with climbs and banked turns.
    let (ia, ib) = (8 * 200, 18 * 200);
    let (a, b) = (&gt.states[ia], &gt.states[ib]);
    assert_eq!((imu[ia].t, imu[ib].t), (a.t, b.t));
    let moved = (b.t_world_body.translation.vector - a.t_world_body.translation.vector).norm();
    let path: f64 = gt.states[ia..ib]
        .windows(2)
        .map(|w| {
            (w[1].t_world_body.translation.vector - w[0].t_world_body.translation.vector).norm()
        })
        .sum();
    assert!(path > 8.0, "window must be a real flight, path {path} m");
    for s in &gt.states {
        assert_eq!(s.gyro_bias_rad_s.unwrap().norm(), 0.0);
        assert_eq!(s.accel_bias_m_s2.unwrap().norm(), 0.0);
    }
    let out = propagate(&nav(a), &imu[ia..=ib], b.t, &ImuBias::default());
    let dp_m = (out.p_world_m - b.t_world_body.translation.vector).norm();
    let dr_deg = out
        .r_world_body
        .angle_to(&b.t_world_body.rotation)
        .to_degrees();
    let dv = (out.v_world_m_s - b.v_world_m_s.unwrap()).norm();
    eprintln!(
        "10 s dead reckoning over {path:.2} m (net {moved:.2} m): position error {:.3} mm, \
         rotation error {dr_deg:.5} deg, velocity error {:.3} mm/s",
        dp_m * 1e3,
        dv * 1e3
    );
    assert!(dp_m < 1e-3, "position error {dp_m} m");
    assert!(dr_deg < 0.01, "rotation error {dr_deg} deg");
    std::fs::remove_dir_all(&dir).ok();
}
