//! The 15-dim state of eq. 11 and the IMU residual of eq. 13 with its analytic Jacobians
//! (appendix eq. 33–52) and its covariance (the IMU block of the weight `A` in eq. 16).
//!
//! Residual order: `[r_R (3), r_t (3), r_v (3), r_bω (3), r_ba (3)]`, as eq. 13.
//! State increment of frame j (eq. 34, 36, 38): `R_j ← R_j Exp(δθ)`, `t_j ← t_j + R_j δt`,
//! `v_j ← v_j + δv`, `b ← b + δb`; increment order `[δθ, δt, δv, δbω, δba]`, as eq. 11.

use super::ImuNoise;
use super::integration::{ImuBias, NavState, Preintegration, gravity_world};
use crate::geometry::{exp_so3, hat, log_so3, right_jacobian, right_jacobian_inv};
use nalgebra::{Isometry3, Matrix3, SMatrix, SVector, Translation3, Vector3};

/// 15-vector in the order of eq. 11 / eq. 13.
pub type Vector15 = SVector<f64, 15>;
/// 15x15 matrix (Jacobians, covariances, information) in the order of eq. 11.
pub type Matrix15 = SMatrix<f64, 15, 15>;

/// Index of each 3-block in the state and residual vectors.
pub mod block {
    pub const ROT: usize = 0;
    pub const POS: usize = 3;
    pub const VEL: usize = 6;
    pub const BG: usize = 9;
    pub const BA: usize = 12;
}

/// The full per-frame state of eq. 11: pose, velocity and biases.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameState {
    pub nav: NavState,
    pub bias: ImuBias,
}

impl FrameState {
    /// This state in a world moved by `c` (`T_new = c · T_old`): the body pose composed with `c`,
    /// the velocity turned with it; time and biases kept.
    pub fn moved_by_world(&self, c: &Isometry3<f64>) -> FrameState {
        let pose = c * Isometry3::from_parts(
            Translation3::from(self.nav.p_world_m),
            self.nav.r_world_body,
        );
        let mut y = *self;
        y.nav.r_world_body = pose.rotation;
        y.nav.p_world_m = pose.translation.vector;
        y.nav.v_world_m_s = c.rotation * self.nav.v_world_m_s;
        y
    }

    /// Every component (pose, velocity, biases) is finite.
    pub fn is_finite(&self) -> bool {
        let n = &self.nav;
        n.p_world_m.iter().all(|v| v.is_finite())
            && n.v_world_m_s.iter().all(|v| v.is_finite())
            && n.r_world_body.coords.iter().all(|v| v.is_finite())
            && self.bias.gyro_rad_s.iter().all(|v| v.is_finite())
            && self.bias.accel_m_s2.iter().all(|v| v.is_finite())
    }

    /// Applies an increment `[δθ, δt, δv, δbω, δba]` (eq. 34, 36, 38).
    pub fn boxplus(&self, d: &Vector15) -> FrameState {
        let r = self.nav.r_world_body.to_rotation_matrix();
        let dth: Vector3<f64> = d.fixed_rows::<3>(block::ROT).into();
        let dt: Vector3<f64> = d.fixed_rows::<3>(block::POS).into();
        let mut out = *self;
        out.nav.r_world_body =
            self.nav.r_world_body * nalgebra::UnitQuaternion::from_scaled_axis(dth);
        out.nav.p_world_m += r * dt;
        out.nav.v_world_m_s += d.fixed_rows::<3>(block::VEL);
        out.bias.gyro_rad_s += d.fixed_rows::<3>(block::BG);
        out.bias.accel_m_s2 += d.fixed_rows::<3>(block::BA);
        out
    }
}

fn put(m: &mut Matrix15, r: usize, c: usize, b: &Matrix3<f64>) {
    m.fixed_view_mut::<3, 3>(r, c).copy_from(b);
}

/// Eq. 13 with frame j's biases in the (first-order corrected) preintegration.
pub fn imu_residual(pre: &Preintegration, xi: &FrameState, xj: &FrameState) -> Vector15 {
    let (dr, dv, dp) = pre.corrected(&xj.bias);
    let dt = pre.dt_s();
    let g = gravity_world();
    let ri = *xi.nav.r_world_body.to_rotation_matrix().matrix();
    let rj = *xj.nav.r_world_body.to_rotation_matrix().matrix();
    let mut r = Vector15::zeros();
    r.fixed_rows_mut::<3>(block::ROT)
        .copy_from(&log_so3(&(dr.transpose() * ri.transpose() * rj)));
    let t_ij = xi.nav.v_world_m_s * dt + ri * dp + g * (0.5 * dt * dt);
    r.fixed_rows_mut::<3>(block::POS)
        .copy_from(&(xj.nav.p_world_m - t_ij - xi.nav.p_world_m));
    let v_ij = ri * dv + g * dt;
    r.fixed_rows_mut::<3>(block::VEL)
        .copy_from(&(xj.nav.v_world_m_s - v_ij - xi.nav.v_world_m_s));
    r.fixed_rows_mut::<3>(block::BG)
        .copy_from(&(xi.bias.gyro_rad_s - xj.bias.gyro_rad_s));
    r.fixed_rows_mut::<3>(block::BA)
        .copy_from(&(xi.bias.accel_m_s2 - xj.bias.accel_m_s2));
    r
}

