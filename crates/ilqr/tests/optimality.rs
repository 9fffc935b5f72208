//! What `Status::Converged` promises, checked from outside the solver: the
//! returned controls are a local minimum of the discrete problem (the
//! rollout cost `J(u_0, …, u_{N−1})`), on the seed and on 40 random
//! problems.
//!
//! The checks use the exact gradient of `J` (an adjoint recursion, itself
//! checked against finite differences of rollouts) and its Hessian
//! (finite differences of that gradient, so it includes the dynamics'
//! second derivatives, which iLQR leaves out of its model):
//!
//! * **First order.** A Newton step on that Hessian, scored by rollouts,
//!   gains at most 100 times the solver's tolerance, relative
//!   ([`STATIONARY`]).
//! * **Second order.** Where the exact Hessian was used throughout (no
//!   convex fallback), the Hessian is positive definite, and `J` itself
//!   curves upward along its softest direction. A converged solve after
//!   the convex fallback is only claimed stationary (the fallback cannot
//!   tell a minimum from a maximum) and gets the first check alone.
//!
//! Each check is also shown failing where it should: on a solve stopped after
//! three iterations, and beside a light new obstacle. With the default
//! tolerance at 1e-8 instead of 1e-9 the first check fails (a converged solve
//! leaves 5.3e-7); at 1e-7 both do.

use crate::common;

use std::sync::atomic::AtomicBool;

use common::{Lcg, MODEL, Seed, hover, seed_problem};
use ilqr::{
    ControlEffort, Cost, DiscreteDynamics, Euler, ExpObstacle, Objective, Options, Problem, Solver,
    StageExpansion, StateTracking, Status, TerminalExpansion, TerminalTracking,
};
use nalgebra::{DMatrix, DVector, SMatrix, SVector, Vector2};

/// `J(us)`: the cost of the rollout of `us` from `x0`.
fn total_cost(p: &Seed, us: &[Vector2<f64>]) -> f64 {
    let mut x = p.x0;
    let mut j = 0.0;
    for (k, u) in us.iter().enumerate() {
        j += p.cost.stage(k, &x, u);
        x = p.dynamics.step(&x, u);
    }
    j + p.cost.terminal(&x)
}

/// `∇J(us)` by central differences of whole rollouts, `[u_0; u_1; …]`,
/// at relative step `h`: only to check [`adjoint_gradient`] with.
fn fd_gradient(p: &Seed, us: &[Vector2<f64>], h: f64) -> Vec<f64> {
    let mut v = us.to_vec();
    let mut g = Vec::with_capacity(2 * us.len());
    for k in 0..us.len() {
        for i in 0..2 {
            let step = h * (1.0 + us[k][i].abs());
            v[k][i] = us[k][i] + step;
            let up = total_cost(p, &v);
            v[k][i] = us[k][i] - step;
            let down = total_cost(p, &v);
            v[k][i] = us[k][i];
            g.push((up - down) / (2.0 * step));
        }
    }
    g
}

/// `∇J(us)` by the adjoint recursion `λ_N = ∂l_f/∂x`,
/// `∂J/∂u_k = l_u + Bᵀλ_{k+1}`, `λ_k = l_x + Aᵀλ_{k+1}`: exact up to
/// round-off, so that its differences give the Hessian. (Finite
/// differences of `J` itself are not precise enough near an optimum: on
/// long horizons their truncation error exceeds the gradient there.)
fn adjoint_gradient(p: &Seed, us: &[Vector2<f64>]) -> DVector<f64> {
    let n = us.len();
    let mut xs = Vec::with_capacity(n + 1);
    xs.push(p.x0);
    for (k, u) in us.iter().enumerate() {
        xs.push(p.dynamics.step(&xs[k], u));
    }
    let mut terminal = TerminalExpansion::zeros();
    p.cost.terminal_expand(&xs[n], &mut terminal);
    let mut lambda: SVector<f64, 6> = terminal.l_x;
    let mut g = DVector::zeros(2 * n);
    for k in (0..n).rev() {
        let mut e = StageExpansion::zeros();
        p.cost.stage_expand(k, &xs[k], &us[k], &mut e);
        let (a, b): (SMatrix<f64, 6, 6>, SMatrix<f64, 6, 2>) = p.dynamics.linearize(&xs[k], &us[k]);
        let g_u = e.l_u + b.transpose() * lambda;
        g[2 * k] = g_u[0];
        g[2 * k + 1] = g_u[1];
        lambda = e.l_x + a.transpose() * lambda;
    }
    g
}

