//! Commands the driver sends (base set 0x01, 3DM set 0x0C): parsed representation, `emit` and
//! `parse` (the fake device in the tests parses what the driver emits).

use crate::descriptor::{base, dm3};
use crate::wire::{Error, Field, Packet, PacketWriter, get_u8, get_u16, get_u32, put_u16, put_u32};

/// Most descriptors in one IMU message format command (the GX4 has fewer IMU fields than this).
pub const MAX_FORMAT_DESCRIPTORS: usize = 16;

/// Device selector of the 3DM "enable/disable continuous stream" command: the IMU data stream.
pub const STREAM_IMU: u8 = 0x01;

/// Function selector of the 3DM settings commands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Function {
    /// Use the new settings (0x01).
    Apply,
    /// Read back the current settings (0x02).
    Read,
    /// Save the current settings as startup settings (0x03).
    Save,
    /// Load the saved startup settings (0x04).
    Load,
    /// Load factory defaults (0x05).
    Default,
}

impl Function {
    pub fn to_u8(self) -> u8 {
        match self {
            Function::Apply => 1,
            Function::Read => 2,
            Function::Save => 3,
            Function::Load => 4,
            Function::Default => 5,
        }
    }
    pub fn from_u8(v: u8) -> Option<Self> {
        Some(match v {
            1 => Function::Apply,
            2 => Function::Read,
            3 => Function::Save,
            4 => Function::Load,
            5 => Function::Default,
            _ => return None,
        })
    }
}

/// A data field descriptor with its decimation from the IMU base rate (rate = base / decimation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DescriptorRate {
    pub descriptor: u8,
    pub decimation: u16,
}

/// A list of descriptor rates (fixed capacity, no allocation).
pub type DescriptorRates = heapless::Vec<DescriptorRate, MAX_FORMAT_DESCRIPTORS>;

/// A command the driver can send.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Command {
    /// Base 0x01: is the device there?
    Ping,
    /// Base 0x02: stop streaming, wait for commands.
    SetIdle,
    /// Base 0x03: firmware version, model, serial number.
    GetDeviceInfo,
    /// Base 0x06: return to the mode before idle (streaming).
    Resume,
    /// Base 0x7E: soft reset of the device.
    SoftReset,
    /// 3DM 0x06: the IMU data base rate (Hz); decimations divide it.
    GetImuBaseRate,
    /// 3DM 0x08: the IMU message format (which fields, at which decimation).
    ImuMessageFormat {
        function: Function,
        descriptors: DescriptorRates,
    },
    /// 3DM 0x11: enable or disable a continuous data stream.
    EnableStream {
        function: Function,
        device: u8,
        enable: bool,
    },
    /// 3DM 0x30: save the current settings as startup settings.
    SaveStartupSettings,
    /// 3DM 0x40: UART baud rate.
    UartBaud { function: Function, baud: u32 },
}

impl Command {
    /// Descriptor set of the command.
    pub fn descriptor_set(&self) -> u8 {
        match self {
            Command::Ping
            | Command::SetIdle
            | Command::GetDeviceInfo
            | Command::Resume
            | Command::SoftReset => base::SET,
            _ => dm3::SET,
        }
    }

    /// Field descriptor of the command (echoed in the device's ACK/NACK).
    pub fn field_descriptor(&self) -> u8 {
        match self {
            Command::Ping => base::PING,
            Command::SetIdle => base::SET_IDLE,
            Command::GetDeviceInfo => base::GET_DEVICE_INFO,
            Command::Resume => base::RESUME,
            Command::SoftReset => base::SOFT_RESET,
            Command::GetImuBaseRate => dm3::GET_IMU_BASE_RATE,
            Command::ImuMessageFormat { .. } => dm3::IMU_MESSAGE_FORMAT,
            Command::EnableStream { .. } => dm3::ENABLE_STREAM,
            Command::SaveStartupSettings => dm3::SAVE_STARTUP_SETTINGS,
            Command::UartBaud { .. } => dm3::UART_BAUD,
        }
    }

