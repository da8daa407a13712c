//! The loop closer's part in the odometry's flow: every new keyframe and every map left handed to
//! [`LoopCloser`], its correction applied to the published pose, and its per-keyframe
//! corrections handed to the returns to stored keyframes (`guide_returns`).
//!
//! Offline the loop closer runs inline, on the tracking thread, at the keyframe that feeds it (so
//! a replay is deterministic). In real time it runs on its own thread behind a bounded queue: a
//! job that does not fit is dropped, never waited for (a keyframe dropped joins the graph at the
//! next one by a looser edge), and its correction is taken when it arrives.

use super::Odometry;
use super::loop_hindsight::{HindsightCorrections, LoopWorld};
use super::loop_log::LoopRecord;
use crate::camera::CameraModel;
use crate::geometry::se3;
use crate::image::Image;
use crate::loop_closure::closer::{LoopCloser, LoopClosure, LoopClosureConfig, LoopClosureStats};
use crate::mapping::semidense::SemidenseMap;
use crate::runtime::true_view_poses::TrueCameraPoses;
use crate::time::TimeNs;
use crate::tracking::Keyframe;
use crossbeam_channel::{Receiver, Sender, TrySendError, bounded};
use nalgebra::{Isometry3, Point3, Vector3};
use std::collections::HashMap;
use std::sync::Arc;

/// Jobs queued for the loop closer's thread.
const QUEUE_LEN: usize = 16;

/// Host links followed at most to find the correction of a keyframe the closer has not taken in
/// yet ([`LoopLink::correction_for`]).
const MAX_HOST_STEPS: usize = 8;

/// A correction that moves the published pose by less than these (m, rad) is not a jump: a new
/// keyframe without a loop carries its host's correction, equal to it but for rounding.
const JUMP_M: f64 = 1e-4;
const JUMP_RAD: f64 = 1e-5;

enum LoopJob {
    Keyframe {
        id: u32,
        t_world_cam: Isometry3<f64>,
        host: Option<(u32, Isometry3<f64>)>,
        image: Arc<Image<u8>>,
        /// Its true camera pose (`--loop-edges gt`, a diagnostic).
        true_pose: Option<Isometry3<f64>>,
    },
    Map {
        id: u32,
        map: Arc<SemidenseMap>,
    },
    OdometryNoiseScale(f64),
    ScaleMap {
        id: u32,
        depth_factor: f64,
    },
    MoveKeyframes(Vec<(u32, Isometry3<f64>)>),
}

/// What the thread reports after each job.
struct LoopReport {
    correction: Isometry3<f64>,
    by_keyframe: HashMap<u32, Isometry3<f64>>,
    stats: LoopClosureStats,
    /// The loops closed since the last report (kept until a report carries them).
    closures: Vec<LoopClosure>,
}

fn run(closer: &mut LoopCloser, job: LoopJob) {
    match job {
        LoopJob::Keyframe {
            id,
            t_world_cam,
            host,
            image,
            true_pose,
        } => {
            if let Some(p) = true_pose {
                closer.set_true_pose(id, p);
            }
            closer.add_keyframe(id, &t_world_cam, host, &image);
        }
        LoopJob::Map { id, map } => closer.attach_map(id, &map),
        LoopJob::OdometryNoiseScale(s) => closer.set_odometry_noise_scale(s),
        LoopJob::ScaleMap { id, depth_factor } => closer.scale_map(id, depth_factor),
        LoopJob::MoveKeyframes(poses) => closer.move_keyframes(&poses),
    }
}

/// A keyframe as handed to the closer ([`LoopLink::started`]).
#[derive(Clone, Copy)]
struct Started {
    t: TimeNs,
    host: Option<u32>,
    t_world_cam: Isometry3<f64>,
}

enum Runner {
    Inline(Box<LoopCloser>),
    Thread {
        jobs: Sender<LoopJob>,
        reports: Receiver<LoopReport>,
    },
}

