//! A sliding window of keyframe states joined by IMU preintegration factors (eq. 13 between
//! consecutive keyframes, weighted by eq. 9–10's noise) and by the relative poses tracking measured
//! between them ([`RelativePose`]); the oldest keyframe is marginalised into a dense Gaussian prior
//! (Schur complement, as eq. 19–22 but over whole keyframe states).
//!
//! Why: the tracker of section III fixes the keyframe it tracks against, so every frame's absolute
//! pose is pinned to that keyframe's estimate, and the IMU can only correct the newest frame. Errors
//! of a keyframe (tilt, scale of the baseline, velocity) are then never revisited: the accelerometer
//! bias absorbs the tilt and the velocity drifts. In the window, vision constrains only *relative*
//! keyframe poses, with its information tempered, while the IMU sees gravity and the accelerations
//! over several keyframe intervals, so tilt, velocity, scale and biases stay observable. The
//! odometry moves the keyframes and the tracker's state onto the window's solution after every
//! new keyframe.
//!
//! With `map_scale` each keyframe's map also has a log-scale λ among the unknowns: the relative
//! poses tracked against a map are measured at its scale `e^λ`, and λ walks from keyframe to
//! keyframe, so the IMU reads the maps' scale over the whole window and the odometry corrects the
//! map tracked by it (`map_scale_gain`).
//!
//! With `gyro_misalignment` the gyro's turn against the body frame, `ω_body = Exp(φ) ω_gyro`
//! ([`crate::imu::misalignment`]), is one more unknown shared by every IMU factor: each factor's
//! preintegration is turned by φ, and the relative poses (the camera's rotations) tell φ from the
//! keyframes' attitudes. Without it a gyro mounted a few tenths of a degree askew turns the
//! keyframes onto its own axes, and the tilt that follows takes the accelerometer's gravity into
//! the velocity. φ is kept through marginalisation (it is never marginalised) and restarts.
//!
//! With `mount_rotation` each keyframe also carries the IMU frame's turn against its body (the
//! camera's) frame, `R_imu = R_body Exp(ψ)` ([`crate::imu::mount_rotation`]): the IMU factors hold
//! between the IMU frames, the relative poses between the body frames, and ψ is a Gauss–Markov
//! process from keyframe to keyframe.
//!
//! State increment per keyframe in the order of eq. 11, `[δθ, δt, δv, δbω, δba]`, then λ with
//! `map_scale`, then ψ's 3 rows with `mount_rotation`; after all keyframes, φ's 3 rows with
//! `gyro_misalignment`.

use super::envelope_cholesky::EnvelopeCholesky;
use super::relative_pose::RelativePose;
use super::zero_skipping_cholesky;
use crate::geometry::log_so3;
use crate::imu::imu_jacobian_j;
use crate::imu::misalignment::{d_residual_d_misalignment, turned};
use crate::imu::mount_rotation::{imu_jacobians_mounted, mounted};
use crate::imu::{
    FrameState, ImuNoise, Matrix15, Preintegration, Vector15, imu_residual,
    imu_residual_covariance, residual::imu_jacobian_i,
};
use crate::time::TimeNs;
use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, SMatrix, SVector, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::ops::AddAssign;