    fn data_len(&self) -> usize {
        match self {
            Command::ImuMessageFormat {
                function: Function::Apply,
                descriptors,
            } => 2 + 3 * descriptors.len(),
            Command::ImuMessageFormat { .. } => 1,
            Command::EnableStream {
                function: Function::Apply,
                ..
            } => 3,
            Command::EnableStream { .. } => 2,
            Command::SaveStartupSettings => 1,
            Command::UartBaud {
                function: Function::Apply,
                ..
            } => 5,
            Command::UartBaud { .. } => 1,
            _ => 0,
        }
    }

    /// Emits the command as a complete packet into `buf`; returns its length.
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, Error> {
        let mut w = PacketWriter::new(buf, self.descriptor_set())?;
        w.field(self.field_descriptor(), self.data_len(), |b| {
            let ok = match self {
                Command::ImuMessageFormat {
                    function,
                    descriptors,
                } => write_format(b, *function, descriptors),
                Command::EnableStream {
                    function,
                    device,
                    enable,
                } => put_bytes(b, &[function.to_u8(), *device, *enable as u8]),
                Command::SaveStartupSettings => put_bytes(b, &[Function::Save.to_u8()]),
                Command::UartBaud { function, baud } => {
                    put_bytes(b, &[function.to_u8()])
                        && (*function != Function::Apply || put_u32(b, 1, *baud))
                }
                _ => true,
            };
            if ok { Ok(()) } else { Err(Error::NoSpace) }
        })?;
        w.finish()
    }

    /// Parses the first field of a command packet (what a device does with it).
    pub fn parse<T: AsRef<[u8]>>(packet: &Packet<T>) -> Result<Self, Error> {
        let set = packet.descriptor_set();
        let field = packet.fields().next().ok_or(Error::Truncated)??;
        Self::parse_field(set, &field)
    }

    /// Parses one command field of descriptor set `set`.
    pub fn parse_field(set: u8, field: &Field<&[u8]>) -> Result<Self, Error> {
        let data = field.data();
        let desc = field.descriptor();
        let bad = Error::BadFieldData {
            descriptor: desc,
            len: data.len(),
        };
        let function = || get_u8(data, 0).and_then(Function::from_u8).ok_or(bad);
        Ok(match (set, desc) {
            (base::SET, base::PING) => Command::Ping,
            (base::SET, base::SET_IDLE) => Command::SetIdle,
            (base::SET, base::GET_DEVICE_INFO) => Command::GetDeviceInfo,
            (base::SET, base::RESUME) => Command::Resume,
            (base::SET, base::SOFT_RESET) => Command::SoftReset,
            (dm3::SET, dm3::GET_IMU_BASE_RATE) => Command::GetImuBaseRate,
            (dm3::SET, dm3::IMU_MESSAGE_FORMAT) => {
                let function = function()?;
                let descriptors = if function == Function::Apply {
                    read_rates(data.get(1..).unwrap_or(&[])).ok_or(bad)?
                } else {
                    DescriptorRates::new()
                };
                Command::ImuMessageFormat {
                    function,
                    descriptors,
                }
            }
            (dm3::SET, dm3::ENABLE_STREAM) => Command::EnableStream {
                function: function()?,
                device: get_u8(data, 1).ok_or(bad)?,
                enable: get_u8(data, 2).unwrap_or(0) != 0,
            },
            (dm3::SET, dm3::SAVE_STARTUP_SETTINGS) => Command::SaveStartupSettings,
            (dm3::SET, dm3::UART_BAUD) => {
                let function = function()?;
                let baud = if function == Function::Apply {
                    get_u32(data, 1).ok_or(bad)?
                } else {
                    0
                };
                Command::UartBaud { function, baud }
            }
            (set, field) => return Err(Error::Unexpected { set, field }),
        })
    }
}

fn put_bytes(b: &mut [u8], bytes: &[u8]) -> bool {
    match b.get_mut(..bytes.len()) {
        Some(dst) => {
            dst.copy_from_slice(bytes);
            true
        }
        None => false,
    }
}

fn write_format(b: &mut [u8], function: Function, descriptors: &DescriptorRates) -> bool {
    if function != Function::Apply {
        return put_bytes(b, &[function.to_u8()]);
    }
    put_bytes(b, &[function.to_u8()]) && write_rates(b.get_mut(1..).unwrap_or(&mut []), descriptors)
}

