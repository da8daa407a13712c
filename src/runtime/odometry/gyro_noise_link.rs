//! `[window] inflight_gyro_noise`: the gyro's rotation noise read in flight
//! ([`crate::imu::gyro_noise_reading`]) from each keyframe interval the window is joined over —
//! the IMU from the window's newest keyframe to the frame about to be the next, against the
//! relative rotation tracking measured between them — and the factor it gives on the rotation
//! part of the back end's IMU factors (the window, the keyframe adjustment, the loop closer's
//! odometry edges) in place of the pad's.

use super::*;
use crate::imu::misalignment::turned;
use crate::tracking::photometric_rotation;
use nalgebra::Vector6;

/// A new factor is applied when it differs from the one applied by more than this fraction.
const RESCALE_STEP: f64 = 0.05;

impl Odometry {
    /// Sets the factor on the rotation part of the back end's IMU factors: the keyframe window
    /// now, the loop closer's odometry edges (`odometry_std_from_rest`) and the keyframe
    /// adjustments from their next job.
    pub(super) fn set_rotation_noise_scale(&mut self, scale: f64) {
        self.rotation_noise_scale = scale;
        self.window.set_imu_rotation_noise_scale(scale);
        self.loop_odometry_noise_scale(scale);
    }

    /// One keyframe interval: `pre` the buffered IMU from the window's newest keyframe to the
    /// frame at `t` (at the window's bias), `t_i_j` the body's motion between them as tracked,
    /// `photometric_step` the tracker's step from the joint solution to the photometric term's
    /// own (`inflight_gyro_noise_photometric`: the rotation read against is moved by it). The
    /// gyro is turned by the window's estimate of its turn, as the window applies it. Once
    /// `inflight_gyro_noise_min_intervals` are read, the median reading over the window's
    /// `imu_noise_scale × imu_rotation_noise_factor` (within 1 ..
    /// `inflight_gyro_noise_max_scale`) is the back end's factor.
    pub(super) fn read_gyro_noise(
        &mut self,
        pre: &Preintegration,
        t_i_j: &Isometry3<f64>,
        photometric_step: &Vector6<f64>,
        t: TimeNs,
    ) {
        let w = &self.cfg.window;
        if !w.inflight_gyro_noise {
            return;
        }
        let mut r_i_j = t_i_j.rotation.to_rotation_matrix().into_inner();
        if w.inflight_gyro_noise_photometric {
            // Where the keyframe's points alone turn the frame.
            r_i_j = photometric_rotation(&r_i_j, photometric_step);
        }
        let modelled = w.imu_noise_scale * w.imu_rotation_noise_factor;
        let (min_intervals, max_scale) = (
            w.inflight_gyro_noise_min_intervals,
            w.inflight_gyro_noise_max_scale.max(1.0),
        );
        let pre = turned(pre, &self.window.gyro_misalignment_rad());
        if self.gyro_noise.observe(&pre, &r_i_j).is_none() {
            return;
        }
        self.stats.inflight_gyro_noise_intervals += 1;
        let Some(ratio) = self.gyro_noise.median_ratio(min_intervals) else {
            return;
        };
        self.stats.inflight_gyro_noise_ratio = Some(ratio);
        if modelled <= 0.0 || !modelled.is_finite() {
            return;
        }
        let scale = (ratio / modelled).clamp(1.0, max_scale);
        if (scale / self.rotation_noise_scale - 1.0).abs() > RESCALE_STEP {
            self.set_rotation_noise_scale(scale);
            self.stats
                .inflight_gyro_noise_scales
                .push((t, ratio, scale));
        }
    }
}
