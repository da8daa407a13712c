//! Trajectory evaluation against ground truth: association, Umeyama alignment, ATE, RPE, scale.
//!
//! The pipeline behind `vidslam eval` (and the replay command's summary):
//!
//! 1. [`associate()`]: every estimated pose whose time lies inside the ground truth is paired with the
//!    ground truth interpolated at that time (linear translation, SLERP rotation), provided the two
//!    bracketing ground-truth samples are at most `max_dt_ns` apart.
//! 2. [`umeyama()`]: the similarity (`sim3`) or rigid (`se3`) transform that best maps the estimated
//!    positions onto the ground-truth positions in the least-squares sense (Umeyama 1991), the same
//!    alignment `evo_ape -a` / `-as` perform. The Sim3 scale is always computed and reported, even
//!    when another alignment is applied, as the scale error of a monocular(-inertial) estimate.
//! 3. [`ate`]: absolute translation error (m) and rotation error (deg) per pose after alignment;
//!    [`body_offset`]: the part of the rotation error that is a rotation fixed in the body frame.
//! 4. [`rpe`]: relative pose error over 1 m and 10 m of travelled ground-truth distance.
//! 5. [`velocity`]: the velocity's error, where the ground truth records one.
//! 6. [`report`]: the figures as a flat, stably-keyed JSON object and a readable table;
//!    [`plot`]: a PNG with the top view of both trajectories and the ATE over time.
//!
//! Poses are `t_world_body` (see [`crate::geometry`]); the "world" of the estimate is mapped into
//! the ground-truth world by the alignment.

pub mod associate;
pub mod ate;
pub mod body_offset;
pub mod imu_consistency;
pub mod plot;
pub mod report;
pub mod rpe;
pub mod stats;
pub mod umeyama;
pub mod velocity;

pub use associate::{PosePair, associate};
pub use plot::{PlotError, plot_report};
pub use report::{EvalReport, PoseError, SegmentError};
pub use umeyama::{Sim3, UmeyamaError, umeyama};

use crate::dataset::Trajectory;
use crate::time::TimeNs;
use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};
use std::fmt;

/// Which transform is estimated and applied to the estimate before computing errors.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Alignment {
    /// Rotation + translation (6 DoF), as `evo_ape -a`.
    #[default]
    Se3,
    /// Rotation + translation + scale (7 DoF), as `evo_ape -as`.
    Sim3,
    /// No alignment: the estimate is assumed to be in the ground-truth world already.
    None,
}

impl Alignment {
    /// The lowercase name used on the command line and in the JSON report.
    pub fn as_str(self) -> &'static str {
        match self {
            Alignment::Se3 => "se3",
            Alignment::Sim3 => "sim3",
            Alignment::None => "none",
        }
    }
}

impl fmt::Display for Alignment {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Options of [`evaluate`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EvalOptions {
    /// Alignment applied before the ATE and RPE are computed.
    pub align: Alignment,
    /// Largest gap between the two ground-truth samples bracketing an estimate time across which
    /// the ground truth is interpolated; estimate poses in longer gaps are not matched.
    pub max_dt_ns: i64,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            align: Alignment::Se3,
            max_dt_ns: 10_000_000,
        }
    }
}

/// Travelled ground-truth distances of the two RPE segment lengths in the report, m.
pub const RPE_SEGMENTS_M: [f64; 2] = [1.0, 10.0];

/// Minimum number of matched poses: Umeyama needs three non-collinear points for a unique rotation.
pub const MIN_MATCHED_POSES: usize = 3;

/// Why an evaluation could not produce figures.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(
        "no estimated pose could be matched to the ground truth: the estimate spans {est_span}, \
         the ground truth spans {gt_span} (is the estimate on the same clock?), and ground truth is \
         interpolated only across gaps of at most {max_dt_ms} ms"
    )]
    NoMatches {
        est_span: String,
        gt_span: String,
        max_dt_ms: f64,
    },
    #[error(
        "only {matched} estimated poses matched the ground truth; at least {needed} are needed"
    )]
    TooFewMatches { matched: usize, needed: usize },
    #[error("alignment failed: {0}")]
    Alignment(#[from] UmeyamaError),
}

/// The pairs of `est` and `gt` at the same times, the Sim3 alignment of the estimate's positions
/// onto the ground truth's, and the transform `opts.align` asks for (the one applied).
struct Aligned {
    pairs: Vec<PosePair>,
    sim3: Sim3,
    t_gtworld_estworld: Sim3,
}

