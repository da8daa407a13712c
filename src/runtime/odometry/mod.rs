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
//! This file holds the configuration, the per-frame flow ([`Odometry::push_frame`]) and the
//! keyframe window's part in it; `mapper_link.rs` the jobs and snapshots of the mapping thread
//! and the decision to install a keyframe; `refinement_jobs.rs` the take-off refinement and the
//! keyframe adjustments on the refinement thread; `keyframe_returns.rs` the returns to stored
//! keyframes. Keyframes of guessed depths are built in [`super::guessed_keyframe`], a turn on the
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
use crate::image::{Image, Pyramid};
use crate::imu::gyro_alignment::GyroAlignmentConfig;
use crate::imu::scale_alignment::AlignmentPrior;
use crate::imu::static_init::{
    StaticDetector, StaticDetectorConfig, StaticEstimate, StaticEvent, rest_covariance,
};
use crate::imu::{FrameState, ImuNoise, ImuSample, Matrix15, NavState, Preintegration};
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
mod gyro_link;
mod keyframe_returns;
mod mapper_link;
mod refinement_jobs;

pub use adjustment_log::{AdjustmentOutcome, AdjustmentRecord, adjustments_csv};
pub use gyro_link::GyroAlignmentStats;
use gyro_link::GyroLink;

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
    /// against it. In real time the frames tracked since it was started decide instead, once
    /// there are enough for its adjustment (`[keyframe_bundle] realtime_min_views`): the
    /// adjustment triangulates it over those frames, and it waits for them even when the mapper
    /// has its forward views.
    pub min_keyframe_forward_views: usize,
    /// …unless fewer than this fraction of the current keyframe's points are still inliers…
    pub urgent_inlier_ratio: f64,
    /// …and, when adjustments come back late (real time, or `[keyframe_bundle] lag_frames`
    /// emulating it), while the new keyframe's adjustment still lacks the frames it needs
    /// (`min_views` tracked since the keyframe was started), unless fewer than this fraction are.
    /// Between the two the new keyframe waits for those frames: installed at the first sign of
    /// slipping, with the mapper behind and unadjusted, its map keeps ~55 % inliers, the next
    /// keyframe is then needed at once and installed the same way, and a fast lap went on with no
    /// keyframe adjusted for seconds while the maps shrank (demo seed 9 with the adjustments 3
    /// frames late, as in real time: none adjusted from 11.7 to 16.8 s, maps −9 to −16 %,
    /// diverged). With adjustments at once (offline by default) the first sign of slipping installs
    /// (waiting there too was better on the demo, median 2.7 → 2.0 cm, but lost seed 23 and made
    /// S-V101 worse: docs/odometry-log.md, *Keyframes installed unadjusted*). A value at or above
    /// `urgent_inlier_ratio` restores installing at the first sign of slipping.
    pub urgent_unadjusted_inlier_ratio: f64,
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
    /// The same for a first map started in flight after a loss, s: it is then started again
    /// with guessed depths (`reinit_guessed_depths`).
    pub reinit_max_s: f64,
    /// Inverse-depth search range of a keyframe started without a previous map, 1/m.
    pub init_inv_depth_min_m_inv: f64,
    pub init_inv_depth_max_m_inv: f64,
    /// Frames before a new keyframe given to the mapper with it.
    pub history_frames: usize,
    /// Consecutive frames with too few inliers before tracking is declared lost.
    pub lost_after_frames: u32,
    /// A lost tracker restarts when the image has at least this many gradient points.
    pub min_texture_points: usize,
    /// A loss shorter than this (a covered lens, a blinded sensor) resumes tracking against the
    /// keyframe it lost, from the IMU-predicted pose, instead of building a new first map from
    /// an IMU baseline of a few tenths of a second, whose scale is that of the velocity error
    /// (0 = always build a new one). Counted as a reset either way.
    pub resume_max_s: f64,
    /// …if at least this fraction of that keyframe's points project into the IMU-predicted view;
    /// else on the stored keyframe that covers it (`[reuse]`), if one does.
    pub resume_min_overlap: f64,
    /// A tracker lost by motion (few inliers) relocalises on the stored keyframe that covers
    /// the IMU-predicted view (`[reuse]`: as a return to it, on probation), if one does, instead
    /// of building a new first map from an IMU baseline whose scale is that of the velocity
    /// error after the loss. Counted as a reset either way.
    pub relocalise: bool,
    /// …on the keyframes of the keyframe window too (the latest ones, nearest to the loss; while
    /// tracking, a return to one of them is not a return to a less drifted map) — the keyframe
    /// lost among them, which is stored at the loss for this.
    pub relocalise_in_window: bool,
    /// …and, failing that, on every frame while a first map is being started in flight.
    pub relocalise_while_rebuilding: bool,
    /// How far from the IMU-predicted camera a keyframe may be to relocalise on it: distance
    /// over its median depth, rotation (rad) and the predicted fraction of its points in view.
    pub relocalise_max_baseline_ratio: f64,
    pub relocalise_max_rotation_rad: f64,
    pub relocalise_min_overlap: f64,
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
    /// Real time: the tracking thread runs under `SCHED_FIFO` at this priority (1–99; 0 = off)
    /// where the process may (root, `CAP_SYS_NICE`, `RLIMIT_RTPRIO`), ahead of every ordinary
    /// thread; otherwise as before, and the report says so
    /// ([`crate::runtime::thread_priority::RealtimeGuard`]).
    pub tracking_fifo_priority: i32,
    /// Seed each new keyframe with the previous keyframe's map (DPPTAM's propagation).
    pub propagate_maps: bool,
    /// Prior standard deviation of the accelerometer bias when motion starts, m/s² (each axis;
    /// across gravity it also loosens the tilt: `imu::static_init::rest_covariance`).
    pub rest_accel_bias_std_m_s2: f64,
    /// Lower bound of the statistical standard deviation of the tilt from the rest period, rad
    /// (before the bias across gravity is added to it).
    pub rest_min_tilt_std_rad: f64,
    /// A keyframe whose map has fewer points than this (a turn on the spot) is tracked with its
    /// depthless gradient pixels too, at the map's median depth, and installed without waiting
    /// for forward views (0 = never).
    pub fill_depthless_below_points: usize,
    /// …if it is closer than this to the keyframe tracked, over that one's median depth.
    pub fill_max_baseline_ratio: f64,
    /// A keyframe started that close to the one tracked (a turn on the spot) is made by the
    /// tracking thread at once — the tracked map's points moved into it, its other gradient
    /// pixels at the median depth — instead of waiting for the mapper's first map of it, which
    /// in real time comes 4–8 frames later, when a fast turn has left the keyframe tracked
    /// meanwhile. The mapper's map replaces it once it has `fill_depthless_below_points`.
    pub fill_without_mapper: bool,
    /// The mapping thread builds the tracker's keyframe of each map the tracking thread says it
    /// would install next (`mapping_worker::InstallHint`, sent with every view), so that the
    /// tracking thread installs it without building it (3–6 ms of its frame on a map of 10–20
    /// thousand points). The same keyframe either way: offline replays do not change.
    pub mapper_builds_keyframes: bool,
    /// After a static start, the first map's views are re-posed (`takeoff_refinement`) and the
    /// first map triangulated again from them this many times before it is tracked
    /// ([`super::takeoff`]; 0 = the paper's bootstrap by dead reckoning alone).
    pub refine_takeoff_passes: u32,
    /// A refinement pass, which runs on a thread of its own, is applied this many frames after it
    /// started (0 = before the next frame): offline exactly, in real time at the earliest (later
    /// if it takes longer). Until then the frames are dead-reckoned.
    pub takeoff_lag_frames: u64,
    /// The first refinement pass re-poses at most this many of the take-off's frames (evenly
    /// spaced, the last one included; the IMU is preintegrated across the others), and the first
    /// map is triangulated again from those; a further pass is not started over more frames
    /// than this (the first map is then installed): in real time each pass is another ~0.7 s of
    /// dead reckoning before the first map is tracked. The demo's take-offs have 13–20 frames,
    /// S-V101's slow ones more than 30, in real time 60 and more. Until 2026-11-28 a take-off
    /// with more frames than this got no pass at all: S-V101 seeds 5 and 8, 1.6 s from the onset
    /// to their first map, kept its dead-reckoned scale (+16 / +25 %; docs/odometry-log.md,
    /// *Slow take-offs got no take-off refinement*).
    pub takeoff_max_pass_frames: usize,
    /// A further pass is started only if the previous one came back within this many frames of
    /// being sent (offline it comes back after `takeoff_lag_frames`): each pass is dead reckoning
    /// the first map is not tracked over, and the second pass, over the frames gathered while the
    /// first ran, takes longer than the first. In real time on the 2-core machine the first pass
    /// comes back 5–6 frames late and the second 14 more: the demo then started tracking 2.0–3.7 s
    /// after the onset (0.85–1.0 s offline) and ran away on 2 of 10 runs; with one pass 0.65–1.7 s
    /// and none of 8 (docs/odometry-log.md, *Real-time take-offs get one pass*).
    pub takeoff_further_pass_max_lag_frames: u64,
    /// Prior standard deviation of the velocity at the rest state, m/s.
    pub takeoff_velocity_std_m_s: f64,
    /// A first map started in flight (after a loss) is refined like the take-off's, with this
    /// prior standard deviation of its start velocity around the one dead-reckoned through the
    /// loss, m/s (0 = not refined: the paper's bootstrap by dead reckoning alone). Off by
    /// default: offline it turns the demo's covered-lens rebuilds that diverged into 4–22 cm,
    /// but with real-time latency the refined first map arrives when the vehicle has left its
    /// view (docs/odometry-log.md, *A first map started in flight*).
    pub reinit_velocity_std_m_s: f64,
    /// A first map started in flight is installed at once, without waiting for the mapper: the
    /// frame's gradient pixels at the median inverse depth of the last map tracked (a room does
    /// not change its depth much in the time a loss takes). Tracked from the next frame on, its
    /// poses come from the camera instead of from the dead reckoning through the loss, whose
    /// velocity error grows by up to 0.5 m/s every second and gives the mapper baselines it
    /// cannot triangulate. Like a keyframe of a turn on the spot, the mapper's own map of it
    /// replaces the guesses, and the keyframe adjustment with its depths free
    /// (`[keyframe_bundle] guessed_min_baseline_ratio`) then takes its scale from the IMU.
    pub reinit_guessed_depths: bool,
    /// Standard deviation of the velocity given to the tracker when such a first map is
    /// installed, and of the start velocity's prior in its adjustment, m/s: the velocity
    /// dead-reckoned through the loss is that uncertain.
    pub reinit_velocity_free_std_m_s: f64,
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
    /// The IMU's white noise as measured on the pad replaces `[tracking] imu_noise_scale`'s fixed
    /// inflation of `sensor.yaml`'s densities from the take-off on (0 = off: the fixed scale
    /// throughout). Each sensor's ratio of its rest density to `sensor.yaml`'s (at least 1,
    /// [`OdometryStats::rest_imu_density`]) times this becomes its scale in the tracker; the
    /// window, the take-off and the keyframe adjustments keep their scales' ratios to the
    /// tracker's. Rotor vibration on the pad is what the fixed 3 stands for, and it is measured
    /// there: 1.1–2.3 × on the demo flights, 5.9 / 6.5 × on S-V101's real IMU. Off by default:
    /// with 1, demo seeds 1–24 median 2.48 → 1.90 cm but 10 resets instead of 2, and S-V101 seeds
    /// 2 / 3 lost (3.4 / 8.9 m; docs/odometry-log.md, *The IMU weighted by the noise its pad
    /// measures*).
    pub rest_imu_noise_factor: f64,
    /// From the take-off on, the rotation part of the IMU factors of the keyframe window and the
    /// keyframe adjustment (`imu_rotation_noise_factor` of each) is multiplied by the gyro's
    /// white-noise density measured on the pad over `sensor.yaml`'s (at least 1,
    /// [`RestImuDensity::rotation_noise_scale`]). Those factors weigh the gyro at a fixed
    /// multiple of the datasheet, far above the relative rotations the images give (a 1000th of
    /// the photometric information), so a gyro that disagrees with the camera by more than that —
    /// rotor vibration, a wander over seconds — turns the keyframes' attitudes, gravity with
    /// them, and the velocity and map scale after it. The translation part, which carries the
    /// metric scale, keeps its weight. On by default since 2026-12-02: on S-V101 (5.9 × on the
    /// pad) seeds 1–16 median 0.152 → 0.132 m, worst 0.558 → 0.421 m, 10 of 16 better (a fixed 5
    /// everywhere: seeds 1–12 0.119 m, but demo seed 13 ran away); the demo flights measure
    /// 0.96–1.47 × (median of 24 seeds 1.44 → 1.48 cm; with the gyro turned 0.7°, seeds 1–8
    /// median 1.84 → 1.67 cm) — docs/odometry-log.md, *The gyro's rotation weighed by its
    /// wander*, *The pad's rotation factor made the default*.
    pub rest_gyro_rotation_noise: bool,
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
            urgent_unadjusted_inlier_ratio: 0.45,
            max_init_s: 3.0,
            reinit_max_s: 3.0,
            min_init_baseline_ratio: 0.1,
            onset_margin_s: 0.3,
            init_inv_depth_min_m_inv: 0.05,
            init_inv_depth_max_m_inv: 4.0,
            history_frames: 5,
            lost_after_frames: 3,
            resume_max_s: 2.0,
            resume_min_overlap: 0.4,
            relocalise: true,
            relocalise_in_window: true,
            relocalise_while_rebuilding: true,
            relocalise_max_baseline_ratio: 0.5,
            relocalise_max_rotation_rad: 0.5,
            relocalise_min_overlap: 0.5,
            min_texture_points: 1500,
            refresh_every_frames: 2,
            offline_lag_frames: 2,
            queue_len: 8,
            max_view_backlog: 2,
            background_nice: 10,
            refinement_nice: 2,
            tracking_fifo_priority: 10,
            propagate_maps: true,
            rest_accel_bias_std_m_s2: 0.1,
            rest_min_tilt_std_rad: 1e-3,
            fill_depthless_below_points: 1500,
            fill_max_baseline_ratio: 0.03,
            fill_without_mapper: true,
            mapper_builds_keyframes: true,
            refine_takeoff_passes: 2,
            takeoff_lag_frames: 0,
            takeoff_max_pass_frames: 30,
            takeoff_further_pass_max_lag_frames: 2,
            takeoff_velocity_std_m_s: 0.01,
            reinit_velocity_std_m_s: 0.0,
            reinit_guessed_depths: true,
            reinit_velocity_free_std_m_s: 0.5,
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
            rest_imu_noise_factor: 0.0,
            rest_gyro_rotation_noise: true,
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
    /// Real-time mode: never wait for the mapper (non-deterministic).
    pub realtime: bool,
    /// Diagnostic: the mapper triangulates from the true motion from each keyframe
    /// ([`crate::runtime::true_view_poses`]); `None` in the product.
    pub mapping_true_view_poses: Option<Arc<TrueCameraPoses>>,
}

