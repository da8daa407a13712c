//! Device replies: the ACK/NACK field (0xF1) and the reply data fields of the commands we send.

use crate::command::{DescriptorRates, read_rates, write_rates};
use crate::descriptor::{ACK_NACK, base, dm3};
use crate::wire::{Error, Packet, PacketWriter, get_u8, get_u16, get_u32, put_u16, put_u32};

/// Error code of an ACK/NACK field.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AckCode {
    /// 0x00: the command succeeded.
    Ok,
    /// 0x01: the device does not know the command.
    UnknownCommand,
    /// 0x02: the device computed a different checksum for the command packet.
    InvalidChecksum,
    /// 0x03: a parameter is missing, invalid or unsupported.
    InvalidParameter,
    /// 0x04: the command could not be executed.
    CommandFailed,
    /// 0x05: the command timed out inside the device.
    CommandTimeout,
    /// Any other code.
    Other(u8),
}

impl AckCode {
    pub fn from_u8(v: u8) -> Self {
        match v {
            0 => AckCode::Ok,
            1 => AckCode::UnknownCommand,
            2 => AckCode::InvalidChecksum,
            3 => AckCode::InvalidParameter,
            4 => AckCode::CommandFailed,
            5 => AckCode::CommandTimeout,
            other => AckCode::Other(other),
        }
    }
    pub fn to_u8(self) -> u8 {
        match self {
            AckCode::Ok => 0,
            AckCode::UnknownCommand => 1,
            AckCode::InvalidChecksum => 2,
            AckCode::InvalidParameter => 3,
            AckCode::CommandFailed => 4,
            AckCode::CommandTimeout => 5,
            AckCode::Other(v) => v,
        }
    }
    /// What the code means, for error messages.
    pub fn describe(self) -> &'static str {
        match self {
            AckCode::Ok => "ok",
            AckCode::UnknownCommand => "unknown command",
            AckCode::InvalidChecksum => "device saw an invalid checksum",
            AckCode::InvalidParameter => "invalid parameter",
            AckCode::CommandFailed => "command failed",
            AckCode::CommandTimeout => "command timed out in the device",
            AckCode::Other(_) => "unknown error code",
        }
    }
}

/// The ACK/NACK field: which command it answers and the outcome.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ack {
    /// Field descriptor of the command being answered.
    pub command: u8,
    pub code: AckCode,
}

/// Length of each string of the device information reply, bytes.
pub const DEVICE_INFO_STR_LEN: usize = 16;
type InfoStr = heapless::String<DEVICE_INFO_STR_LEN>;

/// Device information (base reply 0x81): firmware version and five 16-character strings.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DeviceInfo {
    pub firmware_version: u16,
    pub model_name: InfoStr,
    pub model_number: InfoStr,
    pub serial_number: InfoStr,
    pub lot_number: InfoStr,
    pub device_options: InfoStr,
}

/// Reply data that accompanies an ACK.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ReplyData {
    DeviceInfo(DeviceInfo),
    ImuBaseRate { rate_hz: u16 },
    ImuMessageFormat(DescriptorRates),
    StreamEnabled { device: u8, enabled: bool },
    UartBaud { baud: u32 },
}

/// A reply packet: the ACK/NACK and, for queries, the data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Reply {
    pub descriptor_set: u8,
    pub ack: Ack,
    pub data: Option<ReplyData>,
}

fn info_str(b: &[u8]) -> InfoStr {
    // Space-padded ASCII; keep printable ASCII only, trim padding.
    let mut s = InfoStr::new();
    for &c in b {
        if (0x20..0x7F).contains(&c) {
            let _ = s.push(c as char);
        }
    }
    let trimmed_len = s.trim_end().len();
    s.truncate(trimmed_len);
    s
}

impl Reply {
    /// Parses a reply packet; `Err(Unexpected)` if it has no ACK/NACK field (e.g. a data packet).
    pub fn parse<T: AsRef<[u8]>>(packet: &Packet<T>) -> Result<Self, Error> {
        let set = packet.descriptor_set();
        let mut ack = None;
        let mut data = None;
        for field in packet.fields() {
            let field = field?;
            let d = field.data();
            let bad = Error::BadFieldData {
                descriptor: field.descriptor(),
                len: d.len(),
            };
            match (set, field.descriptor()) {
                (_, ACK_NACK) => {
                    if d.len() != 2 {
                        return Err(bad);
                    }
                    ack = Some(Ack {
                        command: get_u8(d, 0).ok_or(bad)?,
                        code: AckCode::from_u8(get_u8(d, 1).ok_or(bad)?),
                    });
                }
                (base::SET, base::REPLY_DEVICE_INFO) => {
                    if d.len() != 2 + 5 * DEVICE_INFO_STR_LEN {
                        return Err(bad);
                    }
                    let s = |i: usize| {
                        let at = 2 + i * DEVICE_INFO_STR_LEN;
                        info_str(d.get(at..at + DEVICE_INFO_STR_LEN).unwrap_or(&[]))
                    };
                    data = Some(ReplyData::DeviceInfo(DeviceInfo {
                        firmware_version: get_u16(d, 0).ok_or(bad)?,
                        model_name: s(0),
                        model_number: s(1),
                        serial_number: s(2),
                        lot_number: s(3),
                        device_options: s(4),
                    }));
                }
                (dm3::SET, dm3::REPLY_IMU_BASE_RATE) => {
                    data = Some(ReplyData::ImuBaseRate {
                        rate_hz: get_u16(d, 0).ok_or(bad)?,
                    })
                }
                (dm3::SET, dm3::REPLY_IMU_MESSAGE_FORMAT) => {
                    data = Some(ReplyData::ImuMessageFormat(read_rates(d).ok_or(bad)?))
                }
                (dm3::SET, dm3::REPLY_ENABLE_STREAM) => {
                    data = Some(ReplyData::StreamEnabled {
                        device: get_u8(d, 0).ok_or(bad)?,
                        enabled: get_u8(d, 1).ok_or(bad)? != 0,
                    })
                }
                (dm3::SET, dm3::REPLY_UART_BAUD) => {
                    data = Some(ReplyData::UartBaud {
                        baud: get_u32(d, 0).ok_or(bad)?,
                    })
                }
                _ => {}
            }
        }
        let ack = ack.ok_or(Error::Unexpected {
            set,
            field: ACK_NACK,
        })?;
        Ok(Reply {
            descriptor_set: set,
            ack,
            data,
        })
    }

