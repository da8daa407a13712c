//! Unit tests of the whole mapper on a textured plane rendered in code, and on degenerate input.

use super::*;
use crate::image::Image;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector2, Vector3};

/// EuRoC cam0 at half resolution (376x240), with its distortion.
fn camera() -> CameraModel {
    CameraModel::euroc_cam0().scaled_to_level(1)
}

/// Smooth value noise in [0, 1] on a lattice of `cell` metres.
fn value_noise(a: f64, b: f64, cell: f64, seed: u64) -> f64 {
    let hash = |i: i64, j: i64| {
        let mut h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ seed.wrapping_mul(0x1656_67B1_9E37_79F9);
        h ^= h >> 29;
        h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 32;
        (h >> 11) as f64 / (1u64 << 53) as f64
    };
    let (x, y) = (a / cell, b / cell);
    let (i, j) = (x.floor() as i64, y.floor() as i64);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (fx, fy) = (s(x - i as f64), s(y - j as f64));
    let top = hash(i, j) + fx * (hash(i + 1, j) - hash(i, j));
    let bot = hash(i, j + 1) + fx * (hash(i + 1, j + 1) - hash(i, j + 1));
    top + fy * (bot - top)
}

/// A textured plane `n · X = dist` in the world.
struct Plane {
    n: Vector3<f64>,
    dist: f64,
    e1: Vector3<f64>,
    e2: Vector3<f64>,
}

impl Plane {
    fn new(n: Vector3<f64>, dist: f64) -> Self {
        let n = n.normalize();
        let e1 = n.cross(&Vector3::y()).normalize();
        let e2 = n.cross(&e1);
        Plane { n, dist, e1, e2 }
    }

    /// Ray parameter of `o + λ d` on the plane.
    fn hit(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> f64 {
        (self.dist - self.n.dot(o)) / self.n.dot(d)
    }

    fn texture(&self, p: &Vector3<f64>) -> f64 {
        let (a, b) = (p.dot(&self.e1), p.dot(&self.e2));
        40.0 + 110.0 * value_noise(a, b, 0.05, 1) + 70.0 * value_noise(a, b, 0.013, 2)
    }

    /// Renders the plane seen from `t_world_cam` (2x2 supersampling), gray levels `gain·I + offset`.
    fn render(
        &self,
        cam: &CameraModel,
        t_world_cam: &Isometry3<f64>,
        gain: f64,
        offset: f64,
    ) -> Image<f32> {
        let o = t_world_cam.translation.vector;
        Image::from_fn(cam.width, cam.height, |x, y| {
            let mut sum = 0.0;
            for (dx, dy) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                let ray = cam
                    .unproject(&Vector2::new(x as f64 + dx, y as f64 + dy))
                    .expect("unproject");
                let d = t_world_cam.rotation * ray;
                sum += self.texture(&(o + d * self.hit(&o, &d)));
            }
            (gain * sum / 4.0 + offset) as f32
        })
    }

    /// True inverse depth (1/z in the camera) at pixel `(u, v)`.
    fn inv_depth(&self, cam: &CameraModel, t_world_cam: &Isometry3<f64>, u: f64, v: f64) -> f64 {
        let ray = cam.unproject(&Vector2::new(u, v)).unwrap();
        let o = t_world_cam.translation.vector;
        let d = t_world_cam.rotation * ray;
        // ray has z = 1 in the camera, so λ is the z-depth
        1.0 / self.hit(&o, &d)
    }
}

/// Camera poses: keyframe at the origin looking along world z, views moving sideways and a bit
/// forward with small rotations.
fn pose(k: i32) -> Isometry3<f64> {
    let k = k as f64;
    Isometry3::from_parts(
        Translation3::new(0.03 * k, 0.008 * k, 0.01 * k.abs()),
        UnitQuaternion::from_euler_angles(0.004 * k, -0.006 * k, 0.01 * k),
    )
}

fn scene() -> Plane {
    // 2.5 m in front, slanted about 15° and 8°.
    Plane::new(Vector3::new(0.25, -0.14, 1.0), 2.5)
}

