//! One 752x480 frame of the built-in demo (realistic: motion blur, noise), and the same ideal.

use criterion::{Criterion, criterion_group, criterion_main};
use vidslam::camera::CameraModel;
use vidslam::sim::exposure::Exposure;
use vidslam::sim::flights::builtin_flight;
use vidslam::sim::write::{euroc_cam0_t_body_cam, frame_poses};
use vidslam::sim::{Renderer, Scene, fit_pose_spline};

fn bench(c: &mut Criterion) {
    let tb = euroc_cam0_t_body_cam();
    let tr = builtin_flight("demo", &tb).unwrap();
    let (sp, _) = fit_pose_spline(&tr.poses, 50_000_000).unwrap();
    let path: Vec<_> = tr
        .poses
        .iter()
        .map(|p| p.t_world_body.translation.vector)
        .collect();
    let scene = Scene::build(&path, 1);
    let renderer = Renderer::new(&scene, &CameraModel::euroc_cam0()).unwrap();
    let t = sp.start().add_ns(12_000_000_000);
    let exp = Exposure::ideal();
    let blurred = frame_poses(&sp, &tb, t, Some(exp.exposure_s));
    let sharp = frame_poses(&sp, &tb, t, None);
    c.bench_function("render_752x480_realistic", |b| {
        b.iter(|| renderer.render(0, &blurred, &exp, true, 1))
    });
    c.bench_function("render_752x480_ideal", |b| {
        b.iter(|| renderer.render(0, &sharp, &exp, false, 1))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
