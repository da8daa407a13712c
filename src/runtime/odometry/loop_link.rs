//! The loop closer's part in the odometry's flow: every new keyframe and every map left handed to
//! [`LoopCloser`], and its correction applied to the published pose.
//!
//! Offline the loop closer runs inline, on the tracking thread, at the keyframe that feeds it (so
//! a replay is deterministic). In real time it runs on its own thread behind a bounded queue: a
//! job that does not fit is dropped, never waited for (a keyframe dropped joins the graph at the
//! next one by a looser edge), and its correction is taken when it arrives.

use super::Odometry;
use crate::camera::CameraModel;
use crate::geometry::se3;
use crate::image::Image;
use crate::loop_closure::closer::{LoopCloser, LoopClosureConfig, LoopClosureStats};
use crate::mapping::semidense::SemidenseMap;
use crate::tracking::Keyframe;
use crossbeam_channel::{Receiver, Sender, TrySendError, bounded};
use nalgebra::Isometry3;
use std::sync::Arc;

/// Jobs queued for the loop closer's thread.
const QUEUE_LEN: usize = 16;

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
    },
    Map {
        id: u32,
        map: Arc<SemidenseMap>,
    },
}

/// What the thread reports after each job.
struct LoopReport {
    correction: Isometry3<f64>,
    stats: LoopClosureStats,
}

fn run(closer: &mut LoopCloser, job: LoopJob) {
    match job {
        LoopJob::Keyframe {
            id,
            t_world_cam,
            host,
            image,
        } => {
            closer.add_keyframe(id, &t_world_cam, host, &image);
        }
        LoopJob::Map { id, map } => closer.attach_map(id, &map),
    }
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
    correction: Isometry3<f64>,
    stats: LoopClosureStats,
    /// Times the published pose's correction changed (a jump the flight controller must be told
    /// of: MAVLink `reset_counter`).
    pub(super) corrections: u32,
    /// Jobs dropped because the queue was full (real time).
    jobs_dropped: usize,
}

impl LoopLink {
    pub(super) fn new(cfg: &LoopClosureConfig, camera: CameraModel, realtime: bool) -> Self {
        let closer = LoopCloser::new(cfg.clone(), camera);
        let runner = if realtime {
            let (jobs, job_rx) = bounded::<LoopJob>(QUEUE_LEN);
            let (report_tx, reports) = bounded::<LoopReport>(QUEUE_LEN);
            let mut closer = closer;
            std::thread::Builder::new()
                .name("loop-closure".into())
                .spawn(move || {
                    for job in job_rx {
                        run(&mut closer, job);
                        let report = LoopReport {
                            correction: closer.correction(),
                            stats: closer.stats(),
                        };
                        // The odometry takes only the newest; a full queue drops this one.
                        let _ = report_tx.try_send(report);
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
            stats: LoopClosureStats::default(),
            corrections: 0,
            jobs_dropped: 0,
        }
    }

    fn submit(&mut self, job: LoopJob) {
        match &mut self.runner {
            Runner::Inline(closer) => {
                run(closer, job);
                let c = closer.correction();
                self.stats = closer.stats();
                self.take(c);
            }
            Runner::Thread { jobs, .. } => match jobs.try_send(job) {
                Ok(()) => {}
                Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                    self.jobs_dropped += 1
                }
            },
        }
    }

    /// A correction from the closer, taken if it is finite; counted as a jump if it moves the
    /// published pose by more than [`JUMP_M`] or [`JUMP_RAD`].
    fn take(&mut self, c: Isometry3<f64>) {
        if !se3::is_finite(&c) {
            return;
        }
        let d = self.correction.inverse() * c;
        if d.translation.vector.norm() > JUMP_M || d.rotation.angle() > JUMP_RAD {
            self.corrections += 1;
        }
        self.correction = c;
    }

    /// The newest correction of the odometry's world (reports of the thread taken in).
    pub(super) fn correction(&mut self) -> Isometry3<f64> {
        if let Runner::Thread { reports, .. } = &self.runner {
            let mut newest = None;
            while let Ok(r) = reports.try_recv() {
                newest = Some(r);
            }
            if let Some(r) = newest {
                self.stats = r.stats;
                self.take(r.correction);
            }
        }
        self.correction
    }

    /// The closer's counters with the odometry side's: jobs dropped and the published pose's jumps.
    pub(super) fn stats(&self) -> LoopClosureStats {
        LoopClosureStats {
            jobs_dropped: self.jobs_dropped,
            published_jumps: self.corrections,
            ..self.stats.clone()
        }
    }
}

impl Odometry {
    /// A new keyframe `id` at camera pose `t_world_cam` is installed, leaving `left` (tracked
    /// until now) with its final map `left_map` (`left_filled`: its depths were guessed, not
    /// measured — no map for the closer).
    pub(super) fn loop_keyframe(
        &mut self,
        id: u32,
        t_world_cam: Isometry3<f64>,
        image: &Arc<Image<u8>>,
        left: Option<&Keyframe>,
        left_map: Option<&Arc<SemidenseMap>>,
        left_filled: bool,
    ) {
        let Some(link) = &mut self.loop_closer else {
            return;
        };
        if let (Some(l), Some(m), false) = (left, left_map, left_filled) {
            link.submit(LoopJob::Map {
                id: l.id,
                map: m.clone(),
            });
        }
        link.submit(LoopJob::Keyframe {
            id,
            t_world_cam,
            host: left.map(|l| (l.id, l.t_world_cam)),
            image: image.clone(),
        });
    }
}
