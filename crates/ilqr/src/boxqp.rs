//! A box-constrained quadratic program: minimise `½ uᵀH u + gᵀu` subject to
//! `lower ≤ u ≤ upper` componentwise, the subproblem a control-limited
//! backward pass (box-DDP) solves at each knot (Tassa, Mansard and Todorov
//! 2014, "Control-limited differential dynamic programming", Algorithm 3).
//!
//! # Mechanism
//!
//! Projected Newton, as in Tassa's `boxQP.m` and Crocoddyl's `BoxQP`. Each
//! iteration, at the current `u` (always inside the box):
//!
//! 1. the gradient `∇ = H u + g` splits the components into *clamped* ones,
//!    at a bound with the gradient pushing out of the box (`u_i = lower_i`
//!    and `∇_i > 0`, or `u_i = upper_i` and `∇_i < 0`), and *free* ones;
//! 2. `H` restricted to the free set, `H_ff`, is factorised by Cholesky
//!    whenever the free set changed. The factor is of the `M×M` matrix
//!    that is `H_ff` on the free rows and columns and the identity on the
//!    clamped ones, so its storage is fixed-size and nothing is allocated;
//! 3. the solve stops with [`BoxQpStatus::Converged`] when the free
//!    gradient's 2-norm is at most [`BoxQpOptions::gradient_tolerance`] (or
//!    every component is clamped);
//! 4. the Newton step moves the free components to the minimiser of the
//!    objective with the clamped ones held, `u_f ← −H_ff⁻¹ (g + H u_c)_f`,
//!    and leaves the clamped ones where they are;
//! 5. an Armijo line search backtracks along the projected path
//!    `clamp(u + α s)`: the step is taken at the first α (1, then
//!    `step_decrease` times less each time) whose decrease of the
//!    objective is at least `armijo · α · |sᵀ∇|`.
//!
//! Once the free set is the optimum's, the Newton step is exact and the
//! next iteration converges, so a solve warm-started at its own solution
//! takes no step at all.
//!
//! # Limits
//!
//! * `H` must be positive definite on every free set the iteration visits:
//!   a Cholesky pivot that is not positive ends the solve with
//!   [`BoxQpStatus::NotPositiveDefinite`] and the iterate reached so far.
//!   A singular `H` (positive semi-definite) fails there too. Regularise
//!   `H + μI` as the iLQR backward pass does.
//! * Only `H`'s symmetric part `½(H + Hᵀ)` is used: it is all the objective
//!   sees.
//! * The gradient tolerance is absolute. Where `H` or `u` is so large that
//!   the gradient's round-off exceeds it, the iteration ends
//!   [`BoxQpStatus::SmallStep`] instead, at the point it can no longer
//!   move.
//! * Malformed input (a NaN or infinity in `H`, `g` or the warm start, a
//!   NaN bound, `lower_i > upper_i`, `lower_i = +∞` or `upper_i = −∞`, or
//!   options with which the line search might not end) is a
//!   [`BoxQpError`], found before any iteration; nothing panics.

use nalgebra::{SMatrix, SVector};

/// Settings of [`solve_box_qp`]. The defaults follow Tassa's `boxQP.m`
/// except where noted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxQpOptions {
    /// Upper bound on Newton steps. With 0 the warm start is only projected
    /// into the box and checked.
    pub max_iterations: usize,
    /// Convergence threshold on the 2-norm of the gradient's free
    /// components (absolute). Default 1e-8.
    pub gradient_tolerance: f64,
    /// The solve ends [`BoxQpStatus::SmallStep`] after a step that moved
    /// `u` by at most `step_tolerance · (1 + ‖u‖∞)` in the ∞-norm, unless
    /// the point it reached has converged. Default 1e-14 (`boxQP.m` stops
    /// on a relative improvement of the objective below 1e-8 instead,
    /// which allows an error in `u` of order 1e-4 where the objective is of
    /// order 1).
    pub step_tolerance: f64,
    /// Sufficient-decrease fraction of the line search (Armijo). Default 0.1.
    pub armijo: f64,
    /// Factor the line search shrinks α by, in (0, 1) (outside it the line
    /// search might not end: [`BoxQpError::InvalidOptions`]). Default 0.6.
    pub step_decrease: f64,
    /// Smallest α the line search tries, > 0; below it the solve ends
    /// [`BoxQpStatus::SmallStep`]. Default 1e-22.
    pub min_step: f64,
}

