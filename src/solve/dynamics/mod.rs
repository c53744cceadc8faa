//! Time integration: takes a `Model`, a `State` with its accelerations, and a step size; gives the
//! state one step later, or `None` when the step failed (Newton did not converge, or a non-finite
//! number appeared) so that the caller can retry with a smaller step. The state is only written on
//! success.
//!
//! Equations of motion in local coordinates (see `crate::model`):
//! `M vdot + w x (J w) + Phi_q^T lambda = Q(q, v, t)`, `Phi(q) = 0`, with `M` the constant
//! block-diagonal body mass matrix and `w x (J w)` the gyroscopic torque of rigid bodies.
//!
//! The methods, one file each: `generalized_alpha` (implicit, Newton on the analytic tangent),
//! `symplectic_euler` and `explicit` (RK4, Dormand-Prince 5(4)); `error_control` holds what
//! generalized-alpha's error estimate reads (the jerk envelope, the damped modes' relief).

//!
//! Files: `integrator` (the methods by name), `system` (`Dynamics`: the memory, the dispatch,
//! the shared terms and the stability limits), one file per method's step (`generalized_alpha`,
//! `symplectic_euler`, `explicit`, with the Runge-Kutta data in `tableaus`), `error_control`,
//! `joint_schur` (the explicit methods' joint projection). This file only gathers them.

mod error_control;
pub mod explicit;
mod generalized_alpha;
mod integrator;
mod joint_schur;
mod symplectic_euler;
mod system;
mod tableaus;

pub use error_control::*;
pub use generalized_alpha::assemble_newton_matrix;
pub use integrator::{AlphaCoefficients, Integrator};
pub use system::*;
