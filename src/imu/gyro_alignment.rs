//! Online estimate of the rotation between the gyro's axes and the body frame that the camera
//! extrinsic `T_body_cam` defines — a hand-eye rotation calibration from the relative rotations
//! tracking measures and the gyro integrated over the same intervals.
//!
//! The paper's residual (eq. 13, rotation rows) compares the preintegrated gyro `ΔR` (eq. 4) with
//! the relative rotation of two states whose orientations the photometric term fixes through the
//! camera: `R_body = R_cam · R_cam_body`. If the gyro's axes are turned by a small rotation from
//! that body frame, every turn of the vehicle leaks into the other axes (a yaw rate of 0.5 rad/s
//! and 1.3° make 0.011 rad/s about a horizontal axis), and the estimator holds the difference as a
//! tilt of the body against gravity that the accelerometer bias then has to explain. Measured on
//! S-V101 (the real V1_01 gyro against the rendered camera): the real gyro is turned by ~1.3° from
//! the camera's body frame, the estimate's gravity direction is 2.3–2.7° off for the whole flight
//! and its accelerometer bias 0.4 m/s² short (docs/odometry-log.md, *The real gyro is turned
//! against the camera*).
//!
//! Model: `ω_body = R_x ω_gyro`, `R_x` constant. Over an interval `[t_i, t_j]` the gyro
//! integrated in its own axes (bias `b` in those axes, eq. 4) gives `ΔR_g`; a constant rotation of
//! every rate conjugates the product exactly, so in the body frame the gyro predicts
//! `R_x ΔR_g R_xᵀ`, to be compared with the tracked `ΔR_v = R_iᵀ R_j`:
//!
//! `r = log((R_x ΔR_g(b + δb) R_xᵀ)ᵀ ΔR_v)`, unknowns `R_x ← exp(ε) R_x` and a gyro-bias error `δb`
//! shared by the pairs kept (the tracker's bias at each pair is the linearisation point; `δb`
//! takes what it got wrong on average).
//!
//! A pair turning by `φ` about `n` carries information on `ε` across `n` only (`J_ε ≈ (ΔR_vᵀ(ΔR_g
//! − I))`, zero along the axis); a flight that yaws and pitches fixes all three. The pairs are kept
//! in a fixed-capacity ring (no allocation after construction) and the estimate is re-solved from
//! all of them by Gauss–Newton with Huber weights and a prior around the calibrated extrinsic.

use crate::geometry::{exp_so3, log_so3, right_jacobian, right_jacobian_inv};
use nalgebra::{Matrix3, Matrix6, SMatrix, Vector3, Vector6};
use serde::{Deserialize, Serialize};

/// Settings of the gyro alignment (the `[gyro_alignment]` table).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GyroAlignmentConfig {
    /// Estimate the rotation (reported) and turn the gyro's samples by `initial_rotation_deg`.
    pub enabled: bool,
    /// Turn the gyro's samples by the estimate in flight as it firms up (else only by
    /// `initial_rotation_deg`).
    pub apply: bool,
    /// `log(R_x)` known beforehand (a calibration, an earlier flight's `report.json`
    /// `gyro_alignment_estimate_deg`), degrees: applied from the first sample, and the prior's
    /// centre.
    pub initial_rotation_deg: [f64; 3],
    /// A pair spans at least this long (one keyframe's tracked frames, at most its lifetime), s.
    pub min_interval_s: f64,
    /// Pairs turning less than this carry little information and are not kept, rad.
    pub min_rotation_rad: f64,
    /// Pairs whose residual at the current estimate exceeds this are gross errors (a keyframe
    /// moved under them, a failed track) and are dropped, rad.
    pub max_residual_rad: f64,
    /// Std of a pair's residual per axis (gyro white noise and vibration over the interval, the
    /// tracked rotations' error), rad. Measured: 0.06° per axis on S-V101's real gyro, 0.025° on
    /// the simulator's. The estimate's std is inflated by the residuals' RMS when they exceed it.
    pub pair_std_rad: f64,
    /// Huber threshold of a pair's residual norm, in `pair_std_rad`.
    pub huber_sigmas: f64,
    /// Prior std of the rotation about `initial_rotation_deg`, per axis, rad.
    pub prior_std_rad: f64,
    /// Prior std of the shared gyro-bias error, rad/s.
    pub bias_prior_std_rad_s: f64,
    /// Pairs kept (the oldest are dropped).
    pub max_pairs: usize,
    /// Pairs needed before the estimate is applied.
    pub min_pairs: usize,
    /// The estimate is applied only on axes whose std is below this, rad.
    pub max_apply_std_rad: f64,
    /// The applied rotation moves toward the estimate by at most this per update (a pair), rad:
    /// the tracker's state and the buffered samples stay consistent with the gyro.
    pub max_step_rad: f64,
    /// The tracked rotations of a pair are the photometric term's alone
    /// (`TrackResult::photometric_step` undoing the IMU's pull on the joint solution); else the
    /// joint solution itself, which the gyro pulls toward itself (the estimate then falls short).
    /// On S-V101 seeds 1–8 the estimate about body z moved from −0.51 … −0.69° (joint) to
    /// −0.57 … −0.72° (photometric), against −1.31° by a hand-eye fit on the ground truth: the
    /// pull is a small part of the shortfall.
    pub photometric_pairs: bool,
}

