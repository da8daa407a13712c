//! `vidslam dataset imu-check`'s fits on an analytic flight whose IMU is generated from the
//! ground truth: a known frame rotation and gyro bias are recovered, a consistent IMU gives the
//! scale 1 over every window, and an accelerometer reading 5 % high gives 1.05; the full gyro
//! model recovers scale factors and non-orthogonal axes (and resists a noisy ground truth when
//! its span covers several intervals); the accelerometer bias the ground truth implies is the
//! one the IMU was given; the gyro's rotation over a horizon agrees with a consistent gyro's, gives
//! back the density of a white gyro noise, and grows with the horizon for a scale-factor error
//! (which the full gyro model takes out).

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use vidslam::dataset::GroundTruthState;
use vidslam::eval::imu_consistency::{
    align_gyro, fit_gyro_model, gyro_rotation_spread, implied_accel_bias, imu_scale_spread,
};
use vidslam::geometry::log_so3;
use vidslam::imu::ImuSample;
use vidslam::imu::flight_scale::FlightScalePrior;
use vidslam::runtime::scale_observer::ScaleObserverConfig;
use vidslam::time::TimeNs;

const G_M_S2: f64 = 9.81;

fn rotation(t: f64) -> Matrix3<f64> {
    (Rotation3::from_axis_angle(&Vector3::z_axis(), 0.3 * t + 0.4 * (0.5 * t).sin())
        * Rotation3::from_axis_angle(&Vector3::y_axis(), 0.1 * (1.3 * t).sin())
        * Rotation3::from_axis_angle(&Vector3::x_axis(), 0.12 * (0.9 * t).cos()))
    .into_inner()
}

fn position(t: f64) -> Vector3<f64> {
    Vector3::new(
        1.5 * (0.7 * t).sin(),
        (0.5 * t).cos(),
        0.3 * (1.1 * t).sin(),
    )
}

fn acceleration(t: f64) -> Vector3<f64> {
    Vector3::new(
        -1.5 * 0.49 * (0.7 * t).sin(),
        -0.25 * (0.5 * t).cos(),
        -0.3 * 1.21 * (1.1 * t).sin(),
    )
}

fn body_rate(t: f64) -> Vector3<f64> {
    let h = 1e-5;
    log_so3(&(rotation(t - h).transpose() * rotation(t + h))) / (2.0 * h)
}

fn ground_truth(seconds: f64) -> Vec<GroundTruthState> {
    (0..=(seconds * 200.0) as i64)
        .map(|k| {
            let t = k as f64 / 200.0;
            GroundTruthState {
                t: TimeNs(k * 5_000_000),
                t_world_body: Isometry3::from_parts(
                    Translation3::from(position(t)),
                    UnitQuaternion::from_matrix(&rotation(t)),
                ),
                v_world_m_s: None,
                gyro_bias_rad_s: None,
                accel_bias_m_s2: None,
            }
        })
        .collect()
}

/// The IMU rotated by `r_imu_body`, with `gyro_bias`, its accelerometer scaled by `accel_scale`.
fn imu(
    seconds: f64,
    r_imu_body: &Matrix3<f64>,
    gyro_bias: Vector3<f64>,
    accel_scale: f64,
) -> Vec<ImuSample> {
    // 400 Hz, offset from the ground-truth instants.
    (0..=(seconds * 400.0) as i64 + 1)
        .map(|k| {
            let t = k as f64 / 400.0 + 0.001;
            let f_body =
                rotation(t).transpose() * (acceleration(t) + Vector3::new(0.0, 0.0, G_M_S2));
            ImuSample {
                t: TimeNs((t * 1e9).round() as i64),
                gyro_rad_s: r_imu_body * body_rate(t) + gyro_bias,
                accel_m_s2: r_imu_body * f_body * accel_scale,
            }
        })
        .collect()
}

/// The in-flight scale observer's priors, as `vidslam dataset imu-check` uses them.
fn prior() -> FlightScalePrior {
    ScaleObserverConfig::default().prior()
}

