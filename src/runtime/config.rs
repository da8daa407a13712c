//! The daemon's TOML configuration (`config/vidslam.toml`). Unknown keys are errors; every error
//! names the file, line and key.

use super::keyframe_bundle::KeyframeBundleConfig;
use super::keyframe_store::ReuseConfig;
use super::odometry::BootstrapConfig;
use super::scale_observer::ScaleObserverConfig;
use crate::imu::static_init::StaticDetectorConfig;
use crate::mapping::semidense::SemidenseConfig;
use crate::smoother::WindowConfig;
use crate::tracking::TrackerConfig;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// All tables of the configuration file; each has defaults, so an empty file is valid.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// `[tracking]`: the frame-rate visual-inertial tracker.
    pub tracking: TrackerConfig,
    /// `[mapping]`: the semidense mapper.
    pub mapping: SemidenseConfig,
    /// `[static_detector]`: rest detection on the IMU.
    pub static_detector: StaticDetectorConfig,
    /// `[bootstrap]`: first map and loss recovery.
    pub bootstrap: BootstrapConfig,
    /// `[window]`: the keyframe window (IMU between keyframes, relative poses from tracking).
    pub window: WindowConfig,
    /// `[reuse]`: tracking against the closest stored keyframe.
    pub reuse: ReuseConfig,
    /// `[keyframe_bundle]`: in-flight photometric–inertial adjustment of each new keyframe.
    pub keyframe_bundle: KeyframeBundleConfig,
    /// `[scale_observer]`: the map scale measured against the IMU in flight.
    pub scale_observer: ScaleObserverConfig,
}

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Parse { path: String, message: String },
}

impl Config {
    /// Reads and validates a TOML file.
    pub fn read(path: &Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::parse(&text).map_err(|message| ConfigError::Parse {
            path: path.display().to_string(),
            message,
        })
    }

    /// Parses TOML text; the error says where (line, column) and which key.
    pub fn parse(text: &str) -> Result<Config, String> {
        toml::from_str(text).map_err(|e| {
            let at = e
                .span()
                .map(|s| {
                    let line = text[..s.start.min(text.len())].matches('\n').count() + 1;
                    format!("line {line}: ")
                })
                .unwrap_or_default();
            format!("{at}{}", e.message())
        })
    }

    /// The configuration as TOML (every key with its value).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_round_trip_and_errors_name_line_and_key() {
        let c = Config::default();
        assert_eq!(Config::parse(&c.to_toml()).unwrap(), c);
        assert_eq!(Config::parse("").unwrap(), c);
        let e = Config::parse("[tracking]\nhuber_gray = 5.0\nhuber_grey = 3.0\n").unwrap_err();
        assert!(e.contains("line 3") && e.contains("huber_grey"), "{e}");
        let e = Config::parse("[tracking]\nmax_imu_chi2 = \"x\"\n").unwrap_err();
        assert!(e.contains("line 2"), "{e}");
    }

    #[test]
    fn shipped_config_file_parses() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/vidslam.toml");
        // The shipped file documents the defaults: it must say exactly what the code does.
        assert_eq!(Config::read(&p).unwrap(), Config::default());
    }
}
