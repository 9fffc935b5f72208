//! Analytic derivatives against central finite differences at random
//! points: the dynamics Jacobians (eq. 11) and every cost term's gradient and
//! Hessian (eqs. 18–23), including the obstacle's indefinite Hessian; and
//! the Jacobians' stated sparsity pattern against both.

use ilqr::{
    ContinuousDynamics, ControlEffort, DiscreteDynamics, Euler, ExpObstacle, Quadrotor2D,
    StageCost, StageExpansion, StateTracking, TerminalCost, TerminalExpansion, TerminalTracking,
};
use nalgebra::{SMatrix, SVector, Vector2};
use proptest::prelude::*;

const H: f64 = 1e-6;

fn state() -> impl Strategy<Value = SVector<f64, 6>> {
    prop::array::uniform6(-10.0..10.0f64).prop_map(SVector::from)
}

fn control() -> impl Strategy<Value = Vector2<f64>> {
    prop::array::uniform2(-20.0..20.0f64).prop_map(Vector2::from)
}

fn model() -> impl Strategy<Value = Quadrotor2D> {
    (0.1..5.0f64, 0.1..5.0f64, 0.1..2.0f64, 0.0..20.0f64).prop_map(|(m, i, r, g)| Quadrotor2D {
        mass: m,
        inertia: i,
        arm_length: r,
        gravity: g,
    })
}

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

/// Gradient of a scalar function, as a column.
fn gradient<const N: usize>(
    f: impl Fn(&SVector<f64, N>) -> f64,
    z: &SVector<f64, N>,
) -> SVector<f64, N> {
    jacobian(|z| SVector::<f64, 1>::new(f(z)), z).transpose()
}

/// A stage term's full model over z = [x; u].
fn stage_model(
    term: &dyn StageCost<6, 2>,
    z: &SVector<f64, 8>,
) -> (f64, SVector<f64, 8>, SMatrix<f64, 8, 8>) {
    let (x, u) = (
        z.fixed_rows::<6>(0).into_owned(),
        z.fixed_rows::<2>(6).into_owned(),
    );
    let mut e = StageExpansion::<6, 2>::zeros();
    term.expand(0, &x, &u, &mut e);
    let mut g = SVector::<f64, 8>::zeros();
    g.fixed_rows_mut::<6>(0).copy_from(&e.l_x);
    g.fixed_rows_mut::<2>(6).copy_from(&e.l_u);
    let mut h = SMatrix::<f64, 8, 8>::zeros();
    h.fixed_view_mut::<6, 6>(0, 0).copy_from(&e.l_xx);
    h.fixed_view_mut::<2, 2>(6, 6).copy_from(&e.l_uu);
    h.fixed_view_mut::<2, 6>(6, 0).copy_from(&e.l_ux);
    h.fixed_view_mut::<6, 2>(0, 6)
        .copy_from(&e.l_ux.transpose());
    (term.value(0, &x, &u), g, h)
}

fn check_stage_term(
    term: &dyn StageCost<6, 2>,
    z: &SVector<f64, 8>,
    tol: f64,
) -> Result<(), TestCaseError> {
    let value = |z: &SVector<f64, 8>| stage_model(term, z).0;
    let grad = |z: &SVector<f64, 8>| stage_model(term, z).1;
    let (_, g, h) = stage_model(term, z);
    assert_close(&g, &gradient(value, z), tol, "gradient")?;
    assert_close(&h, &jacobian(grad, z), tol, "hessian")?;
    Ok(())
}

