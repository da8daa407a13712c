//! One tracking step (issue 4): a 752x480 frame of the built-in flight tracked against a keyframe
//! 100 ms earlier with ground-truth depth, from the IMU prediction — pyramid, coarse-to-fine joint
//! visual-inertial Gauss-Newton and covariance. Also the keyframe construction it amortises, with
//! the points unprojected and with their rays looked up, and with as many points as a semidense
//! map has.

use criterion::{Criterion, criterion_group, criterion_main};
use vidslam::camera::PixelRays;
use vidslam::imu::{Matrix15, Preintegration};
use vidslam::runtime::replay::start_state;
use vidslam::tracking::{
    Keyframe, Tracker, TrackerConfig, depth_points_from_map, select_gradient_pixels,
};

mod common;

fn bench(c: &mut Criterion) {
    let segment = common::DemoSegment::render("tracking", 12.0, 0.2);
    let ds = &segment.ds;
    let gt = ds.ground_truth().unwrap().unwrap();
    let frames: Vec<_> = ds.frames().unwrap().map(Result::unwrap).collect();
    let imu: Vec<_> = ds.imu_samples().unwrap().map(Result::unwrap).collect();
    let (f0, f1) = (&frames[0], &frames[2]);
    let x0 = start_state(&gt, f0.t).unwrap();
    let cfg = TrackerConfig::default();
    let cam = ds.camera.model;
    let cov0 = Matrix15::identity() * 1e-6;
    let mut tr = Tracker::new(
        cfg.clone(),
        &cam,
        ds.camera.t_body_cam,
        ds.imu.noise,
        x0,
        cov0,
    );
    let img0 = f0.load().unwrap();
    tr.load_frame(&img0);
    let depth = ds.load_depth_m(f0.t).unwrap().unwrap();
    let pixels = select_gradient_pixels(tr.frame_pyramid(), &cfg);
    let pts = depth_points_from_map(&pixels, &depth, 0.05);
    let make_kf = |tr: &mut Tracker| {
        let t_world_cam = tr.t_world_cam();
        Keyframe::new(0, f0.t, tr.frame_pyramid(), &cam, t_world_cam, &pts, &cfg)
    };
    c.bench_function("keyframe_from_gt_depth_752x480", |b| {
        b.iter(|| make_kf(&mut tr))
    });
    // The same keyframe with the points' rays looked up (as the odometry builds its keyframes).
    let rays = PixelRays::new(&cam);
    c.bench_function("keyframe_from_gt_depth_rays_752x480", |b| {
        b.iter(|| {
            let t_world_cam = tr.t_world_cam();
            Keyframe::from_rays(0, f0.t, tr.frame_pyramid(), &rays, t_world_cam, &pts, &cfg)
        })
    });
    // A semidense map's size (the mapper's keyframes carry 8–20 thousand points): every
    // gradient pixel of 2x2 cells, so the per-level selection has many more candidates than cells
    // it keeps.
    let dense_cfg = TrackerConfig {
        select_cell_px: 2,
        ..cfg.clone()
    };
    let dense_pts = depth_points_from_map(
        &select_gradient_pixels(tr.frame_pyramid(), &dense_cfg),
        &depth,
        0.05,
    );
    let dense_name = format!("keyframe_from_rays_{}_points_752x480", dense_pts.len());
    c.bench_function(&dense_name, |b| {
        b.iter(|| {
            let t_world_cam = tr.t_world_cam();
            Keyframe::from_rays(
                0,
                f0.t,
                tr.frame_pyramid(),
                &rays,
                t_world_cam,
                &dense_pts,
                &cfg,
            )
        })
    });
    let kf = make_kf(&mut tr);
    tr.set_keyframe(kf);
    let img1 = f1.load().unwrap();
    let mut pre = Preintegration::new(f0.t, x0.bias);
    pre.integrate(&imu, f1.t, Some(&ds.imu.noise));
    c.bench_function("track_frame_752x480", |b| {
        b.iter(|| {
            tr.reset_state(x0, cov0);
            tr.track(f1.t, &img1, &pre)
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30);
    targets = bench
}
criterion_main!(benches);
