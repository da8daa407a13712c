//! Keyframes of guessed depths, made without the mapper: a turn on the spot's (`[bootstrap]
//! fill_without_mapper`: the tracked map's points moved into the new camera — a rotation keeps
//! their depths meaningful — and its other gradient pixels at their median inverse depth) and a
//! first map started in flight (`[bootstrap] reinit_guessed_depths`: every gradient pixel at the
//! last map's median). Any depth serves a rotation: the photometric residuals of the guessed
//! pixels constrain what changes (eq. 23–26), and the mapper's own map replaces the guesses.
//!
//! The build is a pure function of a [`GuessedKeyframeJob`], so it runs on any thread: the
//! turn on the spot's on [`super::keyframe_builder`]'s, off the tracking thread (4–12 ms on the
//! demo's 752x480 frames that used to fall inside one tracked frame), the first map in flight's
//! inline (rare: once after a loss).

use super::map_keyframe::depth_points;
use super::mapping_worker::MapSnapshot;
use crate::camera::{CameraModel, PixelRays};
use crate::image::{Image, Pyramid};
use crate::mapping::semidense::{MapPoint, SemidenseMap};
use crate::time::TimeNs;
use crate::tracking::{DepthPoint, Keyframe, TrackerConfig, select_gradient_pixels};
use nalgebra::{Isometry3, Point3, Vector2};
use std::sync::Arc;

/// What a keyframe of guessed depths is made of: the frame that becomes it, and the map whose
/// points it takes over.
pub struct GuessedKeyframeJob {
    /// The new keyframe's id (the mapper's, started from the same frame).
    pub id: u32,
    /// Time of the frame.
    pub t: TimeNs,
    pub image: Arc<Image<u8>>,
    /// The frame's pyramid (its gradients computed here if they are not yet).
    pub pyramid: Pyramid,
    /// The frame's camera pose, the tracker's world.
    pub t_world_cam: Isometry3<f64>,
    /// The odometry's map from its world to the mapper's (the snapshot's map is posed there).
    pub mapper_from_world: Isometry3<f64>,
    /// The map tracked (a keyframe's, in its camera's pixels) and that keyframe's camera in the
    /// new one, `T_new_old`: its points move into the new keyframe. `None`: no points, guesses
    /// only.
    pub moved_from: Option<(Arc<SemidenseMap>, Isometry3<f64>)>,
    /// The inverse depth guessed when the moved points give no median, 1/m (the last map's).
    pub fallback_median_inv_depth_m_inv: Option<f32>,
}

/// What every build shares: the camera, its rays, the tracker's settings.
#[derive(Clone, Debug)]
pub struct GuessSettings {
    pub camera: CameraModel,
    pub rays: Arc<PixelRays>,
    pub tracking: TrackerConfig,
    /// Border the moved points are kept inside, px (at least 1).
    pub border_px: f64,
    /// No keyframe of fewer points (`[bootstrap] min_keyframe_points`).
    pub min_keyframe_points: usize,
}

/// The tracker's keyframe of `job` and the snapshot to install it by (its map: the moved points,
/// in the mapper's world) — `None` when there is no depth to guess (no moved points and no
/// fallback) or fewer than `min_keyframe_points` points in all.
pub fn build_guessed_keyframe(
    job: GuessedKeyframeJob,
    s: &GuessSettings,
) -> Option<(Keyframe, MapSnapshot)> {
    let GuessedKeyframeJob {
        id,
        t,
        image,
        mut pyramid,
        t_world_cam,
        mapper_from_world,
        moved_from,
        fallback_median_inv_depth_m_inv,
    } = job;
    let points = moved_from.map_or_else(Vec::new, |(map, t_new_old)| {
        moved_map_points(&map, &t_new_old, &s.camera, s.border_px.max(1.0))
    });
    let map = SemidenseMap {
        t_world_cam: mapper_from_world * t_world_cam,
        camera: s.camera,
        points,
    };
    let median_inv = median_inv_depth(&map).or(fallback_median_inv_depth_m_inv)?;
    pyramid.ensure_gradients();
    let fill = depthless_points(&pyramid, &map, median_inv, &s.tracking);
    if map.points.len() + fill.len() < s.min_keyframe_points {
        return None;
    }
    let mut pts = depth_points(&map);
    pts.extend(fill);
    let kf = Keyframe::from_rays(id, t, &pyramid, &s.rays, t_world_cam, &pts, &s.tracking);
    let snapshot = MapSnapshot {
        seq: 0,
        keyframe_id: id,
        keyframe_t: t,
        keyframe_image: image,
        keyframe_pyramid: Arc::new(pyramid),
        map: Arc::new(map),
        views: 0,
        forward_views: 0,
        time_s: 0.0,
        tracker_keyframe: None,
    };
    Some((kf, snapshot))
}