impl Default for GyroAlignmentConfig {
    fn default() -> Self {
        GyroAlignmentConfig {
            enabled: true,
            apply: false,
            initial_rotation_deg: [0.0; 3],
            min_interval_s: 0.2,
            min_rotation_rad: 0.05,
            max_residual_rad: 0.035,
            pair_std_rad: 0.001,
            huber_sigmas: 2.0,
            prior_std_rad: 0.035,
            bias_prior_std_rad_s: 0.005,
            max_pairs: 600,
            min_pairs: 30,
            max_apply_std_rad: 0.002,
            max_step_rad: 0.0005,
            photometric_pairs: true,
        }
    }
}

/// One interval: the gyro integrated in its own axes and the rotation tracking measured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RotationPair {
    /// `ΔR_g`: the gyro's samples over the interval, its bias (in its axes) removed (eq. 4).
    pub delta_r_gyro: Matrix3<f64>,
    /// `∂(ΔR_g)/∂b` as a right perturbation: `ΔR_g(b + δb) ≈ ΔR_g exp(J δb)`
    /// ([`crate::imu::Preintegration::d_r_d_bg`]).
    pub d_r_d_bg: Matrix3<f64>,
    /// `ΔR_v = R_iᵀ R_j`: the body's relative rotation as tracked.
    pub delta_r_vision: Matrix3<f64>,
}

impl RotationPair {
    /// The residual `r` at `(R_x, δb)` and its Jacobians `∂r/∂ε` (left perturbation of `R_x`) and
    /// `∂r/∂δb`.
    pub fn residual(
        &self,
        r_x: &Matrix3<f64>,
        dbg: &Vector3<f64>,
    ) -> (Vector3<f64>, Matrix3<f64>, Matrix3<f64>) {
        let phi_b = self.d_r_d_bg * dbg;
        let dr_g = self.delta_r_gyro * exp_so3(&phi_b);
        let g = r_x * dr_g * r_x.transpose();
        let m = g.transpose() * self.delta_r_vision;
        let r = log_so3(&m);
        let jr_inv = right_jacobian_inv(&r);
        // exp(ε) Gᵀ exp(−ε) ΔR_v = M exp((Mᵀ − ΔR_vᵀ) ε) to first order.
        let j_eps = jr_inv * (m.transpose() - self.delta_r_vision.transpose());
        // exp(J(δb + d)) ≈ exp(J δb) exp(J_r(J δb) J d) (eq. 30); then R_x exp(−J' d) N with
        // N = ΔR_gᵀ R_xᵀ ΔR_v is M exp(−Nᵀ J' d).
        let n = dr_g.transpose() * r_x.transpose() * self.delta_r_vision;
        let j_b = -jr_inv * n.transpose() * right_jacobian(&phi_b) * self.d_r_d_bg;
        (r, j_eps, j_b)
    }

    /// Rotation of the pair, rad.
    pub fn angle_rad(&self) -> f64 {
        log_so3(&self.delta_r_vision).norm()
    }
}

