//! Dynamics traits and integrators.
//!
//! A model states its continuous-time vector field `ẋ = f(x, u)` and its
//! Jacobians ([`ContinuousDynamics`]). An integrator turns that into the
//! discrete map `x_{k+1} = F(x_k, u_k)` and its Jacobians `A = ∂F/∂x`,
//! `B = ∂F/∂u` ([`DiscreteDynamics`]), which is all the solver sees. Two
//! integrators exist: explicit [`Euler`] (eq. 9 of the seed paper) and the
//! classical fourth-order Runge–Kutta [`Rk4`], whose Jacobians chain the
//! model's through its four stages. Neither the models nor the solver know
//! which is in use.
//!
//! A model may also give the second derivatives of its vector field,
//! contracted with a covector ([`ContinuousDynamics::curvature`]): the
//! terms iLQR drops and DDP keeps ([`crate::Options::second_order`]). An
//! integrator chains those through its stages too (Euler scales them by
//! `dt`; RK4 carries the covector back through the stages as an adjoint).
//! One that leaves [`DiscreteDynamics::curvature`] at its default makes DDP
//! run first-order.
//!
//! A model may also say which entries of its Jacobians can ever be non-zero
//! ([`ContinuousDynamics::JACOBIAN_SPARSITY`], a [`Sparsity`]). The
//! backward pass then skips the others without testing them: with the
//! planar quadrotor's pattern (11 of 36 entries of `A`, 6 of 12 of `B`
//! under Euler) a seed solve runs about a quarter fewer instructions than
//! when the zeros are found at run time. A pattern is a promise: an entry
//! outside it that is not zero is treated as zero, and the solve is wrong
//! (a debug build asserts it). `None`, the default, makes no promise. The
//! pattern is an associated constant, so that the solver is compiled for
//! it; that makes both traits unusable as `dyn` objects, which the solver,
//! generic over its dynamics, does not need.

use nalgebra::{SMatrix, SVector};

