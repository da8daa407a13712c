//! The loop closer on rendered images of a simulated room: back at a place mapped before, with
//! the odometry drifted, the correction takes the drift out; a view of another place closes
//! nothing.

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::collections::HashMap;
use vidslam::camera::CameraModel;
use vidslam::image::Image;
use vidslam::loop_closure::closer::{KeyframeOutcome, LoopCloser, LoopClosureConfig};
use vidslam::mapping::semidense::{MapPoint, SemidenseMap};
use vidslam::sim::exposure::Exposure;
use vidslam::sim::{FramePoses, Renderer, Scene};

/// A camera at `p` looking along world +x turned by `yaw_rad` about the vertical (image y down =
/// world −z).
fn camera_pose(p: Vector3<f64>, yaw_rad: f64) -> Isometry3<f64> {
    let look_x = Rotation3::from_matrix_unchecked(Matrix3::new(
        0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0,
    ));
    let r = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw_rad) * look_x;
    Isometry3::from_parts(
        Translation3::from(p),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

struct Room {
    renderer: Renderer,
    camera: CameraModel,
}

impl Room {
    fn new() -> Room {
        let path: Vec<Vector3<f64>> = (0..20)
            .map(|k| Vector3::new(-1.0 + 0.1 * k as f64, 0.0, 1.2))
            .collect();
        let scene = Scene::build(&path, 11);
        let camera = CameraModel::euroc_cam0();
        Room {
            renderer: Renderer::new(&scene, &camera).expect("renderer"),
            camera,
        }
    }

    /// A blur-free image and its depth at `t_world_cam`.
    fn view(&self, index: u64, t_world_cam: &Isometry3<f64>) -> (Image<u8>, Image<f32>) {
        let poses = FramePoses {
            slots: [*t_world_cam; 4],
            centre: *t_world_cam,
        };
        let f = self
            .renderer
            .render(index, &poses, &Exposure::ideal(), true, 3);
        (f.image, f.depth_m)
    }

    /// A semidense map of the view: its pixels of high gradient at their rendered depth.
    fn map(
        &self,
        t_world_cam: &Isometry3<f64>,
        image: &Image<u8>,
        depth: &Image<f32>,
    ) -> SemidenseMap {
        let mut points = Vec::new();
        for y in 1..image.height() - 1 {
            for x in 1..image.width() - 1 {
                let gx = image.get(x + 1, y) as f32 - image.get(x - 1, y) as f32;
                let gy = image.get(x, y + 1) as f32 - image.get(x, y - 1) as f32;
                let z = depth.get(x, y);
                if gx.hypot(gy) > 12.0 && z.is_finite() && z > 0.1 {
                    points.push(MapPoint {
                        u_px: x as f32,
                        v_px: y as f32,
                        inv_depth_m_inv: 1.0 / z,
                        inv_depth_std_m_inv: 0.01 / z,
                        num_views: 5,
                    });
                }
            }
        }
        SemidenseMap {
            t_world_cam: *t_world_cam,
            camera: self.camera,
            points,
        }
    }
}

/// Keyframes two back are loop candidates; the odometry's edges as uncertain as the drift this
/// flight puts into its two edges (0.16 m and 3° in a few keyframes, where a real flight spreads
/// as much over a hundred); every loop counts fully as it closes (the tests of
/// `confirm_far_loops` turn it on).
fn config() -> LoopClosureConfig {
    LoopClosureConfig {
        enabled: true,
        confirm_far_loops: false,
        min_age_keyframes: 2,
        odometry_position_std_m: 0.1,
        odometry_yaw_std_rad: 0.03,
        ..LoopClosureConfig::default()
    }
}

/// The odometry's drift since the first keyframe: 3° of heading and 0.15 m.
fn drift() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.12, -0.09, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 3f64.to_radians()),
    )
}

/// Keyframe 0 mapped at `a`, then keyframes 1, 2 elsewhere, then keyframe 3 whose odometry pose
/// (drifted) is near `a`, with the image `image_3`. Returns the closer after keyframe 3 and the
/// odometry pose of keyframe 3.
fn fly(
    room: &Room,
    image_3: &Image<u8>,
    truth_3: &Isometry3<f64>,
) -> (LoopCloser, Isometry3<f64>, Option<u32>) {
    fly_with(room, image_3, truth_3, config(), 1.0, |c, m| {
        c.attach_map(0, m)
    })
}

