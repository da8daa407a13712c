//! Tracking parameters (the `[tracking]` table of the TOML config). Every field has a unit in its
//! name or doc; defaults are what `vidslam replay` uses.

use crate::imu::ImuNoise;
use serde::{Deserialize, Serialize};

/// Number of pyramid levels the tracker uses (level 0 = full resolution).
pub const NUM_LEVELS: usize = 4;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackerConfig {
    /// Point selection: a level-0 pixel is a candidate if its gradient magnitude exceeds this,
    /// gray levels per pixel.
    pub min_gradient_gray_px: f32,
    /// Point selection: the image is split into square cells of this size (level-0 pixels) and
    /// the strongest candidate of each cell is kept.
    pub select_cell_px: usize,
    /// Points kept per pyramid level at most, fine to coarse.
    pub max_points_per_level: [usize; NUM_LEVELS],
    /// Cell size (pixels of that level) for thinning each level's points, fine to coarse.
    pub level_cell_px: [usize; NUM_LEVELS],
    /// Gauss-Newton iterations per level at most, fine to coarse.
    pub max_iterations_per_level: [usize; NUM_LEVELS],
    /// A level has converged when an update moves the image by less than this, pixels of that
    /// level.
    pub convergence_px: f64,
    /// Huber threshold of the photometric residual, gray levels.
    pub huber_gray: f32,
    /// Residuals above this are outliers (weight 0), gray levels.
    pub outlier_gray: f32,
    /// Lower bound of the photometric noise scale (estimated per level from the residuals' MAD),
    /// gray levels.
    pub min_sigma_gray: f64,
    /// Photometric information is divided by this (residuals of neighbouring pixels are not
    /// independent; 1 = treat them as independent).
    pub photometric_correlation: f64,
    /// Gradient weighting `c² / (c² + |∇I|²)` of each point, gray levels per pixel (0 = off).
    pub gradient_weight_gray_px: f32,
    /// Points closer to the image border than this are not used, pixels of the level.
    pub border_px: f64,
    /// Prior standard deviation of the log-gain of the affine brightness model, relative to the
    /// previous frame.
    pub affine_gain_prior_std: f64,
    /// Prior standard deviation of the brightness offset, gray levels.
    pub affine_offset_prior_std_gray: f64,
    /// A frame whose affine log-gain relative to the keyframe is below −this asks for another
    /// keyframe (0 = never): the brightness model is collapsing onto the flat-image solution (gain
    /// near 0, offset near the mean grey) that fits a frame misaligned with the keyframe as well as
    /// an aligned one. Over the rendered flights the true exposure ratio stays within e^±0.3
    /// (`cam0/exposure.csv`); frames tracked on against such a keyframe walked to e^-2 … e^-6.5 and
    /// the flights that did so for long diverged (docs/odometry-log.md, *The brightness model
    /// collapsed*).
    pub collapsed_log_gain: f64,
    /// A frame is flagged if fewer than this fraction of the keyframe's level-0 points are inliers.
    pub min_inlier_ratio: f64,
    /// A frame is flagged if the IMU residual's squared Mahalanobis norm exceeds this (15 dof).
    pub max_imu_chi2: f64,
    /// A frame whose visual-inertial solution has an IMU residual χ² (15 dof) above this is
    /// solved again at full resolution with the photometric information scaled by this / χ²
    /// (dynamic covariance scaling of the visual term), unless the frame before was: a run of
    /// frames that disagree with the IMU is the state's velocity or bias being off, which the
    /// images must correct. 0 = never, the default. Over S-V101 (flight median χ² 28, 10 % of
    /// frames above 100) 100 helped the seeds that lost a stretch to a weakly textured floor but
    /// tipped take-offs into runaways (seed 10 1.4 m; 2.8 km without the every-other-frame rule);
    /// docs/odometry-log.md, *The gyro's rotation weighed by its wander*.
    pub vision_downweight_chi2: f64,
    /// A frame with fewer than this fraction of its pixels on an edge (gradient at least
    /// `min_gradient_gray_px`, at a quarter of the resolution) is not aligned but predicted by the
    /// IMU and flagged `no_texture`: a covered lens or a blinded sensor, which the affine
    /// brightness model would otherwise explain with a near-zero gain, most points "inliers".
    /// Measured: 9–23 % on rendered frames, 46 % on the real EuRoC clip, 0 for a black frame
    /// (0 = never).
    pub min_textured_fraction: f64,
    /// New keyframe when fewer than this fraction of the keyframe's points project into the frame.
    pub keyframe_min_overlap: f64,
    /// New keyframe when the distance from the keyframe over its median depth exceeds this.
    pub keyframe_max_baseline_ratio: f64,
    /// New keyframe when the rotation from the keyframe exceeds this, rad.
    pub keyframe_max_rotation_rad: f64,
    /// New keyframe when the keyframe tracked is older than this, s (0 = never, the default); a
    /// stored keyframe returned to is held by `[reuse]`'s limits instead. The keyframe window
    /// reads the IMU only at new keyframes, so a map tracked for seconds keeps whatever scale it
    /// has, and every view the mapper gets from it carries that scale into the next map: on
    /// S-V101 seed 1 one map was tracked for 3.4 s at −21 % depth and the maps after it swung to
    /// +106 % and −55 % (0.49 m ATE; 0.10 m with a 2 s limit). Off because over S-V101 seeds 1–12
    /// a 2 s limit moved the failures rather than removing them (median 0.169 → 0.159 m, but
    /// seed 10 ran away to 16 m where it had 0.47 m); docs/odometry-log.md, *A keyframe tracked
    /// for seconds*.
    pub keyframe_max_age_s: f64,
    /// New keyframe when the tracked velocity differs from the IMU's integrated from the keyframe
    /// window's newest keyframe (its solved state and bias, eq. 1–3) by more than this, m/s (0 =
    /// never, the default; not while a stored keyframe is tracked; needs `[window]`). Between
    /// keyframes only the tracker's one-frame IMU prior holds a map of the wrong scale from
    /// pulling the velocity along, and the window reads the map's scale only at the next
    /// keyframe. Off because on S-V101 seeds 1–20 0.2 m/s keeps seeds 16 / 20's scale (0.412 /
    /// 0.208 → 0.128 / 0.131 m ATE) but the mean over seeds 1–10 goes 0.101 → 0.111 m, and 0.15
    /// or 0.3 m/s run seed 19 or 20 away (3.65 / 4.35 m): more keyframes speed the maps' scale
    /// walk as often as they stop it (docs/odometry-log.md, *A keyframe asked for by the IMU's
    /// dead reckoning*).
    pub keyframe_max_velocity_divergence_m_s: f64,
    /// The divergence rule waits this long after the window's newest keyframe, s: a keyframe
    /// started by it has the window set the velocity, and where the window's velocity and the
    /// images disagree the next frames diverge again at once. The wait bounds how often the rule
    /// starts keyframes (on the built-in flight with an accelerometer step, 1 instead of 4); it
    /// does not stop a runaway: S-V101 seed 19 at 0.15 m/s ran away with it as without it (3.18 /
    /// 3.65 m ATE).
    pub keyframe_divergence_min_age_s: f64,
    /// The IMU noise densities of `imu0/sensor.yaml` are multiplied by this (datasheet values
    /// understate a real MEMS IMU on a vibrating airframe; random walks are kept).
    pub imu_noise_scale: f64,
    /// The gyro bias random walk of `imu0/sensor.yaml` is multiplied by this, everywhere the
    /// odometry uses it (tracker, keyframe window, keyframe adjustment, rest detector; also the
    /// tracking-only `--depth gt` replay and `dataset adjust-check`: [`Self::imu_noise`]). A
    /// datasheet's walk lets the bias move 4e-5 rad/s in 5 s; a gyro that disagrees with the
    /// camera by a slowly wandering rate (S-V101's real gyro against the images rendered along the
    /// Vicon estimate: 0.2°/s on two axes, correlated over seconds — `vidslam dataset imu-check`,
    /// *rotation*) may need a bias that can follow it. Dimensionless; 1 = the datasheet's. On
    /// S-V101, 30 moved its runaways between seeds (median 0.162 → 0.154 m over seeds 1–8) and 100
    /// let the bias take the maps' scale (docs/odometry-log.md, *S-V101's rotation is its maps'*).
    pub gyro_random_walk_scale: f64,
    /// Estimate the gyro bias in every frame's solve (the 15-state of eq. 11). `false` holds it
    /// at the state's value through the solve (its step is zero; the IMU residual still weighs
    /// it): the bias is then what the rest detector and the keyframe window estimate. The
    /// tracker's photometric information is the single frame's, untempered (the window scales
    /// it by `visual_rotation_information_scale` for the map errors all pixels share), so in every
    /// frame it pulls the bias toward whatever rotation error the keyframe's map gives; on
    /// S-V101 the window and the tracker were measured pulling the bias about the up axis
    /// against each other (docs/odometry-log.md, *Where S-V101's heading drift enters*). Held,
    /// the covariance handed to the next frame keeps the prediction's gyro-bias block. Off by
    /// default: S-V101 seeds 1–10 better on 7, two lost (*The held gyro bias's covariance*).
    pub estimate_gyro_bias: bool,
    /// Use the images at all (`false` = IMU-only dead reckoning through the same solver).
    pub use_vision: bool,
    /// Divide every image by the camera's vignetting (`cam0/vignette.yaml` of the dataset, see
    /// `camera::Vignette`) before tracking and mapping. Without a calibration nothing is done.
    /// Off by default: on the simulator's 35 % fall-off it did not help the closed loop (demo seeds
    /// 1–8: median ATE 5.5 m on, 5.3 m off; S-V101 138 m on, 0.62 m off — single chaotic samples,
    /// see docs/odometry-log.md), although it removes a bias the affine brightness model cannot
    /// absorb. The thresholds (gradients, Huber, outliers) were tuned on uncorrected images, whose
    /// corners the correction amplifies by up to 1.5x, noise included.
    pub correct_vignetting: bool,
}