/// The estimate: `R_x` (gyro axes → body), its covariance, the pairs behind it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GyroAlignmentEstimate {
    /// `log(R_x)`, rad.
    pub rotation_rad: Vector3<f64>,
    /// Std of each component of the rotation (from the Gauss–Newton Hessian), rad.
    pub rotation_std_rad: Vector3<f64>,
    /// The shared gyro-bias error: what the pairs' bias (gyro axes) lacked on average, rad/s.
    pub bias_error_rad_s: Vector3<f64>,
    pub pairs: usize,
    /// RMS of the pairs' residuals at the estimate, rad.
    pub residual_rms_rad: f64,
}

/// Ring of pairs and the estimate solved from them.
#[derive(Clone, Debug)]
pub struct GyroAlignment {
    cfg: GyroAlignmentConfig,
    pairs: Vec<RotationPair>,
    next: usize,
    /// Gross pairs dropped.
    pub rejected: usize,
    estimate: Option<GyroAlignmentEstimate>,
    /// `initial_rotation_deg` in radians.
    prior_rad: Vector3<f64>,
}

impl GyroAlignment {
    pub fn new(cfg: GyroAlignmentConfig) -> Self {
        let cap = cfg.max_pairs.max(1);
        let prior_rad = Vector3::from(cfg.initial_rotation_deg).map(f64::to_radians);
        GyroAlignment {
            prior_rad,
            cfg,
            pairs: Vec::with_capacity(cap),
            next: 0,
            rejected: 0,
            estimate: None,
        }
    }

    pub fn config(&self) -> &GyroAlignmentConfig {
        &self.cfg
    }

    /// `initial_rotation_deg` in radians: the prior's centre.
    pub fn initial_rotation_rad(&self) -> Vector3<f64> {
        self.prior_rad
    }

    pub fn estimate(&self) -> Option<&GyroAlignmentEstimate> {
        self.estimate.as_ref()
    }

    pub fn len(&self) -> usize {
        self.pairs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }

    /// Offers a pair; returns whether it was kept. Pairs turning less than `min_rotation_rad` are
    /// ignored, and pairs whose residual at the current estimate exceeds `max_residual_rad`
    /// are counted in [`GyroAlignment::rejected`] and dropped.
    pub fn push(&mut self, pair: RotationPair) -> bool {
        let finite = pair.delta_r_gyro.iter().all(|v| v.is_finite())
            && pair.delta_r_vision.iter().all(|v| v.is_finite())
            && pair.d_r_d_bg.iter().all(|v| v.is_finite());
        if !finite || pair.angle_rad() < self.cfg.min_rotation_rad {
            return false;
        }
        let (r_x, dbg) = self.current();
        let (r, _, _) = pair.residual(&r_x, &dbg);
        let norm = r.norm();
        if norm.is_nan() || norm > self.cfg.max_residual_rad {
            self.rejected += 1;
            return false;
        }
        if self.pairs.len() < self.pairs.capacity() {
            self.pairs.push(pair);
        } else {
            self.pairs[self.next] = pair;
        }
        self.next = (self.next + 1) % self.pairs.capacity();
        true
    }

    fn current(&self) -> (Matrix3<f64>, Vector3<f64>) {
        match &self.estimate {
            Some(e) => (exp_so3(&e.rotation_rad), e.bias_error_rad_s),
            None => (exp_so3(&self.prior_rad), Vector3::zeros()),
        }
    }

