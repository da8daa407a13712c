//! Static-start detection and initial attitude / gyro bias from a resting IMU.
//!
//! The drone sits on the pad with its rotors spinning, then takes off. From the first second the
//! product must publish a pose, so [`StaticDetector`] decides from the IMU alone that the vehicle
//! is static, estimates the gravity direction (roll/pitch) and the gyro bias while it is, holds
//! them, and reports the **motion onset** (take-off) with a small latency and a back-dated onset
//! time, so the visual-inertial bootstrap can start from a known attitude and bias instead of
//! waiting for "excitation".
//!
//! # Method
//! * **Blocks.** Samples are averaged over short blocks of [`StaticDetectorConfig::block_s`]
//!   (0.1 s). Rotor vibration is large per sample (on EuRoC V1_01 up to 0.12 rad/s and 1.6 m/s²
//!   std per 0.2 s) but periodic, so it averages out in a block mean; every decision is made on
//!   block means, never on per-sample variance.
//! * **Thresholds.** A block mean is "consistent" with a reference mean when the vector deviation
//!   is below `noise_sigmas · density / √block_s + vibration margin`, for the gyro and the
//!   accelerometer separately ([`StaticDetector::gyro_threshold_rad_s`],
//!   [`StaticDetector::accel_threshold_m_s2`]). The first term is the white noise of a block mean
//!   from [`ImuNoise`]; the margins are the vibration residual, chosen from the data below.
//!   Deviations are used normalised: `z = max(|Δω̄| / thr_ω, |Δā| / thr_a)`.
//! * **Becoming static.** When the last [`StaticDetectorConfig::window_s`] of blocks (0.5 s, 5
//!   blocks) all have `z ≤ 1` with respect to their common mean, the mean specific force has norm
//!   within [`StaticDetectorConfig::accel_norm_tolerance_m_s2`] of [`GRAVITY_M_S2`], and the mean
//!   rate is a plausible bias, the vehicle is declared static, *since* the first sample of that
//!   window. A plausible bias is one of norm at most
//!   [`StaticDetectorConfig::max_gyro_bias_rad_s`] at first, and after a motion onset one within a
//!   threshold (plus 3 σ of random walk) of the bias estimated before it: a constant rate is
//!   indistinguishable from a bias, so once the bias is known a steady turn or a yaw in hover is
//!   not taken for rest. (The flip side: if the first "rest" was in fact a slow steady rotation,
//!   later rests do not match it; [`StaticDetector::reset`] re-arms the detector. A data gap also
//!   forgets the bias, as it may be a sensor restart.)
//! * **Estimate.** While static every block is accumulated (exact mean/variance merging), so the
//!   bias and gravity direction average over the whole static period, not just the window. The
//!   attitude is the rotation taking the mean specific force (body) to world `+z` (see
//!   [`r_world_body_from_specific_force`]); the gyro bias is the mean rate.
//! * **Motion onset.** While static, each new block is compared with the static mean so far and a
//!   one-sided CUSUM runs on its `z`: `S ← max(0, S + z − drift)`, alarm when `S ≥ alarm`
//!   (defaults 0.5 and 0.5: one block at `z ≥ 1` alarms at once, a few blocks at `z ≈ 0.7` alarm
//!   within a few blocks, `z ≤ 0.5` never accumulates). The onset is **back-dated** to the start
//!   of the CUSUM excursion (the first block after `S` was last 0), so its resolution is one block;
//!   the detection itself comes at the end of the alarming block. Blocks of the excursion are held
//!   apart from the estimate until `S` returns to 0, so the frozen estimate handed over at onset
//!   contains no take-off samples.
//!
//! # Evidence for the thresholds (EuRoC V1_01, ADIS16448 at 200 Hz)
//! The IMU file starts 1.0 s before the ground truth; the vehicle is on the ground for its first
//! ~5 s: rotors spin up between 0.2 s and 1.6 s (gyro x std over 0.2 s rises from 1.6 to
//! 120 mrad/s, accel y std to 1.6 m/s²), idle, and throttle up from 2.6 s to 4.8 s (accel std up
//! to 1.0 m/s²). Yet the 0.1 s block means over 0–4.7 s (47 blocks) deviate from their common mean
//! by at most **14.7 mrad/s** (95th percentile 11.1) for the gyro and **0.19 m/s²** (95th
//! percentile 0.15, the maximum during spin-up) for the accelerometer. The first take-off blocks
//! (from 5.0 s after the file start, t = 1403715278.262 s) deviate by 47, 43, 154 mrad/s and 0.35,
//! 0.50, 0.84 m/s²; ground truth leaves a 1° ball at +5.255 s and a 2 cm ball at +5.355 s.
//! Hence the default margins, **20 mrad/s** and **0.25 m/s²**: with the noise term (5 σ of a
//! 0.1 s block mean, 2.7 mrad/s and 0.032 m/s² for the ADIS16448) the thresholds are 22.7 mrad/s
//! and 0.28 m/s²; every static block of V1_01 has `z ≤ 0.68`, and the first take-off block has
//! `z ≈ 2`. Shorter blocks average vibration worse (0.05 s blocks: 36 mrad/s and 0.41 m/s² worst
//! case), longer ones delay the onset; 0.2 s blocks halve the static deviations (8.5 mrad/s, 0.10
//! m/s²). The simulator's vibration (0.3 m/s², 0.01 rad/s sinusoids at ~83 Hz and its aliased
//! harmonic) leaves under 0.02 m/s² in a 0.1 s block mean.
//!
//! Run on the sequence with the defaults, the running CUSUM (against the growing static mean, as
//! the detector runs) peaks at 0.27 of its 0.5 alarm over the static part and every static block
//! has `z ≤ 0.66`.
//!
//! Measured with the defaults (`tests/static_start.rs --nocapture`):
//! * V1_01: static from the first sample, declared after 0.495 s, held through the camera clip
//!   (to +4.70 s). Onset back-dated to 1403715278.162 s (+4.90 s), detected at 1403715278.357 s,
//!   0.16 s *before* the ground truth leaves a 1° ball (278.517 s) and 0.26 s before it leaves
//!   2 cm (278.617 s). Gyro bias (−1.97, 20.89, 78.20) mrad/s against (−2.23, 20.70, 76.35) in
//!   EuRoC's full ground truth (1.9 mrad/s apart); integrating the gyro over the first 3 s of
//!   flight with it, 0.66° from the ground-truth rotation (0.75° with EuRoC's bias, 13.8° with
//!   none). Gravity direction 2.7° from the first ground-truth pose: this ADIS16448 has a 0.55
//!   m/s² accelerometer bias perpendicular to gravity (EuRoC: (−0.012, 0.548, 0.069) m/s²), which
//!   predicts 3.2° (see below); with that bias removed the difference is 0.5°.
//! * `builtin:demo` (synthetic IMU with noise, bias and vibration): static from the first sample,
//!   declared after 0.495 s; take-off (ground-truth speed above 1 mm/s) at +2.085 s, onset
//!   back-dated to +2.20 s, detected at +2.395 s (the climb's acceleration grows from zero as
//!   ~6 τ² m/s², so it needs ~0.2 s to reach half a threshold; the vehicle has risen 9 mm by
//!   then). Gyro bias within 0.12 mrad/s of the truth; gravity direction 0.53° off, of which the
//!   accelerometer bias explains 0.52° (0.015° once it is removed).
//!
//! # What a static IMU cannot tell
//! * **Accelerometer bias vs tilt.** At rest the accelerometer measures `R_bwᵀ (0, 0, g) + b_a`.
//!   The bias component along gravity changes only the norm (it shows in
//!   [`StaticEstimate::accel_norm_m_s2`] together with local gravity); the component `b_⊥`
//!   perpendicular to it is indistinguishable from a tilt and is absorbed into roll/pitch, with an
//!   error of `atan(|b_⊥| / g) ≈ |b_⊥| / g` rad: 0.058° per 0.01 m/s², 0.58° for 0.1 m/s², 2.9°
//!   for 0.5 m/s². The gyro bias, in contrast, is observed directly. The accelerometer bias must be
//!   estimated later, once the vehicle rotates (the VI bootstrap); [`StaticEstimate::imu_bias`]
//!   reports it as zero, and [`rest_covariance`] gives the rest state a tilt uncertainty that
//!   includes it, so that the estimator can move the tilt when the first turn shows the bias.
//! * **Yaw** is unobservable without a heading sensor; it is set from
//!   [`StaticDetectorConfig::yaw_rad`].
//! * **Slow motion.** A constant rotation slower than about `drift · thr_ω` (11 mrad/s, 0.65°/s
//!   with the defaults) or an acceleration change smaller than `drift · thr_a` (0.14 m/s²) is not
//!   detected and is absorbed into the bias / tilt. A perfect hover (no rotation, or at most
//!   a yaw rate within a threshold of the known bias) is, to an IMU, static.
//! * **Gaps.** Across a data gap longer than [`StaticDetectorConfig::max_gap_s`] nothing is known:
//!   a static period ends with [`StaticEvent::Interrupted`] (no onset) and detection restarts.
//!
//! # Robustness and cost
//! Non-finite samples and samples whose time does not increase are counted
//! ([`StaticDetector::counters`]) and skipped; nothing panics on bad input. Each `push` is O(1)
//! except at block ends (O(window) while not static) and allocates nothing: the window is a
//! fixed-size ring of [`MAX_WINDOW_BLOCKS`] block summaries.

