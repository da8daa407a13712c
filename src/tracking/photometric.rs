//! The photometric residual of eq. 23 with an affine brightness model, and its contribution to
//! the normal equations of eq. 16, in inverse-compositional form.
//!
//! For a keyframe point `p` (keyframe camera frame) the residual is
//! `r = I_j(π(T_ck p)) − (e^α I_i(u) + β)`, where `T_ck` maps keyframe-camera to current-camera
//! coordinates and `(α, β)` model the exposure/gain change. Inverse-compositionally (eq. 23–25) the
//! increment `ε` is applied on the keyframe side, `I_i(π(exp(ε) p))`, so the Jacobian row is
//! `J = −[e^α g, e^α I_i, 1]` with the precomputed `g` of [`super::keyframe::LevelPoints`], and
//! `T_ck ← T_ck · exp(ε)⁻¹` is the update. This module accumulates `G = Σ w ĝ ĝᵀ` and
//! `c = Σ w ĝ r` for the unscaled row `ĝ = [g, I_i, 1]`; [`PhotometricSystem::normal_equations`]
//! applies the scaling `S = diag(e^α·1₆, e^α, 1)`: `H = S G S`, `b = S c` (so that `H δ = b` is
//! eq. 16 for `δ = [ε, δα, δβ]`).

use super::keyframe::LevelPoints;
use crate::camera::CameraModel;
use crate::image::{Image, bilinear};
use nalgebra::{Isometry3, SMatrix, SVector, Vector3};

/// Robust-cost settings of one accumulation.
#[derive(Clone, Copy, Debug)]
pub struct RobustCost {
    /// Huber threshold, gray levels.
    pub huber_gray: f32,
    /// Residuals beyond this get zero weight (and a constant cost), gray levels.
    pub outlier_gray: f32,
    /// Points nearer the border than this are not used, pixels.
    pub border_px: f64,
}

impl RobustCost {
    /// Huber cost `ρ(r)`, capped at `ρ(outlier)`, and the IRLS weight.
    #[inline]
    fn cost_weight(&self, r: f32) -> (f32, f32) {
        let a = r.abs();
        let k = self.huber_gray;
        if a > self.outlier_gray {
            (k * (self.outlier_gray - 0.5 * k), 0.0)
        } else if a <= k {
            (0.5 * r * r, 1.0)
        } else {
            (k * (a - 0.5 * k), k / a)
        }
    }

    /// Cost charged for a point that does not project into the image.
    fn invalid_cost(&self) -> f32 {
        self.cost_weight(self.outlier_gray * 2.0).0
    }
}

/// The accumulated photometric normal equations at one pose, before scaling.
#[derive(Clone, Debug)]
pub struct PhotometricSystem {
    /// `Σ w ĝ ĝᵀ` (8x8, order `[ω, v, α, β]`).
    pub g: SMatrix<f64, 8, 8>,
    /// `Σ w ĝ r`.
    pub c: SVector<f64, 8>,
    /// `Σ ρ(r)` over all points (invalid points charged as outliers), gray levels².
    pub cost: f64,
    /// Points of the level.
    pub num_points: usize,
    /// Points that project into the image.
    pub num_valid: usize,
    /// Valid points with `|r|` within the outlier threshold.
    pub num_inliers: usize,
    /// `Σ r²` over inliers, gray levels².
    pub sum_sq_inliers: f64,
}

impl PhotometricSystem {
    /// `H = S G S`, `b = S c` for gain `e^α` (see the module doc).
    pub fn normal_equations(&self, gain: f64) -> (SMatrix<f64, 8, 8>, SVector<f64, 8>) {
        let mut s = SVector::<f64, 8>::from_element(gain);
        s[7] = 1.0;
        let h = SMatrix::<f64, 8, 8>::from_fn(|i, j| s[i] * self.g[(i, j)] * s[j]);
        let b = self.c.component_mul(&s);
        (h, b)
    }

    /// RMS of the inlier residuals, gray levels.
    pub fn inlier_rms_gray(&self) -> f64 {
        if self.num_inliers == 0 {
            f64::INFINITY
        } else {
            (self.sum_sq_inliers / self.num_inliers as f64).sqrt()
        }
    }
}

/// An inlier of a residual pass: the point's index in its level, its residual `r` (gray levels)
/// and its IRLS weight `w` (robust weight × the point's own weight, non-zero).
#[derive(Clone, Copy, Debug)]
pub struct WeightedResidual {
    index: u32,
    res: f32,
    w: f32,
}

/// The cost part of a [`PhotometricSystem`]: what a residual pass gives before the normal
/// equations are accumulated.
#[derive(Clone, Copy, Debug)]
pub struct PhotometricCost {
    /// `Σ ρ(r)` over all points (invalid points charged as outliers), gray levels².
    pub cost: f64,
    /// Points of the level.
    pub num_points: usize,
    /// Points that project into the image.
    pub num_valid: usize,
    /// Valid points with `|r|` within the outlier threshold.
    pub num_inliers: usize,
    /// `Σ r²` over inliers, gray levels².
    pub sum_sq_inliers: f64,
}

