//! Hard constraints, and the shapes obstacles take.
//!
//! A [`Constraint`] is a set of scalar components `c_i(x, u)`, each to hold
//! as `c_i ≤ 0` (or `c_i = 0` where [`Constraint::is_equality`]), at the
//! knots it names: the stages `(x_k, u_k)`, `k < N`, and the terminal state
//! `x_N`. The solver meets them with an augmented Lagrangian
//! ([`Solver::solve_constrained`](crate::Solver::solve_constrained)): it
//! needs each component's value and gradient, nothing else, so a new kind
//! of constraint is a new implementation of the trait.
//!
//! Bounds on the controls are not a [`Constraint`]: they are a
//! [`ControlBounds`], which the backward pass meets exactly as a box QP at
//! each knot (box-DDP) and the rollouts by clamping.
//!
//! The kinds here:
//!
//! * [`StateBounds`]: `lower ≤ x_k ≤ upper` for `k = 1..N`;
//! * [`GoalTolerance`]: `|x_N − goal| ≤ tolerance` per component, an
//!   equality where the tolerance is 0;
//! * [`Clearance`]: `d(p_k) ≥ clearance` for `k = 1..N`, `d` the signed
//!   distance from the position to a [`Region`].
//!
//! The initial state is given, so no constraint applies to it.

use nalgebra::{Matrix2, SVector, Vector2};

/// Bounds on the controls, `lower ≤ u_k ≤ upper` at every step; an
/// infinite bound is no bound.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControlBounds<const NU: usize> {
    /// Lower bounds (`−∞` for none).
    pub lower: SVector<f64, NU>,
    /// Upper bounds (`+∞` for none).
    pub upper: SVector<f64, NU>,
}

impl<const NU: usize> ControlBounds<NU> {
    /// `u` clamped into the bounds.
    pub fn clamp(&self, u: &SVector<f64, NU>) -> SVector<f64, NU> {
        SVector::from_fn(|i, _| u[i].max(self.lower[i]).min(self.upper[i]))
    }

    /// Whether each bound admits a finite value (`lower ≤ upper`, neither
    /// NaN, `lower < +∞`, `upper > −∞`).
    pub fn is_valid(&self) -> bool {
        (0..NU).all(|i| {
            let (lo, hi) = (self.lower[i], self.upper[i]);
            lo <= hi && lo < f64::INFINITY && hi > f64::NEG_INFINITY
        })
    }
}

/// A knot of the trajectory, as a constraint sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Knot {
    /// Stage `k`: the state `x_k` and the control `u_k`, `k < N`.
    Stage(usize),
    /// The terminal state `x_N` (the control is zero there, and its
    /// gradient is ignored).
    Terminal,
}

/// A hard constraint: `dim()` scalar components, each `c_i(x, u) ≤ 0`, or
/// `= 0` where [`Constraint::is_equality`]. Values are in the
/// constraint's own units (m for a clearance, the component's unit for a
/// bound), which is how violations are reported.
pub trait Constraint<const NX: usize, const NU: usize>: Send + Sync {
    /// The number of scalar components.
    fn dim(&self) -> usize;
    /// Whether component `i` is an equality (`c_i = 0`).
    fn is_equality(&self, _i: usize) -> bool {
        false
    }
    /// Whether the constraint applies at `knot`.
    fn applies(&self, knot: Knot) -> bool;
    /// `c_i(x, u)`.
    fn value(&self, i: usize, x: &SVector<f64, NX>, u: &SVector<f64, NU>) -> f64;
    /// `c_i(x, u)` and its gradients `∂c_i/∂x`, `∂c_i/∂u`.
    fn linearize(
        &self,
        i: usize,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
    ) -> (f64, SVector<f64, NX>, SVector<f64, NU>);
    /// Calls `f(component, value, equality)` for every component if the
    /// constraint applies at `knot`, and returns [`Constraint::dim`] either
    /// way. A solve's penalty terms ask this at every knot of every rollout:
    /// through `dyn Constraint`, one call here stands for the calls to
    /// `dim`, `applies`, `value` and `is_equality` it makes, which the
    /// default makes directly on the implementing type (inlined).
    fn values_at(
        &self,
        knot: Knot,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        f: &mut dyn FnMut(usize, f64, bool),
    ) -> usize {
        let dim = self.dim();
        if self.applies(knot) {
            for i in 0..dim {
                f(i, self.value(i, x, u), self.is_equality(i));
            }
        }
        dim
    }
    /// Calls `f(knot, component, value)` for every component at every knot
    /// where the constraint applies, knots in order (`0..N` for stages,
    /// `N` for the terminal state, where the control is zero). The default
    /// asks [`Constraint::applies`] and [`Constraint::value`] at each; a
    /// constraint evaluated along whole trajectories (reports, the final
    /// violation) may do it in one loop without them.
    fn values_along(
        &self,
        states: &[SVector<f64, NX>],
        controls: &[SVector<f64, NU>],
        f: &mut dyn FnMut(usize, usize, f64),
    ) {
        let n = controls.len();
        let dim = self.dim();
        for k in 0..=n {
            let (knot, u) = if k < n {
                (Knot::Stage(k), controls[k])
            } else {
                (Knot::Terminal, SVector::zeros())
            };
            if !self.applies(knot) {
                continue;
            }
            for i in 0..dim {
                f(k, i, self.value(i, &states[k], &u));
            }
        }
    }
}