/// Counters for the report.
#[derive(Clone, Debug, Default)]
pub struct OdometryStats {
    /// Back-dated motion onset of the first take-off.
    pub onset_t: Option<TimeNs>,
    /// The IMU's effective white-noise density on the pad before the first take-off (rotor
    /// vibration included; [`StaticEstimate::gyro_density_rad_s_sqrt_hz`]) and its ratio to the
    /// rig's `sensor.yaml` density: gyro rad/s/√Hz, accelerometer m/s²/√Hz.
    pub rest_imu_density: Option<RestImuDensity>,
    /// Time of the first tracked frame after the onset.
    pub tracking_since: Option<TimeNs>,
    pub resets: u32,
    /// Of `resets`, those that resumed tracking against the keyframe lost (`resume_max_s`).
    pub resumes: u32,
    /// Of `resets`, those that relocalised on a stored keyframe (`[bootstrap] relocalise`).
    pub relocalisations: u32,
    /// First maps started again in flight that joined the keyframe window across the loss
    /// (`[window] keep_across_rebuild`) instead of restarting it.
    pub window_kept_across_rebuild: u32,
    /// Times the keyframe window restarted at a keyframe in flight (after the bootstrap's first):
    /// at a loss, a return to a stored keyframe it cannot join, a gap in the buffered IMU, or a
    /// solution that is not finite.
    pub window_restarts: u32,
    /// `[window] gyro_misalignment`: the gyro's turn against the body frame (`ω_body = Exp(φ)
    /// ω_gyro`) after every window solve, as (newest keyframe's time, φ in rad)
    /// (`OUT/window_gyro_turn.csv`): how the estimate settles over a flight.
    pub window_gyro_misalignment_history: Vec<(TimeNs, Vector3<f64>)>,
    pub keyframes: usize,
    /// Times the tracker returned to a stored keyframe instead of starting a new one.
    pub keyframe_reuses: usize,
    /// Times a stored keyframe lost track right after the tracker returned to it.
    pub keyframe_reuse_failures: usize,
    /// Of these, failing frames tracked again on the keyframe left from the chain's state
    /// (`Odometry::retrack_on_chain`).
    pub chain_retracks: usize,
    /// First maps started in flight installed at once with guessed depths (`[bootstrap]
    /// reinit_guessed_depths`).
    pub reinit_guessed_keyframes: usize,
    /// Keyframes of turns on the spot made by the tracking thread (`fill_without_mapper`).
    pub spot_turn_keyframes: usize,
    /// Time of each of their builds on the builder thread (`vidslam-kf-build`), s.
    pub spot_turn_build_s: Vec<f64>,
    /// Mapper maps taken for tracking (or for a take-off refinement pass) whose keyframe the
    /// mapper had built (`[bootstrap] mapper_builds_keyframes`), and those the tracking thread
    /// built when it took them (the first map, the depthless fill of a turn on the spot, a hint
    /// missed, or the option off).
    pub keyframes_built_by_mapper: usize,
    pub keyframes_built_on_tracking_thread: usize,
    /// New keyframes started when the keyframe tracked had reached `[tracking]
    /// keyframe_max_age_s` (possibly with another reason as well).
    pub aged_keyframes: usize,
    /// Stored keyframes that failed their probation where the keyframe left was out of view
    /// (`[reuse] return_min_overlap`): a new keyframe was started instead of going back.
    pub returns_out_of_view: usize,
    /// Frames whose velocity was set to zero (the vehicle at rest).
    pub zero_velocity_updates: usize,
    /// Keyframes stored for returning to them.
    pub keyframes_stored: usize,
    /// Scale correction of each applied take-off refinement pass (the take-off's first, then
    /// those of first maps started in flight).
    pub takeoff_scales: Vec<f64>,
    /// Wall time of each applied take-off refinement pass, s.
    pub takeoff_refinement_s: Vec<f64>,
    /// Frames each applied take-off refinement pass re-posed (at most `[bootstrap]
    /// takeoff_max_pass_frames` of the take-off's, evenly spaced).
    pub takeoff_pass_views: Vec<usize>,
    /// Frames between sending each applied take-off refinement pass and applying it.
    pub takeoff_pass_lag_frames: Vec<u64>,
    /// Take-off refinements and keyframe adjustments not started: their thread was still busy
    /// (real time).
    pub refinements_dropped: usize,
    /// Of those started, the ones whose outcome was not used: superseded by a newer one, or their
    /// keyframe (first map) no longer tracked (built) when they came back.
    pub refinements_discarded: usize,
    /// Frames tracked again against an adjusted keyframe that came back after them.
    pub catch_up_frames: usize,
    /// Every keyframe adjustment that came back, in order (`OUT/adjustments.csv`): what each
    /// changed and what became of it ([`OdometryStats::keyframe_bundle_s`] and the other
    /// figures per adjustment are read from it).
    pub adjustments: Vec<AdjustmentRecord>,
    /// Scale change (new / old depths) of each keyframe tracked with guessed depths and then
    /// adjusted with its depths free (`[keyframe_bundle] guessed_min_baseline_ratio`).
    pub guessed_keyframe_scales: Vec<f64>,
    pub jobs_dropped: usize,
    /// The map scale measured against the IMU at each new keyframe (`[scale_observer]`).
    pub imu_scale: Vec<ScaleSample>,
    /// Wall time of each keyframe-window solve (on the tracking thread), s.
    pub window_solve_s: Vec<f64>,
    /// Each window solve's change of the distance from the window's previous newest keyframe
    /// to the new one (solved / as tracked; baselines over 1 cm): the correction by which the
    /// IMU's scale reaches the maps, since the mapper's world is chained through it
    /// (`mapper_from_world`).
    pub window_baseline_ratios: Vec<f64>,
    /// With `[window] map_scale`: after each window solve, the estimated log-scale λ of every
    /// keyframe map in the window, as (keyframe time, λ) (`OUT/window_scale.csv`).
    pub window_map_log_scales: Vec<(TimeNs, f64)>,
    /// With `[window] map_scale_gain`: each correction `c` of a keyframe map's log-scale (its
    /// depths scaled by `e^{−c}` when the next keyframe was started).
    pub window_map_scale_corrections: Vec<f64>,
    /// The gyro's axes turned onto the camera's body frame in flight (`[gyro_alignment]`).
    pub gyro_alignment: GyroAlignmentStats,
    /// Latency of each new keyframe in flight, frames from the frame that started it: to its
    /// first map from the mapper, and to its installation for tracking (which also waits for the
    /// frames its adjustment needs, and for the adjustment). Offline the first is `[bootstrap]
    /// offline_lag_frames`; in real time it is what the mapper's speed gives.
    pub keyframe_map_latency_frames: Vec<u64>,
    pub keyframe_install_latency_frames: Vec<u64>,
    /// Images are divided by the rig's vignetting.
    pub vignette_corrected: bool,
    /// Pixels clipped at 255 by the vignetting correction (bright texture in the corners).
    pub vignette_saturated_px: u64,
}

