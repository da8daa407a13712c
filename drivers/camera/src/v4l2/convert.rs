//! V4L2 buffer → frame conversion: pure Rust, no device needed. Strips the driver's row padding
//! (`bytesperline`), converts `Y16` to our little-endian Mono16 layout (a no-op copy on
//! little-endian data, a byte swap for `Y16` big-endian), and checks completeness.

use crate::frame::PixelFormat;

/// `V4L2_BUF_FLAG_ERROR`: the data may be corrupt.
pub const BUF_FLAG_ERROR: u32 = 0x0000_0040;
/// `V4L2_BUF_FLAG_TIMESTAMP_MASK` and its values.
pub const BUF_FLAG_TIMESTAMP_MASK: u32 = 0x0000_e000;
pub const BUF_FLAG_TIMESTAMP_MONOTONIC: u32 = 0x0000_2000;
/// `V4L2_BUF_FLAG_TSTAMP_SRC_MASK` and its values (EOF = 0).
pub const BUF_FLAG_TSTAMP_SRC_MASK: u32 = 0x0007_0000;
pub const BUF_FLAG_TSTAMP_SRC_SOE: u32 = 0x0001_0000;

/// Pixel formats accepted from V4L2 (fourcc codes as bytes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum V4l2PixelFormat {
    /// `GREY`: 8-bit luminance.
    Grey,
    /// `Y16 `: 16-bit luminance, little-endian.
    Y16,
    /// `Y16 ` with `V4L2_PIX_FMT_FLAG_BE` (`Y16_BE`): 16-bit luminance, big-endian.
    Y16Be,
}

impl V4l2PixelFormat {
    pub const FOURCC_GREY: [u8; 4] = *b"GREY";
    pub const FOURCC_Y16: [u8; 4] = *b"Y16 ";

    /// From a fourcc; `big_endian` is the `V4L2_PIX_FMT_FLAG_BE` bit (bit 31 of the code).
    pub fn from_fourcc(fourcc: [u8; 4], big_endian: bool) -> Option<Self> {
        match (fourcc, big_endian) {
            (Self::FOURCC_GREY, _) => Some(V4l2PixelFormat::Grey),
            (Self::FOURCC_Y16, false) => Some(V4l2PixelFormat::Y16),
            (Self::FOURCC_Y16, true) => Some(V4l2PixelFormat::Y16Be),
            _ => None,
        }
    }

    pub fn pixel_format(self) -> PixelFormat {
        match self {
            V4l2PixelFormat::Grey => PixelFormat::Mono8,
            V4l2PixelFormat::Y16 | V4l2PixelFormat::Y16Be => PixelFormat::Mono16,
        }
    }
}

/// The negotiated capture format (`VIDIOC_S_FMT` result).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct V4l2Format {
    pub pixel_format: V4l2PixelFormat,
    pub width_px: u32,
    pub height_px: u32,
    /// Row stride in the buffer, bytes (>= width * bytes per pixel).
    pub bytes_per_line: u32,
}

impl V4l2Format {
    fn packed_row_bytes(&self) -> usize {
        self.width_px as usize * self.pixel_format.pixel_format().bytes_per_pixel()
    }

    /// Bytes a complete image occupies in the buffer (the last row needs no padding).
    pub fn min_bytes_used(&self) -> usize {
        if self.height_px == 0 {
            return 0;
        }
        (self.height_px as usize - 1) * self.bytes_per_line as usize + self.packed_row_bytes()
    }

    /// Checks the stride can hold a row.
    pub fn validate(&self) -> Result<(), String> {
        if (self.bytes_per_line as usize) < self.packed_row_bytes() {
            return Err(format!(
                "bytesperline {} is smaller than a {} px row of {:?} ({} bytes)",
                self.bytes_per_line,
                self.width_px,
                self.pixel_format,
                self.packed_row_bytes()
            ));
        }
        Ok(())
    }
}

/// One dequeued buffer as the kernel describes it (`struct v4l2_buffer` plus its mapping).
#[derive(Clone, Copy, Debug)]
pub struct V4l2Buffer<'a> {
    /// The whole mapped buffer (`bytesused` of it are valid).
    pub data: &'a [u8],
    pub bytes_used: u32,
    pub sequence: u32,
    /// `timestamp` field converted to nanoseconds (`tv_sec * 1e9 + tv_usec * 1e3`).
    pub timestamp_ns: i64,
    /// `V4L2_BUF_FLAG_*`.
    pub flags: u32,
}

impl V4l2Buffer<'_> {
    /// The driver stamped with `CLOCK_MONOTONIC` (the host clock): no clock model needed.
    pub fn timestamp_is_monotonic(&self) -> bool {
        self.flags & BUF_FLAG_TIMESTAMP_MASK == BUF_FLAG_TIMESTAMP_MONOTONIC
    }

    /// The stamp is at start of exposure (`TSTAMP_SRC_SOE`), else at end of frame.
    pub fn stamped_at_start_of_exposure(&self) -> bool {
        self.flags & BUF_FLAG_TSTAMP_SRC_MASK == BUF_FLAG_TSTAMP_SRC_SOE
    }
}

/// Why a buffer could not become a good frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ConvertError {
    /// The driver flagged the buffer as corrupt (`V4L2_BUF_FLAG_ERROR`).
    DriverError,
    /// Fewer bytes than a full image.
    Short { bytes_used: usize, needed: usize },
    /// The output buffer does not match the format.
    OutputSize { len: usize, needed: usize },
}

impl std::fmt::Display for ConvertError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ConvertError::DriverError => write!(f, "driver flagged the buffer as corrupt"),
            ConvertError::Short { bytes_used, needed } => {
                write!(
                    f,
                    "buffer holds {bytes_used} bytes, a full image needs {needed}"
                )
            }
            ConvertError::OutputSize { len, needed } => {
                write!(f, "output buffer is {len} bytes, the image needs {needed}")
            }
        }
    }
}

/// Copies the image in `buf` into `out` (tightly packed rows, Mono16 little-endian).
///
/// A driver-flagged or short buffer is reported as an error (`out` is then partly written
/// and must not be used as a good frame).
pub fn convert_buffer(
    format: &V4l2Format,
    buf: &V4l2Buffer<'_>,
    out: &mut [u8],
) -> Result<(), ConvertError> {
    let row = format.packed_row_bytes();
    let needed_out = row * format.height_px as usize;
    if out.len() != needed_out {
        return Err(ConvertError::OutputSize {
            len: out.len(),
            needed: needed_out,
        });
    }
    if buf.flags & BUF_FLAG_ERROR != 0 {
        return Err(ConvertError::DriverError);
    }
    let used = (buf.bytes_used as usize).min(buf.data.len());
    let needed = format.min_bytes_used();
    if used < needed {
        return Err(ConvertError::Short {
            bytes_used: used,
            needed,
        });
    }
    let stride = format.bytes_per_line as usize;
    for (y, out_row) in out.chunks_exact_mut(row).enumerate() {
        let src = &buf.data[y * stride..y * stride + row];
        match format.pixel_format {
            V4l2PixelFormat::Grey | V4l2PixelFormat::Y16 => out_row.copy_from_slice(src),
            V4l2PixelFormat::Y16Be => {
                for (o, s) in out_row.chunks_exact_mut(2).zip(src.chunks_exact(2)) {
                    o[0] = s[1];
                    o[1] = s[0];
                }
            }
        }
    }
    Ok(())
}