/// Settings of the keyframe window (the `[window]` table).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WindowConfig {
    /// Run the window and move keyframes and state onto its solution.
    pub enabled: bool,
    /// Keyframes kept before the oldest is marginalised. 12 (since 2026-11-27; 6 before): the IMU
    /// between them spans ~5 s of flight instead of ~2.5 s. Offline, demo seeds 1–24 median 2.67 →
    /// 2.48 cm (resets 6 → 2); S-V101 seeds 1–16 median 1.01 → 0.47 m, runs beyond 2 m 5 → 3; 10
    /// and 16 keyframes lost more S-V101 seeds (docs/odometry-log.md, *A longer keyframe window*).
    pub max_keyframes: usize,
    /// The tracking information of a relative pose is multiplied by these (rotation rows and
    /// translation rows): the photometric Hessian treats every pixel as independent, but the
    /// errors of the map it is tracked against are shared by all of them. Measured on the demo
    /// flight, relative rotations are off by 0.03–0.25° and translations by 1–5 % against a
    /// photometric σ of 0.002° and 0.07 mm.
    pub visual_rotation_information_scale: f64,
    pub visual_translation_information_scale: f64,
    /// Huber threshold of a relative pose's Mahalanobis norm (after the scales above): beyond it
    /// the factor is down-weighted, so a keyframe tracked against a distorted map cannot drag the
    /// window away from the IMU (0 = plain least squares).
    pub visual_huber_sigmas: f64,
    /// Multiplies the IMU white-noise densities (as `[tracking] imu_noise_scale`).
    pub imu_noise_scale: f64,
    /// Multiplies, on top of `imu_noise_scale`, the rotation part of each IMU factor's noise
    /// ([`crate::imu::Preintegration::scale_rotation_noise`]; 1 = as the rest).
    pub imu_rotation_noise_factor: f64,
    /// Levenberg-Marquardt iterations per solve.
    pub max_iterations: usize,
    /// Factor each step's normal equations within their envelope
    /// ([`super::envelope_cholesky`]: ~10x fewer flops, window solve p50 4.0 → 1.9 ms on the
    /// demo) instead of in nalgebra's order. (Off, the default, [`super::zero_skipping_cholesky`]
    /// gives nalgebra's factor and solution to the bit with its products by zero skipped: S-V101
    /// seed 1's window solve p50 4.7 → 3.2 ms offline, session 85.) The envelope's is the same
    /// solution up to rounding, but the closed loop grows those last bits: S-V101 seeds 1–8 offline went from a median of 0.138 to 0.160 m, seed 8
    /// ran away (1.38 m), while the demo's seeds 1–16 kept their distribution. Off until more
    /// seeds tell chaos from a cost (docs/odometry-log.md, *The keyframe window's factorisation
    /// within its envelope*).
    pub envelope_factorisation: bool,
    /// Estimate each keyframe map's scale in the window: a log-scale λ per keyframe (its map is
    /// `e^λ` times metric), which the relative poses tracked against that map are measured in
    /// ([`RelativePose::residual_scaled`]), joined from keyframe to keyframe by a random walk of
    /// `map_scale_step_std` — a new map inherits its predecessor's scale through the mapper's
    /// propagation and the views tracked against it. The IMU then reads one scale over the whole
    /// window instead of correcting every baseline by itself. On since 2026-11-28 (with
    /// `map_scale_gain` 0.5; docs/odometry-log.md, *The window reads each map's scale*).
    pub map_scale: bool,
    /// Standard deviation of λ's step from one keyframe's map to the next.
    pub map_scale_step_std: f64,
    /// Standard deviation of λ at a window (re)start.
    pub map_scale_initial_std: f64,
    /// Fraction of the estimated λ of the keyframe map tracked that is corrected when the next
    /// keyframe is started (its depths scaled by `e^{−gain·λ}` in the tracker and the mapper, so
    /// the new map is propagated from a corrected one); 0 = estimate only. 0.75 since session 70
    /// (0.5 before; docs/odometry-log.md, *Three quarters of the map's scale corrected*).
    pub map_scale_gain: f64,
    /// At most this much of λ is corrected per keyframe.
    pub map_scale_max_step: f64,
    /// A first map started again in flight after a loss joins the window by the IMU through the
    /// loss instead of restarting it ([`KeyframeWindow::push_new_map`]): the velocity, biases and
    /// gravity the window held before the loss anchor the new map's scale. Off: the window
    /// restarts at the new map from the dead-reckoned state.
    pub keep_across_rebuild: bool,
    /// Estimate the gyro's turn against the body frame, `ω_body = Exp(φ) ω_gyro`
    /// ([`crate::imu::misalignment`]), as an unknown shared by every IMU factor of the window
    /// and kept through marginalisation and restarts: a gyro turned by a few tenths of a degree
    /// otherwise turns the window's keyframes onto its own axes (docs/odometry-log.md, *The
    /// keyframe window reads the gyro's turn*).
    pub gyro_misalignment: bool,
    /// Prior standard deviation of φ per axis about zero (and at every window restart about the
    /// estimate then), rad.
    pub gyro_misalignment_prior_std_rad: f64,
    /// The same about the body's up axis (at the attitude of the window's start): a flight turns
    /// about it, which shows the gyro's turn about the other two axes but hardly its turn about
    /// this one, and a turn about the axis a vehicle turns about costs little. Left at the wider
    /// σ, the estimate there took up other errors (0.6° in 2 s on a demo render), rad.
    pub gyro_misalignment_up_std_rad: f64,
    /// At a restart of the window (a loss, a return it cannot join) φ's prior is the information
    /// the window held on it (its nodes Schur-complemented out), centred on the estimate, instead
    /// of the fresh `gyro_misalignment_prior_std_rad`: the estimate does not start over, and
    /// swing by a degree, at every restart.
    pub gyro_misalignment_keep_information: bool,
    /// Standard deviation of a rebuilt map's λ about the λ before the loss (its depths come
    /// from a dead-reckoned baseline or are guessed, unrelated to the maps before).
    pub map_scale_rebuilt_std: f64,
    /// When a keyframe leaves the window, this fraction of what its map's λ then says about the
    /// map as it was stored — λ less the correction `map_scale_gain` already applied to it — is
    /// corrected in the loop closer's points of it, which a loop's PnP places a camera by (edge
    /// errors follow the old map's scale error times the baseline, docs/odometry-log.md, *Stored
    /// maps rescaled as they leave the window*), at most `map_scale_max_step`. 0 = off; 0.75
    /// since session 72 (S-V101 seeds 1–20 offline: loop edges 2.9 → 2.2 cm median, ATE median
    /// 0.112 → 0.108 m, 17 seeds better, 2 worse).
    pub stored_map_scale_gain: f64,
    /// …and in the stored keyframes returns track against. Off: it lost two of twenty S-V101
    /// seeds (a loss in the fast turn) for the gain of a few.
    pub stored_map_scale_in_returns: bool,
    /// A loss longer than this (s, last keyframe to the new map) restarts the window anyway:
    /// the IMU alone over it no longer says much about the velocity.
    pub keep_across_rebuild_max_s: f64,
    /// The window does not turn its keyframes about the world's vertical: every step of a solve
    /// leaves each keyframe's heading where tracking (or a return to a stored keyframe) put it,
    /// while tilt, position, velocity, biases, the maps' scales and the gyro's turn stay free.
    /// Heading is not observable from the IMU (eq. 13 holds under any rotation about gravity),
    /// so in the window it is set by the gyro's rotation factors against the tempered relative
    /// poses, and a gyro that wanders against the camera (S-V101's real one, docs/odometry-log.md,
    /// *The real gyro's error against the truth's rates, regressed*) turns the keyframes with it:
    /// held, the gyro's disagreement with the tracked headings goes into its bias instead.
    /// A diagnostic, off: it tells the window's part of a heading drift, but the tracked
    /// headings drift as far on their own (S-V101 seeds 1–10 median 0.139 → 0.162 m, the
    /// built-in demo lost on 2 of 8 seeds; docs/odometry-log.md, *The keyframe window's
    /// headings held at the tracked ones*).
    pub hold_heading: bool,
    /// The IMU frame's attitude against the camera's body frame as a slowly varying unknown per
    /// keyframe, `R_imu = R_body Exp(ψ_k)` ([`crate::imu::mount_rotation`]): the IMU factors
    /// hold between the IMU frames, the relative poses between the camera's, and ψ follows a
    /// first-order Gauss–Markov process (stationary `mount_rotation_std_rad` per axis, time
    /// constant `mount_rotation_time_constant_s`) from keyframe to keyframe. A soft camera mount,
    /// or an IMU reference that wanders against the camera (S-V101's truth: ~5 mrad of tilt at
    /// 0.1–1 Hz, docs/odometry-log.md, *The real accelerometer against the truth, read both
    /// ways*), otherwise turns the accelerometer's gravity against the camera's attitude.
    pub mount_rotation: bool,
    /// Stationary standard deviation of ψ per axis, rad (also its prior at a window restart).
    pub mount_rotation_std_rad: f64,
    /// Correlation time of ψ, s: consecutive keyframes `Δt` apart are tied by `ψ_j = a ψ_i + w`,
    /// `a = e^{−Δt/τ}`, `w ~ N(0, σ²(1 − a²))`.
    pub mount_rotation_time_constant_s: f64,
    /// The gyro's rotation weighed by its noise as read in flight: the rotation it integrates
    /// from each keyframe to the next against the relative rotation tracking measured over it
    /// ([`crate::imu::gyro_noise_reading`]); the median reading of the last
    /// `inflight_gyro_noise_intervals` over `imu_noise_scale × imu_rotation_noise_factor`
    /// (within 1 .. `inflight_gyro_noise_max_scale`) replaces the pad's factor (`[bootstrap]
    /// rest_gyro_rotation_noise`) on the rotation part of the window's, the keyframe
    /// adjustment's and the loop closer's odometry IMU factors once
    /// `inflight_gyro_noise_min_intervals` are read. The pad sees the gyro's vibration at rest
    /// only; in flight a consistent gyro reads ~1 and a wandering one its wander. The window
    /// itself does not read it: the odometry sets its scale
    /// ([`KeyframeWindow::set_imu_rotation_noise_scale`]). Off: on S-V101's path with the
    /// simulator's IMU (the pad 4.8–4.95 ×, in flight 2.0–2.9 × the datasheet) seeds 1–3 go from
    /// 3.85 / 5.43 / 5.71 to 2.36 / 3.49 / 4.84 cm, but on S-V101's real gyro (in flight 10–15 ×,
    /// a factor of 3.6–4.7 against the pad's 5.86) seeds 1–10 from a mean of 0.101 to 0.113 m
    /// (docs/odometry-log.md, *The gyro's noise read in flight*).
    pub inflight_gyro_noise: bool,
    /// The tracked rotation the gyro is read against is the photometric term's own (the joint
    /// solution moved by `TrackResult::photometric_step`), so the tracker's IMU term does not
    /// pull it toward the gyro it is compared with (as `[gyro_alignment] photometric_pairs`).
    pub inflight_gyro_noise_photometric: bool,
    /// Keyframe intervals read before the reading replaces the pad's factor.
    pub inflight_gyro_noise_min_intervals: usize,
    /// Keyframe intervals the median is taken over (the newest).
    pub inflight_gyro_noise_intervals: usize,
    /// The factor read in flight is kept within 1 .. this.
    pub inflight_gyro_noise_max_scale: f64,
    /// Skip edges: the new keyframe's image is aligned, by vision alone, against the map of the
    /// keyframe two back (the window's second newest), and the length of that relative pose
    /// joins the window as one more row ([`RelativePose::length_residual_scaled`], at that
    /// map's λ as corrected when its successor was started). Along the chain the displacement
    /// crosses two maps, on the skip edge one: the step of the maps' scale is read by the images,
    /// which the IMU alone reads poorly (docs/odometry-log.md, *Where a keyframe interval's
    /// displacement goes wrong*). Off: on S-V101 it keeps seeds 16 / 20's scale (0.409 / 0.165 →
    /// 0.191 / 0.090 m) but seeds 1–10 go from a mean of 0.089 to 0.094 m (six worse, two
    /// better); as a whole relative pose it ran three seeds away (docs/odometry-log.md, *Skip
    /// edges in the keyframe window*, session 88).
    pub skip_edges: bool,
    /// A skip edge is kept only if its alignment keeps at least this fraction of its points as
    /// inliers (in a fast turn the map two back is half out of view).
    pub skip_min_inlier_ratio: f64,
}

