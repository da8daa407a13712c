//! Offline replay of an ASL/EuRoC dataset through the tracker, frame by frame in file order
//! (deterministic: the same input and configuration give a bit-identical trajectory).
//!
//! Keyframe depth comes from a [`DepthSource`]: the semidense mapping thread (the product:
//! [`super::odometry::Odometry`], started from rest or from the ground truth), or the simulator's
//! ground-truth depth maps (`mav0/depth0`, starting from the ground truth), which isolate tracking
//! from mapping.

use super::keyframe_bundle::KeyframeBundleConfig;
use super::keyframe_store::ReuseConfig;
use super::mapping_worker::MappingOutput;
use super::odometry::{
    BootstrapConfig, FrameTimes, LoopWorld, Odometry, OdometryConfig, OdometryFrame, OdometryStats,
    Phase, Rig,
};
use super::scale_observer::ScaleObserverConfig;
use super::thread_priority::RealtimeGuard;
use super::true_view_poses::TrueCameraPoses;
use crate::dataset::{AslDataset, DatasetError, FrameRecord, GroundTruth, read_imu_csv};
use crate::imu::gyro_alignment::GyroAlignmentConfig;
use crate::imu::static_init::StaticDetectorConfig;
use crate::imu::{FrameState, ImuBias, ImuSample, Matrix15, NavState, Preintegration};
use crate::loop_closure::closer::LoopClosureConfig;
use crate::mapping::semidense::SemidenseConfig;
use crate::smoother::WindowConfig;
use crate::time::TimeNs;
use crate::tracking::{
    Keyframe, TrackResult, Tracker, TrackerConfig, depth_points_from_map, select_gradient_pixels,
};
use nalgebra::Vector3;
use std::path::Path;
use std::sync::Arc;

/// Where keyframe depth comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DepthSource {
    /// The semidense mapping thread (the full odometry).
    Semidense,
    /// `mav0/depth0` ground-truth z-depth (simulator output).
    GroundTruth,
}

/// How the full odometry gets its first state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StartMode {
    /// Detect the vehicle at rest and start from it (the product's way).
    Static,
    /// The ground truth's state at the first frame (for sequences that start in motion).
    GroundTruth,
}

/// Options of one replay.
#[derive(Clone, Debug)]
pub struct ReplayOptions {
    pub tracker: TrackerConfig,
    /// Mapping, rest detection and bootstrap settings of the full odometry.
    pub mapping: SemidenseConfig,
    pub static_detector: StaticDetectorConfig,
    pub bootstrap: BootstrapConfig,
    pub window: WindowConfig,
    pub reuse: ReuseConfig,
    pub keyframe_bundle: KeyframeBundleConfig,
    pub scale_observer: ScaleObserverConfig,
    pub gyro_alignment: GyroAlignmentConfig,
    pub loop_closure: LoopClosureConfig,
    pub depth: DepthSource,
    /// Diagnostic of the full odometry: the mapper's views posed by the ground truth's motion
    /// from their keyframe ([`super::true_view_poses`]; needs the dataset's ground truth).
    pub mapping_true_view_poses: bool,
    /// Diagnostic of the full odometry: every loop the loop closer finds goes into its graph with
    /// the keyframes' true relative pose in place of the measured one (needs the dataset's ground
    /// truth and `[loop_closure] enabled`): what the loop edges' errors cost.
    pub loop_edges_true: bool,
    pub start: StartMode,
    /// Pace frames at their timestamps and never wait for the mapper (non-deterministic).
    pub realtime: bool,
    /// Stop after this much data from the first tracked frame, s.
    pub max_seconds: Option<f64>,
    /// Covered-lens intervals `(start_s, duration_s)` after the first replayed frame: their
    /// frames are replaced by black images (a tracking loss on demand). Full odometry only.
    pub covered_lens_s: Vec<(f64, f64)>,
    /// After each covered interval the lens comes free over this long, s: the frames' grey
    /// levels are scaled from 0 up to full linearly in time (a cap being lifted, an exposure
    /// settling). 0 = uncovered at once.
    pub uncover_s: f64,
    /// Initial standard deviations: position m, rotation rad, velocity m/s, gyro bias rad/s,
    /// accel bias m/s².
    pub initial_std: InitialStd,
}

