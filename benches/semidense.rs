//! The semidense mapper's jobs (paper section IV-A, eq. 27–28), each on a 752x480 frame of the
//! built-in flight with ground-truth poses: a new keyframe (candidate selection and 7x7
//! templates), the propagation of the previous keyframe's map into it, and one view observed
//! (epipolar search of every candidate) — the first view of a fresh keyframe and the fourth, when
//! part of the pixels have converged. Views on the global rayon pool (`[mapping] parallel`, as the
//! mapping thread runs them) and on one thread. In real time these are what the mapping thread
//! spends its core on: a new keyframe's map costs the new keyframe, the propagation and
//! `[bootstrap] history_frames` views before the tracker can use it.

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use nalgebra::Isometry3;
use vidslam::image::Image;
use vidslam::mapping::semidense::{SemidenseConfig, SemidenseKeyframe};

mod common;

fn bench(c: &mut Criterion) {
    // The first figure-eight: ~1.5 m/s, frames 7.5 cm apart.
    let segment = common::DemoSegment::render("semidense", 10.0, 0.6);
    let ds = &segment.ds;
    let gt = ds.ground_truth().unwrap().unwrap();
    let (images, poses): (Vec<Image<f32>>, Vec<Isometry3<f64>>) = ds
        .frames()
        .unwrap()
        .map(|f| {
            let f = f.unwrap();
            let pose = gt.nearest(f.t, 0).unwrap().t_world_body * ds.camera.t_body_cam;
            (f.load().unwrap().to_f32(), pose)
        })
        .unzip();
    let cam = ds.camera.model;
    let (prev, kf) = (0, 6);
    let parallel = SemidenseConfig::default();
    let serial = SemidenseConfig {
        parallel: false,
        ..parallel.clone()
    };
    let new_kf = |cfg: &SemidenseConfig| SemidenseKeyframe::new(&images[kf], &cam, &poses[kf], cfg);

    c.bench_function("semidense_new_keyframe_752x480", |b| {
        b.iter(|| new_kf(&parallel))
    });

    // The previous keyframe's map, from four views of its own.
    let mut p = SemidenseKeyframe::new(&images[prev], &cam, &poses[prev], &parallel);
    for v in [1, 2, 3, 4] {
        p.observe(&images[v], &poses[v]);
    }
    let previous = p.map();
    c.bench_function("semidense_propagate_752x480", |b| {
        b.iter_batched(
            || new_kf(&parallel),
            |mut k| k.propagate_from(&previous),
            BatchSize::LargeInput,
        )
    });

    for (name, cfg) in [("parallel", &parallel), ("one_thread", &serial)] {
        c.bench_function(&format!("semidense_first_view_752x480_{name}"), |b| {
            b.iter_batched(
                || new_kf(cfg),
                |mut k| k.observe(&images[kf + 1], &poses[kf + 1]),
                BatchSize::LargeInput,
            )
        });
        let mut warm = new_kf(cfg);
        for v in [kf + 1, kf - 1, kf + 2] {
            warm.observe(&images[v], &poses[v]);
        }
        c.bench_function(&format!("semidense_fourth_view_752x480_{name}"), |b| {
            b.iter_batched(
                || warm.clone(),
                |mut k| k.observe(&images[kf - 2], &poses[kf - 2]),
                BatchSize::LargeInput,
            )
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
