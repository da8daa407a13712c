//! IMU integration between two frames (paper eq. 1–6), in preintegrated form, with the bias
//! Jacobians of the appendix (eq. 41–50) and the noise covariance that weights the IMU residual
//! (eq. 16).
//!
//! # Scheme
//! Eq. 4–6 are Euler-forward sums over IMU steps `p` of length `T`. We keep that form but evaluate
//! each step at its midpoint: the step's angular rate and specific force are the means of the two
//! samples bounding it, and the rotation applied to the specific force is the mid-step rotation.
//! This makes the integration second-order accurate (the simulator test bounds it) while every
//! sum keeps the paper's structure. The sums are accumulated relative to frame i's body frame
//! (`delta_r`, `delta_v`, `delta_p`), which is eq. 5–6 with `R_p = R_i ΔR_ip` factored out:
//! `v_ij^w = R_i Δv − g Δt` and `t_ij^w = v_i Δt + R_i Δp − ½ g Δt²`.
//!
//! # Bias sign
//! We follow the sensor convention `measured = true + bias` (EuRoC ground truth, Kalibr), so the
//! corrected rate is `ω − b_ω`. The paper writes `ω + b_ω` (eq. 4), i.e. its `b` is our `−b`; the
//! bias residuals (eq. 13, rows 4–5) are unchanged and the bias Jacobians change sign.

use super::{ImuNoise, ImuSample};
use crate::geometry::{GRAVITY_M_S2, exp_so3, hat, right_jacobian};
use crate::time::TimeNs;
use nalgebra::{Matrix3, SMatrix, UnitQuaternion, Vector3};

/// Gyro and accelerometer biases (`measured = true + bias`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImuBias {
    pub gyro_rad_s: Vector3<f64>,
    pub accel_m_s2: Vector3<f64>,
}

/// Navigation state of the body frame at time `t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NavState {
    pub t: TimeNs,
    pub r_world_body: UnitQuaternion<f64>,
    pub p_world_m: Vector3<f64>,
    pub v_world_m_s: Vector3<f64>,
}

/// Gravity vector in the world frame (z up), m/s^2.
pub fn gravity_world() -> Vector3<f64> {
    Vector3::new(0.0, 0.0, -GRAVITY_M_S2)
}

/// 9x9 covariance of the preintegrated `[δφ, δv, δp]` (rotation in the end frame's tangent space,
/// velocity and position in frame i's body frame).
pub type PreintCov = SMatrix<f64, 9, 9>;

/// Preintegrated IMU measurements from `t_start` to `t_end` at bias linearisation point `bias`.
#[derive(Clone, Debug, PartialEq)]
pub struct Preintegration {
    pub t_start: TimeNs,
    pub t_end: TimeNs,
    /// Linearisation point of the biases.
    pub bias: ImuBias,
    /// `R_j^i` of eq. 4: rotation from frame j's body to frame i's body.
    pub delta_r: Matrix3<f64>,
    /// `R_i^T v_ij^w + g Δt`: velocity change in frame i's body, gravity excluded, m/s.
    pub delta_v: Vector3<f64>,
    /// Position change in frame i's body without the `v_i Δt` and gravity terms, m.
    pub delta_p: Vector3<f64>,
    /// d(ΔR)/d(b_ω) as a right perturbation (eq. 41: the matrix `A`, with our bias sign), rad per rad/s.
    pub d_r_d_bg: Matrix3<f64>,
    /// dΔv/db_ω (the body-frame part of eq. 45), (m/s) per (rad/s).
    pub d_v_d_bg: Matrix3<f64>,
    /// dΔv/db_a (body-frame part of eq. 50), s.
    pub d_v_d_ba: Matrix3<f64>,
    /// dΔp/db_ω (body-frame part of eq. 43), m per rad/s.
    pub d_p_d_bg: Matrix3<f64>,
    /// dΔp/db_a (body-frame part of eq. 49), s^2.
    pub d_p_d_ba: Matrix3<f64>,
    /// Covariance of `[δφ, δv, δp]` from the white measurement noise.
    pub cov: PreintCov,
    /// dΔv/dφ for a gyro whose axes are turned from the accelerometer's (the body's) by
    /// `Exp(φ)` (`ω_body = Exp(φ) ω_gyro`), at φ = 0: `Σ (ΔR_k [a_k]× − [ΔR_k a_k]×) δt`,
    /// (m/s) per rad ([`crate::imu::misalignment`]).
    pub d_v_d_misalignment: Matrix3<f64>,
    /// dΔp/dφ likewise, m per rad.
    pub d_p_d_misalignment: Matrix3<f64>,
}

