//! `report.json` of a replay: frame counts, tracking time percentiles and the `vidslam eval`
//! figures against ground truth, as one flat JSON object with stable keys.

use super::map_depth::{KeyframeDepthError, median};
use super::odometry::{FrameTimes, Phase};
use super::replay::ReplayOutput;
use crate::dataset::{GroundTruth, Trajectory};
use crate::eval::stats::{percentile, sorted};
use crate::eval::velocity::velocity_errors;
use crate::eval::{EvalOptions, EvalReport, SegmentError, alignment, evaluate};
use crate::loop_closure::closer::LoopClosureStats;
use crate::runtime::odometry::LoopEdgeSummary;
use crate::time::TimeNs;
use crate::tracking::{TrackResult, pose_of};
use serde::Serialize;
use std::collections::BTreeMap;

/// The scale error and ATE of the trajectory from its start up to `t_s` (each prefix aligned on
/// its own): how long a run stays accurate, less chaotic than the whole run's figure.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct ScaleAt {
    /// Seconds since the first pose.
    pub t_s: f64,
    pub scale_error_pct: f64,
    pub ate_rmse_m: f64,
}

/// The parts of the tracking thread's slowest frames ([`crate::runtime::odometry::FrameTimes`]),
/// each the mean over those frames, ms.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct FrameTail {
    /// Tracked frames at or above the p99 of the whole frame's time.
    pub frames: usize,
    pub total_ms: f64,
    pub maps_ms: f64,
    pub adjustments_ms: f64,
    pub tracking_ms: f64,
    pub window_ms: f64,
    pub other_ms: f64,
    /// The tracking thread's CPU time over those frames (`None` where it cannot be read): the
    /// rest of `total_ms` it spent off its core.
    pub cpu_ms: Option<f64>,
}

impl FrameTail {
    /// The mean parts of the frames of `times` whose total is at least `threshold_ms`.
    fn of(times: &[&FrameTimes], threshold_ms: f64) -> Self {
        let tail: Vec<_> = times
            .iter()
            .filter(|t| t.total_s * 1e3 >= threshold_ms)
            .collect();
        if tail.is_empty() {
            return Self::default();
        }
        let mean_ms = |f: &dyn Fn(&FrameTimes) -> f64| {
            tail.iter().map(|t| f(t) * 1e3).sum::<f64>() / tail.len() as f64
        };
        Self {
            frames: tail.len(),
            total_ms: mean_ms(&|t| t.total_s),
            maps_ms: mean_ms(&|t| t.maps_s),
            adjustments_ms: mean_ms(&|t| t.adjustments_s),
            tracking_ms: mean_ms(&|t| t.tracking_s),
            window_ms: mean_ms(&|t| t.window_s),
            other_ms: mean_ms(&|t| t.other_s()),
            cpu_ms: tail
                .iter()
                .all(|t| t.cpu_s.is_some())
                .then(|| mean_ms(&|t| t.cpu_s.unwrap_or(0.0))),
        }
    }
}