use super::{ImuBias, ImuNoise, ImuSample, Matrix15, NavState};
use crate::geometry::GRAVITY_M_S2;
use crate::time::TimeNs;
use nalgebra::{Matrix3, SVector, UnitQuaternion, Vector3};

/// Capacity of the detector's block ring: the window may span at most this many blocks.
pub const MAX_WINDOW_BLOCKS: usize = 32;

/// Tuning of [`StaticDetector`]. The defaults suit a multirotor idling on the pad (see the
/// module docs for the evidence behind them).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StaticDetectorConfig {
    /// Averaging block, s. Should span at least ~10 samples so vibration averages out.
    pub block_s: f64,
    /// Window that must be consistent before the vehicle is declared static, s (rounded to whole
    /// blocks, at least 2 and at most [`MAX_WINDOW_BLOCKS`]).
    pub window_s: f64,
    /// Multiple of the white-noise std of a block mean in the thresholds.
    pub noise_sigmas: f64,
    /// Allowance for rotor vibration left in a block mean of the gyro, rad/s.
    pub gyro_vibration_margin_rad_s: f64,
    /// Allowance for rotor vibration left in a block mean of the accelerometer, m/s².
    pub accel_vibration_margin_m_s2: f64,
    /// CUSUM drift (allowance per block) in units of the thresholds.
    pub cusum_drift: f64,
    /// CUSUM alarm level in units of the thresholds.
    pub cusum_alarm: f64,
    /// Largest mean rate accepted as a gyro bias when declaring static, rad/s.
    pub max_gyro_bias_rad_s: f64,
    /// Largest `| |mean specific force| − g |` accepted when declaring static, m/s² (rejects free
    /// fall and sustained acceleration).
    pub accel_norm_tolerance_m_s2: f64,
    /// Longest gap between consecutive samples that is bridged, s.
    pub max_gap_s: f64,
    /// Yaw given to the estimated attitude (rotation about world z), rad.
    pub yaw_rad: f64,
}

impl Default for StaticDetectorConfig {
    fn default() -> Self {
        StaticDetectorConfig {
            block_s: 0.1,
            window_s: 0.5,
            noise_sigmas: 5.0,
            gyro_vibration_margin_rad_s: 0.02,
            accel_vibration_margin_m_s2: 0.25,
            cusum_drift: 0.5,
            cusum_alarm: 0.5,
            max_gyro_bias_rad_s: 0.2,
            accel_norm_tolerance_m_s2: 0.5,
            max_gap_s: 0.05,
            yaw_rad: 0.0,
        }
    }
}

impl StaticDetectorConfig {
    /// Checks that every field is finite and in range; the error names the field.
    pub fn validate(&self) -> Result<(), String> {
        let positive = [
            ("block_s", self.block_s),
            ("window_s", self.window_s),
            ("cusum_alarm", self.cusum_alarm),
            ("max_gap_s", self.max_gap_s),
            ("max_gyro_bias_rad_s", self.max_gyro_bias_rad_s),
            ("accel_norm_tolerance_m_s2", self.accel_norm_tolerance_m_s2),
        ];
        let non_negative = [
            ("noise_sigmas", self.noise_sigmas),
            (
                "gyro_vibration_margin_rad_s",
                self.gyro_vibration_margin_rad_s,
            ),
            (
                "accel_vibration_margin_m_s2",
                self.accel_vibration_margin_m_s2,
            ),
            ("cusum_drift", self.cusum_drift),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} must be finite and > 0, got {v}"));
            }
        }
        for (name, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} must be finite and >= 0, got {v}"));
            }
        }
        if !self.yaw_rad.is_finite() {
            return Err(format!("yaw_rad must be finite, got {}", self.yaw_rad));
        }
        if self.block_s < 1e-6 {
            return Err(format!(
                "block_s must be at least 1 us, got {}",
                self.block_s
            ));
        }
        Ok(())
    }

    /// Blocks in the static window: `round(window_s / block_s)` clamped to
    /// `2..=MAX_WINDOW_BLOCKS`.
    pub fn window_blocks(&self) -> usize {
        let n = (self.window_s / self.block_s).round();
        if n.is_finite() {
            (n.max(2.0) as usize).min(MAX_WINDOW_BLOCKS)
        } else {
            2
        }
    }
}

/// Initial state from a static period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StaticEstimate {
    /// Attitude: roll/pitch from the mean specific force, yaw from the configuration (see
    /// [`r_world_body_from_specific_force`]). Carries any accelerometer bias perpendicular to
    /// gravity as a tilt error (module docs).
    pub r_world_body: UnitQuaternion<f64>,
    /// Mean gyro rate over the static period (`measured = true + bias`, true = 0), rad/s.
    pub gyro_bias_rad_s: Vector3<f64>,
    /// Per-sample std of the gyro over the static period (white noise and vibration), rad/s.
    pub gyro_std_rad_s: Vector3<f64>,
    /// Standard error of `gyro_bias_rad_s`: scatter of the block means / √blocks, at least the
    /// white-noise value `density / √span`, rad/s.
    pub gyro_bias_sigma_rad_s: Vector3<f64>,
    /// Mean specific force, body frame, m/s².
    pub accel_mean_m_s2: Vector3<f64>,
    /// Per-sample std of the specific force, m/s².
    pub accel_std_m_s2: Vector3<f64>,
    /// Norm of the mean specific force (local gravity plus the accelerometer bias along it), m/s².
    pub accel_norm_m_s2: f64,
    /// Per-sample std of the specific-force norm, m/s².
    pub accel_norm_std_m_s2: f64,
    /// Standard error of the gravity direction from the scatter of the block means (conservative;
    /// excludes the accelerometer-bias error of the module docs), rad.
    pub tilt_sigma_rad: f64,
    /// Effective white-noise density of the gyro at rest: the scatter of the block means times
    /// √(block duration), mean over the axes — rotor vibration included, what the estimator's
    /// IMU noise model meets in flight (the datasheet's `gyroscope_noise_density` is the floor),
    /// rad/s/√Hz. 0 with fewer than two blocks.
    pub gyro_density_rad_s_sqrt_hz: f64,
    /// The same for the accelerometer, m/s²/√Hz.
    pub accel_density_m_s2_sqrt_hz: f64,
    /// First sample of the static period.
    pub t_start: TimeNs,
    /// Last sample included in the estimate.
    pub t_end: TimeNs,
    pub num_samples: usize,
}

impl StaticEstimate {
    /// Biases for the estimator: the gyro bias, and zero accelerometer bias (not observable
    /// while static; it is absorbed into the attitude).
    pub fn imu_bias(&self) -> ImuBias {
        ImuBias {
            gyro_rad_s: self.gyro_bias_rad_s,
            accel_m_s2: Vector3::zeros(),
        }
    }

    /// The held navigation state at `t_end`: the estimated attitude, position `p_world_m`, zero
    /// velocity.
    pub fn nav_state(&self, p_world_m: Vector3<f64>) -> NavState {
        NavState {
            t: self.t_end,
            r_world_body: self.r_world_body,
            p_world_m,
            v_world_m_s: Vector3::zeros(),
        }
    }

    /// Span from the first to the last sample, s.
    pub fn span_s(&self) -> f64 {
        self.t_end.secs_since(self.t_start)
    }
}