/// The Hessian of `J` at `us`: central differences of the adjoint
/// gradient at relative step 1e-7, symmetrised. Truncation error grows
/// with the step squared: on random problem 3 the smallest eigenvalue is
/// −65 at 1e-5, −0.05 at 1e-6 and 0.0278 at 1e-7 and 1e-8, which a
/// second difference of `J` itself along its eigenvector confirms.
fn hessian(p: &Seed, us: &[Vector2<f64>]) -> DMatrix<f64> {
    let m = 2 * us.len();
    let mut h = DMatrix::zeros(m, m);
    let mut v = us.to_vec();
    for c in 0..m {
        let (k, i) = (c / 2, c % 2);
        let step = 1e-7 * (1.0 + us[k][i].abs());
        v[k][i] = us[k][i] + step;
        let up = adjoint_gradient(p, &v);
        v[k][i] = us[k][i] - step;
        let down = adjoint_gradient(p, &v);
        v[k][i] = us[k][i];
        h.set_column(c, &((up - down) / (2.0 * step)));
    }
    (&h + h.transpose()) * 0.5
}

/// What the neighbourhood of `us` looks like to an outside observer.
struct Local {
    /// The largest relative decrease of `J` along the Newton direction
    /// `−|H|⁻¹∇J` (eigenvalues of the Hessian taken by magnitude, so that
    /// it is a descent direction wherever the Hessian is indefinite), over
    /// steps 1, 1/2, …, 2⁻³⁰, each scored by a rollout; 0 if none lowers it.
    newton_gain: f64,
    /// What the quadratic model predicts that step gains, relative:
    /// `½·∇Jᵀ|H|⁻¹∇J / |J|`. Unlike `newton_gain` it cannot hide a wrong
    /// gradient (which points the step uphill, where no step gains).
    predicted_gain: f64,
    /// The smallest eigenvalue of the Hessian.
    lambda_min: f64,
    /// The curvature of `J` itself along that eigenvalue's eigenvector `v`:
    /// `(J(u + s·v) + J(u − s·v) − 2·J(u)) / s²` at `s = 1e-3`. Its
    /// round-off, about 8e-16·|J|/s², is below 4e-5 on these
    /// problems, against a smallest λ_min of 4.3e-3.
    softest_curvature: f64,
}

fn examine(p: &Seed, us: &[Vector2<f64>]) -> Local {
    let g = adjoint_gradient(p, us);
    let eigen = hessian(p, us).symmetric_eigen();
    let j = total_cost(p, us);
    let shifted = |d: &DVector<f64>, t: f64| -> Vec<Vector2<f64>> {
        us.iter()
            .enumerate()
            .map(|(k, u)| u + t * Vector2::new(d[2 * k], d[2 * k + 1]))
            .collect()
    };
    let largest = eigen.eigenvalues.amax();
    let in_basis = eigen.eigenvectors.tr_mul(&g);
    // The floor only guards a division by zero: above round-off it would
    // shorten the step along the softest directions, which are the ones
    // that matter here (at 1e-12 · |λ|max it cuts random problem 3's gain
    // from 6.9e-10 to 9.2e-11).
    let scaled = in_basis.zip_map(&eigen.eigenvalues, |c, l| -c / l.abs().max(1e-15 * largest));
    let predicted = -0.5 * in_basis.dot(&scaled) / j.abs();
    let newton = &eigen.eigenvectors * scaled;
    let mut best = 0.0f64;
    for e in 0..=30 {
        let moved = shifted(&newton, 0.5f64.powi(e));
        best = best.min((total_cost(p, &moved) - j) / j.abs());
    }
    let softest = eigen.eigenvalues.imin();
    let v = eigen.eigenvectors.column(softest).into_owned();
    let s = 1e-3;
    let curvature =
        (total_cost(p, &shifted(&v, s)) + total_cost(p, &shifted(&v, -s)) - 2.0 * j) / (s * s);
    Local {
        newton_gain: -best,
        predicted_gain: predicted,
        lambda_min: eigen.eigenvalues[softest],
        softest_curvature: curvature,
    }
}

