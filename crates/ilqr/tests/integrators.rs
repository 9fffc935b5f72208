//! The models and integrators beside the quadrotor under Euler
//! (`derivatives.rs`): the unicycle's Jacobians and curvature, and RK4's
//! Jacobians, curvature and sparsity pattern against central finite
//! differences of its step, for both models; and RK4's order of accuracy
//! against the unicycle's closed-form arcs.

use ilqr::{ContinuousDynamics, DiscreteDynamics, Euler, Model, Quadrotor2D, Rk4, Unicycle};
use nalgebra::{SMatrix, SVector};
use proptest::prelude::*;

const H: f64 = 1e-6;

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * (1.0 + a.abs().max(b.abs()))
}

fn assert_close<const R: usize, const C: usize>(
    analytic: &SMatrix<f64, R, C>,
    numeric: &SMatrix<f64, R, C>,
    tol: f64,
    what: &str,
) -> Result<(), TestCaseError> {
    for i in 0..R {
        for j in 0..C {
            prop_assert!(
                close(analytic[(i, j)], numeric[(i, j)], tol),
                "{what}[{i},{j}]: analytic {} vs numeric {}",
                analytic[(i, j)],
                numeric[(i, j)]
            );
        }
    }
    Ok(())
}

/// Central-difference Jacobian of `f` at `z`.
fn jacobian<const N: usize, const M: usize>(
    f: impl Fn(&SVector<f64, N>) -> SVector<f64, M>,
    z: &SVector<f64, N>,
) -> SMatrix<f64, M, N> {
    let mut out = SMatrix::<f64, M, N>::zeros();
    for j in 0..N {
        let mut e = SVector::<f64, N>::zeros();
        e[j] = H;
        out.set_column(j, &((f(&(z + e)) - f(&(z - e))) / (2.0 * H)));
    }
    out
}

/// A discrete map's `(A, B)` and its λ-weighted curvature against finite
/// differences of its step and of `λᵀ(A, B)`.
fn check_discrete<const NX: usize, const NU: usize, D: DiscreteDynamics<NX, NU>>(
    d: &D,
    x: &SVector<f64, NX>,
    u: &SVector<f64, NU>,
    lambda: &SVector<f64, NX>,
) -> Result<(), TestCaseError> {
    let (a, b) = d.linearize(x, u);
    assert_close(&a, &jacobian(|x| d.step(x, u), x), 1e-6, "A")?;
    assert_close(&b, &jacobian(|u| d.step(x, u), u), 1e-6, "B")?;
    let c = d
        .curvature(x, u, lambda)
        .expect("both models give curvature");
    // The gradient of λᵀF is (Aᵀλ, Bᵀλ); its Jacobian is the curvature.
    let grad_x =
        |x: &SVector<f64, NX>, u: &SVector<f64, NU>| d.linearize(x, u).0.transpose() * lambda;
    let grad_u =
        |x: &SVector<f64, NX>, u: &SVector<f64, NU>| d.linearize(x, u).1.transpose() * lambda;
    assert_close(&c.xx, &jacobian(|x| grad_x(x, u), x), 1e-5, "xx")?;
    assert_close(&c.ux, &jacobian(|x| grad_u(x, u), x), 1e-5, "ux")?;
    assert_close(&c.uu, &jacobian(|u| grad_u(x, u), u), 1e-5, "uu")?;
    // A pattern, where stated, covers every entry that is not zero.
    if let Some(p) = D::SPARSITY {
        prop_assert!(p.admits(&a, &b), "A {a} B {b} outside the pattern");
    }
    Ok(())
}

fn quadrotor() -> impl Strategy<Value = Quadrotor2D> {
    (0.1..5.0f64, 0.1..5.0f64, 0.1..2.0f64, 0.0..20.0f64).prop_map(|(m, i, r, g)| Quadrotor2D {
        mass: m,
        inertia: i,
        arm_length: r,
        gravity: g,
    })
}

fn vector<const N: usize>(range: std::ops::Range<f64>) -> impl Strategy<Value = SVector<f64, N>> {
    prop::collection::vec(range, N).prop_map(|v| SVector::from_column_slice(&v))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn unicycle_jacobians_and_curvature_match_finite_differences(
        x in vector::<3>(-10.0..10.0), u in vector::<2>(-5.0..5.0), lambda in vector::<3>(-100.0..100.0),
    ) {
        let m = Unicycle;
        let (f_x, f_u) = m.jacobians(&x, &u);
        assert_close(&f_x, &jacobian(|x| m.derivative(x, &u), &x), 1e-6, "f_x")?;
        assert_close(&f_u, &jacobian(|u| m.derivative(&x, u), &u), 1e-6, "f_u")?;
        let pattern = Unicycle::JACOBIAN_SPARSITY.expect("the unicycle states its pattern");
        prop_assert!(pattern.admits(&f_x, &f_u));
        // Euler's curvature is dt times the model's, so this checks both.
        check_discrete(&Euler { model: m, dt: 0.1 }, &x, &u, &lambda)?;
    }

    #[test]
    fn rk4_unicycle_matches_finite_differences(
        x in vector::<3>(-10.0..10.0), u in vector::<2>(-5.0..5.0), lambda in vector::<3>(-100.0..100.0),
        dt in 0.001..0.5f64,
    ) {
        check_discrete(&Rk4 { model: Unicycle, dt }, &x, &u, &lambda)?;
    }

    #[test]
    fn rk4_quadrotor_matches_finite_differences(
        m in quadrotor(), x in vector::<6>(-10.0..10.0), u in vector::<2>(-20.0..20.0),
        lambda in vector::<6>(-100.0..100.0), dt in 0.001..0.2f64,
    ) {
        check_discrete(&Rk4 { model: m, dt }, &x, &u, &lambda)?;
    }
}

