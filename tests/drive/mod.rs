//! Driving the odometry by hand in the integration tests: the built-in flight rendered into a
//! scratch directory, and a dataset fed into [`Odometry`] frame by frame with the IMU samples up
//! to (and one past) each frame, so a test can act between frames (black a frame, inject a
//! fault) where `replay` would not let it.

#![allow(dead_code)] // each test binary uses the helpers it needs

use std::path::{Path, PathBuf};
use vidslam::dataset::AslDataset;
use vidslam::image::Image;
use vidslam::imu::ImuSample;
use vidslam::runtime::odometry::{Odometry, OdometryConfig, OdometryFrame, Rig};
use vidslam::sim::{ImuSource, SimConfig, TrajectorySource, generate};
use vidslam::time::TimeNs;

/// The first `seconds` of the built-in flight, render seed `seed`, with the simulator's noise,
/// in the scratch directory `dir`.
pub fn render_builtin(dir: PathBuf, seconds: f64, seed: u64) -> PathBuf {
    let mut cfg = SimConfig::new(
        dir.clone(),
        TrajectorySource::Builtin("demo".into()),
        ImuSource::Synth,
    );
    cfg.seconds = Some(seconds);
    cfg.seed = seed;
    cfg.force = true;
    generate(&cfg).unwrap();
    dir
}

/// Feeds every frame of `dir` into a new [`Odometry`] with `cfg`; `before(odo, k, t)` runs before
/// frame `k` (at `t`) is pushed and returns the image to push instead of the recorded one, if any;
/// `after` sees each frame's output. Returns the odometry, not yet finished.
pub fn feed(
    dir: &Path,
    cfg: OdometryConfig,
    before: impl FnMut(&mut Odometry, usize, TimeNs) -> Option<Image<u8>>,
    after: impl FnMut(usize, &OdometryFrame),
) -> Odometry {
    feed_imu_mapped(dir, cfg, |s| s, before, after)
}

/// [`feed`] with every IMU sample passed through `map` first (a sensor turned, biased…).
pub fn feed_imu_mapped(
    dir: &Path,
    cfg: OdometryConfig,
    map: impl Fn(ImuSample) -> ImuSample,
    mut before: impl FnMut(&mut Odometry, usize, TimeNs) -> Option<Image<u8>>,
    mut after: impl FnMut(usize, &OdometryFrame),
) -> Odometry {
    let ds = AslDataset::open(dir).unwrap();
    let frames: Vec<_> = ds.frames().unwrap().map(Result::unwrap).collect();
    let imu: Vec<_> = ds.imu_samples().unwrap().map(|s| map(s.unwrap())).collect();
    let mut odo = Odometry::new(
        cfg,
        Rig {
            camera: ds.camera.model,
            t_body_cam: ds.camera.t_body_cam,
            noise: ds.imu.noise,
            vignette: ds.vignette,
        },
    );
    let mut next = 0;
    for (k, f) in frames.iter().enumerate() {
        odo.push_imu_for_frame(&imu, &mut next, f.t);
        let img = match before(&mut odo, k, f.t) {
            Some(img) => img,
            None => f.load().unwrap(),
        };
        let r = odo.push_frame(f.t, img);
        after(k, &r);
    }
    odo
}

/// Every frame's position and the odometry's counters, with the gyro's axes turned from the
/// body by `r` (`ω_gyro = Rᵀ ω_body`; `None`: as recorded).
pub fn positions_with_gyro_turned(
    dir: &Path,
    cfg: OdometryConfig,
    r: Option<nalgebra::Rotation3<f64>>,
) -> (
    Vec<nalgebra::Vector3<f64>>,
    vidslam::runtime::odometry::OdometryStats,
) {
    let mut p = Vec::new();
    let odo = feed_imu_mapped(
        dir,
        cfg,
        |s| match r {
            Some(r) => ImuSample {
                gyro_rad_s: r.inverse() * s.gyro_rad_s,
                ..s
            },
            None => s,
        },
        |_, _, _| None,
        |_, f| p.push(f.result.state.nav.p_world_m),
    );
    (p, odo.stats().clone())
}

/// The largest distance between two equally long position sequences, m.
pub fn max_gap_m(a: &[nalgebra::Vector3<f64>], b: &[nalgebra::Vector3<f64>]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).norm())
        .fold(0.0, f64::max)
}
