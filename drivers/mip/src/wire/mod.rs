//! Zero-copy MIP packet and field views, checksum, and the packet writer.

mod bytes;
mod packet;

pub use bytes::{get_f32, get_f64, get_u8, get_u16, get_u32, put_f32, put_f64, put_u16, put_u32};
pub use packet::{Field, Fields, Packet, PacketWriter};

/// First sync byte.
pub const SYNC1: u8 = 0x75;
/// Second sync byte.
pub const SYNC2: u8 = 0x65;
/// Sync (2) + descriptor set (1) + payload length (1).
pub const HEADER_LEN: usize = 4;
/// Fletcher-16, two bytes.
pub const CHECKSUM_LEN: usize = 2;
/// The payload length is one byte.
pub const MAX_PAYLOAD_LEN: usize = 255;
/// Longest possible packet: 261 bytes.
pub const MAX_PACKET_LEN: usize = HEADER_LEN + MAX_PAYLOAD_LEN + CHECKSUM_LEN;
/// A field's length byte counts its own 2 header bytes (length, descriptor).
pub const FIELD_HEADER_LEN: usize = 2;

/// What is wrong with a packet, a field or an output buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Error {
    /// Fewer bytes than the header or the declared length needs.
    Truncated,
    /// The buffer does not start with `0x75 0x65`.
    BadSync,
    /// Fletcher-16 mismatch: `computed` over the bytes vs `stored` in the packet.
    BadChecksum { computed: u16, stored: u16 },
    /// A field length below 2 or running past the payload end.
    BadFieldLength { offset: usize, len: u8 },
    /// A field whose data length does not match its descriptor's format.
    BadFieldData { descriptor: u8, len: usize },
    /// A descriptor (set, field) this representation does not handle.
    Unexpected { set: u8, field: u8 },
    /// The output buffer or the 255-byte payload limit is too small for what is being emitted.
    NoSpace,
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Error::Truncated => write!(f, "truncated MIP packet"),
            Error::BadSync => write!(f, "missing MIP sync bytes 0x75 0x65"),
            Error::BadChecksum { computed, stored } => write!(
                f,
                "MIP checksum mismatch: computed {computed:#06x}, packet says {stored:#06x}"
            ),
            Error::BadFieldLength { offset, len } => {
                write!(
                    f,
                    "MIP field at payload offset {offset} has invalid length {len}"
                )
            }
            Error::BadFieldData { descriptor, len } => {
                write!(
                    f,
                    "MIP field {descriptor:#04x} has unexpected data length {len}"
                )
            }
            Error::Unexpected { set, field } => {
                write!(
                    f,
                    "unexpected MIP descriptor set {set:#04x} field {field:#04x}"
                )
            }
            Error::NoSpace => write!(f, "MIP packet does not fit (255-byte payload or buffer)"),
        }
    }
}

impl core::error::Error for Error {}

/// Fletcher-16 as MIP defines it: `sum1 = Σ bytes mod 256`, `sum2 = Σ (running sum1) mod 256`,
/// sent as `sum1, sum2`; returned as `u16::from_be_bytes([sum1, sum2])` (wire order).
pub fn fletcher16(bytes: &[u8]) -> u16 {
    let mut sum1: u8 = 0;
    let mut sum2: u8 = 0;
    for &b in bytes {
        sum1 = sum1.wrapping_add(b);
        sum2 = sum2.wrapping_add(sum1);
    }
    u16::from_be_bytes([sum1, sum2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fletcher_of_ping() {
        assert_eq!(fletcher16(&[0x75, 0x65, 0x01, 0x02, 0x02, 0x01]), 0xE0C6);
        assert_eq!(fletcher16(&[0x75, 0x65, 0x0C, 0x02, 0x02, 0x06]), 0xF0F7);
        assert_eq!(fletcher16(&[]), 0);
    }
}