/// A hundred times the default `Options::tolerance`. `Converged` means a
/// full iLQR step gained less than `tolerance·|J|`, but iLQR's model leaves
/// out the dynamics' second derivatives and converges only linearly in
/// narrow valleys, so a Newton step on the exact Hessian can still find a
/// little more: up to 1.65e-8 relative on these problems (random problems
/// 18 and 20, converged after 151 and 157 iterations). With the tolerance
/// at 1e-8 instead, converged solves leave up to 5.3e-7.
const STATIONARY: f64 = 1e-7;

/// A problem like the seed with everything drawn: horizon 50, 100 or 150,
/// dt 0.02–0.1 s, start and goal at rest anywhere in a 10 m square, weights
/// over decades, and 0–3 obstacles (q 10–1e4) within 1 m of the straight
/// path.
fn random_problem(rng: &mut Lcg) -> Seed {
    let horizon = [50, 100, 150][(rng.unit() * 3.0) as usize];
    let dt = rng.range(0.02, 0.1);
    let at_rest = |rng: &mut Lcg| {
        SVector::from([
            rng.range(-5.0, 5.0),
            rng.range(-5.0, 5.0),
            0.0,
            0.0,
            0.0,
            0.0,
        ])
    };
    let x0 = at_rest(rng);
    let goal = at_rest(rng);
    let mut cost = Objective::new()
        .with_stage(StateTracking {
            goal,
            weights: SVector::repeat(10f64.powf(rng.range(-1.0, 1.0))),
        })
        .with_stage(ControlEffort {
            weights: Vector2::repeat(10f64.powf(rng.range(-2.0, 0.0))),
        })
        .with_terminal(TerminalTracking {
            goal,
            weights: SVector::repeat(10f64.powf(rng.range(2.0, 5.0))),
        });
    for _ in 0..(rng.unit() * 4.0) as usize {
        let t = rng.unit();
        let on_path = x0.fixed_rows::<2>(0) * (1.0 - t) + goal.fixed_rows::<2>(0) * t;
        cost = cost.with_stage(ExpObstacle {
            center: Vector2::new(
                on_path[0] + rng.range(-1.0, 1.0),
                on_path[1] + rng.range(-1.0, 1.0),
            ),
            weight: 10f64.powf(rng.range(1.0, 4.0)),
            position: (0, 1),
        });
    }
    Problem {
        dynamics: Euler { model: MODEL, dt },
        cost,
        x0,
        horizon,
    }
}

/// The seed, then `count` random problems.
fn problems(count: usize) -> Vec<Seed> {
    let mut rng = Lcg(1);
    std::iter::once(seed_problem(100, 0.05))
        .chain((0..count).map(|_| random_problem(&mut rng)))
        .collect()
}

fn solve(p: &Seed, options: &Options) -> (Vec<Vector2<f64>>, ilqr::Summary) {
    let mut solver = Solver::new(p.horizon);
    let summary = solver
        .solve(p, &hover(p.horizon), options, &AtomicBool::new(false))
        .expect("valid problem");
    (solver.controls().to_vec(), summary)
}

/// The adjoint gradient the checks below rest on agrees with finite
/// differences of whole rollouts, away from an optimum (at the hover
/// guesses), where the gradient is large against their truncation error.
#[test]
fn the_adjoint_gradient_matches_finite_differences() {
    for (i, p) in problems(10).iter().enumerate() {
        let us = hover(p.horizon);
        let adjoint = adjoint_gradient(p, &us);
        let fd = DVector::from_vec(fd_gradient(p, &us, 1e-6));
        let err = (&fd - &adjoint).norm() / adjoint.norm();
        assert!(err < 1e-6, "problem {i}: relative difference {err:e}");
    }
}

