//! The tracking thread's estimator (section III-C): per frame, one Gauss-Newton problem over the
//! photometric residual against the keyframe (eq. 23) and the IMU residual against the previous
//! frame (eq. 13), coarse to fine, solved with the Schur complement (eq. 16–22) and seeded by the
//! IMU prediction (eq. 1–6).
//!
//! # State and blocks
//! The unknowns are frame j's 15-state of eq. 11 plus the affine brightness `(α, β)`. The pose
//! block `P` of eq. 20 is `[δθ, δt, δα, δβ]` (8; photometric and IMU residuals), the IMU block `I`
//! is `[δv, δb_ω, δb_a]` (9; IMU residual only, `J_I^{r_ph} = 0`). Frame i is fixed (section
//! III-A) but not certain: its covariance enters the IMU residual's weight through
//! [`crate::imu::imu_residual_covariance`], which makes each frame's solution the exact
//! marginalisation of frame i (velocity is corrected through its correlation with position).
//!
//! # From the inverse-compositional increment to the body increment
//! The photometric Jacobian is precomputed for the keyframe-side increment `ε` (eq. 24–26). The
//! body increment `δ = [δθ, δt]` (`T_wb ← T_wb (Exp δθ, δt)`) moves the current camera as the IC
//! update `T_ck ← T_ck exp(ε)⁻¹` does when `ε = Ad(T_kb) δ`, with `T_kb` the current estimate of
//! the body in the keyframe camera frame. Hence `J_P^{r_ph} = J_ε Ad(T_kb)`, and the 8x8 IC system
//! is carried to the body increment as `Adᵀ H Ad`, `Adᵀ b` — the per-point work stays that of the
//! inverse-compositional method.

use super::config::{NUM_LEVELS, TrackerConfig};
use super::keyframe::Keyframe;
use super::photometric::{
    PhotometricCost, PhotometricSystem, RobustCost, WeightedResidual, normal_equations_of,
    residuals,
};
use super::schur::BlockSystem;
use crate::camera::CameraModel;
use crate::geometry::{adjoint, exp_so3};
use crate::image::{Image, Pyramid, textured_fraction};
use crate::imu::residual::block;
use crate::imu::{
    FrameState, ImuNoise, Matrix15, Preintegration, Vector15, imu_jacobian_j, imu_residual,
    imu_residual_covariance,
};
use crate::time::TimeNs;
use nalgebra::{Isometry3, Matrix3, Matrix6, SMatrix, SVector, Vector6};
use std::time::Instant;

/// Pyramid level whose texture decides whether a frame can be aligned (`min_textured_fraction`):
/// a quarter of the resolution, where sensor noise is averaged out.
const TEXTURE_LEVEL: usize = 2;

/// Why a frame's visual-inertial solution was not trusted. The frame's state is then the IMU
/// prediction (with the IMU-only covariance), never the rejected solution.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlagReason {
    /// No keyframe to track against (vision is waiting for a map).
    NoKeyframe,
    /// The normal equations were not positive definite.
    SolverFailed,
    /// The solution or its cost was not finite.
    NonFinite,
    /// Too few photometric inliers (occlusion, covered lens, lost track).
    FewInliers,
    /// The solution contradicts the IMU prediction beyond `max_imu_chi2`.
    ImuInconsistent,
    /// The frame has too little texture to be aligned (`min_textured_fraction`: a covered lens,
    /// a blinded or dark sensor); it was predicted by the IMU alone.
    NoTexture,
}

impl FlagReason {
    pub fn as_str(self) -> &'static str {
        match self {
            FlagReason::NoKeyframe => "no_keyframe",
            FlagReason::SolverFailed => "solver_failed",
            FlagReason::NonFinite => "non_finite",
            FlagReason::FewInliers => "few_inliers",
            FlagReason::ImuInconsistent => "imu_inconsistent",
            FlagReason::NoTexture => "no_texture",
        }
    }
}

/// Everything the tracker knows about one frame.
#[derive(Clone, Debug)]
pub struct TrackResult {
    pub t: TimeNs,
    /// Frame j's 15-state (pose of the body in the world, velocity, biases).
    pub state: FrameState,
    /// Covariance of `state` in the increment order of eq. 11 `[δθ, δt, δv, δb_ω, δb_a]`
    /// (rotation and translation increments in the body frame), from the final Hessian with the
    /// brightness parameters marginalised.
    pub covariance: Matrix15,
    /// Affine brightness relative to the keyframe: `I_j ≈ e^log_gain I_i + offset_gray`.
    pub log_gain: f64,
    pub offset_gray: f64,
    /// `Some` if the visual-inertial solution was rejected (state = IMU prediction).
    pub flag: Option<FlagReason>,
    /// Accepted Gauss-Newton iterations per level (index 0 = full resolution).
    pub iterations: [u8; NUM_LEVELS],
    /// Level-0 keyframe points that are inliers in this frame / all level-0 points.
    pub inlier_ratio: f64,
    /// Level-0 keyframe points that project into this frame / all.
    pub overlap: f64,
    /// RMS of the level-0 inlier residuals, gray levels.
    pub residual_rms_gray: f64,
    /// `rᵀ A r` of the IMU residual at the solution (15 dof).
    pub imu_chi2: f64,
    /// The solution was solved again with the photometric term down-weighted because its IMU
    /// residual's χ² exceeded `vision_downweight_chi2` (`imu_chi2`, `photometric_info` and
    /// `photometric_step` are then those of the down-weighted solution).
    pub downweighted: bool,
    /// Information of the photometric term alone on frame j's pose increment `[δθ, δt]` (body
    /// frame, eq. 34/36) relative to the keyframe, brightness marginalised; zero if untracked.
    /// The keyframe window uses it for the relative pose keyframe → frame.
    pub photometric_info: Matrix6<f64>,
    /// The Gauss–Newton step of the photometric term alone from `state` (`[δθ, δt]` in the body
    /// frame as `FrameState::boxplus`, brightness free): where the keyframe's points alone would
    /// move the pose, i.e. the IMU's pull on the joint solution undone to first order. At the
    /// joint optimum the photometric gradient balances the IMU's (eq. 16), so this is
    /// `H_ph⁻¹ b_ph` at full resolution. Zero if untracked or singular.
    pub photometric_step: Vector6<f64>,
    /// Keyframe tracked against.
    pub keyframe_id: Option<u32>,
    /// The keyframe policy asks for a new keyframe at this frame.
    pub wants_keyframe: bool,
    /// Set by the odometry: `|v − v_IMU|`, the velocity against the IMU integrated from the
    /// keyframe window's newest keyframe (`[tracking] keyframe_max_velocity_divergence_m_s`),
    /// m/s; `None` where not read.
    pub imu_velocity_divergence_m_s: Option<f64>,
    /// Wall time spent in [`Tracker::track`], s.
    pub time_s: f64,
}

