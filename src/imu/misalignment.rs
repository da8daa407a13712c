//! A gyro whose axes are turned from the body frame that the accelerometer and the camera share,
//! `ω_body = Exp(φ) ω_gyro`, in the IMU residual of eq. 13.
//!
//! A real mount turns the gyro by a degree or so (S-V101's by ~1.3°, docs/odometry-log.md, *The
//! real gyro is turned against the camera*), and every turn of the vehicle then leaks into the
//! other two axes: the preintegrated rotation (eq. 4) is conjugated, `ΔR' = Exp(φ) ΔR Exp(φ)ᵀ`,
//! and the velocity and position sums (eq. 5–6), which run through the rotation history, move by
//! [`Preintegration::d_v_d_misalignment`] and [`Preintegration::d_p_d_misalignment`] φ (first
//! order about the samples as integrated, φ = 0). The gyro bias stays in the gyro's axes.
//!
//! [`turned`] gives the preintegration of the turned gyro, so every residual and Jacobian of
//! [`super::residual`] applies to it unchanged; [`d_residual_d_misalignment`] is the residual's
//! derivative with respect to φ (additive increments).

use super::integration::{ImuBias, Preintegration};
use super::residual::{FrameState, Vector15, block};
use super::{ImuNoise, ImuSample};
use crate::geometry::{exp_so3, right_jacobian, right_jacobian_inv};
use crate::time::TimeNs;
use nalgebra::{Matrix3, SMatrix, Vector3};

/// The IMU of one frame interval, `t0` to `t1` (eq. 1–6 at `bias`; `samples` may reach beyond
/// it), as a gyro turned by `Exp(phi)` integrates it ([`turned`]; not turned if `phi` is zero).
pub fn preintegrate_turned(
    samples: &[ImuSample],
    (t0, t1): (TimeNs, TimeNs),
    bias: ImuBias,
    noise: &ImuNoise,
    phi: &Vector3<f64>,
) -> Preintegration {
    let mut pre = Preintegration::new(t0, bias);
    // `integrate` finds the samples bracketing the interval itself.
    pre.integrate(samples, t1, Some(noise));
    if *phi != Vector3::zeros() {
        pre = turned(&pre, phi);
    }
    pre
}

/// `pre` as a gyro turned by `Exp(phi)` would have integrated it (`phi` in rad, gyro → body).
pub fn turned(pre: &Preintegration, phi: &Vector3<f64>) -> Preintegration {
    let r = exp_so3(phi);
    let mut out = pre.clone();
    out.delta_r = r * pre.delta_r * r.transpose();
    // ΔR(b) = ΔR Exp(J δb) turns into Exp(φ) ΔR Exp(J δb) Exp(φ)ᵀ = ΔR' Exp(Exp(φ) J δb).
    out.d_r_d_bg = r * pre.d_r_d_bg;
    out.delta_v = pre.delta_v + pre.d_v_d_misalignment * phi;
    out.delta_p = pre.delta_p + pre.d_p_d_misalignment * phi;
    // The rotation rows of the noise turn with the rotation.
    let mut t = SMatrix::<f64, 9, 9>::identity();
    t.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    out.cov = t * pre.cov * t.transpose();
    out
}

