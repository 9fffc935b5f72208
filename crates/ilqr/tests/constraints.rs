//! Hard constraints: the shapes' signed distances and the constraints'
//! Jacobians against finite differences, and constrained solves checked for
//! what they promise (bounds exact, states the rollout of the controls,
//! violation under the tolerance, `Infeasible` where nothing is feasible)
//! and against IPOPT's optimum of ALTRO's three-obstacle Dubins car.

use std::sync::atomic::AtomicBool;

use ilqr::{
    Clearance, Constraint, Constraints, ControlBounds, DiscreteDynamics, GoalTolerance, Knot,
    Options, Rectangle, Region, Shape, ShapeObstacle, Solver, StageCost, StageExpansion,
    StateBounds, Status, ViaPath,
};
use nalgebra::{SVector, Vector2};

use crate::common;

fn regions() -> Vec<Region> {
    let c = Vector2::new(1.0, -2.0);
    vec![
        Region {
            center: c,
            shape: Shape::Point,
        },
        Region {
            center: c,
            shape: Shape::Circle { radius: 0.7 },
        },
        Region {
            center: c,
            shape: Shape::Rectangle(Rectangle::new(Vector2::new(1.0, 2.0), 0.0)),
        },
        Region {
            center: c,
            shape: Shape::Rectangle(Rectangle::new(Vector2::new(1.0, 2.0), 0.3)),
        },
        Region {
            center: c,
            shape: Shape::Rectangle(Rectangle::new(Vector2::new(3.0, 0.5), -2.1)),
        },
    ]
}

/// Points around the region: outside its faces, beyond its corners, inside.
fn points() -> Vec<Vector2<f64>> {
    let mut out = Vec::new();
    for i in 0..24 {
        let a = f64::from(i) * 0.2618 + 0.05;
        for r in [0.13, 0.41, 0.9, 1.7, 3.2] {
            out.push(Vector2::new(1.0 + r * a.cos(), -2.0 + r * a.sin()));
        }
    }
    out
}

#[test]
fn signed_distance_gradient_and_curvature_match_finite_differences() {
    let h = 1e-6;
    for region in regions() {
        for p in points() {
            let d = region.distance(&p);
            for axis in 0..2 {
                let mut e = Vector2::zeros();
                e[axis] = h;
                let (plus, minus) = (region.distance(&(p + e)), region.distance(&(p - e)));
                // Skip points where a central difference straddles a kink
                // (the medial axis inside a rectangle).
                if (plus.gradient - minus.gradient).norm() > 1e-3 {
                    continue;
                }
                let fd = (plus.value - minus.value) / (2.0 * h);
                assert!(
                    (fd - d.gradient[axis]).abs() < 1e-6,
                    "{region:?} at {p:?}: ∂d/∂p{axis} {} vs {fd}",
                    d.gradient[axis]
                );
                let fd2 = (plus.gradient - minus.gradient) / (2.0 * h);
                for b in 0..2 {
                    assert!(
                        (fd2[b] - d.hessian[(b, axis)]).abs() < 1e-5,
                        "{region:?} at {p:?}: ∂²d {} vs {}",
                        d.hessian[(b, axis)],
                        fd2[b]
                    );
                }
            }
        }
    }
}

#[test]
fn signed_distance_is_negative_inside_and_known_at_known_points() {
    let rect = Region {
        center: Vector2::new(7.0, 6.0),
        shape: Shape::Rectangle(Rectangle::new(Vector2::new(1.0, 2.0), 0.0)),
    };
    let at = |x: f64, y: f64| rect.distance(&Vector2::new(x, y)).value;
    assert!((at(7.0, 6.0) + 0.5).abs() < 1e-15);
    assert!((at(8.0, 6.0) - 0.5).abs() < 1e-15);
    assert!((at(7.0, 8.0) - 1.0).abs() < 1e-15);
    assert!((at(8.5, 8.0) - 1.0f64.hypot(1.0)).abs() < 1e-15);
    // Turned a quarter turn, width and height swap.
    let turned = Region {
        center: Vector2::new(7.0, 6.0),
        shape: Shape::Rectangle(Rectangle::new(
            Vector2::new(1.0, 2.0),
            std::f64::consts::FRAC_PI_2,
        )),
    };
    assert!((turned.distance(&Vector2::new(9.0, 6.0)).value - 1.0).abs() < 1e-12);
    let circle = Region {
        center: Vector2::new(2.0, 6.0),
        shape: Shape::Circle { radius: 0.5 },
    };
    assert!((circle.distance(&Vector2::new(2.0, 6.2)).value + 0.3).abs() < 1e-15);
}

