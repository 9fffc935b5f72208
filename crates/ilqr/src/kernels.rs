//! Small dense kernels for the Riccati recursion.
//!
//! nalgebra's generic `*` and `tr_mul` on fixed sizes are not fully unrolled
//! and call out of line; these plain loops over const bounds are, and LLVM
//! vectorises the contiguous (column-major) inner loop. Measured on the seed
//! problem they make the backward pass several times faster (BENCHMARKS.md).

use nalgebra::SMatrix;

/// `a · b`.
#[inline(always)]
pub(crate) fn mul<const R: usize, const K: usize, const C: usize>(
    a: &SMatrix<f64, R, K>,
    b: &SMatrix<f64, K, C>,
) -> SMatrix<f64, R, C> {
    let mut out = SMatrix::<f64, R, C>::zeros();
    for j in 0..C {
        for k in 0..K {
            let bkj = b[(k, j)];
            for i in 0..R {
                out[(i, j)] += a[(i, k)] * bkj;
            }
        }
    }
    out
}

/// `aᵀ · b`.
#[inline(always)]
pub(crate) fn tr_mul<const R: usize, const K: usize, const C: usize>(
    a: &SMatrix<f64, K, R>,
    b: &SMatrix<f64, K, C>,
) -> SMatrix<f64, R, C> {
    let mut out = SMatrix::<f64, R, C>::zeros();
    for j in 0..C {
        for i in 0..R {
            let mut acc = 0.0;
            for k in 0..K {
                acc += a[(k, i)] * b[(k, j)];
            }
            out[(i, j)] = acc;
        }
    }
    out
}

/// Cholesky factor `L` (lower, `m = L Lᵀ`) of a small symmetric matrix, or
/// `None` when it is not positive definite. Plain loops: for the 2×2 `Q_uu`
/// this is a handful of flops, where nalgebra's generic decomposition
/// carries bookkeeping for any size.
#[inline(always)]
pub(crate) fn cholesky<const N: usize>(m: &SMatrix<f64, N, N>) -> Option<SMatrix<f64, N, N>> {
    let mut l = SMatrix::<f64, N, N>::zeros();
    for j in 0..N {
        let mut d = m[(j, j)];
        for k in 0..j {
            d -= l[(j, k)] * l[(j, k)];
        }
        if d.is_nan() || d <= 0.0 {
            return None;
        }
        let d = d.sqrt();
        l[(j, j)] = d;
        for i in j + 1..N {
            let mut s = m[(i, j)];
            for k in 0..j {
                s -= l[(i, k)] * l[(j, k)];
            }
            l[(i, j)] = s / d;
        }
    }
    Some(l)
}

/// Solve `L Lᵀ X = B` by forward and back substitution.
#[inline(always)]
pub(crate) fn cholesky_solve<const N: usize, const C: usize>(
    l: &SMatrix<f64, N, N>,
    b: &SMatrix<f64, N, C>,
) -> SMatrix<f64, N, C> {
    let mut x = *b;
    for c in 0..C {
        for i in 0..N {
            let mut s = x[(i, c)];
            for k in 0..i {
                s -= l[(i, k)] * x[(k, c)];
            }
            x[(i, c)] = s / l[(i, i)];
        }
        for i in (0..N).rev() {
            let mut s = x[(i, c)];
            for k in i + 1..N {
                s -= l[(k, i)] * x[(k, c)];
            }
            x[(i, c)] = s / l[(i, i)];
        }
    }
    x
}
