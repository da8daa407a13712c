//! The real V4L2 device: `/dev/videoN` through the `v4l` crate, mmap streaming, `GREY`/`Y16`.
//! (This machine has no V4L2 support; the code compiles and shares everything after `dequeue`
//! with the recorded-buffer tests.)

use super::V4l2BufferSource;
use super::convert::{V4l2Buffer, V4l2Format, V4l2PixelFormat};
use crate::camera::CameraInfo;
use crate::config::{CameraConfig, Exposure, Gain};
use crate::frame::PixelFormat;
use std::io;
use std::path::{Path, PathBuf};
use std::time::Duration;
use v4l::buffer::Type;
use v4l::control::{Control, Value};
use v4l::io::mmap::Stream;
use v4l::io::traits::{CaptureStream, Stream as _};
use v4l::video::Capture;
use v4l::{Device, FourCC, Fraction};

/// `V4L2_CID_EXPOSURE_AUTO` (menu: 0 auto, 1 manual), `V4L2_CID_EXPOSURE_ABSOLUTE` (100 us
/// units), `V4L2_CID_AUTOGAIN`, `V4L2_CID_GAIN`.
const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
const CID_AUTOGAIN: u32 = 0x0098_0912;
const CID_GAIN: u32 = 0x0098_0913;
/// mmap buffers queued to the driver.
const STREAM_BUFFERS: u32 = 4;

/// A V4L2 capture device streaming mmap buffers.
pub struct DeviceSource {
    path: PathBuf,
    name: String,
    device: Device,
    stream: Option<Stream<'static>>,
}

impl DeviceSource {
    /// Opens the device node (`/dev/videoN`).
    pub fn open(path: &Path) -> io::Result<Self> {
        let device = Device::with_path(path)?;
        Ok(DeviceSource {
            path: path.to_path_buf(),
            name: format!("v4l2:{}", path.display()),
            device,
            stream: None,
        })
    }

    fn set_control(&self, id: u32, value: i64) -> io::Result<()> {
        self.device.set_control(Control {
            id,
            value: Value::Integer(value),
        })
    }
}

impl V4l2BufferSource for DeviceSource {
    fn set_format(
        &mut self,
        width_px: u32,
        height_px: u32,
        pixel_format: PixelFormat,
        rate_hz: f64,
    ) -> io::Result<(V4l2Format, Option<f64>)> {
        self.stream = None;
        let fourcc = match pixel_format {
            PixelFormat::Mono8 => V4l2PixelFormat::FOURCC_GREY,
            PixelFormat::Mono16 => V4l2PixelFormat::FOURCC_Y16,
        };
        let mut fmt = self.device.format()?;
        fmt.width = width_px;
        fmt.height = height_px;
        fmt.fourcc = FourCC::new(&fourcc);
        let fmt = self.device.set_format(&fmt)?;
        let mut code = fmt.fourcc.repr;
        let big_endian = code[3] & 0x80 != 0;
        code[3] &= 0x7f;
        let pixel = V4l2PixelFormat::from_fourcc(code, big_endian).ok_or_else(|| {
            io::Error::new(
                io::ErrorKind::Unsupported,
                format!(
                    "driver offers fourcc {:?}, not GREY or Y16",
                    String::from_utf8_lossy(&fmt.fourcc.repr)
                ),
            )
        })?;
        // Frame interval as a fraction with microsecond resolution.
        let mut params = self.device.params()?;
        params.interval = Fraction::new(1_000_000, (rate_hz * 1e6).round() as u32);
        let params = self.device.set_params(&params)?;
        let applied_rate_hz = (params.interval.numerator > 0)
            .then(|| params.interval.denominator as f64 / params.interval.numerator as f64);
        let format = V4l2Format {
            pixel_format: pixel,
            width_px: fmt.width,
            height_px: fmt.height,
            bytes_per_line: fmt.stride,
        };
        Ok((format, applied_rate_hz))
    }

    fn set_exposure_gain(&mut self, config: &CameraConfig) -> io::Result<Vec<String>> {
        let mut notes = Vec::new();
        let result = match config.exposure {
            Exposure::Manual { exposure_us } => {
                self.set_control(CID_EXPOSURE_AUTO, 1).and_then(|()| {
                    self.set_control(CID_EXPOSURE_ABSOLUTE, (exposure_us / 100.0).round() as i64)
                })
            }
            Exposure::Auto { .. } => {
                notes.push(
                    "V4L2: auto-exposure limits are not standard controls; not applied".into(),
                );
                self.set_control(CID_EXPOSURE_AUTO, 0)
            }
        };
        if let Err(e) = result {
            notes.push(format!("exposure control not applied: {e}"));
        }
        let result = match config.gain {
            Gain::Manual { gain } => self
                .set_control(CID_AUTOGAIN, 0)
                .and_then(|()| self.set_control(CID_GAIN, gain.round() as i64)),
            Gain::Auto => self.set_control(CID_AUTOGAIN, 1),
        };
        if let Err(e) = result {
            notes.push(format!("gain control not applied: {e}"));
        }
        Ok(notes)
    }

    fn start(&mut self) -> io::Result<()> {
        if self.stream.is_none() {
            self.stream = Some(Stream::with_buffers(
                &self.device,
                Type::VideoCapture,
                STREAM_BUFFERS,
            )?);
        }
        Ok(())
    }

    fn dequeue(&mut self, timeout: Duration) -> io::Result<Option<V4l2Buffer<'_>>> {
        let stream = self
            .stream
            .as_mut()
            .ok_or_else(|| io::Error::other("dequeue before start"))?;
        stream.set_timeout(timeout.max(Duration::from_millis(1)));
        match CaptureStream::next(stream) {
            Ok((data, meta)) => Ok(Some(V4l2Buffer {
                data,
                bytes_used: meta.bytesused,
                sequence: meta.sequence,
                timestamp_ns: timeval_ns(meta.timestamp.sec, meta.timestamp.usec),
                flags: meta.flags.into(),
            })),
            Err(e) if e.kind() == io::ErrorKind::TimedOut => Ok(None),
            Err(e) => Err(e),
        }
    }

    fn stop(&mut self) -> io::Result<()> {
        if let Some(mut stream) = self.stream.take() {
            stream.stop()?;
        }
        Ok(())
    }

    fn reopen(&mut self) -> io::Result<()> {
        self.stream = None;
        self.device = Device::with_path(&self.path)?;
        Ok(())
    }

    fn info(&self) -> CameraInfo {
        let mut info = CameraInfo {
            device: self.name.clone(),
            protocol: "V4L2".into(),
            ..CameraInfo::default()
        };
        if let Ok(caps) = self.device.query_caps() {
            info.vendor = caps.driver.clone();
            info.model = caps.card.clone();
            info.serial = caps.bus.clone();
            info.features
                .push(("capabilities".into(), caps.capabilities.to_string()));
        }
        if let Ok(formats) = self.device.enum_formats() {
            info.pixel_formats = formats
                .iter()
                .map(|f| format!("{} ({})", f.fourcc, f.description))
                .collect();
        }
        if let Ok(fmt) = self.device.format() {
            info.features.push((
                "format".into(),
                format!(
                    "{}x{} {} stride {} B",
                    fmt.width, fmt.height, fmt.fourcc, fmt.stride
                ),
            ));
        }
        info
    }
}

/// `struct timeval` to nanoseconds. (`time_t` is i32 on 32-bit ARM: keep the widening.)
#[allow(clippy::useless_conversion)]
fn timeval_ns(sec: libc::time_t, usec: libc::time_t) -> i64 {
    i64::from(sec) * 1_000_000_000 + i64::from(usec) * 1_000
}
