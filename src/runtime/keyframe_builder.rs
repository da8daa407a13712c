//! The thread that builds a turn on the spot's keyframe ([`super::guessed_keyframe`]) while the
//! tracking thread waits for the next frame.
//!
//! The keyframe is decided at the end of a tracked frame and installed at the start of the next
//! one, before anything else of that frame: exactly where the tracking thread used to finish
//! building it, so a replay is the same either way — but its 4–12 ms (moving the tracked map's
//! points, selecting the depthless pixels, sampling the keyframe's levels) fall in the idle time
//! between frames (50 ms at 20 Hz) instead of inside one frame: they were most of the slowest 1 %
//! of the tracking thread's frames on the demo in real time.
//!
//! The frame's pyramid changes hands without a copy ([`crate::tracking::Tracker::swap_frame_pyramid`]):
//! the tracker loads its next frame into a spare buffer, which this thread allocates (and writes
//! once, so that its pages are mapped here) for the keyframe after. At most one build is under way.

use super::guessed_keyframe::{GuessSettings, GuessedKeyframeJob, build_guessed_keyframe};
use super::mapping_worker::MapSnapshot;
use crate::image::{Image, Pyramid};
use crate::tracking::Keyframe;
use crossbeam_channel::{Receiver, Sender, bounded};
use std::thread::JoinHandle;
use std::time::Instant;

/// A build's outcome.
pub struct BuiltKeyframe {
    /// The job's keyframe id.
    pub id: u32,
    /// The keyframe and the snapshot to install it by; `None` if it had too few points.
    pub built: Option<(Keyframe, MapSnapshot)>,
    /// A pyramid buffer of the frame's size for the tracker to swap in at the next build.
    pub spare: Pyramid,
    /// Wall time of the build on this thread, s.
    pub time_s: f64,
}

/// Handle of the running builder thread.
pub struct KeyframeBuilder {
    jobs: Option<Sender<GuessedKeyframeJob>>,
    built: Receiver<BuiltKeyframe>,
    /// Id of the build under way (sent, not yet taken).
    outstanding: Option<u32>,
    join: Option<JoinHandle<()>>,
}

impl KeyframeBuilder {
    /// Starts the thread.
    pub fn spawn(settings: GuessSettings) -> Self {
        let (jtx, jrx) = bounded::<GuessedKeyframeJob>(1);
        let (btx, brx) = bounded::<BuiltKeyframe>(1);
        let join = std::thread::Builder::new()
            .name("vidslam-kf-build".into())
            .spawn(move || run(&settings, jrx, btx))
            .expect("spawn the keyframe builder thread");
        KeyframeBuilder {
            jobs: Some(jtx),
            built: brx,
            outstanding: None,
            join: Some(join),
        }
    }

    /// Starts building `job`; gives it back if a build is under way or the thread is gone.
    pub fn start(&mut self, job: GuessedKeyframeJob) -> Result<(), Box<GuessedKeyframeJob>> {
        let Some(jobs) = self.jobs.as_ref().filter(|_| self.outstanding.is_none()) else {
            return Err(Box::new(job));
        };
        let id = job.id;
        jobs.try_send(job).map_err(|e| Box::new(e.into_inner()))?;
        self.outstanding = Some(id);
        Ok(())
    }

    /// Id of the build under way, if any.
    pub fn outstanding(&self) -> Option<u32> {
        self.outstanding
    }

    /// Waits for the build under way (`None` if there is none, or the thread is gone).
    pub fn wait(&mut self) -> Option<BuiltKeyframe> {
        self.outstanding.take()?;
        self.built.recv().ok()
    }
}

impl Drop for KeyframeBuilder {
    fn drop(&mut self) {
        // Closing the queue ends the thread after its job; its result never blocks (one build
        // at a time, one result's room).
        self.jobs = None;
        if let Some(j) = self.join.take() {
            let _ = j.join();
        }
    }
}

fn run(settings: &GuessSettings, jobs: Receiver<GuessedKeyframeJob>, out: Sender<BuiltKeyframe>) {
    while let Ok(job) = jobs.recv() {
        let started = Instant::now();
        let (w, h, levels) = {
            let l0 = job.pyramid.level(0);
            (l0.width(), l0.height(), job.pyramid.num_levels())
        };
        let id = job.id;
        let built = build_guessed_keyframe(job, settings);
        // Filled once so that its pages are mapped on this thread, not the tracker's.
        let spare = Pyramid::from_u8(&Image::new(w, h), levels);
        let r = BuiltKeyframe {
            id,
            built,
            spare,
            time_s: started.elapsed().as_secs_f64(),
        };
        if out.send(r).is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraModel;
    use crate::runtime::guessed_keyframe::{test_settings, turned_job};

    /// The thread builds exactly the keyframe built inline, one at a time, and hands back a
    /// buffer of the frame's size; dropped with a build under way, it ends.
    #[test]
    fn a_keyframe_built_on_the_thread_is_the_one_built_inline() {
        let cam = CameraModel::euroc_cam0();
        let s = test_settings(&cam);
        let (inline_kf, inline_snap) =
            build_guessed_keyframe(turned_job(&cam, 7), &s).expect("enough points");
        let mut b = KeyframeBuilder::spawn(s);
        assert!(b.wait().is_none(), "nothing under way");
        assert!(b.start(turned_job(&cam, 7)).is_ok());
        assert_eq!(b.outstanding(), Some(7));
        let refused = b
            .start(turned_job(&cam, 8))
            .expect_err("one build at a time");
        assert_eq!(refused.id, 8, "the job refused is given back");
        let done = b.wait().expect("built");
        assert_eq!(b.outstanding(), None);
        assert_eq!(done.id, 7);
        assert!(done.time_s > 0.0);
        let (kf, snap) = done.built.expect("enough points");
        assert_eq!(kf.t_world_cam, inline_kf.t_world_cam);
        assert_eq!(kf.levels, inline_kf.levels);
        assert_eq!(snap.map.points, inline_snap.map.points);
        let spare = &done.spare;
        assert_eq!(
            spare.num_levels(),
            inline_snap.keyframe_pyramid.num_levels()
        );
        assert_eq!(
            (spare.level(0).width(), spare.level(0).height()),
            (cam.width, cam.height)
        );
        assert!(
            b.start(turned_job(&cam, 9)).is_ok(),
            "the next build once this one is taken"
        );
    }
}
