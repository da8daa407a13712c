//! An IMU whose attitude wanders slowly against the camera's: the IMU frame is the body frame
//! the camera is calibrated in, turned by a small, time-varying `Exp(ψ)`, `R_imu = R_body
//! Exp(ψ)`, and eq. 13's residual holds between the IMU frames, not the camera's.
//!
//! A soft-mounted camera (vibration dampers, a flexing arm) or an IMU reference that is itself an
//! estimate (S-V101's truth, whose attitude the rendered camera follows: ~5 mrad of tilt at
//! 0.1–1 Hz that the real IMU does not feel, docs/odometry-log.md, *The real accelerometer
//! against the truth, read both ways*) turns the accelerometer's gravity against the camera's
//! attitude. Held equal, a tilt of `e` is `g·e` of horizontal acceleration the window must
//! explain by velocity, position or bias (0.05 m/s² for 5 mrad, ~13 cm of position at 0.1 Hz).
//!
//! [`mounted`] gives the IMU frame's state; [`imu_jacobians_mounted`] the residual and its
//! derivatives with respect to both states' increments (of the camera-consistent body frame,
//! eq. 11's right increments) and both ψ (additive).

use super::integration::Preintegration;
use super::residual::{
    FrameState, Matrix15, Vector15, block, imu_jacobian_i, imu_jacobian_j, imu_residual,
};
use crate::geometry::{exp_so3, right_jacobian};
use nalgebra::{SMatrix, UnitQuaternion, Vector3};

/// `x` with its attitude turned into the IMU's, `R Exp(ψ)` (`psi` in rad); the rest unchanged.
pub fn mounted(x: &FrameState, psi_rad: &Vector3<f64>) -> FrameState {
    let mut y = *x;
    y.nav.r_world_body = x.nav.r_world_body * UnitQuaternion::from_scaled_axis(*psi_rad);
    y
}

/// Eq. 13's residual between the IMU frames of `xi` and `xj` (turned by `psi_i`, `psi_j`) and
/// its derivatives: with respect to `xi`'s and `xj`'s increments ([`FrameState::boxplus`] of the
/// body frame), and with respect to `psi_i` and `psi_j` (additive, rad).
///
/// `R Exp(δθ) Exp(ψ) = R Exp(ψ) Exp(Exp(ψ)ᵀ δθ)`: a body increment is the IMU frame's turned by
/// `Exp(ψ)ᵀ`, and so is a position increment (`R δt = R Exp(ψ) Exp(ψ)ᵀ δt`);
/// `R Exp(ψ + δψ) ≈ R Exp(ψ) Exp(J_r(ψ) δψ)`. Velocity and biases are shared.
pub fn imu_jacobians_mounted(
    pre: &Preintegration,
    xi: &FrameState,
    xj: &FrameState,
    psi_i: &Vector3<f64>,
    psi_j: &Vector3<f64>,
) -> MountedJacobians {
    let (mi, mj) = (mounted(xi, psi_i), mounted(xj, psi_j));
    let r = imu_residual(pre, &mi, &mj);
    let mut ji = imu_jacobian_i(pre, &mi, &mj);
    let mut jj = imu_jacobian_j(pre, &mi, &mj);
    let turn = |j: &mut Matrix15, psi: &Vector3<f64>| -> SMatrix<f64, 15, 3> {
        let back = exp_so3(psi).transpose();
        let rot = j.fixed_view::<15, 3>(0, block::ROT).into_owned();
        let pos = j.fixed_view::<15, 3>(0, block::POS).into_owned();
        j.fixed_view_mut::<15, 3>(0, block::ROT)
            .copy_from(&(rot * back));
        j.fixed_view_mut::<15, 3>(0, block::POS)
            .copy_from(&(pos * back));
        rot * right_jacobian(psi)
    };
    let jpsi_i = turn(&mut ji, psi_i);
    let jpsi_j = turn(&mut jj, psi_j);
    MountedJacobians {
        r,
        ji,
        jj,
        jpsi_i,
        jpsi_j,
    }
}

/// What [`imu_jacobians_mounted`] returns.
#[derive(Clone, Debug)]
pub struct MountedJacobians {
    /// Eq. 13's residual between the IMU frames.
    pub r: Vector15,
    /// d r / d(body increment of frame i), and of frame j.
    pub ji: Matrix15,
    pub jj: Matrix15,
    /// d r / dψ_i and d r / dψ_j.
    pub jpsi_i: SMatrix<f64, 15, 3>,
    pub jpsi_j: SMatrix<f64, 15, 3>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::{ImuBias, ImuNoise, ImuSample, NavState};
    use crate::time::TimeNs;

    fn preintegration() -> Preintegration {
        let samples: Vec<ImuSample> = (0..=100)
            .map(|k| {
                let t = k as f64 * 0.005;
                ImuSample {
                    t: TimeNs::from_secs_f64(t),
                    gyro_rad_s: Vector3::new(0.3 * (2.0 * t).sin(), -0.5, 0.9 * t),
                    accel_m_s2: Vector3::new(0.4 * t, 0.2, 9.81 + 0.3 * (4.0 * t).cos()),
                }
            })
            .collect();
        let mut pre = Preintegration::new(TimeNs::from_secs_f64(0.0), ImuBias::default());
        pre.integrate(
            &samples,
            TimeNs::from_secs_f64(0.5),
            Some(&ImuNoise::euroc_adis16448()),
        );
        pre
    }

