//! IMU data set 0x80: parsed representations of the fields the 3DM-GX4-25 streams.
//!
//! Units on the wire: accelerations in g, angular rates in rad/s, delta theta in rad, delta
//! velocity in g·s, internal timestamp in ticks of [`INTERNAL_TICK_HZ`], GPS-correlation
//! timestamp as GPS time of week (s) + week number + flags. Conversion to SI multiplies by
//! [`GRAVITY_M_S2`].

use crate::descriptor::imu as d;
use crate::wire::{Error, Field, Packet, PacketWriter, get_f32, get_f64, get_u16, get_u32};
use crate::wire::{put_f32, put_f64, put_u16, put_u32};

/// The gravity constant behind the GX4's "g" unit, m/s²: standard gravity (9.80665, as used by
/// MicroStrain's SDK and manuals to convert scaled accelerometer output).
pub const GRAVITY_M_S2: f64 = 9.80665;

/// Rate of the internal timestamp counter (field 0x0E): 62.5 kHz, one tick = 16 µs (3DM-GX4
/// DCP manual). The counter is a `u32` and wraps after 2^32 ticks ≈ 19.1 h.
pub const INTERNAL_TICK_HZ: u64 = 62_500;

/// Seconds in a GPS week.
pub const GPS_WEEK_S: u32 = 604_800;

/// Flags of the GPS-correlation timestamp (field 0x12).
pub mod gps_flags {
    /// The PPS signal is present and the device time is beaconed to it.
    pub const PPS_VALID: u16 = 0x0001;
    /// The time was refreshed by the host ("GPS time update" command) or a GNSS receiver.
    pub const TIME_REFRESH: u16 = 0x0002;
    /// The time has been initialised (a GPS time update was received once).
    pub const TIME_INITIALIZED: u16 = 0x0004;
}

/// GPS-correlation timestamp: GPS time of week, week number, validity flags.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpsTimestamp {
    pub time_of_week_s: f64,
    pub week: u16,
    pub flags: u16,
}

impl GpsTimestamp {
    /// Nanoseconds since the GPS epoch (1980-01-06), rounded; `None` if the time of week is not
    /// finite or outside [0, 604800].
    pub fn gps_ns(&self) -> Option<i64> {
        if !self.time_of_week_s.is_finite()
            || self.time_of_week_s < 0.0
            || self.time_of_week_s > GPS_WEEK_S as f64
        {
            return None;
        }
        // Split the f64 so the integer seconds are exact.
        let whole_s = libm_floor(self.time_of_week_s);
        let frac_ns = round_half_away((self.time_of_week_s - whole_s) * 1e9) as i64;
        let week_s = self.week as i64 * GPS_WEEK_S as i64;
        Some((week_s + whole_s as i64) * 1_000_000_000 + frac_ns)
    }

    /// From nanoseconds since the GPS epoch (non-negative).
    pub fn from_gps_ns(gps_ns: i64, flags: u16) -> Self {
        let ns_per_week = GPS_WEEK_S as i64 * 1_000_000_000;
        let week = gps_ns.div_euclid(ns_per_week);
        let tow_ns = gps_ns.rem_euclid(ns_per_week);
        GpsTimestamp {
            time_of_week_s: (tow_ns / 1_000_000_000) as f64
                + (tow_ns % 1_000_000_000) as f64 * 1e-9,
            week: week.clamp(0, u16::MAX as i64) as u16,
            flags,
        }
    }
}

// core has no f64::floor/round without std; these suffice for the non-negative TOW range.
fn libm_floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}
fn round_half_away(x: f64) -> f64 {
    if x >= 0.0 {
        libm_floor(x + 0.5)
    } else {
        -libm_floor(-x + 0.5)
    }
}

/// One field of the IMU data set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ImuField {
    /// Scaled accelerometer, g, sensor frame.
    ScaledAccel([f32; 3]),
    /// Scaled gyro, rad/s, sensor frame.
    ScaledGyro([f32; 3]),
    /// Integrated angle over the sample period, rad.
    DeltaTheta([f32; 3]),
    /// Integrated velocity change over the sample period, g·s.
    DeltaVelocity([f32; 3]),
    /// Internal timestamp, ticks of [`INTERNAL_TICK_HZ`], wrapping.
    InternalTimestamp(u32),
    /// GPS-correlation timestamp.
    GpsTimestamp(GpsTimestamp),
}

fn vec3(data: &[u8], descriptor: u8) -> Result<[f32; 3], Error> {
    if data.len() != 12 {
        return Err(Error::BadFieldData {
            descriptor,
            len: data.len(),
        });
    }
    match (get_f32(data, 0), get_f32(data, 4), get_f32(data, 8)) {
        (Some(x), Some(y), Some(z)) => Ok([x, y, z]),
        _ => Err(Error::Truncated),
    }
}

