//! Streaming packet decoder: bytes in arbitrary chunks → checked packets, with resynchronisation.
//!
//! The decoder keeps at most one candidate packet (≤ 261 bytes) in a fixed buffer. A candidate
//! starts at `0x75 0x65`; once its declared length is buffered the Fletcher-16 decides. On a
//! mismatch only the first sync byte is discarded and the buffered bytes are scanned again, so a
//! valid packet that starts inside a corrupt or fake candidate (garbage that happens to contain
//! `0x75 0x65`) is still found. Each input byte ends up in exactly one of: a returned packet,
//! [`DecoderStats::bytes_skipped`], or the buffer ([`Decoder::buffered`]).

use crate::descriptor::{is_known_field, is_known_set};
use crate::wire::{
    CHECKSUM_LEN, HEADER_LEN, MAX_PACKET_LEN, Packet, SYNC1, SYNC2, fletcher16, get_u16,
};

/// Counters of a [`Decoder`]; they only grow.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Bytes given to the decoder.
    pub bytes_in: u64,
    /// Packets with a valid checksum returned.
    pub packets: u64,
    /// Bytes discarded: garbage between packets, the first byte of each failed candidate, and a
    /// trailing partial packet at [`Decoder::pull_at_end`].
    pub bytes_skipped: u64,
    /// Candidates (sync + length) whose checksum did not match.
    pub checksum_failures: u64,
    /// Valid packets whose fields do not tile the payload (a field length runs past the end).
    pub malformed_packets: u64,
    /// Valid packets of a descriptor set this crate does not interpret.
    pub unknown_sets: u64,
    /// Fields of an interpreted set with a descriptor this crate does not interpret.
    pub unknown_fields: u64,
}

/// Streaming MIP decoder. See the module docs.
#[derive(Clone, Debug)]
pub struct Decoder {
    buf: [u8; MAX_PACKET_LEN],
    len: usize,
    /// Length of the packet returned by the previous call, dropped at the next call.
    consume: usize,
    stats: DecoderStats,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    pub const fn new() -> Self {
        Decoder {
            buf: [0; MAX_PACKET_LEN],
            len: 0,
            consume: 0,
            stats: DecoderStats {
                bytes_in: 0,
                packets: 0,
                bytes_skipped: 0,
                checksum_failures: 0,
                malformed_packets: 0,
                unknown_sets: 0,
                unknown_fields: 0,
            },
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> &DecoderStats {
        &self.stats
    }

    /// Bytes held for an incomplete candidate packet.
    pub fn buffered(&self) -> usize {
        self.len - self.consume
    }

    /// Forgets the buffered candidate (counted as skipped), e.g. after reopening a port.
    pub fn reset(&mut self) {
        self.release();
        self.skip(self.len);
    }

    /// Consumes bytes from the front of `input` until a packet is complete and returns it, or
    /// returns `None` once `input` is exhausted (the bytes are kept for the next call).
    pub fn pull<'s>(&'s mut self, input: &mut &[u8]) -> Option<Packet<&'s [u8]>> {
        self.next_packet(input, false)
    }

    /// At end of stream: returns the packets still hidden in the buffered bytes (call until
    /// `None`); a trailing incomplete packet is counted as skipped.
    pub fn pull_at_end(&mut self) -> Option<Packet<&[u8]>> {
        self.next_packet(&mut &[][..], true)
    }

    /// Feeds a chunk and calls `on_packet` for every packet completed by it.
    pub fn feed(&mut self, mut chunk: &[u8], mut on_packet: impl FnMut(Packet<&[u8]>)) {
        while let Some(p) = self.pull(&mut chunk) {
            on_packet(p);
        }
    }

    /// [`Decoder::pull_at_end`] for every remaining packet.
    pub fn finish(&mut self, mut on_packet: impl FnMut(Packet<&[u8]>)) {
        while let Some(p) = self.pull_at_end() {
            on_packet(p);
        }
    }

