//! The odometry's side of the refinement thread (`super::super::refinement_worker`): which take-off
//! passes and keyframe adjustments are sent and when, how their outcomes are applied (the frames
//! tracked meanwhile tracked again), and when one still out is given up.

use super::*;
use crate::runtime::catch_up::{CatchUpFrame, CatchUpStart, CaughtUp};
use crate::runtime::keyframe_bundle::evenly_spaced;
use crate::runtime::map_keyframe::build;
use crate::runtime::refinement_worker::KeyframeToAdjust;

/// Offline without a lag, frames tracked while an adjustment was out are all tracked again, up to
/// this many (the bound the catch-up always had).
const OFFLINE_MAX_CATCH_UP_FRAMES: usize = 30;

impl Odometry {
    /// Sends one refinement pass of the take-off whose first map `kf` (snapshot `s`) is ready to
    /// the refinement thread; it will re-pose and rescale the views and the first map is started
    /// again from them. Returns whether it was sent (the map is then not installed yet).
    pub(super) fn send_takeoff(&mut self, kf: &Keyframe, s: &MapSnapshot) -> bool {
        let b = &self.cfg.bootstrap;
        let Some(tk) = self.takeoff.as_ref().filter(|_| self.refiner.is_some()) else {
            return false;
        };
        // A further pass over more frames than a pass takes is not started: the first map has
        // waited long enough (in real time each pass is another ~0.7 s of dead reckoning).
        if tk.keyframe_id != s.keyframe_id
            || tk.passes >= b.refine_takeoff_passes
            || (tk.passes > 0 && tk.frames.len() > b.takeoff_max_pass_frames)
            || (tk.passes > 0 && tk.last_pass_lag_frames > b.takeoff_further_pass_max_lag_frames)
        {
            return false; // done
        }
        // A slow take-off waits longer for its baseline: its first pass re-poses an evenly spaced
        // subset of its frames (the IMU preintegrated across the others) and the first map is
        // triangulated again from those.
        let mut rec = tk.clone();
        rec.frames = evenly_spaced(&tk.frames, b.takeoff_max_pass_frames);
        let imu = imu_between(self.imu.make_contiguous(), tk.rest.nav.t, None);
        let velocity_std_m_s = if tk.in_flight {
            b.reinit_velocity_std_m_s
        } else {
            b.takeoff_velocity_std_m_s
        };
        self.refine_seq += 1;
        let job = RefineJob::Takeoff(Box::new(TakeoffJob {
            seq: self.refine_seq,
            rec,
            kf: kf.clone(),
            imu,
            rig: TakeoffRig {
                tracking: self.cfg.tracking.clone(),
                camera: self.rig.camera,
                t_body_cam: self.rig.t_body_cam,
                noise: self.imu_noise,
                prior: AlignmentPrior {
                    velocity_std_m_s,
                    accel_std_m_s2: b.takeoff_accel_std_m_s2,
                    position_std_m: b.takeoff_position_std_m,
                },
                max_scale_correction: b.takeoff_max_scale_correction,
                min_significance_sigmas: b.takeoff_min_significance_sigmas,
                imu_noise_factor: b.takeoff_imu_noise_factor,
            },
            bundle: (b.takeoff_refinement == TakeoffRefinement::BundleAdjustment).then(|| {
                BundleConfig {
                    iterations_per_level: b.takeoff_bundle_iterations,
                    start_velocity_std_m_s: velocity_std_m_s,
                    // In flight the velocity prior holds the scale only loosely (`super::takeoff`).
                    smoothness_scale_neutral: tk.in_flight,
                    accel_bias_std_m_s2: b.takeoff_accel_std_m_s2,
                    smoothness_rel_std: b.takeoff_bundle_smoothness_rel_std,
                    ..BundleConfig::default()
                }
            }),
        }));
        let kind = PendingKind::Takeoff {
            keyframe_id: s.keyframe_id,
            frames_sent: tk.frames.len(),
            snapshot: s.clone(),
        };
        self.send_refinement(job, kind).is_ok()
    }

