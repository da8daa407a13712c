//! Refinement of the first map's take-off: re-posing its views by vision and aligning their scale
//! with the IMU before the first map is tracked.
//!
//! The paper's bootstrap poses the take-off frames by IMU dead reckoning from rest and triangulates
//! the first keyframe from them. On a pad that is not quite at rest (rotors shaking the vehicle by
//! 0.5–1 cm/s and 0.1°, and slowly rotating it — the mean gyro rate then is not the bias), dead
//! reckoning over a half-second hop is 1–2 cm off, several percent of the baseline, and the
//! first map inherits that as a depth-dependent distortion that every later map propagates.
//!
//! Once the first map has its points, its views are re-posed and the first map is triangulated
//! again from them (`[bootstrap] refine_takeoff_passes`, default 2), in one of two ways
//! (`takeoff_refinement`):
//!
//! * `bundle_adjustment` (default, [`bundle_adjust_takeoff`]): the views' states, the velocity at
//!   rest, the accelerometer bias and the first map's inverse depths are optimised jointly —
//!   photometric residuals of the rest keyframe's points in every view, IMU residuals between
//!   consecutive views ([`crate::smoother::photometric_bundle`]). Pose and structure move
//!   together, so the dead reckoning's translation-direction error is corrected rather than baked
//!   into the map. The IMU's white noise is scaled by `takeoff_imu_noise_factor` (0.1): with the
//!   tracker's inflated noise the vision bent the demo's vertical take-off 10 % short, where the
//!   hop's scale is only weakly observable.
//! * `alignment` ([`refine_takeoff`]): the views are tracked again against the map from the rest
//!   state and their scale, the velocity at rest and the dead reckoning's acceleration error
//!   aligned with the IMU ([`crate::imu::scale_alignment`]). Measured without gain: the re-tracked
//!   positions keep the dead-reckoned map's translation-direction error (≈ 5 cm over S-V101's
//!   17 cm hop on the noise-free render), so tracker and mapper settle on a wrong map together;
//!   corrections within `takeoff_min_significance_sigmas` of 1 are not applied.
//!
//! A first map started in flight after a loss (`[bootstrap] reinit_velocity_std_m_s` > 0, off by
//! default; `bundle_adjustment` only) is refined the same way, from the state dead-reckoned through
//! the loss: its velocity is the start velocity's prior, with that standard deviation instead of
//! the rest's. Such a prior holds the scale only loosely, so the smoothness prior's targets are
//! made scale-neutral there
//! ([`crate::smoother::photometric_bundle::BundleConfig::smoothness_scale_neutral`]): without, the
//! passes shortened the covered-lens rebuilds of demo seeds 1–8 by 9 % each (median;
//! docs/odometry-log.md, *A first map started in flight*).
//!
//! A pass (0.8 s on the demo's 12 views and 3000 points) runs on the refinement thread
//! ([`super::refinement_worker`]) while the odometry keeps dead-reckoning the frames; when it is
//! back, the frames dead-reckoned meanwhile are predicted again from its refined last state.

use super::keyframe_bundle::{host_points, imu_chain};
use super::mapping_worker::MapFrame;
use crate::camera::CameraModel;
use crate::image::Pyramid;
use crate::imu::scale_alignment::{AlignmentPrior, AlignmentSample, align_scale};
use crate::imu::{FrameState, ImuNoise, ImuSample, Matrix15, NavState, Preintegration};
use crate::smoother::photometric_bundle::{BundleConfig, BundleView, PhotometricBundle};
use crate::tracking::{Keyframe, Tracker, TrackerConfig};
use nalgebra::Isometry3;

/// The take-off from a static start — or a first map started in flight, after a loss — kept until
/// its first map is installed.
#[derive(Clone, Debug)]
pub struct TakeoffRecord {
    /// The state the IMU is integrated from: at rest (zero velocity) for a take-off; in flight,
    /// the state dead-reckoned through the loss.
    pub rest: FrameState,
    /// Covariance of `rest`.
    pub rest_cov: Matrix15,
    /// The first keyframe (the last frame at rest, or the frame the first map is started at in
    /// flight).
    pub keyframe: MapFrame,
    /// Id of the mapper's keyframe started at `keyframe` (changes at every pass).
    pub keyframe_id: u32,
    /// Frames since the keyframe, oldest first, posed by dead reckoning.
    pub frames: Vec<MapFrame>,
    /// Refinement passes done.
    pub passes: u32,
    /// Frames between sending the last pass and applying it.
    pub last_pass_lag_frames: u64,
    /// A first map started in flight: the start velocity's prior is `rest`'s, not zero, with
    /// `[bootstrap] reinit_velocity_std_m_s` instead of `takeoff_velocity_std_m_s`.
    pub in_flight: bool,
}

