//! Diagnostic: the semidense mapper's views posed by the ground truth relative to their keyframe
//! (`vidslam replay --mapping-poses gt`).
//!
//! The mapper triangulates each keyframe from the poses tracking gave its views, and those were
//! tracked against the previous keyframe's map with the IMU pulling on them: a map's errors are
//! partly the poses' (docs/odometry-log.md, *The maps' geometry from the truth*). Here every view
//! of a keyframe is handed to the mapper at `T_world_kf · (T̄_world_kf⁻¹ · T̄_world_view)`, the
//! tracked keyframe pose times the *true* camera motion from the keyframe to the view (`T̄`: the
//! ground truth's body pose times the camera extrinsic). The keyframe's own pose, the propagation
//! of the previous map into it and everything tracking, the keyframe window and the keyframe
//! adjustment do stay the odometry's: what changes is only the relative geometry each map is
//! triangulated from — its metric baseline included — which measures how much of the odometry's
//! error the maps' triangulation poses cause, as `--depth gt` measures the tracker alone.
//!
//! Never used by the product: only a replay of a dataset with ground truth builds one.

use crate::dataset::Trajectory;
use crate::time::TimeNs;
use nalgebra::Isometry3;
use std::sync::Arc;

/// Ground-truth samples farther apart than this are not interpolated across, ns.
const MAX_GAP_NS: i64 = 50_000_000;

/// The ground truth's camera poses, for [`ViewPoser`].
#[derive(Clone, Debug)]
pub struct TrueCameraPoses {
    body: Trajectory,
    t_body_cam: Isometry3<f64>,
}

impl TrueCameraPoses {
    /// `body`: the ground truth's body (IMU) poses; `t_body_cam`: the camera extrinsic (`T_BS`).
    pub fn new(body: Trajectory, t_body_cam: Isometry3<f64>) -> Self {
        TrueCameraPoses { body, t_body_cam }
    }

    /// The true camera pose at `t`, interpolated; `None` outside the ground truth or across a gap.
    pub fn camera_at(&self, t: TimeNs) -> Option<Isometry3<f64>> {
        self.body
            .interpolate(t, MAX_GAP_NS)
            .map(|b| b * self.t_body_cam)
    }
}

/// Poses the views of the keyframe under construction by the true motion from it.
#[derive(Clone, Debug)]
pub struct ViewPoser {
    truth: Arc<TrueCameraPoses>,
    /// The current keyframe's (tracked, true) camera poses.
    keyframe: Option<(Isometry3<f64>, Isometry3<f64>)>,
}

impl ViewPoser {
    pub fn new(truth: Arc<TrueCameraPoses>) -> Self {
        ViewPoser {
            truth,
            keyframe: None,
        }
    }

    /// A new keyframe at `t`, tracked at `t_world_kf`.
    pub fn start_keyframe(&mut self, t: TimeNs, t_world_kf: &Isometry3<f64>) {
        self.keyframe = self.truth.camera_at(t).map(|truth| (*t_world_kf, truth));
    }

    /// The pose to triangulate a view at `t` from; `tracked` (its tracked pose) where the truth
    /// does not reach the view or its keyframe.
    pub fn view_pose(&self, t: TimeNs, tracked: &Isometry3<f64>) -> Isometry3<f64> {
        match (self.keyframe, self.truth.camera_at(t)) {
            (Some((kf_tracked, kf_true)), Some(view_true)) => {
                kf_tracked * (kf_true.inverse() * view_true)
            }
            _ => *tracked,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::StampedPose;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn pose(t: [f64; 3], r: [f64; 3]) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_scaled_axis(Vector3::from(r)),
        )
    }

    fn truth() -> TrueCameraPoses {
        let poses = (0..=10)
            .map(|k| StampedPose {
                t: TimeNs(k * 10_000_000),
                t_world_body: pose(
                    [0.1 * k as f64, 0.02 * k as f64, 0.0],
                    [0.0, 0.0, 0.03 * k as f64],
                ),
            })
            .collect();
        TrueCameraPoses::new(
            Trajectory::new(poses),
            pose([0.05, 0.0, 0.01], [0.0, 0.2, 0.0]),
        )
    }

    #[test]
    fn a_view_gets_the_true_motion_from_its_keyframe_on_the_tracked_keyframe_pose() {
        let truth = Arc::new(truth());
        let mut poser = ViewPoser::new(truth.clone());
        let kf_tracked = pose([3.0, -1.0, 0.5], [0.1, -0.2, 0.3]);
        poser.start_keyframe(TimeNs(20_000_000), &kf_tracked);
        let view_tracked = pose([9.0, 9.0, 9.0], [0.0, 0.0, 0.0]);
        let posed = poser.view_pose(TimeNs(70_000_000), &view_tracked);
        let true_rel = truth.camera_at(TimeNs(20_000_000)).unwrap().inverse()
            * truth.camera_at(TimeNs(70_000_000)).unwrap();
        let rel = kf_tracked.inverse() * posed;
        assert!((rel.translation.vector - true_rel.translation.vector).norm() < 1e-12);
        assert!(rel.rotation.angle_to(&true_rel.rotation) < 1e-12);
        // The extrinsic matters: the camera's motion is not the body's.
        let body_rel = pose([0.5, 0.1, 0.0], [0.0, 0.0, 0.15]);
        assert!((rel.translation.vector - body_rel.translation.vector).norm() > 1e-3);
    }

    #[test]
    fn without_the_truth_the_tracked_pose_stands() {
        let mut poser = ViewPoser::new(Arc::new(truth()));
        let tracked = pose([1.0, 2.0, 3.0], [0.3, 0.0, 0.0]);
        // No keyframe yet.
        assert_eq!(poser.view_pose(TimeNs(50_000_000), &tracked), tracked);
        // The view after the ground truth's end.
        poser.start_keyframe(TimeNs(0), &tracked);
        assert_eq!(poser.view_pose(TimeNs(200_000_000), &tracked), tracked);
        // A keyframe before its start.
        poser.start_keyframe(TimeNs(-5), &tracked);
        assert_eq!(poser.view_pose(TimeNs(50_000_000), &tracked), tracked);
    }
}