fn align(gt: &Trajectory, est: &Trajectory, opts: &EvalOptions) -> Result<Aligned, EvalError> {
    let pairs = associate(gt, est, opts.max_dt_ns);
    if pairs.is_empty() {
        let span = |t: &Trajectory| match t.span() {
            Some((a, b)) => format!("{} .. {} s", a.to_secs_string(), b.to_secs_string()),
            None => "nothing".to_string(),
        };
        return Err(EvalError::NoMatches {
            est_span: span(est),
            gt_span: span(gt),
            max_dt_ms: opts.max_dt_ns as f64 * 1e-6,
        });
    }
    if pairs.len() < MIN_MATCHED_POSES {
        return Err(EvalError::TooFewMatches {
            matched: pairs.len(),
            needed: MIN_MATCHED_POSES,
        });
    }
    let p_gt: Vec<Vector3<f64>> = pairs
        .iter()
        .map(|p| p.t_world_body_gt.translation.vector)
        .collect();
    let p_est: Vec<Vector3<f64>> = pairs
        .iter()
        .map(|p| p.t_world_body_est.translation.vector)
        .collect();

    let sim3 = umeyama(&p_est, &p_gt, true)?;
    let t_gtworld_estworld = match opts.align {
        Alignment::Sim3 => sim3,
        Alignment::Se3 => umeyama(&p_est, &p_gt, false)?,
        Alignment::None => Sim3::identity(),
    };
    Ok(Aligned {
        pairs,
        sim3,
        t_gtworld_estworld,
    })
}

/// The transform from the estimate's world into the ground truth's that [`evaluate`] applies
/// with the same options (for figures it does not compute itself, such as
/// [`velocity::velocity_errors`]).
pub fn alignment(gt: &Trajectory, est: &Trajectory, opts: &EvalOptions) -> Result<Sim3, EvalError> {
    align(gt, est, opts).map(|a| a.t_gtworld_estworld)
}