impl Preintegration {
    /// An empty preintegration starting at `t`.
    pub fn new(t: TimeNs, bias: ImuBias) -> Self {
        Preintegration {
            t_start: t,
            t_end: t,
            bias,
            delta_r: Matrix3::identity(),
            delta_v: Vector3::zeros(),
            delta_p: Vector3::zeros(),
            d_r_d_bg: Matrix3::zeros(),
            d_v_d_bg: Matrix3::zeros(),
            d_v_d_ba: Matrix3::zeros(),
            d_p_d_bg: Matrix3::zeros(),
            d_p_d_ba: Matrix3::zeros(),
            cov: PreintCov::zeros(),
            d_v_d_misalignment: Matrix3::zeros(),
            d_p_d_misalignment: Matrix3::zeros(),
        }
    }

    /// Multiplies the rotation rows and columns of the noise covariance by `factor` (`D Σ D`,
    /// `D = diag(factor·I₃, I₆)`): the rotation's variance by `factor²`, its correlation with the
    /// velocity and position kept. A gyro whose error wanders over seconds (a real one on a
    /// vibrating airframe, or one turned against the camera) is then weighed by that error
    /// where the velocity and position, which carry the metric scale, keep the white noise.
    pub fn scale_rotation_noise(&mut self, factor: f64) {
        for k in 0..3 {
            for c in 0..9 {
                self.cov[(k, c)] *= factor;
                self.cov[(c, k)] *= factor;
            }
        }
    }

    /// Integration time Δt, s.
    pub fn dt_s(&self) -> f64 {
        self.t_end.secs_since(self.t_start)
    }

    /// Adds one step of `dt_s` with mean measured rate and specific force over the step.
    /// Eq. 4 (rotation), eq. 5 (velocity) and eq. 6 (position, whose weights `2(k+N−1−p)+1`
    /// are what this recursion produces), plus the recursive bias Jacobians and noise covariance.
    pub fn integrate_step(
        &mut self,
        gyro_rad_s: &Vector3<f64>,
        accel_m_s2: &Vector3<f64>,
        dt_s: f64,
        noise: Option<&ImuNoise>,
    ) {
        let w = gyro_rad_s - self.bias.gyro_rad_s;
        let a = accel_m_s2 - self.bias.accel_m_s2;
        let half_phi = w * (0.5 * dt_s);
        let dr_half = exp_so3(&half_phi);
        let dr_full = exp_so3(&(w * dt_s));
        let r_mid = self.delta_r * dr_half; // R_p at mid-step, relative to frame i
        let a_world_i = r_mid * a; // rotated specific force
        let r_mid_ahat = r_mid * hat(&a);

        // Jacobian of the mid-step rotation w.r.t. b_ω (right perturbation).
        let jr_half = right_jacobian(&half_phi);
        let d_rmid_d_bg = dr_half.transpose() * self.d_r_d_bg - jr_half * (0.5 * dt_s);

        // Covariance: error state [δφ, δv, δp], noise [n_ω, n_a] (discrete, per step).
        if let Some(n) = noise {
            let jr_full = right_jacobian(&(w * dt_s));
            let mut f = SMatrix::<f64, 9, 9>::identity();
            f.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&dr_full.transpose());
            let dv_dphi = -r_mid_ahat * dr_half.transpose() * dt_s;
            f.fixed_view_mut::<3, 3>(3, 0).copy_from(&dv_dphi);
            f.fixed_view_mut::<3, 3>(6, 0)
                .copy_from(&(dv_dphi * (0.5 * dt_s)));
            f.fixed_view_mut::<3, 3>(6, 3)
                .copy_from(&(Matrix3::identity() * dt_s));
            let mut g = SMatrix::<f64, 9, 6>::zeros();
            g.fixed_view_mut::<3, 3>(0, 0).copy_from(&(jr_full * dt_s));
            g.fixed_view_mut::<3, 3>(3, 0)
                .copy_from(&(-r_mid_ahat * jr_half * (0.5 * dt_s * dt_s)));
            g.fixed_view_mut::<3, 3>(3, 3).copy_from(&(r_mid * dt_s));
            g.fixed_view_mut::<3, 3>(6, 3)
                .copy_from(&(r_mid * (0.5 * dt_s * dt_s)));
            // Continuous densities -> discrete variance of the step's mean measurement.
            let qg = n.gyro_noise_density.powi(2) / dt_s;
            let qa = n.accel_noise_density.powi(2) / dt_s;
            let mut q = SMatrix::<f64, 6, 6>::zeros();
            for k in 0..3 {
                q[(k, k)] = qg;
                q[(k + 3, k + 3)] = qa;
            }
            self.cov = f * self.cov * f.transpose() + g * q * g.transpose();
        }

