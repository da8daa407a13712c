//! The complete odometry: static start, metric bootstrap, tracking against semidense keyframes
//! built by the mapping thread, and recovery from tracking loss.
//!
//! # Phases
//! * [`Phase::WaitingForStart`]: no IMU window yet (no pose is published).
//! * [`Phase::Static`]: the IMU says the vehicle rests ([`StaticDetector`]). The pose is held at
//!   the origin with the attitude from gravity and the gyro bias from the rest period: a valid,
//!   drift-free pose from the first frames, with no "excitation" needed.
//! * [`Phase::Initializing`]: motion began. The last static frame becomes the first keyframe and
//!   the following frames, posed by IMU integration from the known rest state, are given to the
//!   semidense mapper: the first map's depths come from an IMU-measured baseline, so they are
//!   metric (the paper's bootstrap, section III-D end). Poses meanwhile are IMU-only.
//! * [`Phase::Tracking`]: the first map has enough points; every frame is tracked against one
//!   keyframe (joint visual-inertial, [`Tracker`]). When the tracker asks for a keyframe, a
//!   stored keyframe that the camera sees well is taken first (the paper's *closest* keyframe,
//!   [`KeyframeStore`]: back at a mapped place, the pose is measured against the older, less
//!   drifted map instead of one more link of the chain; the current pose is made uncertain in
//!   position and heading for that, and a stored keyframe that loses its inliers within
//!   `probation_frames` is left again). Otherwise the current frame starts a new keyframe
//!   (seeded by propagating the map of the keyframe tracked and by the last few frames). Frames
//!   that start nothing refine the mapper's keyframe's depths. In a turn on the spot nothing can
//!   be triangulated and each propagated map keeps only the part of the view that is leaving:
//!   a keyframe barely displaced from the one tracked, with a thin map, is tracked with its
//!   depthless gradient pixels too, at the last median depth (any depth serves a rotation), and
//!   installed at once.
//! * [`Phase::Lost`]: several consecutive frames had too few photometric inliers (covered lens,
//!   dark). Poses are IMU-only; as soon as the image has texture again a new keyframe is started
//!   as in the bootstrap, and the reset is counted.
//!
//! # Determinism
//! In offline mode every job's snapshot is awaited a fixed number of frames later
//! (`offline_lag_frames`; mapping of one frame overlaps tracking of the next), so a
//! replay gives the same poses every time. In real-time mode the tracking thread never waits: views
//! that do not fit the queue are dropped (a new keyframe waits on this side for room) and snapshots
//! are taken when they arrive.

use super::keyframe_bundle::{KeyframeBundleConfig, KeyframeRecord, carry_correction};
use super::keyframe_store::{KeyframeStore, ReuseConfig, StoredKeyframe};
use super::mapping_worker::{
    MapFrame, MapJob, MapSnapshot, MappingOptions, MappingOutput, MappingThread,
};
use super::refinement_worker::{
    KeyframeJob, ReadyKeyframe, RefineJob, RefineResult, RefineSettings, RefinementThread,
    TakeoffJob,
};
use super::scale_observer::{ScaleObserver, ScaleObserverConfig, ScaleSample};
use super::takeoff::{RefinedTakeoff, TakeoffRecord, TakeoffRig};
use crate::camera::{CameraModel, Vignette, correct_in_place};
use crate::image::{Image, Pyramid};
use crate::imu::scale_alignment::AlignmentPrior;
use crate::imu::static_init::{StaticDetector, StaticDetectorConfig, StaticEstimate, StaticEvent};
use crate::imu::{FrameState, ImuNoise, ImuSample, Matrix15, NavState, Preintegration};
use crate::mapping::semidense::{SemidenseConfig, SemidenseMap};
use crate::smoother::photometric_bundle::BundleConfig;
use crate::smoother::{KeyframeWindow, RelativePose, WindowConfig};
use crate::time::TimeNs;
use crate::tracking::{
    DepthPoint, FlagReason, Keyframe, NUM_LEVELS, TrackResult, Tracker, TrackerConfig, pose_of,
    select_gradient_pixels,
};
use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::sync::Arc;

/// Static frames remembered to pick the first keyframe before the back-dated motion onset.
const STATIC_FRAMES_KEPT: usize = 16;

/// Bootstrap and loss-recovery settings (the `[bootstrap]` table).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BootstrapConfig {
    /// The first keyframe is tracked once its map has this many points.
    pub min_initial_points: usize,
    /// A later keyframe replaces the current one once its map has this many points…
    pub min_keyframe_points: usize,
    /// …and it has been observed by this many frames after it (tracked against the previous
    /// keyframe), so that it is triangulated with forward parallax before anything is tracked
    /// against it. In real time, where the mapper is behind, the frames tracked since it was
    /// started stand in for them once there are enough for its adjustment
    /// (`[keyframe_bundle] min_views`): the adjustment triangulates it over those frames.
    pub min_keyframe_forward_views: usize,
    /// …unless fewer than this fraction of the current keyframe's points are still inliers.
    pub urgent_inlier_ratio: f64,
    /// The first keyframe is tracked only once the camera has moved this fraction of the map's
    /// median depth from it (the IMU-measured baseline that makes the first depths metric).
    pub min_init_baseline_ratio: f64,
    /// IMU integration restarts this long before the detector's back-dated onset: the detector
    /// dates the onset where the motion became detectable, and integrating a little rest costs
    /// nothing, s.
    pub onset_margin_s: f64,
    /// If the first map is not ready this long after motion onset, restart it at the current
    /// frame, s.
    pub max_init_s: f64,
    /// Inverse-depth search range of a keyframe started without a previous map, 1/m.
    pub init_inv_depth_min_m_inv: f64,
    pub init_inv_depth_max_m_inv: f64,
    /// Frames before a new keyframe given to the mapper with it.
    pub history_frames: usize,
    /// Consecutive frames with too few inliers before tracking is declared lost.
    pub lost_after_frames: u32,
    /// A lost tracker restarts when the image has at least this many gradient points.
    pub min_texture_points: usize,
    /// Rebuild the tracking keyframe from a refined map at most every this many frames.
    pub refresh_every_frames: u32,
    /// Offline replays use a job's snapshot this many frames after sending it (1: the mapper
    /// and the tracker take turns; 2: the mapper works on a frame while the next is tracked).
    pub offline_lag_frames: u64,
    /// Queue length of the mapping thread's job and snapshot channels.
    pub queue_len: usize,
    /// Real time: views the mapper keeps waiting for the current keyframe; older ones are
    /// skipped ([`MappingOptions::max_view_backlog`]).
    pub max_view_backlog: usize,
    /// The mapping thread (and its pool) raises its nice value by this much, so that the
    /// tracking thread gets a core whenever it needs one (Linux; 0 = same priority).
    pub background_nice: i32,
    /// The refinement thread (keyframe adjustment) raises its nice value by this much: less
    /// than the mapper's, since the keyframe it adjusts is waited for while the mapper's views
    /// can be skipped.
    pub refinement_nice: i32,
    /// Seed each new keyframe with the previous keyframe's map (DPPTAM's propagation).
    pub propagate_maps: bool,
    /// Prior standard deviation of the accelerometer bias when motion starts, m/s².
    pub rest_accel_bias_std_m_s2: f64,
    /// Lower bound of the prior standard deviation of the tilt from the rest period, rad.
    pub rest_min_tilt_std_rad: f64,
    /// A keyframe whose map has fewer points than this (a turn on the spot) is tracked with its
    /// depthless gradient pixels too, at the map's median depth, and installed without waiting
    /// for forward views (0 = never).
    pub fill_depthless_below_points: usize,
    /// …if it is closer than this to the keyframe tracked, over that one's median depth.
    pub fill_max_baseline_ratio: f64,
    /// After a static start, the first map's views are re-posed (`takeoff_refinement`) and the
    /// first map triangulated again from them this many times before it is tracked
    /// ([`super::takeoff`]; 0 = the paper's bootstrap by dead reckoning alone).
    pub refine_takeoff_passes: u32,
    /// A refinement pass, which runs on a thread of its own, is applied this many frames after it
    /// started (0 = before the next frame): offline exactly, in real time at the earliest (later
    /// if it takes longer). Until then the frames are dead-reckoned.
    pub takeoff_lag_frames: u64,
    /// A refinement pass is not started over more take-off frames than this (the first map is
    /// then installed as it is): a pass costs ~0.1 s per frame, and in real time the second
    /// pass, started once the first is back and the map rebuilt, would cover 60 frames and take
    /// longer than the first map may wait (offline the passes cover 13–20 frames).
    pub takeoff_max_pass_frames: usize,
    /// Prior standard deviation of the velocity at the rest state, m/s.
    pub takeoff_velocity_std_m_s: f64,
    /// Prior standard deviation of the dead reckoning's world acceleration error, m/s².
    pub takeoff_accel_std_m_s2: f64,
    /// Noise of a tracked take-off position against the integrated one, m.
    pub takeoff_position_std_m: f64,
    /// Scale corrections farther from 1 than this are not applied (a failed alignment).
    pub takeoff_max_scale_correction: f64,
    /// The take-off's IMU white noise is multiplied by this (over the tracker's inflated noise):
    /// the re-tracking of `alignment`, the IMU residuals of `bundle_adjustment` (0.1: the
    /// adjustment may bend the dead-reckoned take-off only where the images insist; at 1 it let
    /// the vision shrink the demo's vertical take-off by 10 %).
    pub takeoff_imu_noise_factor: f64,
    /// Scale corrections within this many standard deviations of 1 are not applied.
    pub takeoff_min_significance_sigmas: f64,
    /// How a refinement pass re-poses the take-off: `alignment` (track the views again, align
    /// their scale with the IMU) or `bundle_adjustment` (the views' states and the first map's
    /// depths optimised jointly with the IMU, [`crate::smoother::photometric_bundle`]).
    pub takeoff_refinement: TakeoffRefinement,
    /// Levenberg–Marquardt iterations per pyramid level of the take-off bundle adjustment.
    pub takeoff_bundle_iterations: usize,
    /// Each inverse depth is pulled toward its image neighbours' median with this relative
    /// standard deviation in the take-off bundle adjustment.
    pub takeoff_bundle_smoothness_rel_std: f64,
    /// Zero-velocity update: while the IMU's static detector says the vehicle rests (landed,
    /// idling on the pad) and the estimated speed is below this, the velocity is set to zero with
    /// `zupt_velocity_std_m_s` (m/s; 0 = off). The speed bound keeps a constant-velocity cruise,
    /// which the IMU cannot tell from rest, from being stopped.
    pub zupt_max_speed_m_s: f64,
    /// Standard deviation of the zero velocity, m/s.
    pub zupt_velocity_std_m_s: f64,
}

/// How the take-off refinement re-poses the first map's views.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TakeoffRefinement {
    Alignment,
    BundleAdjustment,
}

