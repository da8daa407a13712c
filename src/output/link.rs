//! A MAVLink 2 link over one UDP socket: framing and CRC by the `mavlink` crate, one sequence
//! counter for every message we send, and the peer address policy of the endpoint kind.

use crate::output::endpoint::OpenEndpoint;
use mavlink::dialects::common::MavMessage;
use mavlink::{MAVLinkMessageRaw, MavHeader, MavlinkReader, MavlinkVersion, Message};
use std::io;
use std::net::{SocketAddr, UdpSocket};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU8, Ordering};
use std::time::Duration;

/// Result of a send attempt that did not fail at the socket.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sent {
    Yes,
    /// `udpin` and nobody has sent us anything yet: there is no destination.
    NoPeer,
}

/// Shared by the sender and receiver threads (all methods take `&self`).
#[derive(Debug)]
pub struct Link {
    socket: UdpSocket,
    fixed_peer: Option<SocketAddr>,
    learned_peer: Mutex<Option<SocketAddr>>,
    sequence: AtomicU8,
    system_id: u8,
    component_id: u8,
}

impl Link {
    /// Wraps an opened endpoint; `recv` returns after at most `read_timeout`.
    pub fn new(
        open: OpenEndpoint,
        system_id: u8,
        component_id: u8,
        read_timeout: Duration,
    ) -> io::Result<Self> {
        open.socket.set_read_timeout(Some(read_timeout))?;
        Ok(Link {
            socket: open.socket,
            fixed_peer: open.fixed_peer,
            learned_peer: Mutex::new(None),
            sequence: AtomicU8::new(0),
            system_id,
            component_id,
        })
    }

    /// Our own header identity (sequence 0).
    pub fn own_header(&self) -> MavHeader {
        MavHeader {
            system_id: u32::from(self.system_id),
            component_id: self.component_id,
            sequence: 0,
        }
    }

    /// The local address of the socket.
    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    fn peer(&self) -> Option<SocketAddr> {
        self.fixed_peer
            .or(*self.learned_peer.lock().unwrap_or_else(|e| e.into_inner()))
    }

    /// Frames `msg` as MAVLink 2 and sends it as one datagram.
    pub fn send(&self, msg: &MavMessage) -> io::Result<Sent> {
        let Some(peer) = self.peer() else {
            return Ok(Sent::NoPeer);
        };
        let header = MavHeader {
            sequence: self.sequence.fetch_add(1, Ordering::Relaxed),
            ..self.own_header()
        };
        let mut buf = Vec::with_capacity(280);
        mavlink::write_v2_msg(&mut buf, header, msg).map_err(io::Error::other)?;
        self.socket.send_to(&buf, peer)?;
        Ok(Sent::Yes)
    }

    /// Receives one datagram into `buf`; `Ok(None)` on timeout. Remembers the sender as the
    /// destination (udpin).
    pub fn recv(&self, buf: &mut [u8]) -> io::Result<Option<(usize, SocketAddr)>> {
        match self.socket.recv_from(buf) {
            Ok((n, from)) => {
                if self.fixed_peer.is_none() {
                    *self.learned_peer.lock().unwrap_or_else(|e| e.into_inner()) = Some(from);
                }
                Ok(Some((n, from)))
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                Ok(None)
            }
            Err(e) => Err(e),
        }
    }
}

/// The messages of one datagram that pass the CRC (MAVLink 1 or 2, common dialect), and the
/// number of bytes that belonged to no such message (corrupt, truncated, or of another dialect).
pub fn decode_datagram(bytes: &[u8]) -> (Vec<(MavHeader, MavMessage)>, usize) {
    let mut reader = MavlinkReader::new(bytes);
    let mut out = Vec::new();
    let mut used = 0usize;
    while let Ok(raw) = reader.read_any_raw_message::<MavMessage>() {
        let (version, len) = match &raw {
            MAVLinkMessageRaw::V1(r) => (MavlinkVersion::V1, r.raw_bytes().len()),
            MAVLinkMessageRaw::V2(r) => (MavlinkVersion::V2, r.raw_bytes().len()),
        };
        let header = MavHeader {
            system_id: raw.system_id(),
            component_id: raw.component_id(),
            sequence: raw.sequence(),
        };
        // A CRC-valid frame whose payload still does not parse (e.g. an invalid enum value) is
        // counted as skipped bytes too.
        if let Ok(msg) = MavMessage::parse(version, raw.message_id(), raw.payload()) {
            used += len;
            out.push((header, msg));
        }
    }
    (out, bytes.len().saturating_sub(used))
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::TIMESYNC_DATA;

    fn frame(seq: u8, msg: &MavMessage) -> Vec<u8> {
        let mut buf = Vec::new();
        let h = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: seq,
        };
        mavlink::write_v2_msg(&mut buf, h, msg).unwrap();
        buf
    }

    #[test]
    fn decodes_frames_and_counts_garbage() {
        let ts = MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 0,
            ts1: 42,
            ..Default::default()
        });
        let a = frame(7, &ts);
        let mut corrupt = frame(8, &ts);
        let last = corrupt.len() - 1;
        corrupt[last] ^= 0xff; // CRC byte
        let mut data = b"junk".to_vec();
        data.extend(&a);
        data.extend(&corrupt);
        data.extend(&a);
        let (msgs, skipped) = decode_datagram(&data);
        assert_eq!(msgs.len(), 2);
        assert_eq!(msgs[0].0.sequence, 7);
        assert!(matches!(&msgs[1].1, MavMessage::TIMESYNC(t) if t.ts1 == 42));
        assert_eq!(skipped, 4 + corrupt.len());
    }
}