impl OdometryStats {
    /// The in-flight keyframe adjustments applied (`[keyframe_bundle]`), in order.
    fn applied_adjustments(&self) -> impl Iterator<Item = &AdjustmentRecord> {
        self.adjustments
            .iter()
            .filter(|r| r.outcome == AdjustmentOutcome::Applied)
    }

    /// Wall time of each applied keyframe adjustment on the refinement thread, s.
    pub fn keyframe_bundle_s(&self) -> Vec<f64> {
        self.applied_adjustments().map(|r| r.time_s).collect()
    }

    /// Median relative inverse-depth change of each applied keyframe adjustment.
    pub fn keyframe_bundle_depth_changes(&self) -> Vec<f64> {
        self.applied_adjustments().map(|r| r.depth_change).collect()
    }

    /// Norm of the accelerometer-bias change each applied keyframe adjustment handed to the
    /// tracker (its estimate from the keyframe's few tenths of a second of views minus the
    /// tracker's), m/s². The bias should move by its random walk (~0.003 m/s² per √s on the
    /// EuRoC IMU); jumps of tenths mean the adjustment explains a pose or depth error with it.
    pub fn keyframe_bundle_accel_bias_jumps_m_s2(&self) -> Vec<f64> {
        self.applied_adjustments()
            .map(|r| r.accel_bias_jump_m_s2)
            .collect()
    }