impl Default for WindowConfig {
    fn default() -> Self {
        WindowConfig {
            enabled: true,
            max_keyframes: 12,
            visual_rotation_information_scale: 1e-3,
            visual_translation_information_scale: 1e-3,
            visual_huber_sigmas: 0.0,
            imu_noise_scale: 3.0,
            imu_rotation_noise_factor: 1.0,
            max_iterations: 8,
            envelope_factorisation: false,
            map_scale: true,
            map_scale_step_std: 0.02,
            map_scale_initial_std: 0.05,
            map_scale_gain: 0.75,
            map_scale_max_step: 0.05,
            keep_across_rebuild: true,
            gyro_misalignment: true,
            gyro_misalignment_prior_std_rad: 0.035,
            gyro_misalignment_up_std_rad: 0.0017,
            gyro_misalignment_keep_information: true,
            map_scale_rebuilt_std: 0.5,
            stored_map_scale_gain: 0.75,
            stored_map_scale_in_returns: false,
            keep_across_rebuild_max_s: 5.0,
            hold_heading: false,
            mount_rotation: false,
            mount_rotation_std_rad: 0.005,
            mount_rotation_time_constant_s: 2.0,
            inflight_gyro_noise: false,
            inflight_gyro_noise_photometric: true,
            inflight_gyro_noise_min_intervals: 10,
            inflight_gyro_noise_intervals: 200,
            inflight_gyro_noise_max_scale: 10.0,
            skip_edges: false,
            skip_min_inlier_ratio: 0.5,
        }
    }
}

/// Huber threshold of a skip edge's length residual, in its standard deviations
/// ([`KeyframeWindow::add_skip_length`]).
const SKIP_HUBER_SIGMAS: f64 = 2.0;

/// One keyframe of the window and the factors to its predecessor.
#[derive(Clone, Debug)]
struct Node {
    id: u32,
    state: FrameState,
    /// Log-scale λ of this keyframe's map (0 unless `map_scale`).
    log_scale: f64,
    /// The IMU frame's turn against the body frame, ψ, rad (0 unless `mount_rotation`).
    mount_rad: Vector3<f64>,
    /// The correction applied to the predecessor's map when this keyframe was started: this
    /// map's λ is expected at the predecessor's minus it.
    scale_correction: f64,
    /// The relative pose to this keyframe was tracked against a map other than the
    /// predecessor's (a stored keyframe's, which also seeds this keyframe's map): it is measured
    /// at this keyframe's λ, and λ is not tied to the predecessor's by the random walk step but
    /// only by `map_scale_initial_std`.
    visual_on_own_map: bool,
    /// This keyframe's map was started anew (a first map rebuilt in flight): its λ is tied to
    /// the predecessor's only by `map_scale_rebuilt_std`, and no relative pose joins them.
    new_map: bool,
    /// IMU from the previous node to this one (linearised at the previous node's bias then).
    imu: Option<Preintegration>,
    /// Relative pose previous → this, from tracking.
    visual: Option<RelativePose>,
    /// Relative pose from the keyframe two back → this (`skip_edges`, read for its length only),
    /// measured on that keyframe's map as it was after the predecessor's correction: at
    /// `λ_{j−2} − c_{j−1}`.
    skip: Option<RelativePose>,
}

/// Gaussian prior on the first `lin.len()` nodes: `E(δ) = ½ δᵀ H δ − gᵀ δ`, `δ = x ⊟ lin` (per
/// node its 15 state rows, then with `map_scale` its λ, then with `mount_rotation` its ψ), then
/// with `gyro_misalignment` φ's 3 rows.
#[derive(Clone, Debug)]
struct Prior {
    h: DMatrix<f64>,
    g: DVector<f64>,
    lin: Vec<FrameState>,
    lin_log_scale: Vec<f64>,
    lin_mount: Vec<Vector3<f64>>,
    lin_phi: Vector3<f64>,
}

/// The window's unknowns: each node's state and map log-scale.
#[derive(Clone, Debug)]
struct Unknowns {
    states: Vec<FrameState>,
    log_scales: Vec<f64>,
    /// Each node's ψ, rad (zero without `mount_rotation`).
    mounts: Vec<Vector3<f64>>,
    /// The gyro's turn φ, rad (zero without `gyro_misalignment`).
    phi: Vector3<f64>,
}

/// What one [`KeyframeWindow::solve`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SolveSummary {
    pub iterations: usize,
    pub cost_before: f64,
    pub cost_after: f64,
}

/// The sliding window of keyframe states.
#[derive(Clone, Debug)]
pub struct KeyframeWindow {
    cfg: WindowConfig,
    noise: ImuNoise,
    nodes: VecDeque<Node>,
    prior: Option<Prior>,
    /// The gyro's turn φ as last solved, rad.
    phi: Vector3<f64>,
    /// Multiplies `cfg.imu_rotation_noise_factor` ([`Self::set_imu_rotation_noise_scale`]).
    rotation_noise_scale: f64,
    /// Keyframes marginalised and not yet taken ([`Self::pop_marginalised_map_scale`]): id,
    /// time and the log-scale of its map as it was left.
    marginalised: VecDeque<(u32, TimeNs, f64)>,
}

/// `x ⊟ lin` in the increment convention of [`FrameState::boxplus`].
pub fn boxminus(x: &FrameState, lin: &FrameState) -> Vector15 {
    let rl = lin.nav.r_world_body.to_rotation_matrix();
    let dr = (rl.inverse() * x.nav.r_world_body.to_rotation_matrix()).into_inner();
    let mut d = Vector15::zeros();
    d.fixed_rows_mut::<3>(0).copy_from(&log_so3(&dr));
    d.fixed_rows_mut::<3>(3)
        .copy_from(&(rl.inverse() * (x.nav.p_world_m - lin.nav.p_world_m)));
    d.fixed_rows_mut::<3>(6)
        .copy_from(&(x.nav.v_world_m_s - lin.nav.v_world_m_s));
    d.fixed_rows_mut::<3>(9)
        .copy_from(&(x.bias.gyro_rad_s - lin.bias.gyro_rad_s));
    d.fixed_rows_mut::<3>(12)
        .copy_from(&(x.bias.accel_m_s2 - lin.bias.accel_m_s2));
    d
}

impl KeyframeWindow {
    /// Multiplies `imu_rotation_noise_factor` by `scale` from now on (the IMU factors are rebuilt
    /// at every solve): the pad's measurement of the gyro (`[bootstrap] rest_gyro_rotation_noise`),
    /// which reaches the keyframe adjustment the same way (`KeyframeJob::rotation_noise_scale`).
    pub fn set_imu_rotation_noise_scale(&mut self, scale: f64) {
        self.rotation_noise_scale = scale;
    }

    pub fn new(cfg: WindowConfig, noise: ImuNoise) -> Self {
        KeyframeWindow {
            cfg,
            noise,
            nodes: VecDeque::new(),
            prior: None,
            phi: Vector3::zeros(),
            rotation_noise_scale: 1.0,
            marginalised: VecDeque::new(),
        }
    }

    /// The gyro's turn against the body frame as the window estimates it, `ω_body = Exp(φ)
    /// ω_gyro`, rad (zero without `gyro_misalignment`).
    pub fn gyro_misalignment_rad(&self) -> Vector3<f64> {
        self.phi
    }

    /// Unknowns shared by the whole window after the nodes: φ's 3 with `gyro_misalignment`.
    fn extra(&self) -> usize {
        if self.cfg.gyro_misalignment { 3 } else { 0 }
    }

    /// Information of φ's prior for a body at attitude `x`: `gyro_misalignment_prior_std_rad`
    /// across its up axis, `gyro_misalignment_up_std_rad` about it.
    fn phi_prior_h(&self, x: &FrameState) -> nalgebra::Matrix3<f64> {
        let u = x.nav.r_world_body.inverse() * Vector3::z();
        let uu = u * u.transpose();
        let across = self.cfg.gyro_misalignment_prior_std_rad.max(1e-6).powi(-2);
        let up = self.cfg.gyro_misalignment_up_std_rad.max(1e-6).powi(-2);
        (nalgebra::Matrix3::identity() - uu) * across + uu * up
    }

