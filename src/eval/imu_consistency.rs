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
//! - **Rotation over a horizon**: the gyro integrated over windows (with the fitted `R` and `b`)
//!   against the ground truth's rotation over the same window, and the white gyro noise density
//!   that would explain that spread. On V1_01 it is many times `sensor.yaml`'s density and grows
//!   with the horizon: the real gyro and the Vicon attitude (along which S-V101's images are
//!   rendered) disagree by a rate that wanders over seconds, whichever of the two it belongs to.

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

/// One reading of the IMU (`field`: the gyro or the accelerometer) linearly interpolated at `t`;
/// `None` outside the samples.
fn imu_at(
    imu: &[ImuSample],
    t: TimeNs,
    field: impl Fn(&ImuSample) -> Vector3<f64>,
) -> Option<Vector3<f64>> {
    let i = imu.partition_point(|s| s.t <= t);
    let (a, b) = (imu.get(i.checked_sub(1)?)?, imu.get(i)?);
    let span = b.t.secs_since(a.t);
    if span.is_nan() || span <= 0.0 {
        return None;
    }
    let w = t.secs_since(a.t) / span;
    Some(field(a) * (1.0 - w) + field(b) * w)
}

/// The samples of `imu` inside `[t0, t1]` and the one on each side, for a preintegration over it.
fn samples_bracketing(imu: &[ImuSample], t0: TimeNs, t1: TimeNs) -> &[ImuSample] {
    let from = imu.partition_point(|s| s.t < t0).saturating_sub(1);
    let to = (imu.partition_point(|s| s.t <= t1) + 1).min(imu.len());
    &imu[from..to]
}

fn gyro_of(s: &ImuSample) -> Vector3<f64> {
    s.gyro_rad_s
}

/// Means of the ground-truth rates and of the gyro rates of `pairs` (not empty).
fn pair_means(pairs: &[(Vector3<f64>, Vector3<f64>)]) -> (Vector3<f64>, Vector3<f64>) {
    let n = pairs.len() as f64;
    (
        pairs.iter().map(|p| p.0).sum::<Vector3<f64>>() / n,
        pairs.iter().map(|p| p.1).sum::<Vector3<f64>>() / n,
    )
}

/// RMS of `ω_imu − (M ω_gt + b)` over `pairs` (not empty), rad/s.
fn residual_rms(
    pairs: &[(Vector3<f64>, Vector3<f64>)],
    m: &Matrix3<f64>,
    bias: &Vector3<f64>,
) -> f64 {
    let sq: f64 = pairs
        .iter()
        .map(|(g, i)| (i - (m * g + bias)).norm_squared())
        .sum();
    (sq / pairs.len() as f64).sqrt()
}

