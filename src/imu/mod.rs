//! Inertial measurements and the noise model (paper eq. 9–10) — the IMU layer. Preintegration and
//! the IMU residual (eq. 1–6, 13) build on these types.

use crate::time::TimeNs;
use nalgebra::Vector3;

/// One IMU measurement in the body (IMU) frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuSample {
    pub t: TimeNs,
    /// Angular rate, rad/s.
    pub gyro_rad_s: Vector3<f64>,
    /// Specific force (acceleration minus gravity, as the accelerometer measures it), m/s^2.
    pub accel_m_s2: Vector3<f64>,
}

/// Continuous-time IMU noise densities and bias random walks (Kalibr / EuRoC `imu0/sensor.yaml`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuNoise {
    /// Gyro white noise, rad/s/sqrt(Hz).
    pub gyro_noise_density: f64,
    /// Gyro bias diffusion, rad/s^2/sqrt(Hz).
    pub gyro_random_walk: f64,
    /// Accelerometer white noise, m/s^2/sqrt(Hz).
    pub accel_noise_density: f64,
    /// Accelerometer bias diffusion, m/s^3/sqrt(Hz).
    pub accel_random_walk: f64,
}

impl ImuNoise {
    /// EuRoC's ADIS16448 values (V1_01 `imu0/sensor.yaml`).
    pub fn euroc_adis16448() -> Self {
        ImuNoise {
            gyro_noise_density: 1.6968e-04,
            gyro_random_walk: 1.9393e-05,
            accel_noise_density: 2.0e-3,
            accel_random_walk: 3.0e-3,
        }
    }

    /// Discrete per-sample standard deviations at sampling period `dt_s`:
    /// `(gyro_rad_s, accel_m_s2)` white noise = density / sqrt(dt).
    pub fn discrete_white_std(&self, dt_s: f64) -> (f64, f64) {
        let k = 1.0 / dt_s.sqrt();
        (self.gyro_noise_density * k, self.accel_noise_density * k)
    }

    /// Discrete per-sample bias random-walk step std `(gyro_rad_s, accel_m_s2)` = walk * sqrt(dt).
    pub fn discrete_walk_std(&self, dt_s: f64) -> (f64, f64) {
        let k = dt_s.sqrt();
        (self.gyro_random_walk * k, self.accel_random_walk * k)
    }
}

pub mod flight_scale;
pub mod gyro_alignment;
pub mod gyro_noise_reading;
pub mod integration;
pub mod misalignment;
pub mod mount_rotation;

pub use integration::{ImuBias, NavState, Preintegration, propagate};
pub mod residual;
pub mod scale_alignment;
pub mod static_init;

pub use residual::{
    FrameState, Matrix15, Vector15, imu_jacobian_j, imu_residual, imu_residual_covariance,
};
