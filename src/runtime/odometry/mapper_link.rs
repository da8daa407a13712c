//! The odometry's side of the mapping thread (`super::super::mapping_worker`): the jobs sent (new
//! keyframes with their history frames, views), the snapshots taken (offline at fixed frame lags,
//! in real time as they arrive) and the decision to install a new keyframe, or a refresh of the
//! tracked one, for tracking.

use super::*;
use crate::runtime::guessed_keyframe::{
    GuessSettings, GuessedKeyframeJob, build_guessed_keyframe, depthless_points, median_inv_depth,
};
use crate::runtime::keyframe_builder::KeyframeBuilder;
use crate::runtime::map_keyframe::{build, take_keyframe};
use crate::runtime::mapping_worker::{InstallHint, NewKeyframeHint};

impl Odometry {
    pub(super) fn next_seq(&mut self) -> u64 {
        self.seq += 1;
        self.seq
    }

    pub(super) fn send(&mut self, job: MapJob) {
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
    pub(super) fn send_deferred_jobs(&mut self) {
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

    pub(super) fn start_keyframe(
        &mut self,
        frame: MapFrame,
        history: Vec<MapFrame>,
        propagate: bool,
    ) {
        self.resumed = false;
        // Chain the mapper's world through the previous keyframe's corrected pose.
        if let Some((prev, m_prev)) = self.mapper_kf_pose
            && let Some(x) = self.window.state(prev)
        {
            let p_prev = pose_of(x) * self.rig.t_body_cam;
            self.mapper_from_world = m_prev * p_prev.inverse();
        }
        let d = self.mapper_from_world;
        let seed_moved = self.seed_correction.take();
        // Started while tracking a stored keyframe: its map seeds the new one (the mapper's own
        // keyframe is the one left behind).
        let seed = self
            .reusing
            .then(|| {
                let id = self.tracking_kf?;
                let s = self.store.get(id)?;
                let mut m = (*s.map).clone();
                m.t_world_cam = match seed_moved {
                    Some(c) => d * c * s.kf.t_world_cam,
                    None => d * s.kf.t_world_cam,
                };
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
        let previous = self.previous_host(&frame);
        self.kf_record =
            (self.phase == Phase::Tracking && self.cfg.keyframe_bundle.enabled).then(|| {
                KeyframeRecord {
                    id,
                    start: *self.tracker.state(),
                    views: Vec::new(),
                    previous,
                    gyro_turn_rad: self.adjustment_gyro_turn_rad(),
                }
            });
        self.mapper_kf_pose = Some((id, frame.t_world_cam));
        self.next_kf_id += 1;
        self.newest_kf = Some(id);
        self.pending_kf = Some(id);
        self.kf_started = (self.phase == Phase::Tracking).then_some((id, self.frame_number, false));
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
            hint: self.install_hint(),
        });
    }

    /// The keyframe tracked when the keyframe of `frame` is started, with the frames tracked
    /// against it since, for `[keyframe_bundle] previous_host` — if it is the keyframe window's
    /// newest (its state is known there) and was mapped, not a stored one or one of guesses.
    fn previous_host(&self, frame: &MapFrame) -> Option<Box<PreviousHost>> {
        if !self.cfg.keyframe_bundle.previous_host
            || self.phase != Phase::Tracking
            || self.reusing
            || self.tracking_kf_filled
        {
            return None;
        }
        let kf = self.tracker.keyframe()?;
        if self.tracking_kf != Some(kf.id) {
            return None;
        }
        let state = *self.window.state(kf.id)?;
        let frames = self
            .tracked_frames
            .iter()
            .filter(|(f, _)| f.t > kf.t && f.t < frame.t)
            .cloned()
            .collect();
        Some(Box::new(PreviousHost {
            keyframe: kf.clone(),
            image: self.tracking_kf_image.clone()?,
            state,
            frames,
        }))
    }

    pub(super) fn observe(&mut self, frame: MapFrame) {
        let frame = MapFrame {
            t_world_cam: self.mapper_from_world * frame.t_world_cam,
            ..frame
        };
        let seq = self.next_seq();
        let hint = self.install_hint();
        self.send(MapJob::Observe { seq, frame, hint });
    }

    /// Which of the mapper's maps [`Self::apply_snapshot`] may install at the next frames, as far
    /// as this frame can tell (`[bootstrap] mapper_builds_keyframes`): any of the new keyframe
    /// awaited with enough points (whether one is installed before it has forward views depends
    /// on how the keyframe tracked fares in the frames until it arrives; the first map in flight,
    /// whose installation waits for a baseline, is not hinted); a refresh of the keyframe tracked
    /// once its map has grown past a tenth — whatever the frames since the last refresh, which in
    /// real time have passed by the time the map arrives.
    fn install_hint(&self) -> InstallHint {
        if self.phase != Phase::Tracking || !self.cfg.bootstrap.mapper_builds_keyframes {
            return InstallHint::default();
        }
        let b = &self.cfg.bootstrap;
        let new = self.pending_kf.map(|id| NewKeyframeHint {
            id,
            min_points: b.min_keyframe_points,
        });
        let refresh = match (self.pending_kf, self.tracking_kf) {
            (None, Some(id)) if !self.tracking_kf_adjusted => {
                let n = self.tracking_kf_points;
                let above = n + n / 10;
                let above = if self.tracking_kf_filled {
                    above.max(b.fill_depthless_below_points.saturating_sub(1))
                } else {
                    above
                };
                Some((id, above))
            }
            _ => None,
        };
        InstallHint { new, refresh }
    }

    /// Takes the mapper's snapshots: offline, exactly those of the jobs sent at least
    /// `offline_lag_frames` frames ago (waiting for them); real-time, whatever has arrived.
    /// Installs or refreshes the tracking keyframe.
    pub(super) fn collect_snapshots(&mut self) {
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
            self.apply_snapshot(s);
        }
    }

    /// Where new keyframe `id` stands with its adjustment (`[keyframe_bundle]`): the frames
    /// tracked since it was started are recorded for it, and are they enough (`min_views`; in
    /// real time `realtime_min_views`).
    fn adjustment_views(&self, id: u32) -> AdjustmentViews {
        let kb = &self.cfg.keyframe_bundle;
        match self.kf_record.as_ref().filter(|r| r.id == id) {
            Some(r) if kb.enabled && self.refiner.is_some() => {
                if r.views.len() >= adjustment_views_needed(kb, self.cfg.realtime) {
                    AdjustmentViews::Enough
                } else {
                    AdjustmentViews::Awaited
                }
            }
            _ => AdjustmentViews::NotAdjusted,
        }
    }

    /// Keyframe adjustments come back frames after they are sent: in real time, or offline with
    /// `[keyframe_bundle] lag_frames` (which emulates it).
    pub(super) fn adjustments_late(&self) -> bool {
        self.cfg.realtime || self.cfg.keyframe_bundle.lag_frames > 0
    }

    pub(super) fn apply_snapshot(&mut self, mut snapshot: MapSnapshot) {
        let s = &snapshot;
        let is_new = self.pending_kf == Some(s.keyframe_id);
        let is_refresh = self.pending_kf.is_none() && self.tracking_kf == Some(s.keyframe_id);
        if !(is_new || is_refresh) {
            return; // a keyframe that has been superseded already, or left for a stored one
        }
        if let Some((id, started, map_seen @ false)) = self.kf_started.as_mut()
            && *id == s.keyframe_id
        {
            *map_seen = true;
            let latency = self.frame_number - *started;
            self.stats.keyframe_map_latency_frames.push(latency);
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
        let on_the_spot = self.on_the_spot(&(self.mapper_from_world.inverse() * s.map.t_world_cam));
        let fill = if self.phase == Phase::Tracking
            && is_new
            && on_the_spot
            && n < b.fill_depthless_below_points
            && let Some(median_inv) = median_inv_depth(&s.map).or(self.last_median_inv_depth)
        {
            Some(depthless_points(
                &s.keyframe_pyramid,
                &s.map,
                median_inv,
                &self.cfg.tracking,
            ))
        } else {
            None
        };
        let n_fill = fill.as_ref().map_or(0, Vec::len);
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
                            (self.cfg.realtime, self.adjustments_late()),
                            self.last_inlier_ratio,
                            s.forward_views,
                            self.adjustment_views(s.keyframe_id),
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
        let filled = fill.is_some();
        // A new keyframe with enough views goes to its adjustment, which builds it on the
        // refinement thread and hands it back with the adjusted one. Any other is built here.
        if self.phase == Phase::Tracking
            && is_new
            && !filled
            && self.adjustment_views(s.keyframe_id) == AdjustmentViews::Enough
            && self.send_keyframe_adjustment(s)
        {
            return;
        }
        let pose = self.mapper_from_world.inverse() * s.map.t_world_cam;
        let (kf, came_built) = match fill {
            Some(fill) => (build(s, fill, pose, &self.rays, &self.cfg.tracking), false),
            None => take_keyframe(&mut snapshot, pose, &self.rays, &self.cfg.tracking),
        };
        if came_built {
            self.stats.keyframes_built_by_mapper += 1;
        } else {
            self.stats.keyframes_built_on_tracking_thread += 1;
        }
        let s = &snapshot;
        if self.phase == Phase::Initializing && self.send_takeoff(&kf, s) {
            return; // the first map will be triangulated again from the refined take-off
        }
        self.install_keyframe(kf, s, is_new, filled, false);
    }

    /// `[bootstrap] fill_without_mapper`: the keyframe just started (`pending_kf`, at `t`, of
    /// `image`, the frame just tracked) is barely displaced from the one tracked — a turn on the
    /// spot, where nothing new can be triangulated — so it is made at once instead of waiting
    /// for the mapper ([`super::super::guessed_keyframe`]): the tracked map's points moved into
    /// it, its other gradient pixels at their median inverse depth. The builder thread makes it
    /// between this frame and the next, which installs it before anything else
    /// ([`Self::install_spot_turn_keyframe`]). It is installed as a keyframe of guessed depths
    /// (`filled`), exactly as the mapper's first map of a turn on the spot would be; the mapper's
    /// own map of it replaces it once it has `fill_depthless_below_points` points.
    pub(super) fn start_spot_turn_keyframe(&mut self, t: TimeNs, image: &Arc<Image<u8>>) {
        let b = &self.cfg.bootstrap;
        if !b.fill_without_mapper || b.fill_depthless_below_points == 0 {
            return;
        }
        let (Some(id), Some(old), Some(old_map)) = (
            self.pending_kf,
            self.tracker.keyframe(),
            self.tracking_map.clone(),
        ) else {
            return;
        };
        let t_world_cam = self.tracker.t_world_cam();
        if !self.on_the_spot(&t_world_cam) {
            return;
        }
        let t_new_old = t_world_cam.inverse() * old.t_world_cam;
        // (The spare exists with the builder thread, which hands it back with each build.)
        let pyramid = match self.spare_pyramid.take() {
            Some(spare) => self.tracker.swap_frame_pyramid(spare),
            None => self.tracker.frame_pyramid().clone(),
        };
        let job = GuessedKeyframeJob {
            id,
            t,
            image: image.clone(),
            pyramid,
            t_world_cam,
            mapper_from_world: self.mapper_from_world,
            moved_from: Some((old_map, t_new_old)),
            fallback_median_inv_depth_m_inv: self.last_median_inv_depth,
        };
        // (One build at a time: the last one was installed at the start of this frame. Were the
        // builder refusing it — gone — it is built here.)
        let refused = match self.builder.as_mut() {
            Some(builder) => builder.start(job).err().map(|j| *j),
            None => Some(job),
        };
        if let Some(job) = refused
            && let Some((kf, s)) = build_guessed_keyframe(job, &self.guess_settings())
        {
            self.stats.spot_turn_keyframes += 1;
            self.install_keyframe(kf, &s, true, true, false);
        }
    }

    /// Installs the turn on the spot's keyframe started at the end of the last frame
    /// ([`Self::start_spot_turn_keyframe`]), waiting for the builder thread if it is not done:
    /// the first thing of a frame. Its frame counts as one frame since the refresh, as when it
    /// was installed in its own frame.
    pub(super) fn install_spot_turn_keyframe(&mut self) {
        let Some(done) = self.builder.as_mut().and_then(KeyframeBuilder::wait) else {
            return;
        };
        self.spare_pyramid = Some(done.spare);
        self.stats.spot_turn_build_s.push(done.time_s);
        if let Some((kf, s)) = done.built
            && self.pending_kf == Some(done.id)
        {
            self.stats.spot_turn_keyframes += 1;
            self.install_keyframe(kf, &s, true, true, false);
            self.frames_since_refresh = 1;
        }
    }

    /// The settings of a keyframe of guessed depths built on this thread.
    fn guess_settings(&self) -> GuessSettings {
        guess_settings(&self.cfg, self.rig.camera, &self.rays)
    }

    /// `[bootstrap] reinit_guessed_depths`: the first map just started in flight from `frame`
    /// (`pending_kf`; the tracker holds that frame) is installed at once, its gradient pixels at
    /// the median inverse depth of the last map tracked, as a keyframe of guessed depths. Its
    /// record goes to the keyframe adjustment with its depths free once the mapper's own map of
    /// it is in and its views span a baseline; the velocity dead-reckoned through the loss is
    /// given `reinit_velocity_free_std_m_s`. Nothing is installed before any map was tracked
    /// (no depth to guess) or on too little texture: the mapper's first map is awaited then.
    pub(super) fn install_reinit_keyframe(&mut self, frame: &MapFrame) {
        let (Some(id), Some(median_inv)) = (self.pending_kf, self.last_median_inv_depth) else {
            return;
        };
        let job = GuessedKeyframeJob {
            id,
            t: frame.t,
            image: frame.image.clone(),
            pyramid: self.tracker.frame_pyramid().clone(),
            t_world_cam: frame.t_world_cam,
            mapper_from_world: self.mapper_from_world,
            moved_from: None,
            fallback_median_inv_depth_m_inv: Some(median_inv),
        };
        let Some((kf, s)) = build_guessed_keyframe(job, &self.guess_settings()) else {
            return;
        };
        let x = *self.tracker.state();
        let mut cov = *self.tracker.covariance();
        let var = self.cfg.bootstrap.reinit_velocity_free_std_m_s.powi(2);
        for i in 6..9 {
            cov[(i, i)] = cov[(i, i)].max(var);
        }
        self.tracker.reset_state(x, cov);
        self.kf_record = Some(KeyframeRecord {
            id,
            start: x,
            views: Vec::new(),
            previous: None,
            gyro_turn_rad: self.adjustment_gyro_turn_rad(),
        });
        self.reinit_kf = Some(id);
        self.stats.reinit_guessed_keyframes += 1;
        self.install_keyframe(kf, &s, true, true, false);
    }

    /// Turned on the spot: a camera at `t_world_cam` (tracker's world) is barely displaced from
    /// the keyframe tracked (`fill_max_baseline_ratio` of its median depth).
    fn on_the_spot(&self, t_world_cam: &Isometry3<f64>) -> bool {
        self.tracker.keyframe().is_some_and(|k| {
            let d = (t_world_cam.translation.vector - k.t_world_cam.translation.vector).norm();
            d < self.cfg.bootstrap.fill_max_baseline_ratio * k.median_depth_m
        })
    }

    /// Makes `kf` (of snapshot `s`) the keyframe tracked against: a new one (`is_new`) or a refresh
    /// of the current one; `filled` with depthless pixels, `adjusted` by the keyframe adjustment.
    pub(super) fn install_keyframe(
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
        if is_new && let Some((_, started, _)) = self.kf_started.take_if(|(id, ..)| *id == kf.id) {
            self.stats
                .keyframe_install_latency_frames
                .push(self.frame_number - started);
        }
        let (new_id, new_t, new_pose) = (kf.id, kf.t, kf.t_world_cam);
        // A refresh of the same keyframe keeps the brightness estimate.
        let previous = self.tracker.set_keyframe(kf);
        if is_new {
            if self.cfg.window.skip_edges {
                self.skip.left(previous.as_ref());
            }
            // A map of guessed depths is none for the loop closer.
            let left_map = self
                .tracking_map
                .clone()
                .filter(|_| !self.tracking_kf_filled);
            self.loop_keyframe(
                new_id,
                new_t,
                new_pose,
                &s.keyframe_image,
                previous.as_ref(),
                left_map.as_ref(),
            );
            if let (Some(old), Some(map)) = (previous, self.tracking_map.take()) {
                self.store_keyframe(old, map);
            }
            self.pending_kf = None;
            self.reusing = false;
            self.relocalised = false;
            self.left_kf = None;
            self.switch_correction = None;
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
        self.tracking_kf_image = Some(s.keyframe_image.clone());
        if is_new {
            // Frames tracked so far were tracked against the keyframe before; those since this
            // one's time join its chain moved by its adjustment (`apply_keyframe_adjustment`).
            self.tracked_frames.clear();
        }
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

/// The settings of keyframes of guessed depths (built by the builder thread or inline).
pub(super) fn guess_settings(
    cfg: &OdometryConfig,
    camera: CameraModel,
    rays: &Arc<PixelRays>,
) -> GuessSettings {
    GuessSettings {
        camera,
        rays: rays.clone(),
        tracking: cfg.tracking.clone(),
        border_px: cfg.tracking.border_px,
        min_keyframe_points: cfg.bootstrap.min_keyframe_points,
    }
}

/// Where a new keyframe stands with its adjustment (`[keyframe_bundle]`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum AdjustmentViews {
    /// It will not be adjusted (the adjustment is off, or its tracked frames are not recorded).
    NotAdjusted,
    /// Fewer frames have been tracked since it than its adjustment needs (`min_views`).
    Awaited,
    /// Enough frames for its adjustment: it is adjusted before it is installed.
    Enough,
}

/// Frames tracked since a new keyframe was started that its adjustment needs: `min_views`, in
/// real time `realtime_min_views` if more (at least 1).
fn adjustment_views_needed(kb: &KeyframeBundleConfig, realtime: bool) -> usize {
    let n = if realtime {
        kb.min_views.max(kb.realtime_min_views)
    } else {
        kb.min_views
    };
    n.max(1)
}

/// Whether a new keyframe's map may be installed (or handed to its adjustment): it has forward
/// parallax (`min_keyframe_forward_views` views after it in the mapper; in real time the frames
/// tracked since it instead, once its adjustment can use them — not before, however many views
/// the mapper has), or the keyframe tracked meanwhile is
/// slipping away (`urgent_inlier_ratio`; when adjustments come back `late` — in real time, or
/// offline with `[keyframe_bundle] lag_frames` — and its adjustment still awaits its frames, so
/// that installed now it would be installed unadjusted: only below
/// `urgent_unadjusted_inlier_ratio`).
fn new_keyframe_ready(
    b: &BootstrapConfig,
    (realtime, late): (bool, bool),
    inlier_ratio: f64,
    forward_views: usize,
    views: AdjustmentViews,
) -> bool {
    let awaits_adjustment = late && views == AdjustmentViews::Awaited;
    let slipping = inlier_ratio < b.urgent_inlier_ratio
        && (!awaits_adjustment || inlier_ratio < b.urgent_unadjusted_inlier_ratio);
    slipping
        || (forward_views >= b.min_keyframe_forward_views
            && !(realtime && views == AdjustmentViews::Awaited))
        || (realtime && views == AdjustmentViews::Enough)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_new_keyframe_waits_for_forward_views_offline_and_for_its_adjustment_views_in_real_time() {
        use AdjustmentViews::*;
        let b = BootstrapConfig::default();
        let (offline, realtime) = ((false, false), (true, true));
        let tracked_well = b.urgent_inlier_ratio + 0.1;
        let few = b.min_keyframe_forward_views - 1;
        let enough = b.min_keyframe_forward_views;
        // Offline: the mapper's forward views, whatever was tracked since.
        assert!(!new_keyframe_ready(&b, offline, tracked_well, few, Enough));
        assert!(new_keyframe_ready(
            &b,
            offline,
            tracked_well,
            enough,
            Awaited
        ));
        // Real time: the tracked frames its adjustment will use stand in for them…
        assert!(new_keyframe_ready(&b, realtime, tracked_well, 0, Enough));
        // …but not before there are enough of them, even with the mapper's forward views.
        assert!(!new_keyframe_ready(
            &b,
            realtime,
            tracked_well,
            few,
            Awaited
        ));
        assert!(!new_keyframe_ready(
            &b,
            realtime,
            tracked_well,
            enough,
            Awaited
        ));
        // (A keyframe not to be adjusted takes the mapper's forward views, as offline.)
        assert!(new_keyframe_ready(
            &b,
            realtime,
            tracked_well,
            enough,
            NotAdjusted
        ));
        // Either way, a keyframe slipping away does not wait if it is not to be adjusted.
        let slipping = b.urgent_inlier_ratio - 0.05;
        for mode in [offline, realtime] {
            assert!(new_keyframe_ready(&b, mode, slipping, 0, NotAdjusted));
        }
    }

    #[test]
    fn real_time_adjustments_wait_for_the_views_offline_ones_get() {
        let mut kb = KeyframeBundleConfig::default();
        assert_eq!(adjustment_views_needed(&kb, false), kb.min_views);
        assert_eq!(adjustment_views_needed(&kb, true), 4);
        kb.realtime_min_views = 0; // never fewer than offline
        assert_eq!(adjustment_views_needed(&kb, true), kb.min_views);
        kb.min_views = 0;
        assert_eq!(adjustment_views_needed(&kb, false), 1);
    }

    #[test]
    fn with_late_adjustments_a_new_keyframe_waits_for_their_frames_unless_nearly_lost() {
        use AdjustmentViews::*;
        let b = BootstrapConfig::default();
        assert!(b.urgent_unadjusted_inlier_ratio < b.urgent_inlier_ratio);
        let slipping = 0.5 * (b.urgent_inlier_ratio + b.urgent_unadjusted_inlier_ratio);
        let nearly_lost = b.urgent_unadjusted_inlier_ratio - 0.05;
        // Real time, and offline with the adjustments emulated late (`lag_frames`).
        for late in [(true, true), (false, true)] {
            // Slipping, but installed now it would be installed unadjusted: it waits…
            assert!(!new_keyframe_ready(&b, late, slipping, 0, Awaited));
            // …unless the keyframe tracked is nearly lost…
            assert!(new_keyframe_ready(&b, late, nearly_lost, 0, Awaited));
            // …or it is not to be adjusted, or can be adjusted now.
            assert!(new_keyframe_ready(&b, late, slipping, 0, NotAdjusted));
            assert!(new_keyframe_ready(&b, late, slipping, 0, Enough));
        }
        // With adjustments at once (offline by default) the first sign of slipping installs.
        assert!(new_keyframe_ready(&b, (false, false), slipping, 0, Awaited));
    }
}