/// Median of the map's inverse depths over the true ones (NaN without points).
fn median_inv_depth_ratio(plane: &Plane, map: &SemidenseMap) -> f64 {
    let mut r: Vec<f64> = map
        .points
        .iter()
        .map(|p| {
            let want = plane.inv_depth(&map.camera, &map.t_world_cam, p.u_px as f64, p.v_px as f64);
            p.inv_depth_m_inv as f64 / want
        })
        .collect();
    r.sort_by(f64::total_cmp);
    r.get(r.len() / 2).copied().unwrap_or(f64::NAN)
}

fn relative_errors(plane: &Plane, map: &SemidenseMap) -> Vec<f64> {
    let mut e: Vec<f64> = map
        .points
        .iter()
        .map(|p| {
            let want = plane.inv_depth(&map.camera, &map.t_world_cam, p.u_px as f64, p.v_px as f64);
            (p.inv_depth_m_inv as f64 - want).abs() / want
        })
        .collect();
    e.sort_by(f64::total_cmp);
    e
}

#[test]
fn textured_plane_inverse_depth_is_recovered() {
    let cam = camera();
    let plane = scene();
    let cfg = SemidenseConfig::default();
    let kf_pose = pose(0);
    let mut kf = SemidenseKeyframe::new(
        &plane.render(&cam, &kf_pose, 1.0, 0.0),
        &cam,
        &kf_pose,
        &cfg,
    );
    assert!(
        kf.num_candidates() > 5000,
        "{} candidates",
        kf.num_candidates()
    );
    for (i, k) in [1, -1, 2, -2, 3, -3].into_iter().enumerate() {
        // brightness changes between views (auto exposure)
        let (gain, offset) = (1.0 + 0.03 * k as f64, 4.0 * i as f64);
        let s = kf.observe(&plane.render(&cam, &pose(k), gain, offset), &pose(k));
        assert_eq!(s.skipped, None);
        assert!(s.matched > s.candidates / 3, "view {k}: {s:?}");
    }
    let map = kf.map();
    let e = relative_errors(&plane, &map);
    let (median, p90) = (e[e.len() / 2], e[e.len() * 9 / 10]);
    assert!(map.points.len() > 3000, "{} points", map.points.len());
    assert!(median < 0.005 && p90 < 0.02, "median {median}, p90 {p90}");
    for p in &map.points {
        assert!(p.num_views >= 2 && p.inv_depth_std_m_inv > 0.0);
        assert_eq!(p.u_px.fract(), 0.0);
    }
}

/// The keyframe at pose 0 after the six views at poses ±1, ±2, ±3 (rendered there, each given
/// to the mapper at `reported(k)`).
fn keyframe_after_six_views(
    cam: &CameraModel,
    plane: &Plane,
    cfg: &SemidenseConfig,
    reported: impl Fn(i32) -> Isometry3<f64>,
) -> SemidenseKeyframe {
    let mut kf = SemidenseKeyframe::new(&plane.render(cam, &pose(0), 1.0, 0.0), cam, &pose(0), cfg);
    for k in [1, -1, 2, -2, 3, -3] {
        kf.observe(&plane.render(cam, &pose(k), 1.0, 0.0), &reported(k));
    }
    kf
}

#[test]
fn propagation_seeds_the_next_keyframe() {
    let cam = camera();
    let plane = scene();
    let cfg = SemidenseConfig::default();
    let map = keyframe_after_six_views(&cam, &plane, &cfg, pose).map();
    // The next keyframe at pose 2, with two views: only the seeded one has points.
    let kf2_pose = pose(2);
    let kf2_image = plane.render(&cam, &kf2_pose, 1.0, 0.0);
    let views = [5, -1].map(|k| (plane.render(&cam, &pose(k), 1.0, 0.0), pose(k)));
    let mut plain = SemidenseKeyframe::new(&kf2_image, &cam, &kf2_pose, &cfg);
    let mut seeded = plain.clone();
    let n_seeded = seeded.propagate_from(&map);
    assert!(
        n_seeded > map.points.len() / 2,
        "{n_seeded} seeded of {}",
        map.points.len()
    );
    for (img, p) in &views {
        plain.observe(img, p);
        seeded.observe(img, p);
    }
    assert_eq!(plain.map().points.len(), 0);
    let m2 = seeded.map();
    assert!(m2.points.len() > 2000, "{} points", m2.points.len());
    let e = relative_errors(&plane, &m2);
    assert!(e[e.len() / 2] < 0.005, "median {}", e[e.len() / 2]);
}

