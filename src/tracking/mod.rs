//! The tracking thread (paper section III): keyframes with precomputed inverse-compositional
//! Jacobians, the photometric residual with affine brightness, and the joint visual-inertial
//! Gauss-Newton solved with the Schur complement.

pub mod config;
pub mod keyframe;
pub mod photometric;
pub mod schur;
pub mod tracker;

pub use config::{NUM_LEVELS, TrackerConfig};
pub use keyframe::{DepthPoint, Keyframe, depth_points_from_map, select_gradient_pixels};
pub use schur::BlockSystem;
pub use tracker::{FlagReason, TrackResult, Tracker, photometric_rotation, pose_of};
