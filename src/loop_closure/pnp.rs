//! A camera pose from 3D points and their pixels (perspective-n-point), started from a prior.
//!
//! Loop closure knows where the camera roughly is relative to the old keyframe it came back to
//! (the odometry's drift since is a few degrees and decimetres), so no minimal closed-form solver
//! is needed: each RANSAC hypothesis is a Gauss–Newton solve of the reprojection error of a few
//! random matches, started from the prior; the hypothesis with the most inliers (reprojection
//! error within `inlier_px`) is refined on all its inliers with a Huber kernel. A hypothesis whose
//! solve runs away (points behind the camera, a step that does not converge) is dropped.
//!
//! The unknown is `t_query_ref` (a point of the reference camera frame into the query camera
//! frame), perturbed on the left: `T ← (Exp(ω), v) · T`, so `p_q ← Exp(ω) p_q + v` and
//! `∂p_q/∂[ω, v] = [−[p_q]×, I]` (twist order `[ω, v]` as in [`crate::geometry::se3`]).

use crate::camera::CameraModel;
use crate::geometry::hat;
use crate::geometry::se3::increment;
use nalgebra::{Isometry3, Matrix2x3, Matrix2x6, Matrix6, Vector2, Vector3, Vector6};
use serde::{Deserialize, Serialize};

/// PnP settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PnpConfig {
    /// RANSAC hypotheses drawn.
    pub hypotheses: usize,
    /// Matches per hypothesis (≥ 3; 4 makes a wrong minimal set less likely to fit).
    pub sample_size: usize,
    /// A match is an inlier if its reprojection error is within this, px.
    pub inlier_px: f64,
    /// Gauss–Newton iterations per solve.
    pub iterations: usize,
    /// Seed of the sample draws (the solve is deterministic).
    pub seed: u64,
}

impl Default for PnpConfig {
    fn default() -> Self {
        PnpConfig {
            hypotheses: 48,
            sample_size: 4,
            inlier_px: 3.0,
            iterations: 8,
            seed: 0x5eed_10c0,
        }
    }
}

/// A solved pose.
#[derive(Clone, Debug, PartialEq)]
pub struct PnpSolution {
    /// The reference camera frame into the query camera frame.
    pub t_query_ref: Isometry3<f64>,
    /// Per match: within `inlier_px` at the solution.
    pub inliers: Vec<bool>,
    /// Number of inliers.
    pub num_inliers: usize,
    /// RMS reprojection error of the inliers, px.
    pub inlier_rms_px: f64,
}

/// Reprojection residual of one point (pixel predicted − observed) and its Jacobian with respect
/// to the left increment `[ω, v]` of `t_query_ref`; `None` when the point is behind the camera.
fn residual_and_jacobian(
    camera: &CameraModel,
    t_query_ref: &Isometry3<f64>,
    p_ref_m: &Vector3<f64>,
    observed_px: &Vector2<f64>,
) -> Option<(Vector2<f64>, Matrix2x6<f64>)> {
    let p_q = t_query_ref * nalgebra::Point3::from(*p_ref_m);
    let (uv, j_proj): (Vector2<f64>, Matrix2x3<f64>) = camera.project_with_jacobian(&p_q.coords)?;
    let mut j = Matrix2x6::zeros();
    j.fixed_view_mut::<2, 3>(0, 0)
        .copy_from(&(j_proj * (-hat(&p_q.coords))));
    j.fixed_view_mut::<2, 3>(0, 3).copy_from(&j_proj);
    Some((uv - observed_px, j))
}

/// Reprojection error, px; `None` behind the camera.
fn reprojection_error_px(
    camera: &CameraModel,
    t_query_ref: &Isometry3<f64>,
    p_ref_m: &Vector3<f64>,
    observed_px: &Vector2<f64>,
) -> Option<f64> {
    let p_q = t_query_ref * nalgebra::Point3::from(*p_ref_m);
    camera
        .project(&p_q.coords)
        .map(|uv| (uv - observed_px).norm())
}

/// Gauss–Newton on the matches `idx` from `start`, Huber-weighted at `huber_px`. `None` if the
/// system is singular, a point falls behind the camera, or the estimate is not finite.
fn gauss_newton(
    camera: &CameraModel,
    points_ref_m: &[Vector3<f64>],
    pixels_query_px: &[Vector2<f64>],
    idx: &[usize],
    start: &Isometry3<f64>,
    iterations: usize,
    huber_px: f64,
) -> Option<Isometry3<f64>> {
    let mut t = *start;
    for _ in 0..iterations {
        let mut h = Matrix6::<f64>::zeros();
        let mut b = Vector6::<f64>::zeros();
        for &k in idx {
            let (r, j) = residual_and_jacobian(camera, &t, &points_ref_m[k], &pixels_query_px[k])?;
            let n = r.norm();
            let w = if n <= huber_px { 1.0 } else { huber_px / n };
            h += w * j.transpose() * j;
            b += w * j.transpose() * r;
        }
        let step = h.cholesky()?.solve(&(-b));
        if !step.iter().all(|x| x.is_finite()) {
            return None;
        }
        t = increment(&step) * t;
        if step.norm() < 1e-10 {
            break;
        }
    }
    Some(t)
}

