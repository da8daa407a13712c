//! Trajectory files: TUM (`t tx ty tz qx qy qz qw`, seconds, space separated) and the EuRoC
//! ground-truth CSV (`t_ns, px, py, pz, qw, qx, qy, qz[, extra columns ignored]`), both ways.
//!
//! Poses are `t_world_body` (see [`crate::geometry`] for conventions). Reading detects the format
//! from the first data line (a comma means EuRoC CSV). Every parse error names the file and line.

use super::DatasetError;
use crate::time::TimeNs;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use std::fmt::Write as _;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;

/// One timed pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StampedPose {
    pub t: TimeNs,
    pub t_world_body: Isometry3<f64>,
}

/// File formats for trajectories.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrajectoryFormat {
    /// `timestamp_s tx ty tz qx qy qz qw`, space separated, `#` comments.
    Tum,
    /// EuRoC `state_groundtruth_estimate0/data.csv`: `timestamp_ns,px,py,pz,qw,qx,qy,qz,...`.
    EurocCsv,
}

/// A time-ordered sequence of poses.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trajectory {
    pub poses: Vec<StampedPose>,
}

impl Trajectory {
    pub fn new(poses: Vec<StampedPose>) -> Self {
        Trajectory { poses }
    }

    pub fn len(&self) -> usize {
        self.poses.len()
    }

    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Reads a TUM or EuRoC CSV file (detected), returning the format found too.
    /// Timestamps must be strictly increasing.
    pub fn read(path: &Path) -> Result<(Trajectory, TrajectoryFormat), DatasetError> {
        let io = |source| DatasetError::Io {
            path: path.to_path_buf(),
            source,
        };
        let file = std::fs::File::open(path).map_err(io)?;
        let mut format = None;
        let mut poses: Vec<StampedPose> = Vec::new();
        for (idx, line) in BufReader::new(file).lines().enumerate() {
            let line = line.map_err(io)?;
            let lineno = idx + 1;
            let s = line.trim();
            if s.is_empty() || s.starts_with('#') || s.starts_with('%') {
                continue;
            }
            let fmt = *format.get_or_insert(if s.contains(',') {
                TrajectoryFormat::EurocCsv
            } else {
                TrajectoryFormat::Tum
            });
            let err = |msg: String| DatasetError::Parse {
                path: path.to_path_buf(),
                line: lineno,
                msg,
            };
            let pose = parse_line(s, fmt).map_err(err)?;
            if let Some(prev) = poses.last()
                && pose.t <= prev.t
            {
                return Err(err(format!(
                    "timestamp {} is not after the previous one ({})",
                    pose.t.to_secs_string(),
                    prev.t.to_secs_string()
                )));
            }
            poses.push(pose);
        }
        match format {
            Some(f) if !poses.is_empty() => Ok((Trajectory { poses }, f)),
            _ => Err(DatasetError::Layout {
                path: path.to_path_buf(),
                msg: "no poses found".into(),
            }),
        }
    }

    /// Writes the trajectory in `format`.
    pub fn write(&self, path: &Path, format: TrajectoryFormat) -> Result<(), DatasetError> {
        let io = |source| DatasetError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut out = String::with_capacity(self.poses.len() * 96);
        match format {
            TrajectoryFormat::Tum => {
                out.push_str("# timestamp_s tx_m ty_m tz_m qx qy qz qw (t_world_body)\n");
            }
            TrajectoryFormat::EurocCsv => out.push_str(
                "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], \
                 q_RS_y [], q_RS_z []\n",
            ),
        }
        for p in &self.poses {
            let tr = p.t_world_body.translation.vector;
            let q = p.t_world_body.rotation.quaternion();
            match format {
                TrajectoryFormat::Tum => writeln!(
                    out,
                    "{} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}",
                    p.t.to_secs_string(),
                    tr.x,
                    tr.y,
                    tr.z,
                    q.i,
                    q.j,
                    q.k,
                    q.w
                ),
                TrajectoryFormat::EurocCsv => writeln!(
                    out,
                    "{},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}",
                    p.t.0, tr.x, tr.y, tr.z, q.w, q.i, q.j, q.k
                ),
            }
            .expect("writing to a String cannot fail");
        }
        let mut f = std::fs::File::create(path).map_err(io)?;
        f.write_all(out.as_bytes()).map_err(io)?;
        f.sync_all().map_err(io)
    }

    /// Pose at time `t`, interpolated (linear in translation, SLERP in rotation) between the two
    /// neighbouring samples, or `None` if `t` lies outside the trajectory or the neighbouring
    /// samples are more than `max_gap_ns` apart.
    pub fn interpolate(&self, t: TimeNs, max_gap_ns: i64) -> Option<Isometry3<f64>> {
        let idx = self.poses.partition_point(|p| p.t < t);
        if idx < self.poses.len() && self.poses[idx].t == t {
            return Some(self.poses[idx].t_world_body);
        }
        if idx == 0 || idx >= self.poses.len() {
            return None;
        }
        let (a, b) = (&self.poses[idx - 1], &self.poses[idx]);
        let gap_ns = b.t.ns_since(a.t);
        if gap_ns > max_gap_ns {
            return None;
        }
        let s = t.ns_since(a.t) as f64 / gap_ns as f64;
        Some(interpolate_pose(&a.t_world_body, &b.t_world_body, s))
    }

    /// Time span covered, if any.
    pub fn span(&self) -> Option<(TimeNs, TimeNs)> {
        Some((self.poses.first()?.t, self.poses.last()?.t))
    }
}

