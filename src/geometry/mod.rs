//! Lie-group math: the bottom layer. Imports nothing else from the crate.
//!
//! # Frame conventions (used everywhere in vidslam)
//!
//! * `world` (`w`): gravity-aligned, **z up**; gravity is `(0, 0, -GRAVITY_M_S2)` in it. Its origin
//!   and yaw are those of the first pose (or of the dataset's ground truth).
//! * `body` (`b`): the IMU frame. Accelerometer and gyro measurements are expressed in it.
//! * `cam` (`c`): the camera optical frame: x right, y down, z forward (looking direction).
//!
//! A transform is named `t_a_b` and maps coordinates of a point in frame `b` into frame `a`:
//! `p_a = t_a_b * p_b`. Hence `t_world_body` is the pose of the body in the world, and
//! `t_world_cam = t_world_body * t_body_cam`. Rotations follow the same rule (`r_world_body`).
//! Velocities `v_world` are of the body origin, in world coordinates.
//!
//! Paper notation (Concha et al. 2016): `R_j^w`, `t_j^w` are `r_world_body`, `p_world_body` of
//! frame j; `T_w^j` (eq. 15) is the inverse, `t_cam_world`.

pub mod se3;
pub mod so3;

pub use se3::{adjoint, boxplus_se3};
pub use so3::{exp_so3, hat, log_so3, right_jacobian, right_jacobian_inv, vee};

/// Standard gravity magnitude used by the simulator and the estimator, m/s^2.
pub const GRAVITY_M_S2: f64 = 9.81;