impl Default for BootstrapConfig {
    fn default() -> Self {
        BootstrapConfig {
            min_initial_points: 1500,
            min_keyframe_points: 500,
            min_keyframe_forward_views: 3,
            urgent_inlier_ratio: 0.6,
            max_init_s: 3.0,
            min_init_baseline_ratio: 0.1,
            onset_margin_s: 0.3,
            init_inv_depth_min_m_inv: 0.05,
            init_inv_depth_max_m_inv: 4.0,
            history_frames: 5,
            lost_after_frames: 3,
            min_texture_points: 1500,
            refresh_every_frames: 2,
            offline_lag_frames: 2,
            queue_len: 8,
            max_view_backlog: 2,
            background_nice: 10,
            refinement_nice: 2,
            propagate_maps: true,
            rest_accel_bias_std_m_s2: 0.1,
            rest_min_tilt_std_rad: 1e-3,
            fill_depthless_below_points: 1500,
            fill_max_baseline_ratio: 0.03,
            refine_takeoff_passes: 2,
            takeoff_lag_frames: 0,
            takeoff_max_pass_frames: 30,
            takeoff_velocity_std_m_s: 0.01,
            takeoff_accel_std_m_s2: 0.05,
            takeoff_position_std_m: 0.005,
            takeoff_max_scale_correction: 0.3,
            takeoff_imu_noise_factor: 0.1,
            takeoff_min_significance_sigmas: 2.0,
            takeoff_refinement: TakeoffRefinement::BundleAdjustment,
            takeoff_bundle_iterations: 12,
            takeoff_bundle_smoothness_rel_std: 0.1,
            zupt_max_speed_m_s: 0.1,
            zupt_velocity_std_m_s: 0.005,
        }
    }
}

/// What the odometry is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    WaitingForStart,
    Static,
    Initializing,
    Tracking,
    Lost,
}

impl Phase {
    pub fn as_str(self) -> &'static str {
        match self {
            Phase::WaitingForStart => "waiting",
            Phase::Static => "static",
            Phase::Initializing => "initializing",
            Phase::Tracking => "tracking",
            Phase::Lost => "lost",
        }
    }
}

/// One frame's output.
#[derive(Clone, Debug)]
pub struct OdometryFrame {
    pub result: TrackResult,
    pub phase: Phase,
    /// The pose may be sent to the flight controller (false only while waiting for the start).
    pub valid: bool,
    /// Incremented at every re-initialisation after a loss (MAVLink `reset_counter`).
    pub resets: u32,
}

/// Sensor description the odometry needs.
#[derive(Clone, Debug)]
pub struct Rig {
    pub camera: CameraModel,
    pub t_body_cam: Isometry3<f64>,
    pub noise: ImuNoise,
    /// Photometric calibration of the camera, if known.
    pub vignette: Option<Vignette>,
}

/// Every setting of the odometry.
#[derive(Clone, Debug, Default)]
pub struct OdometryConfig {
    pub tracking: TrackerConfig,
    pub mapping: SemidenseConfig,
    pub static_detector: StaticDetectorConfig,
    pub bootstrap: BootstrapConfig,
    pub window: WindowConfig,
    pub reuse: ReuseConfig,
    pub keyframe_bundle: KeyframeBundleConfig,
    pub scale_observer: ScaleObserverConfig,
    /// Real-time mode: never wait for the mapper (non-deterministic).
    pub realtime: bool,
}

/// Counters for the report.
#[derive(Clone, Debug, Default)]
pub struct OdometryStats {
    /// Back-dated motion onset of the first take-off.
    pub onset_t: Option<TimeNs>,
    /// Time of the first tracked frame after the onset.
    pub tracking_since: Option<TimeNs>,
    pub resets: u32,
    pub keyframes: usize,
    /// Times the tracker returned to a stored keyframe instead of starting a new one.
    pub keyframe_reuses: usize,
    /// Times a stored keyframe lost track right after the tracker returned to it.
    pub keyframe_reuse_failures: usize,
    /// Frames whose velocity was set to zero (the vehicle at rest).
    pub zero_velocity_updates: usize,
    /// Keyframes stored for returning to them.
    pub keyframes_stored: usize,
    /// Scale correction of each applied take-off refinement pass.
    pub takeoff_scales: Vec<f64>,
    /// Wall time of each applied take-off refinement pass, s.
    pub takeoff_refinement_s: Vec<f64>,
    /// Wall time of each in-flight keyframe adjustment (`[keyframe_bundle]`), s.
    pub keyframe_bundle_s: Vec<f64>,
    /// Median relative inverse-depth change of each in-flight keyframe adjustment.
    pub keyframe_bundle_depth_changes: Vec<f64>,
    /// Take-off refinements and keyframe adjustments not started: their thread was still busy
    /// (real time).
    pub refinements_dropped: usize,
    /// Of those started, the ones whose outcome was not used: superseded by a newer one, or their
    /// keyframe (first map) no longer tracked (built) when they came back.
    pub refinements_discarded: usize,
    /// Frames tracked again against an adjusted keyframe that came back after them.
    pub catch_up_frames: usize,
    /// Scale change (new / old depths) of each keyframe tracked with guessed depths and then
    /// adjusted with its depths free (`[keyframe_bundle] guessed_min_baseline_ratio`).
    pub guessed_keyframe_scales: Vec<f64>,
    pub jobs_dropped: usize,
    /// The map scale measured against the IMU at each new keyframe (`[scale_observer]`).
    pub imu_scale: Vec<ScaleSample>,
    /// Wall time of each keyframe-window solve (on the tracking thread), s.
    pub window_solve_s: Vec<f64>,
    /// Images are divided by the rig's vignetting.
    pub vignette_corrected: bool,
    /// Pixels clipped at 255 by the vignetting correction (bright texture in the corners).
    pub vignette_saturated_px: u64,
}

/// At most this many frames are tracked again when a keyframe adjustment comes back late (more:
/// the current state is moved by the correction instead).
const MAX_CATCH_UP_FRAMES: usize = 30;

/// A job sent to the refinement thread, awaited.
struct PendingRefinement {
    seq: u64,
    /// Frame number at which it was sent.
    frame_number: u64,
    kind: PendingKind,
}

enum PendingKind {
    Keyframe {
        /// Tracked state of the last view handed over.
        tracked_last: FrameState,
        /// The keyframe as the mapper built it, installed if the adjustment fails.
        unadjusted: Box<Keyframe>,
        /// Its snapshot.
        snapshot: MapSnapshot,
        /// The keyframe is the one tracked (installed with guessed depths), not a new one.
        tracked: bool,
    },
    Takeoff {
        /// The mapper's id of the first map being refined.
        keyframe_id: u32,
        /// Take-off frames handed over.
        frames_sent: usize,
        /// The first map's snapshot, installed as it is if the pass fails.
        snapshot: MapSnapshot,
    },
}

/// The odometry of one camera + IMU rig.
pub struct Odometry {
    cfg: OdometryConfig,
    rig: Rig,
    tracker: Tracker,
    detector: StaticDetector,
    mapping: Option<MappingThread>,
    /// The thread of the take-off refinement and the in-flight keyframe adjustment.
    refiner: Option<RefinementThread>,
    /// The refinement under way, if any.
    refining: Option<PendingRefinement>,
    /// Frames tracked while a keyframe adjustment is under way: tracked again once it is back.
    catch_up: Vec<(TimeNs, Arc<Image<u8>>)>,
    refine_seq: u64,
    /// Jobs sent to the refinement thread whose outcome has not been taken (0 or 1).
    refine_outstanding: usize,
    imu: VecDeque<ImuSample>,
    phase: Phase,
    last_t: Option<TimeNs>,
    seq: u64,
    /// Offline: jobs sent, as (frame number, seq), whose snapshots are still to be awaited.
    awaited: VecDeque<(u64, u64)>,
    /// Real time: keyframe jobs (new keyframe, rescale) that found the mapper's queue full, in
    /// order; sent before anything else as soon as there is room (views are dropped instead).
    deferred_jobs: VecDeque<MapJob>,
    frame_number: u64,
    tracking_kf: Option<u32>,
    /// The mapper's map of the tracking keyframe as installed.
    tracking_map: Option<Arc<SemidenseMap>>,
    /// The tracking keyframe includes depthless pixels at a guessed depth.
    tracking_kf_filled: bool,
    /// Median inverse depth of the last map with points, 1/m (the guess for depthless pixels).
    last_median_inv_depth: Option<f32>,
    /// A keyframe started in the mapper and not yet installed for tracking.
    pending_kf: Option<u32>,
    /// The tracking keyframe is a stored one (the mapper holds another, not tracked).
    reusing: bool,
    /// The mapper's keyframe left for a stored one (returned to if the stored one fails).
    left_kf: Option<StoredKeyframe>,
    /// The stored keyframe tracked before the one now on probation, when the switch was from
    /// one stored keyframe to another that had passed its probation and was still tracking
    /// (`[reuse] probation_min_inlier_ratio` on the last frame): gone back to, on probation
    /// again, if the new one fails.
    reuse_previous: Option<StoredKeyframe>,
    /// Frames tracked since the last switch to a stored keyframe.
    reuse_frames: u32,
    /// Stored keyframes that failed since the last new keyframe was installed.
    failed_reuse: Vec<u32>,
    /// Keyframes no longer tracked, to return to.
    store: KeyframeStore,
    newest_kf: Option<u32>,
    next_kf_id: u32,
    frames_since_refresh: u32,
    tracking_kf_points: usize,
    history: VecDeque<MapFrame>,
    /// The last static frames (held at the rest pose), newest last.
    static_frames: VecDeque<MapFrame>,
    /// The rest estimate at each of those frames, newest last.
    rest_estimates: VecDeque<StaticEstimate>,
    init_started: Option<TimeNs>,
    /// The take-off from rest while its first map is built.
    takeoff: Option<TakeoffRecord>,
    /// The keyframe started in flight and the frames tracked since, until it is installed.
    kf_record: Option<KeyframeRecord>,
    /// The tracking keyframe's depths come from the keyframe adjustment (or will, once it is
    /// back): the mapper's refreshes of it are not installed.
    tracking_kf_adjusted: bool,
    /// A keyframe installed with guessed depths and the frames tracked since it was started,
    /// until they span a baseline (`[keyframe_bundle] guessed_min_baseline_ratio`) and it is
    /// adjusted with its depths free: the map the mapper builds for it has the scale of poses
    /// tracked against the guesses.
    guessed: Option<KeyframeRecord>,
    /// The snapshot of its map as last installed (`None` while only the guesses are).
    guessed_snapshot: Option<MapSnapshot>,
    consecutive_flagged: u32,
    /// Inlier ratio of the last tracked frame against its keyframe.
    last_inlier_ratio: f64,
    stats: OdometryStats,
    /// Keyframe states joined by the IMU and by tracked relative poses.
    window: KeyframeWindow,
    /// Poses sent to the mapper are `mapper_from_world · T_world_cam`: the mapper's world is
    /// chained through the keyframes' corrected *relative* poses, so a keyframe the mapper holds
    /// never moves there; a new keyframe and its history frames are moved together by the
    /// window's correction. (The frames tracked next against the corrected previous keyframe
    /// carry that correction relative to the new one: this is how the IMU's scale reaches the
    /// maps. Sending the mapper the pure tracked chain instead let the map scale, and with it the
    /// velocity, drift on the demo.)
    mapper_from_world: Isometry3<f64>,
    /// Camera pose of the newest keyframe as the mapper holds it.
    mapper_kf_pose: Option<(u32, Isometry3<f64>)>,
    /// The tracked trajectory of the last seconds, for the map scale (`[scale_observer]`).
    scale: ScaleObserver,
    /// The position change tracking made on the current frame (before any correction).
    tracked_step_m: Option<Vector3<f64>>,
    /// The next frame is tracked against another keyframe than the last one was (a stored one,
    /// or back from it), whose pose disagrees with the chain's by the drift.
    keyframe_jump: bool,
    /// Per-pixel `1 / V` of the rig's vignetting (`[tracking] correct_vignetting`).
    vignette_gain: Option<Vec<f32>>,
}

