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
//!   `probation_frames` is left again — for the keyframe left, if that one is still in view,
//!   else for a new keyframe started from the current frame). Otherwise the current frame starts
//!   a new keyframe (seeded by propagating the map of the keyframe tracked and by the last few
//!   frames). Frames that start nothing refine the mapper's keyframe's depths. In a turn on the
//!   spot nothing can be triangulated and each propagated map keeps only the part of the view
//!   that is leaving: a keyframe barely displaced from the one tracked is made at once, without
//!   the mapper (`fill_without_mapper`: the tracked map's points moved into it, its other gradient
//!   pixels at the median depth — any depth serves a rotation; built by the keyframe builder
//!   thread between this frame and the next, and installed first thing in the next), and the
//!   mapper's map of it replaces it once it is full.
//! * [`Phase::Lost`]: several consecutive frames had too few photometric inliers (covered lens,
//!   dark, a keyframe left behind). Poses are IMU-only; a short loss of the image resumes on the
//!   keyframe lost (`resume_max_s`), a loss by motion relocalises on a stored keyframe covering
//!   the IMU-predicted view (`relocalise`: the keyframe lost, which is stored at the loss, and
//!   the keyframe window's are candidates too, within `relocalise_max_*` — and again on every
//!   frame while a first map is started in flight); otherwise, as soon as the image has texture
//!   again, a new keyframe is started as in the bootstrap (its first map refined like the
//!   take-off's, from the velocity dead-reckoned through the loss, if `reinit_velocity_std_m_s`
//!   is positive). If that first map has not started after `reinit_max_s` (the dead reckoning
//!   has drifted too far to triangulate from), the next one is installed at once with guessed
//!   depths and tracked (`reinit_guessed_depths`). Each loss is counted as a reset.
//!
//! # Determinism
//! In offline mode every job's snapshot is awaited a fixed number of frames later
//! (`offline_lag_frames`; mapping of one frame overlaps tracking of the next), so a
//! replay gives the same poses every time. In real-time mode the tracking thread never waits: views
//! that do not fit the queue are dropped (a new keyframe waits on this side for room) and snapshots
//! are taken when they arrive.
//!
//! # Files
//! This file holds the per-frame flow ([`Odometry::push_frame`]) and its phases;
//! `bootstrap_config.rs` the `[bootstrap]` settings; `stats.rs` the counters for the report;
//! `window_link.rs` the keyframe window's part in the flow; `mapper_link.rs` the jobs and
//! snapshots of the mapping thread and the decision to install a keyframe; `refinement_jobs.rs`
//! the take-off refinement and the keyframe adjustments on the refinement thread;
//! `keyframe_returns.rs` the returns to stored keyframes; `gyro_link.rs` the gyro's alignment in
//! flight. Keyframes of guessed depths are built in [`super::guessed_keyframe`], a turn on the
//! spot's on the thread of [`super::keyframe_builder`].

#[cfg(test)]
use super::guessed_keyframe::textured_pyramid;
use super::keyframe_builder::KeyframeBuilder;
use super::keyframe_bundle::{
    KeyframeBundleConfig, KeyframeRecord, PreviousHost, carry_correction,
};
use super::keyframe_store::{KeyframeStore, ReachLimits, ReuseConfig, StoredKeyframe};
use super::map_keyframe;
use super::mapping_worker::{
    MapFrame, MapJob, MapSnapshot, MappingOptions, MappingOutput, MappingThread,
    TrackerKeyframeBuilder,
};
use super::refinement_worker::{
    KeyframeJob, ReadyKeyframe, RefineJob, RefineResult, RefineSettings, RefinementThread,
    TakeoffJob,
};
use super::scale_observer::{ScaleObserver, ScaleObserverConfig, ScaleSample};
use super::takeoff::{RefinedTakeoff, TakeoffRecord, TakeoffRig};
use super::thread_clock::thread_cpu_time_s;
use super::true_view_poses::TrueCameraPoses;
use crate::camera::{CameraModel, PixelRays, Vignette, correct_in_place};
use crate::dataset::StampedPose;
use crate::image::{Image, Pyramid};
use crate::imu::gyro_alignment::GyroAlignmentConfig;
use crate::imu::gyro_noise_reading::GyroNoiseReading;
use crate::imu::misalignment::preintegrate_turned;
use crate::imu::scale_alignment::AlignmentPrior;
use crate::imu::static_init::{
    StaticDetector, StaticDetectorConfig, StaticEstimate, StaticEvent, rest_covariance,
};
use crate::imu::{FrameState, ImuNoise, ImuSample, Matrix15, NavState, Preintegration};
use crate::loop_closure::closer::LoopClosureConfig;
use crate::mapping::semidense::{SemidenseConfig, SemidenseMap};
use crate::smoother::photometric_bundle::BundleConfig;
use crate::smoother::{KeyframeWindow, RelativePose, WindowConfig};
use crate::time::TimeNs;
use crate::tracking::{
    FlagReason, Keyframe, TrackResult, Tracker, TrackerConfig, pose_of, select_gradient_pixels,
};
use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::sync::Arc;

mod adjustment_log;
mod bootstrap_config;
mod gyro_link;
mod gyro_noise_link;
mod keyframe_returns;
mod loop_hindsight;
mod loop_link;
mod loop_log;
mod mapper_link;
mod refinement_jobs;
mod reinit_shape;
mod skip_link;
mod stats;
mod velocity_divergence;
mod window_link;

pub use adjustment_log::{AdjustmentOutcome, AdjustmentRecord, adjustments_csv};
pub use bootstrap_config::{BootstrapConfig, TakeoffRefinement};
pub use gyro_link::GyroAlignmentStats;
use gyro_link::GyroLink;
pub use loop_hindsight::{HindsightCorrections, LoopWorld};
use loop_link::LoopLink;
pub use loop_log::{
    LoopEdgeErrors, LoopEdgeSummary, LoopRecord, loop_edge_errors, loop_edge_summary, loops_csv,
};
pub use stats::{OdometryStats, RestImuDensity};

