//! The keyframe window's part in the per-frame flow ([`crate::smoother::KeyframeWindow`]): a
//! frame about to become a keyframe joined to the window by its relative pose and the IMU, the
//! solve moved onto the tracker's keyframe and state, the window's estimate of the tracked map's
//! scale applied to it (`[window] map_scale_gain`), and the window kept or restarted across a
//! loss or a return to a stored keyframe.

use super::*;

impl Odometry {
    /// A first map is about to be started again in flight, at the tracker's (dead-reckoned)
    /// state: with `[window] keep_across_rebuild`, and the IMU since the window's newest keyframe
    /// still buffered and spanning at most `keep_across_rebuild_max_s`, the new map's first
    /// keyframe joins the window by the IMU through the loss
    /// ([`KeyframeWindow::push_new_map`]); otherwise the window restarts there.
    pub(super) fn window_across_loss(&mut self) {
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
        self.correct_stored_map_scales();
        self.stats.window_kept_across_rebuild += 1;
    }

    /// The gyro's turn against the body frame as the keyframe window reads it (`[window]
    /// gyro_misalignment`; zero when off), rad: the tracker's and the keyframe adjustment's IMU
    /// are turned by it.
    pub(super) fn gyro_turn_rad(&self) -> Vector3<f64> {
        if self.cfg.window.gyro_misalignment {
            self.window.gyro_misalignment_rad()
        } else {
            Vector3::zeros()
        }
    }

    /// The turn the keyframe adjustment's IMU gets: [`Odometry::gyro_turn_rad`] once it is at
    /// least `[keyframe_bundle] gyro_turn_min_rad`, zero before.
    pub(super) fn adjustment_gyro_turn_rad(&self) -> Vector3<f64> {
        let phi = self.gyro_turn_rad();
        if phi.norm() >= self.cfg.keyframe_bundle.gyro_turn_min_rad {
            phi
        } else {
            Vector3::zeros()
        }
    }

    /// Whether the IMU buffer still reaches back to keyframe state `from`.
    pub(super) fn imu_buffered_since(&self, from: &FrameState) -> bool {
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
    pub(super) fn reset_window(&mut self) {
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
    pub(super) fn window_keyframe(
        &mut self,
        result: &mut TrackResult,
        image: &Image<u8>,
    ) -> Option<Isometry3<f64>> {
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
        if tracked_newest && let Some(v) = &visual {
            self.read_gyro_noise(&pre, &v.t_i_j, &result.photometric_step, t);
        }
        let skip = tracked_newest
            .then(|| self.measure_skip_edge(result, image))
            .flatten();
        let old = result.state;
        self.window.push(id, old, pre, visual);
        if let Some((from, rel)) = skip
            && self.window.set_newest_skip(from, rel)
        {
            self.stats.window_skip_edges += 1;
        }
        self.correct_stored_map_scales();
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
        if self.cfg.window.mount_rotation
            && let Some((t_oldest, psi)) = self.window.mount_rotations().next()
        {
            self.stats
                .window_mount_rotation_history
                .push((t_oldest, psi));
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
        if !across_return {
            // (Across a return the move includes the window's change of world.)
            self.stats
                .window_present_moves_m
                .push((x_new.nav.p_world_m - old.nav.p_world_m).norm());
        }
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
        self.stats.window_solve_frames.push(t);
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
        if self.cfg.loop_closure.follow_window_poses
            && let Some(link) = &mut self.loop_closer
        {
            let t_body_cam = self.rig.t_body_cam;
            link.move_keyframes(
                (self.window.states())
                    .map(|(id, x)| (id, pose_of(x) * t_body_cam))
                    .collect(),
            );
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

    /// `[window] stored_map_scale_gain`: each keyframe that left the window has the loop
    /// closer's copy of its map (and with `stored_map_scale_in_returns` the stored keyframe
    /// returns track against) scaled by the window's last word on it: `e^{−g (λ − c)}`, `λ − c`
    /// its log-scale as it was left
    /// ([`crate::smoother::KeyframeWindow::pop_marginalised_map_scale`]), at most
    /// `map_scale_max_step`. Not a keyframe tracked now (a return to it): the tracker holds a
    /// copy of its own, which is stored again as it is when it is left.
    fn correct_stored_map_scales(&mut self) {
        let w = &self.cfg.window;
        let (gain, max, returns) = (
            w.stored_map_scale_gain,
            w.map_scale_max_step,
            w.stored_map_scale_in_returns,
        );
        while let Some((id, t, left)) = self.window.pop_marginalised_map_scale() {
            let c = (gain * left).clamp(-max, max);
            if gain <= 0.0 || !c.is_finite() || c == 0.0 || self.tracking_kf == Some(id) {
                continue;
            }
            let depth_factor = (-c).exp();
            let stored = returns && self.store.scale_depths(id, depth_factor);
            if let Some(link) = &mut self.loop_closer {
                link.scale_map(id, depth_factor);
            }
            if stored || self.loop_closer.is_some() {
                self.stats.stored_map_scale_corrections.push((t, c));
            }
        }
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
    pub(super) fn send_scale_depths(&mut self, id: u32, inv_depth_factor: f64) {
        let seq = self.next_seq();
        self.send(MapJob::ScaleDepths {
            seq,
            id,
            factor: inv_depth_factor,
        });
    }

    /// The frames kept for the next keyframe were tracked against a map now scaled by
    /// `depth_factor` about the camera centre `centre_m`: their positions follow.
    pub(super) fn rescale_history(&mut self, centre_m: Vector3<f64>, depth_factor: f64) {
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
}