/// The replay's own figures (the evaluation's are merged in by [`ReplayReport::to_json`]).
#[derive(Clone, Debug, Serialize)]
pub struct ReplayReport {
    pub frames_in: usize,
    pub frames_tracked: usize,
    pub frames_flagged: usize,
    /// Tracked frames solved again with the photometric term down-weighted (`[tracking]
    /// vision_downweight_chi2`).
    pub frames_downweighted: usize,
    /// Flag counts by reason.
    pub flags: BTreeMap<String, usize>,
    pub keyframes: usize,
    /// Returns to a stored keyframe (the closest one) instead of starting a new keyframe.
    pub keyframe_reuses: usize,
    /// Of these, returns that lost track at once (back to the keyframe left).
    pub keyframe_reuse_failures: usize,
    /// Of these, failing frames tracked again on the keyframe left, from the state the chain of
    /// new keyframes would have had without the return.
    pub chain_retracks: usize,
    /// Keyframes stored for returning to them.
    pub keyframes_stored: usize,
    /// Keyframes of turns on the spot made by the tracking thread without waiting for the mapper
    /// (`[bootstrap] fill_without_mapper`).
    pub spot_turn_keyframes: usize,
    /// Their builds on the builder thread between frames, ms (`None` without any).
    pub spot_turn_build_ms_p50: Option<f64>,
    pub spot_turn_build_ms_max: Option<f64>,
    /// Mapper maps taken for tracking (or a take-off refinement pass) whose keyframe the mapping
    /// thread had built (`[bootstrap] mapper_builds_keyframes`), and those the tracking thread
    /// built itself, inside its frame.
    pub keyframes_built_by_mapper: usize,
    pub keyframes_built_on_tracking_thread: usize,
    /// Tracker keyframes the mapping thread built (installed or not) and their build time, ms.
    pub mapper_keyframe_builds: usize,
    pub mapper_keyframe_build_ms_p50: Option<f64>,
    pub mapper_keyframe_build_ms_max: Option<f64>,
    /// New keyframes started when the keyframe tracked had reached `[tracking]
    /// keyframe_max_age_s`.
    pub aged_keyframes: usize,
    /// New keyframes started when the tracked velocity had left the IMU's dead reckoning from
    /// the window's newest keyframe by more than `[tracking]
    /// keyframe_max_velocity_divergence_m_s`.
    pub diverged_keyframes: usize,
    /// Keyframes aligned against the map two back (`[window] skip_edges`), and those whose
    /// alignment held and joined the keyframe window as a skip edge.
    pub window_skip_edges_tried: usize,
    pub window_skip_edges: usize,
    /// Stored keyframes that failed their probation while the keyframe left for them was out of
    /// view: a new keyframe was started instead of going back (`[reuse] return_min_overlap`).
    pub returns_out_of_view: usize,
    /// Frames whose velocity was set to zero: the IMU said the vehicle rests (`[bootstrap] zupt_*`).
    pub zero_velocity_updates: usize,
    /// Scale factor applied to the first map by each take-off refinement pass.
    pub takeoff_scale_corrections: Vec<f64>,
    /// Wall time of each take-off refinement pass, ms (the frames meanwhile are IMU-only).
    pub takeoff_refinement_ms: Vec<f64>,
    /// Frames each take-off refinement pass re-posed (at most `[bootstrap]
    /// takeoff_max_pass_frames`, evenly spaced over the take-off).
    pub takeoff_pass_views: Vec<usize>,
    /// Frames between sending each take-off refinement pass and applying it.
    pub takeoff_pass_lag_frames: Vec<u64>,
    pub tracking_ms_p50: f64,
    pub tracking_ms_p99: f64,
    pub tracking_ms_max: f64,
    pub tracking_ms_mean: f64,
    /// The tracking thread's whole time per tracked frame (`tracking_ms` is the tracker's
    /// Gauss-Newton and the keyframe window; this adds the image's corrections, taking in the
    /// mapper's and the refinement's results and building and installing keyframes), ms. In real
    /// time that is the frame's latency on the vehicle; offline it also holds the waits for the
    /// mapper's and the refinement's results at their fixed frames (what keeps a replay
    /// deterministic), so only the real-time figure measures the tracking thread.
    pub frame_ms_p50: f64,
    pub frame_ms_p99: f64,
    pub frame_ms_max: f64,
    /// Where the slowest frames' time went: the mean of each part over the tracked frames at or
    /// above `frame_ms_p99` (what the p99 is made of).
    pub frame_tail: FrameTail,
    /// Mean accepted Gauss-Newton iterations per frame, summed over levels.
    pub iterations_mean: f64,
    /// Frames whose pose has a non-finite number (must be 0).
    pub non_finite_poses: usize,
    /// Span of the replayed data, s.
    pub duration_s: f64,
    pub vision: bool,
    pub depth: String,
    /// Poses the mapper triangulated from: `tracked` (the product) or `gt` (`vidslam replay
    /// --mapping-poses gt`, a diagnostic).
    pub mapping_poses: String,
    /// The loop closer's edges: `measured` (the product) or `gt` (`vidslam replay --loop-edges
    /// gt`, a diagnostic: the keyframes' true relative poses).
    pub loop_edge_source: String,
    /// Replayed paced at the camera's timestamps (`--realtime`): the background results arrived
    /// as late as this machine made them, so the figures are one sample of a timing-dependent run.
    pub realtime: bool,
    /// Real time: the tracking thread's `SCHED_FIFO` priority, 0 if it ran under the default
    /// policy (`[bootstrap] tracking_fifo_priority` off, or not permitted: `tracking_fifo_note`).
    pub tracking_fifo_priority: i32,
    /// Why the tracking thread ran without a real-time priority, if it did ("" otherwise).
    pub tracking_fifo_note: String,
    /// Frames read before the first valid pose (rest not yet detected).
    pub frames_waiting: usize,
    /// Frames per odometry phase (static, initializing, tracking, lost).
    pub phases: BTreeMap<String, usize>,
    /// From the (back-dated) motion onset to the first frame tracked against a map, s.
    pub init_time_s: Option<f64>,
    /// The IMU's effective white-noise density on the pad before the take-off (block means'
    /// scatter, rotor vibration included) and its ratio to `sensor.yaml`'s: what the fixed
    /// `[tracking]` / `[window] imu_noise_scale` stands for.
    pub rest_gyro_density_rad_s_sqrt_hz: Option<f64>,
    pub rest_accel_density_m_s2_sqrt_hz: Option<f64>,
    pub rest_gyro_density_ratio: Option<f64>,
    pub rest_accel_density_ratio: Option<f64>,
    /// The scales of `sensor.yaml`'s densities the tracker weighted the IMU with after the
    /// take-off: the ratios above times `[bootstrap] rest_imu_noise_factor`, or the fixed
    /// `[tracking] imu_noise_scale` when that is off.
    pub imu_gyro_noise_scale: Option<f64>,
    pub imu_accel_noise_scale: Option<f64>,
    /// The factor on the rotation part of the keyframe window's and the keyframe adjustment's IMU
    /// factors after the take-off (`[bootstrap] rest_gyro_rotation_noise`; 1 when off), on top
    /// of their `imu_rotation_noise_factor`.
    pub imu_rotation_noise_scale: Option<f64>,
    /// `[window] inflight_gyro_noise`: keyframe intervals the gyro's noise was read over in
    /// flight, its last median reading (the gyro's error against the tracked rotations over its
    /// modelled density, 1 = as modelled; the camera's own error keeps a perfect gyro's reading
    /// a little above 1), and the factor on the back end's IMU rotations at the end (in place of
    /// `imu_rotation_noise_scale` once read; `None` when off).
    pub inflight_gyro_noise_intervals: Option<usize>,
    pub inflight_gyro_noise_ratio: Option<f64>,
    pub inflight_gyro_rotation_noise_scale: Option<f64>,
    /// Re-initialisations after tracking loss.
    pub resets: u32,
    /// Of `resets`, losses of the image (a covered lens) that resumed tracking on the keyframe
    /// lost instead of building a new first map (`[bootstrap] resume_max_s`).
    pub resumes: u32,
    /// Of `resets`, losses by motion that relocalised on a stored keyframe covering the
    /// IMU-predicted view instead of building a new first map (`[bootstrap] relocalise`).
    pub relocalisations: u32,
    /// Views of first maps started in flight whose translation from the keyframe was turned to
    /// the direction their images give (`[bootstrap] reinit_shape_from_images`).
    pub reinit_shaped_views: u32,
    /// First maps started in flight that did not start in time from the dead reckoning and were
    /// installed with guessed depths instead (`[bootstrap] reinit_guessed_depths`).
    pub reinit_guessed_keyframes: usize,
    /// First maps started in flight that joined the keyframe window through the loss instead of
    /// restarting it (`[window] keep_across_rebuild`).
    pub window_kept_across_rebuild: u32,
    /// Times the keyframe window restarted in flight (a loss, a return to a stored keyframe it
    /// could not join, a gap in the buffered IMU, a solution that is not finite).
    pub window_restarts: u32,
    /// Longest time from a loss to tracking again, s (`None`: no loss recovered).
    pub recovery_s_max: Option<f64>,
    /// Lost and not tracking again when the replay ended: for this long, s (an in-flight first
    /// map that never started, docs/odometry-log.md, *S-V101's real-time runaways*).
    pub unrecovered_s: Option<f64>,
    /// Mapper views dropped by the tracking thread, its queue full (real-time mode).
    pub mapping_jobs_dropped: usize,
    /// Views skipped by the mapper to keep up with the camera (real-time mode).
    pub mapping_views_skipped: usize,
    /// Mapping-thread time per job, ms.
    pub mapping_ms_mean: f64,
    pub mapping_ms_p50: f64,
    pub mapping_ms_p99: f64,
    /// Keyframe-window solves (each on the tracking thread, included in that frame's
    /// `tracking_ms`) and their wall time, ms.
    pub window_solves: usize,
    pub window_ms_p50: f64,
    pub window_ms_max: f64,
    /// Each window solve's change of the newest keyframe baseline (solved / as tracked, the
    /// correction that carries the IMU's scale into the maps): 10th / 50th / 90th percentiles.
    pub window_baseline_ratio_p10: Option<f64>,
    pub window_baseline_ratio_p50: Option<f64>,
    pub window_baseline_ratio_p90: Option<f64>,
    /// Each window solve's move of the present (tracked position → solved), m: 50th / 90th
    /// percentiles.
    pub window_present_move_m_p50: Option<f64>,
    pub window_present_move_m_p90: Option<f64>,
    /// `[window] map_scale_gain`: keyframe maps whose scale was corrected by the window's
    /// estimate, and the factor their depths were multiplied by: 10th / 50th / 90th percentiles.
    pub map_scale_corrections: usize,
    pub map_scale_correction_p10: Option<f64>,
    pub map_scale_correction_p50: Option<f64>,
    pub map_scale_correction_p90: Option<f64>,
    /// `[window] stored_map_scale_gain`: stored keyframe maps rescaled as they left the window,
    /// and the factor their depths were multiplied by: 10th / 50th / 90th percentiles.
    pub stored_map_scale_corrections: usize,
    pub stored_map_scale_correction_p10: Option<f64>,
    pub stored_map_scale_correction_p50: Option<f64>,
    pub stored_map_scale_correction_p90: Option<f64>,
    /// In-flight keyframe adjustments applied (`[keyframe_bundle]`, on a thread of their own
    /// started when a new keyframe is installed), their wall time, ms, and the median over
    /// keyframes of each adjustment's median relative inverse-depth change, %; take-off
    /// refinements and keyframe adjustments not started because their thread was busy (real
    /// time) or not used (superseded, or back after their keyframe was left).
    pub keyframe_bundles: usize,
    /// Of those, the adjustments made together with the keyframe tracked when theirs was started,
    /// that one the gauge (`[keyframe_bundle] previous_host`).
    #[serde(default)]
    pub keyframe_bundles_with_previous: usize,
    pub keyframe_bundle_ms_p50: f64,
    pub keyframe_bundle_ms_max: f64,
    pub keyframe_bundle_depth_change_median_pct: f64,
    /// Median and largest change of the accelerometer bias an adjustment handed to the tracker,
    /// m/s² (a diagnostic: the bias's own random walk allows millimetres per second squared).
    pub keyframe_bundle_accel_bias_jump_p50_m_s2: f64,
    pub keyframe_bundle_accel_bias_jump_max_m_s2: f64,
    /// Median and largest change of the last view's velocity an adjustment came back with, m/s,
    /// and the adjustments not applied for it (`[keyframe_bundle] max_velocity_change_m_s`).
    pub keyframe_bundle_velocity_change_p50_m_s: f64,
    pub keyframe_bundle_velocity_change_max_m_s: f64,
    pub refinements_rejected: usize,
    pub refinements_dropped: usize,
    pub refinements_discarded: usize,
    /// Frames tracked again on the tracking thread against an adjusted keyframe that came back
    /// after them, and those the refinement thread tracked again right after the adjustment
    /// (`[keyframe_bundle] catch_up_on_refinement_thread`).
    pub keyframe_bundle_catch_up_frames: usize,
    pub keyframe_bundle_catch_up_frames_on_refinement_thread: usize,
    /// New keyframes in flight: frames from the one that started a keyframe to its first map from
    /// the mapper, and to its installation for tracking (median and largest). In real time this is
    /// the latency the mapper's and the adjustment's speed give (docs/odometry-log.md, *S-V101 in
    /// real time, and its latencies*); offline the map's is `[bootstrap] offline_lag_frames`.
    pub keyframe_map_latency_frames_p50: f64,
    pub keyframe_map_latency_frames_max: f64,
    pub keyframe_install_latency_frames_p50: f64,
    pub keyframe_install_latency_frames_max: f64,
    /// Keyframes started in a turn on the spot, tracked with guessed depths while the mapper
    /// triangulated them from the poses tracked so, then adjusted with their depths free once
    /// their views spanned a baseline: the factor each one's depths were scaled by (adjusted /
    /// as mapped; 1 = the guesses' scale was right).
    pub guessed_keyframe_scales: Vec<f64>,
    /// The map scale measured against the IMU without ground truth (`[scale_observer]`: the
    /// factor from the tracked to the metric trajectory over the seconds before each new
    /// keyframe; 1 = consistent): how many estimates, and their 10th / 50th / 90th percentiles.
    pub imu_scale_estimates: usize,
    pub imu_scale_p10: Option<f64>,
    pub imu_scale_p50: Option<f64>,
    pub imu_scale_p90: Option<f64>,
    /// Estimates that turned the scale fault on (`[scale_observer] fault_min_scale` /
    /// `fault_max_scale`: the map's scale ran away) and the frames published failed for it.
    pub scale_faults: usize,
    pub scale_fault_frames: usize,
    /// Times the estimated speed went beyond the vehicle's (`[scale_observer]
    /// fault_max_speed_m_s`) and the frames published failed for it.
    pub speed_faults: usize,
    pub speed_fault_frames: usize,
    /// Each mapper view's scale against the map propagated from the previous keyframe (the
    /// median ratio of its inverse depths to the priors; 1 = its tracked baseline agrees with
    /// the map chain, `[mapping] view_scale_gain`): how many views, and their 10th / 50th / 90th
    /// percentiles.
    pub view_scale_views: usize,
    pub view_scale_p10: Option<f64>,
    pub view_scale_p50: Option<f64>,
    pub view_scale_p90: Option<f64>,
    /// Images divided by the dataset's vignetting (`cam0/vignette.yaml`), and the pixels that
    /// clipped at 255 doing so.
    pub vignette_corrected: bool,
    pub vignette_saturated_px: u64,
    /// Semidense points over all keyframes.
    pub semidense_points: usize,
    /// Keyframe maps compared with the simulator's depth (`keyframes.csv`; 0 without `depth0`),
    /// the median over keyframes of their median signed and absolute relative depth errors, and
    /// the smallest share of points within 10 % in any keyframe, %.
    pub map_depth_keyframes: usize,
    pub map_depth_signed_median_pct: Option<f64>,
    pub map_depth_abs_median_pct: Option<f64>,
    pub map_depth_worst_within_10pct: Option<f64>,
    /// Sim3 scale error and SE3 ATE of the trajectory up to every 10 s (from the first pose).
    pub scale_error_over_time: Vec<ScaleAt>,
    /// The whole run's SE3 alignment cut into 10 s segments: each one's ATE RMSE, mean signed
    /// heading error and RMS tilt error once the constant world and body rotations are removed
    /// ([`crate::eval::SegmentError`]) — where the heading drifts and where the position
    /// follows it.
    pub error_per_10s: Vec<SegmentError>,
    /// Norm of the error of the velocity the odometry outputs (what ODOMETRY #331 sends), against
    /// the ground truth's recorded velocity, after the SE3 alignment of the poses
    /// ([`crate::eval::velocity`]), m/s; `None` when the ground truth has no velocity column.
    pub velocity_rmse_m_s: Option<f64>,
    pub velocity_median_m_s: Option<f64>,
    pub velocity_p90_m_s: Option<f64>,
    pub velocity_max_m_s: Option<f64>,
    /// The same velocity error (RMS, m/s) on three kinds of frame of the keyframe cycle: the
    /// frame before each keyframe-window solve (tracking's own velocity), the solve's frame
    /// (the tracker's state replaced by the window's newest keyframe: the velocity the frames
    /// until the new keyframe is installed start from) and the first frame tracked against
    /// another keyframe (a new one, installed with its adjustment's last view, or a stored one
    /// returned to). On S-V101's typical seeds the
    /// window's velocity of the present is worse than tracking's and the adjustment's better than
    /// both (session 89: seed 1 0.035 / 0.046 / 0.032, docs/odometry-log.md, *The keyframe
    /// window's velocity of the present*); `None` without a ground-truth velocity or such frames.
    pub velocity_rmse_before_window_solves_m_s: Option<f64>,
    pub velocity_rmse_at_window_solves_m_s: Option<f64>,
    pub velocity_rmse_at_keyframe_switches_m_s: Option<f64>,
    /// The odometry's accelerometer bias (body), per axis the median over its tracked frames,
    /// m/s²; `None` if no frame was tracked.
    pub accel_bias_est_m_s2: Option<[f64; 3]>,
    /// The bias the ground truth implies (body, per axis the median over 2 s windows, see
    /// [`crate::eval::imu_consistency::implied_accel_bias`]), m/s²: what an odometry tracking the
    /// images exactly would estimate; `None` without ground truth.
    pub accel_bias_gt_m_s2: Option<[f64; 3]>,
    /// Norm of the difference of the two, m/s² (S-V101's real IMU: ~0.4, the odometry's attitude
    /// leaning by ~2°, see docs/odometry-log.md, *The accelerometer bias against the ground
    /// truth*).
    pub accel_bias_error_m_s2: Option<f64>,
    /// `[gyro_alignment]`: the rotation applied to the gyro at the end (`log(R_x)`, gyro axes →
    /// the camera's body frame, degrees), the last estimate and its std per component, the RMS
    /// of the pairs' residuals at it, the pairs it rests on, the offered pairs dropped as gross
    /// errors, and when the estimate was first applied in flight (`apply`; s after the first
    /// frame).
    pub gyro_alignment_deg: [f64; 3],
    pub gyro_alignment_estimate_deg: Option<[f64; 3]>,
    pub gyro_alignment_std_deg: Option<[f64; 3]>,
    pub gyro_alignment_residual_rms_deg: Option<f64>,
    pub gyro_alignment_pairs: usize,
    pub gyro_alignment_rejected: usize,
    pub gyro_alignment_applied_from_s: Option<f64>,
    /// `[window] gyro_misalignment`: the gyro's turn against the body frame as the keyframe
    /// window estimated it at the end (`log` of `ω_body = R ω_gyro`), degrees.
    #[serde(default)]
    pub window_gyro_misalignment_deg: Option<[f64; 3]>,
    /// `[loop_closure]`: keyframes seen, candidates tried, loops closed and rejected, and the
    /// correction of the published pose at the end (m, rad); absent when it is off.
    #[serde(default)]
    pub loop_closure: Option<LoopClosureStats>,
    /// The loops' measured edges against the ground truth (`loops.csv`): how many, the median
    /// and largest translation error, m, the largest rotation error, rad, and the median error of
    /// the graph's predictions they replaced, m; absent without loops or ground truth.
    #[serde(default)]
    pub loop_edges: Option<LoopEdgeSummary>,
    /// ATE RMSE (SE3 alignment) of the keyframes as the loop closer's graph placed them at the
    /// end (`keyframes_graph.tum`), m: the map in hindsight, against the published poses'
    /// `ate_rmse_m` as they were then; absent without loop closure or ground truth.
    #[serde(default)]
    pub graph_keyframe_ate_m: Option<f64>,
    /// ATE RMSE (SE3 alignment) of the published frames in hindsight
    /// (`trajectory_hindsight.tum`: each at its pose relative to its keyframe, the keyframe where
    /// the loop closer's graph places it at the end), m —
    /// what `ate_rmse_m` would be had every loop been known from the first frame; absent without
    /// loop closure or ground truth.
    #[serde(default)]
    pub hindsight_ate_m: Option<f64>,
    /// Evaluation against ground truth (SE3 alignment, metric), if it could be computed.
    #[serde(skip)]
    pub eval: Option<EvalReport>,
}

