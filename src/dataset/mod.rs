//! Datasets on disk: the ASL/EuRoC folder layout and trajectory files.

pub mod euroc_imu;
pub mod gx4_recording;
pub mod trajectory;

pub use trajectory::{StampedPose, Trajectory, TrajectoryError, TrajectoryFormat};