/// A static → moving transition.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionOnset {
    /// Back-dated start of the motion: the first sample of the block where the CUSUM excursion
    /// that raised the alarm began (resolution one block).
    pub t_onset: TimeNs,
    /// Last sample of the block that raised the alarm (the decision is taken on it).
    pub t_detected: TimeNs,
    /// Deviation of the alarming block's mean rate from the static mean, rad/s.
    pub gyro_deviation_rad_s: f64,
    /// Deviation of the alarming block's mean specific force from the static mean, m/s².
    pub accel_deviation_m_s2: f64,
    /// The static estimate frozen at the onset (no samples from `t_onset` on).
    pub estimate: StaticEstimate,
}

/// What a [`StaticDetector::push`] changed.
// Events are rare and transient (returned, not stored); boxing the onset would allocate.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StaticEvent {
    /// The vehicle has been found static since `since`; decided on the sample at `t_detected`.
    StaticStart { since: TimeNs, t_detected: TimeNs },
    /// The static period ended with motion.
    MotionOnset(MotionOnset),
    /// The static period ended with a data gap (from `t_last` to `t_next`): nothing is known about
    /// the motion in it, so no onset is claimed.
    Interrupted { t_last: TimeNs, t_next: TimeNs },
}

/// Sample bookkeeping of a [`StaticDetector`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StaticDetectorCounters {
    /// Samples used.
    pub accepted: u64,
    /// Samples skipped because a value was NaN or infinite.
    pub non_finite: u64,
    /// Samples skipped because their time was not after the previous accepted sample.
    pub out_of_order: u64,
    /// Gaps longer than `max_gap_s` (each restarts detection).
    pub gaps: u64,
}

/// The rotation `r_world_body` that maps the measured specific force `f_body_m_s2` (at rest:
/// "up" in the body frame) onto world `+z`, followed by `yaw_rad` about world z.
///
/// Heading convention: with `yaw_rad = 0` it is the smallest such rotation (for an IMU mounted z
/// up and a small tilt, roll and pitch with zero yaw). This is well defined for any mounting —
/// unlike Euler yaw, which degenerates when the IMU x axis points up, as on EuRoC — except
/// upside down (`f` along `−z_body`), where a half turn about body x is used. `None` if `f` is
/// not finite or shorter than 1e-6 m/s².
pub fn r_world_body_from_specific_force(
    f_body_m_s2: &Vector3<f64>,
    yaw_rad: f64,
) -> Option<UnitQuaternion<f64>> {
    let n = f_body_m_s2.norm();
    if !(n.is_finite() && n > 1e-6 && yaw_rad.is_finite()) {
        return None;
    }
    let up_body = f_body_m_s2 / n;
    let z = Vector3::z();
    let tilt = UnitQuaternion::rotation_between(&up_body, &z).unwrap_or_else(|| {
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
    });
    Some(UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad) * tilt)
}

/// Running count, mean and sum of squared deviations (Welford), mergeable exactly (Chan et al.).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Moments<const D: usize> {
    n: u64,
    mean: SVector<f64, D>,
    m2: SVector<f64, D>,
}

impl<const D: usize> Default for Moments<D> {
    fn default() -> Self {
        Moments {
            n: 0,
            mean: SVector::zeros(),
            m2: SVector::zeros(),
        }
    }
}

impl<const D: usize> Moments<D> {
    fn push(&mut self, x: &SVector<f64, D>) {
        self.n += 1;
        let d = x - self.mean;
        self.mean += d / self.n as f64;
        self.m2 += d.component_mul(&(x - self.mean));
    }

    fn merge(&mut self, o: &Self) {
        if o.n == 0 {
            return;
        }
        if self.n == 0 {
            *self = *o;
            return;
        }
        let (na, nb) = (self.n as f64, o.n as f64);
        let n = na + nb;
        let d = o.mean - self.mean;
        self.mean += d * (nb / n);
        self.m2 += o.m2 + d.component_mul(&d) * (na * nb / n);
        self.n += o.n;
    }

    /// Sample standard deviation (zero below two values).
    fn std(&self) -> SVector<f64, D> {
        if self.n < 2 {
            return SVector::zeros();
        }
        (self.m2 / (self.n - 1) as f64).map(|v| v.max(0.0).sqrt())
    }
}

/// Summary of one block of samples.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Block {
    t_first: TimeNs,
    t_last: TimeNs,
    gyro: Moments<3>,
    accel: Moments<3>,
    accel_norm: Moments<1>,
}

impl Block {
    fn start(s: &ImuSample) -> Self {
        let mut b = Block {
            t_first: s.t,
            ..Default::default()
        };
        b.add(s);
        b
    }

    fn add(&mut self, s: &ImuSample) {
        self.t_last = s.t;
        self.gyro.push(&s.gyro_rad_s);
        self.accel.push(&s.accel_m_s2);
        self.accel_norm
            .push(&SVector::<f64, 1>::new(s.accel_m_s2.norm()));
    }
}

/// Accumulated statistics of a run of blocks (a static period or a CUSUM excursion).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Accum {
    t_start: TimeNs,
    t_end: TimeNs,
    gyro: Moments<3>,
    accel: Moments<3>,
    accel_norm: Moments<1>,
    gyro_blocks: Moments<3>,
    accel_blocks: Moments<3>,
}

impl Accum {
    fn is_empty(&self) -> bool {
        self.gyro.n == 0
    }

    fn add_block(&mut self, b: &Block) {
        if self.is_empty() {
            self.t_start = b.t_first;
        }
        self.t_end = b.t_last;
        self.gyro.merge(&b.gyro);
        self.accel.merge(&b.accel);
        self.accel_norm.merge(&b.accel_norm);
        self.gyro_blocks.push(&b.gyro.mean);
        self.accel_blocks.push(&b.accel.mean);
    }

    /// Appends `o`, which must follow `self` in time.
    fn append(&mut self, o: &Accum) {
        if o.is_empty() {
            return;
        }
        if self.is_empty() {
            *self = *o;
            return;
        }
        self.t_end = o.t_end;
        self.gyro.merge(&o.gyro);
        self.accel.merge(&o.accel);
        self.accel_norm.merge(&o.accel_norm);
        self.gyro_blocks.merge(&o.gyro_blocks);
        self.accel_blocks.merge(&o.accel_blocks);
    }

    fn estimate(&self, noise: &ImuNoise, yaw_rad: f64) -> Option<StaticEstimate> {
        let r_world_body = r_world_body_from_specific_force(&self.accel.mean, yaw_rad)?;
        let span_s = self.t_end.secs_since(self.t_start).max(1e-9);
        let blocks = self.gyro_blocks.n as f64;
        let sem = |m: &Moments<3>| m.std() / blocks.sqrt();
        let gyro_floor = noise.gyro_noise_density / span_s.sqrt();
        let density = |m: &Moments<3>| {
            if m.n < 2 {
                return 0.0;
            }
            let block_s = span_s / blocks;
            m.std().mean() * block_s.sqrt()
        };
        let accel_norm = self.accel.mean.norm();
        let accel_floor = std::f64::consts::SQRT_2 * noise.accel_noise_density / span_s.sqrt();
        Some(StaticEstimate {
            r_world_body,
            gyro_bias_rad_s: self.gyro.mean,
            gyro_std_rad_s: self.gyro.std(),
            gyro_bias_sigma_rad_s: sem(&self.gyro_blocks).map(|v| v.max(gyro_floor)),
            accel_mean_m_s2: self.accel.mean,
            accel_std_m_s2: self.accel.std(),
            accel_norm_m_s2: accel_norm,
            accel_norm_std_m_s2: self.accel_norm.std()[0],
            tilt_sigma_rad: sem(&self.accel_blocks).norm().max(accel_floor) / accel_norm,
            gyro_density_rad_s_sqrt_hz: density(&self.gyro_blocks),
            accel_density_m_s2_sqrt_hz: density(&self.accel_blocks),
            t_start: self.t_start,
            t_end: self.t_end,
            num_samples: self.gyro.n as usize,
        })
    }
}

/// Fixed-capacity ring of the most recent blocks.
#[derive(Clone, Debug)]
struct Ring {
    buf: [Block; MAX_WINDOW_BLOCKS],
    head: usize,
    len: usize,
    cap: usize,
}