/// Static frames remembered to pick the first keyframe before the back-dated motion onset.
const STATIC_FRAMES_KEPT: usize = 16;

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
    /// Incremented whenever the loop closer's correction moved the published pose beyond
    /// `[loop_closure] reset_min_jump_m` / `_rad` since the last time (MAVLink `reset_counter`
    /// counts these too).
    pub loop_corrections: u32,
    /// The loop closer's correction applied to this frame's pose and the keyframe whose world it
    /// is (`[loop_closure] correct_published_pose`, valid frames; else `None`): what moves the
    /// pose in hindsight ([`OdometryStats::loop_hindsight`]).
    pub loop_world: Option<LoopWorld>,
    /// The map scale measured against the IMU ran away (`[scale_observer] fault_min_scale` /
    /// `fault_max_scale`): the pose is not to be flown on (MAVLink quality −1) until an estimate
    /// within the band comes.
    pub scale_fault: bool,
    /// The estimated speed is beyond the vehicle's (`[scale_observer] fault_max_speed_m_s`): the
    /// pose is not to be flown on (MAVLink quality −1) while it is.
    pub speed_fault: bool,
    /// Angular rate of the body at the frame, body (IMU) coordinates, rad/s: the last gyro
    /// sample at or before the frame (turned by `[gyro_alignment]`) less the frame's gyro bias —
    /// what MAVLink ODOMETRY's `rollspeed`/`pitchspeed`/`yawspeed` carry. Zero before any sample.
    pub omega_body_rad_s: Vector3<f64>,
    /// The tracking thread's wall time on this frame and where it went.
    pub times: FrameTimes,
}

/// The tracking thread's wall time on one frame, s, and its parts: what makes a slow frame slow.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameTimes {
    /// Wall time of [`Odometry::push_frame`]: all the tracking thread did for the frame — the
    /// image's corrections, the mapper's and the refinement's results taken in, keyframes built
    /// and installed, tracking, the keyframe window; offline also the waits for the mapper's and
    /// the refinement's results at their fixed frames. (`TrackResult::time_s` is tracking and the
    /// window alone.)
    pub total_s: f64,
    /// Taking in the mapper's snapshots: maps turned into the tracker's keyframes and installed
    /// (offline with the wait for a map due at this frame); and installing a turn on the spot's
    /// keyframe built since the last frame ([`super::keyframe_builder`], with any wait for it).
    pub maps_s: f64,
    /// Taking in the refinement thread's outcomes: adjusted keyframes installed, the frames
    /// since tracked again or carried by the correction (offline with the wait for an outcome due).
    pub adjustments_s: f64,
    /// The phase's work on the image: tracking against the keyframe (or holding the pose at rest,
    /// starting the first map).
    pub tracking_s: f64,
    /// The keyframe window's solve, on a frame that starts a keyframe.
    pub window_s: f64,
    /// The tracking thread's CPU time over the frame (`None` where the platform cannot tell): what
    /// `total_s` exceeds it by, the thread waited for a core (preempted) or for the mapper.
    pub cpu_s: Option<f64>,
}

