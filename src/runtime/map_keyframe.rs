//! The tracker's keyframe of a mapper snapshot.
//!
//! Installing a map for tracking means building its [`Keyframe`]: the map's points
//! back-projected (rays looked up, [`PixelRays`]), selected per level of the keyframe image's
//! pyramid (built once per keyframe, by the mapper) and given their intensity Jacobians (eq. 26,
//! precomputed for the inverse-compositional alignment): 3-6 ms on a 752x480 map of ~13k points.
//! The tracking thread did all of it, pyramid and unprojections included (8-18 ms), inside the
//! frame it decided to install the map in: the tail of its per-frame time. A new keyframe that is
//! adjusted is now built by the refinement thread, with its adjustment
//! ([`super::refinement_worker::KeyframeToAdjust`]); the others (the first map, refreshes,
//! keyframes that cannot wait for an adjustment) here, inline. The result does not depend on
//! the thread. Since the mapper builds the keyframes of the maps the tracker says it may
//! install next ([`super::mapping_worker::InstallHint`]), most arrive built
//! ([`MapSnapshot::tracker_keyframe`], [`take_keyframe`]): the build is the same function of the
//! same map, with the pose set afterwards, so a keyframe is the same wherever it was built.

use super::mapping_worker::MapSnapshot;
use crate::camera::PixelRays;
use crate::mapping::semidense::SemidenseMap;
use crate::tracking::{DepthPoint, Keyframe, TrackerConfig};
use nalgebra::Isometry3;
use std::sync::Arc;

/// The tracker's keyframe of snapshot `s` (sampled from its pyramid; `extra` points appended to
/// the map's: the depthless fill) at pose `t_world_cam` (the tracker's world: the mapper's pose
/// of it moved by the odometry's correction of the mapper's world).
pub fn build(
    s: &MapSnapshot,
    extra: Vec<DepthPoint>,
    t_world_cam: Isometry3<f64>,
    rays: &PixelRays,
    cfg: &TrackerConfig,
) -> Keyframe {
    let mut points = depth_points(&s.map);
    points.extend(extra);
    Keyframe::from_rays(
        s.keyframe_id,
        s.keyframe_t,
        &s.keyframe_pyramid,
        rays,
        t_world_cam,
        &points,
        cfg,
    )
}

/// The tracker's keyframe of snapshot `s` at pose `t_world_cam`: the one the mapper built beside
/// the map, taken out of the snapshot (no copy where the snapshot held the only reference), or
/// built now ([`build`], no extra points). Also says whether it came built.
pub fn take_keyframe(
    s: &mut MapSnapshot,
    t_world_cam: Isometry3<f64>,
    rays: &PixelRays,
    cfg: &TrackerConfig,
) -> (Keyframe, bool) {
    let built = s.tracker_keyframe.take().map(Arc::unwrap_or_clone);
    posed_or_built(s, built, t_world_cam, rays, cfg)
}

/// [`take_keyframe`] for a snapshot that stays whole (the refinement thread's): the mapper's
/// keyframe copied, or built now.
pub fn keyframe_of(
    s: &MapSnapshot,
    t_world_cam: Isometry3<f64>,
    rays: &PixelRays,
    cfg: &TrackerConfig,
) -> Keyframe {
    let built = s.tracker_keyframe.as_deref().cloned();
    posed_or_built(s, built, t_world_cam, rays, cfg).0
}

/// `built` (the mapper's keyframe of `s`, posed at the identity) moved to `t_world_cam`, or the
/// keyframe of `s` built now; with whether it came built.
fn posed_or_built(
    s: &MapSnapshot,
    built: Option<Keyframe>,
    t_world_cam: Isometry3<f64>,
    rays: &PixelRays,
    cfg: &TrackerConfig,
) -> (Keyframe, bool) {
    match built {
        Some(mut kf) => {
            kf.t_world_cam = t_world_cam;
            (kf, true)
        }
        None => (build(s, Vec::new(), t_world_cam, rays, cfg), false),
    }
}