/// Per-axis percentile `p` of three sorted lists.
fn axis_percentile(axes: &[Vec<f64>; 3], p: f64) -> Vector3<f64> {
    Vector3::new(
        percentile(&axes[0], p),
        percentile(&axes[1], p),
        percentile(&axes[2], p),
    )
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
        if let Some(omega_imu) = imu_at(imu, mid, gyro_of)
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
    let (mean_gt, mean_imu) = pair_means(&pairs);
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
    Some(GyroAlignment {
        r_imu_gt: r,
        rotation_rad: log_so3(&r),
        gyro_bias_rad_s: bias,
        residual_rms_rad_s: residual_rms(&pairs, &r, &bias),
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
        let samples = samples_bracketing(imu, f0.t, t_end);
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
    let biases = biases.map(|b| sorted(b.into_iter()));
    Some(ScaleSpread {
        horizon_s,
        windows: scales.len(),
        p10: percentile(&scales, 10.0),
        p50: percentile(&scales, 50.0),
        p90: percentile(&scales, 90.0),
        accel_bias_m_s2: axis_percentile(&biases, 50.0),
    })
}

/// The gyro's integrated rotation against the ground truth's over windows of one length.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RotationSpread {
    pub horizon_s: f64,
    /// Windows compared (they start every half horizon).
    pub windows: usize,
    /// Percentiles 50 / 90 of the angle between the two rotations, deg.
    pub p50_deg: f64,
    pub p90_deg: f64,
    /// The per-axis white gyro noise that would give the same RMS angle over the horizon
    /// (`sqrt(E|e|² / (3 H))`), rad/s/√Hz: a noise density for the estimator that makes the gyro
    /// as uncertain as it is against these poses (for a rendered sequence, against its images).
    pub equivalent_density_rad_s_sqrt_hz: f64,
}

/// Integrates the gyro over consecutive windows of `horizon_s` (starting every half horizon),
/// each reading mapped back to the ground truth's body as `M⁻¹ (ω_imu − b)` — `M` the rotation of
/// [`align_gyro`] or the full matrix of [`fit_gyro_model`] — and compares the rotation with the
/// ground truth's over the same window. The rotation analogue of [`imu_scale_spread`]: with a
/// consistent gyro every window agrees up to the gyro's white noise, so the spread over a horizon
/// is the best any odometry can learn about rotation from this gyro over it. `None` if `M` is
/// singular or no window could be compared.
pub fn gyro_rotation_spread(
    gt: &[GroundTruthState],
    imu: &[ImuSample],
    m_imu_gt: &Matrix3<f64>,
    gyro_bias_rad_s: &Vector3<f64>,
    horizon_s: f64,
) -> Option<RotationSpread> {
    if horizon_s.is_nan() || horizon_s <= 0.0 {
        return None;
    }
    let m_inv = m_imu_gt.try_inverse()?;
    // The readings in the ground truth's body frame, bias removed.
    let body: Vec<ImuSample> = imu
        .iter()
        .map(|s| ImuSample {
            gyro_rad_s: m_inv * (s.gyro_rad_s - gyro_bias_rad_s),
            ..*s
        })
        .collect();
    let imu = &body[..];
    let (first, last) = (imu.first()?.t, imu.last()?.t);
    let states: Vec<&GroundTruthState> = gt.iter().filter(|s| s.t > first && s.t < last).collect();
    let bias = ImuBias::default();
    let mut angles_rad = Vec::new();
    let mut start = 0;
    while let Some(s0) = states.get(start) {
        let end = states.partition_point(|s| s.t.secs_since(s0.t) < horizon_s);
        let Some(s1) = states.get(end) else {
            break;
        };
        // (A gap in the ground truth longer than a tenth of the window: not compared.)
        if s1.t.secs_since(s0.t) <= 1.1 * horizon_s {
            let mut pre = Preintegration::new(s0.t, bias);
            pre.integrate(samples_bracketing(imu, s0.t, s1.t), s1.t, None);
            let r0 = s0.t_world_body.rotation.to_rotation_matrix();
            let r1 = s1.t_world_body.rotation.to_rotation_matrix();
            let d_gt = (r0.inverse() * r1).into_inner();
            let e = log_so3(&(d_gt.transpose() * pre.delta_r));
            if e.iter().all(|v| v.is_finite()) {
                angles_rad.push(e.norm());
            }
        }
        start = states.partition_point(|s| s.t.secs_since(s0.t) < horizon_s / 2.0);
    }
    if angles_rad.is_empty() {
        return None;
    }
    let mean_sq = angles_rad.iter().map(|a| a * a).sum::<f64>() / angles_rad.len() as f64;
    let deg = sorted(angles_rad.iter().map(|a| a.to_degrees()));
    Some(RotationSpread {
        horizon_s,
        windows: deg.len(),
        p50_deg: percentile(&deg, 50.0),
        p90_deg: percentile(&deg, 90.0),
        equivalent_density_rad_s_sqrt_hz: (mean_sq / (3.0 * horizon_s)).sqrt(),
    })
}

/// The gyro as a full linear sensor of the ground truth's body rate: `ω_imu ≈ M ω_gt + b`.
///
/// [`align_gyro`] fits a rotation only; a real gyro also has per-axis scale factors and axes
/// that are not quite orthogonal (or a ground truth whose body frame is slightly sheared against
/// it). `M`'s diagonal minus 1 is the scale-factor error, its antisymmetric part a rotation of the
/// frame, its symmetric off-diagonal part the non-orthogonality of the axes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GyroModel {
    pub m: Matrix3<f64>,
    /// `b`, rad/s.
    pub gyro_bias_rad_s: Vector3<f64>,
    /// RMS of `ω_imu − (M ω_gt + b)` over the spans, rad/s.
    pub residual_rms_rad_s: f64,
    /// Spans used.
    pub samples: usize,
    /// Length of each span, s.
    pub span_s: f64,
}