impl ImuField {
    /// Parses a field of set 0x80; `Err(Unexpected)` for descriptors not listed here.
    pub fn parse(field: &Field<&[u8]>) -> Result<Self, Error> {
        let data = field.data();
        let desc = field.descriptor();
        let bad = Error::BadFieldData {
            descriptor: desc,
            len: data.len(),
        };
        Ok(match desc {
            d::SCALED_ACCEL => ImuField::ScaledAccel(vec3(data, desc)?),
            d::SCALED_GYRO => ImuField::ScaledGyro(vec3(data, desc)?),
            d::DELTA_THETA => ImuField::DeltaTheta(vec3(data, desc)?),
            d::DELTA_VELOCITY => ImuField::DeltaVelocity(vec3(data, desc)?),
            d::INTERNAL_TIMESTAMP => {
                if data.len() != 4 {
                    return Err(bad);
                }
                ImuField::InternalTimestamp(get_u32(data, 0).ok_or(bad)?)
            }
            d::GPS_TIMESTAMP => {
                if data.len() != 12 {
                    return Err(bad);
                }
                ImuField::GpsTimestamp(GpsTimestamp {
                    time_of_week_s: get_f64(data, 0).ok_or(bad)?,
                    week: get_u16(data, 8).ok_or(bad)?,
                    flags: get_u16(data, 10).ok_or(bad)?,
                })
            }
            other => {
                return Err(Error::Unexpected {
                    set: d::SET,
                    field: other,
                });
            }
        })
    }

    /// Field descriptor.
    pub fn descriptor(&self) -> u8 {
        match self {
            ImuField::ScaledAccel(_) => d::SCALED_ACCEL,
            ImuField::ScaledGyro(_) => d::SCALED_GYRO,
            ImuField::DeltaTheta(_) => d::DELTA_THETA,
            ImuField::DeltaVelocity(_) => d::DELTA_VELOCITY,
            ImuField::InternalTimestamp(_) => d::INTERNAL_TIMESTAMP,
            ImuField::GpsTimestamp(_) => d::GPS_TIMESTAMP,
        }
    }

    /// Data length in bytes (without the 2 field header bytes).
    pub fn data_len(&self) -> usize {
        match self {
            ImuField::InternalTimestamp(_) => 4,
            _ => 12,
        }
    }

    /// Appends this field to a packet being written.
    pub fn emit(&self, w: &mut PacketWriter<'_>) -> Result<(), Error> {
        let this = *self;
        w.field(self.descriptor(), self.data_len(), |b| {
            let ok = match this {
                ImuField::ScaledAccel(v)
                | ImuField::ScaledGyro(v)
                | ImuField::DeltaTheta(v)
                | ImuField::DeltaVelocity(v) => {
                    put_f32(b, 0, v[0]) && put_f32(b, 4, v[1]) && put_f32(b, 8, v[2])
                }
                ImuField::InternalTimestamp(t) => put_u32(b, 0, t),
                ImuField::GpsTimestamp(g) => {
                    put_f64(b, 0, g.time_of_week_s)
                        && put_u16(b, 8, g.week)
                        && put_u16(b, 10, g.flags)
                }
            };
            if ok { Ok(()) } else { Err(Error::NoSpace) }
        })
    }
}

/// One IMU data packet, parsed: every field the packet carried (each at most once; a repeated
/// field keeps the last value).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImuData {
    pub accel_g: Option<[f32; 3]>,
    pub gyro_rad_s: Option<[f32; 3]>,
    pub delta_theta_rad: Option<[f32; 3]>,
    pub delta_velocity_g_s: Option<[f32; 3]>,
    pub internal_ticks: Option<u32>,
    pub gps_time: Option<GpsTimestamp>,
    /// Fields of set 0x80 present in the packet but not interpreted here.
    pub unknown_fields: u8,
}

impl ImuData {
    /// Parses an IMU data packet (set 0x80). Unknown fields are counted, malformed ones are an
    /// error.
    pub fn parse<T: AsRef<[u8]>>(packet: &Packet<T>) -> Result<Self, Error> {
        if packet.descriptor_set() != d::SET {
            return Err(Error::Unexpected {
                set: packet.descriptor_set(),
                field: 0,
            });
        }
        let mut out = ImuData::default();
        for field in packet.fields() {
            match ImuField::parse(&field?) {
                Ok(f) => out.set(f),
                Err(Error::Unexpected { .. }) => {
                    out.unknown_fields = out.unknown_fields.saturating_add(1)
                }
                Err(e) => return Err(e),
            }
        }
        Ok(out)
    }