/// One evaluation of the joint problem at a state.
struct Evaluation {
    sys: BlockSystem<8, 9>,
    /// The photometric part of `sys.h_pp` (with the brightness prior).
    h_ph: SMatrix<f64, 8, 8>,
    /// The photometric part of `sys.b_p` (with the brightness prior).
    b_ph: SVector<f64, 8>,
    cost: f64,
    ph: Option<PhotometricSystem>,
    r_imu: Vector15,
}

/// The frame-rate visual-inertial tracker. Buffers (current pyramid, residual scratch) are
/// allocated once; [`Tracker::track`] does not allocate.
pub struct Tracker {
    cfg: TrackerConfig,
    cameras: Vec<CameraModel>,
    t_body_cam: Isometry3<f64>,
    noise: ImuNoise,
    frame: Pyramid,
    /// `frame` was handed over ([`Tracker::swap_frame_pyramid`]) and holds no frame until the
    /// next is loaded.
    frame_handed_over: bool,
    keyframe: Option<Keyframe>,
    state: FrameState,
    cov: Matrix15,
    log_gain: f64,
    offset_gray: f64,
    /// The last tracked frame was solved with vision down-weighted (`vision_downweight_chi2`).
    last_downweighted: bool,
    /// `|r|` of the last residual pass (for the noise scale).
    scratch: Vec<f32>,
    /// Inliers of the last residual pass (for its normal equations).
    inliers: Vec<WeightedResidual>,
}

impl Tracker {
    /// A tracker at `state` with covariance `cov` (eq. 11 increment order).
    pub fn new(
        cfg: TrackerConfig,
        camera: &CameraModel,
        t_body_cam: Isometry3<f64>,
        noise: ImuNoise,
        state: FrameState,
        cov: Matrix15,
    ) -> Self {
        let cameras = (0..NUM_LEVELS)
            .map(|l| camera.scaled_to_level(l as u32))
            .collect();
        let max_pts = cfg.max_points_per_level.iter().copied().max().unwrap_or(0);
        Tracker {
            frame: Pyramid::new(camera.width, camera.height, NUM_LEVELS),
            frame_handed_over: false,
            cfg,
            cameras,
            t_body_cam,
            noise,
            keyframe: None,
            state,
            cov,
            log_gain: 0.0,
            offset_gray: 0.0,
            last_downweighted: false,
            scratch: Vec::with_capacity(max_pts),
            inliers: Vec::with_capacity(max_pts),
        }
    }

    pub fn config(&self) -> &TrackerConfig {
        &self.cfg
    }
    pub fn state(&self) -> &FrameState {
        &self.state
    }
    pub fn covariance(&self) -> &Matrix15 {
        &self.cov
    }
    pub fn keyframe(&self) -> Option<&Keyframe> {
        self.keyframe.as_ref()
    }
    /// The pyramid of the last frame given to [`Tracker::track`] or [`Tracker::load_frame`],
    /// with its gradients (computed here on first use: tracking itself needs none of the
    /// current frame's).
    pub fn frame_pyramid(&mut self) -> &Pyramid {
        debug_assert!(
            !self.frame_handed_over,
            "Tracker::frame_pyramid after swap_frame_pyramid and before the next frame"
        );
        self.frame.ensure_gradients();
        &self.frame
    }

    /// Hands the pyramid of the last frame over (its gradients perhaps not computed yet:
    /// [`Pyramid::ensure_gradients`]) for a keyframe built on another thread, and keeps `buffer`
    /// for the next frame to be loaded into: the frame changes hands without a copy on the
    /// tracking thread. [`Tracker::frame_pyramid`] has no frame until the next one is loaded. A
    /// `buffer` of another size than the frame's is dropped and a copy is handed over instead.
    pub fn swap_frame_pyramid(&mut self, buffer: Pyramid) -> Pyramid {
        let same_size = buffer.num_levels() == self.frame.num_levels()
            && (0..buffer.num_levels()).all(|l| {
                let (a, b) = (buffer.level(l), self.frame.level(l));
                (a.width(), a.height()) == (b.width(), b.height())
            });
        if !same_size {
            return self.frame.clone();
        }
        self.frame_handed_over = true;
        std::mem::replace(&mut self.frame, buffer)
    }
    /// Camera pose of the current state, `T_wb · T_bc`.
    pub fn t_world_cam(&self) -> Isometry3<f64> {
        pose_of(&self.state) * self.t_body_cam
    }

    /// A result for frame `t` that was not tracked: the current state and covariance, no
    /// photometric figures.
    pub fn untracked_result(&self, t: TimeNs) -> TrackResult {
        TrackResult {
            t,
            state: self.state,
            covariance: self.cov,
            log_gain: self.log_gain,
            offset_gray: self.offset_gray,
            flag: None,
            iterations: [0; NUM_LEVELS],
            inlier_ratio: 0.0,
            overlap: 0.0,
            residual_rms_gray: f64::NAN,
            imu_chi2: 0.0,
            downweighted: false,
            photometric_info: Matrix6::zeros(),
            photometric_step: Vector6::zeros(),
            keyframe_id: self.keyframe.as_ref().map(|k| k.id),
            wants_keyframe: false,
            imu_velocity_divergence_m_s: None,
            time_s: 0.0,
        }
    }

    /// Loads an image as the current frame without tracking it (the first frame).
    pub fn load_frame(&mut self, image: &Image<u8>) {
        self.frame.fill_from_u8(image);
        self.frame_handed_over = false;
    }

    /// Replaces the state (start-up, re-initialisation).
    pub fn reset_state(&mut self, state: FrameState, cov: Matrix15) {
        self.state = state;
        self.cov = cov;
    }

    /// Makes `kf` the keyframe tracked against and returns the previous one; brightness is then
    /// relative to it (a refreshed map of the same keyframe keeps the brightness estimate).
    pub fn set_keyframe(&mut self, kf: Keyframe) -> Option<Keyframe> {
        if self.keyframe.as_ref().map(|k| k.id) != Some(kf.id) {
            self.log_gain = 0.0;
            self.offset_gray = 0.0;
        }
        self.keyframe.replace(kf)
    }

