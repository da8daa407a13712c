//! The daemon's TOML configuration (`config/vidslam.toml`). Unknown keys are errors; every error
//! names the file, line and key.

use super::keyframe_bundle::KeyframeBundleConfig;
use super::keyframe_store::ReuseConfig;
use super::odometry::BootstrapConfig;
use super::scale_observer::ScaleObserverConfig;
use crate::imu::gyro_alignment::GyroAlignmentConfig;
use crate::imu::static_init::StaticDetectorConfig;
use crate::loop_closure::closer::LoopClosureConfig;
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
    /// `[gyro_alignment]`: the rotation between the gyro's axes and the camera's body frame,
    /// estimated in flight.
    pub gyro_alignment: GyroAlignmentConfig,
    /// `[loop_closure]`: the drift taken out of the published pose at places mapped before.
    pub loop_closure: LoopClosureConfig,
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

    /// [`Config::read`] of `path`, or the defaults without one (the commands' `--config`).
    pub fn read_or_default(path: Option<&Path>) -> Result<Config, ConfigError> {
        path.map_or_else(|| Ok(Config::default()), Config::read)
    }

    /// Parses TOML text; the error says where (line, column) and which key.
    pub fn parse(text: &str) -> Result<Config, String> {
        let c: Config = toml::from_str(text).map_err(|e| {
            let at = e
                .span()
                .map(|s| {
                    let line = text[..s.start.min(text.len())].matches('\n').count() + 1;
                    format!("line {line}: ")
                })
                .unwrap_or_default();
            format!("{at}{}", e.message())
        })?;
        c.check_ranges(text)?;
        Ok(c)
    }

    /// Values the types allow but the code cannot use. A smoothness σ of 0 would make every
    /// inverse depth rigid (infinite information): the photometric bundle adjustment then takes
    /// no step at all and silently leaves the keyframe or the take-off as it was.
    fn check_ranges(&self, text: &str) -> Result<(), String> {
        // "line N: " where the key is set, if it is.
        let at = |table: &str, key: &str| {
            key_line(text, table, key)
                .map(|l| format!("line {l}: "))
                .unwrap_or_default()
        };
        let positive = [
            (
                "keyframe_bundle",
                "smoothness_rel_std",
                self.keyframe_bundle.smoothness_rel_std,
            ),
            (
                "bootstrap",
                "takeoff_bundle_smoothness_rel_std",
                self.bootstrap.takeoff_bundle_smoothness_rel_std,
            ),
            (
                "bootstrap",
                "rest_accel_bias_std_m_s2",
                self.bootstrap.rest_accel_bias_std_m_s2,
            ),
            (
                "bootstrap",
                "rest_min_tilt_std_rad",
                self.bootstrap.rest_min_tilt_std_rad,
            ),
            (
                "window",
                "map_scale_step_std",
                self.window.map_scale_step_std,
            ),
            (
                "window",
                "map_scale_initial_std",
                self.window.map_scale_initial_std,
            ),
            (
                "window",
                "map_scale_rebuilt_std",
                self.window.map_scale_rebuilt_std,
            ),
            (
                "gyro_alignment",
                "pair_std_rad",
                self.gyro_alignment.pair_std_rad,
            ),
            (
                "gyro_alignment",
                "prior_std_rad",
                self.gyro_alignment.prior_std_rad,
            ),
            (
                "gyro_alignment",
                "bias_prior_std_rad_s",
                self.gyro_alignment.bias_prior_std_rad_s,
            ),
        ];
        for (table, key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!(
                    "{}[{table}] {key} = {v}: must be > 0 (a standard deviation; 0 would \
                     hold what it weights rigid)",
                    at(table, key)
                ));
            }
        }
        let r = self.gyro_alignment.initial_rotation_deg;
        if !r.iter().all(|v| v.is_finite() && v.abs() <= 10.0) {
            return Err(format!(
                "{}[gyro_alignment] initial_rotation_deg = {r:?}: each component must be within \
                 −10 … 10 degrees (a mounting error, not a different mounting: change the \
                 camera extrinsic for that)",
                at("gyro_alignment", "initial_rotation_deg")
            ));
        }
        let (w, l) = (&self.window, &self.loop_closure);
        let pi = std::f64::consts::PI;
        for (table, key, v, max) in [
            ("window", "map_scale_gain", w.map_scale_gain, 1.0),
            ("window", "map_scale_max_step", w.map_scale_max_step, 0.5),
            (
                "window",
                "stored_map_scale_gain",
                w.stored_map_scale_gain,
                1.0,
            ),
            (
                "window",
                "keep_across_rebuild_max_s",
                w.keep_across_rebuild_max_s,
                10.0,
            ),
            ("loop_closure", "confirm_beyond_m", l.confirm_beyond_m, 10.0),
            (
                "loop_closure",
                "confirm_beyond_rad",
                l.confirm_beyond_rad,
                pi,
            ),
            (
                "loop_closure",
                "confirm_tolerance_m",
                l.confirm_tolerance_m,
                10.0,
            ),
            (
                "loop_closure",
                "confirm_tolerance_rad",
                l.confirm_tolerance_rad,
                pi,
            ),
            (
                "loop_closure",
                "confirm_tolerance_share",
                l.confirm_tolerance_share,
                10.0,
            ),
            (
                "loop_closure",
                "confirm_weak_std_factor",
                l.confirm_weak_std_factor,
                100.0,
            ),
        ] {
            if !(v.is_finite() && (0.0..=max).contains(&v)) {
                return Err(format!(
                    "{}[{table}] {key} = {v}: must be within 0 … {max}",
                    at(table, key)
                ));
            }
        }
        Ok(())
    }

    /// The configuration as TOML (every key with its value).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_default()
    }
}

