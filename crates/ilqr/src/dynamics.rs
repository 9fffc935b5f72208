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
}
