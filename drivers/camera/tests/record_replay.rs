//! Recording → replay round trip (Mono8 and Mono16), and bad input: a corrupt image is counted
//! and skipped, a malformed CSV line is reported with file and line.

use std::time::Duration;
use vidslam_camera::v4l2::V4l2Camera;
use vidslam_camera::v4l2::convert::{BUF_FLAG_TIMESTAMP_MONOTONIC, V4l2Format, V4l2PixelFormat};
use vidslam_camera::v4l2::recorded::{RecordedBuffer, RecordedSource};
use vidslam_camera::{
    Camera, CameraConfig, CameraError, Frame, Pacing, PixelFormat, Recorder, ReplayCamera,
};

/// Frames with known content from the V4L2 path (so they carry real metadata).
fn frames(format: V4l2PixelFormat, n: u32) -> Vec<Frame> {
    let (w, h) = (6u32, 4u32);
    let bpp = if format == V4l2PixelFormat::Grey {
        1
    } else {
        2
    };
    let fmt = V4l2Format {
        pixel_format: format,
        width_px: w,
        height_px: h,
        bytes_per_line: w * bpp,
    };
    let buffers = (0..n)
        .map(|i| RecordedBuffer {
            data: (0..w * h * bpp).map(|k| (k * 7 + i * 13) as u8).collect(),
            bytes_used: w * h * bpp,
            sequence: if i >= 2 { i + 1 } else { i }, // one frame lost after the second
            timestamp_ns: 1_000_000_000 + i as i64 * 50_000_000,
            flags: BUF_FLAG_TIMESTAMP_MONOTONIC,
        })
        .collect();
    let mut cam = V4l2Camera::new(RecordedSource::new("rec", fmt, buffers));
    let pixel_format = if bpp == 1 {
        PixelFormat::Mono8
    } else {
        PixelFormat::Mono16
    };
    cam.configure(&CameraConfig {
        width_px: w,
        height_px: h,
        pixel_format,
        pool_frames: n as usize,
        ..Default::default()
    })
    .unwrap();
    cam.start().unwrap();
    (0..n)
        .map(|_| cam.next_frame(Duration::from_secs(1)).unwrap())
        .collect()
}

fn round_trip(format: V4l2PixelFormat) {
    let dir = tempfile::tempdir().unwrap();
    let written = frames(format, 5);
    let mut rec = Recorder::create(dir.path()).unwrap();
    for f in &written {
        assert!(rec.write(f).unwrap());
    }
    assert_eq!(rec.written(), 5);
    drop(rec);
    assert!(
        Recorder::create(dir.path()).is_err(),
        "an existing recording is never overwritten"
    );

    let mut cam = ReplayCamera::open(dir.path(), Pacing::AsFastAsConsumed).unwrap();
    cam.configure(&CameraConfig {
        pool_frames: 2,
        ..Default::default()
    })
    .unwrap();
    cam.start().unwrap();
    for w in &written {
        let r = cam.next_frame(Duration::from_secs(1)).unwrap();
        assert_eq!(r.pixels(), w.pixels(), "lossless");
        assert_eq!(r.meta.frame_time_ns, w.meta.frame_time_ns);
        assert_eq!(r.meta.device_ns, w.meta.device_ns);
        assert_eq!(r.meta.host_receive_ns, w.meta.host_receive_ns);
        assert_eq!(r.meta.frame_id, w.meta.frame_id);
        assert_eq!(r.meta.flags, w.meta.flags);
        assert_eq!(r.meta.exposure_us, w.meta.exposure_us);
        assert_eq!(r.meta.pixel_format, w.meta.pixel_format);
    }
    assert_eq!(
        written[2].meta.flags.dropped_before, 1,
        "the sequence gap travels through the recording"
    );
    assert!(matches!(
        cam.next_frame(Duration::from_secs(1)),
        Err(CameraError::EndOfStream { frames: 5, .. })
    ));
}

#[test]
fn mono8_recording_replays_losslessly_with_its_timing() {
    round_trip(V4l2PixelFormat::Grey);
}

#[test]
fn mono16_recording_replays_losslessly_with_its_timing() {
    round_trip(V4l2PixelFormat::Y16);
}

#[test]
fn a_corrupt_image_is_counted_and_skipped() {
    let dir = tempfile::tempdir().unwrap();
    let written = frames(V4l2PixelFormat::Grey, 4);
    let mut rec = Recorder::create(dir.path()).unwrap();
    for f in &written {
        rec.write(f).unwrap();
    }
    let cam0 = rec.cam0().to_path_buf();
    drop(rec);
    // Truncate the third image.
    let third = cam0
        .join("data")
        .join(format!("{}.png", written[2].meta.frame_time_ns.unwrap()));
    let bytes = std::fs::read(&third).unwrap();
    std::fs::write(&third, &bytes[..bytes.len() / 2]).unwrap();

    let mut cam = ReplayCamera::open(dir.path(), Pacing::AsFastAsConsumed).unwrap();
    cam.configure(&CameraConfig::default()).unwrap();
    cam.start().unwrap();
    let ids: Vec<(u64, u32)> = (0..3)
        .map(|_| cam.next_frame(Duration::from_secs(1)).unwrap())
        .map(|f| (f.meta.frame_id, f.meta.flags.dropped_before))
        .collect();
    // Frame 3 (id 3 after the sequence gap) is gone; frame id 4 reports it as dropped.
    assert_eq!(ids, vec![(0, 0), (1, 0), (4, 1)]);
    assert_eq!(cam.stats().incomplete, 1);
}

#[test]
fn a_malformed_csv_line_names_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let cam0 = dir.path().join("mav0/cam0");
    std::fs::create_dir_all(cam0.join("data")).unwrap();
    std::fs::write(
        cam0.join("data.csv"),
        "#timestamp [ns],filename\n100,a.png\nxyz,b.png\n",
    )
    .unwrap();
    let err = ReplayCamera::open(dir.path(), Pacing::AsFastAsConsumed)
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("data.csv:3") && err.contains("xyz"), "{err}");
    std::fs::write(cam0.join("data.csv"), "100,a.png\n100,b.png\n").unwrap();
    let err = ReplayCamera::open(dir.path(), Pacing::AsFastAsConsumed)
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("data.csv:2") && err.contains("not after"),
        "{err}"
    );
}