/// [`fly`] with the closer's configuration `cfg`, its odometry edges' deviations times
/// `odometry_noise_scale`, and keyframe 0's map handed to the closer by `attach`.
fn fly_with(
    room: &Room,
    image_3: &Image<u8>,
    truth_3: &Isometry3<f64>,
    cfg: LoopClosureConfig,
    odometry_noise_scale: f64,
    attach: impl FnOnce(&mut LoopCloser, &SemidenseMap),
) -> (LoopCloser, Isometry3<f64>, Option<u32>) {
    let a = camera_pose(Vector3::new(-0.8, 0.0, 1.2), 0.0);
    let (img_a, depth_a) = room.view(0, &a);
    let mut closer = LoopCloser::new(cfg, room.camera);
    closer.set_odometry_noise_scale(odometry_noise_scale);
    closer.add_keyframe(0, &a, None, &img_a);
    attach(&mut closer, &room.map(&a, &img_a, &depth_a));
    let host = fly_away(room, &mut closer, (0, a));
    let odometry_3 = drift() * truth_3;
    let out = closer.add_keyframe(3, &odometry_3, Some(host), image_3);
    (closer, odometry_3, out.closed_to)
}

/// Two keyframes after `host` (ids `host.0 + 1`, `+ 2`) at the other end of the room looking
/// the other way, placed by the odometry with [`drift`]; neither closes a loop. Returns the
/// last as the next host.
fn fly_away(
    room: &Room,
    closer: &mut LoopCloser,
    host: (u32, Isometry3<f64>),
) -> (u32, Isometry3<f64>) {
    let mut host = host;
    for (x, yaw) in [(0.2, 2.0), (0.5, 2.5)] {
        let id = host.0 + 1;
        let truth = camera_pose(Vector3::new(x, 0.1, 1.2), yaw);
        let (img, _) = room.view(id as u64, &truth);
        let odometry = drift() * truth;
        let out = closer.add_keyframe(id, &odometry, Some(host), &img);
        assert_eq!(
            (out.closed_to, out.loops),
            (None, 0),
            "keyframe {id} closes nothing"
        );
        host = (id, odometry);
    }
    host
}

/// Keyframe 0's camera, keyframe 1's beside it, and keyframe 4's true camera back near both.
fn two_old_maps_poses() -> [Isometry3<f64>; 3] {
    [
        camera_pose(Vector3::new(-0.8, 0.0, 1.2), 0.0),
        camera_pose(Vector3::new(-0.7, -0.1, 1.2), 3f64.to_radians()),
        camera_pose(Vector3::new(-0.55, 0.15, 1.25), 4f64.to_radians()),
    ]
}

/// Keyframes 0 and 1 mapped at [`two_old_maps_poses`] (keyframe 1's depths times
/// `b_depth_factor`; no map for None), two away ([`fly_away`]), then keyframe 4 back near both at
/// its drifted odometry pose. Returns the closer, keyframe 4's outcome, and its pose error after.
fn back_near_two_old_maps(
    room: &Room,
    cfg: LoopClosureConfig,
    b_depth_factor: Option<f64>,
) -> (LoopCloser, KeyframeOutcome, Isometry3<f64>) {
    let [a, b, truth_4] = two_old_maps_poses();
    let mut closer = LoopCloser::new(cfg, room.camera);
    let mut host = None;
    for (id, t) in [(0u32, a), (1, b)] {
        let (img, depth) = room.view(id as u64, &t);
        closer.add_keyframe(id, &t, host, &img);
        match (id, b_depth_factor) {
            (0, _) => closer.attach_map(0, &room.map(&t, &img, &depth)),
            (1, Some(f)) => {
                closer.scale_map(1, f);
                closer.attach_map(1, &room.map(&t, &img, &depth));
            }
            _ => {}
        }
        host = Some((id, t));
    }
    let host = fly_away(room, &mut closer, (1, b));
    let odometry_4 = drift() * truth_4;
    let (image_4, _) = room.view(4, &truth_4);
    let out = closer.add_keyframe(4, &odometry_4, Some(host), &image_4);
    let err = (closer.correction() * odometry_4).inverse() * truth_4;
    (closer, out, err)
}

