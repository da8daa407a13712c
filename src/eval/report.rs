//! The evaluation figures: a flat, stably-keyed serde struct and a readable table.
//!
//! JSON keys are part of the interface (scripts and CI compare them): rename none. Figures that
//! cannot be computed (e.g. RPE over 10 m on a 5 m trajectory) are `null`, never NaN.

use super::Alignment;
use super::ate::AbsoluteErrors;
use super::body_offset::BodyOffset;
use super::rpe::RelativeErrors;
use super::stats::ErrorStats;
use crate::time::TimeNs;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::Path;

/// The figures of one evaluation (see [`super::evaluate`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Alignment applied before the ATE and RPE.
    pub align: Alignment,
    /// Largest ground-truth gap interpolated across, ms.
    pub max_dt_ms: f64,
    /// Poses in the ground-truth and estimate files.
    pub gt_poses: usize,
    pub est_poses: usize,
    /// Estimate poses matched to (interpolated) ground truth.
    pub matched_poses: usize,
    /// Time from the first to the last matched pose, s.
    pub duration_s: f64,
    /// Path length travelled by the ground truth over the matched poses, m. Below a metre or so,
    /// the alignment (and thus the scale) is poorly conditioned.
    pub gt_path_m: f64,
    /// Absolute translation error after alignment, m.
    pub ate_rmse_m: f64,
    pub ate_mean_m: f64,
    pub ate_median_m: f64,
    pub ate_max_m: f64,
    /// Absolute rotation error after alignment (angle of `R_gtᵀ R_est`), degrees.
    pub rot_rmse_deg: f64,
    pub rot_mean_deg: f64,
    pub rot_max_deg: f64,
    /// Constant rotation between the estimate's body frame and the ground truth's: the rotation
    /// vector of `R_b` in `R_est ≈ R_w R_gt R_b` (world rotation `R_w` fitted with it,
    /// [`super::body_offset`]), body frame, degrees; its part about a body direction the flight
    /// barely turns the body away from (a drone's up axis, where it reads as heading) is held at
    /// zero. The signature of a camera–IMU misalignment or of an accelerometer bias held as a
    /// tilt; `null` if it could not be fitted (too few poses, a non-finite one) or the body never
    /// turned enough (a few degrees) for it to differ from a world rotation.
    #[serde(default)]
    pub rot_body_offset_deg: Option<[f64; 3]>,
    /// Rotation RMSE once that offset and the world rotation are removed, degrees: what of
    /// `rot_rmse_deg` is not a fixed offset of the body.
    #[serde(default)]
    pub rot_rmse_without_body_offset_deg: Option<f64>,
    /// RPE over 1 m of travelled ground truth (segments start at every pose); `None` (null) when
    /// the matched ground truth is shorter.
    pub rpe_1m_trans_rmse_m: Option<f64>,
    pub rpe_1m_rot_rmse_deg: Option<f64>,
    pub rpe_1m_segments: usize,
    /// RPE over 10 m of travelled ground truth.
    pub rpe_10m_trans_rmse_m: Option<f64>,
    pub rpe_10m_rot_rmse_deg: Option<f64>,
    pub rpe_10m_segments: usize,
    /// Scale `s` of the Sim3 (Umeyama) alignment mapping the estimate onto the ground truth,
    /// whatever `align` is: `s > 1` means the estimate is too small.
    pub scale: f64,
    /// `100 · |s − 1|`, %.
    pub scale_error_pct: f64,
    /// Per-pose errors for plots; not part of the JSON.
    #[serde(skip)]
    pub per_pose: Vec<PoseError>,
}

/// The error at one matched pose, after alignment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseError {
    pub t: TimeNs,
    /// Seconds since the first matched pose.
    pub time_s: f64,
    pub p_world_gt_m: Vector3<f64>,
    /// Aligned estimate position in the ground-truth world.
    pub p_world_est_m: Vector3<f64>,
    pub ate_m: f64,
    pub rot_err_deg: f64,
    /// The rotation error left after the world rotation and the body offset
    /// ([`super::body_offset::attitude_errors`]): about the world's z axis (signed) and about
    /// horizontal axes, degrees; `None` when no body offset could be fitted.
    pub heading_err_deg: Option<f64>,
    pub tilt_err_deg: Option<f64>,
}

