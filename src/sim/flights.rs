//! Built-in flights: analytic, drone-like paths sampled at 200 Hz as `t_world_body` poses, then fit
//! with the same spline as a recorded ground truth.
//!
//! A multirotor's attitude follows its acceleration: the thrust axis (vehicle z) is aligned with
//! `a_world - g_world`, and the heading is free. The flights below give position and heading; roll
//! and pitch follow from that. The camera is mounted looking forward along the vehicle x axis and
//! [`CAMERA_PITCH_DOWN_RAD`] down; the body (IMU) frame is placed at the vehicle origin with the
//! orientation that makes `t_body_cam` (from the camera's `sensor.yaml`, EuRoC cam0 by default)
//! produce that mount.

use crate::dataset::{StampedPose, Trajectory};
use crate::geometry::GRAVITY_M_S2;
use crate::time::TimeNs;
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Names accepted by [`builtin_flight`].
pub const BUILTIN_FLIGHTS: &[&str] = &["demo"];

/// Camera tilt below the vehicle's forward axis.
pub const CAMERA_PITCH_DOWN_RAD: f64 = 15.0 * std::f64::consts::PI / 180.0;

/// First timestamp of built-in flights (a plausible Unix-epoch time, so consumers meet
/// EuRoC-sized absolute timestamps).
pub const BUILTIN_T0: TimeNs = TimeNs(1_700_000_000_000_000_000);

const SAMPLE_PERIOD_NS: i64 = 5_000_000;

#[derive(Debug, thiserror::Error, PartialEq)]
#[error("unknown built-in flight '{0}' (available: {list})", list = BUILTIN_FLIGHTS.join(", "))]
pub struct UnknownFlight(pub String);

/// Vehicle position (m, world) and heading (unit horizontal vector) at time `t_s` after start.
type PathFn = fn(f64) -> (Vector3<f64>, Vector3<f64>);

/// Samples the built-in flight `name` at 200 Hz as body poses, for a camera mounted with
/// `t_body_cam`. The returned poses start at [`BUILTIN_T0`].
pub fn builtin_flight(
    name: &str,
    t_body_cam: &Isometry3<f64>,
) -> Result<Trajectory, UnknownFlight> {
    let (path, duration_s): (PathFn, f64) = match name {
        "demo" => (demo_path, DEMO_DURATION_S),
        _ => return Err(UnknownFlight(name.to_string())),
    };
    let r_vehicle_body = vehicle_body_mount(t_body_cam);
    let n = (duration_s * 1e9 / SAMPLE_PERIOD_NS as f64).round() as i64;
    let poses = (0..=n)
        .map(|k| {
            let t_s = k as f64 * SAMPLE_PERIOD_NS as f64 * 1e-9;
            let r_wv = vehicle_attitude(path, t_s);
            let (p, _) = path(t_s);
            StampedPose {
                t: BUILTIN_T0.add_ns(k * SAMPLE_PERIOD_NS),
                t_world_body: Isometry3::from_parts(
                    Translation3::from(p),
                    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
                        r_wv * r_vehicle_body,
                    )),
                ),
            }
        })
        .collect();
    Ok(Trajectory::new(poses))
}

/// `r_vehicle_body` such that the camera looks along vehicle x, tilted down, image x to the right.
pub fn vehicle_body_mount(t_body_cam: &Isometry3<f64>) -> Matrix3<f64> {
    let (c, s) = (CAMERA_PITCH_DOWN_RAD.cos(), CAMERA_PITCH_DOWN_RAD.sin());
    let z_cam = Vector3::new(c, 0.0, -s);
    let x_cam = Vector3::new(0.0, -1.0, 0.0);
    let y_cam = z_cam.cross(&x_cam);
    let r_vehicle_cam = Matrix3::from_columns(&[x_cam, y_cam, z_cam]);
    r_vehicle_cam
        * t_body_cam
            .rotation
            .to_rotation_matrix()
            .matrix()
            .transpose()
}

/// Attitude of a multirotor following `path`: thrust along `a - g`, heading from the path.
fn vehicle_attitude(path: PathFn, t_s: f64) -> Matrix3<f64> {
    const H: f64 = 1e-3;
    let (p0, heading) = path(t_s);
    let (pm, _) = path(t_s - H);
    let (pp, _) = path(t_s + H);
    let a = (pp - 2.0 * p0 + pm) / (H * H);
    let z = (a + Vector3::new(0.0, 0.0, GRAVITY_M_S2)).normalize();
    let y = z.cross(&heading).normalize();
    let x = y.cross(&z);
    Matrix3::from_columns(&[x, y, z])
}

/// Septic smoothstep (zero velocity, acceleration and jerk at both ends), clamped.
fn smootherstep(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x.powi(4) * (35.0 - 84.0 * x + 70.0 * x * x - 20.0 * x.powi(3))
}

/// Duration of `builtin:demo`, s.
pub const DEMO_DURATION_S: f64 = 41.0;

// Demo flight timeline (s): idle on the ground with motors running, take-off, three laps of a
// figure eight with climbs and descents, a 180° turn in hover, landing, idle.
const IDLE_END: f64 = 2.0;
const TAKEOFF_END: f64 = 5.0;
const LAPS_END: f64 = 33.0;
const TURN_END: f64 = 36.0;
const LAND_END: f64 = 39.0;
const GROUND_Z_M: f64 = 0.12;
const HOVER_Z_M: f64 = 1.3;
const EIGHT_X_M: f64 = 1.8;
const EIGHT_Y_M: f64 = 1.2;
const EIGHT_CLIMB_M: f64 = 0.35;
const LAPS: f64 = 3.0;
const RAMP_S: f64 = 3.0;