#[test]
fn degenerate_input_never_panics() {
    let cam = camera();
    let plane = scene();
    let cfg = SemidenseConfig::default();
    let img = plane.render(&cam, &pose(0), 1.0, 0.0);
    let nan_pose = Isometry3::from_parts(
        Translation3::new(f64::NAN, 0.0, 0.0),
        UnitQuaternion::identity(),
    );

    // NaN keyframe pose: nothing to do, everything reported.
    let mut kf = SemidenseKeyframe::new(&img, &cam, &nan_pose, &cfg);
    assert_eq!(
        kf.observe(&img, &pose(1)).skipped,
        Some(ViewSkip::NonFinitePose)
    );
    assert!(kf.map().points.is_empty());
    assert_eq!(kf.propagate_from(&kf.map()), 0);

    let mut kf = SemidenseKeyframe::new(&img, &cam, &pose(0), &cfg);
    let n = kf.num_candidates();
    assert!(n > 0);
    // NaN view pose, zero baseline, wrong image size.
    assert_eq!(
        kf.observe(&img, &nan_pose).skipped,
        Some(ViewSkip::NonFinitePose)
    );
    let s = kf.observe(&img, &pose(0));
    assert_eq!((s.skipped, s.candidates), (Some(ViewSkip::NoBaseline), n));
    let small = Image::new(10, 10);
    assert_eq!(
        kf.observe(&small, &pose(1)).skipped,
        Some(ViewSkip::ImageSizeMismatch)
    );
    // Pure rotation about the optical centre (baseline 1 nm): no parallax anywhere.
    let rot = Isometry3::from_parts(
        Translation3::new(1e-9, 0.0, 0.0),
        UnitQuaternion::from_euler_angles(0.0, 0.02, 0.0),
    );
    let s = kf.observe(&img, &rot);
    assert_eq!(s.matched, 0, "{s:?}");
    // A view looking the other way: nothing projects.
    let away = Isometry3::from_parts(
        Translation3::new(0.1, 0.0, 0.0),
        UnitQuaternion::from_euler_angles(0.0, std::f64::consts::PI, 0.0),
    );
    let s = kf.observe(&img, &away);
    assert_eq!(s.matched, 0, "{s:?}");
    assert_eq!(
        s.out_of_view + s.low_parallax + s.gradient_parallel,
        n,
        "{s:?}"
    );
    // A view far to the side: no overlap.
    let aside = Isometry3::translation(50.0, 0.0, 0.0);
    assert_eq!(kf.observe(&img, &aside).matched, 0);
    // Garbage image values and garbage ranges.
    let nan_img = Image::from_fn(cam.width, cam.height, |x, _| {
        if x % 3 == 0 { f32::NAN } else { 1e30 }
    });
    kf.observe(&nan_img, &pose(1));
    let mut k = SemidenseKeyframe::new(&nan_img, &cam, &pose(0), &cfg);
    k.observe(&img, &pose(1));
    k.observe(&nan_img, &pose(2));
    k.map();
    kf.set_inv_depth_range(f64::NAN, 1.0);
    kf.set_inv_depth_range(2.0, 1.0);
    kf.set_inv_depth_range(-1.0, 1.0);
    assert_eq!(
        kf.inv_depth_range(),
        (cfg.min_inv_depth_m_inv, cfg.max_inv_depth_m_inv)
    );
    kf.set_inv_depth_range(0.0, 1.0);
    assert_eq!(kf.inv_depth_range(), (0.0, 1.0));
    kf.observe(&img, &pose(1));
    // Garbage map points.
    let bad = SemidenseMap {
        t_world_cam: pose(1),
        camera: cam,
        points: vec![
            MapPoint {
                u_px: f32::NAN,
                v_px: 3.0,
                inv_depth_m_inv: 1.0,
                inv_depth_std_m_inv: 0.1,
                num_views: 3,
            },
            MapPoint {
                u_px: 10.0,
                v_px: 10.0,
                inv_depth_m_inv: -1.0,
                inv_depth_std_m_inv: f32::INFINITY,
                num_views: 3,
            },
            MapPoint {
                u_px: 1e9,
                v_px: -1e9,
                inv_depth_m_inv: 1e-30,
                inv_depth_std_m_inv: 0.0,
                num_views: 0,
            },
        ],
    };
    kf.propagate_from(&bad);
    kf.map();

    // Tiny images, a size mismatch at construction, a constant image, a broken camera.
    for (w, h) in [(0, 0), (0, 5), (1, 1), (5, 5), (12, 9)] {
        let c = CameraModel {
            width: w,
            height: h,
            ..cam
        };
        let mut k = SemidenseKeyframe::new(&Image::new(w, h), &c, &pose(0), &cfg);
        assert_eq!(k.num_candidates(), 0);
        assert_eq!(k.observe(&Image::new(w, h), &pose(1)).matched, 0);
        assert!(k.map().points.is_empty());
    }
    let k = SemidenseKeyframe::new(&small, &cam, &pose(0), &cfg);
    assert_eq!(k.num_candidates(), 0);
    let flat = Image::from_fn(cam.width, cam.height, |_, _| 100.0f32);
    assert_eq!(
        SemidenseKeyframe::new(&flat, &cam, &pose(0), &cfg).num_candidates(),
        0
    );
    let broken = CameraModel {
        fx: f64::NAN,
        ..cam
    };
    let mut k = SemidenseKeyframe::new(&img, &broken, &pose(0), &cfg);
    assert_eq!(k.num_candidates(), 0);
    assert!(k.observe(&img, &pose(1)).skipped.is_some());
}

