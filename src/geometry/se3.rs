//! SE(3) helpers on `nalgebra::Isometry3` used by the optimisers: the adjoint and the increment
//! convention shared by tracking and the IMU state.
//!
//! Twists are ordered `[ω (3), v (3)]` (rotation first, as the 15-state of eq. 11). The increment
//! `T ⊞ ξ = (R Exp(ω), t + R v)` — the product `T · (Exp(ω), v)` — is the one of
//! [`crate::imu::FrameState::boxplus`] (eq. 34, 36); to first order it equals `T · exp_se3(ξ)`.

use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};

use super::so3::hat;

/// The adjoint `Ad(T)` (6x6, twist order `[ω, v]`): `T · exp(ξ) · T⁻¹ = exp(Ad(T) ξ)`, i.e.
/// `ω' = R ω`, `v' = R v + [t]× R ω`.
pub fn adjoint(t: &Isometry3<f64>) -> Matrix6<f64> {
    let r: Matrix3<f64> = *t.rotation.to_rotation_matrix().matrix();
    let p = t.translation.vector;
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(3, 0).copy_from(&(hat(&p) * r));
    ad
}

/// The group element `(Exp(ω), v)` of a twist `[ω, v]` (the increment of [`boxplus_se3`]).
pub fn increment(xi: &Vector6<f64>) -> Isometry3<f64> {
    let w = Vector3::new(xi[0], xi[1], xi[2]);
    Isometry3::from_parts(
        Translation3::new(xi[3], xi[4], xi[5]),
        UnitQuaternion::from_scaled_axis(w),
    )
}

/// Every number of `t` (translation and quaternion) is finite.
pub fn is_finite(t: &Isometry3<f64>) -> bool {
    t.translation.vector.iter().all(|v| v.is_finite())
        && t.rotation.coords.iter().all(|v| v.is_finite())
}

/// `T ⊞ ξ = T · (Exp(ω), v)`.
pub fn boxplus_se3(t: &Isometry3<f64>, xi: &Vector6<f64>) -> Isometry3<f64> {
    t * increment(xi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adjoint_moves_an_increment_across_a_transform() {
        let t = Isometry3::from_parts(
            Translation3::new(0.4, -1.2, 2.0),
            UnitQuaternion::from_euler_angles(0.3, -0.5, 1.1),
        );
        let xi = Vector6::new(1e-4, -2e-4, 3e-4, 2e-4, 1e-4, -3e-4);
        // T · exp(ξ) · T⁻¹ vs exp(Ad ξ), to first order (error O(|ξ|²)).
        let lhs = t * increment(&xi) * t.inverse();
        let rhs = increment(&(adjoint(&t) * xi));
        let d = lhs.inverse() * rhs;
        assert!(d.translation.vector.norm() < 1e-7, "{d}");
        assert!(d.rotation.angle() < 1e-7);
        // Composition: Ad(AB) = Ad(A) Ad(B).
        let u = Isometry3::from_parts(
            Translation3::new(-0.1, 0.3, 0.7),
            UnitQuaternion::from_euler_angles(-0.2, 0.1, 0.4),
        );
        assert!((adjoint(&(t * u)) - adjoint(&t) * adjoint(&u)).norm() < 1e-12);
    }
}
