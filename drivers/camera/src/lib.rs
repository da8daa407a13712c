//! Camera drivers for vidslam: the visual half of the sensor head (a global-shutter 752x480
//! mono camera at 20–30 Hz, free-running or triggered by the IMU).
//!
//! * [`Camera`]: the small trait the daemon uses — configure, start, next frame with a timeout,
//!   stop. Frames ([`Frame`]) come in pooled buffers ([`FramePool`], no allocation per frame)
//!   with the device timestamp, host receive time, frame id, exposure and [`FrameFlags`].
//! * Backends: Aravis (feature `aravis`: GigE/USB3 Vision and Aravis's fake cameras), V4L2
//!   (feature `v4l2` for the device; buffer conversion is always built and tested with recorded
//!   buffers), and [`ReplayCamera`] (ASL/EuRoC `cam0` folders and our recordings).
//! * [`Recorder`]: lossless ASL-layout recording with a `frames.csv` of timing.
//!
//! # Time
//! All times are `i64` nanoseconds. The frame time ([`FrameMeta::frame_time_ns`]) is the
//! **exposure midpoint on the host `CLOCK_MONOTONIC` clock**: device timestamps are mapped with
//! the shared clock model of `vidslam-timesync` (see [`timing`]), then shifted by half the
//! exposure according to [`TimestampLatch`]. In external-trigger mode the same holds: the
//! exposure starts at the trigger edge, so the midpoint is trigger + exposure/2.
//!
//! Device names: see [`device`]. The default build needs no system C library.

pub mod asl;
pub mod camera;
pub mod config;
pub mod device;
pub mod frame;
pub mod frame_counter;
pub mod host_clock;
pub mod png_io;
pub mod pool;
pub mod record;
pub mod replay;
pub mod timing;
pub mod v4l2;

#[cfg(feature = "aravis")]
pub mod aravis_backend;

pub use camera::{Camera, CameraError, CameraInfo, StreamStats};
pub use config::{Acquisition, AppliedConfig, CameraConfig, Exposure, Gain, TimestampLatch};
pub use device::{DeviceName, ListedDevice, list, open};
pub use frame::{Frame, FrameFlags, FrameMeta, PixelFormat};
pub use pool::{FramePool, PooledBuffer};
pub use record::Recorder;
pub use replay::{Pacing, ReplayCamera};
