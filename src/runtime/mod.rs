//! Running the pipeline: offline replay of recorded datasets, its report, and the configuration.

pub mod adjust_check;
pub mod catch_up;
pub mod config;
pub mod fc_sample;
pub mod guessed_keyframe;
pub mod keyframe_builder;
pub mod keyframe_bundle;
pub mod keyframe_store;
pub mod map_depth;
pub mod map_keyframe;
pub mod mapping_worker;
pub mod odometry;
pub mod refinement_worker;
pub mod replay;
pub mod replay_files;
pub mod report;
mod report_table;
pub mod scale_observer;
pub mod takeoff;
pub mod thread_clock;
pub mod thread_priority;
pub mod true_view_poses;

pub use config::Config;
pub use replay::{DepthSource, Recoveries, ReplayOptions, ReplayOutput, replay};
pub use replay_files::trajectory;
pub use report::ReplayReport;
