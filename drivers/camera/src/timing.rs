//! Frame time from a device timestamp: the device clock is mapped to host `CLOCK_MONOTONIC`
//! with the shared [`vidslam_timesync::ClockModel`] (the one the IMU driver uses), then moved to
//! the exposure midpoint.
//!
//! Observations fed to the model are (device time of the **end of exposure**, host receive
//! time): from the end of exposure to reception only readout and transfer remain, so the
//! model's lower envelope does not depend on the exposure time (which auto-exposure changes).
//! The mapped midpoint therefore still contains the minimum readout + transfer latency; a known
//! value can be given as `transfer_latency_ns` and is subtracted, the remaining constant offset
//! is for the camera–IMU time-offset calibration to absorb.

use crate::config::TimestampLatch;
use vidslam_timesync::{ClockModel, ClockModelConfig};

/// Maps device timestamps to mid-exposure host times.
#[derive(Clone, Debug)]
pub struct FrameTimer {
    model: ClockModel,
    latch: TimestampLatch,
    transfer_latency_ns: i64,
}

impl FrameTimer {
    pub fn new(latch: TimestampLatch, transfer_latency_ns: i64) -> Self {
        // One observation already gives the offset (skew 0), so even the first frame gets a time.
        let config = ClockModelConfig {
            min_observations: 1,
            ..ClockModelConfig::default()
        };
        FrameTimer {
            model: ClockModel::new(config),
            latch,
            transfer_latency_ns,
        }
    }

    /// Feeds one frame's (device timestamp, host receive time) and returns its frame time
    /// (exposure midpoint, host clock, ns). From the first frame on (offset only, then offset
    /// and skew as observations accumulate).
    /// Unknown exposure counts as zero (the latch instant is then the frame time).
    pub fn stamp(
        &mut self,
        device_ns: i64,
        host_receive_ns: i64,
        exposure_us: Option<f64>,
    ) -> Option<i64> {
        let exposure_ns = exposure_us
            .filter(|e| e.is_finite() && *e > 0.0)
            .map_or(0, |e| (e * 1e3).round() as i64);
        let (end_ns, mid_ns) = match self.latch {
            TimestampLatch::ExposureStart => (device_ns + exposure_ns, device_ns + exposure_ns / 2),
            TimestampLatch::ExposureEnd => (device_ns, device_ns - exposure_ns / 2),
        };
        self.model.observe(end_ns, host_receive_ns);
        self.model
            .device_to_host_ns(mid_ns)
            .map(|t| t - self.transfer_latency_ns)
    }

    /// Forgets the device clock (after a reopen the device clock may have restarted).
    pub fn restart(&mut self) {
        self.model.restart();
    }

    /// Host-vs-device clock skew, ppm, once estimated.
    pub fn skew_ppm(&self) -> Option<f64> {
        self.model.skew_ppm()
    }

    /// Observations since the last restart.
    pub fn observations(&self) -> usize {
        self.model.observations()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Device clock 40 ppm fast with a large offset, 5 ms exposure latched at start, receive
    /// delay = 2 ms readout/transfer + a deterministic jitter that is zero on every 4th frame.
    #[test]
    fn frame_time_is_the_host_time_of_mid_exposure() {
        let mut timer = FrameTimer::new(TimestampLatch::ExposureStart, 2_000_000);
        let exposure_us = 5000.0;
        for i in 0..200i64 {
            let true_start_host_ns = 1_000_000_000 + i * 50_000_000;
            let device_ns = 7_000_000_000_000 + (true_start_host_ns as f64 * (1.0 + 40e-6)) as i64;
            let jitter_ns = (i % 4) * 300_000;
            let receive_ns = true_start_host_ns + 5_000_000 + 2_000_000 + jitter_ns;
            let t = timer.stamp(device_ns, receive_ns, Some(exposure_us));
            if i >= 10 {
                let err_ns = t.unwrap() - (true_start_host_ns + 2_500_000);
                assert!(err_ns.abs() < 2_000, "frame {i}: error {err_ns} ns");
            }
        }
        let skew = timer.skew_ppm().unwrap();
        assert!((skew + 40.0).abs() < 1.0, "skew {skew} ppm");
    }

    #[test]
    fn end_latch_moves_back_by_half_the_exposure() {
        let mut timer = FrameTimer::new(TimestampLatch::ExposureEnd, 0);
        let mut last = None;
        for i in 0..10i64 {
            last = timer.stamp(i * 50_000_000, 10_000 + i * 50_000_000, Some(4000.0));
        }
        assert_eq!(last, Some(10_000 + 9 * 50_000_000 - 2_000_000));
    }
}