impl Odometry {
    pub fn new(cfg: OdometryConfig, rig: Rig) -> Self {
        let vignette_gain = rig
            .vignette
            .filter(|_| cfg.tracking.correct_vignetting)
            .map(|v| v.correction_table(rig.camera.width, rig.camera.height));
        let tracker = Tracker::new(
            cfg.tracking.clone(),
            &rig.camera,
            rig.t_body_cam,
            rig.noise,
            rest_state(TimeNs(0), Default::default(), Default::default()),
            Matrix15::identity(),
        );
        let detector = StaticDetector::new(cfg.static_detector, &rig.noise);
        let mapping = MappingThread::spawn(
            cfg.mapping.clone(),
            rig.camera,
            MappingOptions {
                queue_len: cfg.bootstrap.queue_len,
                realtime: cfg.realtime,
                max_view_backlog: cfg.bootstrap.max_view_backlog,
                nice_increment: cfg.bootstrap.background_nice,
            },
        );
        let refiner = ((cfg.keyframe_bundle.enabled || cfg.bootstrap.refine_takeoff_passes > 0)
            && cfg.tracking.use_vision)
            .then(|| {
                RefinementThread::spawn(RefineSettings {
                    camera: rig.camera,
                    t_body_cam: rig.t_body_cam,
                    noise: rig.noise,
                    tracking: cfg.tracking.clone(),
                    keyframe_bundle: cfg.keyframe_bundle.clone(),
                    nice_increment: cfg.bootstrap.refinement_nice,
                })
            });
        Odometry {
            tracker,
            detector,
            mapping: Some(mapping),
            refiner,
            refining: None,
            catch_up: Vec::new(),
            refine_seq: 0,
            refine_outstanding: 0,
            imu: VecDeque::with_capacity(4096),
            scale: ScaleObserver::new(cfg.scale_observer),
            tracked_step_m: None,
            keyframe_jump: false,
            phase: Phase::WaitingForStart,
            last_t: None,
            seq: 0,
            awaited: VecDeque::new(),
            deferred_jobs: VecDeque::new(),
            frame_number: 0,
            tracking_kf: None,
            tracking_map: None,
            tracking_kf_filled: false,
            last_median_inv_depth: None,
            pending_kf: None,
            reusing: false,
            left_kf: None,
            reuse_previous: None,
            failed_reuse: Vec::new(),
            reuse_frames: 0,
            store: KeyframeStore::new(cfg.reuse.clone()),
            newest_kf: None,
            next_kf_id: 0,
            frames_since_refresh: 0,
            tracking_kf_points: 0,
            history: VecDeque::new(),
            static_frames: VecDeque::with_capacity(STATIC_FRAMES_KEPT),
            rest_estimates: VecDeque::with_capacity(STATIC_FRAMES_KEPT),
            init_started: None,
            takeoff: None,
            kf_record: None,
            tracking_kf_adjusted: false,
            guessed: None,
            guessed_snapshot: None,
            consecutive_flagged: 0,
            last_inlier_ratio: 1.0,
            stats: OdometryStats {
                vignette_corrected: vignette_gain.is_some(),
                ..Default::default()
            },
            window: KeyframeWindow::new(cfg.window.clone(), rig.noise),
            mapper_from_world: Isometry3::identity(),
            mapper_kf_pose: None,
            vignette_gain,
            cfg,
            rig,
        }
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }
    pub fn stats(&self) -> &OdometryStats {
        &self.stats
    }

    /// Starts from a known state (e.g. ground truth) instead of a detected rest: the next frame
    /// starts the first keyframe, posed by this state.
    pub fn set_start_state(&mut self, x: FrameState, cov: Matrix15) {
        self.tracker.reset_state(x, cov);
        self.last_t = Some(x.nav.t);
        self.phase = Phase::Initializing;
        self.init_started = Some(x.nav.t);
        if self.stats.onset_t.is_none() {
            self.stats.onset_t = Some(x.nav.t);
        }
    }

    /// Feeds one IMU sample (time ordered).
    pub fn push_imu(&mut self, s: &ImuSample) {
        if let Some(StaticEvent::MotionOnset(o)) = self.detector.push(s)
            && self.stats.onset_t.is_none()
        {
            self.stats.onset_t = Some(o.t_onset);
        }
        self.imu.push_back(*s);
        // Keep ~10 s: enough for any frame gap.
        while self.imu.len() > 2000 {
            self.imu.pop_front();
        }
    }

    /// Processes the frame at `t` (all IMU samples up to at least `t` pushed first).
    pub fn push_frame(&mut self, t: TimeNs, mut image: Image<u8>) -> OdometryFrame {
        if let Some(gain) = &self.vignette_gain
            && gain.len() == image.width() * image.height()
        {
            self.stats.vignette_saturated_px += correct_in_place(&mut image, gain) as u64;
        }
        self.frame_number += 1;
        self.tracked_step_m = None;
        self.send_deferred_jobs();
        self.collect_snapshots();
        self.collect_refinement();
        let image = Arc::new(image);
        let static_now = self.detector.is_static();
        let mut result = match self.phase {
            Phase::WaitingForStart | Phase::Static if static_now => self.hold_static(t, &image),
            Phase::WaitingForStart => {
                self.tracker.load_frame(&image);
                self.last_t = Some(t);
                let r = self.imu_only_result(t);
                return OdometryFrame {
                    result: r,
                    phase: Phase::WaitingForStart,
                    valid: false,
                    resets: self.stats.resets,
                };
            }
            Phase::Static => {
                // Motion began at the (back-dated) onset: integrate the IMU from the rest state
                // there, and make the last frame still at rest the first keyframe.
                if let Some(o) = self.detector.last_onset().copied() {
                    let margin_ns = (self.cfg.bootstrap.onset_margin_s * 1e9) as i64;
                    let t_rest = o.t_onset.add_ns(-margin_ns).max(o.estimate.t_start);
                    // The rest state from the estimate as it stood at `t_rest`: a smooth take-off
                    // accelerates for a few tenths of a second before the CUSUM alarms, and even
                    // the estimate frozen at the back-dated onset has averaged that into the
                    // accelerometer bias along gravity (+0.005 m/s² on the ideal demo take-off:
                    // a 1.5 % short baseline for the first map, whose scale every later map
                    // inherits).
                    let e = self
                        .rest_estimates
                        .iter()
                        .rev()
                        .find(|e| e.t_end <= t_rest && e.t_start == o.estimate.t_start)
                        .copied()
                        .unwrap_or(o.estimate);
                    let x = rest_state_from(&e, t_rest);
                    let cov = *self.tracker.covariance();
                    self.tracker.reset_state(x, cov);
                    if self.last_t.is_some_and(|lt| lt > t_rest) {
                        self.last_t = Some(t_rest);
                    }
                    while self.static_frames.len() > 1
                        && self.static_frames.back().is_some_and(|f| f.t > t_rest)
                    {
                        self.static_frames.pop_back();
                    }
                }
                if let Some(kf) = self.static_frames.pop_back() {
                    let rest = *self.tracker.state();
                    let mut x = rest;
                    x.nav.t = kf.t;
                    let cov = *self.tracker.covariance();
                    self.window.reset(self.next_kf_id, x, &cov);
                    self.takeoff =
                        (self.cfg.bootstrap.refine_takeoff_passes > 0).then(|| TakeoffRecord {
                            rest,
                            rest_cov: cov,
                            keyframe: kf.clone(),
                            keyframe_id: self.next_kf_id,
                            frames: Vec::new(),
                            passes: 0,
                        });
                    self.start_keyframe(kf, Vec::new(), false);
                }
                self.static_frames.clear();
                self.phase = Phase::Initializing;
                self.init_started = Some(t);
                self.track(t, &image)
            }
            Phase::Initializing | Phase::Tracking | Phase::Lost => self.track(t, &image),
        };
        // Phase transitions and jobs after tracking.
        let frame = MapFrame {
            t,
            image: image.clone(),
            t_world_cam: self.tracker.t_world_cam(),
        };
        match self.phase {
            Phase::Static | Phase::WaitingForStart => {}
            Phase::Initializing => {
                result.flag = None; // IMU-only while the first map grows: expected, not a failure
                let started = self.init_started.unwrap_or(t);
                // (Not while the first map is out for its take-off refinement: it has structure,
                // and in real time a pass over all the take-off's frames takes seconds.)
                if self.newest_kf.is_none()
                    || (t.secs_since(started) > self.cfg.bootstrap.max_init_s
                        && !self.refining_takeoff(None))
                {
                    // Not enough structure yet: restart the first map from here (no longer a
                    // take-off from rest).
                    self.takeoff = None;
                    self.reset_window();
                    self.start_keyframe(frame.clone(), Vec::new(), false);
                    self.init_started = Some(t);
                } else {
                    if let Some(tk) = self.takeoff.as_mut() {
                        tk.frames.push(frame.clone());
                    }
                    self.observe(frame.clone());
                }
            }
            Phase::Tracking => {
                self.last_inlier_ratio = result.inlier_ratio;
                if result.flag == Some(FlagReason::FewInliers) {
                    self.consecutive_flagged += 1;
                } else {
                    self.consecutive_flagged = 0;
                }
                if self.reusing {
                    // A stored keyframe is not there to be triangulated (a new one would only
                    // chain the drift again): the baseline and rotation limits of `[reuse]`.
                    self.reuse_frames += 1;
                    let r = &self.cfg.reuse;
                    result.wants_keyframe = self.tracker.wants_keyframe(
                        &result,
                        r.max_baseline_ratio,
                        r.max_rotation_rad,
                    );
                }
                let r = &self.cfg.reuse;
                if self.reusing
                    && self.reuse_frames <= r.probation_frames
                    && (result.flag == Some(FlagReason::FewInliers)
                        || result.inlier_ratio < r.probation_min_inlier_ratio)
                {
                    // The stored keyframe does not fit after all (occlusion, a different
                    // exposure, a bad map): back to the keyframe left.
                    self.return_from_stored_keyframe();
                } else if self.consecutive_flagged >= self.cfg.bootstrap.lost_after_frames {
                    self.phase = Phase::Lost;
                    self.lose_keyframe();
                    self.history.clear();
                    self.stats.resets += 1;
                } else if result.wants_keyframe
                    && result.flag.is_none()
                    && self.pending_kf.is_none()
                    && self.switch_to_stored_keyframe()
                {
                    // Tracking continues against a stored keyframe: nothing for the mapper.
                } else if result.wants_keyframe
                    && result.flag.is_none()
                    && self.pending_kf.is_none()
                    && !self.awaiting_guessed_adjustment()
                {
                    // (A keyframe already pending in the mapper is awaited, not replaced.)
                    let mut frame = frame.clone();
                    if let Some(c) = self.window_keyframe(&mut result) {
                        frame.t_world_cam = c * frame.t_world_cam;
                        for h in self.history.iter_mut() {
                            h.t_world_cam = c * h.t_world_cam;
                        }
                    }
                    if let Some(e) = self.scale.estimate(self.imu.make_contiguous()) {
                        self.stats.imu_scale.push(ScaleSample {
                            t,
                            scale: e.scale,
                            scale_std: e.scale_std,
                            rms_m: e.rms_m,
                        });
                    }
                    let history: Vec<MapFrame> = self.history.iter().cloned().collect();
                    let propagate = self.cfg.bootstrap.propagate_maps;
                    self.start_keyframe(frame, history, propagate);
                } else if result.flag.is_none() && (!self.reusing || self.pending_kf.is_some()) {
                    // (While a stored keyframe is tracked, the mapper's keyframe is the one left
                    // behind until a new one is started: frames corrected against the stored
                    // one would not fit its pose.)
                    if let Some(rec) = self.kf_record.as_mut()
                        && self.pending_kf == Some(rec.id)
                    {
                        rec.views.push((frame.clone(), *self.tracker.state()));
                    } else if let Some(rec) = self.guessed.as_mut()
                        && self.pending_kf.is_none()
                        && !self.reusing
                        && self.tracking_kf == Some(rec.id)
                    {
                        rec.views.push((frame.clone(), *self.tracker.state()));
                    }
                    self.observe(frame.clone());
                    self.adjust_guessed_keyframe();
                }
            }
            Phase::Lost => {
                let textured =
                    select_gradient_pixels(self.tracker.frame_pyramid(), &self.cfg.tracking).len();
                if textured >= self.cfg.bootstrap.min_texture_points {
                    self.reset_window();
                    self.start_keyframe(frame.clone(), Vec::new(), false);
                    self.phase = Phase::Initializing;
                    self.init_started = Some(t);
                }
            }
        }
        if static_now
            && matches!(
                self.phase,
                Phase::Tracking | Phase::Initializing | Phase::Lost
            )
        {
            self.zero_velocity_update(&mut result);
        }
        if self.phase == Phase::Tracking
            && self.adjusting_keyframe().is_some()
            && self.catch_up.len() < MAX_CATCH_UP_FRAMES
        {
            self.catch_up.push((t, image.clone()));
        }
        if self.phase == Phase::Tracking && result.flag.is_none() {
            let frame = MapFrame {
                t_world_cam: self.tracker.t_world_cam(),
                ..frame
            };
            self.history.push_front(frame);
            self.history.truncate(self.cfg.bootstrap.history_frames);
        }
        match (self.phase, self.tracked_step_m.take()) {
            (Phase::Tracking, Some(step)) => self.scale.push(result.state, step),
            _ => self.scale.clear(),
        }
        self.frames_since_refresh += 1;
        OdometryFrame {
            result,
            phase: self.phase,
            valid: true,
            resets: self.stats.resets,
        }
    }