    /// Hands the new keyframe of snapshot `s` to the in-flight keyframe adjustment with the
    /// frames tracked since it was started; the refinement thread builds it into the tracker's
    /// keyframe (posed in the tracker's world as it stands now) and it is installed for tracking
    /// when the adjustment is back. `false` if it was not sent (thread busy in real time).
    pub(super) fn send_keyframe_adjustment(&mut self, s: &MapSnapshot) -> bool {
        let Some(rec) = self.kf_record.take() else {
            return false;
        };
        let kf = KeyframeToAdjust::Mapped {
            snapshot: s.clone(),
            t_world_cam: self.mapper_from_world.inverse() * s.map.t_world_cam,
        };
        self.send_keyframe_job(rec, kf, s.clone(), false)
    }

    /// Hands keyframe `kf` (of snapshot `s`) with the views of `rec` to the
    /// keyframe adjustment: a new keyframe, or the `tracked` one installed with guessed depths
    /// (adjusted with its depths free). `false` if it was not sent (no views, or the thread busy
    /// in real time).
    fn send_keyframe_job(
        &mut self,
        rec: KeyframeRecord,
        kf: KeyframeToAdjust,
        s: MapSnapshot,
        tracked: bool,
    ) -> bool {
        let Some(tracked_last) = rec.views.last().map(|v| v.1) else {
            return false;
        };
        let (unadjusted, unadjusted_pose) = match &kf {
            KeyframeToAdjust::Built(k) => (Some(Box::new(k.clone())), k.t_world_cam),
            KeyframeToAdjust::Mapped { t_world_cam, .. } => (None, *t_world_cam),
        };
        // (From the previous keyframe when it joins the adjustment.)
        let t0 = rec
            .previous
            .as_ref()
            .map_or(rec.start.nav.t, |p| p.state.nav.t);
        let imu = imu_between(self.imu.make_contiguous(), t0, Some(tracked_last.nav.t));
        let chain_imu_gap_s = rec.previous.as_ref().map_or(f64::NAN, |p| {
            let first = p.frames.first().map_or(rec.start.nav.t, |(f, _)| f.t);
            first.secs_since(p.state.nav.t)
        });
        // A first map started in flight with guessed depths: its start velocity is the one
        // dead-reckoned through the loss.
        let reinit = tracked && self.reinit_kf.take_if(|id| *id == rec.id).is_some();
        // The frames of the wait tracked again on the refinement thread: from the last view,
        // with this frame's covariance; a new keyframe's brightness starts at zero, as its
        // installation sets it.
        let catch_up = (self.cfg.keyframe_bundle.catch_up_on_refinement_thread
            && self.adjustments_late())
        .then(|| CatchUpStart {
            covariance: *self.tracker.covariance(),
            brightness: if tracked {
                self.tracker.brightness()
            } else {
                (0.0, 0.0)
            },
            wait_for_end: !self.cfg.realtime,
        });
        let catching_up = catch_up.is_some();
        self.refine_seq += 1;
        let job = RefineJob::Keyframe(Box::new(KeyframeJob {
            seq: self.refine_seq,
            rec,
            kf,
            pyramid: s.keyframe_pyramid.clone(),
            imu,
            noise: self.imu_noise,
            // The pad's measurement of the gyro (1 before it), or the one read in flight.
            rotation_noise_scale: self.rotation_noise_scale,
            free_depths: tracked,
            start_velocity_std_m_s: reinit
                .then_some(self.cfg.bootstrap.reinit_velocity_free_std_m_s),
            catch_up,
        }));
        let kind = PendingKind::Keyframe {
            tracked_last,
            unadjusted,
            unadjusted_pose,
            snapshot: s,
            tracked,
            chain_imu_gap_s,
        };
        let sent = self.send_refinement(job, kind).is_ok();
        if sent
            && catching_up
            && let Some(refiner) = &self.refiner
        {
            refiner.open_catch_up(self.refine_seq);
            self.catch_up_imu_from = tracked_last.nav.t;
        }
        sent
    }

