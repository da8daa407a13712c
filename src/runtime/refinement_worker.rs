//! The thread of the two slow refinements the odometry makes of its own output: the take-off
//! refinement of the first map ([`super::takeoff`], ~1 s a pass) and the in-flight keyframe
//! adjustment ([`super::keyframe_bundle`], 200–400 ms a keyframe). Neither may hold up the
//! odometry thread at frame rate.
//!
//! The odometry hands a job over and goes on: in flight it keeps tracking the previous keyframe, at
//! take-off it keeps dead-reckoning. When the outcome comes back it installs the adjusted keyframe
//! (or starts the first map again from the refined take-off) and brings the frames processed
//! meanwhile onto it. Like the mapper, the thread is
//! joined by bounded crossbeam channels: in real time a job is dropped when the thread is still
//! busy with another and outcomes are drained with `try_recv`; offline the odometry waits for each
//! outcome at a fixed frame lag, which keeps a replay deterministic.

use super::catch_up::{
    CatchUpFrame, CatchUpMessage, CatchUpStart, CaughtUp, catch_up, skip_frames,
};
use super::keyframe_bundle::{KeyframeBundleConfig, KeyframeRecord, bundle_adjust_keyframe};
use super::map_keyframe::keyframe_of;
use super::mapping_worker::MapSnapshot;
use super::takeoff::{
    RefinedTakeoff, TakeoffRecord, TakeoffRig, bundle_adjust_takeoff, refine_takeoff,
};
use crate::camera::{CameraModel, PixelRays};
use crate::image::Pyramid;
use crate::imu::{FrameState, ImuNoise, ImuSample, Matrix15};
use crate::smoother::photometric_bundle::BundleConfig;
use crate::tracking::{Keyframe, Tracker, TrackerConfig};
use crossbeam_channel::{Receiver, Sender, TrySendError, bounded};
use nalgebra::Isometry3;
use std::cell::Cell;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

/// Work for the refinement thread.
pub enum RefineJob {
    Keyframe(Box<KeyframeJob>),
    Takeoff(Box<TakeoffJob>),
}

impl RefineJob {
    fn seq(&self) -> u64 {
        match self {
            RefineJob::Keyframe(j) => j.seq,
            RefineJob::Takeoff(j) => j.seq,
        }
    }
}

/// The in-flight adjustment of one keyframe.
pub struct KeyframeJob {
    pub seq: u64,
    /// The keyframe's record: its state at the start and the views tracked since.
    pub rec: KeyframeRecord,
    /// The keyframe (the mapper's depths): built, or to be built on this thread.
    pub kf: KeyframeToAdjust,
    /// Its image pyramid.
    pub pyramid: Arc<Pyramid>,
    /// IMU samples from before the keyframe to after its last view.
    pub imu: Vec<ImuSample>,
    /// The IMU noise to integrate them with (the odometry's, which the pad's measurement may
    /// have replaced since the thread started).
    pub noise: ImuNoise,
    /// `[keyframe_bundle] imu_rotation_noise_factor` is multiplied by this (the pad's measurement
    /// of the gyro, `[bootstrap] rest_gyro_rotation_noise`).
    pub rotation_noise_scale: f64,
    /// The depths are not held to the mapper's (`depth_rel_std` not applied): their scale is what
    /// is in doubt (a keyframe tracked with guessed depths).
    pub free_depths: bool,
    /// Prior standard deviation of the keyframe's velocity instead of `[keyframe_bundle]
    /// velocity_std_m_s`, m/s, with the smoothness prior made scale-neutral: a first map started
    /// in flight, whose start velocity is only dead-reckoned (`None`: the keyframe window's).
    pub start_velocity_std_m_s: Option<f64>,
    /// `Some`: after the adjustment, the frames the odometry hands over meanwhile
    /// ([`RefinementThread::catch_up_frame`]) are tracked again against the adjusted keyframe
    /// here ([`super::catch_up`]).
    pub catch_up: Option<CatchUpStart>,
}