impl GyroModel {
    /// Scale-factor error per axis (`M_ii − 1`).
    pub fn scale_error(&self) -> Vector3<f64> {
        self.m.diagonal() - Vector3::repeat(1.0)
    }

    /// The rotation in `M` (the vector of its antisymmetric part), rad.
    pub fn rotation_rad(&self) -> Vector3<f64> {
        let a = (self.m - self.m.transpose()) * 0.5;
        Vector3::new(a[(2, 1)], a[(0, 2)], a[(1, 0)])
    }

    /// Non-orthogonality of the axis pairs xy, xz, yz (the symmetric off-diagonal part of `M`),
    /// rad.
    pub fn skew_rad(&self) -> Vector3<f64> {
        let s = (self.m + self.m.transpose()) * 0.5;
        Vector3::new(s[(0, 1)], s[(0, 2)], s[(1, 2)])
    }
}

/// Mean of the linearly interpolated gyro over `[t0, t1]`; `None` outside the samples.
fn mean_gyro(imu: &[ImuSample], t0: TimeNs, t1: TimeNs) -> Option<Vector3<f64>> {
    let span_s = t1.secs_since(t0);
    if span_s.is_nan() || span_s <= 0.0 {
        return None;
    }
    let mut prev = (t0, imu_at(imu, t0, gyro_of)?);
    let mut sum = Vector3::zeros();
    let inner = imu.partition_point(|s| s.t <= t0)..imu.partition_point(|s| s.t < t1);
    for s in &imu[inner] {
        sum += (prev.1 + s.gyro_rad_s) * (0.5 * s.t.secs_since(prev.0));
        prev = (s.t, s.gyro_rad_s);
    }
    let end = imu_at(imu, t1, gyro_of)?;
    sum += (prev.1 + end) * (0.5 * t1.secs_since(prev.0));
    Some(sum / span_s)
}