    /// Norm of the change of the last view's velocity of each keyframe adjustment that came back
    /// with a finite result (its adjusted state minus the one tracking had), applied or
    /// rejected, m/s.
    pub fn keyframe_bundle_velocity_changes_m_s(&self) -> Vec<f64> {
        self.adjustments
            .iter()
            .filter(|r| {
                matches!(
                    r.outcome,
                    AdjustmentOutcome::Applied | AdjustmentOutcome::Rejected
                )
            })
            .map(|r| r.velocity_change_m_s)
            .collect()
    }

    /// Keyframe adjustments not applied because they moved that velocity by more than
    /// `[keyframe_bundle] max_velocity_change_m_s`.
    pub fn refinements_rejected(&self) -> usize {
        self.adjustments
            .iter()
            .filter(|r| r.outcome == AdjustmentOutcome::Rejected)
            .count()
    }

    /// `[window] gyro_misalignment`: the gyro's turn as the keyframe window last solved it, rad
    /// (`None` before its first solve, or without the estimate).
    pub fn window_gyro_misalignment_rad(&self) -> Option<Vector3<f64>> {
        self.window_gyro_misalignment_history
            .last()
            .map(|&(_, phi)| phi)
    }
}

/// The IMU's noise measured at rest (see [`OdometryStats::rest_imu_density`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RestImuDensity {
    pub gyro_rad_s_sqrt_hz: f64,
    pub accel_m_s2_sqrt_hz: f64,
    /// Measured over `sensor.yaml`'s density.
    pub gyro_ratio: f64,
    pub accel_ratio: f64,
    /// The scales of `sensor.yaml`'s densities the tracker weights the IMU with from the take-off
    /// on: the ratios above (at least 1) times `[bootstrap] rest_imu_noise_factor`, or
    /// `[tracking] imu_noise_scale` for both when that is off.
    pub gyro_scale: f64,
    pub accel_scale: f64,
    /// The factor on the rotation part of the keyframe window's and the keyframe adjustment's
    /// IMU factors from the take-off on: `gyro_ratio` (at least 1) when `[bootstrap]
    /// rest_gyro_rotation_noise` is on, else 1.
    pub rotation_noise_scale: f64,
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
    /// [`Self::catch_up_limit`]): tracked again once it is back.
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
    /// The new keyframe awaited in flight: its id, the frame number that started it, and whether
    /// its first map has arrived (for the latency statistics).
    kf_started: Option<(u32, u64, bool)>,
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
            tracking_kf_adjusted: false,
            guessed: None,
            guessed_snapshot: None,
            reinit_kf: None,
            relocalised: false,
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
        self.times.total_s = started.elapsed().as_secs_f64();
        self.times.cpu_s = cpu_started
            .zip(thread_cpu_time_s())
            .map(|(a, b)| (b - a).max(0.0));
        f.times = self.times;
        f
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
                    if let Some(tk) = self.takeoff.as_mut() {
                        tk.frames.push(frame.clone());
                    }
                    self.observe(frame.clone());
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
                let r = &self.cfg.reuse;
                // The stored keyframe does not fit after all — it loses its inliers on probation
                // (occlusion, a different exposure, a bad map) or its brightness collapses at any
                // time: back to the keyframe left — or, if that one is out of view, a new
                // keyframe from here (`return_min_overlap`).
                let failed_probation = self.reuse_frames <= r.probation_frames
                    && (result.flag == Some(FlagReason::FewInliers)
                        || result.inlier_ratio < r.probation_min_inlier_ratio);
                let collapsed = self.tracker.brightness_collapsed(&result);
                let stored_unfit = self.reusing && (failed_probation || collapsed);
                if !self.reusing || (self.reuse_frames > r.probation_frames && !stored_unfit) {
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
                    if let Some(c) = self.window_keyframe(&mut result) {
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
                        self.stats.imu_scale.push(ScaleSample {
                            t,
                            scale: e.scale,
                            scale_std: e.scale_std,
                            rms_m: e.rms_m,
                        });
                    }
                    if self
                        .tracker
                        .keyframe_older_than(t, self.cfg.tracking.keyframe_max_age_s)
                    {
                        self.stats.aged_keyframes += 1;
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
        let max_catch_up = self.catch_up_limit();
        if self.phase == Phase::Tracking && self.adjusting_keyframe().is_some() && max_catch_up > 0
        {
            // The newest ones only.
            if self.catch_up.len() >= max_catch_up {
                self.catch_up.remove(0);
            }
            self.catch_up.push((t, image.clone()));
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
            times: FrameTimes::default(),
        }
    }

    /// Stops the mapping thread and returns what it built.
    pub fn finish(mut self) -> (OdometryStats, MappingOutput) {
        self.record_gyro_alignment();
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
        self.window
            .set_imu_rotation_noise_scale(rotation_noise_scale);
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
        let mut pre = Preintegration::new(t0, self.tracker.state().bias);
        // `integrate` finds the samples bracketing the interval itself.
        pre.integrate(self.imu.make_contiguous(), t, Some(&self.imu_noise));
        let phi = self.gyro_turn_rad();
        if phi != Vector3::zeros() {
            // The gyro turned onto the body frame as the keyframe window reads it.
            pre = crate::imu::misalignment::turned(&pre, &phi);
        }
        self.last_t = Some(t);
        let x0 = *self.tracker.state();
        if let Some(s) = self.chain_shadow.as_mut() {
            s.advance(&pre);
        }
        let r = self.tracker.track(t, image, &pre);
        // The first frame on another keyframe jumps by the drift between the two: the IMU's
        // step stands in for it.
        let p1 = if std::mem::take(&mut self.keyframe_jump) {
            let predicted = FrameState {
                nav: pre.predict(&x0.nav, &x0.bias),
                bias: x0.bias,
            };
            if self.switch_correction == Some(SwitchCorrection::Pending) {
                self.switch_correction = r.flag.is_none().then(|| SwitchCorrection::Measured {
                    c: pose_of(&r.state) * pose_of(&predicted).inverse(),
                    pivot_m: predicted.nav.p_world_m,
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
                    .stored_keyframe_covering(&at, Some(s.kf.id), false)
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
        self.start_keyframe(frame.clone(), Vec::new(), false);
        self.init_started = Some(frame.t);
        self.init_in_flight = true;
        if guessed && self.cfg.bootstrap.reinit_guessed_depths {
            self.install_reinit_keyframe(frame);
        }
    }

    /// A first map is about to be started again in flight, at the tracker's (dead-reckoned)
    /// state: with `[window] keep_across_rebuild`, and the IMU since the window's newest keyframe
    /// still buffered and spanning at most `keep_across_rebuild_max_s`, the new map's first
    /// keyframe joins the window by the IMU through the loss
    /// ([`KeyframeWindow::push_new_map`]); otherwise the window restarts there.
    fn window_across_loss(&mut self) {
        let w = &self.cfg.window;
        let x = *self.tracker.state();
        let joinable = (w.enabled && w.keep_across_rebuild)
            .then(|| self.window.newest().map(|(_, xn)| *xn))
            .flatten()
            .filter(|xn| {
                let gap_s = x.nav.t.secs_since(xn.nav.t);
                gap_s > 0.0 && gap_s <= w.keep_across_rebuild_max_s && self.imu_buffered_since(xn)
            });
        let Some(xn) = joinable else {
            self.reset_window();
            return;
        };
        let pre = self.preintegrate_buffered(&xn, x.nav.t);
        self.window.push_new_map(self.next_kf_id, x, pre);
        self.stats.window_kept_across_rebuild += 1;
    }

    /// The gyro's turn against the body frame as the keyframe window reads it (`[window]
    /// gyro_misalignment`; zero when off), rad: the tracker's and the keyframe adjustment's IMU
    /// are turned by it.
    fn gyro_turn_rad(&self) -> Vector3<f64> {
        if self.cfg.window.gyro_misalignment {
            self.window.gyro_misalignment_rad()
        } else {
            Vector3::zeros()
        }
    }

    /// The turn the keyframe adjustment's IMU gets: [`Odometry::gyro_turn_rad`] once it is at
    /// least `[keyframe_bundle] gyro_turn_min_rad`, zero before.
    fn adjustment_gyro_turn_rad(&self) -> Vector3<f64> {
        let phi = self.gyro_turn_rad();
        if phi.norm() >= self.cfg.keyframe_bundle.gyro_turn_min_rad {
            phi
        } else {
            Vector3::zeros()
        }
    }

    /// Whether the IMU buffer still reaches back to keyframe state `from`.
    fn imu_buffered_since(&self, from: &FrameState) -> bool {
        self.imu.front().is_some_and(|s| s.t <= from.nav.t)
    }

    /// The buffered IMU from keyframe state `from` to `t`, preintegrated at `from`'s bias with
    /// the odometry's noise (a keyframe window factor; [`Odometry::imu_buffered_since`] first).
    fn preintegrate_buffered(&mut self, from: &FrameState, t: TimeNs) -> Preintegration {
        let mut pre = Preintegration::new(from.nav.t, from.bias);
        pre.integrate(self.imu.make_contiguous(), t, Some(&self.imu_noise));
        pre
    }

    /// Restarts the keyframe window at the keyframe about to be started, from the tracker's
    /// state and covariance.
    fn reset_window(&mut self) {
        if !self.window.is_empty() {
            self.stats.window_restarts += 1;
        }
        let x = *self.tracker.state();
        let cov = *self.tracker.covariance();
        self.window.reset(self.next_kf_id, x, &cov);
    }

    /// Adds the frame of `result` (about to become keyframe `next_kf_id`) to the window, joined to
    /// the keyframe it was tracked against (across a return to a stored keyframe, with `[reuse]
    /// keep_window`, to the window's newest through the switch's drift correction), solves, and
    /// moves the tracker's keyframe and state onto the solution. Returns the world correction
    /// applied to the current frame (`T_new = C · T_old`), `None` if the window is off or could
    /// not be used.
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
        let buffered = self.imu_buffered_since(&x_prev);
        let mut across_return = false;
        let visual = if self.tracking_kf == Some(newest) && buffered {
            self.tracker
                .keyframe()
                .filter(|kf| kf.id == newest)
                .map(|kf| {
                    let t_w_bk = kf.t_world_cam * self.rig.t_body_cam.inverse();
                    RelativePose {
                        t_i_j: t_w_bk.inverse() * pose_of(&result.state),
                        information: result.photometric_info,
                    }
                })
        } else if let Some(SwitchCorrection::Measured { c, pivot_m: pivot }) =
            self.switch_correction
            && self.reusing
            && self.cfg.reuse.keep_window
            && buffered
        {
            across_return = true;
            // Tracked against a stored keyframe since leaving the window's newest: the window
            // moves onto the stored keyframe's world by the correction's heading and position
            // (a change of gauge), and the new keyframe is joined to the newest through it.
            self.window.transform_world(&heading_part(&c, &pivot));
            let (_, x_newest) = self.window.newest()?;
            Some(RelativePose {
                t_i_j: pose_of(x_newest).inverse() * pose_of(&result.state),
                information: result.photometric_info,
            })
        } else {
            // Tracked against a stored keyframe (its correction of the drift would fight the
            // window's older keyframes), or the IMU since the last keyframe is no longer
            // buffered: restart the window here.
            self.reset_window();
            return None;
        };
        let tracked_newest = visual.is_some() && !across_return;
        let x_prev = *self.window.newest()?.1;
        let pre = self.preintegrate_buffered(&x_prev, t);
        let old = result.state;
        self.window.push(id, old, pre, visual);
        if across_return {
            self.window.set_newest_visual_on_own_map();
        }
        let started = std::time::Instant::now();
        self.window.solve();
        let solve_s = started.elapsed().as_secs_f64();
        if self.cfg.window.gyro_misalignment {
            let phi = self.window.gyro_misalignment_rad();
            self.stats.window_gyro_misalignment_history.push((t, phi));
        }
        self.stats.window_solve_s.push(solve_s);
        self.times.window_s += solve_s;
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
        // The previous newest keyframe as solved.
        let xk = self.window.state(newest).copied();
        if self.cfg.window.map_scale {
            self.stats
                .window_map_log_scales
                .extend(self.window.log_scales());
        }
        if let Some(xk) = &xk {
            let before_m = (old.nav.p_world_m - x_prev.nav.p_world_m).norm();
            let after_m = (x_new.nav.p_world_m - xk.nav.p_world_m).norm();
            if before_m > 0.01 {
                self.stats.window_baseline_ratios.push(after_m / before_m);
            }
        }
        let cov = *self.tracker.covariance();
        self.tracker.reset_state(x_new, cov);
        if let Some(xk) = &xk
            && self.tracker.keyframe().is_some_and(|kf| kf.id == newest)
        {
            self.tracker
                .set_keyframe_pose(pose_of(xk) * self.rig.t_body_cam);
        }
        if across_return && let Some(kf) = self.tracker.keyframe() {
            // The stored keyframe tracked (the tracker's copy) and its map seeding the new one
            // move with the correction: the new keyframe keeps the pose tracking measured
            // relative to them, and the frames tracked against it until the new one is
            // installed stay in the new keyframe's world.
            let moved = correction * kf.t_world_cam;
            self.tracker.set_keyframe_pose(moved);
            self.seed_correction = Some(correction);
        }
        if tracked_newest {
            self.correct_map_scale(newest, &old);
        }
        // Stored keyframes still in the window move with it.
        for (id, x) in self.window.states() {
            self.store.set_pose(id, pose_of(x) * self.rig.t_body_cam);
        }
        result.state = x_new;
        Some(correction)
    }

    /// `[window] map_scale_gain`: the map of keyframe `id` — the one tracked, the new keyframe's
    /// predecessor — is scaled by the window's estimate of its scale before the new keyframe
    /// (at state `current`, as tracked) is started from it: in the tracker, the map kept with it
    /// and the mapper, and the frames kept for the new keyframe (tracked against the map before)
    /// about the current camera. Not for a keyframe of guessed depths or a stored one.
    fn correct_map_scale(&mut self, id: u32, current: &FrameState) {
        let w = &self.cfg.window;
        let applies = w.map_scale
            && w.map_scale_gain > 0.0
            && self.mapped_keyframe_tracked(id)
            && self.guessed.is_none();
        if !applies {
            return;
        }
        let Some(lambda) = self.window.log_scale(id) else {
            return;
        };
        let c = (w.map_scale_gain * lambda).clamp(-w.map_scale_max_step, w.map_scale_max_step);
        if !c.is_finite() || c == 0.0 {
            return;
        }
        let depth_factor = (-c).exp();
        self.scale_tracked_map(id, depth_factor);
        self.rescale_history(
            (pose_of(current) * self.rig.t_body_cam).translation.vector,
            depth_factor,
        );
        self.window.set_newest_map_correction(c);
        self.stats.window_map_scale_corrections.push(c);
    }

    /// Multiplies the depths of keyframe `id`'s map, the one tracked against, by `depth_factor`
    /// about its camera: the tracker's copy, the map kept with it (stored with it later) and the
    /// mapper's (which propagates it into the next keyframe).
    fn scale_tracked_map(&mut self, id: u32, depth_factor: f64) {
        self.tracker.scale_keyframe_depths(depth_factor);
        if let Some(m) = self.tracking_map.as_mut() {
            let mut scaled = (**m).clone();
            scaled.scale_inv_depths(1.0 / depth_factor);
            *m = Arc::new(scaled);
        }
        self.send_scale_depths(id, 1.0 / depth_factor);
    }

    /// The mapper's copy of keyframe `id` gets its inverse depths multiplied by
    /// `inv_depth_factor` (and so does the next keyframe it propagates from it).
    fn send_scale_depths(&mut self, id: u32, inv_depth_factor: f64) {
        let seq = self.next_seq();
        self.send(MapJob::ScaleDepths {
            seq,
            id,
            factor: inv_depth_factor,
        });
    }

    /// The frames kept for the next keyframe were tracked against a map now scaled by
    /// `depth_factor` about the camera centre `centre_m`: their positions follow.
    fn rescale_history(&mut self, centre_m: Vector3<f64>, depth_factor: f64) {
        for h in self.history.iter_mut() {
            let p = &mut h.t_world_cam.translation.vector;
            *p = centre_m + (*p - centre_m) * depth_factor;
        }
    }

    /// Fault injection for tests: the map tracked against gets its depths multiplied by
    /// `depth_factor`, as if it had been triangulated at a wrong scale — which is how the map
    /// chain's scale wanders (docs/odometry-log.md, *Where S-V101's error comes from*). Returns
    /// whether there was a mapped keyframe to scale (none while lost, initialising, tracking a
    /// stored keyframe or one of guessed depths).
    pub fn inject_map_scale_error(&mut self, depth_factor: f64) -> bool {
        let Some(id) = self.tracking_kf else {
            return false;
        };
        if self.phase != Phase::Tracking
            || !self.mapped_keyframe_tracked(id)
            || self.pending_kf.is_some()
            || !(depth_factor.is_finite() && depth_factor > 0.0)
        {
            return false;
        }
        self.scale_tracked_map(id, depth_factor);
        true
    }

    /// Keyframe `id` is the one tracked against, with the mapper's map (not a stored keyframe,
    /// nor one tracked with guessed depths).
    fn mapped_keyframe_tracked(&self, id: u32) -> bool {
        self.tracking_kf == Some(id)
            && !self.reusing
            && !self.tracking_kf_filled
            && self.tracker.keyframe().is_some_and(|kf| kf.id == id)
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
    /// Switched; the next frame, tracked on the stored keyframe, measures it.
    Pending,
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
