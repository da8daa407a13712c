//! Absolute trajectory error: per-pose translation and rotation error after alignment.

use nalgebra::Isometry3;

/// Per-pose absolute errors, in the order of the poses given.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AbsoluteErrors {
    /// `|p_gt − p_est|`, m (`evo_ape` default `translation_part`).
    pub trans_m: Vec<f64>,
    /// Angle of `R_gtᵀ · R_est`, degrees (`evo_ape -r angle_deg`).
    pub rot_deg: Vec<f64>,
}

/// Errors between ground-truth poses and the aligned estimated poses at the same times.
///
/// # Panics
/// If the slices differ in length (a caller bug: they come from one association).
pub fn absolute_errors(
    t_world_body_gt: &[Isometry3<f64>],
    t_world_body_est_aligned: &[Isometry3<f64>],
) -> AbsoluteErrors {
    assert_eq!(
        t_world_body_gt.len(),
        t_world_body_est_aligned.len(),
        "one pose pair per time"
    );
    let (trans_m, rot_deg) = t_world_body_gt
        .iter()
        .zip(t_world_body_est_aligned)
        .map(|(g, e)| {
            let dp_m = (g.translation.vector - e.translation.vector).norm();
            let angle_deg = g.rotation.angle_to(&e.rotation).to_degrees();
            (dp_m, angle_deg)
        })
        .unzip();
    AbsoluteErrors { trans_m, rot_deg }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn translation_and_rotation_errors() {
        let g = Isometry3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.0, 0.0, 0.5));
        let e = Isometry3::new(
            Vector3::new(4.0, 6.0, 3.0),
            Vector3::new(0.0, 0.0, 0.5 + 0.1),
        );
        let errs = absolute_errors(&[g, g], &[e, g]);
        assert_eq!(errs.trans_m, vec![5.0, 0.0]);
        assert!((errs.rot_deg[0] - 0.1f64.to_degrees()).abs() < 1e-9);
        assert!(errs.rot_deg[1].abs() < 1e-9);
    }
}
