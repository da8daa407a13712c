//! Frame conversions from vidslam's world/body frames to the flight controller's (FC) frames.
//!
//! ```text
//!  vidslam world `w`                          FC local frame `l` (LOCAL_FRD, or LOCAL_NED)
//!  gravity-aligned, z UP, x/y = heading       z DOWN; x = w's x, y = -(w's y)
//!  of the first pose (arbitrary)
//!
//!          z_w (up)                                x_l  (= x_w; north if NED)
//!          ^                                      ^
//!          |   x_w                               /
//!          |  /                                 /
//!          | /                                 o------> y_l  (= -y_w; east if NED)
//!          |/                                  |
//!   y_w <--o                                   |
//!                                              v
//!                     r_fclocal_world          z_l  (= -z_w, down)
//!                     = 180 deg about x
//!
//!  body `b` = IMU frame (axes as mounted)     FC body `f` = vehicle FRD
//!                                             (x Forward, y Right, z Down)
//!          v_f = r_fcbody_imu * v_b           r_fcbody_imu is the mounting rotation; default
//!                                             180 deg about x = an IMU mounted x forward, y left,
//!                                             z up (FLU), as on a level vehicle where our z-up
//!                                             world and the IMU agree.
//! ```
//!
//! Conversions (all rotations named `r_a_b`, mapping frame-b coordinates into frame a):
//!
//! * position `p_l = r_fclocal_world * p_w` — of the IMU origin. The FC corrects for the IMU's
//!   offset from the vehicle's centre with its own parameters (PX4 `EKF2_EV_POS_X/Y/Z`,
//!   ArduPilot `VISO_POS_X/Y/Z`).
//! * attitude `r_l_f = r_fclocal_world * r_world_imu * r_fcbody_imu^T` (sent as `q` = w, x, y, z,
//!   with w >= 0).
//! * linear velocity in the FC body frame (ODOMETRY, `child_frame_id` BODY_FRD):
//!   `v_f = r_fcbody_imu * r_world_imu^T * v_w`; in the local frame (VISION_SPEED_ESTIMATE):
//!   `v_l = r_fclocal_world * v_w`.
//! * angular rate `omega_f = r_fcbody_imu * omega_b` (roll/pitch/yaw speeds).
//! * pose covariance over `[p_w; theta_w]` (see [`PoseCovariance`]) maps with
//!   `blockdiag(r_fclocal_world, r_fclocal_world)`; velocity covariance like the velocity.
//!
//! LOCAL_NED is the same axis mapping; choosing it asserts that the world's x axis points north
//! (a north-west-up world), which vidslam's world only does if the estimator aligned it.

use nalgebra::{Matrix3, Matrix6, Rotation3, UnitQuaternion, Vector3};

/// `r_fclocal_world`: 180 degrees about x (z up to z down, y flipped, x kept).
pub fn r_fclocal_world() -> Rotation3<f64> {
    Rotation3::from_matrix_unchecked(Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0))
}

/// Covariance of a pose `t_world_body`, 6x6 over `[delta_p_world_m (3); delta_theta_world_rad (3)]`,
/// where the true rotation is `exp(hat(delta_theta)) * r_world_body` (a world-frame, left
/// perturbation) and the true position is `p_world + delta_p_world`.
pub type PoseCovariance = Matrix6<f64>;

/// Converts a covariance over `[delta_p_world; delta_theta_body]` (rotation perturbed on the right,
/// `r_world_body * exp(hat(delta_theta_body))`, the usual VIO convention) into a [`PoseCovariance`].
pub fn pose_covariance_from_body_perturbation(
    r_world_body: &UnitQuaternion<f64>,
    cov_p_world_theta_body: &Matrix6<f64>,
) -> PoseCovariance {
    let mut j = Matrix6::identity();
    j.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&r_world_body.to_rotation_matrix().into_inner());
    j * cov_p_world_theta_body * j.transpose()
}

/// The configurable part of the frame conversion: how the IMU is mounted on the vehicle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FcFrames {
    /// Maps IMU-frame vectors into the vehicle's FRD body frame.
    pub r_fcbody_imu: UnitQuaternion<f64>,
}

