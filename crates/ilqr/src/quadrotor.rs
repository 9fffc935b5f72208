//! The planar (2-D) quadrotor of the seed paper, eqs. 4–8.
//!
//! State `[x, y, θ, ẋ, ẏ, θ̇]` (m, m, rad, m/s, m/s, rad/s); controls
//! `[u1, u2]`, the two rotor thrusts (N). The equations of motion are
//!
//! ```text
//! m·ẍ = −(u1 + u2)·sin θ
//! m·ÿ =  (u1 + u2)·cos θ − m·g
//! I·θ̈ =  r·(u1 − u2)
//! ```
//!
//! The paper's eq. 8 prints the angular term as `1/t`; eq. 6 makes it `r/I`,
//! which is what is implemented. Thrusts are not bounded here: control limits
//! are a constraint for a later solver, not part of the model.

use nalgebra::{SMatrix, SVector};

use crate::dynamics::{ContinuousDynamics, Curvature, Sparsity};
use crate::model::{Model, Parameter, Quantity};

/// Physical parameters of the planar quadrotor. All must be finite, and
/// all but gravity positive: [`Model::PARAMETERS`] gives the ranges.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quadrotor2D {
    /// Mass `m` in kg.
    pub mass: f64,
    /// Moment of inertia `I` about the body axis, kg·m².
    pub inertia: f64,
    /// Distance `r` from the centre to each rotor, m.
    pub arm_length: f64,
    /// Gravitational acceleration `g`, m/s².
    pub gravity: f64,
}

impl Quadrotor2D {
    /// The thrust per rotor that holds the quadrotor level and still: `m·g/2`.
    pub fn hover_thrust(&self) -> f64 {
        self.mass * self.gravity / 2.0
    }
}

impl ContinuousDynamics<6, 2> for Quadrotor2D {
    #[inline]
    fn derivative(&self, x: &SVector<f64, 6>, u: &SVector<f64, 2>) -> SVector<f64, 6> {
        let (sin, cos) = x[2].sin_cos();
        let thrust = u[0] + u[1];
        SVector::<f64, 6>::new(
            x[3],
            x[4],
            x[5],
            -thrust * sin / self.mass,
            thrust * cos / self.mass - self.gravity,
            self.arm_length * (u[0] - u[1]) / self.inertia,
        )
    }

    #[inline]
    fn jacobians(
        &self,
        x: &SVector<f64, 6>,
        u: &SVector<f64, 2>,
    ) -> (SMatrix<f64, 6, 6>, SMatrix<f64, 6, 2>) {
        let (sin, cos) = x[2].sin_cos();
        let thrust = u[0] + u[1];
        let m = self.mass;
        let mut f_x = SMatrix::<f64, 6, 6>::zeros();
        f_x[(0, 3)] = 1.0;
        f_x[(1, 4)] = 1.0;
        f_x[(2, 5)] = 1.0;
        f_x[(3, 2)] = -thrust * cos / m;
        f_x[(4, 2)] = -thrust * sin / m;
        let torque = self.arm_length / self.inertia;
        #[rustfmt::skip]
        let f_u = SMatrix::<f64, 6, 2>::new(
            0.0,       0.0,
            0.0,       0.0,
            0.0,       0.0,
            -sin / m,  -sin / m,
            cos / m,   cos / m,
            torque,    -torque,
        );
        (f_x, f_u)
    }

    /// The entries [`Self::jacobians`] sets: 5 of 36 and 6 of 12.
    const JACOBIAN_SPARSITY: Option<Sparsity<6, 2>> = Some(Sparsity::from_entries(
        &[(0, 3), (1, 4), (2, 5), (3, 2), (4, 2)],
        &[(3, 0), (3, 1), (4, 0), (4, 1), (5, 0), (5, 1)],
    ));

