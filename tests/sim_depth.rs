//! Ground-truth depth agrees with an independent ray–plane intersection of the quads in
//! `scene.json`, using the poses of the written ground truth and the camera of the written
//! `cam0/sensor.yaml` (so the files, not the renderer's internals, are what is checked).

mod scratch;

use nalgebra::{Point3, Vector2, Vector3};
use vidslam::camera::CameraModel;
use vidslam::dataset::AslDataset;
use vidslam::sim::{ImuSource, SimConfig, TrajectorySource, generate};

struct Rect {
    c: Vector3<f64>,
    u: Vector3<f64>,
    v: Vector3<f64>,
    n: Vector3<f64>,
}

fn vec3(v: &serde_json::Value) -> Vector3<f64> {
    let a = v.as_array().expect("3-array");
    Vector3::new(
        a[0].as_f64().unwrap(),
        a[1].as_f64().unwrap(),
        a[2].as_f64().unwrap(),
    )
}

/// Nearest front-facing hit of `o + λ d`.
fn nearest(rects: &[Rect], o: &Vector3<f64>, d: &Vector3<f64>) -> Option<f64> {
    let mut best: Option<f64> = None;
    for r in rects {
        let den = r.n.dot(d);
        if den >= 0.0 {
            continue;
        }
        let l = r.n.dot(&(r.c - o)) / den;
        if l <= 0.0 {
            continue;
        }
        let rel = o + d * l - r.c;
        let (a, b) = (
            rel.dot(&r.u) / r.u.norm_squared(),
            rel.dot(&r.v) / r.v.norm_squared(),
        );
        if (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b) && best.is_none_or(|x| l < x) {
            best = Some(l);
        }
    }
    best
}

#[test]
fn depth_maps_match_ray_plane_intersection_of_scene_json() {
    let dir = scratch::dir("sim-depth");
    let mut cfg = SimConfig::new(
        dir.clone(),
        TrajectorySource::Builtin("demo".into()),
        ImuSource::Synth,
    );
    cfg.start_s = Some(14.0);
    cfg.seconds = Some(1.0);
    cfg.seed = 3;
    cfg.force = true;
    cfg.camera.model = CameraModel::euroc_cam0().scaled_to_level(2); // 188x120, distorted
    generate(&cfg).unwrap();

    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("scene.json")).unwrap()).unwrap();
    let rects: Vec<Rect> = json["quads"]
        .as_array()
        .unwrap()
        .iter()
        .map(|q| {
            let (u, v) = (vec3(&q["edge_u_m"]), vec3(&q["edge_v_m"]));
            Rect {
                c: vec3(&q["corner_m"]),
                u,
                v,
                n: u.cross(&v).normalize(),
            }
        })
        .collect();
    assert!(rects.len() > 40);

    let ds = AslDataset::open(&dir).unwrap();
    let cam = ds.camera.clone();
    let gt = ds.ground_truth().unwrap().unwrap();
    let (mut n, mut bad, mut max_err, mut sum_err) = (0usize, 0usize, 0.0f64, 0.0f64);
    let mut frames = 0;
    for (k, f) in ds.frames().unwrap().enumerate() {
        let f = f.unwrap();
        if k % 5 != 0 {
            continue;
        }
        frames += 1;
        let state = gt
            .nearest(f.t, 0)
            .expect("a ground-truth row at every frame time");
        let t_world_cam = state.t_world_body * cam.t_body_cam;
        let depth = ds
            .load_depth_m(f.t)
            .unwrap()
            .expect("depth for every frame");
        let o = t_world_cam.translation.vector;
        for y in 0..cam.model.height {
            for x in 0..cam.model.width {
                let ray = cam
                    .model
                    .unproject(&Vector2::new(x as f64, y as f64))
                    .unwrap();
                let d = t_world_cam.rotation * ray;
                let want = nearest(&rects, &o, &d).expect("closed room");
                // The ray has unit z in the camera frame, so λ is the z-depth.
                let p_cam = t_world_cam.inverse_transform_point(&Point3::from(o + d * want));
                assert!((p_cam.z - want).abs() < 1e-9);
                let got = depth.get(x, y) as f64;
                let err = (got - want).abs();
                n += 1;
                sum_err += err;
                // PNG quantisation 0.1 mm + f32 rendering.
                if err > 2e-4 + 2e-6 * want {
                    bad += 1;
                } else {
                    max_err = max_err.max(err);
                }
            }
        }
    }
    eprintln!(
        "{frames} frames, {n} pixels: mean |error| {:.4} mm, max {:.4} mm on {} agreeing pixels, {bad} disagree",
        sum_err / n as f64 * 1e3,
        max_err * 1e3,
        n - bad
    );
    assert_eq!(frames, 5);
    // Only pixels whose centre ray grazes a quad edge may differ (f32 vs f64 at silhouettes).
    assert!(
        (bad as f64) < 0.002 * n as f64,
        "{bad} of {n} pixels disagree"
    );
    assert!(sum_err / (n as f64) < 1e-3);
    std::fs::remove_dir_all(&dir).ok();
}
