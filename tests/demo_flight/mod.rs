//! The built-in demo flight for the tests that run the keyframe window on it (body frame = the
//! camera's: `t_body_cam` identity): its true states (zero biases), its noise-free IMU
//! preintegrated between keyframes, exact relative poses, and a window that takes both at face
//! value.

#![allow(dead_code)] // each test binary uses the helpers it needs

use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3};
use vidslam::imu::{FrameState, ImuBias, ImuNoise, ImuSample, Preintegration};
use vidslam::sim::flights::builtin_flight;
use vidslam::sim::imu_synth::ideal_imu;
use vidslam::sim::{PoseSpline, fit_pose_spline};
use vidslam::smoother::{KeyframeWindow, RelativePose, WindowConfig};
use vidslam::time::TimeNs;
use vidslam::tracking::pose_of;

/// IMU sample period of the preintegrated factors, ns (200 Hz).
pub const IMU_PERIOD_NS: i64 = 5_000_000;

pub fn flight() -> PoseSpline {
    let tb = Isometry3::from_parts(Translation3::identity(), UnitQuaternion::identity());
    let tr = builtin_flight("demo", &tb).unwrap();
    fit_pose_spline(&tr.poses, 50_000_000).unwrap().0
}

pub fn truth(sp: &PoseSpline, t: TimeNs) -> FrameState {
    FrameState {
        nav: sp.nav_state(t),
        bias: ImuBias::default(),
    }
}

/// The noise-free IMU from keyframe state `from` to `t`, preintegrated at its bias.
pub fn preintegrate(sp: &PoseSpline, from: &FrameState, t: TimeNs) -> Preintegration {
    preintegrate_with_accel_bias(sp, &Vector3::zeros(), from, t)
}

/// The IMU with accelerometer bias `bias_m_s2` (otherwise noise-free), from keyframe state `from`
/// to `t`, preintegrated at `from`'s bias estimate.
pub fn preintegrate_with_accel_bias(
    sp: &PoseSpline,
    bias_m_s2: &Vector3<f64>,
    from: &FrameState,
    t: TimeNs,
) -> Preintegration {
    preintegrate_mapped(sp, from, t, |mut s| {
        s.accel_m_s2 += bias_m_s2;
        s
    })
}

/// The noise-free IMU with every sample passed through `map` (a sensor biased, turned…), from
/// keyframe state `from` to `t`, preintegrated at `from`'s bias estimate.
pub fn preintegrate_mapped(
    sp: &PoseSpline,
    from: &FrameState,
    t: TimeNs,
    map: impl Fn(ImuSample) -> ImuSample,
) -> Preintegration {
    let n = (t.0 - from.nav.t.0) / IMU_PERIOD_NS;
    let imu: Vec<ImuSample> = (0..=n)
        .map(|k| map(ideal_imu(sp, from.nav.t.add_ns(k * IMU_PERIOD_NS))))
        .collect();
    let mut pre = Preintegration::new(from.nav.t, from.bias);
    pre.integrate(&imu, t, Some(&ImuNoise::euroc_adis16448()));
    pre
}

/// The settings of a window that trusts the relative poses and the (noise-free) IMU at face
/// value.
pub fn window_config(max_keyframes: usize) -> WindowConfig {
    WindowConfig {
        visual_rotation_information_scale: 1.0,
        visual_translation_information_scale: 1.0,
        imu_noise_scale: 1.0,
        max_keyframes,
        ..WindowConfig::default()
    }
}

/// A window with `cfg` and the EuRoC IMU's noise.
pub fn window_with(cfg: WindowConfig) -> KeyframeWindow {
    KeyframeWindow::new(cfg, ImuNoise::euroc_adis16448())
}

/// A window that trusts the relative poses and the (noise-free) IMU at face value.
pub fn window(max_keyframes: usize) -> KeyframeWindow {
    window_with(window_config(max_keyframes))
}

/// Relative pose `a → b` at 1 mrad / 1 cm.
pub fn relative(a: &FrameState, b: &FrameState) -> RelativePose {
    let mut info = Matrix6::identity();
    for k in 0..3 {
        info[(k, k)] = 1e6; // 1 mrad
        info[(k + 3, k + 3)] = 1e4; // 1 cm
    }
    RelativePose {
        t_i_j: pose_of(a).inverse() * pose_of(b),
        information: info,
    }
}
