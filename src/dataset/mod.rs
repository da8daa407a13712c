//! Datasets on disk: the ASL/EuRoC folder layout (reader and writer), its `sensor.yaml` files,
//! ground truth, and trajectory files (TUM / EuRoC CSV).

mod asl;
mod csv_lines;
mod groundtruth;
pub mod gx4_recording;
pub mod imu_mix;
mod imu_rewrite;
mod sensor_yaml;
pub mod trajectory;
mod writer;

pub use asl::{
    AslDataset, DEPTH_PNG_UNITS_PER_M, Event, EventIter, FrameIter, FrameRecord, ImuIter,
    read_imu_csv, read_imu_csv_with_lines,
};
pub use groundtruth::{GroundTruth, GroundTruthState, read_groundtruth};
#[cfg(unix)]
pub use imu_rewrite::rewrite_dataset;
pub use imu_rewrite::{DonorMix, ImuRewrite, RewriteSummary};
pub use sensor_yaml::{
    CameraSensor, ImuSensor, SensorYamlError, isometry_from_matrix, read_camera_yaml,
    read_imu_yaml, read_vignette_yaml, write_camera_yaml, write_imu_yaml, write_vignette_yaml,
};
pub use trajectory::{StampedPose, Trajectory, TrajectoryFormat};
pub use writer::AslWriter;

use std::path::PathBuf;

/// Errors reading or writing datasets; each names the file (and line or key where it applies).
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {msg}")]
    Parse {
        path: PathBuf,
        line: usize,
        msg: String,
    },
    #[error("{path}: {msg}")]
    Layout { path: PathBuf, msg: String },
    #[error(transparent)]
    Yaml(#[from] SensorYamlError),
    #[error(transparent)]
    Image(crate::image::PngError),
}

/// `relative` inside the shared test data, if it exists; otherwise prints a `SKIP:` line naming
/// where it was looked for and returns `None` (tests then return early).
pub fn shared_data_or_skip(relative: &str) -> Option<PathBuf> {
    let p = shared_data_dir().join(relative);
    if p.exists() {
        Some(p)
    } else {
        eprintln!(
            "SKIP: shared data not found at {} (set VIDSLAM_DATA)",
            p.display()
        );
        None
    }
}

/// Location of the shared test data: `$VIDSLAM_DATA`, else `../shared/data` next to the crate.
pub fn shared_data_dir() -> PathBuf {
    std::env::var_os("VIDSLAM_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"))
}