/// How far component `c` of a constraint is violated: `max(c, 0)`, or `|c|`
/// for an equality; infinite for a NaN (which `f64::max` would drop).
pub fn violation(c: f64, equality: bool) -> f64 {
    if c.is_nan() {
        f64::INFINITY
    } else if equality {
        c.abs()
    } else {
        c.max(0.0)
    }
}

/// A component `sign·x_index − const` with its value: gradient `sign`
/// along state axis `index`, nothing in the controls.
fn along_axis<const NX: usize, const NU: usize>(
    value: f64,
    index: usize,
    sign: f64,
) -> (f64, SVector<f64, NX>, SVector<f64, NU>) {
    let mut c_x = SVector::zeros();
    c_x[index] = sign;
    (value, c_x, SVector::zeros())
}

/// The position `(x[position.0], x[position.1])` of a state in the plane.
pub(crate) fn position_of<const NX: usize>(
    x: &SVector<f64, NX>,
    position: (usize, usize),
) -> Vector2<f64> {
    Vector2::new(x[position.0], x[position.1])
}

/// `lower ≤ x_k ≤ upper` at every state after the initial one; infinite
/// bounds are skipped. Components: one per finite bound, upper ones
/// (`x_i − upper_i`) first, then lower ones (`lower_i − x_i`).
#[derive(Debug, Clone, PartialEq)]
pub struct StateBounds<const NX: usize> {
    /// `(index, sign, bound)`: the component is `sign·(x_index − bound)`.
    parts: Vec<(usize, f64, f64)>,
}

impl<const NX: usize> StateBounds<NX> {
    /// The bounds; `±∞` (or NaN) for none.
    pub fn new(lower: &SVector<f64, NX>, upper: &SVector<f64, NX>) -> Self {
        let upper = (0..NX)
            .filter(|&i| upper[i].is_finite())
            .map(|i| (i, 1.0, upper[i]));
        let lower = (0..NX)
            .filter(|&i| lower[i].is_finite())
            .map(|i| (i, -1.0, lower[i]));
        Self {
            parts: upper.chain(lower).collect(),
        }
    }

    /// The state index and whether component `i` is an upper bound.
    pub fn component(&self, i: usize) -> (usize, bool) {
        let (index, sign, _) = self.parts[i];
        (index, sign > 0.0)
    }
}

impl<const NX: usize, const NU: usize> Constraint<NX, NU> for StateBounds<NX> {
    fn dim(&self) -> usize {
        self.parts.len()
    }

    fn applies(&self, knot: Knot) -> bool {
        knot != Knot::Stage(0)
    }

    fn value(&self, i: usize, x: &SVector<f64, NX>, _u: &SVector<f64, NU>) -> f64 {
        let (index, sign, bound) = self.parts[i];
        sign * (x[index] - bound)
    }

