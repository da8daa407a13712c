//! Cross-check of `vidslam eval` against `evo` (evo_ape / evo_rpe, the field's reference tool) on
//! the same TUM files: ATE statistics (SE3 and Sim3 alignment), rotation error, and the RPE
//! building block, within 1e-4 m / 1e-4 deg. evo is installed by `.ci/run`
//! (`.ci/requirements.txt`); without it these tests FAIL rather than skip.

mod eval_common;
mod scratch;

use eval_common::{num, perturb, read_json, run_vidslam};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use scratch::dir as scratch_dir;
use std::collections::HashMap;
use std::ffi::OsStr;
use std::path::Path;
use std::process::Command;
use vidslam::dataset::{StampedPose, Trajectory, TrajectoryFormat};
use vidslam::eval::Sim3;
use vidslam::eval::rpe::{SegmentStarts, relative_errors};
use vidslam::eval::stats::ErrorStats;
use vidslam::time::TimeNs;

const TOL: f64 = 1e-4;

/// A smooth 3D flight, 40 s at 100 Hz on a EuRoC-like absolute clock, about 50 m long.
fn synthetic_gt() -> Trajectory {
    let t0 = TimeNs(1_403_715_274_302_140_000);
    let poses = (0..4000)
        .map(|i| {
            let s = i as f64 * 0.01;
            StampedPose {
                t: t0.add_ns(i * 10_000_000),
                t_world_body: Isometry3::from_parts(
                    Translation3::new(
                        4.0 * (0.25 * s).sin() + 0.3 * s.sin(),
                        3.0 * (0.5 * s).sin(),
                        1.2 + 0.5 * (0.3 * s).cos(),
                    ),
                    UnitQuaternion::from_euler_angles(
                        0.2 * (0.7 * s).sin(),
                        0.1 * s.cos(),
                        0.2 * s,
                    ),
                ),
            }
        })
        .collect();
    Trajectory::new(poses)
}

fn est_transform() -> Sim3 {
    Sim3 {
        rotation: UnitQuaternion::from_euler_angles(0.4, -0.3, 2.2),
        translation: Vector3::new(-7.0, 2.5, 0.8),
        scale: 0.7,
    }
}

/// Runs an evo command line and returns the statistics it prints (`rmse`, `mean`, ...).
fn evo(tool: &str, args: &[&OsStr]) -> HashMap<String, f64> {
    // evo creates ~/.evo on its first run and fails if another evo process created it in the
    // meantime (tests run in parallel on a fresh machine): let one run do that first.
    static FIRST_RUN: std::sync::Once = std::sync::Once::new();
    FIRST_RUN.call_once(|| {
        let _ = Command::new("evo_config").arg("show").output();
    });
    let out = Command::new(tool)
        .args(args)
        .arg("--no_warnings")
        .output()
        .unwrap_or_else(|e| {
            panic!(
                "{tool} could not be run ({e}): evo is a test peer of vidslam; install it with \
             `bash .ci/run` (pip: .ci/requirements.txt)"
            )
        });
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{tool} {args:?} failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stats: HashMap<String, f64> = stdout
        .lines()
        .filter_map(|l| {
            let mut it = l.split_whitespace();
            let (k, v) = (it.next()?, it.next()?);
            Some((k.to_string(), v.parse().ok()?))
        })
        .collect();
    assert!(
        stats.contains_key("rmse"),
        "no rmse in {tool} output:\n{stdout}"
    );
    stats
}

fn write_pair(
    dir: &Path,
    gt: &Trajectory,
    est: &Trajectory,
) -> (std::path::PathBuf, std::path::PathBuf) {
    let (gt_path, est_path) = (dir.join("gt.tum"), dir.join("est.tum"));
    gt.write(&gt_path, TrajectoryFormat::Tum).unwrap();
    est.write(&est_path, TrajectoryFormat::Tum).unwrap();
    (gt_path, est_path)
}

fn vidslam_eval(
    gt: &Path,
    est: &Path,
    align: &str,
    json: &Path,
) -> serde_json::Map<String, serde_json::Value> {
    run_vidslam(&[
        OsStr::new("eval"),
        OsStr::new("--gt"),
        gt.as_os_str(),
        OsStr::new("--est"),
        est.as_os_str(),
        OsStr::new("--align"),
        OsStr::new(align),
        OsStr::new("--json"),
        json.as_os_str(),
    ]);
    read_json(json)
}

fn assert_close(what: &str, ours: f64, evo: f64, tol: f64) {
    eprintln!(
        "{what}: vidslam {ours:.7}  evo {evo:.7}  diff {:.2e}",
        (ours - evo).abs()
    );
    assert!(
        (ours - evo).abs() <= tol,
        "{what}: vidslam {ours} vs evo {evo} (tolerance {tol})"
    );
}

