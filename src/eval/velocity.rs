//! Velocity error against the ground truth's recorded velocity.
//!
//! The odometry sends its velocity to the flight controller (MAVLink ODOMETRY #331 `vx vy vz`),
//! which fuses it as a measurement of its own, so its error is a figure of the product beside the
//! ATE: a position that is right on average can still come with a velocity that jitters or lags.
//! The estimate's velocity is turned into the ground truth's world by the same alignment as its
//! poses (and scaled with a Sim3 one) and compared with the ground truth's velocity (EuRoC
//! `v_RS_R`, world frame) linearly interpolated at the estimate's time.

use super::Sim3;
use super::stats::{ErrorStats, percentile, sorted};
use crate::dataset::GroundTruthState;
use crate::time::TimeNs;
use nalgebra::Vector3;

/// Norm of the velocity error over the matched estimates, m/s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VelocityErrors {
    pub rmse_m_s: f64,
    pub median_m_s: f64,
    pub p90_m_s: f64,
    pub max_m_s: f64,
    /// Estimates matched to a ground-truth velocity.
    pub samples: usize,
}

/// The ground truth's velocity at `t`, interpolated between the two samples bracketing it if both
/// carry one and they are at most `max_dt_ns` apart (a sample at exactly `t` is taken as it is).
fn gt_velocity_at(gt: &[GroundTruthState], t: TimeNs, max_dt_ns: i64) -> Option<Vector3<f64>> {
    let i = gt.partition_point(|s| s.t < t);
    let after = gt.get(i)?;
    if after.t == t {
        return after.v_world_m_s;
    }
    let before = gt.get(i.checked_sub(1)?)?;
    let span_ns = after.t.0 - before.t.0;
    if span_ns <= 0 || span_ns > max_dt_ns {
        return None;
    }
    let a = (t.0 - before.t.0) as f64 / span_ns as f64;
    Some(before.v_world_m_s? * (1.0 - a) + after.v_world_m_s? * a)
}

/// Velocity errors of `est` (time, velocity in the estimate's world, m/s) against `gt`, with the
/// estimate's world mapped into the ground truth's by `align` (its rotation and scale; the
/// translation does not enter a velocity). `gt` is time-ordered. `None` when no estimate could be
/// matched: the ground truth has no velocity column (a pose-only file such as the shared
/// V1_01's), or no estimate lies within its time span and gaps of at most `max_dt_ns`, or an
/// estimate is not finite.
pub fn velocity_errors(
    gt: &[GroundTruthState],
    est: &[(TimeNs, Vector3<f64>)],
    align: &Sim3,
    max_dt_ns: i64,
) -> Option<VelocityErrors> {
    let errors: Vec<f64> = est
        .iter()
        .filter_map(|(t, v)| {
            let v_gt = gt_velocity_at(gt, *t, max_dt_ns)?;
            Some((align.rotation * v * align.scale - v_gt).norm())
        })
        .collect();
    let stats = ErrorStats::of(&errors)?;
    let s = sorted(errors.iter().copied());
    Some(VelocityErrors {
        rmse_m_s: stats.rmse,
        median_m_s: stats.median,
        p90_m_s: percentile(&s, 90.0),
        max_m_s: stats.max,
        samples: stats.count,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, UnitQuaternion};

    /// 10 s at 100 Hz of a body circling at 1 m/s (velocity tangent to the circle), with velocity.
    fn circling_gt() -> Vec<GroundTruthState> {
        (0..1000)
            .map(|k| {
                let s = k as f64 * 0.01;
                GroundTruthState {
                    t: TimeNs(k * 10_000_000),
                    t_world_body: Isometry3::identity(),
                    v_world_m_s: Some(Vector3::new(-s.sin(), s.cos(), 0.1)),
                    gyro_bias_rad_s: None,
                    accel_bias_m_s2: None,
                }
            })
            .collect()
    }

    fn align_yaw(yaw_rad: f64, scale: f64) -> Sim3 {
        Sim3 {
            rotation: UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_rad),
            translation: Vector3::new(5.0, -2.0, 1.0),
            scale,
        }
    }

    /// The estimate as the ground truth's velocity at `t`, seen from a world turned by `-yaw` and
    /// shrunk by `scale`, plus `err` (ground-truth world, m/s).
    fn estimate_at(t_s: f64, yaw_rad: f64, scale: f64, err: Vector3<f64>) -> Vector3<f64> {
        let v_gt = Vector3::new(-t_s.sin(), t_s.cos(), 0.1) + err;
        UnitQuaternion::from_euler_angles(0.0, 0.0, -yaw_rad) * v_gt / scale
    }

    #[test]
    fn a_constant_error_is_measured_through_the_alignment() {
        let gt = circling_gt();
        let (yaw, scale) = (0.7, 0.9);
        let err = Vector3::new(0.03, -0.04, 0.0);
        // At the samples and halfway between them (interpolated; the velocity is smooth).
        let est: Vec<_> = (0..1990)
            .map(|k| {
                let t_ns = k * 5_000_000;
                let v = estimate_at(t_ns as f64 * 1e-9, yaw, scale, err);
                (TimeNs(t_ns), v)
            })
            .collect();
        let e = velocity_errors(&gt, &est, &align_yaw(yaw, scale), 20_000_000).unwrap();
        assert_eq!(e.samples, est.len());
        for v in [e.rmse_m_s, e.median_m_s, e.p90_m_s, e.max_m_s] {
            assert!((v - 0.05).abs() < 1e-4, "{e:?}");
        }
        // Without the alignment's rotation the same estimate is far off.
        let e = velocity_errors(&gt, &est, &align_yaw(0.0, scale), 20_000_000).unwrap();
        assert!(e.rmse_m_s > 0.5, "{e:?}");
    }

    #[test]
    fn estimates_outside_the_ground_truth_or_in_its_gaps_are_not_matched() {
        let mut gt = circling_gt();
        gt.retain(|s| !(300..600).contains(&(s.t.0 / 10_000_000))); // a 3 s dropout
        let est: Vec<_> = [-1.0, 1.0, 4.5, 9.0, 12.0]
            .iter()
            .map(|&t_s| {
                let v = estimate_at(t_s, 0.0, 1.0, Vector3::zeros());
                (TimeNs((t_s * 1e9) as i64), v)
            })
            .collect();
        let e = velocity_errors(&gt, &est, &Sim3::identity(), 20_000_000).unwrap();
        assert_eq!(e.samples, 2, "only 1 s and 9 s are inside and off the gap");
        assert!(e.max_m_s < 1e-3, "{e:?}");
    }

    #[test]
    fn a_pose_only_ground_truth_gives_no_figure() {
        let mut gt = circling_gt();
        gt.iter_mut().for_each(|s| s.v_world_m_s = None);
        let est = vec![(TimeNs(1_000_000_000), Vector3::zeros())];
        assert_eq!(
            velocity_errors(&gt, &est, &Sim3::identity(), 20_000_000),
            None
        );
    }

    #[test]
    fn a_non_finite_estimate_gives_no_figure() {
        let gt = circling_gt();
        let est = vec![
            (TimeNs(1_000_000_000), Vector3::zeros()),
            (TimeNs(2_000_000_000), Vector3::new(f64::NAN, 0.0, 0.0)),
        ];
        assert_eq!(
            velocity_errors(&gt, &est, &Sim3::identity(), 20_000_000),
            None
        );
    }
}