    /// φ's information in the window as it stands: the whole system linearised at the current
    /// unknowns with every node's rows Schur-complemented out (`None` with an empty window, without
    /// `gyro_misalignment`, or if the nodes' block is singular).
    fn phi_information(&self) -> Option<nalgebra::Matrix3<f64>> {
        if self.extra() != 3 || self.nodes.is_empty() {
            return None;
        }
        let (h, rhs, _) = self.linearise(&self.unknowns());
        let (marg, _) = schur_complement(&h, &rhs, h.nrows() - 3)?;
        let marg = nalgebra::Matrix3::from_iterator(marg.iter().copied());
        marg.cholesky().map(|_| marg)
    }

    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Unknowns per node: the 15 of the state, λ with `map_scale`, ψ's 3 with `mount_rotation`.
    fn block(&self) -> usize {
        self.mount_row() + if self.cfg.mount_rotation { 3 } else { 0 }
    }

    /// ψ's first row within a node's block (with `mount_rotation`).
    fn mount_row(&self) -> usize {
        if self.cfg.map_scale { 16 } else { 15 }
    }

    /// Information of ψ's prior at a window restart.
    fn mount_prior_information(&self) -> f64 {
        self.cfg.mount_rotation_std_rad.max(1e-6).powi(-2)
    }

    /// The Gauss–Markov step of ψ over `dt_s`: the factor `a` and the step's information.
    fn mount_step(&self, dt_s: f64) -> (f64, f64) {
        let a = (-dt_s.max(0.0) / self.cfg.mount_rotation_time_constant_s.max(1e-6)).exp();
        let var = self.cfg.mount_rotation_std_rad.max(1e-6).powi(2) * (1.0 - a * a).max(1e-6);
        (a, 1.0 / var)
    }