impl ReplayReport {
    pub fn new(out: &ReplayOutput, vision: bool, depth: &str, realtime: bool) -> Self {
        // The tracked frames' results and their whole time on the tracking thread.
        let (tracked, tracked_times): (Vec<&TrackResult>, Vec<&FrameTimes>) = out
            .frames
            .iter()
            .zip(&out.frame_times)
            .zip(&out.phases)
            .skip(1)
            .filter(|(_, p)| **p == Phase::Tracking)
            .map(|(frame, _)| frame)
            .unzip();
        let ms = sorted(tracked.iter().map(|r| r.time_s * 1e3));
        let pct = |p: f64| percentile(&ms, p);
        let frame_ms = sorted(tracked_times.iter().map(|t| t.total_s * 1e3));
        let map_ms = sorted(out.mapping.job_times_s.iter().map(|t| t * 1e3));
        let kf_build_ms = sorted(out.mapping.tracker_keyframe_build_s.iter().map(|t| t * 1e3));
        let spot_turn_ms = sorted(out.odometry.spot_turn_build_s.iter().map(|t| t * 1e3));
        let imu_scale = sorted(out.odometry.imu_scale.iter().map(|e| e.scale));
        let imu_scale_pct = |p: f64| percentile_if_any(&imu_scale, p);
        let view_scale = sorted(out.mapping.view_scales.iter().map(|&s| s as f64));
        let view_scale_pct = |p: f64| percentile_if_any(&view_scale, p);
        let window_ms = sorted(out.odometry.window_solve_s.iter().map(|t| t * 1e3));
        let window_ratio = sorted(out.odometry.window_baseline_ratios.iter().copied());
        let window_ratio_pct = |p: f64| percentile_if_any(&window_ratio, p);
        let present_moves = sorted(out.odometry.window_present_moves_m.iter().copied());
        let map_scale = sorted(
            out.odometry
                .window_map_scale_corrections
                .iter()
                .map(|c| (-c).exp()),
        );
        let map_scale_pct = |p: f64| percentile_if_any(&map_scale, p);
        let stored_scale = sorted(
            out.odometry
                .stored_map_scale_corrections
                .iter()
                .map(|(_, c)| (-c).exp()),
        );
        let stored_scale_pct = |p: f64| percentile_if_any(&stored_scale, p);
        let rest = out.odometry.rest_imu_density;
        let kb_ms = sorted(out.odometry.keyframe_bundle_s().iter().map(|t| t * 1e3));
        let map_lat = sorted(
            out.odometry
                .keyframe_map_latency_frames
                .iter()
                .map(|&n| n as f64),
        );
        let install_lat = sorted(
            out.odometry
                .keyframe_install_latency_frames
                .iter()
                .map(|&n| n as f64),
        );
        let kb_change = sorted(
            out.odometry
                .keyframe_bundle_depth_changes()
                .iter()
                .map(|c| c * 100.0),
        );
        let kb_bias = sorted(
            out.odometry
                .keyframe_bundle_accel_bias_jumps_m_s2()
                .iter()
                .copied(),
        );
        let kb_dv = sorted(
            out.odometry
                .keyframe_bundle_velocity_changes_m_s()
                .iter()
                .copied(),
        );
        let recoveries = out.recoveries();
        let mut phases = BTreeMap::new();
        for p in &out.phases {
            *phases.entry(p.as_str().to_string()).or_insert(0) += 1;
        }
        let mut flags = BTreeMap::new();
        for r in &out.frames {
            if let Some(f) = r.flag {
                *flags.entry(f.as_str().to_string()).or_insert(0) += 1;
            }
        }
        let flagged = out.frames.iter().filter(|r| r.flag.is_some()).count();
        let non_finite = out
            .frames
            .iter()
            .filter(|r| {
                let p = pose_of(&r.state);
                !(p.translation.vector.iter().all(|v| v.is_finite())
                    && p.rotation.coords.iter().all(|v| v.is_finite()))
            })
            .count();
        let duration_s = match (out.frames.first(), out.frames.last()) {
            (Some(a), Some(b)) => b.t.secs_since(a.t),
            _ => 0.0,
        };
        let g = &out.odometry.gyro_alignment;
        ReplayReport {
            frames_in: out.frames_in,
            frames_tracked: out.frames.len() - flagged,
            frames_flagged: flagged,
            frames_downweighted: out.frames.iter().filter(|r| r.downweighted).count(),
            flags,
            keyframes: out.odometry.keyframes,
            keyframe_reuses: out.odometry.keyframe_reuses,
            keyframe_reuse_failures: out.odometry.keyframe_reuse_failures,
            chain_retracks: out.odometry.chain_retracks,
            keyframes_stored: out.odometry.keyframes_stored,
            spot_turn_keyframes: out.odometry.spot_turn_keyframes,
            spot_turn_build_ms_p50: percentile_if_any(&spot_turn_ms, 50.0),
            spot_turn_build_ms_max: spot_turn_ms.last().copied(),
            keyframes_built_by_mapper: out.odometry.keyframes_built_by_mapper,
            keyframes_built_on_tracking_thread: out.odometry.keyframes_built_on_tracking_thread,
            mapper_keyframe_builds: kf_build_ms.len(),
            mapper_keyframe_build_ms_p50: percentile_if_any(&kf_build_ms, 50.0),
            mapper_keyframe_build_ms_max: kf_build_ms.last().copied(),
            aged_keyframes: out.odometry.aged_keyframes,
            diverged_keyframes: out.odometry.diverged_keyframes,
            window_skip_edges_tried: out.odometry.window_skip_edges_tried,
            window_skip_edges: out.odometry.window_skip_edges,
            returns_out_of_view: out.odometry.returns_out_of_view,
            zero_velocity_updates: out.odometry.zero_velocity_updates,
            takeoff_scale_corrections: out.odometry.takeoff_scales.clone(),
            takeoff_refinement_ms: out
                .odometry
                .takeoff_refinement_s
                .iter()
                .map(|s| s * 1e3)
                .collect(),
            takeoff_pass_views: out.odometry.takeoff_pass_views.clone(),
            takeoff_pass_lag_frames: out.odometry.takeoff_pass_lag_frames.clone(),
            tracking_ms_p50: pct(50.0),
            tracking_ms_p99: pct(99.0),
            tracking_ms_max: ms.last().copied().unwrap_or(0.0),
            frame_ms_p50: percentile(&frame_ms, 50.0),
            frame_ms_p99: percentile(&frame_ms, 99.0),
            frame_ms_max: frame_ms.last().copied().unwrap_or(0.0),
            frame_tail: FrameTail::of(&tracked_times, percentile(&frame_ms, 99.0)),
            tracking_ms_mean: if ms.is_empty() {
                0.0
            } else {
                ms.iter().sum::<f64>() / ms.len() as f64
            },
            iterations_mean: if tracked.is_empty() {
                0.0
            } else {
                tracked
                    .iter()
                    .map(|r| r.iterations.iter().map(|&i| i as f64).sum::<f64>())
                    .sum::<f64>()
                    / tracked.len() as f64
            },
            non_finite_poses: non_finite,
            duration_s,
            vision,
            depth: depth.to_string(),
            mapping_poses: "tracked".to_string(),
            loop_edge_source: "measured".to_string(),
            realtime,
            tracking_fifo_priority: match &out.tracking_fifo {
                Some(Ok(p)) => *p,
                _ => 0,
            },
            tracking_fifo_note: match &out.tracking_fifo {
                Some(Err(e)) => e.clone(),
                _ => String::new(),
            },
            frames_waiting: out.frames_waiting,
            phases,
            rest_gyro_density_rad_s_sqrt_hz: rest.map(|d| d.gyro_rad_s_sqrt_hz),
            rest_accel_density_m_s2_sqrt_hz: rest.map(|d| d.accel_m_s2_sqrt_hz),
            // (`sensor.yaml` with a zero density would make these infinite: left out then.)
            rest_gyro_density_ratio: rest.map(|d| d.gyro_ratio).filter(|r| r.is_finite()),
            rest_accel_density_ratio: rest.map(|d| d.accel_ratio).filter(|r| r.is_finite()),
            imu_gyro_noise_scale: rest.map(|d| d.gyro_scale),
            imu_accel_noise_scale: rest.map(|d| d.accel_scale),
            imu_rotation_noise_scale: rest.map(|d| d.rotation_noise_scale),
            inflight_gyro_noise_intervals: (out.odometry.inflight_gyro_noise_intervals > 0)
                .then_some(out.odometry.inflight_gyro_noise_intervals),
            inflight_gyro_noise_ratio: out.odometry.inflight_gyro_noise_ratio,
            inflight_gyro_rotation_noise_scale: out
                .odometry
                .inflight_gyro_noise_scales
                .last()
                .map(|&(_, _, f)| f),
            init_time_s: match (out.odometry.onset_t, out.odometry.tracking_since) {
                (Some(a), Some(b)) => Some(b.secs_since(a)),
                _ => None,
            },
            resets: out.odometry.resets,
            resumes: out.odometry.resumes,
            relocalisations: out.odometry.relocalisations,
            reinit_shaped_views: out.odometry.reinit_shaped_views,
            reinit_guessed_keyframes: out.odometry.reinit_guessed_keyframes,
            window_kept_across_rebuild: out.odometry.window_kept_across_rebuild,
            window_restarts: out.odometry.window_restarts,
            recovery_s_max: recoveries.recovered_s.iter().copied().reduce(f64::max),
            unrecovered_s: recoveries.unrecovered_s,
            mapping_jobs_dropped: out.odometry.jobs_dropped,
            mapping_views_skipped: out.mapping.views_skipped,
            mapping_ms_mean: if map_ms.is_empty() {
                0.0
            } else {
                map_ms.iter().sum::<f64>() / map_ms.len() as f64
            },
            mapping_ms_p50: percentile(&map_ms, 50.0),
            mapping_ms_p99: percentile(&map_ms, 99.0),
            window_solves: out.odometry.window_solve_s.len(),
            window_ms_p50: percentile(&window_ms, 50.0),
            window_ms_max: window_ms.iter().copied().fold(0.0, f64::max),
            window_baseline_ratio_p10: window_ratio_pct(10.0),
            window_baseline_ratio_p50: window_ratio_pct(50.0),
            window_baseline_ratio_p90: window_ratio_pct(90.0),
            window_present_move_m_p50: percentile_if_any(&present_moves, 50.0),
            window_present_move_m_p90: percentile_if_any(&present_moves, 90.0),
            map_scale_corrections: map_scale.len(),
            map_scale_correction_p10: map_scale_pct(10.0),
            map_scale_correction_p50: map_scale_pct(50.0),
            map_scale_correction_p90: map_scale_pct(90.0),
            stored_map_scale_corrections: stored_scale.len(),
            stored_map_scale_correction_p10: stored_scale_pct(10.0),
            stored_map_scale_correction_p50: stored_scale_pct(50.0),
            stored_map_scale_correction_p90: stored_scale_pct(90.0),
            keyframe_bundles: kb_ms.len(),
            keyframe_bundles_with_previous: out.odometry.keyframe_bundles_with_previous(),
            keyframe_bundle_ms_p50: percentile(&kb_ms, 50.0),
            keyframe_bundle_ms_max: kb_ms.last().copied().unwrap_or(0.0),
            keyframe_bundle_depth_change_median_pct: percentile(&kb_change, 50.0),
            keyframe_bundle_accel_bias_jump_p50_m_s2: percentile(&kb_bias, 50.0),
            keyframe_bundle_accel_bias_jump_max_m_s2: kb_bias.last().copied().unwrap_or(0.0),
            keyframe_bundle_velocity_change_p50_m_s: percentile(&kb_dv, 50.0),
            keyframe_bundle_velocity_change_max_m_s: kb_dv.last().copied().unwrap_or(0.0),
            refinements_rejected: out.odometry.refinements_rejected(),
            refinements_dropped: out.odometry.refinements_dropped,
            refinements_discarded: out.odometry.refinements_discarded,
            keyframe_bundle_catch_up_frames: out.odometry.catch_up_frames,
            keyframe_bundle_catch_up_frames_on_refinement_thread: out
                .odometry
                .catch_up_frames_on_refinement_thread,
            keyframe_map_latency_frames_p50: percentile(&map_lat, 50.0),
            keyframe_map_latency_frames_max: map_lat.last().copied().unwrap_or(0.0),
            keyframe_install_latency_frames_p50: percentile(&install_lat, 50.0),
            keyframe_install_latency_frames_max: install_lat.last().copied().unwrap_or(0.0),
            guessed_keyframe_scales: out.odometry.guessed_keyframe_scales.clone(),
            imu_scale_estimates: imu_scale.len(),
            imu_scale_p10: imu_scale_pct(10.0),
            imu_scale_p50: imu_scale_pct(50.0),
            imu_scale_p90: imu_scale_pct(90.0),
            scale_faults: out.odometry.scale_faults,
            scale_fault_frames: out.odometry.scale_fault_frames,
            speed_faults: out.odometry.speed_faults,
            speed_fault_frames: out.odometry.speed_fault_frames,
            view_scale_views: view_scale.len(),
            view_scale_p10: view_scale_pct(10.0),
            view_scale_p50: view_scale_pct(50.0),
            view_scale_p90: view_scale_pct(90.0),
            vignette_corrected: out.odometry.vignette_corrected,
            vignette_saturated_px: out.odometry.vignette_saturated_px,
            semidense_points: out
                .mapping
                .keyframe_maps
                .iter()
                .map(|m| m.points.len())
                .sum(),
            map_depth_keyframes: 0,
            map_depth_signed_median_pct: None,
            map_depth_abs_median_pct: None,
            map_depth_worst_within_10pct: None,
            scale_error_over_time: Vec::new(),
            error_per_10s: Vec::new(),
            velocity_rmse_m_s: None,
            velocity_median_m_s: None,
            velocity_p90_m_s: None,
            velocity_max_m_s: None,
            velocity_rmse_before_window_solves_m_s: None,
            velocity_rmse_at_window_solves_m_s: None,
            velocity_rmse_at_keyframe_switches_m_s: None,
            accel_bias_est_m_s2: (!tracked.is_empty()).then(|| {
                std::array::from_fn(|k| {
                    percentile(
                        &sorted(tracked.iter().map(|r| r.state.bias.accel_m_s2[k])),
                        50.0,
                    )
                })
            }),
            accel_bias_gt_m_s2: None,
            accel_bias_error_m_s2: None,
            window_gyro_misalignment_deg: out
                .odometry
                .window_gyro_misalignment_rad()
                .map(|v| [v.x, v.y, v.z].map(f64::to_degrees)),
            loop_closure: out.odometry.loop_closure.clone(),
            loop_edges: None,
            graph_keyframe_ate_m: None,
            hindsight_ate_m: None,
            gyro_alignment_deg: g.applied_rad.map(f64::to_degrees),
            gyro_alignment_estimate_deg: g.estimate_rad.map(|v| v.map(f64::to_degrees)),
            gyro_alignment_std_deg: g.estimate_std_rad.map(|v| v.map(f64::to_degrees)),
            gyro_alignment_residual_rms_deg: g.residual_rms_rad.map(f64::to_degrees),
            gyro_alignment_pairs: g.pairs,
            gyro_alignment_rejected: g.rejected,
            gyro_alignment_applied_from_s: g
                .first_applied_t
                .zip(out.frames.first())
                .map(|(t, f)| t.secs_since(f.t)),
            eval: None,
        }
    }

