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
}