/// RK4's pattern is the model's through four stages: the quadrotor's
/// velocity-to-position chain fills `A`'s upper blocks and makes `B`
/// reach the positions, which Euler's does not.
#[test]
fn rk4_pattern_reaches_through_the_stages() {
    let euler = <Euler<Quadrotor2D> as DiscreteDynamics<6, 2>>::SPARSITY.unwrap();
    let rk4 = <Rk4<Quadrotor2D> as DiscreteDynamics<6, 2>>::SPARSITY.unwrap();
    // θ → ẋ → x: two stages, so RK4's A has (0, 2) and Euler's does not.
    assert!(!euler.state[2][0] && rk4.state[2][0]);
    // u → ẋ → x.
    assert!(!euler.control[0][0] && rk4.control[0][0]);
    // Nothing drives θ but the rotors and θ̇: A's row 2 stays (2, 2), (2, 5).
    for j in 0..6 {
        assert_eq!(rk4.state[j][2], j == 2 || j == 5, "A[2][{j}]");
    }
    // Every Euler entry is an RK4 entry.
    for j in 0..6 {
        for i in 0..6 {
            assert!(!euler.state[j][i] || rk4.state[j][i]);
        }
    }
}

/// The unicycle at constant `(v, ω)` drives an arc: after time t,
/// `x = x0 + v/ω·(sin(θ0 + ωt) − sin θ0)`, `y = y0 − v/ω·(cos(θ0 + ωt) − cos θ0)`.
fn arc(x0: &SVector<f64, 3>, v: f64, w: f64, t: f64) -> SVector<f64, 3> {
    let th = x0[2] + w * t;
    SVector::<f64, 3>::new(
        x0[0] + v / w * (th.sin() - x0[2].sin()),
        x0[1] - v / w * (th.cos() - x0[2].cos()),
        th,
    )
}

fn flown<D: DiscreteDynamics<3, 2>>(
    d: &D,
    x0: &SVector<f64, 3>,
    u: &SVector<f64, 2>,
    steps: usize,
) -> SVector<f64, 3> {
    (0..steps).fold(*x0, |x, _| d.step(&x, u))
}

/// Over a fixed 2 s, halving the step divides RK4's error by about 16
/// (fourth order) and Euler's by about 2 (first order).
#[test]
fn rk4_is_fourth_order_and_euler_first_on_an_arc() {
    let x0 = SVector::<f64, 3>::new(1.0, -2.0, 0.3);
    let u = SVector::<f64, 2>::new(1.5, 0.8);
    let exact = arc(&x0, u[0], u[1], 2.0);
    let error = |rk4: bool, steps: usize| {
        let dt = 2.0 / steps as f64;
        let x = if rk4 {
            flown(
                &Rk4 {
                    model: Unicycle,
                    dt,
                },
                &x0,
                &u,
                steps,
            )
        } else {
            flown(
                &Euler {
                    model: Unicycle,
                    dt,
                },
                &x0,
                &u,
                steps,
            )
        };
        (x - exact).norm()
    };
    for steps in [10, 20, 40] {
        let ratio = error(true, steps) / error(true, 2 * steps);
        assert!(
            (14.0..18.0).contains(&ratio),
            "RK4 at {steps} steps: ratio {ratio}"
        );
        let ratio = error(false, steps) / error(false, 2 * steps);
        assert!(
            (1.8..2.2).contains(&ratio),
            "Euler at {steps} steps: ratio {ratio}"
        );
    }
    assert!(error(true, 20) < 1e-6, "{}", error(true, 20));
}

/// The metadata the service builds its wire format from is consistent:
/// one name per component, parameters within their own bounds, the
/// position inside the state.
#[test]
fn models_describe_themselves_consistently() {
    fn check<const NX: usize, const NU: usize, M: Model<NX, NU>>() {
        let (px, py) = M::POSITION;
        assert!(px < NX && py < NX && px != py, "{}", M::NAME);
        assert_eq!(M::STATE[px].unit, "m");
        assert_eq!(M::STATE[py].unit, "m");
        for p in M::PARAMETERS {
            assert!(
                p.minimum <= p.default && p.default <= p.maximum,
                "{}",
                p.name
            );
        }
        let defaults: Vec<f64> = M::PARAMETERS.iter().map(|p| p.default).collect();
        let m = M::from_parameters(&defaults);
        assert!(m.rest_controls().iter().all(|u| u.is_finite()));
        // At rest and from rest the model stays where it is (no drift).
        let x = SVector::<f64, NX>::zeros();
        let ẋ = m.derivative(&x, &m.rest_controls());
        assert!(ẋ.norm() < 1e-12, "{}: {ẋ}", M::NAME);
    }
    check::<6, 2, Quadrotor2D>();
    check::<3, 2, Unicycle>();
    assert_eq!(
        Quadrotor2D::from_parameters(&[2.0, 3.0, 0.5, 1.62]),
        Quadrotor2D {
            mass: 2.0,
            inertia: 3.0,
            arm_length: 0.5,
            gravity: 1.62
        }
    );
}