    /// Sets the accelerometer bias the ground truth implies (body, m/s²) and its difference
    /// from the estimated one.
    pub fn set_implied_accel_bias(&mut self, gt_m_s2: nalgebra::Vector3<f64>) {
        self.accel_bias_gt_m_s2 = Some([gt_m_s2.x, gt_m_s2.y, gt_m_s2.z]);
        self.accel_bias_error_m_s2 = self
            .accel_bias_est_m_s2
            .map(|e| (nalgebra::Vector3::from(e) - gt_m_s2).norm());
    }

    /// Fills the `velocity_*` keys: the velocities of `out`'s frames against `gt`'s, the
    /// estimate's world turned into the ground truth's by the SE3 alignment of `est` (`out`'s
    /// trajectory) onto `gt`'s poses. Left `None` when either gives nothing.
    pub fn set_velocity_errors(&mut self, gt: &GroundTruth, est: &Trajectory, out: &ReplayOutput) {
        let opts = EvalOptions::default();
        let Ok(align) = alignment(&gt.trajectory(), est, &opts) else {
            return;
        };
        let v: Vec<_> = out
            .frames
            .iter()
            .map(|r| (r.t, r.state.nav.v_world_m_s))
            .collect();
        if let Some(e) = velocity_errors(&gt.states, &v, &align, opts.max_dt_ns) {
            self.velocity_rmse_m_s = Some(e.rmse_m_s);
            self.velocity_median_m_s = Some(e.median_m_s);
            self.velocity_p90_m_s = Some(e.p90_m_s);
            self.velocity_max_m_s = Some(e.max_m_s);
        }
        let kinds: Vec<_> = (out.frames.iter().zip(&out.phases))
            .map(|(r, &p)| (r.t, p, r.keyframe_id))
            .collect();
        let cycle = cycle_frames(&kinds, &out.odometry.window_solve_frames);
        let rmse = |idx: &[usize]| {
            let sub: Vec<_> = idx.iter().map(|&i| v[i]).collect();
            velocity_errors(&gt.states, &sub, &align, opts.max_dt_ns).map(|e| e.rmse_m_s)
        };
        self.velocity_rmse_before_window_solves_m_s = rmse(&cycle.before_solve);
        self.velocity_rmse_at_window_solves_m_s = rmse(&cycle.solve);
        self.velocity_rmse_at_keyframe_switches_m_s = rmse(&cycle.switch);
    }

