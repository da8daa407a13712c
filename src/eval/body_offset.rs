//! The rotation error of an estimate split into a world part and a constant body part.
//!
//! Why: after the usual alignment, an estimate's rotation error mixes what drifts in the world
//! (heading, unobservable for visual-inertial odometry) with a rotation that stays fixed in the
//! *body* frame — the estimate's body turned against the truth's by the same rotation all flight.
//! Such an offset is the signature of a camera–IMU misalignment, of a gyro whose axes are turned
//! against the camera, or of an accelerometer bias held as a tilt (a bias across gravity and a tilt
//! of the body about the axis perpendicular to both give the same specific force). No world
//! alignment removes it, and every relative rotation of the estimate is the truth's conjugated by
//! it, so its error grows with how far the body turns. Reading it here tells a fixed offset from a
//! wandering attitude without knowing its cause.
//!
//! Model: `R_est,i ≈ R_w · R_gt,i · R_b` for every matched pose i. `(R_w, R_b)` are fitted by
//! Gauss–Newton on the rotation-vector residuals `r_i = log((R_w R_gt,i R_b)ᵀ R_est,i)` (left
//! perturbation of `R_w`, right perturbation of `R_b`; Jacobians `−J_l⁻¹(r_i) (R_w R_gt,i R_b)ᵀ`
//! on `δw`, since `exp(δw) R_w` turns by `δw` in the world, and `−J_l⁻¹(r_i)` on `δb`). The part of
//! a body offset about an axis the body never turns about commutes with every pose and is taken
//! by `R_w`; about an axis it barely turns about (a drone's up axis: it yaws, and tilts by a few
//! degrees) it is nearly so. Such directions are held at zero (`hold_weak_body_axes`), so a
//! flight that mostly yaws reports the offset's tilt part and none about the yaw axis.

use crate::geometry::{exp_so3, log_so3, right_jacobian_inv};
use nalgebra::{Isometry3, Matrix3, Matrix3x6, Matrix6, Rotation3, Vector3, Vector6};

/// A body-frame rotation offset between an estimate and its ground truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyOffset {
    /// Rotation vector of `R_b` (`R_est ≈ R_w R_gt R_b`), expressed in the body frame, rad.
    pub body_rotation_rad: Vector3<f64>,
    /// RMS angle of `(R_w R_gt,i R_b)ᵀ R_est,i`: the rotation error the two rotations leave, rad.
    pub residual_rmse_rad: f64,
    /// Rotation vector of `R_w`, in the ground truth's world, rad.
    pub world_rotation_rad: Vector3<f64>,
}

/// The rotation error one pose has left after the fit (`R_est,i = Exp(φ_i) R_w R_gt,i R_b`, `φ_i`
/// in the ground truth's world), split into its part about the world's z axis — the heading,
/// signed, up in EuRoC's and the simulator's worlds, which gravity does not observe — and the
/// rest, the tilt, rad.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AttitudeError {
    pub heading_rad: f64,
    pub tilt_rad: f64,
}

/// The [`AttitudeError`] of every pose pair under `offset` (fitted by [`body_offset`] on the same
/// pairs): where a heading drifts and where it is corrected, with the constant parts removed.
///
/// # Panics
/// If the slices differ in length.
pub fn attitude_errors(
    gt: &[Isometry3<f64>],
    est: &[Isometry3<f64>],
    offset: &BodyOffset,
) -> Vec<AttitudeError> {
    assert_eq!(gt.len(), est.len(), "one pose pair per time");
    let r_w = exp_so3(&offset.world_rotation_rad);
    let r_b = exp_so3(&offset.body_rotation_rad);
    gt.iter()
        .zip(est)
        .map(|(g, e)| {
            let a = r_w * g.rotation.to_rotation_matrix().matrix() * r_b;
            let phi = a * log_so3(&(a.transpose() * e.rotation.to_rotation_matrix().matrix()));
            AttitudeError {
                heading_rad: phi.z,
                tilt_rad: phi.xy().norm(),
            }
        })
        .collect()
}