    /// Stops the mapping thread and returns what it built.
    pub fn finish(mut self) -> (OdometryStats, MappingOutput) {
        if let Some(r) = self.refiner.take() {
            r.finish();
        }
        let out = self
            .mapping
            .take()
            .map(MappingThread::finish)
            .unwrap_or_default();
        (self.stats.clone(), out)
    }

    fn hold_static(&mut self, t: TimeNs, image: &Arc<Image<u8>>) -> TrackResult {
        let est = self.detector.estimate().copied();
        let x = match est {
            Some(e) => {
                if self.rest_estimates.len() == STATIC_FRAMES_KEPT {
                    self.rest_estimates.pop_front();
                }
                self.rest_estimates.push_back(e);
                rest_state_from(&e, t)
            }
            None => *self.tracker.state(),
        };
        let b = &self.cfg.bootstrap;
        let tilt = est
            .map_or(0.01, |e| e.tilt_sigma_rad)
            .max(b.rest_min_tilt_std_rad);
        let cov = static_covariance(tilt, b.rest_accel_bias_std_m_s2);
        self.tracker.reset_state(x, cov);
        self.tracker.load_frame(image);
        self.last_t = Some(t);
        self.phase = Phase::Static;
        if self.static_frames.len() == STATIC_FRAMES_KEPT {
            self.static_frames.pop_front();
        }
        self.static_frames.push_back(MapFrame {
            t,
            image: image.clone(),
            t_world_cam: self.tracker.t_world_cam(),
        });
        self.imu_only_result(t)
    }

    fn track(&mut self, t: TimeNs, image: &Image<u8>) -> TrackResult {
        let t0 = self.last_t.unwrap_or(t);
        let mut pre = Preintegration::new(t0, self.tracker.state().bias);
        // `integrate` finds the samples bracketing the interval itself.
        pre.integrate(self.imu.make_contiguous(), t, Some(&self.rig.noise));
        self.last_t = Some(t);
        let x0 = *self.tracker.state();
        let r = self.tracker.track(t, image, &pre);
        // The first frame on another keyframe jumps by the drift between the two: the IMU's
        // step stands in for it.
        let p1 = if std::mem::take(&mut self.keyframe_jump) {
            pre.predict(&x0.nav, &x0.bias).p_world_m
        } else {
            r.state.nav.p_world_m
        };
        self.tracked_step_m = Some(p1 - x0.nav.p_world_m);
        r
    }

    /// Sends one refinement pass of the take-off whose first map `kf` (snapshot `s`) is ready to
    /// the refinement thread; it will re-pose and rescale the views and the first map is started
    /// again from them. Returns whether it was sent (the map is then not installed yet).
    fn send_takeoff(&mut self, kf: &Keyframe, s: &MapSnapshot) -> bool {
        let b = &self.cfg.bootstrap;
        let Some(tk) = self.takeoff.as_ref().filter(|_| self.refiner.is_some()) else {
            return false;
        };
        if tk.keyframe_id != s.keyframe_id
            || tk.passes >= b.refine_takeoff_passes
            || tk.frames.len() > b.takeoff_max_pass_frames
        {
            return false; // done
        }
        let imu = imu_between(self.imu.make_contiguous(), tk.rest.nav.t, None);
        self.refine_seq += 1;
        let job = RefineJob::Takeoff(Box::new(TakeoffJob {
            seq: self.refine_seq,
            rec: tk.clone(),
            kf: kf.clone(),
            imu,
            rig: TakeoffRig {
                tracking: self.cfg.tracking.clone(),
                camera: self.rig.camera,
                t_body_cam: self.rig.t_body_cam,
                noise: self.rig.noise,
                prior: AlignmentPrior {
                    velocity_std_m_s: b.takeoff_velocity_std_m_s,
                    accel_std_m_s2: b.takeoff_accel_std_m_s2,
                    position_std_m: b.takeoff_position_std_m,
                },
                max_scale_correction: b.takeoff_max_scale_correction,
                min_significance_sigmas: b.takeoff_min_significance_sigmas,
                imu_noise_factor: b.takeoff_imu_noise_factor,
            },
            bundle: (b.takeoff_refinement == TakeoffRefinement::BundleAdjustment).then(|| {
                BundleConfig {
                    iterations_per_level: b.takeoff_bundle_iterations,
                    start_velocity_std_m_s: b.takeoff_velocity_std_m_s,
                    accel_bias_std_m_s2: b.takeoff_accel_std_m_s2,
                    smoothness_rel_std: b.takeoff_bundle_smoothness_rel_std,
                    ..BundleConfig::default()
                }
            }),
        }));
        let kind = PendingKind::Takeoff {
            keyframe_id: s.keyframe_id,
            frames_sent: tk.frames.len(),
            snapshot: s.clone(),
        };
        self.send_refinement(job, kind).is_ok()
    }

    /// Whether new keyframe `id`, ready to be installed, is to be adjusted first
    /// (`[keyframe_bundle]`): enough frames were tracked since it was started.
    fn keyframe_adjustable(&self, id: u32) -> bool {
        self.cfg.keyframe_bundle.enabled
            && self.refiner.is_some()
            && self.kf_record.as_ref().is_some_and(|r| {
                r.id == id && r.views.len() >= self.cfg.keyframe_bundle.min_views.max(1)
            })
    }

    /// Hands new keyframe `kf` (image pyramid `pyramid`, snapshot `s`) to the in-flight keyframe
    /// adjustment with the frames tracked since it was started; it is installed for tracking when
    /// the adjustment is back. `Err(kf)` if it was not sent (thread busy in real time).
    fn send_keyframe_adjustment(
        &mut self,
        kf: Keyframe,
        pyramid: Pyramid,
        s: &MapSnapshot,
    ) -> Result<(), Box<Keyframe>> {
        let Some(rec) = self.kf_record.take() else {
            return Err(Box::new(kf));
        };
        self.send_keyframe_job(rec, kf, pyramid, s.clone(), false)
    }

    /// Hands keyframe `kf` (image pyramid `pyramid`, snapshot `s`) with the views of `rec` to the
    /// keyframe adjustment: a new keyframe, or the `tracked` one installed with guessed depths
    /// (adjusted with its depths free). `Err(kf)` if it was not sent (no views, or the thread busy
    /// in real time).
    fn send_keyframe_job(
        &mut self,
        rec: KeyframeRecord,
        kf: Keyframe,
        pyramid: Pyramid,
        s: MapSnapshot,
        tracked: bool,
    ) -> Result<(), Box<Keyframe>> {
        let Some(tracked_last) = rec.views.last().map(|v| v.1) else {
            return Err(Box::new(kf));
        };
        let imu = imu_between(
            self.imu.make_contiguous(),
            rec.start.nav.t,
            Some(tracked_last.nav.t),
        );
        self.refine_seq += 1;
        let job = RefineJob::Keyframe(Box::new(KeyframeJob {
            seq: self.refine_seq,
            rec,
            kf: kf.clone(),
            pyramid,
            imu,
            free_depths: tracked,
        }));
        let kind = PendingKind::Keyframe {
            tracked_last,
            unadjusted: Box::new(kf),
            snapshot: s,
            tracked,
        };
        self.send_refinement(job, kind).map_err(|kind| match *kind {
            PendingKind::Keyframe { unadjusted, .. } => unadjusted,
            PendingKind::Takeoff { .. } => unreachable!("sent as a keyframe adjustment"),
        })
    }

