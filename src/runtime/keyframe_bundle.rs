//! In-flight refinement of each new keyframe before it is tracked: the joint photometric–inertial
//! bundle adjustment of the take-off ([`crate::smoother::photometric_bundle`]) applied to every
//! keyframe, with the frames tracked since it as views.
//!
//! The semidense mapper triangulates a keyframe from the poses tracking gave its views, and those
//! poses were tracked against the previous keyframe's map: a map's scale or distortion error is
//! passed on to the next map through the poses (docs/odometry-log.md, *Why S-V101 fails*). Here the
//! keyframe's inverse depths, its views' states, the velocity at the keyframe and the accelerometer
//! bias are optimised together, the views chained by the IMU (eq. 13) from the keyframe's state
//! (its pose is the gauge, its velocity has a prior around the keyframe window's estimate), so the
//! map that is installed for tracking agrees with the IMU's metric displacement and with every
//! view's pixels.
//!
//! It runs on a thread of its own ([`super::refinement_worker`]) once the keyframe's map is ready
//! (`[keyframe_bundle]`); the keyframe is installed when it is back. The frames tracked meanwhile
//! are tracked again against it ([`carry_correction`] moves the state instead when there are too
//! many of them).

use super::mapping_worker::MapFrame;
use crate::image::{Image, Pyramid};
use crate::imu::misalignment::turned;
use crate::imu::{FrameState, ImuNoise, ImuSample, Preintegration};
use crate::smoother::photometric_bundle::{
    BundleConfig, BundleView, ChainHost, HostPoints, PhotometricBundle,
};
use crate::tracking::pose_of;
use crate::tracking::{DepthPoint, Keyframe};
use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Settings of the in-flight keyframe adjustment (the `[keyframe_bundle]` table).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KeyframeBundleConfig {
    /// Adjust every new keyframe (after the take-off) before it is tracked.
    pub enabled: bool,
    /// Fewer views than this: the keyframe is installed as the mapper built it.
    pub min_views: usize,
    /// Levenberg–Marquardt iterations per pyramid level.
    pub iterations_per_level: usize,
    /// Prior standard deviation of the keyframe's velocity around the window's estimate, m/s.
    pub velocity_std_m_s: f64,
    /// Prior standard deviation of the accelerometer bias around the keyframe's, m/s².
    pub accel_bias_std_m_s2: f64,
    /// Each inverse depth is pulled toward its image neighbours' median with this relative σ.
    pub smoothness_rel_std: f64,
    /// Rescale the smoothness prior's targets so that the prior does not pull the map's scale (it
    /// shortened free-depth maps 1.5–8 % per adjustment from the truth; docs/odometry-log.md, *The
    /// keyframe adjustment's smoothness prior moved the map's scale*). Off by default: in the
    /// closed loop it made S-V101 (5 of 6 seeds) and the demo (median of 24 seeds 2.75 → 3.21 cm)
    /// worse — that pull had been offsetting other scale errors of the chain.
    pub smoothness_scale_neutral: bool,
    /// Standard deviation of each inverse depth around the mapper's, relative (0 = none).
    pub depth_rel_std: f64,
    /// The IMU white noise of the tracker (`[tracking] imu_noise_scale`) is multiplied by this.
    pub imu_noise_factor: f64,
    /// The rotation part of that noise is multiplied by this on top
    /// ([`crate::imu::Preintegration::scale_rotation_noise`]; 1 = as the rest).
    pub imu_rotation_noise_factor: f64,
    /// The adjusted keyframe is installed this many frames after its adjustment started (0 =
    /// before the next frame is tracked): offline exactly, in real time at the earliest (later if
    /// the adjustment takes longer). Until then the previous keyframe is tracked.
    pub lag_frames: u64,
    /// A keyframe installed with guessed depths (started in a turn on the spot, where nothing
    /// could be triangulated) gets the scale of the map the mapper then builds for it from the
    /// poses tracked against those guesses. It is adjusted once its views span this fraction of
    /// its median depth, with its depths free of the mapper's (`depth_rel_std` not applied), and
    /// the mapper's copy rescaled to match (0 = never).
    pub guessed_min_baseline_ratio: f64,
    /// At most this many of its views go into that adjustment (evenly spaced, the last one
    /// included; the IMU is preintegrated across the frames left out).
    pub guessed_max_views: usize,
    /// Real time: an adjustment not back yet is given up (the new keyframe installed as the
    /// mapper built it) only once the keyframe tracked meanwhile keeps fewer than this fraction
    /// of its points as inliers. Offline the adjustment is always waited for.
    pub give_up_inlier_ratio: f64,
    /// Adjust a new keyframe together with the keyframe tracked when it was started: that one is
    /// the gauge (its pose fixed, its depths free), the frames tracked against it up to the new
    /// keyframe join the IMU chain, and the new keyframe's pose is free instead of taken as
    /// tracking left it. The pixels of both maps then tie the new map's scale to the one before
    /// over two keyframe intervals of IMU. Off: offline it keeps S-V101's scale where the single
    /// adjustment loses it (seeds 16 / 20 0.409 / 0.165 → 0.087 / 0.102 m, seeds 1–20 mean 0.107
    /// → 0.087 m), but it takes ~3.5 × the adjustment's time, and in real time S-V101 seed 1 runs
    /// away (1.3 m; docs/odometry-log.md, *A new keyframe adjusted together with the one before
    /// it*). Offline with `lag_frames = 7` it ran away too (440 m) until the frames tracked while
    /// an adjustment is under way were kept in the next keyframe's chain (0.145 m); real time
    /// still runs away (1.10 m and 1 km in two of three runs; *The two-keyframe adjustment made
    /// cheaper, and its chain kept across a late install*): offline at `lag_frames = 10` too,
    /// unless the frames of the wait are tracked again (`catch_up_on_refinement_thread`; in real
    /// time with it seeds 1, 2, 5, 16, 20 0.087–0.202 m, seed 8 1.96 and 0.157 m).
    pub previous_host: bool,
    /// At most this many of the frames between the two keyframes go into that adjustment (evenly
    /// spaced, the last one included; the IMU is preintegrated across the others).
    pub previous_host_max_frames: usize,
    /// Prior standard deviation of the previous keyframe's velocity around the window's
    /// estimate in that adjustment, m/s: the chain is long enough for the frames to tell it.
    pub previous_host_velocity_std_m_s: f64,
    /// Of the previous keyframe's points, every this many go into that adjustment (1 = all):
    /// they are the gauge's, observed by every frame of the chain, and most of its cost.
    pub previous_host_point_stride: usize,
    /// Levenberg–Marquardt iterations per pyramid level in that adjustment (its cost; the single
    /// keyframe's adjustment takes `iterations_per_level`). 3 ran S-V101 seed 16 away offline.
    pub previous_host_iterations_per_level: usize,
    /// The finest pyramid level that adjustment solves (0 = all). Every level samples the same
    /// points: 1 / 2 take S-V101's adjustments from 467 to 322 / 224 ms p50 and keep seeds 16 /
    /// 20's scale offline; in real time seed 1 still ran away.
    pub previous_host_finest_level: usize,
    /// In real time a new keyframe waits for this many frames tracked since it was started
    /// before it is adjusted and installed (at least `min_views`; unless the keyframe tracked
    /// meanwhile is nearly lost, `[bootstrap] urgent_unadjusted_inlier_ratio`). Offline the
    /// mapper's `[bootstrap] min_keyframe_forward_views` (3) come with 4 such frames; in real
    /// time, with 3, S-V101's adjustments spanned 0.15 s instead of 0.20 s, moved the
    /// accelerometer bias twice as far (p50 0.18 against 0.11 m/s², 87 jumps beyond 0.25 m/s² on
    /// seed 1 against 16 offline) and 3 of 16 runs ran away (docs/odometry-log.md, *Real-time
    /// keyframe adjustments wait for the views offline ones get*).
    pub realtime_min_views: usize,
    /// The keyframe window's estimate of the gyro's turn (`[window] gyro_misalignment`) turns
    /// this adjustment's IMU only once its angle is at least this, rad. The adjustment weighs the
    /// IMU at a hundred times the tracker's information, and on a gyro that is not turned the
    /// estimate wanders by up to ~0.15°: turned by every such wander, 3 of 24 demo flights ran
    /// away (docs/odometry-log.md, *The keyframe window reads the gyro's turn*).
    pub gyro_turn_min_rad: f64,
    /// An adjustment that moves its last view's velocity by more than this from where tracking
    /// had it is not applied (the keyframe is installed as the mapper built it, and tracking goes
    /// on from its own state), m/s; 0 = no limit. The adjustment holds the keyframe's velocity to
    /// the window's within `velocity_std_m_s` and chains the views by the IMU, so a last view
    /// moved by tenths of a m/s in a fraction of a second means a map it could not fit. 0.3:
    /// S-V101's adjustments move it by 0.025 m/s median, at most 0.10 on seed 2; on seed 4 a
    /// keyframe of 1290 points started after a failed return moved it by 0.76 m/s, and the
    /// flight controller got 0.8–1.0 m/s off for 4 frames and then a 0.46 m jump back
    /// (docs/odometry-log.md, *What the flight controller gets: the velocity, and an adjustment
    /// that threw it*).
    pub max_velocity_change_m_s: f64,
    /// Of the frames tracked while the adjustment was under way (in real time, or offline with
    /// `lag_frames`, which emulates it), the newest this many are tracked again against the
    /// adjusted keyframe when it comes back, from the last view's adjusted state (the IMU across
    /// any frames before them). 0: none; the current state is moved by the last view's
    /// correction instead ([`carry_correction`]). (Offline without a lag all are, at most one.)
    /// In real time they are tracked again within one frame: 3 frames late, that frame took
    /// 3-13 ms longer. Demo in real time: whole-frame p99 13.4 ms re-tracking all (seeds 1-4),
    /// 12.6 ms one (seeds 1-8, refreshes then built on a thread), 11.3 ms none (seeds 1-16,
    /// median ATE 1.89 cm; docs/odometry-log.md, *The tracking thread's whole frame, 17 → 11
    /// ms*).
    pub max_catch_up_frames: usize,
    /// When adjustments come back late (real time, or offline with `lag_frames`), the frames
    /// tracked while one was under way are handed to the refinement thread as they are tracked
    /// and tracked again there against the adjusted keyframe, from its last view's adjusted
    /// state, right after the adjustment ([`super::catch_up`]); the tracking thread tracks again
    /// only those that came after (the newest, usually none or one), `max_catch_up_frames` not
    /// applied. Moved rigidly by the last view's correction instead, the frames of a long wait
    /// keep the previous map's scale, and with `previous_host` S-V101 seed 1 ran away offline
    /// at `lag_frames = 10` (210 m; tracked again, 0.14 m).
    pub catch_up_on_refinement_thread: bool,
}