    /// The affine brightness of the current frame relative to the keyframe tracked against:
    /// `(log_gain, offset_gray)`, `I_j ≈ e^log_gain I_i + offset_gray`.
    pub fn brightness(&self) -> (f64, f64) {
        (self.log_gain, self.offset_gray)
    }

    /// Restores a brightness of [`Self::brightness`] (back on a keyframe tracked before, whose
    /// estimate `set_keyframe` reset).
    pub fn set_brightness(&mut self, (log_gain, offset_gray): (f64, f64)) {
        self.log_gain = log_gain;
        self.offset_gray = offset_gray;
    }

    /// Moves the keyframe tracked against to `t_world_cam` (the keyframe window corrected it).
    pub fn set_keyframe_pose(&mut self, t_world_cam: Isometry3<f64>) {
        if let Some(kf) = &mut self.keyframe {
            kf.t_world_cam = t_world_cam;
        }
    }

    /// Multiplies the depths of the keyframe tracked against by `factor` about its camera (see
    /// [`Keyframe::scale_depths`]).
    pub fn scale_keyframe_depths(&mut self, factor: f64) {
        if let Some(kf) = &mut self.keyframe {
            kf.scale_depths(factor);
        }
    }

    /// Drops the keyframe (tracking loss): frames are IMU-only until a new one is set.
    pub fn clear_keyframe(&mut self) {
        self.keyframe = None;
    }

    /// Tracks frame j at `t`, given the IMU preintegrated from the previous frame
    /// (`pre.t_start` = previous frame, linearised at the current bias estimate).
    pub fn track(&mut self, t: TimeNs, image: &Image<u8>, pre: &Preintegration) -> TrackResult {
        let started = Instant::now();
        self.frame.fill_levels_from_u8(image);
        self.frame_handed_over = false;
        let xi = self.state;
        let x_pred = FrameState {
            nav: pre.predict(&xi.nav, &xi.bias),
            bias: xi.bias,
        };
        // White-noise part inflated by `imu_noise_scale` (covariance ∝ density²).
        let mut pre_w = pre.clone();
        pre_w.cov *= self.cfg.imu_noise_scale.powi(2);
        let mut cov_r = imu_residual_covariance(&pre_w, &self.noise, &xi, &x_pred, &self.cov);
        for k in 0..15 {
            cov_r[(k, k)] += 1e-14; // a zero-length interval has no noise at all
        }
        let a_imu = cov_r
            .cholesky()
            .map(|c| c.inverse())
            .unwrap_or_else(|| Matrix15::identity() * 1e12);
        let mut res = TrackResult {
            state: x_pred,
            ..self.untracked_result(t)
        };

        let outcome = if !self.cfg.use_vision {
            None
        } else if self.keyframe.is_none() {
            res.flag = Some(FlagReason::NoKeyframe);
            None
        } else if self.untextured() {
            res.flag = Some(FlagReason::NoTexture);
            None
        } else {
            self.solve_visual_inertial(pre, &xi, &x_pred, &a_imu, &mut res)
        };
        match outcome {
            Some((x, cov, lg, off)) => {
                res.state = x;
                res.covariance = cov;
                res.log_gain = lg;
                res.offset_gray = off;
            }
            None => {
                // IMU only: the prediction, with the covariance of the IMU-only solution.
                let eval = self.evaluate(None, pre, &xi, &x_pred, &a_imu, (0.0, 0.0), 1.0);
                res.state = x_pred;
                res.covariance = marginal_covariance(&eval.sys).unwrap_or(cov_r);
            }
        }
        self.state = res.state;
        self.cov = res.covariance;
        self.log_gain = res.log_gain;
        self.offset_gray = res.offset_gray;
        self.last_downweighted = res.downweighted;
        res.wants_keyframe = self.wants_keyframe(
            &res,
            self.cfg.keyframe_max_baseline_ratio,
            self.cfg.keyframe_max_rotation_rad,
            self.cfg.keyframe_max_age_s,
        );
        res.time_s = started.elapsed().as_secs_f64();
        res
    }

    /// The keyframe tracked is older than `max_age_s` at time `t` (`false` for 0 = no limit, or
    /// without a keyframe): the age rule of [`Self::wants_keyframe`].
    pub fn keyframe_older_than(&self, t: TimeNs, max_age_s: f64) -> bool {
        max_age_s > 0.0
            && self
                .keyframe
                .as_ref()
                .is_some_and(|kf| t.secs_since(kf.t) > max_age_s)
    }

    /// The current frame has too little texture to be aligned (`min_textured_fraction`).
    fn untextured(&self) -> bool {
        let level = self
            .frame
            .level(TEXTURE_LEVEL.min(self.frame.num_levels() - 1));
        self.cfg.min_textured_fraction > 0.0
            && f64::from(textured_fraction(level, self.cfg.min_gradient_gray_px))
                < self.cfg.min_textured_fraction
    }

    /// The keyframe policy for the frame of `res` (the current state): a new keyframe when too
    /// little of the keyframe is in view, the frame is farther from it than
    /// `max_baseline_ratio` × its median depth or turned by more than `max_rotation_rad`, the
    /// keyframe is older than `max_age_s` (0 = no limit), or too few points are inliers. `false`
    /// without a keyframe or for an untextured frame.
    pub fn wants_keyframe(
        &self,
        res: &TrackResult,
        max_baseline_ratio: f64,
        max_rotation_rad: f64,
        max_age_s: f64,
    ) -> bool {
        let Some(kf) = &self.keyframe else {
            return false;
        };
        if res.flag == Some(FlagReason::NoTexture) {
            return false; // nothing to map in it
        }
        let t_kc = kf.t_world_cam.inverse() * pose_of(&self.state) * self.t_body_cam;
        let baseline = t_kc.translation.vector.norm() / kf.median_depth_m.max(1e-3);
        res.overlap < self.cfg.keyframe_min_overlap
            || baseline > max_baseline_ratio
            || t_kc.rotation.angle() > max_rotation_rad
            || self.keyframe_older_than(res.t, max_age_s)
            || res.flag == Some(FlagReason::FewInliers)
            || self.brightness_collapsed(res)
    }