    /// Solves for `(R_x, δb)` from all pairs kept (Gauss–Newton, `iterations` steps from the last
    /// estimate, Huber-weighted, priors around `initial_rotation_deg` and zero). `None` without
    /// pairs.
    pub fn solve(&mut self, iterations: usize) -> Option<&GyroAlignmentEstimate> {
        if self.pairs.is_empty() {
            return None;
        }
        let (mut r_x, mut dbg) = self.current();
        let w_rot = 1.0 / (self.cfg.prior_std_rad * self.cfg.prior_std_rad);
        let w_b = 1.0 / (self.cfg.bias_prior_std_rad_s * self.cfg.bias_prior_std_rad_s);
        let w_pair = 1.0 / (self.cfg.pair_std_rad * self.cfg.pair_std_rad);
        let huber_rad = self.cfg.huber_sigmas * self.cfg.pair_std_rad;
        let mut h = Matrix6::zeros();
        for _ in 0..iterations.max(1) {
            h = Matrix6::zeros();
            let mut g = Vector6::zeros();
            for p in &self.pairs {
                let (r, j_eps, j_b) = p.residual(&r_x, &dbg);
                let norm = r.norm();
                let w = w_pair
                    * if norm <= huber_rad {
                        1.0
                    } else {
                        huber_rad / norm
                    };
                let mut j = SMatrix::<f64, 3, 6>::zeros();
                j.fixed_view_mut::<3, 3>(0, 0).copy_from(&j_eps);
                j.fixed_view_mut::<3, 3>(0, 3).copy_from(&j_b);
                h += w * j.transpose() * j;
                g += w * j.transpose() * r;
            }
            // Priors: log(R_x) about the initial rotation (the left perturbation moves it by ε to
            // first order near it) and δb about 0.
            let theta = log_so3(&r_x) - self.prior_rad;
            for k in 0..3 {
                h[(k, k)] += w_rot;
                h[(k + 3, k + 3)] += w_b;
            }
            g.fixed_rows_mut::<3>(0).axpy(w_rot, &theta, 1.0);
            g.fixed_rows_mut::<3>(3).axpy(w_b, &dbg, 1.0);
            let Some(chol) = h.cholesky() else {
                return self.estimate.as_ref();
            };
            let dx = -chol.solve(&g);
            if !dx.iter().all(|v| v.is_finite()) {
                return self.estimate.as_ref();
            }
            r_x = exp_so3(&dx.fixed_rows::<3>(0).into_owned()) * r_x;
            dbg += dx.fixed_rows::<3>(3);
            if dx.norm() < 1e-9 {
                break;
            }
        }
        let ss: f64 = self
            .pairs
            .iter()
            .map(|p| p.residual(&r_x, &dbg).0.norm_squared())
            .sum();
        // Residuals larger than assumed: the Hessian's covariance is too optimistic by their
        // ratio (per axis, three per pair).
        let rms_axis = (ss / (3 * self.pairs.len()) as f64).sqrt();
        let inflation = (rms_axis / self.cfg.pair_std_rad).max(1.0);
        let cov = h.try_inverse().unwrap_or_else(Matrix6::zeros) * (inflation * inflation);
        self.estimate = Some(GyroAlignmentEstimate {
            rotation_rad: log_so3(&r_x),
            rotation_std_rad: Vector3::new(
                cov[(0, 0)].max(0.0).sqrt(),
                cov[(1, 1)].max(0.0).sqrt(),
                cov[(2, 2)].max(0.0).sqrt(),
            ),
            bias_error_rad_s: dbg,
            pairs: self.pairs.len(),
            residual_rms_rad: (ss / self.pairs.len() as f64).sqrt(),
        });
        self.estimate.as_ref()
    }

