//! Relative pose error over segments of a given travelled ground-truth distance.
//!
//! A segment runs from pose `i` to the first later pose `j` at which the ground-truth path length
//! travelled since `i` reaches `length_m`. For each segment the error is
//! `E = (T_gt_i⁻¹ T_gt_j)⁻¹ (T_est_i⁻¹ T_est_j)`: its translation norm (m) and rotation angle (deg),
//! the definition of `evo_rpe` (`--delta L --delta_unit m`, `translation_part` / `angle_deg`).

use nalgebra::{Isometry3, Vector3};

/// Where segments start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SegmentStarts {
    /// At every pose, so segments overlap (KITTI odometry and `ov_eval` style): many samples even
    /// on short sequences. Used by the report.
    EveryPose,
    /// At the end of the previous segment, so segments tile the path (`evo_rpe`'s default).
    Consecutive,
}

/// Per-segment relative errors, one entry per segment.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RelativeErrors {
    pub trans_m: Vec<f64>,
    pub rot_deg: Vec<f64>,
}

/// Index pairs `(i, j)` of the segments of travelled length `length_m` along `positions_m`.
pub fn segment_pairs(
    positions_m: &[Vector3<f64>],
    length_m: f64,
    starts: SegmentStarts,
) -> Vec<(usize, usize)> {
    let mut travelled_m = Vec::with_capacity(positions_m.len());
    let mut acc_m = 0.0;
    for (k, p) in positions_m.iter().enumerate() {
        if k > 0 {
            acc_m += (p - positions_m[k - 1]).norm();
        }
        travelled_m.push(acc_m);
    }
    let n = positions_m.len();
    let mut pairs = Vec::new();
    let mut i = 0;
    let mut j = 1;
    while i + 1 < n {
        j = j.max(i + 1);
        while j < n && travelled_m[j] - travelled_m[i] < length_m {
            j += 1;
        }
        if j == n {
            break;
        }
        pairs.push((i, j));
        i = match starts {
            SegmentStarts::EveryPose => i + 1,
            SegmentStarts::Consecutive => j,
        };
    }
    pairs
}

/// Relative errors of `t_world_body_est` against `t_world_body_gt` (same length, same times) over
/// segments of `length_m` travelled along the ground truth.
///
/// # Panics
/// If the slices differ in length (a caller bug: they come from one association).
pub fn relative_errors(
    t_world_body_gt: &[Isometry3<f64>],
    t_world_body_est: &[Isometry3<f64>],
    length_m: f64,
    starts: SegmentStarts,
) -> RelativeErrors {
    assert_eq!(
        t_world_body_gt.len(),
        t_world_body_est.len(),
        "one pose pair per time"
    );
    let positions_m: Vec<Vector3<f64>> = t_world_body_gt
        .iter()
        .map(|t| t.translation.vector)
        .collect();
    let (trans_m, rot_deg) = segment_pairs(&positions_m, length_m, starts)
        .into_iter()
        .map(|(i, j)| {
            let t_i_j_gt = t_world_body_gt[i].inverse() * t_world_body_gt[j];
            let t_i_j_est = t_world_body_est[i].inverse() * t_world_body_est[j];
            let e = t_i_j_gt.inverse() * t_i_j_est;
            (e.translation.vector.norm(), e.rotation.angle().to_degrees())
        })
        .unzip();
    RelativeErrors { trans_m, rot_deg }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(n: usize, step_m: f64) -> Vec<Isometry3<f64>> {
        (0..n)
            .map(|i| Isometry3::new(Vector3::new(step_m * i as f64, 0.0, 0.0), Vector3::zeros()))
            .collect()
    }

    #[test]
    fn segments_on_a_uniform_line() {
        let p: Vec<_> = line(11, 0.25)
            .iter()
            .map(|t| t.translation.vector)
            .collect();
        // 0.25 m steps: a 1 m segment spans 4 steps.
        assert_eq!(
            segment_pairs(&p, 1.0, SegmentStarts::Consecutive),
            vec![(0, 4), (4, 8)]
        );
        let every = segment_pairs(&p, 1.0, SegmentStarts::EveryPose);
        assert_eq!(every.len(), 7);
        assert!(
            every
                .iter()
                .enumerate()
                .all(|(k, &(i, j))| i == k && j == k + 4)
        );
        assert!(segment_pairs(&p, 10.0, SegmentStarts::EveryPose).is_empty());
        assert!(segment_pairs(&p[..1], 0.0, SegmentStarts::EveryPose).is_empty());
    }

    #[test]
    fn rigid_offset_gives_zero_and_scale_gives_proportional_error() {
        let gt = line(41, 0.25);
        let offset = Isometry3::new(Vector3::new(3.0, -2.0, 1.0), Vector3::new(0.1, 0.2, 0.3));
        let shifted: Vec<_> = gt.iter().map(|t| offset * t).collect();
        let r = relative_errors(&gt, &shifted, 1.0, SegmentStarts::EveryPose);
        assert_eq!(r.trans_m.len(), 37);
        assert!(r.trans_m.iter().chain(&r.rot_deg).all(|e| e.abs() < 1e-12));

        // The estimate travels 10 % too far: each 1 m segment is off by 0.1 m.
        let stretched: Vec<_> = gt
            .iter()
            .map(|t| Isometry3::new(1.1 * t.translation.vector, Vector3::zeros()))
            .collect();
        let r = relative_errors(&gt, &stretched, 1.0, SegmentStarts::Consecutive);
        assert_eq!(r.trans_m.len(), 10);
        assert!(
            r.trans_m.iter().all(|e| (e - 0.1).abs() < 1e-12),
            "{:?}",
            r.trans_m
        );
    }

    #[test]
    fn rotation_drift_is_measured_in_degrees() {
        let gt = line(9, 0.25);
        // The estimate turns 1 degree about z per pose more than the ground truth.
        let est: Vec<_> = gt
            .iter()
            .enumerate()
            .map(|(k, t)| {
                Isometry3::new(t.translation.vector, Vector3::z() * (k as f64).to_radians())
            })
            .collect();
        let r = relative_errors(&gt, &est, 1.0, SegmentStarts::Consecutive);
        assert_eq!(r.rot_deg.len(), 2);
        assert!(
            r.rot_deg.iter().all(|a| (a - 4.0).abs() < 1e-9),
            "{:?}",
            r.rot_deg
        );
    }
}