/// The keyframe's level-0 gradient pixels (as the tracker selects them) in cells of its image
/// that `map` has no point in, at the map's median inverse depth.
pub fn depthless_points(
    pyr: &Pyramid,
    map: &SemidenseMap,
    median_inv: f32,
    cfg: &TrackerConfig,
) -> Vec<DepthPoint> {
    let cell = (2 * cfg.select_cell_px).max(1);
    let (w, h) = (pyr.level(0).width(), pyr.level(0).height());
    let (cw, ch) = (w.div_ceil(cell), h.div_ceil(cell));
    let mut occupied = vec![false; cw * ch];
    for p in &map.points {
        let (cx, cy) = (
            p.u_px.max(0.0) as usize / cell,
            p.v_px.max(0.0) as usize / cell,
        );
        if cx < cw && cy < ch {
            occupied[cy * cw + cx] = true;
        }
    }
    select_gradient_pixels(pyr, cfg)
        .into_iter()
        .filter(|&(x, y)| !occupied[(y as usize / cell) * cw + x as usize / cell])
        .map(|(x, y)| DepthPoint {
            u_px: x as f32,
            v_px: y as f32,
            inv_depth_m_inv: median_inv,
        })
        .collect()
}

/// The points of `map` (a keyframe's) as seen from a camera at `t_new_old` (the keyframe's
/// camera in the new one), in the new camera's pixels: each moved to its nearest integer pixel at
/// least `border_px` inside the image, the nearest point where several land on one pixel; inverse
/// depth and its standard deviation scaled by the change of depth.
fn moved_map_points(
    map: &SemidenseMap,
    t_new_old: &Isometry3<f64>,
    camera: &CameraModel,
    border_px: f64,
) -> Vec<MapPoint> {
    let mut moved: Vec<(usize, MapPoint)> = Vec::with_capacity(map.points.len());
    for p in &map.points {
        if p.inv_depth_m_inv.is_nan() || p.inv_depth_m_inv <= 0.0 {
            continue;
        }
        let Some(ray) = camera.unproject(&Vector2::new(p.u_px as f64, p.v_px as f64)) else {
            continue;
        };
        let x_new = t_new_old * Point3::from(ray / p.inv_depth_m_inv as f64);
        let Some(uv) = camera.project(&x_new.coords) else {
            continue;
        };
        let uv = uv.map(f64::round);
        if !camera.in_image(&uv, border_px) {
            continue;
        }
        let inv = (1.0 / x_new.z) as f32;
        moved.push((
            uv.y as usize * camera.width + uv.x as usize,
            MapPoint {
                u_px: uv.x as f32,
                v_px: uv.y as f32,
                inv_depth_m_inv: inv,
                inv_depth_std_m_inv: p.inv_depth_std_m_inv * inv / p.inv_depth_m_inv,
                num_views: p.num_views,
            },
        ));
    }
    // Row-major pixel order, the nearest point first on each pixel; then one per pixel.
    moved.sort_by(|a, b| {
        a.0.cmp(&b.0)
            .then(b.1.inv_depth_m_inv.total_cmp(&a.1.inv_depth_m_inv))
    });
    moved.dedup_by_key(|m| m.0);
    moved.into_iter().map(|(_, p)| p).collect()
}

/// Median inverse depth of a map's points, 1/m.
pub fn median_inv_depth(map: &SemidenseMap) -> Option<f32> {
    let mut inv: Vec<f32> = map.points.iter().map(|p| p.inv_depth_m_inv).collect();
    if inv.is_empty() {
        return None;
    }
    let m = inv.len() / 2;
    Some(*inv.select_nth_unstable_by(m, f32::total_cmp).1)
}

/// A sinusoidal texture over the whole image, for tests that need gradient pixels everywhere.
#[cfg(test)]
pub(crate) fn textured_pyramid(cam: &CameraModel) -> Pyramid {
    let img = Image::from_fn(cam.width, cam.height, |x, y| {
        128.0f32 + 60.0 * ((x as f32) * 0.3).sin() * ((y as f32) * 0.25).cos()
    });
    let mut pyr = Pyramid::new(cam.width, cam.height, crate::tracking::NUM_LEVELS);
    pyr.fill_from_f32(&img);
    pyr
}

