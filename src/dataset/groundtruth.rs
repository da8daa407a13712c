//! EuRoC `state_groundtruth_estimate0/data.csv`: timestamp, position, quaternion (w first) and —
//! when present (17 columns) — velocity, gyro bias and accel bias. 8-column files (pose only, as
//! shared V1_01) are accepted; the extra fields are then `None`.

use super::DatasetError;
use super::csv_lines::CsvRows;
use super::trajectory::{StampedPose, Trajectory};
use crate::time::TimeNs;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use std::fmt::Write as _;
use std::path::Path;

/// Full ground-truth state of the body (IMU) frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroundTruthState {
    pub t: TimeNs,
    pub t_world_body: Isometry3<f64>,
    /// Body velocity in the world frame, m/s.
    pub v_world_m_s: Option<Vector3<f64>>,
    /// Gyro bias, rad/s.
    pub gyro_bias_rad_s: Option<Vector3<f64>>,
    /// Accelerometer bias, m/s^2.
    pub accel_bias_m_s2: Option<Vector3<f64>>,
}

/// All ground-truth rows of a sequence, time ordered.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GroundTruth {
    pub states: Vec<GroundTruthState>,
}

impl GroundTruth {
    /// The pose part, for evaluation.
    pub fn trajectory(&self) -> Trajectory {
        Trajectory::new(
            self.states
                .iter()
                .map(|s| StampedPose {
                    t: s.t,
                    t_world_body: s.t_world_body,
                })
                .collect(),
        )
    }

    /// The row nearest to `t` within `max_dt_ns`.
    pub fn nearest(&self, t: TimeNs, max_dt_ns: i64) -> Option<&GroundTruthState> {
        let i = self.states.partition_point(|s| s.t < t);
        let cands = [i.checked_sub(1), Some(i)];
        cands
            .into_iter()
            .flatten()
            .filter_map(|k| self.states.get(k))
            .min_by_key(|s| (s.t.0 - t.0).abs())
            .filter(|s| (s.t.0 - t.0).abs() <= max_dt_ns)
    }

    /// Writes the EuRoC CSV: 17 columns if every state has velocity and biases, else 8.
    pub fn write(&self, path: &Path) -> Result<(), DatasetError> {
        let full = self.states.iter().all(|s| {
            s.v_world_m_s.is_some() && s.gyro_bias_rad_s.is_some() && s.accel_bias_m_s2.is_some()
        });
        let mut out = String::from(
            "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []",
        );
        if full {
            out.push_str(
                ", v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], \
                 b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], \
                 b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]",
            );
        }
        out.push('\n');
        for s in &self.states {
            let p = s.t_world_body.translation.vector;
            let q = s.t_world_body.rotation.quaternion();
            write!(
                out,
                "{},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}",
                s.t.0, p.x, p.y, p.z, q.w, q.i, q.j, q.k
            )
            .unwrap();
            if full {
                for v in [s.v_world_m_s, s.gyro_bias_rad_s, s.accel_bias_m_s2] {
                    let v = v.expect("checked above");
                    write!(out, ",{:.9},{:.9},{:.9}", v.x, v.y, v.z).unwrap();
                }
            }
            out.push('\n');
        }
        std::fs::write(path, out).map_err(|source| DatasetError::Io {
            path: path.into(),
            source,
        })
    }
}

/// Reads the ground-truth CSV.
pub fn read_groundtruth(path: &Path) -> Result<GroundTruth, DatasetError> {
    let mut rows = CsvRows::open(path)?;
    let mut states = Vec::new();
    while let Some(row) = rows.next_row() {
        let (t, f) = row?;
        if f.len() < 7 {
            return Err(rows.error(format!(
                "expected at least 8 columns, found {}",
                f.len() + 1
            )));
        }
        let n = |i| rows.number(&f, i);
        let q = Quaternion::new(n(3)?, n(4)?, n(5)?, n(6)?);
        let norm = q.norm();
        if !(0.9..=1.1).contains(&norm) {
            return Err(rows.error(format!("quaternion norm {norm:.4} is far from 1")));
        }
        let v3 = |i: usize| -> Result<Option<Vector3<f64>>, DatasetError> {
            if f.len() >= i + 3 {
                Ok(Some(Vector3::new(n(i)?, n(i + 1)?, n(i + 2)?)))
            } else {
                Ok(None)
            }
        };
        states.push(GroundTruthState {
            t,
            t_world_body: Isometry3::from_parts(
                Translation3::new(n(0)?, n(1)?, n(2)?),
                UnitQuaternion::from_quaternion(q),
            ),
            v_world_m_s: v3(7)?,
            gyro_bias_rad_s: v3(10)?,
            accel_bias_m_s2: v3(13)?,
        });
    }
    if states.is_empty() {
        return Err(DatasetError::Layout {
            path: path.into(),
            msg: "no ground-truth rows".into(),
        });
    }
    Ok(GroundTruth { states })
}
