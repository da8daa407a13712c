//! The map scale in flight, without ground truth: the tracked trajectory of the last seconds
//! against the IMU integrated along it ([`crate::imu::flight_scale`], `[scale_observer]`).
//!
//! It measures (`report.json` `imu_scale_*`, `OUT/imu_scale.csv`): feeding the estimate back
//! into the maps was tried and not kept (see docs/odometry-log.md). One use it has: an estimate
//! far outside any healthy flight's (`fault_min_scale`, `fault_max_scale`) marks the odometry's
//! output failed for the flight controller until an estimate within them comes
//! ([`ScaleObserverConfig::is_fault`]): a map whose scale ran away is not flown on.

use crate::imu::flight_scale::{
    FlightScale, FlightScalePrior, TrackedPose, dead_reckon, solve_flight_scale,
};
use crate::imu::{FrameState, ImuSample, Preintegration};
use crate::time::TimeNs;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// Settings of the scale observer (the `[scale_observer]` table).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScaleObserverConfig {
    /// Tracked trajectory used, s (at most the ~10 s of IMU the odometry keeps).
    pub horizon_s: f64,
    /// No estimate from less than this, s.
    pub min_horizon_s: f64,
    /// Priors of the alignment: velocity at the start of the horizon, m/s…
    pub velocity_std_m_s: f64,
    /// …accelerometer bias error, m/s²…
    pub accel_bias_std_m_s2: f64,
    /// …world-frame attitude error, rad…
    pub attitude_std_rad: f64,
    /// …and one tracked position against the integrated one, m.
    pub position_std_m: f64,
    /// An estimate below `fault_min_scale` or above `fault_max_scale` (tracked → metric), with a
    /// standard deviation under `fault_max_rel_std` of it, is a scale fault: the published frames
    /// are failed (MAVLink quality −1) until an estimate within them. Healthy flights stayed
    /// within 0.51–1.56 over 132 replays of the demo and S-V101, offline and real time (sessions
    /// 67–69); over the 219 kept to session 70 one real-time S-V101 replay read 0.26 twice (a
    /// false fault, 1.4 s failed). A real-time S-V101 replay whose scale ran away after a 5.5 s loss measured 0.121 and 0.069.
    pub fault_min_scale: f64,
    pub fault_max_scale: f64,
    pub fault_max_rel_std: f64,
    /// The vehicle's top speed, m/s: a published frame whose estimated speed is above it (or not
    /// finite) is a speed fault, published failed like a scale fault — the first sign of a scale
    /// that runs away, seconds to tens of seconds before the observer's horizon reads it
    /// (S-V101's real-time runaway passed 3 m/s 20 s after its loss and 5 m/s 38 s after, its
    /// first scale fault came 45 s after; healthy replays here stay under 1.7 m/s). 0 = off.
    pub fault_max_speed_m_s: f64,
}

impl ScaleObserverConfig {
    /// The priors of the alignment.
    pub fn prior(&self) -> FlightScalePrior {
        FlightScalePrior {
            velocity_std_m_s: self.velocity_std_m_s,
            accel_bias_std_m_s2: self.accel_bias_std_m_s2,
            attitude_std_rad: self.attitude_std_rad,
            position_std_m: self.position_std_m,
        }
    }

    /// An estimate `scale` ± `scale_std` says the map's scale ran away (see `fault_min_scale`);
    /// a non-finite one says nothing.
    pub fn is_fault(&self, scale: f64, scale_std: f64) -> bool {
        scale.is_finite()
            && scale_std.is_finite()
            && scale_std < self.fault_max_rel_std * scale
            && !(self.fault_min_scale..=self.fault_max_scale).contains(&scale)
    }

    /// An estimated speed `speed_m_s` beyond the vehicle's (`fault_max_speed_m_s`), or not finite.
    pub fn is_speed_fault(&self, speed_m_s: f64) -> bool {
        self.fault_max_speed_m_s > 0.0
            && (speed_m_s.is_nan() || speed_m_s > self.fault_max_speed_m_s)
    }
}