impl Default for BoxQpOptions {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            gradient_tolerance: 1e-8,
            step_tolerance: 1e-14,
            armijo: 0.1,
            step_decrease: 0.6,
            min_step: 1e-22,
        }
    }
}

/// How a box-QP solve ended. Every status comes with the best `u` found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BoxQpStatus {
    /// The free gradient's norm is at most the tolerance, or every
    /// component is clamped: `u` satisfies the KKT conditions.
    Converged,
    /// `max_iterations` Newton steps were taken first.
    MaxIterations,
    /// No progress is possible at the working precision: the last step
    /// moved `u` by less than `step_tolerance`, the Newton step is not a
    /// descent direction, or the line search passed `min_step`.
    SmallStep,
    /// `H` on the free set is not positive definite (a Cholesky pivot
    /// ≤ 0, or a non-finite Newton step). `u` is the last iterate; there is
    /// no factor (see [`BoxQpSolution::feedback_gain`]).
    NotPositiveDefinite,
}

/// Input [`solve_box_qp`] cannot work with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BoxQpError {
    /// An entry of `H` is NaN or infinite.
    NonFiniteHessian,
    /// An entry of `g` is NaN or infinite.
    NonFiniteGradient,
    /// An entry of the warm start is NaN or infinite, or the objective or
    /// its gradient overflows there.
    NonFiniteStart,
    /// The bounds of component `index` admit no finite value: one is NaN,
    /// `lower > upper`, `lower = +∞` or `upper = −∞`.
    InvalidBounds {
        /// The component.
        index: usize,
    },
    /// [`BoxQpOptions::step_decrease`] is not in (0, 1) or
    /// [`BoxQpOptions::min_step`] is not positive.
    InvalidOptions,
}

impl std::fmt::Display for BoxQpError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::NonFiniteHessian => write!(f, "the Hessian has a NaN or infinite entry"),
            Self::NonFiniteGradient => write!(f, "the gradient has a NaN or infinite entry"),
            Self::NonFiniteStart => write!(
                f,
                "the warm start has a NaN or infinite entry, or the objective overflows there"
            ),
            Self::InvalidBounds { index } => write!(
                f,
                "the bounds of component {index} admit no finite value (NaN, lower > upper, \
                 lower = +inf or upper = -inf)"
            ),
            Self::InvalidOptions => {
                write!(f, "step_decrease must be in (0, 1) and min_step positive")
            }
        }
    }
}

impl std::error::Error for BoxQpError {}

/// The result of [`solve_box_qp`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxQpSolution<const M: usize> {
    /// The minimiser found (inside the box).
    pub u: SVector<f64, M>,
    /// Which components are free at `u`; the others are clamped (at a bound
    /// with the gradient pushing out of the box).
    pub free: [bool; M],
    /// The lower-triangular Cholesky factor `L` of `H` on the free set:
    /// `L Lᵀ` is `H_ff` on the free rows and columns and the identity on
    /// the clamped ones (zero between them). Meaningless where `status` is
    /// [`BoxQpStatus::NotPositiveDefinite`].
    pub factor: SMatrix<f64, M, M>,
    /// The objective's gradient `H u + g` at `u`.
    pub gradient: SVector<f64, M>,
    /// The objective `½ uᵀH u + gᵀu` at `u`.
    pub value: f64,
    /// Newton steps taken.
    pub iterations: usize,
    /// How the solve ended.
    pub status: BoxQpStatus,
}