    /// Emits the reply as a complete packet into `buf`; returns its length.
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, Error> {
        let mut w = PacketWriter::new(buf, self.descriptor_set)?;
        w.field_bytes(ACK_NACK, &[self.ack.command, self.ack.code.to_u8()])?;
        let no_space = |ok: bool| if ok { Ok(()) } else { Err(Error::NoSpace) };
        match &self.data {
            None => {}
            Some(ReplyData::DeviceInfo(info)) => {
                w.field(base::REPLY_DEVICE_INFO, 2 + 5 * DEVICE_INFO_STR_LEN, |b| {
                    let strs = [
                        &info.model_name,
                        &info.model_number,
                        &info.serial_number,
                        &info.lot_number,
                        &info.device_options,
                    ];
                    for (i, s) in strs.iter().enumerate() {
                        let at = 2 + i * DEVICE_INFO_STR_LEN;
                        let dst = b
                            .get_mut(at..at + DEVICE_INFO_STR_LEN)
                            .ok_or(Error::NoSpace)?;
                        dst.fill(b' ');
                        let src = s.as_bytes();
                        dst.get_mut(..src.len())
                            .ok_or(Error::NoSpace)?
                            .copy_from_slice(src);
                    }
                    no_space(put_u16(b, 0, info.firmware_version))
                })?;
            }
            Some(ReplyData::ImuBaseRate { rate_hz }) => {
                w.field(dm3::REPLY_IMU_BASE_RATE, 2, |b| {
                    no_space(put_u16(b, 0, *rate_hz))
                })?;
            }
            Some(ReplyData::ImuMessageFormat(rates)) => {
                w.field(dm3::REPLY_IMU_MESSAGE_FORMAT, 1 + 3 * rates.len(), |b| {
                    no_space(write_rates(b, rates))
                })?;
            }
            Some(ReplyData::StreamEnabled { device, enabled }) => {
                w.field_bytes(dm3::REPLY_ENABLE_STREAM, &[*device, *enabled as u8])?;
            }
            Some(ReplyData::UartBaud { baud }) => {
                w.field(dm3::REPLY_UART_BAUD, 4, |b| no_space(put_u32(b, 0, *baud)))?;
            }
        }
        w.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::command::DescriptorRate;

    fn round_trip(r: &Reply) {
        let mut buf = [0u8; 261];
        let n = r.emit(&mut buf).unwrap();
        let p = Packet::new_checked(&buf[..n]).unwrap();
        assert_eq!(&Reply::parse(&p).unwrap(), r);
    }

    #[test]
    fn ping_ack_is_byte_exact() {
        let r = Reply {
            descriptor_set: 0x01,
            ack: Ack {
                command: 0x01,
                code: AckCode::Ok,
            },
            data: None,
        };
        let mut buf = [0u8; 16];
        let n = r.emit(&mut buf).unwrap();
        // Header, field 04 F1 01 00, Fletcher-16 worked by hand.
        assert_eq!(
            &buf[..n],
            &[0x75, 0x65, 0x01, 0x04, 0x04, 0xF1, 0x01, 0x00, 0xD5, 0x6A]
        );
    }

    #[test]
    fn replies_round_trip() {
        let mut rates = DescriptorRates::new();
        rates
            .push(DescriptorRate {
                descriptor: 0x12,
                decimation: 5,
            })
            .unwrap();
        let mut info = DeviceInfo {
            firmware_version: 1102,
            ..Default::default()
        };
        info.model_name.push_str("3DM-GX4-25").unwrap();
        info.serial_number.push_str("6234.12345").unwrap();
        let ack = |c| Ack {
            command: c,
            code: AckCode::Ok,
        };
        for (set, cmd, data) in [
            (0x01, 0x03, Some(ReplyData::DeviceInfo(info))),
            (0x0C, 0x06, Some(ReplyData::ImuBaseRate { rate_hz: 1000 })),
            (0x0C, 0x08, Some(ReplyData::ImuMessageFormat(rates))),
            (
                0x0C,
                0x11,
                Some(ReplyData::StreamEnabled {
                    device: 1,
                    enabled: true,
                }),
            ),
            (0x0C, 0x40, Some(ReplyData::UartBaud { baud: 921_600 })),
            (0x0C, 0x30, None),
        ] {
            round_trip(&Reply {
                descriptor_set: set,
                ack: ack(cmd),
                data,
            });
        }
        round_trip(&Reply {
            descriptor_set: 0x0C,
            ack: Ack {
                command: 0x08,
                code: AckCode::InvalidParameter,
            },
            data: None,
        });
    }
}
