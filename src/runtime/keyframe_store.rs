//! Keyframes kept after they stop being tracked, so that the tracker can return to the *closest*
//! keyframe (section III-C tracks "the closest keyframe", not the newest) when the camera comes
//! back to a place it has mapped — the demo's figure eight and a room flight like V1_01 pass the
//! same places every lap.
//!
//! Tracking against an old keyframe measures the pose against a map built when the drift was
//! smaller, instead of chaining one more relative pose onto the newest keyframe: the drift
//! accumulated since is corrected (the pose jumps back) instead of being inherited by the next
//! map. What is stored is the tracking keyframe itself (points, reference intensities and
//! inverse-compositional Jacobians per level, ≈ 0.3 MB, no image) and the mapper's final map of it
//! (to seed the next keyframe's depths by propagation from the keyframe actually tracked).
//!
//! A keyframe is not stored when an older one already covers its view (baseline and rotation
//! below the redundancy limits): the older one is the better anchor. The store is bounded by
//! `max_keyframes`; once full, new keyframes are not stored (the oldest, least drifted anchors
//! are kept).

use crate::mapping::semidense::SemidenseMap;
use crate::tracking::Keyframe;
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// `[reuse]`: returning to stored keyframes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReuseConfig {
    /// Look for a stored keyframe before starting a new one.
    pub enabled: bool,
    /// Keyframes stored at most.
    pub max_keyframes: usize,
    /// A stored keyframe is a candidate if at least this fraction of its points (pyramid level
    /// `overlap_level`) would project into the current image. Above the tracker's
    /// `keyframe_min_overlap`, or it would ask for a new keyframe at once.
    pub min_overlap: f64,
    /// Pyramid level whose points predict the overlap (coarser = cheaper).
    pub overlap_level: usize,
    /// A candidate's distance from the current camera over its median depth is at most this.
    pub max_baseline_ratio: f64,
    /// A candidate's rotation from the current camera is at most this, rad.
    pub max_rotation_rad: f64,
    /// When the tracker switches to a stored keyframe, the current pose is made this uncertain
    /// (standard deviation per axis, m) so that the drift since the keyframe was mapped can be
    /// corrected instead of being rejected as inconsistent with the IMU.
    pub switch_position_std_m: f64,
    /// The same for the heading (rotation about the world vertical), rad. Tilt is not made
    /// uncertain: gravity observes it, and a stored keyframe that disagrees has a bad map.
    pub switch_yaw_std_rad: f64,
    /// For this many frames after a switch…
    pub probation_frames: u32,
    /// …a stored keyframe with fewer inliers than this fraction is left again. (0.6 rather than
    /// 0.5: on demo render seeds 1–12 the median ATE went 10.2 → 6.8 cm and the diverged runs 4 →
    /// 3, at 17 resets instead of 12 — a stored keyframe left again sends the tracker back to
    /// the keyframe it was leaving, which is sometimes lost before a new one is ready.)
    pub probation_min_inlier_ratio: f64,
    /// A keyframe is not stored if an older stored one is closer than this (baseline over
    /// median depth)…
    pub redundant_baseline_ratio: f64,
    /// …and rotated less than this from it, rad.
    pub redundant_rotation_rad: f64,
    /// The keyframe window is kept across a return instead of restarted at the first keyframe
    /// after it: moved by the heading and position part of the switch's drift correction (a
    /// change of gauge, [`crate::smoother::KeyframeWindow::transform_world`]), the new keyframe
    /// joined to its newest by the IMU and by the relative pose through that correction — so
    /// the IMU's hold on the velocity survives the return. (S-V101 seeds 1–6 0.42–3.98 m with
    /// it, 0.20–96.5 m without; docs/odometry-log.md, *A return that keeps the keyframe window*.)
    pub keep_window: bool,
    /// A stored keyframe that fails its probation sends the tracker back to the keyframe it
    /// left only if at least this fraction of that one's points (`overlap_level`) is still in
    /// view; otherwise a new keyframe is started from the current frame, on the failing one. (In
    /// the demo's hover turn the keyframe left lies seconds behind and out of view: going back
    /// to it was how every reset of the demo happened.) 0 = always go back.
    pub return_min_overlap: f64,
}

