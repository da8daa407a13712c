//! Inputs shared by the benchmarks: a rendered segment of the built-in flight.

use std::path::PathBuf;
use vidslam::dataset::AslDataset;
use vidslam::sim::{ImuSource, SimConfig, TrajectorySource, generate};

/// `seconds` of the built-in demo flight from `start_s`, rendered with its IMU and ground truth
/// into a temporary folder that is removed when this is dropped.
pub struct DemoSegment {
    pub ds: AslDataset,
    dir: PathBuf,
}

impl DemoSegment {
    /// Renders it; `name` tells the benchmark's folder apart.
    pub fn render(name: &str, start_s: f64, seconds: f64) -> Self {
        let dir = std::env::temp_dir().join(format!("vidslam-bench-{name}-{}", std::process::id()));
        let mut sim = SimConfig::new(
            dir.clone(),
            TrajectorySource::Builtin("demo".into()),
            ImuSource::Synth,
        );
        sim.start_s = Some(start_s);
        sim.seconds = Some(seconds);
        sim.force = true;
        generate(&sim).unwrap();
        DemoSegment {
            ds: AslDataset::open(&dir).unwrap(),
            dir,
        }
    }
}

impl Drop for DemoSegment {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}