#[test]
fn back_at_a_mapped_place_the_correction_takes_the_drift_out() {
    let room = Room::new();
    let truth_3 = camera_pose(Vector3::new(-0.55, 0.15, 1.25), 4f64.to_radians());
    let (image_3, _) = room.view(3, &truth_3);
    let (closer, odometry_3, closed_to) = fly(&room, &image_3, &truth_3);
    assert_eq!(closed_to, Some(0), "{:?}", closer.stats());
    let corrected = closer.correction() * odometry_3;
    let err = corrected.inverse() * truth_3;
    let before = odometry_3.inverse() * truth_3;
    println!(
        "drift {:.3} m {:.2}°, after the loop {:.4} m {:.3}°",
        before.translation.vector.norm(),
        before.rotation.angle().to_degrees(),
        err.translation.vector.norm(),
        err.rotation.angle().to_degrees()
    );
    assert!(err.translation.vector.norm() < 0.02, "{err}");
    assert!(err.rotation.angle() < 0.3f64.to_radians(), "{err}");
    let s = closer.stats();
    assert_eq!((s.keyframes, s.loops_closed), (4, 1));
    // The closure's record: keyframe 3 to 0, measured near the truth, predicted with the drift.
    let mut closer = closer;
    let closures = closer.take_closures();
    assert_eq!(closures.len(), 1);
    let c = &closures[0];
    assert_eq!((c.new_id, c.old_id), (3, 0));
    assert!(c.inliers >= config().min_inliers && c.inlier_ratio >= config().min_inlier_ratio);
    let a = camera_pose(Vector3::new(-0.8, 0.0, 1.2), 0.0);
    let measured_err = (a.inverse() * truth_3).inverse() * c.t_old_new;
    assert!(
        measured_err.translation.vector.norm() < 0.02,
        "{measured_err}"
    );
    let prior_err = (a.inverse() * odometry_3).inverse() * c.prior_t_old_new;
    assert!(prior_err.translation.vector.norm() < 1e-9, "{prior_err}");
    assert!(closer.take_closures().is_empty(), "taken once");
}

/// The odometry edges' deviations scaled (`odometry_std_from_rest`: by the gyro noise the pad
/// measured): edges ten times tighter than [`config`]'s hold the drifted keyframes against the
/// loop, and scaled back by ten the loop takes the drift out as with [`config`] itself.
#[test]
fn the_odometry_noise_scale_weighs_the_odometry_against_the_loop() {
    let room = Room::new();
    let truth_3 = camera_pose(Vector3::new(-0.55, 0.15, 1.25), 4f64.to_radians());
    let (image_3, _) = room.view(3, &truth_3);
    let tight = LoopClosureConfig {
        odometry_position_std_m: 0.01,
        odometry_yaw_std_rad: 0.003,
        ..config()
    };
    let error = |scale: f64| {
        let (closer, odometry_3, closed_to) =
            fly_with(&room, &image_3, &truth_3, tight.clone(), scale, |c, m| {
                c.attach_map(0, m)
            });
        assert_eq!(closed_to, Some(0), "{:?}", closer.stats());
        let err = (closer.correction() * odometry_3).inverse() * truth_3;
        (
            err.translation.vector.norm(),
            err.rotation.angle().to_degrees(),
        )
    };
    let (held_m, held_deg) = error(1.0);
    let (freed_m, freed_deg) = error(10.0);
    println!(
        "after the loop: tight edges {held_m:.4} m {held_deg:.3}°, scaled by 10 {freed_m:.4} m {freed_deg:.3}°"
    );
    assert!(
        freed_m < 0.02 && freed_deg < 0.3,
        "{freed_m} m {freed_deg}°"
    );
    assert!(
        held_m > 0.05,
        "tight edges let the loop take out all but {held_m} m"
    );
    // A scale that is not a positive number is ignored.
    let (nan_m, _) = error(f64::NAN);
    assert_eq!(nan_m, held_m);
}

