//! Cost functions and their quadratic models.
//!
//! The solver minimises `J = Σ_{k<N} l(k, x_k, u_k) + l_f(x_N)` (eq. 1) through
//! the [`Cost`] trait. Each call to `expand` *adds* a term's gradient and
//! Hessian into an expansion, so terms compose by summation ([`Objective`]).
//!
//! The terms here are those of the seed paper, eqs. 13–15, written **without**
//! ½ factors so that costs compare with the paper and with other solvers:
//!
//! * [`StateTracking`]: `(x − x_goal)ᵀ Q (x − x_goal)`, `Q` diagonal;
//! * [`ControlEffort`]: `uᵀ R u`, `R` diagonal;
//! * [`ExpObstacle`]: `q · exp(−‖p − c‖)` with `p` the position `(x, y)`;
//! * [`TerminalTracking`]: `(x_N − x_goal)ᵀ Q_f (x_N − x_goal)`;
//! * [`ShapeObstacle`]: `q · exp(−d(p))` with `d` the signed distance to a
//!   circle or rectangle ([`Region`]), the same term for shapes.

use nalgebra::{Matrix2, SMatrix, SVector, Vector2};

use crate::constraint::{Region, position_of};

/// Second-order model of a stage cost at `(x, u)`: the `l_x`, `l_u`, `l_xx`,
/// `l_uu`, `l_ux` of eqs. 18–23.
#[derive(Debug, Clone, Copy, PartialEq)]
#[allow(non_snake_case)]
pub struct StageExpansion<const NX: usize, const NU: usize> {
    /// `∂l/∂x`.
    pub l_x: SVector<f64, NX>,
    /// `∂l/∂u`.
    pub l_u: SVector<f64, NU>,
    /// `∂²l/∂x²`. Symmetric; the solver reads its lower triangle.
    pub l_xx: SMatrix<f64, NX, NX>,
    /// `∂²l/∂u²`.
    pub l_uu: SMatrix<f64, NU, NU>,
    /// `∂²l/∂u∂x`.
    pub l_ux: SMatrix<f64, NU, NX>,
}

impl<const NX: usize, const NU: usize> StageExpansion<NX, NU> {
    /// All derivatives zero.
    pub fn zeros() -> Self {
        Self {
            l_x: SVector::zeros(),
            l_u: SVector::zeros(),
            l_xx: SMatrix::zeros(),
            l_uu: SMatrix::zeros(),
            l_ux: SMatrix::zeros(),
        }
    }
}

/// Second-order model of the terminal cost at `x_N` (eqs. 36–37).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TerminalExpansion<const NX: usize> {
    /// `∂l_f/∂x`.
    pub l_x: SVector<f64, NX>,
    /// `∂²l_f/∂x²`. Symmetric: it seeds `V_xx`, whose symmetry the
    /// backward pass relies on.
    pub l_xx: SMatrix<f64, NX, NX>,
}

impl<const NX: usize> TerminalExpansion<NX> {
    /// All derivatives zero.
    pub fn zeros() -> Self {
        Self {
            l_x: SVector::zeros(),
            l_xx: SMatrix::zeros(),
        }
    }
}

/// What the solver minimises: a stage cost for `k = 0..N` and a terminal cost.
pub trait Cost<const NX: usize, const NU: usize>: Send + Sync {
    /// `l(k, x, u)`.
    fn stage(&self, k: usize, x: &SVector<f64, NX>, u: &SVector<f64, NU>) -> f64;
    /// Add the derivatives of `l(k, ·, ·)` at `(x, u)` into `e`.
    fn stage_expand(
        &self,
        k: usize,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    );
    /// Like [`Cost::stage_expand`], with a positive semi-definite
    /// approximation of the Hessian in place of the exact one. The solver
    /// falls back to it when the exact Hessian leaves `Q_uu` indefinite at
    /// every regularisation up to `Options::mu_max` (see
    /// `Options::convex_fallback`). The default is the exact expansion,
    /// right for a cost that is convex already. A cost that overrides it
    /// must override [`Cost::has_convex_approximation`] too, or the solver
    /// skips the fallback.
    fn stage_expand_convex(
        &self,
        k: usize,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        self.stage_expand(k, x, u, e);
    }
    /// Whether [`Cost::stage_expand_convex`] differs from
    /// [`Cost::stage_expand`]. When it does not (the default), the solver's
    /// convex fallback would repeat what just failed, so it is skipped.
    fn has_convex_approximation(&self) -> bool {
        false
    }
    /// `l_f(x_N)`.
    fn terminal(&self, x: &SVector<f64, NX>) -> f64;
    /// Add the derivatives of `l_f` at `x` into `e`.
    fn terminal_expand(&self, x: &SVector<f64, NX>, e: &mut TerminalExpansion<NX>);
}