/// Evaluates every point of `level` at `t_cur_kf` (keyframe camera → current camera) and
/// brightness `(gain, offset_gray) = (e^α, β)`, writing `|r|` of valid points into `abs_residuals`
/// and the inliers' weighted residuals into `inliers` (both cleared first; their capacity is
/// reused, so tracking does not allocate) and returning the accumulated system.
#[allow(clippy::too_many_arguments)]
pub fn accumulate(
    level: &LevelPoints,
    camera: &CameraModel,
    image: &Image<f32>,
    t_cur_kf: &Isometry3<f64>,
    brightness: (f64, f64),
    robust: &RobustCost,
    abs_residuals: &mut Vec<f32>,
    inliers: &mut Vec<WeightedResidual>,
) -> PhotometricSystem {
    let cost = residuals(
        level,
        camera,
        image,
        t_cur_kf,
        brightness,
        robust,
        abs_residuals,
        inliers,
    );
    normal_equations_of(level, inliers, cost)
}

/// The residual pass of [`accumulate`]: the cost and counts, `|r|` of valid points in
/// `abs_residuals` and the inliers in `inliers` for [`normal_equations_of`]. A trial step the
/// solver rejects needs nothing more.
#[allow(clippy::too_many_arguments)]
pub fn residuals(
    level: &LevelPoints,
    camera: &CameraModel,
    image: &Image<f32>,
    t_cur_kf: &Isometry3<f64>,
    (gain, offset_gray): (f64, f64),
    robust: &RobustCost,
    abs_residuals: &mut Vec<f32>,
    inliers: &mut Vec<WeightedResidual>,
) -> PhotometricCost {
    abs_residuals.clear();
    inliers.clear();
    let rot = t_cur_kf.rotation.to_rotation_matrix();
    let r = rot.matrix();
    let t = t_cur_kf.translation.vector;
    let (gain_f, offset_f) = (gain as f32, offset_gray as f32);
    let mut cost = 0.0f64;
    let mut valid = 0usize;
    let mut sum_sq = 0.0f64;
    let invalid_cost = robust.invalid_cost() as f64;
    for (index, ((p, &i_ref), &prior_w)) in level
        .p_kf_m
        .iter()
        .zip(&level.intensity)
        .zip(&level.weight)
        .enumerate()
    {
        let pk = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        let q = r * pk + t;
        let Some(uv) = camera.project(&q) else {
            cost += invalid_cost;
            continue;
        };
        if !camera.in_image(&uv, robust.border_px) {
            cost += invalid_cost;
            continue;
        }
        let Some(i_cur) = bilinear(image, uv.x as f32, uv.y as f32) else {
            cost += invalid_cost;
            continue;
        };
        valid += 1;
        let res = i_cur - (gain_f * i_ref + offset_f);
        abs_residuals.push(res.abs());
        let (rho, w) = robust.cost_weight(res);
        let w = w * prior_w;
        cost += (rho * prior_w) as f64;
        if w == 0.0 {
            continue;
        }
        sum_sq += (res * res) as f64;
        inliers.push(WeightedResidual {
            index: index as u32,
            res,
            w,
        });
    }
    PhotometricCost {
        cost,
        num_points: level.len(),
        num_valid: valid,
        num_inliers: inliers.len(),
        sum_sq_inliers: sum_sq,
    }
}

/// The normal-equation pass of [`accumulate`]: `G = Σ w ĝ ĝᵀ`, `c = Σ w ĝ r` over the `inliers`
/// a [`residuals`] pass over `level` found (in its point order), with its `cost`.
pub fn normal_equations_of(
    level: &LevelPoints,
    inliers: &[WeightedResidual],
    cost: PhotometricCost,
) -> PhotometricSystem {
    let mut g = [0.0f64; 36]; // upper triangle of the 8x8, row-major
    let mut c = [0.0f64; 8];
    for e in inliers {
        let i = e.index as usize;
        let (jac, i_ref, w) = (&level.jacobian[i], level.intensity[i], e.w);
        let row = [
            jac[0], jac[1], jac[2], jac[3], jac[4], jac[5], i_ref, 1.0f32,
        ];
        let wr = (w * e.res) as f64;
        let mut k = 0;
        for a in 0..8 {
            let wa = (w * row[a]) as f64;
            c[a] += row[a] as f64 * wr;
            for &rb in &row[a..] {
                g[k] += wa * rb as f64;
                k += 1;
            }
        }
    }
    let mut gm = SMatrix::<f64, 8, 8>::zeros();
    let mut k = 0;
    for a in 0..8 {
        for b in a..8 {
            gm[(a, b)] = g[k];
            gm[(b, a)] = g[k];
            k += 1;
        }
    }
    PhotometricSystem {
        g: gm,
        c: SVector::from(c),
        cost: cost.cost,
        num_points: cost.num_points,
        num_valid: cost.num_valid,
        num_inliers: cost.num_inliers,
        sum_sq_inliers: cost.sum_sq_inliers,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn huber_cost_and_weights() {
        let rc = RobustCost {
            huber_gray: 2.0,
            outlier_gray: 10.0,
            border_px: 1.0,
        };
        assert_eq!(rc.cost_weight(1.0), (0.5, 1.0));
        assert_eq!(rc.cost_weight(-4.0), (6.0, 0.5));
        // Continuous at the outlier threshold, constant beyond it.
        assert_eq!(rc.cost_weight(10.0).0, rc.cost_weight(25.0).0);
        assert_eq!(rc.cost_weight(25.0).1, 0.0);
        assert_eq!(rc.invalid_cost(), rc.cost_weight(10.0).0);
    }
}