#[test]
fn candidate_cap_is_respected() {
    let cam = camera();
    let img = scene().render(&cam, &pose(0), 1.0, 0.0);
    let cfg = SemidenseConfig {
        max_candidates: 1000,
        ..Default::default()
    };
    let kf = SemidenseKeyframe::new(&img, &cam, &pose(0), &cfg);
    assert!(
        (900..=1000).contains(&kf.num_candidates()),
        "{}",
        kf.num_candidates()
    );
}

#[test]
fn map_points_lie_on_the_plane_in_3d() {
    // Independent check of the conventions: back-project the points with the public camera API.
    let cam = camera();
    let plane = scene();
    let cfg = SemidenseConfig::default();
    let kf_pose = Isometry3::from_parts(
        Translation3::new(0.1, -0.05, 0.2),
        UnitQuaternion::from_euler_angles(0.02, 0.03, -0.05),
    );
    let mut kf = SemidenseKeyframe::new(
        &plane.render(&cam, &kf_pose, 1.0, 0.0),
        &cam,
        &kf_pose,
        &cfg,
    );
    for k in [1, -1, 2, -2, 3, -3] {
        let p = kf_pose * pose(k);
        kf.observe(&plane.render(&cam, &p, 1.0, 0.0), &p);
    }
    let map = kf.map();
    assert!(map.points.len() > 2000);
    let mut d: Vec<f64> = map
        .points
        .iter()
        .map(|p| {
            let ray = cam
                .unproject(&Vector2::new(p.u_px as f64, p.v_px as f64))
                .unwrap();
            let x = map.t_world_cam * Point3::from(ray / p.inv_depth_m_inv as f64);
            (plane.n.dot(&x.coords) - plane.dist).abs()
        })
        .collect();
    d.sort_by(f64::total_cmp);
    assert!(
        d[d.len() / 2] < 0.01,
        "median distance to the plane {} m",
        d[d.len() / 2]
    );
}

#[test]
fn a_keyframe_triangulated_at_the_wrong_scale_is_rescaled_and_fuses_metric_views() {
    let cam = camera();
    let plane = scene();
    let cfg = SemidenseConfig::default();
    // The views' poses as a tracker with a 30 % too long baseline reports them: the map comes out
    // 30 % too deep (inverse depths 1/1.3 of the truth).
    let scaled = |k: i32| {
        let p = pose(k);
        Isometry3::from_parts(Translation3::from(p.translation.vector * 1.3), p.rotation)
    };
    let mut kf = keyframe_after_six_views(&cam, &plane, &cfg, scaled);
    let before = kf.map();
    let ratio = |m: &SemidenseMap| median_inv_depth_ratio(&plane, m);
    assert!(before.points.len() > 2000, "{} points", before.points.len());
    assert!(
        (ratio(&before) - 1.0 / 1.3).abs() < 0.01,
        "{}",
        ratio(&before)
    );
    // Ignored: not a scale.
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        kf.scale_inv_depths(bad);
    }
    assert_eq!(kf.map(), before);
    kf.scale_inv_depths(1.3);
    let rescaled = kf.map();
    assert_eq!(rescaled.points.len(), before.points.len());
    for (a, b) in rescaled.points.iter().zip(&before.points) {
        assert!((a.inv_depth_m_inv / b.inv_depth_m_inv - 1.3).abs() < 1e-4);
        assert!((a.inv_depth_std_m_inv / b.inv_depth_std_m_inv - 1.3).abs() < 1e-4);
    }
    // Views at the true (metric) poses now agree with the map instead of splitting it.
    for k in [4, -4] {
        let s = kf.observe(&plane.render(&cam, &pose(k), 1.0, 0.0), &pose(k));
        assert!(s.matched > s.candidates / 3, "view {k}: {s:?}");
    }
    let after = kf.map();
    assert!(
        after.points.len() >= before.points.len(),
        "{} points",
        after.points.len()
    );
    let e = relative_errors(&plane, &after);
    assert!(e[e.len() / 2] < 0.01, "median {}", e[e.len() / 2]);
}