impl TrackerConfig {
    /// The IMU's noise (`imu0/sensor.yaml`) as these settings use it: the gyro bias random walk
    /// times `gyro_random_walk_scale`. (The white densities are inflated by `imu_noise_scale`
    /// where each estimator weighs them.)
    pub fn imu_noise(&self, sensor: ImuNoise) -> ImuNoise {
        ImuNoise {
            gyro_random_walk: sensor.gyro_random_walk * self.gyro_random_walk_scale,
            ..sensor
        }
    }
}

impl Default for TrackerConfig {
    fn default() -> Self {
        TrackerConfig {
            min_gradient_gray_px: 6.0,
            select_cell_px: 4,
            max_points_per_level: [3000, 2000, 1000, 500],
            level_cell_px: [3, 2, 1, 1],
            max_iterations_per_level: [6, 8, 10, 12],
            convergence_px: 0.01,
            huber_gray: 9.0,
            outlier_gray: 40.0,
            min_sigma_gray: 2.0,
            photometric_correlation: 1.0,
            gradient_weight_gray_px: 0.0,
            border_px: 2.0,
            affine_gain_prior_std: 0.3,
            affine_offset_prior_std_gray: 30.0,
            collapsed_log_gain: 1.0,
            min_inlier_ratio: 0.25,
            max_imu_chi2: 1000.0,
            vision_downweight_chi2: 0.0,
            min_textured_fraction: 0.01,
            keyframe_min_overlap: 0.7,
            keyframe_max_baseline_ratio: 0.12,
            keyframe_max_rotation_rad: 0.3,
            keyframe_max_age_s: 0.0,
            keyframe_max_velocity_divergence_m_s: 0.0,
            keyframe_divergence_min_age_s: 0.5,
            imu_noise_scale: 3.0,
            gyro_random_walk_scale: 1.0,
            estimate_gyro_bias: true,
            use_vision: true,
            correct_vignetting: false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_noise_used_frees_the_gyro_bias_walk_only() {
        let sensor = ImuNoise::euroc_adis16448();
        let cfg = TrackerConfig::default();
        assert_eq!(cfg.imu_noise(sensor), sensor);
        let free = TrackerConfig {
            gyro_random_walk_scale: 30.0,
            ..cfg
        };
        let n = free.imu_noise(sensor);
        assert_eq!(n.gyro_random_walk, 30.0 * sensor.gyro_random_walk);
        assert_eq!(
            ImuNoise {
                gyro_random_walk: sensor.gyro_random_walk,
                ..n
            },
            sensor
        );
    }
}