/// Information of the prior on `log R_b` per pose, 1/rad²: a millionth of what one pose tells
/// about an axis the body turns about (so the fit moves by a millionth of the offset), enough to
/// fix an axis it never turns about.
const PRIOR_INFORMATION_PER_POSE: f64 = 1e-6;
/// A body direction seen with less than this fraction of the best-seen one's information is held
/// at zero ([`hold_weak_body_axes`]).
const WEAK_AXIS_RATIO: f64 = 0.01;
/// Least information per pose on the best-seen body direction for an offset to be reported,
/// 1/rad² per pose: attitudes spread by a few degrees at least.
const MIN_INFORMATION_PER_POSE: f64 = 5e-4;
/// Gauss–Newton iterations; each is exact to first order and the residuals are small.
const MAX_ITERATIONS: usize = 30;
/// Stop when the step is below this, rad.
const STEP_TOLERANCE_RAD: f64 = 1e-12;

/// Fits the world rotation and the body offset between ground-truth and estimated body poses
/// (`t_world_body`, one pair per time). `None` with fewer than 3 pairs or if the fit is not
/// finite (a non-finite pose), so a report never carries NaN.
///
/// # Panics
/// If the slices differ in length (a caller bug: they come from one association).
pub fn body_offset(gt: &[Isometry3<f64>], est: &[Isometry3<f64>]) -> Option<BodyOffset> {
    assert_eq!(gt.len(), est.len(), "one pose pair per time");
    if gt.len() < 3 {
        return None;
    }
    let rotations = |poses: &[Isometry3<f64>]| -> Vec<Matrix3<f64>> {
        poses
            .iter()
            .map(|p| *p.rotation.to_rotation_matrix().matrix())
            .collect()
    };
    let (r_gt, r_est) = (rotations(gt), rotations(est));
    // (`log_so3` of a NaN matrix reads as no rotation at all: refuse it here.)
    if r_gt
        .iter()
        .chain(&r_est)
        .any(|r| r.iter().any(|v| !v.is_finite()))
    {
        return None;
    }
    if !turns_enough(&r_gt) {
        return None;
    }
    let with_body = fit(&r_gt, &r_est, true);
    let out = BodyOffset {
        body_rotation_rad: log_so3(&with_body.r_b),
        residual_rmse_rad: with_body.rmse_rad,
        world_rotation_rad: log_so3(&with_body.r_w),
    };
    let finite = out.body_rotation_rad.iter().all(|v| v.is_finite())
        && out.world_rotation_rad.iter().all(|v| v.is_finite())
        && out.residual_rmse_rad.is_finite();
    finite.then_some(out)
}

struct Fit {
    r_w: Matrix3<f64>,
    r_b: Matrix3<f64>,
    rmse_rad: f64,
}