        // Bias Jacobians (appendix, eq. 41–50), position first: it uses the old velocity ones.
        self.d_p_d_bg += self.d_v_d_bg * dt_s - r_mid_ahat * d_rmid_d_bg * (0.5 * dt_s * dt_s);
        self.d_p_d_ba += self.d_v_d_ba * dt_s - r_mid * (0.5 * dt_s * dt_s);
        self.d_v_d_bg -= r_mid_ahat * d_rmid_d_bg * dt_s;
        self.d_v_d_ba -= r_mid * dt_s;
        self.d_r_d_bg = dr_full.transpose() * self.d_r_d_bg - right_jacobian(&(w * dt_s)) * dt_s;
        // A turned gyro turns the rotation history the specific force is summed through:
        // d(Exp(φ) R Exp(φ)ᵀ a)/dφ = R [a]× − [R a]× at φ = 0.
        let d_a_d_mis = r_mid_ahat - hat(&a_world_i);
        self.d_p_d_misalignment += self.d_v_d_misalignment * dt_s + d_a_d_mis * (0.5 * dt_s * dt_s);
        self.d_v_d_misalignment += d_a_d_mis * dt_s;

        // State (eq. 4–6).
        self.delta_p += self.delta_v * dt_s + a_world_i * (0.5 * dt_s * dt_s);
        self.delta_v += a_world_i * dt_s;
        self.delta_r *= dr_full;
        self.t_end = self.t_end.add_ns((dt_s * 1e9).round() as i64);
    }

    /// Integrates `samples` (time ordered; they should bracket `[t_start, t_end]`) from the current
    /// end time to `t_end`. Measurements are linearly interpolated at the interval ends, so frame
    /// times need not coincide with IMU sample times. Samples outside the interval are ignored;
    /// if the samples do not cover the interval, the nearest sample is held constant.
    pub fn integrate(&mut self, samples: &[ImuSample], t_end: TimeNs, noise: Option<&ImuNoise>) {
        let t0 = self.t_end;
        if t_end <= t0 || samples.is_empty() {
            return;
        }
        let at = |t: TimeNs| interpolate_sample(samples, t);
        let mut prev = at(t0);
        let mut t_prev = t0;
        let start = samples.partition_point(|s| s.t <= t0);
        for s in samples[start..].iter().take_while(|s| s.t < t_end) {
            self.step_between(&prev, s, t_prev, s.t, noise);
            prev = *s;
            t_prev = s.t;
        }
        let end = at(t_end);
        self.step_between(&prev, &end, t_prev, t_end, noise);
        self.t_end = t_end; // exact, whatever rounding happened per step
    }

    fn step_between(
        &mut self,
        a: &ImuSample,
        b: &ImuSample,
        ta: TimeNs,
        tb: TimeNs,
        noise: Option<&ImuNoise>,
    ) {
        let dt_s = tb.secs_since(ta);
        if dt_s <= 0.0 {
            return;
        }
        let w = (a.gyro_rad_s + b.gyro_rad_s) * 0.5;
        let f = (a.accel_m_s2 + b.accel_m_s2) * 0.5;
        self.integrate_step(&w, &f, dt_s, noise);
    }

    /// First-order bias correction (the paper's eq. 40 and its analogues): the preintegrated
    /// `(ΔR, Δv, Δp)` for biases `bias` instead of the linearisation point.
    pub fn corrected(&self, bias: &ImuBias) -> (Matrix3<f64>, Vector3<f64>, Vector3<f64>) {
        let dbg = bias.gyro_rad_s - self.bias.gyro_rad_s;
        let dba = bias.accel_m_s2 - self.bias.accel_m_s2;
        (
            self.delta_r * exp_so3(&(self.d_r_d_bg * dbg)),
            self.delta_v + self.d_v_d_bg * dbg + self.d_v_d_ba * dba,
            self.delta_p + self.d_p_d_bg * dbg + self.d_p_d_ba * dba,
        )
    }

    /// Predicts the state at `t_end` from `state` at `t_start` (eq. 1–3), using `bias` through the
    /// first-order correction.
    pub fn predict(&self, state: &NavState, bias: &ImuBias) -> NavState {
        let (dr, dv, dp) = self.corrected(bias);
        let dt = self.dt_s();
        let g = gravity_world();
        let r_i = state.r_world_body.to_rotation_matrix();
        let r_j = r_i.matrix() * dr;
        NavState {
            t: self.t_end,
            r_world_body: UnitQuaternion::from_matrix(&r_j),
            p_world_m: state.p_world_m + state.v_world_m_s * dt + r_i * dp + g * (0.5 * dt * dt),
            v_world_m_s: state.v_world_m_s + r_i * dv + g * dt,
        }
    }
}

