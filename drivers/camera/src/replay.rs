//! Replay backend: frames from an ASL/EuRoC `cam0` folder or from one of our recordings,
//! either paced in real time (frame i is released `t_i - t_0` after `start`) or as fast as the
//! consumer pulls them. What the HIL tests and `vidslam replay` use.
//!
//! Frame metadata: `frame_time_ns` is the dataset timestamp (ASL/EuRoC stamps are mid-exposure
//! on the dataset clock). For our recordings every field comes back as recorded (`frames.csv`:
//! device time, host receive time, exposure, frame id, flags), so record → replay is the
//! identity; for other ASL folders `device_ns` = `host_receive_ns` = dataset timestamp and
//! `frame_id` = row index. An image that cannot be decoded is counted (`StreamStats::incomplete`), skipped
//! and reported on the next frame's `dropped_before`.

use crate::asl::{CamEntry, find_cam0, read_cam0};
use crate::camera::{Camera, CameraError, CameraInfo, StreamStats};
use crate::config::{AppliedConfig, CameraConfig};
use crate::frame::{Frame, FrameFlags, FrameMeta, PixelFormat};
use crate::png_io;
use crate::pool::FramePool;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How fast a replay releases frames.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Pacing {
    /// At the recorded rate, relative to `start`.
    RealTime,
    /// Each `next_frame` returns the next frame at once.
    #[default]
    AsFastAsConsumed,
}

/// A [`Camera`] replaying a `cam0` folder.
pub struct ReplayCamera {
    cam0: PathBuf,
    entries: Vec<CamEntry>,
    pacing: Pacing,
    info: CameraInfo,
    width_px: u32,
    height_px: u32,
    format: PixelFormat,
    pool: Option<FramePool>,
    next: usize,
    started_at: Option<Instant>,
    stats: StreamStats,
    pending_drops: u32,
}

impl ReplayCamera {
    /// Opens a dataset root, its `mav0/`, a `cam0/` folder or one of our recordings. The image
    /// size and format are taken from the first image.
    pub fn open(path: &Path, pacing: Pacing) -> Result<Self, CameraError> {
        let device = format!("replay:{}", path.display());
        let cam0 = find_cam0(path)?;
        let entries = read_cam0(&cam0)?;
        let first = entries.first().ok_or_else(|| CameraError::Open {
            device: device.clone(),
            reason: format!("{} lists no images", cam0.join("data.csv").display()),
        })?;
        let (width_px, height_px, format) =
            png_io::read_header(&first.image).map_err(|reason| CameraError::Open {
                device: device.clone(),
                reason: format!("{}: {reason}", first.image.display()),
            })?;
        let t0 = first.t_ns;
        let t1 = entries.last().map_or(t0, |e| e.t_ns);
        let rate_hz = if entries.len() > 1 {
            (entries.len() - 1) as f64 / ((t1 - t0) as f64 * 1e-9)
        } else {
            0.0
        };
        let info = CameraInfo {
            device,
            vendor: "replay".into(),
            model: if entries.iter().any(|e| e.recorded.is_some()) {
                "vidslam recording".into()
            } else {
                "ASL/EuRoC cam0".into()
            },
            serial: cam0.display().to_string(),
            protocol: "replay".into(),
            pixel_formats: vec![format.to_string()],
            features: vec![
                ("Width".into(), width_px.to_string()),
                ("Height".into(), height_px.to_string()),
                ("Frames".into(), entries.len().to_string()),
                ("MeanRate_hz".into(), format!("{rate_hz:.3}")),
                (
                    "Duration_s".into(),
                    format!("{:.3}", (t1 - t0) as f64 * 1e-9),
                ),
            ],
        };
        Ok(ReplayCamera {
            cam0,
            entries,
            pacing,
            info,
            width_px,
            height_px,
            format,
            pool: None,
            next: 0,
            started_at: None,
            stats: StreamStats::default(),
            pending_drops: 0,
        })
    }

    /// The `cam0` folder being replayed.
    pub fn cam0(&self) -> &Path {
        &self.cam0
    }

    /// Number of images listed.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    fn device(&self) -> String {
        self.info.device.clone()
    }
}

