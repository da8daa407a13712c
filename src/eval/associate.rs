//! Association by timestamp: ground truth interpolated at each estimate time.

use crate::dataset::Trajectory;
use crate::time::TimeNs;
use nalgebra::Isometry3;

/// An estimated pose and the ground truth at the same time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PosePair {
    pub t: TimeNs,
    /// Ground truth at `t` (a sample, or interpolated between its two neighbours).
    pub t_world_body_gt: Isometry3<f64>,
    /// The estimate at `t`, in the estimate's own world frame.
    pub t_world_body_est: Isometry3<f64>,
}

/// Pairs every pose of `est` with `gt` interpolated at its time (linear translation, SLERP
/// rotation, see [`Trajectory::interpolate`]). Estimate poses before the first or after the last
/// ground-truth sample, or inside a ground-truth gap longer than `max_dt_ns` (e.g. a motion-capture
/// dropout), are left out. A pose stamped exactly at a ground-truth sample always matches it.
pub fn associate(gt: &Trajectory, est: &Trajectory, max_dt_ns: i64) -> Vec<PosePair> {
    est.poses
        .iter()
        .filter_map(|e| {
            gt.interpolate(e.t, max_dt_ns)
                .map(|t_world_body_gt| PosePair {
                    t: e.t,
                    t_world_body_gt,
                    t_world_body_est: e.t_world_body,
                })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::StampedPose;
    use nalgebra::{UnitQuaternion, Vector3};

    fn pose(t_ns: i64, x_m: f64, yaw_rad: f64) -> StampedPose {
        StampedPose {
            t: TimeNs(t_ns),
            t_world_body: Isometry3::new(Vector3::new(x_m, 0.0, 0.0), Vector3::z() * yaw_rad),
        }
    }

    #[test]
    fn matches_exact_interpolated_and_drops_outside_or_in_gaps() {
        // GT at 0, 5, 10 ms, then a 50 ms dropout, then 65 ms.
        let gt = Trajectory::new(vec![
            pose(0, 0.0, 0.0),
            pose(5_000_000, 1.0, 0.2),
            pose(10_000_000, 2.0, 0.4),
            pose(60_000_000, 3.0, 0.6),
            pose(65_000_000, 4.0, 0.8),
        ]);
        let est = Trajectory::new(vec![
            pose(-1, 9.0, 0.0),         // before GT
            pose(5_000_000, 9.0, 0.0),  // exact
            pose(7_500_000, 9.0, 0.0),  // midpoint
            pose(30_000_000, 9.0, 0.0), // inside the dropout
            pose(62_000_000, 9.0, 0.0), // after the dropout, 2/5 of the way
            pose(65_000_001, 9.0, 0.0), // after GT
        ]);
        let pairs = associate(&gt, &est, 10_000_000);
        let times: Vec<i64> = pairs.iter().map(|p| p.t.0).collect();
        assert_eq!(times, vec![5_000_000, 7_500_000, 62_000_000]);
        assert_eq!(pairs[0].t_world_body_gt, gt.poses[1].t_world_body);
        let mid = &pairs[1].t_world_body_gt;
        assert!((mid.translation.vector - Vector3::new(1.5, 0.0, 0.0)).norm() < 1e-12);
        let expect_rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3);
        assert!(mid.rotation.angle_to(&expect_rot) < 1e-12);
        let late = &pairs[2].t_world_body_gt;
        assert!((late.translation.vector.x - 3.4).abs() < 1e-12);
        assert!(
            pairs
                .iter()
                .all(|p| p.t_world_body_est.translation.vector.x == 9.0)
        );
        // A wider gap tolerance bridges the dropout.
        assert_eq!(associate(&gt, &est, 50_000_000).len(), 4);
    }
}