/// The odometry's handle on the loop closer.
pub(super) struct LoopLink {
    runner: Runner,
    /// The newest keyframe's correction.
    correction: Isometry3<f64>,
    /// Every keyframe's correction (`LoopCloser::corrections_into`).
    by_keyframe: HashMap<u32, Isometry3<f64>>,
    /// The correction last applied to the published pose.
    published: Isometry3<f64>,
    stats: LoopClosureStats,
    /// Times the published pose's correction changed.
    pub(super) corrections: u32,
    /// Of those, the jumps signalled to the flight controller (MAVLink `reset_counter`): the
    /// published pose moved beyond `reset_min_jump_m` / `_rad` from `signalled`.
    pub(super) resets: u32,
    /// The correction last signalled as a reset.
    signalled: Isometry3<f64>,
    /// `[loop_closure] reset_min_jump_m`, `reset_min_jump_rad`.
    reset_min_jump: (f64, f64),
    /// Sum and max of the jumps' size at the body, m, and the largest turn, rad.
    jump_m_sum: f64,
    jump_m_max: f64,
    jump_rad_max: f64,
    /// Jobs dropped because the queue was full (real time).
    jobs_dropped: usize,
    /// Returns to stored keyframes started from the graph's placement.
    pub(super) guided_returns: usize,
    /// Each keyframe handed to the closer: its time (for the loops' records), the keyframe it
    /// was started from (one the closer's thread has not taken in yet carries its host's
    /// correction, as the closer will give it) and its camera pose as handed over.
    started: HashMap<u32, Started>,
    /// Every loop closed, or held and dropped unconfirmed, in order (`OUT/loops.csv`).
    closures: Vec<LoopRecord>,
    /// The newest keyframe handed to the closer.
    newest: Option<u32>,
    /// Diagnostic (`--loop-edges gt`): the truth whose relative poses replace the measured loop
    /// edges ([`LoopCloser::set_true_pose`]); `None` in the product.
    truth: Option<Arc<TrueCameraPoses>>,
}

impl LoopLink {
    pub(super) fn new(
        cfg: &LoopClosureConfig,
        camera: CameraModel,
        realtime: bool,
        truth: Option<Arc<TrueCameraPoses>>,
    ) -> Self {
        let closer = LoopCloser::new(cfg.clone(), camera);
        let runner = if realtime {
            let (jobs, job_rx) = bounded::<LoopJob>(QUEUE_LEN);
            let (report_tx, reports) = bounded::<LoopReport>(QUEUE_LEN);
            let mut closer = closer;
            let nice = cfg.thread_nice;
            std::thread::Builder::new()
                .name("loop-closure".into())
                .spawn(move || {
                    crate::runtime::thread_priority::lower_current_thread(nice);
                    let mut closures = Vec::new();
                    for job in job_rx {
                        run(&mut closer, job);
                        let mut by_keyframe = HashMap::new();
                        closer.corrections_into(&mut by_keyframe);
                        closures.extend(closer.take_closures());
                        let report = LoopReport {
                            correction: closer.correction(),
                            by_keyframe,
                            stats: closer.stats(),
                            closures: std::mem::take(&mut closures),
                        };
                        // The odometry takes only the newest; a full queue drops this one (its
                        // loops go with the next).
                        if let Err(TrySendError::Full(r)) = report_tx.try_send(report) {
                            closures = r.closures;
                        }
                    }
                })
                .expect("spawning the loop-closure thread");
            Runner::Thread { jobs, reports }
        } else {
            Runner::Inline(Box::new(closer))
        };
        LoopLink {
            runner,
            correction: Isometry3::identity(),
            by_keyframe: HashMap::new(),
            published: Isometry3::identity(),
            stats: LoopClosureStats::default(),
            corrections: 0,
            resets: 0,
            signalled: Isometry3::identity(),
            reset_min_jump: (cfg.reset_min_jump_m, cfg.reset_min_jump_rad),
            jump_m_sum: 0.0,
            jump_m_max: 0.0,
            jump_rad_max: 0.0,
            jobs_dropped: 0,
            guided_returns: 0,
            started: HashMap::new(),
            closures: Vec::new(),
            newest: None,
            truth,
        }
    }

    /// Keyframe `id`'s map in the closer is scaled by `depth_factor` about its camera.
    pub(super) fn scale_map(&mut self, id: u32, depth_factor: f64) {
        self.submit(LoopJob::ScaleMap { id, depth_factor });
    }

    /// Keyframes moved by the keyframe window (`[loop_closure] follow_window_poses`): each
    /// `(id, t_world_cam)` moves in the graph with its correction kept.
    pub(super) fn move_keyframes(&mut self, poses: Vec<(u32, Isometry3<f64>)>) {
        for (id, t_world_cam) in &poses {
            if let Some(s) = self.started.get_mut(id) {
                s.t_world_cam = *t_world_cam;
            }
        }
        self.submit(LoopJob::MoveKeyframes(poses));
    }

