//! The odometry's side of the in-flight gyro alignment ([`crate::imu::gyro_alignment`]): raw
//! gyro samples kept, rotation pairs formed from the frames tracked against one keyframe, the
//! estimate applied to the samples fed to everything else.
//!
//! A pair is the body's rotation between two frames tracked against the same keyframe, both taken
//! relative to that keyframe (`R_kfᵀ R_frame` through `T_body_cam`): corrections of the world
//! (keyframe window, returns to stored keyframes) move the keyframe and the frames together and
//! do not enter it. The anchor is dropped whenever a frame is not tracked, the keyframe changes or
//! its pose is moved. The gyro over the pair is integrated from the raw samples with the tracker's
//! bias at the anchor turned into the gyro's axes, so each pair is independent of the rotation
//! applied at the time (eq. 4 with `R_x` conjugating the product exactly).
//!
//! With `photometric_pairs` each frame's rotation is the tracker's solution moved by its
//! `photometric_step`: where the keyframe's points alone put the frame, so the gyro does not pull
//! the rotations it is compared with toward itself.

use super::Odometry;
use crate::geometry::exp_so3;
use crate::imu::gyro_alignment::{GyroAlignment, GyroAlignmentConfig, RotationPair};
use crate::imu::{ImuBias, ImuSample, Preintegration};
use crate::time::TimeNs;
use crate::tracking::photometric_rotation;
use nalgebra::{Matrix3, Vector3, Vector6};
use std::collections::VecDeque;

/// Raw samples kept: ~10 s at 200 Hz, as the odometry's own buffer.
const RAW_SAMPLES_KEPT: usize = 2000;
/// Gauss–Newton steps per new pair (warm-started from the last estimate).
const SOLVE_ITERATIONS: usize = 3;

/// Start of the pair being formed.
#[derive(Clone, Copy, Debug)]
struct Anchor {
    t: TimeNs,
    kf_id: u32,
    /// The keyframe's camera rotation (world) at the anchor: the pair is dropped if it moves.
    r_world_kf_cam: Matrix3<f64>,
    /// `R_kf_bodyᵀ R_body`: the body's rotation relative to the keyframe's body.
    r_kf_body: Matrix3<f64>,
    /// The tracker's gyro bias in the gyro's axes.
    bias_gyro_axes_rad_s: Vector3<f64>,
}

/// The state of the alignment in the odometry.
#[derive(Clone, Debug)]
pub(super) struct GyroLink {
    alignment: GyroAlignment,
    /// `log(R_x)` applied to the samples now, rad.
    applied_rad: Vector3<f64>,
    r_applied: Matrix3<f64>,
    raw: VecDeque<ImuSample>,
    anchor: Option<Anchor>,
}

/// What the report shows of the alignment.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GyroAlignmentStats {
    /// `log(R_x)` applied at the end, rad (gyro axes → body).
    pub applied_rad: [f64; 3],
    /// The last estimate and its std per component, rad.
    pub estimate_rad: Option<[f64; 3]>,
    pub estimate_std_rad: Option<[f64; 3]>,
    /// RMS of the pairs' residuals at the estimate, rad.
    pub residual_rms_rad: Option<f64>,
    /// Pairs kept, and offered pairs dropped as gross errors.
    pub pairs: usize,
    pub rejected: usize,
    /// First time the estimate was applied in flight (`apply`).
    pub first_applied_t: Option<TimeNs>,
}

impl GyroLink {
    pub(super) fn new(cfg: GyroAlignmentConfig) -> Self {
        let alignment = GyroAlignment::new(cfg);
        let applied_rad = if alignment.config().enabled {
            alignment.initial_rotation_rad()
        } else {
            Vector3::zeros()
        };
        GyroLink {
            alignment,
            applied_rad,
            r_applied: exp_so3(&applied_rad),
            raw: VecDeque::with_capacity(RAW_SAMPLES_KEPT + 1),
            anchor: None,
        }
    }

    fn enabled(&self) -> bool {
        self.alignment.config().enabled
    }