/// The keyframe of an adjustment: built by the odometry (a keyframe it tracks), or the mapper's
/// new map, built here into the tracker's keyframe at the pose given (the tracker's world): a
/// build is 4-8 ms that the tracking thread then does not spend in a frame.
pub enum KeyframeToAdjust {
    Built(Keyframe),
    Mapped {
        snapshot: MapSnapshot,
        t_world_cam: Isometry3<f64>,
    },
}

/// One refinement pass of the take-off.
pub struct TakeoffJob {
    pub seq: u64,
    /// The take-off: rest state, first keyframe, frames since.
    pub rec: TakeoffRecord,
    /// The first map, ready to be tracked.
    pub kf: Keyframe,
    /// IMU samples from before the rest state to after the last frame.
    pub imu: Vec<ImuSample>,
    pub rig: TakeoffRig,
    /// `Some`: the photometric–inertial bundle adjustment with these settings; `None`: tracking
    /// again and aligning the scale.
    pub bundle: Option<BundleConfig>,
}

/// The outcome of a [`RefineJob`], with its `seq` and wall time.
pub struct RefineOutcome {
    pub seq: u64,
    pub time_s: f64,
    pub result: RefineResult,
}

pub enum RefineResult {
    /// The keyframe rebuilt with the adjusted depths (`adjusted`, `None` if it was not adjusted:
    /// too few views, an unsound solution), and the keyframe of the mapper's depths if it was
    /// built here ([`KeyframeToAdjust::Mapped`]).
    Keyframe {
        adjusted: Option<ReadyKeyframe>,
        unadjusted: Option<Box<Keyframe>>,
    },
    /// The refined take-off, `None` if the pass failed (the first map is then installed as is).
    Takeoff(Option<RefinedTakeoff>),
}

/// An adjusted keyframe ready to be tracked against.
pub struct ReadyKeyframe {
    pub keyframe: Keyframe,
    /// Adjusted state of the last view.
    pub last_view: FrameState,
    /// The keyframe's adjusted state when its pose was free (`[keyframe_bundle] previous_host`);
    /// `keyframe` is posed there.
    pub keyframe_state: Option<FrameState>,
    /// Median relative change of the inverse depths.
    pub median_inv_depth_change: f64,
    /// Median of adjusted / given inverse depth.
    pub median_inv_depth_ratio: f64,
    /// The frames handed over while it was under way, tracked again against it from
    /// `last_view` ([`KeyframeJob::catch_up`]; none without).
    pub caught_up: Box<CaughtUp>,
}

/// The fixed inputs of every job.
#[derive(Clone, Debug)]
pub struct RefineSettings {
    pub camera: CameraModel,
    pub t_body_cam: Isometry3<f64>,
    pub tracking: TrackerConfig,
    pub keyframe_bundle: KeyframeBundleConfig,
    /// The camera's pixel rays (keyframes built by lookup).
    pub rays: Arc<PixelRays>,
    /// The thread's nice value is raised by this much ([`super::thread_priority`]).
    pub nice_increment: i32,
    /// The IMU noise of the tracking thread's tracker (its bias random walks), for the
    /// catch-up's tracker.
    pub tracker_noise: ImuNoise,
}

/// Frames of the wait the odometry may hand over before the thread reads them (offline one
/// adjustment's lag; a frame that does not fit is tracked again on the tracking thread).
const CATCH_UP_QUEUE_LEN: usize = 256;

/// Handle of a running refinement thread.
pub struct RefinementThread {
    jobs: Sender<RefineJob>,
    outcomes: Receiver<RefineOutcome>,
    catch_up: Sender<CatchUpMessage>,
    /// The adjustment whose frames are being handed over, until its end marker is sent.
    catch_up_open: Cell<Option<u64>>,
    join: JoinHandle<()>,
}

