//! The optimised Riccati step against the textbook formulas (eqs. 31–48)
//! written with plain nalgebra products and a matrix inverse, on random
//! inputs: dense and sparse Jacobians, with and without regularisation,
//! with the zeros found at run time and with a stated [`Sparsity`].

use ilqr::{Sparsity, StageExpansion, Value, riccati_step};
use nalgebra::{SMatrix, SVector};
use proptest::prelude::*;

type M6 = SMatrix<f64, 6, 6>;
type M62 = SMatrix<f64, 6, 2>;

/// What the step must return, computed the obvious way.
#[allow(non_snake_case)]
struct Reference {
    K: SMatrix<f64, 2, 6>,
    d: SVector<f64, 2>,
    V_x: SVector<f64, 6>,
    V_xx: M6,
    dv1: f64,
    dv2: f64,
}

#[allow(non_snake_case)]
fn reference(A: &M6, B: &M62, l: &StageExpansion<6, 2>, next: &Value<6>, mu: f64) -> Reference {
    let (V_x, V_xx) = (next.V_x, next.V_xx);
    let Q_x = l.l_x + A.transpose() * V_x;
    let Q_u = l.l_u + B.transpose() * V_x;
    let Q_xx = l.l_xx + A.transpose() * V_xx * A;
    let Q_uu = l.l_uu + B.transpose() * V_xx * B;
    let Q_ux = l.l_ux + B.transpose() * V_xx * A;
    let inv = (Q_uu + SMatrix::<f64, 2, 2>::identity() * mu)
        .try_inverse()
        .expect("test inputs keep Q_uu + μI invertible");
    let K = -inv * Q_ux;
    let d = -inv * Q_u;
    Reference {
        K,
        d,
        V_x: Q_x + K.transpose() * Q_uu * d + K.transpose() * Q_u + Q_ux.transpose() * d,
        V_xx: Q_xx + K.transpose() * Q_uu * K + K.transpose() * Q_ux + Q_ux.transpose() * K,
        dv1: d.dot(&Q_u),
        dv2: 0.5 * d.dot(&(Q_uu * d)),
    }
}

fn close<const R: usize, const C: usize>(
    what: &str,
    got: &SMatrix<f64, R, C>,
    want: &SMatrix<f64, R, C>,
) -> Result<(), TestCaseError> {
    let scale = want.amax().max(1.0);
    let err = (got - want).amax();
    prop_assert!(
        err <= 1e-9 * scale,
        "{what}: max error {err:e} (scale {scale:e})\ngot {got}\nwant {want}"
    );
    Ok(())
}

fn entries<const N: usize>(sparsity: f64) -> impl Strategy<Value = Vec<f64>> {
    proptest::collection::vec(
        (-2.0..2.0f64, 0.0..1.0f64).prop_map(move |(v, p)| if p < sparsity { 0.0 } else { v }),
        N,
    )
}

