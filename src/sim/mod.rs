//! The simulator: rendered camera + IMU sequences with ground-truth pose, velocity, biases and
//! depth, written in the ASL/EuRoC layout (`vidslam sim`).
//!
//! Pipeline ([`generate`]): a trajectory (a built-in flight from [`flights`], or a recorded ground
//! truth) is fitted with a cumulative cubic B-spline on SO(3) x R³ ([`spline`], [`fit`]); the IMU is
//! synthesised from it ([`imu_synth`]) or a real recording is passed through with biases
//! estimated against the spline ([`real_imu`]); a piecewise-planar textured room is built around
//! the path ([`scene`], [`texture`]) and ray-cast through the distorted camera model with
//! supersampling, motion blur, auto exposure, vignetting and noise ([`render`], [`exposure`]).
//! Every random draw comes from a stream keyed by the seed ([`rng`]), so a seed fixes the output.

pub mod exposure;
pub mod fit;
pub mod flights;
pub mod imu_synth;
pub mod real_imu;
pub mod render;
pub mod rng;
pub mod scene;
pub mod spline;
pub mod texture;
pub mod write;

pub use fit::{FitReport, fit_pose_spline};
pub use render::{FramePoses, RenderedFrame, Renderer};
pub use scene::Scene;
pub use spline::{PoseSpline, SplineState};
pub use write::{ImuSource, SimConfig, SimError, SimReport, TrajectorySource, generate};