    fn set(&mut self, f: ImuField) {
        match f {
            ImuField::ScaledAccel(v) => self.accel_g = Some(v),
            ImuField::ScaledGyro(v) => self.gyro_rad_s = Some(v),
            ImuField::DeltaTheta(v) => self.delta_theta_rad = Some(v),
            ImuField::DeltaVelocity(v) => self.delta_velocity_g_s = Some(v),
            ImuField::InternalTimestamp(t) => self.internal_ticks = Some(t),
            ImuField::GpsTimestamp(g) => self.gps_time = Some(g),
        }
    }

    /// The present fields, in the canonical order accel, gyro, Δθ, Δv, ticks, GPS time.
    pub fn fields(&self) -> impl Iterator<Item = ImuField> + '_ {
        [
            self.accel_g.map(ImuField::ScaledAccel),
            self.gyro_rad_s.map(ImuField::ScaledGyro),
            self.delta_theta_rad.map(ImuField::DeltaTheta),
            self.delta_velocity_g_s.map(ImuField::DeltaVelocity),
            self.internal_ticks.map(ImuField::InternalTimestamp),
            self.gps_time.map(ImuField::GpsTimestamp),
        ]
        .into_iter()
        .flatten()
    }

    /// Emits a complete set-0x80 packet into `buf`; returns its length.
    pub fn emit(&self, buf: &mut [u8]) -> Result<usize, Error> {
        let mut w = PacketWriter::new(buf, d::SET)?;
        for f in self.fields() {
            f.emit(&mut w)?;
        }
        w.finish()
    }

    /// Encoded packet length of a packet with these fields, bytes.
    pub fn packet_len(&self) -> usize {
        crate::wire::HEADER_LEN
            + self.fields().map(|f| 2 + f.data_len()).sum::<usize>()
            + crate::wire::CHECKSUM_LEN
    }
}

/// Encoded packet length, bytes, of an IMU packet with the given field descriptors (unknown
/// descriptors count as 12 data bytes, the common size).
pub fn packet_len_for(fields: &[u8]) -> usize {
    let data: usize = fields
        .iter()
        .map(|&f| if f == d::INTERNAL_TIMESTAMP { 6 } else { 14 })
        .sum();
    crate::wire::HEADER_LEN + data + crate::wire::CHECKSUM_LEN
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> ImuData {
        ImuData {
            accel_g: Some([0.01, -0.02, -1.0]),
            gyro_rad_s: Some([0.1, 0.2, -0.3]),
            delta_theta_rad: Some([1e-4, 2e-4, 3e-4]),
            delta_velocity_g_s: Some([1e-3, 0.0, -5e-3]),
            internal_ticks: Some(u32::MAX),
            gps_time: Some(GpsTimestamp {
                time_of_week_s: 123_456.789_012_345,
                week: 1_798,
                flags: gps_flags::PPS_VALID | gps_flags::TIME_INITIALIZED,
            }),
            unknown_fields: 0,
        }
    }

    #[test]
    fn emit_parse_round_trip() {
        let x = sample();
        let mut buf = [0u8; 261];
        let n = x.emit(&mut buf).unwrap();
        assert_eq!(n, x.packet_len());
        assert_eq!(n, packet_len_for(&[4, 5, 7, 8, 0x0E, 0x12]));
        let p = Packet::new_checked(&buf[..n]).unwrap();
        assert_eq!(ImuData::parse(&p).unwrap(), x);
    }

    #[test]
    fn accel_field_bytes_are_big_endian_f32() {
        let mut buf = [0u8; 32];
        let mut w = PacketWriter::new(&mut buf, 0x80).unwrap();
        ImuField::ScaledAccel([1.0, -1.0, 0.5])
            .emit(&mut w)
            .unwrap();
        let n = w.finish().unwrap();
        assert_eq!(
            &buf[4..18],
            &[14, 0x04, 0x3F, 0x80, 0, 0, 0xBF, 0x80, 0, 0, 0x3F, 0, 0, 0]
        );
        assert_eq!(n, 20);
    }

    #[test]
    fn wrong_length_is_rejected() {
        let mut buf = [0u8; 32];
        let mut w = PacketWriter::new(&mut buf, 0x80).unwrap();
        w.field_bytes(0x0E, &[1, 2, 3]).unwrap();
        let n = w.finish().unwrap();
        let p = Packet::new_checked(&buf[..n]).unwrap();
        assert_eq!(
            ImuData::parse(&p),
            Err(Error::BadFieldData {
                descriptor: 0x0E,
                len: 3
            })
        );
    }

    #[test]
    fn gps_time_ns_round_trip() {
        let ns = 1_088_000_000_000_000_123i64 - 315_964_800_000_000_000;
        let g = GpsTimestamp::from_gps_ns(ns, 0);
        assert_eq!(g.gps_ns(), Some(ns));
        let bad = GpsTimestamp {
            time_of_week_s: f64::NAN,
            week: 0,
            flags: 0,
        };
        assert_eq!(bad.gps_ns(), None);
    }
}