/// Keyframe 0's map 10 % too deep places the loop's camera off along the baseline by as much;
/// scaled back by its window's word on it (`scale_map`, `[window] stored_map_scale_gain`),
/// whether before or after the map comes, the loop measures as on the true map.
#[test]
fn a_stored_map_scaled_back_measures_its_loops_as_the_true_one() {
    let room = Room::new();
    let truth_3 = camera_pose(Vector3::new(-0.55, 0.15, 1.25), 4f64.to_radians());
    let (image_3, _) = room.view(3, &truth_3);
    let a = camera_pose(Vector3::new(-0.8, 0.0, 1.2), 0.0);
    let deep = |m: &SemidenseMap| {
        let mut m = m.clone();
        m.scale_inv_depths(1.0 / 1.1);
        m
    };
    let edge_error_m = |attach: &dyn Fn(&mut LoopCloser, &SemidenseMap)| {
        let (mut closer, _, closed_to) = fly_with(&room, &image_3, &truth_3, config(), 1.0, attach);
        assert_eq!(closed_to, Some(0), "{:?}", closer.stats());
        let c = &closer.take_closures()[0];
        ((a.inverse() * truth_3).inverse() * c.t_old_new)
            .translation
            .vector
            .norm()
    };
    let exact = edge_error_m(&|c, m| c.attach_map(0, m));
    let too_deep = edge_error_m(&|c, m| c.attach_map(0, &deep(m)));
    let scaled_after = edge_error_m(&|c, m| {
        c.attach_map(0, &deep(m));
        c.scale_map(0, 1.0 / 1.1);
    });
    let scaled_before = edge_error_m(&|c, m| {
        c.scale_map(0, 1.0 / 1.1);
        c.attach_map(0, &deep(m));
    });
    println!(
        "loop edge error: true map {exact:.4} m, 10 % deep {too_deep:.4} m, scaled back after / \
         before it came {scaled_after:.4} / {scaled_before:.4} m"
    );
    assert!(too_deep > exact + 0.015, "{too_deep} m against {exact} m");
    for scaled in [scaled_after, scaled_before] {
        assert!(
            (scaled - exact).abs() < 0.002,
            "{scaled} m against {exact} m"
        );
    }
}

/// `vidslam replay --loop-edges gt` (a diagnostic): with both keyframes' true camera poses given,
/// a loop found on keyframe 0's map made 10 % too deep goes into the graph — and into its record —
/// as their true relative pose, and the correction ends nearer the truth than with the measured
/// edge; with keyframe 3's true pose missing the loop keeps its measured edge.
#[test]
fn with_true_poses_given_a_loop_goes_in_as_the_true_relative_pose() {
    let room = Room::new();
    let truth_3 = camera_pose(Vector3::new(-0.55, 0.15, 1.25), 4f64.to_radians());
    let (image_3, _) = room.view(3, &truth_3);
    let a = camera_pose(Vector3::new(-0.8, 0.0, 1.2), 0.0);
    let true_edge = a.inverse() * truth_3;
    // The loop's edge as recorded, and keyframe 3's error after it, m.
    let run = |true_poses: &[(u32, Isometry3<f64>)]| {
        let (mut closer, odometry_3, closed_to) =
            fly_with(&room, &image_3, &truth_3, config(), 1.0, |c, m| {
                for (id, p) in true_poses {
                    c.set_true_pose(*id, *p);
                }
                let mut deep = m.clone();
                deep.scale_inv_depths(1.0 / 1.1);
                c.attach_map(0, &deep);
            });
        assert_eq!(closed_to, Some(0), "{:?}", closer.stats());
        let err = (closer.correction() * odometry_3).inverse() * truth_3;
        let closures = closer.take_closures();
        assert_eq!(closures.len(), 1);
        (closures[0].t_old_new, err.translation.vector.norm())
    };
    let (measured, measured_err_m) = run(&[]);
    let (given, given_err_m) = run(&[(0, a), (3, truth_3)]);
    let (one_missing, one_missing_err_m) = run(&[(0, a)]);
    let edge_err_m = |t: &Isometry3<f64>| (true_edge.inverse() * t).translation.vector.norm();
    println!(
        "loop edge error: measured on the deep map {:.4} m (keyframe 3 after it {measured_err_m:.4} m), \
         true poses given {:.1e} m ({given_err_m:.4} m)",
        edge_err_m(&measured),
        edge_err_m(&given)
    );
    assert!(edge_err_m(&measured) > 0.01, "{measured}");
    assert!(edge_err_m(&given) < 1e-12, "{given}");
    assert!((true_edge.inverse() * given).rotation.angle() < 1e-12);
    assert!(given_err_m < measured_err_m, "{given_err_m} m");
    assert_eq!(one_missing, measured);
    assert_eq!(one_missing_err_m, measured_err_m);
}

