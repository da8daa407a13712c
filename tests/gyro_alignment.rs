//! The in-flight gyro alignment (`[gyro_alignment]`, `src/imu/gyro_alignment.rs`) on the built-in
//! flight: estimating it does not touch the odometry, and a rotation known beforehand
//! (`initial_rotation_deg`) turns a gyro mounted askew back onto the camera's body frame.
//! (The estimator's accuracy is tested on synthetic rotation pairs in its own module.)

mod drive;
mod scratch;

use drive::{max_gap_m, positions_with_gyro_turned as run};
use nalgebra::{Rotation3, Vector3};
use vidslam::runtime::odometry::OdometryConfig;

/// The gyro's axes turned from the body by `log(R) = (0.1°, −0.2°, 0.5°)` (`ω_gyro = Rᵀ ω_body`).
fn turned() -> Rotation3<f64> {
    Rotation3::new(Vector3::new(0.1f64, -0.2, 0.5).map(f64::to_radians))
}

/// The defaults without the keyframe window's own estimate of the gyro's turn (`[window]
/// gyro_misalignment`, tested in `tests/gyro_misalignment.rs`), which would take up most of the
/// turn this test gives the gyro (13 cm → 1.8 cm) and hide what `initial_rotation_deg` does.
fn base() -> OdometryConfig {
    let mut c = OdometryConfig::default();
    c.window.gyro_misalignment = false;
    c
}

#[test]
fn estimating_leaves_the_odometry_alone_and_a_known_rotation_undoes_a_turned_gyro() {
    let dir = drive::render_builtin(scratch::dir("gyro-alignment"), 12.0, 3);
    let mut off = base();
    off.gyro_alignment.enabled = false;
    let (p_off, _) = run(&dir, off, None);
    // On by default, estimating and reporting only: the same poses to the bit.
    let (p_on, s_on) = run(&dir, base(), None);
    assert_eq!(p_on, p_off);
    assert!(s_on.gyro_alignment.pairs > 0, "no rotation pair was formed");
    assert_eq!(s_on.gyro_alignment.applied_rad, [0.0; 3]);

    // The gyro turned by 0.5°: the poses move off the recorded gyro's.
    let (p_turned, _) = run(&dir, base(), Some(turned()));
    let moved_m = max_gap_m(&p_turned, &p_on);
    // Told the rotation: turned back on every sample, the poses are the recorded gyro's up to
    // the rounding of turning each sample there and back (1e-16 rad/s, which the closed loop of
    // keyframes and maps grows to ~1 mm over 12 s).
    let mut told = base();
    let log = turned().scaled_axis().map(f64::to_degrees);
    told.gyro_alignment.initial_rotation_deg = [log.x, log.y, log.z];
    let (p_told, s_told) = run(&dir, told, Some(turned()));
    let undone_m = max_gap_m(&p_told, &p_on);
    println!(
        "gyro turned 0.55°: poses up to {:.1} mm off; told the rotation: {:.3} mm",
        moved_m * 1e3,
        undone_m * 1e3
    );
    assert!(
        moved_m > 5e-3,
        "turning the gyro moved nothing ({moved_m} m)"
    );
    assert!(
        undone_m < 0.03 * moved_m,
        "the known rotation left {undone_m} m of {moved_m} m"
    );
    let applied = Vector3::from(s_told.gyro_alignment.applied_rad).map(f64::to_degrees);
    assert!((applied - log).norm() < 1e-12, "{applied} vs {log}");
}