    /// Fills the `map_depth_*` keys from the keyframes' depth errors.
    pub fn set_map_depth(&mut self, rows: &[KeyframeDepthError]) {
        let med = |v: Vec<f64>| {
            let mut v: Vec<f64> = v.into_iter().filter(|x| x.is_finite()).collect();
            (!v.is_empty()).then(|| median(&mut v))
        };
        self.map_depth_keyframes = rows.len();
        self.map_depth_signed_median_pct = med(rows.iter().map(|r| r.signed_median_pct).collect());
        self.map_depth_abs_median_pct = med(rows.iter().map(|r| r.abs_median_pct).collect());
        self.map_depth_worst_within_10pct = rows
            .iter()
            .map(|r| r.within_10pct)
            .filter(|v| v.is_finite())
            .min_by(f64::total_cmp);
    }

    /// Evaluates `est` against `gt` with SE3 alignment (metric: no scale fix), and the scale
    /// error and ATE of the trajectory up to every 10 s.
    pub fn evaluate_against(&mut self, gt: &Trajectory, est: &Trajectory) {
        self.eval = evaluate(gt, est, &EvalOptions::default()).ok();
        self.error_per_10s = self.eval.as_ref().map_or_else(Vec::new, |e| {
            let cuts_s: Vec<f64> = (1..)
                .map(|k| 10.0 * k as f64)
                .take_while(|&c| c < e.duration_s)
                .collect();
            e.segment_errors(&cuts_s)
        });
        self.scale_error_over_time.clear();
        let Some((t0, t1)) = est.span() else { return };
        let mut t = 10.0;
        loop {
            let end = t0.add_ns((t * 1e9) as i64).min(t1);
            let part = Trajectory::new(est.poses.iter().filter(|p| p.t <= end).copied().collect());
            if let Ok(e) = evaluate(gt, &part, &EvalOptions::default())
                && e.gt_path_m > 1.0
            {
                self.scale_error_over_time.push(ScaleAt {
                    t_s: end.secs_since(t0),
                    scale_error_pct: e.scale_error_pct,
                    ate_rmse_m: e.ate_rmse_m,
                });
            }
            if end >= t1 {
                break;
            }
            t += 10.0;
        }
    }