/// The errors over one time segment of a run ([`EvalReport::segment_errors`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SegmentError {
    /// Start and end of the segment, s since the first matched pose.
    pub from_s: f64,
    pub to_s: f64,
    /// Matched poses in it.
    pub poses: usize,
    /// ATE RMSE of those poses, m (`None` without any).
    pub ate_rmse_m: Option<f64>,
    /// Mean of their signed heading errors and RMS of their tilt errors ([`PoseError`]),
    /// degrees (`None` without poses or without a body-offset fit).
    pub heading_mean_deg: Option<f64>,
    pub tilt_rms_deg: Option<f64>,
}

impl SegmentError {
    /// One table row: `ATE 5.0–33.0 s [m]   0.012345 (560 poses)`, then the heading and tilt
    /// when known: `  heading -0.52° tilt 0.31°`.
    pub fn to_row(&self) -> String {
        let label = format!("ATE {:.1}-{:.1} s [m]", self.from_s, self.to_s);
        let attitude = match (self.heading_mean_deg, self.tilt_rms_deg) {
            (Some(h), Some(t)) => format!("  heading {h:+.2}° tilt {t:.2}°"),
            _ => String::new(),
        };
        match self.ate_rmse_m {
            Some(e) => format!("{label:<24} {e:.6} ({} poses){attitude}\n", self.poses),
            None => format!("{label:<24} n/a (no poses)\n"),
        }
    }
}

/// What [`EvalReport::new`] summarises.
pub(super) struct ReportInputs<'a> {
    pub align: Alignment,
    pub max_dt_ms: f64,
    pub gt_poses: usize,
    pub est_poses: usize,
    pub sim3_scale: f64,
    pub absolute: &'a AbsoluteErrors,
    pub rpe_1m: &'a RelativeErrors,
    pub rpe_10m: &'a RelativeErrors,
    pub body_offset: Option<BodyOffset>,
    pub per_pose: Vec<PoseError>,
}

impl EvalReport {
    pub(super) fn new(inp: ReportInputs<'_>) -> EvalReport {
        // Absolute errors of >= 3 finite poses always have statistics; the fallback only guards
        // against a caller passing none (then the figures read 0 with matched_poses 0).
        let zero = ErrorStats {
            rmse: 0.0,
            mean: 0.0,
            median: 0.0,
            max: 0.0,
            count: 0,
        };
        let ate = ErrorStats::of(&inp.absolute.trans_m).unwrap_or(zero);
        let rot = ErrorStats::of(&inp.absolute.rot_deg).unwrap_or(zero);
        let rmse = |e: &[f64]| ErrorStats::of(e).map(|s| s.rmse);
        let gt_path_m = inp
            .per_pose
            .windows(2)
            .map(|w| (w[1].p_world_gt_m - w[0].p_world_gt_m).norm())
            .sum();
        EvalReport {
            duration_s: inp.per_pose.last().map_or(0.0, |p| p.time_s),
            gt_path_m,
            align: inp.align,
            max_dt_ms: inp.max_dt_ms,
            gt_poses: inp.gt_poses,
            est_poses: inp.est_poses,
            matched_poses: inp.per_pose.len(),
            ate_rmse_m: ate.rmse,
            ate_mean_m: ate.mean,
            ate_median_m: ate.median,
            ate_max_m: ate.max,
            rot_rmse_deg: rot.rmse,
            rot_mean_deg: rot.mean,
            rot_max_deg: rot.max,
            rot_body_offset_deg: inp.body_offset.map(|b| {
                let d = b.body_rotation_rad.map(f64::to_degrees);
                [d.x, d.y, d.z]
            }),
            rot_rmse_without_body_offset_deg: inp
                .body_offset
                .map(|b| b.residual_rmse_rad.to_degrees()),
            rpe_1m_trans_rmse_m: rmse(&inp.rpe_1m.trans_m),
            rpe_1m_rot_rmse_deg: rmse(&inp.rpe_1m.rot_deg),
            rpe_1m_segments: inp.rpe_1m.trans_m.len(),
            rpe_10m_trans_rmse_m: rmse(&inp.rpe_10m.trans_m),
            rpe_10m_rot_rmse_deg: rmse(&inp.rpe_10m.rot_deg),
            rpe_10m_segments: inp.rpe_10m.trans_m.len(),
            scale: inp.sim3_scale,
            scale_error_pct: 100.0 * (inp.sim3_scale - 1.0).abs(),
            per_pose: inp.per_pose,
        }
    }