    fn linearize(
        &self,
        i: usize,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
    ) -> (f64, SVector<f64, NX>, SVector<f64, NU>) {
        let (index, sign, _) = self.parts[i];
        along_axis(
            <Self as Constraint<NX, NU>>::value(self, i, x, u),
            index,
            sign,
        )
    }
}

/// `|x_N,i − goal_i| ≤ tolerance_i` at the terminal state: two
/// inequalities per component (`x − goal − tol`, `goal − x − tol`), or one
/// equality (`x − goal`) where the tolerance is 0. Components in state
/// order.
#[derive(Debug, Clone, PartialEq)]
pub struct GoalTolerance<const NX: usize> {
    /// `(index, sign, offset, equality)`: the component is
    /// `sign·(x_index − goal_index) − offset`.
    parts: Vec<(usize, f64, f64, bool)>,
    goal: SVector<f64, NX>,
}

impl<const NX: usize> GoalTolerance<NX> {
    /// The goal and the tolerance of each component (≥ 0).
    pub fn new(goal: SVector<f64, NX>, tolerance: &SVector<f64, NX>) -> Self {
        let mut parts = Vec::new();
        for i in 0..NX {
            let t = tolerance[i];
            if t == 0.0 {
                parts.push((i, 1.0, 0.0, true));
            } else if t.is_finite() {
                parts.push((i, 1.0, t, false));
                parts.push((i, -1.0, t, false));
            }
        }
        Self { parts, goal }
    }

    /// The state index of component `i`.
    pub fn index(&self, i: usize) -> usize {
        self.parts[i].0
    }
}

impl<const NX: usize, const NU: usize> Constraint<NX, NU> for GoalTolerance<NX> {
    fn dim(&self) -> usize {
        self.parts.len()
    }

    fn is_equality(&self, i: usize) -> bool {
        self.parts[i].3
    }

    fn applies(&self, knot: Knot) -> bool {
        knot == Knot::Terminal
    }

    fn value(&self, i: usize, x: &SVector<f64, NX>, _u: &SVector<f64, NU>) -> f64 {
        let (index, sign, offset, _) = self.parts[i];
        sign * (x[index] - self.goal[index]) - offset
    }

    fn linearize(
        &self,
        i: usize,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
    ) -> (f64, SVector<f64, NX>, SVector<f64, NU>) {
        let (index, sign, _, _) = self.parts[i];
        along_axis(
            <Self as Constraint<NX, NU>>::value(self, i, x, u),
            index,
            sign,
        )
    }
}

/// The shape of a region in the plane, about its centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// A point: the distance is to the centre itself.
    Point,
    /// A disc of this radius (m).
    Circle {
        /// Radius, m, ≥ 0.
        radius: f64,
    },
    /// A turned rectangle.
    Rectangle(Rectangle),
}

/// A rectangle `size = [width, height]` (m), turned by `angle` (rad,
/// counter-clockwise) about its centre: width along the turned x axis.
/// Its rotation is computed once here, not at every distance: a solve
/// with 100 rectangles at N = 10000 asks for millions of distances.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rectangle {
    size: Vector2<f64>,
    angle: f64,
    cos: f64,
    sin: f64,
}

impl Rectangle {
    /// A rectangle of `size` (m, each ≥ 0) turned by `angle` (rad).
    pub fn new(size: Vector2<f64>, angle: f64) -> Self {
        let (sin, cos) = angle.sin_cos();
        Self {
            size,
            angle,
            cos,
            sin,
        }
    }

    /// Width and height, m.
    pub fn size(&self) -> Vector2<f64> {
        self.size
    }

    /// Rotation, rad.
    pub fn angle(&self) -> f64 {
        self.angle
    }

    /// `p` (relative to the centre) in the rectangle's own axes.
    fn local(&self, p: Vector2<f64>) -> Vector2<f64> {
        Vector2::new(
            self.cos * p.x + self.sin * p.y,
            -self.sin * p.x + self.cos * p.y,
        )
    }