    /// The rotation to apply next, starting from `applied` (`log(R_x)` now in use): toward the
    /// estimate on the axes it knows to `max_apply_std_rad`, by at most `max_step_rad`. `None`
    /// while fewer than `min_pairs` pairs are kept, and without `apply`.
    pub fn next_applied(&self, applied: &Vector3<f64>) -> Option<Vector3<f64>> {
        if !self.cfg.apply {
            return None;
        }
        let e = self.estimate.as_ref()?;
        if e.pairs < self.cfg.min_pairs {
            return None;
        }
        let mut target = *applied;
        for k in 0..3 {
            if e.rotation_std_rad[k] <= self.cfg.max_apply_std_rad {
                target[k] = e.rotation_rad[k];
            }
        }
        let step = target - applied;
        let n = step.norm();
        let step = if n > self.cfg.max_step_rad {
            step * (self.cfg.max_step_rad / n)
        } else {
            step
        };
        Some(applied + step)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::{ImuBias, Preintegration};
    use crate::time::TimeNs;

    /// A pair whose gyro is turned by `r_true` from the body (ω_gyro = r_trueᵀ ω_body) and biased
    /// by `bias` (gyro axes), over `n` steps of `dt` at body rate `w_body(k)`.
    fn pair(
        r_true: &Matrix3<f64>,
        bias: &Vector3<f64>,
        w_body: impl Fn(usize) -> Vector3<f64>,
        n: usize,
        dt: f64,
    ) -> RotationPair {
        let mut dr_v = Matrix3::identity();
        // The odometry's own preintegration (eq. 4 and its bias Jacobian), bias 0.
        let mut pre = Preintegration::new(TimeNs(0), ImuBias::default());
        for k in 0..n {
            let wb = w_body(k);
            dr_v *= exp_so3(&(wb * dt));
            // The gyro measures r_trueᵀ ω + bias; the tracker removed no bias (δb = bias).
            let wg = r_true.transpose() * wb + bias;
            pre.integrate_step(&wg, &Vector3::zeros(), dt, None);
        }
        RotationPair {
            delta_r_gyro: pre.delta_r,
            d_r_d_bg: pre.d_r_d_bg,
            delta_r_vision: dr_v,
        }
    }

    fn flight(r_true: &Matrix3<f64>, bias: &Vector3<f64>) -> Vec<RotationPair> {
        (0..120)
            .map(|i| {
                let f = i as f64 * 0.37;
                pair(
                    r_true,
                    bias,
                    |k| {
                        let s = f + k as f64 * 0.005;
                        Vector3::new(
                            0.6 * (0.7 * s).sin(),
                            0.25 * (1.3 * s + 1.0).sin(),
                            0.2 * (0.9 * s + 2.0).cos(),
                        )
                    },
                    100,
                    0.005,
                )
            })
            .collect()
    }

    #[test]
    fn jacobians_match_numeric_differentiation() {
        let r_true = exp_so3(&Vector3::new(0.01, -0.02, 0.03));
        let p = pair(
            &r_true,
            &Vector3::new(0.003, -0.002, 0.001),
            |k| Vector3::new(0.8, -0.3 + 0.01 * k as f64, 0.4),
            80,
            0.005,
        );
        let r_x = exp_so3(&Vector3::new(-0.004, 0.006, 0.01));
        let dbg = Vector3::new(0.001, 0.002, -0.001);
        let (r0, j_eps, j_b) = p.residual(&r_x, &dbg);
        let h = 1e-6;
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let (rp, _, _) = p.residual(&(exp_so3(&d) * r_x), &dbg);
            let (rm, _, _) = p.residual(&(exp_so3(&-d) * r_x), &dbg);
            let num = (rp - rm) / (2.0 * h);
            assert!(
                (num - j_eps.column(k)).norm() < 1e-6,
                "eps {k}: {num} vs {}",
                j_eps.column(k)
            );
            let (rp, _, _) = p.residual(&r_x, &(dbg + d));
            let (rm, _, _) = p.residual(&r_x, &(dbg - d));
            let num = (rp - rm) / (2.0 * h);
            assert!(
                (num - j_b.column(k)).norm() < 1e-6,
                "bias {k}: {num} vs {}",
                j_b.column(k)
            );
        }
        assert!(
            r0.norm() > 1e-3,
            "the test pair must not be at the solution"
        );
    }