    /// Keeps the frame just tracked (at `t`) while a keyframe adjustment is under way, to be
    /// tracked again against the adjusted keyframe when it is back: handed to the refinement
    /// thread (`[keyframe_bundle] catch_up_on_refinement_thread`) and kept here for the frames
    /// it has not done by then (all of them, up to [`OFFLINE_MAX_CATCH_UP_FRAMES`]); otherwise
    /// the newest [`Self::catch_up_limit`] kept here.
    pub(super) fn keep_for_catch_up(&mut self, t: TimeNs, image: &Arc<Image<u8>>) {
        let Some(seq) = self
            .refining
            .as_ref()
            .filter(|p| matches!(p.kind, PendingKind::Keyframe { .. }))
            .map(|p| p.seq)
        else {
            return;
        };
        let handed_over = match &self.refiner {
            Some(r) if r.catching_up(seq) => {
                let frame = CatchUpFrame {
                    seq,
                    t,
                    image: image.clone(),
                    imu: imu_between(self.imu.make_contiguous(), self.catch_up_imu_from, Some(t)),
                    gyro_turn_rad: self.gyro_turn_rad(),
                };
                if r.catch_up_frame(frame) {
                    self.catch_up_imu_from = t;
                }
                true
            }
            _ => false,
        };
        let max = if handed_over {
            OFFLINE_MAX_CATCH_UP_FRAMES
        } else {
            self.catch_up_limit()
        };
        if max == 0 {
            return;
        }
        // The newest ones only.
        if self.catch_up.len() >= max {
            self.catch_up.remove(0);
        }
        self.catch_up.push((t, image.clone()));
    }

    /// Queues `job` (offline waiting for room, real time only if there is room) and awaits it.
    /// At most one job is out at a time (so neither queue can fill up and block): an earlier one
    /// still out is superseded — offline its outcome is awaited and dropped, in real time the new
    /// job is dropped while the thread is busy. Not sent: `kind` is handed back.
    fn send_refinement(
        &mut self,
        job: RefineJob,
        kind: PendingKind,
    ) -> Result<(), Box<PendingKind>> {
        let Some(refiner) = &self.refiner else {
            return Err(Box::new(kind));
        };
        while self.refine_outstanding > 0 && refiner.next_outcome(!self.cfg.realtime).is_some() {
            self.refine_outstanding -= 1;
        }
        let sent = self.refine_outstanding == 0
            && if self.cfg.realtime {
                refiner.try_send(job)
            } else {
                refiner.send(job)
            };
        if !sent {
            self.stats.refinements_dropped += 1;
            return Err(Box::new(kind));
        }
        let seq = self.refine_seq;
        self.refine_outstanding = 1;
        if self.refining.is_some() {
            self.stats.refinements_discarded += 1; // superseded before it came back
        }
        self.catch_up.clear();
        self.refining = Some(PendingRefinement {
            seq,
            frame_number: self.frame_number,
            kind,
        });
        Ok(())
    }

    /// Takes the awaited refinement's outcome a fixed number of frames after it was sent
    /// (`[keyframe_bundle] lag_frames`, `[bootstrap] takeoff_lag_frames`): offline waiting for it,
    /// in real time if it has arrived by then.
    pub(super) fn collect_refinement(&mut self) {
        let Some(refiner) = &self.refiner else {
            return;
        };
        let Some(p) = &self.refining else {
            // Real time: an outcome of a superseded job is taken off the queue.
            while self.refine_outstanding > 0 && self.cfg.realtime && refiner.try_recv().is_some() {
                self.refine_outstanding -= 1;
            }
            return;
        };
        let lag = match p.kind {
            PendingKind::Keyframe { .. } => self.cfg.keyframe_bundle.lag_frames,
            PendingKind::Takeoff { .. } => self.cfg.bootstrap.takeoff_lag_frames,
        };
        if self.frame_number < p.frame_number + lag {
            return; // not before its lag, however early it is ready
        }
        let want = p.seq;
        let mut outcome = None;
        while let Some(o) = refiner.next_outcome(!self.cfg.realtime) {
            self.refine_outstanding = self.refine_outstanding.saturating_sub(1);
            if o.seq == want {
                outcome = Some(o);
                break;
            }
            // (An older job's, superseded meanwhile: counted when it was.)
        }
        let Some(o) = outcome else {
            // Real time, not back yet: if the keyframe tracked meanwhile is being lost, the new
            // one is installed as the mapper built it (its adjustment is dropped).
            if self.phase == Phase::Tracking
                && gives_up_adjustment(self.last_inlier_ratio, &self.cfg.keyframe_bundle)
                && let Some(PendingRefinement {
                    kind:
                        PendingKind::Keyframe {
                            unadjusted,
                            unadjusted_pose,
                            snapshot,
                            tracked: false,
                            ..
                        },
                    ..
                }) = self
                    .refining
                    .take_if(|p| matches!(p.kind, PendingKind::Keyframe { .. }))
            {
                self.catch_up.clear();
                self.stats.refinements_discarded += 1;
                if self.pending_kf == Some(snapshot.keyframe_id) {
                    let kf = self.unadjusted_keyframe(unadjusted, unadjusted_pose, &snapshot);
                    self.install_keyframe(kf, &snapshot, true, false, false);
                }
            }
            return;
        };
        let Some(p) = self.refining.take() else {
            return;
        };
        let catch_up = std::mem::take(&mut self.catch_up);
        let frames_late = self.frame_number - p.frame_number;
        match (o.result, p.kind) {
            (
                RefineResult::Keyframe {
                    adjusted,
                    unadjusted: built,
                },
                PendingKind::Keyframe {
                    tracked_last,
                    unadjusted,
                    unadjusted_pose,
                    snapshot,
                    tracked,
                    chain_imu_gap_s,
                },
            ) => self.apply_keyframe_adjustment(
                adjusted,
                (
                    self.unadjusted_keyframe(unadjusted.or(built), unadjusted_pose, &snapshot),
                    &snapshot,
                    tracked,
                ),
                &tracked_last,
                &catch_up,
                (o.time_s, frames_late, chain_imu_gap_s),
            ),
            (
                RefineResult::Takeoff(refined),
                PendingKind::Takeoff {
                    keyframe_id,
                    frames_sent,
                    snapshot,
                },
            ) => self.apply_takeoff(
                refined,
                keyframe_id,
                frames_sent,
                &snapshot,
                (o.time_s, frames_late),
            ),
            _ => {} // (a job and its outcome are always of the same kind)
        }
    }

