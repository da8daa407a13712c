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
        self.chain_shadow = None;
    }

    /// The tracker asks for a new keyframe: if a stored keyframe (not the one tracked, not one
    /// of the window) covers the current view, track against it instead. Its pose is that of an
    /// earlier, less drifted map, so the current pose is made uncertain enough for the next
    /// frames to be pulled onto it. Returns whether it switched.
    pub(super) fn switch_to_stored_keyframe(&mut self, after_loss: bool) -> bool {
        if !self.cfg.reuse.enabled || self.store.is_empty() {
            return false;
        }
        let at = self.tracker.t_world_cam();
        let tracked = self.tracking_kf;
        let now = match &mut self.loop_closer {
            Some(link) if self.cfg.loop_closure.guide_returns => Some(link.correction_for(tracked)),
            _ => None,
        };
        let Some((id, change)) = self.stored_keyframe_covering(&at, tracked, after_loss, now)
        else {
            return false;
        };
        self.switch_to(id, after_loss, change)
    }

    /// Tracks stored keyframe `id` from the next frame on (see
    /// [`Self::switch_to_stored_keyframe`]), the state moved first by the world change `change`
    /// (a rotation about the vertical and a translation: the loop closure's placement of the
    /// odometry against the stored keyframe's world; the identity without it). `false` if there
    /// is no such keyframe.
    fn switch_to(&mut self, id: u32, after_loss: bool, change: Isometry3<f64>) -> bool {
        let Some(stored) = self.store.get(id).cloned() else {
            return false;
        };
        if change != Isometry3::identity()
            && let Some(link) = &mut self.loop_closer
        {
            link.guided_returns += 1;
        }
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
            self.switch_correction = Some(SwitchCorrection::Pending { premove: change });
            // Leaving the chain of new keyframes: the stored keyframes agree with each other,
            // not with the drift of the chain. Position and heading drift; tilt does not
            // (gravity observes it), so a stored keyframe may move the first two only.
            let r = &self.cfg.reuse;
            let x = *self.tracker.state();
            let mut cov = *self.tracker.covariance();
            // The chain's own state, to go back to if the stored keyframe fails.
            self.chain_shadow =
                (!after_loss).then(|| ChainShadow::new(x, cov, self.tracker.brightness()));
            let x = x.moved_by_world(&change);
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
        } else if change != Isometry3::identity() {
            // From one stored keyframe to another: the state moved into the new one's world.
            let (x, cov) = (*self.tracker.state(), *self.tracker.covariance());
            self.tracker.reset_state(x.moved_by_world(&change), cov);
        }
        self.reusing = true;
        self.relocalised = after_loss;
        self.keyframe_jump = true;
        self.stats.keyframe_reuses += 1;
        true
    }

    /// For tests: leaves the chain of new keyframes for a stored copy of the keyframe tracked,
    /// misplaced by `offset_m` in the world — a stored keyframe that cannot fit the next frame,
    /// as one whose map drifted far from the chain's. `false` (nothing done) unless a keyframe
    /// of the chain is tracked and `[reuse]` is on.
    pub fn inject_return_to_misplaced_keyframe(&mut self, offset_m: Vector3<f64>) -> bool {
        if self.phase != Phase::Tracking || self.reusing || !self.cfg.reuse.enabled {
            return false;
        }
        let (Some(mut kf), Some(map)) =
            (self.tracker.keyframe().cloned(), self.tracking_map.clone())
        else {
            return false;
        };
        let mut map = (*map).clone();
        kf.id = MISPLACED_KEYFRAME_ID;
        kf.t_world_cam.translation.vector += offset_m;
        map.t_world_cam.translation.vector += offset_m;
        self.store.insert(kf, Arc::new(map))
            && self.switch_to(MISPLACED_KEYFRAME_ID, false, Isometry3::identity())
    }

    /// The stored keyframe that covers the view from `t_world_cam`, other than `current`, a
    /// keyframe of the window or one that failed since it was stored (`[reuse]`), with the
    /// change of world that takes the odometry's pose into that keyframe's: with `now`, the
    /// loop closer's correction of the odometry's world (`guide_returns`), each stored keyframe
    /// is seen from the pose the graph places in its world; else the identity.
    pub(super) fn stored_keyframe_covering(
        &self,
        t_world_cam: &Isometry3<f64>,
        current: Option<u32>,
        after_loss: bool,
        now: Option<Isometry3<f64>>,
    ) -> Option<(u32, Isometry3<f64>)> {
        let (window, failed) = (&self.window, &self.failed_reuse);
        let window_too = after_loss && self.cfg.bootstrap.relocalise_in_window;
        let excluded = |id| {
            Some(id) == current
                || (!window_too && window.state(id).is_some())
                || failed.contains(&id)
        };
        let change = |id: u32| match (&self.loop_closer, &now) {
            (Some(link), Some(now)) => link.world_change(id, now),
            _ => Isometry3::identity(),
        };
        let border_px = self.cfg.tracking.border_px;
        let b = &self.cfg.bootstrap;
        let limits = if after_loss {
            ReachLimits {
                max_baseline_ratio: b.relocalise_max_baseline_ratio,
                max_rotation_rad: b.relocalise_max_rotation_rad,
                min_overlap: b.relocalise_min_overlap,
            }
        } else {
            self.store.limits()
        };
        self.store
            .closest_seen_from(|id| change(id) * t_world_cam, border_px, excluded, &limits)
            .map(|(id, _overlap)| (id, change(id)))
    }

    /// Keeps the tracking keyframe `kf` (with its map), which is being left, for returning to it
    /// — unless it was tracked with guessed depths: that is no place to return to.
    pub(super) fn store_keyframe(&mut self, kf: Keyframe, map: Arc<SemidenseMap>) {
        if self.cfg.reuse.enabled && !self.tracking_kf_filled && self.store.insert(kf, map) {
            self.stats.keyframes_stored = self.store.len();
        }
    }

    /// A stored keyframe lost track: mark it failed and track the keyframe left for it again —
    /// if that one is still in view (`return_min_overlap`). Returns whether it went back; if not,
    /// the failing keyframe stays tracked until a new one replaces it.
    pub(super) fn return_from_stored_keyframe(&mut self, keyframe_at_fault: bool) -> bool {
        if keyframe_at_fault && let Some(id) = self.tracking_kf {
            self.failed_reuse.push(id);
        }
        self.stats.keyframe_reuse_failures += 1;
        let t_world_cam = self.tracker.t_world_cam();
        let (level, border_px, min) = (
            self.cfg.reuse.overlap_level,
            self.cfg.tracking.border_px,
            self.cfg.reuse.return_min_overlap,
        );
        let target = go_back_to(
            self.reuse_previous.as_ref(),
            self.left_kf.as_ref(),
            |s: &StoredKeyframe| s.kf.predicted_overlap(&t_world_cam, level, border_px) >= min,
        );
        match target {
            GoBack::Previous => {
                // Back to the stored keyframe tracked before (still reusing, on probation
                // again): after a chain of stored keyframes the one left in the chain of new
                // keyframes may be seconds behind and out of view.
                if let Some(s) = self.reuse_previous.take() {
                    self.track_again(s);
                }
                self.reuse_frames = 0;
            }
            GoBack::Left => {
                self.reuse_previous = None;
                match self.left_kf.take() {
                    Some(s) => {
                        self.track_again(s);
                        self.reusing = false;
                        self.switch_correction = None;
                    }
                    None => {
                        // A relocalisation after a loss left none behind: lost again.
                        self.lose_keyframe();
                        self.phase = Phase::Lost;
                        self.stats.resets += 1;
                    }
                }
            }
            GoBack::Stay => {
                self.reuse_previous = None;
                self.stats.returns_out_of_view += 1;
                // Failed, but tracked on until a new keyframe replaces it: its probation is over.
                self.reuse_frames = self.cfg.reuse.probation_frames + 1;
                return false;
            }
        }
        true
    }

    /// Back on the chain after a stored keyframe failed its probation
    /// ([`Self::return_from_stored_keyframe`] went back to the keyframe left): the failing frame
    /// at `t` is tracked again on that keyframe from the chain's state before it — the IMU's
    /// prediction from the last frame tracked on the chain — instead of from the state the
    /// failing keyframe pulled it to, so neither that frame's pose nor the chain's next ones
    /// carry the disagreement between the two maps. `None` (nothing changed) if the return went
    /// elsewhere or there is no such state.
    pub(super) fn retrack_on_chain(&mut self, t: TimeNs, image: &Image<u8>) -> Option<TrackResult> {
        let shadow = self.chain_shadow.take()?;
        if self.reusing {
            return None;
        }
        let pre = shadow.pre?;
        self.tracker.set_brightness(shadow.brightness);
        self.tracker.reset_state(shadow.before, shadow.cov);
        let r = self.tracker.track(t, image, &pre);
        // Continuous with the chain: no jump for the next frame to stand in for.
        self.keyframe_jump = false;
        self.tracked_step_m = Some(r.state.nav.p_world_m - shadow.before.nav.p_world_m);
        self.stats.chain_retracks += 1;
        Some(r)
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

/// The id of the keyframe [`Odometry::inject_return_to_misplaced_keyframe`] stores (no mapper
/// keyframe gets it).
const MISPLACED_KEYFRAME_ID: u32 = u32::MAX;

/// Where a stored keyframe that failed its probation sends the tracker.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum GoBack {
    /// The stored keyframe tracked before it (it had passed its own probation).
    Previous,
    /// The keyframe left in the chain of new keyframes for the stored ones.
    Left,
    /// Nowhere: both are out of view; the failing keyframe stays tracked and a new keyframe is
    /// started from the current frame.
    Stay,
}

