//! nalgebra's dense Cholesky factorisation with its products by an exact zero skipped: the same
//! floating-point operations on every non-zero in the same order, so the same bits, at a fraction
//! of the flops on the keyframe window's chain-structured normal equations.
//!
//! `nalgebra::Cholesky::new` is left-looking: column `j` of `L` is `A[j.., j]` updated by
//! `L[j.., j] += (−L[j, k]) · L[j.., k]` for `k = 0 … j − 1` in that order (one `axpy` each, whose
//! element is `a·x + y`), then divided by the square root of its diagonal. Where `L[j, k]` or
//! `L[i, k]` is exactly zero that update adds a zero product — nothing, but for the sign of a
//! zero — so [`factor`] runs only the updates whose two factors are non-zero, per element in the
//! same ascending `k`, and for a finite matrix the factor it returns equals nalgebra's bit for bit
//! (zeros aside: a `-0.0` may come out `0.0`, which no later product or sum tells apart; with a
//! NaN or an infinity in the matrix nalgebra's zero products may be NaN where these are skipped). [`solve`] then runs
//! nalgebra's own triangular solves on it, as `Cholesky::solve` does, so a solution is identical
//! too — unlike [`super::envelope_cholesky`], which sums in another order: the same solution up to
//! rounding, whose last bits the closed loop grows (docs/odometry-log.md, *The keyframe window's
//! factorisation within its envelope*).
//!
//! The window's matrix is a chain (each keyframe's 16 rows share factors with its neighbours'
//! only) with the gyro turn's three full rows last: row `j` has ~32 non-zeros left of the diagonal
//! and column `k` ~32 below it plus the last three, so the updates cost ~n·32·35 multiply-adds
//! against nalgebra's ~n³/6 (n = 195: 0.22 M against 1.2 M). Any square matrix works; only the
//! cost depends on its zeros.

use nalgebra::{DMatrix, DVector};

/// The lower-triangular factor `L` of `A = L Lᵀ`, in the lower triangle of the returned matrix
/// (the strict upper triangle keeps `a`'s, as nalgebra's factor does). Reads `a`'s lower triangle
/// only. `None` where nalgebra's `Cholesky::new` gives `None`: a diagonal that is not positive
/// (zero, negative or NaN) when its column is reached. Panics if `a` is not square.
pub fn factor(mut a: DMatrix<f64>) -> Option<DMatrix<f64>> {
    let n = a.nrows();
    assert_eq!(a.ncols(), n, "Cholesky of a non-square matrix");
    // Rows i > k with L[i, k] != 0 of each finished column k, ascending:
    // `rows[starts[k]..starts[k + 1]]`.
    let mut rows: Vec<usize> = Vec::new();
    let mut starts: Vec<usize> = Vec::with_capacity(n + 1);
    starts.push(0);
    for j in 0..n {
        for k in 0..j {
            let l_jk = a[(j, k)];
            if l_jk == 0.0 {
                continue;
            }
            let factor = -l_jk;
            // Column k's rows ascend and hold j (L[j, k] != 0): start there.
            let column = &rows[starts[k]..starts[k + 1]];
            let from = column.partition_point(|&i| i < j);
            for &i in &column[from..] {
                // nalgebra's axpy element, `a·x + y` (the sum is commutative, bit for bit).
                a[(i, j)] += factor * a[(i, k)];
            }
        }
        let diag = a[(j, j)];
        // nalgebra: zero, or no real square root (negative, NaN) → not positive definite.
        if diag.is_nan() || diag <= 0.0 {
            return None;
        }
        let denom = diag.sqrt();
        a[(j, j)] = denom;
        for i in j + 1..n {
            let v = a[(i, j)] / denom;
            a[(i, j)] = v;
            if v != 0.0 {
                rows.push(i);
            }
        }
        starts.push(rows.len());
    }
    Some(a)
}

/// Solves `A x = b` with `L` from [`factor`]: nalgebra's forward and adjoint triangular solves,
/// as `Cholesky::solve` runs them.
pub fn solve(l: &DMatrix<f64>, b: &DVector<f64>) -> DVector<f64> {
    let mut x = b.clone();
    l.solve_lower_triangular_unchecked_mut(&mut x);
    l.ad_solve_lower_triangular_unchecked_mut(&mut x);
    x
}

#[cfg(test)]
mod tests {
    use super::*;
    // The window-shaped matrices the envelope factorisation is tested on.
    use crate::smoother::envelope_cholesky::tests::{chain_with_arrow as chain, rnd as noise};

    fn same_bits(x: &DMatrix<f64>, y: &DMatrix<f64>) -> bool {
        x.shape() == y.shape()
            && x.iter()
                .zip(y.iter())
                .all(|(a, b)| a.to_bits() == b.to_bits() || (*a == 0.0 && *b == 0.0))
    }

    #[test]
    fn the_factor_and_the_solution_are_nalgebras_bit_for_bit_on_the_windows_structure() {
        for (blocks, b, tail, seed) in [(12, 16, 3, 1), (12, 16, 0, 2), (3, 15, 3, 3), (1, 4, 0, 4)]
        {
            let a = chain(blocks, b, tail, seed);
            let n = a.nrows();
            let mut s = seed + 100;
            let rhs = DVector::from_fn(n, |_, _| noise(&mut s));
            let theirs = a.clone().cholesky().expect("positive definite");
            let ours = factor(a.clone()).expect("positive definite");
            // The lower triangle is L; the strict upper keeps the input, in both.
            assert!(
                same_bits(&ours, &theirs.clone().unpack_dirty()),
                "factor {blocks}x{b}+{tail}"
            );
            let x_theirs = theirs.solve(&rhs);
            let x_ours = solve(&ours, &rhs);
            assert!(
                x_ours
                    .iter()
                    .zip(x_theirs.iter())
                    .all(|(p, q)| p.to_bits() == q.to_bits()),
                "solution {blocks}x{b}+{tail}"
            );
            // And it solves the system.
            assert!((&a * &x_ours - &rhs).amax() < 1e-9);
        }
    }

    #[test]
    fn a_dense_matrix_gives_nalgebras_factor_too() {
        let mut s = 7;
        let j = DMatrix::<f64>::from_fn(40, 30, |_, _| noise(&mut s));
        let a = j.transpose() * j + DMatrix::<f64>::identity(30, 30);
        let theirs = a.clone().cholesky().unwrap().unpack_dirty();
        assert!(same_bits(&factor(a).unwrap(), &theirs));
    }

    #[test]
    fn not_positive_definite_is_none_where_nalgebra_says_none() {
        let mut a = chain(4, 6, 2, 9);
        // A negative pivot in the middle.
        a[(10, 10)] = -1.0;
        assert!(a.clone().cholesky().is_none());
        assert!(factor(a).is_none());
        // A zero pivot.
        let z = DMatrix::<f64>::from_diagonal(&DVector::from_vec(vec![1.0, 0.0, 2.0]));
        assert!(z.clone().cholesky().is_none());
        assert!(factor(z).is_none());
        // NaN.
        let mut q = chain(2, 3, 0, 5);
        q[(3, 3)] = f64::NAN;
        assert!(q.clone().cholesky().is_none());
        assert!(factor(q).is_none());
    }
}