/// The 1-based line of `key` inside `[table]` in TOML `text`, if it is written there.
fn key_line(text: &str, table: &str, key: &str) -> Option<usize> {
    let mut in_table = false;
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.starts_with('[') {
            in_table = l == format!("[{table}]");
        } else if in_table
            && l.split('=')
                .next()
                .is_some_and(|k| k.trim() == key && l.contains('='))
        {
            return Some(i + 1);
        }
    }
    None
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
        // In range for the type, not for the code: named with its line.
        let e = Config::parse(
            "[tracking]\nhuber_gray = 5.0\n\n[keyframe_bundle]\nsmoothness_rel_std = 0.0\n",
        )
        .unwrap_err();
        assert!(
            e.contains("line 5") && e.contains("[keyframe_bundle] smoothness_rel_std"),
            "{e}"
        );
        let e =
            Config::parse("[bootstrap]\ntakeoff_bundle_smoothness_rel_std = -1.0\n").unwrap_err();
        assert!(e.contains("line 2") && e.contains("must be > 0"), "{e}");
        assert!(Config::parse("[keyframe_bundle]\nsmoothness_rel_std = 0.3\n").is_ok());
        let e = Config::parse("[window]\nmap_scale = true\nmap_scale_gain = 1.5\n").unwrap_err();
        assert!(
            e.contains("line 3") && e.contains("[window] map_scale_gain"),
            "{e}"
        );
        let e = Config::parse("[loop_closure]\nenabled = true\nconfirm_weak_std_factor = -3.0\n")
            .unwrap_err();
        assert!(
            e.contains("line 3") && e.contains("[loop_closure] confirm_weak_std_factor"),
            "{e}"
        );
        assert!(Config::parse("[loop_closure]\nconfirm_weak_std_factor = 0.0\n").is_ok());
        let e = Config::parse("[window]\nmap_scale_step_std = 0.0\n").unwrap_err();
        assert!(e.contains("line 2") && e.contains("must be > 0"), "{e}");
        let e = Config::parse("[gyro_alignment]\n\ninitial_rotation_deg = [0.0, 12.0, 0.0]\n")
            .unwrap_err();
        assert!(
            e.contains("line 3") && e.contains("[gyro_alignment] initial_rotation_deg"),
            "{e}"
        );
        let c =
            Config::parse("[gyro_alignment]\ninitial_rotation_deg = [0.3, 0.0, -1.3]\n").unwrap();
        assert_eq!(c.gyro_alignment.initial_rotation_deg, [0.3, 0.0, -1.3]);
    }

    #[test]
    fn shipped_config_file_parses() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/vidslam.toml");
        // The shipped file documents the defaults: it must say exactly what the code does.
        assert_eq!(Config::read(&p).unwrap(), Config::default());
    }
}
