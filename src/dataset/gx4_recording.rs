//! GX4-format recordings made from EuRoC IMU rows: the byte stream a 3DM-GX4-25 would send for
//! the same motion, used as a replay fixture for the MIP decoder and driver.
//!
//! Each row becomes one IMU packet (set 0x80) with, in this order: scaled accel (g), scaled gyro
//! (rad/s), delta theta (rad), delta velocity (g·s), internal timestamp (ticks) and
//! GPS-correlation timestamp. Conventions, so the encoding is reproducible byte for byte:
//! * accel in g = m/s² / [`GRAVITY_M_S2`] (9.80665), rounded to f32; gyro rounded to f32;
//! * delta theta / delta velocity = rate × the time since the previous row (the nominal 5 ms for
//!   the first row);
//! * GPS time = EuRoC (Unix) time − 315 964 800 s + 16 leap seconds (GPS − UTC in 2014), flags
//!   PPS valid | time refreshed | time initialised;
//! * internal ticks at 62.5 kHz starting [`FIRST_TICK`], 2 s before the u32 wraps, so every
//!   recording longer than 2 s exercises the wraparound.

use crate::imu::ImuSample;
use vidslam_mip::imu::{GRAVITY_M_S2, GpsTimestamp, INTERNAL_TICK_HZ, ImuData, gps_flags};
use vidslam_mip::wire::MAX_PACKET_LEN;

/// Unix time of the GPS epoch (1980-01-06T00:00:00Z), s.
pub const GPS_EPOCH_UNIX_S: i64 = 315_964_800;
/// GPS − UTC in 2014 (the EuRoC recordings), s.
pub const GPS_UTC_LEAP_S_2014: i64 = 16;
/// Tick counter value of the first packet: 2 s before the u32 wraps.
pub const FIRST_TICK: u32 = u32::MAX - 2 * INTERNAL_TICK_HZ as u32 + 1;
/// Nominal EuRoC IMU period, ns (200 Hz).
pub const NOMINAL_PERIOD_NS: i64 = 5_000_000;

/// The parsed packet for one row (`prev_t_ns`: previous row's time, for the deltas).
pub fn gx4_packet_for(row: &ImuSample, prev_t_ns: Option<i64>, first_t_ns: i64) -> ImuData {
    let t_ns = row.t.0;
    let dt_s = (t_ns - prev_t_ns.unwrap_or(t_ns - NOMINAL_PERIOD_NS)) as f64 * 1e-9;
    let accel_g: [f64; 3] = (row.accel_m_s2 / GRAVITY_M_S2).into();
    let gyro_rad_s: [f64; 3] = row.gyro_rad_s.into();
    let ticks = ((t_ns - first_t_ns) as i128 * INTERNAL_TICK_HZ as i128 / 1_000_000_000) as u32;
    let gps_ns = t_ns - GPS_EPOCH_UNIX_S * 1_000_000_000 + GPS_UTC_LEAP_S_2014 * 1_000_000_000;
    ImuData {
        accel_g: Some(accel_g.map(|a| a as f32)),
        gyro_rad_s: Some(gyro_rad_s.map(|w| w as f32)),
        delta_theta_rad: Some(gyro_rad_s.map(|w| (w * dt_s) as f32)),
        delta_velocity_g_s: Some(accel_g.map(|a| (a * dt_s) as f32)),
        internal_ticks: Some(FIRST_TICK.wrapping_add(ticks)),
        gps_time: Some(GpsTimestamp::from_gps_ns(
            gps_ns,
            gps_flags::PPS_VALID | gps_flags::TIME_REFRESH | gps_flags::TIME_INITIALIZED,
        )),
        unknown_fields: 0,
    }
}

/// The parsed packets for the rows within `seconds` of the first one.
pub fn gx4_packets(rows: &[ImuSample], seconds: f64) -> Vec<ImuData> {
    let Some(first) = rows.first() else {
        return Vec::new();
    };
    let end_ns = first.t.0 + (seconds * 1e9).round() as i64;
    let mut prev = None;
    rows.iter()
        .take_while(|r| r.t.0 < end_ns)
        .map(|r| {
            let p = gx4_packet_for(r, prev, first.t.0);
            prev = Some(r.t.0);
            p
        })
        .collect()
}

/// The recording bytes: the packets of [`gx4_packets`] back to back.
pub fn encode_gx4_recording(rows: &[ImuSample], seconds: f64) -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = [0u8; MAX_PACKET_LEN];
    for p in gx4_packets(rows, seconds) {
        // Six fields = 82 bytes: always fits a MIP packet.
        if let Ok(n) = p.emit(&mut buf) {
            out.extend_from_slice(&buf[..n]);
        }
    }
    out
}