impl Default for ReuseConfig {
    fn default() -> Self {
        ReuseConfig {
            enabled: true,
            max_keyframes: 400,
            min_overlap: 0.85,
            overlap_level: 2,
            max_baseline_ratio: 0.2,
            max_rotation_rad: 0.3,
            switch_position_std_m: 0.1,
            switch_yaw_std_rad: 0.03,
            probation_frames: 3,
            probation_min_inlier_ratio: 0.6,
            redundant_baseline_ratio: 0.04,
            redundant_rotation_rad: 0.1,
            keep_window: true,
            return_min_overlap: 0.4,
        }
    }
}

/// A keyframe no longer tracked, kept for returning to it.
#[derive(Clone, Debug)]
pub struct StoredKeyframe {
    /// The tracking keyframe (its `t_world_cam` in the tracker's world).
    pub kf: Keyframe,
    /// The mapper's map of it (pose in the mapper's world at the time it was mapped).
    pub map: Arc<SemidenseMap>,
}

/// How far from a stored keyframe a camera may be for it to be tracked against.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReachLimits {
    /// Distance to the keyframe / its median depth.
    pub max_baseline_ratio: f64,
    /// Rotation from the keyframe, rad.
    pub max_rotation_rad: f64,
    /// Predicted fraction of its points in view.
    pub min_overlap: f64,
}

/// Keyframes kept for tracking against the closest one.
#[derive(Debug)]
pub struct KeyframeStore {
    cfg: ReuseConfig,
    entries: Vec<StoredKeyframe>,
}

/// Baseline over the keyframe's median depth and rotation angle (rad) from a keyframe to a
/// camera pose.
fn distance(kf: &Keyframe, t_world_cam: &Isometry3<f64>) -> (f64, f64) {
    let t_kc = kf.t_world_cam.inverse() * t_world_cam;
    (
        t_kc.translation.vector.norm() / kf.median_depth_m.max(1e-3),
        t_kc.rotation.angle(),
    )
}

