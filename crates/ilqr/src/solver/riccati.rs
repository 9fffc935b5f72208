//! One knot of the backward pass: the Riccati step of eqs. 31–48, in place
//! for the solver's pass and by value for callers ([`riccati_step`]).

use nalgebra::{SMatrix, SVector};

use crate::boxqp::{BoxQpOptions, solve_box_qp};
use crate::cost::StageExpansion;
use crate::dynamics::Sparsity;
use crate::kernels::{
    Nonzeros, add_mul, add_mul_lower, axpy, copy_lower, dot, ldlt, ldlt_solve_right,
    ldlt_solve_vec, mirror_lower, mul_square_sparse, transpose,
};

/// The quadratic model `V(x̄ + δx) ≈ V + V_xᵀδx + ½ δxᵀV_xx δx` of the cost-to-go
/// at one knot (eqs. 27–28).
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Value<const NX: usize> {
    /// Gradient `V_x` (the paper's `s`).
    pub V_x: SVector<f64, NX>,
    /// Hessian `V_xx` (the paper's `S`).
    pub V_xx: SMatrix<f64, NX, NX>,
}

/// The bounds on one knot's step `d` in a control-limited backward pass:
/// the control bounds less the nominal control, and where the box QP
/// starts (the previous pass's `d`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Boxed<const NU: usize> {
    pub(super) lower: SVector<f64, NU>,
    pub(super) upper: SVector<f64, NU>,
    pub(super) start: SVector<f64, NU>,
}

/// What one knot of the backward pass produces.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RiccatiStep<const NX: usize, const NU: usize> {
    /// Feedback gain `K = −(Q_uu + μI)⁻¹ Q_ux` (eq. 44).
    pub K: SMatrix<f64, NU, NX>,
    /// Feedforward `d = −(Q_uu + μI)⁻¹ Q_u` (eq. 43).
    pub d: SVector<f64, NU>,
    /// Cost-to-go at this knot (eqs. 47–48).
    pub value: Value<NX>,
    /// `dᵀQ_u`, the linear part of the expected reduction (eq. 46).
    pub dv1: f64,
    /// `½ dᵀQ_uu d`, its quadratic part.
    pub dv2: f64,
}

/// One knot of the backward pass: eqs. 31–35 form `Q` from the stage
/// expansion `l`, the linearisation `(A, B)` and the next knot's value
/// function; eqs. 43–48 give the gains and this knot's value function.
///
/// `Q_uu` is regularised to `Q_uu + μI` before it is factorised; the value
/// update uses the unregularised `Q_uu` in the form of eqs. 47–48, which stays
/// consistent for any `K` and `d`. Returns `None` when `Q_uu + μI` is not
/// positive definite (or the gains are not finite).
///
/// `sparsity`, where given, says which entries of `A` and `B` can be
/// non-zero (see [`Sparsity`]; the others are taken as zero, untested);
/// without it the exact zeros are found at run time. The results are equal
/// either way (under `==`) whenever `A`, `B` and the value function are
/// finite and `A`, `B` fit the pattern; a debug build asserts the fit.
/// Where a product overflows, an entry inside the pattern that is zero
/// at the point gives `0·∞ = NaN` where the run-time test skipped it; the
/// step then reports `None`, as for any non-finite gain.
///
/// The arithmetic is arranged for speed (see `kernels`): every product is a
/// sum of column axpys, products with `A` and `B` skip their zeros, the
/// symmetric `Q_xx` and `V_xx` are formed as lower triangles (so `V_xx` is
/// exactly symmetric, whatever the rounding), `Q_uu + μI` is factorised as
/// `L D Lᵀ` (no square roots on the critical path), and `K` is formed
/// transposed (`Kᵀ = −Q_xu (Q_uu + μI)⁻¹`, `NX×NU`) so its columns are long.
///
/// Always inlined, so that a constant `sparsity` folds into the caller's
/// copy as it does in the solver's: a pattern read at run time trades the
/// test of each entry's value for a test of its flag, so that one knot
/// takes as long as with no pattern at all.
#[allow(non_snake_case)]
#[inline(always)]
pub fn riccati_step<const NX: usize, const NU: usize>(
    A: &SMatrix<f64, NX, NX>,
    B: &SMatrix<f64, NX, NU>,
    l: &StageExpansion<NX, NU>,
    next: &Value<NX>,
    mu: f64,
    sparsity: Option<&Sparsity<NX, NU>>,
) -> Option<RiccatiStep<NX, NU>> {
    let mut out = RiccatiStep {
        K: SMatrix::zeros(),
        d: SVector::zeros(),
        value: Value {
            V_x: SVector::zeros(),
            V_xx: SMatrix::zeros(),
        },
        dv1: 0.0,
        dv2: 0.0,
    };
    let (dv1, dv2) = riccati_step_into(
        A,
        B,
        l,
        next,
        mu,
        sparsity,
        None,
        &mut out.K,
        &mut out.d,
        &mut out.value,
    )?;
    out.dv1 = dv1;
    out.dv2 = dv2;
    Some(out)
}