    /// One flat JSON object: these fields plus every key of the evaluation (`ate_rmse_m`,
    /// `scale_error_pct`, …).
    pub fn to_json(&self) -> String {
        let mut v = serde_json::to_value(self).unwrap_or_default();
        if let (Some(obj), Some(e)) = (v.as_object_mut(), &self.eval)
            && let Ok(serde_json::Value::Object(ev)) = serde_json::to_value(e)
        {
            for (k, val) in ev {
                let key = match k.as_str() {
                    "duration_s" => "eval_duration_s".to_string(),
                    _ => k,
                };
                obj.insert(key, val);
            }
        }
        serde_json::to_string_pretty(&v).unwrap_or_default()
    }
}

/// [`percentile`] of ascending `sorted`, `None` when there is nothing to take it of (where 0
/// would read as a measurement).
fn percentile_if_any(sorted: &[f64], p: f64) -> Option<f64> {
    (!sorted.is_empty()).then(|| percentile(sorted, p))
}

/// Frames of the keyframe cycle, as indices into a replay's frames (each list ascending).
#[derive(Debug, Default, PartialEq)]
struct CycleFrames {
    /// A tracked frame followed by a window solve's frame.
    before_solve: Vec<usize>,
    /// A tracked frame whose state a keyframe-window solve replaced.
    solve: Vec<usize>,
    /// A tracked frame after a tracked one, on another keyframe (a new one installed or a stored
    /// one returned to), that is not a solve's frame.
    switch: Vec<usize>,
}