prop_compose! {
    /// A well-posed knot: random (possibly sparse) Jacobians, a positive
    /// definite next-step `V_xx`, and a stage expansion whose `l_uu` keeps
    /// `Q_uu` positive definite.
    #[allow(non_snake_case)]
    fn knot()(
        sparsity in prop_oneof![Just(0.0), Just(0.6)],
    )(
        a in entries::<36>(sparsity),
        b in entries::<12>(sparsity),
        g in entries::<36>(0.0),
        h in entries::<36>(0.0),
        v_x in entries::<6>(0.0),
        l_x in entries::<6>(0.0),
        l_u in entries::<2>(0.0),
        l_ux in entries::<12>(0.0),
        mu in prop_oneof![Just(0.0), 1e-6..10.0f64],
    ) -> (M6, M62, StageExpansion<6, 2>, Value<6>, f64) {
        let A = M6::identity() + M6::from_column_slice(&a) * 0.1;
        let B = M62::from_column_slice(&b);
        let G = M6::from_column_slice(&g);
        let H = M6::from_column_slice(&h);
        let next = Value { V_x: SVector::from_column_slice(&v_x), V_xx: G * G.transpose() + M6::identity() };
        let l = StageExpansion {
            l_x: SVector::from_column_slice(&l_x),
            l_u: SVector::from_column_slice(&l_u),
            // Symmetric and indefinite, like the obstacle term's Hessian.
            l_xx: H + H.transpose(),
            l_uu: SMatrix::<f64, 2, 2>::identity() * 0.2,
            l_ux: SMatrix::<f64, 2, 6>::from_column_slice(&l_ux),
        };
        (A, B, l, next, mu)
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    #[allow(non_snake_case)]
    fn riccati_step_matches_the_textbook_formulas((A, B, l, next, mu) in knot()) {
        let want = reference(&A, &B, &l, &next, mu);
        // The zeros found at run time, then stated: exactly where they
        // are, and (a pattern may be loose) not at all.
        let exact = pattern_of(&A, &B);
        let unstated = riccati_step(&A, &B, &l, &next, mu, None).expect("Q_uu + μI is positive definite");
        for sparsity in [None, Some(&exact), Some(&Sparsity::DENSE)] {
            let got = riccati_step(&A, &B, &l, &next, mu, sparsity).expect("Q_uu + μI is positive definite");
            close("K", &got.K, &want.K)?;
            close("d", &got.d, &want.d)?;
            close("V_x", &got.value.V_x, &want.V_x)?;
            close("V_xx", &got.value.V_xx, &want.V_xx)?;
            prop_assert_eq!(got.value.V_xx, got.value.V_xx.transpose(), "V_xx is exactly symmetric");
            let scale = want.dv1.abs().max(1.0);
            prop_assert!((got.dv1 - want.dv1).abs() <= 1e-9 * scale);
            prop_assert!((got.dv2 - want.dv2).abs() <= 1e-9 * scale);
        }
        // Skipping the same zeros by the pattern as by the test at run time
        // leaves every sum as it was (equal under `==`; the dot products
        // the pattern shortens add only exact zeros).
        prop_assert_eq!(riccati_step(&A, &B, &l, &next, mu, Some(&exact)), Some(unstated));
    }
}

/// The pattern of the non-zero entries of `(A, B)`.
#[allow(non_snake_case)]
fn pattern_of(A: &M6, B: &M62) -> Sparsity<6, 2> {
    let mut p = Sparsity::DENSE;
    for j in 0..6 {
        for i in 0..6 {
            p.state[j][i] = A[(i, j)] != 0.0;
        }
        for (c, column) in p.control.iter_mut().enumerate() {
            column[j] = B[(j, c)] != 0.0;
        }
    }
    p
}

/// A stated pattern is trusted, not checked, in a release build: an entry
/// outside it is taken as zero. (What makes a model's pattern right is its
/// own test, in `derivatives.rs`.) This shows the pattern is what the step
/// uses. A debug build asserts instead that the matrices fit it.
#[test]
#[allow(non_snake_case)]
fn entries_outside_a_stated_pattern_are_taken_as_zero() {
    let B = M62::from_column_slice(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
    let next = Value {
        V_x: SVector::from([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]),
        V_xx: M6::identity() * 2.0,
    };
    let mut l = StageExpansion::zeros();
    l.l_uu = SMatrix::<f64, 2, 2>::identity() * 0.2;
    // A with one entry the pattern leaves out, and the same A without it.
    let mut A = M6::identity();
    A[(0, 3)] = 0.05;
    let mut pattern = pattern_of(&M6::identity(), &B);
    let without = riccati_step(&M6::identity(), &B, &l, &next, 0.0, None).unwrap();
    if cfg!(debug_assertions) {
        let broken =
            std::panic::catch_unwind(|| riccati_step(&A, &B, &l, &next, 0.0, Some(&pattern)));
        assert!(
            broken.is_err(),
            "a debug build refuses A outside its pattern"
        );
    } else {
        let with = riccati_step(&A, &B, &l, &next, 0.0, Some(&pattern)).unwrap();
        assert_eq!(with, without);
    }
    // Stated, the entry counts.
    pattern.state[3][0] = true;
    let stated = riccati_step(&A, &B, &l, &next, 0.0, Some(&pattern)).unwrap();
    assert_eq!(stated, riccati_step(&A, &B, &l, &next, 0.0, None).unwrap());
    assert_ne!(stated, without);
}

/// `Q_uu + μI` that is not positive definite is reported, not factorised.
#[test]
#[allow(non_snake_case)]
fn an_indefinite_q_uu_is_rejected_until_mu_is_large_enough() {
    let A = M6::identity();
    let B = M62::from_column_slice(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
    let next = Value {
        V_x: SVector::zeros(),
        V_xx: M6::from_diagonal(&SVector::from([1.0, 1.0, 1.0, -3.0, 1.0, 1.0])),
    };
    let mut l = StageExpansion::zeros();
    l.l_uu = SMatrix::<f64, 2, 2>::identity() * 0.2;
    // Q_uu = diag(0.2 − 3, 0.2 + 1): one negative eigenvalue, −2.8.
    for sparsity in [None, Some(&pattern_of(&A, &B))] {
        assert!(riccati_step(&A, &B, &l, &next, 0.0, sparsity).is_none());
        assert!(riccati_step(&A, &B, &l, &next, 2.7, sparsity).is_none());
        assert!(riccati_step(&A, &B, &l, &next, 2.9, sparsity).is_some());
    }
}