impl Default for KeyframeBundleConfig {
    fn default() -> Self {
        KeyframeBundleConfig {
            enabled: true,
            min_views: 3,
            iterations_per_level: 6,
            velocity_std_m_s: 0.01,
            accel_bias_std_m_s2: 0.05,
            smoothness_rel_std: 0.1,
            smoothness_scale_neutral: false,
            depth_rel_std: 0.05,
            imu_noise_factor: 0.1,
            imu_rotation_noise_factor: 1.0,
            lag_frames: 0,
            guessed_min_baseline_ratio: 0.1,
            guessed_max_views: 10,
            give_up_inlier_ratio: 0.3,
            previous_host: false,
            previous_host_max_frames: 6,
            previous_host_velocity_std_m_s: 0.1,
            previous_host_point_stride: 1,
            previous_host_iterations_per_level: 6,
            previous_host_finest_level: 0,
            realtime_min_views: 4,
            gyro_turn_min_rad: 0.0044,
            max_velocity_change_m_s: 0.3,
            max_catch_up_frames: 0,
            catch_up_on_refinement_thread: false,
        }
    }
}

/// A keyframe started in the mapper and the frames tracked since, kept until it is installed.
#[derive(Clone, Debug)]
pub struct KeyframeRecord {
    /// Mapper id of the keyframe.
    pub id: u32,
    /// The keyframe's state when it was started (after the keyframe window's correction).
    pub start: FrameState,
    /// Frames tracked since, with their tracked states, oldest first (world frame).
    pub views: Vec<(MapFrame, FrameState)>,
    /// The keyframe tracked when this one was started, for `[keyframe_bundle] previous_host`.
    pub previous: Option<Box<PreviousHost>>,
    /// The gyro's turn against the body frame when the keyframe was started (`[window]
    /// gyro_misalignment`, `ω_body = Exp(φ) ω_gyro`), rad: its IMU is turned by it.
    pub gyro_turn_rad: Vector3<f64>,
}

