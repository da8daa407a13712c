//! Datasets on disk: the ASL/EuRoC folder layout and trajectory files.

pub mod trajectory;

pub use trajectory::{StampedPose, Trajectory, TrajectoryError, TrajectoryFormat};
