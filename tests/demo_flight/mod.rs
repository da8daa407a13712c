//! The built-in demo flight as a pose spline, for the tests that run the keyframe window on it
//! (body frame = the camera's: `t_body_cam` identity), and its true states (zero biases).

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use vidslam::imu::{FrameState, ImuBias};
use vidslam::sim::flights::builtin_flight;
use vidslam::sim::{PoseSpline, fit_pose_spline};
use vidslam::time::TimeNs;

pub fn flight() -> PoseSpline {
    let tb = Isometry3::from_parts(Translation3::identity(), UnitQuaternion::identity());
    let tr = builtin_flight("demo", &tb).unwrap();
    fit_pose_spline(&tr.poses, 50_000_000).unwrap().0
}

pub fn truth(sp: &PoseSpline, t: TimeNs) -> FrameState {
    FrameState {
        nav: sp.nav_state(t),
        bias: ImuBias::default(),
    }
}