    /// `collapsed_log_gain`: the frame's brightness relative to the keyframe is collapsing.
    pub fn brightness_collapsed(&self, res: &TrackResult) -> bool {
        let g = self.cfg.collapsed_log_gain;
        g > 0.0 && res.flag.is_none() && res.log_gain < -g
    }

    /// Coarse-to-fine Gauss-Newton with step control; `None` if the solution is rejected
    /// (`res.flag` says why).
    fn solve_visual_inertial(
        &mut self,
        pre: &Preintegration,
        xi: &FrameState,
        x_pred: &FrameState,
        a_imu: &Matrix15,
        res: &mut TrackResult,
    ) -> Option<(FrameState, Matrix15, f64, f64)> {
        let mut x = *x_pred;
        let mut aff = (self.log_gain, self.offset_gray);
        let mut last: Option<(Evaluation, f64)> = None;
        for level in (0..NUM_LEVELS).rev() {
            // Photometric noise scale of this level from the residuals at the start state; the
            // same accumulation is then weighted by it.
            let Some(probe) = self.photometric(level, &x, aff) else {
                continue;
            };
            if probe.num_valid < 8 {
                continue;
            }
            let sigma2 = self.robust_sigma2();
            let start = self.assemble(Some(probe), pre, xi, &x, a_imu, aff, sigma2);
            let Some((cur, accepted)) =
                self.gauss_newton_level(level, start, pre, xi, a_imu, &mut x, &mut aff, sigma2)
            else {
                res.flag = Some(FlagReason::SolverFailed);
                return None;
            };
            res.iterations[level] = accepted;
            if level == 0 {
                last = Some((cur, sigma2));
            }
        }
        // Dynamic covariance scaling of the visual term (Agarwal et al., ICRA 2013): a solution
        // whose IMU residual (eq. 13) has χ² above `vision_downweight_chi2` is solved again at
        // full resolution with the photometric information scaled by `vision_downweight_chi2 /
        // χ²` — over a frame interval the IMU is the better witness of translation, and a
        // photometric optimum pulled off by a straight edge or a biased map should not carry the
        // state (and its velocity) with it at full weight. Not two frames running: a run of
        // disagreeing frames is the state's velocity or bias being off, which the images correct.
        let imu_chi2 = |e: &Evaluation| e.r_imu.dot(&(a_imu * e.r_imu));
        let phi = self.cfg.vision_downweight_chi2;
        if phi > 0.0
            && !self.last_downweighted
            && let Some((chi2, sigma2)) = last.as_ref().map(|(fin, s2)| (imu_chi2(fin), *s2))
            && chi2 > phi
            && chi2.is_finite()
            && let Some(probe) = self.photometric(0, &x, aff)
        {
            let sigma2_w = sigma2 * (chi2 / phi);
            let start = self.assemble(Some(probe), pre, xi, &x, a_imu, aff, sigma2_w);
            let Some((cur, accepted)) =
                self.gauss_newton_level(0, start, pre, xi, a_imu, &mut x, &mut aff, sigma2_w)
            else {
                res.flag = Some(FlagReason::SolverFailed);
                return None;
            };
            res.iterations[0] = res.iterations[0].saturating_add(accepted);
            res.downweighted = true;
            last = Some((cur, sigma2_w));
        }
        let Some((fin, _)) = last else {
            res.flag = Some(FlagReason::FewInliers);
            return None;
        };
        let ph = fin.ph.as_ref()?;
        let n0 = ph.num_points.max(1) as f64;
        res.inlier_ratio = ph.num_inliers as f64 / n0;
        res.overlap = ph.num_valid as f64 / n0;
        res.residual_rms_gray = ph.inlier_rms_gray();
        res.imu_chi2 = imu_chi2(&fin);
        let all_finite =
            fin.cost.is_finite() && x.is_finite() && aff.0.is_finite() && aff.1.is_finite();
        if !all_finite {
            res.flag = Some(FlagReason::NonFinite);
            return None;
        }
        if res.inlier_ratio < self.cfg.min_inlier_ratio {
            res.flag = Some(FlagReason::FewInliers);
            return None;
        }
        if res.imu_chi2 > self.cfg.max_imu_chi2 {
            res.flag = Some(FlagReason::ImuInconsistent);
            return None;
        }
        res.photometric_info = pose_information(&fin.h_ph);
        res.photometric_step = photometric_step(&fin.h_ph, &fin.b_ph);
        let cov = if self.cfg.estimate_gyro_bias {
            marginal_covariance(&fin.sys)
        } else {
            held_gyro_bias_covariance(&fin.sys, a_imu)
        };
        let Some(cov) = cov else {
            res.flag = Some(FlagReason::SolverFailed);
            return None;
        };
        Some((x, cov, aff.0, aff.1))
    }

    /// Levenberg-damped Gauss-Newton at one pyramid level from `cur` (the evaluation at `x`,
    /// `aff` with the photometric term weighted by `1/sigma2`): `x` and `aff` are moved to the
    /// accepted steps. Returns the evaluation at the final state and the accepted iterations;
    /// `None` if the damped system could not be solved.
    #[allow(clippy::too_many_arguments)]
    fn gauss_newton_level(
        &mut self,
        level: usize,
        mut cur: Evaluation,
        pre: &Preintegration,
        xi: &FrameState,
        a_imu: &Matrix15,
        x: &mut FrameState,
        aff: &mut (f64, f64),
        sigma2: f64,
    ) -> Option<(Evaluation, u8)> {
        let median_depth = self.keyframe.as_ref().map_or(1.0, |k| k.median_depth_m);
        let max_iterations = self.cfg.max_iterations_per_level[level.min(NUM_LEVELS - 1)];
        let mut lambda = 0.0f64;
        let f_px = self.cameras[level].fx.max(self.cameras[level].fy);
        let mut accepted = 0u8;
        let mut tries = 0usize;
        while tries < 3 * max_iterations {
            if accepted as usize >= max_iterations {
                break;
            }
            tries += 1;
            let Some((dp, di)) =
                step_system(&cur.sys, lambda, self.cfg.estimate_gyro_bias).solve_schur()
            else {
                if lambda == 0.0 {
                    lambda = 1e-4;
                    continue;
                }
                return None;
            };
            let (x_new, aff_new) = apply(x, *aff, &dp, &di);
            // The trial's cost first; its normal equations only if it is accepted.
            let trial = self.photometric_cost(level, &x_new, aff_new);
            let new_cost = self.total_cost(
                trial.map(|c| c.cost),
                pre,
                xi,
                &x_new,
                a_imu,
                aff_new,
                sigma2,
            );
            if new_cost.is_finite() && new_cost <= cur.cost {
                let ph = trial.and_then(|c| self.normal_equations_of_last(level, c));
                *x = x_new;
                *aff = aff_new;
                cur = self.assemble(ph, pre, xi, x, a_imu, *aff, sigma2);
                accepted += 1;
                lambda = if lambda < 1e-6 { 0.0 } else { lambda * 0.1 };
                let step_px = f_px
                    * (dp.fixed_rows::<3>(0).norm()
                        + dp.fixed_rows::<3>(3).norm() / median_depth.max(1e-3));
                if step_px < self.cfg.convergence_px {
                    break;
                }
            } else {
                lambda = if lambda == 0.0 { 1e-4 } else { lambda * 10.0 };
                if lambda > 1e3 {
                    break;
                }
            }
        }
        Some((cur, accepted))
    }

