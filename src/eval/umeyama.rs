//! Least-squares similarity / rigid alignment of two point sets (Umeyama, PAMI 1991).

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// A similarity transform `p ↦ scale · rotation · p + translation`.
///
/// Used as `t_gtworld_estworld`: it maps estimate-world coordinates into the ground-truth world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sim3 {
    pub rotation: UnitQuaternion<f64>,
    pub translation: Vector3<f64>,
    pub scale: f64,
}

impl Sim3 {
    pub fn identity() -> Self {
        Sim3 {
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
            scale: 1.0,
        }
    }

    /// `scale · rotation · p + translation`.
    pub fn transform_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * (self.scale * p) + self.translation
    }

    /// Maps a pose `t_a_body` (frame `a` = this transform's source) into the target frame: the
    /// position is transformed as a point, the orientation is rotated. The body's own scale is
    /// untouched (a pose stays rigid), as in `evo`'s trajectory alignment.
    pub fn transform_pose(&self, t_a_body: &Isometry3<f64>) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.transform_point(&t_a_body.translation.vector)),
            self.rotation * t_a_body.rotation,
        )
    }
}

/// Why no alignment could be computed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum UmeyamaError {
    #[error("point sets differ in size ({src} vs {dst})")]
    LengthMismatch { src: usize, dst: usize },
    #[error("{0} point pairs given, at least 3 are needed")]
    TooFewPoints(usize),
    #[error(
        "the source positions do not spread (variance {variance_m2:e} m^2): a static estimate \
         cannot be aligned"
    )]
    NoSpread { variance_m2: f64 },
    #[error("the SVD of the cross-covariance did not converge")]
    SvdFailed,
}

/// Below this source variance (m^2) the alignment is refused: the scale would be meaningless.
const MIN_VARIANCE_M2: f64 = 1e-18;