    fn submit(&mut self, job: LoopJob) {
        match &mut self.runner {
            Runner::Inline(closer) => {
                run(closer, job);
                let c = closer.correction();
                closer.corrections_into(&mut self.by_keyframe);
                self.stats = closer.stats();
                let closures = closer.take_closures();
                self.take(c);
                self.record(&closures);
            }
            Runner::Thread { jobs, .. } => match jobs.try_send(job) {
                Ok(()) => {}
                Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                    self.jobs_dropped += 1
                }
            },
        }
    }

    /// The newest keyframe's correction from the closer, taken if it is finite.
    fn take(&mut self, c: Isometry3<f64>) {
        if se3::is_finite(&c) {
            self.correction = c;
        }
    }

    /// Takes in the thread's newest report (real time).
    fn receive(&mut self) {
        if let Runner::Thread { reports, .. } = &self.runner {
            let mut newest = None;
            let mut closures = Vec::new();
            while let Ok(mut r) = reports.try_recv() {
                closures.append(&mut r.closures);
                newest = Some(r);
            }
            self.record(&closures);
            if let Some(r) = newest {
                self.stats = r.stats;
                self.by_keyframe = r.by_keyframe;
                self.take(r.correction);
            }
        }
    }

    /// Keeps the loops closed with their keyframes' times.
    fn record(&mut self, closures: &[LoopClosure]) {
        let started = &self.started;
        self.closures.extend(closures.iter().filter_map(|c| {
            Some(LoopRecord {
                new_t: started.get(&c.new_id)?.t,
                old_t: started.get(&c.old_id)?.t,
                closure: *c,
            })
        }));
    }

    /// Every loop closed so far, in order (real time: those the closer's thread reported).
    pub(super) fn closures(&mut self) -> &[LoopRecord] {
        self.receive();
        &self.closures
    }

    /// Every keyframe the closer holds, by time: its camera pose as the graph now places it (its
    /// correction times its pose as handed over) — the trajectory of the keyframes in hindsight
    /// (real time: as of the closer's last report).
    pub(super) fn keyframe_poses(&mut self) -> Vec<(TimeNs, Isometry3<f64>)> {
        self.receive();
        let mut out: Vec<_> = (self.started.iter())
            .filter_map(|(id, s)| {
                let c = self.by_keyframe.get(id)?;
                let t_world_cam = c * s.t_world_cam;
                se3::is_finite(&t_world_cam).then_some((s.t, t_world_cam))
            })
            .collect();
        out.sort_by_key(|&(t, _)| t);
        out
    }

    /// The correction of the odometry's world while keyframe `tracked` is tracked: that
    /// keyframe's (after a return to a stored keyframe the odometry is in its world); for one the
    /// closer has not taken in yet (its thread lags in real time), that of the nearest keyframe
    /// up its chain of hosts the closer has — the correction the closer starts it with; else the
    /// newest keyframe's.
    pub(super) fn correction_for(&mut self, tracked: Option<u32>) -> Isometry3<f64> {
        self.receive();
        self.resolve(tracked)
    }

    /// [`Self::correction_for`] as of the closer's last report.
    fn resolve(&self, tracked: Option<u32>) -> Isometry3<f64> {
        let mut id = tracked;
        for _ in 0..=MAX_HOST_STEPS {
            let Some(k) = id else { break };
            if let Some(c) = self.by_keyframe.get(&k).filter(|c| se3::is_finite(c)) {
                return *c;
            }
            id = self.started.get(&k).and_then(|s| s.host);
        }
        self.correction
    }

    /// The world of a pose published with correction `c` while keyframe `tracked` is tracked
    /// (none tracked: the newest keyframe's, whose correction [`Self::correction_for`] gives).
    pub(super) fn world(&self, tracked: Option<u32>, c: Isometry3<f64>) -> LoopWorld {
        let keyframe = tracked.or(self.newest);
        LoopWorld {
            keyframe,
            correction: c,
            keyframe_pose: (keyframe.and_then(|k| self.started.get(&k))).map(|s| c * s.t_world_cam),
        }
    }

    /// Every keyframe's correction and pose as the graph gives them now, the end of a replay
    /// (real time: as of the closer's last report): the published poses in hindsight.
    pub(super) fn hindsight(&mut self) -> HindsightCorrections {
        self.receive();
        let first = (self.started.iter()).min_by_key(|(_, s)| s.t);
        HindsightCorrections {
            by_keyframe: (self.started.iter())
                .map(|(&id, s)| {
                    let c = self.resolve(Some(id));
                    (id, (c, c * s.t_world_cam))
                })
                .collect(),
            first: first.map_or(self.correction, |(&id, _)| self.resolve(Some(id))),
            newest: self.correction,
        }
    }

    /// The correction applied to the published pose while keyframe `tracked` is tracked
    /// ([`Self::correction_for`]); counted as a jump if it moves the published pose by more than
    /// [`JUMP_M`] or [`JUMP_RAD`] from the last one applied, and the jump measured where the
    /// body is (`p_world_m`, the odometry's position the correction applies to); a reset for the
    /// flight controller once it has moved the pose beyond `reset_min_jump_m` / `_rad` from the
    /// correction last signalled.
    pub(super) fn publish(
        &mut self,
        tracked: Option<u32>,
        p_world_m: &Vector3<f64>,
    ) -> Isometry3<f64> {
        let c = self.correction_for(tracked);
        let d = self.published.inverse() * c;
        if d.translation.vector.norm() > JUMP_M || d.rotation.angle() > JUMP_RAD {
            self.corrections += 1;
            let p = Point3::from(*p_world_m);
            let cp = c * p;
            let jump_m = (cp - self.published * p).norm();
            if jump_m.is_finite() {
                self.jump_m_sum += jump_m;
                self.jump_m_max = self.jump_m_max.max(jump_m);
            }
            self.jump_rad_max = self.jump_rad_max.max(d.rotation.angle());
            let (min_m, min_rad) = self.reset_min_jump;
            let since = self.signalled.inverse() * c;
            let moved_m = (cp - self.signalled * p).norm();
            if !(moved_m <= min_m && since.rotation.angle() <= min_rad) {
                self.resets += 1;
                self.signalled = c;
            }
        }
        self.published = c;
        c
    }

    /// The change of world that takes a pose of the odometry whose correction is `now`
    /// ([`Self::correction_for`] the keyframe tracked) into stored keyframe `stored`'s world as
    /// the graph places the two: `C_stored⁻¹ · C_now`. The identity for a keyframe the closer
    /// does not know (the odometry's own relation is all there is).
    pub(super) fn world_change(&self, stored: u32, now: &Isometry3<f64>) -> Isometry3<f64> {
        match self.by_keyframe.get(&stored).filter(|c| se3::is_finite(c)) {
            Some(c) => c.inverse() * now,
            None => Isometry3::identity(),
        }
    }

    /// The closer's counters with the odometry side's: jobs dropped and the published pose's jumps.
    pub(super) fn stats(&self) -> LoopClosureStats {
        LoopClosureStats {
            jobs_dropped: self.jobs_dropped,
            published_jumps: self.corrections,
            published_jump_m_mean: self.jump_m_sum / f64::from(self.corrections.max(1)),
            published_jump_m_max: self.jump_m_max,
            published_jump_rad_max: self.jump_rad_max,
            reset_jumps: self.resets,
            guided_returns: self.guided_returns,
            ..self.stats.clone()
        }
    }
}

