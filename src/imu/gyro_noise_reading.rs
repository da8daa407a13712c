//! The gyro's noise as read in flight: the rotation it integrates between two keyframes against
//! the relative rotation the camera tracked over the same interval.
//!
//! Over one interval the preintegrated rotation `ΔR` (eq. 4) and the tracked `R_iᵀ R_j` differ by
//! `r = log(ΔRᵀ R_iᵀ R_j)`; if the gyro's only error were the white noise its preintegration
//! covariance models (eq. 9–10, the `δφ` block of [`Preintegration::cov`]), `rᵀ Σ_φ⁻¹ r` would be
//! χ² with 3 degrees of freedom. Its square root over the median of χ₃ (1.538) is then one reading
//! of how many times the modelled density the gyro's error really is: rotor vibration, a bias that
//! wanders within the interval, a clock or axis error — and the camera's own error, which keeps
//! the reading of a perfect gyro somewhat above 1. The median over the last intervals is the
//! estimate, robust to an interval tracked badly.
//!
//! A pad reading ([`crate::imu::static_init`]) sees the vibration at rest only; this one sees the
//! gyro as it flies. Fixed capacity: no allocation after construction.

use super::Preintegration;
use crate::geometry::log_so3;
use nalgebra::Matrix3;
use std::collections::VecDeque;

/// Median of the χ distribution with 3 degrees of freedom (`√2.366`).
const CHI3_MEDIAN: f64 = 1.538_2;

/// The last intervals' readings and their median.
#[derive(Clone, Debug)]
pub struct GyroNoiseReading {
    ratios: VecDeque<f64>,
    capacity: usize,
    /// Scratch for the median, preallocated.
    sorted: Vec<f64>,
}