/// The keyframe tracked when a new one was started, and the frames tracked against it up to the
/// new one.
#[derive(Clone, Debug)]
pub struct PreviousHost {
    pub keyframe: Keyframe,
    pub image: Arc<Image<u8>>,
    /// Its body state (the keyframe window's, consistent with `keyframe.t_world_cam`).
    pub state: FrameState,
    /// Frames tracked between it and the new keyframe with their states, oldest first.
    pub frames: Vec<(MapFrame, FrameState)>,
}

/// What the adjustment produced.
#[derive(Clone, Debug)]
pub struct AdjustedKeyframe {
    /// The keyframe's points with their adjusted inverse depths (level 0 pixels).
    pub points: Vec<DepthPoint>,
    /// The views' adjusted states, oldest first.
    pub views: Vec<FrameState>,
    /// The keyframe's own adjusted state when its pose was free (adjusted with the previous
    /// keyframe as the gauge), `None` when its pose was the gauge.
    pub keyframe_state: Option<FrameState>,
    /// Median relative change of the inverse depths.
    pub median_inv_depth_change: f64,
    /// Median of adjusted / given inverse depth (the map's scale change is its inverse).
    pub median_inv_depth_ratio: f64,
}

/// The host points of `kf`'s level-0 point set (rays, inverse depths, host intensities and
/// gradient weights on every level of `host`).
pub fn host_points(kf: &Keyframe, host: &Pyramid, gradient_weight_gray_px: f32) -> HostPoints {
    host_points_every(kf, host, gradient_weight_gray_px, 1)
}