/// The choice of [`Odometry::return_from_stored_keyframe`]: the stored keyframe tracked before,
/// if any and `in_view`; else the keyframe left, if `in_view` (or if there is none: the loss
/// that follows is what happened before `return_min_overlap`); else stay.
fn go_back_to(
    previous: Option<&StoredKeyframe>,
    left: Option<&StoredKeyframe>,
    in_view: impl Fn(&StoredKeyframe) -> bool,
) -> GoBack {
    if previous.is_some_and(&in_view) {
        GoBack::Previous
    } else if left.is_some_and(|s| !in_view(s)) {
        GoBack::Stay
    } else {
        GoBack::Left
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::semidense::MapPoint;
    use crate::tracking::DepthPoint;

    /// A keyframe at the origin looking along +z at a textured plane 2 m away, with its map.
    fn stored(id: u32, t_world_cam: Isometry3<f64>) -> StoredKeyframe {
        let cam = CameraModel::euroc_cam0();
        let pyr = textured_pyramid(&cam);
        let cfg = TrackerConfig::default();
        let pts: Vec<DepthPoint> = select_gradient_pixels(&pyr, &cfg)
            .into_iter()
            .map(|(x, y)| DepthPoint {
                u_px: x as f32,
                v_px: y as f32,
                inv_depth_m_inv: 0.5,
            })
            .collect();
        let map = SemidenseMap {
            t_world_cam,
            camera: cam,
            points: pts
                .iter()
                .map(|p| MapPoint {
                    u_px: p.u_px,
                    v_px: p.v_px,
                    inv_depth_m_inv: p.inv_depth_m_inv,
                    inv_depth_std_m_inv: 0.01,
                    num_views: 3,
                })
                .collect(),
        };
        let kf = Keyframe::new(id, TimeNs(0), &pyr, &cam, t_world_cam, &pts, &cfg);
        StoredKeyframe {
            kf,
            map: Arc::new(map),
        }
    }

    /// The demo's hover turn: the stored keyframe on probation fails half-way through the turn,
    /// and the keyframe left for it faces where the camera looked a second ago.
    #[test]
    fn a_failed_return_goes_back_only_to_a_keyframe_still_in_view() {
        let cfg = ReuseConfig::default();
        let border_px = TrackerConfig::default().border_px;
        let ahead = stored(1, Isometry3::identity());
        // Turned by 0.2 rad: still mostly in view. Turned by 1.5 rad: out of view.
        let turned = |yaw: f64| Isometry3::new(Vector3::zeros(), Vector3::y() * yaw);
        let (near, behind) = (stored(2, turned(0.2)), stored(3, turned(1.5)));
        let camera = turned(0.1);
        let in_view = |s: &StoredKeyframe| {
            s.kf.predicted_overlap(&camera, cfg.overlap_level, border_px) >= cfg.return_min_overlap
        };
        assert!(in_view(&ahead) && in_view(&near) && !in_view(&behind));
        // Before `return_min_overlap`: always back (to the previous stored one first).
        assert_eq!(
            go_back_to(Some(&behind), Some(&behind), |_| true),
            GoBack::Previous
        );
        assert_eq!(go_back_to(None, Some(&behind), |_| true), GoBack::Left);
        // Now: the previous stored keyframe if it is in view, else the one left if it is…
        assert_eq!(
            go_back_to(Some(&near), Some(&behind), in_view),
            GoBack::Previous
        );
        assert_eq!(
            go_back_to(Some(&behind), Some(&ahead), in_view),
            GoBack::Left
        );
        assert_eq!(go_back_to(None, Some(&ahead), in_view), GoBack::Left);
        // …else stay (and start a new keyframe from here).
        assert_eq!(
            go_back_to(Some(&behind), Some(&behind), in_view),
            GoBack::Stay
        );
        assert_eq!(go_back_to(None, Some(&behind), in_view), GoBack::Stay);
        // No keyframe left at all: as before (the tracker is lost).
        assert_eq!(go_back_to(None, None, in_view), GoBack::Left);
    }
}