#[test]
fn converged_solves_are_stationary() {
    let mut converged = 0;
    for (i, p) in problems(40).iter().enumerate() {
        let (us, summary) = solve(p, &Options::default());
        if summary.status != Status::Converged {
            continue;
        }
        converged += 1;
        let local = examine(p, &us);
        assert!(
            local.newton_gain <= STATIONARY && local.predicted_gain <= STATIONARY,
            "problem {i}: converged, but a Newton step lowers the cost by {:e} relative \
             ({:e} predicted)",
            local.newton_gain,
            local.predicted_gain
        );
    }
    // 40 of the 41 converge (the other stops at the iteration cap); the
    // check must not pass by having nothing to check.
    assert!(converged >= 35, "only {converged} of 41 converged");
}

#[test]
fn converged_solves_on_the_exact_hessian_are_local_minima() {
    let mut checked = 0;
    for (i, p) in problems(40).iter().enumerate() {
        let (us, summary) = solve(p, &Options::default());
        if summary.status != Status::Converged || summary.convexified_after.is_some() {
            continue;
        }
        checked += 1;
        let local = examine(p, &us);
        assert!(
            local.lambda_min > 0.0 && local.softest_curvature > 0.0,
            "problem {i}: converged, but the Hessian's smallest eigenvalue is {:e} and the \
             cost's curvature along it {:e}",
            local.lambda_min,
            local.softest_curvature
        );
    }
    assert!(checked >= 35, "only {checked} of 41 checked");
}

/// The checks above can fail: a solve stopped after three iterations is
/// not stationary, and the seed's optimum with a light obstacle (q = 10)
/// added 1 m beside its midpoint sits in negative curvature that is small
/// against the rest of the Hessian (λ_max ≈ 3e8).
#[test]
fn the_checks_catch_an_unfinished_solve_and_negative_curvature() {
    let seed = seed_problem(100, 0.05);
    let three = Options {
        max_iterations: 3,
        ..Options::default()
    };
    let (early, summary) = solve(&seed, &three);
    assert_eq!(summary.status, Status::MaxIterations);
    let gain = examine(&seed, &early).newton_gain;
    assert!(gain > 1e3 * STATIONARY, "gain {gain:e} after 3 iterations");

    let (optimum, _) = solve(&seed, &Options::default());
    let mut x = seed.x0;
    for u in &optimum[..50] {
        x = seed.dynamics.step(&x, u);
    }
    let mut moved = seed_problem(100, 0.05);
    moved.cost = moved.cost.with_stage(ExpObstacle {
        center: Vector2::new(x[0] + 1.0, x[1]),
        weight: 10.0,
        position: (0, 1),
    });
    let local = examine(&moved, &optimum);
    assert!(local.lambda_min < 0.0, "λ_min {:e}", local.lambda_min);
    assert!(
        local.softest_curvature < 0.0,
        "curvature {:e}",
        local.softest_curvature
    );
}

/// Where the rollout of `us` crosses the obstacle's height: its x there.
fn x_beside_the_obstacle(p: &Seed, us: &[Vector2<f64>]) -> f64 {
    let mut x = p.x0;
    for u in us {
        let next = p.dynamics.step(&x, u);
        if (x[1] - common::OBSTACLE[1]) * (next[1] - common::OBSTACLE[1]) <= 0.0 {
            return x[0];
        }
        x = next;
    }
    panic!("the path never reaches the obstacle's height");
}