/// The transform `T` minimising `Σ |dst_i − T(src_i)|²`, with `T` a similarity when `with_scale`
/// and a rigid transform (scale 1) otherwise. Reflections are excluded (det R = +1).
///
/// Same estimator as `evo`'s `umeyama_alignment`: with centroids `μ`, source variance
/// `σ² = mean |src − μ_src|²` and cross-covariance `Σ = mean (dst − μ_dst)(src − μ_src)ᵀ = U D Vᵀ`,
/// `R = U S Vᵀ` (`S = diag(1, 1, ±1)` so that det R = +1), `c = tr(D S) / σ²`, `t = μ_dst − c R μ_src`.
pub fn umeyama(
    src: &[Vector3<f64>],
    dst: &[Vector3<f64>],
    with_scale: bool,
) -> Result<Sim3, UmeyamaError> {
    if src.len() != dst.len() {
        return Err(UmeyamaError::LengthMismatch {
            src: src.len(),
            dst: dst.len(),
        });
    }
    let n = src.len();
    if n < 3 {
        return Err(UmeyamaError::TooFewPoints(n));
    }
    let inv_n = 1.0 / n as f64;
    let mu_src = src.iter().sum::<Vector3<f64>>() * inv_n;
    let mu_dst = dst.iter().sum::<Vector3<f64>>() * inv_n;
    let mut cov = Matrix3::zeros();
    let mut var_src = 0.0;
    for (s, d) in src.iter().zip(dst) {
        let (sc, dc) = (s - mu_src, d - mu_dst);
        cov += dc * sc.transpose();
        var_src += sc.norm_squared();
    }
    cov *= inv_n;
    var_src *= inv_n;
    // Inputs are finite (trajectory files reject NaN), so this also rejects a NaN variance.
    if var_src.is_nan() || var_src <= MIN_VARIANCE_M2 {
        return Err(UmeyamaError::NoSpread {
            variance_m2: var_src,
        });
    }
    let svd = cov
        .try_svd(true, true, f64::EPSILON, 0)
        .ok_or(UmeyamaError::SvdFailed)?;
    let (u, v_t) = (
        svd.u.ok_or(UmeyamaError::SvdFailed)?,
        svd.v_t.ok_or(UmeyamaError::SvdFailed)?,
    );
    let mut s_diag = Vector3::new(1.0, 1.0, 1.0);
    if u.determinant() * v_t.determinant() < 0.0 {
        // nalgebra sorts singular values in decreasing order: flip the smallest.
        s_diag.z = -1.0;
    }
    let r = u * Matrix3::from_diagonal(&s_diag) * v_t;
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let scale = if with_scale {
        svd.singular_values.dot(&s_diag) / var_src
    } else {
        1.0
    };
    let translation = mu_dst - scale * (rotation * mu_src);
    Ok(Sim3 {
        rotation,
        translation,
        scale,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic, non-collinear, non-coplanar points.
    fn points(n: usize) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|i| {
                let a = i as f64;
                Vector3::new((0.7 * a).sin() * 3.0, (1.3 * a).cos() * 2.0, 0.05 * a - 1.0)
            })
            .collect()
    }

    fn known() -> Sim3 {
        Sim3 {
            rotation: UnitQuaternion::from_euler_angles(2.5, -0.4, -1.9),
            translation: Vector3::new(-3.0, 12.0, 0.25),
            scale: 3.7,
        }
    }

    #[test]
    fn recovers_a_known_sim3_exactly() {
        let src = points(50);
        let truth = known();
        let dst: Vec<_> = src.iter().map(|p| truth.transform_point(p)).collect();
        let est = umeyama(&src, &dst, true).unwrap();
        assert!(
            (est.scale - truth.scale).abs() < 1e-12,
            "scale {}",
            est.scale
        );
        assert!(est.rotation.angle_to(&truth.rotation) < 1e-12);
        assert!((est.translation - truth.translation).norm() < 1e-11);
    }

    #[test]
    fn rigid_alignment_keeps_unit_scale_and_finds_the_rotation() {
        let src = points(50);
        let truth = Sim3 {
            scale: 1.0,
            ..known()
        };
        let dst: Vec<_> = src.iter().map(|p| truth.transform_point(p)).collect();
        let est = umeyama(&src, &dst, false).unwrap();
        assert_eq!(est.scale, 1.0);
        assert!(est.rotation.angle_to(&truth.rotation) < 1e-12);
        assert!((est.translation - truth.translation).norm() < 1e-11);
        // With a scaled target, the rigid fit still finds the rotation (the centred cross-
        // covariance only changes by a positive factor) but leaves a residual.
        let scaled: Vec<_> = src.iter().map(|p| known().transform_point(p)).collect();
        let est = umeyama(&src, &scaled, false).unwrap();
        assert!(est.rotation.angle_to(&known().rotation) < 1e-12);
    }

    #[test]
    fn noisy_fit_is_the_least_squares_optimum() {
        let src = points(200);
        let truth = known();
        let dst: Vec<_> = src
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let n = Vector3::new((i as f64 * 12.9898).sin(), (i as f64 * 78.233).sin(), 0.0);
                truth.transform_point(p) + 0.05 * n
            })
            .collect();
        let est = umeyama(&src, &dst, true).unwrap();
        let cost = |t: &Sim3| -> f64 {
            src.iter()
                .zip(&dst)
                .map(|(s, d)| (d - t.transform_point(s)).norm_squared())
                .sum()
        };
        let c0 = cost(&est);
        // Any small perturbation of the optimum raises the cost.
        for k in 0..7 {
            let mut t = est;
            match k {
                0..=2 => t.translation[k] += 1e-4,
                3 => t.scale *= 1.0 + 1e-5,
                _ => {
                    let mut axis = Vector3::zeros();
                    axis[k - 4] = 1e-5;
                    t.rotation = UnitQuaternion::from_scaled_axis(axis) * t.rotation;
                }
            }
            assert!(cost(&t) > c0, "perturbation {k} lowered the cost");
        }
    }

    #[test]
    fn reflections_are_excluded() {
        // A mirrored target: the best proper rotation is returned, never a reflection.
        let src = points(30);
        let dst: Vec<_> = src.iter().map(|p| Vector3::new(p.x, p.y, -p.z)).collect();
        let est = umeyama(&src, &dst, true).unwrap();
        let r = est.rotation.to_rotation_matrix();
        assert!((r.matrix().determinant() - 1.0).abs() < 1e-12);
        assert!(est.scale > 0.0 && est.scale.is_finite());
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        let p = points(5);
        assert_eq!(
            umeyama(&p[..2], &p[..2], true),
            Err(UmeyamaError::TooFewPoints(2))
        );
        assert_eq!(
            umeyama(&p, &p[..4], true),
            Err(UmeyamaError::LengthMismatch { src: 5, dst: 4 })
        );
        let still = vec![Vector3::new(1.0, 2.0, 3.0); 10];
        assert!(matches!(
            umeyama(&still, &p.repeat(2), true),
            Err(UmeyamaError::NoSpread { .. })
        ));
    }
}
