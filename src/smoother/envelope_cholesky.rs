//! Cholesky factorisation of a symmetric positive-definite matrix within its envelope (profile),
//! for the keyframe window's normal equations.
//!
//! The window's information matrix is a chain: keyframe k shares factors (eq. 13's IMU residual,
//! the tracked relative pose, the map's scale) with k − 1 and k + 1 only, the marginalisation
//! prior sits on the oldest keyframe, and the gyro's turn φ — shared by every IMU factor — comes
//! last. Row i's first non-zero column is then at most two blocks (32 columns) left of the
//! diagonal except for φ's three full rows, and a Cholesky factor has no fill-in left of a row's
//! first non-zero (George & Liu, *Computer Solution of Large Sparse Positive Definite Systems*,
//! ch. 4). Factoring row by row within that envelope costs ~0.2 Mflop for a 12-keyframe window
//! where the dense factorisation costs n³/3 ≈ 2.5 Mflop, on the tracking thread at every new
//! keyframe. Any matrix works (a dense one has a full envelope); only the cost depends on the
//! structure.

use nalgebra::{DMatrix, DVector};

/// `L` of `A = L Lᵀ`, row i stored from its envelope's first column to the diagonal.
#[derive(Clone, Debug)]
pub struct EnvelopeCholesky {
    /// First stored column of each row.
    first: Vec<usize>,
    /// Start of each row in `l`.
    offset: Vec<usize>,
    /// The rows of `L`, each from `first[i]` to `i` inclusive, one after the other.
    l: Vec<f64>,
}

impl EnvelopeCholesky {
    /// Factors the square matrix `a`, read from its lower triangle (its upper is taken to mirror
    /// it). `None` if `a` is not square, not positive definite or not finite.
    pub fn factor(a: &DMatrix<f64>) -> Option<Self> {
        let n = a.nrows();
        if a.ncols() != n {
            return None;
        }
        let first: Vec<usize> = (0..n)
            .map(|i| (0..i).find(|&j| a[(i, j)] != 0.0).unwrap_or(i))
            .collect();
        let mut offset = Vec::with_capacity(n + 1);
        let mut len = 0;
        for (i, f) in first.iter().enumerate() {
            offset.push(len);
            len += i - f + 1;
        }
        offset.push(len);
        let mut l = vec![0.0; len];
        for i in 0..n {
            let fi = first[i];
            let row_i = offset[i];
            for j in fi..=i {
                // L[i][j] = (A[i][j] − Σ_k L[i][k] L[j][k]) / L[j][j], k over both envelopes.
                let fj = first[j];
                let k0 = fi.max(fj);
                let (ri, rj) = (row_i + k0 - fi, offset[j] + k0 - fj);
                let m = j - k0;
                // (On the diagonal both slices are row i's: the sum of its squares.)
                let s = a[(i, j)] - dot(&l[ri..ri + m], &l[rj..rj + m]);
                let v = if j == i {
                    if !(s > 0.0 && s.is_finite()) {
                        return None;
                    }
                    s.sqrt()
                } else {
                    s / l[offset[j] + j - fj]
                };
                l[row_i + j - fi] = v;
            }
        }
        Some(EnvelopeCholesky { first, offset, l })
    }

    fn n(&self) -> usize {
        self.first.len()
    }

    fn at(&self, i: usize, j: usize) -> f64 {
        self.l[self.offset[i] + j - self.first[i]]
    }

    /// `x` with `A x = b`.
    pub fn solve(&self, b: &DVector<f64>) -> DVector<f64> {
        let n = self.n();
        assert_eq!(b.len(), n, "right-hand side of the wrong length");
        // L y = b, row by row.
        let mut y = b.clone();
        for i in 0..n {
            let fi = self.first[i];
            let row = &self.l[self.offset[i]..self.offset[i] + i - fi];
            let s = y[i] - dot(row, &y.as_slice()[fi..i]);
            y[i] = s / self.at(i, i);
        }
        // Lᵀ x = y, column by column of Lᵀ (row by row of L, backwards).
        for i in (0..n).rev() {
            y[i] /= self.at(i, i);
            let fi = self.first[i];
            let xi = y[i];
            let row = &self.l[self.offset[i]..self.offset[i] + i - fi];
            for (yk, lk) in y.as_mut_slice()[fi..i].iter_mut().zip(row) {
                *yk -= lk * xi;
            }
        }
        y
    }

