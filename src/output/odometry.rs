//! Builds the pose messages: ODOMETRY (#331), or the legacy pair VISION_POSITION_ESTIMATE (#102)
//! + VISION_SPEED_ESTIMATE (#103) for older ArduPilot setups. Pure functions of one sample.

use crate::output::frames::{FcFrames, upper_triangle_21};
use crate::output::sample::OdometrySample;
use mavlink::dialects::common::{
    MavEstimatorType, MavFrame, MavMessage, ODOMETRY_DATA, VISION_POSITION_ESTIMATE_DATA,
    VISION_SPEED_ESTIMATE_DATA,
};
use nalgebra::{Matrix3, Matrix6};

/// ODOMETRY `frame_id` (the child frame is always MAV_FRAME_BODY_FRD).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum LocalFrame {
    /// MAV_FRAME_LOCAL_FRD: z down, heading arbitrary (what a VIO world is).
    #[default]
    Frd,
    /// MAV_FRAME_LOCAL_NED: asserts the world's x axis points north.
    Ned,
}

/// Which messages carry the pose.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum MessageSet {
    /// ODOMETRY (#331): PX4, and ArduPilot 4.x.
    #[default]
    Odometry,
    /// VISION_POSITION_ESTIMATE (#102) + VISION_SPEED_ESTIMATE (#103): older ArduPilot.
    Legacy,
}

/// Fallback uncertainties, used when a sample carries no covariance. `None` = unknown: the
/// covariance array is sent with NaN in element 0 (MAVLink's "unknown" marker), zeros elsewhere.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CovarianceFallback {
    /// Position standard deviation (each axis), m; used together with `attitude_std_rad`.
    pub position_std_m: Option<f64>,
    /// Attitude standard deviation (each axis), rad.
    pub attitude_std_rad: Option<f64>,
    /// Linear velocity standard deviation (each axis), m/s.
    pub velocity_std_m_s: Option<f64>,
    /// Angular rate standard deviation (each axis), rad/s: the rate block of ODOMETRY's velocity
    /// covariance (the estimator provides none). Required for any known velocity covariance.
    pub angular_rate_std_rad_s: Option<f64>,
}

/// Everything about the wire format that does not change per sample.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MessageConfig {
    pub frames: FcFrames,
    pub local_frame: LocalFrame,
    pub message_set: MessageSet,
    pub covariance: CovarianceFallback,
}

/// Per-message values owned by the sender, not the sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WireStamp {
    /// `time_usec` / `usec`, in the time base the sender chose.
    pub time_usec: u64,
    pub reset_counter: u8,
    /// -1..=100.
    pub quality: i8,
}

fn unknown<const N: usize>() -> [f32; N] {
    let mut a = [0.0f32; N];
    a[0] = f32::NAN;
    a
}

fn to_f32<const N: usize>(a: [f64; N]) -> [f32; N] {
    a.map(|v| v as f32)
}

impl MessageConfig {
    fn pose_covariance_local(&self, s: &OdometrySample) -> Option<Matrix6<f64>> {
        let cov_world = match (s.pose_covariance, self.covariance) {
            (Some(c), _) => c,
            (
                None,
                CovarianceFallback {
                    position_std_m: Some(p),
                    attitude_std_rad: Some(a),
                    ..
                },
            ) => Matrix6::from_diagonal(&nalgebra::Vector6::new(
                p * p,
                p * p,
                p * p,
                a * a,
                a * a,
                a * a,
            )),
            _ => return None,
        };
        Some(self.frames.pose_covariance_to_local(&cov_world))
    }

    fn velocity_covariance_world(&self, s: &OdometrySample) -> Option<Matrix3<f64>> {
        s.velocity_covariance.or_else(|| {
            self.covariance
                .velocity_std_m_s
                .map(|v| Matrix3::identity() * (v * v))
        })
    }