/// Initial uncertainty of the start state.
#[derive(Clone, Copy, Debug)]
pub struct InitialStd {
    pub rotation_rad: f64,
    pub position_m: f64,
    pub velocity_m_s: f64,
    pub gyro_bias_rad_s: f64,
    pub accel_bias_m_s2: f64,
}

impl Default for InitialStd {
    fn default() -> Self {
        InitialStd {
            rotation_rad: 1e-3,
            position_m: 1e-3,
            velocity_m_s: 0.01,
            gyro_bias_rad_s: 2e-3,
            accel_bias_m_s2: 0.05,
        }
    }
}

impl InitialStd {
    /// Diagonal covariance in the increment order of eq. 11.
    pub fn covariance(&self) -> Matrix15 {
        let s = [
            self.rotation_rad,
            self.position_m,
            self.velocity_m_s,
            self.gyro_bias_rad_s,
            self.accel_bias_m_s2,
        ];
        Matrix15::from_fn(|a, b| if a == b { s[a / 3].powi(2) } else { 0.0 })
    }
}

impl Default for ReplayOptions {
    fn default() -> Self {
        ReplayOptions {
            tracker: TrackerConfig::default(),
            mapping: SemidenseConfig::default(),
            static_detector: StaticDetectorConfig::default(),
            bootstrap: BootstrapConfig::default(),
            window: WindowConfig::default(),
            reuse: ReuseConfig::default(),
            keyframe_bundle: KeyframeBundleConfig::default(),
            scale_observer: ScaleObserverConfig::default(),
            gyro_alignment: GyroAlignmentConfig::default(),
            loop_closure: LoopClosureConfig::default(),
            depth: DepthSource::Semidense,
            mapping_true_view_poses: false,
            loop_edges_true: false,
            start: StartMode::Static,
            realtime: false,
            max_seconds: None,
            covered_lens_s: Vec::new(),
            uncover_s: 0.0,
            initial_std: InitialStd::default(),
        }
    }
}

/// Errors of a replay; each names the file or the missing input.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("{0}")]
    Input(String),
}

/// What a replay produced, frame by frame.
#[derive(Clone, Debug, Default)]
pub struct ReplayOutput {
    /// One result per frame with a valid pose (the first frame's result is its start state).
    pub frames: Vec<TrackResult>,
    /// The odometry phase of each of `frames`.
    pub phases: Vec<Phase>,
    /// The tracking thread's wall time on each of `frames` and its parts
    /// ([`super::odometry::OdometryFrame::times`]; with ground-truth depth, tracking alone).
    pub frame_times: Vec<FrameTimes>,
    /// The loop closer's world and correction of each of `frames`
    /// ([`super::odometry::OdometryFrame::loop_world`]; empty with ground-truth depth).
    pub loop_worlds: Vec<Option<LoopWorld>>,
    /// Frames read before the first valid pose (no rest detected yet).
    pub frames_waiting: usize,
    /// What the mapping thread built (empty with ground-truth depth).
    pub mapping: MappingOutput,
    /// Real time: the tracking thread's `SCHED_FIFO` priority (`[bootstrap]
    /// tracking_fifo_priority`), or why it ran without one (`Err`: not permitted here, or off);
    /// `None` offline.
    pub tracking_fifo: Option<Result<i32, String>>,
    /// Frames of the dataset inside the replayed span.
    pub frames_in: usize,
    /// The odometry's counters and timings (with ground-truth depth only `keyframes`).
    pub odometry: OdometryStats,
}

/// The losses of a replay and how long each took to recover, from its frames' phases.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Recoveries {
    /// Time from each loss (the first frame left `Lost`) to the first frame tracked again —
    /// resumed, relocalised or on a new first map — s.
    pub recovered_s: Vec<f64>,
    /// Lost and not tracking again at the last frame: for this long, s.
    pub unrecovered_s: Option<f64>,
}

