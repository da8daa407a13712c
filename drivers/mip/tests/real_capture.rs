//! The real MIP byte stream from the MIP SDK's test data (a newer MicroStrain device: same framing
//! and checksum, other field set) decodes completely. Skips when the shared data is absent.

use std::path::PathBuf;
use vidslam_mip::Decoder;

fn shared_data() -> Option<PathBuf> {
    let dir = std::env::var_os("VIDSLAM_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    dir.is_dir().then_some(dir)
}

#[test]
fn sdk_capture_decodes_exactly() {
    let Some(dir) = shared_data() else {
        eprintln!("skipped: shared data not found (set VIDSLAM_DATA)");
        return;
    };
    let path = dir.join("mip/mip_sdk_test_capture.bin");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(bytes.len(), 368_940);
    // Same result in 1-byte chunks, odd chunks and all at once.
    for chunk in [1usize, 61, 65_536, bytes.len()] {
        let mut d = Decoder::new();
        let mut per_set = std::collections::BTreeMap::<u8, u64>::new();
        let mut packet_bytes = 0u64;
        for c in bytes.chunks(chunk) {
            d.feed(c, |p| {
                *per_set.entry(p.descriptor_set()).or_default() += 1;
                packet_bytes += p.as_bytes().len() as u64;
            });
        }
        d.finish(|_| panic!("no packet should be pending at the end"));
        let s = d.stats();
        assert_eq!(s.packets, 8_384, "chunk {chunk}");
        assert_eq!(s.checksum_failures, 0);
        assert_eq!(s.malformed_packets, 0);
        assert_eq!(s.bytes_skipped, 0);
        assert_eq!(packet_bytes, bytes.len() as u64);
        if chunk == 1 {
            eprintln!("per set: {per_set:x?}, stats: {s:?}");
        }
        // IMU, filter and 0xA0 data, plus a few base-set (0x01) command replies.
        assert_eq!(
            per_set.keys().copied().collect::<Vec<_>>(),
            vec![0x01, 0x80, 0x82, 0xA0]
        );
        // Sets 0x82 and 0xA0 are not interpreted: skipped and counted.
        assert_eq!(s.unknown_sets, per_set[&0x82] + per_set[&0xA0]);
        // 0x80 carries fields the GX4 does not have (magnetometer, shared timestamps).
        assert!(s.unknown_fields > 0);
    }
}
