//! Photometric consistency of ideal (`--no-noise`) renders at full EuRoC size: warping frame k into
//! frame k+1 with the ground-truth depth and poses reproduces frame k+1 to under 2 grey levels
//! mean absolute error on non-occluded pixels.
//!
//! "Non-occluded": the warped point is inside frame k+1, frame k+1's bilinearly interpolated depth
//! there agrees with the point's predicted depth within 1 % and its four neighbouring depths
//! within 5 % (visible, not at a depth edge), and frame k's 3x3 depth neighbourhood is continuous
//! within 5 % (the source pixel is not a mix of two surfaces).

mod scratch;

use nalgebra::{Point3, Vector2};
use vidslam::dataset::AslDataset;
use vidslam::image::bilinear;
use vidslam::sim::{ImuSource, SimConfig, TrajectorySource, generate};

#[test]
fn warping_with_ground_truth_depth_and_pose_reproduces_the_next_frame() {
    let dir = scratch::dir("sim-photo");
    let mut cfg = SimConfig::new(
        dir.clone(),
        TrajectorySource::Builtin("demo".into()),
        ImuSource::Synth,
    );
    cfg.start_s = Some(11.0); // mid figure-eight: ~1.5 m/s, turning
    cfg.seconds = Some(0.25);
    cfg.realism = false;
    cfg.force = true;
    generate(&cfg).unwrap();

    let ds = AslDataset::open(&dir).unwrap();
    assert!(
        ds.vignette.is_none(),
        "an ideal render has no vignetting to calibrate"
    );
    let cam = ds.camera.model;
    let t_bc = ds.camera.t_body_cam;
    let gt = ds.ground_truth().unwrap().unwrap();
    let frames: Vec<_> = ds.frames().unwrap().map(|f| f.unwrap()).collect();
    assert_eq!(frames.len(), 6);
    let (w, h) = (cam.width, cam.height);
    for pair in frames.windows(2) {
        let (fa, fb) = (&pair[0], &pair[1]);
        let ia = fa.load().unwrap().to_f32();
        let ib = fb.load().unwrap().to_f32();
        let da = ds.load_depth_m(fa.t).unwrap().unwrap();
        let db = ds.load_depth_m(fb.t).unwrap().unwrap();
        let ta = gt.nearest(fa.t, 0).unwrap().t_world_body * t_bc;
        let tb = gt.nearest(fb.t, 0).unwrap().t_world_body * t_bc;
        let t_b_a = tb.inverse() * ta;
        let moved_m = t_b_a.translation.vector.norm();
        let (mut n, mut sum) = (0usize, 0.0f64);
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let z = da.get(x, y) as f64;
                if z <= 0.0 {
                    continue;
                }
                let continuous = (0..3).all(|j| {
                    (0..3).all(|i| ((da.get(x + i - 1, y + j - 1) as f64) - z).abs() < 0.05 * z)
                });
                if !continuous {
                    continue;
                }
                let ray = cam.unproject(&Vector2::new(x as f64, y as f64)).unwrap();
                let pb = t_b_a.transform_point(&Point3::from(ray * z));
                let Some(uv) = cam.project(&pb.coords) else {
                    continue;
                };
                if !cam.in_image(&uv, 1.0) {
                    continue;
                }
                let (x0, y0) = (uv.x.floor() as usize, uv.y.floor() as usize);
                let zb = bilinear(&db, uv.x as f32, uv.y as f32).unwrap() as f64;
                let visible = (zb - pb.z).abs() < 0.01 * pb.z
                    && [(0, 0), (1, 0), (0, 1), (1, 1)].iter().all(|&(i, j)| {
                        ((db.get(x0 + i, y0 + j) as f64) - pb.z).abs() < 0.05 * pb.z
                    });
                if !visible {
                    continue;
                }
                let vb = bilinear(&ib, uv.x as f32, uv.y as f32).unwrap() as f64;
                sum += (ia.get(x, y) as f64 - vb).abs();
                n += 1;
            }
        }
        let mean = sum / n as f64;
        eprintln!(
            "{} -> {}: moved {:.1} mm, {n} pixels ({:.0} %), mean |error| {mean:.3} grey levels",
            fa.t.0,
            fb.t.0,
            moved_m * 1e3,
            100.0 * n as f64 / (w * h) as f64
        );
        assert!(moved_m > 0.03, "the camera must move between frames");
        assert!(n > w * h * 6 / 10, "too few comparable pixels: {n}");
        assert!(mean < 2.0, "mean abs error {mean}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A realistic render ships the photometric calibration of the vignetting it applied
/// (`cam0/vignette.yaml`, read back by the dataset reader); the correction itself is tested in
/// `camera::vignette`.
#[test]
fn realistic_renders_carry_their_vignetting_calibration() {
    let dir = scratch::dir("sim-vignette");
    let mut cfg = SimConfig::new(
        dir.clone(),
        TrajectorySource::Builtin("demo".into()),
        ImuSource::Synth,
    );
    cfg.seconds = Some(0.1);
    cfg.force = true;
    generate(&cfg).unwrap();
    let ds = AslDataset::open(&dir).unwrap();
    let v = ds.vignette.expect("cam0/vignette.yaml");
    let cam = ds.camera.model;
    assert_eq!(v.centre_px, [cam.cx, cam.cy]);
    assert_eq!(v.factor(cam.cx, cam.cy), 1.0);
    // The farthest corner loses the simulator's 35 %.
    let corner = [(0.0, 0.0), (752.0, 0.0), (0.0, 480.0), (752.0, 480.0)]
        .iter()
        .map(|&(x, y)| v.factor(x, y))
        .fold(f64::INFINITY, f64::min);
    assert!(
        (corner - (1.0 - vidslam::sim::exposure::VIGNETTING)).abs() < 1e-9,
        "{corner}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
