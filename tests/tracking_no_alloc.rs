//! Per-frame tracking does not allocate (issue 4: buffers belong to the keyframe and the tracker).
//! A counting global allocator wraps the system one; one frame is tracked after a warm-up frame.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use vidslam::camera::CameraModel;
use vidslam::image::{Image, Pyramid};
use vidslam::imu::{FrameState, ImuBias, ImuNoise, ImuSample, Matrix15, NavState, Preintegration};
use vidslam::time::TimeNs;
use vidslam::tracking::{
    Keyframe, NUM_LEVELS, Tracker, TrackerConfig, depth_points_from_map, select_gradient_pixels,
};

struct Counting;
static ALLOCS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn tracking_a_frame_does_not_allocate() {
    let cam = CameraModel::euroc_cam0();
    let img = Image::from_fn(cam.width, cam.height, |x, y| {
        let (x, y) = (x as f32, y as f32);
        (120.0 + 60.0 * (x * 0.09).sin() * (y * 0.06).cos() + 30.0 * (0.04 * (x + 2.0 * y)).sin())
            as u8
    });
    let x0 = FrameState {
        nav: NavState {
            t: TimeNs(0),
            r_world_body: Default::default(),
            p_world_m: Default::default(),
            v_world_m_s: Default::default(),
        },
        bias: ImuBias::default(),
    };
    let cfg = TrackerConfig::default();
    let cov = Matrix15::identity() * 1e-6;
    let mut tr = Tracker::new(
        cfg.clone(),
        &cam,
        Default::default(),
        ImuNoise::euroc_adis16448(),
        x0,
        cov,
    );
    let mut pyr = Pyramid::new(cam.width, cam.height, NUM_LEVELS);
    pyr.fill_from_u8(&img);
    let depth = Image::from_fn(cam.width, cam.height, |_, _| 2.5f32);
    let pts = depth_points_from_map(&select_gradient_pixels(&pyr, &cfg), &depth, 0.05);
    tr.set_keyframe(Keyframe::new(
        0,
        TimeNs(0),
        &pyr,
        &cam,
        Default::default(),
        &pts,
        &cfg,
    ));
    let imu: Vec<ImuSample> = (0..=11)
        .map(|k| ImuSample {
            t: TimeNs(k * 5_000_000),
            gyro_rad_s: Default::default(),
            accel_m_s2: nalgebra::Vector3::new(0.0, 0.0, 9.81),
        })
        .collect();
    let t1 = TimeNs(50_000_000);
    let mut pre = Preintegration::new(TimeNs(0), ImuBias::default());
    pre.integrate(&imu, t1, Some(&ImuNoise::euroc_adis16448()));
    let warm = tr.track(t1, &img, &pre);
    assert_eq!(warm.flag, None);
    tr.reset_state(x0, cov);
    let before = ALLOCS.load(Ordering::Relaxed);
    let r = tr.track(t1, &img, &pre);
    let after = ALLOCS.load(Ordering::Relaxed);
    assert_eq!(r.flag, None);
    assert!(r.iterations.iter().any(|&i| i > 0) || r.inlier_ratio > 0.9);
    assert_eq!(
        after - before,
        0,
        "Tracker::track allocated {} times",
        after - before
    );
}
