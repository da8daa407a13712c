//! `vidslam camera` end to end through the built binary.

mod cli;

use std::path::{Path, PathBuf};
use vidslam::dataset::shared_data_or_skip;

/// `vidslam ARGS…`: `(succeeded, stdout, stderr)`.
fn vidslam(args: &[&str]) -> (bool, String, String) {
    let out = cli::vidslam(args);
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

fn euroc_clip() -> Option<PathBuf> {
    shared_data_or_skip("euroc/V1_01_easy_micro")
}

fn rows(csv: &Path) -> Vec<String> {
    std::fs::read_to_string(csv)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(String::from)
        .collect()
}

#[test]
fn recording_a_replayed_euroc_clip_reproduces_its_frames_and_timestamps() {
    let Some(clip) = euroc_clip() else { return };
    let out = tempfile::tempdir().unwrap();
    let dev = format!("replay:{}", clip.display());
    let out_s = out.path().to_str().unwrap();
    let (ok, stdout, stderr) = vidslam(&[
        "camera",
        "record",
        "--device",
        &dev,
        "--seconds",
        "60",
        "--out",
        out_s,
        "--replay-pacing",
        "fast",
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("95 frames written") && stdout.contains("dropped 0"),
        "{stdout}"
    );
    let original = rows(&clip.join("mav0/cam0/data.csv"));
    let recorded = rows(&out.path().join("mav0/cam0/data.csv"));
    assert_eq!(recorded, original, "same timestamps and file names");
    // Lossless: the recorded PNGs decode to the dataset's pixels.
    for name in [&original[0], &original[94]] {
        let file = name.split(',').nth(1).unwrap();
        let a = decode(&clip.join("mav0/cam0/data").join(file));
        let b = decode(&out.path().join("mav0/cam0/data").join(file));
        assert_eq!(a, b, "{file}");
    }
    // `info` on the recording describes it.
    let (ok, stdout, stderr) = vidslam(&["camera", "info", "--device", &format!("replay:{out_s}")]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("model: vidslam recording") && stdout.contains("Frames: 95"),
        "{stdout}"
    );
}

fn decode(path: &Path) -> Vec<u8> {
    let mut r = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()))
        .read_info()
        .unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    r.next_frame(&mut buf).unwrap();
    buf
}

#[test]
fn bad_device_names_give_clear_errors() {
    let (ok, _, stderr) = vidslam(&["camera", "info", "--device", "replay:/nonexistent/x"]);
    assert!(!ok);
    assert!(
        stderr.contains("replay:/nonexistent/x") && stderr.contains("cam0/data.csv"),
        "{stderr}"
    );
    let (ok, _, stderr) = vidslam(&[
        "camera",
        "record",
        "--device",
        "Fake_1",
        "--seconds",
        "-1",
        "--out",
        "/tmp/x",
    ]);
    assert!(!ok && stderr.contains("--seconds"), "{stderr}");
}

#[cfg(not(feature = "aravis"))]
#[test]
fn aravis_names_say_the_binary_lacks_the_feature() {
    let (ok, _, stderr) = vidslam(&["camera", "info", "--device", "Fake_1"]);
    assert!(!ok);
    assert!(
        stderr.contains("Fake_1") && stderr.contains("without the `aravis` feature"),
        "{stderr}"
    );
}

#[cfg(feature = "aravis")]
#[test]
fn fake_camera_is_listed_described_and_recorded() {
    let (ok, stdout, stderr) = vidslam(&["camera", "list", "--fake"]);
    assert!(ok && stdout.contains("Fake_1"), "{stdout}{stderr}");
    let (ok, stdout, stderr) = vidslam(&["camera", "info", "--device", "Fake_1"]);
    assert!(
        ok && stdout.contains("model: Fake") && stdout.contains("Mono16"),
        "{stdout}{stderr}"
    );
    let out = tempfile::tempdir().unwrap();
    let (ok, stdout, stderr) = vidslam(&[
        "camera",
        "record",
        "--device",
        "Fake_1",
        "--seconds",
        "1.5",
        "--out",
        out.path().to_str().unwrap(),
        "--latch",
        "end",
    ]);
    assert!(ok, "{stderr}");
    let frames = rows(&out.path().join("mav0/cam0/frames.csv"));
    let data = rows(&out.path().join("mav0/cam0/data.csv"));
    assert_eq!(frames.len(), data.len());
    assert!(
        frames.len() >= 20,
        "{} frames in 1.5 s at 20 Hz: {stdout}",
        frames.len()
    );
    // Every PNG listed exists, and frame times increase.
    let mut last = i64::MIN;
    for row in &data {
        let (t, file) = row.split_once(',').unwrap();
        let t: i64 = t.parse().unwrap();
        assert!(t > last);
        last = t;
        assert!(out.path().join("mav0/cam0/data").join(file).is_file());
    }
}
