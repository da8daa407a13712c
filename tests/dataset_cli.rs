//! `vidslam dataset imu-rewrite` through the binary, on the real EuRoC clip: the copy reads as a
//! dataset, its images are the original's (linked), every IMU sample is turned and de-biased as
//! asked, the original is untouched, and bad vectors or an existing output are refused.

mod cli;
mod scratch;

use cli::{text, vidslam};
use nalgebra::{Rotation3, Vector3};
use std::process::Output;
use vidslam::dataset::{AslDataset, shared_data_or_skip};

/// `vidslam dataset imu-rewrite DIR --out OUT FLAGS…`.
fn imu_rewrite(dir: &str, out: &str, flags: &[&str]) -> Output {
    let mut args = vec!["dataset", "imu-rewrite", dir, "--out", out];
    args.extend_from_slice(flags);
    vidslam(&args)
}

#[test]
fn the_real_clip_rewritten_with_a_turned_gyro_and_an_accelerometer_bias_taken_out() {
    let Some(src) = shared_data_or_skip("euroc/V1_01_easy_micro") else {
        return;
    };
    let out = scratch::path("imu-rewrite-real-clip");
    let before = std::fs::read(src.join("mav0/imu0/data.csv")).unwrap();
    let (src_s, out_s) = (src.to_str().unwrap(), out.to_str().unwrap());
    let o = imu_rewrite(
        src_s,
        out_s,
        &[
            "--gyro-rotation-deg",
            "-0.339,-0.013,-1.305",
            "--accel-bias-m-s2",
            "-0.017,0.542,0.064",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("linked from"), "{}", text(&o));
    assert_eq!(
        std::fs::read(src.join("mav0/imu0/data.csv")).unwrap(),
        before
    );

    let (a, b) = (
        AslDataset::open(&src).unwrap(),
        AslDataset::open(&out).unwrap(),
    );
    let frames = |d: &AslDataset| -> Vec<_> {
        d.frames()
            .unwrap()
            .map(|f| f.unwrap().t)
            .collect::<Vec<_>>()
    };
    assert_eq!(frames(&a), frames(&b));
    assert!(out.join("mav0/cam0").is_symlink());
    assert_eq!(a.camera.model, b.camera.model);

    let rg = Rotation3::new(Vector3::new(-0.339_f64, -0.013, -1.305).map(f64::to_radians));
    let ba = Vector3::new(-0.017, 0.542, 0.064);
    let (sa, sb): (Vec<_>, Vec<_>) = (
        a.imu_samples().unwrap().map(|s| s.unwrap()).collect(),
        b.imu_samples().unwrap().map(|s| s.unwrap()).collect(),
    );
    assert_eq!(sa.len(), sb.len());
    assert!(sa.len() > 900, "{} IMU samples", sa.len());
    for (x, y) in sa.iter().zip(&sb) {
        assert_eq!(x.t, y.t);
        assert!((rg * x.gyro_rad_s - y.gyro_rad_s).norm() < 1e-12);
        assert!((x.accel_m_s2 - ba - y.accel_m_s2).norm() < 1e-12);
    }
    // The turn is real: about z by 1.3°, a rate about x shows on y.
    let moved = sa
        .iter()
        .zip(&sb)
        .map(|(x, y)| (x.gyro_rad_s - y.gyro_rad_s).norm())
        .fold(0.0, f64::max);
    assert!(moved > 1e-4, "largest change {moved} rad/s");

    let info = vidslam(&["dataset", "info", out_s]);
    assert!(info.status.success(), "{}", text(&info));

    let again = imu_rewrite(src_s, out_s, &[]);
    assert!(!again.status.success());
    assert!(text(&again).contains("not empty"), "{}", text(&again));
    // Removing the copy removes its links, never what they point at.
    std::fs::remove_dir_all(&out).unwrap();
    assert!(src.join("mav0/cam0/data.csv").is_file());
}

#[test]
fn a_vector_that_is_not_three_finite_numbers_names_its_flag() {
    for (flag, value) in [
        ("--accel-bias-m-s2", "0.1,0.2"),
        ("--gyro-rotation-deg", "1,x,0"),
        ("--gyro-bias-rad-s", "0,0,NaN"),
    ] {
        let o = imu_rewrite("nowhere", "nowhere-out", &[flag, value]);
        assert!(!o.status.success());
        assert!(text(&o).contains(flag), "{flag} {value}: {}", text(&o));
    }
    let o = imu_rewrite(
        "nowhere",
        "nowhere-out",
        &["--accel-rotation-deg", "45,0,0"],
    );
    assert!(
        !o.status.success() && text(&o).contains("30°"),
        "{}",
        text(&o)
    );
    assert!(!std::path::Path::new("nowhere-out").exists());
}