/// [`host_points`] of every `stride`-th point of the keyframe (in its order; 0 counts as 1).
pub fn host_points_every(
    kf: &Keyframe,
    host: &Pyramid,
    gradient_weight_gray_px: f32,
    stride: usize,
) -> HostPoints {
    let (rays, inv_depth): (Vec<_>, Vec<_>) = kf
        .levels
        .first()
        .map(|l| l.p_kf_m.as_slice())
        .unwrap_or_default()
        .iter()
        .step_by(stride.max(1))
        .filter(|p| p[2] > 0.0)
        .map(|p| {
            let p = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            (p / p.z, 1.0 / p.z)
        })
        .unzip();
    HostPoints::from_pyramid(
        host,
        kf.cameras.clone(),
        rays,
        inv_depth,
        gradient_weight_gray_px,
    )
}

/// The IMU between consecutive times: `t0 → times[0] → times[1] …`, each linearised at `bias`,
/// its covariance integrated with `noise` and multiplied by `inflate`.
pub fn imu_chain(
    t0: crate::time::TimeNs,
    times: impl IntoIterator<Item = crate::time::TimeNs>,
    bias: &crate::imu::ImuBias,
    imu: &[ImuSample],
    noise: &ImuNoise,
    inflate: f64,
) -> Vec<Preintegration> {
    let mut t_prev = t0;
    times
        .into_iter()
        .map(|t| {
            let mut pre = Preintegration::new(t_prev, *bias);
            pre.integrate(imu, t, Some(noise));
            pre.cov *= inflate;
            t_prev = t;
            pre
        })
        .collect()
}

/// At most `max` of `items` (at least one), evenly spaced, the last one included.
pub fn evenly_spaced<T: Clone>(items: &[T], max: usize) -> Vec<T> {
    let (n, max) = (items.len(), max.max(1));
    if n <= max {
        return items.to_vec();
    }
    (1..=max).map(|k| items[k * n / max - 1].clone()).collect()
}