    /// The adjustment of the new keyframe of `snapshot` is back: the keyframe is installed (as
    /// the mapper built it if the adjustment failed) and tracking continues from the last view's
    /// adjusted state, the frames tracked since against the old keyframe (`catch_up`) tracked again
    /// against the new one (too many of them: the current state is moved by the last view's
    /// correction instead).
    fn apply_keyframe_adjustment(
        &mut self,
        adjusted: Option<ReadyKeyframe>,
        (unadjusted, snapshot, tracked): (Keyframe, &MapSnapshot, bool),
        tracked_last: &FrameState,
        catch_up: &[(TimeNs, Arc<Image<u8>>)],
        (time_s, frames_late, chain_imu_gap_s): (f64, u64, f64),
    ) {
        let id = snapshot.keyframe_id;
        let mut record = AdjustmentRecord {
            keyframe_t: unadjusted.t,
            taken_after_t: self.last_t.unwrap_or(unadjusted.t),
            frames_late,
            guessed: tracked,
            with_previous: false,
            chain_imu_gap_s: f64::NAN,
            velocity_change_m_s: f64::NAN,
            accel_bias_jump_m_s2: f64::NAN,
            depth_change: f64::NAN,
            time_s,
            outcome: AdjustmentOutcome::Discarded,
        };
        let current = if tracked {
            self.pending_kf.is_none() && self.tracking_kf == Some(id) && !self.reusing
        } else {
            self.pending_kf == Some(id)
        };
        if !(self.phase == Phase::Tracking && current) {
            self.stats.refinements_discarded += 1; // lost meanwhile
            self.stats.adjustments.push(record);
            return;
        }
        let mut adjusted = adjusted.filter(|a| {
            a.last_view.is_finite()
                && a.median_inv_depth_ratio.is_finite()
                && a.median_inv_depth_ratio > 0.0
        });
        if let Some(a) = &adjusted {
            record.with_previous = a.keyframe_state.is_some();
            if record.with_previous {
                record.chain_imu_gap_s = chain_imu_gap_s;
            }
            let dv_m_s = (a.last_view.nav.v_world_m_s - tracked_last.nav.v_world_m_s).norm();
            record.velocity_change_m_s = dv_m_s;
            record.accel_bias_jump_m_s2 =
                (a.last_view.bias.accel_m_s2 - self.tracker.state().bias.accel_m_s2).norm();
            record.depth_change = a.median_inv_depth_change;
            // (A keyframe tracked with guessed depths is rescaled by its adjustment, velocity
            // and all: not limited.)
            let max_m_s = self.cfg.keyframe_bundle.max_velocity_change_m_s;
            if !tracked && max_m_s > 0.0 && dv_m_s > max_m_s {
                record.outcome = AdjustmentOutcome::Rejected;
                adjusted = None;
            }
        } else {
            record.outcome = AdjustmentOutcome::Failed;
        }
        if adjusted.is_some() {
            record.outcome = AdjustmentOutcome::Applied;
        }
        self.stats.adjustments.push(record);
        let Some(a) = adjusted else {
            if !tracked {
                self.install_keyframe(unadjusted, snapshot, true, false, false);
            }
            return;
        };
        if tracked {
            // The whole keyframe was mapped at the scale of the guesses: the mapper's copy, the
            // installed map and the frames kept for the next keyframe are rescaled about its
            // camera with the adjustment's median change (the tracker continues from the last
            // view's adjusted state below).
            let factor = a.median_inv_depth_ratio;
            self.send_scale_depths(id, factor);
            self.rescale_history(unadjusted.t_world_cam.translation.vector, 1.0 / factor);
            let mut map = (*snapshot.map).clone();
            map.scale_inv_depths(factor);
            let snapshot = MapSnapshot {
                map: Arc::new(map),
                tracker_keyframe: None, // (of the map before)
                ..snapshot.clone()
            };
            self.install_keyframe(a.keyframe, &snapshot, false, false, true);
            self.tracking_kf_adjusted = true;
            self.stats.guessed_keyframe_scales.push(1.0 / factor);
        } else {
            let moved = a.keyframe_state;
            // The frames tracked since the keyframe's time (its views, and those of the wait
            // for its adjustment) stay in the chain of the next keyframe's adjustment with this
            // one (`previous_host`), moved by the last view's correction: installing the
            // keyframe clears them, and without them a late adjustment (real time) left that
            // chain to the IMU alone from the keyframe to the first frame after the install.
            let kept = self.chain_frames_since(a.keyframe.t, tracked_last, &a.last_view);
            self.install_keyframe(a.keyframe, snapshot, true, false, true);
            self.tracked_frames.extend(kept);
            if let Some(x) = moved {
                self.keyframe_moved(id, &x);
            }
        }
        // (Installing the keyframe leaves the tracker's state alone: the jump measured above.)
        let cov = *self.tracker.covariance();
        // The frames kept for the next keyframe that were tracked after the last view and are not
        // tracked again are moved by the last view's correction.
        let correction = pose_of(&a.last_view) * pose_of(tracked_last).inverse();
        let after_last_view = tracked_last.nav.t;
        let worker = &a.caught_up;
        if !worker.frames.is_empty() || self.catch_up_limit() > 0 || frames_late == 0 {
            // (`catch_up` holds the newest frames: the IMU spans any before them. Back in the
            // frame it was sent in, tracking goes on from the last view; after the frames the
            // refinement thread tracked again, from the newest of them.)
            let state_now = *self.tracker.state();
            let last_t = self.last_t;
            let mut poses = Vec::with_capacity(catch_up.len());
            let from = match worker.frames.last() {
                Some(newest) => {
                    self.tracker.reset_state(newest.state, worker.covariance);
                    self.tracker.set_brightness(worker.brightness);
                    self.take_caught_up(worker, catch_up, &mut poses);
                    newest.state.nav.t
                }
                None => {
                    self.tracker.reset_state(a.last_view, cov);
                    a.last_view.nav.t
                }
            };
            self.last_t = Some(from);
            let on_this_thread = catch_up.iter().filter(|(t, _)| *t > from);
            self.stats.catch_up_frames += on_this_thread.clone().count();
            self.stats.catch_up_frames_on_refinement_thread += worker.frames.len();
            for (t, image) in on_this_thread {
                self.track(*t, image);
                poses.push((*t, self.tracker.t_world_cam()));
                let (pose, x) = (self.tracker.t_world_cam(), *self.tracker.state());
                self.retracked_chain_frame(*t, pose, x, Some(image));
            }
            if self.tracker.state().is_finite() {
                // The frames kept for the next keyframe get their new poses.
                for h in self.history.iter_mut() {
                    if let Some((_, p)) = poses.iter().find(|(t, _)| *t == h.t) {
                        h.t_world_cam = *p;
                    } else if h.t > after_last_view {
                        h.t_world_cam = correction * h.t_world_cam;
                    }
                }
            } else {
                self.tracker.reset_state(state_now, cov);
                self.last_t = last_t;
            }
        } else {
            let x = carry_correction(self.tracker.state(), tracked_last, &a.last_view);
            if x.is_finite() {
                self.tracker.reset_state(x, cov);
                for h in self.history.iter_mut().filter(|h| h.t > after_last_view) {
                    h.t_world_cam = correction * h.t_world_cam;
                }
            }
        }
    }