/// Gauss–Newton over `δw` (and `δb` when `body`; without it, the best rotation-only world
/// alignment, which the tests compare with), from the chordal mean as the world start.
fn fit(r_gt: &[Matrix3<f64>], r_est: &[Matrix3<f64>], body: bool) -> Fit {
    let n = r_gt.len() as f64;
    // Start: R_w as the rotation nearest to Σ R_est R_gtᵀ (the chordal L2 mean), R_b = I.
    let sum: Matrix3<f64> = r_gt.iter().zip(r_est).map(|(g, e)| e * g.transpose()).sum();
    let mut r_w = nearest_rotation(&sum);
    let mut r_b = Matrix3::identity();
    for _ in 0..MAX_ITERATIONS {
        let mut h = Matrix6::<f64>::zeros();
        let mut g = Vector6::<f64>::zeros();
        for (rg, re) in r_gt.iter().zip(r_est) {
            let (r, mut j) = residual_and_jacobian(&r_w, rg, &r_b, re);
            if !body {
                j.fixed_view_mut::<3, 3>(0, 3).fill(0.0);
            }
            h += j.transpose() * j;
            g += j.transpose() * r;
        }
        if body {
            let lb = log_so3(&r_b);
            hold_weak_body_axes(&mut h, &mut g, &lb);
            let prior = PRIOR_INFORMATION_PER_POSE * n;
            for k in 3..6 {
                h[(k, k)] += prior;
            }
            let mut g_b = g.fixed_rows_mut::<3>(3);
            g_b += lb * prior;
        } else {
            for k in 3..6 {
                h[(k, k)] = 1.0;
            }
        }
        let Some(step) = h.cholesky().map(|c| c.solve(&(-g))) else {
            break;
        };
        let dw = step.fixed_rows::<3>(0).into_owned();
        let db = step.fixed_rows::<3>(3).into_owned();
        r_w = exp_so3(&dw) * r_w;
        if body {
            r_b *= exp_so3(&db);
        }
        if step.norm() < STEP_TOLERANCE_RAD {
            break;
        }
    }
    let sq: f64 = r_gt
        .iter()
        .zip(r_est)
        .map(|(rg, re)| log_so3(&((r_w * rg * r_b).transpose() * re)).norm_squared())
        .sum();
    Fit {
        r_w,
        r_b,
        rmse_rad: (sq / n).sqrt(),
    }
}

/// Holds at zero the directions of `log R_b` the data barely sees: those whose information,
/// with the world rotation marginalised (the Schur complement of `h`'s body block), is below
/// [`WEAK_AXIS_RATIO`] of the best-seen direction's get a prior of that best information. A drone
/// turns about its up axis far more than about the others, so an offset about that axis reads
/// almost like a heading error; fitted freely it wanders by degrees between two fits that
/// differ by a hundredth of a degree of residual.
fn hold_weak_body_axes(h: &mut Matrix6<f64>, g: &mut Vector6<f64>, log_r_b: &Vector3<f64>) {
    let h_ww = h.fixed_view::<3, 3>(0, 0).into_owned();
    let h_wb = h.fixed_view::<3, 3>(0, 3).into_owned();
    let h_bb = h.fixed_view::<3, 3>(3, 3).into_owned();
    let Some(h_ww_inv) = h_ww.try_inverse() else {
        return;
    };
    let schur = h_bb - h_wb.transpose() * h_ww_inv * h_wb;
    let eig = schur.symmetric_eigen();
    let best = eig.eigenvalues.max();
    if best <= 0.0 {
        return;
    }
    for k in 0..3 {
        if eig.eigenvalues[k] < WEAK_AXIS_RATIO * best {
            let v = eig.eigenvectors.column(k).into_owned();
            let prior = v * v.transpose() * best;
            let mut h_b = h.fixed_view_mut::<3, 3>(3, 3);
            h_b += prior;
            let mut g_b = g.fixed_rows_mut::<3>(3);
            g_b += prior * log_r_b;
        }
    }
}

/// Whether the attitudes turn the body enough for any offset to be seen: the best-seen body
/// direction's information per pose (with the world rotation marginalised, at the start of the
/// fit: `I − MᵀM` for `M` the mean attitude matrix, whose eigenvalues no constant world or body
/// rotation changes) must reach [`MIN_INFORMATION_PER_POSE`]. A vehicle on the pad, or one that
/// only translates, shows none: every body offset is then a world rotation.
fn turns_enough(r_gt: &[Matrix3<f64>]) -> bool {
    let n = r_gt.len() as f64;
    let mean: Matrix3<f64> = r_gt.iter().sum::<Matrix3<f64>>() / n;
    let info = Matrix3::identity() - mean.transpose() * mean;
    info.symmetric_eigen().eigenvalues.max() >= MIN_INFORMATION_PER_POSE
}