/// One additive term of a stage cost.
pub trait StageCost<const NX: usize, const NU: usize>: Send + Sync {
    /// The term's value at stage `k`.
    fn value(&self, k: usize, x: &SVector<f64, NX>, u: &SVector<f64, NU>) -> f64;
    /// Add the term's gradient and Hessian into `e`.
    fn expand(
        &self,
        k: usize,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    );
    /// Add the term's gradient and a positive semi-definite approximation
    /// of its Hessian into `e` (see [`Cost::stage_expand_convex`]). The
    /// default adds the exact Hessian: a convex term overrides nothing. A
    /// term that overrides it must override
    /// [`StageCost::has_convex_approximation`] too.
    fn expand_convex(
        &self,
        k: usize,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        self.expand(k, x, u, e);
    }
    /// Whether [`StageCost::expand_convex`] differs from
    /// [`StageCost::expand`]: true for a term that overrides it.
    fn has_convex_approximation(&self) -> bool {
        false
    }
}

/// One additive term of a terminal cost.
pub trait TerminalCost<const NX: usize>: Send + Sync {
    /// The term's value at `x_N`.
    fn value(&self, x: &SVector<f64, NX>) -> f64;
    /// Add the term's gradient and Hessian into `e`.
    fn expand(&self, x: &SVector<f64, NX>, e: &mut TerminalExpansion<NX>);
}

/// A sum of stage terms and terminal terms.
///
/// Terms are boxed trait objects: building an objective allocates, evaluating
/// one does not. One dynamic call per term per knot costs a few nanoseconds
/// against the hundreds spent in the Riccati step.
#[derive(Default)]
pub struct Objective<const NX: usize, const NU: usize> {
    stage: Vec<Box<dyn StageCost<NX, NU>>>,
    terminal: Vec<Box<dyn TerminalCost<NX>>>,
}

impl<const NX: usize, const NU: usize> Objective<NX, NU> {
    /// An objective with no terms (zero everywhere).
    pub fn new() -> Self {
        Self {
            stage: Vec::new(),
            terminal: Vec::new(),
        }
    }

    /// Add a stage term.
    #[must_use]
    pub fn with_stage(mut self, term: impl StageCost<NX, NU> + 'static) -> Self {
        self.stage.push(Box::new(term));
        self
    }

    /// Add a terminal term.
    #[must_use]
    pub fn with_terminal(mut self, term: impl TerminalCost<NX> + 'static) -> Self {
        self.terminal.push(Box::new(term));
        self
    }
}

impl<const NX: usize, const NU: usize> Cost<NX, NU> for Objective<NX, NU> {
    fn stage(&self, k: usize, x: &SVector<f64, NX>, u: &SVector<f64, NU>) -> f64 {
        self.stage.iter().map(|t| t.value(k, x, u)).sum()
    }

    fn stage_expand(
        &self,
        k: usize,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        for t in &self.stage {
            t.expand(k, x, u, e);
        }
    }

    fn stage_expand_convex(
        &self,
        k: usize,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        for t in &self.stage {
            t.expand_convex(k, x, u, e);
        }
    }

    fn has_convex_approximation(&self) -> bool {
        self.stage.iter().any(|t| t.has_convex_approximation())
    }

    fn terminal(&self, x: &SVector<f64, NX>) -> f64 {
        self.terminal.iter().map(|t| t.value(x)).sum()
    }

    fn terminal_expand(&self, x: &SVector<f64, NX>, e: &mut TerminalExpansion<NX>) {
        for t in &self.terminal {
            t.expand(x, e);
        }
    }
}

