//! Pose output to the flight controller: MAVLink 2 ODOMETRY (#331) over UDP, with HEARTBEAT and
//! TIMESYNC, for PX4 and ArduPilot (or VISION_POSITION_ESTIMATE + VISION_SPEED_ESTIMATE for older
//! ArduPilot setups). Independent of the SLAM core: it streams any [`OdometrySample`]s.
//!
//! Use: build a [`SenderConfig`] (defaults via [`SenderConfig::new`]), [`MavlinkSender::start`]
//! it, [`MavlinkSender::push`] one [`OdometrySample`] per estimator output from the tracking
//! thread (never blocks), and [`MavlinkSender::finish`] at the end.
//!
//! * [`frames`]: world/body to FC frame conversions (with the drawing).
//! * [`sample`]: the input type.
//! * [`odometry`]: message construction (pure).
//! * [`heartbeat`]: MAV_STATE from tracking health.
//! * [`timesync`]: TIMESYNC replies and the FC clock estimate; why `time_usec` is in our clock.
//! * [`endpoint`]: `udpout:HOST:PORT` / `udpin:HOST:PORT`.
//! * [`link`]: one UDP socket, MAVLink 2 framing by the `mavlink` crate.
//! * [`sender`]: the queue and the threads.

pub mod endpoint;
pub mod frames;
pub mod heartbeat;
pub mod link;
pub mod odometry;
pub mod sample;
pub mod sender;
pub mod timesync;

pub use endpoint::{Endpoint, EndpointError};
pub use frames::{FcFrames, PoseCovariance};
pub use odometry::{CovarianceFallback, LocalFrame, MessageConfig, MessageSet};
pub use sample::{OdometrySample, TrackingHealth};
pub use sender::{MavlinkSender, SenderConfig, SenderStats, TimeBase};

/// Why the sender could not start.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error(transparent)]
    Endpoint(#[from] EndpointError),
    #[error("endpoint '{endpoint}': {what}: {source}")]
    Io {
        endpoint: String,
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("invalid MAVLink sender configuration: {0}")]
    Config(String),
}