impl ReplayOutput {
    /// The losses and recoveries in `phases` (`report.json` `recovery_s_max`, `unrecovered_s`).
    pub fn recoveries(&self) -> Recoveries {
        let mut out = Recoveries::default();
        let mut lost_since: Option<TimeNs> = None;
        for (r, phase) in self.frames.iter().zip(&self.phases) {
            match (phase, lost_since) {
                (Phase::Lost, None) => lost_since = Some(r.t),
                (Phase::Tracking, Some(t0)) => {
                    out.recovered_s.push(r.t.secs_since(t0));
                    lost_since = None;
                }
                _ => {}
            }
        }
        if let (Some(t0), Some(last)) = (lost_since, self.frames.last()) {
            out.unrecovered_s = Some(last.t.secs_since(t0));
        }
        out
    }
}

/// Progress callback: `(frames done, frames total)`.
pub type Progress<'a> = &'a mut dyn FnMut(usize, usize);

/// Observer of the full odometry's frames as they come out (e.g. the MAVLink output): called
/// for every frame, valid or not, right after [`Odometry::push_frame`].
pub type FrameObserver<'a> = &'a mut dyn FnMut(&OdometryFrame);

/// Replays `dir` with `opts`; `progress` is called after every frame.
pub fn replay(
    dir: &Path,
    opts: &ReplayOptions,
    progress: Progress,
) -> Result<ReplayOutput, ReplayError> {
    replay_observed(dir, opts, progress, None)
}

/// [`replay`], with `observer` given every frame of the full odometry as it comes out (with
/// `--depth gt` there is no odometry to observe: an error).
pub fn replay_observed(
    dir: &Path,
    opts: &ReplayOptions,
    progress: Progress,
    observer: Option<FrameObserver>,
) -> Result<ReplayOutput, ReplayError> {
    match opts.depth {
        DepthSource::GroundTruth if observer.is_some() => Err(ReplayError::Input(
            "the odometry's frames (e.g. --mavlink) come from the full odometry; --depth gt \
             tracks alone"
                .into(),
        )),
        DepthSource::GroundTruth if opts.mapping_true_view_poses => Err(ReplayError::Input(
            "--mapping-poses gt poses the semidense mapper's views; --depth gt has no mapper"
                .into(),
        )),
        DepthSource::GroundTruth if opts.loop_edges_true => Err(ReplayError::Input(
            "--loop-edges gt sets the loop closer's edges; --depth gt has no loop closer".into(),
        )),
        DepthSource::Semidense if opts.loop_edges_true && !opts.loop_closure.enabled => {
            Err(ReplayError::Input(
                "--loop-edges gt sets the loop closer's edges; [loop_closure] enabled = false"
                    .into(),
            ))
        }
        DepthSource::GroundTruth => replay_gt_depth(dir, opts, progress),
        DepthSource::Semidense => replay_full(dir, opts, progress, observer),
    }
}

/// What a replay reads: the IMU, and the frames to replay — from the first frame after the
/// first IMU sample (and, if `gt` is given, with ground truth at it) for at most `max_seconds`,
/// while the IMU covers them.
struct ReplayInput {
    imu: Vec<ImuSample>,
    span: Vec<FrameRecord>,
    /// Time of the first frame replayed.
    t0: TimeNs,
}

impl ReplayInput {
    fn read(
        ds: &AslDataset,
        gt: Option<&GroundTruth>,
        max_seconds: Option<f64>,
    ) -> Result<Self, ReplayError> {
        let imu = read_imu_csv(&ds.mav0().join("imu0/data.csv"))?;
        let (Some(imu_first), Some(imu_last)) = (imu.first(), imu.last()) else {
            return Err(ReplayError::Input(format!(
                "{}: no IMU samples",
                ds.mav0().join("imu0/data.csv").display()
            )));
        };
        let (first_t, last_t) = (imu_first.t, imu_last.t);
        let frames: Vec<FrameRecord> = ds.frames()?.collect::<Result<_, _>>()?;
        let start = frames
            .iter()
            .position(|f| f.t > first_t && gt.is_none_or(|g| g.nearest(f.t, 5_000_000).is_some()))
            .ok_or_else(|| {
                ReplayError::Input(
                    "no frame has IMU data before it (and ground truth at it, where needed)".into(),
                )
            })?;
        let t0 = frames[start].t;
        let end_t = max_seconds
            .map(|s| t0.add_ns((s * 1e9).round() as i64))
            .unwrap_or(TimeNs(i64::MAX))
            .min(last_t);
        let span = frames
            .into_iter()
            .skip(start)
            .take_while(|f| f.t <= end_t)
            .collect();
        Ok(ReplayInput { imu, span, t0 })
    }
}