impl Default for ScaleObserverConfig {
    fn default() -> Self {
        ScaleObserverConfig {
            horizon_s: 8.0,
            min_horizon_s: 4.0,
            velocity_std_m_s: 1.0,
            accel_bias_std_m_s2: 0.3,
            attitude_std_rad: 0.05,
            position_std_m: 0.01,
            fault_min_scale: 1.0 / 3.0,
            fault_max_scale: 3.0,
            fault_max_rel_std: 0.25,
            fault_max_speed_m_s: 5.0,
        }
    }
}

/// One estimate: at `t`, metric = `scale` × tracked over the horizon before it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleSample {
    pub t: TimeNs,
    pub scale: f64,
    pub scale_std: f64,
    /// RMS of the alignment's position residuals, m.
    pub rms_m: f64,
}

/// `imu_scale.csv`: one row per estimate.
pub fn imu_scale_csv(samples: &[ScaleSample]) -> String {
    let mut s = String::from("t_ns,scale,scale_std,rms_m\n");
    for e in samples {
        s.push_str(&format!(
            "{},{:.5},{:.5},{:.5}\n",
            e.t.0, e.scale, e.scale_std, e.rms_m
        ));
    }
    s
}

/// The tracked frames of the horizon.
#[derive(Clone, Debug, Default)]
pub struct ScaleObserver {
    cfg: ScaleObserverConfig,
    track: VecDeque<FrameState>,
}

impl ScaleObserver {
    pub fn new(cfg: ScaleObserverConfig) -> Self {
        ScaleObserver {
            cfg,
            track: VecDeque::new(),
        }
    }

    /// Appends a tracked frame: its state (after every correction of the frame) and the position
    /// change tracking alone made from the previous state. The horizon's positions are the sum of
    /// those steps: the corrections (keyframe window, keyframe adjustment, a stored keyframe) move
    /// the pose by jumps that no IMU motion explains.
    pub fn push(&mut self, x: FrameState, tracked_step_m: Vector3<f64>) {
        if !(x.is_finite() && tracked_step_m.iter().all(|v| v.is_finite())) {
            self.track.clear();
            return;
        }
        let mut x = x;
        x.nav.p_world_m = match self.track.back() {
            Some(prev) => prev.nav.p_world_m + tracked_step_m,
            None => x.nav.p_world_m,
        };
        self.track.push_back(x);
        let keep_s = self.cfg.horizon_s + 1.0;
        while self
            .track
            .front()
            .is_some_and(|f| x.nav.t.secs_since(f.nav.t) > keep_s)
        {
            self.track.pop_front();
        }
    }

    /// Forgets the horizon (a jump of the tracked pose: loss, a stored keyframe).
    pub fn clear(&mut self) {
        self.track.clear();
    }