    /// The frames of the wait the refinement thread tracked again against the adjusted keyframe
    /// (`worker`): their poses go to `poses` (for the frames kept for the next keyframe) and, with
    /// `previous_host`, their entries in the next keyframe's chain are replaced (the image from
    /// `catch_up`, which holds every frame handed over).
    fn take_caught_up(
        &mut self,
        worker: &CaughtUp,
        catch_up: &[(TimeNs, Arc<Image<u8>>)],
        poses: &mut Vec<(TimeNs, Isometry3<f64>)>,
    ) {
        for f in &worker.frames {
            poses.push((f.t, f.t_world_cam));
            let image = catch_up.iter().find(|(t, _)| *t == f.t).map(|(_, i)| i);
            self.retracked_chain_frame(f.t, f.t_world_cam, f.state, image);
        }
    }

    /// With `previous_host`, a frame of the next keyframe's chain tracked again (at `t`, to
    /// `t_world_cam` and state `x`): its first tracking is replaced, or — not kept — it is added
    /// (given its `image`).
    fn retracked_chain_frame(
        &mut self,
        t: TimeNs,
        t_world_cam: Isometry3<f64>,
        x: FrameState,
        image: Option<&Arc<Image<u8>>>,
    ) {
        if !self.cfg.keyframe_bundle.previous_host {
            return;
        }
        match self.tracked_frames.iter_mut().find(|(m, _)| m.t == t) {
            Some((m, kept)) => {
                m.t_world_cam = t_world_cam;
                *kept = x;
            }
            None => {
                if let Some(image) = image {
                    let frame = MapFrame {
                        t,
                        image: image.clone(),
                        t_world_cam,
                    };
                    self.tracked_frames.push_back((frame, x));
                }
            }
        }
    }