/// `(x − goal)ᵀ diag(weights) (x − goal)`: the state part of eq. 13.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StateTracking<const NX: usize> {
    /// The target state `x'`.
    pub goal: SVector<f64, NX>,
    /// The diagonal of `Q`.
    pub weights: SVector<f64, NX>,
}

impl<const NX: usize, const NU: usize> StageCost<NX, NU> for StateTracking<NX> {
    fn value(&self, _k: usize, x: &SVector<f64, NX>, _u: &SVector<f64, NU>) -> f64 {
        weighted_square(&self.weights, &(x - self.goal))
    }

    fn expand(
        &self,
        _k: usize,
        x: &SVector<f64, NX>,
        _u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        let err = x - self.goal;
        for i in 0..NX {
            e.l_x[i] += 2.0 * self.weights[i] * err[i];
            e.l_xx[(i, i)] += 2.0 * self.weights[i];
        }
    }
}

/// `uᵀ diag(weights) u`: the control part of eq. 13. Note it penalises the
/// thrust itself, not its deviation from hover, as the paper does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControlEffort<const NU: usize> {
    /// The diagonal of `R`.
    pub weights: SVector<f64, NU>,
}

impl<const NX: usize, const NU: usize> StageCost<NX, NU> for ControlEffort<NU> {
    fn value(&self, _k: usize, _x: &SVector<f64, NX>, u: &SVector<f64, NU>) -> f64 {
        weighted_square(&self.weights, u)
    }

    fn expand(
        &self,
        _k: usize,
        _x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        for i in 0..NU {
            e.l_u[i] += 2.0 * self.weights[i] * u[i];
            e.l_uu[(i, i)] += 2.0 * self.weights[i];
        }
    }
}

/// `(x_N − goal)ᵀ diag(weights) (x_N − goal)`: the terminal cost, eq. 15.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TerminalTracking<const NX: usize> {
    /// The target state.
    pub goal: SVector<f64, NX>,
    /// The diagonal of `Q_f`.
    pub weights: SVector<f64, NX>,
}

impl<const NX: usize> TerminalCost<NX> for TerminalTracking<NX> {
    fn value(&self, x: &SVector<f64, NX>) -> f64 {
        weighted_square(&self.weights, &(x - self.goal))
    }

    fn expand(&self, x: &SVector<f64, NX>, e: &mut TerminalExpansion<NX>) {
        let err = x - self.goal;
        for i in 0..NX {
            e.l_x[i] += 2.0 * self.weights[i] * err[i];
            e.l_xx[(i, i)] += 2.0 * self.weights[i];
        }
    }
}

/// `weight · ‖p_k − r_k‖²` at every stage within `reach` of `knot`: pulls
/// the position along a route through a via-point, `r_k` moving at
/// constant speed from `from` to `via` over stages `0..=knot`, then from
/// `via` to `to` over `knot..=horizon`. Not part of any problem's cost: a search over routes
/// ([`crate::search`]) adds it to a short guiding solve that bends the
/// initial guess to one side of an obstacle. Pulling every stage, not the
/// via-point's alone, keeps the guided path on the route before and after
/// it, whatever the number of stages: a pull at one stage bends the path
/// less the more stages share the rest of the cost, and a vehicle with
/// momentum swings past a lone via-point and back round the other side.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViaPath {
    /// Where the route starts, m.
    pub from: Vector2<f64>,
    /// The via-point, m.
    pub via: Vector2<f64>,
    /// Where the route ends, m.
    pub to: Vector2<f64>,
    /// The stage at the via-point (`1 ≤ knot < horizon`).
    pub knot: usize,
    /// The number of stages `N`.
    pub horizon: usize,
    /// How many stages either side of `knot` are pulled: `horizon` for
    /// the whole route, 0 for the via-point alone.
    pub reach: usize,
    /// Weight per stage (cost units per m²).
    pub weight: f64,
    /// Indices of the position components in the state.
    pub position: (usize, usize),
}

impl ViaPath {
    /// The route's point at stage `k`.
    pub fn point(&self, k: usize) -> Vector2<f64> {
        let (k, knot, n) = (k as f64, self.knot as f64, self.horizon as f64);
        if k <= knot {
            self.from + (self.via - self.from) * (k / knot)
        } else {
            self.via + (self.to - self.via) * ((k - knot) / (n - knot))
        }
    }

