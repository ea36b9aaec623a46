//! Small dense linear algebra generic over the scalar (`f64` or a dual number), for the
//! filters' moment equations and measurement updates, so that the prediction-error likelihood
//! can be differentiated through them (the PEM, [`super::pem`]).
//!
//! Matrices are `n × n` (or `n × k`) slices stored column-major, as the rest of the crate's
//! model layer ([`crate::model::Sde::diffusion`]). The dimensions are those of a state vector
//! (a handful), so plain loops are the right tool; the `f64`-only smoother uses `nalgebra`.

use crate::model::Scalar;

/// The lower Cholesky factor L of the symmetric `n × n` matrix `a` (A = L Lᵀ; only the lower
/// triangle of `a` is read), column-major with zeros above the diagonal. `None` when A is not
/// numerically positive definite (a pivot ≤ 0 or not finite, judged on the real parts).
pub(crate) fn cholesky<D: Scalar>(a: &[D], n: usize) -> Option<Vec<D>> {
    let mut l = vec![D::from(0.0); n * n];
    for j in 0..n {
        let mut d = a[j + j * n];
        for k in 0..j {
            d -= l[j + k * n] * l[j + k * n];
        }
        if !(d.re() > 0.0 && d.re().is_finite()) {
            return None;
        }
        let djj = d.sqrt();
        l[j + j * n] = djj;
        for i in j + 1..n {
            let mut s = a[i + j * n];
            for k in 0..j {
                s -= l[i + k * n] * l[j + k * n];
            }
            l[i + j * n] = s / djj;
        }
    }
    Some(l)
}

/// Solves A X = B in place for the `n × k` right-hand side `b` (column-major), given the
/// Cholesky factor `l` of A from [`cholesky`].
pub(crate) fn cholesky_solve_in_place<D: Scalar>(l: &[D], n: usize, b: &mut [D]) {
    let k = b.len() / n.max(1);
    for c in 0..k {
        let col = &mut b[c * n..(c + 1) * n];
        // L y = b
        for i in 0..n {
            let mut s = col[i];
            for j in 0..i {
                s -= l[i + j * n] * col[j];
            }
            col[i] = s / l[i + i * n];
        }
        // Lᵀ x = y
        for i in (0..n).rev() {
            let mut s = col[i];
            for j in i + 1..n {
                s -= l[j + i * n] * col[j];
            }
            col[i] = s / l[i + i * n];
        }
    }
}

/// ln det A = 2 Σ ln L_ii from the Cholesky factor of A.
pub(crate) fn cholesky_log_det<D: Scalar>(l: &[D], n: usize) -> D {
    (0..n).map(|i| l[i + i * n].ln()).sum::<D>() * 2.0
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
        assert_relative_eq!(l[0], 2.0, epsilon = 1e-15);
        assert_relative_eq!(l[1], 1.0, epsilon = 1e-15);
        assert_relative_eq!(l[3], 2f64.sqrt(), epsilon = 1e-15);
        assert_eq!(l[2], 0.0);
        let mut b = [6.0, 5.0];
        cholesky_solve_in_place(&l, 2, &mut b);
        assert_relative_eq!(b[0], 1.0, epsilon = 1e-14);
        assert_relative_eq!(b[1], 1.0, epsilon = 1e-14);
        assert_relative_eq!(cholesky_log_det(&l, 2), 8f64.ln(), epsilon = 1e-14);
        // Not positive definite (eigenvalues 3, −1), and the empty matrix.
        assert!(cholesky(&[1.0, 2.0, 2.0, 1.0], 2).is_none());
        assert!(cholesky::<f64>(&[], 0).unwrap().is_empty());
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