    /// `σ²` of the photometric residual from the last accumulation's MAD, floored.
    fn robust_sigma2(&mut self) -> f64 {
        let n = self.scratch.len();
        let mad = if n == 0 {
            0.0
        } else {
            let m = n / 2;
            self.scratch.select_nth_unstable_by(m, f32::total_cmp);
            self.scratch[m] as f64
        };
        let sigma = (1.4826 * mad).max(self.cfg.min_sigma_gray);
        sigma * sigma * self.cfg.photometric_correlation.max(1e-6)
    }

    /// The normal equations and cost at `x` (photometric at `level` if `Some`, plus IMU, plus the
    /// brightness prior), with the photometric term weighted by `1/sigma2`.
    #[allow(clippy::too_many_arguments)]
    fn evaluate(
        &mut self,
        photometric_level: Option<usize>,
        pre: &Preintegration,
        xi: &FrameState,
        x: &FrameState,
        a_imu: &Matrix15,
        aff: (f64, f64),
        sigma2: f64,
    ) -> Evaluation {
        let ph = photometric_level.and_then(|level| self.photometric(level, x, aff));
        self.assemble(ph, pre, xi, x, a_imu, aff, sigma2)
    }

    /// The photometric system of the keyframe's points at `level` for the state `x` and
    /// brightness `aff` (unweighted by the noise scale; `|r|` of the valid points left in the
    /// scratch buffer). `None` without a keyframe.
    fn photometric(
        &mut self,
        level: usize,
        x: &FrameState,
        aff: (f64, f64),
    ) -> Option<PhotometricSystem> {
        let cost = self.photometric_cost(level, x, aff)?;
        self.normal_equations_of_last(level, cost)
    }

    /// The residual pass of [`Tracker::photometric`] alone: cost and counts, the inliers kept for
    /// [`Tracker::normal_equations_of_last`]. `None` without a keyframe.
    fn photometric_cost(
        &mut self,
        level: usize,
        x: &FrameState,
        aff: (f64, f64),
    ) -> Option<PhotometricCost> {
        let kf = self.keyframe.as_ref()?;
        let t_k_b = kf.t_world_cam.inverse() * pose_of(x);
        let t_c_k = (t_k_b * self.t_body_cam).inverse();
        let robust = RobustCost {
            huber_gray: self.cfg.huber_gray,
            outlier_gray: self.cfg.outlier_gray,
            border_px: self.cfg.border_px,
        };
        Some(residuals(
            &kf.levels[level],
            &kf.cameras[level],
            self.frame.level(level),
            &t_c_k,
            (aff.0.exp(), aff.1),
            &robust,
            &mut self.scratch,
            &mut self.inliers,
        ))
    }

    /// The photometric system of the last [`Tracker::photometric_cost`] pass (at `level`, with
    /// its `cost`): the same sums [`Tracker::photometric`] would have given.
    fn normal_equations_of_last(
        &self,
        level: usize,
        cost: PhotometricCost,
    ) -> Option<PhotometricSystem> {
        let kf = self.keyframe.as_ref()?;
        Some(normal_equations_of(&kf.levels[level], &self.inliers, cost))
    }

    /// The cost [`Tracker::assemble`] gives at `x` for a photometric cost `ph_cost` (unweighted,
    /// `None` = no photometric term): `ph_cost/σ² + brightness prior + ½ rᵀ A r` of the IMU.
    #[allow(clippy::too_many_arguments)]
    fn total_cost(
        &self,
        ph_cost: Option<f64>,
        pre: &Preintegration,
        xi: &FrameState,
        x: &FrameState,
        a_imu: &Matrix15,
        aff: (f64, f64),
        sigma2: f64,
    ) -> f64 {
        let mut cost = 0.0;
        if let (Some(c), Some(_)) = (ph_cost, &self.keyframe) {
            cost += c * (1.0 / sigma2);
            let (wa, wb) = self.brightness_prior_weights();
            let (ea, eb) = (aff.0 - self.log_gain, aff.1 - self.offset_gray);
            cost += 0.5 * (wa * ea * ea + wb * eb * eb);
        }
        let r = imu_residual(pre, xi, x);
        cost + 0.5 * r.dot(&(a_imu * r))
    }

    /// Information of the brightness prior `(log-gain, offset)`.
    fn brightness_prior_weights(&self) -> (f64, f64) {
        (
            1.0 / self.cfg.affine_gain_prior_std.powi(2),
            1.0 / self.cfg.affine_offset_prior_std_gray.powi(2),
        )
    }