    /// Keeps the raw sample and returns it with the gyro turned into the body frame.
    pub(super) fn correct(&mut self, s: &ImuSample) -> ImuSample {
        if !self.enabled() {
            return *s;
        }
        self.raw.push_back(*s);
        while self.raw.len() > RAW_SAMPLES_KEPT {
            self.raw.pop_front();
        }
        ImuSample {
            gyro_rad_s: self.r_applied * s.gyro_rad_s,
            ..*s
        }
    }

    /// `log(R_x)` now turning the samples, rad.
    pub(super) fn applied_rad(&self) -> [f64; 3] {
        self.applied_rad.into()
    }

    pub(super) fn drop_anchor(&mut self) {
        self.anchor = None;
    }
}

impl Odometry {
    /// After the frame at `t` was tracked: closes the pair begun on the tracker's keyframe if it
    /// is long enough, solves and applies the estimate, and begins the next pair here (no
    /// keyframe: the pair is dropped).
    pub(super) fn observe_gyro_alignment(&mut self, t: TimeNs, photometric_step: &Vector6<f64>) {
        if !self.gyro.enabled() {
            return;
        }
        let Some((kf_id, r_world_kf_cam)) = self.tracker.keyframe().map(|kf| {
            (
                kf.id,
                *kf.t_world_cam.rotation.to_rotation_matrix().matrix(),
            )
        }) else {
            self.gyro.drop_anchor();
            return;
        };
        let mut r_world_body = *self
            .tracker
            .state()
            .nav
            .r_world_body
            .to_rotation_matrix()
            .matrix();
        if self.gyro.alignment.config().photometric_pairs {
            // The photometric term's own solution.
            r_world_body = photometric_rotation(&r_world_body, photometric_step);
        }
        let r_cam_body = self.rig.t_body_cam.rotation.inverse().to_rotation_matrix();
        let r_kf_body = (r_world_kf_cam * r_cam_body.matrix()).transpose() * r_world_body;
        let bias_body = self.tracker.state().bias.gyro_rad_s;
        let here = Anchor {
            t,
            kf_id,
            r_world_kf_cam,
            r_kf_body,
            bias_gyro_axes_rad_s: self.gyro.r_applied.transpose() * bias_body,
        };
        let min_interval_s = self.gyro.alignment.config().min_interval_s;
        let Some(a) = self.gyro.anchor else {
            self.gyro.anchor = Some(here);
            return;
        };
        let same_keyframe = a.kf_id == kf_id && a.r_world_kf_cam == r_world_kf_cam;
        if !same_keyframe {
            self.gyro.anchor = Some(here);
            return;
        }
        if t.secs_since(a.t) < min_interval_s {
            return;
        }
        self.gyro.anchor = Some(here);
        let raw = self.gyro.raw.make_contiguous();
        if raw.first().is_none_or(|s| s.t > a.t) || raw.last().is_none_or(|s| s.t < t) {
            return;
        }
        let mut pre = Preintegration::new(
            a.t,
            ImuBias {
                gyro_rad_s: a.bias_gyro_axes_rad_s,
                accel_m_s2: Vector3::zeros(),
            },
        );
        pre.integrate(raw, t, None);
        let pair = RotationPair {
            delta_r_gyro: pre.delta_r,
            d_r_d_bg: pre.d_r_d_bg,
            delta_r_vision: a.r_kf_body.transpose() * r_kf_body,
        };
        if !self.gyro.alignment.push(pair) {
            return;
        }
        self.gyro.alignment.solve(SOLVE_ITERATIONS);
        if let Some(next) = self.gyro.alignment.next_applied(&self.gyro.applied_rad)
            && next != self.gyro.applied_rad
        {
            self.gyro.applied_rad = next;
            self.gyro.r_applied = exp_so3(&next);
            self.stats.gyro_alignment.first_applied_t.get_or_insert(t);
        }
        self.record_gyro_alignment();
    }

    pub(super) fn record_gyro_alignment(&mut self) {
        let s = &mut self.stats.gyro_alignment;
        let g = &self.gyro;
        s.applied_rad = g.applied_rad.into();
        s.pairs = g.alignment.len();
        s.rejected = g.alignment.rejected;
        if let Some(e) = g.alignment.estimate() {
            s.estimate_rad = Some(e.rotation_rad.into());
            s.estimate_std_rad = Some(e.rotation_std_rad.into());
            s.residual_rms_rad = Some(e.residual_rms_rad);
        }
    }
}