impl FrameTimes {
    /// What the parts leave: the image's corrections, starting keyframes and the threads' jobs,
    /// re-tracking after a return, the rest state's updates.
    pub fn other_s(&self) -> f64 {
        (self.total_s - self.maps_s - self.adjustments_s - self.tracking_s - self.window_s).max(0.0)
    }
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
    /// `[gyro_alignment]` ([`crate::imu::gyro_alignment`]).
    pub gyro_alignment: GyroAlignmentConfig,
    /// `[loop_closure]` ([`crate::loop_closure`]).
    pub loop_closure: LoopClosureConfig,
    /// Real-time mode: never wait for the mapper (non-deterministic).
    pub realtime: bool,
    /// Diagnostic: the mapper triangulates from the true motion from each keyframe
    /// ([`crate::runtime::true_view_poses`]); `None` in the product.
    pub mapping_true_view_poses: Option<Arc<TrueCameraPoses>>,
    /// Diagnostic: the loop closer's edges are the true relative poses of the keyframes it
    /// closes (`vidslam replay --loop-edges gt`); `None` in the product.
    pub loop_true_camera_poses: Option<Arc<TrueCameraPoses>>,
}

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
        /// The keyframe as the mapper built it, installed if the adjustment fails (`None`: being
        /// built on the refinement thread, which hands it back; posed at `unadjusted_pose`).
        unadjusted: Option<Box<Keyframe>>,
        unadjusted_pose: Isometry3<f64>,
        /// Its snapshot.
        snapshot: MapSnapshot,
        /// The keyframe is the one tracked (installed with guessed depths), not a new one.
        tracked: bool,
        /// With the keyframe before as the gauge (`previous_host`): the time from it to the
        /// first frame after it in the chain, s (NaN: without it).
        chain_imu_gap_s: f64,
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
    /// The current frame's times, filled in by its parts ([`Odometry::push_frame`]).
    times: FrameTimes,
    /// The rays of the camera's pixels (the keyframes' points back-projected by lookup).
    rays: Arc<PixelRays>,
    /// The thread that builds a turn on the spot's keyframe between two frames (`[bootstrap]
    /// fill_without_mapper`; `None` when that is off).
    builder: Option<KeyframeBuilder>,
    /// The buffer the tracker loads the frame after the next spot-turn keyframe into (the
    /// builder's, handed back with each build).
    spare_pyramid: Option<Pyramid>,
    /// Frames tracked while a keyframe adjustment is under way (the newest
    /// [`Self::catch_up_limit`]; all, when they are also handed to the refinement thread): tracked
    /// again once it is back (those the refinement thread has not).
    catch_up: Vec<(TimeNs, Arc<Image<u8>>)>,
    /// `[keyframe_bundle] catch_up_on_refinement_thread`: the IMU of the next frame handed to
    /// the refinement thread starts here (the last view, then the last frame handed over).
    catch_up_imu_from: TimeNs,
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
    /// The new keyframe awaited in flight: its id, the frame number that started it, and whether
    /// its first map has arrived (for the latency statistics).
    kf_started: Option<(u32, u64, bool)>,
    tracking_kf: Option<u32>,
    /// The keyframe the newest frame was tracked against (whose world its pose is in: the loop
    /// closer's correction of it is the one to publish it with).
    tracked_against: Option<u32>,
    /// The keyframe whose loop-closure correction the last frame was published with
    /// (`[loop_closure] hold_world_on_probation`: not a stored keyframe still on probation).
    published_world: Option<u32>,
    /// The last frame published had a speed fault (`[scale_observer] fault_max_speed_m_s`).
    speed_fault: bool,
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
    /// The drift correction of the last switch from the chain of new keyframes to a stored one
    /// (`[reuse] keep_window`), pending until the first frame on the stored keyframe.
    switch_correction: Option<SwitchCorrection>,
    /// The keyframe window's correction of the keyframe about to be started across a return
    /// (`[reuse] keep_window`): the stored map seeding it moves with it.
    seed_correction: Option<Isometry3<f64>>,
    /// The chain's state as if the last switch from it to a stored keyframe had not happened,
    /// carried on by the IMU while that keyframe is on probation: a return that fails goes back
    /// to the chain from it ([`Self::retrack_on_chain`]).
    chain_shadow: Option<ChainShadow>,
    /// The keyframe tracking was lost on, when, and whether it was a stored one being reused,
    /// for `[bootstrap] resume_max_s`.
    resume: Option<(StoredKeyframe, TimeNs, bool)>,
    /// Tracking resumed on the keyframe lost and no new keyframe has been started since.
    resumed: bool,
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
    /// The first map being started is one after a loss in flight (`[bootstrap] reinit_max_s`).
    init_in_flight: bool,
    /// The take-off from rest while its first map is built.
    takeoff: Option<TakeoffRecord>,
    /// The keyframe started in flight and the frames tracked since, until it is installed.
    kf_record: Option<KeyframeRecord>,
    /// The last tracked frames with their states, oldest first (`[keyframe_bundle]
    /// previous_host`: those since the tracked keyframe join a new keyframe's adjustment).
    tracked_frames: VecDeque<(MapFrame, FrameState)>,
    /// The image of the keyframe tracked against.
    tracking_kf_image: Option<Arc<Image<u8>>>,
    /// The keyframe window's skip edges (`[window] skip_edges`).
    skip: skip_link::SkipEdges,
    /// The loop closer (`[loop_closure] enabled`), fed with every new keyframe and every map
    /// left; its correction is applied to the published pose only.
    loop_closer: Option<LoopLink>,
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
    /// The first map started in flight with guessed depths (`[bootstrap] reinit_guessed_depths`)
    /// while it awaits its adjustment: that adjustment's start velocity is uncertain.
    reinit_kf: Option<u32>,
    /// The stored keyframe tracked was relocalised on after a loss (cleared by a return while
    /// tracking or a new keyframe).
    relocalised: bool,
    /// The first map being started in flight, to shape its views by (`reinit_shape_from_images`).
    reinit_shape: Option<reinit_shape::ReinitShape>,
    /// When tracking was last lost (`[bootstrap] reinit_shape_min_loss_s`).
    lost_since: Option<TimeNs>,
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
    /// The in-flight gyro alignment (`[gyro_alignment]`, `gyro_link.rs`).
    gyro: GyroLink,
    /// The position change tracking made on the current frame (before any correction).
    tracked_step_m: Option<Vector3<f64>>,
    /// The next frame is tracked against another keyframe than the last one was (a stored one,
    /// or back from it), whose pose disagrees with the chain's by the drift.
    keyframe_jump: bool,
    /// Per-pixel `1 / V` of the rig's vignetting (`[tracking] correct_vignetting`).
    vignette_gain: Option<Vec<f32>>,
    /// The IMU noise the preintegrations are integrated with: `rig.noise`, its white densities
    /// rescaled at the take-off to the ones measured on the pad (`[bootstrap]
    /// rest_imu_noise_factor`) over the tracker's `imu_noise_scale`, which multiplies them again.
    imu_noise: ImuNoise,
    /// The factor on the rotation part of the keyframe window's, the keyframe adjustment's and
    /// the loop closer's odometry IMU factors: 1, from the take-off the pad's
    /// ([`RestImuDensity::rotation_noise_scale`]), with `[window] inflight_gyro_noise` the one
    /// read in flight once it is read.
    rotation_noise_scale: f64,
    /// `[window] inflight_gyro_noise`: the gyro's rotation against the tracked one, per keyframe
    /// interval.
    gyro_noise: GyroNoiseReading,
    /// `[tracking] keyframe_max_velocity_divergence_m_s`: the IMU integrated from the window's
    /// newest keyframe.
    dead_reckoning: Option<velocity_divergence::DeadReckoning>,
}