    fn next_packet<'s>(&'s mut self, input: &mut &[u8], at_end: bool) -> Option<Packet<&'s [u8]>> {
        self.release();
        loop {
            self.align();
            if self.len == 0 {
                // Nothing buffered: skip garbage in the input without copying it.
                match input.iter().position(|&b| b == SYNC1) {
                    None => {
                        self.take_input(input, input.len());
                        return None;
                    }
                    Some(i) => {
                        self.take_input(input, i);
                    }
                }
                if input.is_empty() {
                    return None;
                }
            }
            let need = if self.len < HEADER_LEN {
                HEADER_LEN
            } else {
                HEADER_LEN + self.buf.get(3).copied().unwrap_or(0) as usize + CHECKSUM_LEN
            };
            if self.len < need {
                if input.is_empty() {
                    if at_end && self.len > 0 {
                        // Incomplete candidate at end of stream: drop its first byte, rescan.
                        self.skip(1);
                        continue;
                    }
                    return None;
                }
                let take = (need - self.len).min(input.len());
                let (head, rest) = input.split_at(take);
                if let Some(dst) = self.buf.get_mut(self.len..self.len + take) {
                    dst.copy_from_slice(head);
                }
                self.len += take;
                self.stats.bytes_in += take as u64;
                *input = rest;
                continue;
            }
            let body = self.buf.get(..need - CHECKSUM_LEN).unwrap_or(&[]);
            let stored = get_u16(&self.buf, need - CHECKSUM_LEN).unwrap_or(0);
            if fletcher16(body) == stored {
                self.consume = need;
                self.stats.packets += 1;
                let packet = Packet::new_unchecked(self.buf.get(..need).unwrap_or(&[]));
                classify(&packet, &mut self.stats);
                return Some(packet);
            }
            self.stats.checksum_failures += 1;
            self.skip(1);
        }
    }

    /// Drops the packet returned by the previous call.
    fn release(&mut self) {
        if self.consume > 0 {
            self.buf.copy_within(self.consume..self.len, 0);
            self.len -= self.consume;
            self.consume = 0;
        }
    }

    /// Discards `n` buffered bytes as skipped.
    fn skip(&mut self, n: usize) {
        let n = n.min(self.len);
        self.buf.copy_within(n..self.len, 0);
        self.len -= n;
        self.stats.bytes_skipped += n as u64;
    }

    /// Discards `n` input bytes as skipped (only with an empty buffer).
    fn take_input(&mut self, input: &mut &[u8], n: usize) {
        let n = n.min(input.len());
        *input = input.get(n..).unwrap_or(&[]);
        self.stats.bytes_in += n as u64;
        self.stats.bytes_skipped += n as u64;
    }

    /// Drops buffered bytes before the first possible packet start.
    fn align(&mut self) {
        let b = self.buf.get(..self.len).unwrap_or(&[]);
        let start = (0..b.len())
            .find(|&i| b.get(i) == Some(&SYNC1) && b.get(i + 1).is_none_or(|&next| next == SYNC2))
            .unwrap_or(b.len());
        if start > 0 {
            self.skip(start);
        }
    }
}

fn classify(packet: &Packet<&[u8]>, stats: &mut DecoderStats) {
    let set = packet.descriptor_set();
    if !is_known_set(set) {
        stats.unknown_sets += 1;
        if packet.fields().any(|f| f.is_err()) {
            stats.malformed_packets += 1;
        }
        return;
    }
    for field in packet.fields() {
        match field {
            Ok(f) if !is_known_field(set, f.descriptor()) => stats.unknown_fields += 1,
            Ok(_) => {}
            Err(_) => stats.malformed_packets += 1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PING: [u8; 8] = [0x75, 0x65, 0x01, 0x02, 0x02, 0x01, 0xE0, 0xC6];

    fn decode_all(stream: &[u8], chunk: usize) -> (Vec<Vec<u8>>, DecoderStats) {
        let mut d = Decoder::new();
        let mut out = Vec::new();
        for c in stream.chunks(chunk.max(1)) {
            d.feed(c, |p| out.push(p.as_bytes().to_vec()));
        }
        d.finish(|p| out.push(p.as_bytes().to_vec()));
        (out, *d.stats())
    }

    #[test]
    fn garbage_and_fake_sync_before_a_packet() {
        // Fake header claiming 200 bytes of payload, then a real ping right after.
        let mut s = vec![0x00, 0x75, 0x13, 0x75, 0x65, 0x80, 200];
        s.extend_from_slice(&PING);
        s.extend_from_slice(&[0xAA; 3]);
        s.extend_from_slice(&PING);
        for chunk in [1, 2, 3, 7, 64, 65_536] {
            let (packets, stats) = decode_all(&s, chunk);
            assert_eq!(packets, vec![PING.to_vec(), PING.to_vec()], "chunk {chunk}");
            assert_eq!(stats.packets, 2);
            assert_eq!(stats.bytes_in, s.len() as u64);
            assert_eq!(stats.bytes_skipped, s.len() as u64 - 16);
        }
    }

    #[test]
    fn bad_checksum_then_valid_packet() {
        let mut bad = PING;
        bad[7] ^= 0xFF;
        let mut s = bad.to_vec();
        s.extend_from_slice(&PING);
        let (packets, stats) = decode_all(&s, 5);
        assert_eq!(packets, vec![PING.to_vec()]);
        assert_eq!(stats.checksum_failures, 1);
        assert_eq!(stats.bytes_skipped, 8);
    }

    #[test]
    fn unknown_set_and_field_are_counted() {
        let mut buf = [0u8; 32];
        let mut w = crate::PacketWriter::new(&mut buf, 0xA0).unwrap();
        w.field_bytes(0x01, &[1]).unwrap();
        let n = w.finish().unwrap();
        let mut s = buf[..n].to_vec();
        let mut w = crate::PacketWriter::new(&mut buf, 0x80).unwrap();
        w.field_bytes(0x06, &[0; 12]).unwrap();
        w.field_bytes(0x0E, &[0; 4]).unwrap();
        let n = w.finish().unwrap();
        s.extend_from_slice(&buf[..n]);
        let (packets, stats) = decode_all(&s, 4);
        assert_eq!(packets.len(), 2);
        assert_eq!(stats.unknown_sets, 1);
        assert_eq!(stats.unknown_fields, 1);
        assert_eq!(stats.malformed_packets, 0);
    }
}