impl Default for FcFrames {
    /// IMU mounted FLU (x forward, y left, z up): 180 degrees about x.
    fn default() -> Self {
        FcFrames::from_mount_rpy_rad(std::f64::consts::PI, 0.0, 0.0)
    }
}

/// A pose, velocity and rate expressed in the FC's frames (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FcState {
    pub p_local_m: Vector3<f64>,
    /// `r_fclocal_fcbody` as a unit quaternion with w >= 0.
    pub q_local_fcbody: UnitQuaternion<f64>,
    pub v_fcbody_m_s: Vector3<f64>,
    pub v_local_m_s: Vector3<f64>,
    pub omega_fcbody_rad_s: Vector3<f64>,
}

impl FcFrames {
    /// Mounting given as the rotation `r_fcbody_imu = Rz(yaw) * Ry(pitch) * Rx(roll)`.
    pub fn from_mount_rpy_rad(roll_rad: f64, pitch_rad: f64, yaw_rad: f64) -> Self {
        FcFrames {
            r_fcbody_imu: UnitQuaternion::from_euler_angles(roll_rad, pitch_rad, yaw_rad),
        }
    }

    /// Converts a world/IMU pose, world velocity and IMU angular rate into the FC's frames.
    pub fn to_fc(
        &self,
        t_world_imu: &nalgebra::Isometry3<f64>,
        v_world_m_s: &Vector3<f64>,
        omega_imu_rad_s: &Vector3<f64>,
    ) -> FcState {
        let r_lw = UnitQuaternion::from_rotation_matrix(&r_fclocal_world());
        let r_wi = t_world_imu.rotation;
        let mut q = r_lw * r_wi * self.r_fcbody_imu.inverse();
        if q.w < 0.0 {
            q = UnitQuaternion::new_unchecked(-q.into_inner());
        }
        let r_fcbody_world = self.r_fcbody_imu * r_wi.inverse();
        FcState {
            p_local_m: r_lw * t_world_imu.translation.vector,
            q_local_fcbody: q,
            v_fcbody_m_s: r_fcbody_world * v_world_m_s,
            v_local_m_s: r_lw * v_world_m_s,
            omega_fcbody_rad_s: self.r_fcbody_imu * omega_imu_rad_s,
        }
    }

    /// Inverse of the pose part of [`FcFrames::to_fc`]: `t_world_imu` from the FC's position
    /// and attitude.
    pub fn pose_from_fc(
        &self,
        p_local_m: &Vector3<f64>,
        q_local_fcbody: &UnitQuaternion<f64>,
    ) -> nalgebra::Isometry3<f64> {
        let r_wl = UnitQuaternion::from_rotation_matrix(&r_fclocal_world().inverse());
        nalgebra::Isometry3::from_parts(
            nalgebra::Translation3::from(r_wl * p_local_m),
            r_wl * q_local_fcbody * self.r_fcbody_imu,
        )
    }

    /// [`PoseCovariance`] in world coordinates to the FC local frame `[x, y, z, roll, pitch, yaw]`.
    pub fn pose_covariance_to_local(&self, cov_world: &PoseCovariance) -> Matrix6<f64> {
        let r = r_fclocal_world().into_inner();
        let mut j = Matrix6::zeros();
        j.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        j.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
        j * cov_world * j.transpose()
    }

    /// Covariance of `v_world_m_s` to the FC body frame (the frame of ODOMETRY's velocity).
    pub fn velocity_covariance_to_fcbody(
        &self,
        r_world_imu: &UnitQuaternion<f64>,
        cov_world: &Matrix3<f64>,
    ) -> Matrix3<f64> {
        let r = (self.r_fcbody_imu * r_world_imu.inverse())
            .to_rotation_matrix()
            .into_inner();
        r * cov_world * r.transpose()
    }

    /// Covariance of `v_world_m_s` to the FC local frame (VISION_SPEED_ESTIMATE).
    pub fn velocity_covariance_to_local(&self, cov_world: &Matrix3<f64>) -> Matrix3<f64> {
        let r = r_fclocal_world().into_inner();
        r * cov_world * r.transpose()
    }
}

