//! Small dense products for the Riccati recursion.
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
