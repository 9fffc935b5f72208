//! The box-constrained QP ([`solve_box_qp`]) against an independent brute
//! force and the KKT conditions on random problems (M = 1..4, a fixed-seed
//! generator), the closed form where nothing binds, warm starts, malformed
//! and indefinite input, and the clamped feedback gain against nalgebra's
//! dense inverse.

use ilqr::{BoxQpError, BoxQpOptions, BoxQpStatus, solve_box_qp};
use nalgebra::{DMatrix, DVector, SMatrix, SVector};

/// SplitMix64: a fixed-seed source of test problems, independent of any
/// crate's choice of generator.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [a, b).
    fn uniform(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }
}

/// A random box QP: `H = AᵀA + 0.1 I` (symmetric positive definite), `g`
/// large enough that bounds often bind, and bounds of which about one in
/// five is infinite.
struct Qp<const M: usize> {
    h: SMatrix<f64, M, M>,
    g: SVector<f64, M>,
    lower: SVector<f64, M>,
    upper: SVector<f64, M>,
}

fn random_qp<const M: usize>(rng: &mut Rng) -> Qp<M> {
    let a = SMatrix::<f64, M, M>::from_fn(|_, _| rng.uniform(-1.0, 1.0));
    let h = a.transpose() * a + SMatrix::identity() * 0.1;
    let g = SVector::<f64, M>::from_fn(|_, _| rng.uniform(-5.0, 5.0));
    let mut lower = SVector::<f64, M>::zeros();
    let mut upper = SVector::<f64, M>::zeros();
    for i in 0..M {
        lower[i] = if rng.uniform(0.0, 1.0) < 0.2 {
            f64::NEG_INFINITY
        } else {
            rng.uniform(-2.0, 1.0)
        };
        upper[i] = if rng.uniform(0.0, 1.0) < 0.2 {
            f64::INFINITY
        } else if lower[i].is_finite() {
            lower[i] + rng.uniform(0.0, 2.0)
        } else {
            rng.uniform(-1.0, 2.0)
        };
    }
    Qp { h, g, lower, upper }
}

fn objective<const M: usize>(qp: &Qp<M>, u: &SVector<f64, M>) -> f64 {
    qp.g.dot(u) + 0.5 * u.dot(&(qp.h * u))
}

/// Every assignment of each component to {lower, upper, free} (skipping
/// infinite bounds), each solved as an equality-constrained QP with a
/// dense inverse; of the candidates inside the box that satisfy the KKT
/// sign conditions, the one of least objective, with that objective. Also
/// checks that no candidate inside the box has a smaller objective.
fn brute_force<const M: usize>(qp: &Qp<M>) -> (SVector<f64, M>, f64) {
    let mut best: Option<(SVector<f64, M>, f64)> = None;
    let mut least_feasible = f64::INFINITY;
    'assignments: for code in 0..3usize.pow(M as u32) {
        let mut u = SVector::<f64, M>::zeros();
        let mut free = Vec::new();
        let mut c = code;
        for i in 0..M {
            match c % 3 {
                0 if qp.lower[i].is_finite() => u[i] = qp.lower[i],
                1 if qp.upper[i].is_finite() => u[i] = qp.upper[i],
                2 => free.push(i),
                _ => continue 'assignments,
            }
            c /= 3;
        }
        if !free.is_empty() {
            // H_ff u_f = −(g + H u_c)_f with u_c the fixed components.
            let rhs = qp.g + qp.h * u;
            let h_ff = DMatrix::from_fn(free.len(), free.len(), |a, b| qp.h[(free[a], free[b])]);
            let r_f = DVector::from_fn(free.len(), |a, _| -rhs[free[a]]);
            let inverse = h_ff.try_inverse().expect("H_ff is positive definite");
            let u_f = inverse * r_f;
            for (a, &i) in free.iter().enumerate() {
                u[i] = u_f[a];
            }
        }
        let inside = (0..M).all(|i| u[i] >= qp.lower[i] - 1e-12 && u[i] <= qp.upper[i] + 1e-12);
        if !inside {
            continue;
        }
        let value = objective(qp, &u);
        least_feasible = least_feasible.min(value);
        let gradient = qp.h * u + qp.g;
        let kkt = (0..M).all(|i| {
            free.contains(&i)
                || (u[i] == qp.lower[i] && gradient[i] >= -1e-10)
                || (u[i] == qp.upper[i] && gradient[i] <= 1e-10)
        });
        if kkt && best.is_none_or(|(_, v)| value < v) {
            best = Some((u, value));
        }
    }
    let (u, value) = best.expect("a strictly convex box QP has a KKT point");
    assert!(value <= least_feasible + 1e-10);
    (u, value)
}