    /// Time and ψ (rad) of the keyframes in the window, oldest first (zero without
    /// `mount_rotation`).
    pub fn mount_rotations(&self) -> impl Iterator<Item = (TimeNs, Vector3<f64>)> + '_ {
        self.nodes.iter().map(|n| (n.state.nav.t, n.mount_rad))
    }

    /// The IMU frame's turn ψ of keyframe `id` against its body frame, rad (zero without
    /// `mount_rotation`), if it is in the window.
    pub fn mount_rotation_rad(&self, id: u32) -> Option<Vector3<f64>> {
        self.nodes.iter().find(|n| n.id == id).map(|n| n.mount_rad)
    }

    /// Restarts the window at keyframe `id` with state `x` and covariance `cov` (bootstrap, or a
    /// re-initialisation after tracking loss); its map's λ starts at 0. φ keeps its estimate, held
    /// by the information the window had on it (`gyro_misalignment_keep_information`, when that
    /// says more than the fresh prior) or by the fresh prior.
    pub fn reset(&mut self, id: u32, x: FrameState, cov: &Matrix15) {
        let h = cov
            .cholesky()
            .map(|c| c.inverse())
            .unwrap_or_else(|| Matrix15::identity() * 1e6);
        let (b, e) = (self.block(), self.extra());
        let mut hp = DMatrix::zeros(b + e, b + e);
        hp.view_mut((0, 0), (15, 15)).copy_from(&h);
        if self.cfg.map_scale {
            hp[(15, 15)] = self.cfg.map_scale_initial_std.max(1e-6).powi(-2);
        }
        if self.cfg.mount_rotation {
            let m = self.mount_row();
            for k in m..m + 3 {
                hp[(k, k)] = self.mount_prior_information();
            }
        }
        if e == 3 {
            let fresh = self.phi_prior_h(&x);
            let kept = if self.cfg.gyro_misalignment_keep_information {
                self.phi_information().filter(|h| h.trace() > fresh.trace())
            } else {
                None
            };
            hp.view_mut((b, b), (3, 3))
                .copy_from(&kept.unwrap_or(fresh));
        }
        self.nodes.clear();
        self.prior = Some(Prior {
            h: hp,
            g: DVector::zeros(b + e),
            lin: vec![x],
            lin_log_scale: vec![0.0],
            lin_mount: vec![Vector3::zeros()],
            lin_phi: self.phi,
        });
        self.nodes.push_back(Node {
            id,
            state: x,
            log_scale: 0.0,
            mount_rad: Vector3::zeros(),
            scale_correction: 0.0,
            visual_on_own_map: false,
            new_map: false,
            imu: None,
            visual: None,
            skip: None,
        });
    }

    /// The state of keyframe `id`, if it is in the window.
    pub fn state(&self, id: u32) -> Option<&FrameState> {
        self.nodes.iter().find(|n| n.id == id).map(|n| &n.state)
    }

    /// The estimated log-scale λ of keyframe `id`'s map (`e^λ` = its size over the metric one;
    /// 0 without `map_scale`), if it is in the window.
    pub fn log_scale(&self, id: u32) -> Option<f64> {
        self.nodes.iter().find(|n| n.id == id).map(|n| n.log_scale)
    }

    /// Time and map log-scale λ of the keyframes in the window, oldest first.
    pub fn log_scales(&self) -> impl Iterator<Item = (TimeNs, f64)> + '_ {
        self.nodes.iter().map(|n| (n.state.nav.t, n.log_scale))
    }

    /// The newest keyframe's relative pose was tracked against a stored keyframe's map, which
    /// seeds the newest's map (a return to a stored keyframe): see `Node::visual_on_own_map`.
    pub fn set_newest_visual_on_own_map(&mut self) {
        if let Some(n) = self.nodes.back_mut() {
            n.visual_on_own_map = true;
        }
    }

    /// The keyframe two back from the newest, as `(id, state)` before a push (`skip_edges`: the
    /// keyframe whose map the next keyframe is aligned against too), if the window has two.
    pub fn second_newest(&self) -> Option<(u32, &FrameState)> {
        let n = self.nodes.len();
        (n >= 2).then(|| (self.nodes[n - 2].id, &self.nodes[n - 2].state))
    }

    /// Joins the newest keyframe to keyframe `from_id` two back by `rel`'s length (`skip_edges`),
    /// if that is the keyframe two back and both steps between them were tracked on the
    /// predecessor's map (not across a return to a stored keyframe or a rebuilt map). Returns
    /// whether it was added.
    pub fn set_newest_skip(&mut self, from_id: u32, rel: RelativePose) -> bool {
        let n = self.nodes.len();
        if !self.cfg.skip_edges || n < 3 || self.nodes[n - 3].id != from_id {
            return false;
        }
        let chained =
            |m: &Node| m.visual.is_some() && !m.visual_on_own_map && !m.new_map && m.imu.is_some();
        if !(chained(&self.nodes[n - 2]) && chained(&self.nodes[n - 1])) {
            return false;
        }
        self.nodes[n - 1].skip = Some(rel);
        true
    }

    /// The map of the newest keyframe's predecessor was scaled by `e^{−c}` when the newest was
    /// started (so the newest's map comes from a corrected one): the random walk between them
    /// expects `λ_newest = λ_prev − c`, and the newest's λ starts there.
    pub fn set_newest_map_correction(&mut self, c: f64) {
        let n = self.nodes.len();
        if n < 2 || !c.is_finite() {
            return;
        }
        let prev = self.nodes[n - 2].log_scale;
        let newest = &mut self.nodes[n - 1];
        newest.scale_correction = c;
        newest.log_scale = prev - c;
    }

    /// The oldest keyframe marginalised since last asked (with `map_scale`): its id, time and
    /// the log-scale of its map as it was left, `λ − c` — λ as the window last solved it, less
    /// the correction `c` its successor was started with ([`Self::set_newest_map_correction`]),
    /// which was applied to the map when it was left.
    pub fn pop_marginalised_map_scale(&mut self) -> Option<(u32, TimeNs, f64)> {
        self.marginalised.pop_front()
    }

    /// Moves keyframe `id`'s state to `x` (adjusted elsewhere); the factors and the prior stay.
    pub fn set_state(&mut self, id: u32, x: &FrameState) {
        if let Some(n) = self.nodes.iter_mut().find(|n| n.id == id) {
            n.state = *x;
        }
    }

    /// Ids and states of the keyframes in the window, oldest first.
    pub fn states(&self) -> impl Iterator<Item = (u32, &FrameState)> + '_ {
        self.nodes.iter().map(|n| (n.id, &n.state))
    }

    /// Moves the whole window by `T_new = c · T_old` (states, and the prior's linearisation
    /// points). For a `c` that turns about the world vertical only, every factor is unchanged —
    /// yaw and position are unobservable by the IMU and the tracked relative poses — so this is
    /// a change of gauge: the window's solution moves with it and nothing else does. (The prior's
    /// velocity rows turn with it: they are in the world frame, the rest in the body frame.)
    pub fn transform_world(&mut self, c: &Isometry3<f64>) {
        let move_state = |x: &mut FrameState| *x = x.moved_by_world(c);
        for n in self.nodes.iter_mut() {
            move_state(&mut n.state);
        }
        let b = self.block();
        if let Some(p) = self.prior.as_mut() {
            p.lin.iter_mut().for_each(move_state);
            // δv' = R δv: H' = T H Tᵀ, g' = T g with T block-diagonal.
            let r = c.rotation.to_rotation_matrix().into_inner();
            let m = p.lin.len();
            let d = p.h.nrows(); // b·m, then φ's rows (body frame: unchanged)
            let mut t = DMatrix::<f64>::identity(d, d);
            for k in 0..m {
                t.view_mut((b * k + 6, b * k + 6), (3, 3)).copy_from(&r);
            }
            p.h = &t * &p.h * t.transpose();
            p.g = &t * &p.g;
        }
    }

    /// The newest keyframe's id and state.
    pub fn newest(&self) -> Option<(u32, &FrameState)> {
        self.nodes.back().map(|n| (n.id, &n.state))
    }

    /// Adds keyframe `id` at state `x` (the tracker's estimate), joined to the newest keyframe by
    /// the IMU preintegrated between them and, if tracked against it, by the relative pose; its
    /// map's λ starts at the newest's. Marginalises the oldest keyframe first if the window is
    /// full. Does nothing on an empty window (call [`KeyframeWindow::reset`] first).
    pub fn push(
        &mut self,
        id: u32,
        x: FrameState,
        imu: Preintegration,
        visual: Option<RelativePose>,
    ) {
        let Some((log_scale, mount_rad, t_prev)) = self
            .nodes
            .back()
            .map(|n| (n.log_scale, n.mount_rad, n.state.nav.t))
        else {
            return;
        };
        // ψ starts at the Gauss–Markov process's prediction.
        let mount_rad = mount_rad * self.mount_step(x.nav.t.secs_since(t_prev)).0;
        while self.nodes.len() >= self.cfg.max_keyframes.max(2) {
            self.marginalise_oldest();
        }
        self.nodes.push_back(Node {
            id,
            state: x,
            log_scale,
            mount_rad,
            scale_correction: 0.0,
            visual_on_own_map: false,
            new_map: false,
            imu: Some(imu),
            visual,
            skip: None,
        });
    }

    /// Adds keyframe `id` at state `x` as the first keyframe of a map started anew after a loss,
    /// joined to the newest by the IMU through the loss only (no relative pose was tracked) and
    /// its λ loosely to the newest's (`map_scale_rebuilt_std`). Nothing is solved: `x` is the
    /// IMU's prediction from the newest already. Does nothing on an empty window.
    pub fn push_new_map(&mut self, id: u32, x: FrameState, imu: Preintegration) {
        if self.nodes.is_empty() {
            return;
        }
        self.push(id, x, imu, None);
        if let Some(n) = self.nodes.back_mut() {
            n.new_map = true;
        }
    }

    fn unknowns(&self) -> Unknowns {
        Unknowns {
            states: self.nodes.iter().map(|n| n.state).collect(),
            log_scales: self.nodes.iter().map(|n| n.log_scale).collect(),
            mounts: self.nodes.iter().map(|n| n.mount_rad).collect(),
            phi: self.phi,
        }
    }

    /// Levenberg-Marquardt on all keyframe states of the window.
    pub fn solve(&mut self) -> SolveSummary {
        let mut x = self.unknowns();
        let (mut h, mut rhs, mut cost) = self.linearise(&x);
        let mut summary = SolveSummary {
            cost_before: cost,
            cost_after: cost,
            ..Default::default()
        };
        let mut lambda = 1e-6;
        let n = x.states.len();
        let b = self.block();
        for _ in 0..self.cfg.max_iterations {
            // With `hold_heading` the step is solved in coordinates whose rotation rows are, per
            // keyframe, two axes across the world vertical and one along it (in the body frame of
            // `boxplus`'s right increment), the vertical one held at zero.
            let basis = self.cfg.hold_heading.then(|| heading_basis(&x.states, b));
            let (mut hd, rhs_s) = match &basis {
                Some(q) => held_heading_system(&h, &rhs, q),
                None => (h.clone(), rhs.clone()),
            };
            for k in 0..hd.nrows() {
                hd[(k, k)] *= 1.0 + lambda;
                hd[(k, k)] += 1e-12;
            }
            let dx = if self.cfg.envelope_factorisation {
                EnvelopeCholesky::factor(&hd).map(|c| c.solve(&rhs_s))
            } else {
                // nalgebra's factorisation and solve to the bit, without its products by zero.
                zero_skipping_cholesky::factor(hd)
                    .map(|l| zero_skipping_cholesky::solve(&l, &rhs_s))
            };
            let dx = match (dx, &basis) {
                (Some(du), Some(q)) => Some(from_heading_basis(du, q)),
                (dx, _) => dx,
            };
            let Some(dx) = dx else {
                lambda *= 10.0;
                continue;
            };
            let cand = Unknowns {
                states: (0..n)
                    .map(|k| {
                        x.states[k]
                            .boxplus(&Vector15::from_iterator(dx.rows(b * k, 15).iter().copied()))
                    })
                    .collect(),
                log_scales: (0..n)
                    .map(|k| {
                        x.log_scales[k]
                            + if self.cfg.map_scale {
                                dx[b * k + 15]
                            } else {
                                0.0
                            }
                    })
                    .collect(),
                mounts: (0..n)
                    .map(|k| {
                        if self.cfg.mount_rotation {
                            let m = b * k + self.mount_row();
                            x.mounts[k] + Vector3::new(dx[m], dx[m + 1], dx[m + 2])
                        } else {
                            x.mounts[k]
                        }
                    })
                    .collect(),
                phi: if self.extra() == 3 {
                    x.phi + Vector3::new(dx[b * n], dx[b * n + 1], dx[b * n + 2])
                } else {
                    x.phi
                },
            };
            let (h2, rhs2, cost2) = self.linearise(&cand);
            summary.iterations += 1;
            if cost2.is_finite() && cost2 <= cost {
                let small = dx.amax() < 1e-9;
                x = cand;
                h = h2;
                rhs = rhs2;
                cost = cost2;
                lambda = (lambda * 0.1).max(1e-9);
                if small {
                    break;
                }
            } else {
                lambda *= 10.0;
                if lambda > 1e6 {
                    break;
                }
            }
        }
        summary.cost_after = cost;
        for (((node, s), l), m) in self
            .nodes
            .iter_mut()
            .zip(x.states)
            .zip(x.log_scales)
            .zip(x.mounts)
        {
            node.state = s;
            node.log_scale = l;
            node.mount_rad = m;
        }
        self.phi = x.phi;
        summary
    }

    /// Normal equations `H Δ = rhs` (rhs = −gradient) and cost at `x`.
    fn linearise(&self, x: &Unknowns) -> (DMatrix<f64>, DVector<f64>, f64) {
        self.linearise_parts(x, x.states.len())
    }

    /// As [`Self::linearise`] with the prior and only the factors of nodes `1..factor_nodes` (each
    /// node holds the factors to its predecessor).
    fn linearise_parts(
        &self,
        x: &Unknowns,
        factor_nodes: usize,
    ) -> (DMatrix<f64>, DVector<f64>, f64) {
        let states = &x.states;
        let n = states.len();
        let (b, e) = (self.block(), self.extra());
        let of = b * n; // φ's rows
        let mut h = DMatrix::zeros(b * n + e, b * n + e);
        let mut rhs = DVector::zeros(b * n + e);
        let mut cost = 0.0;
        if let Some(p) = &self.prior {
            let m = p.lin.len().min(n);
            let mut d = DVector::zeros(b * m + e);
            for (k, (xk, lin)) in states.iter().zip(&p.lin).take(m).enumerate() {
                d.rows_mut(b * k, 15).copy_from(&boxminus(xk, lin));
                if self.cfg.map_scale {
                    d[b * k + 15] = x.log_scales[k] - p.lin_log_scale[k];
                }
                if self.cfg.mount_rotation {
                    d.rows_mut(b * k + self.mount_row(), 3)
                        .copy_from(&(x.mounts[k] - p.lin_mount[k]));
                }
            }
            if e == 3 {
                d.rows_mut(b * m, 3).copy_from(&(x.phi - p.lin_phi));
            }
            let hd = &p.h * &d;
            cost += 0.5 * d.dot(&hd) - p.g.dot(&d);
            let r = &p.g - hd;
            // The prior's rows: its m nodes, then φ, which sits after all n nodes here.
            let at = |k: usize| if k < b * m { k } else { of + k - b * m };
            for c in 0..b * m + e {
                rhs[at(c)] += r[c];
                for q in 0..b * m + e {
                    h[(at(q), at(c))] += p.h[(q, c)];
                }
            }
        }
        for j in 1..factor_nodes.min(n) {
            let i = j - 1;
            let node = &self.nodes[j];
            let (xi, xj) = (&states[i], &states[j]);
            if let Some(pre0) = &node.imu {
                let turned_pre;
                let pre = if e == 3 {
                    turned_pre = turned(pre0, &x.phi);
                    &turned_pre
                } else {
                    pre0
                };
                let mut pre_w = pre.clone();
                pre_w.cov *= self.cfg.imu_noise_scale.powi(2);
                pre_w.scale_rotation_noise(
                    self.cfg.imu_rotation_noise_factor * self.rotation_noise_scale,
                );
                // With `mount_rotation` the factor holds between the IMU frames R Exp(ψ).
                let (xi_m, xj_m) = if self.cfg.mount_rotation {
                    (mounted(xi, &x.mounts[i]), mounted(xj, &x.mounts[j]))
                } else {
                    (*xi, *xj)
                };
                let (xi, xj) = (&xi_m, &xj_m);
                let mut cov =
                    imu_residual_covariance(&pre_w, &self.noise, xi, xj, &Matrix15::zeros());
                for k in 0..15 {
                    cov[(k, k)] += 1e-14;
                }
                let w = cov
                    .cholesky()
                    .map(|c| c.inverse())
                    .unwrap_or_else(|| Matrix15::identity() * 1e12);
                if self.cfg.mount_rotation {
                    let m = imu_jacobians_mounted(
                        pre,
                        &states[i],
                        &states[j],
                        &x.mounts[i],
                        &x.mounts[j],
                    );
                    cost += 0.5 * m.r.dot(&(w * m.r));
                    let mo = self.mount_row();
                    let mut blocks: Vec<(usize, DMatrix<f64>)> = vec![
                        (b * i, DMatrix::from_column_slice(15, 15, m.ji.as_slice())),
                        (b * j, DMatrix::from_column_slice(15, 15, m.jj.as_slice())),
                        (
                            b * i + mo,
                            DMatrix::from_column_slice(15, 3, m.jpsi_i.as_slice()),
                        ),
                        (
                            b * j + mo,
                            DMatrix::from_column_slice(15, 3, m.jpsi_j.as_slice()),
                        ),
                    ];
                    if e == 3 {
                        let jf = d_residual_d_misalignment(pre0, &x.phi, &m.r, xi, xj);
                        blocks.push((of, DMatrix::from_column_slice(15, 3, jf.as_slice())));
                    }
                    add_blocks(&mut h, &mut rhs, &blocks, &w, &m.r);
                } else {
                    let r = imu_residual(pre, xi, xj);
                    let ji = imu_jacobian_i(pre, xi, xj);
                    let jj = imu_jacobian_j(pre, xi, xj);
                    cost += 0.5 * r.dot(&(w * r));
                    add_pair(&mut h, &mut rhs, b * i, b * j, &ji, &jj, &w, &r);
                    if e == 3 {
                        let jf = d_residual_d_misalignment(pre0, &x.phi, &r, xi, xj);
                        add_shared(
                            &mut h,
                            &mut rhs,
                            [b * i, b * j],
                            of,
                            [&ji, &jj],
                            &jf,
                            &w,
                            &r,
                        );
                    }
                }
            }
            if self.cfg.mount_rotation {
                // ψ's Gauss–Markov step from keyframe i to j.
                let dt_s = xj.nav.t.secs_since(xi.nav.t);
                let (a, wm) = self.mount_step(dt_s);
                let mo = self.mount_row();
                let r = x.mounts[j] - x.mounts[i] * a;
                cost += 0.5 * wm * r.norm_squared();
                let (pi, pj) = (b * i + mo, b * j + mo);
                for k in 0..3 {
                    h[(pi + k, pi + k)] += wm * a * a;
                    h[(pj + k, pj + k)] += wm;
                    h[(pi + k, pj + k)] -= wm * a;
                    h[(pj + k, pi + k)] -= wm * a;
                    rhs[pi + k] += wm * a * r[k];
                    rhs[pj + k] -= wm * r[k];
                }
            }
            if let Some(vis) = &node.visual {
                // The relative pose i → j was tracked against keyframe i's map (or, across a
                // return, against the stored map that seeds j's).
                let k_map = if node.visual_on_own_map { j } else { i };
                let lk = x.log_scales[k_map];
                cost += self.add_visual(&mut h, &mut rhs, vis, (i, j, k_map), states, lk);
            }
            if self.cfg.map_scale {
                // The random walk of the map's scale from keyframe i to j.
                let std = if node.new_map {
                    self.cfg.map_scale_rebuilt_std
                } else if node.visual_on_own_map {
                    self.cfg.map_scale_initial_std
                } else {
                    self.cfg.map_scale_step_std
                };
                let w = std.max(1e-6).powi(-2);
                let r = x.log_scales[j] - x.log_scales[i] + node.scale_correction;
                let (li, lj) = (b * i + 15, b * j + 15);
                cost += 0.5 * w * r * r;
                h[(li, li)] += w;
                h[(lj, lj)] += w;
                h[(li, lj)] -= w;
                h[(lj, li)] -= w;
                rhs[li] += w * r;
                rhs[lj] -= w * r;
            }
        }
        // Skip edges (`skip_edges`): node j's relative pose from node j − 2, on j − 2's map as
        // corrected when j − 1 was started. (When marginalising, `factor_nodes` = 2: only the
        // one of node 2 touches node 0.)
        for j in 2..(factor_nodes + 1).min(n) {
            let node = &self.nodes[j];
            if let Some(vis) = &node.skip {
                let i = j - 2;
                let lk = x.log_scales[i] - self.nodes[i + 1].scale_correction;
                cost += self.add_skip_length(&mut h, &mut rhs, vis, (i, j), states, lk);
            }
        }
        (h, rhs, cost)
    }

    /// Adds skip edge `vis` from node `i` to node `j` as its length only
    /// ([`RelativePose::length_residual_scaled`] at log-scale `lk` of node `i`'s map): one row,
    /// weighed by the tempered translation variance of the alignment along the baseline
    /// ([`Self::visual_weight`]), Huber beyond [`SKIP_HUBER_SIGMAS`]; returns its cost. The
    /// edge's direction and rotation are left out: as a whole relative pose it doubled vision's
    /// weight in the window and its far-off alignments in fast turns ran flights away
    /// (docs/odometry-log.md, session 88).
    fn add_skip_length(
        &self,
        h: &mut DMatrix<f64>,
        rhs: &mut DVector<f64>,
        vis: &RelativePose,
        (i, j): (usize, usize),
        states: &[FrameState],
        lk: f64,
    ) -> f64 {
        let b = self.block();
        let (xi, xj) = (&states[i], &states[j]);
        let (ji, jj, jl) = vis.length_jacobians_scaled(xi, xj);
        if jl == 0.0 {
            return 0.0;
        }
        let Some(cov) = self.visual_weight(&vis.information).try_inverse() else {
            return 0.0;
        };
        // The baseline's direction in frame j's body (the information is on its increment).
        let d = xj.nav.p_world_m - xi.nav.p_world_m;
        let u = xj.nav.r_world_body.inverse() * d.normalize();
        let ctt: Matrix3<f64> = cov.fixed_view::<3, 3>(3, 3).into_owned();
        let var_m2 = u.dot(&(ctt * u));
        if !(var_m2.is_finite() && var_m2 > 0.0) {
            return 0.0;
        }
        let t_m = vis.t_i_j.translation.vector.norm();
        let r = SVector::<f64, 1>::new(vis.length_residual_scaled(xi, xj, lk));
        let mut w = SMatrix::<f64, 1, 1>::new(t_m * t_m / var_m2);
        let (cost, f) = huber(r[0] * r[0] * w[(0, 0)], SKIP_HUBER_SIGMAS);
        w *= f;
        add_pair(h, rhs, b * i, b * j, &ji, &jj, &w, &r);
        if self.cfg.map_scale {
            let jl = SVector::<f64, 1>::new(jl);
            add_scale_column(h, rhs, (b * i, b * j, b * i + 15), (&ji, &jj, &jl), &w, &r);
        }
        cost
    }

    /// Adds relative pose `vis` between nodes `i` and `j`, measured on node `k_map`'s map at
    /// log-scale `lk`, to `h` and `rhs` (Huber-weighted, tempered by [`Self::visual_weight`]);
    /// returns its cost.
    fn add_visual(
        &self,
        h: &mut DMatrix<f64>,
        rhs: &mut DVector<f64>,
        vis: &RelativePose,
        (i, j, k_map): (usize, usize, usize),
        states: &[FrameState],
        lk: f64,
    ) -> f64 {
        let b = self.block();
        let (xi, xj) = (&states[i], &states[j]);
        let mut w = self.visual_weight(&vis.information);
        let r = vis.residual_scaled(xi, xj, lk);
        let (ji, jj, jl) = vis.jacobians_scaled(xi, xj, lk);
        let (cost, f) = huber(r.dot(&(w * r)), self.cfg.visual_huber_sigmas);
        w *= f;
        add_pair(h, rhs, b * i, b * j, &ji, &jj, &w, &r);
        if self.cfg.map_scale {
            add_scale_column(
                h,
                rhs,
                (b * i, b * j, b * k_map + 15),
                (&ji, &jj, &jl),
                &w,
                &r,
            );
        }
        cost
    }

    /// `S H S` with `S` = √scale of the rotation and translation rows.
    fn visual_weight(&self, h: &nalgebra::Matrix6<f64>) -> nalgebra::Matrix6<f64> {
        let (sr, st) = (
            self.cfg.visual_rotation_information_scale.max(0.0).sqrt(),
            self.cfg
                .visual_translation_information_scale
                .max(0.0)
                .sqrt(),
        );
        let s = nalgebra::Vector6::new(sr, sr, sr, st, st, st);
        h.component_mul(&(s * s.transpose()))
    }

    /// Schur-complements the oldest node out of the system linearised at the current states; the
    /// result is the prior on the remaining nodes (at their current states).
    fn marginalise_oldest(&mut self) {
        let x = self.unknowns();
        let n = x.states.len();
        if n < 2 {
            return;
        }
        let (b, e) = (self.block(), self.extra());
        if self.cfg.map_scale {
            let left = self.nodes[0].log_scale - self.nodes[1].scale_correction;
            // Bounded: a consumer that never asks keeps only the latest few.
            if self.marginalised.len() >= 4 {
                self.marginalised.pop_front();
            }
            let n = &self.nodes[0];
            self.marginalised.push_back((n.id, n.state.nav.t, left));
        }
        // The prior and the factors touching node 0 (those between nodes 0 and 1); the factors
        // among the others stay factors. φ is kept (it comes last).
        let (h, rhs, _) = self.linearise_parts(&x, 2);
        let Some((hp, gp)) = schur_complement(&h, &rhs, b) else {
            // Degenerate: drop the node without information (φ keeps a prior about its value).
            self.nodes.pop_front();
            if let Some(n1) = self.nodes.get_mut(1) {
                n1.skip = None;
            }
            self.prior = (e == 3).then(|| Prior {
                h: DMatrix::from_column_slice(3, 3, self.phi_prior_h(&x.states[1]).as_slice()),
                g: DVector::zeros(3),
                lin: Vec::new(),
                lin_log_scale: Vec::new(),
                lin_mount: Vec::new(),
                lin_phi: x.phi,
            });
            return;
        };
        self.nodes.pop_front();
        self.nodes[0].imu = None;
        self.nodes[0].visual = None;
        self.nodes[0].skip = None;
        if let Some(n1) = self.nodes.get_mut(1) {
            n1.skip = None;
        }
        self.prior = Some(Prior {
            h: hp,
            g: gp,
            lin: x.states[1..].to_vec(),
            lin_log_scale: x.log_scales[1..].to_vec(),
            lin_mount: x.mounts[1..].to_vec(),
            lin_phi: x.phi,
        });
    }
}

