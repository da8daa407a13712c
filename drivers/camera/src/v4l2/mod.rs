//! V4L2 backend: [`V4l2Camera`] turns buffers from any [`V4l2BufferSource`] into frames. The
//! real device source (`device::DeviceSource`, feature `v4l2`) streams mmap buffers from
//! `/dev/videoN`; [`recorded::RecordedSource`] plays back buffers recorded from a driver, which
//! is how the conversion path is tested on machines without V4L2 (no `/dev/video*` here).
//!
//! Timing: V4L2 drivers stamp buffers on the host (`CLOCK_MONOTONIC` when
//! `V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC` is set), so the device stamp already is host time and no
//! clock model is involved. The frame time is the exposure midpoint: stamp + exposure/2 for
//! start-of-exposure stamps (`TSTAMP_SRC_SOE`), stamp − exposure/2 for end-of-frame stamps (an
//! approximation that ignores readout time). Buffers without a monotonic stamp use the host
//! dequeue time as an end-of-frame stamp.

pub mod convert;
#[cfg(feature = "v4l2")]
pub mod device;
pub mod recorded;

use crate::camera::{Camera, CameraError, CameraInfo, StreamStats};
use crate::config::{AppliedConfig, CameraConfig, Exposure};
use crate::frame::{Frame, FrameFlags, FrameMeta, PixelFormat};
use crate::frame_counter::FrameCounter;
use crate::host_clock::monotonic_now_ns;
use crate::pool::FramePool;
use convert::{V4l2Buffer, V4l2Format, convert_buffer};
use std::io;
use std::time::{Duration, Instant};

/// Where V4L2 buffers come from: a real device or a recording of one.
pub trait V4l2BufferSource: Send {
    /// Negotiates size, pixel format and frame rate; returns the format the driver chose and
    /// the frame rate it reports (Hz), if any.
    fn set_format(
        &mut self,
        width_px: u32,
        height_px: u32,
        pixel_format: PixelFormat,
        rate_hz: f64,
    ) -> io::Result<(V4l2Format, Option<f64>)>;
    /// Applies exposure (manual: microseconds) and gain; returns notes on what could not be set.
    fn set_exposure_gain(&mut self, config: &CameraConfig) -> io::Result<Vec<String>>;
    fn start(&mut self) -> io::Result<()>;
    /// Waits up to `timeout` for a filled buffer. `Ok(None)`: timeout. `UnexpectedEof`: a
    /// recording ended. The buffer is requeued at the next call.
    fn dequeue(&mut self, timeout: Duration) -> io::Result<Option<V4l2Buffer<'_>>>;
    fn stop(&mut self) -> io::Result<()>;
    /// Closes and opens the device again after it was lost.
    fn reopen(&mut self) -> io::Result<()>;
    fn info(&self) -> CameraInfo;
}

/// A [`Camera`] over a V4L2 buffer source.
pub struct V4l2Camera<S: V4l2BufferSource> {
    source: S,
    info: CameraInfo,
    config: Option<CameraConfig>,
    format: Option<V4l2Format>,
    pool: Option<FramePool>,
    counter: FrameCounter,
    stats: StreamStats,
    /// Frames lost since the last delivered one (skipped incomplete, pool exhaustion).
    pending_drops: u32,
    streaming: bool,
    lost: bool,
    reconnect_attempts: u32,
}

impl<S: V4l2BufferSource> V4l2Camera<S> {
    pub fn new(source: S) -> Self {
        let info = source.info();
        V4l2Camera {
            source,
            info,
            config: None,
            format: None,
            pool: None,
            counter: FrameCounter::new(32, false),
            stats: StreamStats::default(),
            pending_drops: 0,
            streaming: false,
            lost: false,
            reconnect_attempts: 0,
        }
    }

    fn err(&self, operation: &str, e: io::Error) -> CameraError {
        CameraError::Device {
            device: self.info.device.clone(),
            operation: operation.to_string(),
            reason: e.to_string(),
        }
    }

    fn exposure_us(&self) -> Option<f64> {
        match self.config.as_ref()?.exposure {
            Exposure::Manual { exposure_us } => Some(exposure_us),
            Exposure::Auto { .. } => None,
        }
    }

    fn try_reconnect(&mut self) -> Result<(), CameraError> {
        self.reconnect_attempts += 1;
        let attempt = self.reconnect_attempts;
        let device = self.info.device.clone();
        let reconnecting = |reason: String| CameraError::Reconnecting {
            device: device.clone(),
            attempt,
            reason,
        };
        self.source
            .reopen()
            .map_err(|e| reconnecting(e.to_string()))?;
        if let Some(config) = self.config.clone() {
            self.apply(&config)
                .map_err(|e| reconnecting(e.to_string()))?;
        }
        self.source
            .start()
            .map_err(|e| reconnecting(e.to_string()))?;
        self.lost = false;
        self.stats.reconnects += 1;
        self.counter.reset();
        self.pending_drops = self.pending_drops.saturating_add(1);
        Ok(())
    }