    /// The turned x and y axes, as unit vectors.
    pub fn axes(&self) -> (Vector2<f64>, Vector2<f64>) {
        (
            Vector2::new(self.cos, self.sin),
            Vector2::new(-self.sin, self.cos),
        )
    }

    /// The signed distance from `p` (relative to the centre).
    fn signed_distance(&self, p: Vector2<f64>) -> f64 {
        let q = self.local(p);
        let a = q.abs() - self.size / 2.0;
        if a.x > 0.0 && a.y > 0.0 {
            a.norm()
        } else {
            a.x.max(a.y)
        }
    }
}

/// A shape at a place: what an obstacle occupies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Region {
    /// Centre, m.
    pub center: Vector2<f64>,
    /// Its shape.
    pub shape: Shape,
}

/// The signed distance from a point to a [`Region`], with its first and
/// second derivatives in the point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Distance {
    /// `d`, m: positive outside, negative inside.
    pub value: f64,
    /// `∇d`, a unit vector (zero at a point's or circle's centre).
    pub gradient: Vector2<f64>,
    /// `∇²d`: the boundary's curvature where it is curved (around a point,
    /// a circle, a rectangle's corner), zero elsewhere. Positive
    /// semi-definite.
    pub hessian: Matrix2<f64>,
}

impl Region {
    /// Distance floor (m) below which the curvature of the distance to a
    /// point (`(I − nnᵀ)/ρ`) is evaluated at the floor instead.
    pub const MIN_DISTANCE: f64 = 1e-3;

    /// The signed distance from `p` to the region, without its
    /// derivatives: what a rollout needs.
    pub fn signed_distance(&self, p: &Vector2<f64>) -> f64 {
        match self.shape {
            Shape::Point => (p - self.center).norm(),
            Shape::Circle { radius } => (p - self.center).norm() - radius,
            Shape::Rectangle(r) => r.signed_distance(p - self.center),
        }
    }

    /// The signed distance from `p` to the region. Non-differentiable on the
    /// region's medial axis (the centre of a circle, the diagonals inside
    /// a rectangle), where one side's gradient is taken.
    pub fn distance(&self, p: &Vector2<f64>) -> Distance {
        match self.shape {
            Shape::Point => radial(p - self.center, 0.0),
            Shape::Circle { radius } => radial(p - self.center, radius),
            Shape::Rectangle(rect) => {
                let q = rect.local(p - self.center);
                let sign = |v: f64| if v < 0.0 { -1.0 } else { 1.0 };
                let s = Vector2::new(sign(q.x), sign(q.y));
                let a = q.abs() - rect.size / 2.0;
                let local = if a.x > 0.0 && a.y > 0.0 {
                    // Nearest a corner: the distance to it.
                    let corner = radial(a, 0.0);
                    let flip = Matrix2::from_diagonal(&s);
                    Distance {
                        value: corner.value,
                        gradient: flip * corner.gradient,
                        hessian: flip * corner.hessian * flip,
                    }
                } else if a.x >= a.y {
                    Distance {
                        value: a.x,
                        gradient: Vector2::new(s.x, 0.0),
                        hessian: Matrix2::zeros(),
                    }
                } else {
                    Distance {
                        value: a.y,
                        gradient: Vector2::new(0.0, s.y),
                        hessian: Matrix2::zeros(),
                    }
                };
                let (ax, ay) = rect.axes();
                let r = Matrix2::from_columns(&[ax, ay]);
                Distance {
                    value: local.value,
                    gradient: r * local.gradient,
                    hessian: r * local.hessian * r.transpose(),
                }
            }
        }
    }
}

/// The distance from the origin to `delta`, less `radius`.
fn radial(delta: Vector2<f64>, radius: f64) -> Distance {
    let rho = delta.norm();
    if rho == 0.0 {
        return Distance {
            value: -radius,
            gradient: Vector2::zeros(),
            hessian: Matrix2::identity() / Region::MIN_DISTANCE,
        };
    }
    let n = delta / rho;
    Distance {
        value: rho - radius,
        gradient: n,
        hessian: (Matrix2::identity() - n * n.transpose()) / rho.max(Region::MIN_DISTANCE),
    }
}

