//! The record of every loop the loop closer closed, or held and dropped (`OUT/loops.csv`): which keyframes, how well
//! PnP explained the matches, the drift it corrected, and — with ground truth — how far the
//! measured loop edge and the graph's prediction before it were from the true relative pose: the
//! figures that tell a wrong loop from a drifted odometry.

use crate::loop_closure::closer::LoopClosure;
use crate::runtime::map_depth::median;
use crate::runtime::true_view_poses::TrueCameraPoses;
use crate::time::TimeNs;
use nalgebra::Isometry3;
use serde::Serialize;

/// One loop closed, with its keyframes' times.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopRecord {
    /// The new keyframe's time and the stored one's it was closed to.
    pub new_t: TimeNs,
    pub old_t: TimeNs,
    pub closure: LoopClosure,
}

/// Size of a relative pose: translation m, rotation rad.
fn size(t: &Isometry3<f64>) -> (f64, f64) {
    (t.translation.vector.norm(), t.rotation.angle())
}

impl LoopRecord {
    /// The drift the loop corrected: the measured relative pose against the graph's prediction,
    /// (m, rad).
    pub fn correction(&self) -> (f64, f64) {
        let c = &self.closure;
        size(&(c.prior_t_old_new.inverse() * c.t_old_new))
    }

    /// The new camera's true pose in the old camera's frame (`None` outside the ground truth).
    fn true_t_old_new(&self, truth: &TrueCameraPoses) -> Option<Isometry3<f64>> {
        Some(truth.camera_at(self.old_t)?.inverse() * truth.camera_at(self.new_t)?)
    }

    /// Errors against the ground truth, (m, rad): of the measured loop edge, and of the graph's
    /// prediction it replaced.
    pub fn errors(&self, truth: &TrueCameraPoses) -> Option<LoopEdgeErrors> {
        let t = self.true_t_old_new(truth)?;
        let c = &self.closure;
        let (edge_m, edge_rad) = size(&(t.inverse() * c.t_old_new));
        let (prior_m, prior_rad) = size(&(t.inverse() * c.prior_t_old_new));
        Some(LoopEdgeErrors {
            edge_m,
            edge_rad,
            prior_m,
            prior_rad,
        })
    }
}

/// A loop's errors against the ground truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopEdgeErrors {
    /// The measured loop edge's, m and rad.
    pub edge_m: f64,
    pub edge_rad: f64,
    /// The graph's prediction's (before the loop), m and rad.
    pub prior_m: f64,
    pub prior_rad: f64,
}

/// Each loop's errors against the ground truth (`None` without it, or outside it), computed once
/// for [`loops_csv`] and [`loop_edge_summary`].
pub fn loop_edge_errors(
    rows: &[LoopRecord],
    truth: Option<&TrueCameraPoses>,
) -> Vec<Option<LoopEdgeErrors>> {
    rows.iter()
        .map(|r| truth.and_then(|t| r.errors(t)))
        .collect()
}

/// `loops.csv`: one row per loop closed or dropped (`dropped` 1: held for another loop to agree
/// and never in the graph), with its errors ([`loop_edge_errors`], one per row); the error
/// columns NaN where there are none.
pub fn loops_csv(rows: &[LoopRecord], errors: &[Option<LoopEdgeErrors>]) -> String {
    let mut s = String::from(
        "new_t_ns,old_t_ns,inliers,inlier_ratio,inlier_rms_px,correction_m,correction_rad,\
         edge_error_m,edge_error_rad,prior_error_m,prior_error_rad,dropped\n",
    );
    for (r, e) in rows.iter().zip(errors) {
        let c = &r.closure;
        let (corr_m, corr_rad) = r.correction();
        let e = e.unwrap_or(LoopEdgeErrors {
            edge_m: f64::NAN,
            edge_rad: f64::NAN,
            prior_m: f64::NAN,
            prior_rad: f64::NAN,
        });
        s.push_str(&format!(
            "{},{},{},{:.3},{:.3},{:.4},{:.5},{:.4},{:.5},{:.4},{:.5},{}\n",
            r.new_t.0,
            r.old_t.0,
            c.inliers,
            c.inlier_ratio,
            c.inlier_rms_px,
            corr_m,
            corr_rad,
            e.edge_m,
            e.edge_rad,
            e.prior_m,
            e.prior_rad,
            u8::from(c.dropped)
        ));
    }
    s
}

/// The loop edges' errors against the ground truth over a run (the loops that went into the
/// graph), for the report.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LoopEdgeSummary {
    /// Loops with ground truth at both keyframes.
    pub evaluated: usize,
    /// Median and largest translation error of the measured edges, m; largest rotation, rad.
    pub edge_m_p50: f64,
    pub edge_m_max: f64,
    pub edge_rad_max: f64,
    /// Median translation error of the graph's predictions they replaced, m.
    pub prior_m_p50: f64,
}

