//! How well a dataset's IMU agrees with its ground-truth trajectory, before any odometry runs
//! (`vidslam dataset imu-check`).
//!
//! A rendered sequence that pairs a real IMU with a ground-truth path (S-V101: the real V1_01 IMU
//! and the images rendered along the Vicon estimate) is only as consistent as that estimate is
//! with the IMU. Two checks:
//!
//! - **Rotation**: the ground truth's body rate (`log(R_kᵀ R_{k+1}) / Δt`) against the gyro
//!   interpolated at the same instants. The rotation `R` and bias `b` with `ω_imu ≈ R ω_gt + b`
//!   (centred Kabsch fit) is the rotation between the ground truth's body frame and the IMU's; a
//!   rendered camera follows the former, so `R` acts as an error of the camera–IMU extrinsic.
//! - **Scale**: over windows of a given length, the ground-truth poses (at `frame_rate_hz`) taken
//!   as a perfectly tracked trajectory and aligned with the IMU integrated along them, exactly as
//!   the in-flight scale observer does ([`crate::imu::flight_scale`]: unknown scale, start
//!   velocity, accelerometer-bias error and tilt). With a consistent IMU every window gives 1; the
//!   spread (p10–p90) is the best any odometry can learn about the scale from this IMU over that
//!   horizon.

use super::stats::{percentile, sorted};
use crate::dataset::GroundTruthState;
use crate::geometry::log_so3;
use crate::imu::flight_scale::{FlightScalePrior, TrackedPose, dead_reckon, solve_flight_scale};
use crate::imu::{ImuBias, ImuSample, Preintegration};
use crate::time::TimeNs;
use nalgebra::{Matrix3, Vector3};

/// The gyro against the ground truth's body rate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GyroAlignment {
    /// `R` of `ω_imu ≈ R ω_gt + b`: ground-truth body frame to IMU frame.
    pub r_imu_gt: Matrix3<f64>,
    /// `log(R)`, rad (its norm is the angle between the two frames).
    pub rotation_rad: Vector3<f64>,
    /// `b`, rad/s.
    pub gyro_bias_rad_s: Vector3<f64>,
    /// RMS of `ω_imu − (R ω_gt + b)`, rad/s.
    pub residual_rms_rad_s: f64,
    /// Ground-truth intervals used.
    pub samples: usize,
}

/// Ground-truth intervals longer than this are skipped (a gap), s.
const MAX_GT_INTERVAL_S: f64 = 0.05;

/// The gyro linearly interpolated at `t`; `None` outside the samples.
fn gyro_at(imu: &[ImuSample], t: TimeNs) -> Option<Vector3<f64>> {
    let i = imu.partition_point(|s| s.t <= t);
    let (a, b) = (imu.get(i.checked_sub(1)?)?, imu.get(i)?);
    let span = b.t.secs_since(a.t);
    if span.is_nan() || span <= 0.0 {
        return None;
    }
    let w = t.secs_since(a.t) / span;
    Some(a.gyro_rad_s * (1.0 - w) + b.gyro_rad_s * w)
}

/// Fits the rotation and bias between the ground truth's body rate and the gyro; `None` with
/// fewer than 10 usable intervals or a rotation too poor in axes to fix `R`.
pub fn align_gyro(gt: &[GroundTruthState], imu: &[ImuSample]) -> Option<GyroAlignment> {
    let mut pairs: Vec<(Vector3<f64>, Vector3<f64>)> = Vec::with_capacity(gt.len());
    for w in gt.windows(2) {
        let dt_s = w[1].t.secs_since(w[0].t);
        if !(dt_s > 0.0 && dt_s <= MAX_GT_INTERVAL_S) {
            continue;
        }
        let r0 = w[0].t_world_body.rotation.to_rotation_matrix();
        let r1 = w[1].t_world_body.rotation.to_rotation_matrix();
        let omega_gt = log_so3((r0.inverse() * r1).matrix()) / dt_s;
        let mid = w[0].t.add_ns((w[1].t.0 - w[0].t.0) / 2);
        if let Some(omega_imu) = gyro_at(imu, mid)
            && omega_gt
                .iter()
                .chain(omega_imu.iter())
                .all(|v| v.is_finite())
        {
            pairs.push((omega_gt, omega_imu));
        }
    }
    if pairs.len() < 10 {
        return None;
    }
    let n = pairs.len() as f64;
    let mean_gt = pairs.iter().map(|p| p.0).sum::<Vector3<f64>>() / n;
    let mean_imu = pairs.iter().map(|p| p.1).sum::<Vector3<f64>>() / n;
    let h: Matrix3<f64> = pairs
        .iter()
        .map(|(g, i)| (g - mean_gt) * (i - mean_imu).transpose())
        .sum();
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    // Two axes at least must be excited, or the rotation about the third is free.
    let mut s = svd.singular_values;
    s.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    if s[1].is_nan() || s[1] <= 1e-9 * s[0].max(1e-300) {
        return None;
    }
    let v = v_t.transpose();
    let d = (v * u.transpose()).determinant().signum();
    let r = v * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * u.transpose();
    let bias = mean_imu - r * mean_gt;
    let sq: f64 = pairs
        .iter()
        .map(|(g, i)| (i - (r * g + bias)).norm_squared())
        .sum();
    Some(GyroAlignment {
        r_imu_gt: r,
        rotation_rad: log_so3(&r),
        gyro_bias_rad_s: bias,
        residual_rms_rad_s: (sq / n).sqrt(),
        samples: pairs.len(),
    })
}