#[test]
fn recovers_the_frame_rotation_and_the_gyro_bias() {
    let offset = Vector3::new(0.004, -0.002, 0.015); // rad, 0.9°
    let r = vidslam::geometry::exp_so3(&offset);
    let bias = Vector3::new(-0.002, 0.02, 0.076);
    let g = align_gyro(&ground_truth(60.0), &imu(60.0, &r, bias, 1.0)).expect("enough rotation");
    assert!(
        (g.rotation_rad - offset).norm() < 2e-4,
        "{:?}",
        g.rotation_rad
    );
    assert!(
        (g.gyro_bias_rad_s - bias).norm() < 2e-4,
        "{:?}",
        g.gyro_bias_rad_s
    );
    assert!(g.residual_rms_rad_s < 2e-3, "{}", g.residual_rms_rad_s);
    // Rotation about one axis only: the other two are not fixed.
    let yaw_only: Vec<GroundTruthState> = ground_truth(10.0)
        .into_iter()
        .map(|mut s| {
            let t = s.t.0 as f64 * 1e-9;
            s.t_world_body.rotation = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3 * t);
            s
        })
        .collect();
    let flat: Vec<ImuSample> = imu(10.0, &Matrix3::identity(), Vector3::zeros(), 1.0)
        .into_iter()
        .map(|mut s| {
            s.gyro_rad_s = Vector3::new(0.0, 0.0, 0.3);
            s
        })
        .collect();
    assert!(align_gyro(&yaw_only, &flat).is_none());
}

#[test]
fn a_consistent_imu_gives_scale_one_and_a_high_accelerometer_more() {
    let gt = ground_truth(40.0);
    let id = Matrix3::identity();
    for horizon_s in [4.0, 8.0, 16.0] {
        let s = imu_scale_spread(
            &gt,
            &imu(40.0, &id, Vector3::zeros(), 1.0),
            Vector3::zeros(),
            20.0,
            horizon_s,
            &prior(),
        )
        .expect("windows");
        assert!(s.windows >= 3, "{s:?}");
        assert!(s.p10 > 0.99 && s.p90 < 1.01, "{s:?}");
        assert!(s.accel_bias_m_s2.norm() < 0.02, "{s:?}");
    }
    let high = imu_scale_spread(
        &gt,
        &imu(40.0, &id, Vector3::zeros(), 1.05),
        Vector3::zeros(),
        20.0,
        8.0,
        &prior(),
    )
    .expect("windows");
    assert!((high.p50 - 1.05).abs() < 0.01, "{high:?}");
    // Shorter than one horizon: nothing.
    assert!(
        imu_scale_spread(
            &gt,
            &imu(40.0, &id, Vector3::zeros(), 1.0),
            Vector3::zeros(),
            20.0,
            60.0,
            &prior()
        )
        .is_none()
    );
}

/// The IMU with a full gyro matrix `m` (body rate to gyro reading) and an accelerometer bias.
fn imu_with(
    seconds: f64,
    m: &Matrix3<f64>,
    gyro_bias: Vector3<f64>,
    accel_bias: Vector3<f64>,
) -> Vec<ImuSample> {
    imu(seconds, &Matrix3::identity(), Vector3::zeros(), 1.0)
        .into_iter()
        .map(|mut s| {
            s.gyro_rad_s = m * s.gyro_rad_s + gyro_bias;
            s.accel_m_s2 += accel_bias;
            s
        })
        .collect()
}

/// Deterministic noise in [-1, 1).
fn noise(state: &mut u64) -> f64 {
    *state = state
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
}