/// The residual `r = log((R_w R_gt R_b)ᵀ R_est)` and its Jacobian on `[δw, δb]` (`exp(δw) R_w`,
/// `R_b exp(δb)`): `X' = exp(−Aᵀδw) X` and `X' = exp(−δb) X` with `A = R_w R_gt R_b`,
/// `X = Aᵀ R_est`, so both blocks are `−J_l⁻¹(r)` times `Aᵀ` and `I`.
fn residual_and_jacobian(
    r_w: &Matrix3<f64>,
    r_gt: &Matrix3<f64>,
    r_b: &Matrix3<f64>,
    r_est: &Matrix3<f64>,
) -> (Vector3<f64>, Matrix3x6<f64>) {
    let a = r_w * r_gt * r_b;
    let r = log_so3(&(a.transpose() * r_est));
    // J_l⁻¹(r) = J_r⁻¹(r)ᵀ.
    let jl_inv = right_jacobian_inv(&r).transpose();
    let mut j = Matrix3x6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-jl_inv * a.transpose()));
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-jl_inv));
    (r, j)
}

/// The rotation nearest to `m` in the Frobenius norm (SVD projection onto SO(3)).
fn nearest_rotation(m: &Matrix3<f64>) -> Matrix3<f64> {
    Rotation3::from_matrix_eps(m, 1e-12, 100, Rotation3::identity()).into_inner()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// `n` poses at `s = 0, 0.05, 0.1, …`: position `(x, 0, 0)` and roll, pitch, yaw `[r, p, y]`
    /// from `f(s) = (x, [r, p, y])`.
    fn poses(n: usize, f: impl Fn(f64) -> (f64, [f64; 3])) -> Vec<Isometry3<f64>> {
        (0..n)
            .map(|i| {
                let (x, [r, p, y]) = f(i as f64 * 0.05);
                Isometry3::from_parts(
                    Translation3::new(x, 0.0, 0.0),
                    UnitQuaternion::from_euler_angles(r, p, y),
                )
            })
            .collect()
    }

    /// Body attitudes of a flight that yaws through a full turn while rolling and pitching.
    fn attitudes(n: usize) -> Vec<Isometry3<f64>> {
        poses(n, |s| (s, [0.3 * (0.9 * s).sin(), 0.2 * s.cos(), 0.4 * s]))
    }

    /// The RMS rotation error of the best rotation-only world alignment (no body offset), rad.
    fn world_only_rmse_rad(gt: &[Isometry3<f64>], est: &[Isometry3<f64>]) -> f64 {
        let rot = |p: &[Isometry3<f64>]| -> Vec<Matrix3<f64>> {
            p.iter()
                .map(|x| *x.rotation.to_rotation_matrix().matrix())
                .collect()
        };
        fit(&rot(gt), &rot(est), false).rmse_rad
    }

    fn turned(
        gt: &[Isometry3<f64>],
        world: Vector3<f64>,
        body: Vector3<f64>,
    ) -> Vec<Isometry3<f64>> {
        let w = UnitQuaternion::from_scaled_axis(world);
        let b = UnitQuaternion::from_scaled_axis(body);
        gt.iter()
            .map(|p| Isometry3::from_parts(p.translation, w * p.rotation * b))
            .collect()
    }

    #[test]
    fn recovers_a_body_offset_that_no_world_rotation_removes() {
        let gt = attitudes(400);
        let body = Vector3::new(0.004, -0.002, 0.035); // 2° about z, a little about x and y
        let est = turned(&gt, Vector3::new(0.1, -0.3, 1.2), body);
        let off = body_offset(&gt, &est).unwrap();
        assert!(
            (off.body_rotation_rad - body).norm() < 1e-6,
            "{:?} vs {body:?}",
            off.body_rotation_rad
        );
        // The prior moves the fit by a millionth of the offset.
        assert!(off.residual_rmse_rad < 1e-6, "{off:?}");
        // A world rotation alone takes the part about the axis the body mostly turns about (z),
        // and leaves the rest.
        assert!(
            world_only_rmse_rad(&gt, &est) > 0.2 * body.norm(),
            "{off:?}"
        );
    }

    #[test]
    fn attitude_errors_follow_a_heading_drift_and_a_tilt_apart_from_the_offsets() {
        // A heading that drifts linearly by 2° over the flight, on top of a world rotation and a
        // body offset, and a tilt of 0.5° about world x in the middle fifth.
        let gt = attitudes(400);
        let body = Vector3::new(0.004, -0.002, 0.035);
        let drift_rad = |i: usize| 0.035 * i as f64 / 399.0;
        let tilt_rad = |i: usize| if (160..240).contains(&i) { 0.0087 } else { 0.0 };
        let est: Vec<_> = turned(&gt, Vector3::new(0.1, -0.3, 1.2), body)
            .into_iter()
            .enumerate()
            .map(|(i, mut p)| {
                let d = UnitQuaternion::from_scaled_axis(
                    Vector3::z() * drift_rad(i) + Vector3::x() * tilt_rad(i),
                );
                p.rotation = d * p.rotation;
                p
            })
            .collect();
        let off = body_offset(&gt, &est).unwrap();
        let err = attitude_errors(&gt, &est, &off);
        assert_eq!(err.len(), gt.len());
        // The world rotation takes the drift's mean (1°), so the heading error runs from −1° to
        // +1°; the fitted offsets take a little of it (here up to 0.08°).
        for (i, e) in err.iter().enumerate() {
            let want = drift_rad(i) - 0.0175;
            assert!((e.heading_rad - want).abs() < 2e-3, "{i}: {e:?} vs {want}");
        }
        // The tilt stands out where it was made (the offsets take a part of it: 0.27° of the
        // 0.5° is left there, 0.11° elsewhere).
        let mean_tilt =
            |e: &[AttitudeError]| e.iter().map(|e| e.tilt_rad).sum::<f64>() / e.len() as f64;
        let outside: Vec<_> = err[..160].iter().chain(&err[240..]).copied().collect();
        let (mid, out) = (mean_tilt(&err[160..240]), mean_tilt(&outside));
        assert!(mid > 0.004 && mid > 2.0 * out, "{mid} {out}");
        // Without the drift and the tilt nothing is left.
        let clean = turned(&gt, Vector3::new(0.1, -0.3, 1.2), body);
        let off = body_offset(&gt, &clean).unwrap();
        let err = attitude_errors(&gt, &clean, &off);
        assert!(
            err.iter()
                .all(|e| e.heading_rad.abs() < 1e-6 && e.tilt_rad < 1e-6)
        );
    }

    #[test]
    fn a_world_rotation_alone_gives_no_body_offset() {
        let gt = attitudes(400);
        let est = turned(&gt, Vector3::new(-0.7, 0.2, 2.5), Vector3::zeros());
        let off = body_offset(&gt, &est).unwrap();
        assert!(off.body_rotation_rad.norm() < 1e-8, "{off:?}");
        assert!(
            off.residual_rmse_rad < 1e-8 && world_only_rmse_rad(&gt, &est) < 1e-8,
            "{off:?}"
        );
    }

    #[test]
    fn noise_is_left_in_the_residual_not_taken_as_an_offset() {
        let gt = attitudes(400);
        let body = Vector3::new(0.0, 0.0, 0.02);
        let mut est = turned(&gt, Vector3::new(0.0, 0.0, 0.5), body);
        // A deterministic wobble of ±0.5° about alternating axes.
        for (i, p) in est.iter_mut().enumerate() {
            let a = 0.0087 * ((i as f64) * 1.7).sin();
            let axis = [Vector3::x(), Vector3::y(), Vector3::z()][i % 3];
            p.rotation = UnitQuaternion::from_scaled_axis(axis * a) * p.rotation;
        }
        let off = body_offset(&gt, &est).unwrap();
        assert!(
            (off.body_rotation_rad - body).norm() < 1.5e-3,
            "{:?}",
            off.body_rotation_rad
        );
        assert!(
            off.residual_rmse_rad > 0.002 && off.residual_rmse_rad < 0.01,
            "{off:?}"
        );
    }

    #[test]
    fn an_offset_about_the_only_turning_axis_is_left_to_the_world() {
        // Yaw only: a body offset about the yaw axis commutes with every pose.
        let gt = poses(200, |s| (0.0, [0.0, 0.0, 0.6 * s]));
        let body = Vector3::new(0.01, 0.0, 0.03);
        let est = turned(&gt, Vector3::zeros(), body);
        let off = body_offset(&gt, &est).unwrap();
        assert!((off.body_rotation_rad.x - 0.01).abs() < 1e-4, "{off:?}");
        assert!(off.body_rotation_rad.z.abs() < 1e-3, "{off:?}");
        assert!(off.residual_rmse_rad < 1e-4, "{off:?}");
    }

    #[test]
    fn jacobian_matches_numeric_differentiation() {
        let r_w = exp_so3(&Vector3::new(0.3, -1.1, 0.4));
        let r_gt = exp_so3(&Vector3::new(-0.8, 0.2, 2.0));
        let r_b = exp_so3(&Vector3::new(0.02, 0.01, -0.04));
        // An estimate 0.2 rad from the model, so J_l⁻¹ is not the identity.
        let r_est = r_w * r_gt * r_b * exp_so3(&Vector3::new(0.1, -0.15, 0.08));
        let (r0, j) = residual_and_jacobian(&r_w, &r_gt, &r_b, &r_est);
        let eps = 1e-6;
        for k in 0..6 {
            let mut d = Vector3::zeros();
            d[k % 3] = eps;
            let (rw, rb) = if k < 3 {
                (exp_so3(&d) * r_w, r_b)
            } else {
                (r_w, r_b * exp_so3(&d))
            };
            let (r1, _) = residual_and_jacobian(&rw, &r_gt, &rb, &r_est);
            let numeric = (r1 - r0) / eps;
            let analytic = j.column(k).into_owned();
            assert!(
                (numeric - analytic).norm() < 1e-5,
                "column {k}: numeric {numeric:?} analytic {analytic:?}"
            );
        }
    }

    #[test]
    fn an_offset_about_an_axis_the_body_barely_turns_about_is_held_at_zero() {
        // A drone's flight: full yaw turns, tilts of ±3° only.
        let gt = poses(600, |s| {
            (
                0.0,
                [0.05 * (0.7 * s).sin(), 0.05 * (0.5 * s).cos(), 0.3 * s],
            )
        });
        let body = Vector3::new(0.0, -0.037, 0.02); // 2.1° of tilt, 1.1° about the up axis
        let est = turned(&gt, Vector3::new(0.0, 0.0, 0.4), body);
        let off = body_offset(&gt, &est).unwrap();
        assert!(
            (off.body_rotation_rad - Vector3::new(0.0, -0.037, 0.0)).norm() < 1e-3,
            "{off:?}"
        );
        // The up-axis part reads as a heading error; the tilts leave ~1e-3 rad of it.
        assert!(off.residual_rmse_rad < 2e-3, "{off:?}");
    }

    #[test]
    fn a_body_that_never_turns_gives_none() {
        // Translating with the attitude held to ±0.5°.
        let gt = poses(300, |s| (s, [0.0087 * s.sin(), 0.0, 0.4]));
        let est = turned(
            &gt,
            Vector3::new(0.0, 0.0, 0.2),
            Vector3::new(0.0, 0.03, 0.0),
        );
        assert!(body_offset(&gt, &est).is_none());
    }

    #[test]
    fn too_few_poses_or_a_non_finite_one_give_none() {
        let gt = attitudes(2);
        assert!(body_offset(&gt, &gt).is_none());
        let gt = attitudes(50);
        let mut est = gt.clone();
        est[7].rotation =
            UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(f64::NAN, 0.0, 0.0, 0.0));
        assert!(body_offset(&gt, &est).is_none());
    }
}
