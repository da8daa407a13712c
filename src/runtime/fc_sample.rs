//! One odometry frame as the flight controller's sample ([`OdometrySample`], sent by
//! [`crate::output::MavlinkSender`] as ODOMETRY #331): the published pose and velocity, the
//! tracker's covariance in the sender's convention, a health from the phase and the tracking, and
//! the reset epoch.
//!
//! The epoch counts every discontinuity of the published pose: re-initialisations after a loss
//! ([`OdometryFrame::resets`]) and the loop closer's jumps of the published pose beyond
//! `[loop_closure] reset_min_jump_m` ([`OdometryFrame::loop_corrections`]); the sender turns each
//! change into MAVLink `reset_counter` + 1, so the flight controller's estimator resets its vision
//! fusion instead of taking a jump as motion.

use crate::imu::residual::block;
use crate::output::frames::pose_covariance_from_body_perturbation;
use crate::output::{OdometrySample, TrackingHealth};
use crate::runtime::odometry::{OdometryFrame, Phase};
use crate::time::TimeNs;
use crate::tracking::pose_of;
use nalgebra::{Matrix3, Matrix6};

/// The sample for `f`, stamped `t_host` (host monotonic clock), or `None` for a frame that
/// carries no pose (waiting for the start: nothing valid to send). A sample with a non-finite
/// number is returned as is: the sender drops it ([`OdometrySample::is_finite`]).
pub fn fc_sample(f: &OdometryFrame, t_host: TimeNs) -> Option<OdometrySample> {
    if !f.valid {
        return None;
    }
    let x = &f.result.state;
    let mut s = OdometrySample::new(t_host, pose_of(x), x.nav.v_world_m_s, f.omega_body_rad_s);
    let cov = &f.result.covariance;
    // Eq. 11's increments `[δθ_body, δt_body]` (`FrameState::boxplus`: `p + R δt`) to
    // `[δp_world; δθ_body]`: `δp_world = R δt_body`.
    let r = x.nav.r_world_body.to_rotation_matrix().into_inner();
    let mut j = Matrix6::zeros();
    j.fixed_view_mut::<3, 3>(0, block::POS).copy_from(&r);
    j.fixed_view_mut::<3, 3>(3, block::ROT)
        .copy_from(&Matrix3::identity());
    let pose_body = cov.fixed_view::<6, 6>(0, 0).into_owned();
    let pose = pose_covariance_from_body_perturbation(
        &x.nav.r_world_body,
        &(j * pose_body * j.transpose()),
    );
    s.pose_covariance = usable(&pose);
    let vel: Matrix3<f64> = cov.fixed_view::<3, 3>(block::VEL, block::VEL).into_owned();
    s.velocity_covariance = usable(&vel);
    s.health = health(f);
    s.reset_epoch = f.resets.wrapping_add(f.loop_corrections);
    Some(s)
}

/// The tracking health of a frame: failed while lost, while the map's scale has run away
/// ([`OdometryFrame::scale_fault`]) or while the speed is beyond the vehicle's
/// ([`OdometryFrame::speed_fault`]); the worst quality (1) for a pose the IMU
/// alone carried (the first map being built, or a frame whose visual solution was rejected);
/// at rest the best; tracking, the share of the keyframe's points that are inliers.
pub fn health(f: &OdometryFrame) -> TrackingHealth {
    if f.scale_fault || f.speed_fault {
        return TrackingHealth::Failed;
    }
    let quality_percent = match f.phase {
        Phase::Lost => return TrackingHealth::Failed,
        Phase::Static => 100,
        _ if f.result.flag.is_some() => 1,
        Phase::Initializing | Phase::WaitingForStart => 1,
        Phase::Tracking => (f.result.inlier_ratio * 100.0).round().clamp(1.0, 100.0) as u8,
    };
    TrackingHealth::Tracking { quality_percent }
}

