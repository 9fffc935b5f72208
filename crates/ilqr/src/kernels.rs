//! Small dense kernels for the Riccati recursion (and the RK4 step's
//! Jacobians).
//!
//! Everything here works on nalgebra's column-major storage directly
//! (`[[f64; R]; C]`, one array per column) with loop bounds known at compile
//! time, mostly as `y += a·x` over a column ("axpy"), the shape LLVM unrolls
//! and vectorises well for tiny matrices. nalgebra's generic products on
//! fixed sizes call out of line, and those calls would be most of the
//! backward pass.
//!
//! Three choices that matter for speed (BENCHMARKS.md, "Solver", times the
//! Riccati step with the first one's zeros known and tested):
//!
//! * Products with the dynamics Jacobians skip their zeros. `A = I + dt·∂f/∂x`
//!   and `B = dt·∂f/∂u` of mechanical models are mostly zeros (for the planar
//!   quadrotor 11 of 36 entries of `A` and 6 of 12 of `B` are non-zero), so
//!   `V_xx·A` and `Aᵀ·V_xx·A` shrink to a third. Where the model states its
//!   pattern ([`crate::Sparsity`]) the skipped entries are known when the
//!   solver is compiled for it, and nothing is tested at run time
//!   ([`Nonzeros::Known`]): a seed solve runs about a quarter fewer
//!   instructions than with the tests. Otherwise each entry is tested at
//!   run time ([`Nonzeros::Tested`]): dense models lose only the compare.
//!   Skipping `0·x` changes a result only when `x` is infinite or NaN, and
//!   the Riccati step rejects non-finite gains either way.
//! * Symmetric results (`Q_xx`, `V_xx`) are formed as lower triangles and
//!   mirrored: half the work, and exactly symmetric whatever the rounding.
//! * `Q_uu + μI` is factorised as `L D Lᵀ`, with one division per pivot and
//!   no square root: the factorisation sits on the backward pass's critical
//!   path (each knot needs the previous knot's `V_xx`), so its latency costs
//!   more than its flops.

// Index loops over const bounds are the readable form of these kernels (and
// the one LLVM unrolls); iterator chains would hide the subscripts.
#![allow(clippy::needless_range_loop)]

/// One column of an `N`-row matrix.
pub(crate) type Col<const N: usize> = [f64; N];

/// `y += a·x`.
#[inline(always)]
pub(crate) fn axpy<const N: usize>(y: &mut Col<N>, a: f64, x: &Col<N>) {
    for i in 0..N {
        y[i] += a * x[i];
    }
}

/// `xᵀ·y`.
#[inline(always)]
pub(crate) fn dot<const N: usize>(x: &Col<N>, y: &Col<N>) -> f64 {
    let mut acc = 0.0;
    for i in 0..N {
        acc += x[i] * y[i];
    }
    acc
}

/// Which entries of a matrix a product may skip as zeros.
#[derive(Clone, Copy)]
pub(crate) enum Nonzeros<'a, const R: usize, const C: usize> {
    /// None: every entry is used.
    All,
    /// The entries that are exactly zero, tested one by one at run time.
    Tested,
    /// Those outside this pattern (column-major, `[column][row]`), untested.
    /// Constant after inlining, the tests fold away and the loops over the
    /// pattern unroll to its entries.
    Known(&'a [[bool; R]; C]),
}

impl<const R: usize, const C: usize> Nonzeros<'_, R, C> {
    /// Whether entry `(i, j)` of `n` takes part in a product.
    #[inline(always)]
    fn used(self, n: &[Col<R>; C], i: usize, j: usize) -> bool {
        match self {
            Self::All => true,
            Self::Tested => n[j][i] != 0.0,
            Self::Known(pattern) => pattern[j][i],
        }
    }

    /// `n[:, j]ᵀ·y`, over the known pattern only: with `Tested` a test per
    /// entry would cost as much as the product it saves.
    #[inline(always)]
    pub(crate) fn dot_column(self, n: &[Col<R>; C], j: usize, y: &Col<R>) -> f64 {
        match self {
            Self::Known(pattern) => {
                let mut acc = 0.0;
                for i in 0..R {
                    if pattern[j][i] {
                        acc += n[j][i] * y[i];
                    }
                }
                acc
            }
            Self::All | Self::Tested => dot(&n[j], y),
        }
    }
}

/// `out += m·n` (`m` is `R×K`, `n` is `K×C`, both column-major), skipping
/// the entries of `n` that `nz` says are zero.
#[inline(always)]
pub(crate) fn add_mul<const R: usize, const K: usize, const C: usize>(
    out: &mut [Col<R>; C],
    m: &[Col<R>; K],
    n: &[Col<K>; C],
    nz: Nonzeros<'_, K, C>,
) {
    for j in 0..C {
        for k in 0..K {
            if nz.used(n, k, j) {
                axpy(&mut out[j], n[j][k], &m[k]);
            }
        }
    }
}

/// `m·n` (`m` is `R×K`, `n` is `K×C`), skipping the entries of `m` that
/// `nz` says are zero. Each entry sums over `k` in ascending order, as
/// nalgebra's products do, so that skipping exact zeros changes at most
/// the sign of a zero result.
#[inline(always)]
pub(crate) fn mul_sparse_left<const R: usize, const K: usize, const C: usize>(
    m: &[Col<R>; K],
    nz: Nonzeros<'_, R, K>,
    n: &[Col<K>; C],
) -> [Col<R>; C] {
    let mut out = [[0.0; R]; C];
    for j in 0..C {
        for k in 0..K {
            for i in 0..R {
                if nz.used(m, i, k) {
                    out[j][i] += m[k][i] * n[j][k];
                }
            }
        }
    }
    out
}

