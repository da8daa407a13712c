//! IMU samples in SI units with device and host timestamps (std).

use crate::imu::{GRAVITY_M_S2, INTERNAL_TICK_HZ, ImuData};
use vidslam_timesync::{ClockModel, ClockModelConfig, TickUnwrapper};

/// Where a sample's device time came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeviceTimeSource {
    /// GPS-correlation timestamp (0x80, 0x12): ns since the GPS epoch.
    Gps,
    /// Internal tick counter (0x80, 0x0E), unwrapped: ns since the counter's first reading.
    InternalTicks,
}

/// Which device timestamp to use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TimePreference {
    /// The GPS-correlation timestamp when the packet has one, else the internal ticks.
    #[default]
    Auto,
    /// Only the GPS-correlation timestamp.
    Gps,
    /// Only the internal tick counter.
    InternalTicks,
}

/// One IMU measurement: what the daemon consumes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuSample {
    /// Device time, ns (see [`ImuSample::device_time_source`] for its epoch).
    pub device_time_ns: i64,
    pub device_time_source: DeviceTimeSource,
    /// Host monotonic time at which the packet was read, ns.
    pub host_receive_ns: i64,
    /// Device time mapped to host monotonic time by the clock model, ns; `None` until the model
    /// has seen enough packets. This is the time the estimator uses.
    pub host_time_ns: Option<i64>,
    /// Angular rate, rad/s, body (IMU) frame.
    pub gyro_rad_s: [f64; 3],
    /// Specific force, m/s², body (IMU) frame.
    pub accel_m_s2: [f64; 3],
}

/// Why a data packet did not become a sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SampleError {
    #[error("IMU packet has no scaled accelerometer field (0x80,0x04)")]
    MissingAccel,
    #[error("IMU packet has no scaled gyro field (0x80,0x05)")]
    MissingGyro,
    #[error("IMU packet has no usable device timestamp (0x80,0x12 GPS time or 0x80,0x0E ticks)")]
    MissingTime,
    #[error("IMU packet holds a non-finite accelerometer or gyro value")]
    NonFinite,
}

/// Turns parsed IMU packets into [`ImuSample`]s: unwraps the tick counter, feeds the clock
/// model with (device time, host receive time), converts units.
#[derive(Clone, Debug)]
pub struct SampleTimer {
    preference: TimePreference,
    ticks: TickUnwrapper,
    clock: ClockModel,
}

impl SampleTimer {
    pub fn new(preference: TimePreference, clock: ClockModelConfig) -> Self {
        SampleTimer {
            preference,
            ticks: TickUnwrapper::new(INTERNAL_TICK_HZ),
            clock: ClockModel::new(clock),
        }
    }

    /// The clock model (skew, observation count).
    pub fn clock(&self) -> &ClockModel {
        &self.clock
    }

    /// Starts over (after a reopen the device may have restarted its clocks).
    pub fn restart(&mut self) {
        self.ticks.reset();
        self.clock.restart();
    }

    /// The device time of a packet and its source, per the preference.
    pub fn device_time_ns(&mut self, data: &ImuData) -> Option<(i64, DeviceTimeSource)> {
        let gps = || {
            data.gps_time
                .and_then(|g| g.gps_ns())
                .map(|t| (t, DeviceTimeSource::Gps))
        };
        match self.preference {
            TimePreference::Gps => gps(),
            TimePreference::InternalTicks => data
                .internal_ticks
                .map(|t| (self.ticks.unwrap_ns(t), DeviceTimeSource::InternalTicks)),
            TimePreference::Auto => gps().or_else(|| {
                data.internal_ticks
                    .map(|t| (self.ticks.unwrap_ns(t), DeviceTimeSource::InternalTicks))
            }),
        }
    }

    /// A sample from a parsed packet received at `host_receive_ns`.
    pub fn sample(
        &mut self,
        data: &ImuData,
        host_receive_ns: i64,
    ) -> Result<ImuSample, SampleError> {
        let accel = data.accel_g.ok_or(SampleError::MissingAccel)?;
        let gyro = data.gyro_rad_s.ok_or(SampleError::MissingGyro)?;
        if !accel.iter().chain(gyro.iter()).all(|v| v.is_finite()) {
            return Err(SampleError::NonFinite);
        }
        let (device_time_ns, source) = self.device_time_ns(data).ok_or(SampleError::MissingTime)?;
        self.clock.observe(device_time_ns, host_receive_ns);
        Ok(ImuSample {
            device_time_ns,
            device_time_source: source,
            host_receive_ns,
            host_time_ns: self.clock.device_to_host_ns(device_time_ns),
            gyro_rad_s: gyro.map(f64::from),
            accel_m_s2: accel.map(|a| f64::from(a) * GRAVITY_M_S2),
        })
    }
}

/// Host monotonic time now, ns: `CLOCK_MONOTONIC`, the clock every vidslam driver stamps with.
pub fn host_monotonic_ns() -> i64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    #[allow(clippy::unnecessary_cast)] // time_t and c_long are i32 on 32-bit targets
    let (sec, nsec) = (ts.tv_sec as i64, ts.tv_nsec as i64);
    sec.saturating_mul(1_000_000_000).saturating_add(nsec)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::GpsTimestamp;

    #[test]
    fn converts_units_and_prefers_gps() {
        let mut t = SampleTimer::new(TimePreference::Auto, ClockModelConfig::default());
        let data = ImuData {
            accel_g: Some([0.0, 0.0, -1.0]),
            gyro_rad_s: Some([0.5, 0.0, 0.0]),
            internal_ticks: Some(62_500),
            gps_time: Some(GpsTimestamp {
                time_of_week_s: 10.5,
                week: 2,
                flags: 0,
            }),
            ..Default::default()
        };
        let s = t.sample(&data, 1_000).unwrap();
        assert_eq!(s.device_time_source, DeviceTimeSource::Gps);
        assert_eq!(
            s.device_time_ns,
            (2 * 604_800 + 10) * 1_000_000_000 + 500_000_000
        );
        assert_eq!(s.accel_m_s2, [0.0, 0.0, -GRAVITY_M_S2]);
        assert_eq!(s.gyro_rad_s, [0.5, 0.0, 0.0]);
        assert_eq!(s.host_time_ns, None); // one observation is not enough

        let mut ticks_only = SampleTimer::new(TimePreference::InternalTicks, Default::default());
        let s = ticks_only.sample(&data, 1_000).unwrap();
        assert_eq!(s.device_time_ns, 1_000_000_000);
    }

    #[test]
    fn nan_is_refused() {
        let mut t = SampleTimer::new(TimePreference::Auto, ClockModelConfig::default());
        let data = ImuData {
            accel_g: Some([f32::NAN, 0.0, -1.0]),
            gyro_rad_s: Some([0.5, 0.0, 0.0]),
            internal_ticks: Some(1),
            ..Default::default()
        };
        assert_eq!(t.sample(&data, 0), Err(SampleError::NonFinite));
    }
}
