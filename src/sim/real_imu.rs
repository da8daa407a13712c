//! A real EuRoC `imu0/data.csv` used as is: rows kept byte-for-byte for pass-through, parsed
//! samples for bias estimation.
//!
//! Bias ground truth: the real IMU is compared with the ideal IMU of the spline fitted to the
//! ground-truth path, `e_k = meas_k - ideal_k`, and the bias at sample k is the centred moving
//! average of `e` over [`BIAS_WINDOW_S`] (truncated at the ends). White noise and vibration
//! average out; what remains is the bias plus the slowly varying part of the spline's error (the
//! Vicon-to-gravity alignment, accelerations the 20 Hz-bandwidth spline cannot follow) — an
//! estimate, not a measurement: the real biases of the recording are unknown. The generator first
//! levels the world frame with [`estimate_gravity_tilt`], so that the tilt of the motion-capture
//! frame does not leak into the accelerometer bias.

use super::imu_synth::ideal_imu;
use super::spline::PoseSpline;
use crate::dataset::{DatasetError, read_imu_csv_with_lines};
use crate::imu::ImuSample;
use nalgebra::Vector3;
use std::path::{Path, PathBuf};

/// Window of the bias moving average, s.
pub const BIAS_WINDOW_S: f64 = 10.0;

#[derive(Debug, thiserror::Error)]
pub enum RealImuError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("{path}: no IMU rows")]
    Empty { path: PathBuf },
}

/// One data row: the parsed sample and the exact text of its line (without the newline).
#[derive(Clone, Debug, PartialEq)]
pub struct RawImuRow {
    pub sample: ImuSample,
    pub line: String,
}

/// Reads every data row of an EuRoC IMU CSV (`t_ns, gyro xyz rad/s, accel xyz m/s²`), keeping the
/// raw text. Comment (`#`) and blank lines are skipped; any malformed row or non-increasing
/// timestamp is an error naming the file and line.
pub fn read_real_imu(path: &Path) -> Result<Vec<RawImuRow>, RealImuError> {
    let rows: Vec<RawImuRow> = read_imu_csv_with_lines(path)?
        .into_iter()
        .map(|(sample, line)| RawImuRow { sample, line })
        .collect();
    if rows.is_empty() {
        return Err(RealImuError::Empty { path: path.into() });
    }
    Ok(rows)
}

/// Tilt `(θx, θy)` (rad, rotations about the world x and y axes) of gravity in the trajectory's
/// world frame: the true gravity is `exp([θx, θy, 0]^) · (0, 0, -g)`. Estimated by linear least
/// squares from `meas - ideal = b_a + R_world_bodyᵀ (g θy, -g θx, 0)` over all samples, with a
/// constant accelerometer bias `b_a`: the tilt rotates with the vehicle's heading, the bias does
/// not, so the two separate when the heading varies. `None` when they do not (condition > 1e4).
pub fn estimate_gravity_tilt(spline: &PoseSpline, samples: &[ImuSample]) -> Option<[f64; 2]> {
    use crate::geometry::GRAVITY_M_S2 as G;
    let mut h = nalgebra::SMatrix::<f64, 5, 5>::zeros();
    let mut r = nalgebra::SVector::<f64, 5>::zeros();
    for s in samples {
        let st = spline.state(s.t);
        let rt = st.t_world_body.rotation.inverse();
        let e = s.accel_m_s2 - ideal_imu(spline, s.t).accel_m_s2;
        let (u, w) = (
            rt * Vector3::new(0.0, -G, 0.0),
            rt * Vector3::new(G, 0.0, 0.0),
        );
        for row in 0..3 {
            let mut j = nalgebra::SVector::<f64, 5>::zeros();
            j[row] = 1.0;
            j[3] = u[row];
            j[4] = w[row];
            h += j * j.transpose();
            r += j * e[row];
        }
    }
    let eig = h.symmetric_eigen().eigenvalues;
    let (lo, hi) = (eig.min(), eig.max());
    if !(lo > 0.0 && hi / lo < 1e4) {
        return None;
    }
    let x = h.cholesky()?.solve(&r);
    Some([x[3], x[4]])
}