/// Writes `count u8, (descriptor u8, decimation u16)*`.
pub(crate) fn write_rates(b: &mut [u8], descriptors: &DescriptorRates) -> bool {
    let mut ok = put_bytes(b, &[descriptors.len() as u8]);
    for (i, r) in descriptors.iter().enumerate() {
        let at = 1 + 3 * i;
        ok = ok
            && put_bytes(b.get_mut(at..).unwrap_or(&mut []), &[r.descriptor])
            && put_u16(b, at + 1, r.decimation);
    }
    ok
}

/// Reads `count u8, (descriptor u8, decimation u16)*`; `None` if the length does not match.
pub(crate) fn read_rates(b: &[u8]) -> Option<DescriptorRates> {
    let count = get_u8(b, 0)? as usize;
    if b.len() != 1 + 3 * count {
        return None;
    }
    let mut out = DescriptorRates::new();
    for i in 0..count {
        let at = 1 + 3 * i;
        out.push(DescriptorRate {
            descriptor: get_u8(b, at)?,
            decimation: get_u16(b, at + 1)?,
        })
        .ok()?;
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bytes(c: &Command) -> Vec<u8> {
        let mut buf = [0u8; 261];
        let n = c.emit(&mut buf).unwrap();
        buf[..n].to_vec()
    }

    #[test]
    fn ping_is_byte_exact() {
        assert_eq!(
            bytes(&Command::Ping),
            [0x75, 0x65, 0x01, 0x02, 0x02, 0x01, 0xE0, 0xC6]
        );
    }

    #[test]
    fn get_imu_base_rate_is_byte_exact() {
        assert_eq!(
            bytes(&Command::GetImuBaseRate),
            [0x75, 0x65, 0x0C, 0x02, 0x02, 0x06, 0xF0, 0xF7]
        );
    }

    #[test]
    fn set_idle_and_resume_are_byte_exact() {
        // Fletcher-16 worked by hand over 75 65 01 02 02 02 and 75 65 01 02 02 06.
        assert_eq!(
            bytes(&Command::SetIdle),
            [0x75, 0x65, 0x01, 0x02, 0x02, 0x02, 0xE1, 0xC7]
        );
        assert_eq!(
            bytes(&Command::Resume),
            [0x75, 0x65, 0x01, 0x02, 0x02, 0x06, 0xE5, 0xCB]
        );
    }

    #[test]
    fn message_format_layout() {
        let mut descriptors = DescriptorRates::new();
        descriptors
            .push(DescriptorRate {
                descriptor: 0x04,
                decimation: 10,
            })
            .unwrap();
        descriptors
            .push(DescriptorRate {
                descriptor: 0x05,
                decimation: 10,
            })
            .unwrap();
        let c = Command::ImuMessageFormat {
            function: Function::Apply,
            descriptors,
        };
        let b = bytes(&c);
        assert_eq!(
            &b[..14],
            &[
                0x75, 0x65, 0x0C, 0x0A, 0x0A, 0x08, 0x01, 0x02, 0x04, 0x00, 0x0A, 0x05, 0x00, 0x0A
            ]
        );
        let p = Packet::new_checked(&b[..]).unwrap();
        assert_eq!(Command::parse(&p).unwrap(), c);
    }

    #[test]
    fn every_command_round_trips() {
        let all = [
            Command::Ping,
            Command::SetIdle,
            Command::GetDeviceInfo,
            Command::Resume,
            Command::SoftReset,
            Command::GetImuBaseRate,
            Command::ImuMessageFormat {
                function: Function::Read,
                descriptors: DescriptorRates::new(),
            },
            Command::EnableStream {
                function: Function::Apply,
                device: STREAM_IMU,
                enable: true,
            },
            Command::SaveStartupSettings,
            Command::UartBaud {
                function: Function::Apply,
                baud: 921_600,
            },
            Command::UartBaud {
                function: Function::Read,
                baud: 0,
            },
        ];
        for c in all {
            let b = bytes(&c);
            let p = Packet::new_checked(&b[..]).unwrap();
            assert_eq!(Command::parse(&p).unwrap(), c, "{c:?}");
        }
    }
}