fn solve<const M: usize>(qp: &Qp<M>, u0: &SVector<f64, M>) -> ilqr::BoxQpSolution<M> {
    solve_box_qp(
        &qp.h,
        &qp.g,
        &qp.lower,
        &qp.upper,
        u0,
        &BoxQpOptions::default(),
    )
    .expect("valid input")
}

fn brute_force_agrees<const M: usize>(rng: &mut Rng, cases: usize) -> usize {
    let mut binding = 0;
    for case in 0..cases {
        let qp = random_qp::<M>(rng);
        let u0 = SVector::<f64, M>::from_fn(|_, _| rng.uniform(-3.0, 3.0));
        let s = solve(&qp, &u0);
        let (u, value) = brute_force(&qp);
        assert_eq!(s.status, BoxQpStatus::Converged, "M = {M}, case {case}");
        assert!(
            (s.u - u).amax() <= 1e-8,
            "M = {M}, case {case}: {} against {}",
            s.u,
            u
        );
        assert!(s.value <= value + 1e-10, "M = {M}, case {case}");
        assert!((s.value - objective(&qp, &s.u)).abs() <= 1e-12 * (1.0 + s.value.abs()));
        binding += usize::from(s.free.iter().any(|&f| !f));
    }
    binding
}

/// The solution is the brute force's, to 1e-8, and its objective is
/// minimal, on 400 random problems for each M in 1..4.
#[test]
fn agrees_with_the_brute_force_over_active_sets() {
    let mut rng = Rng(0x5EED_B0C5);
    let binding = brute_force_agrees::<1>(&mut rng, 400)
        + brute_force_agrees::<2>(&mut rng, 400)
        + brute_force_agrees::<3>(&mut rng, 400)
        + brute_force_agrees::<4>(&mut rng, 400);
    // The problems exercise the bounds: most of them have a clamped control.
    assert!(
        binding > 800,
        "{binding} of 1600 problems had a bound active"
    );
}

fn kkt_holds<const M: usize>(rng: &mut Rng, cases: usize) {
    for case in 0..cases {
        let qp = random_qp::<M>(rng);
        let s = solve(&qp, &SVector::zeros());
        assert_eq!(s.status, BoxQpStatus::Converged);
        let gradient = qp.h * s.u + qp.g;
        assert!((gradient - s.gradient).amax() <= 1e-12);
        for i in 0..M {
            assert!(s.u[i] >= qp.lower[i] && s.u[i] <= qp.upper[i]);
            if s.free[i] {
                assert!(gradient[i].abs() <= 1e-8, "M = {M}, case {case}, {i}");
            } else if s.u[i] == qp.lower[i] {
                assert!(gradient[i] >= 0.0, "M = {M}, case {case}, {i}");
            } else {
                assert_eq!(s.u[i], qp.upper[i], "M = {M}, case {case}, {i}");
                assert!(gradient[i] <= 0.0, "M = {M}, case {case}, {i}");
            }
        }
    }
}

/// At the solution free components have zero gradient, components at
/// their lower bound a gradient ≥ 0 and at their upper bound ≤ 0, and the
/// reported gradient is `H u + g`.
#[test]
fn the_solution_satisfies_kkt() {
    let mut rng = Rng(7);
    kkt_holds::<1>(&mut rng, 200);
    kkt_holds::<2>(&mut rng, 200);
    kkt_holds::<3>(&mut rng, 200);
    kkt_holds::<4>(&mut rng, 200);
    kkt_holds::<6>(&mut rng, 200);
}

/// With infinite bounds the solution is the Newton step `−H⁻¹g`, in one
/// step, every component free.
#[test]
fn unbounded_is_the_newton_step() {
    let mut rng = Rng(11);
    for _ in 0..100 {
        let mut qp = random_qp::<4>(&mut rng);
        qp.lower = SVector::repeat(f64::NEG_INFINITY);
        qp.upper = SVector::repeat(f64::INFINITY);
        let s = solve(&qp, &SVector::from_fn(|_, _| rng.uniform(-3.0, 3.0)));
        let newton = -qp.h.try_inverse().unwrap() * qp.g;
        assert_eq!(s.status, BoxQpStatus::Converged);
        assert_eq!(s.iterations, 1);
        assert_eq!(s.free, [true; 4]);
        assert!((s.u - newton).amax() <= 1e-10 * (1.0 + newton.amax()));
    }
}