/// Summary of the errors ([`loop_edge_errors`], one per row) of the loops in the graph (`None` if
/// none has any).
pub fn loop_edge_summary(
    rows: &[LoopRecord],
    errors: &[Option<LoopEdgeErrors>],
) -> Option<LoopEdgeSummary> {
    let errors: Vec<LoopEdgeErrors> = (rows.iter().zip(errors))
        .filter(|(r, _)| !r.closure.dropped)
        .filter_map(|(_, e)| *e)
        .collect();
    if errors.is_empty() {
        return None;
    }
    let mut edge_m: Vec<f64> = errors.iter().map(|e| e.edge_m).collect();
    let mut prior_m: Vec<f64> = errors.iter().map(|e| e.prior_m).collect();
    Some(LoopEdgeSummary {
        evaluated: errors.len(),
        edge_m_max: edge_m.iter().copied().fold(0.0, f64::max),
        edge_rad_max: errors.iter().map(|e| e.edge_rad).fold(0.0, f64::max),
        edge_m_p50: median(&mut edge_m),
        prior_m_p50: median(&mut prior_m),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::trajectory::{StampedPose, Trajectory};
    use nalgebra::Vector3;

    fn pose(x_m: f64, yaw_rad: f64) -> Isometry3<f64> {
        Isometry3::new(Vector3::new(x_m, 0.2, 1.0), Vector3::z() * yaw_rad)
    }

    /// A body flying along x and turning, the camera 10 cm ahead of it.
    fn truth() -> TrueCameraPoses {
        let poses = (0..=10)
            .map(|k| StampedPose {
                t: TimeNs(k * 10_000_000),
                t_world_body: pose(0.1 * k as f64, 0.05 * k as f64),
            })
            .collect();
        TrueCameraPoses::new(
            Trajectory::new(poses),
            Isometry3::translation(0.1, 0.0, 0.0),
        )
    }

    /// A loop measured exactly has no edge error; its prior's error is the drift it corrected;
    /// outside the ground truth there is no error and the CSV says NaN.
    #[test]
    fn errors_are_measured_against_the_true_relative_pose() {
        let truth = truth();
        let (old_t, new_t) = (TimeNs(20_000_000), TimeNs(90_000_000));
        let exact = truth.camera_at(old_t).unwrap().inverse() * truth.camera_at(new_t).unwrap();
        let drift = Isometry3::new(Vector3::new(0.03, -0.04, 0.0), Vector3::z() * 0.01);
        let record = |new_t| LoopRecord {
            new_t,
            old_t,
            closure: LoopClosure {
                new_id: 9,
                old_id: 2,
                inliers: 40,
                inlier_ratio: 0.8,
                inlier_rms_px: 0.6,
                t_old_new: exact,
                prior_t_old_new: exact * drift,
                dropped: false,
            },
        };
        let r = record(new_t);
        let e = r.errors(&truth).unwrap();
        assert!(e.edge_m < 1e-9 && e.edge_rad < 1e-9, "{e:?}");
        assert!((e.prior_m - 0.05).abs() < 1e-9 && (e.prior_rad - 0.01).abs() < 1e-9);
        let (corr_m, corr_rad) = r.correction();
        assert!((corr_m - 0.05).abs() < 1e-9 && (corr_rad - 0.01).abs() < 1e-9);
        let outside = record(TimeNs(500_000_000));
        assert_eq!(outside.errors(&truth), None);
        let errors = loop_edge_errors(&[r, outside], Some(&truth));
        assert_eq!(errors, vec![Some(e), None]);
        let csv = loops_csv(&[r, outside], &errors);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 3);
        assert!(lines[1].starts_with("90000000,20000000,40,0.800,0.600,0.0500,0.01000,0.0000,"));
        assert!(lines[1].ends_with(",0"), "{}", lines[1]);
        assert!(lines[2].ends_with("NaN,NaN,NaN,NaN,0"), "{}", lines[2]);
        let s = loop_edge_summary(&[r, outside], &errors).unwrap();
        assert_eq!(s.evaluated, 1);
        assert!(s.edge_m_max < 1e-9 && (s.prior_m_p50 - 0.05).abs() < 1e-9);
        assert_eq!(
            loop_edge_summary(&[outside], &loop_edge_errors(&[outside], Some(&truth))),
            None
        );
        // A dropped loop is written, with its errors, and left out of the summary.
        let mut dropped = r;
        dropped.closure.dropped = true;
        let errors = loop_edge_errors(&[dropped], Some(&truth));
        assert_eq!(errors, vec![Some(e)]);
        assert!(loops_csv(&[dropped], &errors).ends_with(",1\n"));
        assert_eq!(loop_edge_summary(&[dropped], &errors), None);
        assert_eq!(loop_edge_errors(&[r], None), vec![None]);
    }
}