    fn offset<const NX: usize>(&self, k: usize, x: &SVector<f64, NX>) -> Vector2<f64> {
        Vector2::new(x[self.position.0], x[self.position.1]) - self.point(k)
    }

    fn pulls(&self, k: usize) -> bool {
        k.abs_diff(self.knot) <= self.reach
    }
}

impl<const NX: usize, const NU: usize> StageCost<NX, NU> for ViaPath {
    fn value(&self, k: usize, x: &SVector<f64, NX>, _u: &SVector<f64, NU>) -> f64 {
        if self.pulls(k) {
            self.weight * self.offset(k, x).norm_squared()
        } else {
            0.0
        }
    }

    fn expand(
        &self,
        k: usize,
        x: &SVector<f64, NX>,
        _u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        if !self.pulls(k) {
            return;
        }
        let grad = self.offset(k, x) * (2.0 * self.weight);
        let hess = Matrix2::identity() * (2.0 * self.weight);
        add_in_plane(self.position, &grad, &hess, e);
    }
}

/// A soft obstacle `q · exp(−‖p − c‖)` (eqs. 13–14), where `p` is the position
/// read from state components `position = (ix, iy)`.
///
/// The distance `ρ = ‖p − c‖` is not differentiable at `ρ = 0`. The gradient
/// `−q e^{−ρ} (p − c)/ρ` is taken as 0 there (the cost peaks at the centre),
/// and below [`ExpObstacle::MIN_DISTANCE`] the Hessian is evaluated at that
/// floor instead of diverging. The Hessian is indefinite everywhere (negative
/// curvature across the radial direction), which the solver's regularisation
/// absorbs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExpObstacle {
    /// Centre `c` in m.
    pub center: Vector2<f64>,
    /// Weight `q` (cost units).
    pub weight: f64,
    /// Indices of the position components in the state.
    pub position: (usize, usize),
}

impl ExpObstacle {
    /// Distance floor (m) used by the derivatives near the centre.
    pub const MIN_DISTANCE: f64 = 1e-3;

    fn offset<const NX: usize>(&self, x: &SVector<f64, NX>) -> Vector2<f64> {
        Vector2::new(
            x[self.position.0] - self.center.x,
            x[self.position.1] - self.center.y,
        )
    }

    /// Value, gradient and Hessian with respect to the position.
    fn position_model<const NX: usize>(
        &self,
        x: &SVector<f64, NX>,
    ) -> (f64, Vector2<f64>, Matrix2<f64>) {
        let delta = self.offset(x);
        let rho = delta.norm();
        let value = self.weight * (-rho).exp();
        let r = rho.max(Self::MIN_DISTANCE);
        // ∇ρ = δ/ρ, ∇²ρ = (I − δδᵀ/ρ²)/ρ; ∇²e^{−ρ} = e^{−ρ}(∇ρ∇ρᵀ − ∇²ρ).
        let grad = -delta * (value / r);
        let outer = delta * delta.transpose() / (r * r);
        let hess = (outer * (1.0 + 1.0 / r) - Matrix2::identity() / r) * value;
        (value, grad, hess)
    }
}

impl<const NX: usize, const NU: usize> StageCost<NX, NU> for ExpObstacle {
    fn value(&self, _k: usize, x: &SVector<f64, NX>, _u: &SVector<f64, NU>) -> f64 {
        self.weight * (-self.offset(x).norm()).exp()
    }

    fn expand(
        &self,
        _k: usize,
        x: &SVector<f64, NX>,
        _u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        let (_, grad, hess) = self.position_model(x);
        self.add(&grad, &hess, e);
    }