/// A keyframe's map for tests: points at 2 m on a grid of `step_px` over the left half of the
/// image, `margin_px` from its edges.
#[cfg(test)]
pub(crate) fn left_half_map(cam: &CameraModel, margin_px: u32, step_px: usize) -> SemidenseMap {
    let points = (margin_px..cam.height as u32 - margin_px)
        .step_by(step_px)
        .flat_map(|v| {
            (margin_px..cam.width as u32 / 2)
                .step_by(step_px)
                .map(move |u| (u, v))
        })
        .map(|(u, v)| MapPoint::at_2_m(u as f32, v as f32))
        .collect();
    SemidenseMap {
        t_world_cam: Isometry3::identity(),
        camera: *cam,
        points,
    }
}

/// A turn on the spot's job for tests: a camera turned 0.1 rad to the right of a keyframe whose
/// map (a sparse grid) covers the left half of its image at 2 m, on [`textured_pyramid`].
#[cfg(test)]
pub(crate) fn turned_job(cam: &CameraModel, id: u32) -> GuessedKeyframeJob {
    let map = left_half_map(cam, 20, 24);
    let t_new_old = Isometry3::new(nalgebra::Vector3::zeros(), nalgebra::Vector3::y() * -0.1);
    GuessedKeyframeJob {
        id,
        t: TimeNs(1_000_000_000),
        image: Arc::new(Image::new(cam.width, cam.height)),
        pyramid: textured_pyramid(cam),
        t_world_cam: t_new_old.inverse(),
        mapper_from_world: Isometry3::translation(0.0, 0.0, 1.0),
        moved_from: Some((Arc::new(map), t_new_old)),
        fallback_median_inv_depth_m_inv: None,
    }
}

