//! Looking for the closest stored keyframe (issue 5, `[reuse]`): what the tracking thread does
//! each time it asks for a new keyframe — a full store of 400 keyframes on a 20 x 20 grid of
//! poses (every 0.1 m, all facing a wall 2 m ahead), queried from a pose among them and from one
//! far from all of them.

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::sync::Arc;
use vidslam::camera::CameraModel;
use vidslam::image::{Image, Pyramid};
use vidslam::mapping::semidense::SemidenseMap;
use vidslam::runtime::keyframe_store::{KeyframeStore, ReuseConfig};
use vidslam::time::TimeNs;
use vidslam::tracking::{DepthPoint, Keyframe, NUM_LEVELS, TrackerConfig};

fn bench(c: &mut Criterion) {
    let cam = CameraModel::euroc_cam0();
    let img = Image::from_fn(cam.width, cam.height, |x, y| {
        128.0f32 + 60.0 * ((x as f32) * 0.21).sin() * ((y as f32) * 0.17).cos()
    });
    let mut pyr = Pyramid::new(cam.width, cam.height, NUM_LEVELS);
    pyr.fill_from_f32(&img);
    let pts: Vec<DepthPoint> = (8..cam.height - 8)
        .step_by(4)
        .flat_map(|v| {
            (8..cam.width - 8).step_by(4).map(move |u| DepthPoint {
                u_px: u as f32,
                v_px: v as f32,
                inv_depth_m_inv: 0.5,
            })
        })
        .collect();
    let cfg = TrackerConfig::default();
    let map = Arc::new(SemidenseMap {
        t_world_cam: Isometry3::identity(),
        camera: cam,
        points: Vec::new(),
    });
    let mut store = KeyframeStore::new(ReuseConfig::default());
    let pose = |x: f64, y: f64| {
        Isometry3::from_parts(Translation3::new(x, y, 0.0), UnitQuaternion::identity())
    };
    for i in 0..400u32 {
        let (x, y) = ((i % 20) as f64 * 0.1, (i / 20) as f64 * 0.1);
        let kf = Keyframe::new(i, TimeNs(i as i64), &pyr, &cam, pose(x, y), &pts, &cfg);
        assert!(store.insert(kf, map.clone()));
    }
    let near = pose(1.03, 0.97);
    let far = pose(50.0, 0.0);
    assert!(store.closest(&near, 2.0, |_| false).is_some());
    assert!(store.closest(&far, 2.0, |_| false).is_none());
    c.bench_function("closest of 400 stored keyframes, near", |b| {
        b.iter(|| store.closest(&near, 2.0, |_| false))
    });
    c.bench_function("closest of 400 stored keyframes, none near", |b| {
        b.iter(|| store.closest(&far, 2.0, |_| false))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
