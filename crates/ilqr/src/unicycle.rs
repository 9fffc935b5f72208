//! The unicycle (the kinematic car of ALTRO's and Crocoddyl's examples).
//!
//! State `[x, y, θ]` (m, m, rad): position in the plane and heading,
//! counter-clockwise from the x axis. Controls `[v, ω]`: forward speed (m/s)
//! and turn rate (rad/s). The equations of motion are
//!
//! ```text
//! ẋ = v·cos θ
//! ẏ = v·sin θ
//! θ̇ = ω
//! ```
//!
//! It has no parameters. Speeds are not bounded here; bounds are
//! constraints, not part of the model.

use nalgebra::{SMatrix, SVector};

use crate::dynamics::{ContinuousDynamics, Curvature, Sparsity};
use crate::model::{Model, Parameter, Quantity};

/// The unicycle. A unit struct: the model has no parameters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Unicycle;

impl ContinuousDynamics<3, 2> for Unicycle {
    #[inline]
    fn derivative(&self, x: &SVector<f64, 3>, u: &SVector<f64, 2>) -> SVector<f64, 3> {
        let (sin, cos) = x[2].sin_cos();
        SVector::<f64, 3>::new(u[0] * cos, u[0] * sin, u[1])
    }

    #[inline]
    fn jacobians(
        &self,
        x: &SVector<f64, 3>,
        u: &SVector<f64, 2>,
    ) -> (SMatrix<f64, 3, 3>, SMatrix<f64, 3, 2>) {
        let (sin, cos) = x[2].sin_cos();
        let mut f_x = SMatrix::<f64, 3, 3>::zeros();
        f_x[(0, 2)] = -u[0] * sin;
        f_x[(1, 2)] = u[0] * cos;
        #[rustfmt::skip]
        let f_u = SMatrix::<f64, 3, 2>::new(
            cos, 0.0,
            sin, 0.0,
            0.0, 1.0,
        );
        (f_x, f_u)
    }

    /// The entries [`Self::jacobians`] sets: 2 of 9 and 3 of 6.
    const JACOBIAN_SPARSITY: Option<Sparsity<3, 2>> = Some(Sparsity::from_entries(
        &[(0, 2), (1, 2)],
        &[(0, 0), (1, 0), (2, 1)],
    ));

    /// Only the velocity components are curved, in θ and `v`: `v·cos θ`
    /// and `v·sin θ`. They are linear in `v`, so `uu` is zero.
    #[inline]
    fn curvature(
        &self,
        x: &SVector<f64, 3>,
        u: &SVector<f64, 2>,
        lambda: &SVector<f64, 3>,
    ) -> Option<Curvature<3, 2>> {
        let (sin, cos) = x[2].sin_cos();
        let mut xx = SMatrix::<f64, 3, 3>::zeros();
        // ∂²/∂θ² of v·cos θ is −v·cos θ; of v·sin θ, −v·sin θ.
        xx[(2, 2)] = -u[0] * (lambda[0] * cos + lambda[1] * sin);
        let mut ux = SMatrix::<f64, 2, 3>::zeros();
        // ∂²/∂v∂θ: −sin θ and cos θ.
        ux[(0, 2)] = -lambda[0] * sin + lambda[1] * cos;
        Some(Curvature {
            xx,
            ux,
            uu: SMatrix::zeros(),
        })
    }
}

impl Model<3, 2> for Unicycle {
    const NAME: &'static str = "unicycle";
    const DESCRIPTION: &'static str = "A unicycle (the kinematic car): position `(x, y)` in the \
        plane and heading θ counter-clockwise from the x axis, driven by its forward speed `v` \
        and turn rate `ω`: `ẋ = v·cos θ`, `ẏ = v·sin θ`, `θ̇ = ω`. No parameters.";
    const STATE: [Quantity; 3] = [
        Quantity {
            name: "x",
            unit: "m",
            description: "position, x",
        },
        Quantity {
            name: "y",
            unit: "m",
            description: "position, y",
        },
        Quantity {
            name: "θ",
            unit: "rad",
            description: "heading, counter-clockwise from the x axis",
        },
    ];
    const CONTROL: [Quantity; 2] = [
        Quantity {
            name: "v",
            unit: "m/s",
            description: "forward speed",
        },
        Quantity {
            name: "ω",
            unit: "rad/s",
            description: "turn rate, counter-clockwise",
        },
    ];
    const PARAMETERS: &'static [Parameter] = &[];
    const POSITION: (usize, usize) = (0, 1);

    fn from_parameters(_values: &[f64]) -> Self {
        Self
    }

    /// Standing still.
    fn rest_controls(&self) -> SVector<f64, 2> {
        SVector::zeros()
    }
}