/// Warm-started at its own solution, a solve takes at most one step (none
/// where the gradient there is already below the tolerance) and returns
/// the same point and free set.
#[test]
fn a_warm_start_at_the_solution_converges_at_once() {
    let mut rng = Rng(13);
    let mut no_step = 0;
    for _ in 0..300 {
        let qp = random_qp::<4>(&mut rng);
        let cold = solve(&qp, &SVector::zeros());
        assert!(cold.iterations >= 1);
        let warm = solve(&qp, &cold.u);
        assert_eq!(warm.status, BoxQpStatus::Converged);
        assert!(warm.iterations <= 1, "{} steps", warm.iterations);
        assert_eq!(warm.free, cold.free);
        assert!((warm.u - cold.u).amax() <= 1e-12 * (1.0 + cold.u.amax()));
        no_step += usize::from(warm.iterations == 0);
    }
    assert!(no_step > 250, "{no_step} of 300 took no step");
}

/// A warm start outside the box is projected into it first: with no steps
/// allowed, the result is the projection.
#[test]
fn the_warm_start_is_projected_into_the_box() {
    let h = SMatrix::<f64, 2, 2>::identity();
    let g = SVector::<f64, 2>::new(1.0, -1.0);
    let lower = SVector::<f64, 2>::new(-1.0, f64::NEG_INFINITY);
    let upper = SVector::<f64, 2>::new(1.0, 0.5);
    let options = BoxQpOptions {
        max_iterations: 0,
        ..BoxQpOptions::default()
    };
    let u0 = SVector::<f64, 2>::new(5.0, 7.0);
    let s = solve_box_qp(&h, &g, &lower, &upper, &u0, &options).unwrap();
    assert_eq!(s.status, BoxQpStatus::MaxIterations);
    assert_eq!((s.u[0], s.u[1], s.iterations), (1.0, 0.5, 0));
    // Component 1 is at its upper bound with the gradient (−0.5) pushing
    // out: clamped.
    assert_eq!(s.free, [true, false]);
}

/// Malformed input is an error, not a panic: a NaN or infinity in `H`, `g`
/// or the warm start, bounds the wrong way round or NaN, `lower = +∞`,
/// `upper = −∞`, line-search options with which it might not end.
#[test]
fn malformed_input_is_an_error() {
    let h = SMatrix::<f64, 2, 2>::identity();
    let g = SVector::<f64, 2>::new(1.0, -1.0);
    let lower = SVector::<f64, 2>::new(-1.0, -1.0);
    let upper = SVector::<f64, 2>::new(1.0, 1.0);
    let u0 = SVector::<f64, 2>::zeros();
    let o = BoxQpOptions::default();
    let nan = f64::NAN;
    let inf = f64::INFINITY;

    let mut bad_h = h;
    bad_h[(0, 1)] = nan;
    assert_eq!(
        solve_box_qp(&bad_h, &g, &lower, &upper, &u0, &o),
        Err(BoxQpError::NonFiniteHessian)
    );
    bad_h[(0, 1)] = inf;
    assert_eq!(
        solve_box_qp(&bad_h, &g, &lower, &upper, &u0, &o),
        Err(BoxQpError::NonFiniteHessian)
    );
    assert_eq!(
        solve_box_qp(&h, &SVector::from([nan, 0.0]), &lower, &upper, &u0, &o),
        Err(BoxQpError::NonFiniteGradient)
    );
    assert_eq!(
        solve_box_qp(&h, &g, &lower, &upper, &SVector::from([0.0, nan]), &o),
        Err(BoxQpError::NonFiniteStart)
    );
    assert_eq!(
        solve_box_qp(&h, &g, &lower, &upper, &SVector::from([-inf, 0.0]), &o),
        Err(BoxQpError::NonFiniteStart)
    );
    for (lo, hi) in [
        (2.0, 1.0),
        (nan, 1.0),
        (-1.0, nan),
        (inf, inf),
        (-inf, -inf),
    ] {
        let lower = SVector::<f64, 2>::new(-1.0, lo);
        let upper = SVector::<f64, 2>::new(1.0, hi);
        assert_eq!(
            solve_box_qp(&h, &g, &lower, &upper, &u0, &o),
            Err(BoxQpError::InvalidBounds { index: 1 }),
            "[{lo}, {hi}]"
        );
    }
    for (step_decrease, min_step) in [(1.0, 1e-22), (0.0, 1e-22), (nan, 1e-22), (0.5, 0.0)] {
        let o = BoxQpOptions {
            step_decrease,
            min_step,
            ..BoxQpOptions::default()
        };
        assert_eq!(
            solve_box_qp(&h, &g, &lower, &upper, &u0, &o),
            Err(BoxQpError::InvalidOptions),
            "{o:?}"
        );
    }
    // Equal bounds are valid: they fix the component.
    let pinned = SVector::<f64, 2>::new(-1.0, 0.25);
    let upper = SVector::<f64, 2>::new(1.0, 0.25);
    let s = solve_box_qp(&h, &g, &pinned, &upper, &u0, &o).map(|s| (s.u[1], s.status));
    assert_eq!(s, Ok((0.25, BoxQpStatus::Converged)));
}