    /// Queues `job` (offline waiting for room, real time only if there is room) and awaits it.
    /// At most one job is out at a time (so neither queue can fill up and block): an earlier one
    /// still out is superseded — offline its outcome is awaited and dropped, in real time the new
    /// job is dropped while the thread is busy. Not sent: `kind` is handed back.
    fn send_refinement(
        &mut self,
        job: RefineJob,
        kind: PendingKind,
    ) -> Result<(), Box<PendingKind>> {
        let Some(refiner) = &self.refiner else {
            return Err(Box::new(kind));
        };
        while self.refine_outstanding > 0 && refiner.next_outcome(!self.cfg.realtime).is_some() {
            self.refine_outstanding -= 1;
        }
        let sent = self.refine_outstanding == 0
            && if self.cfg.realtime {
                refiner.try_send(job)
            } else {
                refiner.send(job)
            };
        if !sent {
            self.stats.refinements_dropped += 1;
            return Err(Box::new(kind));
        }
        let seq = self.refine_seq;
        self.refine_outstanding = 1;
        if self.refining.is_some() {
            self.stats.refinements_discarded += 1; // superseded before it came back
        }
        self.catch_up.clear();
        self.refining = Some(PendingRefinement {
            seq,
            frame_number: self.frame_number,
            kind,
        });
        Ok(())
    }

    /// Takes the awaited refinement's outcome a fixed number of frames after it was sent
    /// (`[keyframe_bundle] lag_frames`, `[bootstrap] takeoff_lag_frames`): offline waiting for it,
    /// in real time if it has arrived by then.
    fn collect_refinement(&mut self) {
        let Some(refiner) = &self.refiner else {
            return;
        };
        let Some(p) = &self.refining else {
            // Real time: an outcome of a superseded job is taken off the queue.
            while self.refine_outstanding > 0 && self.cfg.realtime && refiner.try_recv().is_some() {
                self.refine_outstanding -= 1;
            }
            return;
        };
        let lag = match p.kind {
            PendingKind::Keyframe { .. } => self.cfg.keyframe_bundle.lag_frames,
            PendingKind::Takeoff { .. } => self.cfg.bootstrap.takeoff_lag_frames,
        };
        if self.frame_number < p.frame_number + lag {
            return; // not before its lag, however early it is ready
        }
        let want = p.seq;
        let mut outcome = None;
        while let Some(o) = refiner.next_outcome(!self.cfg.realtime) {
            self.refine_outstanding = self.refine_outstanding.saturating_sub(1);
            if o.seq == want {
                outcome = Some(o);
                break;
            }
            // (An older job's, superseded meanwhile: counted when it was.)
        }
        let Some(o) = outcome else {
            // Real time, not back yet: if the keyframe tracked meanwhile is being lost, the new
            // one is installed as the mapper built it (its adjustment is dropped).
            if self.phase == Phase::Tracking
                && gives_up_adjustment(self.last_inlier_ratio, &self.cfg.keyframe_bundle)
                && let Some(PendingRefinement {
                    kind:
                        PendingKind::Keyframe {
                            unadjusted,
                            snapshot,
                            tracked: false,
                            ..
                        },
                    ..
                }) = self
                    .refining
                    .take_if(|p| matches!(p.kind, PendingKind::Keyframe { .. }))
            {
                self.catch_up.clear();
                self.stats.refinements_discarded += 1;
                if self.pending_kf == Some(snapshot.keyframe_id) {
                    self.install_keyframe(*unadjusted, &snapshot, true, false, false);
                }
            }
            return;
        };
        let Some(p) = self.refining.take() else {
            return;
        };
        let catch_up = std::mem::take(&mut self.catch_up);
        match (o.result, p.kind) {
            (
                RefineResult::Keyframe(adjusted),
                PendingKind::Keyframe {
                    tracked_last,
                    unadjusted,
                    snapshot,
                    tracked,
                },
            ) => self.apply_keyframe_adjustment(
                adjusted,
                (*unadjusted, &snapshot, tracked),
                &tracked_last,
                &catch_up,
                o.time_s,
            ),
            (
                RefineResult::Takeoff(refined),
                PendingKind::Takeoff {
                    keyframe_id,
                    frames_sent,
                    snapshot,
                },
            ) => self.apply_takeoff(refined, keyframe_id, frames_sent, &snapshot, o.time_s),
            _ => {} // (a job and its outcome are always of the same kind)
        }
    }

    /// The adjustment of the new keyframe of `snapshot` is back: the keyframe is installed (as
    /// the mapper built it if the adjustment failed) and tracking continues from the last view's
    /// adjusted state, the frames tracked since against the old keyframe (`catch_up`) tracked again
    /// against the new one (too many of them: the current state is moved by the last view's
    /// correction instead).
    fn apply_keyframe_adjustment(
        &mut self,
        adjusted: Option<ReadyKeyframe>,
        (unadjusted, snapshot, tracked): (Keyframe, &MapSnapshot, bool),
        tracked_last: &FrameState,
        catch_up: &[(TimeNs, Arc<Image<u8>>)],
        time_s: f64,
    ) {
        let id = snapshot.keyframe_id;
        let current = if tracked {
            self.pending_kf.is_none() && self.tracking_kf == Some(id) && !self.reusing
        } else {
            self.pending_kf == Some(id)
        };
        if !(self.phase == Phase::Tracking && current) {
            self.stats.refinements_discarded += 1; // lost meanwhile
            return;
        }
        let Some(a) = adjusted.filter(|a| {
            a.last_view.is_finite()
                && a.median_inv_depth_ratio.is_finite()
                && a.median_inv_depth_ratio > 0.0
        }) else {
            if !tracked {
                self.install_keyframe(unadjusted, snapshot, true, false, false);
            }
            return;
        };
        if tracked {
            // The whole keyframe was mapped at the scale of the guesses: the mapper's copy, the
            // installed map and the frames kept for the next keyframe are rescaled about its
            // camera with the adjustment's median change (the tracker continues from the last
            // view's adjusted state below).
            let factor = a.median_inv_depth_ratio;
            let seq = self.next_seq();
            self.send(MapJob::ScaleDepths { seq, id, factor });
            let centre = unadjusted.t_world_cam.translation.vector;
            for h in self.history.iter_mut() {
                let p = &mut h.t_world_cam.translation.vector;
                *p = centre + (*p - centre) / factor;
            }
            let mut map = (*snapshot.map).clone();
            map.scale_inv_depths(factor);
            let snapshot = MapSnapshot {
                map: Arc::new(map),
                ..snapshot.clone()
            };
            self.install_keyframe(a.keyframe, &snapshot, false, false, true);
            self.tracking_kf_adjusted = true;
            self.stats.guessed_keyframe_scales.push(1.0 / factor);
        } else {
            self.install_keyframe(a.keyframe, snapshot, true, false, true);
        }
        let cov = *self.tracker.covariance();
        if catch_up.len() < MAX_CATCH_UP_FRAMES {
            let state_now = *self.tracker.state();
            let last_t = self.last_t;
            self.tracker.reset_state(a.last_view, cov);
            self.last_t = Some(a.last_view.nav.t);
            let mut poses = Vec::with_capacity(catch_up.len());
            for (t, image) in catch_up {
                self.track(*t, image);
                poses.push((*t, self.tracker.t_world_cam()));
            }
            if self.tracker.state().is_finite() {
                // The frames kept for the next keyframe get their new poses.
                for h in self.history.iter_mut() {
                    if let Some((_, p)) = poses.iter().find(|(t, _)| *t == h.t) {
                        h.t_world_cam = *p;
                    }
                }
            } else {
                self.tracker.reset_state(state_now, cov);
                self.last_t = last_t;
            }
            self.stats.catch_up_frames += catch_up.len();
        } else {
            let x = carry_correction(self.tracker.state(), tracked_last, &a.last_view);
            if x.is_finite() {
                self.tracker.reset_state(x, cov);
            }
        }
        self.stats.keyframe_bundle_s.push(time_s);
        self.stats
            .keyframe_bundle_depth_changes
            .push(a.median_inv_depth_change);
    }

    /// A take-off refinement pass is back: the first map is started again from the refined views
    /// (and the frames dead-reckoned since, re-predicted from the refined state); a failed pass
    /// installs the first map as it was.
    fn apply_takeoff(
        &mut self,
        refined: Option<RefinedTakeoff>,
        keyframe_id: u32,
        frames_sent: usize,
        snapshot: &MapSnapshot,
        time_s: f64,
    ) {
        if self.phase != Phase::Initializing
            || self.takeoff.as_ref().map(|t| t.keyframe_id) != Some(keyframe_id)
        {
            self.stats.refinements_discarded += 1; // the first map was restarted meanwhile
            return;
        }
        let Some(r) = refined else {
            if let Some(tk) = self.takeoff.as_mut() {
                tk.passes = u32::MAX; // no further pass: install it now
            }
            self.apply_snapshot(snapshot);
            return;
        };
        let Some(mut tk) = self.takeoff.take() else {
            return;
        };
        // The tracker continues from the refined state on the IMU until the new map is ready.
        let mut x = r.last;
        let mut views = r.views;
        for f in tk.frames.iter().skip(frames_sent) {
            x = self.dead_reckon(&x, f.t);
            views.push(MapFrame {
                t_world_cam: pose_of(&x) * self.rig.t_body_cam,
                ..f.clone()
            });
        }
        let t_now = self.tracker.state().nav.t;
        if x.nav.t < t_now {
            x = self.dead_reckon(&x, t_now);
        }
        let cov = *self.tracker.covariance();
        self.tracker.reset_state(x, cov);
        let mut x0 = r.rest;
        x0.nav.t = tk.keyframe.t;
        self.window.reset(self.next_kf_id, x0, &tk.rest_cov);
        tk.rest = r.rest;
        tk.keyframe_id = self.next_kf_id;
        tk.passes += 1;
        tk.frames = views.clone();
        self.start_keyframe(tk.keyframe.clone(), views, false);
        // The first map starts again: it gets the whole `max_init_s` to grow.
        self.init_started = self.last_t;
        self.stats.takeoff_scales.push(r.scale);
        self.stats.takeoff_refinement_s.push(time_s);
        self.takeoff = Some(tk);
    }

    /// `x` predicted by the IMU to `t`, as the tracker does without a map.
    fn dead_reckon(&mut self, x: &FrameState, t: TimeNs) -> FrameState {
        let mut pre = Preintegration::new(x.nav.t, x.bias);
        pre.integrate(self.imu.make_contiguous(), t, None); // (the mean only)
        FrameState {
            nav: pre.predict(&x.nav, &x.bias),
            bias: x.bias,
        }
    }

    /// Restarts the keyframe window at the keyframe about to be started, from the tracker's
    /// state and covariance.
    fn reset_window(&mut self) {
        let x = *self.tracker.state();
        let cov = *self.tracker.covariance();
        self.window.reset(self.next_kf_id, x, &cov);
    }