    /// The frames kept for `previous_host` tracked after `t`, moved as the current state is by
    /// the correction the adjustment made to its last view (tracked at `tracked`, adjusted to
    /// `adjusted`; [`carry_correction`]).
    fn chain_frames_since(
        &self,
        t: TimeNs,
        tracked: &FrameState,
        adjusted: &FrameState,
    ) -> Vec<(MapFrame, FrameState)> {
        let c = pose_of(adjusted) * pose_of(tracked).inverse();
        self.tracked_frames
            .iter()
            .filter(|(f, _)| f.t > t)
            .map(|(f, x)| {
                let f = MapFrame {
                    t_world_cam: c * f.t_world_cam,
                    ..f.clone()
                };
                (f, carry_correction(x, tracked, adjusted))
            })
            .collect()
    }

    /// How many of the frames tracked while an adjustment is under way are tracked again when it
    /// is back (the newest ones): `[keyframe_bundle] max_catch_up_frames` when adjustments come
    /// back late (real time, or offline with `lag_frames`, which emulates it); otherwise all (up
    /// to [`OFFLINE_MAX_CATCH_UP_FRAMES`]; offline there is at most one, when an adjustment was
    /// sent after the frame's tracking).
    pub(super) fn catch_up_limit(&self) -> usize {
        if self.adjustments_late() {
            self.cfg.keyframe_bundle.max_catch_up_frames
        } else {
            OFFLINE_MAX_CATCH_UP_FRAMES
        }
    }

    /// The keyframe of an adjustment's snapshot `s` as the mapper built it: `kf` (built by the
    /// tracking thread or the refinement thread), or — given up before the refinement thread
    /// handed it back — built here at `t_world_cam`.
    fn unadjusted_keyframe(
        &self,
        kf: Option<Box<Keyframe>>,
        t_world_cam: Isometry3<f64>,
        s: &MapSnapshot,
    ) -> Keyframe {
        match kf {
            Some(k) => *k,
            None => build(s, Vec::new(), t_world_cam, &self.rays, &self.cfg.tracking),
        }
    }

