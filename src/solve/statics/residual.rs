//! What a static solve measures and reports: takes a model, a state and its evaluation, gives
//! the residual and its scales (`Residual`, `residual_of`), the load's rate along a schedule
//! (`load_rate`), why a solve stopped (`StopReason`) and the report of an equilibrium
//! (`EquilibriumReport`).

use nalgebra::DVector;

use crate::evaluate::Workspace;
use crate::model::{Model, SolverSettings};
use crate::state::State;

/// Outcome of one equilibrium solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EquilibriumReport {
    /// Newton iterations used.
    pub iterations: usize,
    /// `|Q - Phi_q^T lambda|_inf` at the solution, N.
    pub residual: f64,
    /// Force scale the tolerance is relative to (largest tension or weight), N.
    pub force_scale: f64,
    /// `|Phi|_inf` at the solution, m.
    pub constraint_residual: f64,
    /// Smallest eigenvalue of the reduced tangent stiffness (N/m or N m/rad).
    pub min_stiffness_eigenvalue: f64,
    /// True when the reduced tangent stiffness is positive definite.
    pub stable: bool,
    /// Directions of the reduced tangent stiffness with negative curvature (the point is a
    /// saddle or a maximum of the energy when there are any).
    pub negative_modes: usize,
    /// Directions with zero stiffness (within `1e-9` of the largest): neutral motions such as a
    /// body spinning about the line it hangs on, free rigid-body motions, unstressed mechanisms.
    pub zero_modes: usize,
    /// Free rigid-body motions of the whole structure (`rigid_body_motions`) that cost no energy:
    /// 6 for a structure held by nothing, 3 in a planar scene, fewer with partial supports or
    /// under gravity. Counted among `zero_modes`.
    pub rigid_modes: usize,
    /// Total potential energy at the solution, J: the cables' elastic energy plus the
    /// gravitational potential `-sum_b m_b g . x_b`. Of two stable equilibria of the same
    /// rest lengths, the lower one is the deeper minimum.
    pub potential_energy: f64,
}

impl EquilibriumReport {
    /// "stable", "stable (N rigid-body modes)", "neutrally stable (N zero-stiffness modes ...)" or
    /// "UNSTABLE (M negative-stiffness modes)": what the reduced tangent stiffness says of this
    /// equilibrium, with the structure's free rigid-body motions told apart.
    pub fn stability_words(&self) -> String {
        let plural = |n: usize| if n == 1 { "" } else { "s" };
        let rigid = self.rigid_modes.min(self.zero_modes);
        let other = self.zero_modes - rigid;
        let rigid_words = format!("{rigid} rigid-body mode{}", plural(rigid));
        match (self.negative_modes, other, rigid) {
            (0, 0, 0) => "stable".into(),
            (0, 0, _) => format!("stable ({rigid_words})"),
            (0, z, 0) => format!("neutrally stable ({z} zero-stiffness mode{})", plural(z)),
            (0, z, _) => {
                format!("neutrally stable ({z} zero-stiffness mode{} besides {rigid_words})", plural(z))
            }
            (m, _, _) => format!("UNSTABLE ({m} negative-stiffness mode{})", plural(m)),
        }
    }
}

/// Why the last `StaticSolver::equilibrate` stopped (`StaticSolver::stop_reason`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StopReason {
    /// The residual passed the convergence test.
    #[default]
    Converged,
    /// The solve was still converging at its cap (`SolverSettings::max_iterations`: its best
    /// residual over the last `STAGNATION_WINDOW` iterations below half the best before them) and
    /// went on to `CAP_EXTENSION` times the cap, or was stopped at a cap too short to judge.
    IterationLimit,
    /// The residual had stopped falling at the cap.
    Stagnated,
    /// A residual or every trial of a step's line search was not finite.
    Diverged,
    /// The Newton matrix could not be solved even with regularization.
    Singular,
    /// No equilibrium found while a stick-slip contact slipped at the last iteration: the
    /// friction its cone allows (`mu F_n`) cannot hold it (`StaticSolver::slipping_contacts`
    /// names the contacts).
    ContactSlips,
}

impl StopReason {
    /// The reason in words (`converged`, `iteration limit`, `stagnated`, `diverged`, `singular`,
    /// `contact slips`).
    pub fn words(self) -> &'static str {
        match self {
            StopReason::Converged => "converged",
            StopReason::IterationLimit => "iteration limit",
            StopReason::Stagnated => "stagnated",
            StopReason::Diverged => "diverged",
            StopReason::Singular => "singular",
            StopReason::ContactSlips => "contact slips",
        }
    }

    /// `IterationLimit` or `Stagnated` for a solve that reached its cap with the residuals
    /// `history` (one per iteration, N).
    pub(crate) fn at_cap(history: &[f64]) -> Self {
        let k = history.len();
        if k < 2 * STAGNATION_WINDOW {
            return StopReason::IterationLimit;
        }
        let best = |h: &[f64]| h.iter().copied().fold(f64::INFINITY, f64::min);
        let (before, last) = history.split_at(k - STAGNATION_WINDOW);
        if best(last) < 0.5 * best(before) {
            StopReason::IterationLimit
        } else {
            StopReason::Stagnated
        }
    }
}