impl GyroNoiseReading {
    /// Keeps the readings of the last `capacity` intervals (at least 1).
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        GyroNoiseReading {
            ratios: VecDeque::with_capacity(capacity),
            capacity,
            sorted: Vec::with_capacity(capacity),
        }
    }

    /// One interval: `pre` the gyro's preintegration over it (its covariance as modelled, the
    /// gyro turned as it is applied), `r_i_j` the body's rotation over it as tracked (`R_iᵀ R_j`,
    /// body j to body i). Returns the reading — the error's Mahalanobis norm over χ₃'s median —
    /// or `None` (kept out) if the interval has no modelled rotation noise or is not finite.
    pub fn observe(&mut self, pre: &Preintegration, r_i_j: &Matrix3<f64>) -> Option<f64> {
        let r = log_so3(&(pre.delta_r.transpose() * r_i_j));
        let cov = pre.cov.fixed_view::<3, 3>(0, 0).into_owned();
        let mahalanobis_sq = cov.cholesky()?.solve(&r).dot(&r);
        let ratio = mahalanobis_sq.sqrt() / CHI3_MEDIAN;
        if !ratio.is_finite() {
            return None;
        }
        if self.ratios.len() == self.capacity {
            self.ratios.pop_front();
        }
        self.ratios.push_back(ratio);
        Some(ratio)
    }

    /// Intervals read (at most the capacity).
    pub fn len(&self) -> usize {
        self.ratios.len()
    }

    pub fn is_empty(&self) -> bool {
        self.ratios.is_empty()
    }

    /// The median reading: the gyro's error over the modelled density (1 = as modelled), or
    /// `None` with fewer than `min_intervals` read.
    pub fn median_ratio(&mut self, min_intervals: usize) -> Option<f64> {
        if self.ratios.is_empty() || self.ratios.len() < min_intervals {
            return None;
        }
        self.sorted.clear();
        self.sorted.extend(self.ratios.iter().copied());
        let mid = self.sorted.len() / 2;
        let (_, m, _) = self.sorted.select_nth_unstable_by(mid, f64::total_cmp);
        Some(*m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::exp_so3;
    use crate::imu::{ImuBias, ImuNoise, ImuSample};
    use crate::sim::rng::SimRng;
    use crate::time::TimeNs;
    use nalgebra::Vector3;

    const RATE_HZ: f64 = 200.0;
    /// 0.4 s between keyframes: 80 samples.
    const SAMPLES_PER_INTERVAL: usize = 80;

    /// A body turning at a slowly varying rate; the gyro reads it with white noise of
    /// `white_factor` × the modelled density and a bias that wanders as a random walk of
    /// `walk_rad_s2_sqrt_hz` (unmodelled within an interval). Each interval's preintegration
    /// (modelled noise: the datasheet density) is read against the true rotation.
    fn read(white_factor: f64, walk_rad_s2_sqrt_hz: f64, seed: u64) -> GyroNoiseReading {
        let noise = ImuNoise::euroc_adis16448();
        let dt_s = 1.0 / RATE_HZ;
        let (white_std, _) = noise.discrete_white_std(dt_s);
        let mut rng = SimRng::new(seed);
        let mut reading = GyroNoiseReading::new(64);
        let mut wander = Vector3::zeros();
        let mut k = 0usize;
        for _ in 0..100 {
            let t0 = TimeNs::from_secs_f64(k as f64 * dt_s);
            let mut samples = Vec::with_capacity(SAMPLES_PER_INTERVAL + 1);
            let mut r_true = Matrix3::identity();
            let omega_at =
                |t_s: f64| Vector3::new(0.3 * (0.7 * t_s).sin(), 0.2, -0.4 * (0.3 * t_s).cos());
            for i in 0..=SAMPLES_PER_INTERVAL {
                let t_s = (k + i) as f64 * dt_s;
                let omega = omega_at(t_s);
                if i < SAMPLES_PER_INTERVAL {
                    // The rate at the step's middle, as the preintegration's mean of its ends.
                    r_true *= exp_so3(&(omega_at(t_s + 0.5 * dt_s) * dt_s));
                }
                let white = Vector3::new(rng.normal(), rng.normal(), rng.normal());
                samples.push(ImuSample {
                    t: TimeNs::from_secs_f64(t_s),
                    gyro_rad_s: omega + wander + white * white_std * white_factor,
                    accel_m_s2: Vector3::new(0.0, 0.0, 9.81),
                });
                let step = Vector3::new(rng.normal(), rng.normal(), rng.normal());
                wander += step * walk_rad_s2_sqrt_hz * dt_s.sqrt();
            }
            k += SAMPLES_PER_INTERVAL;
            let t1 = TimeNs::from_secs_f64(k as f64 * dt_s);
            let mut pre = Preintegration::new(t0, ImuBias::default());
            pre.integrate(&samples, t1, Some(&noise));
            reading.observe(&pre, &r_true);
            // The bias the next interval is integrated at knows the wander so far (as a window
            // solve would), so only its change within the interval is unmodelled.
            wander = Vector3::zeros();
        }
        reading
    }

    #[test]
    fn a_gyro_as_modelled_reads_about_one() {
        let mut r = read(1.0, 0.0, 1);
        let m = r.median_ratio(10).unwrap();
        assert!((0.8..1.25).contains(&m), "median reading {m}");
        assert_eq!(r.len(), 64, "capacity bounds the readings");
    }

    #[test]
    fn a_noisier_gyro_reads_its_factor() {
        let mut r = read(4.0, 0.0, 2);
        let m = r.median_ratio(10).unwrap();
        assert!((3.3..4.8).contains(&m), "median reading {m}");
    }

    #[test]
    fn a_wandering_bias_reads_above_the_white_noise() {
        let mut quiet = read(1.0, 0.0, 3);
        // A wander of 0.005 rad/s²/√Hz: ~250 × the datasheet's walk.
        let mut wandering = read(1.0, 0.005, 3);
        let (q, w) = (
            quiet.median_ratio(10).unwrap(),
            wandering.median_ratio(10).unwrap(),
        );
        assert!(w > 2.0 * q, "wandering {w} against quiet {q}");
    }

    #[test]
    fn too_few_intervals_read_nothing() {
        let mut r = GyroNoiseReading::new(8);
        assert_eq!(r.median_ratio(1), None);
        let mut pre = Preintegration::new(TimeNs(0), ImuBias::default());
        // No samples: no modelled noise, kept out.
        assert_eq!(pre.dt_s(), 0.0);
        assert_eq!(r.observe(&pre, &Matrix3::identity()), None);
        pre.cov.fixed_view_mut::<3, 3>(0, 0).fill_with_identity();
        pre.cov.fixed_view_mut::<3, 3>(0, 0).scale_mut(1e-6);
        let turned = exp_so3(&Vector3::new(0.0, 0.0, 2e-3));
        let ratio = r.observe(&pre, &turned).unwrap();
        // 2 mrad against σ = 1 mrad per axis: Mahalanobis 2, over χ₃'s median.
        assert!((ratio - 2.0 / CHI3_MEDIAN).abs() < 1e-9, "{ratio}");
        assert_eq!(r.median_ratio(2), None);
        assert_eq!(r.median_ratio(1), Some(ratio));
    }
}
