//! The visual factor between two keyframes of the window: the relative body pose that tracking
//! measured, weighted by the photometric information of that tracking (eq. 16's photometric block,
//! brightness marginalised), tempered because the pixels' errors are correlated through the map.
//!
//! Residual, in the increment convention of eq. 34/36 (`R ← R Exp(δθ)`, `p ← p + R δt`):
//! `r = [Log(R_zᵀ R_iᵀ R_j), R_zᵀ (R_iᵀ (p_j − p_i) − t_z)]` for the measurement `Z = (R_z, t_z)`
//! of `T_i⁻¹ T_j`. At `Z = T_i⁻¹ T_j` its Jacobian w.r.t. frame j's increment is the identity, so
//! the tracker's information on frame j's pose is the information of `r`.

use crate::geometry::{hat, log_so3, right_jacobian_inv};
use crate::imu::FrameState;
use nalgebra::{Isometry3, Matrix3, Matrix6, SMatrix, Vector3, Vector6};

/// 6x15 Jacobian of the relative-pose residual w.r.t. one frame's 15-state increment.
pub type Jacobian6x15 = SMatrix<f64, 6, 15>;
/// 1x15 Jacobian of the length residual w.r.t. one frame's 15-state increment.
pub type Jacobian1x15 = SMatrix<f64, 1, 15>;

/// Below this length (m) a translation has no direction to read a scale along.
const MIN_LENGTH_M: f64 = 1e-3;

/// A measured relative body pose `T_i⁻¹ T_j` with its information (on `[δθ, δt]` of frame j).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RelativePose {
    pub t_i_j: Isometry3<f64>,
    pub information: Matrix6<f64>,
}

fn rot(x: &FrameState) -> Matrix3<f64> {
    *x.nav.r_world_body.to_rotation_matrix().matrix()
}

impl RelativePose {
    /// The residual `r` of the module documentation.
    pub fn residual(&self, xi: &FrameState, xj: &FrameState) -> Vector6<f64> {
        self.residual_scaled(xi, xj, 0.0)
    }

    /// Jacobians of [`RelativePose::residual`] w.r.t. the increments of frames i and j (only the
    /// pose columns are non-zero).
    pub fn jacobians(&self, xi: &FrameState, xj: &FrameState) -> (Jacobian6x15, Jacobian6x15) {
        let (ji, jj, _) = self.jacobians_scaled(xi, xj, 0.0);
        (ji, jj)
    }

    /// The residual when the measurement was tracked against a map whose scale is `e^λ` times
    /// the metric one (`log_scale` = λ; a map too large by 5 % has λ = ln 1.05): the tracked
    /// translation is then `e^λ` times the true one, so the translation rows compare
    /// `e^λ R_iᵀ (p_j − p_i)` with `t_z`: `r_t = R_zᵀ (e^λ R_iᵀ (p_j − p_i) − t_z)`. At λ = 0 this
    /// is [`RelativePose::residual`] exactly.
    pub fn residual_scaled(
        &self,
        xi: &FrameState,
        xj: &FrameState,
        log_scale: f64,
    ) -> Vector6<f64> {
        let (ri, rj) = (rot(xi), rot(xj));
        let rz = *self.t_i_j.rotation.to_rotation_matrix().matrix();
        let tz = self.t_i_j.translation.vector;
        let t_rel = ri.transpose() * (xj.nav.p_world_m - xi.nav.p_world_m) * log_scale.exp();
        let mut r = Vector6::zeros();
        r.fixed_rows_mut::<3>(0)
            .copy_from(&log_so3(&(rz.transpose() * ri.transpose() * rj)));
        r.fixed_rows_mut::<3>(3)
            .copy_from(&(rz.transpose() * (t_rel - tz)));
        r
    }

