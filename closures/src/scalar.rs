//! The generic scalar and the small dense linear algebra written once over it.
//!
//! Matrices are dense, square and stored row-major in slices: entry $(i, j)$ of an $n\times n$
//! matrix `a` is `a[i * n + j]`.

use crate::error::{check_len, Error};

/// A real scalar: `f64` or a (nested) dual number of `num-dual` over `f64`.
///
/// The main crate `onsager` has an identical alias; both have blanket implementations, so every
/// type satisfying one satisfies the other. Constants are built with `D::from(2.0)`, the `f64`
/// value is `x.re()`, and `D * f64` works.
pub trait Scalar: num_dual::DualNum<Primitive = f64> + Copy {}

impl<T: num_dual::DualNum<Primitive = f64> + Copy> Scalar for T {}

/// $\sum_i a_i b_i$ over the common length of two `f64` slices: a plain loop below 8 terms (the
/// short rows of a narrow band), otherwise four independent accumulators over exact chunks so
/// that the loop vectorises (the order differs from a left-to-right sum only by round-off). The
/// one dot-product kernel of the workspace's hot loops (band LDLᵀ, closure drifts, exact grid).
#[inline]
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    if n < 8 {
        return a.iter().zip(b).fold(0.0, |s, (x, y)| s + x * y);
    }
    let (ac, bc) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ar, br) = (ac.remainder(), bc.remainder());
    let mut acc = [0.0f64; 4];
    for (x, y) in ac.zip(bc) {
        acc[0] += x[0] * y[0];
        acc[1] += x[1] * y[1];
        acc[2] += x[2] * y[2];
        acc[3] += x[3] * y[3];
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (x, y) in ar.iter().zip(br) {
        s += x * y;
    }
    s
}

/// Cholesky factor $L$ (lower triangular, row-major, zeros above the diagonal) of the symmetric
/// positive definite $n\times n$ matrix `a`, so that $a = L L^\top$.
///
/// Only the lower triangle of `a` is read. Derivatives propagate through the factorisation when
/// `D` is a dual number.
///
/// # Errors
/// [`Error::DimensionMismatch`] if `a.len() != n * n`, [`Error::NonFinite`] for a non-finite
/// entry, [`Error::NotPositiveDefinite`] if a pivot is not positive.
pub fn cholesky<D: Scalar>(a: &[D], n: usize) -> Result<Vec<D>, Error> {
    let mut l = vec![D::zero(); n * n];
    cholesky_into(a, n, &mut l)?;
    Ok(l)
}

/// [`cholesky`] into a caller's buffer `l` ($n\times n$, overwritten), without allocating: the
/// hot-loop form.
///
/// # Errors
/// As [`cholesky`]; [`Error::DimensionMismatch`] also if `l.len() != n * n`.
pub fn cholesky_into<D: Scalar>(a: &[D], n: usize, l: &mut [D]) -> Result<(), Error> {
    check_len("matrix", a, n * n)?;
    check_len("cholesky factor", l, n * n)?;
    if a.iter().any(|v| !v.re().is_finite()) {
        return Err(Error::NonFinite { what: "matrix" });
    }
    l.iter_mut().for_each(|v| *v = D::zero());
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= l[j * n + k] * l[j * n + k];
        }
        // The pivot must be positive, and not negligible relative to the diagonal entry.
        let scale = a[j * n + j].re().abs();
        if d.re().is_nan() || d.re() <= 1e-14 * scale || d.re() <= f64::MIN_POSITIVE {
            return Err(Error::NotPositiveDefinite { what: "matrix" });
        }
        let djj = d.sqrt();
        l[j * n + j] = djj;
        for i in (j + 1)..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= l[i * n + k] * l[j * n + k];
            }
            l[i * n + j] = s / djj;
        }
    }
    Ok(())
}

/// Solves $L L^\top x = b$ given the Cholesky factor `l` of [`cholesky`].
///
/// # Errors
/// [`Error::DimensionMismatch`] if `l` is not $n\times n$ with $n$ = `b.len()`.
pub fn cholesky_solve<D: Scalar>(l: &[D], b: &[D]) -> Result<Vec<D>, Error> {
    let mut y = b.to_vec();
    cholesky_solve_in_place(l, &mut y)?;
    Ok(y)
}

/// Solves $L L^\top x = b$ in place (`y` holds $b$ on entry and $x$ on return), without
/// allocating: the hot-loop form of [`cholesky_solve`].
///
/// # Errors
/// [`Error::DimensionMismatch`] if `l` is not $n\times n$ with $n$ = `y.len()`.
pub fn cholesky_solve_in_place<D: Scalar>(l: &[D], y: &mut [D]) -> Result<(), Error> {
    check_len("cholesky factor", l, y.len() * y.len())?;
    solve_in_place(l, y);
    Ok(())
}