    /// Only the two translational accelerations are curved, in θ and the
    /// thrust: `−s·sinθ/m` and `s·cosθ/m − g` with `s = u1 + u2`. They are
    /// linear in `u`, so `uu` is zero.
    #[inline]
    fn curvature(
        &self,
        x: &SVector<f64, 6>,
        u: &SVector<f64, 2>,
        lambda: &SVector<f64, 6>,
    ) -> Option<Curvature<6, 2>> {
        let (sin, cos) = x[2].sin_cos();
        let thrust = u[0] + u[1];
        let m = self.mass;
        let mut xx = SMatrix::<f64, 6, 6>::zeros();
        // ∂²/∂θ² of −s·sinθ/m is s·sinθ/m; of s·cosθ/m − g, −s·cosθ/m.
        xx[(2, 2)] = thrust * (lambda[3] * sin - lambda[4] * cos) / m;
        // ∂²/∂u_j∂θ: −cosθ/m and −sinθ/m, the same for both rotors.
        let theta_u = -(lambda[3] * cos + lambda[4] * sin) / m;
        let mut ux = SMatrix::<f64, 2, 6>::zeros();
        ux[(0, 2)] = theta_u;
        ux[(1, 2)] = theta_u;
        Some(Curvature {
            xx,
            ux,
            uu: SMatrix::zeros(),
        })
    }
}

const fn quantity(name: &'static str, unit: &'static str, description: &'static str) -> Quantity {
    Quantity {
        name,
        unit,
        description,
    }
}

/// Smallest mass, inertia and arm length: below it the accelerations of a
/// bounded thrust no longer fit the state bounds a caller checks.
const MIN_PARAMETER: f64 = 1e-6;
/// Largest mass, inertia and arm length.
const MAX_PARAMETER: f64 = 1e6;

impl Model<6, 2> for Quadrotor2D {
    const NAME: &'static str = "quadrotor_2d";
    const DESCRIPTION: &'static str = "The planar quadrotor of the seed paper (eqs. 4–6): `x` \
        right, `y` up, θ counter-clockwise from upright, `u1` the rotor at `+r` along the body's \
        x axis: `m·ẍ = −(u1 + u2)·sin θ`, `m·ÿ = (u1 + u2)·cos θ − m·g`, `I·θ̈ = r·(u1 − u2)`.";
    const STATE: [Quantity; 6] = [
        quantity("x", "m", "position, right"),
        quantity("y", "m", "position, up"),
        quantity("θ", "rad", "attitude, counter-clockwise from upright"),
        quantity("ẋ", "m/s", "velocity, right"),
        quantity("ẏ", "m/s", "velocity, up"),
        quantity("θ̇", "rad/s", "angular velocity"),
    ];
    const CONTROL: [Quantity; 2] = [
        quantity(
            "u1",
            "N",
            "thrust of the rotor at +r along the body's x axis",
        ),
        quantity("u2", "N", "thrust of the rotor at −r"),
    ];
    const PARAMETERS: &'static [Parameter] = &[
        Parameter {
            name: "mass",
            unit: "kg",
            description: "mass m",
            default: 1.0,
            minimum: MIN_PARAMETER,
            maximum: MAX_PARAMETER,
        },
        Parameter {
            name: "inertia",
            unit: "kg·m²",
            description: "moment of inertia I about the body axis",
            default: 1.0,
            minimum: MIN_PARAMETER,
            maximum: MAX_PARAMETER,
        },
        Parameter {
            name: "arm_length",
            unit: "m",
            description: "distance r from the centre to each rotor",
            default: 1.0,
            minimum: MIN_PARAMETER,
            maximum: MAX_PARAMETER,
        },
        Parameter {
            name: "gravity",
            unit: "m/s²",
            description: "gravitational acceleration g",
            default: 9.81,
            minimum: 0.0,
            maximum: 1e4,
        },
    ];
    const POSITION: (usize, usize) = (0, 1);

    /// `[mass, inertia, arm_length, gravity]`.
    fn from_parameters(values: &[f64]) -> Self {
        let value = |i: usize| {
            values
                .get(i)
                .copied()
                .unwrap_or(Self::PARAMETERS[i].default)
        };
        Self {
            mass: value(0),
            inertia: value(1),
            arm_length: value(2),
            gravity: value(3),
        }
    }

    /// A rotor's thrust cannot be negative.
    const CONTROL_MINIMUM: Option<[f64; 2]> = Some([0.0, 0.0]);

    /// Hover thrust on both rotors.
    fn rest_controls(&self) -> SVector<f64, 2> {
        SVector::repeat(self.hover_thrust())
    }
}