/// Evaluates `est` against `gt`: associates, aligns as `opts.align` asks, and computes the ATE,
/// rotation error, RPE over [`RPE_SEGMENTS_M`] and the Sim3 scale. Both trajectories must be
/// time-ordered (as [`Trajectory::read`] guarantees).
pub fn evaluate(
    gt: &Trajectory,
    est: &Trajectory,
    opts: &EvalOptions,
) -> Result<EvalReport, EvalError> {
    let Aligned {
        pairs,
        sim3,
        t_gtworld_estworld,
    } = align(gt, est, opts)?;
    let gt_poses: Vec<Isometry3<f64>> = pairs.iter().map(|p| p.t_world_body_gt).collect();
    let est_aligned: Vec<Isometry3<f64>> = pairs
        .iter()
        .map(|p| t_gtworld_estworld.transform_pose(&p.t_world_body_est))
        .collect();

    let abs = ate::absolute_errors(&gt_poses, &est_aligned);
    let rpe: Vec<rpe::RelativeErrors> = RPE_SEGMENTS_M
        .iter()
        .map(|&len_m| {
            rpe::relative_errors(
                &gt_poses,
                &est_aligned,
                len_m,
                rpe::SegmentStarts::EveryPose,
            )
        })
        .collect();

    let t0: TimeNs = pairs[0].t;
    let offset = body_offset::body_offset(&gt_poses, &est_aligned);
    let attitude = offset.map(|o| body_offset::attitude_errors(&gt_poses, &est_aligned, &o));
    let per_pose = pairs
        .iter()
        .zip(&est_aligned)
        .zip(abs.trans_m.iter().zip(&abs.rot_deg))
        .enumerate()
        .map(|(i, ((p, e), (&trans_m, &rot_deg)))| {
            let att = attitude.as_ref().map(|a| a[i]);
            PoseError {
                t: p.t,
                time_s: p.t.secs_since(t0),
                p_world_gt_m: p.t_world_body_gt.translation.vector,
                p_world_est_m: e.translation.vector,
                ate_m: trans_m,
                rot_err_deg: rot_deg,
                heading_err_deg: att.map(|a| a.heading_rad.to_degrees()),
                tilt_err_deg: att.map(|a| a.tilt_rad.to_degrees()),
            }
        })
        .collect();

    Ok(EvalReport::new(report::ReportInputs {
        align: opts.align,
        max_dt_ms: opts.max_dt_ns as f64 * 1e-6,
        gt_poses: gt.len(),
        est_poses: est.len(),
        sim3_scale: sim3.scale,
        absolute: &abs,
        rpe_1m: &rpe[0],
        rpe_10m: &rpe[1],
        body_offset: offset,
        per_pose,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::StampedPose;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A 3D figure-of-eight, 20 s at 50 Hz, with varying yaw, pitch and roll.
    fn lissajous() -> Trajectory {
        let poses = (0..1000)
            .map(|i| {
                let s = i as f64 * 0.02;
                StampedPose {
                    t: TimeNs(1_000_000_000 + i * 20_000_000),
                    t_world_body: Isometry3::from_parts(
                        Translation3::new(
                            3.0 * (0.5 * s).sin(),
                            2.0 * (1.0 * s).sin(),
                            1.0 + 0.3 * (0.7 * s).cos(),
                        ),
                        UnitQuaternion::from_euler_angles(0.1 * s.sin(), 0.05 * s, 0.4 * s),
                    ),
                }
            })
            .collect();
        Trajectory::new(poses)
    }

    fn transformed(tr: &Trajectory, sim3: &Sim3) -> Trajectory {
        Trajectory::new(
            tr.poses
                .iter()
                .map(|p| StampedPose {
                    t: p.t,
                    t_world_body: sim3.transform_pose(&p.t_world_body),
                })
                .collect(),
        )
    }

    fn known_sim3(scale: f64) -> Sim3 {
        Sim3 {
            rotation: UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
            translation: Vector3::new(4.0, -1.0, 0.5),
            scale,
        }
    }

    #[test]
    fn sim3_alignment_removes_an_exact_similarity() {
        let gt = lissajous();
        let est = transformed(&gt, &known_sim3(0.5));
        let opts = EvalOptions {
            align: Alignment::Sim3,
            ..Default::default()
        };
        let r = evaluate(&gt, &est, &opts).unwrap();
        assert_eq!(r.matched_poses, 1000);
        assert!(r.ate_rmse_m < 1e-9 && r.ate_max_m < 1e-9, "{r:?}");
        assert!(r.rot_rmse_deg < 1e-6, "{r:?}");
        assert!((r.scale - 2.0).abs() < 1e-9, "scale {}", r.scale);
        assert!((r.scale_error_pct - 100.0).abs() < 1e-6);
        assert!(r.rpe_1m_trans_rmse_m.unwrap() < 1e-9);
        assert!(r.rpe_10m_trans_rmse_m.unwrap() < 1e-9);
    }

    #[test]
    fn se3_alignment_keeps_the_scale_error_and_still_reports_the_sim3_scale() {
        let gt = lissajous();
        let est = transformed(&gt, &known_sim3(0.5));
        let r = evaluate(&gt, &est, &EvalOptions::default()).unwrap();
        assert_eq!(r.align, Alignment::Se3);
        assert!((r.scale - 2.0).abs() < 1e-9, "scale {}", r.scale);
        // Positions shrunk by half cannot be matched rigidly: a large residual remains, but the
        // orientation, which a scale does not affect, is recovered exactly.
        assert!(r.ate_rmse_m > 0.5, "{r:?}");
        assert!(r.rot_rmse_deg < 1e-6, "{r:?}");
        // A 1 m GT segment is 0.5 m in the estimate: the RPE translation is about 0.5 m.
        let rpe1 = r.rpe_1m_trans_rmse_m.unwrap();
        assert!((rpe1 - 0.5).abs() < 0.05, "rpe 1 m {rpe1}");
    }

    #[test]
    fn no_alignment_sees_the_whole_offset() {
        let gt = lissajous();
        let offset = Sim3 {
            rotation: UnitQuaternion::identity(),
            translation: Vector3::new(0.0, 0.0, 2.0),
            scale: 1.0,
        };
        let est = transformed(&gt, &offset);
        let opts = EvalOptions {
            align: Alignment::None,
            ..Default::default()
        };
        let r = evaluate(&gt, &est, &opts).unwrap();
        assert!((r.ate_rmse_m - 2.0).abs() < 1e-9 && (r.ate_median_m - 2.0).abs() < 1e-9);
        assert!(r.rpe_1m_trans_rmse_m.unwrap() < 1e-9);
    }

    #[test]
    fn disjoint_clocks_give_a_clear_error() {
        let gt = lissajous();
        let mut est = lissajous();
        for p in &mut est.poses {
            p.t = p.t.add_ns(3_600 * TimeNs::NS_PER_S);
        }
        let msg = evaluate(&gt, &est, &EvalOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("same clock") && msg.contains("3601.000000000"),
            "{msg}"
        );
    }

    #[test]
    fn too_few_matches_is_an_error() {
        let gt = lissajous();
        let est = Trajectory::new(gt.poses[..2].to_vec());
        let err = evaluate(&gt, &est, &EvalOptions::default()).unwrap_err();
        assert!(
            matches!(
                err,
                EvalError::TooFewMatches {
                    matched: 2,
                    needed: 3
                }
            ),
            "{err}"
        );
    }
}