/// Classifies `frames` (time, phase, keyframe tracked) by the times of the window solves
/// (`solves`, ascending).
fn cycle_frames(frames: &[(TimeNs, Phase, Option<u32>)], solves: &[TimeNs]) -> CycleFrames {
    let mut c = CycleFrames::default();
    let tracked = |i: usize| frames[i].1 == Phase::Tracking;
    for i in (0..frames.len()).filter(|&i| tracked(i)) {
        if solves.binary_search(&frames[i].0).is_ok() {
            c.solve.push(i);
            if i > 0 && tracked(i - 1) {
                c.before_solve.push(i - 1);
            }
        } else if i > 0
            && tracked(i - 1)
            && frames[i].2.is_some()
            && frames[i - 1].2.is_some()
            && frames[i].2 != frames[i - 1].2
        {
            c.switch.push(i);
        }
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_keyframe_cycle_splits_tracked_frames_into_before_at_a_solve_and_at_a_switch() {
        use Phase::*;
        let t = |k: i64| TimeNs(k * 50_000_000);
        let frames = [
            (t(0), Static, None),
            (t(1), Tracking, Some(1)),
            (t(2), Tracking, Some(1)), // before the solve
            (t(3), Tracking, Some(1)), // solve
            (t(4), Tracking, Some(1)),
            (t(5), Tracking, Some(2)), // switch
            (t(6), Tracking, Some(2)),
            (t(7), Lost, None),
            (t(8), Tracking, Some(3)), // solve after a loss: nothing tracked before it
            (t(9), Tracking, Some(7)), // switch (a stored keyframe)
            (t(10), Tracking, Some(7)),
        ];
        // A solve time without a tracked frame (t(7): lost) is not counted.
        let c = cycle_frames(&frames, &[t(3), t(7), t(8)]);
        assert_eq!(
            c,
            CycleFrames {
                before_solve: vec![2],
                solve: vec![3, 8],
                switch: vec![5, 9],
            }
        );
    }
}