impl Camera for ReplayCamera {
    /// Replay delivers the recording's own size and format; differences from the request are
    /// reported in the notes. Only the pool size is taken from the configuration.
    fn configure(&mut self, config: &CameraConfig) -> Result<AppliedConfig, CameraError> {
        if config.pool_frames < 2 {
            return Err(CameraError::Config {
                device: self.device(),
                reason: "pool_frames must be >= 2".into(),
            });
        }
        let mut notes = Vec::new();
        if (config.width_px, config.height_px, config.pixel_format)
            != (self.width_px, self.height_px, self.format)
        {
            notes.push(format!(
                "replay delivers the recording's {}x{} {} (requested {}x{} {})",
                self.width_px,
                self.height_px,
                self.format,
                config.width_px,
                config.height_px,
                config.pixel_format
            ));
        }
        let len = self.width_px as usize * self.height_px as usize * self.format.bytes_per_pixel();
        self.pool = Some(FramePool::new(config.pool_frames, len));
        Ok(AppliedConfig {
            width_px: self.width_px,
            height_px: self.height_px,
            pixel_format: self.format,
            rate_hz: None,
            exposure_us: None,
            notes,
        })
    }

    fn start(&mut self) -> Result<(), CameraError> {
        if self.pool.is_none() {
            self.configure(&CameraConfig {
                width_px: self.width_px,
                height_px: self.height_px,
                pixel_format: self.format,
                ..CameraConfig::default()
            })?;
        }
        // Real-time pacing restarts from the current position.
        let offset_ns = self.entries.get(self.next).map_or(0, |e| e.t_ns)
            - self.entries.first().map_or(0, |e| e.t_ns);
        self.started_at = Some(Instant::now() - Duration::from_nanos(offset_ns.max(0) as u64));
        Ok(())
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<Frame, CameraError> {
        let Some(started_at) = self.started_at else {
            return Err(CameraError::Config {
                device: self.device(),
                reason: "next_frame while stopped".into(),
            });
        };
        let pool = self.pool.clone().expect("start configures the pool");
        loop {
            let Some(entry) = self.entries.get(self.next) else {
                return Err(CameraError::EndOfStream {
                    device: self.device(),
                    frames: self.stats.delivered,
                });
            };
            if self.pacing == Pacing::RealTime {
                let due =
                    started_at + Duration::from_nanos((entry.t_ns - self.entries[0].t_ns) as u64);
                let now = Instant::now();
                if due > now {
                    if due - now > timeout {
                        std::thread::sleep(timeout);
                        return Err(CameraError::Timeout {
                            device: self.device(),
                            waited_ms: timeout.as_millis() as u64,
                        });
                    }
                    std::thread::sleep(due - now);
                }
            }
            let Some(mut buf) = pool.take() else {
                // The consumer holds every buffer: in real time the frame is lost, as from a
                // camera; as-fast-as-consumed waits for the consumer instead.
                if self.pacing == Pacing::RealTime {
                    self.stats.pool_exhausted += 1;
                    self.pending_drops += 1;
                    self.next += 1;
                    continue;
                }
                return Err(CameraError::Timeout {
                    device: self.device(),
                    waited_ms: 0,
                });
            };
            let entry = entry.clone();
            self.next += 1;
            if let Err(reason) = png_io::decode_into(
                &entry.image,
                self.width_px,
                self.height_px,
                self.format,
                buf.as_mut_slice(),
            ) {
                // Counted and skipped; the consumer sees the gap in `dropped_before`.
                self.stats.incomplete += 1;
                self.pending_drops += 1;
                eprintln!(
                    "warning: {}: {}: {reason}; frame skipped",
                    self.info.device,
                    entry.image.display()
                );
                continue;
            }
            let rec = entry.recorded;
            let mut flags = rec.map_or(FrameFlags::default(), |r| r.flags);
            flags.dropped_before += std::mem::take(&mut self.pending_drops);
            let meta = FrameMeta {
                frame_id: rec.map_or((self.next - 1) as u64, |r| r.frame_id),
                width_px: self.width_px,
                height_px: self.height_px,
                pixel_format: self.format,
                device_ns: rec.map_or(entry.t_ns, |r| r.device_ns),
                host_receive_ns: rec.map_or(entry.t_ns, |r| r.host_receive_ns),
                exposure_us: rec.and_then(|r| r.exposure_us),
                frame_time_ns: Some(entry.t_ns),
                flags,
            };
            self.stats.delivered += 1;
            return Ok(Frame::new(meta, buf));
        }
    }

    fn stop(&mut self) -> Result<(), CameraError> {
        self.started_at = None;
        Ok(())
    }

    fn stats(&self) -> StreamStats {
        self.stats
    }

    fn info(&self) -> &CameraInfo {
        &self.info
    }
}
