//! The estimator's per-frame output handed to the MAVLink sender: a small plain struct.

use crate::output::frames::PoseCovariance;
use crate::time::TimeNs;
use nalgebra::{Isometry3, Matrix3, Vector3};

/// Tracking health reported with each sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrackingHealth {
    /// Tracking. `quality_percent` 0 (barely usable) to 100 (best); values above 100 are clamped.
    Tracking { quality_percent: u8 },
    /// Tracking lost or the estimate is not usable: sent with quality -1 (the FC ignores it).
    Failed,
}

impl TrackingHealth {
    /// MAVLink ODOMETRY `quality`: 0..=100, or -1 when failed.
    pub fn mavlink_quality(self) -> i8 {
        match self {
            TrackingHealth::Tracking { quality_percent } => quality_percent.min(100) as i8,
            TrackingHealth::Failed => -1,
        }
    }
}

/// One estimator output, in vidslam's conventions (see [`crate::geometry`]): world gravity-aligned
/// z up, body = IMU frame. The sender converts it to the FC's frames ([`crate::output::frames`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OdometrySample {
    /// Time of validity of the state, on the host monotonic clock
    /// ([`crate::time::host_monotonic_now`]); the sender answers TIMESYNC from the same clock.
    pub t: TimeNs,
    /// Pose of the body (IMU) in the world.
    pub t_world_body: Isometry3<f64>,
    /// Velocity of the body origin, world coordinates.
    pub v_world_m_s: Vector3<f64>,
    /// Angular rate of the body, body (IMU) coordinates (bias-corrected gyro).
    pub omega_body_rad_s: Vector3<f64>,
    /// Pose covariance over `[delta_p_world; delta_theta_world]`, see [`PoseCovariance`];
    /// `None` sends the configured fallback.
    pub pose_covariance: Option<PoseCovariance>,
    /// Covariance of `v_world_m_s`, world coordinates; `None` sends the configured fallback.
    pub velocity_covariance: Option<Matrix3<f64>>,
    pub health: TrackingHealth,
    /// Incremented by the estimator at every discontinuity (re-initialisation, recovery after
    /// loss, map reset). The sender increments MAVLink's `reset_counter` whenever it changes, so a
    /// discontinuity is not lost if the sample that carried it is dropped.
    pub reset_epoch: u32,
}

impl OdometrySample {
    /// A healthy (quality 100) sample without covariance, epoch 0.
    pub fn new(
        t: TimeNs,
        t_world_body: Isometry3<f64>,
        v_world_m_s: Vector3<f64>,
        omega_body_rad_s: Vector3<f64>,
    ) -> Self {
        OdometrySample {
            t,
            t_world_body,
            v_world_m_s,
            omega_body_rad_s,
            pose_covariance: None,
            velocity_covariance: None,
            health: TrackingHealth::Tracking {
                quality_percent: 100,
            },
            reset_epoch: 0,
        }
    }

    /// True when every number in the sample is finite (NaN/Inf anywhere makes it unsendable).
    pub fn is_finite(&self) -> bool {
        let iso = &self.t_world_body;
        iso.translation.vector.iter().all(|v| v.is_finite())
            && iso.rotation.coords.iter().all(|v| v.is_finite())
            && self.v_world_m_s.iter().all(|v| v.is_finite())
            && self.omega_body_rad_s.iter().all(|v| v.is_finite())
            && self
                .pose_covariance
                .is_none_or(|c| c.iter().all(|v| v.is_finite()))
            && self
                .velocity_covariance
                .is_none_or(|c| c.iter().all(|v| v.is_finite()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn any_non_finite_number_is_detected() {
        let ok = OdometrySample::new(
            TimeNs(1),
            Isometry3::identity(),
            Vector3::zeros(),
            Vector3::zeros(),
        );
        assert!(ok.is_finite());
        let mut s = ok;
        s.t_world_body.translation.vector.y = f64::NAN;
        assert!(!s.is_finite());
        let mut s = ok;
        s.omega_body_rad_s.z = f64::INFINITY;
        assert!(!s.is_finite());
        let mut s = ok;
        let mut c = Matrix3::identity();
        c[(2, 1)] = f64::NAN;
        s.velocity_covariance = Some(c);
        assert!(!s.is_finite());
    }

    #[test]
    fn quality_mapping() {
        assert_eq!(TrackingHealth::Failed.mavlink_quality(), -1);
        assert_eq!(
            TrackingHealth::Tracking {
                quality_percent: 42
            }
            .mavlink_quality(),
            42
        );
        assert_eq!(
            TrackingHealth::Tracking {
                quality_percent: 250
            }
            .mavlink_quality(),
            100
        );
    }
}