/// `d(p_k) ≥ clearance` at every state after the initial one, `d` the
/// signed distance from the position `p = (x[position.0], x[position.1])`
/// to `region`. One component, `clearance − d`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clearance {
    /// The region to keep clear of.
    pub region: Region,
    /// The smallest allowed signed distance, m.
    pub clearance: f64,
    /// Indices of the position components in the state.
    pub position: (usize, usize),
}

impl<const NX: usize, const NU: usize> Constraint<NX, NU> for Clearance {
    fn dim(&self) -> usize {
        1
    }

    fn applies(&self, knot: Knot) -> bool {
        knot != Knot::Stage(0)
    }

    fn value(&self, _i: usize, x: &SVector<f64, NX>, _u: &SVector<f64, NU>) -> f64 {
        self.clearance - self.region.signed_distance(&position_of(x, self.position))
    }

    fn linearize(
        &self,
        _i: usize,
        x: &SVector<f64, NX>,
        _u: &SVector<f64, NU>,
    ) -> (f64, SVector<f64, NX>, SVector<f64, NU>) {
        let d = self.region.distance(&position_of(x, self.position));
        let mut c_x = SVector::zeros();
        c_x[self.position.0] = -d.gradient.x;
        c_x[self.position.1] = -d.gradient.y;
        (self.clearance - d.value, c_x, SVector::zeros())
    }

    fn values_along(
        &self,
        states: &[SVector<f64, NX>],
        _controls: &[SVector<f64, NU>],
        f: &mut dyn FnMut(usize, usize, f64),
    ) {
        // Every state after the initial one.
        for (k, x) in states.iter().enumerate().skip(1) {
            f(
                k,
                0,
                self.clearance - self.region.signed_distance(&position_of(x, self.position)),
            );
        }
    }
}

/// Everything a constrained solve must meet: control bounds (met exactly,
/// by the backward pass and the rollouts) and the other constraints (met
/// to a tolerance by the augmented Lagrangian).
pub struct Constraints<const NX: usize, const NU: usize> {
    /// Bounds on the controls, if any.
    pub control: Option<ControlBounds<NU>>,
    /// The other constraints.
    pub other: Vec<Box<dyn Constraint<NX, NU>>>,
}

impl<const NX: usize, const NU: usize> Default for Constraints<NX, NU> {
    fn default() -> Self {
        Self {
            control: None,
            other: Vec::new(),
        }
    }
}

impl<const NX: usize, const NU: usize> Constraints<NX, NU> {
    /// No constraints at all.
    pub fn is_empty(&self) -> bool {
        self.control.is_none() && self.components() == 0
    }

    /// The number of scalar components of the other constraints at a knot
    /// (the sum of their `dim`s).
    pub fn components(&self) -> usize {
        self.other.iter().map(|c| c.dim()).sum()
    }

    /// The largest violation along a trajectory (`states` has one more
    /// entry than `controls`), of the other constraints: `max(c, 0)`, or
    /// `|c|` for equalities. Control bounds are met exactly and not counted.
    pub fn violation(&self, states: &[SVector<f64, NX>], controls: &[SVector<f64, NU>]) -> f64 {
        let mut worst = 0.0f64;
        self.for_each_value(states, controls, |_, _, _, c, eq| {
            worst = worst.max(violation(c, eq));
        });
        worst
    }

    /// Calls `f(constraint, component, knot, value, equality)` for every
    /// component at every knot where its constraint applies (`knot` is
    /// `0..N` for stages, `N` for the terminal state).
    pub fn for_each_value(
        &self,
        states: &[SVector<f64, NX>],
        controls: &[SVector<f64, NU>],
        mut f: impl FnMut(usize, usize, usize, f64, bool),
    ) {
        for (j, c) in self.other.iter().enumerate() {
            // Equalities are rare (a zero goal tolerance): ask once per
            // component, not at every knot.
            let dim = c.dim();
            let equalities: Vec<bool> = (0..dim).map(|i| c.is_equality(i)).collect();
            c.values_along(states, controls, &mut |k, i, value| {
                f(j, i, k, value, equalities[i]);
            });
        }
    }
}