/// Lap angle of the figure eight, `τ` s after it starts: angular speed ramps up with a smoothstep
/// (`3x² - 2x³`, integrated in closed form) over [`RAMP_S`], cruises, and ramps down, ending exactly after [`LAPS`] laps.
fn eight_angle(tau: f64) -> f64 {
    let dur = LAPS_END - TAKEOFF_END;
    let w_max = LAPS * std::f64::consts::TAU / (dur - RAMP_S);
    // ∫₀ˣ smoothstep = x³ - x⁴/2
    let ramp_int = |x: f64| x.powi(3) - 0.5 * x.powi(4);
    if tau <= 0.0 {
        0.0
    } else if tau < RAMP_S {
        w_max * RAMP_S * ramp_int(tau / RAMP_S)
    } else if tau <= dur - RAMP_S {
        w_max * (0.5 * RAMP_S + tau - RAMP_S)
    } else if tau < dur {
        w_max * (dur - RAMP_S) - w_max * RAMP_S * ramp_int((dur - tau) / RAMP_S)
    } else {
        w_max * (dur - RAMP_S)
    }
}

fn eight(theta: f64) -> (Vector3<f64>, Vector3<f64>) {
    let p = Vector3::new(
        EIGHT_X_M * theta.sin(),
        EIGHT_Y_M * theta.sin() * theta.cos(),
        HOVER_Z_M + EIGHT_CLIMB_M * theta.sin() * (0.5 * theta).cos(),
    );
    let tangent = Vector3::new(
        EIGHT_X_M * theta.cos(),
        EIGHT_Y_M * (2.0 * theta).cos(),
        0.0,
    );
    (p, tangent.normalize())
}

fn demo_path(t: f64) -> (Vector3<f64>, Vector3<f64>) {
    let (_, heading0) = eight(0.0);
    let rot_z = |h: &Vector3<f64>, a: f64| {
        Vector3::new(
            h.x * a.cos() - h.y * a.sin(),
            h.x * a.sin() + h.y * a.cos(),
            0.0,
        )
    };
    let at = |z: f64| Vector3::new(0.0, 0.0, z);
    if t < IDLE_END {
        (at(GROUND_Z_M), heading0)
    } else if t < TAKEOFF_END {
        let s = smootherstep((t - IDLE_END) / (TAKEOFF_END - IDLE_END));
        (at(GROUND_Z_M + s * (HOVER_Z_M - GROUND_Z_M)), heading0)
    } else if t < LAPS_END {
        eight(eight_angle(t - TAKEOFF_END))
    } else if t < TURN_END {
        let a = std::f64::consts::PI * smootherstep((t - LAPS_END) / (TURN_END - LAPS_END));
        (at(HOVER_Z_M), rot_z(&heading0, a))
    } else {
        let s = smootherstep((t - TURN_END) / (LAND_END - TURN_END));
        (
            at(HOVER_Z_M + s * (GROUND_Z_M - HOVER_Z_M)),
            rot_z(&heading0, std::f64::consts::PI),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::CameraModel;

    fn euroc_t_body_cam() -> Isometry3<f64> {
        let m = nalgebra::Matrix4::from_row_slice(&[
            0.0148655429818,
            -0.999880929698,
            0.00414029679422,
            -0.0216401454975,
            0.999557249008,
            0.0149672133247,
            0.025715529948,
            -0.064676986768,
            -0.0257744366974,
            0.00375618835797,
            0.999660727178,
            0.00981073058949,
            0.0,
            0.0,
            0.0,
            1.0,
        ]);
        crate::dataset::isometry_from_matrix(&m).unwrap()
    }

    #[test]
    fn demo_is_continuous_starts_and_ends_still_on_the_ground() {
        let _ = CameraModel::euroc_cam0();
        let tb = euroc_t_body_cam();
        let tr = builtin_flight("demo", &tb).unwrap();
        let (t0, t1) = tr.span().unwrap();
        assert_eq!(t1.ns_since(t0), 41_000_000_000);
        let first = tr.poses[0].t_world_body;
        assert!((first.translation.vector.z - GROUND_Z_M).abs() < 1e-12);
        // Camera looks forward (horizontal heading) and 15° down at rest.
        let r_wc = (first * tb).rotation;
        let z_cam_world = r_wc * Vector3::z();
        assert!((z_cam_world.z + CAMERA_PITCH_DOWN_RAD.sin()).abs() < 1e-9);
        let mut max_step_m: f64 = 0.0;
        let mut max_speed: f64 = 0.0;
        for w in tr.poses.windows(2) {
            let d = (w[1].t_world_body.translation.vector - w[0].t_world_body.translation.vector)
                .norm();
            max_step_m = max_step_m.max(d);
            max_speed = max_speed.max(d / 0.005);
            assert!(
                w[0].t_world_body
                    .rotation
                    .angle_to(&w[1].t_world_body.rotation)
                    < 0.05
            );
        }
        assert!(max_speed > 1.0 && max_speed < 4.0, "{max_speed}");
        assert!(builtin_flight("nope", &tb).is_err());
    }
}
