//! `vidslam dataset imu-rewrite` through the binary, on the real EuRoC clip: the copy reads as a
//! dataset, its images are the original's (linked), every IMU sample is turned and de-biased as
//! asked, the original is untouched, and bad vectors or an existing output are refused; a band of
//! another copy's accelerometer mixed in takes only what differs in that band.

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

#[test]
fn a_band_of_another_copy_s_accelerometer_takes_only_what_differs_in_that_band() {
    let Some(src) = shared_data_or_skip("euroc/V1_01_easy_micro") else {
        return;
    };
    // The donor: the clip with 0.5 m/s² taken off its accelerometer's y (a constant, so all of it
    // at 0 Hz) and its gyro turned.
    let donor = scratch::path("imu-mix-donor");
    let (src_s, donor_s) = (src.to_str().unwrap(), donor.to_str().unwrap());
    let o = imu_rewrite(
        src_s,
        donor_s,
        &[
            "--accel-bias-m-s2",
            "0,0.5,0",
            "--gyro-rotation-deg",
            "0,0,2",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    let samples = |d: &std::path::Path| -> Vec<_> {
        AslDataset::open(d)
            .unwrap()
            .imu_samples()
            .unwrap()
            .map(|s| s.unwrap())
            .collect::<Vec<_>>()
    };
    let (orig, don) = (samples(&src), samples(&donor));

    // Below 0.1 Hz: the constant comes in whole, the gyro stays the clip's.
    let low = scratch::path("imu-mix-low");
    let o = imu_rewrite(
        src_s,
        low.to_str().unwrap(),
        &["--accel-from", donor_s, "--mix-band-hz", "0,0.1"],
    );
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("0 without a donor row"), "{}", text(&o));
    let mixed = samples(&low);
    assert_eq!(mixed.len(), orig.len());
    for (m, o) in mixed.iter().zip(&orig) {
        assert_eq!(m.t, o.t);
        assert_eq!(m.gyro_rad_s, o.gyro_rad_s);
        assert!((m.accel_m_s2 - o.accel_m_s2 - Vector3::new(0.0, -0.5, 0.0)).norm() < 1e-9);
    }
    // At 0.1–1 Hz a constant has nothing: the copy reads as the clip.
    let mid = scratch::path("imu-mix-mid");
    let o = imu_rewrite(
        src_s,
        mid.to_str().unwrap(),
        &["--accel-from", donor_s, "--mix-band-hz", "0.1,1"],
    );
    assert!(o.status.success(), "{}", text(&o));
    for (m, o) in samples(&mid).iter().zip(&orig) {
        assert!((m.accel_m_s2 - o.accel_m_s2).norm() < 1e-9);
    }
    // The whole band is the donor's gyro, bit for bit.
    let whole = scratch::path("imu-mix-whole");
    let o = imu_rewrite(src_s, whole.to_str().unwrap(), &["--gyro-from", donor_s]);
    assert!(o.status.success(), "{}", text(&o));
    for ((m, d), o) in samples(&whole).iter().zip(&don).zip(&orig) {
        assert_eq!(m.gyro_rad_s, d.gyro_rad_s);
        assert_eq!(m.accel_m_s2, o.accel_m_s2);
    }

    // A band needs a donor, and a band is LO < HI; neither leaves a copy behind.
    let bad = scratch::path("imu-mix-bad");
    let bad_s = bad.to_str().unwrap();
    let o = imu_rewrite(src_s, bad_s, &["--mix-band-hz", "0.1,1"]);
    assert!(
        !o.status.success() && text(&o).contains("--accel-from"),
        "{}",
        text(&o)
    );
    let o = imu_rewrite(
        src_s,
        bad_s,
        &["--accel-from", donor_s, "--mix-band-hz", "1,0.5"],
    );
    assert!(
        !o.status.success() && text(&o).contains("--mix-band-hz"),
        "{}",
        text(&o)
    );
    let o = imu_rewrite(src_s, bad_s, &["--accel-from", "no-such-dataset"]);
    assert!(
        !o.status.success() && text(&o).contains("no-such-dataset"),
        "{}",
        text(&o)
    );
    assert!(!bad.exists());
    for d in [donor, low, mid, whole] {
        std::fs::remove_dir_all(d).unwrap();
    }
}