    /// Keyframe `id`, just installed, was moved by its adjustment to state `x`: the keyframe
    /// window holds it there, and the mapper's world is chained through its new pose (the frames
    /// tracked against it reach the mapper relative to the pose the mapper holds it at).
    fn keyframe_moved(&mut self, id: u32, x: &FrameState) {
        self.window.set_state(id, x);
        if let Some((kid, m_kf)) = self.mapper_kf_pose
            && kid == id
        {
            let new_pose = pose_of(x) * self.rig.t_body_cam;
            self.mapper_from_world = m_kf * new_pose.inverse();
        }
    }

    /// A take-off refinement pass is back: the first map is started again from the refined views
    /// (and the frames dead-reckoned since, re-predicted from the refined state); a failed pass
    /// installs the first map as it was.
    fn apply_takeoff(
        &mut self,
        refined: Option<RefinedTakeoff>,
        keyframe_id: u32,
        frames_sent: usize,
        snapshot: &MapSnapshot,
        (time_s, lag_frames): (f64, u64),
    ) {
        if self.phase != Phase::Initializing
            || self.takeoff.as_ref().map(|t| t.keyframe_id) != Some(keyframe_id)
        {
            self.stats.refinements_discarded += 1; // the first map was restarted meanwhile
            return;
        }
        let Some(r) = refined else {
            if let Some(tk) = self.takeoff.as_mut() {
                tk.passes = u32::MAX; // no further pass: install it now
            }
            self.apply_snapshot(snapshot.clone());
            return;
        };
        let Some(mut tk) = self.takeoff.take() else {
            return;
        };
        // The tracker continues from the refined state on the IMU until the new map is ready.
        let mut x = r.last;
        let pass_views = r.views.len();
        let mut views = r.views;
        for f in tk.frames.iter().skip(frames_sent) {
            x = self.dead_reckon(&x, f.t);
            views.push(MapFrame {
                t_world_cam: pose_of(&x) * self.rig.t_body_cam,
                ..f.clone()
            });
        }
        let t_now = self.tracker.state().nav.t;
        if x.nav.t < t_now {
            x = self.dead_reckon(&x, t_now);
        }
        let cov = *self.tracker.covariance();
        self.tracker.reset_state(x, cov);
        let mut x0 = r.rest;
        x0.nav.t = tk.keyframe.t;
        self.window.reset(self.next_kf_id, x0, &tk.rest_cov);
        tk.rest = r.rest;
        tk.keyframe_id = self.next_kf_id;
        tk.passes += 1;
        tk.last_pass_lag_frames = lag_frames;
        tk.frames = views.clone();
        self.start_keyframe(tk.keyframe.clone(), views, false);
        // The first map starts again: it gets the whole `max_init_s` to grow.
        self.init_started = self.last_t;
        self.stats.takeoff_scales.push(r.scale);
        self.stats.takeoff_refinement_s.push(time_s);
        self.stats.takeoff_pass_views.push(pass_views);
        self.stats.takeoff_pass_lag_frames.push(lag_frames);
        self.takeoff = Some(tk);
    }

    /// `x` predicted by the IMU to `t`, as the tracker does without a map.
    fn dead_reckon(&mut self, x: &FrameState, t: TimeNs) -> FrameState {
        let mut pre = Preintegration::new(x.nav.t, x.bias);
        pre.integrate(self.imu.make_contiguous(), t, None); // (the mean only)
        FrameState {
            nav: pre.predict(&x.nav, &x.bias),
            bias: x.bias,
        }
    }

