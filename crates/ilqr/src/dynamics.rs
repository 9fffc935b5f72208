//! Dynamics traits and integrators.
//!
//! A model states its continuous-time vector field `ẋ = f(x, u)` and its
//! Jacobians ([`ContinuousDynamics`]). An integrator turns that into the
//! discrete map `x_{k+1} = F(x_k, u_k)` and its Jacobians `A = ∂F/∂x`,
//! `B = ∂F/∂u` ([`DiscreteDynamics`]), which is all the solver sees.
//!
//! Only explicit Euler (eq. 9) exists today. A Runge–Kutta integrator is a new
//! type implementing [`DiscreteDynamics`] by chaining the model's Jacobians
//! through its stages; neither the models nor the solver change.
//!
//! A model may also give the second derivatives of its vector field,
//! contracted with a covector ([`ContinuousDynamics::curvature`]): the
//! terms iLQR drops and DDP keeps ([`crate::Options::second_order`]). An
//! integrator must chain those through its stages too (Euler scales them by
//! `dt`); one that leaves [`DiscreteDynamics::curvature`] at its default
//! makes DDP run first-order, without a word.
//!
//! A model may also say which entries of its Jacobians can ever be non-zero
//! ([`ContinuousDynamics::JACOBIAN_SPARSITY`], a [`Sparsity`]). The
//! backward pass then skips the others without testing them: with the
//! planar quadrotor's pattern (11 of 36 entries of `A`, 6 of 12 of `B`) a
//! seed solve runs 27% fewer instructions than when the zeros are found at
//! run time (BENCHMARKS.md). A pattern is a promise: an entry
//! outside it that is not zero is treated as zero, and the solve is wrong
//! (a debug build asserts it). `None`, the default, makes no promise. The
//! pattern is an associated constant, so that the solver is compiled for
//! it; that makes both traits unusable as `dyn` objects, which the solver,
//! generic over its dynamics, never needed.

use nalgebra::{SMatrix, SVector};

/// A continuous-time model `ẋ = f(x, u)` with analytic Jacobians.
pub trait ContinuousDynamics<const NX: usize, const NU: usize>: Send + Sync {
    /// The time derivative `f(x, u)` of the state.
    fn derivative(&self, x: &SVector<f64, NX>, u: &SVector<f64, NU>) -> SVector<f64, NX>;

    /// The Jacobians `(∂f/∂x, ∂f/∂u)` at `(x, u)`.
    fn jacobians(
        &self,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
    ) -> (SMatrix<f64, NX, NX>, SMatrix<f64, NX, NU>);

    /// `Σ_i λ_i ∇²f_i` at `(x, u)`, the second derivatives of the vector
    /// field weighted by the covector `λ`; `None` (the default) where the
    /// model does not give them, and the solver then stays first-order.
    fn curvature(
        &self,
        _x: &SVector<f64, NX>,
        _u: &SVector<f64, NU>,
        _lambda: &SVector<f64, NX>,
    ) -> Option<Curvature<NX, NU>> {
        None
    }

    /// The entries of `(∂f/∂x, ∂f/∂u)` that can be non-zero at some
    /// `(x, u)` for any parameters; every other entry must be exactly zero
    /// everywhere. `None` (the default) where the model does not say: the
    /// solver then tests each entry at run time instead. A constant, so
    /// that the solver is compiled for the pattern.
    const JACOBIAN_SPARSITY: Option<Sparsity<NX, NU>> = None;
}

/// Which entries of a pair of Jacobians `(∂/∂x, ∂/∂u)` can be non-zero.
///
/// Stored column by column like nalgebra's matrices: `state[j][i]` stands
/// for entry `(i, j)`, row `i` and column `j`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Sparsity<const NX: usize, const NU: usize> {
    /// The state Jacobian's pattern, `NX×NX`.
    pub state: [[bool; NX]; NX],
    /// The control Jacobian's pattern, `NX×NU`.
    pub control: [[bool; NX]; NU],
}

impl<const NX: usize, const NU: usize> Sparsity<NX, NU> {
    /// No entry known to be zero.
    pub const DENSE: Self = Self {
        state: [[true; NX]; NX],
        control: [[true; NX]; NU],
    };

    /// The pattern with exactly the listed `(row, column)` entries of each
    /// Jacobian. An index out of range panics (a compile error in a
    /// constant).
    pub const fn from_entries(state: &[(usize, usize)], control: &[(usize, usize)]) -> Self {
        let mut out = Self {
            state: [[false; NX]; NX],
            control: [[false; NX]; NU],
        };
        // `while`, not `for`: this is a `const fn`.
        let mut e = 0;
        while e < state.len() {
            let (i, j) = state[e];
            out.state[j][i] = true;
            e += 1;
        }
        e = 0;
        while e < control.len() {
            let (i, j) = control[e];
            out.control[j][i] = true;
            e += 1;
        }
        out
    }