/// Solves $L L^\top X = B$ in place for $m$ right-hand sides at once: `y` holds $B$ on entry
/// and $X$ on return, row-major $n\times m$ (row $i$ is `y[i * m..(i + 1) * m]`), so each
/// substitution step updates a whole contiguous row. For $m = 1$ it is
/// [`cholesky_solve_in_place`], and for $m > 1$ each column is exactly that solve (the same
/// operations in the same order).
///
/// # Errors
/// [`Error::DimensionMismatch`] if $m = 0$, `y.len()` is not a multiple of $m$, or `l` is not
/// $n\times n$ with $n$ = `y.len()` / $m$.
pub fn cholesky_solve_rows_in_place<D: Scalar>(l: &[D], y: &mut [D], m: usize) -> Result<(), Error> {
    if m == 0 || !y.len().is_multiple_of(m) {
        return Err(Error::DimensionMismatch {
            what: "right-hand sides (a multiple of m)",
            expected: m,
            got: y.len(),
        });
    }
    let n = y.len() / m;
    check_len("cholesky factor", l, n * n)?;
    if m == 1 {
        solve_in_place(l, y);
        return Ok(());
    }
    for i in 0..n {
        let (done, rest) = y.split_at_mut(i * m);
        let row = &mut rest[..m];
        for k in 0..i {
            let c = l[i * n + k];
            row.iter_mut().zip(&done[k * m..(k + 1) * m]).for_each(|(v, &u)| *v -= c * u);
        }
        let d = l[i * n + i];
        row.iter_mut().for_each(|v| *v /= d);
    }
    for i in (0..n).rev() {
        let (head, tail) = y.split_at_mut((i + 1) * m);
        let row = &mut head[i * m..];
        for k in (i + 1)..n {
            let c = l[k * n + i];
            row.iter_mut().zip(&tail[(k - i - 1) * m..(k - i) * m]).for_each(|(v, &u)| *v -= c * u);
        }
        let d = l[i * n + i];
        row.iter_mut().for_each(|v| *v /= d);
    }
    Ok(())
}

/// y ← (LLᵀ)⁻¹y for a factor of matching size (checked by the callers).
fn solve_in_place<D: Scalar>(l: &[D], y: &mut [D]) {
    let n = y.len();
    for i in 0..n {
        let mut s = y[i];
        for k in 0..i {
            s -= l[i * n + k] * y[k];
        }
        y[i] = s / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = y[i];
        for k in (i + 1)..n {
            s -= l[k * n + i] * y[k];
        }
        y[i] = s / l[i * n + i];
    }
}

/// Inverse $(L L^\top)^{-1}$ (row-major, symmetric) from the Cholesky factor `l` of an
/// $n\times n$ matrix.
///
/// # Errors
/// [`Error::DimensionMismatch`] if `l.len() != n * n`.
pub fn cholesky_inverse<D: Scalar>(l: &[D], n: usize) -> Result<Vec<D>, Error> {
    let mut inv = vec![D::zero(); n * n];
    cholesky_inverse_into(l, n, &mut inv)?;
    Ok(inv)
}

/// [`cholesky_inverse`] into a caller's buffer `inv` ($n\times n$, overwritten), without
/// allocating: the hot-loop form.
///
/// # Errors
/// As [`cholesky_inverse`]; [`Error::DimensionMismatch`] also if `inv.len() != n * n`.
pub fn cholesky_inverse_into<D: Scalar>(l: &[D], n: usize, inv: &mut [D]) -> Result<(), Error> {
    check_len("cholesky factor", l, n * n)?;
    check_len("inverse", inv, n * n)?;
    inv.iter_mut().for_each(|v| *v = D::zero());
    // Row j of the inverse is (LLᵀ)⁻¹e_j (the inverse is symmetric): solved in place.
    for (j, row) in inv.chunks_exact_mut(n.max(1)).enumerate().take(n) {
        row[j] = D::one();
        solve_in_place(l, row);
    }
    // Symmetrise against round-off.
    for i in 0..n {
        for j in (i + 1)..n {
            let s = (inv[i * n + j] + inv[j * n + i]) * 0.5;
            inv[i * n + j] = s;
            inv[j * n + i] = s;
        }
    }
    Ok(())
}