/// Measurement at time `t`, linearly interpolated between the bracketing samples (held at the
/// ends).
fn interpolate_sample(samples: &[ImuSample], t: TimeNs) -> ImuSample {
    let i = samples.partition_point(|s| s.t < t);
    if i == 0 {
        return ImuSample { t, ..samples[0] };
    }
    if i >= samples.len() {
        return ImuSample {
            t,
            ..samples[samples.len() - 1]
        };
    }
    let (a, b) = (&samples[i - 1], &samples[i]);
    let s = t.ns_since(a.t) as f64 / b.t.ns_since(a.t) as f64;
    ImuSample {
        t,
        gyro_rad_s: a.gyro_rad_s.lerp(&b.gyro_rad_s, s),
        accel_m_s2: a.accel_m_s2.lerp(&b.accel_m_s2, s),
    }
}

/// Propagates `state` to `t_end` with the samples covering `[state.t, t_end]` (midpoint scheme).
pub fn propagate(
    state: &NavState,
    samples: &[ImuSample],
    t_end: TimeNs,
    bias: &ImuBias,
) -> NavState {
    let mut pre = Preintegration::new(state.t, *bias);
    pre.integrate(samples, t_end, None);
    pre.predict(state, bias)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::log_so3;

    /// Body motion with closed-form angular rate and acceleration: rotation exp(phi(t)) with
    /// phi = (0.3 sin t, 0.2 t, 0.1 cos 2t) is awkward to differentiate, so we use a constant
    /// body rate and a world acceleration a(t) = (sin t, cos 2t, 0.5 sin 3t).
    fn motion(t: f64) -> (Matrix3<f64>, Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let w_body = Vector3::new(0.3, -0.2, 0.5);
        let r = exp_so3(&(w_body * t));
        let a = Vector3::new(t.sin(), (2.0 * t).cos(), 0.5 * (3.0 * t).sin());
        let v = Vector3::new(
            1.0 - t.cos(),
            (2.0 * t).sin() / 2.0,
            0.5 * (1.0 - (3.0 * t).cos()) / 3.0,
        );
        let p = Vector3::new(
            t - t.sin(),
            (1.0 - (2.0 * t).cos()) / 4.0,
            0.5 * (t - (3.0 * t).sin() / 3.0) / 3.0,
        );
        (r, v, p, a)
    }

    fn samples(bias: &ImuBias, t_end_s: f64, rate_hz: f64) -> Vec<ImuSample> {
        let n = (t_end_s * rate_hz).round() as i64;
        (0..=n)
            .map(|k| {
                let t = k as f64 / rate_hz;
                let (r, _, _, a) = motion(t);
                ImuSample {
                    t: TimeNs::from_secs_f64(t),
                    gyro_rad_s: Vector3::new(0.3, -0.2, 0.5) + bias.gyro_rad_s,
                    accel_m_s2: r.transpose() * (a - gravity_world()) + bias.accel_m_s2,
                }
            })
            .collect()
    }

    fn start() -> NavState {
        NavState {
            t: TimeNs(0),
            r_world_body: UnitQuaternion::identity(),
            p_world_m: Vector3::zeros(),
            v_world_m_s: Vector3::zeros(),
        }
    }

    #[test]
    fn propagation_follows_analytic_motion() {
        let bias = ImuBias {
            gyro_rad_s: Vector3::new(0.01, -0.02, 0.005),
            accel_m_s2: Vector3::new(0.1, 0.0, -0.2),
        };
        let s = samples(&bias, 10.0, 200.0);
        let end = propagate(&start(), &s, TimeNs::from_secs_f64(10.0), &bias);
        let (r, v, p, _) = motion(10.0);
        let rot_err =
            log_so3(&(r.transpose() * end.r_world_body.to_rotation_matrix().matrix())).norm();
        assert!(rot_err < 1e-9, "rotation error {rot_err}");
        assert!(
            (end.v_world_m_s - v).norm() < 2e-4,
            "velocity error {}",
            (end.v_world_m_s - v).norm()
        );
        assert!(
            (end.p_world_m - p).norm() < 1e-3,
            "position error {}",
            (end.p_world_m - p).norm()
        );
    }

    #[test]
    fn off_grid_interval_ends_are_interpolated() {
        let bias = ImuBias::default();
        let s = samples(&bias, 1.0, 200.0);
        let (t0, t1) = (TimeNs(12_345_678), TimeNs(987_654_321));
        let (r0, v0, p0, _) = motion(t0.as_secs_f64());
        let st = NavState {
            t: t0,
            r_world_body: UnitQuaternion::from_matrix(&r0),
            p_world_m: p0,
            v_world_m_s: v0,
        };
        let end = propagate(&st, &s, t1, &bias);
        let (_, v1, p1, _) = motion(t1.as_secs_f64());
        assert!((end.p_world_m - p1).norm() < 1e-5 && (end.v_world_m_s - v1).norm() < 1e-4);
    }

    fn numeric_bias_jacobian(which: usize) -> (SMatrix<f64, 9, 3>, SMatrix<f64, 9, 3>) {
        // Columns: d[δφ, δv, δp]/d b for a 50 ms window at 200 Hz with a fresh integration
        // (numeric) versus the first-order Jacobians (analytic).
        let base = ImuBias {
            gyro_rad_s: Vector3::new(0.02, -0.01, 0.03),
            accel_m_s2: Vector3::new(0.1, -0.05, 0.2),
        };
        let s = samples(&ImuBias::default(), 0.05, 200.0);
        let t_end = TimeNs::from_secs_f64(0.05);
        let run = |b: ImuBias| {
            let mut p = Preintegration::new(TimeNs(0), b);
            p.integrate(&s, t_end, None);
            p
        };
        let p0 = run(base);
        let h = 1e-6;
        let mut num = SMatrix::<f64, 9, 3>::zeros();
        let mut ana = SMatrix::<f64, 9, 3>::zeros();
        for k in 0..3 {
            let mut b = base;
            if which == 0 {
                b.gyro_rad_s[k] += h
            } else {
                b.accel_m_s2[k] += h
            }
            let p1 = run(b);
            let dphi = log_so3(&(p0.delta_r.transpose() * p1.delta_r)) / h;
            num.fixed_view_mut::<3, 1>(0, k).copy_from(&dphi);
            num.fixed_view_mut::<3, 1>(3, k)
                .copy_from(&((p1.delta_v - p0.delta_v) / h));
            num.fixed_view_mut::<3, 1>(6, k)
                .copy_from(&((p1.delta_p - p0.delta_p) / h));
        }
        if which == 0 {
            ana.fixed_view_mut::<3, 3>(0, 0).copy_from(&p0.d_r_d_bg);
            ana.fixed_view_mut::<3, 3>(3, 0).copy_from(&p0.d_v_d_bg);
            ana.fixed_view_mut::<3, 3>(6, 0).copy_from(&p0.d_p_d_bg);
        } else {
            ana.fixed_view_mut::<3, 3>(3, 0).copy_from(&p0.d_v_d_ba);
            ana.fixed_view_mut::<3, 3>(6, 0).copy_from(&p0.d_p_d_ba);
        }
        (num, ana)
    }

    #[test]
    fn rotation_noise_scales_the_rotation_block_only() {
        let s = samples(&ImuBias::default(), 0.5, 200.0);
        let mut p = Preintegration::new(TimeNs(0), ImuBias::default());
        p.integrate(
            &s,
            TimeNs::from_secs_f64(0.5),
            Some(&ImuNoise::euroc_adis16448()),
        );
        let before = p.cov;
        p.scale_rotation_noise(5.0);
        for r in 0..9 {
            for c in 0..9 {
                let k = match (r < 3, c < 3) {
                    (true, true) => 25.0,
                    (false, false) => 1.0,
                    _ => 5.0,
                };
                let want = k * before[(r, c)];
                assert!(
                    (p.cov[(r, c)] - want).abs() <= 1e-12 * want.abs().max(1e-30),
                    "({r}, {c}): {} against {want}",
                    p.cov[(r, c)]
                );
            }
        }
        // The rotation–velocity coupling the preintegration builds is there to be scaled.
        assert!(before.fixed_view::<3, 3>(3, 0).norm() > 0.0);
        assert!(p.cov.cholesky().is_some());
    }

    #[test]
    fn bias_jacobians_match_numeric_differentiation() {
        for which in 0..2 {
            let (num, ana) = numeric_bias_jacobian(which);
            let err = (num - ana).abs().max();
            assert!(
                err < 1e-6 * num.abs().max().max(1e-3),
                "bias {which}: {err}\n{num}\n{ana}"
            );
        }
    }

    #[test]
    fn first_order_bias_correction_error_is_bounded_for_50ms() {
        // The paper's first-order updates (eq. 40, 43, 45) vs re-integration, for a bias change
        // of 0.01 rad/s and 0.1 m/s^2 over 50 ms at 200 Hz.
        let s = samples(&ImuBias::default(), 0.05, 200.0);
        let t_end = TimeNs::from_secs_f64(0.05);
        let lin = ImuBias::default();
        let mut p = Preintegration::new(TimeNs(0), lin);
        p.integrate(&s, t_end, None);
        let nb = ImuBias {
            gyro_rad_s: Vector3::new(0.01, -0.01, 0.01),
            accel_m_s2: Vector3::new(0.1, 0.1, -0.1),
        };
        let mut q = Preintegration::new(TimeNs(0), nb);
        q.integrate(&s, t_end, None);
        let (dr, dv, dp) = p.corrected(&nb);
        // Second-order terms: the cross term δb_ω·δb_a·Δt² ≈ 2.5e-6 m/s dominates.
        let (er, ev, ep) = (
            log_so3(&(dr.transpose() * q.delta_r)).norm(),
            (dv - q.delta_v).norm(),
            (dp - q.delta_p).norm(),
        );
        assert!(
            er < 1e-8 && ev < 1e-5 && ep < 2e-7,
            "rot {er:e} rad, vel {ev:e} m/s, pos {ep:e} m"
        );
    }

    #[test]
    fn covariance_grows_like_a_random_walk() {
        // Static IMU: velocity variance after T seconds = sigma_a^2 * T (per axis).
        let noise = ImuNoise::euroc_adis16448();
        let s: Vec<ImuSample> = (0..=200)
            .map(|k| ImuSample {
                t: TimeNs(k * 5_000_000),
                gyro_rad_s: Vector3::zeros(),
                accel_m_s2: Vector3::new(0.0, 0.0, GRAVITY_M_S2),
            })
            .collect();
        let mut p = Preintegration::new(TimeNs(0), ImuBias::default());
        p.integrate(&s, TimeNs(1_000_000_000), Some(&noise));
        // Vertical axis (along gravity: no coupling with attitude error).
        let var_v = p.cov[(5, 5)];
        let expect = noise.accel_noise_density.powi(2) * 1.0;
        assert!((var_v / expect - 1.0).abs() < 0.05, "{var_v} vs {expect}");
        let var_phi = p.cov[(0, 0)];
        let expect_phi = noise.gyro_noise_density.powi(2) * 1.0;
        assert!(
            (var_phi / expect_phi - 1.0).abs() < 0.05,
            "{var_phi} vs {expect_phi}"
        );
        // Position variance of integrated white acceleration noise: sigma^2 T^3 / 3.
        let var_p = p.cov[(8, 8)];
        assert!(
            (var_p / (noise.accel_noise_density.powi(2) / 3.0) - 1.0).abs() < 0.05,
            "{var_p}"
        );
        // Horizontal velocity also integrates g × attitude error: σ_a² T + g² σ_ω² T³ / 3.
        let expect_h = expect + GRAVITY_M_S2.powi(2) * expect_phi / 3.0;
        assert!(
            (p.cov[(3, 3)] / expect_h - 1.0).abs() < 0.05,
            "{} vs {expect_h}",
            p.cov[(3, 3)]
        );
    }
}