impl KeyframeStore {
    pub fn new(cfg: ReuseConfig) -> Self {
        KeyframeStore {
            cfg,
            entries: Vec::new(),
        }
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    pub fn get(&self, id: u32) -> Option<&StoredKeyframe> {
        self.entries.iter().find(|e| e.kf.id == id)
    }

    /// Keeps `kf` (replacing a stored keyframe of the same id). Returns `false` if it was not
    /// kept: the store is full, or an older stored keyframe already covers its view.
    pub fn insert(&mut self, kf: Keyframe, map: Arc<SemidenseMap>) -> bool {
        if let Some(e) = self.entries.iter_mut().find(|e| e.kf.id == kf.id) {
            *e = StoredKeyframe { kf, map };
            return true;
        }
        if kf.num_points() == 0 || self.entries.len() >= self.cfg.max_keyframes {
            return false;
        }
        let redundant = self.entries.iter().any(|e| {
            let (b, r) = distance(&e.kf, &kf.t_world_cam);
            b < self.cfg.redundant_baseline_ratio && r < self.cfg.redundant_rotation_rad
        });
        if redundant {
            return false;
        }
        self.entries.push(StoredKeyframe { kf, map });
        true
    }

    /// Multiplies the depths of stored keyframe `id` by `depth_factor` about its camera, in the
    /// keyframe tracked against and in its map (its scale corrected, `[window]
    /// stored_map_scale_gain`). Returns whether it is stored.
    pub fn scale_depths(&mut self, id: u32, depth_factor: f64) -> bool {
        let Some(e) = self.entries.iter_mut().find(|e| e.kf.id == id) else {
            return false;
        };
        if !(depth_factor.is_finite() && depth_factor > 0.0) {
            return false;
        }
        e.kf.scale_depths(depth_factor);
        Arc::make_mut(&mut e.map).scale_inv_depths(1.0 / depth_factor);
        true
    }

    /// Moves stored keyframe `id` (the keyframe window corrected it).
    pub fn set_pose(&mut self, id: u32, t_world_cam: Isometry3<f64>) {
        if let Some(e) = self.entries.iter_mut().find(|e| e.kf.id == id) {
            e.kf.t_world_cam = t_world_cam;
        }
    }

    /// The stored keyframe a camera at `t_world_cam` should track against: among those not
    /// `excluded`, within the baseline and rotation limits, the one with the largest predicted
    /// overlap, if that reaches `min_overlap`. Returns its id and the predicted overlap.
    pub fn closest(
        &self,
        t_world_cam: &Isometry3<f64>,
        border_px: f64,
        excluded: impl Fn(u32) -> bool,
    ) -> Option<(u32, f64)> {
        self.closest_within(t_world_cam, border_px, excluded, &self.limits())
    }

    /// `[reuse]`'s reach: `max_baseline_ratio`, `max_rotation_rad`, `min_overlap`.
    pub fn limits(&self) -> ReachLimits {
        let c = &self.cfg;
        ReachLimits {
            max_baseline_ratio: c.max_baseline_ratio,
            max_rotation_rad: c.max_rotation_rad,
            min_overlap: c.min_overlap,
        }
    }

    /// [`KeyframeStore::closest`] within other limits than `[reuse]`'s.
    pub fn closest_within(
        &self,
        t_world_cam: &Isometry3<f64>,
        border_px: f64,
        excluded: impl Fn(u32) -> bool,
        l: &ReachLimits,
    ) -> Option<(u32, f64)> {
        self.closest_seen_from(|_| *t_world_cam, border_px, excluded, l)
    }

    /// [`KeyframeStore::closest_within`] with the camera's pose given per stored keyframe, in
    /// that keyframe's world: `t_world_cam(id)` (a loop closure places the drifted odometry
    /// differently against each old map).
    pub fn closest_seen_from(
        &self,
        t_world_cam: impl Fn(u32) -> Isometry3<f64>,
        border_px: f64,
        excluded: impl Fn(u32) -> bool,
        l: &ReachLimits,
    ) -> Option<(u32, f64)> {
        // Nearest first; the overlap (a projection of every point) only until one passes.
        let mut near: Vec<(f64, u32, &StoredKeyframe, Isometry3<f64>)> = self
            .entries
            .iter()
            .filter(|e| !excluded(e.kf.id))
            .filter_map(|e| {
                let at = t_world_cam(e.kf.id);
                let (b, r) = distance(&e.kf, &at);
                let d = b / l.max_baseline_ratio.max(1e-9) + r / l.max_rotation_rad.max(1e-9);
                (b <= l.max_baseline_ratio && r <= l.max_rotation_rad)
                    .then_some((d, e.kf.id, e, at))
            })
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        near.into_iter().find_map(|(_, id, e, at)| {
            let o =
                e.kf.predicted_overlap(&at, self.cfg.overlap_level, border_px);
            (o >= l.min_overlap).then_some((id, o))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraModel;
    use crate::image::Pyramid;
    use crate::time::TimeNs;
    use crate::tracking::{DepthPoint, NUM_LEVELS, TrackerConfig};
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    /// A keyframe at `t_world_cam` seeing a textured wall 2 m ahead.
    fn keyframe(id: u32, t_world_cam: Isometry3<f64>) -> Keyframe {
        let cam = CameraModel::euroc_cam0();
        let mut pyr = Pyramid::new(cam.width, cam.height, NUM_LEVELS);
        let img: Vec<f32> = (0..cam.width * cam.height)
            .map(|i| {
                let (x, y) = ((i % cam.width) as f32, (i / cam.width) as f32);
                128.0 + 60.0 * (x * 0.21).sin() * (y * 0.17).cos()
            })
            .collect();
        pyr.fill_from_f32(&crate::image::Image::from_vec(cam.width, cam.height, img));
        let pts: Vec<DepthPoint> = (8..cam.height - 8)
            .step_by(6)
            .flat_map(|v| {
                (8..cam.width - 8).step_by(6).map(move |u| DepthPoint {
                    u_px: u as f32,
                    v_px: v as f32,
                    inv_depth_m_inv: 0.5,
                })
            })
            .collect();
        let cfg = TrackerConfig::default();
        Keyframe::new(id, TimeNs(id as i64), &pyr, &cam, t_world_cam, &pts, &cfg)
    }

    fn map() -> Arc<SemidenseMap> {
        Arc::new(SemidenseMap {
            t_world_cam: Isometry3::identity(),
            camera: CameraModel::euroc_cam0(),
            points: Vec::new(),
        })
    }

    fn pose(x_m: f64, yaw_rad: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x_m, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw_rad),
        )
    }

    #[test]
    fn a_stored_keyframe_scaled_has_its_depths_and_its_map_scaled() {
        let mut store = KeyframeStore::new(ReuseConfig::default());
        let mut m = (*map()).clone();
        m.points.push(crate::mapping::semidense::MapPoint {
            u_px: 10.0,
            v_px: 20.0,
            inv_depth_m_inv: 0.5,
            inv_depth_std_m_inv: 0.01,
            num_views: 3,
        });
        let shared = Arc::new(m);
        assert!(store.insert(keyframe(1, pose(0.0, 0.0)), shared.clone()));
        assert!(store.scale_depths(1, 0.9));
        let s = store.get(1).unwrap();
        // The wall 2 m ahead is 1.8 m ahead in both; the map handed in elsewhere is not touched.
        assert!(
            (s.kf.median_depth_m - 1.8).abs() < 1e-4,
            "{}",
            s.kf.median_depth_m
        );
        let p = s.map.points[0];
        assert!((p.inv_depth_m_inv - 0.5 / 0.9).abs() < 1e-6, "{p:?}");
        assert!((p.inv_depth_std_m_inv - 0.01 / 0.9).abs() < 1e-6, "{p:?}");
        assert_eq!(shared.points[0].inv_depth_m_inv, 0.5);
        // Not stored, or not a factor: nothing.
        assert!(!store.scale_depths(2, 0.9));
        assert!(!store.scale_depths(1, f64::NAN) && !store.scale_depths(1, 0.0));
        assert!((store.get(1).unwrap().kf.median_depth_m - 1.8).abs() < 1e-4);
    }

    #[test]
    fn predicted_overlap_falls_as_the_camera_turns_away() {
        let kf = keyframe(0, Isometry3::identity());
        let same = kf.predicted_overlap(&Isometry3::identity(), 2, 2.0);
        assert!(same > 0.99, "{same}");
        // Turning by a fifth of the horizontal field of view loses about a fifth of the points.
        let turned = kf.predicted_overlap(&pose(0.0, 0.3), 2, 2.0);
        assert!(turned > 0.4 && turned < 0.85, "{turned}");
        // Facing away: none.
        assert_eq!(kf.predicted_overlap(&pose(0.0, 3.0), 2, 2.0), 0.0);
    }

    #[test]
    fn closest_is_the_nearest_within_limits_that_overlaps_and_honours_exclusions() {
        let mut store = KeyframeStore::new(ReuseConfig::default());
        assert!(store.insert(keyframe(1, pose(0.0, 0.0)), map()));
        assert!(store.insert(keyframe(2, pose(0.3, 0.0)), map()));
        assert!(store.insert(keyframe(3, pose(0.0, 0.5)), map()));
        // 0.05 m from keyframe 2, 0.25 m (0.125 of the 2 m depth) from keyframe 1: 2 is closest;
        // excluding it, keyframe 1 is still within the 0.2 limit and sees 90 % of the view.
        let at = pose(0.25, 0.0);
        assert_eq!(store.closest(&at, 2.0, |_| false).map(|c| c.0), Some(2));
        let (id, overlap) = store.closest(&at, 2.0, |id| id == 2).unwrap();
        assert_eq!(id, 1);
        assert!(overlap > 0.85 && overlap < 1.0, "{overlap}");
        // 0.6 m (0.3) from keyframe 1 is beyond the baseline limit.
        assert_eq!(store.closest(&pose(-0.6, 0.0), 2.0, |_| false), None);
        // Turned 0.25 rad from keyframes 1 and 3: within the rotation limit, but too little of
        // either would be in view (keyframe 2, 0.3 m to the side the camera turned to, would).
        assert_eq!(store.closest(&pose(0.0, 0.25), 2.0, |id| id == 2), None);
        assert_eq!(
            store.closest(&pose(0.0, 0.25), 2.0, |_| false).map(|c| c.0),
            Some(2)
        );
        // Turned 0.45 rad: keyframe 3.
        assert_eq!(
            store.closest(&pose(0.0, 0.45), 2.0, |_| false).map(|c| c.0),
            Some(3)
        );
        // Facing away from all of them: nothing.
        assert_eq!(store.closest(&pose(0.0, 3.0), 2.0, |_| false), None);
    }

    /// A loop closure places the drifted camera differently in each stored keyframe's world: a
    /// keyframe out of reach from the odometry's pose is found from the pose seen in its world.
    #[test]
    fn closest_seen_from_looks_at_each_keyframe_from_its_own_world() {
        let mut store = KeyframeStore::new(ReuseConfig::default());
        assert!(store.insert(keyframe(1, pose(0.0, 0.0)), map()));
        assert!(store.insert(keyframe(2, pose(1.5, 0.0)), map()));
        let limits = ReachLimits {
            max_baseline_ratio: 0.2,
            max_rotation_rad: 0.3,
            min_overlap: 0.85,
        };
        // The odometry has drifted 0.8 m along x: out of reach of both (0.8 / 0.7 m, over the
        // 2 m depth 0.4 / 0.35).
        let drifted = pose(0.8, 0.0);
        let same = |_| drifted;
        assert_eq!(store.closest_seen_from(same, 2.0, |_| false, &limits), None);
        // In keyframe 1's world the camera is back 0.75 m (0.05 m from it); keyframe 2's world
        // is the odometry's.
        let back = Isometry3::translation(-0.75, 0.0, 0.0);
        let seen = |id: u32| if id == 1 { back * drifted } else { drifted };
        let (id, overlap) = store
            .closest_seen_from(seen, 2.0, |_| false, &limits)
            .unwrap();
        assert_eq!(id, 1);
        assert!(overlap > 0.9, "{overlap}");
        // Excluded, nothing else is in reach.
        assert_eq!(
            store.closest_seen_from(seen, 2.0, |id| id == 1, &limits),
            None
        );
        // The same pose everywhere is `closest_within`.
        assert_eq!(
            store.closest_within(&pose(0.05, 0.0), 2.0, |_| false, &limits),
            store.closest_seen_from(|_| pose(0.05, 0.0), 2.0, |_| false, &limits)
        );
    }

    #[test]
    fn redundant_and_overflowing_keyframes_are_not_stored() {
        let cfg = ReuseConfig {
            max_keyframes: 2,
            ..ReuseConfig::default()
        };
        let mut store = KeyframeStore::new(cfg);
        assert!(store.insert(keyframe(1, pose(0.0, 0.0)), map()));
        // 0.05 m at 2 m depth = 0.025 < 0.04 and no rotation: covered by keyframe 1.
        assert!(!store.insert(keyframe(2, pose(0.05, 0.0)), map()));
        assert!(store.insert(keyframe(3, pose(0.5, 0.0)), map()));
        assert!(!store.insert(keyframe(4, pose(2.0, 0.0)), map()), "full");
        assert_eq!(store.len(), 2);
        // The same id replaces (a refreshed map), even when full.
        assert!(store.insert(keyframe(3, pose(0.6, 0.0)), map()));
        store.set_pose(3, pose(0.7, 0.0));
        let p = store.get(3).unwrap().kf.t_world_cam.translation.vector.x;
        assert!((p - 0.7).abs() < 1e-12);
    }
}