impl<const M: usize> BoxQpSolution<M> {
    /// The feedback gain of a control-limited backward pass,
    /// `K = −H_ff⁻¹ Q_ux` on the free rows and zero on the clamped ones
    /// (a clamped control does not respond to the state to first order).
    /// `None` where there is no factor
    /// ([`BoxQpStatus::NotPositiveDefinite`]).
    #[allow(non_snake_case)]
    pub fn feedback_gain<const N: usize>(
        &self,
        Q_ux: &SMatrix<f64, M, N>,
    ) -> Option<SMatrix<f64, M, N>> {
        if self.status == BoxQpStatus::NotPositiveDefinite {
            return None;
        }
        // The factor is of a matrix block-diagonal between the free and the
        // clamped components, identity on the latter: zero right-hand rows
        // there give zero rows of the solution.
        let mut k = *Q_ux;
        cholesky_solve_free(&self.factor, &self.free, &mut k);
        k.neg_mut();
        Some(k)
    }
}

/// Minimises `½ uᵀH u + gᵀu` subject to `lower ≤ u ≤ upper` by projected
/// Newton (see the [module documentation](self)), from `u0` projected into
/// the box. Bounds may be infinite. Allocates nothing.
pub fn solve_box_qp<const M: usize>(
    h: &SMatrix<f64, M, M>,
    g: &SVector<f64, M>,
    lower: &SVector<f64, M>,
    upper: &SVector<f64, M>,
    u0: &SVector<f64, M>,
    options: &BoxQpOptions,
) -> Result<BoxQpSolution<M>, BoxQpError> {
    // Written so that NaN fails: the line search ends only with these.
    let line_search_ends =
        options.step_decrease > 0.0 && options.step_decrease < 1.0 && options.min_step > 0.0;
    if !line_search_ends {
        return Err(BoxQpError::InvalidOptions);
    }
    if !h.iter().all(|x| x.is_finite()) {
        return Err(BoxQpError::NonFiniteHessian);
    }
    if !g.iter().all(|x| x.is_finite()) {
        return Err(BoxQpError::NonFiniteGradient);
    }
    for i in 0..M {
        let (lo, hi) = (lower[i], upper[i]);
        // Also false for a NaN bound.
        let valid = lo <= hi && lo < f64::INFINITY && hi > f64::NEG_INFINITY;
        if !valid {
            return Err(BoxQpError::InvalidBounds { index: i });
        }
    }
    if !u0.iter().all(|x| x.is_finite()) {
        return Err(BoxQpError::NonFiniteStart);
    }

    let h = (h + h.transpose()) * 0.5;
    let objective = |u: &SVector<f64, M>| g.dot(u) + 0.5 * u.dot(&(h * u));
    // `f64::clamp` without its check that the bounds are ordered (done
    // above): the check's panic kept the projection out of line.
    let project = |u: &mut SVector<f64, M>| {
        for i in 0..M {
            if u[i] < lower[i] {
                u[i] = lower[i];
            } else if u[i] > upper[i] {
                u[i] = upper[i];
            }
        }
    };

    let mut u = *u0;
    project(&mut u);
    let mut value = objective(&u);
    let mut gradient = h * u + g;
    if !value.is_finite() || !gradient.iter().all(|x| x.is_finite()) {
        return Err(BoxQpError::NonFiniteStart);
    }

    let mut free = [true; M];
    let mut factor = SMatrix::<f64, M, M>::zeros();
    let mut factored = false;
    let mut stalled = false;
    let mut iterations = 0;
    let status = loop {
        // 1. The clamped set at u.
        let mut changed = !factored;
        for i in 0..M {
            let clamped =
                (u[i] == lower[i] && gradient[i] > 0.0) || (u[i] == upper[i] && gradient[i] < 0.0);
            changed |= free[i] == clamped;
            free[i] = !clamped;
        }
        // 2. Factorise H on the free set where the set changed.
        if changed {
            factored = cholesky_masked(&h, &free, &mut factor);
            if !factored {
                break BoxQpStatus::NotPositiveDefinite;
            }
        }
        // 3. Termination.
        let free_norm2: f64 = (0..M)
            .filter(|&i| free[i])
            .map(|i| gradient[i] * gradient[i])
            .sum();
        if free_norm2.sqrt() <= options.gradient_tolerance {
            break BoxQpStatus::Converged;
        }
        if stalled {
            break BoxQpStatus::SmallStep;
        }
        if iterations >= options.max_iterations {
            break BoxQpStatus::MaxIterations;
        }
        // 4. Newton step on the free set: the target is
        // −H_ff⁻¹ (g + H u_c)_f, with u_c = u on the clamped components and
        // zero on the free ones.
        let mut u_clamped = u;
        for i in 0..M {
            if free[i] {
                u_clamped[i] = 0.0;
            }
        }
        let mut target = h * u_clamped + g;
        cholesky_solve_free(&factor, &free, &mut target);
        let mut search = SVector::<f64, M>::zeros();
        for i in 0..M {
            if free[i] {
                search[i] = -target[i] - u[i];
            }
        }
        if !search.iter().all(|x| x.is_finite()) {
            break BoxQpStatus::NotPositiveDefinite;
        }
        let slope = search.dot(&gradient);
        if slope.is_nan() || slope >= 0.0 {
            break BoxQpStatus::SmallStep;
        }
        // 5. Armijo line search along the projected path. A NaN ratio
        // (overflow) is a rejection.
        let mut alpha = 1.0;
        let accepted = loop {
            let mut candidate = u + search * alpha;
            project(&mut candidate);
            let candidate_value = objective(&candidate);
            if (candidate_value - value) / (alpha * slope) >= options.armijo {
                break Some((candidate, candidate_value));
            }
            alpha *= options.step_decrease;
            if alpha < options.min_step {
                break None;
            }
        };
        let Some((next, next_value)) = accepted else {
            break BoxQpStatus::SmallStep;
        };
        let moved = (next - u).amax();
        stalled = moved <= options.step_tolerance * (1.0 + next.amax());
        u = next;
        value = next_value;
        gradient = h * u + g;
        iterations += 1;
    };

    Ok(BoxQpSolution {
        u,
        free,
        factor,
        gradient,
        value,
        iterations,
        status,
    })
}