    /// Entries stored (the envelope's size), for tests and benchmarks.
    pub fn stored(&self) -> usize {
        self.l.len()
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A deterministic pseudo-random number in [−1, 1).
    pub(crate) fn rnd(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    /// The window's structure: `blocks` blocks of `b` unknowns, each coupled with the next, then
    /// `e` unknowns coupled with all; symmetric positive definite (J Jᵀ plus a diagonal).
    pub(crate) fn chain_with_arrow(blocks: usize, b: usize, e: usize, seed: u64) -> DMatrix<f64> {
        let n = blocks * b + e;
        let mut s = seed;
        let mut a = DMatrix::<f64>::zeros(n, n);
        // Factors between consecutive blocks (and one on the first block alone, the prior),
        // each touching the shared unknowns.
        for k in 0..blocks {
            let cols: Vec<usize> = (k.saturating_sub(1) * b..(k + 1) * b)
                .chain(blocks * b..n)
                .collect();
            for _ in 0..b {
                let row: Vec<f64> = cols.iter().map(|_| rnd(&mut s)).collect();
                for (p, &i) in cols.iter().enumerate() {
                    for (q, &j) in cols.iter().enumerate() {
                        a[(i, j)] += row[p] * row[q];
                    }
                }
            }
        }
        for i in 0..n {
            a[(i, i)] += 0.1;
        }
        a
    }

    fn check_solves_as_dense(a: &DMatrix<f64>, seed: u64) {
        let n = a.nrows();
        let mut s = seed;
        let b = DVector::from_fn(n, |_, _| rnd(&mut s));
        let env = EnvelopeCholesky::factor(a).expect("positive definite");
        let x = env.solve(&b);
        let dense = a.clone().cholesky().expect("positive definite").solve(&b);
        let err = (&x - &dense).amax() / dense.amax();
        assert!(err < 1e-10, "relative difference {err}");
        let residual = (a * &x - &b).amax() / b.amax();
        assert!(residual < 1e-9, "residual {residual}");
    }

    #[test]
    fn solves_the_windows_structure_as_the_dense_factorisation_does() {
        for (blocks, b, e, seed) in [(12, 16, 3, 1), (12, 15, 0, 2), (3, 16, 3, 3), (1, 15, 3, 4)] {
            let a = chain_with_arrow(blocks, b, e, seed);
            check_solves_as_dense(&a, seed + 100);
        }
    }

    #[test]
    fn stores_only_the_envelope_of_a_chain() {
        let (blocks, b, e) = (12, 16, 3);
        let a = chain_with_arrow(blocks, b, e, 7);
        let env = EnvelopeCholesky::factor(&a).unwrap();
        let n = blocks * b + e;
        // Block 0: its lower triangle; blocks 1..: one block to the left and their triangle;
        // the shared rows: full.
        let tri = b * (b + 1) / 2;
        let expected =
            tri + (blocks - 1) * (b * b + tri) + (0..e).map(|k| n - e + k + 1).sum::<usize>();
        assert_eq!(env.stored(), expected);
        assert!(env.stored() < n * (n + 1) / 2 / 3);
    }

    #[test]
    fn a_dense_matrix_is_factored_whole() {
        let mut s = 11;
        let n = 20;
        let j = DMatrix::from_fn(n, n, |_, _| rnd(&mut s));
        let a = &j * j.transpose() + DMatrix::identity(n, n) * 0.01;
        let env = EnvelopeCholesky::factor(&a).unwrap();
        assert_eq!(env.stored(), n * (n + 1) / 2);
        check_solves_as_dense(&a, 12);
    }

    #[test]
    fn refuses_what_is_not_positive_definite() {
        let mut a = chain_with_arrow(4, 6, 2, 5);
        a[(10, 10)] = -1.0;
        assert!(EnvelopeCholesky::factor(&a).is_none());
        let mut nan = chain_with_arrow(4, 6, 2, 6);
        nan[(3, 3)] = f64::NAN;
        assert!(EnvelopeCholesky::factor(&nan).is_none());
        assert!(EnvelopeCholesky::factor(&DMatrix::zeros(3, 4)).is_none());
        let empty = EnvelopeCholesky::factor(&DMatrix::zeros(0, 0)).unwrap();
        assert_eq!(empty.solve(&DVector::zeros(0)).len(), 0);
    }
}
