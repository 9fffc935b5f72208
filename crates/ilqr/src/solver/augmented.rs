//! The augmented Lagrangian of a constrained problem (ALTRO's outer loop):
//! the cost the inner iLQR solves minimise, and the multiplier update
//! between them.
//!
//! Each component `c ≤ 0` adds the Powell–Hestenes–Rockafellar term
//! `max(0, λ + ρc)² / 2ρ` (an equality `c = 0` adds `(λ + ρc)² / 2ρ`):
//! smooth, zero where the constraint is slack and its multiplier zero, and
//! never negative, so a cost bounded below by 0 stays so. Its gradient is
//! `max(0, λ + ρc)·∇c`, and its Hessian is taken as `ρ∇c∇cᵀ` where the term
//! is active (Gauss–Newton: the constraint's own curvature is dropped, as
//! ALTRO does), which is positive semi-definite. Between inner solves the
//! multiplier takes the gradient's factor, `λ ← max(0, λ + ρc)`, and ρ
//! grows.

use std::sync::atomic::{AtomicU64, Ordering};

use nalgebra::SVector;

use crate::constraint::{Constraint, Constraints, Knot, violation};
use crate::cost::{Cost, StageExpansion, TerminalExpansion};

/// Largest multiplier: keeps a constraint that cannot be met from driving
/// its multiplier, and the cost, to overflow.
pub(super) const MAX_MULTIPLIER: f64 = 1e8;

/// The base cost plus the penalty terms at multipliers `lambda` and
/// penalties `rho`. `lambda` holds `m` multipliers per knot, knots `0..=N`
/// (the terminal state's last), components in constraint order; `rho` one
/// penalty per component, the same at every knot.
pub(super) struct Augmented<'a, C, const NX: usize, const NU: usize> {
    pub(super) base: &'a C,
    pub(super) constraints: &'a Constraints<NX, NU>,
    pub(super) lambda: &'a [f64],
    pub(super) m: usize,
    pub(super) n: usize,
    pub(super) rho: &'a [f64],
    /// The largest violation of the last rollout under this cost, as
    /// [`Constraints::violation`] counts it: each rollout's penalty terms
    /// evaluate every constraint anyway, so the trace's violation needs no
    /// pass of its own. Reset at stage 0, where every rollout begins;
    /// complete once its terminal state is costed. (An atomic only because
    /// a cost must be `Sync`; one thread uses it.)
    pub(super) worst: Worst,
}

/// An `f64` kept as its bits (see [`Augmented::worst`]).
#[derive(Debug, Default)]
pub(super) struct Worst(AtomicU64);

impl Worst {
    pub(super) fn get(&self) -> f64 {
        f64::from_bits(self.0.load(Ordering::Relaxed))
    }

    fn set(&self, v: f64) {
        self.0.store(v.to_bits(), Ordering::Relaxed);
    }
}

/// `λ + ρc`, cut at 0 for an inequality: the multiplier the update gives,
/// and the penalty's gradient factor.
#[inline]
fn shifted(lambda: f64, rho: f64, c: f64, equality: bool) -> f64 {
    let s = lambda + rho * c;
    if equality { s } else { s.max(0.0) }
}