    /// Adds the frame of `result` (about to become keyframe `next_kf_id`) to the window, joined to
    /// the keyframe it was tracked against, solves, and moves the tracker's keyframe and state onto
    /// the solution. Returns the world correction applied to the current frame
    /// (`T_new = C · T_old`), `None` if the window is off or could not be used.
    fn window_keyframe(&mut self, result: &mut TrackResult) -> Option<Isometry3<f64>> {
        let id = self.next_kf_id;
        if !self.cfg.window.enabled {
            return None;
        }
        let t = result.t;
        let Some((newest, x_prev)) = self.window.newest().map(|(i, x)| (i, *x)) else {
            self.reset_window();
            return None;
        };
        let buffered_from = self.imu.front().map(|s| s.t);
        if self.tracking_kf != Some(newest) || buffered_from.is_none_or(|t0| t0 > x_prev.nav.t) {
            // Tracked against a stored keyframe (its correction of the drift would fight the
            // window's older keyframes), or the IMU since the last keyframe is no longer
            // buffered: restart the window here.
            self.reset_window();
            return None;
        }
        let mut pre = Preintegration::new(x_prev.nav.t, x_prev.bias);
        pre.integrate(self.imu.make_contiguous(), t, Some(&self.rig.noise));
        let visual = match self.tracker.keyframe() {
            Some(kf) if kf.id == newest => {
                let t_w_bk = kf.t_world_cam * self.rig.t_body_cam.inverse();
                Some(RelativePose {
                    t_i_j: t_w_bk.inverse() * pose_of(&result.state),
                    information: result.photometric_info,
                })
            }
            _ => None,
        };
        let old = result.state;
        self.window.push(id, old, pre, visual);
        let started = std::time::Instant::now();
        self.window.solve();
        let solve_s = started.elapsed().as_secs_f64();
        self.stats.window_solve_s.push(solve_s);
        // The frame's tracking-thread time includes the window it triggered.
        result.time_s += solve_s;

        let (_, x_new) = self.window.newest()?;
        let mut x_new = *x_new;
        x_new.nav.t = t;
        if !x_new.is_finite() {
            self.reset_window();
            return None;
        }
        let correction = pose_of(&x_new) * pose_of(&old).inverse();
        let cov = *self.tracker.covariance();
        self.tracker.reset_state(x_new, cov);
        if let Some(xk) = self.window.state(newest) {
            self.tracker
                .set_keyframe_pose(pose_of(xk) * self.rig.t_body_cam);
        }
        // Stored keyframes still in the window move with it.
        for (id, x) in self.window.states() {
            self.store.set_pose(id, pose_of(x) * self.rig.t_body_cam);
        }
        result.state = x_new;
        Some(correction)
    }

    /// The IMU says the vehicle rests: if the estimated speed is small enough to be drift, the
    /// velocity is set to zero (`zupt_*` of `[bootstrap]`).
    fn zero_velocity_update(&mut self, result: &mut TrackResult) {
        let b = &self.cfg.bootstrap;
        let mut x = *self.tracker.state();
        let speed_m_s = x.nav.v_world_m_s.norm();
        if speed_m_s.is_nan() || speed_m_s >= b.zupt_max_speed_m_s {
            return;
        }
        x.nav.v_world_m_s = Vector3::zeros();
        let mut cov = *self.tracker.covariance();
        for i in 6..9 {
            for j in 0..15 {
                cov[(i, j)] = 0.0;
                cov[(j, i)] = 0.0;
            }
            cov[(i, i)] = b.zupt_velocity_std_m_s.powi(2);
        }
        self.tracker.reset_state(x, cov);
        result.state.nav.v_world_m_s = Vector3::zeros();
        self.stats.zero_velocity_updates += 1;
    }

    /// Tracking is lost: no keyframe until a new one is installed.
    fn lose_keyframe(&mut self) {
        self.tracker.clear_keyframe();
        self.tracking_kf = None;
        self.tracking_map = None;
        self.reusing = false;
        self.reuse_previous = None;
    }

    /// The tracker asks for a new keyframe: if a stored keyframe (not the one tracked, not one
    /// of the window) covers the current view, track against it instead. Its pose is that of an
    /// earlier, less drifted map, so the current pose is made uncertain enough for the next
    /// frames to be pulled onto it. Returns whether it switched.
    fn switch_to_stored_keyframe(&mut self) -> bool {
        if !self.cfg.reuse.enabled || self.store.is_empty() {
            return false;
        }
        let t_world_cam = self.tracker.t_world_cam();
        let current = self.tracking_kf;
        let (window, failed) = (&self.window, &self.failed_reuse);
        let Some((id, _overlap)) =
            self.store
                .closest(&t_world_cam, self.cfg.tracking.border_px, |id| {
                    Some(id) == current || window.state(id).is_some() || failed.contains(&id)
                })
        else {
            return false;
        };
        let Some(stored) = self.store.get(id).cloned() else {
            return false;
        };
        let previous_fits = self.reuse_frames > self.cfg.reuse.probation_frames
            && self.last_inlier_ratio >= self.cfg.reuse.probation_min_inlier_ratio;
        let previous = self.tracker.set_keyframe(stored.kf);
        self.reuse_previous = None;
        if let (Some(kf), Some(map)) = (previous, self.tracking_map.take()) {
            if !self.reusing {
                self.store_keyframe(kf.clone(), map.clone());
                self.left_kf = Some(StoredKeyframe { kf, map });
            } else if previous_fits {
                self.reuse_previous = Some(StoredKeyframe { kf, map });
            }
        }
        self.tracking_map = Some(stored.map);
        self.tracking_kf = Some(id);
        self.frames_since_refresh = 0;
        self.reuse_frames = 0;
        // Frames since the last keyframe carry the drift the stored keyframe corrects.
        self.history.clear();
        if !self.reusing {
            // Leaving the chain of new keyframes: the stored keyframes agree with each other,
            // not with the drift of the chain. Position and heading drift; tilt does not
            // (gravity observes it), so a stored keyframe may move the first two only.
            let r = &self.cfg.reuse;
            let x = *self.tracker.state();
            let mut cov = *self.tracker.covariance();
            // World vertical in the body frame: the axis of a heading change.
            let a = x.nav.r_world_body.inverse() * Vector3::z();
            let yaw = a * a.transpose() * r.switch_yaw_std_rad.powi(2);
            for i in 0..3 {
                for j in 0..3 {
                    cov[(i, j)] += yaw[(i, j)];
                }
                cov[(i + 3, i + 3)] += r.switch_position_std_m.powi(2);
            }
            self.tracker.reset_state(x, cov);
        }
        self.reusing = true;
        self.keyframe_jump = true;
        self.stats.keyframe_reuses += 1;
        true
    }

    /// Keeps the tracking keyframe `kf` (with its map), which is being left, for returning to it
    /// — unless it was tracked with guessed depths: that is no place to return to.
    fn store_keyframe(&mut self, kf: Keyframe, map: Arc<SemidenseMap>) {
        if self.cfg.reuse.enabled && !self.tracking_kf_filled && self.store.insert(kf, map) {
            self.stats.keyframes_stored = self.store.len();
        }
    }

    /// A stored keyframe lost track: mark it failed and track the keyframe left for it again.
    fn return_from_stored_keyframe(&mut self) {
        if let Some(id) = self.tracking_kf {
            self.failed_reuse.push(id);
        }
        self.stats.keyframe_reuse_failures += 1;
        if let Some(s) = self.reuse_previous.take() {
            // Back to the stored keyframe tracked before (still reusing, on probation again):
            // after a chain of stored keyframes the one left in the chain of new keyframes may
            // be seconds behind and out of view.
            self.track_again(s);
            self.reuse_frames = 0;
            return;
        }
        match self.left_kf.take() {
            Some(s) => {
                self.track_again(s);
                self.reusing = false;
            }
            None => {
                // (Not reached: a switch always leaves a keyframe behind.)
                self.lose_keyframe();
                self.phase = Phase::Lost;
                self.stats.resets += 1;
            }
        }
    }

    /// Tracks keyframe `s` again (gone back to after a stored keyframe failed).
    fn track_again(&mut self, s: StoredKeyframe) {
        self.tracking_kf = Some(s.kf.id);
        self.tracker.set_keyframe(s.kf);
        self.tracking_map = Some(s.map);
        self.history.clear();
        self.keyframe_jump = true;
        self.consecutive_flagged = 0;
    }

    fn imu_only_result(&self, t: TimeNs) -> TrackResult {
        self.tracker.untracked_result(t)
    }

    fn next_seq(&mut self) -> u64 {
        self.seq += 1;
        self.seq
    }

    fn send(&mut self, job: MapJob) {
        let Some(m) = &self.mapping else { return };
        if !self.cfg.realtime {
            let seq = job.seq();
            if m.jobs.send(job).is_ok() {
                self.awaited.push_back((self.frame_number, seq));
            }
            return;
        }
        // Real time: never wait. A keyframe job may not be dropped (the tracker would wait for a
        // keyframe the mapper never heard of): it queues here behind any held back before it. A
        // view goes only if none is held back and the mapper's queue has room.
        if !matches!(job, MapJob::Observe { .. }) {
            self.deferred_jobs.push_back(job);
            self.send_deferred_jobs();
            return;
        }
        self.send_deferred_jobs();
        let sent = self.deferred_jobs.is_empty()
            && self
                .mapping
                .as_ref()
                .is_some_and(|m| m.jobs.try_send(job).is_ok());
        if !sent {
            self.stats.jobs_dropped += 1;
        }
    }

    /// Real time: sends the keyframe jobs that found the mapper's queue full, in order, while
    /// there is room.
    fn send_deferred_jobs(&mut self) {
        let Some(m) = &self.mapping else { return };
        while let Some(job) = self.deferred_jobs.pop_front() {
            match m.jobs.try_send(job) {
                Ok(()) => {}
                Err(crossbeam_channel::TrySendError::Full(job)) => {
                    self.deferred_jobs.push_front(job);
                    return;
                }
                Err(crossbeam_channel::TrySendError::Disconnected(_)) => {
                    self.deferred_jobs.clear();
                    return;
                }
            }
        }
    }

    fn start_keyframe(&mut self, frame: MapFrame, history: Vec<MapFrame>, propagate: bool) {
        // Chain the mapper's world through the previous keyframe's corrected pose.
        if let Some((prev, m_prev)) = self.mapper_kf_pose
            && let Some(x) = self.window.state(prev)
        {
            let p_prev = pose_of(x) * self.rig.t_body_cam;
            self.mapper_from_world = m_prev * p_prev.inverse();
        }
        let d = self.mapper_from_world;
        // Started while tracking a stored keyframe: its map seeds the new one (the mapper's own
        // keyframe is the one left behind).
        let seed = self
            .reusing
            .then(|| {
                let id = self.tracking_kf?;
                let s = self.store.get(id)?;
                let mut m = (*s.map).clone();
                m.t_world_cam = d * s.kf.t_world_cam;
                Some(Arc::new(m))
            })
            .flatten();
        let frame = MapFrame {
            t_world_cam: d * frame.t_world_cam,
            ..frame
        };
        let history = history
            .into_iter()
            .map(|h| MapFrame {
                t_world_cam: d * h.t_world_cam,
                ..h
            })
            .collect();
        let id = self.next_kf_id;
        self.kf_record =
            (self.phase == Phase::Tracking && self.cfg.keyframe_bundle.enabled).then(|| {
                KeyframeRecord {
                    id,
                    start: *self.tracker.state(),
                    views: Vec::new(),
                }
            });
        self.mapper_kf_pose = Some((id, frame.t_world_cam));
        self.next_kf_id += 1;
        self.newest_kf = Some(id);
        self.pending_kf = Some(id);
        self.stats.keyframes += 1;
        let b = &self.cfg.bootstrap;
        let range =
            (!propagate).then_some((b.init_inv_depth_min_m_inv, b.init_inv_depth_max_m_inv));
        let seq = self.next_seq();
        self.send(MapJob::NewKeyframe {
            seq,
            id,
            frame,
            history,
            propagate,
            seed,
            inv_depth_range_m_inv: range,
        });
    }

