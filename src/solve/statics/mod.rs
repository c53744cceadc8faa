//! Quasi-static equilibrium: takes a model and a state (rest lengths set), gives the equilibrium
//! configuration and joint reactions by Newton's method with a backtracking line search, its
//! residual and iteration count, whether it is stable and its potential energy. The deployment
//! path built from these equilibria is `crate::solve::deploy`'s.
//!
//! Equations (inertia dropped): `F(q, lambda) = [Q(q) - Phi_q^T lambda; Phi(q)] = 0`.
//! Newton step from the KKT system
//! `[[K + H_lambda, Phi_q^T], [Phi_q, 0]] [dq; dlambda] = [Q - Phi_q^T lambda; -Phi]`,
//! with `K = -dQ/dq` and `H_lambda = d(Phi_q^T lambda)/dq`; the pose update is the group retraction
//! `crate::state::retract`. Converged when `|Q - Phi_q^T lambda|_inf <= max(tol * F_scale, F_floor)`
//! (N, N m), with the round-off floor `F_floor = 16 eps max_c(EA_c L_c / L0_c)`, and
//! `|Phi|_inf <= tol * L_scale` (m), with `F_scale` the largest of the cable tensions and body
//! weights and `L_scale` the largest cable length.
//!
//! Globalization (starts far from the equilibrium, as sketched by a user): the joint reactions
//! start at their least-squares values (`least_squares_multipliers`), so the joints' geometric
//! stiffness is right from the first iteration; where the reduced tangent has negative or zero
//! curvature (a structure tilted past a maximum of its energy, a hanging mass, a slack cable),
//! those eigen-directions are replaced by positive curvature (`convexity_correction`) and the step
//! is a descent step of the potential energy, accepted when the energy falls after projecting back
//! onto the joints (`project_onto_joints`); otherwise a Newton step is accepted when it lowers the
//! residual norm or the energy. Translations are capped at the structure's length scale (the
//! largest cable length or body size) per iteration, rotations at 0.5 rad.
//!
//! Stiff cables (`stiff_cables`: `EA/L0` above `STIFF_CABLE_RATIO` times the structure's own
//! force-per-length scale, in a structure loaded by its weights rather than held by prestress)
//! have their tensions as unknowns (`equilibrate_mixed`): Newton then measures their misfit as a
//! length, not as `EA/L0` times it, and its iteration count does not grow with EA
//! (`tests/stiff_statics.rs`: 1e2 to 1e9 N at the same cost). Stiff elastic members (they push;
//! without a buckling law) join them in scenes below `SPARSE_STATICS_MIN` coordinates, prestressed
//! structures included, since a member never goes slack; larger scenes and buckling members stay
//! in the displacement form.
//!
//! Stability: the equilibrium is stable when the symmetric part of `K + H_lambda`, restricted to
//! the null space of `Phi_q`, is positive definite (smallest eigenvalue above `1e-9` of the largest);
//! with stiff members in the mixed form, on the motions that also keep their lengths
//! (`dense_stability`).
//! Neutral directions (free rigid motions, unstressed mechanisms) count as not stable.
//!
//! Size: from `SPARSE_STATICS_MIN` coordinates the solver works on the sparse KKT system of the
//! dynamics (`crate::solve::linear::KktSystem`, clustered cables bordered): Newton steps by its
//! sparse LU, and the stability test by the inertia of shifted sparse `LDL^T` factorizations
//! (`sparse_stability`) instead of a dense eigenproblem over a null-space basis, so that `statics`
//! and quasi-static deployment cost about linearly in the structure (docs/benchmarks.md).
//!
//! Files: `solver` (the solver's buffers, the displacement form, the report), `mixed` (the mixed
//! form), `stiff` (which cables are stiff, their tension unknowns), `residual` (the residual, its
//! scales, the stop reasons, the report type), `kkt` (the joints' reactions, the convexity shift,
//! the KKT solves), `line_search` (the one line search both forms use), `align` (a settled
//! structure moved rigidly back onto its contacts' anchors); the stability test is
//! `crate::solve::stability`. This file only gathers them.

mod align;
pub(crate) mod kkt;
mod line_search;
mod mixed;
pub(crate) mod residual;
mod solver;
mod stiff;

pub use kkt::{MAX_CONVEXITY_CHECK, SPARSE_STATICS_MIN, STEP_CAP};
pub(crate) use residual::residual_of;
pub use residual::{
    body_size, load_rate, EquilibriumReport, StopReason, CAP_EXTENSION, ROUND_OFF_CEILING, STAGNATION_WINDOW,
};
pub use solver::StaticSolver;
pub use stiff::{
    prestressed_stiff_cables, stiff_cables, PRESTRESSED_START, PRESTRESSED_STIFF_RATIO, STIFF_CABLE_RATIO,
};