/// An indefinite `H` on a free set the iteration visits is reported, with
/// no gain; where the bounds clamp the negative curvature away from the
/// start on, the problem is solved.
#[test]
fn an_indefinite_hessian_is_reported_where_it_is_free() {
    let h = SMatrix::<f64, 2, 2>::new(-1.0, 0.0, 0.0, 1.0);
    let g = SVector::<f64, 2>::new(1.0, 1.0);
    let o = BoxQpOptions::default();
    let inf = SVector::<f64, 2>::repeat(f64::INFINITY);
    let s = solve_box_qp(&h, &g, &-inf, &inf, &SVector::zeros(), &o).unwrap();
    assert_eq!(s.status, BoxQpStatus::NotPositiveDefinite);
    assert_eq!(s.feedback_gain(&SMatrix::<f64, 2, 3>::repeat(1.0)), None);

    // A singular H (positive semi-definite) too.
    let singular = SMatrix::<f64, 2, 2>::new(1.0, 1.0, 1.0, 1.0);
    let s = solve_box_qp(&singular, &g, &-inf, &inf, &SVector::zeros(), &o).unwrap();
    assert_eq!(s.status, BoxQpStatus::NotPositiveDefinite);

    // u_0 starts at its lower bound 0 with ∂/∂u_0 = 1 > 0: clamped there
    // for good, and H on {u_1} is positive definite.
    let lower = SVector::<f64, 2>::new(0.0, -10.0);
    let upper = SVector::<f64, 2>::new(0.5, 10.0);
    let s = solve_box_qp(&h, &g, &lower, &upper, &SVector::zeros(), &o).unwrap();
    assert_eq!(s.status, BoxQpStatus::Converged);
    assert_eq!((s.u[0], s.u[1], s.free), (0.0, -1.0, [false, true]));
}

/// Only the symmetric part of `H` counts: `H` and `½(H + Hᵀ)` give the same
/// solution.
#[test]
fn only_the_symmetric_part_of_h_counts() {
    let mut rng = Rng(17);
    for _ in 0..50 {
        let qp = random_qp::<3>(&mut rng);
        let skew = SMatrix::<f64, 3, 3>::from_fn(|_, _| rng.uniform(-1.0, 1.0));
        let skew = skew - skew.transpose();
        let s = solve(&qp, &SVector::zeros());
        let lopsided = Qp {
            h: qp.h + skew,
            ..qp
        };
        let t = solve(&lopsided, &SVector::zeros());
        assert!((s.u - t.u).amax() <= 1e-12, "{} against {}", s.u, t.u);
        assert_eq!(s.free, t.free);
    }
}

/// The feedback gain has zero rows for the clamped controls, and on the
/// free ones `−H_ff⁻¹ (Q_ux)_f`, computed with nalgebra's dense inverse of
/// the free block.
#[test]
fn the_feedback_gain_is_zero_where_clamped_and_newton_where_free() {
    let mut rng = Rng(19);
    let mut mixed = 0;
    for _ in 0..300 {
        let qp = random_qp::<4>(&mut rng);
        let q_ux = SMatrix::<f64, 4, 5>::from_fn(|_, _| rng.uniform(-2.0, 2.0));
        let s = solve(&qp, &SVector::zeros());
        let k = s.feedback_gain(&q_ux).unwrap();
        let free: Vec<usize> = (0..4).filter(|&i| s.free[i]).collect();
        mixed += usize::from(!free.is_empty() && free.len() < 4);
        for i in (0..4).filter(|&i| !s.free[i]) {
            assert!(k.row(i).iter().all(|&x| x == 0.0), "row {i}: {k}");
        }
        if free.is_empty() {
            continue;
        }
        let h_ff = DMatrix::from_fn(free.len(), free.len(), |a, b| qp.h[(free[a], free[b])]);
        let q_f = DMatrix::from_fn(free.len(), 5, |a, c| q_ux[(free[a], c)]);
        let expected = -h_ff.try_inverse().unwrap() * q_f;
        for (a, &i) in free.iter().enumerate() {
            for c in 0..5 {
                let e = expected[(a, c)];
                assert!((k[(i, c)] - e).abs() <= 1e-10 * (1.0 + e.abs()), "{k}");
            }
        }
    }
    assert!(mixed > 100, "{mixed} of 300 had free and clamped controls");
}