    /// The ATE RMSE of the matched poses in the time segments that `cuts_s` (s since the first
    /// matched pose, increasing) divide the run into: `[0, c₁)`, `[c₁, c₂)`, …, `[cₙ, end]` — the
    /// flight phases of one alignment (the whole run's), to see where the error is made.
    pub fn segment_errors(&self, cuts_s: &[f64]) -> Vec<SegmentError> {
        let mut bounds = vec![0.0];
        bounds.extend_from_slice(cuts_s);
        bounds.push(f64::INFINITY);
        bounds
            .windows(2)
            .map(|w| {
                let in_segment: Vec<&PoseError> = self
                    .per_pose
                    .iter()
                    .filter(|p| p.time_s >= w[0] && p.time_s < w[1])
                    .collect();
                let e: Vec<f64> = in_segment.iter().map(|p| p.ate_m).collect();
                let heading: Option<Vec<f64>> =
                    in_segment.iter().map(|p| p.heading_err_deg).collect();
                let tilt: Option<Vec<f64>> = in_segment.iter().map(|p| p.tilt_err_deg).collect();
                SegmentError {
                    from_s: w[0],
                    to_s: w[1].min(self.duration_s),
                    poses: e.len(),
                    ate_rmse_m: ErrorStats::of(&e).map(|s| s.rmse),
                    heading_mean_deg: heading.and_then(|h| ErrorStats::of(&h)).map(|s| s.mean),
                    tilt_rms_deg: tilt.and_then(|t| ErrorStats::of(&t)).map(|s| s.rmse),
                }
            })
            .collect()
    }