/// Cholesky factor `L` (lower triangle, zero above) of the matrix that is
/// `h` on the rows and columns where `free` is set and the identity
/// elsewhere. False where a pivot is not positive.
fn cholesky_masked<const M: usize>(
    h: &SMatrix<f64, M, M>,
    free: &[bool; M],
    l: &mut SMatrix<f64, M, M>,
) -> bool {
    l.fill(0.0);
    for j in 0..M {
        if !free[j] {
            l[(j, j)] = 1.0;
            continue;
        }
        let mut pivot = h[(j, j)];
        for k in 0..j {
            pivot -= l[(j, k)] * l[(j, k)];
        }
        if pivot.is_nan() || pivot <= 0.0 {
            return false;
        }
        let d = pivot.sqrt();
        l[(j, j)] = d;
        for i in j + 1..M {
            if !free[i] {
                continue;
            }
            let mut s = h[(i, j)];
            for k in 0..j {
                s -= l[(i, k)] * l[(j, k)];
            }
            l[(i, j)] = s / d;
        }
    }
    true
}

/// Solves `L Lᵀ X = B` in place of `B`, column by column, for the factor
/// [`cholesky_masked`] makes, with `B`'s clamped rows (where `free` is not
/// set) taken as zero. The factor is the identity on those rows and
/// columns and zero between them and the free ones, so the solution is
/// zero there and the free rows see only each other: the clamped rows are
/// set to zero and skipped, with results equal to the full solve's
/// (`0·x` adds nothing to a sum). Half the divisions with one of two
/// controls clamped.
fn cholesky_solve_free<const M: usize, const N: usize>(
    l: &SMatrix<f64, M, M>,
    free: &[bool; M],
    b: &mut SMatrix<f64, M, N>,
) {
    for c in 0..N {
        for i in 0..M {
            if !free[i] {
                b[(i, c)] = 0.0;
            }
        }
        // L y = b.
        for i in 0..M {
            if !free[i] {
                continue;
            }
            let mut s = b[(i, c)];
            for k in 0..i {
                if free[k] {
                    s -= l[(i, k)] * b[(k, c)];
                }
            }
            b[(i, c)] = s / l[(i, i)];
        }
        // Lᵀ x = y.
        for i in (0..M).rev() {
            if !free[i] {
                continue;
            }
            let mut s = b[(i, c)];
            for k in i + 1..M {
                if free[k] {
                    s -= l[(k, i)] * b[(k, c)];
                }
            }
            b[(i, c)] = s / l[(i, i)];
        }
    }
}