    /// The pattern with the state Jacobian's diagonal added: that of
    /// `(I + c·∂f/∂x, c·∂f/∂u)`, the explicit Euler step's.
    pub const fn with_identity(mut self) -> Self {
        let mut i = 0;
        while i < NX {
            self.state[i][i] = true;
            i += 1;
        }
        self
    }

    /// Whether every entry outside the pattern is exactly zero in `a`
    /// (`NX×NX`) and `b` (`NX×NU`).
    pub fn admits(&self, a: &SMatrix<f64, NX, NX>, b: &SMatrix<f64, NX, NU>) -> bool {
        let fits = |pattern: &[[bool; NX]], values: &[[f64; NX]]| {
            pattern
                .iter()
                .flatten()
                .zip(values.iter().flatten())
                .all(|(&used, &v)| used || v == 0.0)
        };
        fits(&self.state, &a.data.0) && fits(&self.control, &b.data.0)
    }
}

/// Second derivatives with respect to the state, control and both, of a
/// scalar function of `(x, u)`: here a vector field contracted with a
/// covector ([`ContinuousDynamics::curvature`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Curvature<const NX: usize, const NU: usize> {
    /// `∂²/∂x²`, symmetric.
    pub xx: SMatrix<f64, NX, NX>,
    /// `∂²/∂u∂x`.
    pub ux: SMatrix<f64, NU, NX>,
    /// `∂²/∂u²`, symmetric.
    pub uu: SMatrix<f64, NU, NU>,
}

/// A discrete-time map `x_{k+1} = F(x_k, u_k)`, the form iLQR works with
/// (eqs. 2 and 10–12).
pub trait DiscreteDynamics<const NX: usize, const NU: usize>: Send + Sync {
    /// One step of the map.
    fn step(&self, x: &SVector<f64, NX>, u: &SVector<f64, NU>) -> SVector<f64, NX>;

    /// The linearisation `(A, B)` of the step at `(x, u)` (eq. 11).
    fn linearize(
        &self,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
    ) -> (SMatrix<f64, NX, NX>, SMatrix<f64, NX, NU>);

    /// `Σ_i λ_i ∇²F_i` at `(x, u)`: the step's second derivatives weighted
    /// by `λ` (the value gradient at the next knot, in DDP). `None` (the
    /// default) where they are not available.
    fn curvature(
        &self,
        _x: &SVector<f64, NX>,
        _u: &SVector<f64, NU>,
        _lambda: &SVector<f64, NX>,
    ) -> Option<Curvature<NX, NU>> {
        None
    }

    /// The entries of `(A, B)` that can be non-zero at some `(x, u)`; see
    /// [`ContinuousDynamics::JACOBIAN_SPARSITY`]. `None` (the default)
    /// where not known.
    const SPARSITY: Option<Sparsity<NX, NU>> = None;
}

/// Explicit (forward) Euler: `x_{k+1} = x_k + dt·f(x_k, u_k)` (eq. 9).
///
/// First-order accurate; stable here only because `dt` is small against the
/// quadrotor's time constants. Its Jacobians are exact for the discrete map:
/// `A = I + dt·∂f/∂x`, `B = dt·∂f/∂u`.
#[derive(Debug, Clone, PartialEq)]
pub struct Euler<M> {
    /// The continuous-time model.
    pub model: M,
    /// Time step in seconds.
    pub dt: f64,
}

impl<M, const NX: usize, const NU: usize> DiscreteDynamics<NX, NU> for Euler<M>
where
    M: ContinuousDynamics<NX, NU>,
{
    #[inline]
    fn step(&self, x: &SVector<f64, NX>, u: &SVector<f64, NU>) -> SVector<f64, NX> {
        x + self.model.derivative(x, u) * self.dt
    }

    #[inline]
    fn linearize(
        &self,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
    ) -> (SMatrix<f64, NX, NX>, SMatrix<f64, NX, NU>) {
        let (f_x, f_u) = self.model.jacobians(x, u);
        (SMatrix::identity() + f_x * self.dt, f_u * self.dt)
    }

    /// `x` has no curvature, so the step's is `dt` times the model's.
    #[inline]
    fn curvature(
        &self,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        lambda: &SVector<f64, NX>,
    ) -> Option<Curvature<NX, NU>> {
        self.model.curvature(x, u, lambda).map(|c| Curvature {
            xx: c.xx * self.dt,
            ux: c.ux * self.dt,
            uu: c.uu * self.dt,
        })
    }

    /// The model's pattern with the diagonal of `I` added.
    const SPARSITY: Option<Sparsity<NX, NU>> = match M::JACOBIAN_SPARSITY {
        Some(pattern) => Some(pattern.with_identity()),
        None => None,
    };
}