/// d r / dφ of eq. 13's residual `r = imu_residual(&turned(pre, phi), xi, xj)` for the gyro
/// turned by `Exp(phi)` (passed in: the caller has it), additive increments of `phi`.
///
/// Rotation rows: with `ΔR_c` the gyro's bias-corrected rotation, `Exp(φ + δ) ≈ Exp(φ)
/// Exp(J_r(φ) δ)` and `Exp(u) ΔR_c Exp(−u) ≈ ΔR_c Exp((ΔR_cᵀ − I) u)`, so
/// `dr/dδ = −J_r⁻¹(r) Exp(r)ᵀ Exp(φ) (ΔR_cᵀ − I) J_r(φ)`. Velocity and position rows:
/// `−R_i dΔv/dφ`, `−R_i dΔp/dφ`. Bias rows: zero.
pub fn d_residual_d_misalignment(
    pre: &Preintegration,
    phi: &Vector3<f64>,
    r: &Vector15,
    xi: &FrameState,
    xj: &FrameState,
) -> SMatrix<f64, 15, 3> {
    let r_rot: Vector3<f64> = r.fixed_rows::<3>(block::ROT).into();
    let dbg = xj.bias.gyro_rad_s - pre.bias.gyro_rad_s;
    let dr_c = pre.delta_r * exp_so3(&(pre.d_r_d_bg * dbg));
    let ri = *xi.nav.r_world_body.to_rotation_matrix().matrix();
    let mut j = SMatrix::<f64, 15, 3>::zeros();
    let d_rot = -right_jacobian_inv(&r_rot)
        * exp_so3(&r_rot).transpose()
        * exp_so3(phi)
        * (dr_c.transpose() - Matrix3::identity())
        * right_jacobian(phi);
    j.fixed_view_mut::<3, 3>(block::ROT, 0).copy_from(&d_rot);
    j.fixed_view_mut::<3, 3>(block::VEL, 0)
        .copy_from(&(-ri * pre.d_v_d_misalignment));
    j.fixed_view_mut::<3, 3>(block::POS, 0)
        .copy_from(&(-ri * pre.d_p_d_misalignment));
    j
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::residual::imu_residual;
    use crate::imu::{ImuBias, ImuNoise, ImuSample, NavState};
    use crate::time::TimeNs;
    use nalgebra::{UnitQuaternion, Vector3};

    /// A 0.6 s turn with a changing rate and a changing specific force, 200 Hz, as the body
    /// feels it.
    fn samples(turn: &Matrix3<f64>) -> Vec<ImuSample> {
        (0..=130)
            .map(|k| {
                let t = k as f64 * 0.005;
                let w = Vector3::new(0.4 * (3.0 * t).sin(), -0.9 + 0.5 * t, 1.6 * (2.0 * t).cos());
                let a = Vector3::new(
                    0.8 * t,
                    9.81 + 0.5 * (5.0 * t).sin(),
                    -1.2 * (4.0 * t).cos(),
                );
                ImuSample {
                    t: TimeNs::from_secs_f64(t),
                    gyro_rad_s: turn.transpose() * w,
                    accel_m_s2: a,
                }
            })
            .collect()
    }

    fn integrate(s: &[ImuSample], bias: ImuBias) -> Preintegration {
        let mut pre = Preintegration::new(TimeNs::from_secs_f64(0.0), bias);
        pre.integrate(
            s,
            TimeNs::from_secs_f64(0.6),
            Some(&ImuNoise::euroc_adis16448()),
        );
        pre
    }

    fn bias() -> ImuBias {
        ImuBias {
            gyro_rad_s: Vector3::new(0.002, -0.001, 0.003),
            accel_m_s2: Vector3::new(0.05, -0.02, 0.03),
        }
    }

    #[test]
    fn turned_matches_integrating_the_turned_samples() {
        // The gyro's samples are turned from the body's by Exp(φ)ᵀ; turning the preintegration
        // of those by φ must give the body's own (to second order in φ).
        let phi = Vector3::new(0.2f64, -0.3, 0.6).map(f64::to_radians);
        // The body's own rates with the bias the gyro's turns into.
        let body_bias = ImuBias {
            gyro_rad_s: exp_so3(&phi) * bias().gyro_rad_s,
            ..bias()
        };
        let body = integrate(&samples(&Matrix3::identity()), body_bias);
        let raw = integrate(&samples(&exp_so3(&phi)), bias());
        let back = turned(&raw, &phi);
        let rot_err = crate::geometry::log_so3(&(back.delta_r.transpose() * body.delta_r));
        assert!(rot_err.norm() < 1e-6, "rotation {rot_err:?}");
        // Without the first-order terms the sums are off by millimetres per second.
        let dv_off = (raw.delta_v - body.delta_v).norm();
        let dv_err = (back.delta_v - body.delta_v).norm();
        let dp_err = (back.delta_p - body.delta_p).norm();
        assert!(
            dv_off > 1e-3,
            "the test must turn the velocity sum: {dv_off}"
        );
        assert!(dv_err < 0.02 * dv_off, "Δv {dv_err} of {dv_off}");
        assert!(
            dp_err < 0.02 * (raw.delta_p - body.delta_p).norm(),
            "Δp {dp_err}"
        );
        // The gyro bias still corrects in the gyro's axes.
        let b2 = ImuBias {
            gyro_rad_s: bias().gyro_rad_s + Vector3::new(1e-3, -2e-3, 1.5e-3),
            ..bias()
        };
        let (dr, _, _) = back.corrected(&b2);
        let (dr_exact, _, _) =
            turned(&integrate(&samples(&exp_so3(&phi)), b2), &phi).corrected(&b2);
        let e = crate::geometry::log_so3(&(dr.transpose() * dr_exact));
        assert!(e.norm() < 1e-5, "bias correction {e:?}");
    }

    #[test]
    fn misalignment_jacobian_matches_numeric_differentiation() {
        let pre = integrate(&samples(&Matrix3::identity()), bias());
        let xi = FrameState {
            nav: NavState {
                t: pre.t_start,
                r_world_body: UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7),
                p_world_m: Vector3::new(1.0, 2.0, 0.5),
                v_world_m_s: Vector3::new(0.3, -0.2, 0.1),
            },
            bias: bias(),
        };
        let mut xj = xi;
        xj.nav = pre.predict(&xi.nav, &xi.bias);
        // Off the solution, with another bias, so that every term counts.
        xj.nav.r_world_body *= UnitQuaternion::from_euler_angles(0.01, 0.02, -0.015);
        xj.nav.p_world_m += Vector3::new(0.01, -0.02, 0.005);
        xj.bias.gyro_rad_s += Vector3::new(1e-3, 0.0, -1e-3);
        let phi = Vector3::new(0.01, -0.02, 0.015);
        let r = imu_residual(&turned(&pre, &phi), &xi, &xj);
        let j = d_residual_d_misalignment(&pre, &phi, &r, &xi, &xj);
        let h = 1e-6;
        for c in 0..3 {
            let mut d = Vector3::zeros();
            d[c] = h;
            let rp = imu_residual(&turned(&pre, &(phi + d)), &xi, &xj);
            let rm = imu_residual(&turned(&pre, &(phi - d)), &xi, &xj);
            let num = (rp - rm) / (2.0 * h);
            for row in 0..15 {
                assert!(
                    (num[row] - j[(row, c)]).abs() < 1e-6 * (1.0 + num[row].abs()),
                    "row {row} col {c}: numeric {} analytic {}",
                    num[row],
                    j[(row, c)]
                );
            }
        }
    }
}