/// d r / d(increment of frame j): eq. 35, 37, 38 (pose and velocity), eq. 42, 43, 45 (gyro bias),
/// eq. 46–52 (accel bias, bias rows). Bias columns carry our sign convention (see
/// [`super::integration`]).
pub fn imu_jacobian_j(pre: &Preintegration, xi: &FrameState, xj: &FrameState) -> Matrix15 {
    use block::*;
    let r = imu_residual(pre, xi, xj);
    let r_rot: Vector3<f64> = r.fixed_rows::<3>(ROT).into();
    let jr_inv = right_jacobian_inv(&r_rot);
    let ri = *xi.nav.r_world_body.to_rotation_matrix().matrix();
    let rj = *xj.nav.r_world_body.to_rotation_matrix().matrix();
    let dbg = xj.bias.gyro_rad_s - pre.bias.gyro_rad_s;
    let mut j = Matrix15::zeros();
    put(&mut j, ROT, ROT, &jr_inv); // eq. 35
    let d_rot_d_bg = -jr_inv
        * exp_so3(&r_rot).transpose()
        * right_jacobian(&(pre.d_r_d_bg * dbg))
        * pre.d_r_d_bg;
    put(&mut j, ROT, BG, &d_rot_d_bg); // eq. 42
    put(&mut j, POS, POS, &rj); // eq. 37
    put(&mut j, POS, BG, &(-ri * pre.d_p_d_bg)); // eq. 43
    put(&mut j, POS, BA, &(-ri * pre.d_p_d_ba)); // eq. 49
    put(&mut j, VEL, VEL, &Matrix3::identity()); // eq. 38
    put(&mut j, VEL, BG, &(-ri * pre.d_v_d_bg)); // eq. 45
    put(&mut j, VEL, BA, &(-ri * pre.d_v_d_ba)); // eq. 50
    put(&mut j, BG, BG, &-Matrix3::identity()); // eq. 46
    put(&mut j, BA, BA, &-Matrix3::identity()); // eq. 52
    j
}

/// d r / d(increment of frame i) — not optimised (frame i is fixed, section III-A), but needed to
/// carry frame i's uncertainty into the residual covariance.
pub fn imu_jacobian_i(pre: &Preintegration, xi: &FrameState, xj: &FrameState) -> Matrix15 {
    use block::*;
    let r = imu_residual(pre, xi, xj);
    let r_rot: Vector3<f64> = r.fixed_rows::<3>(ROT).into();
    let (_, dv, dp) = pre.corrected(&xj.bias);
    let ri = *xi.nav.r_world_body.to_rotation_matrix().matrix();
    let rj = *xj.nav.r_world_body.to_rotation_matrix().matrix();
    let dt = pre.dt_s();
    let mut j = Matrix15::zeros();
    put(
        &mut j,
        ROT,
        ROT,
        &(-right_jacobian_inv(&r_rot) * rj.transpose() * ri),
    );
    put(&mut j, POS, ROT, &(ri * hat(&dp)));
    put(&mut j, POS, POS, &-ri);
    put(&mut j, POS, VEL, &(-Matrix3::identity() * dt));
    put(&mut j, VEL, ROT, &(ri * hat(&dv)));
    put(&mut j, VEL, VEL, &-Matrix3::identity());
    put(&mut j, BG, BG, &Matrix3::identity());
    put(&mut j, BA, BA, &Matrix3::identity());
    j
}

