//! The keyframe back end: a sliding window of keyframe states joined by IMU preintegration and by
//! the relative poses tracking measured, that moves keyframes onto an IMU-consistent solution
//! (see [`keyframe_window`] for why the paper's frame-to-keyframe tracking needs it).

pub mod envelope_cholesky;
pub mod keyframe_window;
mod nearest;
pub mod photometric_bundle;
pub mod relative_pose;
pub mod zero_skipping_cholesky;

pub use keyframe_window::{KeyframeWindow, SolveSummary, WindowConfig, boxminus};
pub use relative_pose::RelativePose;