/// A map's points as the tracker's keyframe takes them.
pub fn depth_points(map: &SemidenseMap) -> Vec<DepthPoint> {
    map.points
        .iter()
        .map(|p| DepthPoint {
            u_px: p.u_px,
            v_px: p.v_px,
            inv_depth_m_inv: p.inv_depth_m_inv,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{CameraModel, Distortion};
    use crate::image::{Image, Pyramid};
    use crate::mapping::semidense::MapPoint;
    use crate::time::TimeNs;
    use crate::tracking::NUM_LEVELS;
    use nalgebra::{Translation3, UnitQuaternion};

    /// Every other pixel of the 64x48 test image from `(first, first)`, 4 pixels inside.
    fn every_other_pixel(first: u32) -> impl Iterator<Item = (u32, u32)> {
        (first..44)
            .step_by(2)
            .flat_map(move |v| (first..60).step_by(2).map(move |u| (u, v)))
    }

    fn snapshot() -> MapSnapshot {
        let camera = CameraModel::new(64, 48, [50.0, 50.0, 31.5, 23.5], Distortion::None).unwrap();
        let mut img = Image::<u8>::new(64, 48);
        for y in 0..48 {
            for x in 0..64 {
                img.set(x, y, (((x / 4 + y / 4) % 2) * 180 + 30) as u8);
            }
        }
        let points = every_other_pixel(4)
            .map(|(u, v)| MapPoint::at_2_m(u as f32, v as f32))
            .collect();
        let t_world_cam = Isometry3::from_parts(
            Translation3::new(0.5, -0.2, 1.0),
            UnitQuaternion::from_euler_angles(0.1, 0.0, -0.2),
        );
        MapSnapshot {
            seq: 7,
            keyframe_id: 3,
            keyframe_t: TimeNs(1_000_000_000),
            keyframe_pyramid: Arc::new(Pyramid::from_u8(&img, NUM_LEVELS)),
            keyframe_image: Arc::new(img),
            map: Arc::new(SemidenseMap {
                t_world_cam,
                camera,
                points,
            }),
            views: 4,
            forward_views: 2,
            time_s: 0.0,
            tracker_keyframe: None,
        }
    }

    #[test]
    fn a_snapshot_builds_the_keyframe_of_its_map_and_extra_points() {
        let s = snapshot();
        let rays = PixelRays::new(&s.map.camera);
        let cfg = TrackerConfig::default();
        let pose = Isometry3::translation(0.1, 0.2, 0.3);
        let kf = build(&s, Vec::new(), pose, &rays, &cfg);
        assert_eq!((kf.id, kf.t), (3, s.keyframe_t));
        assert_eq!(kf.t_world_cam, pose, "posed where it is told");
        assert!(kf.num_points() > 0, "the checkerboard has gradients");
        // The same as the keyframe of the map's points built directly.
        let points = depth_points(&s.map);
        let direct = Keyframe::new(
            3,
            s.keyframe_t,
            &s.keyframe_pyramid,
            &s.map.camera,
            pose,
            &points,
            &cfg,
        );
        for (a, b) in kf.levels.iter().zip(&direct.levels) {
            assert_eq!(a.p_kf_m, b.p_kf_m);
            assert_eq!(a.jacobian, b.jacobian);
        }
        // Extra (depthless-fill) points join the map's: nearer ones on the pixels between its.
        let extra: Vec<DepthPoint> = every_other_pixel(5)
            .map(|(u, v)| DepthPoint {
                u_px: u as f32,
                v_px: v as f32,
                inv_depth_m_inv: 2.0,
            })
            .collect();
        let more = build(&s, extra, pose, &rays, &cfg);
        let near = |k: &Keyframe| {
            k.levels[0]
                .p_kf_m
                .iter()
                .filter(|p| (p[2] - 0.5).abs() < 1e-6)
                .count()
        };
        assert_eq!(near(&kf), 0);
        assert!(near(&more) > 0, "no extra point at 0.5 m selected");
    }

    #[test]
    fn a_keyframe_the_mapper_built_is_the_one_built_here_posed_where_installed() {
        let mut s = snapshot();
        let rays = PixelRays::new(&s.map.camera);
        let cfg = TrackerConfig::default();
        let pose = Isometry3::translation(0.1, 0.2, 0.3);
        let here = build(&s, Vec::new(), pose, &rays, &cfg);
        // Not built by the mapper: built now.
        let (kf, came_built) = take_keyframe(&mut s.clone(), pose, &rays, &cfg);
        assert!(!came_built);
        assert_eq!(kf.levels, here.levels);
        // Built by the mapper at the identity: posed, otherwise the same, and taken out.
        s.tracker_keyframe = Some(Arc::new(build(
            &s,
            Vec::new(),
            Isometry3::identity(),
            &rays,
            &cfg,
        )));
        let copied = keyframe_of(&s, pose, &rays, &cfg);
        assert_eq!((copied.t_world_cam, &copied.levels), (pose, &here.levels));
        let (kf, came_built) = take_keyframe(&mut s, pose, &rays, &cfg);
        assert!(came_built);
        assert!(s.tracker_keyframe.is_none(), "left in the snapshot");
        assert_eq!((kf.id, kf.t, kf.t_world_cam), (here.id, here.t, pose));
        assert_eq!(kf.levels, here.levels);
        assert_eq!(kf.median_depth_m, here.median_depth_m);
    }
}