impl TakeoffRecord {
    /// The record of a first map about to be started as mapper keyframe `keyframe_id` at
    /// `keyframe`, from state `rest` with covariance `rest_cov`; no frames or passes yet.
    pub fn new(
        rest: FrameState,
        rest_cov: Matrix15,
        keyframe: MapFrame,
        keyframe_id: u32,
        in_flight: bool,
    ) -> Self {
        TakeoffRecord {
            rest,
            rest_cov,
            keyframe,
            keyframe_id,
            frames: Vec::new(),
            passes: 0,
            last_pass_lag_frames: 0,
            in_flight,
        }
    }
}

/// What a refinement pass produced.
#[derive(Clone, Debug)]
pub struct RefinedTakeoff {
    /// The scale correction applied to the take-off (new over old displacement of the last view).
    pub scale: f64,
    /// The rest state with the aligned velocity and accelerometer bias.
    pub rest: FrameState,
    /// The take-off frames, re-posed and rescaled, oldest first.
    pub views: Vec<MapFrame>,
    /// The state at the last frame.
    pub last: FrameState,
    /// Frames tracked against the first map in the pass.
    pub tracked: usize,
}

/// The rig and settings a pass needs.
#[derive(Clone, Debug)]
pub struct TakeoffRig {
    pub tracking: TrackerConfig,
    pub camera: CameraModel,
    pub t_body_cam: Isometry3<f64>,
    pub noise: ImuNoise,
    pub prior: AlignmentPrior,
    /// Scale corrections farther from 1 than this fail the pass.
    pub max_scale_correction: f64,
    /// Scale corrections within this many of their standard deviations of 1 are not applied:
    /// the dead reckoning was as good as the alignment can tell.
    pub min_significance_sigmas: f64,
    /// The take-off is re-tracked with the IMU white noise multiplied by this (over the live
    /// tracker's): the rest state's dead reckoning is what is being corrected.
    pub imu_noise_factor: f64,
}

/// Tracks `rec`'s frames against `kf` (the first map) from the rest state, aligns their scale
/// with the IMU (`imu` must cover the rest state onwards) and returns the corrected take-off;
/// `None` if too few frames were tracked or the alignment is unsound.
pub fn refine_takeoff(
    rec: &TakeoffRecord,
    kf: Keyframe,
    imu: &[ImuSample],
    rig: &TakeoffRig,
) -> Option<RefinedTakeoff> {
    let rest = rec.rest;
    if imu.first().is_none_or(|s| s.t > rest.nav.t) {
        return None; // the rest state's IMU is no longer buffered
    }
    // Each frame dead-reckoned from rest with zero initial velocity.
    let dead_reckoned: Vec<NavState> = rec
        .frames
        .iter()
        .map(|f| {
            let mut pre = Preintegration::new(rest.nav.t, rest.bias);
            pre.integrate(imu, f.t, None);
            pre.predict(&rest.nav, &rest.bias)
        })
        .collect();
    let mut tracking = rig.tracking.clone();
    tracking.imu_noise_scale *= rig.imu_noise_factor;
    let mut tracker = Tracker::new(
        tracking,
        &rig.camera,
        rig.t_body_cam,
        rig.noise,
        rest,
        rec.rest_cov,
    );
    tracker.set_keyframe(kf);
    let mut t_prev = rest.nav.t;
    let mut tracked: Vec<Option<FrameState>> = Vec::with_capacity(rec.frames.len());
    for f in &rec.frames {
        let mut pre = Preintegration::new(t_prev, tracker.state().bias);
        pre.integrate(imu, f.t, Some(&rig.noise));
        let r = tracker.track(f.t, &f.image, &pre);
        t_prev = f.t;
        tracked.push(r.flag.is_none().then_some(r.state));
    }
    let p0 = rest.nav.p_world_m;
    let samples: Vec<AlignmentSample> = rec
        .frames
        .iter()
        .zip(&tracked)
        .zip(&dead_reckoned)
        .filter_map(|((f, x), dr)| {
            let x = x.as_ref()?;
            Some(AlignmentSample {
                dt_s: f.t.secs_since(rest.nav.t),
                tracked_m: x.nav.p_world_m - p0,
                dead_reckoned_m: dr.p_world_m - p0,
            })
        })
        .collect();
    let a = align_scale(&samples, &rig.prior)?;
    let change = (a.scale - 1.0).abs();
    if change > rig.max_scale_correction || change < rig.min_significance_sigmas * a.scale_std {
        return None;
    }
    let corrected_nav = |dr: &NavState, x: Option<&FrameState>| -> NavState {
        let t = dr.t;
        let dt = t.secs_since(rest.nav.t);
        let v = dr.v_world_m_s + a.v0_m_s + a.accel_m_s2 * dt;
        match x {
            Some(x) => NavState {
                t,
                r_world_body: x.nav.r_world_body,
                p_world_m: p0 + (x.nav.p_world_m - p0) * a.scale,
                v_world_m_s: v,
            },
            None => NavState {
                t,
                r_world_body: dr.r_world_body,
                p_world_m: dr.p_world_m + a.v0_m_s * dt + a.accel_m_s2 * (0.5 * dt * dt),
                v_world_m_s: v,
            },
        }
    };
    let corrected: Vec<NavState> = dead_reckoned
        .iter()
        .zip(&tracked)
        .map(|(dr, x)| corrected_nav(dr, x.as_ref()))
        .collect();
    let views = rec
        .frames
        .iter()
        .zip(&corrected)
        .map(|(f, nav)| {
            let t_world_body = Isometry3::from_parts(nav.p_world_m.into(), nav.r_world_body);
            MapFrame {
                t_world_cam: t_world_body * rig.t_body_cam,
                ..f.clone()
            }
        })
        .collect();
    let mut rest_new = rest;
    rest_new.nav.v_world_m_s = a.v0_m_s;
    // The acceleration error, taken at the rest attitude, is an accelerometer bias correction.
    rest_new.bias.accel_m_s2 =
        rest.bias.accel_m_s2 - rest.nav.r_world_body.inverse() * a.accel_m_s2;
    let last = FrameState {
        nav: *corrected.last()?,
        bias: rest_new.bias,
    };
    Some(RefinedTakeoff {
        scale: a.scale,
        rest: rest_new,
        views,
        last,
        tracked: samples.len(),
    })
}