/// Adjusts keyframe `kf` (its image pyramid `host_pyr`) with the views of `rec`; `imu` must cover the
/// keyframe's time onwards (the previous keyframe's, with `[keyframe_bundle] previous_host` and
/// `rec.previous`: the two are adjusted together, the previous one the gauge). `None` if there is
/// too little to adjust or the solution is unsound.
#[allow(clippy::too_many_arguments)]
pub fn bundle_adjust_keyframe(
    rec: &KeyframeRecord,
    kf: &Keyframe,
    host_pyr: &Pyramid,
    imu: &[ImuSample],
    t_body_cam: Isometry3<f64>,
    noise: ImuNoise,
    tracker_imu_noise_scale: f64,
    gradient_weight_gray_px: f32,
    cfg: &KeyframeBundleConfig,
) -> Option<AdjustedKeyframe> {
    let covers = |t| imu.first().is_some_and(|s| s.t <= t);
    let prev = rec
        .previous
        .as_deref()
        .filter(|p| cfg.previous_host && covers(p.state.nav.t));
    let start = prev.map_or(rec.start, |p| p.state);
    if rec.views.len() < cfg.min_views.max(1) || !covers(start.nav.t) {
        return None;
    }
    let levels = host_pyr.num_levels();
    let inflate = (tracker_imu_noise_scale * cfg.imu_noise_factor).powi(2);
    // The chain: [frames between the two keyframes, the keyframe itself,] the keyframe's views.
    let between = prev.map_or_else(Vec::new, |p| {
        evenly_spaced(&p.frames, cfg.previous_host_max_frames)
    });
    let n_before = prev.map_or(0, |_| between.len() + 1);
    let kf_view = prev.map(|_| (rec.start.nav.t, rec.start));
    let frames: Vec<(crate::time::TimeNs, FrameState)> = between
        .iter()
        .map(|(f, x)| (f.t, *x))
        .chain(kf_view)
        .chain(rec.views.iter().map(|(f, x)| (f.t, *x)))
        .collect();
    let pres = imu_chain(
        start.nav.t,
        frames.iter().map(|(t, _)| *t),
        &start.bias,
        imu,
        &noise,
        inflate,
    )
    .into_iter()
    .map(|mut p| {
        p.scale_rotation_noise(cfg.imu_rotation_noise_factor);
        if rec.gyro_turn_rad == Vector3::zeros() {
            p
        } else {
            turned(&p, &rec.gyro_turn_rad)
        }
    });
    let between_pyrs: Vec<Pyramid> = between
        .iter()
        .map(|(f, _)| Pyramid::from_u8(&f.image, levels))
        .collect();
    let view_pyrs: Vec<Pyramid> = rec
        .views
        .iter()
        .map(|(f, _)| Pyramid::from_u8(&f.image, levels))
        .collect();
    let pyramids = between_pyrs
        .iter()
        .chain(kf_view.map(|_| host_pyr))
        .chain(&view_pyrs);
    let own = host_points(kf, host_pyr, gradient_weight_gray_px);
    let (t_world_host_cam, host, chain_hosts) = match prev {
        Some(p) => {
            let pyr = Pyramid::from_u8(&p.image, levels);
            let gauge = host_points_every(
                &p.keyframe,
                &pyr,
                gradient_weight_gray_px,
                cfg.previous_host_point_stride,
            );
            let chain = ChainHost {
                view: between.len(),
                points: own,
            };
            (p.keyframe.t_world_cam, gauge, vec![chain])
        }
        None => (kf.t_world_cam, own, Vec::new()),
    };
    // The two-keyframe adjustment's own settings (`previous_host_*`).
    let (iterations_per_level, finest_level, start_velocity_std_m_s) = match prev {
        Some(_) => (
            cfg.previous_host_iterations_per_level,
            cfg.previous_host_finest_level,
            cfg.previous_host_velocity_std_m_s,
        ),
        None => (cfg.iterations_per_level, 0, cfg.velocity_std_m_s),
    };
    let problem = PhotometricBundle {
        t_world_host_cam,
        t_body_cam,
        host,
        start,
        views: frames
            .iter()
            .zip(pyramids)
            .zip(pres)
            .map(|(((_, x), pyramid), pre)| BundleView {
                pyramid,
                state: *x,
                pre,
            })
            .collect(),
        chain_hosts,
        noise,
        cfg: BundleConfig {
            iterations_per_level,
            finest_level,
            start_velocity_std_m_s,
            accel_bias_std_m_s2: cfg.accel_bias_std_m_s2,
            smoothness_rel_std: cfg.smoothness_rel_std,
            smoothness_scale_neutral: cfg.smoothness_scale_neutral,
            initial_depth_rel_std: cfg.depth_rel_std,
            ..BundleConfig::default()
        },
    };
    let mut r = problem.solve()?;
    let (given, adjusted) = match problem.chain_hosts.first() {
        Some(c) => (&c.points, r.chain_host_inv_depth_m_inv.first()?),
        None => (&problem.host, &r.inv_depth_m_inv),
    };
    let cam = kf.cameras.first()?;
    let mut changes = Vec::with_capacity(given.rays.len());
    let mut ratios = Vec::with_capacity(given.rays.len());
    let points: Vec<DepthPoint> = given
        .rays
        .iter()
        .zip(adjusted)
        .zip(&given.inv_depth_m_inv)
        .filter_map(|((ray, &rho), &rho0)| {
            if !(rho.is_finite() && rho > 0.0) {
                return None;
            }
            let uv = cam.project(ray)?;
            changes.push(((rho - rho0) / rho0).abs());
            ratios.push(rho / rho0);
            Some(DepthPoint {
                u_px: uv.x as f32,
                v_px: uv.y as f32,
                inv_depth_m_inv: rho as f32,
            })
        })
        .collect();
    if points.is_empty() {
        return None;
    }
    let mid = changes.len() / 2;
    let median_inv_depth_change = *changes.select_nth_unstable_by(mid, f64::total_cmp).1;
    let median_inv_depth_ratio = *ratios.select_nth_unstable_by(mid, f64::total_cmp).1;
    let keyframe_state = n_before.checked_sub(1).map(|k| r.views[k]);
    Some(AdjustedKeyframe {
        points,
        views: r.views.split_off(n_before),
        keyframe_state,
        median_inv_depth_change,
        median_inv_depth_ratio,
    })
}