/// For `hold_heading`: an orthonormal change of the step's coordinates, `δ = Q u`, identity but
/// for each keyframe's rotation rows (at `b · k`), which it turns by the returned `T_k`: with the
/// right increment of [`FrameState::boxplus`] a keyframe at `R` turns about the world vertical by
/// `(Rᵀ e_z)ᵀ δθ`, so `T_k`'s third column is `Rᵀ e_z` and its first two complete it. The third
/// coordinate of each is the one held.
fn heading_basis(states: &[FrameState], b: usize) -> Vec<(usize, Matrix3<f64>)> {
    states
        .iter()
        .enumerate()
        .map(|(k, x)| {
            let up = x.nav.r_world_body.inverse() * Vector3::z();
            // Any axis not along `up` starts the completion.
            let seed = if up.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            let a1 = (seed - up * up.dot(&seed)).normalize();
            let a2 = up.cross(&a1);
            (b * k, Matrix3::from_columns(&[a1, a2, up]))
        })
        .collect()
}

/// `Qᵀ H Q` and `Qᵀ rhs` for the `Q` of [`heading_basis`], with each held coordinate's row and
/// column cleared (a unit diagonal and a zero right-hand side, so its step is zero).
fn held_heading_system(
    h: &DMatrix<f64>,
    rhs: &DVector<f64>,
    basis: &[(usize, Matrix3<f64>)],
) -> (DMatrix<f64>, DVector<f64>) {
    let (mut hq, mut rq) = (h.clone(), rhs.clone());
    for (r, t) in basis {
        let cols = hq.fixed_columns::<3>(*r) * t;
        hq.fixed_columns_mut::<3>(*r).copy_from(&cols);
    }
    for (r, t) in basis {
        let rows = t.transpose() * hq.fixed_rows::<3>(*r);
        hq.fixed_rows_mut::<3>(*r).copy_from(&rows);
        let v: Vector3<f64> = t.transpose() * rq.fixed_rows::<3>(*r);
        rq.fixed_rows_mut::<3>(*r).copy_from(&v);
    }
    for (r, _) in basis {
        let i = r + 2;
        hq.row_mut(i).fill(0.0);
        hq.column_mut(i).fill(0.0);
        hq[(i, i)] = 1.0;
        rq[i] = 0.0;
    }
    (hq, rq)
}