/// Covariance of the IMU residual: the preintegrated measurement noise (rotated into the world for
/// the translation and velocity rows), the bias random walk over Δt (eq. 9–10), and frame i's own
/// covariance `cov_i` carried through [`imu_jacobian_i`]. Its inverse is the IMU block of `A`.
pub fn imu_residual_covariance(
    pre: &Preintegration,
    noise: &ImuNoise,
    xi: &FrameState,
    xj: &FrameState,
    cov_i: &Matrix15,
) -> Matrix15 {
    use block::*;
    let ri = *xi.nav.r_world_body.to_rotation_matrix().matrix();
    // Map preintegration noise [δφ, δv, δp] into residual rows [rot, pos, vel].
    let mut m = SMatrix::<f64, 15, 9>::zeros();
    m.fixed_view_mut::<3, 3>(ROT, 0)
        .copy_from(&Matrix3::identity());
    m.fixed_view_mut::<3, 3>(VEL, 3).copy_from(&ri);
    m.fixed_view_mut::<3, 3>(POS, 6).copy_from(&ri);
    let mut cov = m * pre.cov * m.transpose();
    let dt = pre.dt_s();
    for k in 0..3 {
        cov[(BG + k, BG + k)] += noise.gyro_random_walk.powi(2) * dt;
        cov[(BA + k, BA + k)] += noise.accel_random_walk.powi(2) * dt;
    }
    let ji = imu_jacobian_i(pre, xi, xj);
    cov + ji * cov_i * ji.transpose()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::ImuSample;
    use crate::time::TimeNs;
    use nalgebra::UnitQuaternion;

    fn setup() -> (Preintegration, FrameState, FrameState) {
        let lin = ImuBias {
            gyro_rad_s: Vector3::new(0.01, 0.0, -0.02),
            accel_m_s2: Vector3::new(0.05, -0.1, 0.02),
        };
        let samples: Vec<ImuSample> = (0..=10)
            .map(|k| ImuSample {
                t: TimeNs(k * 5_000_000),
                gyro_rad_s: Vector3::new(0.5, -0.3 + 0.05 * k as f64, 0.8),
                accel_m_s2: Vector3::new(1.0 + 0.1 * k as f64, -0.4, 9.6),
            })
            .collect();
        let mut pre = Preintegration::new(TimeNs(0), lin);
        pre.integrate(
            &samples,
            TimeNs(50_000_000),
            Some(&ImuNoise::euroc_adis16448()),
        );
        let xi = FrameState {
            nav: NavState {
                t: TimeNs(0),
                r_world_body: UnitQuaternion::from_scaled_axis(Vector3::new(0.2, -0.4, 1.0)),
                p_world_m: Vector3::new(1.0, 2.0, 0.5),
                v_world_m_s: Vector3::new(0.3, -0.2, 0.1),
            },
            bias: lin,
        };
        // Frame j: the prediction, perturbed so the residual is not zero.
        let pred = pre.predict(&xi.nav, &lin);
        let xj = FrameState {
            nav: NavState {
                r_world_body: pred.r_world_body
                    * UnitQuaternion::from_scaled_axis(Vector3::new(0.01, -0.02, 0.015)),
                p_world_m: pred.p_world_m + Vector3::new(0.01, 0.0, -0.02),
                v_world_m_s: pred.v_world_m_s + Vector3::new(-0.03, 0.02, 0.0),
                ..pred
            },
            bias: ImuBias {
                gyro_rad_s: lin.gyro_rad_s + Vector3::new(0.003, -0.002, 0.001),
                accel_m_s2: lin.accel_m_s2 + Vector3::new(-0.02, 0.01, 0.03),
            },
        };
        (pre, xi, xj)
    }

    fn numeric(f: impl Fn(&Vector15) -> Vector15) -> Matrix15 {
        let h = 1e-7;
        let mut j = Matrix15::zeros();
        for k in 0..15 {
            let mut d = Vector15::zeros();
            d[k] = h;
            j.set_column(k, &((f(&d) - f(&-d)) / (2.0 * h)));
        }
        j
    }

    #[test]
    fn residual_is_zero_at_the_prediction() {
        let (pre, xi, _) = setup();
        let xj = FrameState {
            nav: pre.predict(&xi.nav, &xi.bias),
            bias: xi.bias,
        };
        assert!(imu_residual(&pre, &xi, &xj).norm() < 1e-12);
    }

    #[test]
    fn jacobian_wrt_frame_j_matches_numeric() {
        let (pre, xi, xj) = setup();
        let num = numeric(|d| imu_residual(&pre, &xi, &xj.boxplus(d)));
        let ana = imu_jacobian_j(&pre, &xi, &xj);
        let err = (num - ana).abs().max();
        assert!(
            err < 1e-6,
            "max error {err:e}\nnumeric {num}\nanalytic {ana}"
        );
    }

    #[test]
    fn jacobian_wrt_frame_i_matches_numeric() {
        let (pre, xi, xj) = setup();
        let num = numeric(|d| imu_residual(&pre, &xi.boxplus(d), &xj));
        let ana = imu_jacobian_i(&pre, &xi, &xj);
        // Bias columns of frame i: only the bias rows (the preintegration uses frame j's bias).
        let err = (num - ana).abs().max();
        assert!(
            err < 1e-6,
            "max error {err:e}\nnumeric {num}\nanalytic {ana}"
        );
    }

    #[test]
    fn covariance_is_symmetric_positive_definite() {
        let (pre, xi, xj) = setup();
        let cov_i = Matrix15::identity() * 1e-4;
        let c = imu_residual_covariance(&pre, &ImuNoise::euroc_adis16448(), &xi, &xj, &cov_i);
        assert!((c - c.transpose()).abs().max() < 1e-15);
        assert!(c.cholesky().is_some());
        let c0 = imu_residual_covariance(
            &pre,
            &ImuNoise::euroc_adis16448(),
            &xi,
            &xj,
            &Matrix15::zeros(),
        );
        assert!(
            c0.cholesky().is_some(),
            "measurement noise alone must be full rank"
        );
        assert!(c[(block::POS, block::POS)] > c0[(block::POS, block::POS)]);
    }
}
