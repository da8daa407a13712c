//! What the daemon asks of a camera, and what the device actually applied.

use crate::frame::PixelFormat;

/// How exposures are started.
#[derive(Clone, Debug, PartialEq)]
pub enum Acquisition {
    /// The camera runs on its own clock at this rate.
    FreeRunning { rate_hz: f64 },
    /// Each exposure starts on an edge of a trigger input (the IMU's sync output or a GPIO
    /// strobe). `source` is the device's name for the input (GenICam `TriggerSource`, e.g.
    /// `Line0`, `Line1`, or `Software`). `expected_rate_hz` only sizes timeouts and drop
    /// detection.
    ExternalTrigger {
        source: String,
        expected_rate_hz: f64,
    },
}

impl Acquisition {
    /// The nominal frame rate, Hz.
    pub fn rate_hz(&self) -> f64 {
        match self {
            Acquisition::FreeRunning { rate_hz } => *rate_hz,
            Acquisition::ExternalTrigger {
                expected_rate_hz, ..
            } => *expected_rate_hz,
        }
    }
}

/// Exposure control.
#[derive(Clone, Debug, PartialEq)]
pub enum Exposure {
    /// Fixed exposure time, microseconds.
    Manual { exposure_us: f64 },
    /// Device auto-exposure, kept within `[min_us, max_us]` where the device exposes the limits
    /// (SFNC `AutoExposureTimeLowerLimit`/`UpperLimit`, or `ExposureAutoMin`/`Max`).
    Auto { min_us: f64, max_us: f64 },
}

/// Analog gain control, in the device's gain unit (dB on SFNC `Gain`, raw counts on `GainRaw`).
#[derive(Clone, Debug, PartialEq)]
pub enum Gain {
    Manual { gain: f64 },
    Auto,
}

/// Which instant of the exposure the device's timestamp refers to. The frame time handed to
/// SLAM is always the exposure midpoint: `latch + exposure/2` for [`TimestampLatch::ExposureStart`],
/// `latch - exposure/2` for [`TimestampLatch::ExposureEnd`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TimestampLatch {
    /// GigE Vision / USB3 Vision cameras latch the timestamp at the frame start trigger, i.e.
    /// the start of exposure (SFNC `Timestamp`), which is also where V4L2 drivers that set
    /// `V4L2_BUF_FLAG_TSTAMP_SRC_SOE` stamp.
    #[default]
    ExposureStart,
    /// Drivers that stamp at end of frame (`V4L2_BUF_FLAG_TSTAMP_SRC_EOF`) and Aravis's fake
    /// cameras, which stamp when the buffer is filled.
    ExposureEnd,
}

/// A full camera configuration.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraConfig {
    pub width_px: u32,
    pub height_px: u32,
    pub pixel_format: PixelFormat,
    pub acquisition: Acquisition,
    pub exposure: Exposure,
    pub gain: Gain,
    pub timestamp_latch: TimestampLatch,
    /// Known minimum delay from the end of exposure to the host receiving the frame (readout +
    /// transfer), ns; subtracted from clock-model frame times (see [`crate::timing`]). 0 leaves
    /// that constant offset to the camera–IMU time-offset calibration.
    pub transfer_latency_ns: i64,
    /// Frames the driver can lend to the consumer at once (pool size).
    pub pool_frames: usize,
    /// Hand on incomplete frames (flagged) instead of counting and skipping them.
    pub deliver_incomplete: bool,
}

impl Default for CameraConfig {
    /// The paper's sensor: 752x480 Mono8 at 20 Hz, 5 ms manual exposure, gain 0.
    fn default() -> Self {
        CameraConfig {
            width_px: 752,
            height_px: 480,
            pixel_format: PixelFormat::Mono8,
            acquisition: Acquisition::FreeRunning { rate_hz: 20.0 },
            exposure: Exposure::Manual {
                exposure_us: 5000.0,
            },
            gain: Gain::Manual { gain: 0.0 },
            timestamp_latch: TimestampLatch::ExposureStart,
            transfer_latency_ns: 0,
            pool_frames: 8,
            deliver_incomplete: false,
        }
    }
}

impl CameraConfig {
    /// Bytes of one tightly packed frame.
    pub fn frame_len_bytes(&self) -> usize {
        self.width_px as usize * self.height_px as usize * self.pixel_format.bytes_per_pixel()
    }

    /// Rejects configurations no backend can honour.
    pub fn validate(&self) -> Result<(), String> {
        if self.width_px == 0 || self.height_px == 0 {
            return Err(format!(
                "image size {}x{} px is empty",
                self.width_px, self.height_px
            ));
        }
        let rate_hz = self.acquisition.rate_hz();
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            return Err(format!("frame rate {rate_hz} Hz must be positive"));
        }
        match self.exposure {
            Exposure::Manual { exposure_us } if !(exposure_us.is_finite() && exposure_us > 0.0) => {
                return Err(format!("exposure {exposure_us} us must be positive"));
            }
            Exposure::Auto { min_us, max_us } if !(min_us > 0.0 && max_us >= min_us) => {
                return Err(format!(
                    "auto-exposure limits [{min_us}, {max_us}] us are not a range"
                ));
            }
            _ => {}
        }
        if self.transfer_latency_ns < 0 {
            return Err(format!(
                "transfer latency {} ns must not be negative",
                self.transfer_latency_ns
            ));
        }
        if self.pool_frames < 2 {
            return Err(format!(
                "pool of {} frames is too small (need >= 2)",
                self.pool_frames
            ));
        }
        Ok(())
    }
}

/// The configuration as the device accepted it (devices round sizes and clamp rates).
#[derive(Clone, Debug, PartialEq)]
pub struct AppliedConfig {
    pub width_px: u32,
    pub height_px: u32,
    pub pixel_format: PixelFormat,
    /// Rate the device reports after configuration, Hz (`None` if it cannot say).
    pub rate_hz: Option<f64>,
    /// Exposure the device reports, microseconds (`None` if it cannot say).
    pub exposure_us: Option<f64>,
    /// Human-readable notes on requests that were clamped or not supported by this device.
    pub notes: Vec<String>,
}
