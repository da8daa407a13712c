//! SO(3) helpers in the paper's notation (eq. 7, 8, 29–32).

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

/// The hat operator of eq. 7: `hat(x) * y == x.cross(y)`.
pub fn hat(x: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -x.z, x.y, x.z, 0.0, -x.x, -x.y, x.x, 0.0)
}

/// The vee operator of eq. 8 (inverse of [`hat`]; reads the skew-symmetric part).
pub fn vee(m: &Matrix3<f64>) -> Vector3<f64> {
    Vector3::new(
        0.5 * (m[(2, 1)] - m[(1, 2)]),
        0.5 * (m[(0, 2)] - m[(2, 0)]),
        0.5 * (m[(1, 0)] - m[(0, 1)]),
    )
}

/// `exp_SO(3)([phi]^)` as a rotation matrix (Rodrigues).
pub fn exp_so3(phi: &Vector3<f64>) -> Matrix3<f64> {
    *Rotation3::new(*phi).matrix()
}

/// `log_SO(3)(R)^v`: the rotation vector, with angle in [0, pi].
pub fn log_so3(r: &Matrix3<f64>) -> Vector3<f64> {
    let rot = Rotation3::from_matrix_unchecked(*r);
    UnitQuaternion::from_rotation_matrix(&rot).scaled_axis()
}

/// Right Jacobian of SO(3), eq. 30:
/// `exp([phi + d]^) ≈ exp([phi]^) exp([J_r(phi) d]^)`.
pub fn right_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let w = hat(phi);
    if theta2 < 1e-10 {
        // Series: I - 1/2 W + 1/6 W^2.
        return Matrix3::identity() - 0.5 * w + (1.0 / 6.0) * w * w;
    }
    let theta = theta2.sqrt();
    Matrix3::identity() - ((1.0 - theta.cos()) / theta2) * w
        + ((theta - theta.sin()) / (theta2 * theta)) * w * w
}

/// Inverse of the right Jacobian (eq. 31): `log(exp([phi]^) exp([d]^)) ≈ phi + J_r(phi)^-1 d`.
pub fn right_jacobian_inv(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let w = hat(phi);
    if theta2 < 1e-10 {
        // Series: I + 1/2 W + 1/12 W^2.
        return Matrix3::identity() + 0.5 * w + (1.0 / 12.0) * w * w;
    }
    let theta = theta2.sqrt();
    Matrix3::identity()
        + 0.5 * w
        + (1.0 / theta2 - (1.0 + theta.cos()) / (2.0 * theta * theta.sin())) * w * w
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples() -> Vec<Vector3<f64>> {
        vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1e-7, -2e-7, 3e-8),
            Vector3::new(0.1, -0.2, 0.3),
            Vector3::new(1.0, 0.5, -0.7),
            Vector3::new(-2.0, 1.0, 0.5),
        ]
    }

    #[test]
    fn hat_vee_round_trip_and_cross_product() {
        let a = Vector3::new(0.3, -1.2, 2.0);
        let b = Vector3::new(-0.5, 0.25, 4.0);
        assert!((hat(&a) * b - a.cross(&b)).norm() < 1e-15);
        assert!((vee(&hat(&a)) - a).norm() < 1e-15);
    }

    #[test]
    fn exp_log_round_trip() {
        for phi in samples() {
            let back = log_so3(&exp_so3(&phi));
            assert!((back - phi).norm() < 1e-12, "{phi:?} -> {back:?}");
        }
    }

    #[test]
    fn right_jacobian_matches_numeric_eq29() {
        // exp(phi + d) == exp(phi) exp(Jr d) to first order: compare log(exp(phi)^T exp(phi+d))/eps.
        let eps = 1e-6;
        for phi in samples() {
            let jr = right_jacobian(&phi);
            for k in 0..3 {
                let mut d = Vector3::zeros();
                d[k] = eps;
                let num = log_so3(&(exp_so3(&phi).transpose() * exp_so3(&(phi + d)))) / eps;
                assert!((num - jr.column(k)).norm() < 1e-5, "phi {phi:?} col {k}");
            }
        }
    }

    #[test]
    fn right_jacobian_inverse_is_inverse_and_matches_eq31() {
        let eps = 1e-6;
        for phi in samples() {
            let prod = right_jacobian(&phi) * right_jacobian_inv(&phi);
            assert!((prod - Matrix3::identity()).norm() < 1e-9, "{phi:?}");
            let jri = right_jacobian_inv(&phi);
            for k in 0..3 {
                let mut d = Vector3::zeros();
                d[k] = eps;
                let num = (log_so3(&(exp_so3(&phi) * exp_so3(&d))) - phi) / eps;
                assert!((num - jri.column(k)).norm() < 1e-5, "phi {phi:?} col {k}");
            }
        }
    }
}
