//! Sensor time synchronisation shared by the vidslam drivers (IMU, camera).
//!
//! * [`ClockModel`]: maps a device clock to the host monotonic clock (offset + skew) from pairs
//!   (device timestamp, host receive time). Receive times are the true times plus a non-negative,
//!   heavy-tailed transport delay (USB, serial, kernel scheduling), so a least-squares fit would be
//!   biased by the mean delay; the model instead fits the *lower envelope* of the observations over
//!   a sliding window (the convex-hull estimator of TICSync, Harrison & Newman, ICRA 2011), which
//!   converges to the minimum-delay line.
//! * [`TickUnwrapper`]: turns a wrapping `u32` hardware tick counter into monotonic nanoseconds.
//!
//! All times are `i64` nanoseconds; the host clock is whatever monotonic clock the caller samples
//! (`CLOCK_MONOTONIC` in the daemon).

mod clock_model;
mod tick_unwrapper;

pub use clock_model::{ClockModel, ClockModelConfig};
pub use tick_unwrapper::TickUnwrapper;