impl<C, const NX: usize, const NU: usize> Augmented<'_, C, NX, NU> {
    /// Calls `f(multiplier index, component index at the knot, constraint,
    /// component, value, equality)` for each component that applies at
    /// `(knot, x, u)`.
    #[inline]
    fn components(
        &self,
        knot: Knot,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        mut f: impl FnMut(usize, usize, &dyn Constraint<NX, NU>, usize, f64, bool),
    ) {
        let k = match knot {
            Knot::Stage(k) => k,
            Knot::Terminal => self.n,
        };
        let (base, mut at) = (k * self.m, 0);
        for c in &self.constraints.other {
            let c = c.as_ref();
            let first = at;
            at += c.values_at(knot, x, u, &mut |i, value, equality| {
                f(base + first + i, first + i, c, i, value, equality);
            });
        }
    }

    fn penalty(&self, knot: Knot, x: &SVector<f64, NX>, u: &SVector<f64, NU>) -> f64 {
        let mut total = 0.0;
        let mut worst = if knot == Knot::Stage(0) {
            0.0
        } else {
            self.worst.get()
        };
        self.components(knot, x, u, |at, j, _, _, value, equality| {
            worst = worst.max(violation(value, equality));
            let rho = self.rho[j];
            let s = shifted(self.lambda[at], rho, value, equality);
            // Most components are slack with a zero multiplier. Their term
            // is +0, which leaves the sum of terms (each ≥ +0) as it was:
            // skipping its division changes nothing.
            if s != 0.0 {
                total += s * s / (2.0 * rho);
            }
        });
        self.worst.set(worst);
        total
    }

    fn expand_penalty(
        &self,
        knot: Knot,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        self.components(knot, x, u, |at, j, c, i, value, equality| {
            let rho = self.rho[j];
            // Most components are slack with a zero multiplier: their term
            // is zero, and only its value is needed to see that.
            if !equality && shifted(self.lambda[at], rho, value, false) == 0.0 {
                return;
            }
            let (value, c_x, c_u) = c.linearize(i, x, u);
            let s = shifted(self.lambda[at], rho, value, equality);
            e.l_x += c_x * s;
            e.l_u += c_u * s;
            e.l_xx += c_x * c_x.transpose() * rho;
            e.l_uu += c_u * c_u.transpose() * rho;
            e.l_ux += c_u * c_x.transpose() * rho;
        });
    }

    /// The multipliers after an inner solve that ended at `(states,
    /// controls)`: `λ ← max(0, λ + ρc)` (`λ + ρc` for an equality), at most
    /// [`MAX_MULTIPLIER`] in size; and each component's largest violation
    /// along the trajectory, into `violations`.
    pub(super) fn update(
        &self,
        states: &[SVector<f64, NX>],
        controls: &[SVector<f64, NU>],
        out: &mut [f64],
        violations: &mut [f64],
    ) {
        violations.fill(0.0);
        for k in 0..=self.n {
            let (knot, u) = if k < self.n {
                (Knot::Stage(k), controls[k])
            } else {
                (Knot::Terminal, SVector::zeros())
            };
            self.components(knot, &states[k], &u, |at, j, _, _, value, equality| {
                violations[j] = violations[j].max(violation(value, equality));
                let s = shifted(self.lambda[at], self.rho[j], value, equality);
                out[at] = s.clamp(-MAX_MULTIPLIER, MAX_MULTIPLIER);
            });
        }
    }
}

impl<C: Cost<NX, NU>, const NX: usize, const NU: usize> Cost<NX, NU> for Augmented<'_, C, NX, NU> {
    fn stage(&self, k: usize, x: &SVector<f64, NX>, u: &SVector<f64, NU>) -> f64 {
        self.base.stage(k, x, u) + self.penalty(Knot::Stage(k), x, u)
    }

    fn stage_expand(
        &self,
        k: usize,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        self.base.stage_expand(k, x, u, e);
        self.expand_penalty(Knot::Stage(k), x, u, e);
    }

    /// The penalty's Gauss–Newton Hessian is positive semi-definite
    /// already: only the base cost's curvature is dropped.
    fn stage_expand_convex(
        &self,
        k: usize,
        x: &SVector<f64, NX>,
        u: &SVector<f64, NU>,
        e: &mut StageExpansion<NX, NU>,
    ) {
        self.base.stage_expand_convex(k, x, u, e);
        self.expand_penalty(Knot::Stage(k), x, u, e);
    }

    fn has_convex_approximation(&self) -> bool {
        self.base.has_convex_approximation()
    }

    fn terminal(&self, x: &SVector<f64, NX>) -> f64 {
        self.base.terminal(x) + self.penalty(Knot::Terminal, x, &SVector::zeros())
    }

    fn terminal_expand(&self, x: &SVector<f64, NX>, e: &mut TerminalExpansion<NX>) {
        self.base.terminal_expand(x, e);
        let mut stage = StageExpansion::zeros();
        self.expand_penalty(Knot::Terminal, x, &SVector::zeros(), &mut stage);
        e.l_x += stage.l_x;
        e.l_xx += stage.l_xx;
    }
}