/// The settings of the tests' builds.
#[cfg(test)]
pub(crate) fn test_settings(cam: &CameraModel) -> GuessSettings {
    GuessSettings {
        camera: *cam,
        rays: Arc::new(PixelRays::new(cam)),
        tracking: TrackerConfig::default(),
        border_px: 2.0,
        min_keyframe_points: 100,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::Vector3;

    /// A turn on the spot's keyframe: the map's points moved in (their pixels and depths from
    /// [`moved_map_points`]), the gradient pixels of the cells they leave empty at their median
    /// inverse depth, posed at the frame (the snapshot's map in the mapper's world).
    #[test]
    fn a_turned_keyframe_takes_the_moved_points_and_fills_the_rest_at_their_median() {
        let cam = CameraModel::euroc_cam0();
        let s = test_settings(&cam);
        let job = turned_job(&cam, 3);
        let (map, t_new_old) = job.moved_from.clone().unwrap();
        let moved = moved_map_points(&map, &t_new_old, &cam, 2.0);
        let (t_world_cam, mapper_from_world) = (job.t_world_cam, job.mapper_from_world);
        let (kf, snap) = build_guessed_keyframe(job, &s).expect("enough points");
        assert_eq!(snap.map.points, moved);
        assert_eq!(snap.keyframe_id, 3);
        assert_eq!(kf.id, 3);
        assert_eq!(kf.t_world_cam, t_world_cam);
        assert_eq!(snap.map.t_world_cam, mapper_from_world * t_world_cam);
        // (The turn changes each point's depth by a few %.)
        let median = median_inv_depth(&snap.map).unwrap();
        assert!((median - 0.5).abs() < 0.03, "{median}");
        let fill = depthless_points(&snap.keyframe_pyramid, &snap.map, median, &s.tracking);
        assert!(fill.len() > 100, "{}", fill.len());
        assert!(kf.num_points() > moved.len(), "the fill is tracked too");
        // Most points are the fill, at the moved points' median.
        let fill_depth_m = 1.0 / median as f64;
        assert!(
            (kf.median_depth_m - fill_depth_m).abs() < 1e-3 * fill_depth_m,
            "{} {fill_depth_m}",
            kf.median_depth_m
        );
    }

    /// No depth to guess (no points moved in, no map tracked before) or too few points: nothing
    /// is built. A first map in flight (nothing moved in, the last map's median given): every
    /// gradient pixel at that depth.
    #[test]
    fn without_a_depth_to_guess_or_enough_points_nothing_is_built() {
        let cam = CameraModel::euroc_cam0();
        let mut s = test_settings(&cam);
        let guesses_only = |fallback| GuessedKeyframeJob {
            moved_from: None,
            fallback_median_inv_depth_m_inv: fallback,
            ..turned_job(&cam, 4)
        };
        assert!(build_guessed_keyframe(guesses_only(None), &s).is_none());
        let (kf, snap) = build_guessed_keyframe(guesses_only(Some(0.25)), &s).expect("built");
        assert!(snap.map.points.is_empty());
        assert!(kf.num_points() >= s.min_keyframe_points);
        for p in &kf.levels[0].p_kf_m {
            assert!((p[2] - 4.0).abs() < 1e-4, "{p:?}");
        }
        // The limit counts the pixels given depths (the tracker's keyframe keeps at most
        // `max_points_per_level` of them).
        let pixels = select_gradient_pixels(&textured_pyramid(&cam), &s.tracking).len();
        s.min_keyframe_points = pixels;
        assert!(build_guessed_keyframe(guesses_only(Some(0.25)), &s).is_some());
        s.min_keyframe_points = pixels + 1;
        assert!(build_guessed_keyframe(guesses_only(Some(0.25)), &s).is_none());
    }

    /// A turn on the spot's keyframe made by the tracker: the tracked map's points moved into
    /// it must land where the camera sees them, at their depth in the new camera, one per pixel
    /// (the nearest), none outside the image.
    #[test]
    fn map_points_moved_into_a_turned_camera_land_where_it_sees_them() {
        let cam = CameraModel::euroc_cam0();
        let point = |u: f32, v: f32, inv: f32| MapPoint {
            u_px: u,
            v_px: v,
            inv_depth_m_inv: inv,
            inv_depth_std_m_inv: 0.02 * inv,
            num_views: 4,
        };
        // A grid over the image at 2 m, a second point at 1 m on one of its pixels and one at
        // the left edge, which the turn takes out of the image.
        let mut points: Vec<MapPoint> = (20..460)
            .step_by(40)
            .flat_map(|v| (100..700).step_by(40).map(move |u| (u, v)))
            .map(|(u, v)| point(u as f32, v as f32, 0.5))
            .collect();
        let grid = points.len();
        points.push(point(300.0, 220.0, 1.0));
        points.push(point(8.0, 240.0, 0.5));
        let map = SemidenseMap {
            t_world_cam: Isometry3::identity(),
            camera: cam,
            points,
        };
        // The camera turned by 0.15 rad about its y axis (to the right: points move left), on
        // the spot: the old camera in the new one.
        let t_new_old = Isometry3::new(Vector3::zeros(), Vector3::y() * -0.15);
        let moved = moved_map_points(&map, &t_new_old, &cam, 2.0);
        // Every grid point stays in view (the grid starts 100 px inside), the edge point leaves,
        // and of the two on one pixel only one is kept.
        assert_eq!(moved.len(), grid, "{}", moved.len());
        let mut pixels: Vec<_> = moved
            .iter()
            .map(|p| (p.u_px as i32, p.v_px as i32))
            .collect();
        pixels.sort_unstable();
        pixels.dedup();
        assert_eq!(pixels.len(), moved.len(), "two points on one pixel");
        for p in &map.points[..grid] {
            let ray = cam
                .unproject(&Vector2::new(p.u_px as f64, p.v_px as f64))
                .unwrap();
            // Of the two on (300, 220), the nearer one (1 m).
            let inv = if (p.u_px, p.v_px) == (300.0, 220.0) {
                1.0
            } else {
                0.5
            };
            let x = t_new_old * Point3::from(ray / inv);
            let uv = cam.project(&x.coords).unwrap();
            assert!(uv.x < p.u_px as f64 - 50.0, "the turn moves points left");
            let m = moved
                .iter()
                .find(|m| m.u_px == uv.x.round() as f32 && m.v_px == uv.y.round() as f32)
                .expect("grid point moved");
            assert_relative_eq!(m.inv_depth_m_inv, (1.0 / x.z) as f32, max_relative = 1e-5);
            assert_relative_eq!(
                m.inv_depth_std_m_inv / m.inv_depth_m_inv,
                0.02,
                max_relative = 1e-4
            );
            assert_eq!(m.num_views, 4);
        }
    }

    #[test]
    fn depthless_pixels_fill_only_cells_without_map_points() {
        let cam = CameraModel::euroc_cam0();
        let pyr = textured_pyramid(&cam);
        let cfg = TrackerConfig::default();
        // Map points over the left half of the image.
        let map = left_half_map(&cam, 0, 4);
        assert_eq!(median_inv_depth(&map), Some(0.5));
        let all = select_gradient_pixels(&pyr, &cfg).len();
        let fill = depthless_points(&pyr, &map, 0.25, &cfg);
        assert!(
            fill.len() > all / 3 && fill.len() < all * 2 / 3,
            "{} of {all}",
            fill.len()
        );
        let cell = 2 * cfg.select_cell_px;
        for p in &fill {
            assert!(p.u_px as usize >= (cam.width / 2).div_ceil(cell) * cell - cell);
            assert_eq!(p.inv_depth_m_inv, 0.25);
        }
        let empty = SemidenseMap {
            points: Vec::new(),
            ..map
        };
        assert_eq!(median_inv_depth(&empty), None);
        assert_eq!(depthless_points(&pyr, &empty, 0.25, &cfg).len(), all);
    }
}
