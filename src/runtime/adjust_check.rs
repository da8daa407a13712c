//! The in-flight keyframe adjustment ([`super::keyframe_bundle`]) started at the truth, on a
//! dataset with ground-truth states and depth maps (the simulator's): every `every_frames`-th frame
//! becomes a keyframe with its points at the rendered depth, the next `views` frames its views at
//! their true states, and the adjustment runs with free depths (the prior toward given depths would
//! hold them at the truth). An unbiased adjustment leaves the map where it is; how far it moves the
//! map's scale (median inverse depth and the last view's baseline against the truth) is what this
//! measures (`vidslam dataset adjust-check`; docs/odometry-log.md, *The keyframe adjustment's
//! smoothness prior moved the map's scale*).

use super::Config;
use super::keyframe_bundle::{KeyframeBundleConfig, KeyframeRecord, bundle_adjust_keyframe};
use super::mapping_worker::MapFrame;
use super::replay::start_state;
use crate::dataset::{AslDataset, DatasetError};
use crate::image::Pyramid;
use crate::imu::{FrameState, ImuSample};
use crate::time::TimeNs;
use crate::tracking::{DepthPoint, Keyframe, NUM_LEVELS, pose_of, select_gradient_pixels};
use std::sync::Arc;

/// Below this true baseline the baseline ratio is not defined, m.
const MIN_BASELINE_M: f64 = 1e-3;

/// Which keyframes and views.
#[derive(Clone, Debug, PartialEq)]
pub struct AdjustCheckOptions {
    /// Views per keyframe (the frames right after it).
    pub views: usize,
    /// A keyframe every this many frames (from the first).
    pub every_frames: usize,
}

impl Default for AdjustCheckOptions {
    fn default() -> Self {
        AdjustCheckOptions {
            views: 4,
            every_frames: 10,
        }
    }
}

/// One keyframe's adjustment from the truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdjustCheckRow {
    /// Keyframe time.
    pub t: TimeNs,
    /// Keyframe points with a rendered depth.
    pub points: usize,
    /// True distance from the keyframe to its last view, m.
    pub baseline_m: f64,
    /// Median adjusted / true inverse depth (> 1: the map ends short).
    pub inv_depth_ratio: f64,
    /// Adjusted / true distance from the keyframe to its last view (NaN when the views are
    /// within 1 mm of the keyframe: on the pad).
    pub baseline_ratio: f64,
    /// Largest position error of the adjusted views, m.
    pub position_error_m: f64,
    /// Largest rotation error of the adjusted views, rad.
    pub rotation_error_rad: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum AdjustCheckError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("{0}: needed to start the adjustment at the truth (a `vidslam sim` dataset has it)")]
    Missing(String),
}

/// Adjusts a keyframe every `opts.every_frames` frames of `ds` from the truth with `cfg`'s
/// tracker and `[keyframe_bundle]` settings (depths free); `on_row` sees each result as it comes.
/// Keyframes without a depth map, ground truth or enough views are skipped.
pub fn adjust_from_truth(
    ds: &AslDataset,
    cfg: &Config,
    opts: &AdjustCheckOptions,
    mut on_row: impl FnMut(&AdjustCheckRow),
) -> Result<Vec<AdjustCheckRow>, AdjustCheckError> {
    let missing =
        |what: &str| AdjustCheckError::Missing(format!("{}: {what}", ds.mav0().display()));
    let gt = ds
        .ground_truth()?
        .ok_or_else(|| missing("no state_groundtruth_estimate0/"))?;
    if gt.states.first().is_none_or(|s| s.v_world_m_s.is_none()) {
        return Err(missing("no velocity in the ground truth"));
    }
    if !ds.mav0().join("depth0/data.csv").exists() {
        return Err(missing("no depth0/data.csv"));
    }
    let frames = ds.frames()?.collect::<Result<Vec<_>, _>>()?;
    let imu: Vec<ImuSample> = ds.imu_samples()?.collect::<Result<Vec<_>, _>>()?;
    let cam = ds.camera.model;
    let t_body_cam = ds.camera.t_body_cam;
    let bundle = KeyframeBundleConfig {
        depth_rel_std: 0.0,
        ..cfg.keyframe_bundle.clone()
    };
    let views = opts.views.max(1);
    let mut rows = Vec::new();
    for k in (0..frames.len().saturating_sub(views)).step_by(opts.every_frames.max(1)) {
        let kf_frame = &frames[k];
        let (Some(depth), Some(start)) = (
            ds.load_depth_m(kf_frame.t)?,
            start_state(&gt, kf_frame.t).ok(),
        ) else {
            continue;
        };
        let pyr = Pyramid::from_u8(&kf_frame.load()?, NUM_LEVELS);
        let points: Vec<DepthPoint> = select_gradient_pixels(&pyr, &cfg.tracking)
            .into_iter()
            .filter_map(|(u, v)| {
                let z = depth.get(u as usize, v as usize);
                (z > 0.0).then_some(DepthPoint {
                    u_px: u as f32,
                    v_px: v as f32,
                    inv_depth_m_inv: 1.0 / z,
                })
            })
            .collect();
        let mut view_states = Vec::with_capacity(views);
        for f in &frames[k + 1..=k + views] {
            let Ok(x) = start_state(&gt, f.t) else {
                break;
            };
            let frame = MapFrame {
                t: f.t,
                image: Arc::new(f.load()?),
                t_world_cam: pose_of(&x) * t_body_cam,
            };
            view_states.push((frame, x));
        }
        if view_states.len() < views || points.is_empty() {
            continue;
        }
        let truth: Vec<FrameState> = view_states.iter().map(|(_, x)| *x).collect();
        let kf = Keyframe::new(
            0,
            kf_frame.t,
            &pyr,
            &cam,
            pose_of(&start) * t_body_cam,
            &points,
            &cfg.tracking,
        );
        let rec = KeyframeRecord {
            id: 0,
            start,
            views: view_states,
            previous: None,
            gyro_turn_rad: nalgebra::Vector3::zeros(),
        };
        let Some(a) = bundle_adjust_keyframe(
            &rec,
            &kf,
            &pyr,
            &imu,
            t_body_cam,
            cfg.tracking.imu_noise(ds.imu.noise),
            cfg.tracking.imu_noise_scale,
            cfg.tracking.gradient_weight_gray_px,
            &bundle,
        ) else {
            continue;
        };
        let baseline = |x: &FrameState| (x.nav.p_world_m - start.nav.p_world_m).norm();
        let (last, last_true) = (a.views.last(), truth.last());
        let (Some(last), Some(last_true)) = (last, last_true) else {
            continue;
        };
        let baseline_m = baseline(last_true);
        let row = AdjustCheckRow {
            t: kf_frame.t,
            points: points.len(),
            baseline_m,
            inv_depth_ratio: a.median_inv_depth_ratio,
            baseline_ratio: match baseline_m {
                b if b >= MIN_BASELINE_M => baseline(last) / b,
                _ => f64::NAN,
            },
            position_error_m: a
                .views
                .iter()
                .zip(&truth)
                .map(|(x, t)| (x.nav.p_world_m - t.nav.p_world_m).norm())
                .fold(0.0, f64::max),
            rotation_error_rad: a
                .views
                .iter()
                .zip(&truth)
                .map(|(x, t)| x.nav.r_world_body.angle_to(&t.nav.r_world_body))
                .fold(0.0, f64::max),
        };
        on_row(&row);
        rows.push(row);
    }
    Ok(rows)
}