/// The dataset's ground truth, which `option` needs; the error names the file.
fn required_ground_truth(ds: &AslDataset, option: &str) -> Result<GroundTruth, ReplayError> {
    ds.ground_truth()?.ok_or_else(|| {
        ReplayError::Input(format!(
            "{}: {option} needs mav0/state_groundtruth_estimate0/data.csv",
            ds.mav0().display()
        ))
    })
}

/// The full odometry (semidense mapping thread, rest detection, bootstrap).
fn replay_full(
    dir: &Path,
    opts: &ReplayOptions,
    progress: Progress,
    mut observer: Option<FrameObserver>,
) -> Result<ReplayOutput, ReplayError> {
    let ds = AslDataset::open(dir)?;
    // The ground truth is read once, for whichever option needs it.
    let truth = match opts.start {
        StartMode::GroundTruth => Some(required_ground_truth(&ds, "--start gt")?),
        _ if opts.mapping_true_view_poses => {
            Some(required_ground_truth(&ds, "--mapping-poses gt")?)
        }
        _ if opts.loop_edges_true => Some(required_ground_truth(&ds, "--loop-edges gt")?),
        StartMode::Static => None,
    };
    let true_poses = truth
        .as_ref()
        .filter(|_| opts.mapping_true_view_poses || opts.loop_edges_true)
        .map(|g| Arc::new(TrueCameraPoses::new(g.trajectory(), ds.camera.t_body_cam)));
    let true_view_poses = true_poses.clone().filter(|_| opts.mapping_true_view_poses);
    let loop_true_camera_poses = true_poses.filter(|_| opts.loop_edges_true);
    let gt = truth.filter(|_| opts.start == StartMode::GroundTruth);
    let ReplayInput { imu, span, t0 } = ReplayInput::read(&ds, gt.as_ref(), opts.max_seconds)?;
    let cfg = OdometryConfig {
        tracking: opts.tracker.clone(),
        mapping: opts.mapping.clone(),
        static_detector: opts.static_detector,
        bootstrap: opts.bootstrap.clone(),
        window: opts.window.clone(),
        reuse: opts.reuse.clone(),
        keyframe_bundle: opts.keyframe_bundle.clone(),
        scale_observer: opts.scale_observer,
        gyro_alignment: opts.gyro_alignment.clone(),
        loop_closure: opts.loop_closure.clone(),
        realtime: opts.realtime,
        mapping_true_view_poses: true_view_poses,
        loop_true_camera_poses,
    };
    let rig = Rig {
        camera: ds.camera.model,
        t_body_cam: ds.camera.t_body_cam,
        noise: ds.imu.noise,
        vignette: ds.vignette,
    };
    let mut odo = Odometry::new(cfg, rig);
    if let Some(g) = &gt {
        odo.set_start_state(start_state(g, t0)?, opts.initial_std.covariance());
    }
    let mut out = ReplayOutput {
        frames_in: span.len(),
        ..Default::default()
    };
    // Real time: the frames at a real-time priority where permitted, taken after the odometry
    // started its threads and given back when the replay ends (a thread started meanwhile does
    // not inherit it).
    let fifo_priority = opts.bootstrap.tracking_fifo_priority;
    let fifo = (opts.realtime && fifo_priority > 0).then(|| RealtimeGuard::fifo(fifo_priority));
    out.tracking_fifo = opts.realtime.then(|| match &fifo {
        Some(Ok(_)) => Ok(fifo_priority),
        Some(Err(e)) => Err(format!("SCHED_FIFO {fifo_priority} not permitted: {e}")),
        None => Err("off ([bootstrap] tracking_fifo_priority = 0)".to_string()),
    });
    let mut next_imu = 0usize;
    let wall0 = std::time::Instant::now();
    for (k, rec) in span.iter().enumerate() {
        odo.push_imu_for_frame(&imu, &mut next_imu, rec.t);
        let since_s = rec.t.secs_since(t0);
        let covered = opts
            .covered_lens_s
            .iter()
            .any(|&(a, d)| since_s >= a && since_s < a + d);
        let img = if covered {
            let c = &ds.camera.model;
            crate::image::Image::<u8>::new(c.width, c.height)
        } else {
            let mut img = rec.load()?;
            if let Some(gain) = uncovering_gain(&opts.covered_lens_s, opts.uncover_s, since_s) {
                img.data_mut()
                    .iter_mut()
                    .for_each(|v| *v = (f64::from(*v) * gain).round() as u8);
            }
            img
        };
        if opts.realtime {
            let due = std::time::Duration::from_secs_f64(since_s.max(0.0));
            if let Some(wait) = due.checked_sub(wall0.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        let f = odo.push_frame(rec.t, img);
        if let Some(o) = observer.as_mut() {
            o(&f);
        }
        if f.valid {
            out.frames.push(f.result);
            out.phases.push(f.phase);
            out.frame_times.push(f.times);
            out.loop_worlds.push(f.loop_world);
        } else {
            out.frames_waiting += 1;
        }
        progress(k + 1, span.len());
    }
    drop(fifo);
    let (stats, mapping) = odo.finish();
    out.odometry = stats;
    out.mapping = mapping;
    Ok(out)
}

/// Tracking alone: keyframe depth and start state from the ground truth.
fn replay_gt_depth(
    dir: &Path,
    opts: &ReplayOptions,
    progress: Progress,
) -> Result<ReplayOutput, ReplayError> {
    let ds = AslDataset::open(dir)?;
    let gt = required_ground_truth(&ds, "--depth gt (its start state)")?;
    let ReplayInput { imu, span, t0 } = ReplayInput::read(&ds, Some(&gt), opts.max_seconds)?;

    let state0 = start_state(&gt, t0)?;
    let cam = ds.camera.model;
    let t_body_cam = ds.camera.t_body_cam;
    let noise = opts.tracker.imu_noise(ds.imu.noise);
    let mut tracker = Tracker::new(
        opts.tracker.clone(),
        &cam,
        t_body_cam,
        noise,
        state0,
        opts.initial_std.covariance(),
    );
    let mut out = ReplayOutput {
        frames_in: span.len(),
        ..Default::default()
    };
    let mut next_kf_id = 0u32;
    let mut prev_t = t0;
    for (k, rec) in span.iter().enumerate() {
        let img = rec.load()?;
        let result = if k == 0 {
            tracker.load_frame(&img);
            first_result(rec.t, &tracker)
        } else {
            let mut pre = Preintegration::new(prev_t, tracker.state().bias);
            pre.integrate(&imu, rec.t, Some(&noise));
            tracker.track(rec.t, &img, &pre)
        };
        let need_kf = k == 0 || result.wants_keyframe;
        out.frame_times.push(FrameTimes {
            total_s: result.time_s,
            tracking_s: result.time_s,
            ..FrameTimes::default()
        });
        out.frames.push(result);
        out.phases.push(Phase::Tracking);
        if need_kf && opts.tracker.use_vision {
            let kf = ground_truth_keyframe(&ds, &mut tracker, &cam, rec.t, next_kf_id)?;
            tracker.set_keyframe(kf);
            next_kf_id += 1;
            out.odometry.keyframes += 1;
        }
        prev_t = rec.t;
        progress(k + 1, span.len());
    }
    Ok(out)
}

/// The rig's state at `t` from the ground truth sample within 5 ms: its pose, its velocity (else a
/// central difference over ±25 ms) and its biases (zero if not given). The replay starts from it
/// (`--start gt`), the benchmarks and `dataset adjust-check` pose their frames with it; the error
/// speaks of the first frame, where the replay asks.
pub fn start_state(gt: &GroundTruth, t: TimeNs) -> Result<FrameState, ReplayError> {
    let s = gt
        .nearest(t, 5_000_000)
        .ok_or_else(|| ReplayError::Input("no ground truth at the first frame".into()))?;
    // Velocity: the ground truth's, else a central difference over ±25 ms.
    let v = match s.v_world_m_s {
        Some(v) => v,
        None => {
            let a = gt.nearest(t.add_ns(-25_000_000), 5_000_000);
            let b = gt.nearest(t.add_ns(25_000_000), 5_000_000);
            match (a, b) {
                (Some(a), Some(b)) if b.t > a.t => {
                    (b.t_world_body.translation.vector - a.t_world_body.translation.vector)
                        / b.t.secs_since(a.t)
                }
                _ => Vector3::zeros(),
            }
        }
    };
    Ok(FrameState {
        nav: NavState {
            t,
            r_world_body: s.t_world_body.rotation,
            p_world_m: s.t_world_body.translation.vector,
            v_world_m_s: v,
        },
        bias: ImuBias {
            gyro_rad_s: s.gyro_bias_rad_s.unwrap_or_default(),
            accel_m_s2: s.accel_bias_m_s2.unwrap_or_default(),
        },
    })
}

/// The first frame: its start state, a keyframe wanted.
fn first_result(t: TimeNs, tracker: &Tracker) -> TrackResult {
    TrackResult {
        inlier_ratio: 1.0,
        overlap: 1.0,
        residual_rms_gray: 0.0,
        wants_keyframe: true,
        ..tracker.untracked_result(t)
    }
}

/// A keyframe at the tracker's current frame and pose with ground-truth depth.
fn ground_truth_keyframe(
    ds: &AslDataset,
    tracker: &mut Tracker,
    cam: &crate::camera::CameraModel,
    t: TimeNs,
    id: u32,
) -> Result<Keyframe, ReplayError> {
    let depth = ds.load_depth_m(t)?.ok_or_else(|| {
        ReplayError::Input(format!(
            "--depth gt: no ground-truth depth for frame {} (expected {})",
            t.0,
            ds.mav0().join(format!("depth0/data/{}.png", t.0)).display()
        ))
    })?;
    let cfg = tracker.config().clone();
    let t_world_cam = tracker.t_world_cam();
    let pyramid = tracker.frame_pyramid();
    let pixels = select_gradient_pixels(pyramid, &cfg);
    let points = depth_points_from_map(&pixels, &depth, 0.05);
    Ok(Keyframe::new(
        id,
        t,
        pyramid,
        cam,
        t_world_cam,
        &points,
        &cfg,
    ))
}

/// `uncover_s`: the grey-level gain of a frame `since_s` after the first one while the lens comes
/// free after one of the `covered` intervals `(start_s, duration_s)`, in (0, 1); `None` when it
/// is not coming free.
fn uncovering_gain(covered: &[(f64, f64)], uncover_s: f64, since_s: f64) -> Option<f64> {
    if uncover_s.is_nan() || uncover_s <= 0.0 {
        return None;
    }
    covered.iter().find_map(|&(a, d)| {
        let into_s = since_s - (a + d);
        (into_s >= 0.0 && into_s < uncover_s).then(|| (into_s / uncover_s).max(1e-3))
    })
}

#[cfg(test)]
mod tests {
    use super::uncovering_gain;

    #[test]
    fn the_lens_comes_free_linearly_after_each_cover() {
        let covers = [(1.0, 0.5), (4.0, 1.0)];
        assert_eq!(uncovering_gain(&covers, 0.0, 1.6), None);
        assert_eq!(uncovering_gain(&covers, 0.2, 1.4), None); // still covered
        assert!((uncovering_gain(&covers, 0.2, 1.55).unwrap() - 0.25).abs() < 1e-9);
        assert!((uncovering_gain(&covers, 0.2, 5.15).unwrap() - 0.75).abs() < 1e-9);
        assert_eq!(uncovering_gain(&covers, 0.2, 1.75), None); // free again
        assert_eq!(uncovering_gain(&covers, 0.2, 0.5), None);
    }
}
