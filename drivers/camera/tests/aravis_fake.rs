//! Aravis's in-process fake camera (`Fake_1`, no network) through the real libaravis: open,
//! configure 752x480 Mono8 at 20 Hz, grab frames, check timestamps and rate, stop and reopen.
#![cfg(feature = "aravis")]

use std::time::Duration;
use vidslam_camera::aravis_backend::AravisCamera;
use vidslam_camera::{Acquisition, Camera, CameraConfig, CameraError, PixelFormat, TimestampLatch};

const FRAMES: usize = 45;

fn config() -> CameraConfig {
    // The fake stamps buffers when it fills them (after the frame period), so: end latch.
    CameraConfig {
        timestamp_latch: TimestampLatch::ExposureEnd,
        ..CameraConfig::default()
    }
}

/// Grabs `n` frames and checks them; returns the device timestamps.
fn grab(cam: &mut AravisCamera, n: usize) -> Vec<i64> {
    let mut device_ns = Vec::new();
    let mut last_id = None;
    for i in 0..n {
        let frame = cam
            .next_frame(Duration::from_secs(2))
            .unwrap_or_else(|e| panic!("frame {i}: {e}"));
        let m = frame.meta;
        assert_eq!(
            (m.width_px, m.height_px, m.pixel_format),
            (752, 480, PixelFormat::Mono8)
        );
        assert_eq!(frame.pixels().len(), 752 * 480);
        assert!(!m.flags.incomplete);
        if let Some(last) = last_id {
            assert!(
                m.frame_id > last,
                "frame ids increase: {} after {last}",
                m.frame_id
            );
        }
        last_id = Some(m.frame_id);
        // The mapped mid-exposure time lies before the frame was received.
        let t = m.frame_time_ns.expect("every frame gets a host time");
        assert!(
            t <= m.host_receive_ns,
            "frame {i}: frame time {t} after receive {}",
            m.host_receive_ns
        );
        device_ns.push(m.device_ns);
    }
    device_ns
}

fn check_rate(device_ns: &[i64], label: &str) -> f64 {
    assert!(
        device_ns.windows(2).all(|w| w[1] > w[0]),
        "{label}: device timestamps strictly increase"
    );
    // Median interval (robust to a slot the fake's pacing thread skips on a loaded machine);
    // the mean is printed too.
    let mut periods_ns: Vec<i64> = device_ns.windows(2).map(|w| w[1] - w[0]).collect();
    periods_ns.sort_unstable();
    let rate_hz = 1e9 / periods_ns[periods_ns.len() / 2] as f64;
    let span_s = (device_ns[device_ns.len() - 1] - device_ns[0]) as f64 * 1e-9;
    let mean_rate_hz = (device_ns.len() - 1) as f64 / span_s;
    eprintln!(
        "{label}: {} frames, device-clock rate {rate_hz:.3} Hz (median interval), \
         {mean_rate_hz:.3} Hz (mean)",
        device_ns.len()
    );
    assert!(
        (rate_hz - 20.0).abs() <= 1.0,
        "{label}: measured {rate_hz} Hz, configured 20 Hz (±5 %)"
    );
    rate_hz
}

#[test]
fn fake_camera_streams_752x480_mono8_at_20_hz_and_reopens() {
    let mut cam = AravisCamera::open("Fake_1").expect("open Fake_1");
    let info = cam.info().clone();
    eprintln!("info: {info:?}");
    assert_eq!(info.protocol, "Fake");
    assert!(
        info.pixel_formats.iter().any(|f| f == "Mono8"),
        "{:?}",
        info.pixel_formats
    );
    let applied = cam.configure(&config()).expect("configure");
    eprintln!("applied: {applied:?}");
    assert_eq!((applied.width_px, applied.height_px), (752, 480));
    assert!((applied.rate_hz.unwrap() - 20.0).abs() < 1e-6);
    cam.start().unwrap();
    let first = grab(&mut cam, FRAMES);
    check_rate(&first, "first run");
    cam.stop().unwrap();
    cam.stop().unwrap(); // idempotent
    let stats = cam.stats();
    assert_eq!(stats.delivered, FRAMES as u64);
    assert_eq!(stats.incomplete, 0);
    drop(cam);

    // Reopen the device from scratch and stream again.
    let mut cam = AravisCamera::open("Fake_1").expect("reopen Fake_1");
    cam.configure(&config()).unwrap();
    cam.start().unwrap();
    let second = grab(&mut cam, FRAMES);
    check_rate(&second, "after reopen");
    assert!(
        second[0] > first[FRAMES - 1],
        "the device clock goes on across a reopen"
    );
    cam.stop().unwrap();
}

#[test]
fn holding_every_pool_buffer_drops_frames_instead_of_allocating() {
    let mut cam = AravisCamera::open("Fake_1").expect("open Fake_1");
    let cfg = CameraConfig {
        pool_frames: 2,
        acquisition: Acquisition::FreeRunning { rate_hz: 50.0 },
        ..config()
    };
    cam.configure(&cfg).unwrap();
    cam.start().unwrap();
    let a = cam.next_frame(Duration::from_secs(2)).unwrap();
    let b = cam.next_frame(Duration::from_secs(2)).unwrap();
    // Both pool buffers are held: the next frames cannot be delivered.
    let err = cam.next_frame(Duration::from_millis(300)).unwrap_err();
    assert!(matches!(err, CameraError::Timeout { .. }), "{err}");
    assert!(cam.stats().pool_exhausted > 0);
    drop((a, b));
    let c = cam.next_frame(Duration::from_secs(2)).unwrap();
    assert!(
        c.meta.flags.dropped_before > 0,
        "the gap is reported on the next frame"
    );
    cam.stop().unwrap();
}

#[test]
fn mono16_frames_come_through_at_the_requested_size() {
    let mut cam = AravisCamera::open("Fake_1").expect("open Fake_1");
    let cfg = CameraConfig {
        width_px: 320,
        height_px: 240,
        pixel_format: PixelFormat::Mono16,
        ..config()
    };
    let applied = cam.configure(&cfg).unwrap();
    assert_eq!(applied.pixel_format, PixelFormat::Mono16);
    cam.start().unwrap();
    for _ in 0..3 {
        let f = cam.next_frame(Duration::from_secs(2)).unwrap();
        assert_eq!(
            (f.meta.width_px, f.meta.height_px, f.meta.pixel_format),
            (320, 240, PixelFormat::Mono16)
        );
        assert_eq!(f.pixels().len(), 320 * 240 * 2);
        assert_eq!(f.stride_bytes(), 640);
    }
    cam.stop().unwrap();
}