impl Odometry {
    pub fn new(cfg: OdometryConfig, mut rig: Rig) -> Self {
        rig.noise = cfg.tracking.imu_noise(rig.noise);
        let gyro = GyroLink::new(cfg.gyro_alignment.clone());
        let gyro_applied_rad = gyro.applied_rad();
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
        let rays = Arc::new(PixelRays::new(&rig.camera));
        let tracker_keyframes = (cfg.bootstrap.mapper_builds_keyframes && cfg.tracking.use_vision)
            .then(|| {
                let (rays, tracking) = (rays.clone(), cfg.tracking.clone());
                TrackerKeyframeBuilder(Arc::new(move |s: &MapSnapshot| {
                    map_keyframe::build(s, Vec::new(), Isometry3::identity(), &rays, &tracking)
                }))
            });
        let mapping = MappingThread::spawn(
            cfg.mapping.clone(),
            rig.camera,
            MappingOptions {
                queue_len: cfg.bootstrap.queue_len,
                realtime: cfg.realtime,
                max_view_backlog: cfg.bootstrap.max_view_backlog,
                nice_increment: cfg.bootstrap.background_nice,
                true_view_poses: cfg.mapping_true_view_poses.clone(),
                tracker_keyframes,
            },
        );
        let refiner = ((cfg.keyframe_bundle.enabled || cfg.bootstrap.refine_takeoff_passes > 0)
            && cfg.tracking.use_vision)
            .then(|| {
                RefinementThread::spawn(RefineSettings {
                    camera: rig.camera,
                    t_body_cam: rig.t_body_cam,
                    tracking: cfg.tracking.clone(),
                    keyframe_bundle: cfg.keyframe_bundle.clone(),
                    rays: rays.clone(),
                    nice_increment: cfg.bootstrap.refinement_nice,
                    tracker_noise: rig.noise,
                })
            });
        let b = &cfg.bootstrap;
        let builder = (b.fill_without_mapper && b.fill_depthless_below_points > 0)
            .then(|| KeyframeBuilder::spawn(mapper_link::guess_settings(&cfg, rig.camera, &rays)));
        // Written once here, so that the frames loaded into it later do not map its pages.
        let spare_pyramid = builder.as_ref().map(|_| {
            Pyramid::from_u8(
                &Image::new(rig.camera.width, rig.camera.height),
                crate::tracking::NUM_LEVELS,
            )
        });
        Odometry {
            tracker,
            detector,
            builder,
            spare_pyramid,
            mapping: Some(mapping),
            refiner,
            refining: None,
            times: FrameTimes::default(),
            rays,
            catch_up: Vec::new(),
            catch_up_imu_from: TimeNs(0),
            refine_seq: 0,
            refine_outstanding: 0,
            imu: VecDeque::with_capacity(4096),
            scale: ScaleObserver::new(cfg.scale_observer),
            gyro,
            tracked_step_m: None,
            keyframe_jump: false,
            phase: Phase::WaitingForStart,
            last_t: None,
            seq: 0,
            awaited: VecDeque::new(),
            deferred_jobs: VecDeque::new(),
            frame_number: 0,
            kf_started: None,
            tracking_kf: None,
            tracked_against: None,
            published_world: None,
            speed_fault: false,
            tracking_map: None,
            tracking_kf_filled: false,
            last_median_inv_depth: None,
            pending_kf: None,
            reusing: false,
            left_kf: None,
            switch_correction: None,
            chain_shadow: None,
            seed_correction: None,
            resume: None,
            resumed: false,
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
            init_in_flight: false,
            takeoff: None,
            kf_record: None,
            tracked_frames: VecDeque::new(),
            tracking_kf_image: None,
            skip: Default::default(),
            loop_closer: cfg.loop_closure.enabled.then(|| {
                let truth = cfg.loop_true_camera_poses.clone();
                LoopLink::new(&cfg.loop_closure, rig.camera, cfg.realtime, truth)
            }),
            tracking_kf_adjusted: false,
            guessed: None,
            guessed_snapshot: None,
            reinit_kf: None,
            relocalised: false,
            reinit_shape: None,
            lost_since: None,
            consecutive_flagged: 0,
            last_inlier_ratio: 1.0,
            stats: OdometryStats {
                vignette_corrected: vignette_gain.is_some(),
                gyro_alignment: GyroAlignmentStats {
                    applied_rad: gyro_applied_rad,
                    ..Default::default()
                },
                ..Default::default()
            },
            window: KeyframeWindow::new(cfg.window.clone(), rig.noise),
            mapper_from_world: Isometry3::identity(),
            mapper_kf_pose: None,
            vignette_gain,
            imu_noise: rig.noise,
            rotation_noise_scale: 1.0,
            gyro_noise: GyroNoiseReading::new(cfg.window.inflight_gyro_noise_intervals),
            dead_reckoning: None,
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

    /// Feeds the samples of `imu` (time ordered) from index `*next` up to frame time `t` and one
    /// past it — so the frame's interval end is interpolated, not extrapolated — and advances
    /// `*next` past them: what a recording's frame needs before [`Odometry::push_frame`].
    pub fn push_imu_for_frame(&mut self, imu: &[ImuSample], next: &mut usize, t: TimeNs) {
        while let Some(s) = imu.get(*next).filter(|s| s.t <= t) {
            self.push_imu(s);
            *next += 1;
        }
        if let Some(s) = imu.get(*next) {
            self.push_imu(s);
            *next += 1;
        }
    }

    /// Feeds one IMU sample (time ordered).
    pub fn push_imu(&mut self, s: &ImuSample) {
        // The gyro turned onto the camera's body frame (`[gyro_alignment]`: by
        // `initial_rotation_deg`, and with `apply` by the estimate as it firms up).
        let s = &self.gyro.correct(s);
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
    pub fn push_frame(&mut self, t: TimeNs, image: Image<u8>) -> OdometryFrame {
        let started = std::time::Instant::now();
        let cpu_started = thread_cpu_time_s();
        self.times = FrameTimes::default();
        let mut f = self.process_frame(t, image);
        let on_probation = self.on_probation();
        if let Some(link) = &mut self.loop_closer {
            if self.cfg.loop_closure.correct_published_pose {
                if !(on_probation && self.cfg.loop_closure.hold_world_on_probation) {
                    self.published_world = self.tracked_against;
                }
                let c = link.publish(self.published_world, &f.result.state.nav.p_world_m);
                if f.valid {
                    f.result.state = f.result.state.moved_by_world(&c);
                    f.loop_world = Some(link.world(self.published_world, c));
                }
            }
            f.loop_corrections = link.resets;
            self.stats.loop_closure = Some(link.stats());
        }
        f.omega_body_rad_s = self.body_rate_rad_s(t, &f.result.state.bias.gyro_rad_s);
        f.scale_fault = self.scale_fault();
        if f.valid && f.scale_fault {
            self.stats.scale_fault_frames += 1;
        }
        let speed_m_s = f.result.state.nav.v_world_m_s.norm();
        f.speed_fault = f.valid && self.cfg.scale_observer.is_speed_fault(speed_m_s);
        if f.speed_fault {
            self.stats.speed_fault_frames += 1;
            if !self.speed_fault {
                self.stats.speed_faults += 1;
            }
        }
        self.speed_fault = f.speed_fault;
        self.times.total_s = started.elapsed().as_secs_f64();
        self.times.cpu_s = cpu_started
            .zip(thread_cpu_time_s())
            .map(|(a, b)| (b - a).max(0.0));
        f.times = self.times;
        f
    }

    /// The latest map-scale estimate is a fault (`[scale_observer] fault_min_scale`).
    fn scale_fault(&self) -> bool {
        (self.stats.imu_scale.last())
            .is_some_and(|e| self.cfg.scale_observer.is_fault(e.scale, e.scale_std))
    }

    /// Tracking a stored keyframe that has not yet passed its probation (`[reuse]
    /// probation_frames`).
    fn on_probation(&self) -> bool {
        self.reusing && self.reuse_frames <= self.cfg.reuse.probation_frames
    }

    /// The last (corrected) gyro sample at or before `t` less `gyro_bias_rad_s`; zero if none.
    fn body_rate_rad_s(&self, t: TimeNs, gyro_bias_rad_s: &Vector3<f64>) -> Vector3<f64> {
        self.imu
            .iter()
            .rev()
            .find(|s| s.t <= t)
            .map_or_else(Vector3::zeros, |s| s.gyro_rad_s - gyro_bias_rad_s)
    }

    fn process_frame(&mut self, t: TimeNs, mut image: Image<u8>) -> OdometryFrame {
        let mark = std::time::Instant::now();
        self.install_spot_turn_keyframe();
        let spot_turn_s = mark.elapsed().as_secs_f64();
        if let Some(gain) = &self.vignette_gain
            && gain.len() == image.width() * image.height()
        {
            self.stats.vignette_saturated_px += correct_in_place(&mut image, gain) as u64;
        }
        self.frame_number += 1;
        self.tracked_step_m = None;
        self.send_deferred_jobs();
        let mark = std::time::Instant::now();
        self.collect_snapshots();
        self.times.maps_s = spot_turn_s + mark.elapsed().as_secs_f64();
        let mark = std::time::Instant::now();
        self.collect_refinement();
        self.times.adjustments_s = mark.elapsed().as_secs_f64();
        let image = Arc::new(image);
        let static_now = self.detector.is_static();
        let mark = std::time::Instant::now();
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
                    loop_corrections: 0,
                    loop_world: None,
                    scale_fault: false,
                    speed_fault: false,
                    omega_body_rad_s: Vector3::zeros(),
                    times: FrameTimes::default(),
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
                    if self.stats.rest_imu_density.is_none() {
                        self.stats.rest_imu_density = Some(self.noise_from_rest(&e));
                    }
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
                    self.takeoff = (self.cfg.bootstrap.refine_takeoff_passes > 0)
                        .then(|| TakeoffRecord::new(rest, cov, kf.clone(), self.next_kf_id, false));
                    self.start_keyframe(kf, Vec::new(), false);
                }
                self.static_frames.clear();
                self.phase = Phase::Initializing;
                self.init_started = Some(t);
                self.init_in_flight = false;
                self.track(t, &image)
            }
            Phase::Initializing | Phase::Tracking | Phase::Lost => self.track(t, &image),
        };
        self.times.tracking_s = mark.elapsed().as_secs_f64();
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
                let max_init_s = if self.init_in_flight {
                    self.cfg.bootstrap.reinit_max_s
                } else {
                    self.cfg.bootstrap.max_init_s
                };
                // (Not while the first map is out for its take-off refinement: it has structure,
                // and in real time a pass over all the take-off's frames takes seconds.)
                if self.init_in_flight
                    && self.cfg.bootstrap.relocalise_while_rebuilding
                    && self.relocalise_instead_of_first_map()
                {
                    // Tracked from the next frame on against a stored keyframe (probation).
                } else if self.newest_kf.is_none()
                    || (t.secs_since(started) > max_init_s && !self.refining_takeoff(None))
                {
                    // Not enough structure yet: restart the first map from here (no longer a
                    // take-off from rest).
                    self.restart_first_map(&frame, true);
                } else {
                    let frame = self.shape_reinit_view(frame.clone());
                    if let Some(tk) = self.takeoff.as_mut() {
                        tk.frames.push(frame.clone());
                    }
                    self.observe(frame);
                }
            }
            Phase::Tracking => {
                self.last_inlier_ratio = result.inlier_ratio;
                if matches!(
                    result.flag,
                    Some(FlagReason::FewInliers | FlagReason::NoTexture)
                ) {
                    self.consecutive_flagged += 1;
                } else {
                    self.consecutive_flagged = 0;
                }
                if self.reusing {
                    // A stored keyframe is not there to be triangulated (a new one would only
                    // chain the drift again): the baseline and rotation limits of `[reuse]`, and
                    // no age limit (its map is not the chain's newest, whose scale the age limit
                    // has the window read).
                    self.reuse_frames += 1;
                    let r = &self.cfg.reuse;
                    result.wants_keyframe = self.tracker.wants_keyframe(
                        &result,
                        r.max_baseline_ratio,
                        r.max_rotation_rad,
                        0.0,
                    );
                }
                result.imu_velocity_divergence_m_s = self.velocity_divergence_m_s(&result);
                let max_divergence_m_s = self.cfg.tracking.keyframe_max_velocity_divergence_m_s;
                let diverged = max_divergence_m_s > 0.0
                    && result
                        .imu_velocity_divergence_m_s
                        .is_some_and(|d| d > max_divergence_m_s)
                    && self.window.newest().is_some_and(|(_, x)| {
                        t.secs_since(x.nav.t) >= self.cfg.tracking.keyframe_divergence_min_age_s
                    });
                result.wants_keyframe |= diverged;
                let r = &self.cfg.reuse;
                // The stored keyframe does not fit after all — it loses its inliers on probation
                // (occlusion, a different exposure, a bad map) or its brightness collapses at any
                // time: back to the keyframe left — or, if that one is out of view, a new
                // keyframe from here (`return_min_overlap`).
                let failed_probation = self.on_probation()
                    && (result.flag == Some(FlagReason::FewInliers)
                        || result.inlier_ratio < r.probation_min_inlier_ratio);
                let collapsed = self.tracker.brightness_collapsed(&result);
                let stored_unfit = self.reusing && (failed_probation || collapsed);
                if !self.on_probation() && !stored_unfit {
                    // The stored keyframe passed its probation: the chain is left for good.
                    self.chain_shadow = None;
                }
                // Relocalised after a loss, a brightness collapse is the image's doing (a lens
                // still being uncovered, the exposure settling), not the keyframe's: it stays a
                // candidate for the next frames.
                let at_fault = !(collapsed && self.relocalised);
                let stay = stored_unfit && !self.return_from_stored_keyframe(at_fault);
                if stay {
                    result.wants_keyframe = true;
                }
                if stored_unfit && !stay {
                    // Back on the chain: this frame tracked again on the keyframe left, from the
                    // chain's own state (else tracked against the keyframe gone back to from the
                    // next frame on).
                    if let Some(r) = self.retrack_on_chain(t, &image) {
                        result = r;
                    }
                } else if self.consecutive_flagged >= self.cfg.bootstrap.lost_after_frames {
                    self.phase = Phase::Lost;
                    self.lost_since = Some(t);
                    self.resume = self
                        .tracker
                        .keyframe()
                        .cloned()
                        .zip(self.tracking_map.clone())
                        .filter(|_| {
                            // Only a loss of the image itself, once: a keyframe lost by
                            // motion, or lost again right after resuming, does not fit.
                            result.flag == Some(FlagReason::NoTexture)
                                && !self.resumed
                                && self.cfg.bootstrap.resume_max_s > 0.0
                        })
                        .map(|(kf, map)| (StoredKeyframe { kf, map }, t, self.reusing));
                    // The keyframe lost is the nearest map to relocalise on (a stored one is
                    // stored already).
                    if self.cfg.bootstrap.relocalise_in_window
                        && !self.reusing
                        && let (Some(kf), Some(map)) =
                            (self.tracker.keyframe().cloned(), self.tracking_map.clone())
                    {
                        self.store_keyframe(kf, map);
                    }
                    self.lose_keyframe();
                    self.history.clear();
                    self.stats.resets += 1;
                } else if result.wants_keyframe
                    && result.flag.is_none()
                    && self.pending_kf.is_none()
                    && self.switch_to_stored_keyframe(false)
                {
                    // Tracking continues against a stored keyframe: nothing for the mapper.
                } else if result.wants_keyframe
                    && result.flag.is_none()
                    && self.pending_kf.is_none()
                    && !self.awaiting_guessed_adjustment()
                {
                    // (A keyframe already pending in the mapper is awaited, not replaced.)
                    let mut frame = frame.clone();
                    if let Some(c) = self.window_keyframe(&mut result, &image) {
                        frame.t_world_cam = c * frame.t_world_cam;
                        for h in self.history.iter_mut() {
                            h.t_world_cam = c * h.t_world_cam;
                        }
                        for (f, x) in self.tracked_frames.iter_mut() {
                            f.t_world_cam = c * f.t_world_cam;
                            *x = x.moved_by_world(&c);
                        }
                    }
                    if let Some(e) = self.scale.estimate(self.imu.make_contiguous()) {
                        let was_fault = self.scale_fault();
                        self.stats.imu_scale.push(ScaleSample {
                            t,
                            scale: e.scale,
                            scale_std: e.scale_std,
                            rms_m: e.rms_m,
                        });
                        if self.scale_fault() && !was_fault {
                            self.stats.scale_faults += 1;
                        }
                    }
                    if self
                        .tracker
                        .keyframe_older_than(t, self.cfg.tracking.keyframe_max_age_s)
                    {
                        self.stats.aged_keyframes += 1;
                    }
                    if diverged {
                        self.stats.diverged_keyframes += 1;
                    }
                    let history: Vec<MapFrame> = self.history.iter().cloned().collect();
                    let propagate = self.cfg.bootstrap.propagate_maps;
                    self.start_keyframe(frame, history, propagate);
                    self.start_spot_turn_keyframe(t, &image);
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
                let resume = self.resume.take().filter(|(_, since, _)| {
                    t.secs_since(*since) <= self.cfg.bootstrap.resume_max_s
                });
                if textured < self.cfg.bootstrap.min_texture_points {
                    self.resume = resume;
                } else if let Some((s, _, reusing)) = resume
                    && self.resume_tracking(s, reusing)
                {
                    self.stats.resumes += 1;
                } else if self.relocalise_after_loss() {
                    // Tracked from the next frame on against a stored keyframe covering the
                    // IMU-predicted view, on probation (no keyframe left to go back to: a failed
                    // probation is a loss again).
                } else {
                    self.phase = Phase::Initializing;
                    self.restart_first_map(&frame, false);
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
        if self.phase == Phase::Tracking {
            self.keep_for_catch_up(t, &image);
        }
        if self.phase == Phase::Tracking && result.flag.is_none() {
            let frame = MapFrame {
                t_world_cam: self.tracker.t_world_cam(),
                ..frame
            };
            if self.cfg.keyframe_bundle.previous_host {
                self.tracked_frames
                    .push_back((frame.clone(), *self.tracker.state()));
                if self.tracked_frames.len() > MAX_TRACKED_FRAMES {
                    self.tracked_frames.pop_front();
                }
            }
            self.history.push_front(frame);
            self.history.truncate(self.cfg.bootstrap.history_frames);
            self.observe_gyro_alignment(t, &result.photometric_step);
        } else {
            self.gyro.drop_anchor();
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
            loop_corrections: 0,
            loop_world: None,
            scale_fault: false,
            speed_fault: false,
            omega_body_rad_s: Vector3::zeros(),
            times: FrameTimes::default(),
        }
    }

    /// Stops the mapping thread and returns what it built.
    pub fn finish(mut self) -> (OdometryStats, MappingOutput) {
        self.record_gyro_alignment();
        if let Some(link) = &mut self.loop_closer {
            self.stats.loop_closures = link.closures().to_vec();
            self.stats.loop_hindsight = Some(link.hindsight());
            let t_cam_body = self.rig.t_body_cam.inverse();
            self.stats.loop_keyframe_poses = (link.keyframe_poses().into_iter())
                .map(|(t, t_world_cam)| StampedPose {
                    t,
                    t_world_body: t_world_cam * t_cam_body,
                })
                .collect();
        }
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
        // The tilt also carries the accelerometer bias across gravity that the rest cannot tell
        // from it (`rest_covariance`); a correlated prior saying exactly that (only the
        // combination known) lost on the demo and S-V101 when the keyframe window was new
        // (docs/odometry-log.md, *The rest prior held a tilt the accelerometer bias had taken*).
        let cov = rest_covariance(&x.nav.r_world_body, tilt, b.rest_accel_bias_std_m_s2);
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

    /// The IMU's noise measured on the pad (`e`), and from now on the white densities of
    /// [`Self::imu_noise`] from it when `[bootstrap] rest_imu_noise_factor` is on: each sensor's
    /// measured ratio to `sensor.yaml` (at least 1) times the factor becomes its effective scale,
    /// in place of `[tracking] imu_noise_scale` (by which the tracker multiplies the densities).
    fn noise_from_rest(&mut self, e: &StaticEstimate) -> RestImuDensity {
        let n = &self.rig.noise;
        let gyro_ratio = e.gyro_density_rad_s_sqrt_hz / n.gyro_noise_density;
        let accel_ratio = e.accel_density_m_s2_sqrt_hz / n.accel_noise_density;
        let fixed = self.cfg.tracking.imu_noise_scale;
        let factor = self.cfg.bootstrap.rest_imu_noise_factor;
        let measured = |ratio: f64| {
            (factor > 0.0 && ratio.is_finite() && fixed > 0.0).then(|| ratio.max(1.0) * factor)
        };
        let (gyro_scale, accel_scale) = match (measured(gyro_ratio), measured(accel_ratio)) {
            (Some(g), Some(a)) => {
                self.imu_noise.gyro_noise_density = n.gyro_noise_density * g / fixed;
                self.imu_noise.accel_noise_density = n.accel_noise_density * a / fixed;
                (g, a)
            }
            _ => (fixed, fixed),
        };
        let rotation_noise_scale =
            if self.cfg.bootstrap.rest_gyro_rotation_noise && gyro_ratio.is_finite() {
                gyro_ratio.max(1.0)
            } else {
                1.0
            };
        self.set_rotation_noise_scale(rotation_noise_scale);
        RestImuDensity {
            gyro_rad_s_sqrt_hz: e.gyro_density_rad_s_sqrt_hz,
            accel_m_s2_sqrt_hz: e.accel_density_m_s2_sqrt_hz,
            gyro_ratio,
            accel_ratio,
            gyro_scale,
            accel_scale,
            rotation_noise_scale,
        }
    }

    fn track(&mut self, t: TimeNs, image: &Image<u8>) -> TrackResult {
        let t0 = self.last_t.unwrap_or(t);
        // The gyro turned onto the body frame as the keyframe window reads it.
        let phi = self.gyro_turn_rad();
        let bias = self.tracker.state().bias;
        let samples = self.imu.make_contiguous();
        let pre = preintegrate_turned(samples, (t0, t), bias, &self.imu_noise, &phi);
        self.last_t = Some(t);
        let x0 = *self.tracker.state();
        if let Some(s) = self.chain_shadow.as_mut() {
            s.advance(&pre);
        }
        let r = self.tracker.track(t, image, &pre);
        self.tracked_against = self.tracking_kf;
        // The first frame on another keyframe jumps by the drift between the two: the IMU's
        // step stands in for it.
        let p1 = if std::mem::take(&mut self.keyframe_jump) {
            let predicted = FrameState {
                nav: pre.predict(&x0.nav, &x0.bias),
                bias: x0.bias,
            };
            if let Some(SwitchCorrection::Pending { premove }) = self.switch_correction {
                // The state was moved by `premove` before this frame: the correction from the
                // chain's world is the tracked jump after it.
                self.switch_correction = r.flag.is_none().then(|| SwitchCorrection::Measured {
                    c: pose_of(&r.state) * pose_of(&predicted).inverse() * premove,
                    pivot_m: premove
                        .inverse_transform_point(&predicted.nav.p_world_m.into())
                        .coords,
                });
            }
            predicted.nav.p_world_m
        } else {
            r.state.nav.p_world_m
        };
        self.tracked_step_m = Some(p1 - x0.nav.p_world_m);
        r
    }

    /// Tracking resumes after a loss of the image on keyframe `s` (lost while `reusing` a stored
    /// one or not): on it if the IMU-predicted view still overlaps it, else on the stored keyframe
    /// that covers the view (the vehicle moved on meanwhile). `false` if neither: nothing is
    /// changed and a new first map is needed.
    fn resume_tracking(&mut self, s: StoredKeyframe, reusing: bool) -> bool {
        let at = self.tracker.t_world_cam();
        let overlap = s.kf.predicted_overlap(
            &at,
            self.cfg.reuse.overlap_level,
            self.cfg.tracking.border_px,
        );
        let fits = overlap >= self.cfg.bootstrap.resume_min_overlap;
        let covered = || {
            self.cfg.reuse.enabled
                && self
                    .stored_keyframe_covering(&at, Some(s.kf.id), false, None)
                    .is_some()
        };
        if !fits && !covered() {
            return false;
        }
        // Back on the keyframe lost (the next frame is tracked against it); a stored one on
        // probation again, the keyframe left for it kept to fall back on.
        self.reusing = reusing;
        self.reuse_frames = 0;
        self.tracking_kf = Some(s.kf.id);
        self.tracker.set_keyframe(s.kf);
        self.tracking_map = Some(s.map);
        self.consecutive_flagged = 0;
        self.keyframe_jump = true;
        self.phase = Phase::Tracking;
        self.resumed = true;
        if !fits {
            // (Covered: the switch finds the stored keyframe checked above.)
            self.switch_to_stored_keyframe(false);
        }
        true
    }

    /// The record of a first map started in flight at `frame` (after a loss, or restarted for
    /// lack of structure), refined like a take-off ([`super::takeoff`]) from the tracker's state
    /// at `frame` — dead-reckoned through the loss — with `[bootstrap] reinit_velocity_std_m_s`
    /// on its velocity. `None` if that is 0, if the take-off is not refined by bundle adjustment
    /// (the alignment was never measured in flight), or if the tracker's state is not at `frame`.
    fn in_flight_takeoff(&self, frame: &MapFrame) -> Option<TakeoffRecord> {
        let b = &self.cfg.bootstrap;
        let start = *self.tracker.state();
        if b.refine_takeoff_passes == 0
            || b.reinit_velocity_std_m_s <= 0.0
            || b.takeoff_refinement != TakeoffRefinement::BundleAdjustment
            || start.nav.t != frame.t
        {
            return None;
        }
        Some(TakeoffRecord::new(
            start,
            *self.tracker.covariance(),
            frame.clone(),
            self.next_kf_id,
            true,
        ))
    }

    /// After a loss (`relocalise`): if a stored keyframe covers the IMU-predicted view
    /// (`relocalise_*`), it is tracked from the next frame on and the phase is `Tracking`.
    fn relocalise_after_loss(&mut self) -> bool {
        if !(self.cfg.bootstrap.relocalise && self.switch_to_stored_keyframe(true)) {
            return false;
        }
        self.phase = Phase::Tracking;
        self.consecutive_flagged = 0;
        self.stats.relocalisations += 1;
        true
    }

    /// While a first map is being started in flight: relocalised instead
    /// ([`Odometry::relocalise_after_loss`]), the first map is dropped.
    fn relocalise_instead_of_first_map(&mut self) -> bool {
        if self.refining_takeoff(None) || !self.relocalise_after_loss() {
            return false;
        }
        self.pending_kf = None;
        self.takeoff = None;
        self.kf_record = None;
        self.reinit_kf = None;
        self.reset_window();
        true
    }

    /// Starts a first map in flight from `frame` (the frame just tracked on the IMU alone; phase
    /// `Initializing`), triangulated by the mapper from the dead reckoning. When the last one did
    /// not start in time (`guessed`; `reinit_max_s`), the dead reckoning has drifted too far to
    /// triangulate from and the new one is installed at once with guessed depths
    /// (`[bootstrap] reinit_guessed_depths`; phase `Tracking`).
    fn restart_first_map(&mut self, frame: &MapFrame, guessed: bool) {
        self.window_across_loss();
        self.takeoff = self.in_flight_takeoff(frame);
        self.start_reinit_shape(frame);
        self.start_keyframe(frame.clone(), Vec::new(), false);
        self.init_started = Some(frame.t);
        self.init_in_flight = true;
        if guessed && self.cfg.bootstrap.reinit_guessed_depths {
            self.install_reinit_keyframe(frame);
        }
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

    fn imu_only_result(&self, t: TimeNs) -> TrackResult {
        self.tracker.untracked_result(t)
    }
}

/// Frames kept for a new keyframe's adjustment with the previous one (`tracked_frames`): more
/// than a keyframe interval (a keyframe lasts 0.3–2 s at 20 Hz).
const MAX_TRACKED_FRAMES: usize = 80;

/// The state of the chain of new keyframes left for a stored one (`Odometry::chain_shadow`),
/// predicted by the IMU from the last frame tracked on the chain.
#[derive(Clone, Debug)]
struct ChainShadow {
    /// At the frame before the current one.
    before: FrameState,
    /// At the current frame.
    now: FrameState,
    /// The IMU from `before` to `now` (`None` until a frame has been predicted).
    pre: Option<Preintegration>,
    /// The chain's covariance at the switch (the switch inflates the tracker's).
    cov: Matrix15,
    /// The brightness relative to the keyframe left, at the switch.
    brightness: (f64, f64),
}

impl ChainShadow {
    fn new(x: FrameState, cov: Matrix15, brightness: (f64, f64)) -> Self {
        ChainShadow {
            before: x,
            now: x,
            pre: None,
            cov,
            brightness,
        }
    }

    /// Predicts the next frame by the IMU `pre` (from the current frame to it).
    fn advance(&mut self, pre: &Preintegration) {
        self.before = self.now;
        self.now.nav = pre.predict(&self.before.nav, &self.before.bias);
        self.pre = Some(pre.clone());
    }
}

/// The drift correction a switch to a stored keyframe makes (`Odometry::switch_correction`).
#[derive(Clone, Copy, Debug, PartialEq)]
enum SwitchCorrection {
    /// Switched, the state moved first by `premove` (the loop closure's change of world; the
    /// identity without it); the next frame, tracked on the stored keyframe, measures the rest.
    Pending { premove: Isometry3<f64> },
    /// `T_stored = c · T_chain` from that frame's tracked pose against its IMU prediction from
    /// the last frame on the chain, and that predicted position, m.
    Measured {
        c: Isometry3<f64>,
        pivot_m: Vector3<f64>,
    },
}

/// The heading and position part of the world correction `c`: the rotation about the world
/// vertical closest to `c`'s, and the translation that moves `pivot_m` where `c` moves it.
fn heading_part(c: &Isometry3<f64>, pivot_m: &Vector3<f64>) -> Isometry3<f64> {
    use nalgebra::{Point3, Translation3, UnitQuaternion};
    let r = c.rotation.to_rotation_matrix();
    let m = r.matrix();
    let yaw_rad = (m[(1, 0)] - m[(0, 1)]).atan2(m[(0, 0)] + m[(1, 1)]);
    let rz = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad);
    let t = c * Point3::from(*pivot_m) - rz * Point3::from(*pivot_m);
    Isometry3::from_parts(Translation3::from(t), rz)
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

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn a_world_correction_moves_pose_and_velocity_and_keeps_the_rest() {
        let mut x = rest_state(
            TimeNs(5),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.1, -0.2, 0.3)),
            Vector3::new(0.001, 0.002, -0.001),
        );
        x.nav.p_world_m = Vector3::new(1.0, 2.0, 3.0);
        x.nav.v_world_m_s = Vector3::new(0.5, -0.1, 0.2);
        x.bias.accel_m_s2 = Vector3::new(0.01, 0.02, 0.03);
        let c = Isometry3::from_parts(
            Translation3::new(0.1, -0.05, 0.02),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.2)),
        );
        let y = x.moved_by_world(&c);
        let expect = c * pose_of(&x);
        assert!((pose_of(&y).translation.vector - expect.translation.vector).norm() < 1e-12);
        assert!(pose_of(&y).rotation.angle_to(&expect.rotation) < 1e-12);
        assert!((y.nav.v_world_m_s - c.rotation * x.nav.v_world_m_s).norm() < 1e-12);
        assert_eq!(y.bias, x.bias);
        assert_eq!(y.nav.t, x.nav.t);
    }

    #[test]
    fn the_heading_part_of_a_correction_keeps_its_yaw_and_where_it_moves_the_pivot() {
        let yaw = Isometry3::from_parts(
            Translation3::new(0.3, -0.2, 0.1),
            UnitQuaternion::from_scaled_axis(Vector3::z() * 0.4),
        );
        let pivot = Vector3::new(2.0, 1.0, -0.5);
        let h = heading_part(&yaw, &pivot);
        assert!((h.translation.vector - yaw.translation.vector).norm() < 1e-12);
        assert!(h.rotation.angle_to(&yaw.rotation) < 1e-12);
        // With a tilt on top: the tilt is dropped, the yaw and the pivot's image kept.
        let tilted = Isometry3::from_parts(
            yaw.translation,
            UnitQuaternion::from_scaled_axis(Vector3::x() * 0.02) * yaw.rotation,
        );
        let h = heading_part(&tilted, &pivot);
        let axis = h.rotation.axis().unwrap();
        assert!((axis.z.abs() - 1.0).abs() < 1e-12);
        assert!((h.rotation.angle() - 0.4).abs() < 1e-3);
        assert!(
            (h * nalgebra::Point3::from(pivot) - tilted * nalgebra::Point3::from(pivot)).norm()
                < 1e-12
        );
    }
}