/// `Q u` for the `Q` of [`heading_basis`].
fn from_heading_basis(mut u: DVector<f64>, basis: &[(usize, Matrix3<f64>)]) -> DVector<f64> {
    for (r, t) in basis {
        let v: Vector3<f64> = t * u.fixed_rows::<3>(*r);
        u.fixed_rows_mut::<3>(*r).copy_from(&v);
    }
    u
}

/// Schur-complements the first `m` unknowns out of the system `(h, rhs)`: the information
/// (symmetrised) and right-hand side left on the others. `None` if the `m` block, regularised by
/// 1e-9 on its diagonal, is not positive definite.
fn schur_complement(
    h: &DMatrix<f64>,
    rhs: &DVector<f64>,
    m: usize,
) -> Option<(DMatrix<f64>, DVector<f64>)> {
    let r = h.nrows() - m;
    let mut hmm = h.view((0, 0), (m, m)).into_owned();
    for k in 0..m {
        hmm[(k, k)] += 1e-9;
    }
    let chol = hmm.cholesky()?;
    let hmr = h.view((0, m), (m, r));
    let mut hp = h.view((m, m), (r, r)) - hmr.transpose() * chol.solve(&hmr.into_owned());
    hp = (&hp + hp.transpose()) * 0.5;
    let gp = rhs.rows(m, r) - hmr.transpose() * chol.solve(&rhs.rows(0, m).into_owned());
    Some((hp, gp))
}

