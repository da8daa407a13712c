//! A [`V4l2BufferSource`] that plays back buffers captured from a V4L2 driver (bytes exactly as
//! mapped, with `bytesused`, `sequence`, timestamp and flags), through the same path as a
//! device. Used to test conversion, gap counting and timing where no `/dev/video*` exists.

use super::V4l2BufferSource;
use super::convert::{V4l2Buffer, V4l2Format};
use crate::camera::CameraInfo;
use crate::config::CameraConfig;
use crate::frame::PixelFormat;
use std::io;
use std::time::Duration;

/// One captured `struct v4l2_buffer` and its mapped bytes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RecordedBuffer {
    pub data: Vec<u8>,
    pub bytes_used: u32,
    pub sequence: u32,
    pub timestamp_ns: i64,
    pub flags: u32,
}

/// Plays back recorded buffers once, then reports end of stream.
#[derive(Clone, Debug)]
pub struct RecordedSource {
    name: String,
    format: V4l2Format,
    buffers: Vec<RecordedBuffer>,
    next: usize,
    streaming: bool,
}

impl RecordedSource {
    /// `format` is the format the driver had negotiated when the buffers were captured.
    pub fn new(name: &str, format: V4l2Format, buffers: Vec<RecordedBuffer>) -> Self {
        RecordedSource {
            name: name.to_string(),
            format,
            buffers,
            next: 0,
            streaming: false,
        }
    }
}

impl V4l2BufferSource for RecordedSource {
    fn set_format(
        &mut self,
        width_px: u32,
        height_px: u32,
        pixel_format: PixelFormat,
        _rate_hz: f64,
    ) -> io::Result<(V4l2Format, Option<f64>)> {
        // Like a driver, answer with the format we have; the camera checks it matches.
        let _ = (width_px, height_px, pixel_format);
        Ok((self.format, None))
    }

    fn set_exposure_gain(&mut self, _config: &CameraConfig) -> io::Result<Vec<String>> {
        Ok(vec![
            "recorded buffers: exposure and gain are those of the recording".into(),
        ])
    }

    fn start(&mut self) -> io::Result<()> {
        self.streaming = true;
        Ok(())
    }

    fn dequeue(&mut self, _timeout: Duration) -> io::Result<Option<V4l2Buffer<'_>>> {
        if !self.streaming {
            return Err(io::Error::other("dequeue while not streaming"));
        }
        let Some(b) = self.buffers.get(self.next) else {
            return Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                "recording ended",
            ));
        };
        self.next += 1;
        Ok(Some(V4l2Buffer {
            data: &b.data,
            bytes_used: b.bytes_used,
            sequence: b.sequence,
            timestamp_ns: b.timestamp_ns,
            flags: b.flags,
        }))
    }

    fn stop(&mut self) -> io::Result<()> {
        self.streaming = false;
        Ok(())
    }

    fn reopen(&mut self) -> io::Result<()> {
        Ok(())
    }

    fn info(&self) -> CameraInfo {
        CameraInfo {
            device: self.name.clone(),
            vendor: "recording".into(),
            model: "V4L2 buffers".into(),
            protocol: "V4L2".into(),
            pixel_formats: vec![format!("{:?}", self.format.pixel_format)],
            ..CameraInfo::default()
        }
    }
}