impl Ring {
    fn new(cap: usize) -> Self {
        Ring {
            buf: [Block::default(); MAX_WINDOW_BLOCKS],
            head: 0,
            len: 0,
            cap: cap.clamp(1, MAX_WINDOW_BLOCKS),
        }
    }

    fn push(&mut self, b: Block) {
        self.buf[(self.head + self.len) % MAX_WINDOW_BLOCKS] = b;
        if self.len < self.cap {
            self.len += 1;
        } else {
            self.head = (self.head + 1) % MAX_WINDOW_BLOCKS;
        }
    }

    fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }

    fn iter(&self) -> impl Iterator<Item = &Block> + '_ {
        (0..self.len).map(move |i| &self.buf[(self.head + i) % MAX_WINDOW_BLOCKS])
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    NotStatic,
    Static { since: TimeNs },
}

/// Streaming static / motion-onset detector (see the module docs).
///
/// ```
/// use vidslam::imu::static_init::{StaticDetector, StaticDetectorConfig, StaticEvent};
/// use vidslam::imu::{ImuNoise, ImuSample};
/// use vidslam::time::TimeNs;
/// use nalgebra::Vector3;
///
/// let mut det = StaticDetector::new(StaticDetectorConfig::default(), &ImuNoise::euroc_adis16448());
/// for k in 0..200 {
///     let s = ImuSample {
///         t: TimeNs(k * 5_000_000),
///         gyro_rad_s: Vector3::new(0.01, 0.0, 0.0),
///         accel_m_s2: Vector3::new(0.0, 0.0, 9.81),
///     };
///     if let Some(StaticEvent::MotionOnset(onset)) = det.push(&s) {
///         println!("take-off at {}", onset.t_onset);
///     }
/// }
/// assert!(det.is_static());
/// let est = det.estimate().unwrap();
/// assert!((est.gyro_bias_rad_s.x - 0.01).abs() < 1e-12);
/// ```
#[derive(Clone, Debug)]
pub struct StaticDetector {
    cfg: StaticDetectorConfig,
    noise: ImuNoise,
    gyro_thr_rad_s: f64,
    accel_thr_m_s2: f64,
    block_ns: i64,
    max_gap_ns: i64,
    window_blocks: usize,
    last_t: Option<TimeNs>,
    /// Smallest sample step in the current block and in the previous one (the sample period,
    /// robust to skipped samples).
    dt_block_ns: Option<i64>,
    dt_prev_block_ns: Option<i64>,
    block: Option<Block>,
    ring: Ring,
    phase: Phase,
    /// Static blocks accepted into the estimate.
    confirmed: Accum,
    /// Blocks of the current CUSUM excursion (static phase only).
    pending: Accum,
    cusum: f64,
    /// The latest static period's estimate.
    estimate: Option<StaticEstimate>,
    /// Gyro bias and its time, known from the static period that ended in a motion onset; a new
    /// static window must match it. Forgotten at a data gap (possibly a sensor restart).
    known_gyro_bias: Option<(Vector3<f64>, TimeNs)>,
    last_onset: Option<MotionOnset>,
    counters: StaticDetectorCounters,
}

impl StaticDetector {
    /// A detector with thresholds from `cfg` and the white noise of `noise`.
    ///
    /// # Panics
    /// If `cfg` fails [`StaticDetectorConfig::validate`] (a programming error; samples never
    /// cause a panic).
    pub fn new(cfg: StaticDetectorConfig, noise: &ImuNoise) -> Self {
        if let Err(e) = cfg.validate() {
            panic!("invalid StaticDetectorConfig: {e}");
        }
        let k = cfg.noise_sigmas / cfg.block_s.sqrt();
        let window_blocks = cfg.window_blocks();
        StaticDetector {
            cfg,
            noise: *noise,
            gyro_thr_rad_s: k * noise.gyro_noise_density.abs() + cfg.gyro_vibration_margin_rad_s,
            accel_thr_m_s2: k * noise.accel_noise_density.abs() + cfg.accel_vibration_margin_m_s2,
            block_ns: ((cfg.block_s * 1e9).round() as i64).max(1),
            max_gap_ns: ((cfg.max_gap_s * 1e9).round() as i64).max(1),
            window_blocks,
            last_t: None,
            dt_block_ns: None,
            dt_prev_block_ns: None,
            block: None,
            ring: Ring::new(window_blocks),
            phase: Phase::NotStatic,
            confirmed: Accum::default(),
            pending: Accum::default(),
            cusum: 0.0,
            estimate: None,
            known_gyro_bias: None,
            last_onset: None,
            counters: StaticDetectorCounters::default(),
        }
    }

    pub fn config(&self) -> &StaticDetectorConfig {
        &self.cfg
    }

    /// Deviation of a block-mean rate that counts as one threshold unit, rad/s.
    pub fn gyro_threshold_rad_s(&self) -> f64 {
        self.gyro_thr_rad_s
    }

    /// Deviation of a block-mean specific force that counts as one threshold unit, m/s².
    pub fn accel_threshold_m_s2(&self) -> f64 {
        self.accel_thr_m_s2
    }

    /// Feeds one sample (in time order). Returns an event when the static state changed.
    /// Non-finite or out-of-order samples are counted and ignored (after a clock reset every
    /// sample is out of order until [`StaticDetector::reset`]).
    pub fn push(&mut self, s: &ImuSample) -> Option<StaticEvent> {
        let finite = s
            .gyro_rad_s
            .iter()
            .chain(s.accel_m_s2.iter())
            .all(|v| v.is_finite());
        if !finite {
            self.counters.non_finite += 1;
            return None;
        }
        let mut event = None;
        if let Some(last) = self.last_t {
            if s.t <= last {
                self.counters.out_of_order += 1;
                return None;
            }
            let dt = s.t.ns_since(last);
            if dt > self.max_gap_ns {
                self.counters.gaps += 1;
                event = self.interrupt(last, s.t);
            } else {
                self.dt_block_ns = Some(self.dt_block_ns.map_or(dt, |d| d.min(dt)));
            }
        }
        self.counters.accepted += 1;
        self.last_t = Some(s.t);
        let block = match self.block.as_mut() {
            Some(b) => {
                b.add(s);
                b
            }
            None => self.block.insert(Block::start(s)),
        };
        // The block is complete when the next sample would reach past its end (half a sample
        // period of tolerance absorbs timestamp jitter).
        let dt_ns = match (self.dt_block_ns, self.dt_prev_block_ns) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        let complete = dt_ns.is_some_and(|dt| {
            s.t.ns_since(block.t_first).saturating_add(dt + dt / 2) >= self.block_ns
        });
        if complete {
            let b = *block;
            self.block = None;
            self.dt_prev_block_ns = self.dt_block_ns.take().or(self.dt_prev_block_ns);
            if let Some(e) = self.close_block(b) {
                event = Some(e);
            }
        }
        event
    }

    /// Whether the vehicle is static now (as of the last completed block).
    pub fn is_static(&self) -> bool {
        matches!(self.phase, Phase::Static { .. })
    }

    /// Start of the current static period (its first sample), if static.
    pub fn static_since(&self) -> Option<TimeNs> {
        match self.phase {
            Phase::Static { since } => Some(since),
            Phase::NotStatic => None,
        }
    }

    /// The latest static period's estimate: updated at every block while static, frozen at the
    /// motion onset (or gap) afterwards; `None` before the first static period.
    pub fn estimate(&self) -> Option<&StaticEstimate> {
        self.estimate.as_ref()
    }

    /// The most recent motion onset.
    pub fn last_onset(&self) -> Option<&MotionOnset> {
        self.last_onset.as_ref()
    }

    pub fn counters(&self) -> StaticDetectorCounters {
        self.counters
    }

    /// Forgets everything but the configuration and the counters (e.g. after a clock reset, since
    /// samples earlier than the last one are otherwise skipped).
    pub fn reset(&mut self) {
        let counters = self.counters;
        *self = StaticDetector::new(self.cfg, &self.noise);
        self.counters = counters;
    }

    /// Normalised deviation `z` of `b` from the means `(gyro, accel)`, and the two deviations.
    fn deviation(&self, b: &Block, gyro: &Vector3<f64>, accel: &Vector3<f64>) -> (f64, f64, f64) {
        let dg = (b.gyro.mean - gyro).norm();
        let da = (b.accel.mean - accel).norm();
        (
            (dg / self.gyro_thr_rad_s).max(da / self.accel_thr_m_s2),
            dg,
            da,
        )
    }