/// Each constraint's `linearize` against central differences of `value`.
fn check_jacobian<const NX: usize, const NU: usize>(
    c: &dyn Constraint<NX, NU>,
    x: SVector<f64, NX>,
    u: SVector<f64, NU>,
) {
    let h = 1e-6;
    for i in 0..c.dim() {
        let (value, c_x, c_u) = c.linearize(i, &x, &u);
        assert_eq!(value, c.value(i, &x, &u));
        for j in 0..NX {
            let mut e = SVector::<f64, NX>::zeros();
            e[j] = h;
            let fd = (c.value(i, &(x + e), &u) - c.value(i, &(x - e), &u)) / (2.0 * h);
            assert!(
                (fd - c_x[j]).abs() < 1e-6,
                "component {i}, ∂/∂x{j}: {} vs {fd}",
                c_x[j]
            );
        }
        for j in 0..NU {
            let mut e = SVector::<f64, NU>::zeros();
            e[j] = h;
            let fd = (c.value(i, &x, &(u + e)) - c.value(i, &x, &(u - e))) / (2.0 * h);
            assert!(
                (fd - c_u[j]).abs() < 1e-6,
                "component {i}, ∂/∂u{j}: {} vs {fd}",
                c_u[j]
            );
        }
    }
}

#[test]
fn constraint_jacobians_match_finite_differences() {
    let x = SVector::<f64, 6>::from([1.3, -1.1, 0.2, 0.5, -0.3, 0.1]);
    let u = SVector::<f64, 2>::from([4.0, 6.0]);
    let inf = f64::INFINITY;
    let bounds = StateBounds::new(
        &SVector::from([-inf, 0.0, -0.35, -inf, -1.0, -inf]),
        &SVector::from([inf, 9.0, 0.35, inf, inf, 2.0]),
    );
    assert_eq!(Constraint::<6, 2>::dim(&bounds), 6);
    check_jacobian::<6, 2>(&bounds, x, u);
    let goal = GoalTolerance::new(
        common::goal(),
        &SVector::from([0.01, 0.0, 0.05, 0.1, 0.0, inf]),
    );
    assert_eq!(Constraint::<6, 2>::dim(&goal), 2 + 1 + 2 + 2 + 1);
    check_jacobian::<6, 2>(&goal, x, u);
    for region in regions() {
        let clear = Clearance {
            region,
            clearance: 0.2,
            position: (0, 1),
        };
        for p in points() {
            let mut x = x;
            (x[0], x[1]) = (p.x, p.y);
            let kink = {
                let g = |q: Vector2<f64>| region.distance(&q).gradient;
                (g(p + Vector2::new(1e-6, 0.0)) - g(p - Vector2::new(1e-6, 0.0))).norm()
                    + (g(p + Vector2::new(0.0, 1e-6)) - g(p - Vector2::new(0.0, 1e-6))).norm()
            };
            if kink < 1e-3 {
                check_jacobian::<6, 2>(&clear, x, u);
            }
        }
    }
    // Where each applies: never at the given initial state.
    assert!(!Constraint::<6, 2>::applies(&bounds, Knot::Stage(0)));
    assert!(Constraint::<6, 2>::applies(&bounds, Knot::Stage(1)));
    assert!(Constraint::<6, 2>::applies(&bounds, Knot::Terminal));
    assert!(!Constraint::<6, 2>::applies(&goal, Knot::Stage(5)));
    assert!(Constraint::<6, 2>::applies(&goal, Knot::Terminal));
}