impl RefinementThread {
    /// Starts the thread. It works on one job and holds one more.
    pub fn spawn(settings: RefineSettings) -> Self {
        let (jtx, jrx) = bounded::<RefineJob>(1);
        let (otx, orx) = bounded::<RefineOutcome>(2);
        let (ctx, crx) = bounded::<CatchUpMessage>(CATCH_UP_QUEUE_LEN);
        let join = std::thread::Builder::new()
            .name("vidslam-refine".into())
            .spawn(move || {
                // The adjustment's points are linearised on a pool of the thread's own, as low
                // in priority as the thread.
                let nice = settings.nice_increment;
                super::thread_priority::run_lowered("vidslam-refine", nice, true, || {
                    run(&settings, jrx, otx, crx)
                })
            })
            .expect("spawn the refinement thread");
        RefinementThread {
            jobs: jtx,
            outcomes: orx,
            catch_up: ctx,
            catch_up_open: Cell::new(None),
            join,
        }
    }

    /// The frames handed over from now on are of adjustment `seq` (sent with
    /// [`KeyframeJob::catch_up`]).
    pub fn open_catch_up(&self, seq: u64) {
        self.close_catch_up();
        self.catch_up_open.set(Some(seq));
    }

    /// Hands a frame tracked while adjustment `frame.seq` is under way to the thread; `false` if
    /// it was not (another adjustment's, closed, or the queue full).
    pub fn catch_up_frame(&self, frame: CatchUpFrame) -> bool {
        self.catch_up_open.get() == Some(frame.seq)
            && self
                .catch_up
                .try_send(CatchUpMessage::Frame(Box::new(frame)))
                .is_ok()
    }

    /// Whether the frames of adjustment `seq` are being handed over.
    pub fn catching_up(&self, seq: u64) -> bool {
        self.catch_up_open.get() == Some(seq)
    }

    /// No more frames for the open adjustment: its end marker (the thread, offline, tracks
    /// frames until it comes).
    fn close_catch_up(&self) {
        if let Some(seq) = self.catch_up_open.take() {
            // (Full: the thread gives up waiting after `catch_up::OFFLINE_WAIT`.)
            let _ = self.catch_up.try_send(CatchUpMessage::End(seq));
        }
    }

    /// Queues `job` without waiting (real time); `false` if the queue is full.
    pub fn try_send(&self, job: RefineJob) -> bool {
        match self.jobs.try_send(job) {
            Ok(()) => true,
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => false,
        }
    }

    /// Queues `job`, waiting for room (offline).
    pub fn send(&self, job: RefineJob) -> bool {
        self.jobs.send(job).is_ok()
    }

    /// An outcome if one has arrived.
    pub fn try_recv(&self) -> Option<RefineOutcome> {
        self.outcomes.try_recv().ok()
    }

    /// Waits for the next outcome (`None` if the thread is gone); the frames handed over so far
    /// are all there will be for it.
    pub fn recv(&self) -> Option<RefineOutcome> {
        self.close_catch_up();
        self.outcomes.recv().ok()
    }

    /// [`Self::recv`] if `wait` (offline), else [`Self::try_recv`] (real time).
    pub fn next_outcome(&self, wait: bool) -> Option<RefineOutcome> {
        if wait { self.recv() } else { self.try_recv() }
    }

    /// Closes the queue and waits for the thread.
    pub fn finish(self) {
        self.close_catch_up();
        drop(self.jobs);
        drop(self.catch_up);
        let rx = self.outcomes;
        let drain = std::thread::spawn(move || while rx.recv().is_ok() {});
        let _ = self.join.join();
        let _ = drain.join();
    }
}