    /// ODOMETRY for one sample.
    pub fn odometry(&self, s: &OdometrySample, stamp: WireStamp) -> ODOMETRY_DATA {
        let fc = self
            .frames
            .to_fc(&s.t_world_body, &s.v_world_m_s, &s.omega_body_rad_s);
        let q = fc.q_local_fcbody;
        let pose_covariance = match self.pose_covariance_local(s) {
            Some(c) => to_f32(upper_triangle_21(&c)),
            None => unknown(),
        };
        let velocity_covariance = match (
            self.velocity_covariance_world(s),
            self.covariance.angular_rate_std_rad_s,
        ) {
            (Some(cv), Some(w)) => {
                let body = self
                    .frames
                    .velocity_covariance_to_fcbody(&s.t_world_body.rotation, &cv);
                let mut c = Matrix6::zeros();
                c.fixed_view_mut::<3, 3>(0, 0).copy_from(&body);
                for k in 3..6 {
                    c[(k, k)] = w * w;
                }
                to_f32(upper_triangle_21(&c))
            }
            _ => unknown(),
        };
        ODOMETRY_DATA {
            time_usec: stamp.time_usec,
            x: fc.p_local_m.x as f32,
            y: fc.p_local_m.y as f32,
            z: fc.p_local_m.z as f32,
            q: [q.w as f32, q.i as f32, q.j as f32, q.k as f32],
            vx: fc.v_fcbody_m_s.x as f32,
            vy: fc.v_fcbody_m_s.y as f32,
            vz: fc.v_fcbody_m_s.z as f32,
            rollspeed: fc.omega_fcbody_rad_s.x as f32,
            pitchspeed: fc.omega_fcbody_rad_s.y as f32,
            yawspeed: fc.omega_fcbody_rad_s.z as f32,
            pose_covariance,
            velocity_covariance,
            frame_id: match self.local_frame {
                LocalFrame::Frd => MavFrame::MAV_FRAME_LOCAL_FRD,
                LocalFrame::Ned => MavFrame::MAV_FRAME_LOCAL_NED,
            },
            child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
            reset_counter: stamp.reset_counter,
            estimator_type: MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO,
            quality: stamp.quality,
        }
    }

    /// VISION_POSITION_ESTIMATE (local-frame position, ZYX Euler angles of the FC attitude).
    /// It has no quality field: a sample with quality -1 is not sent in legacy mode.
    pub fn vision_position(
        &self,
        s: &OdometrySample,
        stamp: WireStamp,
    ) -> VISION_POSITION_ESTIMATE_DATA {
        let fc = self
            .frames
            .to_fc(&s.t_world_body, &s.v_world_m_s, &s.omega_body_rad_s);
        let (roll, pitch, yaw) = fc.q_local_fcbody.euler_angles();
        VISION_POSITION_ESTIMATE_DATA {
            usec: stamp.time_usec,
            x: fc.p_local_m.x as f32,
            y: fc.p_local_m.y as f32,
            z: fc.p_local_m.z as f32,
            roll: roll as f32,
            pitch: pitch as f32,
            yaw: yaw as f32,
            covariance: match self.pose_covariance_local(s) {
                Some(c) => to_f32(upper_triangle_21(&c)),
                None => unknown(),
            },
            reset_counter: stamp.reset_counter,
        }
    }

    /// VISION_SPEED_ESTIMATE (velocity in the local frame; full 3x3 row-major covariance).
    pub fn vision_speed(&self, s: &OdometrySample, stamp: WireStamp) -> VISION_SPEED_ESTIMATE_DATA {
        let fc = self
            .frames
            .to_fc(&s.t_world_body, &s.v_world_m_s, &s.omega_body_rad_s);
        let covariance = match self.velocity_covariance_world(s) {
            Some(cv) => {
                let l = self.frames.velocity_covariance_to_local(&cv);
                let mut a = [0.0f32; 9];
                for (k, v) in a.iter_mut().enumerate() {
                    *v = l[(k / 3, k % 3)] as f32;
                }
                a
            }
            None => unknown(),
        };
        VISION_SPEED_ESTIMATE_DATA {
            usec: stamp.time_usec,
            x: fc.v_local_m_s.x as f32,
            y: fc.v_local_m_s.y as f32,
            z: fc.v_local_m_s.z as f32,
            covariance,
            reset_counter: stamp.reset_counter,
        }
    }

