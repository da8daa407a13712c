//! Arbitrary bytes in arbitrary chunkings through the streaming decoder and every parser.
//! Invariants: no panic; every input byte is in a packet or counted as skipped; every packet
//! returned passes the checked view; the chunking does not change the packets found.
#![no_main]

use libfuzzer_sys::fuzz_target;
use vidslam_mip::command::Command;
use vidslam_mip::imu::ImuData;
use vidslam_mip::reply::Reply;
use vidslam_mip::{Decoder, Packet};

fn decode(data: &[u8], chunk: usize) -> (Vec<Vec<u8>>, u64) {
    let mut d = Decoder::new();
    let mut out = Vec::new();
    for c in data.chunks(chunk.max(1)) {
        d.feed(c, |p| {
            assert!(Packet::new_checked(p.as_bytes()).is_ok());
            let _ = ImuData::parse(&p);
            let _ = Reply::parse(&p);
            let _ = Command::parse(&p);
            out.push(p.as_bytes().to_vec());
        });
    }
    d.finish(|p| out.push(p.as_bytes().to_vec()));
    let s = d.stats();
    let in_packets: u64 = out.iter().map(|p| p.len() as u64).sum();
    assert_eq!(in_packets + s.bytes_skipped, data.len() as u64);
    (out, s.packets)
}

fuzz_target!(|data: &[u8]| {
    // The first byte picks a chunk size; the rest is the stream.
    let Some((&k, stream)) = data.split_first() else {
        return;
    };
    let (a, _) = decode(stream, k as usize + 1);
    let (b, _) = decode(stream, stream.len().max(1));
    assert_eq!(a, b);
});