/// The take-off refined by a joint photometric–inertial bundle adjustment
/// ([`crate::smoother::photometric_bundle`]) of the first map's depths and its views' states
/// (dead-reckoned from the rest state as the start), instead of tracking the views again: pose and
/// structure move together, so a translation-direction error of the dead reckoning is not baked
/// into the map first. `None` if there is nothing to adjust or the solution is unsound.
pub fn bundle_adjust_takeoff(
    rec: &TakeoffRecord,
    kf: &Keyframe,
    imu: &[ImuSample],
    rig: &TakeoffRig,
    cfg: &BundleConfig,
) -> Option<RefinedTakeoff> {
    let rest = rec.rest;
    if rec.frames.is_empty() || imu.first().is_none_or(|s| s.t > rest.nav.t) {
        return None;
    }
    let noise = rig.noise;
    let inflate = (rig.tracking.imu_noise_scale * rig.imu_noise_factor).powi(2);
    // The chain: rest → frame 1 → frame 2 …, each frame dead-reckoned from rest.
    let pres = imu_chain(
        rest.nav.t,
        rec.frames.iter().map(|f| f.t),
        &rest.bias,
        imu,
        &noise,
        inflate,
    );
    let mut from_rest = Preintegration::new(rest.nav.t, rest.bias);
    let states: Vec<FrameState> = rec
        .frames
        .iter()
        .map(|f| {
            from_rest.integrate(imu, f.t, None);
            FrameState {
                nav: from_rest.predict(&rest.nav, &rest.bias),
                bias: rest.bias,
            }
        })
        .collect();
    let levels = kf.cameras.len();
    let host_pyr = Pyramid::from_u8(&rec.keyframe.image, levels);
    let view_pyrs: Vec<Pyramid> = rec
        .frames
        .iter()
        .map(|f| Pyramid::from_u8(&f.image, levels))
        .collect();
    if kf.levels.is_empty() {
        return None;
    }
    let host = host_points(kf, &host_pyr, rig.tracking.gradient_weight_gray_px);
    // A take-off from rest: the start velocity's prior is zero (in flight: the velocity
    // dead-reckoned through the loss).
    let mut start = rest;
    if !rec.in_flight {
        start.nav.v_world_m_s = nalgebra::Vector3::zeros();
    }
    let problem = PhotometricBundle {
        t_world_host_cam: kf.t_world_cam,
        t_body_cam: rig.t_body_cam,
        host,
        start,
        views: states
            .iter()
            .zip(&view_pyrs)
            .zip(pres)
            .map(|((x, pyramid), pre)| BundleView {
                pyramid,
                state: *x,
                pre,
            })
            .collect(),
        chain_hosts: Vec::new(),
        noise,
        cfg: cfg.clone(),
    };
    let r = problem.solve()?;
    let p0 = rest.nav.p_world_m;
    let before = (states.last()?.nav.p_world_m - p0).norm();
    let after = (r.views.last()?.nav.p_world_m - p0).norm();
    let scale = after / before.max(1e-9);
    if (scale - 1.0).abs() > rig.max_scale_correction {
        return None;
    }
    let views = rec
        .frames
        .iter()
        .zip(&r.views)
        .map(|(f, x)| MapFrame {
            t_world_cam: Isometry3::from_parts(x.nav.p_world_m.into(), x.nav.r_world_body)
                * rig.t_body_cam,
            ..f.clone()
        })
        .collect();
    Some(RefinedTakeoff {
        scale,
        rest: r.start,
        views,
        last: *r.views.last()?,
        tracked: rec.frames.len(),
    })
}