    /// Jacobians of [`RelativePose::residual_scaled`] w.r.t. the increments of frames i and j
    /// and w.r.t. λ.
    pub fn jacobians_scaled(
        &self,
        xi: &FrameState,
        xj: &FrameState,
        log_scale: f64,
    ) -> (Jacobian6x15, Jacobian6x15, Vector6<f64>) {
        let (ri, rj) = (rot(xi), rot(xj));
        let s = log_scale.exp();
        let rz = *self.t_i_j.rotation.to_rotation_matrix().matrix();
        let r_rel = ri.transpose() * rj;
        let t_rel: Vector3<f64> = ri.transpose() * (xj.nav.p_world_m - xi.nav.p_world_m) * s;
        let r_rot = log_so3(&(rz.transpose() * r_rel));
        let jr_inv = right_jacobian_inv(&r_rot);
        let mut ji = Jacobian6x15::zeros();
        let mut jj = Jacobian6x15::zeros();
        // R_i ← R_i Exp(δθ_i): R_rel ← Exp(−δθ_i) R_rel = R_rel Exp(−R_relᵀ δθ_i).
        ji.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(-jr_inv * r_rel.transpose()));
        // R_iᵀ ← Exp(−δθ_i) R_iᵀ: t_rel ← t_rel + [t_rel]× δθ_i.
        ji.fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&(rz.transpose() * hat(&t_rel)));
        // p_i ← p_i + R_i δt_i: t_rel ← t_rel − e^λ δt_i.
        ji.fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&(-rz.transpose() * s));
        jj.fixed_view_mut::<3, 3>(0, 0).copy_from(&jr_inv);
        // p_j ← p_j + R_j δt_j: t_rel ← t_rel + e^λ R_rel δt_j.
        jj.fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&(rz.transpose() * r_rel * s));
        let mut jl = Vector6::zeros();
        jl.fixed_rows_mut::<3>(3)
            .copy_from(&(rz.transpose() * t_rel));
        (ji, jj, jl)
    }

    /// The measured translation's length against the two frames' distance at map scale `e^λ`:
    /// `r = ln|t_z| − λ − ln|p_j − p_i|` — the relative pose read for its map's scale only (the
    /// keyframe window's skip edges, `[window] skip_edges`). Zero for a degenerate length.
    pub fn length_residual_scaled(&self, xi: &FrameState, xj: &FrameState, log_scale: f64) -> f64 {
        let d_m = (xj.nav.p_world_m - xi.nav.p_world_m).norm();
        let t_m = self.t_i_j.translation.vector.norm();
        if d_m < MIN_LENGTH_M || t_m < MIN_LENGTH_M {
            return 0.0;
        }
        t_m.ln() - log_scale - d_m.ln()
    }

    /// Jacobians of [`RelativePose::length_residual_scaled`] w.r.t. the increments of frames i
    /// and j (only the position columns are non-zero: `p ← p + R δt` moves `ln|d|` by
    /// `dᵀ R δt / |d|²`) and w.r.t. λ (−1). Zero for a degenerate length.
    pub fn length_jacobians_scaled(
        &self,
        xi: &FrameState,
        xj: &FrameState,
    ) -> (Jacobian1x15, Jacobian1x15, f64) {
        let d = xj.nav.p_world_m - xi.nav.p_world_m;
        let d2 = d.norm_squared();
        let (mut ji, mut jj) = (Jacobian1x15::zeros(), Jacobian1x15::zeros());
        if d2.sqrt() < MIN_LENGTH_M || self.t_i_j.translation.vector.norm() < MIN_LENGTH_M {
            return (ji, jj, 0.0);
        }
        let gi = rot(xi).transpose() * d / d2;
        let gj = -(rot(xj).transpose() * d) / d2;
        for c in 0..3 {
            ji[(0, 3 + c)] = gi[c];
            jj[(0, 3 + c)] = gj[c];
        }
        (ji, jj, -1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::{ImuBias, NavState, Vector15};
    use crate::time::TimeNs;
    use nalgebra::{Translation3, UnitQuaternion};

    fn state(axis: Vector3<f64>, p: Vector3<f64>) -> FrameState {
        FrameState {
            nav: NavState {
                t: TimeNs(0),
                r_world_body: UnitQuaternion::from_scaled_axis(axis),
                p_world_m: p,
                v_world_m_s: Vector3::new(0.1, 0.2, 0.3),
            },
            bias: ImuBias::default(),
        }
    }

    /// Two frames apart in position and attitude, and the relative pose `T_i⁻¹ T_j` between them.
    fn two_frames() -> (FrameState, FrameState, Isometry3<f64>) {
        let xi = state(Vector3::new(0.3, -0.2, 1.1), Vector3::new(1.0, -2.0, 0.5));
        let xj = state(Vector3::new(0.1, 0.25, 0.9), Vector3::new(1.4, -1.7, 0.6));
        let pose = |x: &FrameState| {
            Isometry3::from_parts(Translation3::from(x.nav.p_world_m), x.nav.r_world_body)
        };
        let t_i_j = pose(&xi).inverse() * pose(&xj);
        (xi, xj, t_i_j)
    }

    /// Central differences of `f` (R rows) w.r.t. a frame's 15-state increment.
    fn numeric_rows<const R: usize>(
        f: impl Fn(&Vector15) -> SMatrix<f64, R, 1>,
    ) -> SMatrix<f64, R, 15> {
        let h = 1e-7;
        SMatrix::<f64, R, 15>::from_fn(|r, c| {
            let mut d = Vector15::zeros();
            d[c] = h;
            let a = f(&d);
            d[c] = -h;
            (a[r] - f(&d)[r]) / (2.0 * h)
        })
    }

    fn numeric(f: impl Fn(&Vector15) -> Vector6<f64>) -> Jacobian6x15 {
        numeric_rows(f)
    }

    #[test]
    fn residual_vanishes_at_the_measurement_and_jacobians_match_numeric() {
        let (xi, xj, t_i_j) = two_frames();
        let exact = RelativePose {
            t_i_j,
            information: Matrix6::identity(),
        };
        assert!(exact.residual(&xi, &xj).norm() < 1e-12);
        // A measurement off the truth, so the Jacobians are checked away from r = 0.
        let z = RelativePose {
            t_i_j: exact.t_i_j
                * Isometry3::new(
                    Vector3::new(0.05, -0.02, 0.03),
                    Vector3::new(0.02, 0.01, -0.03),
                ),
            ..exact
        };
        let (ji, jj) = z.jacobians(&xi, &xj);
        let ni = numeric(|d| z.residual(&xi.boxplus(d), &xj));
        let nj = numeric(|d| z.residual(&xi, &xj.boxplus(d)));
        assert!((ji - ni).abs().max() < 1e-6, "d/di\n{ji}\nnumeric\n{ni}");
        assert!((jj - nj).abs().max() < 1e-6, "d/dj\n{jj}\nnumeric\n{nj}");
    }

    #[test]
    fn the_scaled_residual_vanishes_at_the_scaled_measurement_and_its_jacobians_match_numeric() {
        let (xi, xj, exact) = two_frames();
        // Tracked against a map 8 % too large.
        let lambda = 1.08f64.ln();
        let mut scaled = exact;
        scaled.translation.vector *= 1.08;
        let z = RelativePose {
            t_i_j: scaled,
            information: Matrix6::identity(),
        };
        assert!(z.residual_scaled(&xi, &xj, lambda).norm() < 1e-12);
        assert!(z.residual(&xi, &xj).norm() > 1e-3);
        let z = RelativePose {
            t_i_j: scaled
                * Isometry3::new(
                    Vector3::new(0.05, -0.02, 0.03),
                    Vector3::new(0.02, 0.01, -0.03),
                ),
            ..z
        };
        let l = 0.03;
        let (ji, jj, jl) = z.jacobians_scaled(&xi, &xj, l);
        let ni = numeric(|d| z.residual_scaled(&xi.boxplus(d), &xj, l));
        let nj = numeric(|d| z.residual_scaled(&xi, &xj.boxplus(d), l));
        let h = 1e-7;
        let nl =
            (z.residual_scaled(&xi, &xj, l + h) - z.residual_scaled(&xi, &xj, l - h)) / (2.0 * h);
        assert!((ji - ni).abs().max() < 1e-6, "d/di\n{ji}\nnumeric\n{ni}");
        assert!((jj - nj).abs().max() < 1e-6, "d/dj\n{jj}\nnumeric\n{nj}");
        assert!((jl - nl).abs().max() < 1e-6, "d/dλ\n{jl}\nnumeric\n{nl}");
    }

    #[test]
    fn the_length_residual_reads_the_map_scale_and_its_jacobians_match_numeric() {
        let (xi, xj, exact) = two_frames();
        // Tracked against a map 8 % too large, its direction and rotation off: only the length
        // counts.
        let mut z = RelativePose {
            t_i_j: exact * Isometry3::new(Vector3::zeros(), Vector3::new(0.05, -0.02, 0.03)),
            information: Matrix6::identity(),
        };
        let turned = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.2, -0.1));
        z.t_i_j.translation.vector = turned * exact.translation.vector * 1.08;
        let lambda = 1.08f64.ln();
        assert!(z.length_residual_scaled(&xi, &xj, lambda).abs() < 1e-12);
        assert!((z.length_residual_scaled(&xi, &xj, 0.0) - lambda).abs() < 1e-12);
        let l = 0.03;
        let (ji, jj, jl) = z.length_jacobians_scaled(&xi, &xj);
        let one = |v: f64| SMatrix::<f64, 1, 1>::new(v);
        let ni: Jacobian1x15 =
            numeric_rows(|d| one(z.length_residual_scaled(&xi.boxplus(d), &xj, l)));
        let nj: Jacobian1x15 =
            numeric_rows(|d| one(z.length_residual_scaled(&xi, &xj.boxplus(d), l)));
        let h = 1e-7;
        let nl = (z.length_residual_scaled(&xi, &xj, l + h)
            - z.length_residual_scaled(&xi, &xj, l - h))
            / (2.0 * h);
        assert!((ji - ni).abs().max() < 1e-6, "d/di\n{ji}\nnumeric\n{ni}");
        assert!((jj - nj).abs().max() < 1e-6, "d/dj\n{jj}\nnumeric\n{nj}");
        assert!((jl - nl).abs() < 1e-6, "d/dλ {jl}, numeric {nl}");
        // A zero-length measurement reads nothing.
        let mut still = z;
        still.t_i_j.translation.vector = Vector3::zeros();
        assert_eq!(still.length_residual_scaled(&xi, &xj, l), 0.0);
        assert_eq!(still.length_jacobians_scaled(&xi, &xj).2, 0.0);
    }
}