fn joined(x: &SVector<f64, 6>, u: &Vector2<f64>) -> SVector<f64, 8> {
    let mut z = SVector::<f64, 8>::zeros();
    z.fixed_rows_mut::<6>(0).copy_from(x);
    z.fixed_rows_mut::<2>(6).copy_from(u);
    z
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn quadrotor_jacobians_match_finite_differences(m in model(), x in state(), u in control()) {
        let (f_x, f_u) = m.jacobians(&x, &u);
        assert_close(&f_x, &jacobian(|x| m.derivative(x, &u), &x), 1e-6, "f_x")?;
        assert_close(&f_u, &jacobian(|u| m.derivative(&x, u), &u), 1e-6, "f_u")?;
    }

    /// The step's second derivatives weighted by a covector (DDP's terms):
    /// the Jacobian of `λᵀ·(A, B)` in `(x, u)`.
    #[test]
    fn euler_curvature_matches_finite_differences(
        m in model(), x in state(), u in control(), dt in 0.001..0.2f64,
        lambda in prop::array::uniform6(-100.0..100.0f64),
    ) {
        let d = Euler { model: m, dt };
        let lambda = SVector::from(lambda);
        let c = d.curvature(&x, &u, &lambda).expect("the quadrotor gives its curvature");
        // The gradient of λᵀF, as a function of (x, u), is [Aᵀλ; Bᵀλ].
        let grad = |z: &SVector<f64, 8>| {
            let (x, u) = (z.fixed_rows::<6>(0).into_owned(), z.fixed_rows::<2>(6).into_owned());
            let (a, b) = d.linearize(&x, &u);
            joined(&(a.transpose() * lambda), &(b.transpose() * lambda))
        };
        let h = jacobian(grad, &joined(&x, &u));
        assert_close(&c.xx, &h.fixed_view::<6, 6>(0, 0).into_owned(), 1e-5, "xx")?;
        assert_close(&c.ux, &h.fixed_view::<2, 6>(6, 0).into_owned(), 1e-5, "ux")?;
        assert_close(&c.uu, &h.fixed_view::<2, 2>(6, 6).into_owned(), 1e-5, "uu")?;
    }

    /// The solver takes the entries outside the stated pattern as zero
    /// without looking, so it must hold everywhere: for the analytic
    /// Jacobians exactly, and for the finite differences of the vector
    /// field (the pattern is the model's, not only its Jacobians').
    #[test]
    fn quadrotor_jacobians_fit_their_stated_pattern(
        m in model(), x in state(), u in control(), dt in 0.001..0.2f64,
    ) {
        let pattern = Quadrotor2D::JACOBIAN_SPARSITY.expect("the quadrotor states its pattern");
        let (f_x, f_u) = m.jacobians(&x, &u);
        prop_assert!(pattern.admits(&f_x, &f_u), "f_x {f_x} f_u {f_u}");
        let fd_x = jacobian(|x| m.derivative(x, &u), &x);
        let fd_u = jacobian(|u| m.derivative(&x, u), &u);
        let zero_outside = |used: &[[bool; 6]], fd: &[[f64; 6]]| {
            used.iter().flatten().zip(fd.iter().flatten()).all(|(&used, &v)| used || v.abs() < 1e-9)
        };
        prop_assert!(zero_outside(&pattern.state, &fd_x.data.0), "{fd_x}");
        prop_assert!(zero_outside(&pattern.control, &fd_u.data.0), "{fd_u}");
        // Euler's adds the diagonal of I.
        let d = Euler { model: m, dt };
        let stepped = <Euler<Quadrotor2D> as DiscreteDynamics<6, 2>>::SPARSITY.expect("Euler keeps it");
        prop_assert_eq!(stepped, pattern.with_identity());
        let (a, b) = d.linearize(&x, &u);
        prop_assert!(stepped.admits(&a, &b), "A {a} B {b}");
    }

    #[test]
    fn euler_linearisation_matches_finite_differences(m in model(), x in state(), u in control(), dt in 0.001..0.2f64) {
        let d = Euler { model: m, dt };
        let (a, b) = d.linearize(&x, &u);
        assert_close(&a, &jacobian(|x| d.step(x, &u), &x), 1e-6, "A")?;
        assert_close(&b, &jacobian(|u| d.step(&x, u), &u), 1e-6, "B")?;
    }

    #[test]
    fn quadratic_terms_match_finite_differences(
        x in state(), u in control(), goal in state(),
        w in prop::array::uniform6(0.0..100.0f64), r in prop::array::uniform2(0.0..10.0f64),
    ) {
        let z = joined(&x, &u);
        check_stage_term(&StateTracking { goal, weights: SVector::from(w) }, &z, 1e-5)?;
        check_stage_term(&ControlEffort { weights: Vector2::from(r) }, &z, 1e-5)?;

        let t = TerminalTracking { goal, weights: SVector::from(w) };
        let mut e = TerminalExpansion::<6>::zeros();
        t.expand(&x, &mut e);
        assert_close(&e.l_x, &gradient(|x| t.value(x), &x), 1e-5, "terminal gradient")?;
        let grad = |x: &SVector<f64, 6>| { let mut e = TerminalExpansion::zeros(); t.expand(x, &mut e); e.l_x };
        assert_close(&e.l_xx, &jacobian(grad, &x), 1e-5, "terminal hessian")?;
    }

    /// Away from the centre (ρ > 0.05) the obstacle term is smooth and its
    /// Hessian is checked exactly, indefinite parts included.
    #[test]
    fn obstacle_term_matches_finite_differences(
        x in state(), u in control(), c in prop::array::uniform2(-10.0..10.0f64), q in 0.0..2000.0f64,
    ) {
        let term = ExpObstacle { center: Vector2::from(c), weight: q, position: (0, 1) };
        prop_assume!((Vector2::new(x[0], x[1]) - term.center).norm() > 0.05);
        check_stage_term(&term, &joined(&x, &u), 1e-5)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// The convex expansion keeps the gradient and the curvature away from
    /// the centre, and drops the negative curvature across: its Hessian is
    /// the exact one's projection onto the positive semi-definite matrices.
    #[test]
    fn obstacle_convex_expansion_is_the_psd_projection(
        x in state(), u in control(), c in prop::array::uniform2(-10.0..10.0f64), q in 0.0..2000.0f64,
        // Half the cases within 2 mm of the centre, across the clamp at 1 mm.
        near in prop::option::of((0.0..2e-3f64, 0.0..std::f64::consts::TAU)),
    ) {
        let term = ExpObstacle { center: Vector2::from(c), weight: q, position: (0, 1) };
        let mut x = x;
        if let Some((rho, angle)) = near {
            x[0] = c[0] + rho * angle.cos();
            x[1] = c[1] + rho * angle.sin();
        }
        check_convex_projection(&term, &x, &u)?;
    }
}

/// `term.expand_convex` at `(x, u)` keeps the exact gradient, and its
/// position Hessian is the exact one's projection onto the positive
/// semi-definite matrices (eigenvalues clipped at zero); nothing else.
fn check_convex_projection(
    term: &ExpObstacle,
    x: &SVector<f64, 6>,
    u: &Vector2<f64>,
) -> Result<(), TestCaseError> {
    let (mut exact, mut convex) = (
        StageExpansion::<6, 2>::zeros(),
        StageExpansion::<6, 2>::zeros(),
    );
    term.expand(0, x, u, &mut exact);
    term.expand_convex(0, x, u, &mut convex);
    prop_assert_eq!(exact.l_x, convex.l_x);
    let h = exact.l_xx.fixed_view::<2, 2>(0, 0).into_owned();
    let eig = h.symmetric_eigen();
    let mut d = eig.eigenvalues;
    d.iter_mut().for_each(|v| *v = v.max(0.0));
    let projected =
        eig.eigenvectors * nalgebra::Matrix2::from_diagonal(&d) * eig.eigenvectors.transpose();
    let got = convex.l_xx.fixed_view::<2, 2>(0, 0).into_owned();
    let scale = h.amax().max(1e-300);
    prop_assert!(
        (got - projected).amax() <= 1e-9 * scale,
        "{} vs {}",
        got,
        projected
    );
    // Nothing else is touched.
    let mut rest = convex.l_xx;
    rest.fixed_view_mut::<2, 2>(0, 0).fill(0.0);
    prop_assert_eq!(rest.amax(), 0.0);
    Ok(())
}

/// A case the proptest above draws about once in 4000: just inside the
/// 1 mm clamp, the clamped exact Hessian's radial eigenvalue is still
/// positive (down to 0.9995 mm), and the projection keeps it.
#[test]
fn obstacle_convex_expansion_just_inside_the_clamp() {
    let term = ExpObstacle {
        center: Vector2::zeros(),
        weight: 1493.2718668972875,
        position: (0, 1),
    };
    for rho in [0.999_549_777_195_254_5e-3, 0.9996e-3, 0.9994e-3, 0.5e-3] {
        let x = SVector::from([rho, 0.0, 0.0, 0.0, 0.0, 0.0]);
        check_convex_projection(&term, &x, &Vector2::zeros()).unwrap();
    }
}

#[test]
fn obstacle_hessian_is_indefinite() {
    let term = ExpObstacle {
        center: Vector2::zeros(),
        weight: 1000.0,
        position: (0, 1),
    };
    let x = SVector::<f64, 6>::from([0.5, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let mut e = StageExpansion::<6, 2>::zeros();
    term.expand(0, &x, &Vector2::zeros(), &mut e);
    let eig = e
        .l_xx
        .fixed_view::<2, 2>(0, 0)
        .into_owned()
        .symmetric_eigenvalues();
    assert!(eig.min() < 0.0 && eig.max() > 0.0, "{eig:?}");
}

#[test]
fn obstacle_derivatives_are_finite_at_the_centre() {
    let term = ExpObstacle {
        center: Vector2::new(1.0, 2.0),
        weight: 1000.0,
        position: (0, 1),
    };
    for x in [[1.0, 2.0], [1.0 + 1e-12, 2.0], [1.0, 2.0 - 1e-300]] {
        let x = SVector::<f64, 6>::from([x[0], x[1], 0.0, 0.0, 0.0, 0.0]);
        let mut e = StageExpansion::<6, 2>::zeros();
        term.expand(0, &x, &Vector2::zeros(), &mut e);
        assert!(
            e.l_x.iter().chain(e.l_xx.iter()).all(|v| v.is_finite()),
            "{e:?}"
        );
        assert!((StageCost::<6, 2>::value(&term, 0, &x, &Vector2::zeros()) - 1000.0).abs() < 1e-6);
    }
}