    /// The scale of the horizon's trajectory, if it is long enough (`imu` must cover it).
    pub fn estimate(&self, imu: &[ImuSample]) -> Option<FlightScale> {
        let last = self.track.back()?.nav.t;
        let first = self
            .track
            .iter()
            .position(|x| last.secs_since(x.nav.t) <= self.cfg.horizon_s)?;
        let t0: TimeNs = self.track[first].nav.t;
        if last.secs_since(t0) < self.cfg.min_horizon_s || imu.first().is_none_or(|s| s.t > t0) {
            return None;
        }
        let frames: Vec<&FrameState> = self.track.range(first..).collect();
        let poses: Vec<TrackedPose> = frames
            .iter()
            .map(|x| TrackedPose {
                r_world_body: *x.nav.r_world_body.to_rotation_matrix().matrix(),
                p_world_m: x.nav.p_world_m,
            })
            .collect();
        let intervals: Vec<Preintegration> = frames
            .windows(2)
            .map(|w| {
                let mut pre = Preintegration::new(w[0].nav.t, w[0].bias);
                pre.integrate(imu, w[1].nav.t, None);
                pre
            })
            .collect();
        let reckoned = dead_reckon(&poses, &intervals);
        solve_flight_scale(&poses, &reckoned, &self.cfg.prior())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::integration::gravity_world;
    use crate::imu::{ImuBias, NavState};
    use nalgebra::UnitQuaternion;

    /// A speed beyond the vehicle's, or not finite, is a fault; at or below it, none; off at 0.
    #[test]
    fn a_speed_beyond_the_vehicles_is_a_speed_fault() {
        let c = ScaleObserverConfig::default();
        assert!(!c.is_speed_fault(1.7), "the fastest healthy replay here");
        assert!(!c.is_speed_fault(5.0), "the limit itself");
        assert!(c.is_speed_fault(5.01));
        assert!(c.is_speed_fault(12.4), "S-V101's runaway");
        assert!(c.is_speed_fault(f64::NAN) && c.is_speed_fault(f64::INFINITY));
        let off = ScaleObserverConfig {
            fault_max_speed_m_s: 0.0,
            ..c
        };
        assert!(!off.is_speed_fault(100.0) && !off.is_speed_fault(f64::NAN));
    }

    /// A fault is a confident estimate outside the band; an uncertain or non-finite one is none.
    #[test]
    fn a_confident_estimate_outside_the_band_is_a_scale_fault() {
        let c = ScaleObserverConfig::default();
        assert!(c.is_fault(0.121, 0.00239), "S-V101's runaway");
        assert!(c.is_fault(3.5, 0.1));
        assert!(!c.is_fault(0.508, 0.02), "the lowest healthy estimate");
        assert!(!c.is_fault(1.56, 0.02), "the highest healthy estimate");
        assert!(!c.is_fault(0.2, 0.06), "uncertain: 30 % of the estimate");
        assert!(!c.is_fault(f64::NAN, 0.01));
        assert!(!c.is_fault(0.2, f64::NAN));
        assert!(
            !c.is_fault(1.0 / 3.0, 0.01) && !c.is_fault(3.0, 0.01),
            "the band is closed"
        );
    }

    /// Accelerating along x and y (a sine, so that velocity and scale separate), level body.
    fn acc(t: f64) -> Vector3<f64> {
        Vector3::new(0.6 * (1.3 * t).sin(), 0.4 * (0.9 * t).cos(), 0.1)
    }

    fn imu(seconds: f64) -> Vec<ImuSample> {
        (0..=(seconds * 200.0) as usize + 2)
            .map(|i| {
                let t = i as f64 / 200.0;
                ImuSample {
                    t: TimeNs::from_secs_f64(t),
                    gyro_rad_s: Vector3::zeros(),
                    accel_m_s2: acc(t) - gravity_world(),
                }
            })
            .collect()
    }

    fn state(t: f64, p: Vector3<f64>) -> FrameState {
        FrameState {
            nav: NavState {
                t: TimeNs::from_secs_f64(t),
                r_world_body: UnitQuaternion::identity(),
                p_world_m: p,
                v_world_m_s: Vector3::zeros(),
            },
            bias: ImuBias::default(),
        }
    }

    #[test]
    fn measures_the_scale_from_the_tracked_steps_not_the_corrected_positions() {
        let imu = imu(8.0);
        // Truth integrated finely from rest; tracked steps are 1/1.1 of it (map 9 % small), and
        // every 10th frame's corrected position jumps by 5 cm (a keyframe correction).
        let mut obs = ScaleObserver::new(ScaleObserverConfig::default());
        let (mut p, mut v) = (Vector3::zeros(), Vector3::zeros());
        let mut prev_p = p;
        for k in 0..=140 {
            let t = k as f64 * 0.05;
            if k > 0 {
                for i in 0..50 {
                    let tt = t - 0.05 + i as f64 * 0.001;
                    p += v * 0.001 + 0.5 * acc(tt) * 1e-6;
                    v += acc(tt) * 0.001;
                }
            }
            let step = (p - prev_p) / 1.1;
            prev_p = p;
            let jump = if k % 10 == 0 {
                Vector3::new(0.05, 0.0, 0.0)
            } else {
                Vector3::zeros()
            };
            obs.push(state(t, p / 1.1 + jump), step);
        }
        let e = obs.estimate(&imu).expect("8 s of horizon");
        assert!((e.scale - 1.1).abs() < 0.01, "{e:?}");
        assert!(e.rms_m < 0.005, "{e:?}");
        // Too short a horizon: no estimate.
        obs.clear();
        obs.push(state(0.0, Vector3::zeros()), Vector3::zeros());
        obs.push(state(1.0, Vector3::zeros()), Vector3::zeros());
        assert!(obs.estimate(&imu).is_none());
    }
}
