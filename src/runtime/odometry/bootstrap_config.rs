//! The `[bootstrap]` table: static start, the take-off and its refinement, loss recovery, the
//! threads' queues and priorities, and the rest measurements that weigh the IMU.

use super::*;

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
    /// ([`crate::runtime::takeoff`]; 0 = the paper's bootstrap by dead reckoning alone).
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
    /// A first map started in flight after a loss is triangulated from views whose translation
    /// from the map's keyframe points where the images say (corners matched to the keyframe's,
    /// the rotation the gyro's), its length from the parallax (`reinit_shape_length_from_parallax`;
    /// else the dead reckoning's): after a loss of seconds the
    /// dead-reckoned velocity is off by tenths of a m/s in any direction, and a map triangulated
    /// along it comes out distorted, which the keyframe window's map scale cannot correct
    /// (`odometry::reinit_shape`). The tracker's position follows the views.
    pub reinit_shape_from_images: bool,
    /// …if it is started at least this long after the loss, s: after a short loss (a fast turn
    /// lost for a frame or two) the dead reckoning is still right, and in a fast turn the gyro's
    /// own error over the turn (its scale, its axes) is as large as the parallax the images
    /// show — S-V101 seed 2, lost in V1_01's 120 s turn and rebuilt at once: 0.18 m as
    /// dead-reckoned, 10.8 m shaped.
    pub reinit_shape_min_loss_s: f64,
    /// …for a view with at least this many matches within 0.004 rad of its epipolar plane…
    pub reinit_shape_min_inliers: usize,
    /// …and a median parallax of at least this, rad (the direction is that of the parallax).
    pub reinit_shape_min_parallax_rad: f64,
    /// Corners matched within this of where the gyro's rotation alone puts them, px.
    pub reinit_shape_radius_px: f32,
    /// The shaped view's distance from the keyframe: its median parallax times the median depth
    /// of the last map before the loss (else the dead reckoning's distance, whose error after a
    /// loss can be as large as the distance flown).
    pub reinit_shape_length_from_parallax: bool,
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
            reinit_shape_from_images: true,
            reinit_shape_min_loss_s: 1.0,
            reinit_shape_min_inliers: 20,
            reinit_shape_min_parallax_rad: 0.01,
            reinit_shape_radius_px: 100.0,
            reinit_shape_length_from_parallax: true,
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
