//! The committed GX4-format fixture (`tests/data/euroc_v1_01_easy_gx4_5s.mip`, made by
//! `vidslam imu encode-euroc --csv $VIDSLAM_DATA/euroc/V1_01_easy_micro/mav0/imu0/data.csv
//! --seconds 5 --out tests/data/euroc_v1_01_easy_gx4_5s.mip`) and the `vidslam imu decode` command.

mod scratch;

use std::path::{Path, PathBuf};
use vidslam::cli::imu::decode_file;
use vidslam::dataset::gx4_recording::{encode_gx4_recording, gx4_packets};
use vidslam::dataset::{read_imu_csv, shared_data_or_skip};
use vidslam_mip::Decoder;
use vidslam_mip::imu::{INTERNAL_TICK_HZ, ImuData};
use vidslam_timesync::TickUnwrapper;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/euroc_v1_01_easy_gx4_5s.mip")
}

fn shared_data() -> Option<PathBuf> {
    shared_data_or_skip("")
}

fn decode_imu(bytes: &[u8]) -> Vec<ImuData> {
    let mut d = Decoder::new();
    let mut out = Vec::new();
    d.feed(bytes, |p| out.push(ImuData::parse(&p).expect("IMU packet")));
    d.finish(|_| panic!("trailing packet"));
    assert_eq!(d.stats().bytes_skipped, 0);
    out
}

#[test]
fn fixture_is_a_clean_200hz_gx4_stream_across_tick_wraparound() {
    let bytes = std::fs::read(fixture()).unwrap();
    assert!(bytes.len() < 100_000);
    let packets = decode_imu(&bytes);
    assert_eq!(packets.len(), 1000);
    let mut ticks = TickUnwrapper::new(INTERNAL_TICK_HZ);
    let mut prev: Option<(i64, i64)> = None;
    for p in &packets {
        let gps_ns = p.gps_time.unwrap().gps_ns().unwrap();
        let tick_ns = ticks.unwrap_ns(p.internal_ticks.unwrap());
        if let Some((g0, t0)) = prev {
            // Both clocks advance by the EuRoC period (5 ms ± jitter) and agree to one tick.
            assert!(
                (4_000_000..6_000_000).contains(&(gps_ns - g0)),
                "{}",
                gps_ns - g0
            );
            assert!(((gps_ns - g0) - (tick_ns - t0)).abs() <= 16_000);
        }
        prev = Some((gps_ns, tick_ns));
        assert!(p.accel_g.unwrap().iter().all(|a| a.is_finite()));
    }
    assert_eq!(
        ticks.wraps(),
        1,
        "the fixture crosses the u32 tick wraparound once"
    );
}

#[test]
fn fixture_reencodes_byte_for_byte_and_decodes_to_what_was_encoded() {
    let Some(dir) = shared_data() else { return };
    let csv = dir.join("euroc/V1_01_easy_micro/mav0/imu0/data.csv");
    let rows = read_imu_csv(&csv).unwrap();
    let expected = gx4_packets(&rows, 5.0);
    let bytes = encode_gx4_recording(&rows, 5.0);
    assert_eq!(
        bytes,
        std::fs::read(fixture()).unwrap(),
        "fixture is stale: re-run the encoder"
    );
    assert_eq!(decode_imu(&bytes), expected);
    // Units survive: accel back in m/s² within f32 rounding.
    let a = expected[0].accel_g.unwrap()[0] as f64 * vidslam_mip::imu::GRAVITY_M_S2;
    assert!((a - rows[0].accel_m_s2.x).abs() < 1e-5);
}

#[test]
fn decode_command_reports_json_counts() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_vidslam"))
        .args(["imu", "decode", "--json"])
        .arg(fixture())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["packets"], 1000);
    assert_eq!(v["checksum_failures"], 0);
    assert_eq!(v["bytes_skipped"], 0);
    assert_eq!(v["per_set"]["0x80"]["fields"]["0x12"], 1000);
    assert_eq!(v["time_source"], "gps");
    let rate = v["rate_hz"].as_f64().unwrap();
    assert!((rate - 200.0).abs() < 0.01, "{rate}");
}

#[test]
fn decode_counts_garbage_and_corruption() {
    let mut bytes = std::fs::read(fixture()).unwrap();
    bytes[82 * 10 + 20] ^= 0x40; // corrupt packet 10
    let mut with_garbage = b"\x75\x65garbage".to_vec();
    with_garbage.extend_from_slice(&bytes);
    let dir = scratch::dir("imu-decode");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("damaged.mip");
    std::fs::write(&path, &with_garbage).unwrap();
    let r = decode_file(&path).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(r.packets, 999);
    assert_eq!(r.checksum_failures, 2); // the fake header and the corrupted packet
    assert_eq!(r.bytes_skipped, 9 + 82);
}

#[test]
fn sdk_capture_through_the_command() {
    let Some(dir) = shared_data() else { return };
    let r = decode_file(&dir.join("mip/mip_sdk_test_capture.bin")).unwrap();
    assert_eq!(r.packets, 8_384);
    assert_eq!(r.checksum_failures, 0);
    assert_eq!(r.per_set["0x80"].packets, 7_157);
    assert!(
        r.time_span_s.is_none(),
        "no GX4 timestamps in the SDK capture"
    );
}
