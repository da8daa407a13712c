//! The published poses in hindsight: each frame keeps its pose relative to the keyframe whose
//! world it was published in, as the odometry and the loop correction had the two then, and is
//! put where the loop closer's graph places that keyframe at the end — the published trajectory
//! as it would have been had every loop been known from the first frame
//! (`OUT/trajectory_hindsight.tum`, `report.json` `hindsight_ate_m`). A diagnostic, not a
//! pose anyone can fly on: its gap to the published poses' ATE is the part of the error that
//! comes from correcting causally (a loop closed at 80 s moves the graph's keyframes of 60 s, but
//! the poses published at 60 s are gone).

use nalgebra::Isometry3;
use std::collections::HashMap;

/// The world a frame's published pose was corrected in
/// ([`super::OdometryFrame::loop_world`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopWorld {
    /// The keyframe whose correction was applied: the one tracked (after a return to a stored
    /// keyframe, that one), else the newest handed to the loop closer; `None` before the first.
    pub keyframe: Option<u32>,
    /// The correction applied: the published pose is `correction · ` the odometry's pose.
    pub correction: Isometry3<f64>,
    /// That keyframe's camera pose as the correction placed it then (`correction · ` its pose in
    /// the odometry as the loop closer had it; `None` for a keyframe it does not hold): the
    /// frame's pose relative to it is what tracking measured, and stays when the keyframe window
    /// or the graph moves the keyframe later.
    pub keyframe_pose: Option<Isometry3<f64>>,
}

/// Every keyframe's correction and camera pose as the loop closer's graph gives them at the end
/// ([`super::OdometryStats::loop_hindsight`]).
#[derive(Clone, Debug, Default)]
pub struct HindsightCorrections {
    /// Each keyframe handed to the closer: its correction (one the closer never took in: its
    /// nearest host's, as it was published) and its camera pose as the graph places it.
    pub(super) by_keyframe: HashMap<u32, (Isometry3<f64>, Isometry3<f64>)>,
    /// The first keyframe's correction: the world of the frames published before it.
    pub(super) first: Isometry3<f64>,
    /// The newest keyframe's: for a keyframe the closer did not keep (`[loop_closure]
    /// max_keyframes`), as it was published.
    pub(super) newest: Isometry3<f64>,
}

impl HindsightCorrections {
    /// The correction at the end of the world of `keyframe` (`None`: before the first keyframe).
    pub fn correction(&self, keyframe: Option<u32>) -> Isometry3<f64> {
        match keyframe {
            None => self.first,
            Some(k) => self.by_keyframe.get(&k).map_or(self.newest, |&(c, _)| c),
        }
    }

    /// The camera pose of `keyframe` as the graph places it at the end (`None` for one the
    /// closer was not handed).
    pub fn keyframe_pose(&self, keyframe: u32) -> Option<Isometry3<f64>> {
        self.by_keyframe.get(&keyframe).map(|&(_, pose)| pose)
    }

    /// A published body pose `t_world_body`, corrected in `world`, as the graph places it at the
    /// end: moved as its keyframe moved since (from `world.keyframe_pose` to the graph's pose of
    /// it now) — the pose relative to the keyframe is kept —, or where either is unknown, from
    /// the correction it was published with to that world's correction now.
    pub fn moved(&self, world: &LoopWorld, t_world_body: &Isometry3<f64>) -> Isometry3<f64> {
        let now = world.keyframe.and_then(|k| self.by_keyframe.get(&k));
        match (now, world.keyframe_pose) {
            (Some((_, kf_now)), Some(kf_then)) => kf_now * kf_then.inverse() * t_world_body,
            _ => self.correction(world.keyframe) * world.correction.inverse() * t_world_body,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn yawed(yaw_rad: f64, x_m: f64) -> Isometry3<f64> {
        Isometry3::new(Vector3::new(x_m, 0.3, -0.1), Vector3::z() * yaw_rad)
    }

    fn close(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
        (a.to_homogeneous() - b.to_homogeneous()).norm() < 1e-12
    }

    /// A pose published with one correction is placed as the end's correction of its world
    /// places the odometry's pose; before the first keyframe that is the first keyframe's world,
    /// and a keyframe the closer never placed takes the newest keyframe's.
    #[test]
    fn a_published_pose_is_moved_from_its_correction_then_to_its_worlds_at_the_end() {
        let (c1, c2, first, newest) = (
            yawed(0.1, 0.5),
            yawed(-0.05, 0.2),
            yawed(0.01, 0.0),
            yawed(0.2, -0.4),
        );
        let kf = yawed(0.4, 2.0);
        let h = HindsightCorrections {
            by_keyframe: HashMap::from([(1, (c1, c1 * kf)), (2, (c2, c2 * kf))]),
            first,
            newest,
        };
        let odometry = yawed(0.7, 3.0);
        let then = yawed(0.03, 0.1);
        let published = then * odometry;
        for (keyframe, end) in [
            (Some(1), c1),
            (Some(2), c2),
            (None, first),
            (Some(9), newest),
        ] {
            let world = LoopWorld {
                keyframe,
                correction: then,
                keyframe_pose: keyframe.map(|_| then * kf),
            };
            assert!(close(&h.correction(keyframe), &end));
            assert!(close(&h.moved(&world, &published), &(end * odometry)));
        }
        // Published with the end's correction already: unmoved.
        let world = LoopWorld {
            keyframe: Some(2),
            correction: c2,
            keyframe_pose: Some(c2 * kf),
        };
        assert!(close(&h.moved(&world, &(c2 * odometry)), &(c2 * odometry)));
    }

    /// A keyframe the odometry moved after the frame was published (the keyframe window): the
    /// frame keeps its pose relative to the keyframe as it was then, placed where the graph puts
    /// the keyframe now — not the end's correction times its odometry pose.
    #[test]
    fn a_frame_keeps_its_pose_relative_to_its_keyframe_when_the_keyframe_moved() {
        let c_then = yawed(0.02, 0.1);
        let kf_then = yawed(0.4, 2.0);
        let (c_end, kf_end) = (yawed(-0.03, 0.3), yawed(0.41, 2.05));
        let h = HindsightCorrections {
            by_keyframe: HashMap::from([(5, (c_end, c_end * kf_end))]),
            first: Isometry3::identity(),
            newest: Isometry3::identity(),
        };
        let odometry = yawed(0.5, 2.4);
        let published = c_then * odometry;
        let world = LoopWorld {
            keyframe: Some(5),
            correction: c_then,
            keyframe_pose: Some(c_then * kf_then),
        };
        let relative = kf_then.inverse() * odometry;
        assert!(close(
            &h.moved(&world, &published),
            &(c_end * kf_end * relative)
        ));
    }
}