/// Identical timestamps: both tools pair the same poses; ATE after SE3 and Sim3 alignment.
#[test]
fn ate_matches_evo_ape_se3_and_sim3() {
    let dir = scratch_dir("eval-evo-ape");
    let gt = synthetic_gt();
    let (est, _) = perturb(&gt, &est_transform(), 0.05, 1.0f64.to_radians(), 7);
    let (gt_path, est_path) = write_pair(&dir, &gt, &est);
    let (g, e) = (gt_path.as_os_str(), est_path.as_os_str());

    for (align, evo_flag) in [("se3", "-a"), ("sim3", "-as")] {
        let ours = vidslam_eval(
            &gt_path,
            &est_path,
            align,
            &dir.join(format!("{align}.json")),
        );
        assert_eq!(num(&ours, "matched_poses"), 4000.0);
        let t = evo("evo_ape", &[OsStr::new("tum"), g, e, OsStr::new(evo_flag)]);
        for (key, stat) in [
            ("ate_rmse_m", "rmse"),
            ("ate_mean_m", "mean"),
            ("ate_median_m", "median"),
            ("ate_max_m", "max"),
        ] {
            assert_close(&format!("{align} {key}"), num(&ours, key), t[stat], TOL);
        }
        let r = evo(
            "evo_ape",
            &[
                OsStr::new("tum"),
                g,
                e,
                OsStr::new(evo_flag),
                OsStr::new("-r"),
                OsStr::new("angle_deg"),
            ],
        );
        assert_close(
            &format!("{align} rot_rmse_deg"),
            num(&ours, "rot_rmse_deg"),
            r["rmse"],
            TOL,
        );
        assert_close(
            &format!("{align} rot_max_deg"),
            num(&ours, "rot_max_deg"),
            r["max"],
            TOL,
        );
        // The Sim3 case is a real test of the scale: 1 / 0.7.
        assert!((num(&ours, "scale") * 0.7 - 1.0).abs() < 1e-3, "{ours:?}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Estimate at 20 Hz between ground-truth samples: ground truth interpolated (linear + SLERP) at
/// the estimate times, as `evo_ape --sync_method interpolation` does.
#[test]
fn ate_with_interpolated_ground_truth_matches_evo() {
    let dir = scratch_dir("eval-evo-interp");
    let gt = synthetic_gt();
    // True poses 3 ms after every fifth ground-truth sample, then perturbed.
    let truth = Trajectory::new(
        gt.poses
            .iter()
            .step_by(5)
            .filter_map(|p| {
                let t = p.t.add_ns(3_000_000);
                Some(StampedPose {
                    t,
                    t_world_body: gt.interpolate(t, 10_000_000)?,
                })
            })
            .collect(),
    );
    let (est, _) = perturb(&truth, &est_transform(), 0.03, 0.5f64.to_radians(), 11);
    let (gt_path, est_path) = write_pair(&dir, &gt, &est);
    let ours = vidslam_eval(&gt_path, &est_path, "sim3", &dir.join("interp.json"));
    assert_eq!(num(&ours, "matched_poses"), est.len() as f64);
    let (g, e) = (gt_path.as_os_str(), est_path.as_os_str());
    let sync = [OsStr::new("--sync_method"), OsStr::new("interpolation")];
    let mut args = vec![OsStr::new("tum"), g, e, OsStr::new("-as")];
    args.extend(sync);
    let t = evo("evo_ape", &args);
    assert_close(
        "interpolated sim3 ate_rmse_m",
        num(&ours, "ate_rmse_m"),
        t["rmse"],
        TOL,
    );
    assert_close(
        "interpolated sim3 ate_max_m",
        num(&ours, "ate_max_m"),
        t["max"],
        TOL,
    );
    args.extend([OsStr::new("-r"), OsStr::new("angle_deg")]);
    let r = evo("evo_ape", &args);
    assert_close(
        "interpolated sim3 rot_rmse_deg",
        num(&ours, "rot_rmse_deg"),
        r["rmse"],
        TOL,
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The RPE per segment equals evo_rpe's for the same (consecutive, reference-path) segments; the
/// report then uses segments starting at every pose, which only changes the sampling.
#[test]
fn rpe_segments_match_evo_rpe() {
    let dir = scratch_dir("eval-evo-rpe");
    let gt = synthetic_gt();
    let (est, _) = perturb(&gt, &est_transform(), 0.02, 0.5f64.to_radians(), 13);
    let (gt_path, est_path) = write_pair(&dir, &gt, &est);
    let (g, e) = (gt_path.as_os_str(), est_path.as_os_str());
    let gt_poses: Vec<_> = gt.poses.iter().map(|p| p.t_world_body).collect();
    let est_poses: Vec<_> = est.poses.iter().map(|p| p.t_world_body).collect();
    for len_m in ["1", "10"] {
        let ours = relative_errors(
            &gt_poses,
            &est_poses,
            len_m.parse().unwrap(),
            SegmentStarts::Consecutive,
        );
        let trans = ErrorStats::of(&ours.trans_m).unwrap();
        let rot = ErrorStats::of(&ours.rot_deg).unwrap();
        let base = [
            OsStr::new("tum"),
            g,
            e,
            OsStr::new("--delta"),
            OsStr::new(len_m),
            OsStr::new("--delta_unit"),
            OsStr::new("m"),
            OsStr::new("--pairs_from_reference"),
        ];
        let t = evo("evo_rpe", &base);
        assert_close(
            &format!("RPE {len_m} m trans rmse"),
            trans.rmse,
            t["rmse"],
            TOL,
        );
        assert_close(
            &format!("RPE {len_m} m trans max"),
            trans.max,
            t["max"],
            TOL,
        );
        let mut rot_args = base.to_vec();
        rot_args.extend([OsStr::new("-r"), OsStr::new("angle_deg")]);
        let r = evo("evo_rpe", &rot_args);
        assert_close(&format!("RPE {len_m} m rot rmse"), rot.rmse, r["rmse"], TOL);
    }
    std::fs::remove_dir_all(&dir).ok();
}
