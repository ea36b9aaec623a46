//! Small dense linear algebra generic over the scalar (`f64` or a dual number), for the
//! filters' moment equations and measurement updates, so that the prediction-error likelihood
//! can be differentiated through them (the PEM, [`super::pem`]).
//!
//! Matrices are `n × n` (or `n × k`) slices stored column-major, as the rest of the crate's
//! model layer ([`crate::model::Sde::diffusion`]). The dimensions are those of a state vector
//! (a handful), so plain loops are the right tool; the `f64`-only smoother uses `nalgebra`.

use crate::model::Scalar;

/// The lower Cholesky factor L of a symmetric positive definite `n × n` matrix (A = L Lᵀ),
/// computed by the crate's one generic Cholesky, [`onsager_closures::cholesky`] (row-major
/// storage: L_ik at `i * n + k`).
pub(crate) struct CholeskyFactor<D> {
    l: Vec<D>,
    n: usize,
}

/// The Cholesky factor of the symmetric `n × n` matrix `a` (symmetric, so its storage order
/// does not matter). `None` when A is not numerically positive definite or not finite.
pub(crate) fn cholesky<D: Scalar>(a: &[D], n: usize) -> Option<CholeskyFactor<D>> {
    onsager_closures::cholesky(a, n).ok().map(|l| CholeskyFactor { l, n })
}

impl<D: Scalar> CholeskyFactor<D> {
    /// The entry L_ij (zero above the diagonal).
    pub(crate) fn entry(&self, i: usize, j: usize) -> D {
        self.l[i * self.n + j]
    }

    /// Solves A X = B in place for the `n × k` right-hand side `b` (column-major).
    pub(crate) fn solve_in_place(&self, b: &mut [D]) {
        let n = self.n;
        for col in b.chunks_mut(n.max(1)) {
            let x = onsager_closures::cholesky_solve(&self.l, col).expect("the factor is n × n");
            col.copy_from_slice(&x);
        }
    }

    /// ln det A = 2 Σ ln L_ii.
    pub(crate) fn log_det(&self) -> D {
        onsager_closures::cholesky_log_det(&self.l, self.n).expect("the factor is n × n")
    }
}

/// C = A B for A `r × s` and B `s × c`, column-major.
pub(crate) fn matmul<D: Scalar>(a: &[D], b: &[D], r: usize, s: usize, c: usize) -> Vec<D> {
    let mut out = vec![D::from(0.0); r * c];
    for j in 0..c {
        for k in 0..s {
            let bkj = b[k + j * s];
            for i in 0..r {
                out[i + j * r] += a[i + k * r] * bkj;
            }
        }
    }
    out
}

/// Aᵀ of the `r × c` matrix A, column-major.
pub(crate) fn transpose<D: Scalar>(a: &[D], r: usize, c: usize) -> Vec<D> {
    let mut out = vec![D::from(0.0); r * c];
    for j in 0..c {
        for i in 0..r {
            out[j + i * c] = a[i + j * r];
        }
    }
    out
}

/// Replaces the square `n × n` matrix A by ½(A + Aᵀ).
pub(crate) fn symmetrize_in_place<D: Scalar>(a: &mut [D], n: usize) {
    for j in 0..n {
        for i in j + 1..n {
            let v = (a[i + j * n] + a[j + i * n]) * 0.5;
            a[i + j * n] = v;
            a[j + i * n] = v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn cholesky_solves_a_known_system() {
        // A = [[4, 2], [2, 3]]: L = [[2, 0], [1, √2]], det A = 8; A [1, 1]ᵀ = [6, 5]ᵀ.
        let a = [4.0, 2.0, 2.0, 3.0];
        let l = cholesky(&a, 2).unwrap();
        assert_relative_eq!(l.entry(0, 0), 2.0, epsilon = 1e-15);
        assert_relative_eq!(l.entry(1, 0), 1.0, epsilon = 1e-15);
        assert_relative_eq!(l.entry(1, 1), 2f64.sqrt(), epsilon = 1e-15);
        assert_eq!(l.entry(0, 1), 0.0);
        // Two right-hand sides, column-major: A [1, 1]ᵀ = [6, 5]ᵀ and A [1, 0]ᵀ = [4, 2]ᵀ.
        let mut b = [6.0, 5.0, 4.0, 2.0];
        l.solve_in_place(&mut b);
        for (got, want) in b.iter().zip([1.0, 1.0, 1.0, 0.0]) {
            assert_relative_eq!(*got, want, epsilon = 1e-14);
        }
        assert_relative_eq!(l.log_det(), 8f64.ln(), epsilon = 1e-14);
        // Not positive definite (eigenvalues 3, −1).
        assert!(cholesky(&[1.0, 2.0, 2.0, 1.0], 2).is_none());
    }

    #[test]
    fn matmul_and_transpose_agree_with_nalgebra() {
        // Independent reference: nalgebra's product of the same column-major matrices.
        let a = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]; // 2 × 3
        let b = [1.0, -1.0, 0.5, 2.0, 0.0, 1.0]; // 3 × 2
        let c = matmul(&a, &b, 2, 3, 2);
        let na = nalgebra::DMatrix::from_column_slice(2, 3, &a);
        let nb = nalgebra::DMatrix::from_column_slice(3, 2, &b);
        assert_eq!(c, (na.clone() * nb).as_slice().to_vec());
        assert_eq!(transpose(&a, 2, 3), na.transpose().as_slice().to_vec());
    }
}
