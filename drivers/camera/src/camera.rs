//! The `Camera` trait every backend implements, its error type and its counters.

use crate::config::{AppliedConfig, CameraConfig};
use crate::frame::Frame;
use std::path::PathBuf;
use std::time::Duration;

/// A frame source: configure, start, pull frames, stop.
///
/// Call order: [`Camera::configure`] (while stopped), [`Camera::start`], then
/// [`Camera::next_frame`] repeatedly, [`Camera::stop`]. `start` after `stop` resumes with the
/// same configuration. Frames are lent from a pool sized by `CameraConfig::pool_frames`: holding
/// all of them makes the driver drop (and count) new frames.
pub trait Camera: Send {
    /// Applies a configuration; the camera must be stopped.
    fn configure(&mut self, config: &CameraConfig) -> Result<AppliedConfig, CameraError>;
    /// Starts acquisition.
    fn start(&mut self) -> Result<(), CameraError>;
    /// Waits up to `timeout` for the next good frame.
    ///
    /// Errors: [`CameraError::Timeout`] (no frame in time, still streaming), [`CameraError::Lost`]
    /// (the device went away; later calls try to reopen it and return
    /// [`CameraError::Reconnecting`] until it is back), [`CameraError::EndOfStream`] (replay).
    fn next_frame(&mut self, timeout: Duration) -> Result<Frame, CameraError>;
    /// Stops acquisition; idempotent.
    fn stop(&mut self) -> Result<(), CameraError>;
    /// Counters since the camera was opened.
    fn stats(&self) -> StreamStats;
    /// Static description of the device.
    fn info(&self) -> &CameraInfo;
}

/// Counters since the camera was opened.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StreamStats {
    /// Frames handed to the consumer.
    pub delivered: u64,
    /// Buffers that arrived incomplete (missing packets, short buffer, bad status).
    pub incomplete: u64,
    /// Frames the device counted but we never received (frame-id gaps).
    pub missing: u64,
    /// Frames dropped because the consumer held every pool buffer.
    pub pool_exhausted: u64,
    /// Times the device was lost.
    pub lost: u64,
    /// Successful reopens after a loss.
    pub reconnects: u64,
}

impl StreamStats {
    /// Every frame that did not reach the consumer as a good frame.
    pub fn dropped_total(&self) -> u64 {
        self.incomplete + self.missing + self.pool_exhausted
    }
}

/// Static description of a device.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CameraInfo {
    /// The device name as given to [`crate::open`].
    pub device: String,
    pub vendor: String,
    pub model: String,
    pub serial: String,
    /// Transport or backend: `GigEVision`, `USB3Vision`, `Fake`, `V4L2`, `replay`.
    pub protocol: String,
    /// Pixel formats the device offers (device names).
    pub pixel_formats: Vec<String>,
    /// `(name, value)` of notable device features (size bounds, rate, exposure, trigger...).
    pub features: Vec<(String, String)>,
}

/// Errors of every backend; each names the device (or file) and what happened.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    #[error("{device}: no frame within {waited_ms} ms")]
    Timeout { device: String, waited_ms: u64 },
    #[error("{device}: device lost ({reason}); reconnecting")]
    Lost { device: String, reason: String },
    #[error("{device}: reconnecting (attempt {attempt}: {reason})")]
    Reconnecting {
        device: String,
        attempt: u32,
        reason: String,
    },
    #[error("{device}: end of stream after {frames} frames")]
    EndOfStream { device: String, frames: u64 },
    #[error("{device}: cannot open: {reason}")]
    Open { device: String, reason: String },
    #[error("{device}: invalid configuration: {reason}")]
    Config { device: String, reason: String },
    #[error("{device}: {operation} failed: {reason}")]
    Device {
        device: String,
        operation: String,
        reason: String,
    },
    #[error("{device}: {reason}")]
    Unsupported { device: String, reason: String },
    #[error("{path}:{line}: {msg}")]
    Parse {
        path: PathBuf,
        line: usize,
        msg: String,
    },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

impl CameraError {
    /// True for errors after which `next_frame` may succeed again (timeouts, loss, reconnect).
    pub fn is_transient(&self) -> bool {
        matches!(
            self,
            CameraError::Timeout { .. }
                | CameraError::Lost { .. }
                | CameraError::Reconnecting { .. }
        )
    }
}