fn run(
    s: &RefineSettings,
    jobs: Receiver<RefineJob>,
    outcomes: Sender<RefineOutcome>,
    catch_up: Receiver<CatchUpMessage>,
) {
    // (Made at the first catch-up, kept: no allocation per adjustment.)
    let mut catch_up_tracker: Option<Tracker> = None;
    for job in jobs.iter() {
        let started = Instant::now();
        let seq = job.seq();
        let result = match &job {
            RefineJob::Keyframe(j) => match &j.kf {
                KeyframeToAdjust::Built(kf) => RefineResult::Keyframe {
                    adjusted: adjust_and_catch_up(s, j, kf, (&catch_up, &mut catch_up_tracker)),
                    unadjusted: None,
                },
                KeyframeToAdjust::Mapped {
                    snapshot,
                    t_world_cam,
                } => {
                    let kf = keyframe_of(snapshot, *t_world_cam, &s.rays, &s.tracking);
                    RefineResult::Keyframe {
                        adjusted: adjust_and_catch_up(
                            s,
                            j,
                            &kf,
                            (&catch_up, &mut catch_up_tracker),
                        ),
                        unadjusted: Some(Box::new(kf)),
                    }
                }
            },
            RefineJob::Takeoff(j) => RefineResult::Takeoff(refine(j)),
        };
        let outcome = RefineOutcome {
            seq,
            time_s: started.elapsed().as_secs_f64(),
            result,
        };
        if outcomes.send(outcome).is_err() {
            break;
        }
    }
}

/// [`adjust_keyframe`], then the frames handed over meanwhile tracked again against the result
/// ([`KeyframeJob::catch_up`]; read and dropped if the adjustment failed).
fn adjust_and_catch_up(
    s: &RefineSettings,
    job: &KeyframeJob,
    kf: &Keyframe,
    (rx, tracker): (&Receiver<CatchUpMessage>, &mut Option<Tracker>),
) -> Option<ReadyKeyframe> {
    let mut ready = adjust_keyframe(s, job, kf);
    let Some(start) = &job.catch_up else {
        return ready;
    };
    match &mut ready {
        Some(r) => {
            // (Its state and covariance are set by each catch-up.)
            let t = tracker.get_or_insert_with(|| {
                let (cfg, cov) = (s.tracking.clone(), Matrix15::identity());
                Tracker::new(
                    cfg,
                    &s.camera,
                    s.t_body_cam,
                    s.tracker_noise,
                    r.last_view,
                    cov,
                )
            });
            let views = (&r.keyframe, &r.last_view);
            *r.caught_up = catch_up(t, (rx, job.seq), views, start, &job.noise);
        }
        None => skip_frames(rx, job.seq, start),
    }
    ready
}

fn adjust_keyframe(s: &RefineSettings, job: &KeyframeJob, kf: &Keyframe) -> Option<ReadyKeyframe> {
    let base = &s.keyframe_bundle;
    let mut cfg = KeyframeBundleConfig {
        imu_rotation_noise_factor: base.imu_rotation_noise_factor * job.rotation_noise_scale,
        ..base.clone()
    };
    if job.free_depths {
        cfg.depth_rel_std = 0.0;
        cfg.velocity_std_m_s = job.start_velocity_std_m_s.unwrap_or(base.velocity_std_m_s);
        cfg.smoothness_scale_neutral =
            job.start_velocity_std_m_s.is_some() || base.smoothness_scale_neutral;
    }
    let cfg = &cfg;
    let a = bundle_adjust_keyframe(
        &job.rec,
        kf,
        &job.pyramid,
        &job.imu,
        s.t_body_cam,
        job.noise,
        s.tracking.imu_noise_scale,
        s.tracking.gradient_weight_gray_px,
        cfg,
    )?;
    let last_view = *a.views.last()?;
    let t_world_cam = a.keyframe_state.map_or(kf.t_world_cam, |x| {
        crate::tracking::pose_of(&x) * s.t_body_cam
    });
    let keyframe = Keyframe::from_rays(
        kf.id,
        kf.t,
        &job.pyramid,
        &s.rays,
        t_world_cam,
        &a.points,
        &s.tracking,
    );
    Some(ReadyKeyframe {
        keyframe,
        last_view,
        keyframe_state: a.keyframe_state,
        median_inv_depth_change: a.median_inv_depth_change,
        median_inv_depth_ratio: a.median_inv_depth_ratio,
        caught_up: Box::default(),
    })
}

fn refine(job: &TakeoffJob) -> Option<RefinedTakeoff> {
    match &job.bundle {
        None => refine_takeoff(&job.rec, job.kf.clone(), &job.imu, &job.rig),
        Some(cfg) => bundle_adjust_takeoff(&job.rec, &job.kf, &job.imu, &job.rig, cfg),
    }
}
