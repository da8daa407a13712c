//! Offline replay of an ASL/EuRoC dataset through the tracker, frame by frame in file order
//! (deterministic: the same input and configuration give a bit-identical trajectory).
//!
//! Keyframe depth comes from a [`DepthSource`]: the simulator's ground-truth depth maps
//! (`mav0/depth0`) isolate tracking from mapping.

use crate::dataset::{AslDataset, DatasetError, FrameRecord, GroundTruth, read_imu_csv};
use crate::imu::{FrameState, ImuBias, ImuSample, Matrix15, NavState, Preintegration};
use crate::time::TimeNs;
use crate::tracking::{
    Keyframe, TrackResult, Tracker, TrackerConfig, depth_points_from_map, select_gradient_pixels,
};
use nalgebra::Vector3;
use std::path::Path;

/// Where keyframe depth comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DepthSource {
    /// `mav0/depth0` ground-truth z-depth (simulator output).
    GroundTruth,
}

/// Options of one replay.
#[derive(Clone, Debug)]
pub struct ReplayOptions {
    pub tracker: TrackerConfig,
    pub depth: DepthSource,
    /// Stop after this much data from the first tracked frame, s.
    pub max_seconds: Option<f64>,
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
            depth: DepthSource::GroundTruth,
            max_seconds: None,
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
    /// One result per tracked frame (the first frame's result is its start state).
    pub frames: Vec<TrackResult>,
    /// Frames of the dataset inside the replayed span.
    pub frames_in: usize,
    /// Keyframes created.
    pub keyframes: usize,
}

/// Progress callback: `(frames done, frames total)`.
pub type Progress<'a> = &'a mut dyn FnMut(usize, usize);

/// Replays `dir` with `opts`; `progress` is called after every frame.
pub fn replay(
    dir: &Path,
    opts: &ReplayOptions,
    progress: Progress,
) -> Result<ReplayOutput, ReplayError> {
    let ds = AslDataset::open(dir)?;
    let gt = ds.ground_truth()?.ok_or_else(|| {
        ReplayError::Input(format!(
            "{}: no mav0/state_groundtruth_estimate0/data.csv (the start state comes from it)",
            ds.mav0().display()
        ))
    })?;
    let imu = read_imu_csv(&ds.mav0().join("imu0/data.csv"))?;
    let frames: Vec<FrameRecord> = ds.frames()?.collect::<Result<_, _>>()?;
    let (Some(imu_first), Some(imu_last)) = (imu.first(), imu.last()) else {
        return Err(ReplayError::Input(format!(
            "{}: no IMU samples",
            ds.mav0().join("imu0/data.csv").display()
        )));
    };
    // First frame with IMU before it and ground truth at it.
    let start = frames
        .iter()
        .position(|f| f.t > imu_first.t && gt.nearest(f.t, 5_000_000).is_some())
        .ok_or_else(|| {
            ReplayError::Input("no frame has both IMU data before it and ground truth".into())
        })?;
    let t0 = frames[start].t;
    let end_t = opts
        .max_seconds
        .map(|s| t0.add_ns((s * 1e9).round() as i64))
        .unwrap_or(TimeNs(i64::MAX))
        .min(imu_last.t);
    let span: Vec<&FrameRecord> = frames[start..]
        .iter()
        .take_while(|f| f.t <= end_t)
        .collect();

    let state0 = start_state(&gt, t0)?;
    let cam = ds.camera.model;
    let t_body_cam = ds.camera.t_body_cam;
    let mut tracker = Tracker::new(
        opts.tracker.clone(),
        &cam,
        t_body_cam,
        ds.imu.noise,
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
            pre.integrate(imu_window(&imu, prev_t, rec.t), rec.t, Some(&ds.imu.noise));
            tracker.track(rec.t, &img, &pre)
        };
        let need_kf = k == 0 || result.wants_keyframe;
        out.frames.push(result);
        if need_kf && opts.tracker.use_vision {
            let kf = match opts.depth {
                DepthSource::GroundTruth => {
                    ground_truth_keyframe(&ds, &tracker, &cam, rec.t, next_kf_id)?
                }
            };
            tracker.set_keyframe(kf);
            next_kf_id += 1;
            out.keyframes += 1;
        }
        prev_t = rec.t;
        progress(k + 1, span.len());
    }
    Ok(out)
}

/// The IMU samples bracketing `[t0, t1]` (one before and one after, when they exist).
pub fn imu_window(imu: &[ImuSample], t0: TimeNs, t1: TimeNs) -> &[ImuSample] {
    let a = imu.partition_point(|s| s.t < t0).saturating_sub(1);
    let b = (imu.partition_point(|s| s.t <= t1) + 1).min(imu.len());
    &imu[a..b]
}

fn start_state(gt: &GroundTruth, t: TimeNs) -> Result<FrameState, ReplayError> {
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

fn first_result(t: TimeNs, tracker: &Tracker) -> TrackResult {
    TrackResult {
        t,
        state: *tracker.state(),
        covariance: *tracker.covariance(),
        log_gain: 0.0,
        offset_gray: 0.0,
        flag: None,
        iterations: [0; crate::tracking::NUM_LEVELS],
        inlier_ratio: 1.0,
        overlap: 1.0,
        residual_rms_gray: 0.0,
        imu_chi2: 0.0,
        keyframe_id: None,
        wants_keyframe: true,
        time_s: 0.0,
    }
}

/// A keyframe at the tracker's current frame and pose with ground-truth depth.
fn ground_truth_keyframe(
    ds: &AslDataset,
    tracker: &Tracker,
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
    let cfg = tracker.config();
    let pixels = select_gradient_pixels(tracker.frame_pyramid(), cfg);
    let points = depth_points_from_map(&pixels, &depth, 0.05);
    Ok(Keyframe::new(
        id,
        t,
        tracker.frame_pyramid().clone(),
        cam,
        tracker.t_world_cam(),
        &points,
        cfg,
    ))
}
