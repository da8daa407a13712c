//! How far a loop moves the new keyframe from where the pose graph has it, in the graph's four
//! degrees of freedom (world position and heading about the world vertical), and whether two
//! loops ask for the same move.
//!
//! A loop edge measured right corrects the drift the odometry gathered since the old keyframe;
//! two loops closed within a few keyframes of each other, to different old keyframes, then ask
//! for nearly the same move, since little drift is gathered in between. A wrong one (a few
//! matches on a map whose depths are off, a PnP pose that fits them) asks for a move of its own.
//! This is ORB-SLAM's check of a loop against the next detections, read in the graph's terms:
//! the closer holds a loop that moves the graph far until another agrees with it
//! ([`LoopClosureConfig::confirm_far_loops`](super::closer::LoopClosureConfig::confirm_far_loops)).

use super::pose_graph::{wrap_angle, yaw_of};
use nalgebra::{Isometry3, Vector3};

/// The move a loop asks of its new keyframe: the camera's position by the loop minus the graph's,
/// world frame, m, and its heading (the camera x axis about world z) likewise, rad in (−π, π].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopShift {
    pub position_m: Vector3<f64>,
    pub yaw_rad: f64,
}

/// Heading of a pose's x axis about world z, rad (the pose graph's yaw).
fn heading_rad(t: &Isometry3<f64>) -> f64 {
    yaw_of(t.rotation.to_rotation_matrix().matrix())
}

impl LoopShift {
    /// The new keyframe where the loop edge `t_old_new` puts it from the old keyframe's graph
    /// pose `t_world_old`, against its graph pose `t_world_new`.
    pub fn of(
        t_world_old: &Isometry3<f64>,
        t_world_new: &Isometry3<f64>,
        t_old_new: &Isometry3<f64>,
    ) -> Self {
        let by_loop = t_world_old * t_old_new;
        LoopShift {
            position_m: by_loop.translation.vector - t_world_new.translation.vector,
            yaw_rad: wrap_angle(heading_rad(&by_loop) - heading_rad(t_world_new)),
        }
    }

    /// Whether the loop moves the keyframe by more than `m` or turns it by more than `rad`.
    pub fn beyond(&self, m: f64, rad: f64) -> bool {
        self.position_m.norm() > m || self.yaw_rad.abs() > rad
    }

    /// Whether two loops ask for the same move within `tol_m` and `tol_rad` (false if either is
    /// not finite).
    pub fn agrees(&self, other: &LoopShift, tol_m: f64, tol_rad: f64) -> bool {
        let dyaw = wrap_angle(self.yaw_rad - other.yaw_rad).abs();
        (self.position_m - other.position_m).norm() <= tol_m && dyaw <= tol_rad
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use std::f64::consts::PI;

    fn pose(yaw_rad: f64, pitch_rad: f64, p: [f64; 3]) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(p[0], p[1], p[2]),
            UnitQuaternion::from_euler_angles(0.0, pitch_rad, yaw_rad),
        )
    }

    #[test]
    fn a_loop_that_agrees_with_the_graph_asks_for_no_move() {
        let old = pose(0.3, 0.1, [1.0, 2.0, 0.5]);
        let new = pose(-2.0, -0.2, [1.5, 1.0, 0.7]);
        let s = LoopShift::of(&old, &new, &(old.inverse() * new));
        assert!(
            s.position_m.norm() < 1e-12 && s.yaw_rad.abs() < 1e-12,
            "{s:?}"
        );
        assert!(!s.beyond(1e-9, 1e-9));
    }

    #[test]
    fn the_move_is_the_world_offset_and_heading_the_loop_puts_on_the_new_keyframe() {
        let old = pose(0.3, 0.1, [1.0, 2.0, 0.5]);
        let truth = pose(3.12, 0.05, [1.5, 1.0, 0.7]);
        // The graph has the new keyframe 0.2 m off along world x and turned by 0.05 rad, across
        // the ±π seam of the heading (3.12 → 3.17 rad, read as −3.11).
        let drifted = Isometry3::from_parts(
            Translation3::new(1.7, 1.0, 0.7),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.05) * truth.rotation,
        );
        let s = LoopShift::of(&old, &drifted, &(old.inverse() * truth));
        assert!(
            (s.position_m - Vector3::new(-0.2, 0.0, 0.0)).norm() < 1e-12,
            "{s:?}"
        );
        assert!((s.yaw_rad + 0.05).abs() < 1e-9, "{s:?}");
        assert!(s.beyond(0.19, 1.0) && !s.beyond(0.21, 1.0));
        assert!(s.beyond(1.0, 0.049) && !s.beyond(1.0, 0.051));
    }

    #[test]
    fn two_moves_agree_within_the_tolerances_and_across_the_heading_seam() {
        let a = LoopShift {
            position_m: Vector3::new(0.2, 0.0, 0.0),
            yaw_rad: PI - 0.01,
        };
        let b = LoopShift {
            position_m: Vector3::new(0.23, 0.04, 0.0),
            yaw_rad: -PI + 0.01,
        };
        assert!(a.agrees(&b, 0.05, 0.021) && b.agrees(&a, 0.05, 0.021));
        assert!(!a.agrees(&b, 0.049, 0.021));
        assert!(!a.agrees(&b, 0.05, 0.019));
        let nan = LoopShift {
            position_m: Vector3::new(f64::NAN, 0.0, 0.0),
            yaw_rad: 0.0,
        };
        assert!(!a.agrees(&nan, 1.0, 1.0) && !nan.agrees(&nan, 1.0, 1.0));
    }
}