    fn states(pre: &Preintegration) -> (FrameState, FrameState) {
        let xi = FrameState {
            nav: NavState {
                t: pre.t_start,
                r_world_body: UnitQuaternion::from_euler_angles(0.2, -0.1, 1.1),
                p_world_m: Vector3::new(0.5, -1.0, 1.2),
                v_world_m_s: Vector3::new(0.4, 0.1, -0.2),
            },
            bias: ImuBias {
                gyro_rad_s: Vector3::new(0.001, -0.002, 0.0015),
                accel_m_s2: Vector3::new(0.03, 0.02, -0.04),
            },
        };
        let mut xj = xi;
        xj.nav = pre.predict(&xi.nav, &xi.bias);
        // Off the solution, so that every term counts.
        xj.nav.r_world_body *= UnitQuaternion::from_euler_angles(-0.01, 0.015, 0.02);
        xj.nav.v_world_m_s += Vector3::new(0.02, -0.01, 0.03);
        xj.bias.accel_m_s2 += Vector3::new(0.01, 0.0, -0.02);
        (xi, xj)
    }

    fn assert_close(num: &Vector15, ana: &Vector15, what: &str) {
        for row in 0..15 {
            assert!(
                (num[row] - ana[row]).abs() < 1e-6 * (1.0 + num[row].abs()),
                "{what} row {row}: numeric {} analytic {}",
                num[row],
                ana[row]
            );
        }
    }

    #[test]
    fn mounted_jacobians_match_numeric_differentiation() {
        let pre = preintegration();
        let (xi, xj) = states(&pre);
        let (psi_i, psi_j) = (
            Vector3::new(0.004, -0.006, 0.002),
            Vector3::new(-0.003, 0.005, 0.007),
        );
        let m = imu_jacobians_mounted(&pre, &xi, &xj, &psi_i, &psi_j);
        let res = |xi: &FrameState, xj: &FrameState, pi: &Vector3<f64>, pj: &Vector3<f64>| {
            imu_residual(&pre, &mounted(xi, pi), &mounted(xj, pj))
        };
        assert_eq!(m.r, res(&xi, &xj, &psi_i, &psi_j));
        let h = 1e-6;
        for c in 0..15 {
            let mut d = Vector15::zeros();
            d[c] = h;
            let num_i = (res(&xi.boxplus(&d), &xj, &psi_i, &psi_j)
                - res(&xi.boxplus(&-d), &xj, &psi_i, &psi_j))
                / (2.0 * h);
            assert_close(&num_i, &m.ji.column(c).into_owned(), &format!("xi col {c}"));
            let num_j = (res(&xi, &xj.boxplus(&d), &psi_i, &psi_j)
                - res(&xi, &xj.boxplus(&-d), &psi_i, &psi_j))
                / (2.0 * h);
            assert_close(&num_j, &m.jj.column(c).into_owned(), &format!("xj col {c}"));
        }
        for c in 0..3 {
            let mut d = Vector3::zeros();
            d[c] = h;
            let num_i = (res(&xi, &xj, &(psi_i + d), &psi_j) - res(&xi, &xj, &(psi_i - d), &psi_j))
                / (2.0 * h);
            assert_close(
                &num_i,
                &m.jpsi_i.column(c).into_owned(),
                &format!("ψi col {c}"),
            );
            let num_j = (res(&xi, &xj, &psi_i, &(psi_j + d)) - res(&xi, &xj, &psi_i, &(psi_j - d)))
                / (2.0 * h);
            assert_close(
                &num_j,
                &m.jpsi_j.column(c).into_owned(),
                &format!("ψj col {c}"),
            );
        }
    }

    #[test]
    fn a_tilt_of_the_imu_frame_is_gravity_in_the_velocity_rows() {
        // The IMU turned by ψ about body x: its velocity residual moves by about g·ψ·Δt, which
        // the body-frame residual (ψ = 0) would have to absorb.
        let pre = preintegration();
        let (xi, _) = states(&pre);
        let mut xj = xi;
        xj.nav = pre.predict(&xi.nav, &xi.bias);
        let psi = Vector3::new(0.005, 0.0, 0.0);
        let r0 = imu_residual(&pre, &xi, &xj);
        let r1 = imu_residual(&pre, &mounted(&xi, &psi), &mounted(&xj, &psi));
        let dv = (r1 - r0).fixed_rows::<3>(block::VEL).norm();
        assert!(r0.norm() < 1e-9, "at the prediction: {r0:?}");
        let expected = 9.81 * 0.005 * pre.dt_s();
        assert!(
            (dv - expected).abs() < 0.3 * expected,
            "velocity rows moved {dv}, g·ψ·Δt = {expected}"
        );
    }
}
