//! Replay of the shared EuRoC clip (V1_01_easy, first 95 frames): every frame, in order, with
//! the dataset's timestamps and pixels. Skips with a message when the shared data is absent.

use std::path::PathBuf;
use std::time::{Duration, Instant};
use vidslam_camera::{Camera, CameraConfig, CameraError, Pacing, PixelFormat, ReplayCamera};

fn euroc_clip() -> Option<PathBuf> {
    let root = std::env::var_os("VIDSLAM_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    let clip = root.join("euroc/V1_01_easy_micro");
    if clip.join("mav0/cam0/data.csv").is_file() {
        Some(clip)
    } else {
        eprintln!(
            "SKIP: EuRoC clip not found at {} (set VIDSLAM_DATA)",
            clip.display()
        );
        None
    }
}

/// Timestamps straight from the dataset's `data.csv`, parsed here independently.
fn dataset_stamps(clip: &std::path::Path) -> Vec<i64> {
    std::fs::read_to_string(clip.join("mav0/cam0/data.csv"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| l.split(',').next().unwrap().trim().parse().unwrap())
        .collect()
}

#[test]
fn euroc_clip_replays_as_95_frames_in_order_with_dataset_timestamps() {
    let Some(clip) = euroc_clip() else { return };
    let expected = dataset_stamps(&clip);
    assert_eq!(expected.len(), 95);
    let mut cam = ReplayCamera::open(&clip, Pacing::AsFastAsConsumed).unwrap();
    let applied = cam.configure(&CameraConfig::default()).unwrap();
    assert_eq!(
        (applied.width_px, applied.height_px, applied.pixel_format),
        (752, 480, PixelFormat::Mono8)
    );
    assert!(applied.notes.is_empty(), "{:?}", applied.notes);
    cam.start().unwrap();
    let mut got = Vec::new();
    let mut checksum_first = 0u64;
    loop {
        match cam.next_frame(Duration::from_secs(1)) {
            Ok(f) => {
                assert_eq!(f.meta.frame_id, got.len() as u64);
                assert_eq!(f.meta.flags, Default::default());
                assert_eq!(f.meta.frame_time_ns, Some(f.meta.device_ns));
                if got.is_empty() {
                    checksum_first = f.pixels().iter().map(|&p| p as u64).sum();
                }
                got.push(f.meta.device_ns);
            }
            Err(CameraError::EndOfStream { frames, .. }) => {
                assert_eq!(frames, 95);
                break;
            }
            Err(e) => panic!("{e}"),
        }
    }
    assert_eq!(got, expected);
    assert_eq!(
        (got[0], got[94]),
        (1_403_715_273_262_142_976, 1_403_715_277_962_142_976)
    );
    // Pixels are the real image (not a zeroed buffer): a mid-grey indoor scene.
    let mean = checksum_first as f64 / (752.0 * 480.0);
    assert!(mean > 20.0 && mean < 235.0, "mean intensity {mean}");
    assert_eq!(cam.stats().delivered, 95);
}

#[test]
fn real_time_pacing_holds_frames_until_their_time() {
    let Some(clip) = euroc_clip() else { return };
    let mut cam = ReplayCamera::open(&clip, Pacing::RealTime).unwrap();
    cam.configure(&CameraConfig::default()).unwrap();
    cam.start().unwrap();
    let t0 = Instant::now();
    for _ in 0..4 {
        cam.next_frame(Duration::from_secs(1)).unwrap();
    }
    // Frame 3 is due 150 ms after the start: it cannot have come earlier. (A lower bound only:
    // no upper timing threshold, the machine may be loaded.)
    assert!(
        t0.elapsed() >= Duration::from_millis(150),
        "{:?}",
        t0.elapsed()
    );
    // A timeout shorter than the wait to the next frame returns Timeout and keeps the frame.
    let err = cam.next_frame(Duration::from_millis(1)).unwrap_err();
    assert!(matches!(err, CameraError::Timeout { .. }), "{err}");
    let f = cam.next_frame(Duration::from_secs(1)).unwrap();
    assert_eq!(f.meta.frame_id, 4);
}