/// Iterations over which `StopReason::at_cap` judges whether a solve that reached its cap was
/// still making progress.
pub const STAGNATION_WINDOW: usize = 10;

/// A solve that is still converging at its cap (`SolverSettings::max_iterations`) goes on, up to
/// this many times the cap: the cap ends a solve that stagnates, not one that makes progress.
pub const CAP_EXTENSION: usize = 4;

pub(crate) struct Residual {
    pub(crate) force: f64,
    pub(crate) constraint: f64,
    pub(crate) force_scale: f64,
    pub(crate) length_scale: f64,
    /// Round-off floor of the force residual: positions carry an absolute error of about machine
    /// epsilon times their magnitude, so a cable's force is only known to `~eps EA R / L0`, with
    /// `R` the larger of its length and the largest point coordinate (a structure far from the
    /// origin knows its lengths less well than one at it).
    pub(crate) force_floor: f64,
}

impl Residual {
    /// True when this residual passes the convergence test of `StaticSolver::equilibrate`.
    pub(crate) fn converged(&self, settings: &SolverSettings) -> bool {
        self.force <= (settings.tolerance * self.force_scale).max(self.force_floor)
            && self.force <= ROUND_OFF_CEILING * self.force_scale
            && self.constraint <= settings.tolerance * self.length_scale
    }

    pub(crate) fn merit(&self, f_scale: f64, l_scale: f64) -> f64 {
        (self.force / f_scale).powi(2) + (self.constraint / l_scale).powi(2)
    }
}

/// The derivative of the statics residual `r = [Q - Phi_q^T lambda; -Phi]` with respect to the
/// schedule time, `out = [dQ/dt; 0]` (N/s): a taut cable's tension `T = EA (L/L0 - 1)` changes by
/// `dT/dL0 = -EA L / L0^2` and its force `Q = -T g` by `EA L / L0^2 g` per metre of rest length,
/// times the rest-length rate `rates[c]` (m/s, `Model::scheduled_rest_rates`). `ws` must hold the
/// point kinematics and cable responses of `state` (its route scratch is overwritten).
pub fn load_rate(model: &Model, state: &State, ws: &mut Workspace, rates: &[f64], out: &mut DVector<f64>) {
    out.fill(0.0);
    let mut dq = DVector::zeros(model.dof_count);
    for (c, cable) in model.cables.iter().enumerate() {
        let response = &ws.cables[c];
        if rates[c] == 0.0 || (cable.tension_only && response.length <= response.rest_length) {
            continue; // a member's force changes with its rest length in compression too
        }
        if cable.friction.is_some() {
            continue; // no predictor through the pulleys' return map: the corrector finds it
        }
        let route = model.route(crate::model::CableId(c));
        crate::forces::cable::route_geometry(route, &ws.points, &mut ws.scratch);
        let l0 = state.rest_lengths[c];
        let coefficient = cable.axial_stiffness * response.length / (l0 * l0) * rates[c];
        crate::forces::cable::add_length_gradient(
            model,
            route,
            &ws.points,
            &ws.scratch,
            coefficient,
            &mut dq,
        );
    }
    out.rows_mut(0, model.dof_count).copy_from(&dq);
}

/// Largest residual, relative to the force scale, that may ever be called converged: the
/// round-off floor of very stiff cables relaxes the tolerance up to this and no further.
pub const ROUND_OFF_CEILING: f64 = 1e-6;

/// The size of a model's bodies, m: twice the largest distance of an attachment point from its
/// body's origin (a bar's length), at least 1 mm. With the cable lengths it sets the length scale,
/// so that a structure with few or short cables still takes steps of its own size.
pub fn body_size(model: &Model) -> f64 {
    model.points.iter().map(|p| 2.0 * p.local.norm()).fold(1e-3, f64::max)
}

pub(crate) fn residual_of(
    model: &Model,
    state: &State,
    ws: &mut Workspace,
    rhs: &mut DVector<f64>,
    size: f64,
) -> Residual {
    let n = model.dof_count;
    let mut r = ws.force.clone_owned();
    if model.constraint_count > 0 {
        crate::constraints::add_reaction_force(
            model,
            &state.poses,
            &ws.points,
            &state.multipliers,
            -1.0,
            &mut r,
        );
    }
    rhs.rows_mut(0, n).copy_from(&r);
    if model.constraint_count > 0 {
        rhs.rows_mut(n, model.constraint_count).copy_from(&(-&ws.constraint));
    }
    let weight = model.bodies.iter().map(|b| b.mass * model.gravity.norm()).fold(0.0, f64::max);
    let tension = ws.cables.iter().map(|c| c.tension.abs()).fold(0.0, f64::max);
    let length = ws.cables.iter().map(|c| c.length).fold(0.0, f64::max);
    let reach = ws.points.iter().map(|p| p.position.amax()).fold(0.0, f64::max);
    let force_floor = model
        .cables
        .iter()
        .zip(&ws.cables)
        .map(|(m, c)| 16.0 * f64::EPSILON * m.axial_stiffness * c.length.max(reach) / c.rest_length)
        .fold(0.0, f64::max);
    Residual {
        force_floor,
        force: r.amax(),
        constraint: ws.constraint.amax(),
        force_scale: weight.max(tension).max(1e-12),
        length_scale: length.max(size),
    }
}
