//! The Gauss-Newton step of eq. 16 solved with the Schur complement, eq. 19–22: the pose block
//! `P` (photometric + IMU) and the IMU block `I` (velocity and biases, IMU residual only).

use nalgebra::{SMatrix, SVector};

/// Normal equations `[[H_PP, H_PI], [H_PIᵀ, H_II]] [δ_P; δ_I] = [B_P; B_I]` (eq. 20).
#[derive(Clone, Debug, PartialEq)]
pub struct BlockSystem<const P: usize, const I: usize> {
    pub h_pp: SMatrix<f64, P, P>,
    pub h_pi: SMatrix<f64, P, I>,
    pub h_ii: SMatrix<f64, I, I>,
    pub b_p: SVector<f64, P>,
    pub b_i: SVector<f64, I>,
}

impl<const P: usize, const I: usize> BlockSystem<P, I> {
    pub fn zeros() -> Self {
        BlockSystem {
            h_pp: SMatrix::zeros(),
            h_pi: SMatrix::zeros(),
            h_ii: SMatrix::zeros(),
            b_p: SVector::zeros(),
            b_i: SVector::zeros(),
        }
    }

    /// Solves by the Schur complement: eq. 21 for `δ_I` (Cholesky), then eq. 22 for `δ_P`.
    /// `None` if `H_PP` or the reduced system is not positive definite.
    pub fn solve_schur(&self) -> Option<(SVector<f64, P>, SVector<f64, I>)> {
        let pp = self.h_pp.cholesky()?;
        let pp_inv_pi = pp.solve(&self.h_pi); // H_PP⁻¹ H_PI
        let pp_inv_bp = pp.solve(&self.b_p); // H_PP⁻¹ B_P
        let s = self.h_ii - self.h_pi.transpose() * pp_inv_pi;
        let rhs = self.b_i - self.h_pi.transpose() * pp_inv_bp;
        let d_i = s.cholesky()?.solve(&rhs); // eq. 21
        let d_p = pp_inv_bp - pp_inv_pi * d_i; // eq. 22
        Some((d_p, d_i))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    #[test]
    fn schur_solution_equals_the_full_solve() {
        // A random SPD 17x17 system (8 pose+affine, 9 IMU), deterministic.
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let a = DMatrix::from_fn(40, 17, |_, _| rnd());
        let h = a.transpose() * &a + DMatrix::identity(17, 17) * 1e-3;
        let b = nalgebra::DVector::from_fn(17, |_, _| rnd());
        let mut sys = BlockSystem::<8, 9>::zeros();
        sys.h_pp.copy_from(&h.view((0, 0), (8, 8)));
        sys.h_pi.copy_from(&h.view((0, 8), (8, 9)));
        sys.h_ii.copy_from(&h.view((8, 8), (9, 9)));
        sys.b_p.copy_from(&b.rows(0, 8));
        sys.b_i.copy_from(&b.rows(8, 9));
        let (dp, di) = sys.solve_schur().unwrap();
        let full = h.clone().lu().solve(&b).unwrap();
        assert!((dp - full.rows(0, 8)).norm() < 1e-9 * full.norm());
        assert!((di - full.rows(8, 9)).norm() < 1e-9 * full.norm());
    }

    #[test]
    fn indefinite_systems_are_refused() {
        let mut sys = BlockSystem::<2, 1>::zeros();
        sys.h_pp = SMatrix::<f64, 2, 2>::new(1.0, 0.0, 0.0, -1.0);
        sys.h_ii[(0, 0)] = 1.0;
        assert!(sys.solve_schur().is_none());
        sys.h_pp = SMatrix::<f64, 2, 2>::identity();
        sys.h_pi = SMatrix::<f64, 2, 1>::new(2.0, 0.0);
        // Reduced system 1 - 4 < 0.
        assert!(sys.solve_schur().is_none());
    }
}