    /// [`Tracker::evaluate`] from an already accumulated photometric system `ph` (of the same
    /// `x` and `aff`): the system is weighted by `1/sigma2`, the brightness prior and the IMU
    /// residual added.
    #[allow(clippy::too_many_arguments)]
    fn assemble(
        &self,
        ph: Option<PhotometricSystem>,
        pre: &Preintegration,
        xi: &FrameState,
        x: &FrameState,
        a_imu: &Matrix15,
        aff: (f64, f64),
        sigma2: f64,
    ) -> Evaluation {
        let mut sys = BlockSystem::<8, 9>::zeros();
        let mut h_ph = SMatrix::<f64, 8, 8>::zeros();
        let mut b_ph = SVector::<f64, 8>::zeros();
        let cost = self.total_cost(ph.as_ref().map(|p| p.cost), pre, xi, x, a_imu, aff, sigma2);
        let mut ph_out = None;
        if let (Some(ph), Some(kf)) = (ph, &self.keyframe) {
            let t_k_b = kf.t_world_cam.inverse() * pose_of(x);
            let gain = aff.0.exp();
            let (h8, b8) = ph.normal_equations(gain);
            let mut a8 = SMatrix::<f64, 8, 8>::identity();
            a8.fixed_view_mut::<6, 6>(0, 0).copy_from(&adjoint(&t_k_b));
            let inv_s2 = 1.0 / sigma2;
            sys.h_pp = a8.transpose() * h8 * a8 * inv_s2;
            sys.b_p = a8.transpose() * b8 * inv_s2;
            ph_out = Some(ph);
            // Brightness prior relative to the previous frame's values.
            let (wa, wb) = self.brightness_prior_weights();
            let (ea, eb) = (aff.0 - self.log_gain, aff.1 - self.offset_gray);
            sys.h_pp[(6, 6)] += wa;
            sys.h_pp[(7, 7)] += wb;
            sys.b_p[6] -= wa * ea;
            sys.b_p[7] -= wb * eb;
            h_ph = sys.h_pp;
            b_ph = sys.b_p;
        } else {
            // No photometric term: keep the brightness block regular.
            sys.h_pp[(6, 6)] = 1.0;
            sys.h_pp[(7, 7)] = 1.0;
        }
        // IMU residual (eq. 13) with its analytic Jacobian w.r.t. frame j (eq. 33–52).
        let r = imu_residual(pre, xi, x);
        let j = imu_jacobian_j(pre, xi, x);
        let h15 = j.transpose() * a_imu * j;
        let b15 = -(j.transpose() * (a_imu * r));
        // Pose columns [θ, t] -> P[0..6]; [v, bω, ba] -> I[0..9].
        let pose = block::VEL; // first 6 entries are the pose
        for a in 0..15 {
            for b in 0..15 {
                let v = h15[(a, b)];
                match (a < pose, b < pose) {
                    (true, true) => sys.h_pp[(a, b)] += v,
                    (true, false) => sys.h_pi[(a, b - pose)] += v,
                    (false, false) => sys.h_ii[(a - pose, b - pose)] += v,
                    (false, true) => {}
                }
            }
            if a < pose {
                sys.b_p[a] += b15[a];
            } else {
                sys.b_i[a - pose] += b15[a];
            }
        }
        Evaluation {
            sys,
            h_ph,
            b_ph,
            cost,
            ph: ph_out,
            r_imu: r,
        }
    }
}

/// `r_to_body`, any rotation whose right-hand frame is frame j's body (world ← body, or a
/// keyframe's body ← body), turned as [`TrackResult::photometric_step`] turns frame j: where the
/// keyframe's points alone put its attitude, the IMU's pull undone (`FrameState::boxplus` turns
/// on the right).
pub fn photometric_rotation(
    r_to_body: &Matrix3<f64>,
    photometric_step: &Vector6<f64>,
) -> Matrix3<f64> {
    r_to_body * exp_so3(&photometric_step.fixed_rows::<3>(0).into_owned())
}

/// Body pose `T_wb` of a state.
pub fn pose_of(x: &FrameState) -> Isometry3<f64> {
    Isometry3::from_parts(x.nav.p_world_m.into(), x.nav.r_world_body)
}

/// The system a step is solved from: Levenberg-style damping of the diagonal (`λ = 0`: the
/// paper's plain Gauss-Newton) and, unless `estimate_gyro_bias`, the gyro bias's rows and
/// columns (`δbω`, rows 3–5 of `δ_I`) replaced by the identity with a zero right-hand side, so
/// its step is exactly zero and the other unknowns are solved with it held.
fn step_system(
    sys: &BlockSystem<8, 9>,
    lambda: f64,
    estimate_gyro_bias: bool,
) -> BlockSystem<8, 9> {
    let mut s = sys.clone();
    if !estimate_gyro_bias {
        for k in 3..6 {
            s.h_ii.row_mut(k).fill(0.0);
            s.h_ii.column_mut(k).fill(0.0);
            s.h_pi.column_mut(k).fill(0.0);
            s.h_ii[(k, k)] = 1.0;
            s.b_i[k] = 0.0;
        }
    }
    if lambda > 0.0 {
        for k in 0..8 {
            s.h_pp[(k, k)] *= 1.0 + lambda;
        }
        for k in 0..9 {
            s.h_ii[(k, k)] *= 1.0 + lambda;
        }
    }
    s
}

/// Applies `δ_P = [δθ, δt, δα, δβ]`, `δ_I = [δv, δbω, δba]` (eq. 34, 36, 38 and the biases).
fn apply(
    x: &FrameState,
    aff: (f64, f64),
    dp: &SVector<f64, 8>,
    di: &SVector<f64, 9>,
) -> (FrameState, (f64, f64)) {
    let mut d = Vector15::zeros();
    d.fixed_rows_mut::<6>(0).copy_from(&dp.fixed_rows::<6>(0));
    d.fixed_rows_mut::<9>(6).copy_from(di);
    (x.boxplus(&d), (aff.0 + dp[6], aff.1 + dp[7]))
}

/// The pose block of an 8x8 `[pose, α, β]` information with the brightness marginalised (Schur).
fn pose_information(h: &SMatrix<f64, 8, 8>) -> Matrix6<f64> {
    let hpp = h.fixed_view::<6, 6>(0, 0).into_owned();
    let hpa = h.fixed_view::<6, 2>(0, 6).into_owned();
    let haa = h.fixed_view::<2, 2>(6, 6).into_owned();
    match haa.try_inverse() {
        Some(inv) => {
            let m = hpp - hpa * inv * hpa.transpose();
            (m + m.transpose()) * 0.5
        }
        None => hpp,
    }
}

/// The pose part of `h⁻¹ b` for an 8x8 `[pose, α, β]` system (brightness free); zero if `h` is
/// not positive definite or the step is not finite.
fn photometric_step(h: &SMatrix<f64, 8, 8>, b: &SVector<f64, 8>) -> Vector6<f64> {
    h.cholesky()
        .map(|c| c.solve(b).fixed_rows::<6>(0).into_owned())
        .filter(|d| d.iter().all(|v| v.is_finite()))
        .unwrap_or_else(Vector6::zeros)
}