#[test]
fn a_view_of_another_place_closes_nothing() {
    let room = Room::new();
    let truth_3 = camera_pose(Vector3::new(-0.55, 0.15, 1.25), 4f64.to_radians());
    // The camera is really at the other end of the room looking the other way, while the
    // odometry places it near keyframe 0 (a wrong prior must not make a loop).
    let elsewhere = camera_pose(Vector3::new(0.9, -0.1, 1.2), std::f64::consts::PI);
    let (image_3, _) = room.view(3, &elsewhere);
    let (closer, _, closed_to) = fly(&room, &image_3, &truth_3);
    assert_eq!(closed_to, None, "{:?}", closer.stats());
    assert_eq!(closer.correction(), Isometry3::identity());
    assert!(closer.stats().candidates_tried >= 1);
}

/// Two old keyframes mapped near each other (0 at `a`, 1 beside it), two more elsewhere with the
/// odometry drifted, then keyframe 4 back between the first two. With one loop per keyframe the
/// search ends at the first closure; with `max_loops_per_keyframe = 2` keyframe 4 closes to both
/// old maps, the second predicted from the graph as solved with the first (the drift already
/// mostly out of its prior), and the correction still takes the drift out.
#[test]
fn a_keyframe_closes_to_several_old_maps_when_allowed() {
    let room = Room::new();
    let [a, b, truth_4] = two_old_maps_poses();
    let run = |max_loops: usize| {
        let cfg = LoopClosureConfig {
            max_loops_per_keyframe: max_loops,
            ..config()
        };
        let (mut closer, out, err) = back_near_two_old_maps(&room, cfg, Some(1.0));
        (out, closer.take_closures(), err, drift() * truth_4)
    };

    let (one, closures, err, _) = run(1);
    assert_eq!((one.loops, closures.len()), (1, 1), "{one:?}");
    assert!(err.translation.vector.norm() < 0.02, "{err}");
    let (zero, closures, _, _) = run(0);
    assert_eq!(
        (zero.loops, closures.len()),
        (1, 1),
        "0 is taken as 1: {zero:?}"
    );

    let (two, closures, err, odometry_4) = run(2);
    assert_eq!((two.loops, closures.len()), (2, 2), "{two:?}");
    assert_eq!(two.closed_to, Some(closures[0].old_id));
    let mut old: Vec<u32> = closures.iter().map(|c| c.old_id).collect();
    old.sort_unstable();
    assert_eq!(old, vec![0, 1]);
    assert!(closures.iter().all(|c| c.new_id == 4));
    // The first loop was predicted from the drifted odometry, the second from the graph after
    // the first: its prior is near the truth.
    let prior_error_m = |c: &vidslam::loop_closure::closer::LoopClosure| {
        let t_old = if c.old_id == 0 { a } else { b };
        ((t_old.inverse() * truth_4).inverse() * c.prior_t_old_new)
            .translation
            .vector
            .norm()
    };
    let drift_m = (odometry_4.inverse() * truth_4).translation.vector.norm();
    let (first_m, second_m) = (prior_error_m(&closures[0]), prior_error_m(&closures[1]));
    println!(
        "drift {drift_m:.3} m; priors of the two loops off by {first_m:.4} / {second_m:.4} m; \
         after both {:.4} m {:.3}°",
        err.translation.vector.norm(),
        err.rotation.angle().to_degrees()
    );
    assert!(first_m > 0.1, "{first_m}");
    assert!(second_m < 0.03, "{second_m}");
    assert!(err.translation.vector.norm() < 0.02, "{err}");
    assert!(err.rotation.angle() < 0.3f64.to_radians(), "{err}");
}