/// `m·n` for a square, sparse `n` with a non-zero diagonal (a Jacobian
/// `I + dt·∂f/∂x`): the diagonal term assigns each output column and the
/// other entries `nz` keeps are added, so the result never needs zeroing
/// first. (A zero on the diagonal costs a product, nothing more.)
#[inline(always)]
pub(crate) fn mul_square_sparse<const R: usize, const N: usize>(
    m: &[Col<R>; N],
    n: &[Col<N>; N],
    nz: Nonzeros<'_, N, N>,
) -> [Col<R>; N] {
    let mut out: [Col<R>; N] = std::array::from_fn(|j| m[j].map(|x| x * n[j][j]));
    for j in 0..N {
        for k in 0..N {
            if k != j && nz.used(n, k, j) {
                axpy(&mut out[j], n[j][k], &m[k]);
            }
        }
    }
    out
}

/// `mᵀ`.
#[inline(always)]
pub(crate) fn transpose<const R: usize, const C: usize>(m: &[Col<R>; C]) -> [Col<C>; R] {
    let mut t = [[0.0; C]; R];
    for (j, col) in m.iter().enumerate() {
        for (i, v) in col.iter().enumerate() {
            t[i][j] = *v;
        }
    }
    t
}

/// The lower triangle (row ≥ column) of `out += m·n`; the strict upper
/// triangle of `out` is left as it was. Half the work of [`add_mul`] for a
/// product known to be symmetric.
#[inline(always)]
pub(crate) fn add_mul_lower<const N: usize, const K: usize>(
    out: &mut [Col<N>; N],
    m: &[Col<N>; K],
    n: &[Col<K>; N],
    nz: Nonzeros<'_, K, N>,
) {
    for j in 0..N {
        for k in 0..K {
            if !nz.used(n, k, j) {
                continue;
            }
            let nkj = n[j][k];
            for i in j..N {
                out[j][i] += nkj * m[k][i];
            }
        }
    }
}

/// Copy the lower triangle of `m` into `out`, leaving `out`'s upper
/// triangle alone. Element by element on purpose: a whole-matrix
/// assignment compiles to a `memcpy` call, which would cost about 6% of a
/// seed solve at one call per knot of every backward pass.
#[inline(always)]
pub(crate) fn copy_lower<const N: usize>(out: &mut [Col<N>; N], m: &[Col<N>; N]) {
    for j in 0..N {
        for i in j..N {
            out[j][i] = m[j][i];
        }
    }
}

/// Copy the lower triangle of a square matrix onto its upper triangle.
#[inline(always)]
pub(crate) fn mirror_lower<const N: usize>(m: &mut [Col<N>; N]) {
    for j in 0..N {
        for i in j + 1..N {
            m[i][j] = m[j][i];
        }
    }
}

/// `L D Lᵀ` factorisation of a small symmetric matrix (`L` unit lower
/// triangular), or `None` when it is not positive definite. Returns `L` and
/// `1/D`. No square roots, and one division per pivot: the factorisation
/// sits on the backward pass's critical path, so its latency matters more
/// than its flops.
#[inline(always)]
pub(crate) fn ldlt<const N: usize>(m: &[Col<N>; N]) -> Option<([Col<N>; N], Col<N>)> {
    // l[j][i] = L[i, j] (column-major); the diagonal of L is 1, not stored.
    let mut l = [[0.0; N]; N];
    let mut d = [0.0; N];
    let mut d_inv = [0.0; N];
    for j in 0..N {
        let mut dj = m[j][j];
        for k in 0..j {
            dj -= l[k][j] * l[k][j] * d[k];
        }
        if dj.is_nan() || dj <= 0.0 {
            return None;
        }
        d[j] = dj;
        d_inv[j] = 1.0 / dj;
        for i in j + 1..N {
            let mut s = m[j][i];
            for k in 0..j {
                s -= l[k][i] * l[k][j] * d[k];
            }
            l[j][i] = s * d_inv[j];
        }
    }
    Some((l, d_inv))
}

/// Solve `L D Lᵀ x = b` for one vector.
#[inline(always)]
pub(crate) fn ldlt_solve_vec<const N: usize>(
    l: &[Col<N>; N],
    d_inv: &Col<N>,
    b: &Col<N>,
) -> Col<N> {
    let mut x = *b;
    for i in 0..N {
        for k in 0..i {
            x[i] -= l[k][i] * x[k];
        }
    }
    for i in 0..N {
        x[i] *= d_inv[i];
    }
    for i in (0..N).rev() {
        for k in i + 1..N {
            x[i] -= l[i][k] * x[k];
        }
    }
    x
}

/// Solve `X·(L D Lᵀ) = B` for `X` (`R×N`), column by column, so that every
/// operation is an axpy over a whole column of length `R`.
#[inline(always)]
pub(crate) fn ldlt_solve_right<const R: usize, const N: usize>(
    l: &[Col<N>; N],
    d_inv: &Col<N>,
    b: &[Col<R>; N],
) -> [Col<R>; N] {
    // Y Lᵀ = B: Y[:, j] = B[:, j] − Σ_{i<j} L[j, i]·Y[:, i].
    let mut y = *b;
    for j in 0..N {
        for i in 0..j {
            let yi = y[i];
            axpy(&mut y[j], -l[i][j], &yi);
        }
    }
    // Z D = Y.
    for (col, s) in y.iter_mut().zip(d_inv) {
        col.iter_mut().for_each(|v| *v *= s);
    }
    // X L = Z: X[:, j] = Z[:, j] − Σ_{i>j} L[i, j]·X[:, i].
    for j in (0..N).rev() {
        for i in j + 1..N {
            let xi = y[i];
            axpy(&mut y[j], -l[j][i], &xi);
        }
    }
    y
}