/// Adds a factor whose Jacobian is split into column blocks at the given offsets of the system
/// (`JᵀWJ` block by block, `−JᵀWr`).
fn add_blocks(
    h: &mut DMatrix<f64>,
    rhs: &mut DVector<f64>,
    blocks: &[(usize, DMatrix<f64>)],
    w: &Matrix15,
    r: &Vector15,
) {
    let wr = DVector::from_column_slice((w * r).as_slice());
    let w = DMatrix::from_column_slice(15, 15, w.as_slice());
    for (oa, ja) in blocks {
        let wja = &w * ja;
        for (ob, jb) in blocks {
            h.view_mut((*ob, *oa), (jb.ncols(), ja.ncols()))
                .add_assign(&(jb.transpose() * &wja));
        }
        let g = ja.transpose() * &wr;
        rhs.rows_mut(*oa, ja.ncols()).add_assign(&(-g));
    }
}

#[allow(clippy::too_many_arguments)]
/// Adds the columns of a factor's unknown shared by the window (at offset `of`, `C` wide) to
/// the system [`add_pair`] built for its two states (offsets `os`, Jacobians `js`).
fn add_shared<const R: usize, const C: usize>(
    h: &mut DMatrix<f64>,
    rhs: &mut DVector<f64>,
    os: [usize; 2],
    of: usize,
    js: [&SMatrix<f64, R, 15>; 2],
    jf: &SMatrix<f64, R, C>,
    w: &SMatrix<f64, R, R>,
    r: &SVector<f64, R>,
) {
    let wjf = w * jf;
    h.view_mut((of, of), (C, C))
        .add_assign(&(jf.transpose() * wjf));
    for (o, j) in os.into_iter().zip(js) {
        let hsf = j.transpose() * wjf;
        h.view_mut((o, of), (15, C)).add_assign(&hsf);
        h.view_mut((of, o), (C, 15)).add_assign(&hsf.transpose());
    }
    rhs.rows_mut(of, C)
        .add_assign(&(-(jf.transpose() * (w * r))));
}

#[allow(clippy::too_many_arguments)]
/// Adds a factor between the unknowns at offsets `oi` and `oj` (each a 15-state block).
fn add_pair<const R: usize>(
    h: &mut DMatrix<f64>,
    rhs: &mut DVector<f64>,
    oi: usize,
    oj: usize,
    ji: &nalgebra::SMatrix<f64, R, 15>,
    jj: &nalgebra::SMatrix<f64, R, 15>,
    w: &nalgebra::SMatrix<f64, R, R>,
    r: &nalgebra::SVector<f64, R>,
) {
    let wji = w * ji;
    let wjj = w * jj;
    let wr = w * r;
    h.view_mut((oi, oi), (15, 15))
        .add_assign(&(ji.transpose() * wji));
    h.view_mut((oj, oj), (15, 15))
        .add_assign(&(jj.transpose() * wjj));
    let hij = ji.transpose() * wjj;
    h.view_mut((oi, oj), (15, 15)).add_assign(&hij);
    h.view_mut((oj, oi), (15, 15)).add_assign(&hij.transpose());
    rhs.rows_mut(oi, 15).add_assign(&(-(ji.transpose() * wr)));
    rhs.rows_mut(oj, 15).add_assign(&(-(jj.transpose() * wr)));
}

/// Huber on a factor's squared Mahalanobis norm `s` with threshold `k` sigmas (0 = none): its
/// cost and the factor its weight is multiplied by (IRLS weight `k/‖r‖` beyond `k`, else 1).
fn huber(s: f64, k: f64) -> (f64, f64) {
    if k > 0.0 && s > k * k {
        let norm = s.sqrt();
        (0.5 * (2.0 * k * norm - k * k), k / norm)
    } else {
        (0.5 * s, 1.0)
    }
}

/// The map log-scale λ's column (row `ol`) of a factor between the states at rows `oi` and `oj`
/// (Jacobians `ji`, `jj`, `jl` w.r.t. them and λ, weight `w`, residual `r`), added to `h` and
/// `rhs` beside what [`add_pair`] adds for the states.
fn add_scale_column<const R: usize>(
    h: &mut DMatrix<f64>,
    rhs: &mut DVector<f64>,
    (oi, oj, ol): (usize, usize, usize),
    (ji, jj, jl): (
        &nalgebra::SMatrix<f64, R, 15>,
        &nalgebra::SMatrix<f64, R, 15>,
        &SVector<f64, R>,
    ),
    w: &nalgebra::SMatrix<f64, R, R>,
    r: &SVector<f64, R>,
) {
    let wl = w * jl;
    h[(ol, ol)] += jl.dot(&wl);
    let hli = ji.transpose() * wl;
    let hlj = jj.transpose() * wl;
    for c in 0..15 {
        h[(oi + c, ol)] += hli[c];
        h[(ol, oi + c)] += hli[c];
        h[(oj + c, ol)] += hlj[c];
        h[(ol, oj + c)] += hlj[c];
    }
    rhs[ol] -= wl.dot(r);
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    /// The held step is the minimiser of `½ δᵀ H δ − rhsᵀ δ` among the steps that turn no
    /// keyframe about the world vertical: checked against the same system with that turn
    /// penalised by a weight far above `H`'s.
    #[test]
    fn the_held_step_is_the_constrained_minimiser() {
        let b = 16;
        let states: Vec<FrameState> = [(0.3, -0.2, 1.0), (-0.1, 0.4, -2.0)]
            .iter()
            .map(|&(x, y, z)| FrameState {
                nav: crate::imu::NavState {
                    t: TimeNs(0),
                    r_world_body: UnitQuaternion::from_scaled_axis(Vector3::new(x, y, z)),
                    p_world_m: Vector3::zeros(),
                    v_world_m_s: Vector3::zeros(),
                },
                bias: Default::default(),
            })
            .collect();
        let n = b * states.len() + 3;
        let a = DMatrix::<f64>::from_fn(n, n, |i, j| ((i * 7 + j * 13) % 11) as f64 - 5.0);
        let h = &a * a.transpose() + DMatrix::<f64>::identity(n, n);
        let rhs = DVector::<f64>::from_fn(n, |i, _| ((i * 5) % 7) as f64 - 3.0);

        let basis = heading_basis(&states, b);
        let (hq, rq) = held_heading_system(&h, &rhs, &basis);
        let held = from_heading_basis(hq.cholesky().unwrap().solve(&rq), &basis);

        let mut penalised = h.clone();
        for (k, x) in states.iter().enumerate() {
            let up = x.nav.r_world_body.inverse() * Vector3::z();
            let mut v = DVector::<f64>::zeros(n);
            v.fixed_rows_mut::<3>(b * k).copy_from(&up);
            penalised += 1e9 * &v * v.transpose();
            // The held step turns the keyframe about the vertical by nothing.
            let turn = up.dot(&held.fixed_rows::<3>(b * k));
            assert!(turn.abs() < 1e-12, "keyframe {k} turned by {turn}");
        }
        let reference = penalised.cholesky().unwrap().solve(&rhs);
        let err = (&held - &reference).amax() / reference.amax();
        assert!(err < 1e-6, "relative difference {err}");
    }
}