/// Interpolates `a` (s = 0) to `b` (s = 1): linear translation, SLERP rotation.
pub fn interpolate_pose(a: &Isometry3<f64>, b: &Isometry3<f64>, s: f64) -> Isometry3<f64> {
    let tr = a.translation.vector.lerp(&b.translation.vector, s);
    let rot = a.rotation.slerp(&b.rotation, s);
    Isometry3::from_parts(Translation3::from(tr), rot)
}

fn parse_line(s: &str, fmt: TrajectoryFormat) -> Result<StampedPose, String> {
    let fields: Vec<&str> = match fmt {
        TrajectoryFormat::EurocCsv => s.split(',').map(str::trim).collect(),
        TrajectoryFormat::Tum => s.split_whitespace().collect(),
    };
    if fields.len() < 8 {
        return Err(format!(
            "expected at least 8 columns, found {}",
            fields.len()
        ));
    }
    if fmt == TrajectoryFormat::Tum && fields.len() != 8 {
        return Err(format!("TUM lines have 8 columns, found {}", fields.len()));
    }
    let num = |i: usize| -> Result<f64, String> {
        let v: f64 = fields[i]
            .parse()
            .map_err(|_| format!("column {}: '{}' is not a number", i + 1, fields[i]))?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(format!("column {}: '{}' is not finite", i + 1, fields[i]))
        }
    };
    let t = match fmt {
        TrajectoryFormat::EurocCsv => TimeNs(
            fields[0]
                .parse()
                .map_err(|_| format!("column 1: '{}' is not integer nanoseconds", fields[0]))?,
        ),
        TrajectoryFormat::Tum => TimeNs::parse_secs(fields[0])
            .ok_or_else(|| format!("column 1: '{}' is not a time in seconds", fields[0]))?,
    };
    let p = Vector3::new(num(1)?, num(2)?, num(3)?);
    let (w, x, y, z) = match fmt {
        TrajectoryFormat::EurocCsv => (num(4)?, num(5)?, num(6)?, num(7)?),
        TrajectoryFormat::Tum => (num(7)?, num(4)?, num(5)?, num(6)?),
    };
    let q = Quaternion::new(w, x, y, z);
    let n = q.norm();
    if !(0.9..=1.1).contains(&n) {
        return Err(format!("quaternion norm {n:.4} is far from 1"));
    }
    Ok(StampedPose {
        t,
        t_world_body: Isometry3::from_parts(
            Translation3::from(p),
            UnitQuaternion::from_quaternion(q),
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Trajectory {
        let poses = (0..5)
            .map(|i| StampedPose {
                t: TimeNs(1_403_715_274_302_140_000 + i * 5_000_000),
                t_world_body: Isometry3::new(
                    Vector3::new(0.1 * i as f64, -0.2, 1.0 + 0.01 * i as f64),
                    Vector3::new(0.0, 0.1 * i as f64, 0.3),
                ),
            })
            .collect();
        Trajectory { poses }
    }

    fn assert_close(a: &Trajectory, b: &Trajectory) {
        assert_eq!(a.len(), b.len());
        for (p, q) in a.poses.iter().zip(&b.poses) {
            assert_eq!(p.t, q.t);
            let d = p.t_world_body.inverse() * q.t_world_body;
            assert!(d.translation.vector.norm() < 1e-8 && d.rotation.angle() < 1e-8);
        }
    }

    #[test]
    fn tum_and_euroc_round_trip() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let tr = sample();
        for (name, fmt) in [
            ("a.tum", TrajectoryFormat::Tum),
            ("b.csv", TrajectoryFormat::EurocCsv),
        ] {
            let path = dir.join(name);
            tr.write(&path, fmt).unwrap();
            let (back, found) = Trajectory::read(&path).unwrap();
            assert_eq!(found, fmt);
            assert_close(&tr, &back);
        }
    }

    #[test]
    fn parse_errors_name_file_and_line() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let path = dir.join("bad.tum");
        std::fs::write(&path, "# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 x 0 0 0 1\n").unwrap();
        let msg = Trajectory::read(&path).unwrap_err().to_string();
        assert!(
            msg.contains("bad.tum:3") && msg.contains("column 4"),
            "{msg}"
        );
        std::fs::write(&path, "1.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n").unwrap();
        let msg = Trajectory::read(&path).unwrap_err().to_string();
        assert!(
            msg.contains("bad.tum:2") && msg.contains("not after"),
            "{msg}"
        );
        std::fs::write(&path, "1,0,0,0,0.2,0,0,0\n").unwrap();
        let msg = Trajectory::read(&path).unwrap_err().to_string();
        assert!(msg.contains("bad.tum:1") && msg.contains("norm"), "{msg}");
    }

    #[test]
    fn interpolation_hits_samples_and_midpoints() {
        let tr = sample();
        let p0 = tr.poses[1];
        assert_eq!(tr.interpolate(p0.t, 10_000_000), Some(p0.t_world_body));
        let mid = tr.interpolate(p0.t.add_ns(2_500_000), 10_000_000).unwrap();
        let expect = interpolate_pose(&tr.poses[1].t_world_body, &tr.poses[2].t_world_body, 0.5);
        assert!((mid.translation.vector - expect.translation.vector).norm() < 1e-12);
        assert!(tr.interpolate(TimeNs(0), 10_000_000).is_none());
        assert!(tr.interpolate(p0.t.add_ns(2_500_000), 1_000_000).is_none());
    }
}