#[test]
fn the_full_gyro_model_recovers_scale_factors_and_non_orthogonal_axes() {
    // Scale errors +2 % / −1 % / 0, a rotation of 0.5° about z and a 0.6° shear of x and y
    // (S-V101's gyro has 0.55° and 0.51°).
    let rot_z = 0.5f64.to_radians();
    let skew_xy = 0.6f64.to_radians();
    let m = Matrix3::new(
        1.02,
        -rot_z + skew_xy,
        0.0,
        rot_z + skew_xy,
        0.99,
        0.0,
        0.0,
        0.0,
        1.0,
    );
    let bias = Vector3::new(-0.002, 0.02, 0.076);
    let g = fit_gyro_model(
        &ground_truth(60.0),
        &imu_with(60.0, &m, bias, Vector3::zeros()),
        0.05,
    )
    .expect("all axes rotate");
    assert!((g.m - m).abs().max() < 2e-4, "{}", g.m);
    assert!(
        (g.gyro_bias_rad_s - bias).norm() < 2e-4,
        "{:?}",
        g.gyro_bias_rad_s
    );
    assert!((g.scale_error() - Vector3::new(0.02, -0.01, 0.0)).norm() < 2e-4);
    assert!((g.rotation_rad() - Vector3::new(0.0, 0.0, rot_z)).norm() < 2e-4);
    assert!((g.skew_rad() - Vector3::new(skew_xy, 0.0, 0.0)).norm() < 2e-4);
    // The rotation-only fit sees neither the scale nor the shear.
    let r = align_gyro(
        &ground_truth(60.0),
        &imu_with(60.0, &m, bias, Vector3::zeros()),
    )
    .expect("enough rotation");
    assert!(r.residual_rms_rad_s > 5.0 * g.residual_rms_rad_s);

    // A ground truth whose orientation jitters by ±0.5 mrad: rates over one 5 ms interval are
    // noisier than the pitch and roll rates themselves and the fit shrinks those scale factors;
    // over 0.2 s spans they come back within 1 %.
    let mut state = 7u64;
    let noisy: Vec<GroundTruthState> = ground_truth(60.0)
        .into_iter()
        .map(|mut s| {
            let d = Vector3::new(noise(&mut state), noise(&mut state), noise(&mut state)) * 5e-4;
            s.t_world_body.rotation *= UnitQuaternion::from_scaled_axis(d);
            s
        })
        .collect();
    let id = Matrix3::identity();
    let imu0 = imu_with(60.0, &id, Vector3::zeros(), Vector3::zeros());
    let short = fit_gyro_model(&noisy, &imu0, 0.004).expect("fits");
    assert!(
        short.scale_error().min() < -0.3,
        "{:?}",
        short.scale_error()
    );
    let long = fit_gyro_model(&noisy, &imu0, 0.2).expect("fits");
    assert!(
        long.scale_error().abs().max() < 0.01,
        "{:?}",
        long.scale_error()
    );

    // Rotation about one axis only: the model is not determined.
    let yaw_only: Vec<GroundTruthState> = ground_truth(20.0)
        .into_iter()
        .map(|mut s| {
            let t = s.t.0 as f64 * 1e-9;
            s.t_world_body.rotation = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3 * t);
            s
        })
        .collect();
    assert!(fit_gyro_model(&yaw_only, &imu0, 0.05).is_none());
}

#[test]
fn the_implied_accelerometer_bias_is_the_one_the_imu_was_given() {
    let gt = ground_truth(40.0);
    let id = Matrix3::identity();
    let bias = Vector3::new(-0.0125, 0.5477, 0.0691); // the V1_01 estimate's
    let b = implied_accel_bias(&gt, &imu_with(40.0, &id, Vector3::zeros(), bias), 2.0)
        .expect("windows");
    assert!(b.windows >= 18, "{b:?}");
    assert!((b.p50_m_s2 - bias).norm() < 5e-3, "{b:?}");
    assert!((b.p90_m_s2 - b.p10_m_s2).abs().max() < 1e-2, "{b:?}");
    let none = implied_accel_bias(
        &gt,
        &imu_with(40.0, &id, Vector3::zeros(), Vector3::zeros()),
        2.0,
    )
    .expect("windows");
    assert!(none.p50_m_s2.norm() < 5e-3, "{none:?}");
    // The same IMU against a ground truth tilted by 1° about x: gravity leaks 0.17 m/s² into
    // body y, which is what a bias estimated against a tilted attitude absorbs.
    let tilt = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 1f64.to_radians());
    let tilted: Vec<GroundTruthState> = gt
        .iter()
        .map(|s| {
            let mut s = *s;
            s.t_world_body.rotation *= tilt;
            s
        })
        .collect();
    let leak = implied_accel_bias(
        &tilted,
        &imu_with(40.0, &id, Vector3::zeros(), Vector3::zeros()),
        2.0,
    )
    .expect("windows");
    assert!(leak.p50_m_s2.norm() > 0.1, "{leak:?}");
    assert!(implied_accel_bias(&gt, &imu_with(40.0, &id, Vector3::zeros(), bias), 60.0).is_none());
}