    fn close_block(&mut self, b: Block) -> Option<StaticEvent> {
        match self.phase {
            Phase::NotStatic => {
                self.ring.push(b);
                if self.ring.len < self.window_blocks || !self.window_is_static() {
                    return None;
                }
                let mut acc = Accum::default();
                for blk in self.ring.iter() {
                    acc.add_block(blk);
                }
                let since = acc.t_start;
                self.confirmed = acc;
                self.pending = Accum::default();
                self.cusum = 0.0;
                self.phase = Phase::Static { since };
                self.estimate = self.confirmed.estimate(&self.noise, self.cfg.yaw_rad);
                Some(StaticEvent::StaticStart {
                    since,
                    t_detected: b.t_last,
                })
            }
            Phase::Static { .. } => {
                let (gyro, accel) = (self.confirmed.gyro.mean, self.confirmed.accel.mean);
                let (z, dg, da) = self.deviation(&b, &gyro, &accel);
                self.cusum = (self.cusum + z - self.cfg.cusum_drift).max(0.0);
                if self.cusum >= self.cfg.cusum_alarm {
                    let t_onset = if self.pending.is_empty() {
                        b.t_first
                    } else {
                        self.pending.t_start
                    };
                    let estimate = self
                        .confirmed
                        .estimate(&self.noise, self.cfg.yaw_rad)
                        .or(self.estimate);
                    self.end_static();
                    self.ring.push(b);
                    // Always `Some`: the window that started the static period had |ā| ≈ g.
                    let estimate = estimate?;
                    let onset = MotionOnset {
                        t_onset,
                        t_detected: b.t_last,
                        gyro_deviation_rad_s: dg,
                        accel_deviation_m_s2: da,
                        estimate,
                    };
                    self.estimate = Some(estimate);
                    self.known_gyro_bias = Some((estimate.gyro_bias_rad_s, estimate.t_end));
                    self.last_onset = Some(onset);
                    Some(StaticEvent::MotionOnset(onset))
                } else {
                    if self.cusum > 0.0 {
                        self.pending.add_block(&b);
                    } else {
                        let pending = std::mem::take(&mut self.pending);
                        self.confirmed.append(&pending);
                        self.confirmed.add_block(&b);
                        if let Some(e) = self.confirmed.estimate(&self.noise, self.cfg.yaw_rad) {
                            self.estimate = Some(e);
                        }
                    }
                    None
                }
            }
        }
    }

    /// All window blocks consistent with the window mean, plausible bias and gravity norm.
    fn window_is_static(&self) -> bool {
        let mut gyro = Moments::<3>::default();
        let mut accel = Moments::<3>::default();
        for b in self.ring.iter() {
            gyro.merge(&b.gyro);
            accel.merge(&b.accel);
        }
        let (g, a) = (gyro.mean, accel.mean);
        let bias_ok = match self.known_gyro_bias {
            // No bias known yet: any plausible one.
            None => g.norm() <= self.cfg.max_gyro_bias_rad_s,
            // Known since a motion onset; it drifts by `gyro_random_walk · √Δt` (3 σ allowed). A
            // constant-rate turn, or a yaw in hover, is not taken for rest with a new bias.
            Some((bias, t_bias)) => {
                let t = self.ring.iter().next().map_or(t_bias, |b| b.t_first);
                let dt_s = t.secs_since(t_bias).abs();
                let walk = 3.0 * self.noise.gyro_random_walk.abs() * dt_s.sqrt();
                (g - bias).norm() <= self.gyro_thr_rad_s + walk
            }
        };
        bias_ok
            && (a.norm() - GRAVITY_M_S2).abs() <= self.cfg.accel_norm_tolerance_m_s2
            && self.ring.iter().all(|b| self.deviation(b, &g, &a).0 <= 1.0)
    }

    fn end_static(&mut self) {
        self.phase = Phase::NotStatic;
        self.ring.clear();
        self.confirmed = Accum::default();
        self.pending = Accum::default();
        self.cusum = 0.0;
    }

    /// A gap from `t_last` to `t_next`: drop the partial block and the window.
    fn interrupt(&mut self, t_last: TimeNs, t_next: TimeNs) -> Option<StaticEvent> {
        self.block = None;
        self.ring.clear();
        self.known_gyro_bias = None;
        if self.is_static() {
            self.end_static();
            Some(StaticEvent::Interrupted { t_last, t_next })
        } else {
            None
        }
    }
}

/// Standard deviation of the rest state's yaw, rad: unobservable by the IMU, set by
/// [`StaticDetectorConfig::yaw_rad`]; loose, but not free (the estimator's gauge).
pub const REST_YAW_STD_RAD: f64 = 0.01;