/// `follow_window_poses`: keyframes the odometry moves after they joined the graph (the keyframe
/// window's solve) move in it with their corrections kept — the published pose does not jump —,
/// a keyframe the closer does not hold is ignored, and the graph takes later keyframes and loops
/// as before.
#[test]
fn keyframes_moved_by_the_window_keep_their_corrections() {
    let room = Room::new();
    let truth_3 = camera_pose(Vector3::new(-0.55, 0.15, 1.25), 4f64.to_radians());
    let (image_3, _) = room.view(3, &truth_3);
    let cfg = LoopClosureConfig {
        follow_window_poses: true,
        ..config()
    };
    let (mut closer, odometry_3, closed_to) =
        fly_with(&room, &image_3, &truth_3, cfg, 1.0, |c, m| {
            c.attach_map(0, m)
        });
    assert_eq!(closed_to, Some(0));
    let mut before = HashMap::new();
    closer.corrections_into(&mut before);
    assert!(
        before[&3].translation.vector.norm() > 0.05,
        "the loop corrected"
    );
    let nudge = Isometry3::new(Vector3::new(0.03, -0.02, 0.01), Vector3::z() * 0.01);
    let moved_3 = odometry_3 * nudge;
    closer.move_keyframes(&[(2, drift() * nudge), (3, moved_3), (99, nudge)]);
    let mut after = HashMap::new();
    closer.corrections_into(&mut after);
    assert_eq!(after.len(), before.len());
    for (id, c) in &before {
        let d = c.inverse() * after[id];
        assert!(
            d.translation.vector.norm() < 1e-9 && d.rotation.angle() < 1e-12,
            "keyframe {id}: {d}"
        );
    }
    let host = fly_away(&room, &mut closer, (3, moved_3));
    assert_eq!(host.0, 5);
    let mut last = HashMap::new();
    closer.corrections_into(&mut last);
    assert_eq!(last.len(), 6);
    assert!(
        last.values()
            .all(|c| c.translation.vector.iter().all(|v| v.is_finite()))
    );
}

/// `confirm_far_loops`: a loop that moves the graph by more than `confirm_beyond_m` (this
/// flight's drift, 0.15 m, against 0.1) goes in only once a loop to another old map asks for the
/// same move. Two right maps agree (both loops in, the drift out); one map alone is held and
/// dropped after `confirm_within_keyframes`; a map whose depths are 50 % too deep asks for
/// another move than the right one, and neither goes in.
#[test]
fn a_far_loop_goes_in_only_when_another_old_map_agrees() {
    let room = Room::new();
    let truth_4 = two_old_maps_poses()[2];
    let run = |b_depth_factor: Option<f64>| {
        let cfg = LoopClosureConfig {
            confirm_far_loops: true,
            confirm_weak_std_factor: 0.0,
            ..config()
        };
        back_near_two_old_maps(&room, cfg, b_depth_factor)
    };

    let (mut closer, out, err) = run(Some(1.0));
    let s = closer.stats();
    println!(
        "two right maps: {out:?}, {s:?}, error after {:.4} m",
        err.translation.vector.norm()
    );
    assert_eq!(
        (out.loops, s.loops_held, s.loops_closed, s.loops_unconfirmed),
        (1, 1, 2, 0)
    );
    let mut old: Vec<u32> = closer.take_closures().iter().map(|c| c.old_id).collect();
    old.sort_unstable();
    assert_eq!(old, vec![0, 1]);
    assert!(err.translation.vector.norm() < 0.02, "{err}");
    assert!(err.rotation.angle() < 0.3f64.to_radians(), "{err}");

    let (mut closer, out, err) = run(None);
    let s = closer.stats();
    assert_eq!(
        (out.loops, s.loops_held, s.loops_closed),
        (0, 1, 0),
        "{s:?}"
    );
    assert!(closer.take_closures().is_empty());
    assert!(
        err.translation.vector.norm() > 0.1,
        "the drift stays: {err}"
    );
    // Held through `confirm_within_keyframes` (4) new keyframes without a loop, dropped at the
    // next.
    let mut host = (4, drift() * truth_4);
    for _ in 0..2 {
        host = fly_away(&room, &mut closer, host);
        assert_eq!(
            closer.stats().loops_unconfirmed,
            0,
            "held at keyframe {}",
            host.0
        );
    }
    fly_away(&room, &mut closer, host);
    let s = closer.stats();
    assert_eq!((s.loops_unconfirmed, s.loops_closed), (1, 0), "{s:?}");
    assert_eq!(closer.correction(), Isometry3::identity());
    let dropped = closer.take_closures();
    assert_eq!(dropped.len(), 1, "recorded as dropped");
    assert!(dropped[0].dropped && (dropped[0].new_id, dropped[0].old_id) == (4, 0));

    let (mut closer, out, _) = run(Some(1.5));
    let s = closer.stats();
    println!("a map 50 % deep beside the right one: {out:?}, {s:?}");
    assert_eq!(
        (out.loops, s.loops_held, s.loops_closed),
        (0, 2, 0),
        "{s:?}"
    );
    assert_eq!(
        s.loops_unconfirmed, 1,
        "the first held, dropped by the second"
    );
    let dropped = closer.take_closures();
    assert!(dropped.len() == 1 && dropped[0].dropped, "{dropped:?}");
    assert_eq!(closer.correction(), Isometry3::identity());
}