    /// The messages for one sample under the configured [`MessageSet`], each checked by
    /// [`is_wire_finite`]; `None` when nothing may be sent (a non-finite result, e.g. an f32
    /// overflow, or a failed-quality sample in legacy mode, which has no way to flag it).
    pub fn messages(&self, s: &OdometrySample, stamp: WireStamp) -> Option<Vec<MavMessage>> {
        let msgs = match self.message_set {
            MessageSet::Odometry => vec![MavMessage::ODOMETRY(self.odometry(s, stamp))],
            MessageSet::Legacy if stamp.quality < 0 => return None,
            MessageSet::Legacy => vec![
                MavMessage::VISION_POSITION_ESTIMATE(self.vision_position(s, stamp)),
                MavMessage::VISION_SPEED_ESTIMATE(self.vision_speed(s, stamp)),
            ],
        };
        msgs.iter().all(is_wire_finite).then_some(msgs)
    }
}

/// A covariance array is fine when all finite, or when it is exactly the "unknown" marker:
/// NaN in element 0 and finite elsewhere.
fn covariance_ok(a: &[f32]) -> bool {
    a[1..].iter().all(|v| v.is_finite()) && (a[0].is_finite() || a[0].is_nan())
}

/// True when a pose message holds no NaN/Inf other than the covariance "unknown" marker.
pub fn is_wire_finite(m: &MavMessage) -> bool {
    match m {
        MavMessage::ODOMETRY(o) => {
            [
                o.x,
                o.y,
                o.z,
                o.vx,
                o.vy,
                o.vz,
                o.rollspeed,
                o.pitchspeed,
                o.yawspeed,
            ]
            .iter()
            .chain(o.q.iter())
            .all(|v| v.is_finite())
                && covariance_ok(&o.pose_covariance)
                && covariance_ok(&o.velocity_covariance)
        }
        MavMessage::VISION_POSITION_ESTIMATE(v) => {
            [v.x, v.y, v.z, v.roll, v.pitch, v.yaw]
                .iter()
                .all(|v| v.is_finite())
                && covariance_ok(&v.covariance)
        }
        MavMessage::VISION_SPEED_ESTIMATE(v) => {
            [v.x, v.y, v.z].iter().all(|v| v.is_finite()) && covariance_ok(&v.covariance)
        }
        _ => true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::sample::TrackingHealth;
    use crate::time::TimeNs;
    use nalgebra::{Isometry3, Vector3};

    fn sample() -> OdometrySample {
        OdometrySample::new(
            TimeNs(5_000_000_000),
            Isometry3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.0, 0.0, 0.5)),
            Vector3::new(0.5, 0.0, -0.1),
            Vector3::new(0.0, 0.0, 0.2),
        )
    }

    const STAMP: WireStamp = WireStamp {
        time_usec: 5_000_000,
        reset_counter: 3,
        quality: 77,
    };

    #[test]
    fn odometry_fields_and_unknown_covariance() {
        let cfg = MessageConfig::default();
        let o = cfg.odometry(&sample(), STAMP);
        assert_eq!((o.x, o.y, o.z), (1.0, -2.0, -3.0));
        assert_eq!(o.time_usec, 5_000_000);
        assert_eq!((o.reset_counter, o.quality), (3, 77));
        assert_eq!(o.frame_id, MavFrame::MAV_FRAME_LOCAL_FRD);
        assert_eq!(o.child_frame_id, MavFrame::MAV_FRAME_BODY_FRD);
        assert_eq!(o.estimator_type, MavEstimatorType::MAV_ESTIMATOR_TYPE_VIO);
        let qn: f32 = o.q.iter().map(|v| v * v).sum();
        assert!((qn - 1.0).abs() < 1e-6);
        // FLU yaw +0.5 rad about z up = FRD yaw -0.5: q = (cos 0.25, 0, 0, -sin 0.25).
        assert!((o.q[3] + (0.25f32).sin()).abs() < 1e-6 && o.q[0] > 0.0);
        assert!((o.yawspeed + 0.2).abs() < 1e-7);
        assert!(o.pose_covariance[0].is_nan() && o.pose_covariance[1..].iter().all(|&v| v == 0.0));
        assert!(o.velocity_covariance[0].is_nan());
        assert!(is_wire_finite(&MavMessage::ODOMETRY(o)));
        let ned = MessageConfig {
            local_frame: LocalFrame::Ned,
            ..cfg
        };
        assert_eq!(
            ned.odometry(&sample(), STAMP).frame_id,
            MavFrame::MAV_FRAME_LOCAL_NED
        );
    }

    #[test]
    fn configured_and_estimator_covariances() {
        let cfg = MessageConfig {
            covariance: CovarianceFallback {
                position_std_m: Some(0.1),
                attitude_std_rad: Some(0.02),
                velocity_std_m_s: Some(0.3),
                angular_rate_std_rad_s: Some(0.01),
            },
            ..Default::default()
        };
        let o = cfg.odometry(&sample(), STAMP);
        let diag = |a: &[f32; 21]| [0, 6, 11, 15, 18, 20].map(|k| a[k]);
        let pd = diag(&o.pose_covariance);
        assert!(
            (pd[0] - 0.01).abs() < 1e-9 && (pd[5] - 0.0004).abs() < 1e-9,
            "{pd:?}"
        );
        let vd = diag(&o.velocity_covariance);
        assert!(
            (vd[2] - 0.09).abs() < 1e-7 && (vd[3] - 1e-4).abs() < 1e-9,
            "{vd:?}"
        );
        // An estimator covariance wins over the fallback.
        let mut s = sample();
        let mut c = Matrix6::zeros();
        c[(2, 2)] = 9.0;
        s.pose_covariance = Some(c);
        // A world-frame velocity covariance along world x, seen from the body yawed 0.5 rad left
        // (FLU IMU, FRD body): rotated into the body frame, trace kept, x/y correlated.
        let mut cv = Matrix3::zeros();
        cv[(0, 0)] = 4.0;
        s.velocity_covariance = Some(cv);
        let o = cfg.odometry(&s, STAMP);
        assert_eq!(o.pose_covariance[11], 9.0);
        assert_eq!(o.pose_covariance[0], 0.0);
        let (c, sn) = (0.5f32.cos(), 0.5f32.sin());
        let v = &o.velocity_covariance;
        assert!(
            (v[0] - 4.0 * c * c).abs() < 1e-6 && (v[6] - 4.0 * sn * sn).abs() < 1e-6,
            "{v:?}"
        );
        assert!((v[1] - 4.0 * c * sn).abs() < 1e-6, "FRD y = -FLU y: {v:?}");
        assert!(
            (v[15] - 1e-4).abs() < 1e-9,
            "rate block from the fallback: {v:?}"
        );
    }

    #[test]
    fn legacy_pair_and_failed_quality() {
        let cfg = MessageConfig {
            message_set: MessageSet::Legacy,
            ..Default::default()
        };
        let msgs = cfg.messages(&sample(), STAMP).unwrap();
        let (MavMessage::VISION_POSITION_ESTIMATE(p), MavMessage::VISION_SPEED_ESTIMATE(v)) =
            (&msgs[0], &msgs[1])
        else {
            panic!("{msgs:?}")
        };
        assert_eq!(
            (p.x, p.y, p.z, p.usec, p.reset_counter),
            (1.0, -2.0, -3.0, 5_000_000, 3)
        );
        assert!((p.yaw + 0.5).abs() < 1e-6 && p.roll.abs() < 1e-6 && p.pitch.abs() < 1e-6);
        assert_eq!((v.x, v.y, v.z), (0.5, 0.0, 0.1));
        assert!(v.covariance[0].is_nan() && p.covariance[0].is_nan());
        let failed = WireStamp {
            quality: TrackingHealth::Failed.mavlink_quality(),
            ..STAMP
        };
        assert!(cfg.messages(&sample(), failed).is_none());
        let odo = MessageConfig::default()
            .messages(&sample(), failed)
            .unwrap();
        assert!(matches!(&odo[0], MavMessage::ODOMETRY(o) if o.quality == -1));
    }

    #[test]
    fn f32_overflow_is_refused() {
        let mut s = sample();
        s.t_world_body.translation.vector.x = 1e300; // finite f64, Inf as f32
        assert!(s.is_finite());
        assert!(MessageConfig::default().messages(&s, STAMP).is_none());
    }
}
