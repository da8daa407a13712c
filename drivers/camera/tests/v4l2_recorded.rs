//! The V4L2 buffer → frame path (always built, no device needed), fed with driver-style buffers
//! through the same `V4l2BufferSource` interface the real device implements: Mono8 and Mono16
//! with stride padding, Y16 big-endian, short and driver-flagged buffers, sequence gaps, and the
//! timestamp rules.

use std::time::Duration;
use vidslam_camera::v4l2::V4l2Camera;
use vidslam_camera::v4l2::convert::{
    BUF_FLAG_ERROR, BUF_FLAG_TIMESTAMP_MONOTONIC, BUF_FLAG_TSTAMP_SRC_SOE, V4l2Format,
    V4l2PixelFormat,
};
use vidslam_camera::v4l2::recorded::{RecordedBuffer, RecordedSource};
use vidslam_camera::{Camera, CameraConfig, CameraError, Exposure, PixelFormat};

const PAD: u8 = 0xEE;

/// A driver buffer of `w x h` samples with `stride` bytes per row; sample value = f(x, y);
/// padding bytes are `PAD`, and the mapping is longer than `bytesused` (as mmap buffers are).
fn buffer(
    format: V4l2PixelFormat,
    w: u32,
    h: u32,
    stride: u32,
    f: impl Fn(u32, u32) -> u16,
) -> Vec<u8> {
    let mut data = vec![PAD; (stride * h) as usize + 64];
    for y in 0..h {
        for x in 0..w {
            let v = f(x, y);
            let o = (y * stride) as usize;
            match format {
                V4l2PixelFormat::Grey => data[o + x as usize] = v as u8,
                V4l2PixelFormat::Y16 => data[o + 2 * x as usize..o + 2 * x as usize + 2]
                    .copy_from_slice(&v.to_le_bytes()),
                V4l2PixelFormat::Y16Be => data[o + 2 * x as usize..o + 2 * x as usize + 2]
                    .copy_from_slice(&v.to_be_bytes()),
            }
        }
    }
    data
}

fn rec(
    data: Vec<u8>,
    bytes_used: u32,
    sequence: u32,
    timestamp_ns: i64,
    flags: u32,
) -> RecordedBuffer {
    RecordedBuffer {
        data,
        bytes_used,
        sequence,
        timestamp_ns,
        flags,
    }
}

fn camera(
    fmt: V4l2Format,
    buffers: Vec<RecordedBuffer>,
    config: CameraConfig,
) -> V4l2Camera<RecordedSource> {
    let mut cam = V4l2Camera::new(RecordedSource::new("v4l2:recorded", fmt, buffers));
    cam.configure(&config).unwrap();
    cam.start().unwrap();
    cam
}

fn config(w: u32, h: u32, pixel_format: PixelFormat) -> CameraConfig {
    CameraConfig {
        width_px: w,
        height_px: h,
        pixel_format,
        ..CameraConfig::default()
    }
}

const MONO: u32 = BUF_FLAG_TIMESTAMP_MONOTONIC;

#[test]
fn mono8_rows_are_unpadded() {
    let (w, h, stride) = (5, 3, 8);
    let fmt = V4l2Format {
        pixel_format: V4l2PixelFormat::Grey,
        width_px: w,
        height_px: h,
        bytes_per_line: stride,
    };
    let data = buffer(fmt.pixel_format, w, h, stride, |x, y| (10 * y + x) as u16);
    let used = stride * (h - 1) + w; // last row unpadded: the minimum a driver may report
    let mut cam = camera(
        fmt,
        vec![rec(data, used, 0, 0, MONO)],
        config(w, h, PixelFormat::Mono8),
    );
    let f = cam.next_frame(Duration::from_secs(1)).unwrap();
    assert_eq!(
        f.pixels(),
        &[0, 1, 2, 3, 4, 10, 11, 12, 13, 14, 20, 21, 22, 23, 24]
    );
    assert!(!f.pixels().contains(&PAD));
}

#[test]
fn mono16_little_and_big_endian_rows_are_unpadded() {
    let (w, h, stride) = (3, 2, 10); // 6 bytes of samples + 4 of padding per row
    for pixel_format in [V4l2PixelFormat::Y16, V4l2PixelFormat::Y16Be] {
        let fmt = V4l2Format {
            pixel_format,
            width_px: w,
            height_px: h,
            bytes_per_line: stride,
        };
        // 12-bit samples MSB-aligned, as Y16 carries them.
        let value = |x: u32, y: u32| ((0x100 * (y + 1) + x) << 4) as u16;
        let data = buffer(pixel_format, w, h, stride, value);
        let mut cam = camera(
            fmt,
            vec![rec(data, stride * h, 0, 0, MONO)],
            config(w, h, PixelFormat::Mono16),
        );
        let f = cam.next_frame(Duration::from_secs(1)).unwrap();
        assert_eq!(f.meta.pixel_format, PixelFormat::Mono16);
        assert_eq!(f.pixels().len(), (w * h * 2) as usize);
        for y in 0..h {
            for x in 0..w {
                assert_eq!(f.value_at(x, y), value(x, y), "{pixel_format:?} ({x},{y})");
            }
        }
    }
}