/// Inliers of `t` (within `inlier_px`).
fn inliers_of(
    camera: &CameraModel,
    points_ref_m: &[Vector3<f64>],
    pixels_query_px: &[Vector2<f64>],
    t: &Isometry3<f64>,
    inlier_px: f64,
) -> Vec<bool> {
    points_ref_m
        .iter()
        .zip(pixels_query_px)
        .map(|(p, uv)| reprojection_error_px(camera, t, p, uv).is_some_and(|e| e <= inlier_px))
        .collect()
}

/// A small deterministic generator for the sample draws (xorshift64*; also
/// [`super::two_view`]'s). Seed it odd.
pub(super) struct Draws(pub(super) u64);

impl Draws {
    /// The next draw in `0..n`.
    pub(super) fn below(&mut self, n: usize) -> usize {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 33) as usize % n
    }
}

/// The pose of the query camera relative to the reference one from `points_ref_m` (3D, reference
/// camera frame, m) matched to `pixels_query_px` (the query image's distorted pixels), started
/// from `prior_t_query_ref`. `None` if there are fewer matches than a sample or no hypothesis
/// converges; the caller judges the inlier count.
pub fn solve_from_prior(
    camera: &CameraModel,
    points_ref_m: &[Vector3<f64>],
    pixels_query_px: &[Vector2<f64>],
    prior_t_query_ref: &Isometry3<f64>,
    cfg: &PnpConfig,
) -> Option<PnpSolution> {
    let n = points_ref_m.len().min(pixels_query_px.len());
    let sample = cfg.sample_size.max(3);
    if n < sample {
        return None;
    }
    let (points_ref_m, pixels_query_px) = (&points_ref_m[..n], &pixels_query_px[..n]);
    let mut draws = Draws(cfg.seed | 1);
    let mut best: Option<(usize, Isometry3<f64>)> = None;
    let mut idx = Vec::with_capacity(sample);
    // The prior itself is the first hypothesis: a small drift needs no sample at all.
    for hypothesis in 0..=cfg.hypotheses {
        let candidate = if hypothesis == 0 {
            Some(*prior_t_query_ref)
        } else {
            idx.clear();
            while idx.len() < sample {
                let k = draws.below(n);
                if !idx.contains(&k) {
                    idx.push(k);
                }
            }
            gauss_newton(
                camera,
                points_ref_m,
                pixels_query_px,
                &idx,
                prior_t_query_ref,
                cfg.iterations,
                f64::INFINITY,
            )
        };
        let Some(t) = candidate else { continue };
        let count = inliers_of(camera, points_ref_m, pixels_query_px, &t, cfg.inlier_px)
            .iter()
            .filter(|&&i| i)
            .count();
        if best.as_ref().is_none_or(|(c, _)| count > *c) {
            best = Some((count, t));
        }
    }
    let (_, mut t) = best?;
    // Refine on the inliers, twice (the inlier set of the refined pose may grow).
    for _ in 0..2 {
        let inl = inliers_of(camera, points_ref_m, pixels_query_px, &t, cfg.inlier_px);
        let idx: Vec<usize> = (0..n).filter(|&k| inl[k]).collect();
        if idx.len() < sample {
            break;
        }
        t = gauss_newton(
            camera,
            points_ref_m,
            pixels_query_px,
            &idx,
            &t,
            cfg.iterations,
            cfg.inlier_px,
        )?;
    }
    let inliers = inliers_of(camera, points_ref_m, pixels_query_px, &t, cfg.inlier_px);
    let (sum_sq, num_inliers) = points_ref_m
        .iter()
        .zip(pixels_query_px)
        .zip(&inliers)
        .filter(|(_, i)| **i)
        .filter_map(|((p, uv), _)| reprojection_error_px(camera, &t, p, uv))
        .fold((0.0, 0usize), |(s, c), e| (s + e * e, c + 1));
    Some(PnpSolution {
        t_query_ref: t,
        inliers,
        num_inliers,
        inlier_rms_px: if num_inliers > 0 {
            (sum_sq / num_inliers as f64).sqrt()
        } else {
            f64::INFINITY
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn scene(n: usize, seed: u64) -> Vec<Vector3<f64>> {
        let mut d = Draws(seed);
        (0..n)
            .map(|_| {
                let u = d.below(1000) as f64 / 1000.0;
                let v = d.below(1000) as f64 / 1000.0;
                let z = 1.5 + 3.0 * d.below(1000) as f64 / 1000.0;
                Vector3::new((u - 0.5) * 1.4 * z, (v - 0.5) * 0.9 * z, z)
            })
            .collect()
    }

    fn pose(rx: f64, ry: f64, rz: f64, x: f64, y: f64, z: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(rx, ry, rz),
        )
    }

    #[test]
    fn the_jacobian_matches_numeric_differences() {
        let camera = CameraModel::euroc_cam0();
        let t = pose(0.1, -0.2, 0.05, 0.3, -0.1, 0.2);
        let p = Vector3::new(0.4, -0.3, 2.5);
        let obs = Vector2::new(300.0, 200.0);
        let (r0, j) = residual_and_jacobian(&camera, &t, &p, &obs).unwrap();
        let eps = 1e-6;
        for k in 0..6 {
            let mut xi = Vector6::zeros();
            xi[k] = eps;
            let (rp, _) = residual_and_jacobian(&camera, &(increment(&xi) * t), &p, &obs).unwrap();
            xi[k] = -eps;
            let (rm, _) = residual_and_jacobian(&camera, &(increment(&xi) * t), &p, &obs).unwrap();
            let numeric = (rp - rm) / (2.0 * eps);
            assert!(
                (numeric - j.column(k)).norm() < 1e-4 * (1.0 + numeric.norm()),
                "column {k}: numeric {numeric}, analytic {}",
                j.column(k)
            );
        }
        assert!(r0.norm() > 0.0);
    }

    #[test]
    fn a_drifted_prior_and_a_third_of_wrong_matches_give_the_true_pose() {
        let camera = CameraModel::euroc_cam0();
        let truth = pose(0.02, 0.25, -0.03, -0.4, 0.05, 0.3);
        let points = scene(120, 7);
        let mut d = Draws(99);
        let pixels: Vec<Vector2<f64>> = points
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let uv = camera
                    .project(&(truth * nalgebra::Point3::from(*p)).coords)
                    .unwrap_or(Vector2::new(-100.0, -100.0));
                if k % 3 == 0 {
                    // A wrong match: a pixel tens of pixels away.
                    uv + Vector2::new(20.0 + d.below(60) as f64, -15.0 - d.below(60) as f64)
                } else {
                    uv + Vector2::new(
                        (d.below(100) as f64 - 50.0) / 100.0,
                        (d.below(100) as f64 - 50.0) / 100.0,
                    )
                }
            })
            .collect();
        // 5° of heading and 0.25 m of drift in the prior.
        let prior = pose(0.0, 5f64.to_radians(), 0.0, 0.2, 0.0, -0.15) * truth;
        let sol = solve_from_prior(&camera, &points, &pixels, &prior, &PnpConfig::default())
            .expect("a solution");
        let err = sol.t_query_ref.inverse() * truth;
        assert!(err.translation.vector.norm() < 0.01, "{err}");
        assert!(err.rotation.angle() < 0.002, "{}", err.rotation.angle());
        for (k, inl) in sol.inliers.iter().enumerate() {
            assert_eq!(*inl, k % 3 != 0, "match {k}");
        }
        assert_eq!(sol.num_inliers, 80);
        assert!(sol.inlier_rms_px < 0.5, "{}", sol.inlier_rms_px);
    }

    #[test]
    fn matches_that_fit_no_pose_give_few_inliers() {
        let camera = CameraModel::euroc_cam0();
        let points = scene(80, 3);
        let mut d = Draws(5);
        let pixels: Vec<Vector2<f64>> = (0..80)
            .map(|_| Vector2::new(d.below(752) as f64, d.below(480) as f64))
            .collect();
        let prior = Isometry3::identity();
        let inliers = solve_from_prior(&camera, &points, &pixels, &prior, &PnpConfig::default())
            .map_or(0, |s| s.num_inliers);
        assert!(inliers < 12, "{inliers} inliers among random pixels");
    }

    #[test]
    fn too_few_matches_give_none() {
        let camera = CameraModel::euroc_cam0();
        let points = scene(3, 1);
        let pixels = vec![Vector2::new(100.0, 100.0); 3];
        assert!(
            solve_from_prior(
                &camera,
                &points,
                &pixels,
                &Isometry3::identity(),
                &PnpConfig::default()
            )
            .is_none()
        );
    }
}
