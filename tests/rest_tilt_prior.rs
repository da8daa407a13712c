//! The rest prior and the accelerometer bias across gravity. On the pad the accelerometer measures
//! `R_wbᵀ g_up + b_a`: a bias across gravity is absorbed into the tilt
//! (`imu::static_init`, *What a static IMU cannot tell*), and it becomes observable only when the
//! vehicle turns — in the first turn of the flight, where the keyframe window also reads the maps'
//! scale from the IMU. A rest prior that holds the tilt to its statistical σ (1 mrad) keeps the
//! tilt error the bias left there, and the window explains the turn's accelerations with a wrong
//! map scale instead; `rest_covariance` frees the tilt by the bias it may hide (σ_ba / g).
//!
//! The built-in demo flight (take-off, straight, the first turn at 7 s), noise-free IMU with a
//! bias across gravity, exact relative poses; the window starts from the rest state the pad
//! gives (tilt absorbing the bias, bias zero).

mod demo_flight;

use demo_flight::{flight, preintegrate_with_accel_bias, relative, truth, window};
use nalgebra::{UnitQuaternion, Vector3};
use vidslam::geometry::GRAVITY_M_S2;
use vidslam::imu::static_init::rest_covariance;
use vidslam::imu::{FrameState, Matrix15};
use vidslam::smoother::WindowConfig;
use vidslam::tracking::pose_of;

const KF_PERIOD_NS: i64 = 250_000_000;

/// The prior the odometry used until 2026-11-28: diagonal, 1 mrad about body x and y, 0.01 rad
/// about body z taken for yaw. Body z is not up here either (this flight's body frame is its
/// camera's: z looks forward, −y is nearly up), so the tilt about body x is the one held.
fn diagonal_tilt_prior() -> Matrix15 {
    let s = [
        1e-3, 1e-3, 0.01, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 0.1, 0.1, 0.1,
    ];
    Matrix15::from_fn(|a, b| if a == b { s[a] * s[a] } else { 0.0 })
}

struct Outcome {
    /// Largest |λ| of the newest keyframe's map over the first turn (7–11 s); the maps are exact.
    worst_log_scale_in_turn: f64,
    /// Accelerometer bias error of the newest keyframe at the end, m/s².
    final_bias_error_m_s2: f64,
}

/// From rest at 1.5 s to 11 s, one keyframe every 0.25 s; the start state is the pad's estimate
/// (tilted by the bias across gravity, bias zero) with covariance `prior(start)`.
fn fly(bias_m_s2: Vector3<f64>, prior: impl Fn(&FrameState) -> Matrix15) -> Outcome {
    let sp = flight();
    let t0 = sp.start().add_ns(1_500_000_000);
    let x0 = truth(&sp, t0);
    assert!(x0.nav.v_world_m_s.norm() < 1e-6, "the pad: at rest");
    // The pad's estimate: the gravity direction the accelerometer shows, bias zero.
    let f_true = x0.nav.r_world_body.inverse() * Vector3::new(0.0, 0.0, GRAVITY_M_S2);
    let f_meas = f_true + bias_m_s2;
    let up_seen = f_meas.normalize();
    let tilt = UnitQuaternion::rotation_between(&up_seen, &f_true.normalize()).unwrap();
    let mut start = x0;
    start.nav.r_world_body = x0.nav.r_world_body * tilt;
    let seen = start.nav.r_world_body.inverse() * Vector3::z();
    assert!((seen - up_seen).norm() < 1e-9);
    let mut w = window(WindowConfig::default().max_keyframes);
    w.reset(0, start, &prior(&start));
    let mut prev_true = x0;
    let mut worst = 0.0f64;
    let mut last = start;
    for k in 1..=38u32 {
        let t = t0.add_ns(k as i64 * KF_PERIOD_NS);
        let xt = truth(&sp, t);
        let (_, newest) = w.newest().unwrap();
        let pre = preintegrate_with_accel_bias(&sp, &bias_m_s2, newest, t);
        // The tracker's guess: the truth relative to the newest estimate.
        let guess_pose = pose_of(newest) * relative(&prev_true, &xt).t_i_j;
        let mut g = *newest;
        g.nav.t = t;
        g.nav.p_world_m = guess_pose.translation.vector;
        g.nav.r_world_body = guess_pose.rotation;
        w.push(k, g, pre, Some(relative(&prev_true, &xt)));
        w.solve();
        prev_true = xt;
        let (id, x) = w.newest().unwrap();
        let ts = (t.0 - sp.start().0) as f64 * 1e-9;
        if (7.0..=11.0).contains(&ts) {
            worst = worst.max(w.log_scale(id).unwrap().abs());
        }
        last = *x;
    }
    Outcome {
        worst_log_scale_in_turn: worst,
        final_bias_error_m_s2: (last.bias.accel_m_s2 - bias_m_s2).norm(),
    }
}

#[test]
fn a_bias_across_gravity_hidden_in_the_rest_tilt_does_not_become_a_map_scale_in_the_first_turn() {
    let sp = flight();
    let x0 = truth(&sp, sp.start().add_ns(1_500_000_000));
    let up = x0.nav.r_world_body.inverse() * Vector3::z();
    // 0.12 m/s² across gravity (the demo's render seed 23 had 0.13 on one axis), where the rest
    // hides it in a tilt about body x — the axis the old prior held at 1 mrad.
    let across = up.cross(&Vector3::x()).normalize();
    let bias = across * 0.12;
    let hidden_in_tilt_about = up.cross(&across);
    assert!(
        hidden_in_tilt_about.x.abs() > 0.99,
        "{hidden_in_tilt_about}"
    );
    let freed = fly(bias, |x| rest_covariance(&x.nav.r_world_body, 1e-3, 0.1));
    let held = fly(bias, |_| diagonal_tilt_prior());
    eprintln!(
        "tilt freed by the bias: worst |λ| in the turn {:.4}, final bias error {:.4} m/s²; \
         tilt held at 1 mrad: {:.4}, {:.4} m/s²",
        freed.worst_log_scale_in_turn,
        freed.final_bias_error_m_s2,
        held.worst_log_scale_in_turn,
        held.final_bias_error_m_s2
    );
    // Measured: freed 0.039 (−3.9 % at 8.75 s, −1.4 % at 11 s), bias within 0.009 m/s² at 11 s;
    // held: −15 %, the bias still 0.10 m/s² off.
    assert!(
        freed.worst_log_scale_in_turn < 0.05,
        "λ {}",
        freed.worst_log_scale_in_turn
    );
    assert!(
        freed.final_bias_error_m_s2 < 0.02,
        "bias {}",
        freed.final_bias_error_m_s2
    );
    assert!(
        held.worst_log_scale_in_turn > 3.0 * freed.worst_log_scale_in_turn
            && held.final_bias_error_m_s2 > 0.05,
        "the held tilt should read the bias as a map scale: λ {} vs {}, bias {}",
        held.worst_log_scale_in_turn,
        freed.worst_log_scale_in_turn,
        held.final_bias_error_m_s2
    );
}