#[test]
fn short_and_driver_flagged_buffers_are_counted_never_delivered_as_good() {
    let (w, h) = (4, 4);
    let fmt = V4l2Format {
        pixel_format: V4l2PixelFormat::Grey,
        width_px: w,
        height_px: h,
        bytes_per_line: w,
    };
    let img = || buffer(fmt.pixel_format, w, h, w, |x, _| x as u16);
    let buffers = vec![
        rec(img(), 16, 0, 0, MONO),
        rec(img(), 15, 1, 50, MONO),                   // one byte short
        rec(img(), 16, 2, 100, MONO | BUF_FLAG_ERROR), // driver says corrupt
        rec(img(), 16, 3, 150, MONO),
        rec(img(), 16, 6, 300, MONO), // sequence 4 and 5 never arrived
    ];
    let mut cam = camera(fmt, buffers.clone(), config(w, h, PixelFormat::Mono8));
    let got: Vec<(u64, u32, bool)> = (0..3)
        .map(|_| cam.next_frame(Duration::from_secs(1)).unwrap().meta)
        .map(|m| (m.frame_id, m.flags.dropped_before, m.flags.incomplete))
        .collect();
    assert_eq!(got, vec![(0, 0, false), (3, 2, false), (6, 2, false)]);
    let s = cam.stats();
    assert_eq!((s.delivered, s.incomplete, s.missing), (3, 2, 2));
    assert_eq!(s.dropped_total(), 4);
    assert!(matches!(
        cam.next_frame(Duration::from_secs(1)),
        Err(CameraError::EndOfStream { frames: 3, .. })
    ));

    // When asked to, incomplete frames are delivered, flagged.
    let mut cam = camera(
        fmt,
        buffers,
        CameraConfig {
            deliver_incomplete: true,
            ..config(w, h, PixelFormat::Mono8)
        },
    );
    let flags: Vec<bool> = (0..5)
        .map(|_| {
            cam.next_frame(Duration::from_secs(1))
                .unwrap()
                .meta
                .flags
                .incomplete
        })
        .collect();
    assert_eq!(flags, vec![false, true, true, false, false]);
}

#[test]
fn frame_time_is_mid_exposure_by_timestamp_source() {
    let (w, h) = (2, 2);
    let fmt = V4l2Format {
        pixel_format: V4l2PixelFormat::Grey,
        width_px: w,
        height_px: h,
        bytes_per_line: w,
    };
    let img = || vec![0u8; 4];
    let t = 5_000_000_000i64;
    let buffers = vec![
        rec(img(), 4, 0, t, MONO | BUF_FLAG_TSTAMP_SRC_SOE), // start of exposure
        rec(img(), 4, 1, t, MONO),                           // end of frame
        rec(img(), 4, 2, 123, 0),                            // unknown clock: host time used
    ];
    let cfg = CameraConfig {
        exposure: Exposure::Manual {
            exposure_us: 4000.0,
        },
        ..config(w, h, PixelFormat::Mono8)
    };
    let mut cam = camera(fmt, buffers, cfg);
    let soe = cam.next_frame(Duration::from_secs(1)).unwrap().meta;
    assert_eq!((soe.device_ns, soe.frame_time_ns), (t, Some(t + 2_000_000)));
    assert_eq!(soe.exposure_us, Some(4000.0));
    let eof = cam.next_frame(Duration::from_secs(1)).unwrap().meta;
    assert_eq!(eof.frame_time_ns, Some(t - 2_000_000));
    let unknown = cam.next_frame(Duration::from_secs(1)).unwrap().meta;
    assert_eq!(
        unknown.device_ns, unknown.host_receive_ns,
        "no monotonic stamp: the dequeue time stands in"
    );
    assert_eq!(
        unknown.frame_time_ns,
        Some(unknown.host_receive_ns - 2_000_000)
    );
}

#[test]
fn a_driver_that_picks_another_format_is_a_configuration_error() {
    let fmt = V4l2Format {
        pixel_format: V4l2PixelFormat::Grey,
        width_px: 640,
        height_px: 480,
        bytes_per_line: 640,
    };
    let mut cam = V4l2Camera::new(RecordedSource::new("v4l2:recorded", fmt, vec![]));
    let err = cam
        .configure(&config(752, 480, PixelFormat::Mono8))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("v4l2:recorded") && err.contains("640x480"),
        "{err}"
    );
    // A stride too small for a row is rejected too.
    let bad = V4l2Format {
        bytes_per_line: 600,
        ..fmt
    };
    let mut cam = V4l2Camera::new(RecordedSource::new("v4l2:recorded", bad, vec![]));
    let err = cam
        .configure(&config(640, 480, PixelFormat::Mono8))
        .unwrap_err()
        .to_string();
    assert!(err.contains("bytesperline 600"), "{err}");
}