use crate::kernels::{Nonzeros, mul_sparse_left};

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

    /// The pattern of the classical RK4 step's Jacobians for a model with
    /// this pattern: `A = I + Σ c_k·P^k` up to `P⁴` and `B = Σ c_k·P^k·G`
    /// up to `P³·G`, where `P` and `G` are the model's state and control
    /// patterns (see [`Rk4`]). A superset of the entries that can be
    /// non-zero, which is all a pattern must be.
    pub const fn rk4(self) -> Self {
        let mut out = Self {
            state: [[false; NX]; NX],
            control: self.control,
        };
        // Powers of P applied to I (state) and to G (control).
        let mut power = [[false; NX]; NX];
        let mut i = 0;
        while i < NX {
            power[i][i] = true;
            out.state[i][i] = true;
            i += 1;
        }
        let mut through_g = self.control;
        let mut stage = 0;
        while stage < 4 {
            power = bool_product(&self.state, &power);
            or_into(&mut out.state, &power);
            if stage < 3 {
                through_g = bool_product(&self.state, &through_g);
                or_into(&mut out.control, &through_g);
            }
            stage += 1;
        }
        out
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

/// The pattern of `p·q`, column-major like [`Sparsity`]: entry `(i, j)` is
/// set where some `p(i, k)` and `q(k, j)` both are.
const fn bool_product<const R: usize, const C: usize>(
    p: &[[bool; R]; R],
    q: &[[bool; R]; C],
) -> [[bool; R]; C] {
    let mut out = [[false; R]; C];
    let mut j = 0;
    while j < C {
        let mut k = 0;
        while k < R {
            if q[j][k] {
                let mut i = 0;
                while i < R {
                    if p[k][i] {
                        out[j][i] = true;
                    }
                    i += 1;
                }
            }
            k += 1;
        }
        j += 1;
    }
    out
}

/// `into |= from`, entry by entry.
const fn or_into<const R: usize, const C: usize>(into: &mut [[bool; R]; C], from: &[[bool; R]; C]) {
    let mut j = 0;
    while j < C {
        let mut i = 0;
        while i < R {
            if from[j][i] {
                into[j][i] = true;
            }
            i += 1;
        }
        j += 1;
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

/// The classical fourth-order Runge–Kutta step:
///
/// ```text
/// k1 = f(x, u)                k2 = f(x + h/2·k1, u)
/// k3 = f(x + h/2·k2, u)       k4 = f(x + h·k3, u)
/// F(x, u) = x + h/6·(k1 + 2·k2 + 2·k3 + k4)
/// ```
///
/// with the control held constant over the step (zero-order hold) and
/// `h = dt`. Fourth-order accurate, at four evaluations of the model and
/// its Jacobians per step against Euler's one.
///
/// Its Jacobians are exact for the discrete map, by the chain rule
/// through the stages: with `y_i` the point stage `i` evaluates `f` at and
/// `(A_i, B_i)` the model's Jacobians there,
/// `∂k_i/∂x = A_i·∂y_i/∂x` and `∂k_i/∂u = A_i·∂y_i/∂u + B_i`, where
/// `∂y_i/∂· = a_i·h·∂k_{i−1}/∂·` (plus `I` for `x`), `a = (½, ½, 1)`.
/// Its curvature (for DDP) is exact too: the covector is carried back
/// through the stages as an adjoint, and each stage's model curvature is
/// mapped through that stage's `∂y_i/∂(x, u)`.
#[derive(Debug, Clone, PartialEq)]
pub struct Rk4<M> {
    /// The continuous-time model.
    pub model: M,
    /// Time step in seconds.
    pub dt: f64,
}

/// One stage of [`Rk4`]: where it evaluates the model, the model's
/// Jacobians there, and the derivatives of that point and of the stage's
/// slope with respect to `(x, u)`.
#[derive(Clone, Copy)]
struct Stage<const NX: usize, const NU: usize> {
    y: SVector<f64, NX>,
    a: SMatrix<f64, NX, NX>,
    y_x: SMatrix<f64, NX, NX>,
    y_u: SMatrix<f64, NX, NU>,
    k: SVector<f64, NX>,
    k_x: SMatrix<f64, NX, NX>,
    k_u: SMatrix<f64, NX, NU>,
}

/// How far along the previous stage's slope each stage evaluates `f`,
/// in steps: `y_i = x + OFFSET[i]·h·k_{i−1}`.
const RK4_OFFSET: [f64; 4] = [0.0, 0.5, 0.5, 1.0];
/// Each stage's weight in the step, in steps: `F = x + Σ WEIGHT[i]·h·k_i`.
const RK4_WEIGHT: [f64; 4] = [1.0 / 6.0, 2.0 / 6.0, 2.0 / 6.0, 1.0 / 6.0];

impl<M> Rk4<M> {
    /// The four stages at `(x, u)`, with their derivatives.
    fn stages<const NX: usize, const NU: usize>(
        &self,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
    ) -> [Stage<NX, NU>; 4]
    where
        M: ContinuousDynamics<NX, NU>,
    {
        let h = self.dt;
        let mut stages = [Stage {
            y: *x,
            a: SMatrix::zeros(),
            y_x: SMatrix::identity(),
            y_u: SMatrix::zeros(),
            k: SVector::zeros(),
            k_x: SMatrix::zeros(),
            k_u: SMatrix::zeros(),
        }; 4];
        for i in 0..4 {
            if i > 0 {
                let (p, c) = (stages[i - 1], RK4_OFFSET[i] * h);
                let s = &mut stages[i];
                s.y = x + p.k * c;
                s.y_x = SMatrix::identity() + p.k_x * c;
                s.y_u = p.k_u * c;
            }
            let s = &mut stages[i];
            let (a, b) = self.model.jacobians(&s.y, u);
            s.k = self.model.derivative(&s.y, u);
            s.k_x = a * s.y_x;
            s.k_u = a * s.y_u + b;
            s.a = a;
        }
        stages
    }
}

impl<M, const NX: usize, const NU: usize> DiscreteDynamics<NX, NU> for Rk4<M>
where
    M: ContinuousDynamics<NX, NU>,
{
    #[inline]
    fn step(&self, x: &SVector<f64, NX>, u: &SVector<f64, NU>) -> SVector<f64, NX> {
        let h = self.dt;
        let k1 = self.model.derivative(x, u);
        let k2 = self.model.derivative(&(x + k1 * (0.5 * h)), u);
        let k3 = self.model.derivative(&(x + k2 * (0.5 * h)), u);
        let k4 = self.model.derivative(&(x + k3 * h), u);
        x + (k1 + (k2 + k3) * 2.0 + k4) * (h / 6.0)
    }

    /// The chain rule through the stages (see [`Rk4`]), one stage at a
    /// time: nothing is kept but the previous stage's slope and its
    /// derivatives, where an array of all four stages cost a copy per knot
    /// (about a fifth of a Dubins car solve). The products with the model's
    /// `∂f/∂x` skip the entries its pattern says are zero (7 of 9 for the
    /// unicycle), summing the rest in the order nalgebra's products do, so
    /// that the result differs from the dense product only where that
    /// multiplies a zero by a non-finite entry, or in the sign of a zero.
    #[inline]
    fn linearize(
        &self,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
    ) -> (SMatrix<f64, NX, NX>, SMatrix<f64, NX, NU>) {
        let h = self.dt;
        let pattern: &'static Option<Sparsity<NX, NU>> = const { &M::JACOBIAN_SPARSITY };
        let nz = match pattern {
            Some(p) => Nonzeros::Known(&p.state),
            None => Nonzeros::All,
        };
        let mut a = SMatrix::<f64, NX, NX>::identity();
        let mut b = SMatrix::<f64, NX, NU>::zeros();
        // Stage 0 evaluates at `x` itself: `∂y/∂x = I`, `∂y/∂u = 0`.
        let (f_x, f_u) = self.model.jacobians(x, u);
        let mut k = self.model.derivative(x, u);
        let mut k_x = f_x;
        let mut k_u = f_u;
        for i in 0..4 {
            if i > 0 {
                let c = RK4_OFFSET[i] * h;
                let y = x + k * c;
                let y_x = SMatrix::<f64, NX, NX>::identity() + k_x * c;
                let y_u = k_u * c;
                let (f_x, f_u) = self.model.jacobians(&y, u);
                k = self.model.derivative(&y, u);
                k_x.data.0 = mul_sparse_left(&f_x.data.0, nz, &y_x.data.0);
                k_u.data.0 = mul_sparse_left(&f_x.data.0, nz, &y_u.data.0);
                k_u += f_u;
            }
            let w = RK4_WEIGHT[i] * h;
            a += k_x * w;
            b += k_u * w;
        }
        (a, b)
    }

    /// `λᵀF = λᵀx + h·Σ w_i·λᵀk_i`, and stage `i`'s slope also moves every
    /// later stage's point: the weight on `k_i`'s second derivatives is
    /// `μ_i = h·w_i·λ + a_{i+1}·h·A_{i+1}ᵀ·μ_{i+1}` (an adjoint, from the
    /// last stage back). Each stage then adds the model's curvature at
    /// `(y_i, u)` weighted by `μ_i`, mapped through `∂y_i/∂(x, u)`.
    fn curvature(
        &self,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        lambda: &SVector<f64, NX>,
    ) -> Option<Curvature<NX, NU>> {
        let h = self.dt;
        let stages = self.stages(x, u);
        let mut out = Curvature {
            xx: SMatrix::zeros(),
            ux: SMatrix::zeros(),
            uu: SMatrix::zeros(),
        };
        let mut mu = SVector::<f64, NX>::zeros();
        for i in (0..4).rev() {
            mu = lambda * (RK4_WEIGHT[i] * h)
                + match stages.get(i + 1) {
                    Some(next) => next.a.transpose() * mu * (RK4_OFFSET[i + 1] * h),
                    None => SVector::zeros(),
                };
            let s = &stages[i];
            let c = self.model.curvature(&s.y, u, &mu)?;
            let cxx_yx = c.xx * s.y_x;
            out.xx += s.y_x.transpose() * cxx_yx;
            out.ux += (s.y_u.transpose() * c.xx + c.ux) * s.y_x;
            out.uu += s.y_u.transpose() * c.xx * s.y_u
                + s.y_u.transpose() * c.ux.transpose()
                + c.ux * s.y_u
                + c.uu;
        }
        Some(out)
    }

    /// The model's pattern through the four stages ([`Sparsity::rk4`]).
    const SPARSITY: Option<Sparsity<NX, NU>> = match M::JACOBIAN_SPARSITY {
        Some(pattern) => Some(pattern.rk4()),
        None => None,
    };
}