/// The state `now` moved by the correction the adjustment made to an earlier view: that view was
/// tracked at `tracked` and adjusted to `adjusted`. The view's pose correction
/// `C = P_adj · P_tracked⁻¹` is applied to the pose, its velocity change (rotated by `C`) and its
/// bias changes are added. `now` is the view itself (same time): `adjusted`.
pub fn carry_correction(
    now: &FrameState,
    tracked: &FrameState,
    adjusted: &FrameState,
) -> FrameState {
    if now.nav.t == tracked.nav.t {
        return *adjusted;
    }
    let c = pose_of(adjusted) * pose_of(tracked).inverse();
    let p = c * pose_of(now);
    let mut x = *now;
    x.nav.r_world_body = p.rotation;
    x.nav.p_world_m = p.translation.vector;
    x.nav.v_world_m_s =
        adjusted.nav.v_world_m_s + c.rotation * (now.nav.v_world_m_s - tracked.nav.v_world_m_s);
    x.bias.gyro_rad_s += adjusted.bias.gyro_rad_s - tracked.bias.gyro_rad_s;
    x.bias.accel_m_s2 += adjusted.bias.accel_m_s2 - tracked.bias.accel_m_s2;
    x
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::{ImuBias, NavState};
    use crate::time::TimeNs;
    use nalgebra::{Translation3, UnitQuaternion};

    fn state(t_ns: i64, axis_angle: [f64; 3], p: [f64; 3], v: [f64; 3], ba: f64) -> FrameState {
        FrameState {
            nav: NavState {
                t: TimeNs(t_ns),
                r_world_body: UnitQuaternion::from_scaled_axis(Vector3::from(axis_angle)),
                p_world_m: Vector3::from(p),
                v_world_m_s: Vector3::from(v),
            },
            bias: ImuBias {
                gyro_rad_s: Vector3::new(0.001, -0.002, 0.0005),
                accel_m_s2: Vector3::new(ba, 0.02, -0.01),
            },
        }
    }

    /// The view as tracked, before its adjustment.
    fn tracked_view() -> FrameState {
        state(
            100,
            [0.1, 0.2, 0.3],
            [1.0, 2.0, 3.0],
            [0.5, 0.0, -0.1],
            0.01,
        )
    }

    #[test]
    fn evenly_spaced_keeps_the_last_item_and_at_most_max() {
        let items: Vec<u32> = (0..10).collect();
        assert_eq!(evenly_spaced(&items, 3), vec![2, 5, 9]);
        assert_eq!(evenly_spaced(&items, 10), items);
        assert_eq!(evenly_spaced(&items, 20), items);
        assert_eq!(evenly_spaced(&items, 0), vec![9]);
        assert!(evenly_spaced::<u32>(&[], 4).is_empty());
    }

    #[test]
    fn the_view_itself_becomes_the_adjusted_state() {
        let tracked = tracked_view();
        let adjusted = state(
            100,
            [0.11, 0.19, 0.3],
            [1.02, 2.0, 2.99],
            [0.52, 0.01, -0.1],
            0.03,
        );
        assert_eq!(carry_correction(&tracked, &tracked, &adjusted), adjusted);
    }

    #[test]
    fn a_later_state_keeps_its_motion_relative_to_the_corrected_view() {
        let tracked = tracked_view();
        let adjusted = state(
            100,
            [0.12, 0.18, 0.31],
            [1.03, 1.98, 2.99],
            [0.53, 0.01, -0.1],
            0.03,
        );
        // `now` is 0.1 s later: the tracked view moved by a body-frame motion M, velocity turned.
        let m = Isometry3::from_parts(
            Translation3::new(0.05, -0.01, 0.002),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.03, -0.02)),
        );
        let mut now = tracked;
        now.nav.t = TimeNs(200);
        let p_now = pose_of(&tracked) * m;
        now.nav.r_world_body = p_now.rotation;
        now.nav.p_world_m = p_now.translation.vector;
        now.nav.v_world_m_s = Vector3::new(0.6, 0.05, -0.1);
        now.bias.accel_m_s2.x = 0.015;
        let x = carry_correction(&now, &tracked, &adjusted);
        // The adjusted view followed by the same body motion.
        let expect = pose_of(&adjusted) * m;
        let got = pose_of(&x);
        assert!((got.translation.vector - expect.translation.vector).norm() < 1e-12);
        assert!(got.rotation.angle_to(&expect.rotation) < 1e-12);
        let c = pose_of(&adjusted) * pose_of(&tracked).inverse();
        let v_expect =
            adjusted.nav.v_world_m_s + c.rotation * (now.nav.v_world_m_s - tracked.nav.v_world_m_s);
        assert!((x.nav.v_world_m_s - v_expect).norm() < 1e-12);
        assert!((x.bias.accel_m_s2.x - (0.015 + 0.02)).abs() < 1e-12);
        assert_eq!(x.nav.t, TimeNs(200));
    }

    /// `previous_host_point_stride`: the gauge keeps every k-th point of its keyframe, each with
    /// its own ray and inverse depth, and a stride of 1 (or 0) keeps them all.
    #[test]
    fn the_gauge_keeps_every_kth_point_of_its_keyframe() {
        use crate::camera::CameraModel;
        use crate::runtime::guessed_keyframe::textured_pyramid;
        use crate::tracking::TrackerConfig;
        let cam = CameraModel::euroc_cam0();
        let pyr = textured_pyramid(&cam);
        let points: Vec<DepthPoint> = (0..40)
            .map(|i| DepthPoint {
                u_px: 100.0 + 12.0 * (i % 8) as f32,
                v_px: 100.0 + 15.0 * (i / 8) as f32,
                inv_depth_m_inv: 0.2 + 0.01 * i as f32,
            })
            .collect();
        let kf = Keyframe::new(
            1,
            TimeNs(0),
            &pyr,
            &cam,
            Isometry3::identity(),
            &points,
            &TrackerConfig::default(),
        );
        let all = host_points(&kf, &pyr, 8.0);
        assert_eq!(all.rays.len(), kf.levels[0].p_kf_m.len());
        assert!(all.rays.len() >= 20, "{}", all.rays.len());
        assert_eq!(host_points_every(&kf, &pyr, 8.0, 0).rays, all.rays);
        let every3 = host_points_every(&kf, &pyr, 8.0, 3);
        assert_eq!(every3.rays.len(), all.rays.len().div_ceil(3));
        for (k, (ray, rho)) in every3.rays.iter().zip(&every3.inv_depth_m_inv).enumerate() {
            assert_eq!(*ray, all.rays[3 * k]);
            assert_eq!(*rho, all.inv_depth_m_inv[3 * k]);
        }
        // Each level's samples are the kept points' (one intensity per point and level).
        assert!(
            every3
                .intensity
                .iter()
                .all(|l| l.len() == every3.rays.len())
        );
    }
}