    fn apply(&mut self, config: &CameraConfig) -> Result<AppliedConfig, CameraError> {
        let device = self.info.device.clone();
        config.validate().map_err(|reason| CameraError::Config {
            device: device.clone(),
            reason,
        })?;
        let rate_hz = config.acquisition.rate_hz();
        let (format, applied_rate_hz) = self
            .source
            .set_format(
                config.width_px,
                config.height_px,
                config.pixel_format,
                rate_hz,
            )
            .map_err(|e| self.err("set format", e))?;
        format.validate().map_err(|reason| CameraError::Config {
            device: device.clone(),
            reason,
        })?;
        if format.pixel_format.pixel_format() != config.pixel_format
            || format.width_px != config.width_px
            || format.height_px != config.height_px
        {
            return Err(CameraError::Config {
                device,
                reason: format!(
                    "driver chose {}x{} {:?} instead of {}x{} {}",
                    format.width_px,
                    format.height_px,
                    format.pixel_format,
                    config.width_px,
                    config.height_px,
                    config.pixel_format
                ),
            });
        }
        let mut notes = self
            .source
            .set_exposure_gain(config)
            .map_err(|e| self.err("set exposure", e))?;
        if let crate::config::Acquisition::ExternalTrigger { .. } = config.acquisition {
            notes.push(
                "V4L2 has no standard trigger control; the driver's own trigger setup applies"
                    .into(),
            );
        }
        self.format = Some(format);
        self.pool = Some(FramePool::new(config.pool_frames, config.frame_len_bytes()));
        self.config = Some(config.clone());
        Ok(AppliedConfig {
            width_px: format.width_px,
            height_px: format.height_px,
            pixel_format: config.pixel_format,
            rate_hz: applied_rate_hz,
            exposure_us: self.exposure_us(),
            notes,
        })
    }
}

impl<S: V4l2BufferSource> Camera for V4l2Camera<S> {
    fn configure(&mut self, config: &CameraConfig) -> Result<AppliedConfig, CameraError> {
        if self.streaming {
            return Err(CameraError::Config {
                device: self.info.device.clone(),
                reason: "cannot configure while streaming; stop first".into(),
            });
        }
        self.apply(config)
    }

    fn start(&mut self) -> Result<(), CameraError> {
        if self.format.is_none() {
            return Err(CameraError::Config {
                device: self.info.device.clone(),
                reason: "start before configure".into(),
            });
        }
        if !self.streaming {
            self.source
                .start()
                .map_err(|e| self.err("start streaming", e))?;
            self.streaming = true;
            self.counter.reset();
        }
        Ok(())
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<Frame, CameraError> {
        let device = self.info.device.clone();
        if !self.streaming {
            return Err(CameraError::Config {
                device,
                reason: "next_frame while stopped".into(),
            });
        }
        if self.lost {
            self.try_reconnect()?;
        }
        let deadline = Instant::now() + timeout;
        let (Some(format), Some(pool)) = (self.format, self.pool.clone()) else {
            return Err(CameraError::Config {
                device,
                reason: "not configured".into(),
            });
        };
        let exposure_us = self.exposure_us();
        let deliver_incomplete = self.config.as_ref().is_some_and(|c| c.deliver_incomplete);
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            let buf = match self.source.dequeue(remaining) {
                Ok(Some(buf)) => buf,
                Ok(None) => {
                    return Err(CameraError::Timeout {
                        device,
                        waited_ms: timeout.as_millis() as u64,
                    });
                }
                Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => {
                    return Err(CameraError::EndOfStream {
                        device,
                        frames: self.stats.delivered,
                    });
                }
                Err(e)
                    if e.raw_os_error() == Some(libc::ENODEV)
                        || e.raw_os_error() == Some(libc::EIO) =>
                {
                    self.lost = true;
                    self.stats.lost += 1;
                    return Err(CameraError::Lost {
                        device,
                        reason: e.to_string(),
                    });
                }
                Err(e) => return Err(self.err("dequeue buffer", e)),
            };
            let host_receive_ns = monotonic_now_ns();
            let (frame_id, missing) = self.counter.next(buf.sequence as u64);
            self.stats.missing += missing;
            self.pending_drops = self.pending_drops.saturating_add(missing as u32);
            let (stamp_ns, at_start) = if buf.timestamp_is_monotonic() {
                (buf.timestamp_ns, buf.stamped_at_start_of_exposure())
            } else {
                (host_receive_ns, false)
            };
            let Some(mut out) = pool.take() else {
                self.stats.pool_exhausted += 1;
                self.pending_drops = self.pending_drops.saturating_add(1);
                continue;
            };
            let incomplete = match convert_buffer(&format, &buf, out.as_mut_slice()) {
                Ok(()) => false,
                Err(_) if !deliver_incomplete => {
                    self.stats.incomplete += 1;
                    self.pending_drops = self.pending_drops.saturating_add(1);
                    continue;
                }
                Err(_) => {
                    self.stats.incomplete += 1;
                    true
                }
            };
            let half_exposure_ns = exposure_us.map_or(0, |e| (e * 500.0).round() as i64);
            let frame_time_ns = if at_start {
                stamp_ns + half_exposure_ns
            } else {
                stamp_ns - half_exposure_ns
            };
            let meta = FrameMeta {
                frame_id,
                width_px: format.width_px,
                height_px: format.height_px,
                pixel_format: format.pixel_format.pixel_format(),
                device_ns: stamp_ns,
                host_receive_ns,
                exposure_us,
                frame_time_ns: Some(frame_time_ns),
                flags: FrameFlags {
                    incomplete,
                    dropped_before: std::mem::take(&mut self.pending_drops),
                },
            };
            self.stats.delivered += 1;
            return Ok(Frame::new(meta, out));
        }
    }

    fn stop(&mut self) -> Result<(), CameraError> {
        if self.streaming {
            self.streaming = false;
            self.source
                .stop()
                .map_err(|e| self.err("stop streaming", e))?;
        }
        Ok(())
    }

    fn stats(&self) -> StreamStats {
        self.stats
    }

    fn info(&self) -> &CameraInfo {
        &self.info
    }
}