/// Bias estimates `(gyro rad/s, accel m/s²)` at every sample (see the module docs).
pub fn estimate_biases(
    spline: &PoseSpline,
    samples: &[ImuSample],
    window_s: f64,
) -> Vec<(Vector3<f64>, Vector3<f64>)> {
    let n = samples.len();
    // Prefix sums of the errors.
    let mut pg = vec![Vector3::zeros(); n + 1];
    let mut pa = vec![Vector3::zeros(); n + 1];
    for (k, s) in samples.iter().enumerate() {
        let ideal = ideal_imu(spline, s.t);
        pg[k + 1] = pg[k] + (s.gyro_rad_s - ideal.gyro_rad_s);
        pa[k + 1] = pa[k] + (s.accel_m_s2 - ideal.accel_m_s2);
    }
    let half_ns = (0.5 * window_s * 1e9) as i64;
    let (mut lo, mut hi) = (0usize, 0usize);
    samples
        .iter()
        .map(|s| {
            while samples[lo].t.ns_since(s.t) < -half_ns {
                lo += 1;
            }
            while hi < n && samples[hi].t.ns_since(s.t) <= half_ns {
                hi += 1;
            }
            let c = (hi - lo) as f64;
            ((pg[hi] - pg[lo]) / c, (pa[hi] - pa[lo]) / c)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::fit::fit_pose_spline;
    use crate::sim::flights::builtin_flight;
    use nalgebra::Isometry3;

    #[test]
    fn gravity_tilt_and_constant_bias_are_recovered_and_biases_follow() {
        let tr = builtin_flight("demo", &Isometry3::identity()).unwrap();
        let (sp, _) = fit_pose_spline(&tr.poses, 50_000_000).unwrap();
        let bias_a = Vector3::new(0.05, -0.3, 0.1);
        let bias_g = Vector3::new(0.01, 0.02, -0.03);
        let samples: Vec<ImuSample> = (0..8000)
            .map(|k| {
                let m = ideal_imu(&sp, sp.start().add_ns(k * 5_000_000));
                ImuSample {
                    t: m.t,
                    gyro_rad_s: m.gyro_rad_s + bias_g,
                    accel_m_s2: m.accel_m_s2 + bias_a,
                }
            })
            .collect();
        // The same motion seen in a frame tilted by (0.02, -0.01) rad about x and y.
        let (ax, ay) = (0.02, -0.01);
        let tilted = sp.left_transformed(&Isometry3::rotation(Vector3::new(ax, ay, 0.0)));
        let [tx, ty] = estimate_gravity_tilt(&tilted, &samples).unwrap();
        assert!(
            (tx - ax).abs() < 2e-4 && (ty - ay).abs() < 2e-4,
            "{tx} {ty}"
        );
        // In the untilted frame the moving averages give back the biases.
        let b = estimate_biases(&sp, &samples, BIAS_WINDOW_S);
        for (bg, ba) in [&b[0], &b[4000], &b[7999]] {
            assert!((bg - bias_g).norm() < 1e-9);
            assert!((ba - bias_a).norm() < 1e-9);
        }
    }

    #[test]
    fn keeps_raw_lines_and_names_bad_rows() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let p = dir.join("imu.csv");
        let text = "#timestamp [ns],w..\n10,0.1,0.2,0.3,9.8,0.0,-0.10000000000000001\r\n20,1e-3,0,0,9.81,0,0\n";
        std::fs::write(&p, text).unwrap();
        let rows = read_real_imu(&p).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(
            rows[0].line,
            "10,0.1,0.2,0.3,9.8,0.0,-0.10000000000000001\r"
        );
        assert_eq!(rows[1].sample.gyro_rad_s.x, 1e-3);
        std::fs::write(&p, "10,0,0,0,0,0,0\n20,0,0,x,0,0,0\n").unwrap();
        let e = read_real_imu(&p).unwrap_err().to_string();
        assert!(e.contains("imu.csv:2") && e.contains("column 4"), "{e}");
        std::fs::write(&p, "10,0,0,0,0,0,0\n10,0,0,0,0,0,0\n").unwrap();
        assert!(read_real_imu(&p).unwrap_err().to_string().contains(":2:"));
    }
}