    /// The Hessian's negative curvature dropped: its projection onto the
    /// positive semi-definite matrices, in closed form. The exact Hessian
    /// has the eigenvalue `−q e^{−ρ}/r` across the direction `n` away from
    /// the centre, where `r = max(ρ, MIN_DISTANCE)`, and
    /// `q e^{−ρ} ((ρ/r)²(1 + 1/r) − 1/r)` along it: `q e^{−ρ}` from
    /// `MIN_DISTANCE` out, so the projection there is `q e^{−ρ} n nᵀ`.
    /// Closer in, where the exact Hessian is evaluated at the clamped
    /// distance, the radial eigenvalue turns negative below
    /// `ρ = r/√(1 + r)` (0.9995 mm) and the projection is zero; between
    /// that and 1 mm it is the radial eigenvalue's part, small and positive.
    fn expand_convex(
        &self,
        _k: usize,
        x: &SVector<f64, NX>,
        _u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        let (value, grad, _) = self.position_model(x);
        let delta = self.offset(x);
        let rho = delta.norm();
        let radial = if rho >= Self::MIN_DISTANCE {
            value
        } else {
            let r = Self::MIN_DISTANCE;
            value * ((rho * rho) / (r * r) * (1.0 + 1.0 / r) - 1.0 / r)
        };
        let hess = if radial > 0.0 {
            delta * delta.transpose() * (radial / (rho * rho))
        } else {
            Matrix2::zeros()
        };
        self.add(&grad, &hess, e);
    }

    /// A zero weight has no curvature to drop.
    fn has_convex_approximation(&self) -> bool {
        self.weight != 0.0
    }
}

impl ExpObstacle {
    fn add<const NX: usize, const NU: usize>(
        &self,
        grad: &Vector2<f64>,
        hess: &Matrix2<f64>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        add_in_plane(self.position, grad, hess, e);
    }
}

/// Add a term's gradient and Hessian in the plane's position (state
/// entries `position`) into `e`.
fn add_in_plane<const NX: usize, const NU: usize>(
    position: (usize, usize),
    grad: &Vector2<f64>,
    hess: &Matrix2<f64>,
    e: &mut StageExpansion<NX, NU>,
) {
    let idx = [position.0, position.1];
    for a in 0..2 {
        e.l_x[idx[a]] += grad[a];
        for b in 0..2 {
            e.l_xx[(idx[a], idx[b])] += hess[(a, b)];
        }
    }
}

/// A soft obstacle of any shape: `q · exp(−d(p))`, `d` the signed distance
/// from the position `p` to `region` (negative inside). For a
/// [`Shape::Point`](crate::Shape::Point) this is [`ExpObstacle`]'s term.
///
/// Its Hessian in `p` is `q e^{−d} (∇d∇dᵀ − ∇²d)`: the first part is
/// positive semi-definite, and `∇²d` is the boundary's curvature (around a
/// circle, a rectangle's corner), which the convex expansion drops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShapeObstacle {
    /// What the obstacle occupies.
    pub region: Region,
    /// Weight `q` (cost units).
    pub weight: f64,
    /// Indices of the position components in the state.
    pub position: (usize, usize),
}

impl ShapeObstacle {
    fn add<const NX: usize, const NU: usize>(
        &self,
        x: &SVector<f64, NX>,
        convex: bool,
        e: &mut StageExpansion<NX, NU>,
    ) {
        let d = self.region.distance(&position_of(x, self.position));
        let value = self.weight * (-d.value).exp();
        let grad = -d.gradient * value;
        let mut hess = d.gradient * d.gradient.transpose() * value;
        if !convex {
            hess -= d.hessian * value;
        }
        add_in_plane(self.position, &grad, &hess, e);
    }
}

impl<const NX: usize, const NU: usize> StageCost<NX, NU> for ShapeObstacle {
    fn value(&self, _k: usize, x: &SVector<f64, NX>, _u: &SVector<f64, NU>) -> f64 {
        self.weight * (-self.region.signed_distance(&position_of(x, self.position))).exp()
    }

    fn expand(
        &self,
        _k: usize,
        x: &SVector<f64, NX>,
        _u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        self.add(x, false, e);
    }

    fn expand_convex(
        &self,
        _k: usize,
        x: &SVector<f64, NX>,
        _u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        self.add(x, true, e);
    }

    fn has_convex_approximation(&self) -> bool {
        self.weight != 0.0
    }
}

fn weighted_square<const N: usize>(w: &SVector<f64, N>, v: &SVector<f64, N>) -> f64 {
    v.iter().zip(w.iter()).map(|(vi, wi)| wi * vi * vi).sum()
}