/// `confirm_weak_std_factor`: a far loop goes in at once, weakened, and gets its own deviations
/// back when a loop to another old map agrees. Alone, it pulls the drifted keyframe only part of
/// the way; with a second right map both pull fully, as without the check.
#[test]
fn a_far_loop_goes_in_weak_and_is_restored_when_another_old_map_agrees() {
    let room = Room::new();
    let truth_3 = camera_pose(Vector3::new(-0.55, 0.15, 1.25), 4f64.to_radians());
    let (image_3, _) = room.view(3, &truth_3);
    let weak = LoopClosureConfig {
        confirm_far_loops: true,
        confirm_weak_std_factor: 3.0,
        ..config()
    };
    let error_m = |cfg: LoopClosureConfig| {
        let (mut closer, odometry_3, closed_to) =
            fly_with(&room, &image_3, &truth_3, cfg, 1.0, |c, m| {
                c.attach_map(0, m)
            });
        assert_eq!(closed_to, Some(0));
        let taken = closer.take_closures();
        assert!(taken.len() == 1 && !taken[0].dropped);
        let err = (closer.correction() * odometry_3).inverse() * truth_3;
        (closer.stats(), err.translation.vector.norm())
    };
    let (s_full, full_m) = error_m(config());
    let (s_weak, weak_m) = error_m(weak.clone());
    let drift_m = (drift() * truth_3).inverse() * truth_3;
    let drift_m = drift_m.translation.vector.norm();
    println!("one old map: drift {drift_m:.3} m, after the loop {full_m:.4} m, weak {weak_m:.4} m");
    assert_eq!((s_full.loops_held, s_full.loops_closed), (0, 1));
    assert_eq!(
        (s_weak.loops_held, s_weak.loops_closed),
        (1, 1),
        "{s_weak:?}"
    );
    assert!(weak_m > 2.0 * full_m && weak_m < 0.8 * drift_m, "{weak_m}");

    // Two right old maps: the second agrees and restores the first.
    let two_maps = |cfg: LoopClosureConfig| {
        let (closer, _, err) = back_near_two_old_maps(&room, cfg, Some(1.0));
        (closer.stats(), err)
    };
    let both = LoopClosureConfig {
        max_loops_per_keyframe: 2,
        ..config()
    };
    let (s_both, err_both) = two_maps(both.clone());
    let (s, err) = two_maps(LoopClosureConfig {
        confirm_far_loops: true,
        confirm_weak_std_factor: 3.0,
        ..both
    });
    assert_eq!((s_both.loops_closed, s_both.loops_held), (2, 0));
    assert_eq!(
        (s.loops_closed, s.loops_held, s.loops_unconfirmed),
        (2, 1, 0),
        "{s:?}"
    );
    let d = err_both.inverse() * err;
    assert!(
        d.translation.vector.norm() < 1e-9,
        "as without the check: {d}"
    );
}