/// Covariance of a state held at rest with attitude `r_world_body`, in the order and increment
/// convention of [`super::FrameState::boxplus`] (`[δθ, δp, δv, δbω, δba]`, δθ in the body frame):
/// position and velocity known to 1 mm / 1 mm/s (the pad is the origin), gyro bias to 1 mrad/s,
/// the accelerometer bias to `accel_bias_std_m_s2` on each axis, and the attitude —
///
/// * about the axes across gravity (roll/pitch): `σ² = tilt_sigma_rad² + (accel_bias_std_m_s2 /
///   g)²`. The first term is the statistical error of the gravity direction
///   ([`StaticEstimate::tilt_sigma_rad`]); the second is the accelerometer bias across gravity
///   that the rest absorbed into the tilt (module docs, *What a static IMU cannot tell*) — a tilt
///   held to the first alone keeps that bias's error once the vehicle turns and the bias becomes
///   observable;
/// * about the vertical (yaw): [`REST_YAW_STD_RAD`].
///
/// The axes are taken about the body's up direction `R_wbᵀ ẑ`, whatever the IMU's mounting (on
/// EuRoC and the built-in flights body x points up, so body z is a tilt axis, not yaw).
pub fn rest_covariance(
    r_world_body: &UnitQuaternion<f64>,
    tilt_sigma_rad: f64,
    accel_bias_std_m_s2: f64,
) -> Matrix15 {
    let up = r_world_body.inverse() * Vector3::z();
    let along = up * up.transpose();
    let across = Matrix3::identity() - along;
    let tilt_var = tilt_sigma_rad.powi(2) + (accel_bias_std_m_s2 / GRAVITY_M_S2).powi(2);
    let rot = across * tilt_var + along * REST_YAW_STD_RAD.powi(2);
    let mut cov = Matrix15::zeros();
    cov.fixed_view_mut::<3, 3>(0, 0).copy_from(&rot);
    for k in 3..12 {
        cov[(k, k)] = 1e-6;
    }
    for k in 12..15 {
        cov[(k, k)] = accel_bias_std_m_s2.powi(2);
    }
    cov
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT_NS: i64 = 5_000_000; // 200 Hz
    const T0: TimeNs = TimeNs(1_000_000_000_000);

    /// SplitMix64 + Box–Muller: deterministic normals without depending on the simulator layer.
    struct Rng(u64);

    impl Rng {
        fn uniform(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }

        fn normal(&mut self) -> f64 {
            let (u, v) = (self.uniform(), self.uniform());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        }

        fn normal3(&mut self) -> Vector3<f64> {
            Vector3::new(self.normal(), self.normal(), self.normal())
        }
    }

    /// A vibrating IMU at rest with attitude `r_world_body`, biases, ADIS16448 white noise and a
    /// rotor sinusoid (83 Hz and its 166 Hz harmonic, aliased to 34 Hz at 200 Hz).
    struct SynthImu {
        rng: Rng,
        r_world_body: UnitQuaternion<f64>,
        gyro_bias: Vector3<f64>,
        accel_bias: Vector3<f64>,
        gyro_vib_rad_s: f64,
        accel_vib_m_s2: f64,
        phases: [f64; 12],
    }

    impl SynthImu {
        fn new(seed: u64, r_world_body: UnitQuaternion<f64>, gyro_bias: Vector3<f64>) -> Self {
            let mut rng = Rng(seed);
            let phases = std::array::from_fn(|_| rng.uniform() * std::f64::consts::TAU);
            SynthImu {
                rng,
                r_world_body,
                gyro_bias,
                accel_bias: Vector3::zeros(),
                gyro_vib_rad_s: 0.1,
                accel_vib_m_s2: 1.0,
                phases,
            }
        }

        /// Sample `k`, with true body rate `omega` and world acceleration `a_world`.
        fn sample_moving(
            &mut self,
            k: i64,
            omega: Vector3<f64>,
            a_world: Vector3<f64>,
        ) -> ImuSample {
            let (wg, wa) = ImuNoise::euroc_adis16448().discrete_white_std(DT_NS as f64 * 1e-9);
            let ts = (k * DT_NS) as f64 * 1e-9;
            let w = std::f64::consts::TAU * 83.0 * ts;
            let p = self.phases;
            let vib = |i: usize| (w + p[i]).sin() + 0.5 * (2.0 * w + p[i + 6]).sin();
            let vg = Vector3::new(vib(0), vib(1), vib(2)) * self.gyro_vib_rad_s;
            let va = Vector3::new(vib(3), vib(4), vib(5)) * self.accel_vib_m_s2;
            let f = self.r_world_body.inverse() * (a_world + Vector3::new(0.0, 0.0, GRAVITY_M_S2));
            // The body turns at `omega` (gravity rotates in the body frame accordingly).
            self.r_world_body *= UnitQuaternion::from_scaled_axis(omega * (DT_NS as f64 * 1e-9));
            ImuSample {
                t: T0.add_ns(k * DT_NS),
                gyro_rad_s: omega + self.gyro_bias + vg + self.rng.normal3() * wg,
                accel_m_s2: f + self.accel_bias + va + self.rng.normal3() * wa,
            }
        }

        fn sample(&mut self, k: i64) -> ImuSample {
            self.sample_moving(k, Vector3::zeros(), Vector3::zeros())
        }
    }

    fn detector() -> StaticDetector {
        StaticDetector::new(
            StaticDetectorConfig::default(),
            &ImuNoise::euroc_adis16448(),
        )
    }

    /// Angle between the estimated and the true "up" direction in the body frame, degrees.
    fn tilt_error_deg(est: &UnitQuaternion<f64>, truth: &UnitQuaternion<f64>) -> f64 {
        let z = Vector3::z();
        (est.inverse() * z)
            .angle(&(truth.inverse() * z))
            .to_degrees()
    }

    fn tilted() -> UnitQuaternion<f64> {
        UnitQuaternion::from_euler_angles(5f64.to_radians(), -8f64.to_radians(), 0.5)
    }

    #[test]
    fn the_noise_density_at_rest_is_the_white_noise_and_grows_with_vibration() {
        // 10 s at rest (100 blocks of 0.1 s), white noise only: the datasheet's densities come
        // back…
        let noise = ImuNoise::euroc_adis16448();
        let estimate = |gyro_vib_rad_s: f64, accel_vib_m_s2: f64| {
            let mut imu = SynthImu::new(7, tilted(), Vector3::zeros());
            imu.gyro_vib_rad_s = gyro_vib_rad_s;
            imu.accel_vib_m_s2 = accel_vib_m_s2;
            let mut det = detector();
            for k in 0..2000 {
                det.push(&imu.sample(k));
            }
            *det.estimate().unwrap()
        };
        let quiet = estimate(0.0, 0.0);
        let g = quiet.gyro_density_rad_s_sqrt_hz / noise.gyro_noise_density;
        let a = quiet.accel_density_m_s2_sqrt_hz / noise.accel_noise_density;
        assert!((0.75..1.25).contains(&g), "gyro {g} x datasheet");
        assert!((0.75..1.25).contains(&a), "accel {a} x datasheet");
        // …and the rotor sinusoid, aliased into the block means, raises them above it.
        let shaking = estimate(0.1, 1.0);
        assert!(
            shaking.gyro_density_rad_s_sqrt_hz > 1.5 * quiet.gyro_density_rad_s_sqrt_hz,
            "{} vs {}",
            shaking.gyro_density_rad_s_sqrt_hz,
            quiet.gyro_density_rad_s_sqrt_hz
        );
        assert!(
            shaking.accel_density_m_s2_sqrt_hz > 1.5 * quiet.accel_density_m_s2_sqrt_hz,
            "{} vs {}",
            shaking.accel_density_m_s2_sqrt_hz,
            quiet.accel_density_m_s2_sqrt_hz
        );
    }

    #[test]
    fn static_tilt_and_gyro_bias_are_recovered_under_vibration() {
        let bias = Vector3::new(0.01, -0.02, 0.005);
        let mut imu = SynthImu::new(1, tilted(), bias);
        let mut det = detector();
        let mut events = vec![];
        for k in 0..1000 {
            if let Some(e) = det.push(&imu.sample(k)) {
                events.push(e);
            }
        }
        assert_eq!(events.len(), 1, "{events:?}");
        let StaticEvent::StaticStart { since, t_detected } = events[0] else {
            panic!("{events:?}")
        };
        assert_eq!(since, T0);
        assert_eq!(
            t_detected,
            T0.add_ns(99 * DT_NS),
            "after the 5-block window"
        );
        assert!(det.is_static() && det.static_since() == Some(T0));
        let est = *det.estimate().unwrap();
        assert_eq!(est.num_samples, 1000);
        assert_eq!((est.t_start, est.t_end), (T0, T0.add_ns(999 * DT_NS)));
        let tilt = tilt_error_deg(&est.r_world_body, &tilted());
        let dbias = (est.gyro_bias_rad_s - bias).norm();
        eprintln!(
            "tilt error {tilt:.4} deg, bias error {:.3} mrad/s (sigma {:.3?} mrad/s), gyro std \
             {:.1?} mrad/s, accel std {:.2?} m/s^2",
            dbias * 1e3,
            (est.gyro_bias_sigma_rad_s * 1e3).as_slice(),
            (est.gyro_std_rad_s * 1e3).as_slice(),
            est.accel_std_m_s2.as_slice(),
        );
        assert!(tilt < 0.03, "tilt error {tilt} deg");
        assert!(dbias < 3e-4, "bias error {dbias} rad/s");
        for i in 0..3 {
            let e = (est.gyro_bias_rad_s[i] - bias[i]).abs();
            assert!(e < 5.0 * est.gyro_bias_sigma_rad_s[i], "axis {i}: {e}");
        }
        assert!((est.accel_norm_m_s2 - GRAVITY_M_S2).abs() < 0.01);
        assert!(
            est.tilt_sigma_rad.to_degrees() < 0.2,
            "{}",
            est.tilt_sigma_rad
        );
        // Vibration dominates the per-sample spread (0.1 rad/s and 1 m/s² amplitudes).
        assert!(est.gyro_std_rad_s.min() > 0.05 && est.accel_std_m_s2.min() > 0.5);
        assert_eq!(est.imu_bias().gyro_rad_s, est.gyro_bias_rad_s);
        assert_eq!(est.imu_bias().accel_m_s2, Vector3::zeros());
        let nav = est.nav_state(Vector3::new(1.0, 2.0, 3.0));
        assert_eq!((nav.t, nav.v_world_m_s), (est.t_end, Vector3::zeros()));
    }

    #[test]
    fn configured_yaw_is_applied_about_world_z() {
        let cfg = StaticDetectorConfig {
            yaw_rad: 1.2,
            ..Default::default()
        };
        let mut det = StaticDetector::new(cfg, &ImuNoise::euroc_adis16448());
        let mut det0 = detector();
        let mut imu = SynthImu::new(2, tilted(), Vector3::zeros());
        for k in 0..200 {
            let s = imu.sample(k);
            det.push(&s);
            det0.push(&s);
        }
        let (r, r0) = (
            det.estimate().unwrap().r_world_body,
            det0.estimate().unwrap().r_world_body,
        );
        let expected = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 1.2) * r0;
        assert!(r.angle_to(&expected) < 1e-12);
    }

    #[test]
    fn accelerometer_bias_is_absorbed_into_the_tilt() {
        let truth = UnitQuaternion::identity();
        let mut imu = SynthImu::new(3, truth, Vector3::zeros());
        imu.accel_bias = Vector3::new(0.1, -0.05, 0.2);
        let mut det = detector();
        for k in 0..2000 {
            det.push(&imu.sample(k));
        }
        let est = det.estimate().unwrap();
        let predicted = (imu.accel_bias.xy().norm() / GRAVITY_M_S2)
            .atan()
            .to_degrees();
        let tilt = tilt_error_deg(&est.r_world_body, &truth);
        eprintln!("tilt error {tilt:.4} deg, predicted atan(|b_perp|/g) = {predicted:.4} deg");
        assert!((tilt - predicted).abs() < 0.02, "{tilt} vs {predicted}");
        // The bias along gravity shows in the norm instead.
        assert!((est.accel_norm_m_s2 - (GRAVITY_M_S2 + 0.2)).abs() < 0.01);
    }

    #[test]
    fn rate_step_is_detected_within_two_blocks_and_back_dated() {
        let bias = Vector3::new(-0.003, 0.02, 0.08);
        let mut imu = SynthImu::new(4, tilted(), bias);
        let mut det = detector();
        let k_motion = 607; // 3.035 s: inside the block [3.0, 3.1) s
        let t_motion = T0.add_ns(k_motion * DT_NS);
        let mut onsets = vec![];
        for k in 0..800 {
            let omega = if k >= k_motion {
                Vector3::new(0.1, 0.0, 0.0)
            } else {
                Vector3::zeros()
            };
            let s = imu.sample_moving(k, omega, Vector3::zeros());
            if let Some(StaticEvent::MotionOnset(o)) = det.push(&s) {
                onsets.push(o);
            }
        }
        assert_eq!(onsets.len(), 1, "{onsets:?}");
        let o = onsets[0];
        let (back_s, latency_s) = (
            t_motion.secs_since(o.t_onset),
            o.t_detected.secs_since(t_motion),
        );
        eprintln!("onset {back_s:.3} s before the step, detected {latency_s:.3} s after it");
        assert!(
            (0.0..0.1).contains(&back_s),
            "onset {back_s} s before the step"
        );
        assert!((0.0..0.2).contains(&latency_s), "latency {latency_s} s");
        assert!(!det.is_static() && det.static_since().is_none());
        assert_eq!(det.last_onset(), Some(&o));
        // The frozen estimate holds no moving samples and keeps the bias.
        assert!(o.estimate.t_end < o.t_onset);
        assert_eq!(det.estimate(), Some(&o.estimate));
        assert!((o.estimate.gyro_bias_rad_s - bias).norm() < 5e-4);
        assert!(o.gyro_deviation_rad_s > det.gyro_threshold_rad_s());
    }

    #[test]
    fn smooth_take_off_is_detected_and_onset_precedes_detection() {
        // Vertical acceleration growing as 6 τ² m/s² (a septic smoothstep climb of ~1.2 m in 3 s
        // starts like this): deviations reach half a threshold ~0.15 s in.
        let mut imu = SynthImu::new(5, UnitQuaternion::identity(), Vector3::zeros());
        let mut det = detector();
        let k_motion = 400;
        let t_motion = T0.add_ns(k_motion * DT_NS);
        let mut onset = None;
        for k in 0..800 {
            let tau = ((k - k_motion) * DT_NS) as f64 * 1e-9;
            let a = Vector3::new(0.0, 0.0, if tau > 0.0 { 6.0 * tau * tau } else { 0.0 });
            if let Some(StaticEvent::MotionOnset(o)) =
                det.push(&imu.sample_moving(k, Vector3::zeros(), a))
            {
                onset.get_or_insert(o);
            }
        }
        let o = onset.expect("onset");
        let (on_s, det_s) = (
            o.t_onset.secs_since(t_motion),
            o.t_detected.secs_since(t_motion),
        );
        eprintln!("onset {on_s:.3} s, detection {det_s:.3} s after the start of the climb");
        assert!((0.0..=0.25).contains(&on_s), "onset {on_s}");
        assert!(det_s < 0.35, "detection {det_s}");
        assert!(o.t_onset < o.t_detected);
        assert!(o.accel_deviation_m_s2 > 0.5 * det.accel_threshold_m_s2());
    }

    #[test]
    fn a_yaw_in_hover_is_not_rest_but_landing_again_is() {
        // Rest, then a steady yaw about world z at 0.05 rad/s: gravity stays fixed in the body
        // frame, so only the known gyro bias tells this from rest. Then rest again.
        let bias = Vector3::new(0.002, -0.004, 0.003);
        let mut imu = SynthImu::new(14, UnitQuaternion::identity(), bias);
        let mut det = detector();
        let mut events = vec![];
        for k in 0..1600 {
            let omega = if (400..1000).contains(&k) {
                Vector3::new(0.0, 0.0, 0.05)
            } else {
                Vector3::zeros()
            };
            if let Some(e) = det.push(&imu.sample_moving(k, omega, Vector3::zeros())) {
                events.push((k, e));
            }
        }
        let kinds: Vec<_> = events
            .iter()
            .map(|(k, e)| match e {
                StaticEvent::StaticStart { .. } => ("static", *k),
                StaticEvent::MotionOnset(_) => ("onset", *k),
                StaticEvent::Interrupted { .. } => ("gap", *k),
            })
            .collect();
        eprintln!("{kinds:?}");
        assert_eq!(kinds.len(), 3, "{kinds:?}");
        assert_eq!(
            (kinds[0].0, kinds[1].0, kinds[2].0),
            ("static", "onset", "static")
        );
        assert!(
            (400..420).contains(&kinds[1].1),
            "onset at sample {}",
            kinds[1].1
        );
        assert!(
            (1000..1140).contains(&kinds[2].1),
            "rest again at sample {}",
            kinds[2].1
        );
        let est = det.estimate().unwrap();
        assert!((est.gyro_bias_rad_s - bias).norm() < 5e-4);
        // 0.6 rad of yaw in between: the new attitude has the same gravity direction.
        assert!(tilt_error_deg(&est.r_world_body, &UnitQuaternion::identity()) < 0.05);
    }

    #[test]
    fn a_minute_of_vibrating_rest_raises_no_onset() {
        let mut imu = SynthImu::new(6, tilted(), Vector3::new(0.01, 0.0, -0.01));
        let mut det = detector();
        let walk = ImuNoise::euroc_adis16448().discrete_walk_std(DT_NS as f64 * 1e-9);
        let mut rng = Rng(99);
        for k in 0..12_000 {
            imu.gyro_bias += rng.normal3() * walk.0;
            imu.accel_bias += rng.normal3() * walk.1;
            if let Some(e) = det.push(&imu.sample(k)) {
                assert!(matches!(e, StaticEvent::StaticStart { .. }), "{e:?}");
            }
        }
        assert!(det.is_static() && det.static_since() == Some(T0));
        assert_eq!(det.counters().accepted, 12_000);
    }

    #[test]
    fn non_finite_and_non_increasing_samples_are_counted_and_skipped() {
        let mut imu = SynthImu::new(7, tilted(), Vector3::new(0.01, 0.02, 0.03));
        // A fifth of the samples go missing: the mean of a sinusoid with holes is no longer zero,
        // so keep the vibration at the simulator's level here.
        imu.gyro_vib_rad_s = 0.01;
        imu.accel_vib_m_s2 = 0.3;
        let mut det = detector();
        let (mut good, mut dup) = (0, 0);
        let mut prev: Option<ImuSample> = None;
        for k in 0..400 {
            let mut s = imu.sample(k);
            if k % 11 == 5 {
                s.gyro_rad_s.y = f64::NAN;
            } else if k % 13 == 6 {
                s.accel_m_s2.z = f64::INFINITY;
            } else if k % 17 == 7 {
                s.accel_m_s2.x = f64::NEG_INFINITY;
                s.t = TimeNs(i64::MIN);
            } else {
                good += 1;
                assert!(!matches!(det.push(&s), Some(StaticEvent::MotionOnset(_))));
                if let Some(p) = prev.filter(|_| k % 19 == 0) {
                    det.push(&p); // earlier than `s`
                    det.push(&ImuSample { t: TimeNs(0), ..p }); // far in the past
                    det.push(&s); // duplicate time
                    dup += 3;
                }
                prev = Some(s);
                continue;
            }
            assert!(!matches!(det.push(&s), Some(StaticEvent::MotionOnset(_))));
        }
        let c = det.counters();
        let bad = 400 - good;
        assert_eq!((c.accepted, c.non_finite), (good, bad));
        assert_eq!(c.out_of_order, dup);
        assert!(dup > 20);
        assert_eq!(c.gaps, 0, "a skipped sample is not a gap");
        assert!(det.is_static());
        let est = det.estimate().unwrap();
        assert!((est.gyro_bias_rad_s - Vector3::new(0.01, 0.02, 0.03)).norm() < 1e-3);
        assert!(tilt_error_deg(&est.r_world_body, &tilted()) < 0.1);
    }

    #[test]
    fn a_gap_interrupts_the_static_period_without_an_onset() {
        let mut imu = SynthImu::new(8, tilted(), Vector3::zeros());
        let mut det = detector();
        let mut events = vec![];
        for k in (0..400).chain(440..800) {
            if let Some(e) = det.push(&imu.sample(k)) {
                events.push(e);
            }
        }
        let t = |k: i64| T0.add_ns(k * DT_NS);
        assert_eq!(
            events,
            vec![
                StaticEvent::StaticStart {
                    since: t(0),
                    t_detected: t(99)
                },
                StaticEvent::Interrupted {
                    t_last: t(399),
                    t_next: t(440)
                },
                StaticEvent::StaticStart {
                    since: t(440),
                    t_detected: t(539)
                },
            ]
        );
        assert_eq!(det.counters().gaps, 1);
        assert!(det.last_onset().is_none());
    }

    #[test]
    fn rotation_or_free_fall_is_never_declared_static() {
        let mut det = detector();
        let mut imu = SynthImu::new(9, tilted(), Vector3::new(0.25, 0.0, 0.0)); // > max bias
        for k in 0..400 {
            assert!(det.push(&imu.sample(k)).is_none());
        }
        let mut det = detector();
        let mut imu = SynthImu::new(10, tilted(), Vector3::zeros());
        let fall = Vector3::new(0.0, 0.0, -GRAVITY_M_S2);
        for k in 0..400 {
            assert!(
                det.push(&imu.sample_moving(k, Vector3::zeros(), fall))
                    .is_none()
            );
        }
        assert!(!det.is_static() && det.estimate().is_none());
    }

    #[test]
    fn reset_forgets_the_state_but_keeps_the_counters() {
        let mut imu = SynthImu::new(11, tilted(), Vector3::zeros());
        let mut det = detector();
        for k in 0..200 {
            det.push(&imu.sample(k));
        }
        det.push(&ImuSample {
            t: TimeNs(0),
            ..imu.sample(0)
        });
        assert!(det.is_static());
        det.reset();
        assert!(!det.is_static() && det.estimate().is_none());
        assert_eq!(det.counters().out_of_order, 1);
        assert!(
            det.push(&imu.sample(0)).is_none(),
            "accepted again after reset"
        );
        assert_eq!(det.counters().accepted, 201);
    }

    #[test]
    fn attitude_from_specific_force_maps_up_to_world_z() {
        let mut rng = Rng(12);
        for _ in 0..100 {
            let r = UnitQuaternion::from_scaled_axis(rng.normal3() * 1.5);
            let f = r.inverse() * Vector3::new(0.0, 0.0, 9.81);
            for yaw in [0.0, 0.7, -2.0] {
                let q = r_world_body_from_specific_force(&f, yaw).unwrap();
                assert!((q * f.normalize() - Vector3::z()).norm() < 1e-12);
            }
        }
        let level = r_world_body_from_specific_force(&Vector3::new(0.0, 0.0, 9.8), 0.0).unwrap();
        assert!(level.angle() < 1e-15);
        let small = r_world_body_from_specific_force(&Vector3::new(0.1, 0.0, 9.8), 0.0).unwrap();
        let (roll, pitch, yaw) = small.euler_angles();
        assert!(roll.abs() < 1e-15 && yaw.abs() < 1e-15);
        assert!(
            (pitch + (0.1f64 / 9.8).atan()).abs() < 1e-12,
            "pitch {pitch}"
        );
        let flipped = r_world_body_from_specific_force(&Vector3::new(0.0, 0.0, -9.8), 0.0).unwrap();
        assert!((flipped * Vector3::new(0.0, 0.0, -1.0) - Vector3::z()).norm() < 1e-12);
        assert!(r_world_body_from_specific_force(&Vector3::zeros(), 0.0).is_none());
        assert!(r_world_body_from_specific_force(&Vector3::new(f64::NAN, 0.0, 9.8), 0.0).is_none());
    }

    #[test]
    fn config_validation_and_window_blocks() {
        let cfg = StaticDetectorConfig::default();
        assert_eq!(cfg.validate(), Ok(()));
        assert_eq!(cfg.window_blocks(), 5);
        let bad = StaticDetectorConfig {
            block_s: -0.1,
            ..cfg
        };
        assert!(bad.validate().unwrap_err().contains("block_s"));
        let bad = StaticDetectorConfig {
            accel_vibration_margin_m_s2: f64::NAN,
            ..cfg
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .contains("accel_vibration_margin_m_s2")
        );
        let long = StaticDetectorConfig {
            window_s: 100.0,
            ..cfg
        };
        assert_eq!(long.window_blocks(), MAX_WINDOW_BLOCKS);
        let short = StaticDetectorConfig {
            window_s: 0.01,
            ..cfg
        };
        assert_eq!(short.window_blocks(), 2);
        let det = detector();
        assert!((det.gyro_threshold_rad_s() - 0.022_683).abs() < 1e-5);
        assert!((det.accel_threshold_m_s2() - 0.281_623).abs() < 1e-5);
    }

    #[test]
    #[should_panic(expected = "invalid StaticDetectorConfig: cusum_alarm")]
    fn invalid_config_panics_in_new() {
        let cfg = StaticDetectorConfig {
            cusum_alarm: 0.0,
            ..Default::default()
        };
        StaticDetector::new(cfg, &ImuNoise::euroc_adis16448());
    }

    #[test]
    fn merged_moments_equal_direct_ones() {
        let mut rng = Rng(13);
        let xs: Vec<Vector3<f64>> = (0..50)
            .map(|_| rng.normal3() * 3.0 + Vector3::repeat(9.0))
            .collect();
        let mut all = Moments::<3>::default();
        xs.iter().for_each(|x| all.push(x));
        let (mut a, mut b) = (Moments::<3>::default(), Moments::<3>::default());
        xs[..17].iter().for_each(|x| a.push(x));
        xs[17..].iter().for_each(|x| b.push(x));
        a.merge(&b);
        assert_eq!(a.n, 50);
        assert!((a.mean - all.mean).norm() < 1e-12 && (a.m2 - all.m2).norm() < 1e-9);
        let mean: Vector3<f64> = xs.iter().sum::<Vector3<f64>>() / 50.0;
        let var = xs
            .iter()
            .map(|x| (x - mean).component_mul(&(x - mean)))
            .sum::<Vector3<f64>>()
            / 49.0;
        assert!((all.std() - var.map(f64::sqrt)).norm() < 1e-12);
    }

    #[test]
    fn the_rest_covariance_frees_the_tilt_that_a_bias_across_gravity_can_be() {
        // Body x up (EuRoC's mounting), pitched 14°: the rotation block has the yaw variance
        // along the body's up direction and σ² = tilt² + (σ_ba/g)² across it.
        let r = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -std::f64::consts::FRAC_PI_2)
            * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.25);
        let up = r.inverse() * Vector3::z();
        assert!(up.x > 0.95, "body x is up: {up}");
        let cov = rest_covariance(&r, 1e-3, 0.1);
        let rot = cov.fixed_view::<3, 3>(0, 0).into_owned();
        let yaw_var = (up.transpose() * rot * up)[0];
        assert!(
            (yaw_var - REST_YAW_STD_RAD.powi(2)).abs() < 1e-12,
            "{yaw_var}"
        );
        let tilt_var = 1e-6 + (0.1 / GRAVITY_M_S2).powi(2);
        for across in [
            up.cross(&Vector3::y()).normalize(),
            up.cross(&Vector3::z()).normalize(),
        ] {
            let v = (across.transpose() * rot * across)[0];
            assert!((v - tilt_var).abs() < 1e-12, "{v} vs {tilt_var}");
            assert!((rot * across - across * tilt_var).norm() < 1e-12);
        }
        // A bias across gravity of σ_ba, absorbed into the tilt, is a 1-σ tilt.
        assert!((tilt_var.sqrt() - 0.1 / GRAVITY_M_S2).abs() < 1e-4);
        for k in 12..15 {
            assert!((cov[(k, k)] - 0.01).abs() < 1e-15);
        }
        assert!(cov.cholesky().is_some());
    }
}