#[test]
fn thinned_candidates_keep_one_pixel_per_cell_and_the_depth_accuracy() {
    let cam = camera();
    let plane = scene();
    let img = plane.render(&cam, &pose(0), 1.0, 0.0);
    let all = SemidenseKeyframe::new(&img, &cam, &pose(0), &SemidenseConfig::default());
    let cfg = SemidenseConfig {
        candidate_cell_px: 2,
        ..Default::default()
    };
    let mut kf = SemidenseKeyframe::new(&img, &cam, &pose(0), &cfg);
    let (n_all, n) = (all.num_candidates(), kf.num_candidates());
    // At most one per 2x2 cell inside the 5 px margin; on this texture most cells have one.
    let b = cfg.border_px.max(4);
    let n_cells = (cam.width - 2 * b).div_ceil(2) * (cam.height - 2 * b).div_ceil(2);
    assert!(
        n < n_all && n <= n_cells && n * 2 > n_cells,
        "{n} of {n_all}, {n_cells} cells"
    );
    for k in [1, -1, 2, -2, 3, -3] {
        kf.observe(&plane.render(&cam, &pose(k), 1.0, 0.0), &pose(k));
    }
    let map = kf.map();
    assert!(map.points.len() > 1500, "{} points", map.points.len());
    // Cells are aligned to the candidates' border margin.
    let b = b as u32;
    let mut cells: Vec<(u32, u32)> = map
        .points
        .iter()
        .map(|p| ((p.u_px as u32 - b) / 2, (p.v_px as u32 - b) / 2))
        .collect();
    cells.sort_unstable();
    let before = cells.len();
    cells.dedup();
    assert_eq!(cells.len(), before, "two points in one 2x2 cell");
    let e = relative_errors(&plane, &map);
    let median = e[e.len() / 2];
    assert!(
        median < 0.005,
        "median relative inverse-depth error {median}"
    );
}

/// A new keyframe of a plane 1 m away observed by three views 1.8–3 cm to the side whose
/// tracked poses share a 25 % baseline error (a tracker 4.5–7.5 mm off), then, if `wide`, by
/// two views 9–10 cm to either side at their true poses. Returns the median inverse depth of its
/// map over the truth, and the map's number of points.
fn keyframe_after_short_biased_views(cfg: &SemidenseConfig, wide: bool) -> (f64, usize) {
    let cam = camera();
    let plane = Plane::new(Vector3::new(0.25, -0.14, 1.0), 1.0);
    let kf_pose = pose(0);
    let mut kf =
        SemidenseKeyframe::new(&plane.render(&cam, &kf_pose, 1.0, 0.0), &cam, &kf_pose, cfg);
    for side in [1.0, -1.0, 0.6] {
        let offset = Vector3::new(0.03, 0.006, 0.002) * side;
        let view = |scale: f64| {
            Isometry3::from_parts(Translation3::from(offset * scale), kf_pose.rotation)
        };
        let s = kf.observe(&plane.render(&cam, &view(1.0), 1.0, 0.0), &view(0.75));
        assert!(s.matched > s.candidates / 3, "{s:?}");
    }
    if wide {
        for k in [3, -3] {
            kf.observe(&plane.render(&cam, &pose(k), 1.0, 0.0), &pose(k));
        }
    }
    let m = kf.map();
    (median_inv_depth_ratio(&plane, &m), m.points.len())
}