/// [`riccati_step`] writing its results in place, so the backward pass
/// copies nothing: `K`, `d` go straight into the solver's gain buffers and
/// `value` into the other half of a ping-pong pair. Returns `(dᵀQ_u,
/// ½dᵀQ_uu d)`. The outputs are unspecified when it returns `None`.
///
/// With `boxed`, the step `d` is bounded (box-DDP, Tassa et al. 2014):
/// `d` minimises `½ dᵀ(Q_uu + μI)d + dᵀQ_u` over `lower ≤ d ≤ upper` by
/// [`solve_box_qp`], warm-started at `start`, and `K` is the free set's
/// gain, zero on the rows of clamped controls.
#[allow(non_snake_case, clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn riccati_step_into<const NX: usize, const NU: usize>(
    A: &SMatrix<f64, NX, NX>,
    B: &SMatrix<f64, NX, NU>,
    l: &StageExpansion<NX, NU>,
    next: &Value<NX>,
    mu: f64,
    sparsity: Option<&Sparsity<NX, NU>>,
    boxed: Option<&Boxed<NU>>,
    K_out: &mut SMatrix<f64, NU, NX>,
    d_out: &mut SVector<f64, NU>,
    value: &mut Value<NX>,
) -> Option<(f64, f64)> {
    debug_assert!(
        sparsity.is_none_or(|p| p.admits(A, B)),
        "A or B has a non-zero entry outside the stated sparsity pattern"
    );
    let (nz_a, nz_b) = match sparsity {
        Some(p) => (Nonzeros::Known(&p.state), Nonzeros::Known(&p.control)),
        None => (Nonzeros::Tested, Nonzeros::Tested),
    };
    let a = &A.data.0;
    let b = &B.data.0;
    let v = &next.V_xx.data.0;
    let v_x = &next.V_x.data.0[0];

    // P = V_xx·A and V_xx·B, shared by eqs. 33–35.
    let P = mul_square_sparse(v, a, nz_a);
    let mut VB = [[0.0; NX]; NU];
    add_mul(&mut VB, v, b, nz_b);
    // Pᵀ = Aᵀ·V_xx, because V_xx is symmetric.
    let Pt = transpose(&P);

    // Eq. 33: Q_xx = l_xx + Aᵀ V_xx A = l_xx + Pᵀ·A, lower triangle only,
    // built where V_xx will be (eq. 48 adds to it).
    let V_xx = &mut value.V_xx.data.0;
    copy_lower(V_xx, &l.l_xx.data.0);
    add_mul_lower(V_xx, &Pt, a, nz_a);
    // Eq. 35, transposed: Q_xu = l_uxᵀ + Aᵀ V_xx B = l_uxᵀ + Pᵀ·B.
    let mut Q_xu = transpose(&l.l_ux.data.0);
    add_mul(&mut Q_xu, &Pt, b, nz_b);
    // Eq. 34: Q_uu = l_uu + Bᵀ V_xx B.
    let mut Q_uu = l.l_uu.data.0;
    for (j, col) in Q_uu.iter_mut().enumerate() {
        for (i, q) in col.iter_mut().enumerate() {
            *q += nz_b.dot_column(b, i, &VB[j]);
        }
    }
    // Eqs. 31–32: Q_x = l_x + Aᵀ V_x (built where V_x will be), Q_u = l_u + Bᵀ V_x.
    let V_x = &mut value.V_x.data.0[0];
    *V_x = l.l_x.data.0[0];
    for (i, q) in V_x.iter_mut().enumerate() {
        *q += nz_a.dot_column(a, i, v_x);
    }
    let mut Q_u = l.l_u.data.0[0];
    for (i, q) in Q_u.iter_mut().enumerate() {
        *q += nz_b.dot_column(b, i, v_x);
    }

    // Eqs. 43–44 with Q_uu + μI: d = −(Q_uu + μI)⁻¹Q_u, Kᵀ = −Q_xu(Q_uu + μI)⁻¹.
    let mut Q_uu_reg = Q_uu;
    for (i, col) in Q_uu_reg.iter_mut().enumerate() {
        col[i] += mu;
    }
    // The unconstrained step; with bounds it is also the box QP's answer
    // whenever it lies inside them (every control free), which spares the
    // QP at most knots.
    let unconstrained = ldlt(&Q_uu_reg).map(|(L, D_inv)| {
        let d = ldlt_solve_vec(&L, &D_inv, &Q_u).map(|x| -x);
        (d, L, D_inv)
    });
    let inside =
        |d: &[f64; NU], b: &Boxed<NU>| (0..NU).all(|i| d[i] >= b.lower[i] && d[i] <= b.upper[i]);
    let (d, Kt) = match (boxed, unconstrained) {
        (None, None) => return None,
        (None, Some((d, L, D_inv))) => {
            let Kt = ldlt_solve_right(&L, &D_inv, &Q_xu).map(|col| col.map(|x| -x));
            (d, Kt)
        }
        (Some(b), Some((d, L, D_inv))) if inside(&d, b) => {
            let Kt = ldlt_solve_right(&L, &D_inv, &Q_xu).map(|col| col.map(|x| -x));
            (d, Kt)
        }
        (Some(b), _) => {
            let h = SMatrix::<f64, NU, NU>::from_fn(|i, j| Q_uu_reg[j][i]);
            let g = SVector::<f64, NU>::from(Q_u);
            let qp = solve_box_qp(
                &h,
                &g,
                &b.lower,
                &b.upper,
                &b.start,
                &BoxQpOptions::default(),
            )
            .ok()?;
            let Q_ux = SMatrix::<f64, NU, NX>::from_fn(|i, j| Q_xu[i][j]);
            let K = qp.feedback_gain(&Q_ux)?;
            (qp.u.data.0[0], transpose(&K.data.0))
        }
    };
    if !d.iter().chain(Kt.iter().flatten()).all(|x| x.is_finite()) {
        return None;
    }

    // Eq. 47: V_x = Q_x + Kᵀ(Q_uu d + Q_u) + Q_uxᵀ d.
    let mut Q_uu_d = [0.0; NU];
    for (j, col) in Q_uu.iter().enumerate() {
        for i in 0..NU {
            Q_uu_d[i] += col[i] * d[j];
        }
    }
    for i in 0..NU {
        axpy(V_x, Q_uu_d[i] + Q_u[i], &Kt[i]);
        axpy(V_x, d[i], &Q_xu[i]);
    }
    // Eq. 48: V_xx = Q_xx + Kᵀ(Q_uu K + Q_ux) + Q_uxᵀK = Q_xx + Kᵀ·Mtᵀ + Q_xu·K
    // with Mt = KᵀQ_uu + Q_xu. It is symmetric, so the lower triangle is
    // computed and mirrored.
    let mut Mt = Q_xu;
    add_mul(&mut Mt, &Kt, &Q_uu, Nonzeros::All);
    let K = transpose(&Kt);
    add_mul_lower(V_xx, &Kt, &transpose(&Mt), Nonzeros::All);
    add_mul_lower(V_xx, &Q_xu, &K, Nonzeros::All);
    mirror_lower(V_xx);

    K_out.data.0 = K;
    d_out.data.0[0] = d;
    Some((dot(&d, &Q_u), 0.5 * dot(&d, &Q_uu_d)))
}
