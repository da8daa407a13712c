//! The in-flight keyframe adjustment (`src/runtime/keyframe_bundle.rs`, `[keyframe_bundle]`):
//! a 752x480 keyframe of the built-in flight whose ground-truth inverse depths are off by ±10 %,
//! with the three frames tracked after it (`min_views`) and the IMU between them — its depths,
//! the views' states, the velocity and the accelerometer bias optimised jointly, coarse to fine,
//! on the global rayon pool as on the refinement thread's. In real time a new keyframe waits for
//! this before it is tracked, so its time is latency (offline, the demo's p50 is in `report.json`
//! `keyframe_bundle_ms_p50`).

use criterion::{Criterion, criterion_group, criterion_main};
use std::sync::Arc;
use vidslam::image::Pyramid;
use vidslam::imu::FrameState;
use vidslam::runtime::keyframe_bundle::{
    KeyframeBundleConfig, KeyframeRecord, bundle_adjust_keyframe,
};
use vidslam::runtime::mapping_worker::MapFrame;
use vidslam::runtime::replay::start_state;
use vidslam::tracking::{
    Keyframe, NUM_LEVELS, TrackerConfig, depth_points_from_map, select_gradient_pixels,
};

mod common;

fn bench(c: &mut Criterion) {
    let segment = common::DemoSegment::render("kfba", 12.0, 0.25);
    let ds = &segment.ds;
    let gt = ds.ground_truth().unwrap().unwrap();
    let frames: Vec<_> = ds.frames().unwrap().map(Result::unwrap).collect();
    let imu: Vec<_> = ds.imu_samples().unwrap().map(Result::unwrap).collect();
    let state = |t| start_state(&gt, t).unwrap();
    let cam = ds.camera.model;
    let cfg = TrackerConfig::default();
    let f0 = &frames[0];
    let img0 = f0.load().unwrap();
    let host = Pyramid::from_u8(&img0, NUM_LEVELS);
    let depth = ds.load_depth_m(f0.t).unwrap().unwrap();
    let mut pts = depth_points_from_map(&select_gradient_pixels(&host, &cfg), &depth, 0.05);
    // A mapper's errors: ±10 % in a fixed pattern.
    for (i, p) in pts.iter_mut().enumerate() {
        p.inv_depth_m_inv *= 1.0 + 0.1 * ((i as f32) * 0.7).sin();
    }
    let x0 = state(f0.t);
    let pose = |x: &FrameState| {
        nalgebra::Isometry3::from_parts(x.nav.p_world_m.into(), x.nav.r_world_body)
            * ds.camera.t_body_cam
    };
    let kf = Keyframe::new(0, f0.t, &host, &cam, pose(&x0), &pts, &cfg);
    let views = frames[1..=3]
        .iter()
        .map(|f| {
            let x = state(f.t);
            let frame = MapFrame {
                t: f.t,
                image: Arc::new(f.load().unwrap()),
                t_world_cam: pose(&x),
            };
            (frame, x)
        })
        .collect();
    let rec = KeyframeRecord {
        id: 0,
        start: x0,
        views,
        previous: None,
        gyro_turn_rad: nalgebra::Vector3::zeros(),
    };
    let kb = KeyframeBundleConfig::default();
    let adjust = || {
        bundle_adjust_keyframe(
            &rec,
            &kf,
            &host,
            &imu,
            ds.camera.t_body_cam,
            ds.imu.noise,
            cfg.imu_noise_scale,
            cfg.gradient_weight_gray_px,
            &kb,
        )
    };
    let a = adjust().expect("adjusted");
    println!(
        "{} points, median inverse-depth change {:.1} %",
        a.points.len(),
        a.median_inv_depth_change * 100.0
    );
    c.bench_function("keyframe_adjustment_752x480_3_views", |b| b.iter(adjust));
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
