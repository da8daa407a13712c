//! The real `Gx4` driver against a fake GX4 on a pseudo-terminal: configuration handshake, every
//! recorded sample received, garbage on the line, and a mid-stream disconnect with reopen.
//! The streamed packets are 400 consecutive packets (2 s, across the tick-counter wraparound) of
//! the committed GX4-format EuRoC fixture.

#![cfg(feature = "serial")]

mod common;

use common::fake_gx4::{FakeGx4, Script};
use vidslam_mip::command::{Command, Function};
use vidslam_mip::descriptor::imu as d;
use vidslam_mip::gx4::{Gx4, Gx4Error};
use vidslam_mip::imu::{GRAVITY_M_S2, ImuData};
use vidslam_mip::sample::{DeviceTimeSource, ImuSample};
use vidslam_mip::{Decoder, Packet};

const FIELDS: [u8; 6] = [
    d::SCALED_ACCEL,
    d::SCALED_GYRO,
    d::DELTA_THETA,
    d::DELTA_VELOCITY,
    d::INTERNAL_TIMESTAMP,
    d::GPS_TIMESTAMP,
];

/// Packets 200..600 of the fixture (ticks wrap at packet 400).
fn recorded_packets() -> Vec<Vec<u8>> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/data/euroc_v1_01_easy_gx4_5s.mip"
    );
    let bytes = std::fs::read(path).unwrap();
    let mut out = Vec::new();
    Decoder::new().feed(&bytes, |p| out.push(p.as_bytes().to_vec()));
    out[200..600].to_vec()
}

fn expected(packet: &[u8]) -> ImuData {
    ImuData::parse(&Packet::new_checked(packet).unwrap()).unwrap()
}

fn receive_all(dev: &mut Gx4, n: usize) -> Vec<ImuSample> {
    (0..n).map(|_| dev.next_sample().expect("sample")).collect()
}

fn check_samples(samples: &[ImuSample], packets: &[Vec<u8>]) {
    assert_eq!(samples.len(), packets.len());
    for (i, (s, p)) in samples.iter().zip(packets).enumerate() {
        let e = expected(p);
        assert_eq!(s.device_time_source, DeviceTimeSource::Gps);
        assert_eq!(
            s.device_time_ns,
            e.gps_time.unwrap().gps_ns().unwrap(),
            "sample {i}"
        );
        assert_eq!(s.gyro_rad_s, e.gyro_rad_s.unwrap().map(f64::from));
        assert_eq!(
            s.accel_m_s2,
            e.accel_g.unwrap().map(|a| a as f64 * GRAVITY_M_S2)
        );
        if i >= 1 {
            // Mapped by the clock model, and never later than the receive time (lower envelope).
            let host = s.host_time_ns.expect("clock model ready");
            assert!(
                host <= s.host_receive_ns + 1,
                "sample {i}: {host} > {}",
                s.host_receive_ns
            );
        }
    }
}

#[test]
fn configures_and_receives_every_sample() {
    let packets = recorded_packets();
    let fake = FakeGx4::start(Script {
        packets: packets.clone(),
        ..Default::default()
    });
    let mut dev = Gx4::open(fake.path(), 921_600).unwrap();
    dev.ping().unwrap();
    let info = dev.device_info().unwrap();
    assert_eq!(info.model_name.as_str(), "3DM-GX4-25");
    let format = dev.configure(200, &FIELDS).unwrap();
    assert_eq!((format.decimation, format.packet_len), (5, 82));
    let samples = receive_all(&mut dev, packets.len());
    check_samples(&samples, &packets);
    // A NACK names the command and the reason.
    let e = dev
        .command(&Command::UartBaud {
            function: Function::Apply,
            baud: 12_345,
        })
        .unwrap_err();
    assert!(matches!(e, Gx4Error::Nack { code: 3, .. }), "{e}");
    assert!(e.to_string().contains("invalid parameter"), "{e}");
    dev.stop().unwrap();
    let c = dev.counters();
    assert_eq!(c.samples, packets.len() as u64);
    assert_eq!(c.decoder.bytes_skipped, 0);
    assert_eq!(c.reopens, 0);
    drop(dev);
    let log = fake.finish();
    // The handshake, in order, after ping and device info.
    let kinds: Vec<u8> = log.commands.iter().map(|c| c.field_descriptor()).collect();
    assert_eq!(&kinds[..7], &[0x01, 0x03, 0x02, 0x06, 0x08, 0x11, 0x06]);
    assert!(matches!(
        &log.commands[4],
        Command::ImuMessageFormat { function: Function::Apply, descriptors }
            if descriptors.len() == 6 && descriptors.iter().all(|r| r.decimation == 5)
    ));
    assert_eq!(log.packets_sent, packets.len());
}

#[test]
fn garbage_on_the_line_loses_no_sample() {
    let packets = recorded_packets();
    let fake = FakeGx4::start(Script {
        packets: packets.clone(),
        garbage_every: Some(3),
        ..Default::default()
    });
    let mut dev = Gx4::open(fake.path(), 921_600).unwrap();
    dev.configure(200, &FIELDS).unwrap();
    let samples = receive_all(&mut dev, packets.len());
    check_samples(&samples, &packets);
    dev.stop().unwrap();
    let c = dev.counters();
    drop(dev);
    let log = fake.finish();
    assert!(log.garbage_bytes > 1000);
    assert_eq!(c.decoder.bytes_skipped, log.garbage_bytes as u64);
    assert!(c.decoder.checksum_failures > 100, "{c:?}");
    assert_eq!(c.bad_imu_packets, 0);
}

#[test]
fn mid_stream_disconnect_reopens_and_resumes() {
    let packets = recorded_packets();
    let fake = FakeGx4::start(Script {
        packets: packets.clone(),
        disconnect_after: Some(150),
        ..Default::default()
    });
    let mut dev = Gx4::open(fake.path(), 921_600).unwrap();
    dev.configure(200, &FIELDS).unwrap();
    let samples = receive_all(&mut dev, packets.len());
    check_samples(&samples, &packets);
    let c = dev.counters();
    assert_eq!(c.reopens, 1, "{c:?}");
    assert_eq!(c.io_errors, 1, "{c:?}");
    dev.stop().unwrap();
    drop(dev);
    let log = fake.finish();
    assert_eq!(log.connections, 2);
    // Configured twice: once at start, once after the reopen.
    let resumes = log
        .commands
        .iter()
        .filter(|c| **c == Command::Resume)
        .count();
    assert_eq!(resumes, 2);
}

#[test]
fn unreachable_port_is_a_clear_error() {
    let e = Gx4::open("/nonexistent/ttyGX4", 921_600).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.starts_with("cannot open /nonexistent/ttyGX4 at 921600 baud"),
        "{msg}"
    );
}