    /// Hands the tracked keyframe installed with guessed depths (`guessed`) to the keyframe
    /// adjustment, depths free, once the mapper has built its map and the frames tracked since it
    /// was started span `[keyframe_bundle] guessed_min_baseline_ratio` × its median depth (at most
    /// `guessed_max_views` of them, evenly spaced). Those frames were tracked against guesses,
    /// and the map against them: the IMU between them is what gives the keyframe its scale.
    pub(super) fn adjust_guessed_keyframe(&mut self) {
        let Some(rec) = &self.guessed else { return };
        if self.tracking_kf != Some(rec.id) || self.reusing || self.phase != Phase::Tracking {
            self.guessed = None;
            self.guessed_snapshot = None;
            return;
        }
        let cfg = &self.cfg.keyframe_bundle;
        let Some(kf) = self.tracker.keyframe() else {
            return;
        };
        let span_m = rec
            .views
            .iter()
            .map(|(_, x)| (x.nav.p_world_m - rec.start.nav.p_world_m).norm())
            .fold(0.0, f64::max);
        if self.tracking_kf_filled
            || self.guessed_snapshot.is_none()
            || self.pending_kf.is_some()
            || self.refining.is_some()
            || rec.views.len() < cfg.min_views.max(1)
            || span_m < cfg.guessed_min_baseline_ratio * kf.median_depth_m
        {
            return;
        }
        let kf = kf.clone();
        let max_views = cfg.guessed_max_views.max(1);
        let (Some(mut rec), Some(s)) = (self.guessed.take(), self.guessed_snapshot.take()) else {
            return;
        };
        rec.views = evenly_spaced(&rec.views, max_views);
        // (Not sent — real time, thread busy: the keyframe stays as the mapper built it.)
        let _ = self.send_keyframe_job(rec, KeyframeToAdjust::Built(kf), s, true);
    }

    /// The tracked keyframe's adjustment with its depths free is under way (real time: it takes
    /// ~1 s) and the keyframe still tracks well: no new keyframe is started until it is back —
    /// one started now would be mapped at the scale the adjustment is about to correct, and the
    /// adjustment would be discarded as superseded. (Offline it is back before the next frame.)
    pub(super) fn awaiting_guessed_adjustment(&self) -> bool {
        self.last_inlier_ratio >= self.cfg.bootstrap.urgent_inlier_ratio
            && self
                .refining
                .as_ref()
                .is_some_and(|p| matches!(p.kind, PendingKind::Keyframe { tracked: true, .. }))
    }

    /// A take-off refinement pass is under way (of first map `id`, if given).
    pub(super) fn refining_takeoff(&self, id: Option<u32>) -> bool {
        self.refining.as_ref().is_some_and(|p| match p.kind {
            PendingKind::Takeoff { keyframe_id, .. } => id.is_none_or(|id| id == keyframe_id),
            PendingKind::Keyframe { .. } => false,
        })
    }

    /// The keyframe whose adjustment is under way, if any.
    pub(super) fn adjusting_keyframe(&self) -> Option<u32> {
        match &self.refining.as_ref()?.kind {
            PendingKind::Keyframe { snapshot, .. } => Some(snapshot.keyframe_id),
            PendingKind::Takeoff { .. } => None,
        }
    }
}

/// Real time: whether an adjustment not back yet is given up because the keyframe tracked
/// meanwhile keeps too few inliers (`[keyframe_bundle] give_up_inlier_ratio`). Giving up at the
/// first sign of slipping (it was `urgent_inlier_ratio`, 0.6) dropped the adjustment in the very
/// frame it was sent, and unadjusted maps then slipped sooner, one after the other.
fn gives_up_adjustment(inlier_ratio: f64, cfg: &KeyframeBundleConfig) -> bool {
    inlier_ratio < cfg.give_up_inlier_ratio
}

/// The samples of `imu` from before `t0` to after `t1` (all after `t0` if `None`), with one sample
/// of margin each side for the interpolation at the ends.
fn imu_between(imu: &[ImuSample], t0: TimeNs, t1: Option<TimeNs>) -> Vec<ImuSample> {
    let i0 = imu.partition_point(|s| s.t <= t0).saturating_sub(2);
    let i1 = t1.map_or(imu.len(), |t1| {
        (imu.partition_point(|s| s.t <= t1) + 2).min(imu.len())
    });
    imu[i0..i1.max(i0)].to_vec()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_adjustment_is_given_up_only_when_the_tracked_keyframe_is_being_lost() {
        let kb = KeyframeBundleConfig::default();
        let urgent = BootstrapConfig::default().urgent_inlier_ratio;
        assert!(kb.give_up_inlier_ratio < urgent);
        // Slipping (below the urgent ratio) is not enough: the adjustment is worth waiting for.
        assert!(!gives_up_adjustment(urgent - 0.05, &kb));
        assert!(!gives_up_adjustment(kb.give_up_inlier_ratio, &kb));
        assert!(gives_up_adjustment(kb.give_up_inlier_ratio - 0.01, &kb));
    }
}