/// A covariance worth sending: finite with a positive diagonal (a zero one would claim
/// certainty); otherwise `None`, and the sender's configured fallback goes out.
fn usable<const N: usize>(
    m: &nalgebra::SMatrix<f64, N, N>,
) -> Option<nalgebra::SMatrix<f64, N, N>> {
    (m.iter().all(|v| v.is_finite()) && m.diagonal().iter().all(|&d| d > 0.0)).then_some(*m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::Matrix15;
    use crate::imu::integration::{ImuBias, NavState};
    use crate::imu::residual::FrameState;
    use crate::runtime::odometry::FrameTimes;
    use crate::tracking::{NUM_LEVELS, TrackResult};
    use nalgebra::{UnitQuaternion, Vector3, Vector6};

    fn frame(phase: Phase) -> OdometryFrame {
        let state = FrameState {
            nav: NavState {
                t: TimeNs(7),
                r_world_body: UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
                p_world_m: Vector3::new(1.0, 2.0, 3.0),
                v_world_m_s: Vector3::new(0.5, -0.1, 0.2),
            },
            bias: ImuBias::default(),
        };
        OdometryFrame {
            result: TrackResult {
                t: TimeNs(7),
                state,
                covariance: Matrix15::identity() * 1e-4,
                log_gain: 0.0,
                offset_gray: 0.0,
                flag: None,
                iterations: [0; NUM_LEVELS],
                inlier_ratio: 0.834,
                overlap: 1.0,
                residual_rms_gray: 1.0,
                imu_chi2: 0.0,
                downweighted: false,
                photometric_info: Matrix6::zeros(),
                photometric_step: Vector6::zeros(),
                keyframe_id: Some(1),
                wants_keyframe: false,
                imu_velocity_divergence_m_s: None,
                time_s: 0.0,
            },
            phase,
            valid: true,
            resets: 2,
            loop_corrections: 3,
            loop_world: None,
            scale_fault: false,
            speed_fault: false,
            omega_body_rad_s: Vector3::new(0.01, 0.02, -0.03),
            times: FrameTimes::default(),
        }
    }

    #[test]
    fn the_pose_velocity_rate_and_epoch_are_the_frames() {
        let f = frame(Phase::Tracking);
        let s = fc_sample(&f, TimeNs(42)).unwrap();
        assert_eq!(s.t, TimeNs(42));
        assert_eq!(s.t_world_body, pose_of(&f.result.state));
        assert_eq!(s.v_world_m_s, f.result.state.nav.v_world_m_s);
        assert_eq!(s.omega_body_rad_s, f.omega_body_rad_s);
        assert_eq!(s.reset_epoch, 5, "resets + loop closer's jumps");
        assert_eq!(
            s.health,
            TrackingHealth::Tracking {
                quality_percent: 83
            }
        );
        let waiting = OdometryFrame {
            valid: false,
            ..frame(Phase::WaitingForStart)
        };
        assert!(fc_sample(&waiting, TimeNs(0)).is_none());
    }

    #[test]
    fn health_follows_the_phase_and_the_visual_solution() {
        let q = |p: Phase| health(&frame(p));
        assert_eq!(q(Phase::Lost), TrackingHealth::Failed);
        assert_eq!(
            q(Phase::Static),
            TrackingHealth::Tracking {
                quality_percent: 100
            }
        );
        assert_eq!(
            q(Phase::Initializing),
            TrackingHealth::Tracking { quality_percent: 1 }
        );
        let mut runaway = frame(Phase::Tracking);
        runaway.scale_fault = true;
        assert_eq!(health(&runaway), TrackingHealth::Failed);
        runaway.phase = Phase::Static;
        assert_eq!(health(&runaway), TrackingHealth::Failed);
        let mut too_fast = frame(Phase::Tracking);
        too_fast.speed_fault = true;
        assert_eq!(health(&too_fast), TrackingHealth::Failed);
        let mut rejected = frame(Phase::Tracking);
        rejected.result.flag = Some(crate::tracking::FlagReason::FewInliers);
        assert_eq!(
            health(&rejected),
            TrackingHealth::Tracking { quality_percent: 1 }
        );
        let mut none_inlier = frame(Phase::Tracking);
        none_inlier.result.inlier_ratio = 0.0;
        assert_eq!(
            health(&none_inlier),
            TrackingHealth::Tracking { quality_percent: 1 },
            "tracking is never sent as quality 0 (MAVLink: unknown)"
        );
    }

    /// The covariance of eq. 11's body-frame increments against the spread of poses perturbed by
    /// them (`FrameState::boxplus`): a 1-σ step along each increment axis moves the world
    /// position / world rotation by the column the conversion predicts.
    #[test]
    fn the_covariance_is_turned_into_world_position_and_world_rotation() {
        let mut f = frame(Phase::Tracking);
        let x = f.result.state;
        // Independent increments with distinct deviations, so a wrong block shows.
        let sd = [0.01, 0.02, 0.03, 0.1, 0.2, 0.3];
        let mut cov = Matrix15::identity() * 1e-6;
        for (i, s) in sd.iter().enumerate() {
            cov[(i, i)] = s * s;
        }
        f.result.covariance = cov;
        let got = fc_sample(&f, TimeNs(0)).unwrap().pose_covariance.unwrap();
        // Expected: Σ_k e_k e_kᵀ with e_k = [δp_world; δθ_world] of a σ_k step along axis k.
        let mut want = Matrix6::zeros();
        for (k, s) in sd.iter().enumerate() {
            let mut d = nalgebra::SVector::<f64, 15>::zeros();
            d[k] = *s;
            let y = x.boxplus(&d);
            let dp = y.nav.p_world_m - x.nav.p_world_m;
            let dth = (y.nav.r_world_body * x.nav.r_world_body.inverse()).scaled_axis();
            let mut e = Vector6::zeros();
            e.fixed_rows_mut::<3>(0).copy_from(&dp);
            e.fixed_rows_mut::<3>(3).copy_from(&dth);
            want += e * e.transpose();
        }
        assert!((got - want).abs().max() < 1e-9, "got\n{got}\nwant\n{want}");
        let v = fc_sample(&f, TimeNs(0))
            .unwrap()
            .velocity_covariance
            .unwrap();
        assert!((v - Matrix3::identity() * 1e-6).abs().max() < 1e-15);
    }

    #[test]
    fn a_covariance_claiming_certainty_or_not_finite_is_not_sent() {
        let mut f = frame(Phase::Static);
        f.result.covariance = Matrix15::zeros();
        let s = fc_sample(&f, TimeNs(0)).unwrap();
        assert!(s.pose_covariance.is_none() && s.velocity_covariance.is_none());
        f.result.covariance = Matrix15::identity();
        f.result.covariance[(7, 7)] = f64::NAN;
        let s = fc_sample(&f, TimeNs(0)).unwrap();
        assert!(s.pose_covariance.is_some() && s.velocity_covariance.is_none());
    }
}
