//! The odometry's counters and per-keyframe records for the report (`report.json`, the CSVs),
//! and the IMU noise measured on the pad.

use super::*;
use crate::loop_closure::closer::LoopClosureStats;

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
    /// Views of first maps started in flight whose translation was turned to the images'
    /// direction (`[bootstrap] reinit_shape_from_images`).
    pub reinit_shaped_views: u32,
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
    /// `[window] mount_rotation`: the IMU frame's turn ψ against the body frame of the oldest
    /// keyframe in the window (the best-read one) after every window solve, as (that keyframe's
    /// time, ψ in rad) (`OUT/window_mount_rotation.csv`).
    pub window_mount_rotation_history: Vec<(TimeNs, Vector3<f64>)>,
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
    /// New keyframes started when the tracked velocity had left the IMU's dead reckoning by more
    /// than `[tracking] keyframe_max_velocity_divergence_m_s` (possibly with another reason).
    pub diverged_keyframes: usize,
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
    /// Frames tracked again on this thread against an adjusted keyframe that came back after
    /// them.
    pub catch_up_frames: usize,
    /// Frames the refinement thread tracked again against the keyframe it had just adjusted
    /// (`[keyframe_bundle] catch_up_on_refinement_thread`).
    pub catch_up_frames_on_refinement_thread: usize,
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
    /// Times an estimate turned the scale fault on (`[scale_observer] fault_min_scale`), and the
    /// valid frames published failed because of it.
    pub scale_faults: usize,
    pub scale_fault_frames: usize,
    /// Times the estimated speed went beyond the vehicle's (`[scale_observer]
    /// fault_max_speed_m_s`), and the valid frames published failed because of it.
    pub speed_faults: usize,
    pub speed_fault_frames: usize,
    /// Wall time of each keyframe-window solve (on the tracking thread), s.
    pub window_solve_s: Vec<f64>,
    /// The frames whose state a keyframe-window solve replaced (the tracker's state reset to the
    /// window's newest keyframe), in time order.
    pub window_solve_frames: Vec<TimeNs>,
    /// Each window solve's change of the distance from the window's previous newest keyframe
    /// to the new one (solved / as tracked; baselines over 1 cm): the correction by which the
    /// IMU's scale reaches the maps, since the mapper's world is chained through it
    /// (`mapper_from_world`).
    pub window_baseline_ratios: Vec<f64>,
    /// Each window solve's move of the present: the distance from the frame's position as
    /// tracked to where the solve put it (the tracker's state is reset there), m; not across a
    /// return to a stored keyframe, where the window also changes its world. Beyond what the
    /// vehicle moved, so a run without ground truth shows how far the window and tracking
    /// disagree (S-V101's real IMU 1.9 cm median, its path with the simulator's IMU 0.5 cm;
    /// docs/odometry-log.md, session 74).
    pub window_present_moves_m: Vec<f64>,
    /// Skip edges aligned (`[window] skip_edges`), and those joined to the window.
    pub window_skip_edges_tried: usize,
    pub window_skip_edges: usize,
    /// `[window] inflight_gyro_noise`: keyframe intervals the gyro's noise was read over, the
    /// last median reading (the gyro's error over its modelled density: 1 = as modelled), and
    /// each factor applied to the back end's IMU rotations from it, as (time, the median reading
    /// it came from, factor).
    pub inflight_gyro_noise_intervals: usize,
    pub inflight_gyro_noise_ratio: Option<f64>,
    pub inflight_gyro_noise_scales: Vec<(TimeNs, f64, f64)>,
    /// With `[window] map_scale`: after each window solve, the estimated log-scale λ of every
    /// keyframe map in the window, as (keyframe time, λ) (`OUT/window_scale.csv`).
    pub window_map_log_scales: Vec<(TimeNs, f64)>,
    /// With `[window] map_scale_gain`: each correction `c` of a keyframe map's log-scale (its
    /// depths scaled by `e^{−c}` when the next keyframe was started).
    pub window_map_scale_corrections: Vec<f64>,
    /// With `[window] stored_map_scale_gain`: each keyframe map whose stored copies were
    /// corrected as it left the window, (keyframe time, `c`): their depths scaled by `e^{−c}`.
    pub stored_map_scale_corrections: Vec<(TimeNs, f64)>,
    /// The gyro's axes turned onto the camera's body frame in flight (`[gyro_alignment]`).
    pub gyro_alignment: GyroAlignmentStats,
    /// The loop closer's counters (`[loop_closure] enabled`).
    pub loop_closure: Option<LoopClosureStats>,
    /// Every loop closed, or held and dropped unconfirmed, in order (`OUT/loops.csv`; real time: those the closer's thread had
    /// reported by the last frame).
    pub loop_closures: Vec<LoopRecord>,
    /// Every keyframe the loop closer holds, by time, with its body pose `t_world_body` as the
    /// graph placed it at the end (`OUT/keyframes_graph.tum`: the keyframes' trajectory in
    /// hindsight, every loop applied to every keyframe; what was published is each frame's pose
    /// as it was then).
    pub loop_keyframe_poses: Vec<StampedPose>,
    /// Every keyframe's correction as the loop closer's graph gave it at the end: with each
    /// frame's [`super::OdometryFrame::loop_world`], the published poses in hindsight
    /// (`OUT/trajectory_hindsight.tum`); `None` without loop closure.
    pub loop_hindsight: Option<super::HindsightCorrections>,
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

    /// The applied keyframe adjustments that took the keyframe tracked before as their gauge
    /// (`[keyframe_bundle] previous_host`).
    pub fn keyframe_bundles_with_previous(&self) -> usize {
        self.applied_adjustments()
            .filter(|r| r.with_previous)
            .count()
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