/// $\log\det(L L^\top) = 2\sum_i \log L_{ii}$ from the Cholesky factor `l` of an $n\times n$
/// matrix.
///
/// # Errors
/// [`Error::DimensionMismatch`] if `l.len() != n * n`.
pub fn cholesky_log_det<D: Scalar>(l: &[D], n: usize) -> Result<D, Error> {
    check_len("cholesky factor", l, n * n)?;
    let mut s = D::zero();
    for i in 0..n {
        s += l[i * n + i].ln();
    }
    Ok(s * 2.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn dot_equals_the_plain_sum_for_every_length() {
        // Lengths 0..=13 cover the empty slice, the remainder only, exact chunks and both; a
        // longer b is cut to a's length.
        for n in 0..=13usize {
            let a: Vec<f64> = (0..n).map(|i| 1.0 + 0.5 * i as f64).collect();
            let b: Vec<f64> = (0..n + 3).map(|i| (i as f64 * 0.7).sin()).collect();
            let plain: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
            assert_relative_eq!(dot(&a, &b), plain, epsilon = 1e-14, max_relative = 1e-14);
            assert_relative_eq!(dot(&b, &a), plain, epsilon = 1e-14, max_relative = 1e-14);
        }
    }

    #[test]
    fn cholesky_reconstructs_and_inverts() {
        // A = B Bᵀ + I with a fixed B is symmetric positive definite by construction.
        let b = [1.0, 2.0, 0.5, -0.3, 1.0, 0.7, 0.2, -1.0, 2.0];
        let n = 3;
        let mut a = vec![0.0; 9];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] =
                    (0..n).map(|k| b[i * n + k] * b[j * n + k]).sum::<f64>() + if i == j { 1.0 } else { 0.0 };
            }
        }
        let l = cholesky(&a, n).unwrap();
        let inv = cholesky_inverse(&l, n).unwrap();
        // Identity: A A⁻¹ = I.
        for i in 0..n {
            for j in 0..n {
                let p: f64 = (0..n).map(|k| a[i * n + k] * inv[k * n + j]).sum();
                let expected = if i == j { 1.0 } else { 0.0 };
                assert_relative_eq!(p, expected, epsilon = 1e-13);
            }
        }
        // Identity: log det A = log of the determinant by cofactor expansion.
        let det = a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6])
            + a[2] * (a[3] * a[7] - a[4] * a[6]);
        assert_relative_eq!(
            cholesky_log_det(&l, n).unwrap(),
            det.ln(),
            epsilon = 1e-13,
            max_relative = 1e-13
        );
        // Several right-hand sides at once: each column is its own solve, bit for bit.
        let mut rows = [1.0, 3.0, -2.0, 0.25, 0.5, -1.0];
        cholesky_solve_rows_in_place(&l, &mut rows, 2).unwrap();
        for (j, b) in [[1.0, -2.0, 0.5], [3.0, 0.25, -1.0]].iter().enumerate() {
            let x = cholesky_solve(&l, b).unwrap();
            for i in 0..n {
                assert_eq!(rows[i * 2 + j], x[i]);
            }
        }
        assert!(matches!(
            cholesky_solve_rows_in_place(&l, &mut [0.0; 5], 2),
            Err(Error::DimensionMismatch { .. })
        ));
        // Identity: A x = b for the solve, allocating and in place alike.
        let rhs = [1.0, -2.0, 0.5];
        let x = cholesky_solve(&l, &rhs).unwrap();
        let mut y = rhs;
        cholesky_solve_in_place(&l, &mut y).unwrap();
        for i in 0..n {
            let ax: f64 = (0..n).map(|k| a[i * n + k] * x[k]).sum();
            assert_relative_eq!(ax, rhs[i], epsilon = 1e-13);
            assert_eq!(x[i], y[i]);
        }
    }

    #[test]
    fn cholesky_rejects_bad_input() {
        assert!(matches!(cholesky(&[1.0, 2.0, 2.0, 1.0], 2), Err(Error::NotPositiveDefinite { .. })));
        assert!(matches!(cholesky(&[f64::NAN], 1), Err(Error::NonFinite { .. })));
        assert!(matches!(cholesky(&[1.0, 0.0, 0.0], 2), Err(Error::DimensionMismatch { .. })));
        assert!(matches!(
            cholesky_solve_in_place(&[1.0], &mut [1.0, 2.0]),
            Err(Error::DimensionMismatch { .. })
        ));
        // Degenerate size: the empty matrix has the empty factor.
        assert_eq!(cholesky::<f64>(&[], 0).unwrap(), Vec::<f64>::new());
        // The buffer forms check their output sizes.
        let mut l = [0.0; 3];
        assert!(matches!(
            cholesky_into(&[4.0, 0.0, 0.0, 1.0], 2, &mut l),
            Err(Error::DimensionMismatch { .. })
        ));
        assert!(matches!(
            cholesky_inverse_into(&[2.0, 0.0, 0.0, 1.0], 2, &mut l),
            Err(Error::DimensionMismatch { .. })
        ));
    }

    #[test]
    fn buffer_forms_overwrite_stale_buffers_and_match_the_allocating_forms() {
        let a = [4.0, 1.0, 1.0, 3.0];
        let (mut l, mut inv) = ([7.0; 4], [-3.0; 4]);
        cholesky_into(&a, 2, &mut l).unwrap();
        cholesky_inverse_into(&l, 2, &mut inv).unwrap();
        assert_eq!(l.to_vec(), cholesky(&a, 2).unwrap());
        assert_eq!(inv.to_vec(), cholesky_inverse(&cholesky(&a, 2).unwrap(), 2).unwrap());
        // Identity: the inverse of [[4, 1], [1, 3]] is [[3, −1], [−1, 4]]/11.
        for (v, e) in inv.iter().zip([3.0, -1.0, -1.0, 4.0]) {
            assert_relative_eq!(*v, e / 11.0, epsilon = 1e-15);
        }
    }
}