    /// Pretty-printed JSON of the figures (flat object, keys as the field names).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a struct of numbers and strings serialises")
    }

    /// Writes [`EvalReport::to_json`] to `path`.
    pub fn write_json(&self, path: &Path) -> std::io::Result<()> {
        let mut s = self.to_json();
        s.push('\n');
        std::fs::write(path, s)
            .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", path.display())))
    }

    /// A human-readable table of the figures, one per line, units in the first column.
    pub fn to_table(&self) -> String {
        let opt = |v: Option<f64>, prec: usize| match v {
            Some(x) => format!("{x:.prec$}"),
            None => "n/a".to_string(),
        };
        let rows: Vec<(String, String)> = vec![
            ("alignment".into(), self.align.to_string()),
            (
                "matched poses".into(),
                format!(
                    "{} of {} estimated ({} GT, max gap {} ms)",
                    self.matched_poses, self.est_poses, self.gt_poses, self.max_dt_ms
                ),
            ),
            (
                "matched span".into(),
                format!(
                    "{:.3} s, {:.3} m travelled (GT)",
                    self.duration_s, self.gt_path_m
                ),
            ),
            ("ATE RMSE [m]".into(), format!("{:.6}", self.ate_rmse_m)),
            ("ATE mean [m]".into(), format!("{:.6}", self.ate_mean_m)),
            ("ATE median [m]".into(), format!("{:.6}", self.ate_median_m)),
            ("ATE max [m]".into(), format!("{:.6}", self.ate_max_m)),
            (
                "rotation RMSE [deg]".into(),
                format!("{:.4}", self.rot_rmse_deg),
            ),
            (
                "rotation max [deg]".into(),
                format!("{:.4}", self.rot_max_deg),
            ),
            (
                "body rot offset [deg]".into(),
                match self.rot_body_offset_deg {
                    Some([x, y, z]) => format!(
                        "({x:+.3}, {y:+.3}, {z:+.3}), rotation RMSE without it {}",
                        opt(self.rot_rmse_without_body_offset_deg, 4)
                    ),
                    None => "n/a".to_string(),
                },
            ),
            (
                "RPE 1 m trans RMSE [m]".into(),
                format!(
                    "{} ({} segments)",
                    opt(self.rpe_1m_trans_rmse_m, 6),
                    self.rpe_1m_segments
                ),
            ),
            (
                "RPE 1 m rot RMSE [deg]".into(),
                opt(self.rpe_1m_rot_rmse_deg, 4),
            ),
            (
                "RPE 10 m trans RMSE [m]".into(),
                format!(
                    "{} ({} segments)",
                    opt(self.rpe_10m_trans_rmse_m, 6),
                    self.rpe_10m_segments
                ),
            ),
            (
                "RPE 10 m rot RMSE [deg]".into(),
                opt(self.rpe_10m_rot_rmse_deg, 4),
            ),
            (
                "Sim3 scale (est -> GT)".into(),
                format!("{:.6}", self.scale),
            ),
            (
                "scale error [%]".into(),
                format!("{:.4}", self.scale_error_pct),
            ),
        ];
        let width = rows.iter().map(|(k, _)| k.len()).max().unwrap_or(0);
        let mut out = String::new();
        for (k, v) in rows {
            writeln!(out, "{k:<width$}  {v}").expect("writing to a String cannot fail");
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> EvalReport {
        let abs = AbsoluteErrors {
            trans_m: vec![0.1, 0.2, 0.2],
            rot_deg: vec![1.0, 1.0, 1.0],
        };
        let rpe_1m = RelativeErrors {
            trans_m: vec![0.03, 0.04],
            rot_deg: vec![0.5, 0.5],
        };
        EvalReport::new(ReportInputs {
            align: Alignment::Sim3,
            max_dt_ms: 10.0,
            gt_poses: 100,
            est_poses: 4,
            sim3_scale: 0.98,
            absolute: &abs,
            rpe_1m: &rpe_1m,
            rpe_10m: &RelativeErrors::default(),
            body_offset: Some(BodyOffset {
                body_rotation_rad: Vector3::new(0.0, 0.0, 0.02f64.to_radians()),
                residual_rmse_rad: 0.5f64.to_radians(),
                world_rotation_rad: Vector3::zeros(),
            }),
            // Ground truth along x at 0, 1, 3 m, at 0, 1, 2 s: 3 m travelled in 2 s.
            per_pose: [0.0, 1.0, 3.0]
                .iter()
                .enumerate()
                .map(|(k, &x_m)| PoseError {
                    t: TimeNs(k as i64 * TimeNs::NS_PER_S),
                    time_s: k as f64,
                    p_world_gt_m: Vector3::new(x_m, 0.0, 0.0),
                    p_world_est_m: Vector3::zeros(),
                    ate_m: 0.0,
                    rot_err_deg: 0.0,
                    heading_err_deg: Some(0.0),
                    tilt_err_deg: Some(0.0),
                })
                .collect(),
        })
    }

    #[test]
    fn segment_errors_split_the_matched_poses_at_the_cut_times() {
        let mut r = sample();
        for (p, e) in r.per_pose.iter_mut().zip([0.3, 0.4, 0.1]) {
            p.ate_m = e;
        }
        for (p, (h, t)) in r
            .per_pose
            .iter_mut()
            .zip([(0.5, 0.2), (-1.5, 0.4), (2.0, 0.1)])
        {
            (p.heading_err_deg, p.tilt_err_deg) = (Some(h), Some(t));
        }
        let segs = r.segment_errors(&[1.5, 5.0]);
        assert_eq!(segs.len(), 3);
        assert_eq!((segs[0].from_s, segs[0].to_s, segs[0].poses), (0.0, 1.5, 2));
        assert!((segs[0].ate_rmse_m.unwrap() - 0.125f64.sqrt()).abs() < 1e-12);
        assert!((segs[0].heading_mean_deg.unwrap() + 0.5).abs() < 1e-12);
        assert!((segs[0].tilt_rms_deg.unwrap() - 0.1f64.sqrt()).abs() < 1e-12);
        assert!(
            segs[0].to_row().ends_with("heading -0.50° tilt 0.32°\n"),
            "{}",
            segs[0].to_row()
        );
        assert_eq!((segs[1].from_s, segs[1].to_s, segs[1].poses), (1.5, 2.0, 1));
        assert!((segs[1].ate_rmse_m.unwrap() - 0.1).abs() < 1e-12);
        // Past the last pose: empty, ends at the run's end.
        assert_eq!((segs[2].from_s, segs[2].to_s, segs[2].poses), (5.0, 2.0, 0));
        assert_eq!(segs[2].ate_rmse_m, None);
        assert_eq!(
            (segs[2].heading_mean_deg, segs[2].tilt_rms_deg),
            (None, None)
        );
        assert!(
            segs[0].to_row().starts_with("ATE 0.0-1.5 s [m]"),
            "{}",
            segs[0].to_row()
        );
        assert!(segs[2].to_row().contains("n/a"));
        // No cuts: the whole run.
        let all = r.segment_errors(&[]);
        assert_eq!(all.len(), 1);
        assert_eq!(all[0].poses, 3);
    }

    #[test]
    fn json_keys_are_stable_and_flat_with_null_for_missing() {
        let r = sample();
        let v: serde_json::Value = serde_json::from_str(&r.to_json()).unwrap();
        let obj = v.as_object().unwrap();
        let mut keys: Vec<&str> = obj.keys().map(String::as_str).collect();
        keys.sort_unstable();
        assert_eq!(
            keys,
            vec![
                "align",
                "ate_max_m",
                "ate_mean_m",
                "ate_median_m",
                "ate_rmse_m",
                "duration_s",
                "est_poses",
                "gt_path_m",
                "gt_poses",
                "matched_poses",
                "max_dt_ms",
                "rot_body_offset_deg",
                "rot_max_deg",
                "rot_mean_deg",
                "rot_rmse_deg",
                "rot_rmse_without_body_offset_deg",
                "rpe_10m_rot_rmse_deg",
                "rpe_10m_segments",
                "rpe_10m_trans_rmse_m",
                "rpe_1m_rot_rmse_deg",
                "rpe_1m_segments",
                "rpe_1m_trans_rmse_m",
                "scale",
                "scale_error_pct",
            ]
        );
        assert_eq!(obj["align"], "sim3");
        assert_eq!(obj["matched_poses"], 3);
        assert_eq!(obj["gt_path_m"], 3.0);
        assert_eq!(obj["duration_s"], 2.0);
        assert!(obj["rpe_10m_trans_rmse_m"].is_null());
        assert!((obj["ate_rmse_m"].as_f64().unwrap() - 0.03f64.sqrt()).abs() < 1e-12);
        assert!((obj["scale_error_pct"].as_f64().unwrap() - 2.0).abs() < 1e-9);
        assert!((obj["rpe_1m_trans_rmse_m"].as_f64().unwrap() - 0.00125f64.sqrt()).abs() < 1e-12);
        // Round trip (per-pose data is not serialised).
        let back: EvalReport = serde_json::from_str(&r.to_json()).unwrap();
        assert_eq!(
            EvalReport {
                per_pose: vec![],
                ..r
            },
            back
        );
    }

    #[test]
    fn table_has_one_aligned_row_per_figure() {
        let t = sample().to_table();
        assert!(t.contains("ATE RMSE [m]") && t.contains("0.173205"), "{t}");
        assert!(
            t.contains("RPE 10 m trans RMSE [m]  n/a (0 segments)"),
            "{t}"
        );
        assert!(t.contains("scale error [%]") && t.contains("2.0000"), "{t}");
        assert!(
            t.contains("(+0.000, +0.000, +0.020), rotation RMSE without it 0.5000"),
            "{t}"
        );
        let value_cols: Vec<usize> = t
            .lines()
            .map(|l| {
                l.find("  ")
                    .map(|i| i + l[i..].len() - l[i..].trim_start().len())
                    .unwrap()
            })
            .collect();
        assert!(value_cols.windows(2).all(|w| w[0] == w[1]), "{t}");
    }
}
