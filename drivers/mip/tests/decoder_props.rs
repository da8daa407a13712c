//! Property tests of the streaming decoder and the representations (run in CI; the cargo-fuzz
//! target in `fuzz/` checks the same invariants without bounds). The RNG seed is fixed so runs
//! are reproducible.

use proptest::prelude::*;
use proptest::test_runner::{Config, RngSeed};
use vidslam_mip::command::Command;
use vidslam_mip::imu::{GpsTimestamp, ImuData};
use vidslam_mip::reply::Reply;
use vidslam_mip::{Decoder, Packet, PacketWriter};

fn config() -> Config {
    Config {
        cases: 256,
        rng_seed: RngSeed::Fixed(0x6D69_7021),
        failure_persistence: None,
        ..Config::default()
    }
}

/// A valid packet: any set, 0..6 fields of 0..40 data bytes.
fn packet() -> impl Strategy<Value = Vec<u8>> {
    (
        any::<u8>(),
        prop::collection::vec(
            (any::<u8>(), prop::collection::vec(any::<u8>(), 0..40)),
            0..6,
        ),
    )
        .prop_map(|(set, fields)| {
            let mut buf = [0u8; 261];
            let mut w = PacketWriter::new(&mut buf, set).unwrap();
            for (desc, data) in &fields {
                w.field_bytes(*desc, data).unwrap();
            }
            let n = w.finish().unwrap();
            buf[..n].to_vec()
        })
}

/// Garbage biased towards sync bytes and fake headers.
fn garbage() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(
        prop_oneof![
            4 => any::<u8>().prop_map(|b| vec![b]),
            1 => Just(vec![0x75]),
            1 => (any::<u8>(), any::<u8>()).prop_map(|(s, l)| vec![0x75, 0x65, s, l]),
        ],
        0..12,
    )
    .prop_map(|v| v.concat())
}

/// Feeds `stream` in chunks of the given sizes (cycled), then finishes; returns the packets.
fn decode(stream: &[u8], chunks: &[usize]) -> (Vec<Vec<u8>>, Decoder) {
    let mut d = Decoder::new();
    let mut out = Vec::new();
    let mut rest = stream;
    let mut i = 0;
    while !rest.is_empty() {
        let n = chunks[i % chunks.len()].clamp(1, rest.len());
        let (c, r) = rest.split_at(n);
        d.feed(c, |p| {
            // Every returned packet passes the checked view and the parsers do not panic.
            assert!(Packet::new_checked(p.as_bytes()).is_ok());
            let _ = ImuData::parse(&p);
            let _ = Reply::parse(&p);
            let _ = Command::parse(&p);
            out.push(p.as_bytes().to_vec());
        });
        rest = r;
        i += 1;
    }
    d.finish(|p| out.push(p.as_bytes().to_vec()));
    (out, d)
}

fn is_subsequence(needle: &[Vec<u8>], hay: &[Vec<u8>]) -> bool {
    let mut it = hay.iter();
    needle.iter().all(|n| it.any(|h| h == n))
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn arbitrary_bytes_never_panic_and_every_byte_is_accounted(
        bytes in prop::collection::vec(any::<u8>(), 0..2048),
        chunks in prop::collection::vec(1usize..300, 1..8),
    ) {
        let (packets, d) = decode(&bytes, &chunks);
        let s = d.stats();
        prop_assert_eq!(s.bytes_in, bytes.len() as u64);
        prop_assert_eq!(d.buffered(), 0);
        let packet_bytes: u64 = packets.iter().map(|p| p.len() as u64).sum();
        prop_assert_eq!(packet_bytes + s.bytes_skipped, s.bytes_in);
        prop_assert_eq!(s.packets, packets.len() as u64);
    }

    #[test]
    fn every_valid_packet_in_garbage_is_found(
        parts in prop::collection::vec((garbage(), packet()), 1..12),
        tail in garbage(),
        chunks in prop::collection::vec(1usize..300, 1..8),
    ) {
        let mut stream = Vec::new();
        let mut expected = Vec::new();
        for (g, p) in &parts {
            stream.extend_from_slice(g);
            stream.extend_from_slice(p);
            expected.push(p.clone());
        }
        stream.extend_from_slice(&tail);
        let (found, d) = decode(&stream, &chunks);
        prop_assert!(is_subsequence(&expected, &found), "expected {:?}\nfound {:?}", expected, found);
        // Same result fed one byte at a time and all at once.
        let (one, _) = decode(&stream, &[1]);
        let (all, _) = decode(&stream, &[usize::MAX]);
        prop_assert_eq!(&one, &found);
        prop_assert_eq!(&all, &found);
        let s = d.stats();
        let packet_bytes: u64 = found.iter().map(|p| p.len() as u64).sum();
        prop_assert_eq!(packet_bytes + s.bytes_skipped, stream.len() as u64);
    }

    #[test]
    fn imu_data_round_trips_bit_exactly(
        v in prop::array::uniform12(any::<u32>()),
        ticks in proptest::option::of(any::<u32>()),
        tow_ns in 0i64..604_800_000_000_000,
        week in any::<u16>(),
        flags in any::<u16>(),
    ) {
        let f = |i: usize| [f32::from_bits(v[i]), f32::from_bits(v[i + 1]), f32::from_bits(v[i + 2])];
        let x = ImuData {
            accel_g: Some(f(0)),
            gyro_rad_s: Some(f(3)),
            delta_theta_rad: None,
            delta_velocity_g_s: Some(f(9)),
            internal_ticks: ticks,
            gps_time: Some(GpsTimestamp::from_gps_ns(week as i64 * 604_800_000_000_000 + tow_ns, flags)),
            unknown_fields: 0,
        };
        let mut buf = [0u8; 261];
        let n = x.emit(&mut buf).unwrap();
        let y = ImuData::parse(&Packet::new_checked(&buf[..n]).unwrap()).unwrap();
        let mut again = [0u8; 261];
        let m = y.emit(&mut again).unwrap();
        prop_assert_eq!(&buf[..n], &again[..m]);
    }
}
