//! Returns to stored keyframes (`[reuse]`, [`KeyframeStore`]): switching to the closest one,
//! its probation, going back when it fails, and losing the keyframe altogether.

use super::*;

impl Odometry {
    /// Tracking is lost: no keyframe until a new one is installed.
    pub(super) fn lose_keyframe(&mut self) {
        self.tracker.clear_keyframe();
        self.tracking_kf = None;
        self.tracking_map = None;
        self.reusing = false;
        self.reuse_previous = None;
        self.switch_correction = None;
    }

    /// The tracker asks for a new keyframe: if a stored keyframe (not the one tracked, not one
    /// of the window) covers the current view, track against it instead. Its pose is that of an
    /// earlier, less drifted map, so the current pose is made uncertain enough for the next
    /// frames to be pulled onto it. Returns whether it switched.
    pub(super) fn switch_to_stored_keyframe(&mut self) -> bool {
        if !self.cfg.reuse.enabled || self.store.is_empty() {
            return false;
        }
        let Some(id) = self.stored_keyframe_covering(&self.tracker.t_world_cam(), self.tracking_kf)
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
            self.switch_correction = Some(SwitchCorrection::Pending);
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

    /// The stored keyframe that covers the view from `t_world_cam`, other than `current`, a
    /// keyframe of the window or one that failed since it was stored (`[reuse]`).
    pub(super) fn stored_keyframe_covering(
        &self,
        t_world_cam: &Isometry3<f64>,
        current: Option<u32>,
    ) -> Option<u32> {
        let (window, failed) = (&self.window, &self.failed_reuse);
        self.store
            .closest(t_world_cam, self.cfg.tracking.border_px, |id| {
                Some(id) == current || window.state(id).is_some() || failed.contains(&id)
            })
            .map(|(id, _overlap)| id)
    }

    /// Keeps the tracking keyframe `kf` (with its map), which is being left, for returning to it
    /// — unless it was tracked with guessed depths: that is no place to return to.
    pub(super) fn store_keyframe(&mut self, kf: Keyframe, map: Arc<SemidenseMap>) {
        if self.cfg.reuse.enabled && !self.tracking_kf_filled && self.store.insert(kf, map) {
            self.stats.keyframes_stored = self.store.len();
        }
    }

    /// A stored keyframe lost track: mark it failed and track the keyframe left for it again.
    pub(super) fn return_from_stored_keyframe(&mut self) {
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
                self.switch_correction = None;
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
}