    /// Hands the tracked keyframe installed with guessed depths (`guessed`) to the keyframe
    /// adjustment, depths free, once the mapper has built its map and the frames tracked since it
    /// was started span `[keyframe_bundle] guessed_min_baseline_ratio` × its median depth (at most
    /// `guessed_max_views` of them, evenly spaced). Those frames were tracked against guesses,
    /// and the map against them: the IMU between them is what gives the keyframe its scale.
    fn adjust_guessed_keyframe(&mut self) {
        let Some(rec) = &self.guessed else { return };
        if self.tracking_kf != Some(rec.id) || self.reusing || self.phase != Phase::Tracking {
            self.guessed = None;
            self.guessed_snapshot = None;
            return;
        }
        let cfg = &self.cfg.keyframe_bundle;
        let Some(kf) = self.tracker.keyframe() else {
            return;
        };
        let span_m = rec
            .views
            .iter()
            .map(|(_, x)| (x.nav.p_world_m - rec.start.nav.p_world_m).norm())
            .fold(0.0, f64::max);
        if self.tracking_kf_filled
            || self.guessed_snapshot.is_none()
            || self.pending_kf.is_some()
            || self.refining.is_some()
            || rec.views.len() < cfg.min_views.max(1)
            || span_m < cfg.guessed_min_baseline_ratio * kf.median_depth_m
        {
            return;
        }
        let kf = kf.clone();
        let max_views = cfg.guessed_max_views.max(1);
        let (Some(mut rec), Some(s)) = (self.guessed.take(), self.guessed_snapshot.take()) else {
            return;
        };
        let n = rec.views.len();
        if n > max_views {
            // Evenly spaced, the newest included.
            let keep: Vec<usize> = (1..=max_views).map(|k| k * n / max_views - 1).collect();
            rec.views = keep.into_iter().map(|i| rec.views[i].clone()).collect();
        }
        let pyramid = Pyramid::from_u8(&s.keyframe_image, NUM_LEVELS);
        // (Not sent — real time, thread busy: the keyframe stays as the mapper built it.)
        let _ = self.send_keyframe_job(rec, kf, pyramid, s, true);
    }

    /// The tracked keyframe's adjustment with its depths free is under way (real time: it takes
    /// ~1 s) and the keyframe still tracks well: no new keyframe is started until it is back —
    /// one started now would be mapped at the scale the adjustment is about to correct, and the
    /// adjustment would be discarded as superseded. (Offline it is back before the next frame.)
    fn awaiting_guessed_adjustment(&self) -> bool {
        self.last_inlier_ratio >= self.cfg.bootstrap.urgent_inlier_ratio
            && self
                .refining
                .as_ref()
                .is_some_and(|p| matches!(p.kind, PendingKind::Keyframe { tracked: true, .. }))
    }

    /// A take-off refinement pass is under way (of first map `id`, if given).
    fn refining_takeoff(&self, id: Option<u32>) -> bool {
        self.refining.as_ref().is_some_and(|p| match p.kind {
            PendingKind::Takeoff { keyframe_id, .. } => id.is_none_or(|id| id == keyframe_id),
            PendingKind::Keyframe { .. } => false,
        })
    }

    /// The keyframe whose adjustment is under way, if any.
    fn adjusting_keyframe(&self) -> Option<u32> {
        match &self.refining.as_ref()?.kind {
            PendingKind::Keyframe { snapshot, .. } => Some(snapshot.keyframe_id),
            PendingKind::Takeoff { .. } => None,
        }
    }

    fn observe(&mut self, frame: MapFrame) {
        let frame = MapFrame {
            t_world_cam: self.mapper_from_world * frame.t_world_cam,
            ..frame
        };
        let seq = self.next_seq();
        self.send(MapJob::Observe { seq, frame });
    }

    /// Takes the mapper's snapshots: offline, exactly those of the jobs sent at least
    /// `offline_lag_frames` frames ago (waiting for them); real-time, whatever has arrived.
    /// Installs or refreshes the tracking keyframe.
    fn collect_snapshots(&mut self) {
        let mut latest: Option<MapSnapshot> = None;
        let lag = self.cfg.bootstrap.offline_lag_frames.max(1);
        if let Some(m) = &self.mapping {
            if self.cfg.realtime {
                while let Ok(s) = m.snapshots.try_recv() {
                    latest = Some(s);
                }
            } else {
                let mut want = None;
                while self
                    .awaited
                    .front()
                    .is_some_and(|(f, _)| f + lag <= self.frame_number)
                {
                    want = self.awaited.pop_front().map(|(_, seq)| seq);
                }
                if let Some(want) = want {
                    while let Ok(s) = m.snapshots.recv() {
                        let done = s.seq >= want;
                        latest = Some(s);
                        if done {
                            break;
                        }
                    }
                }
            }
        }
        if let Some(s) = latest {
            self.apply_snapshot(&s);
        }
    }

    fn apply_snapshot(&mut self, s: &MapSnapshot) {
        let is_new = self.pending_kf == Some(s.keyframe_id);
        let is_refresh = self.pending_kf.is_none() && self.tracking_kf == Some(s.keyframe_id);
        if !(is_new || is_refresh) {
            return; // a keyframe that has been superseded already, or left for a stored one
        }
        if self.refining_takeoff(Some(s.keyframe_id))
            || self.adjusting_keyframe() == Some(s.keyframe_id)
        {
            // The first map is waiting for its take-off refinement, the keyframe for its
            // adjustment.
            return;
        }
        let n = s.map.points.len();
        // A keyframe whose map covers little of its image (started in a turn on the spot, where
        // nothing can be triangulated) is tracked with its other gradient pixels too, at the
        // map's median depth: their photometric residuals constrain the rotation, which is what
        // changes, whatever their depth. Such a keyframe is installed at once: waiting for
        // forward views adds no parallax in a turn on the spot.
        let b = &self.cfg.bootstrap;
        // Turned on the spot: the new keyframe is barely displaced from the one tracked.
        let on_the_spot = self.tracker.keyframe().is_some_and(|k| {
            let new_pose = self.mapper_from_world.inverse() * s.map.t_world_cam;
            let d = (new_pose.translation.vector - k.t_world_cam.translation.vector).norm();
            d < b.fill_max_baseline_ratio * k.median_depth_m
        });
        let pyramid = || Pyramid::from_u8(&s.keyframe_image, NUM_LEVELS);
        let fill = if self.phase == Phase::Tracking
            && is_new
            && on_the_spot
            && n < b.fill_depthless_below_points
            && let Some(median_inv) = median_inv_depth(&s.map).or(self.last_median_inv_depth)
        {
            let pyr = pyramid();
            let f = depthless_points(&pyr, &s.map, median_inv, &self.cfg.tracking);
            Some((pyr, f))
        } else {
            None
        };
        let n_fill = fill.as_ref().map_or(0, |f| f.1.len());
        let install = match self.phase {
            Phase::Initializing => {
                let mut depths: Vec<f32> = s
                    .map
                    .points
                    .iter()
                    .map(|p| 1.0 / p.inv_depth_m_inv)
                    .collect();
                let median_depth_m = if depths.is_empty() {
                    f64::INFINITY
                } else {
                    let m = depths.len() / 2;
                    *depths.select_nth_unstable_by(m, f32::total_cmp).1 as f64
                };
                let kf_world = self.mapper_from_world.inverse() * s.map.t_world_cam;
                let baseline_m = (self.tracker.t_world_cam().translation.vector
                    - kf_world.translation.vector)
                    .norm();
                n >= self.cfg.bootstrap.min_initial_points
                    && baseline_m >= self.cfg.bootstrap.min_init_baseline_ratio * median_depth_m
            }
            Phase::Tracking if is_new => {
                n + n_fill >= self.cfg.bootstrap.min_keyframe_points
                    && (fill.is_some()
                        || new_keyframe_ready(
                            &self.cfg.bootstrap,
                            self.cfg.realtime,
                            self.last_inlier_ratio,
                            s.forward_views,
                            self.keyframe_adjustable(s.keyframe_id),
                        ))
            }
            Phase::Tracking => {
                // (A keyframe tracked with guessed depths keeps them until its own map is full.)
                !self.tracking_kf_adjusted
                    && self.frames_since_refresh >= self.cfg.bootstrap.refresh_every_frames
                    && n > self.tracking_kf_points + self.tracking_kf_points / 10
                    && (!self.tracking_kf_filled
                        || n >= self.cfg.bootstrap.fill_depthless_below_points)
            }
            _ => false,
        };
        if !install {
            return;
        }
        let mut pts: Vec<DepthPoint> = s
            .map
            .points
            .iter()
            .map(|p| DepthPoint {
                u_px: p.u_px,
                v_px: p.v_px,
                inv_depth_m_inv: p.inv_depth_m_inv,
            })
            .collect();
        let filled = fill.is_some();
        let pyr = match fill {
            Some((pyr, f)) => {
                pts.extend(f);
                pyr
            }
            None => pyramid(),
        };
        let kf = Keyframe::new(
            s.keyframe_id,
            s.keyframe_t,
            &pyr,
            &self.rig.camera,
            self.mapper_from_world.inverse() * s.map.t_world_cam,
            &pts,
            &self.cfg.tracking,
        );
        if self.phase == Phase::Initializing && self.send_takeoff(&kf, s) {
            return; // the first map will be triangulated again from the refined take-off
        }
        let kf = if self.phase == Phase::Tracking
            && is_new
            && !filled
            && self.keyframe_adjustable(s.keyframe_id)
        {
            match self.send_keyframe_adjustment(kf, pyr, s) {
                Ok(()) => return, // installed when the adjustment is back
                Err(kf) => *kf,
            }
        } else {
            kf
        };
        self.install_keyframe(kf, s, is_new, filled, false);
    }