/// Covariance of the 15-state from the joint Hessian (inverse of the full 17x17, brightness
/// marginalised by taking the sub-block).
fn marginal_covariance(sys: &BlockSystem<8, 9>) -> Option<Matrix15> {
    let mut h = SMatrix::<f64, 17, 17>::zeros();
    h.fixed_view_mut::<8, 8>(0, 0).copy_from(&sys.h_pp);
    h.fixed_view_mut::<8, 9>(0, 8).copy_from(&sys.h_pi);
    h.fixed_view_mut::<9, 8>(8, 0)
        .copy_from(&sys.h_pi.transpose());
    h.fixed_view_mut::<9, 9>(8, 8).copy_from(&sys.h_ii);
    let inv = h.cholesky()?.inverse();
    // 17-index of each 15-state entry: θ,t = 0..6; v, bω, ba = 8..17.
    let idx = |k: usize| if k < 6 { k } else { k + 2 };
    let cov = Matrix15::from_fn(|a, b| inv[(idx(a), idx(b))]);
    cov.iter().all(|v| v.is_finite()).then_some(cov)
}

/// The covariance of a solution whose gyro bias was held (`estimate_gyro_bias = false`): the
/// other unknowns' from the system with the bias's rows and columns taken out (their covariance
/// given the bias, as the step was solved), the bias's the prediction's (`a_imu⁻¹`, the prior
/// and the random walk of eq. 9–10: the images did not move it, so they must not narrow it),
/// uncorrelated with the rest.
fn held_gyro_bias_covariance(sys: &BlockSystem<8, 9>, a_imu: &Matrix15) -> Option<Matrix15> {
    let mut cov = marginal_covariance(&step_system(sys, 0.0, false))?;
    let predicted = a_imu.cholesky()?.inverse();
    let bg = block::BG;
    // The held system is block-diagonal in the bias, so its inverse has exact zeros beside it.
    cov.fixed_view_mut::<3, 3>(bg, bg)
        .copy_from(&predicted.fixed_view::<3, 3>(bg, bg));
    cov.iter().all(|v| v.is_finite()).then_some(cov)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::boxplus_se3;
    use crate::tracking::keyframe::{DepthPoint, Keyframe};
    use crate::tracking::photometric::accumulate;
    use nalgebra::{Translation3, UnitQuaternion, Vector3, Vector6};

    /// A tracker with the default settings, at rest at the origin.
    fn tracker_at_origin(cam: &CameraModel) -> Tracker {
        let state = FrameState {
            nav: crate::imu::NavState {
                t: TimeNs(0),
                r_world_body: UnitQuaternion::identity(),
                p_world_m: Vector3::zeros(),
                v_world_m_s: Vector3::zeros(),
            },
            bias: crate::imu::ImuBias::default(),
        };
        Tracker::new(
            TrackerConfig::default(),
            cam,
            Isometry3::identity(),
            ImuNoise::euroc_adis16448(),
            state,
            Matrix15::identity(),
        )
    }

    /// `collapsed_log_gain`: a solution whose gain relative to the keyframe has fallen below
    /// e^-1 asks for another keyframe (and the odometry leaves a stored keyframe for it); a flagged
    /// frame or the option off does not. A keyframe older than the age limit asks for another.
    #[test]
    fn a_collapsing_brightness_or_an_old_keyframe_asks_for_another() {
        let cam = CameraModel::euroc_cam0();
        let mut tracker = tracker_at_origin(&cam);
        let img = Image::from_fn(cam.width, cam.height, |x, y| {
            120.0 + 60.0 * ((x as f32) * 0.09).sin() * ((y as f32) * 0.06).cos()
        });
        let mut pyr = Pyramid::new(cam.width, cam.height, NUM_LEVELS);
        pyr.fill_from_f32(&img);
        let points: Vec<DepthPoint> = (40..440)
            .step_by(20)
            .flat_map(|v| (40..720).step_by(20).map(move |u| (u, v)))
            .map(|(u, v)| DepthPoint {
                u_px: u as f32,
                v_px: v as f32,
                inv_depth_m_inv: 0.5,
            })
            .collect();
        tracker.set_keyframe(Keyframe::new(
            1,
            TimeNs(0),
            &pyr,
            &cam,
            Isometry3::identity(),
            &points,
            tracker.config(),
        ));
        // At the keyframe, fully in view, well tracked: no new keyframe…
        let mut res = tracker.untracked_result(TimeNs(50_000_000));
        res.overlap = 1.0;
        res.inlier_ratio = 0.9;
        res.log_gain = -0.5;
        assert!(!tracker.brightness_collapsed(&res));
        assert!(!tracker.wants_keyframe(&res, 1.0, 1.0, 0.0));
        // …unless the keyframe is older than the age limit (50 ms after it here).
        assert!(!tracker.wants_keyframe(&res, 1.0, 1.0, 0.051));
        assert!(tracker.wants_keyframe(&res, 1.0, 1.0, 0.049));
        // …or the gain collapses (e^-1.2 with everything else as good).
        res.log_gain = -1.2;
        assert!(tracker.brightness_collapsed(&res));
        assert!(tracker.wants_keyframe(&res, 1.0, 1.0, 0.0));
        // A flagged frame's brightness is not a solution.
        res.flag = Some(FlagReason::ImuInconsistent);
        assert!(!tracker.brightness_collapsed(&res));
        res.flag = None;
        // Off.
        tracker.cfg.collapsed_log_gain = 0.0;
        assert!(!tracker.brightness_collapsed(&res));
        assert!(!tracker.wants_keyframe(&res, 1.0, 1.0, 0.0));
    }

    /// `swap_frame_pyramid`: the frame's pyramid is handed over as loaded (no copy) and the next
    /// frame is loaded into the buffer given; a buffer of another size is refused and a copy of
    /// the frame handed over instead.
    #[test]
    fn the_frame_pyramid_changes_hands_and_the_next_frame_loads_into_the_buffer_given() {
        let cam = CameraModel::euroc_cam0();
        let mut tracker = tracker_at_origin(&cam);
        let frame = |k: f32| {
            Image::from_fn(cam.width, cam.height, |x, y| {
                (100.0 + k + 40.0 * ((x as f32) * 0.07).sin() * ((y as f32) * 0.05).cos()) as u8
            })
        };
        let (a, b) = (frame(0.0), frame(30.0));
        tracker.load_frame(&a);
        let mut buffer = Pyramid::new(cam.width, cam.height, NUM_LEVELS);
        buffer.fill_from_u8(&b); // anything: overwritten by the next frame
        let mut handed = tracker.swap_frame_pyramid(buffer);
        handed.ensure_gradients();
        let expected = Pyramid::from_u8(&a, NUM_LEVELS);
        for l in 0..NUM_LEVELS {
            assert_eq!(
                handed.level(l).data(),
                expected.level(l).data(),
                "level {l}"
            );
            assert_eq!(handed.gradients(l).0.data(), expected.gradients(l).0.data());
        }
        tracker.load_frame(&b);
        let loaded = Pyramid::from_u8(&b, NUM_LEVELS);
        assert_eq!(
            tracker.frame_pyramid().level(0).data(),
            loaded.level(0).data()
        );
        // A buffer of the wrong size: refused, the frame copied, the tracker's kept.
        let small = Pyramid::new(cam.width / 2, cam.height / 2, NUM_LEVELS);
        let copy = tracker.swap_frame_pyramid(small);
        assert_eq!(copy.level(0).data(), loaded.level(0).data());
        assert_eq!(tracker.frame_pyramid().level(0).width(), cam.width);
        assert_eq!(
            tracker.frame_pyramid().level(0).data(),
            loaded.level(0).data()
        );
    }

    /// The photometric Jacobian w.r.t. the body increment, `J_ε Ad(T_kb)`, against numeric
    /// differentiation of the forward residual `I_j(π(T_ck(x ⊞ δ) p)) − I_i(u)` at the solution
    /// (current image = keyframe image, current pose = keyframe pose), where inverse-compositional
    /// and forward Jacobians coincide.
    #[test]
    fn body_increment_jacobian_matches_numeric_differentiation() {
        let cam = CameraModel::euroc_cam0();
        let img = Image::from_fn(cam.width, cam.height, |x, y| {
            let (x, y) = (x as f32, y as f32);
            120.0 + 60.0 * (x * 0.09).sin() * (y * 0.06).cos() + 30.0 * (0.04 * (x + 2.0 * y)).sin()
        });
        let mut pyr = Pyramid::new(cam.width, cam.height, NUM_LEVELS);
        pyr.fill_from_f32(&img);
        let t_body_cam = Isometry3::from_parts(
            Translation3::new(-0.02, 0.06, 0.01),
            UnitQuaternion::from_euler_angles(1.5, 0.02, 1.6),
        );
        let t_world_body = Isometry3::from_parts(
            Translation3::new(1.0, -2.0, 1.3),
            UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7),
        );
        let cfg = TrackerConfig::default();
        let pts = [DepthPoint {
            u_px: 300.0,
            v_px: 200.0,
            inv_depth_m_inv: 0.4,
        }];
        let kf = Keyframe::new(
            0,
            TimeNs(0),
            &pyr,
            &cam,
            t_world_body * t_body_cam,
            &pts,
            &cfg,
        );
        let lv = &kf.levels[0];
        assert_eq!(lv.len(), 1);
        let robust = RobustCost {
            huber_gray: 1e6,
            outlier_gray: 2e6,
            border_px: 1.0,
        };
        let mut scratch = (Vec::new(), Vec::new());
        let residual = |t_wb: &Isometry3<f64>, (abs_r, inliers): &mut (Vec<f32>, Vec<_>)| {
            let t_ck = (kf.t_world_cam.inverse() * t_wb * t_body_cam).inverse();
            let s = accumulate(lv, &cam, &img, &t_ck, (1.0, 0.0), &robust, abs_r, inliers);
            s.c[7] // Σ w ĝ r with ĝ[7] = 1 and w = 1: the residual itself
        };
        // Analytic: r(δ) ≈ r0 + J δ with J = −g Ad(T_kb) (gain 1).
        let g = Vector6::from_row_slice(&lv.jacobian[0].map(|v| v as f64));
        let t_kb = kf.t_world_cam.inverse() * t_world_body;
        let j = -(g.transpose() * adjoint(&t_kb));
        for k in 0..6 {
            let h = 1e-4;
            let mut d = Vector6::zeros();
            d[k] = h;
            let rp = residual(&boxplus_se3(&t_world_body, &d), &mut scratch);
            let rm = residual(&boxplus_se3(&t_world_body, &-d), &mut scratch);
            let num = (rp - rm) / (2.0 * h);
            assert!(
                (num - j[k]).abs() < 0.03 * j.norm() + 1e-3,
                "k={k}: numeric {num}, analytic {}",
                j[k]
            );
        }
    }

    /// The photometric attitude is the rotation `FrameState::boxplus` gives for the step, and it
    /// turns a keyframe-relative rotation the same way (the keyframe's side is untouched).
    #[test]
    fn photometric_rotation_turns_as_boxplus_on_the_right() {
        let r_world_body = UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -0.7, 1.1));
        let state = FrameState {
            nav: crate::imu::NavState {
                t: TimeNs(0),
                r_world_body,
                p_world_m: Vector3::new(1.0, 2.0, 3.0),
                v_world_m_s: Vector3::zeros(),
            },
            bias: crate::imu::ImuBias::default(),
        };
        let step = Vector6::new(0.02, -0.01, 0.03, 0.1, 0.2, -0.3);
        let mut d = crate::imu::Vector15::zeros();
        d.fixed_rows_mut::<3>(block::ROT)
            .copy_from(&step.fixed_rows::<3>(0));
        d.fixed_rows_mut::<3>(block::POS)
            .copy_from(&step.fixed_rows::<3>(3));
        let moved = state.boxplus(&d);
        let r = *r_world_body.to_rotation_matrix().matrix();
        let want = *moved.nav.r_world_body.to_rotation_matrix().matrix();
        assert!((photometric_rotation(&r, &step) - want).norm() < 1e-12);
        // Relative to a keyframe's body: R_kb' = R_kwᵀ R_wb'.
        let r_world_kf = *UnitQuaternion::from_scaled_axis(Vector3::new(-0.2, 0.4, 0.1))
            .to_rotation_matrix()
            .matrix();
        let rel = r_world_kf.transpose() * r;
        let got = photometric_rotation(&rel, &step);
        assert!((got - r_world_kf.transpose() * want).norm() < 1e-12);
        // A zero step leaves the attitude as it is; a non-zero one moves it.
        assert_eq!(photometric_rotation(&r, &Vector6::zeros()), r);
        assert!((photometric_rotation(&r, &step) - r).norm() > 0.01);
    }
}