#[test]
fn the_rotation_spread_gives_back_a_white_gyro_noise_and_grows_with_a_scale_error() {
    let seconds = 120.0;
    let gt = ground_truth(seconds);
    let turned = vidslam::geometry::exp_so3(&Vector3::new(0.004, -0.002, 0.015));
    let bias = Vector3::new(-0.002, 0.02, 0.076);
    // Consistent (turned and biased, both taken out by the alignment): nothing over any horizon.
    let clean = imu(seconds, &turned, bias, 1.0);
    let g = align_gyro(&gt, &clean).expect("enough rotation");
    for horizon_s in [0.2, 1.0, 4.0] {
        let s = gyro_rotation_spread(&gt, &clean, &g.r_imu_gt, &g.gyro_bias_rad_s, horizon_s)
            .expect("windows");
        let expected = (2.0 * seconds / horizon_s) as usize;
        assert!(s.windows + 3 >= expected && s.windows <= expected, "{s:?}");
        assert!(s.p90_deg < 0.01, "{s:?}");
        assert!(s.equivalent_density_rad_s_sqrt_hz < 2e-5, "{s:?}");
    }
    // White noise of 1e-3 rad/s/√Hz at 400 Hz (uniform samples of that standard deviation).
    let density = 1e-3;
    let amplitude = density * 400f64.sqrt() * 3f64.sqrt();
    let mut state = 7;
    let noisy: Vec<ImuSample> = clean
        .iter()
        .map(|s| {
            let mut s = *s;
            for k in 0..3 {
                s.gyro_rad_s[k] += amplitude * noise(&mut state);
            }
            s
        })
        .collect();
    let g = align_gyro(&gt, &noisy).expect("enough rotation");
    for horizon_s in [0.2, 1.0] {
        let s = gyro_rotation_spread(&gt, &noisy, &g.r_imu_gt, &g.gyro_bias_rad_s, horizon_s)
            .expect("windows");
        let ratio = s.equivalent_density_rad_s_sqrt_hz / density;
        assert!((ratio - 1.0).abs() < 0.15, "{horizon_s} s: {s:?}");
    }
    // A 1 % scale error on z (the yaw axis, ~0.3 rad/s): an error that grows with the rotation,
    // so with the horizon, unlike white noise whose equivalent density stays put.
    let m = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 1.01));
    let scaled = imu_with(seconds, &m, Vector3::zeros(), Vector3::zeros());
    let g = align_gyro(&gt, &scaled).expect("enough rotation");
    let short =
        gyro_rotation_spread(&gt, &scaled, &g.r_imu_gt, &g.gyro_bias_rad_s, 1.0).expect("windows");
    let long =
        gyro_rotation_spread(&gt, &scaled, &g.r_imu_gt, &g.gyro_bias_rad_s, 4.0).expect("windows");
    assert!(short.p50_deg > 0.05, "{short:?}");
    assert!(long.p50_deg > 3.0 * short.p50_deg, "{short:?} {long:?}");
    assert!(
        long.equivalent_density_rad_s_sqrt_hz > 1.5 * short.equivalent_density_rad_s_sqrt_hz,
        "{short:?} {long:?}"
    );
    // Through the full gyro model the scale error is taken out again.
    let model = fit_gyro_model(&gt, &scaled, 0.05).expect("model");
    let through =
        gyro_rotation_spread(&gt, &scaled, &model.m, &model.gyro_bias_rad_s, 4.0).expect("windows");
    assert!(
        through.p90_deg < 0.05 * long.p50_deg,
        "{through:?} {long:?}"
    );
    // No window longer than the flight, no singular model.
    assert!(gyro_rotation_spread(&gt, &clean, &g.r_imu_gt, &g.gyro_bias_rad_s, 200.0).is_none());
    assert!(
        gyro_rotation_spread(&gt, &clean, &Matrix3::zeros(), &bias, 1.0).is_none(),
        "singular"
    );
}