impl Odometry {
    /// The gyro's noise measured on the pad (`rotation_noise_scale`, at least 1) scales the loop
    /// closer's odometry edges from now on (`odometry_std_from_rest`).
    pub(super) fn loop_odometry_noise_scale(&mut self, rotation_noise_scale: f64) {
        if let Some(link) = &mut self.loop_closer
            && self.cfg.loop_closure.odometry_std_from_rest
        {
            link.submit(LoopJob::OdometryNoiseScale(rotation_noise_scale));
        }
    }

    /// A new keyframe `id` of time `t` at camera pose `t_world_cam` is installed, leaving `left`
    /// (tracked until now) with its final map `left_map` (`None` if its depths were guessed, not
    /// measured: no map for the closer).
    pub(super) fn loop_keyframe(
        &mut self,
        id: u32,
        t: TimeNs,
        t_world_cam: Isometry3<f64>,
        image: &Arc<Image<u8>>,
        left: Option<&Keyframe>,
        left_map: Option<&Arc<SemidenseMap>>,
    ) {
        let Some(link) = &mut self.loop_closer else {
            return;
        };
        if let (Some(l), Some(m)) = (left, left_map) {
            link.submit(LoopJob::Map {
                id: l.id,
                map: m.clone(),
            });
        }
        // As many as the closer keeps at most.
        if link.started.len() < self.cfg.loop_closure.max_keyframes {
            let host = left.map(|l| l.id);
            link.started.insert(
                id,
                Started {
                    t,
                    host,
                    t_world_cam,
                },
            );
        }
        link.newest = Some(id);
        link.submit(LoopJob::Keyframe {
            id,
            t_world_cam,
            host: left.map(|l| (l.id, l.t_world_cam)),
            image: image.clone(),
            true_pose: link.truth.as_ref().and_then(|tr| tr.camera_at(t)),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn yawed(yaw_rad: f64, x_m: f64) -> Isometry3<f64> {
        Isometry3::new(Vector3::new(x_m, 0.3, 0.0), Vector3::z() * yaw_rad)
    }

    fn close(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
        (a.to_homogeneous() - b.to_homogeneous()).norm() < 1e-12
    }

    /// The published pose takes the correction of the keyframe it was tracked against (after a
    /// return, the stored keyframe's world), and a pose moves between two keyframes' worlds so
    /// that the graph places it the same from either.
    #[test]
    fn corrections_follow_the_keyframe_tracked_and_change_worlds_consistently() {
        let cfg = LoopClosureConfig::default();
        let mut link = LoopLink::new(&cfg, CameraModel::euroc_cam0(), false, None);
        let (c1, c2) = (yawed(0.1, 0.5), yawed(-0.05, 0.2));
        link.by_keyframe.insert(1, c1);
        link.by_keyframe.insert(2, c2);
        let mut nan = c1;
        nan.translation.vector.x = f64::NAN;
        link.by_keyframe.insert(3, nan);
        link.correction = c2;
        assert!(close(&link.correction_for(Some(1)), &c1));
        // Unknown, not finite or none: the newest keyframe's.
        for id in [Some(9), Some(3), None] {
            assert!(close(&link.correction_for(id), &c2));
        }
        // A pose of keyframe 2's world, moved into keyframe 1's, is placed where it was.
        let p = yawed(0.3, 1.0);
        let now = link.correction_for(Some(2));
        let change = link.world_change(1, &now);
        assert!(close(&(c1 * (change * p)), &(c2 * p)));
        assert!(close(&link.world_change(2, &now), &Isometry3::identity()));
        assert_eq!(link.world_change(9, &now), Isometry3::identity());
        assert_eq!(link.world_change(3, &now), Isometry3::identity());
        // Each change of the published correction is one jump; the same one again is none. The
        // jumps are measured where the body is: identity → c2, c2 → c1, c1 → c2.
        let body = Vector3::new(2.0, 1.0, 0.5);
        assert!(close(&link.publish(Some(2), &body), &c2));
        link.publish(Some(2), &body);
        assert_eq!(link.corrections, 1);
        link.publish(Some(1), &body);
        link.publish(Some(2), &body);
        assert_eq!(link.corrections, 3);
        let stats = link.stats();
        assert_eq!(stats.published_jumps, 3);
        assert_eq!(stats.reset_jumps, 3, "each beyond the default 5 cm");
        let b = nalgebra::Point3::from(body);
        let first_m = (c2 * b - b).norm();
        let switch_m = (c1 * b - c2 * b).norm();
        assert!((stats.published_jump_m_mean - (first_m + 2.0 * switch_m) / 3.0).abs() < 1e-12);
        assert!((stats.published_jump_m_max - first_m.max(switch_m)).abs() < 1e-12);
        assert!((stats.published_jump_rad_max - 0.15).abs() < 1e-12);
    }

    /// A keyframe the closer has not taken in yet (its thread lags) is corrected as its nearest
    /// known host is, not as the newest keyframe: after a return to a stored keyframe the two are
    /// in different worlds.
    #[test]
    fn a_keyframe_not_yet_in_the_graph_takes_its_hosts_correction() {
        let cfg = LoopClosureConfig::default();
        let mut link = LoopLink::new(&cfg, CameraModel::euroc_cam0(), false, None);
        let (stored, newest) = (yawed(0.2, -0.6), yawed(-0.05, 0.2));
        link.by_keyframe.insert(3, stored);
        link.by_keyframe.insert(40, newest);
        link.correction = newest;
        let from = |host| Started {
            t: TimeNs(0),
            host,
            t_world_cam: Isometry3::identity(),
        };
        // 41 was started from stored keyframe 3 (a return), 42 from 41: neither in the graph yet.
        link.started.insert(41, from(Some(3)));
        link.started.insert(42, from(Some(41)));
        assert!(close(&link.correction_for(Some(42)), &stored));
        assert!(close(&link.correction_for(Some(41)), &stored));
        // A chain longer than MAX_HOST_STEPS, or one that ends unknown: the newest keyframe's.
        let m = MAX_HOST_STEPS as u32;
        for k in 100..100 + m {
            link.started.insert(k + 1, from(Some(k)));
        }
        link.started.insert(100, from(Some(3)));
        // 100 + m - 1 is m links from 3, 100 + m one more.
        assert!(close(&link.correction_for(Some(100 + m - 1)), &stored));
        assert!(close(&link.correction_for(Some(100 + m)), &newest));
        link.started.insert(50, from(Some(49)));
        assert!(close(&link.correction_for(Some(50)), &newest));
        // Once the closer has taken a keyframe in, its own correction counts, not its host's.
        let own = yawed(0.1, 0.4);
        link.by_keyframe.insert(41, own);
        assert!(close(&link.correction_for(Some(41)), &own));
        assert!(close(&link.correction_for(Some(42)), &own));
    }

    /// The keyframes in hindsight: each keyframe's pose as handed over, moved by its correction,
    /// in time order; one the closer has given no correction yet is left out.
    #[test]
    fn the_keyframes_in_hindsight_are_their_poses_moved_by_their_corrections() {
        let cfg = LoopClosureConfig::default();
        let mut link = LoopLink::new(&cfg, CameraModel::euroc_cam0(), false, None);
        let handed = [
            (7, 30, yawed(0.1, 1.0)),
            (5, 10, yawed(0.0, 0.0)),
            (6, 20, yawed(0.05, 0.5)),
        ];
        for &(id, t_ns, t_world_cam) in &handed {
            let started = Started {
                t: TimeNs(t_ns),
                host: None,
                t_world_cam,
            };
            link.started.insert(id, started);
        }
        let c = yawed(0.02, 0.1);
        link.by_keyframe.insert(5, Isometry3::identity());
        link.by_keyframe.insert(7, c);
        let poses = link.keyframe_poses();
        assert_eq!(poses.len(), 2);
        assert_eq!((poses[0].0, poses[1].0), (TimeNs(10), TimeNs(30)));
        assert!(close(&poses[0].1, &handed[1].2));
        assert!(close(&poses[1].1, &(c * handed[0].2)));
    }

    /// Jumps of the published pose are signalled as resets only once the pose has moved beyond
    /// the threshold from the correction last signalled: small steps add up to one reset.
    #[test]
    fn small_jumps_add_up_to_a_reset_beyond_the_threshold() {
        let cfg = LoopClosureConfig {
            reset_min_jump_m: 0.05,
            reset_min_jump_rad: 0.035,
            ..LoopClosureConfig::default()
        };
        let mut link = LoopLink::new(&cfg, CameraModel::euroc_cam0(), false, None);
        let body = Vector3::new(1.0, 2.0, 1.0);
        let step = |x_m: f64| Isometry3::new(Vector3::new(x_m, 0.0, 0.0), Vector3::zeros());
        // 2 cm at a time: unsignalled at 2 and 4 cm, a reset at 6 cm, then again from there.
        for (k, x_m) in [0.02, 0.04, 0.06, 0.08, 0.10, 0.12].iter().enumerate() {
            link.correction = step(*x_m);
            link.publish(None, &body);
            let want = match k {
                0 | 1 => 0,
                2..=4 => 1,
                _ => 2,
            };
            assert_eq!(link.resets, want, "after {x_m} m");
        }
        assert_eq!(link.corrections, 6);
        // A turn alone: 0.03 rad about the vertical is below 0.035 rad but moves a body 2.2 m
        // from the origin by 7 cm: a reset.
        link.correction = link.signalled * Isometry3::new(Vector3::zeros(), Vector3::z() * 0.03);
        link.publish(None, &body);
        assert_eq!(link.resets, 3);
        assert_eq!(link.stats().reset_jumps, 3);
    }
}
