//! The human summary of a replay (`vidslam replay`'s and `vidslam demo`'s printed table): the
//! figures of [`ReplayReport`] by row, with units, and only the rows that apply to the run.

use super::report::ReplayReport;

impl ReplayReport {
    /// A human summary table.
    pub fn to_table(&self) -> String {
        let mut s = String::new();
        let mut row = |k: &str, v: String| s.push_str(&format!("{k:<24} {v}\n"));
        if self.mapping_poses != "tracked" {
            row(
                "mapping poses",
                format!("{} (diagnostic, not the product)", self.mapping_poses),
            );
        }
        if self.loop_edge_source != "measured" {
            row(
                "loop edges",
                format!("{} (diagnostic, not the product)", self.loop_edge_source),
            );
        }
        row("frames in", self.frames_in.to_string());
        row("frames tracked", self.frames_tracked.to_string());
        row(
            "frames flagged",
            format!("{} {:?}", self.frames_flagged, self.flags),
        );
        row(
            "frames with vision down-weighted",
            self.frames_downweighted.to_string(),
        );
        row("keyframes", self.keyframes.to_string());
        row(
            "keyframe returns (failed, re-tracked) / stored",
            format!(
                "{} ({}, {}) / {}",
                self.keyframe_reuses,
                self.keyframe_reuse_failures,
                self.chain_retracks,
                self.keyframes_stored
            ),
        );
        row(
            "turn keyframes (tracker)",
            match (self.spot_turn_build_ms_p50, self.spot_turn_build_ms_max) {
                (Some(p50), Some(max)) => format!(
                    "{} (built between frames, ms p50/max {p50:.1} / {max:.1})",
                    self.spot_turn_keyframes
                ),
                _ => self.spot_turn_keyframes.to_string(),
            },
        );
        row(
            "keyframes built by mapper / tracker",
            format!(
                "{} / {} ({} built by the mapper, {} ms p50)",
                self.keyframes_built_by_mapper,
                self.keyframes_built_on_tracking_thread,
                self.mapper_keyframe_builds,
                self.mapper_keyframe_build_ms_p50
                    .map_or("-".to_string(), |v| format!("{v:.1}"))
            ),
        );
        row(
            "keyframes at the age limit",
            self.aged_keyframes.to_string(),
        );
        row(
            "keyframes at the velocity divergence limit",
            self.diverged_keyframes.to_string(),
        );
        row(
            "failed returns, left out of view",
            self.returns_out_of_view.to_string(),
        );
        row(
            "zero-velocity updates",
            self.zero_velocity_updates.to_string(),
        );
        if !self.takeoff_scale_corrections.is_empty() {
            let joined = |v: &[f64], decimals: usize| {
                let s: Vec<String> = v.iter().map(|x| format!("{x:.decimals$}")).collect();
                s.join(" ")
            };
            row(
                "take-off scale corrections",
                joined(&self.takeoff_scale_corrections, 3),
            );
            row(
                "take-off refinement ms",
                joined(&self.takeoff_refinement_ms, 0),
            );
            let counts = |v: &mut dyn Iterator<Item = u64>| {
                let s: Vec<String> = v.map(|n| n.to_string()).collect();
                s.join(" ")
            };
            row(
                "take-off pass views",
                counts(&mut self.takeoff_pass_views.iter().map(|&n| n as u64)),
            );
            row(
                "take-off pass lag frames",
                counts(&mut self.takeoff_pass_lag_frames.iter().copied()),
            );
        }
        row(
            "tracking ms p50/p99/max",
            format!(
                "{:.2} / {:.2} / {:.2}",
                self.tracking_ms_p50, self.tracking_ms_p99, self.tracking_ms_max
            ),
        );
        row(
            "frame ms p50/p99/max",
            format!(
                "{:.2} / {:.2} / {:.2} (the tracking thread's whole work per frame{})",
                self.frame_ms_p50,
                self.frame_ms_p99,
                self.frame_ms_max,
                match (self.realtime, self.tracking_fifo_priority) {
                    (false, _) => "; offline with the waits for the mapper".to_string(),
                    (true, 0) => format!("; {}", self.tracking_fifo_note),
                    (true, p) => format!("; under SCHED_FIFO {p}"),
                }
            ),
        );
        let tail = &self.frame_tail;
        if tail.frames > 0 {
            row(
                "slowest 1 % of frames, ms",
                format!(
                    "{:.2} in {} frames: maps {:.2}, adjustments {:.2}, tracking {:.2}, window \
                     {:.2}, other {:.2}; on the CPU {} (means)",
                    tail.total_ms,
                    tail.frames,
                    tail.maps_ms,
                    tail.adjustments_ms,
                    tail.tracking_ms,
                    tail.window_ms,
                    tail.other_ms,
                    tail.cpu_ms
                        .map_or_else(|| "unknown".to_string(), |c| format!("{c:.2}"))
                ),
            );
        }
        row(
            "GN iterations / frame",
            format!("{:.1}", self.iterations_mean),
        );
        row("non-finite poses", self.non_finite_poses.to_string());
        if !self.phases.is_empty() {
            row("phases (frames)", format!("{:?}", self.phases));
        }
        if self.frames_waiting > 0 {
            row("frames before rest", self.frames_waiting.to_string());
        }
        if let (Some(g), Some(a), Some(gr), Some(ar)) = (
            self.rest_gyro_density_rad_s_sqrt_hz,
            self.rest_accel_density_m_s2_sqrt_hz,
            self.rest_gyro_density_ratio,
            self.rest_accel_density_ratio,
        ) {
            row(
                "IMU noise at rest",
                format!(
                    "gyro {g:.2e} rad/s/√Hz ({gr:.1}× sensor.yaml), accel {a:.2e} m/s²/√Hz \
                     ({ar:.1}×)"
                ),
            );
        }
        if let (Some(g), Some(a)) = (self.imu_gyro_noise_scale, self.imu_accel_noise_scale) {
            row(
                "IMU noise weighted",
                format!("gyro {g:.2}×, accel {a:.2}× sensor.yaml"),
            );
        }
        if let Some(r) = self.imu_rotation_noise_scale {
            row(
                "back end's gyro rotation noise",
                format!("{r:.2}× its setting"),
            );
        }
        if let (Some(n), Some(r)) = (
            self.inflight_gyro_noise_intervals,
            self.inflight_gyro_noise_ratio,
        ) {
            let applied = self
                .inflight_gyro_rotation_noise_scale
                .map_or("none applied".to_string(), |f| format!("{f:.2}× applied"));
            row(
                "gyro noise in flight",
                format!("{r:.2}× modelled over {n} keyframe intervals, {applied}"),
            );
        }
        if let Some(s) = self.init_time_s {
            row("init after onset", format!("{s:.2} s"));
        }
        row(
            "resets",
            format!(
                "{} ({} resumed on the keyframe lost, {} relocalised on a stored one{}){}{}",
                self.resets,
                self.resumes,
                self.relocalisations,
                match self.reinit_guessed_keyframes {
                    0 => String::new(),
                    n => format!(", {n} first maps restarted with guessed depths"),
                },
                match self.window_kept_across_rebuild {
                    0 => String::new(),
                    n => format!("; {n} first maps in flight joined the window through the loss"),
                },
                match self.reinit_shaped_views {
                    0 => String::new(),
                    n => format!("; {n} views of first maps in flight shaped by the images"),
                }
            ),
        );
        row("window restarts", self.window_restarts.to_string());
        if let Some(l) = &self.loop_closure {
            row(
                "loop closures",
                format!(
                    "{} closed of {} candidates ({} implausible, {} held wrong by the graph); \
                     correction at the end {:.3} m, {:.2}°; {:.1} ms mean / {:.1} ms max per \
                     keyframe{}{}",
                    l.loops_closed,
                    l.candidates_tried,
                    l.loops_implausible,
                    l.loops_rejected_by_graph,
                    l.final_correction_m,
                    l.final_correction_rad.to_degrees(),
                    l.keyframe_ms_mean,
                    l.keyframe_ms_max,
                    match l.jobs_dropped {
                        0 => String::new(),
                        n => format!(", {n} jobs dropped"),
                    },
                    match l.loops_held {
                        0 => String::new(),
                        n => format!(
                            "; {n} far loops held for another to agree, {} of them dropped",
                            l.loops_unconfirmed
                        ),
                    }
                ),
            );
            row(
                "published pose jumps",
                format!(
                    "{} ({} beyond reset_min_jump: MAVLink reset_counter steps), at the body \
                     mean/max {:.1} / {:.1} cm, turn max {:.2}°",
                    l.published_jumps,
                    l.reset_jumps,
                    l.published_jump_m_mean * 100.0,
                    l.published_jump_m_max * 100.0,
                    l.published_jump_rad_max.to_degrees()
                ),
            );
            if let Some(e) = &self.loop_edges {
                row(
                    "loop edges vs truth",
                    format!(
                        "{} loops: {} edge error median {:.1} cm, max {:.1} cm, {:.2}° \
                         (the graph's prediction before them: median {:.1} cm)",
                        e.evaluated,
                        if self.loop_edge_source == "measured" {
                            "measured"
                        } else {
                            "true"
                        },
                        e.edge_m_p50 * 100.0,
                        e.edge_m_max * 100.0,
                        e.edge_rad_max.to_degrees(),
                        e.prior_m_p50 * 100.0
                    ),
                );
            }
            if let Some(ate_m) = self.graph_keyframe_ate_m {
                row(
                    "keyframes in hindsight",
                    format!(
                        "ATE RMSE {:.4} m of the keyframes as the graph placed them at the end \
                         (keyframes_graph.tum)",
                        ate_m
                    ),
                );
            }
            if let Some(ate_m) = self.hindsight_ate_m {
                row(
                    "frames in hindsight",
                    format!(
                        "ATE RMSE {:.4} m of the published frames, each kept relative to its \
                         keyframe, the keyframe where the graph ends (trajectory_hindsight.tum; \
                         not flyable: causality costs the rest)",
                        ate_m
                    ),
                );
            }
            if l.guided_returns > 0 {
                row(
                    "guided returns",
                    format!(
                        "{} returns started from the graph's placement",
                        l.guided_returns
                    ),
                );
            }
        }
        if self.recovery_s_max.is_some() || self.unrecovered_s.is_some() {
            let longest = self
                .recovery_s_max
                .map_or_else(|| "none".to_string(), |s| format!("{s:.2} s"));
            let end = self
                .unrecovered_s
                .map_or_else(String::new, |s| format!(", lost at the end for {s:.2} s"));
            row("longest recovery", format!("{longest}{end}"));
        }
        if self.semidense_points > 0 {
            row(
                "semidense",
                format!(
                    "{} points, mapping ms mean/p50/p99 {:.1} / {:.1} / {:.1}, views dropped / \
                     skipped {} / {}",
                    self.semidense_points,
                    self.mapping_ms_mean,
                    self.mapping_ms_p50,
                    self.mapping_ms_p99,
                    self.mapping_jobs_dropped,
                    self.mapping_views_skipped
                ),
            );
        }
        if let (Some(abs), Some(signed), Some(worst)) = (
            self.map_depth_abs_median_pct,
            self.map_depth_signed_median_pct,
            self.map_depth_worst_within_10pct,
        ) {
            row(
                "map depth vs truth",
                format!(
                    "{} keyframes: median |error| {abs:.2} % (signed {signed:+.2} %), worst \
                     keyframe {worst:.0} % of points within 10 %",
                    self.map_depth_keyframes
                ),
            );
        }
        row(
            "vignetting",
            if self.vignette_corrected {
                format!(
                    "corrected (cam0/vignette.yaml), {} px clipped",
                    self.vignette_saturated_px
                )
            } else {
                "not corrected ([tracking] correct_vignetting off, or no cam0/vignette.yaml)".into()
            },
        );
        if let (Some(p10), Some(p50), Some(p90)) =
            (self.imu_scale_p10, self.imu_scale_p50, self.imu_scale_p90)
        {
            row(
                "scale vs IMU",
                format!(
                    "{} estimates, tracked→metric p10/p50/p90 {:.3} / {:.3} / {:.3}{}",
                    self.imu_scale_estimates,
                    p10,
                    p50,
                    p90,
                    match self.scale_faults {
                        0 => String::new(),
                        n => format!(
                            "; SCALE RAN AWAY: {n} faults, {} frames published failed",
                            self.scale_fault_frames
                        ),
                    }
                ),
            );
        }
        if self.speed_faults > 0 {
            row(
                "speed beyond the vehicle's",
                format!(
                    "{} times, {} frames published failed ([scale_observer] fault_max_speed_m_s)",
                    self.speed_faults, self.speed_fault_frames
                ),
            );
        }
        if let (Some(p10), Some(p50), Some(p90)) = (
            self.view_scale_p10,
            self.view_scale_p50,
            self.view_scale_p90,
        ) {
            row(
                "view scale vs map",
                format!(
                    "{} mapper views, p10/p50/p90 {:.3} / {:.3} / {:.3}",
                    self.view_scale_views, p10, p50, p90
                ),
            );
        }
        if let (Some(e), Some(g), Some(d)) = (
            self.accel_bias_est_m_s2,
            self.accel_bias_gt_m_s2,
            self.accel_bias_error_m_s2,
        ) {
            row(
                "accel bias",
                format!(
                    "estimated ({:+.3}, {:+.3}, {:+.3}), implied by gt ({:+.3}, {:+.3}, {:+.3}), \
                     off by {:.3} m/s²",
                    e[0], e[1], e[2], g[0], g[1], g[2], d
                ),
            );
        }
        if let Some(e) = self.window_gyro_misalignment_deg {
            row(
                "gyro turn (window)",
                format!("({:+.2}, {:+.2}, {:+.2})°", e[0], e[1], e[2]),
            );
        }
        if let Some(e) = self.gyro_alignment_estimate_deg {
            let a = self.gyro_alignment_deg;
            let sd = self.gyro_alignment_std_deg.unwrap_or([f64::NAN; 3]);
            row(
                "gyro alignment",
                format!(
                    "applied ({:+.2}, {:+.2}, {:+.2})°, estimate ({:+.2}, {:+.2}, {:+.2})° ± \
                     ({:.2}, {:.2}, {:.2})° from {} pairs ({} dropped)",
                    a[0],
                    a[1],
                    a[2],
                    e[0],
                    e[1],
                    e[2],
                    sd[0],
                    sd[1],
                    sd[2],
                    self.gyro_alignment_pairs,
                    self.gyro_alignment_rejected
                ),
            );
        }
        if self.window_solves > 0 {
            row("keyframe window", {
                let mut text = format!(
                    "{} solves, ms p50/max {:.2} / {:.2}",
                    self.window_solves, self.window_ms_p50, self.window_ms_max
                );
                if let (Some(p10), Some(p50), Some(p90)) = (
                    self.window_baseline_ratio_p10,
                    self.window_baseline_ratio_p50,
                    self.window_baseline_ratio_p90,
                ) {
                    text += &format!(
                        ", baseline solved/tracked p10/p50/p90 {p10:.3} / {p50:.3} / {p90:.3}"
                    );
                }
                if let (Some(p50), Some(p90)) = (
                    self.window_present_move_m_p50,
                    self.window_present_move_m_p90,
                ) {
                    text += &format!(
                        ", the present moved p50/p90 {:.2} / {:.2} cm",
                        p50 * 100.0,
                        p90 * 100.0
                    );
                }
                if let (Some(p10), Some(p50), Some(p90)) = (
                    self.map_scale_correction_p10,
                    self.map_scale_correction_p50,
                    self.map_scale_correction_p90,
                ) {
                    text += &format!(
                        ", {} maps rescaled, depth factor p10/p50/p90 {p10:.3} / {p50:.3} / \
                         {p90:.3}",
                        self.map_scale_corrections
                    );
                }
                if let (Some(p10), Some(p50), Some(p90)) = (
                    self.stored_map_scale_correction_p10,
                    self.stored_map_scale_correction_p50,
                    self.stored_map_scale_correction_p90,
                ) {
                    text += &format!(
                        ", {} stored maps rescaled as they left, p10/p50/p90 {p10:.3} / \
                         {p50:.3} / {p90:.3}",
                        self.stored_map_scale_corrections
                    );
                }
                text
            });
        }
        if self.keyframe_install_latency_frames_max > 0.0 {
            row(
                "keyframe latency",
                format!(
                    "frames from start to map p50/max {:.0} / {:.0}, to installed {:.0} / {:.0}",
                    self.keyframe_map_latency_frames_p50,
                    self.keyframe_map_latency_frames_max,
                    self.keyframe_install_latency_frames_p50,
                    self.keyframe_install_latency_frames_max
                ),
            );
        }
        if self.keyframe_bundles > 0 {
            row(
                "keyframe adjustments",
                format!(
                    "{} ({} with the keyframe before), ms p50/max {:.0} / {:.0}, depth change \
                     median {:.1} %, accel bias jump p50/max {:.3} / {:.3} m/s², velocity \
                     change p50/max {:.3} / {:.3} m/s, dropped {}, discarded {}, rejected {}",
                    self.keyframe_bundles,
                    self.keyframe_bundles_with_previous,
                    self.keyframe_bundle_ms_p50,
                    self.keyframe_bundle_ms_max,
                    self.keyframe_bundle_depth_change_median_pct,
                    self.keyframe_bundle_accel_bias_jump_p50_m_s2,
                    self.keyframe_bundle_accel_bias_jump_max_m_s2,
                    self.keyframe_bundle_velocity_change_p50_m_s,
                    self.keyframe_bundle_velocity_change_max_m_s,
                    self.refinements_dropped,
                    self.refinements_discarded,
                    self.refinements_rejected
                ),
            );
        }
        if !self.guessed_keyframe_scales.is_empty() {
            let scales: Vec<String> = self
                .guessed_keyframe_scales
                .iter()
                .map(|s| format!("{s:.3}"))
                .collect();
            row("guessed keyframes rescaled", scales.join(", "));
        }
        if let Some(e) = &self.eval {
            row("ATE RMSE (SE3)", format!("{:.4} m", e.ate_rmse_m));
            row("ATE max", format!("{:.4} m", e.ate_max_m));
            row("rotation RMSE", format!("{:.3} deg", e.rot_rmse_deg));
            if let (Some([x, y, z]), Some(rest)) =
                (e.rot_body_offset_deg, e.rot_rmse_without_body_offset_deg)
            {
                row(
                    "body rotation offset",
                    format!("({x:+.2}, {y:+.2}, {z:+.2}) deg, {rest:.3} deg RMSE without it"),
                );
            }
            row(
                "scale error (Sim3)",
                format!("{:.2} % (s = {:.4})", e.scale_error_pct, e.scale),
            );
            if let Some(r) = e.rpe_1m_trans_rmse_m {
                row("RPE 1 m", format!("{r:.4} m"));
            }
            if let (Some(rmse), Some(p90)) = (self.velocity_rmse_m_s, self.velocity_p90_m_s) {
                row(
                    "velocity error",
                    format!("{rmse:.4} m/s RMSE, {p90:.4} m/s p90"),
                );
            }
            if let (Some(b), Some(w), Some(k)) = (
                self.velocity_rmse_before_window_solves_m_s,
                self.velocity_rmse_at_window_solves_m_s,
                self.velocity_rmse_at_keyframe_switches_m_s,
            ) {
                row(
                    "velocity error in the keyframe cycle",
                    format!(
                        "{b:.4} before / {w:.4} at window solves, {k:.4} at new keyframes, m/s RMSE"
                    ),
                );
            }
            row(
                "evaluated",
                format!(
                    "{} poses, {:.1} s, {:.1} m",
                    e.matched_poses, e.duration_s, e.gt_path_m
                ),
            );
        } else {
            row(
                "evaluation",
                "not available (no ground truth overlap)".into(),
            );
        }
        s
    }
}