    #[test]
    fn recovers_a_turned_gyro_and_its_bias() {
        let theta = Vector3::new(0.006, -0.004, 0.023); // 0.34°, −0.23°, 1.3°
        let r_true = exp_so3(&theta);
        let bias = Vector3::new(0.002, -0.001, 0.0015);
        let mut a = GyroAlignment::new(GyroAlignmentConfig {
            apply: true,
            ..GyroAlignmentConfig::default()
        });
        for p in flight(&r_true, &bias) {
            a.push(p);
        }
        assert!(a.len() > 90, "{} pairs kept", a.len());
        assert_eq!(a.rejected, 0);
        let e = *a.solve(10).unwrap();
        assert!(
            (e.rotation_rad - theta).norm() < 2e-4,
            "{} vs {theta}",
            e.rotation_rad
        );
        // The bias correction is the gyro's bias (the pairs removed none), in its axes.
        assert!(
            (e.bias_error_rad_s - bias).norm() < 2e-4,
            "{} vs {bias}",
            e.bias_error_rad_s
        );
        assert!(e.residual_rms_rad < 1e-5);
        assert!(
            e.rotation_std_rad.iter().all(|s| *s < 3e-3),
            "{}",
            e.rotation_std_rad
        );
        // Applied in steps of at most max_step_rad.
        let cfg = a.config().clone();
        let mut applied = Vector3::zeros();
        let mut steps = 0;
        while (applied - e.rotation_rad).norm() > 1e-9 && steps < 1000 {
            let next = a.next_applied(&applied).unwrap();
            assert!((next - applied).norm() <= cfg.max_step_rad + 1e-12);
            applied = next;
            steps += 1;
        }
        assert!((applied - e.rotation_rad).norm() < 1e-9);
    }

    #[test]
    fn an_aligned_gyro_stays_at_identity() {
        let mut a = GyroAlignment::new(GyroAlignmentConfig::default());
        for p in flight(&Matrix3::identity(), &Vector3::zeros()) {
            a.push(p);
        }
        let e = *a.solve(10).unwrap();
        assert!(e.rotation_rad.norm() < 1e-9, "{}", e.rotation_rad);
    }

    #[test]
    fn gross_and_small_pairs_are_not_kept_and_the_ring_is_bounded() {
        let cfg = GyroAlignmentConfig {
            max_pairs: 50,
            ..GyroAlignmentConfig::default()
        };
        let mut a = GyroAlignment::new(cfg);
        let mut bad = pair(
            &Matrix3::identity(),
            &Vector3::zeros(),
            |_| Vector3::new(0.5, 0.0, 0.0),
            100,
            0.005,
        );
        bad.delta_r_vision = exp_so3(&Vector3::new(0.0, 0.1, 0.0)) * bad.delta_r_vision;
        assert!(!a.push(bad));
        assert_eq!(a.rejected, 1);
        let still = pair(
            &Matrix3::identity(),
            &Vector3::zeros(),
            |_| Vector3::new(0.01, 0.0, 0.0),
            100,
            0.005,
        );
        assert!(!a.push(still));
        let mut nan = still;
        nan.delta_r_vision[(0, 0)] = f64::NAN;
        assert!(!a.push(nan));
        for p in flight(&Matrix3::identity(), &Vector3::zeros()) {
            a.push(p);
        }
        assert_eq!(a.len(), 50);
        assert_eq!(a.pairs.capacity(), 50);
    }

    #[test]
    fn the_prior_is_centred_on_the_initial_rotation_and_apply_false_applies_nothing() {
        let theta = Vector3::new(0.0, 0.0, 0.02);
        let cfg = GyroAlignmentConfig {
            apply: false,
            initial_rotation_deg: [0.0, 0.0, 0.02f64.to_degrees()],
            ..GyroAlignmentConfig::default()
        };
        let mut a = GyroAlignment::new(cfg);
        // Pairs that say nothing about z (turns about z only): the estimate stays at the prior.
        for i in 0..60 {
            let p = pair(
                &exp_so3(&theta),
                &Vector3::zeros(),
                |k| Vector3::new(0.0, 0.0, 0.5 + 0.01 * ((i + k) % 7) as f64),
                100,
                0.005,
            );
            assert!(a.push(p));
        }
        let e = *a.solve(10).unwrap();
        assert!((e.rotation_rad - theta).norm() < 1e-6, "{}", e.rotation_rad);
        assert!(a.next_applied(&theta).is_none());
    }

    #[test]
    fn nothing_is_applied_before_min_pairs() {
        let theta = Vector3::new(0.0, 0.0, 0.02);
        let mut a = GyroAlignment::new(GyroAlignmentConfig {
            apply: true,
            ..GyroAlignmentConfig::default()
        });
        for p in flight(&exp_so3(&theta), &Vector3::zeros())
            .into_iter()
            .take(10)
        {
            a.push(p);
        }
        a.solve(5);
        assert!(a.next_applied(&Vector3::zeros()).is_none());
    }
}