/// Row-major upper triangle of a symmetric 6x6 matrix, the MAVLink covariance layout: row 0
/// (6 entries), row 1 from column 1 (5 entries), ... — diagonal at indices 0, 6, 11, 15, 18, 20.
pub fn upper_triangle_21(m: &Matrix6<f64>) -> [f64; 21] {
    let mut out = [0.0; 21];
    let mut k = 0;
    for i in 0..6 {
        for j in i..6 {
            out[k] = m[(i, j)];
            k += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3};
    use std::f64::consts::{FRAC_PI_2, PI};

    fn iso(p: [f64; 3], rotvec: [f64; 3]) -> Isometry3<f64> {
        Isometry3::new(Vector3::from(p), Vector3::from(rotvec))
    }

    fn close(a: &Vector3<f64>, b: &Vector3<f64>) -> bool {
        (a - b).norm() < 1e-12
    }

    #[test]
    fn level_flu_imu_gives_identity_attitude_and_z_down() {
        // Default mount (FLU IMU) at rest, level, 1 m up, 2 m along world x.
        let f = FcFrames::default();
        let s = f.to_fc(
            &iso([2.0, 0.5, 1.0], [0.0; 3]),
            &Vector3::zeros(),
            &Vector3::zeros(),
        );
        assert!(
            close(&s.p_local_m, &Vector3::new(2.0, -0.5, -1.0)),
            "{:?}",
            s.p_local_m
        );
        assert!(s.q_local_fcbody.angle() < 1e-12, "{:?}", s.q_local_fcbody);
    }

    #[test]
    fn known_rotations_yaw_left_is_negative_fc_yaw() {
        // Vehicle (FLU IMU) yawed +90 deg about world z-up (turned left) flies along world +y at
        // 1 m/s (its own forward) and yaws left at 0.3 rad/s.
        let f = FcFrames::default();
        let t_wi = iso([0.0; 3], [0.0, 0.0, FRAC_PI_2]);
        let v_w = Vector3::new(0.0, 1.0, 0.0);
        let omega_imu = Vector3::new(0.0, 0.0, 0.3);
        let s = f.to_fc(&t_wi, &v_w, &omega_imu);
        // In FRD/NED terms the heading is -90 deg (left of x), the body moves forward, and the
        // yaw rate is negative (z down).
        let (roll, pitch, yaw) = s.q_local_fcbody.euler_angles();
        assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12, "{roll} {pitch}");
        assert!((yaw + FRAC_PI_2).abs() < 1e-12, "yaw {yaw}");
        assert!(
            close(&s.v_fcbody_m_s, &Vector3::new(1.0, 0.0, 0.0)),
            "{:?}",
            s.v_fcbody_m_s
        );
        assert!(
            close(&s.v_local_m_s, &Vector3::new(0.0, -1.0, 0.0)),
            "{:?}",
            s.v_local_m_s
        );
        assert!(close(&s.omega_fcbody_rad_s, &Vector3::new(0.0, 0.0, -0.3)));
    }

    #[test]
    fn known_rotation_pitch_nose_up_is_positive_fc_pitch() {
        // FLU IMU pitched nose up by 0.2 rad: rotation about the IMU's y (left) axis by -0.2.
        let f = FcFrames::default();
        let s = f.to_fc(
            &iso([0.0; 3], [0.0, -0.2, 0.0]),
            &Vector3::zeros(),
            &Vector3::zeros(),
        );
        let (roll, pitch, yaw) = s.q_local_fcbody.euler_angles();
        assert!((pitch - 0.2).abs() < 1e-12 && roll.abs() < 1e-12 && yaw.abs() < 1e-12);
    }

    #[test]
    fn identity_mount_is_frd_imu() {
        // An IMU mounted FRD (z down) sitting level has r_world_imu = 180 deg about x.
        let f = FcFrames::from_mount_rpy_rad(0.0, 0.0, 0.0);
        let s = f.to_fc(
            &iso([0.0; 3], [PI, 0.0, 0.0]),
            &Vector3::zeros(),
            &Vector3::zeros(),
        );
        assert!(s.q_local_fcbody.angle() < 1e-12);
        let omega = Vector3::new(0.1, -0.2, 0.3);
        let s = f.to_fc(&Isometry3::identity(), &Vector3::zeros(), &omega);
        assert!(close(&s.omega_fcbody_rad_s, &omega));
    }

    #[test]
    fn round_trip_through_fc_frames() {
        for (mount, pose) in [
            ((PI, 0.0, 0.0), iso([1.0, -2.0, 3.0], [0.3, -0.2, 1.0])),
            ((0.1, -0.4, 2.5), iso([-0.5, 0.25, 0.0], [-1.2, 0.4, -2.9])),
            ((0.0, FRAC_PI_2, 0.0), iso([0.0, 0.0, 0.0], [3.0, 0.0, 0.0])),
        ] {
            let f = FcFrames::from_mount_rpy_rad(mount.0, mount.1, mount.2);
            let s = f.to_fc(&pose, &Vector3::zeros(), &Vector3::zeros());
            assert!(s.q_local_fcbody.w >= 0.0);
            let back = f.pose_from_fc(&s.p_local_m, &s.q_local_fcbody);
            let d = pose.inverse() * back;
            assert!(d.translation.vector.norm() < 1e-12 && d.rotation.angle() < 1e-12);
        }
    }

    #[test]
    fn velocity_body_and_local_agree_with_attitude() {
        let f = FcFrames::from_mount_rpy_rad(0.3, -1.1, 0.7);
        let t = Isometry3::from_parts(
            Translation3::new(0.0, 0.0, 0.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.4, 0.9, -0.3)),
        );
        let v_w = Vector3::new(0.7, -1.3, 0.2);
        let s = f.to_fc(&t, &v_w, &Vector3::zeros());
        assert!(close(&(s.q_local_fcbody * s.v_fcbody_m_s), &s.v_local_m_s));
    }

    #[test]
    fn covariances_rotate_like_their_vectors() {
        let f = FcFrames::default();
        // A position-only covariance along world y stays along local y (sign flips cancel).
        let mut c = Matrix6::zeros();
        c[(1, 1)] = 4.0;
        c[(0, 1)] = 1.0;
        c[(1, 0)] = 1.0;
        c[(5, 5)] = 0.01;
        let l = f.pose_covariance_to_local(&c);
        assert_eq!(l[(1, 1)], 4.0);
        assert_eq!(l[(0, 1)], -1.0);
        assert_eq!(l[(5, 5)], 0.01);
        // Velocity along world x seen from a body yawed 90 deg left lies on the body's -y (FLU),
        // i.e. +y in FRD.
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, FRAC_PI_2));
        let mut cv = Matrix3::zeros();
        cv[(0, 0)] = 2.0;
        let b = f.velocity_covariance_to_fcbody(&r, &cv);
        assert!((b[(1, 1)] - 2.0).abs() < 1e-12 && b[(0, 0)].abs() < 1e-12);
    }

    #[test]
    fn body_perturbation_covariance_rotates_the_attitude_block() {
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, FRAC_PI_2));
        let mut c = Matrix6::zeros();
        c[(0, 0)] = 1.0;
        c[(3, 3)] = 0.04; // about body x = world y after a 90 deg yaw
        let w = pose_covariance_from_body_perturbation(&r, &c);
        assert_eq!(w[(0, 0)], 1.0);
        assert!((w[(4, 4)] - 0.04).abs() < 1e-15 && w[(3, 3)].abs() < 1e-15);
    }

    #[test]
    fn upper_triangle_layout() {
        let m = Matrix6::from_fn(|i, j| (10 * i.min(j) + i.max(j)) as f64);
        let t = upper_triangle_21(&m);
        assert_eq!(t[0], 0.0);
        assert_eq!(t[5], 5.0);
        assert_eq!(t[6], 11.0);
        assert_eq!(t[20], 55.0);
        let diag: Vec<f64> = [0, 6, 11, 15, 18, 20].iter().map(|&k| t[k]).collect();
        assert_eq!(diag, vec![0.0, 11.0, 22.0, 33.0, 44.0, 55.0]);
    }
}