/// The IMU's view of the scale over windows of one length.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleSpread {
    pub horizon_s: f64,
    /// Windows solved (they start every half horizon).
    pub windows: usize,
    /// Percentiles 10 / 50 / 90 of the windows' scales (`metric = scale · ground truth`; 1 for a
    /// consistent IMU).
    pub p10: f64,
    pub p50: f64,
    pub p90: f64,
    /// Median of the windows' accelerometer-bias estimates (body frame, on top of none), m/s².
    pub accel_bias_m_s2: Vector3<f64>,
}

/// Aligns the IMU with the ground truth over consecutive windows of `horizon_s` (starting every
/// half horizon), the ground truth subsampled at `frame_rate_hz` like tracked frames and the IMU
/// integrated with `gyro_bias_rad_s` (e.g. from [`align_gyro`]) and no accelerometer bias. `None`
/// if no window could be solved.
pub fn imu_scale_spread(
    gt: &[GroundTruthState],
    imu: &[ImuSample],
    gyro_bias_rad_s: Vector3<f64>,
    frame_rate_hz: f64,
    horizon_s: f64,
    prior: &FlightScalePrior,
) -> Option<ScaleSpread> {
    if !(frame_rate_hz > 0.0 && horizon_s > 0.0) {
        return None;
    }
    let (first, last) = (imu.first()?.t, imu.last()?.t);
    let period_ns = (1e9 / frame_rate_hz).round() as i64;
    let mut frames: Vec<&GroundTruthState> = Vec::new();
    for s in gt.iter().filter(|s| s.t > first && s.t < last) {
        if frames.last().is_none_or(|f| s.t.0 - f.t.0 >= period_ns) {
            frames.push(s);
        }
    }
    let bias = ImuBias {
        gyro_rad_s: gyro_bias_rad_s,
        accel_m_s2: Vector3::zeros(),
    };
    let mut scales = Vec::new();
    let mut biases: [Vec<f64>; 3] = Default::default();
    let mut start = 0;
    while let Some(f0) = frames.get(start) {
        let end = frames.partition_point(|f| f.t.secs_since(f0.t) <= horizon_s);
        let window = &frames[start..end];
        if window.len() < 3 || window.last()?.t.secs_since(f0.t) < 0.9 * horizon_s {
            break;
        }
        let poses: Vec<TrackedPose> = window
            .iter()
            .map(|f| TrackedPose {
                r_world_body: *f.t_world_body.rotation.to_rotation_matrix().matrix(),
                p_world_m: f.t_world_body.translation.vector,
            })
            .collect();
        let t_end = window.last()?.t;
        let from = imu.partition_point(|s| s.t < f0.t).saturating_sub(1);
        let to = (imu.partition_point(|s| s.t <= t_end) + 1).min(imu.len());
        let samples = &imu[from..to];
        let intervals: Vec<Preintegration> = window
            .windows(2)
            .map(|w| {
                let mut pre = Preintegration::new(w[0].t, bias);
                pre.integrate(samples, w[1].t, None);
                pre
            })
            .collect();
        let reckoned = dead_reckon(&poses, &intervals);
        if let Some(e) = solve_flight_scale(&poses, &reckoned, prior)
            && e.scale.is_finite()
        {
            scales.push(e.scale);
            for (k, b) in biases.iter_mut().enumerate() {
                b.push(e.accel_bias_m_s2[k]);
            }
        }
        let step_s = horizon_s / 2.0;
        start = frames.partition_point(|f| f.t.secs_since(f0.t) < step_s);
    }
    if scales.is_empty() {
        return None;
    }
    let scales = sorted(scales.into_iter());
    let median = |b: &Vec<f64>| percentile(&sorted(b.iter().copied()), 50.0);
    Some(ScaleSpread {
        horizon_s,
        windows: scales.len(),
        p10: percentile(&scales, 10.0),
        p50: percentile(&scales, 50.0),
        p90: percentile(&scales, 90.0),
        accel_bias_m_s2: Vector3::new(median(&biases[0]), median(&biases[1]), median(&biases[2])),
    })
}