/// Fits [`GyroModel`] over consecutive spans of about `span_s`: the ground truth's mean body rate
/// over each span (`log(R_0ᵀ R_1) / Δt`) against the gyro averaged over the same span. Spans of
/// several ground-truth intervals matter: a rate differenced over one interval carries the
/// ground truth's orientation noise divided by 5 ms, and a least-squares fit against a noisy
/// regressor shrinks `M` toward zero on the axes that rotate least (errors in variables; S-V101's
/// pitch axis reads 4 % low at one interval, 0.5 % at 0.05 s). `None` with fewer than 20 spans or
/// an axis that hardly rotates (its rate's standard deviation under 0.01 rad/s).
pub fn fit_gyro_model(
    gt: &[GroundTruthState],
    imu: &[ImuSample],
    span_s: f64,
) -> Option<GyroModel> {
    if span_s.is_nan() || span_s <= 0.0 {
        return None;
    }
    let mut pairs: Vec<(Vector3<f64>, Vector3<f64>)> = Vec::new();
    let mut i = 0;
    while i < gt.len() {
        let t0 = gt[i].t;
        let j = i + gt[i..].partition_point(|s| s.t.secs_since(t0) < span_s);
        let Some(end) = gt.get(j) else { break };
        let dt_s = end.t.secs_since(t0);
        // A gap in the ground truth inside the span: skip it.
        let gap = gt[i..=j]
            .windows(2)
            .any(|w| w[1].t.secs_since(w[0].t) > MAX_GT_INTERVAL_S);
        if !gap {
            let r0 = gt[i].t_world_body.rotation.to_rotation_matrix();
            let r1 = end.t_world_body.rotation.to_rotation_matrix();
            let omega_gt = log_so3((r0.inverse() * r1).matrix()) / dt_s;
            if let Some(omega_imu) = mean_gyro(imu, t0, end.t)
                && omega_gt
                    .iter()
                    .chain(omega_imu.iter())
                    .all(|v| v.is_finite())
            {
                pairs.push((omega_gt, omega_imu));
            }
        }
        i = j;
    }
    if pairs.len() < 20 {
        return None;
    }
    let n = pairs.len() as f64;
    let (mean_gt, mean_imu) = pair_means(&pairs);
    // Centred normal equations: M = Σ (i − ī)(g − ḡ)ᵀ · (Σ (g − ḡ)(g − ḡ)ᵀ)⁻¹, b = ī − M ḡ.
    let cov_gt: Matrix3<f64> = pairs
        .iter()
        .map(|(g, _)| (g - mean_gt) * (g - mean_gt).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let cross: Matrix3<f64> = pairs
        .iter()
        .map(|(g, i)| (i - mean_imu) * (g - mean_gt).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let min_var = cov_gt.symmetric_eigenvalues().min();
    if min_var.is_nan() || min_var < MIN_AXIS_RATE_STD_RAD_S * MIN_AXIS_RATE_STD_RAD_S {
        return None;
    }
    let m = cross * cov_gt.try_inverse()?;
    let bias = mean_imu - m * mean_gt;
    Some(GyroModel {
        m,
        gyro_bias_rad_s: bias,
        residual_rms_rad_s: residual_rms(&pairs, &m, &bias),
        samples: pairs.len(),
        span_s,
    })
}

/// An axis whose rate varies less than this over the flight leaves `M`'s column undetermined,
/// rad/s.
const MIN_AXIS_RATE_STD_RAD_S: f64 = 0.01;

/// The accelerometer bias the ground truth implies, window by window (body frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImpliedAccelBias {
    pub window_s: f64,
    /// Windows solved.
    pub windows: usize,
    /// Per-axis percentiles 10 / 50 / 90 over the windows, m/s².
    pub p10_m_s2: Vector3<f64>,
    pub p50_m_s2: Vector3<f64>,
    pub p90_m_s2: Vector3<f64>,
}

/// Half the span over which a ground-truth velocity is differenced, s.
const VELOCITY_HALF_SPAN_S: f64 = 0.05;

/// The ground truth's orientation at `t` (spherical interpolation); `None` outside it.
fn rotation_at(gt: &[GroundTruthState], t: TimeNs) -> Option<Matrix3<f64>> {
    let i = gt.partition_point(|s| s.t <= t);
    let (a, b) = (gt.get(i.checked_sub(1)?)?, gt.get(i)?);
    let span = b.t.secs_since(a.t);
    if span.is_nan() || span <= 0.0 || span > MAX_GT_INTERVAL_S {
        return None;
    }
    let w = t.secs_since(a.t) / span;
    let q = a.t_world_body.rotation.slerp(&b.t_world_body.rotation, w);
    Some(*q.to_rotation_matrix().matrix())
}

/// The ground truth's velocity at state `i`, differenced over ±[`VELOCITY_HALF_SPAN_S`], m/s.
fn velocity_at(gt: &[GroundTruthState], i: usize) -> Option<Vector3<f64>> {
    let t = gt.get(i)?.t;
    let lo = gt[..i].partition_point(|s| t.secs_since(s.t) > VELOCITY_HALF_SPAN_S);
    let hi = i + gt[i..].partition_point(|s| s.t.secs_since(t) < VELOCITY_HALF_SPAN_S);
    let (a, b) = (gt.get(lo)?, gt.get(hi)?);
    let dt_s = b.t.secs_since(a.t);
    if dt_s.is_nan() || dt_s <= 0.0 || dt_s > 4.0 * VELOCITY_HALF_SPAN_S || lo == i || hi == i {
        return None;
    }
    Some((b.t_world_body.translation.vector - a.t_world_body.translation.vector) / dt_s)
}

/// The accelerometer bias that makes the IMU agree with the ground truth over consecutive
/// windows of `window_s`: with `f = a_imu − b` the specific force, `∫ R f dt = Δv + g T` over a
/// window (`R` the ground truth's orientation, `Δv` its velocity change, `g` gravity up), so
/// `(∫ R dt) b = ∫ R a_imu dt − Δv − g T`. This is the bias an odometry tracking the rendered
/// images exactly should estimate; an estimate elsewhere means its attitude or its map is off
/// (S-V101: the ground truth implies 0.55 m/s² on body y, the odometry settles near 0.15).
/// `None` if no window could be solved.
pub fn implied_accel_bias(
    gt: &[GroundTruthState],
    imu: &[ImuSample],
    window_s: f64,
) -> Option<ImpliedAccelBias> {
    if window_s.is_nan() || window_s <= 0.0 {
        return None;
    }
    let (first, last) = (imu.first()?.t, imu.last()?.t);
    let gravity_up = Vector3::new(0.0, 0.0, crate::geometry::GRAVITY_M_S2);
    let mut biases: [Vec<f64>; 3] = Default::default();
    let mut i = gt.partition_point(|s| s.t.secs_since(first) < VELOCITY_HALF_SPAN_S);
    while i < gt.len() {
        let t0 = gt[i].t;
        let j = i + gt[i..].partition_point(|s| s.t.secs_since(t0) < window_s);
        let Some(end) = gt.get(j) else { break };
        if end.t.secs_since(last) > -VELOCITY_HALF_SPAN_S {
            break;
        }
        if let Some(b) = window_bias(gt, imu, i, j, gravity_up) {
            for (k, list) in biases.iter_mut().enumerate() {
                list.push(b[k]);
            }
        }
        i = j;
    }
    if biases[0].is_empty() {
        return None;
    }
    let axes = biases.map(|b| sorted(b.into_iter()));
    Some(ImpliedAccelBias {
        window_s,
        windows: axes[0].len(),
        p10_m_s2: axis_percentile(&axes, 10.0),
        p50_m_s2: axis_percentile(&axes, 50.0),
        p90_m_s2: axis_percentile(&axes, 90.0),
    })
}

/// One window of [`implied_accel_bias`], between ground-truth states `i` and `j`.
fn window_bias(
    gt: &[GroundTruthState],
    imu: &[ImuSample],
    i: usize,
    j: usize,
    gravity_up: Vector3<f64>,
) -> Option<Vector3<f64>> {
    let (t0, t1) = (gt[i].t, gt[j].t);
    let dv = velocity_at(gt, j)? - velocity_at(gt, i)?;
    // Trapezoids between t0, every IMU sample inside, and t1.
    let inner = imu.partition_point(|s| s.t <= t0)..imu.partition_point(|s| s.t < t1);
    let times = std::iter::once(t0)
        .chain(imu[inner].iter().map(|s| s.t))
        .chain(std::iter::once(t1));
    let mut int_r = Matrix3::zeros();
    let mut int_ra = Vector3::zeros();
    let mut prev: Option<(TimeNs, Matrix3<f64>, Vector3<f64>)> = None;
    for t in times {
        let r = rotation_at(gt, t)?;
        let ra = r * imu_at(imu, t, |s| s.accel_m_s2)?;
        if let Some((tp, rp, rap)) = prev {
            let h = 0.5 * t.secs_since(tp);
            int_r += (rp + r) * h;
            int_ra += (rap + ra) * h;
        }
        prev = Some((t, r, ra));
    }
    let rhs = int_ra - dv - gravity_up * t1.secs_since(t0);
    let b = int_r.try_inverse()? * rhs;
    b.iter().all(|v| v.is_finite()).then_some(b)
}
