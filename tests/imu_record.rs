//! `vidslam imu record` against the fake GX4 on a pseudo-terminal (the one of the driver's own
//! tests): the recording holds every IMU packet the device sent, byte for byte, and a recording
//! killed mid-stream keeps every complete packet received.

#[path = "../drivers/mip/tests/common/fake_gx4.rs"]
mod fake_gx4;
mod scratch;

use fake_gx4::{FakeGx4, Script};
use std::path::Path;
use std::time::{Duration, Instant};
use vidslam_mip::Decoder;

fn fixture_packets(range: std::ops::Range<usize>) -> Vec<Vec<u8>> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/euroc_v1_01_easy_gx4_5s.mip");
    let bytes = std::fs::read(path).unwrap();
    let mut out = Vec::new();
    Decoder::new().feed(&bytes, |p| out.push(p.as_bytes().to_vec()));
    out[range].to_vec()
}

/// (IMU packets, other packets, checksum failures) of a recording.
fn split(bytes: &[u8]) -> (Vec<Vec<u8>>, usize, u64) {
    let mut d = Decoder::new();
    let mut imu = Vec::new();
    let mut other = 0;
    d.feed(bytes, |p| {
        if p.descriptor_set() == 0x80 {
            imu.push(p.as_bytes().to_vec());
        } else {
            other += 1;
        }
    });
    (imu, other, d.stats().checksum_failures)
}

fn temp_file(name: &str) -> std::path::PathBuf {
    scratch::path(&format!("imu-record-{name}"))
}

#[test]
fn record_writes_every_packet_sent() {
    let packets = fixture_packets(0..200);
    let fake = FakeGx4::start(Script {
        packets: packets.clone(),
        ..Default::default()
    });
    let out = temp_file("rec.mip");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_vidslam"))
        .args([
            "imu",
            "record",
            "--port",
            fake.path(),
            "--rate-hz",
            "200",
            "--seconds",
            "1.5",
        ])
        .arg("--out")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    let log = fake.finish();
    let bytes = std::fs::read(&out).unwrap();
    std::fs::remove_file(&out).unwrap();
    let (imu, other, failures) = split(&bytes);
    assert_eq!(failures, 0);
    // Everything the device streamed before it acknowledged "set idle", in order.
    assert_eq!(imu.len(), log.packets_sent);
    assert_eq!(imu, packets[..log.packets_sent]);
    assert!(other >= 1, "the final set-idle ACK is recorded too");
}

#[test]
fn killed_recording_keeps_what_was_received() {
    let packets = fixture_packets(0..1000);
    let fake = FakeGx4::start(Script {
        packets,
        ..Default::default()
    });
    let out = temp_file("killed.mip");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_vidslam"))
        .args(["imu", "record", "--port", fake.path()])
        .arg("--out")
        .arg(&out)
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Wait for 100 packets on disk (polling; bounded so a broken recorder fails instead of hanging).
    let deadline = Instant::now() + Duration::from_secs(30);
    while std::fs::metadata(&out).map_or(0, |m| m.len()) < 100 * 82 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let bytes = std::fs::read(&out).unwrap();
    std::fs::remove_file(&out).unwrap();
    let (imu, _, failures) = split(&bytes);
    assert_eq!(failures, 0);
    assert!(
        imu.len() >= 100,
        "{} packets on disk after the kill",
        imu.len()
    );
    drop(fake);
}