/// The seed's 5520.212 (the reference solvers' answer, from hover) is a
/// local minimum west of the obstacle, not the only one: pushed east by a
/// second obstacle, then released, the solve settles on a cheaper minimum
/// east of it. Both pass the first- and second-order checks.
#[test]
fn the_seed_has_a_cheaper_local_minimum_east_of_the_obstacle() {
    let seed = seed_problem(100, 0.05);
    let mut pushed = seed_problem(100, 0.05);
    pushed.cost = pushed.cost.with_stage(ExpObstacle {
        center: Vector2::new(2.0, 5.0),
        weight: 3000.0,
        position: (0, 1),
    });
    let (detour, _) = solve(&pushed, &Options::default());
    let mut solver = Solver::new(seed.horizon);
    let summary = solver
        .solve(&seed, &detour, &Options::default(), &AtomicBool::new(false))
        .expect("valid problem");
    assert_eq!(summary.status, Status::Converged);
    assert_eq!(summary.convexified_after, None);
    let east = solver.controls().to_vec();
    let (west, _) = solve(&seed, &Options::default());

    let (j_east, j_west) = (total_cost(&seed, &east), total_cost(&seed, &west));
    assert!((j_west - common::SEED_OPTIMUM).abs() < 1e-3, "{j_west}");
    assert!((j_east - 5418.304).abs() < 1e-3, "{j_east}");
    assert!(x_beside_the_obstacle(&seed, &west) < common::OBSTACLE[0] - 2.0);
    assert!(x_beside_the_obstacle(&seed, &east) > common::OBSTACLE[0] + 2.0);
    for (side, us) in [("west", &west), ("east", &east)] {
        let local = examine(&seed, us);
        assert!(
            local.newton_gain <= STATIONARY && local.predicted_gain <= STATIONARY,
            "{side}: a Newton step gains {:e}",
            local.newton_gain
        );
        assert!(
            local.lambda_min > 0.0 && local.softest_curvature > 0.0,
            "{side}: λ_min {:e}, curvature {:e}",
            local.lambda_min,
            local.softest_curvature
        );
    }
}

/// A slow descent is not cut short by one poor full step. On this problem (a
/// light, agile vehicle without gravity, a strong terminal weight) the steps
/// gain 2e-3 to 8e-3 each until one full step predicts 7.7e-3 and gains
/// 7.6e-6, under `tolerance·|J|` (2.2e-5), at a cost still 4.3e-6 relative
/// above IPOPT's 21681.40098; the model at the new iterate predicts that a
/// full step would gain 1300 times the tolerance. That model must agree
/// before the step's small gain counts.
#[test]
fn one_poor_full_step_does_not_end_a_slow_descent() {
    let goal = SVector::from([-1.9650065416112303, -3.4448468852091563, 0.0, 0.0, 0.0, 0.0]);
    let p: Seed = Problem {
        dynamics: Euler {
            model: ilqr::Quadrotor2D {
                mass: 3.98847831512413,
                inertia: 0.08662667330322268,
                arm_length: 0.18068063403433382,
                gravity: 0.0,
            },
            dt: 0.02,
        },
        cost: Objective::new()
            .with_stage(StateTracking {
                goal,
                weights: SVector::repeat(0.04488415090710977),
            })
            .with_stage(ControlEffort {
                weights: Vector2::repeat(0.0008742490110706006),
            })
            .with_stage(ExpObstacle {
                center: Vector2::new(-1.5404541335471904, -2.0005816366373304),
                weight: 8400.644157717266,
                position: (0, 1),
            })
            .with_terminal(TerminalTracking {
                goal,
                weights: SVector::repeat(7395.625958596107),
            }),
        x0: SVector::from([-0.28555167403484916, 2.307701268405669, 0.0, 0.0, 0.0, 0.0]),
        horizon: 30,
    };
    let mut solver = Solver::new(p.horizon);
    let summary = solver
        .solve(
            &p,
            &vec![Vector2::zeros(); 30],
            &Options::default(),
            &AtomicBool::new(false),
        )
        .expect("valid problem");
    assert_eq!(summary.status, Status::Converged);
    let us = solver.controls().to_vec();
    let local = examine(&p, &us);
    assert!(
        local.newton_gain <= STATIONARY && local.predicted_gain <= STATIONARY,
        "converged, but a Newton step gains {:e} ({:e} predicted)",
        local.newton_gain,
        local.predicted_gain
    );
    let ipopt = 21681.40098;
    assert!(
        (summary.cost - ipopt) / ipopt < STATIONARY,
        "cost {}",
        summary.cost
    );
}