    /// Makes `kf` (of snapshot `s`) the keyframe tracked against: a new one (`is_new`) or a refresh
    /// of the current one; `filled` with depthless pixels, `adjusted` by the keyframe adjustment.
    fn install_keyframe(
        &mut self,
        kf: Keyframe,
        s: &MapSnapshot,
        is_new: bool,
        filled: bool,
        adjusted: bool,
    ) {
        let n = s.map.points.len();
        self.takeoff = None;
        let kf_median_depth_m = kf.median_depth_m;
        // A refresh of the same keyframe keeps the brightness estimate.
        let previous = self.tracker.set_keyframe(kf);
        if is_new {
            if let (Some(old), Some(map)) = (previous, self.tracking_map.take()) {
                self.store_keyframe(old, map);
            }
            self.pending_kf = None;
            self.reusing = false;
            self.left_kf = None;
            self.reuse_previous = None;
            self.failed_reuse.clear();
        }
        if n > 0 && !filled {
            self.last_median_inv_depth = Some((1.0 / kf_median_depth_m) as f32);
        }
        if is_new {
            self.guessed_snapshot = None;
            self.guessed = (filled && self.cfg.keyframe_bundle.guessed_min_baseline_ratio > 0.0)
                .then(|| self.kf_record.take())
                .flatten()
                .filter(|r| r.id == s.keyframe_id);
        } else if !filled && self.guessed.as_ref().is_some_and(|r| r.id == s.keyframe_id) {
            self.guessed_snapshot = Some(s.clone());
        }
        self.tracking_map = Some(s.map.clone());
        self.tracking_kf_filled = filled;
        if is_new {
            self.tracking_kf_adjusted = adjusted;
        }
        self.tracking_kf = Some(s.keyframe_id);
        self.tracking_kf_points = n;
        self.frames_since_refresh = 0;
        if self.phase == Phase::Initializing {
            self.phase = Phase::Tracking;
            self.consecutive_flagged = 0;
            if self.stats.tracking_since.is_none() {
                self.stats.tracking_since = self.last_t;
            }
        }
    }
}

/// Whether a new keyframe's map may be installed (or handed to its adjustment): it has forward
/// parallax (`min_keyframe_forward_views` views after it in the mapper; in real time also the
/// frames tracked since it, once its adjustment can use them), or the keyframe tracked meanwhile is
/// slipping away (`urgent_inlier_ratio`).
fn new_keyframe_ready(
    b: &BootstrapConfig,
    realtime: bool,
    inlier_ratio: f64,
    forward_views: usize,
    adjustable: bool,
) -> bool {
    inlier_ratio < b.urgent_inlier_ratio
        || forward_views >= b.min_keyframe_forward_views
        || (realtime && adjustable)
}

/// Real time: whether an adjustment not back yet is given up because the keyframe tracked
/// meanwhile keeps too few inliers (`[keyframe_bundle] give_up_inlier_ratio`). Giving up at the
/// first sign of slipping (it was `urgent_inlier_ratio`, 0.6) dropped the adjustment in the very
/// frame it was sent, and unadjusted maps then slipped sooner, one after the other.
fn gives_up_adjustment(inlier_ratio: f64, cfg: &KeyframeBundleConfig) -> bool {
    inlier_ratio < cfg.give_up_inlier_ratio
}

/// The samples of `imu` from before `t0` to after `t1` (all after `t0` if `None`), with one sample
/// of margin each side for the interpolation at the ends.
fn imu_between(imu: &[ImuSample], t0: TimeNs, t1: Option<TimeNs>) -> Vec<ImuSample> {
    let i0 = imu.partition_point(|s| s.t <= t0).saturating_sub(2);
    let i1 = t1.map_or(imu.len(), |t1| {
        (imu.partition_point(|s| s.t <= t1) + 2).min(imu.len())
    });
    imu[i0..i1.max(i0)].to_vec()
}

/// The keyframe's level-0 gradient pixels (as the tracker selects them) in cells of its image
/// that `map` has no point in, at the map's median inverse depth.
fn depthless_points(
    pyr: &Pyramid,
    map: &SemidenseMap,
    median_inv: f32,
    cfg: &TrackerConfig,
) -> Vec<DepthPoint> {
    let cell = (2 * cfg.select_cell_px).max(1);
    let (w, h) = (pyr.level(0).width(), pyr.level(0).height());
    let (cw, ch) = (w.div_ceil(cell), h.div_ceil(cell));
    let mut occupied = vec![false; cw * ch];
    for p in &map.points {
        let (cx, cy) = (
            p.u_px.max(0.0) as usize / cell,
            p.v_px.max(0.0) as usize / cell,
        );
        if cx < cw && cy < ch {
            occupied[cy * cw + cx] = true;
        }
    }
    select_gradient_pixels(pyr, cfg)
        .into_iter()
        .filter(|&(x, y)| !occupied[(y as usize / cell) * cw + x as usize / cell])
        .map(|(x, y)| DepthPoint {
            u_px: x as f32,
            v_px: y as f32,
            inv_depth_m_inv: median_inv,
        })
        .collect()
}

/// Median inverse depth of a map's points, 1/m.
fn median_inv_depth(map: &SemidenseMap) -> Option<f32> {
    let mut inv: Vec<f32> = map.points.iter().map(|p| p.inv_depth_m_inv).collect();
    if inv.is_empty() {
        return None;
    }
    let m = inv.len() / 2;
    Some(*inv.select_nth_unstable_by(m, f32::total_cmp).1)
}

/// At rest at the origin with attitude `r_world_body` and gyro bias `bg`.
fn rest_state(
    t: TimeNs,
    r_world_body: nalgebra::UnitQuaternion<f64>,
    bg: Vector3<f64>,
) -> FrameState {
    FrameState {
        nav: NavState {
            t,
            r_world_body,
            p_world_m: Vector3::zeros(),
            v_world_m_s: Vector3::zeros(),
        },
        bias: crate::imu::ImuBias {
            gyro_rad_s: bg,
            accel_m_s2: Vector3::zeros(),
        },
    }
}

/// The held rest state of a static estimate at time `t`. At rest the accelerometer bias along
/// gravity shows as the excess of the mean specific force over g; across gravity it is absorbed
/// in the tilt. Taking both makes IMU dead reckoning from rest exact while the attitude stays near
/// it.
fn rest_state_from(e: &StaticEstimate, t: TimeNs) -> FrameState {
    let mut x = rest_state(t, e.r_world_body, e.imu_bias().gyro_rad_s);
    let f = e.accel_mean_m_s2;
    if f.norm() > 1e-6 {
        x.bias.accel_m_s2 = f.normalize() * (f.norm() - crate::geometry::GRAVITY_M_S2);
    }
    x
}

/// Covariance of the held rest state: position and velocity known (the pad is the origin), tilt
/// from the rest estimate, yaw free-ish, gyro bias well known, accelerometer bias not observed.
///
/// Tilt and the accelerometer bias across gravity are confounded at rest (only their combination
/// `R_wbᵀ g_up + b_a` is measured). A correlated prior that says exactly that was tried: it lets
/// the keyframe window swing the tilt by 2° when the first keyframes' relative poses disagree with
/// the IMU, and lost on both the demo and S-V101, so the diagonal prior stays.
fn static_covariance(tilt_sigma_rad: f64, accel_bias_std_m_s2: f64) -> Matrix15 {
    let tilt = tilt_sigma_rad.max(1e-3);
    let ba = accel_bias_std_m_s2;
    // [θx, θy, θz (yaw), p, v, bω, ba]
    let s = [
        tilt, tilt, 0.01, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, ba, ba, ba,
    ];
    Matrix15::from_fn(|a, b| if a == b { s[a] * s[a] } else { 0.0 })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::semidense::MapPoint;

    #[test]
    fn a_new_keyframe_waits_for_forward_views_offline_and_for_its_adjustment_views_in_real_time() {
        let b = BootstrapConfig::default();
        let tracked_well = b.urgent_inlier_ratio + 0.1;
        let few = b.min_keyframe_forward_views - 1;
        // Offline: the mapper's forward views, whatever was tracked since.
        assert!(!new_keyframe_ready(&b, false, tracked_well, few, true));
        assert!(new_keyframe_ready(
            &b,
            false,
            tracked_well,
            b.min_keyframe_forward_views,
            false
        ));
        // Real time: the tracked frames its adjustment will use stand in for them…
        assert!(new_keyframe_ready(&b, true, tracked_well, 0, true));
        // …but not before there are enough of them.
        assert!(!new_keyframe_ready(&b, true, tracked_well, few, false));
        // Either way, a keyframe slipping away does not wait.
        for realtime in [false, true] {
            assert!(new_keyframe_ready(
                &b,
                realtime,
                b.urgent_inlier_ratio - 0.1,
                0,
                false
            ));
        }
    }

    #[test]
    fn an_adjustment_is_given_up_only_when_the_tracked_keyframe_is_being_lost() {
        let kb = KeyframeBundleConfig::default();
        let urgent = BootstrapConfig::default().urgent_inlier_ratio;
        assert!(kb.give_up_inlier_ratio < urgent);
        // Slipping (below the urgent ratio) is not enough: the adjustment is worth waiting for.
        assert!(!gives_up_adjustment(urgent - 0.05, &kb));
        assert!(!gives_up_adjustment(kb.give_up_inlier_ratio, &kb));
        assert!(gives_up_adjustment(kb.give_up_inlier_ratio - 0.01, &kb));
    }

    #[test]
    fn depthless_pixels_fill_only_cells_without_map_points() {
        let cam = CameraModel::euroc_cam0();
        let img = Image::from_fn(cam.width, cam.height, |x, y| {
            128.0f32 + 60.0 * ((x as f32) * 0.3).sin() * ((y as f32) * 0.25).cos()
        });
        let mut pyr = Pyramid::new(cam.width, cam.height, NUM_LEVELS);
        pyr.fill_from_f32(&img);
        let cfg = TrackerConfig::default();
        // Map points over the left half of the image.
        let points = (0..cam.height as u32)
            .step_by(4)
            .flat_map(|v| {
                (0..cam.width as u32 / 2).step_by(4).map(move |u| MapPoint {
                    u_px: u as f32,
                    v_px: v as f32,
                    inv_depth_m_inv: 0.5,
                    inv_depth_std_m_inv: 0.01,
                    num_views: 3,
                })
            })
            .collect();
        let map = SemidenseMap {
            t_world_cam: Isometry3::identity(),
            camera: cam,
            points,
        };
        assert_eq!(median_inv_depth(&map), Some(0.5));
        let all = select_gradient_pixels(&pyr, &cfg).len();
        let fill = depthless_points(&pyr, &map, 0.25, &cfg);
        assert!(
            fill.len() > all / 3 && fill.len() < all * 2 / 3,
            "{} of {all}",
            fill.len()
        );
        let cell = 2 * cfg.select_cell_px;
        for p in &fill {
            assert!(p.u_px as usize >= (cam.width / 2).div_ceil(cell) * cell - cell);
            assert_eq!(p.inv_depth_m_inv, 0.25);
        }
        let empty = SemidenseMap {
            points: Vec::new(),
            ..map
        };
        assert_eq!(median_inv_depth(&empty), None);
        assert_eq!(depthless_points(&pyr, &empty, 0.25, &cfg).len(), all);
    }
}