#[test]
fn shaped_soft_obstacle_expansion_matches_finite_differences() {
    let h = 1e-5;
    for region in regions() {
        let term = ShapeObstacle {
            region,
            weight: 1000.0,
            position: (0, 1),
        };
        for p in points() {
            let x = SVector::<f64, 6>::from([p.x, p.y, 0.0, 0.0, 0.0, 0.0]);
            let u = SVector::<f64, 2>::zeros();
            let mut e = StageExpansion::<6, 2>::zeros();
            term.expand(0, &x, &u, &mut e);
            for a in 0..2 {
                let mut dx = SVector::<f64, 6>::zeros();
                dx[a] = h;
                let mut ep = StageExpansion::<6, 2>::zeros();
                let mut em = StageExpansion::<6, 2>::zeros();
                term.expand(0, &(x + dx), &u, &mut ep);
                term.expand(0, &(x - dx), &u, &mut em);
                if (ep.l_x - em.l_x).norm() > 1e-2 * (1.0 + e.l_xx.norm()) * 2.0 * h * 1e3 {
                    continue; // a kink of the distance between the two points
                }
                let v = |x: &SVector<f64, 6>| StageCost::<6, 2>::value(&term, 0, x, &u);
                let fd = (v(&(x + dx)) - v(&(x - dx))) / (2.0 * h);
                assert!(
                    (fd - e.l_x[a]).abs() < 1e-4 * (1.0 + fd.abs()),
                    "{region:?} {p:?}"
                );
                for b in 0..2 {
                    let fd2 = (ep.l_x[b] - em.l_x[b]) / (2.0 * h);
                    assert!(
                        (fd2 - e.l_xx[(b, a)]).abs() < 1e-3 * (1.0 + fd2.abs()),
                        "{region:?} {p:?}: {} vs {fd2}",
                        e.l_xx[(b, a)]
                    );
                }
            }
        }
    }
}

/// IPOPT's optimum of the Dubins car in this crate's cost convention (no
/// ½, no dt), the 377.4202: what IPOPT reaches from most starts
/// (controls [1, 0], or this solver's answer). From ALTRO's own start
/// (controls 0.01) IPOPT goes round the other side, to 481.6134.
/// BENCHMARKS.md has the commands.
pub const DUBINS_IPOPT: f64 = 377.4202298140171;

/// A default constrained solve of `problem` from `u0`.
fn solve<D: DiscreteDynamics<NX, NU>, C: ilqr::Cost<NX, NU>, const NX: usize, const NU: usize>(
    problem: &ilqr::Problem<D, C, NX>,
    constraints: &Constraints<NX, NU>,
    u0: Vec<SVector<f64, NU>>,
) -> (Solver<NX, NU>, ilqr::Summary) {
    let mut solver = Solver::new(problem.horizon);
    let cancel = AtomicBool::new(false);
    let summary = solver
        .solve_constrained(
            problem,
            constraints,
            &u0,
            &Options::default(),
            &cancel,
            &mut |_| {},
        )
        .unwrap();
    (solver, summary)
}

/// What every constrained solve promises, whatever its status.
fn check_promises<D: DiscreteDynamics<NX, NU>, const NX: usize, const NU: usize>(
    solver: &Solver<NX, NU>,
    dynamics: &D,
    bounds: Option<&ControlBounds<NU>>,
) {
    let (xs, us) = (solver.states(), solver.controls());
    for (k, u) in us.iter().enumerate() {
        assert_eq!(
            xs[k + 1],
            dynamics.step(&xs[k], u),
            "states are the rollout, step {k}"
        );
        if let Some(b) = bounds {
            for i in 0..NU {
                assert!(
                    u[i] >= b.lower[i] && u[i] <= b.upper[i],
                    "u_{k}[{i}] = {}",
                    u[i]
                );
            }
        }
    }
}

#[test]
fn dubins_three_obstacles_reaches_ipopts_optimum() {
    let (problem, constraints) = common::dubins();
    let (solver, summary) = solve(
        &problem,
        &constraints,
        vec![SVector::from([0.01, 0.01]); 100],
    );
    assert_eq!(summary.status, Status::Converged);
    assert!(summary.constraint_violation <= 1e-6);
    assert!(
        ((summary.cost - DUBINS_IPOPT) / DUBINS_IPOPT).abs() < 1e-6,
        "{}",
        summary.cost
    );
    check_promises(&solver, &problem.dynamics, constraints.control.as_ref());
}