#[test]
fn short_baselines_with_a_shared_pose_error_do_not_make_a_map_at_their_scale() {
    // Poses taken as exact: the three biased views agree with each other and make points at
    // their scale (inverse depths × 1/0.75) — a keyframe installed on them is tracked at it.
    let exact = SemidenseConfig::default();
    let (ratio, n_exact) = keyframe_after_short_biased_views(&exact, false);
    assert!(n_exact > 300, "{n_exact} points");
    assert!((ratio - 1.0 / 0.75).abs() < 0.05, "median ratio {ratio}");
    // With the views' pose uncertainty (5 mm against 1.8–3 cm) no point is certain enough to
    // be output yet…
    let cfg = SemidenseConfig {
        baseline_std_m: 0.005,
        ..exact
    };
    let (_, n) = keyframe_after_short_biased_views(&cfg, false);
    assert!(n < n_exact / 20, "{n} points");
    // …until wider views make the map, at the metric scale.
    let (ratio, n) = keyframe_after_short_biased_views(&cfg, true);
    assert!(n > 5000, "{n} points");
    assert!((ratio - 1.0).abs() < 0.02, "median ratio {ratio}");
}

/// A keyframe whose left half holds a propagated map at the true scale, observed by four views
/// whose tracked baselines share a 5 % error (inverse depths triangulated from them × 1/0.95).
/// Returns each view's measured scale and the median inverse depth over the truth of the points
/// in the right half, which only those views see.
fn keyframe_half_propagated_then_biased_views(cfg: &SemidenseConfig) -> (Vec<f32>, f64) {
    let cam = camera();
    let plane = Plane::new(Vector3::new(0.25, -0.14, 1.0), 1.0);
    let kf_pose = pose(0);
    let image = plane.render(&cam, &kf_pose, 1.0, 0.0);
    let mut earlier = SemidenseKeyframe::new(&image, &cam, &kf_pose, cfg);
    for k in [1, -1, 2, -2, 3, -3] {
        earlier.observe(&plane.render(&cam, &pose(k), 1.0, 0.0), &pose(k));
    }
    let mut prior = earlier.map();
    let half = cam.width as f32 / 2.0;
    prior.points.retain(|p| p.u_px < half - 10.0);
    let mut kf = SemidenseKeyframe::new(&image, &cam, &kf_pose, cfg);
    assert!(kf.propagate_from(&prior) > 1000);
    let mut scales = Vec::new();
    for k in [1, -1, 2, -2] {
        let truth = pose(k);
        let tracked = Isometry3::from_parts(
            Translation3::from(truth.translation.vector * 0.95),
            truth.rotation,
        );
        let s = kf.observe(&plane.render(&cam, &truth, 1.0, 0.0), &tracked);
        scales.extend(s.view_scale);
    }
    let mut m = kf.map();
    m.points.retain(|p| p.u_px > half + 10.0);
    assert!(m.points.len() > 1000, "{} points", m.points.len());
    (scales, median_inv_depth_ratio(&plane, &m))
}

#[test]
fn a_views_shared_baseline_error_reaches_the_map_only_with_the_view_scale_gain() {
    // Each view's scale against the propagated map is measured (×1/0.95 = 1.053)…
    let full = SemidenseConfig::default();
    let (scales, ratio) = keyframe_half_propagated_then_biased_views(&full);
    assert_eq!(scales.len(), 4, "{scales:?}");
    assert!(
        scales.iter().all(|s| (s - 1.0 / 0.95).abs() < 0.01),
        "{scales:?}"
    );
    // …and the points only these views see take their scale…
    assert!((ratio - 1.0 / 0.95).abs() < 0.01, "median ratio {ratio}");
    // …while with gain 0 every view is moved onto the map's scale, and so are the points only
    // they see.
    let anchored = SemidenseConfig {
        view_scale_gain: 0.0,
        ..full
    };
    let (scales, ratio) = keyframe_half_propagated_then_biased_views(&anchored);
    assert!(
        scales.iter().all(|s| (s - 1.0 / 0.95).abs() < 0.01),
        "{scales:?}"
    );
    assert!((ratio - 1.0).abs() < 0.01, "median ratio {ratio}");
}
