//! Frames as the daemon sees them: tightly packed pixels in a pooled buffer plus timing metadata.

use crate::pool::PooledBuffer;
use std::fmt;
use std::str::FromStr;

/// Monochrome pixel formats the SLAM front end consumes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PixelFormat {
    /// 8 bits per pixel.
    Mono8,
    /// 16 bits per pixel, stored little-endian in [`Frame::pixels`]; sensors with fewer bits
    /// (10/12) are MSB-aligned as GenICam `Mono16` and V4L2 `Y16` define it.
    Mono16,
}

impl PixelFormat {
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Mono8 => 1,
            PixelFormat::Mono16 => 2,
        }
    }
}

impl fmt::Display for PixelFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            PixelFormat::Mono8 => "Mono8",
            PixelFormat::Mono16 => "Mono16",
        })
    }
}

impl FromStr for PixelFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "mono8" | "grey" | "gray8" => Ok(PixelFormat::Mono8),
            "mono16" | "y16" | "gray16" => Ok(PixelFormat::Mono16),
            _ => Err(format!(
                "unknown pixel format {s:?} (expected Mono8 or Mono16)"
            )),
        }
    }
}

/// Per-frame condition flags.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameFlags {
    /// Some of the frame's data never arrived (missing packets, short V4L2 buffer). Only set on
    /// frames delivered because the configuration asked for incomplete frames; by default they
    /// are counted and skipped.
    pub incomplete: bool,
    /// How many frames were lost between the previous delivered frame and this one (device frame
    /// counter gaps, skipped incomplete frames, pool exhaustion, a reconnect). 0 = contiguous.
    pub dropped_before: u32,
}

impl FrameFlags {
    /// Compact text form used in `frames.csv`: `ok`, or `incomplete` and/or `dropped=N`
    /// joined by `|`.
    pub fn to_field(self) -> String {
        let mut parts = Vec::new();
        if self.incomplete {
            parts.push("incomplete".to_string());
        }
        if self.dropped_before > 0 {
            parts.push(format!("dropped={}", self.dropped_before));
        }
        if parts.is_empty() {
            "ok".to_string()
        } else {
            parts.join("|")
        }
    }

    /// Inverse of [`FrameFlags::to_field`].
    pub fn parse_field(s: &str) -> Option<Self> {
        let mut flags = FrameFlags::default();
        for part in s.trim().split('|') {
            match part {
                "ok" => {}
                "incomplete" => flags.incomplete = true,
                p => flags.dropped_before = p.strip_prefix("dropped=")?.parse().ok()?,
            }
        }
        Some(flags)
    }
}

/// Everything known about one frame except its pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameMeta {
    /// Device frame counter, unwrapped to 64 bits (GigE Vision block ids are 16 bits, V4L2
    /// sequence numbers 32 bits). Replay: index in the recording.
    pub frame_id: u64,
    pub width_px: u32,
    pub height_px: u32,
    pub pixel_format: PixelFormat,
    /// Timestamp on the device clock, as the device latched it (see
    /// [`crate::TimestampLatch`]). Replay: the dataset timestamp.
    pub device_ns: i64,
    /// Host `CLOCK_MONOTONIC` time at which the frame finished arriving. Replay: as recorded
    /// (the dataset timestamp for plain ASL folders).
    pub host_receive_ns: i64,
    /// Exposure time used, microseconds, when known.
    pub exposure_us: Option<f64>,
    /// **The frame time**: the middle of the exposure, on the host monotonic clock (device time
    /// mapped through the clock model, shifted by half the exposure according to the latch).
    /// `None` until the clock model has enough observations. Replay: the dataset timestamp
    /// (ASL/EuRoC stamps are already mid-exposure on the dataset clock).
    pub frame_time_ns: Option<i64>,
    pub flags: FrameFlags,
}

/// One image in a pooled buffer. Rows are tightly packed (`stride = width * bytes_per_pixel`);
/// Mono16 samples are little-endian. Dropping the frame returns its buffer to the pool.
#[derive(Debug)]
pub struct Frame {
    pub meta: FrameMeta,
    buffer: PooledBuffer,
}

impl Frame {
    /// Wraps a filled pool buffer; its length must be `width * height * bytes_per_pixel`.
    pub fn new(meta: FrameMeta, buffer: PooledBuffer) -> Self {
        debug_assert_eq!(
            buffer.as_slice().len(),
            meta.width_px as usize * meta.height_px as usize * meta.pixel_format.bytes_per_pixel()
        );
        Frame { meta, buffer }
    }

    /// Row stride, bytes.
    pub fn stride_bytes(&self) -> usize {
        self.meta.width_px as usize * self.meta.pixel_format.bytes_per_pixel()
    }

    /// All pixels, row-major, tightly packed.
    pub fn pixels(&self) -> &[u8] {
        self.buffer.as_slice()
    }

    /// Row `y` (panics if out of range).
    pub fn row(&self, y: u32) -> &[u8] {
        let s = self.stride_bytes();
        &self.pixels()[y as usize * s..(y as usize + 1) * s]
    }

    /// Pixel value at (x, y) widened to u16 (Mono8 values are 0..=255).
    pub fn value_at(&self, x: u32, y: u32) -> u16 {
        let row = self.row(y);
        match self.meta.pixel_format {
            PixelFormat::Mono8 => row[x as usize] as u16,
            PixelFormat::Mono16 => {
                u16::from_le_bytes([row[2 * x as usize], row[2 * x as usize + 1]])
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_field_round_trips() {
        for f in [
            FrameFlags::default(),
            FrameFlags {
                incomplete: true,
                dropped_before: 0,
            },
            FrameFlags {
                incomplete: false,
                dropped_before: 7,
            },
            FrameFlags {
                incomplete: true,
                dropped_before: 2,
            },
        ] {
            assert_eq!(
                FrameFlags::parse_field(&f.to_field()),
                Some(f),
                "{}",
                f.to_field()
            );
        }
        assert_eq!(FrameFlags::parse_field("dropped=x"), None);
    }
}