#[test]
fn a_goal_inside_a_hard_obstacle_is_infeasible_quickly() {
    let (mut problem, mut constraints) = common::dubins();
    problem.horizon = 100;
    constraints.other.push(Box::new(Clearance {
        region: Region {
            center: Vector2::new(3.0, 3.0),
            shape: Shape::Circle { radius: 0.3 },
        },
        clearance: 0.0,
        position: (0, 1),
    }));
    let (solver, summary) = solve(
        &problem,
        &constraints,
        vec![SVector::from([0.01, 0.01]); 100],
    );
    assert_eq!(summary.status, Status::Infeasible);
    assert!(summary.constraint_violation > 1e-3 && summary.constraint_violation.is_finite());
    assert!(summary.cost.is_finite());
    check_promises(&solver, &problem.dynamics, constraints.control.as_ref());
}

#[test]
fn the_seed_with_thrust_bounds_keeps_them_exactly() {
    let problem = common::seed_problem(100, 0.05);
    let constraints = Constraints {
        control: Some(ControlBounds {
            lower: SVector::from([0.0, 0.0]),
            upper: SVector::from([20.0, 20.0]),
        }),
        other: Vec::new(),
    };
    let (solver, summary) = solve(
        &problem,
        &constraints,
        vec![SVector::repeat(common::MODEL.hover_thrust()); 100],
    );
    assert_eq!(summary.status, Status::Converged);
    check_promises(&solver, &problem.dynamics, constraints.control.as_ref());
    // The optimum without the bounds pulls on a rotor (−11.6 N): with them
    // some control sits on the lower bound, exactly.
    assert!(solver.controls().iter().any(|u| u.min() == 0.0));
}

/// The guiding solve's route: `w‖p_k − r_k‖²` at every stage, `r_k` on the
/// two legs through the via-point at constant speed; its gradient and
/// Hessian those of finite differences.
#[test]
fn via_path_term_matches_its_route_and_finite_differences() {
    let term = ViaPath {
        from: Vector2::new(0.0, 0.0),
        via: Vector2::new(4.0, 2.0),
        to: Vector2::new(6.0, 10.0),
        knot: 4,
        horizon: 8,
        reach: 8,
        weight: 3.0,
        position: (1, 3),
    };
    assert_eq!(term.point(0), Vector2::new(0.0, 0.0));
    assert_eq!(term.point(2), Vector2::new(2.0, 1.0));
    assert_eq!(term.point(4), Vector2::new(4.0, 2.0));
    assert_eq!(term.point(6), Vector2::new(5.0, 6.0));
    assert_eq!(term.point(8), Vector2::new(6.0, 10.0));
    let x = SVector::<f64, 6>::from([9.0, 0.4, 5.0, 1.1, -2.0, 3.0]);
    let u = SVector::<f64, 2>::zeros();
    let v = |k: usize, x: &SVector<f64, 6>| StageCost::<6, 2>::value(&term, k, x, &u);
    // Position (x[1], x[3]) = (0.4, 1.1) against (2, 1) at stage 2.
    assert!((v(2, &x) - 3.0 * (1.6f64.powi(2) + 0.1f64.powi(2))).abs() < 1e-12);
    for k in [0, 3, 4, 7] {
        let mut e = StageExpansion::<6, 2>::zeros();
        term.expand(k, &x, &u, &mut e);
        let h = 1e-6;
        for a in 0..6 {
            let mut dx = SVector::<f64, 6>::zeros();
            dx[a] = h;
            let fd = (v(k, &(x + dx)) - v(k, &(x - dx))) / (2.0 * h);
            assert!(
                (fd - e.l_x[a]).abs() < 1e-5 * (1.0 + fd.abs()),
                "l_x[{a}] at {k}"
            );
        }
        for (i, j) in [(1, 1), (3, 3)] {
            assert_eq!(e.l_xx[(i, j)], 6.0);
        }
        assert_eq!(e.l_xx.iter().filter(|v| **v != 0.0).count(), 2);
    }
    // Within `reach` of the via-point's stage only.
    let near = ViaPath { reach: 1, ..term };
    for (k, pulled) in [(2, false), (3, true), (4, true), (5, true), (6, false)] {
        let mut e = StageExpansion::<6, 2>::zeros();
        near.expand(k, &x, &u, &mut e);
        assert_eq!(e != StageExpansion::<6, 2>::zeros(), pulled, "stage {k}");
        assert_eq!(StageCost::<6, 2>::value(&near, k, &x, &u) > 0.0, pulled);
    }
}
