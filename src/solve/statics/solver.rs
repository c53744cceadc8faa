//! The static solver: takes a model and a state (rest lengths set), gives the equilibrium by
//! Newton's method in the displacement form (`StaticSolver::equilibrate`), or in the mixed form
//! for stiff cables (`crate::solve::statics::mixed`), and its report.

use nalgebra::{DMatrix, DVector};

use crate::constraints::add_multiplier_hessian;
use crate::evaluate::{evaluate, evaluate_forces, Tangents, Workspace};
use crate::forces::contact::FrictionState;
use crate::model::{BodyId, Model, Pose, SolverSettings};
use crate::solve::linear::{KktSystem, LinearBackend};
use crate::solve::stability::{dense_stability, sparse_stability};
use crate::solve::statics::align::align_onto_anchors;
use crate::solve::statics::kkt::{
    assemble_sparse, commit_friction, convexity_correction, least_squares_multipliers, project_onto_joints,
    solve_regularized, solve_sparse, sparse_least_squares_multipliers, MAX_CONVEXITY_CHECK,
    SPARSE_STATICS_MIN,
};
use crate::solve::statics::line_search::{line_search, LineSearch, Searched};
use crate::solve::statics::residual::{
    body_size, load_rate, residual_of, EquilibriumReport, Residual, StopReason, CAP_EXTENSION,
};
use crate::solve::statics::stiff::stiff_sets;
use crate::state::{retract, State};

/// What `StaticSolver::start_iteration` found.
pub(crate) enum Start {
    /// Go on with this residual.
    Go(Residual),
    /// Converged: the report (the pulleys' friction already committed at the equilibrium).
    Converged(EquilibriumReport),
    /// Stop without an equilibrium (`StaticSolver::stop_reason` says why).
    Stop,
}

/// Buffers for the Newton iteration, sized once per model.
#[derive(Debug, Clone)]
pub struct StaticSolver {
    /// The dense KKT matrix (`assemble_kkt`), sized on first use.
    pub(crate) kkt: DMatrix<f64>,
    /// The sparse KKT system of a model of at least `SPARSE_STATICS_MIN` coordinates: its
    /// stability test (`sparse_stability`), and its Newton steps when `sparse_newton`.
    pub(crate) sparse: Option<KktSystem>,
    /// Newton steps on `sparse` (a model without stiff cables, solved in the displacement form).
    pub(crate) sparse_newton: bool,
    pub(crate) rhs: DVector<f64>,
    pub(crate) dq: DVector<f64>,
    pub(crate) trial_poses: Vec<Pose>,
    pub(crate) best_poses: Vec<Pose>,
    /// Mass matrix in local coordinates (constant), the metric of the convexity shift.
    pub(crate) mass: DMatrix<f64>,
    /// `body_size(model)`, m.
    pub(crate) size: f64,
    /// The force residual at the start of each iteration of the last solve, N.
    pub(crate) history: Vec<f64>,
    /// Why the last solve stopped.
    pub(crate) stop: StopReason,
    /// The model's stiff cables (`stiff_cables`), whose tensions `equilibrate` solves for.
    pub(crate) stiff: Vec<usize>,
    /// The stiff cables of a structure held by prestress (`prestressed_stiff_cables`), which
    /// `equilibrate` first solves for as if they could push.
    pub(crate) prestressed: Vec<usize>,
    /// `equilibrate_holding` found no equilibrium with the contacts held once: the rest of the
    /// path is solved as structures set down (each failed attempt costs a whole Newton solve).
    pub(crate) holding_failed: bool,
    /// `slipping_contacts`.
    pub(crate) slipping: Vec<usize>,
}

impl StaticSolver {
    /// Buffers for `model`. A model of at least `SPARSE_STATICS_MIN` coordinates is solved on
    /// the sparse KKT system (`KktSystem`, its symbolic analysis done here): its stability test,
    /// and its Newton steps when it has no stiff cables, so that its cost grows with the
    /// structure, not with its square or cube.
    pub fn new(model: &Model) -> Self {
        let size = model.dof_count + model.constraint_count;
        let poses: Vec<Pose> = model.bodies.iter().map(|b| b.initial_pose).collect();
        let (stiff, prestressed) = stiff_sets(model, &mut Workspace::for_forces(model), body_size(model));
        let large = model.dof_count >= SPARSE_STATICS_MIN;
        let mut solver = Self {
            kkt: DMatrix::zeros(0, 0),
            sparse: None,
            sparse_newton: false,
            rhs: DVector::zeros(size),
            dq: DVector::zeros(model.dof_count),
            trial_poses: poses.clone(),
            best_poses: poses,
            mass: if model.dof_count > MAX_CONVEXITY_CHECK {
                DMatrix::zeros(0, 0)
            } else {
                crate::solve::dynamics::mass_matrix(model)
            },
            size: body_size(model),
            history: Vec::new(),
            stop: StopReason::Converged,
            stiff,
            prestressed,
            holding_failed: false,
            slipping: Vec::new(),
        };
        if large {
            solver = solver.with_sparse_kkt(model, true);
        }
        solver
    }

    /// The same solver with its Newton steps and stability test on the sparse KKT system
    /// (`sparse = true`) or on dense matrices, whatever the model's size: for comparing the two
    /// (`tests/large_statics.rs`). A model without sparse structure stays dense; one with stiff
    /// cables (`stiff_cables`, the mixed form) takes dense Newton steps either way.
    pub fn with_sparse_kkt(mut self, model: &Model, sparse: bool) -> Self {
        self.sparse = None;
        self.sparse_newton = false;
        if sparse {
            let kkt = KktSystem::new(model, LinearBackend::Sparse);
            if kkt.backend() == LinearBackend::Sparse {
                self.sparse = Some(kkt);
                self.sparse_newton = self.stiff.is_empty();
            }
        }
        self
    }

    /// False once `equilibrate_holding` has given up holding the contacts (the rest of the path
    /// is solved as structures set down).
    pub fn contacts_held(&self) -> bool {
        !self.holding_failed
    }

    /// True when this solver's Newton steps are made on the sparse KKT system (`new`).
    pub fn is_sparse(&self) -> bool {
        self.sparse_newton
    }

    /// Fills the KKT matrix `[[K + H_lambda, Phi_q^T], [Phi_q, 0]]` at `state` from the tangents
    /// last evaluated into `ws` (`Tangents::Stiffness`).
    pub(crate) fn assemble_kkt(&mut self, model: &Model, state: &State, ws: &Workspace) {
        let n = model.dof_count;
        let nc = model.constraint_count;
        if self.kkt.nrows() != n + nc {
            self.kkt = DMatrix::zeros(n + nc, n + nc);
        }
        self.kkt.fill(0.0);
        self.kkt.view_mut((0, 0), (n, n)).copy_from(&ws.stiffness);
        if nc > 0 {
            let mut h = DMatrix::zeros(n, n);
            add_multiplier_hessian(model, &state.poses, &state.multipliers, &mut h);
            let mut top = self.kkt.view_mut((0, 0), (n, n));
            top += &h;
            self.kkt.view_mut((0, n), (n, nc)).copy_from(&ws.constraint_jacobian.transpose());
            self.kkt.view_mut((n, 0), (nc, n)).copy_from(&ws.constraint_jacobian);
        }
    }

    /// The start of every Newton iteration of `equilibrate` (both forms): evaluates `state`
    /// with its stiffness, records the displacement form's force residual, and tells whether the
    /// solve converged (the residual test below `settings.tolerance`, or its round-off floor but
    /// never above `ROUND_OFF_CEILING`: ill-conditioned input gets no claim), diverged (a
    /// non-finite residual) or stops at its cap (`StopReason::at_cap`; a solve still converging
    /// goes on to `CAP_EXTENSION` times the cap). `best` keeps the smallest residual seen.
    pub(crate) fn start_iteration(
        &mut self,
        model: &Model,
        state: &mut State,
        ws: &mut Workspace,
        settings: &SolverSettings,
        iterations: usize,
        best: &mut f64,
    ) -> Start {
        if self.sparse_newton {
            evaluate_forces(model, state, ws);
        } else {
            evaluate(model, state, ws, Tangents::Stiffness);
        }
        let res = residual_of(model, state, ws, &mut self.rhs, self.size);
        self.history.push(res.force);
        self.slipping.clear();
        if !state.contact_anchors.is_empty() {
            let slipping =
                ws.contacts.iter().enumerate().filter(|(_, c)| c.friction_state == FrictionState::Slipping);
            self.slipping.extend(slipping.map(|(k, _)| k));
        }
        crate::progress::report(crate::progress::Report {
            unit: "Newton iterations",
            done: iterations as u64,
            total: None,
            residual_n: Some(res.force),
        });
        if !res.force.is_finite() || !res.constraint.is_finite() {
            self.stop = StopReason::Diverged;
            return Start::Stop;
        }
        *best = best.min(res.force);
        if res.converged(settings) {
            self.stop = StopReason::Converged;
            let report = self.report(model, state, ws, &res, iterations);
            commit_friction(model, state, ws);
            return Start::Converged(report);
        }
        if iterations >= settings.max_iterations {
            self.stop = StopReason::at_cap(&self.history);
            if self.stop != StopReason::IterationLimit
                || iterations >= CAP_EXTENSION * settings.max_iterations
            {
                return Start::Stop;
            }
        }
        Start::Go(res)
    }

    /// Why the last `equilibrate` stopped.
    pub fn stop_reason(&self) -> StopReason {
        self.stop
    }

    /// The contacts (`Model::contact_labels` order) that slipped at the last iteration of the
    /// last `equilibrate` (stick-slip grounds only): the ones a `StopReason::ContactSlips` names.
    pub fn slipping_contacts(&self) -> &[usize] {
        &self.slipping
    }

    /// Why the last `equilibrate` stopped, in words, naming the slipping contacts for
    /// `StopReason::ContactSlips` (`contact slips: block@slope, beyond mu F_n`), and saying, for
    /// a model with contacts whose grounds have no stick-slip friction, that statics holds them
    /// up but not sideways.
    pub fn stop_words(&self, model: &Model) -> String {
        let mut words = self.stop.words().to_string();
        if self.stop == StopReason::ContactSlips {
            words = format!("{words}: {} beyond mu F_n", self.slipping_contact_labels(model).join(", "));
        } else if self.stop != StopReason::Converged && model.contact_pairs() > 0 {
            let grounds = |f: fn(&crate::model::GroundModel) -> bool| model.grounds.iter().any(f);
            if grounds(|g| g.material.friction == 0.0) {
                words.push_str("; a frictionless ground (mu = 0) holds a structure up but not sideways");
            }
            if grounds(|g| g.material.friction > 0.0 && g.material.stick.is_none()) {
                words.push_str(
                    "; grounds without stick_stiffness hold a structure up but not sideways in statics \
                     (their regularized friction needs motion): give a ground stick_stiffness for friction at rest",
                );
            }
        }
        words
    }

    /// `slipping_contacts` as `point@ground` labels (`Model::contact_labels`).
    pub fn slipping_contact_labels(&self, model: &Model) -> Vec<String> {
        let labels: Vec<(&str, &str)> = model.contact_labels().collect();
        self.slipping.iter().map(|&k| format!("{}@{}", labels[k].0, labels[k].1)).collect()
    }

    /// The force residual `|Q - Phi_q^T lambda|_inf` (N) at the start of each Newton iteration of
    /// the last `equilibrate`, and at its end: `iterations + 1` values for a converged solve.
    pub fn residual_history(&self) -> &[f64] {
        &self.history
    }

    /// The KKT matrix last assembled by `assemble_kkt`.
    pub(crate) fn kkt(&self) -> &DMatrix<f64> {
        &self.kkt
    }

    /// The body size used for the length scale (`body_size`), m.
    pub(crate) fn size(&self) -> f64 {
        self.size
    }

    /// The constant mass matrix in local coordinates (formed on first use for a large model).
    pub(crate) fn mass(&mut self, model: &Model) -> &DMatrix<f64> {
        if self.mass.nrows() != model.dof_count {
            self.mass = crate::solve::dynamics::mass_matrix(model);
        }
        &self.mass
    }

    /// Tangent of the equilibrium path at the equilibrium `state`: `(dq/dt, dlambda/dt)` from
    /// `A z = dr/dt` (see `load_rate`), with the regularized solve of the Newton steps (a free
    /// rigid-body motion gets no component). `None` when the KKT matrix cannot be solved (a
    /// limit point). Leaves `ws` evaluated at `state` with its stiffness.
    pub fn path_tangent(&mut self, model: &Model, state: &State, ws: &mut Workspace) -> Option<DVector<f64>> {
        if self.sparse_newton {
            evaluate_forces(model, state, ws);
        } else {
            evaluate(model, state, ws, Tangents::Stiffness);
        }
        let mut rates = vec![0.0; model.cables.len()];
        model.scheduled_rest_rates(state.time, &mut rates);
        let mut r_t = DVector::zeros(model.dof_count + model.constraint_count);
        load_rate(model, state, ws, &rates, &mut r_t);
        if r_t.amax() == 0.0 {
            return Some(r_t);
        }
        if let Some(kkt) = self.sparse.as_mut().filter(|_| self.sparse_newton) {
            assemble_sparse(kkt, model, state, ws);
            return solve_sparse(kkt, &r_t);
        }
        self.assemble_kkt(model, state, ws);
        solve_regularized(&self.kkt, &r_t, model.dof_count)
    }

    /// Solves for equilibrium from `state` (its rest lengths fixed), updating its poses and
    /// multipliers; velocities are set to zero. On failure the state is restored.
    ///
    /// For a structure set down where it stands (a scene's pose, the start of a run or a
    /// deployment). With stick-slip grounds (`crate::model::StickFriction`) the contacts hold
    /// where the bodies stand (the state's anchors, `State::contact_anchors`), sticking and
    /// slipping as in `equilibrate_holding`. At a sketch the contacts barely touch and carry
    /// nothing, so the solve first settles the structure on the grounds' normal springs alone,
    /// moves each free group of bodies rigidly back onto its anchors (`align_onto_anchors`: the
    /// turn or slide a frictionless settle allows) and holds the contacts from there; the
    /// iterations of both solves are counted. Where the held solve finds nothing, the contacts
    /// are stuck where the settle put them (unstretched anchors); where the settle finds nothing
    /// (a body on an incline), they are held from the state's anchors. A model whose form
    /// finding needed friction (`Model::friction_holds_sketch`: a foot pulled sideways by a
    /// prestressed cable) is held from its anchors first, and set down on its normal springs only where that fails (a
    /// solve failing both ways reports the held attempt's reason). Along a path (a deployment's
    /// load steps) use `equilibrate_holding`, which carries the anchors.
    pub fn equilibrate(
        &mut self,
        model: &Model,
        state: &mut State,
        ws: &mut Workspace,
        settings: &SolverSettings,
    ) -> Result<EquilibriumReport, (usize, f64)> {
        if state.contact_anchors.is_empty() {
            return self.equilibrate_from(model, state, ws, settings);
        }
        // (a failed solve leaves the state as it found it)
        if !model.friction_holds_sketch {
            return self.equilibrate_set_down(model, state, ws, settings);
        }
        let held = self.equilibrate_from(model, state, ws, settings);
        let Err(held_error) = held else { return held };
        let (held_stop, held_history, held_slipping) =
            (self.stop, self.history.clone(), self.slipping.clone());
        match self.settle_unanchored(model, state, ws, settings) {
            Ok(report) => {
                stick_where_it_stands(model, state, ws);
                Ok(report)
            }
            Err(_) => {
                self.stop = held_stop;
                self.history = held_history;
                self.slipping = held_slipping;
                Err(held_error)
            }
        }
    }

    /// `equilibrate_from` on the grounds' normal springs alone: the state's contact anchors
    /// taken out (left empty where it converges, put back where it fails).
    fn settle_unanchored(
        &mut self,
        model: &Model,
        state: &mut State,
        ws: &mut Workspace,
        settings: &SolverSettings,
    ) -> Result<EquilibriumReport, (usize, f64)> {
        let anchors = std::mem::take(&mut state.contact_anchors);
        let settled = self.equilibrate_from(model, state, ws, settings);
        if settled.is_err() {
            state.contact_anchors = anchors;
        }
        settled
    }

    /// `equilibrate` of a structure set down without friction in its form finding: the normal
    /// springs alone first, then held from the state's anchors after a rigid alignment onto
    /// them (or stuck where the settle put them when that finds nothing); where the settle finds
    /// nothing (a body on an incline), the contacts held from the state's anchors.
    fn equilibrate_set_down(
        &mut self,
        model: &Model,
        state: &mut State,
        ws: &mut Workspace,
        settings: &SolverSettings,
    ) -> Result<EquilibriumReport, (usize, f64)> {
        let anchors = state.contact_anchors.clone();
        let Ok(report) = self.settle_unanchored(model, state, ws, settings) else {
            return self.equilibrate_from(model, state, ws, settings);
        };
        // then held where the bodies stood: moved back rigidly onto the anchors, the contacts
        // stretched only by the structure's own deformation
        let settled = (state.poses.clone(), state.multipliers.clone());
        let (stop, history) = (self.stop, self.history.clone());
        state.contact_anchors = anchors;
        evaluate_forces(model, state, ws);
        align_onto_anchors(model, state, ws);
        if let Ok(mut held) = self.equilibrate_from(model, state, ws, settings) {
            held.iterations += report.iterations;
            return Ok(held);
        }
        // no held equilibrium near: the contacts stuck where the normal springs put them
        state.poses.copy_from_slice(&settled.0);
        state.multipliers.copy_from(&settled.1);
        (self.stop, self.history) = (stop, history);
        stick_where_it_stands(model, state, ws);
        Ok(report)
    }

    /// `equilibrate` from a previous equilibrium along a path: stick-slip contacts hold from the
    /// state's anchors (where the path left them), stick while their springs pull inside the
    /// friction cone and slip along it beyond, and the equilibrium commits where they slipped to
    /// (the pulleys' friction likewise). Without stick-slip grounds the same as `equilibrate`.
    /// While a contact slips, the Newton steps are the consistent tangent's own, judged by the
    /// residual (no convexity shift: slipping friction is not the gradient of an energy). A
    /// failed solve leaves the state as it found it; the caller cuts the load step, and where
    /// that does not help either gives up holding (`release_contacts`), after which this is
    /// `equilibrate`.
    pub fn equilibrate_holding(
        &mut self,
        model: &Model,
        state: &mut State,
        ws: &mut Workspace,
        settings: &SolverSettings,
    ) -> Result<EquilibriumReport, (usize, f64)> {
        if state.contact_anchors.is_empty() {
            return self.equilibrate_from(model, state, ws, settings);
        }
        if self.holding_failed {
            return self.equilibrate(model, state, ws, settings);
        }
        self.equilibrate_from(model, state, ws, settings)
    }

    /// Gives up holding the contacts along the path: every later `equilibrate_holding` of this
    /// solver solves its state as `equilibrate` solves a structure set down, its contacts stuck
    /// where the normal springs alone put it (`contacts_held` is false from now on). For a path
    /// whose held solve found no equilibrium even in small load steps.
    pub fn release_contacts(&mut self) {
        self.holding_failed = true;
    }

    /// `equilibrate` with the contacts as the state has them (its anchors, or none). A solve
    /// that stops without an equilibrium while a stick-slip contact slipped at its last
    /// iteration stops for `StopReason::ContactSlips`: no equilibrium holds that contact inside
    /// its friction cone (a block on an incline steeper than `atan(mu)`).
    fn equilibrate_from(
        &mut self,
        model: &Model,
        state: &mut State,
        ws: &mut Workspace,
        settings: &SolverSettings,
    ) -> Result<EquilibriumReport, (usize, f64)> {
        self.slipping.clear();
        let result = self.equilibrate_contacts_as_they_are(model, state, ws, settings);
        if result.is_err() && !self.slipping.is_empty() {
            self.stop = StopReason::ContactSlips;
        }
        result
    }

    fn equilibrate_contacts_as_they_are(
        &mut self,
        model: &Model,
        state: &mut State,
        ws: &mut Workspace,
        settings: &SolverSettings,
    ) -> Result<EquilibriumReport, (usize, f64)> {
        self.history.clear();
        self.stop = StopReason::Converged;
        if !self.stiff.is_empty() {
            return self.equilibrate_mixed(model, state, ws, settings, self.stiff.clone(), false);
        }
        // a prestressed structure with stiff cables: the mixed form with its cables as if they
        // could push, which keeps its self-stress; an equilibrium in which they all pull is the
        // structure's (the residual test below is the displacement form's, with the cables'
        // own law). Otherwise the displacement form from the same start.
        let mut tried = 0;
        if !self.prestressed.is_empty() {
            let start = (state.poses.clone(), state.multipliers.clone());
            match self.equilibrate_mixed(model, state, ws, settings, self.prestressed.clone(), true) {
                Ok(report) => {
                    evaluate(model, state, ws, Tangents::None);
                    if self.prestressed.iter().all(|&c| !ws.cables[c].slack) {
                        return Ok(report);
                    }
                    tried = report.iterations;
                    state.poses.copy_from_slice(&start.0);
                    state.multipliers.copy_from(&start.1);
                }
                Err((iterations, _)) => tried = iterations,
            }
            self.history.clear();
            self.stop = StopReason::Converged;
        }
        self.displacement_form(model, state, ws, settings)
            .map(|mut r| {
                r.iterations += tried;
                r
            })
            .map_err(|(iterations, residual)| (iterations + tried, residual))
    }

    /// `equilibrate` in the displacement form (no tension unknowns).
    fn displacement_form(
        &mut self,
        model: &Model,
        state: &mut State,
        ws: &mut Workspace,
        settings: &SolverSettings,
    ) -> Result<EquilibriumReport, (usize, f64)> {
        let n = model.dof_count;
        let nc = model.constraint_count;
        state.velocities.fill(0.0);
        let start_poses = state.poses.clone();
        let start_multipliers = state.multipliers.clone();
        // a fresh start has no reactions yet; a continuation (deployment) keeps the last ones
        let fresh = state.multipliers.iter().all(|l| *l == 0.0);
        if fresh {
            match self.sparse.as_mut().filter(|_| self.sparse_newton) {
                Some(kkt) => sparse_least_squares_multipliers(kkt, model, state, ws),
                None => least_squares_multipliers(model, state, ws),
            }
        }
        let mut best = f64::INFINITY;
        let mut iterations = 0;
        // the definiteness check costs a dense eigenproblem: made on the first iteration of a fresh
        // start (a continuation starts at an equilibrium) and after any iteration whose Newton
        // step had to be cut or did not halve the residual
        let mut check_convexity = fresh || model.constraint_count == 0;
        let mut previous_merit = f64::INFINITY;
        // the Levenberg-Marquardt shift of the sparse path, 1/s^2: 0 while plain Newton steps
        // make progress; `mu M` is added to the tangent after a step that was capped or lowered
        // neither the residual nor the energy (an indefinite or singular tangent at a rough
        // start, which the dense path's convexity check would have shifted), grown tenfold while
        // shifted steps fail and shrunk tenfold while they succeed (`next_sparse_shift`)
        let mut sparse_shift = 0.0;
        loop {
            let res = match self.start_iteration(model, state, ws, settings, iterations, &mut best) {
                Start::Go(res) => res,
                Start::Converged(report) => return Ok(report),
                Start::Stop => break,
            };
            iterations += 1;

            let mut energy_mode = false;
            let merit_now = res.merit(res.force_scale, res.length_scale);
            check_convexity |= merit_now > 0.25 * previous_merit;
            previous_merit = merit_now;
            // the sparse path takes plain Newton steps; up to `MAX_CONVEXITY_CHECK` coordinates an
            // iteration that wants the convexity check (a fresh start, a step that had to be cut)
            // takes the dense step with it
            let dense_check = check_convexity && n <= MAX_CONVEXITY_CHECK;
            let sparse_step = self.sparse_newton && !dense_check;
            let step = match self.sparse.as_mut().filter(|_| sparse_step) {
                Some(kkt) => {
                    assemble_sparse(kkt, model, state, ws);
                    if sparse_shift > 0.0 {
                        // a descent step of the energy where K + mu M is positive definite; the
                        // line search judges it as a Newton step (by the residual or the energy:
                        // near the solution the energy's decrease drowns in round-off)
                        add_mass_shift(kkt, model, sparse_shift);
                    }
                    solve_sparse(kkt, &self.rhs)
                }
                None => {
                    if self.sparse_newton {
                        evaluate(model, state, ws, Tangents::Stiffness);
                    }
                    self.dense_newton_step(model, state, ws, &res, &mut check_convexity, &mut energy_mode)
                }
            };
            let Some(step) = step else {
                self.stop = StopReason::Singular;
                break;
            };
            self.dq.copy_from(&step.rows(0, n));
            let limit = self.step_limit(model, res.length_scale);
            let dlambda = step.rows(n, nc).into_owned();

            // backtracking line search: a Newton step is accepted when it lowers the residual norm
            // or the potential energy (plus a joint-violation penalty); a modified (descent) step
            // only when it lowers the energy on the joints' manifold
            let penalty = 10.0 * ((&state.multipliers + &dlambda).amax() + res.force_scale);
            let energy_merit = |ws: &Workspace| {
                ws.energies.elastic + ws.energies.gravitational + penalty * ws.constraint.amax()
            };
            let search = LineSearch {
                limit,
                merit0: res.merit(res.force_scale, res.length_scale),
                energy0: energy_merit(ws),
                energy_mode,
            };
            let base_multipliers = state.multipliers.clone();
            self.best_poses.copy_from_slice(&state.poses);
            let searched = line_search(&search, |alpha| {
                self.trial_poses.copy_from_slice(&self.best_poses);
                retract(model, &mut self.trial_poses, &self.dq, alpha);
                std::mem::swap(&mut state.poses, &mut self.trial_poses);
                state.multipliers = &base_multipliers + &dlambda * alpha;
                if energy_mode {
                    // compare energies on the joints' manifold: the shifted step is a descent
                    // direction of the energy there, and a joint violation of second order in a
                    // large rotation would otherwise hide a first-order energy decrease
                    project_onto_joints(model, state, ws, res.length_scale);
                }
                evaluate_forces(model, state, ws);
                let residual_merit = residual_of(model, state, ws, &mut self.rhs, self.size)
                    .merit(res.force_scale, res.length_scale);
                std::mem::swap(&mut state.poses, &mut self.trial_poses);
                (residual_merit, energy_merit(ws))
            });
            let Some(Searched { alpha, decreased }) = searched else {
                self.stop = StopReason::Diverged;
                break;
            };
            check_convexity |= alpha < limit.min(1.0);
            if sparse_step {
                // a full step that lowered the merit is a success; a capped or failed one not
                let success = decreased && alpha >= 1.0;
                sparse_shift = next_sparse_shift(sparse_shift, success, sparse_shift_base(model, &res));
            }
            retract(model, &mut state.poses, &self.dq, alpha);
            state.multipliers = &base_multipliers + &dlambda * alpha;
            if energy_mode {
                // a descent step moves the poses, not towards the reactions: take them afresh
                project_onto_joints(model, state, ws, res.length_scale);
                least_squares_multipliers(model, state, ws);
            }
        }
        state.poses.copy_from_slice(&start_poses);
        state.multipliers.copy_from(&start_multipliers);
        Err((iterations, best))
    }

    /// The Newton step of the dense displacement form at `state` (evaluated into `ws` with its
    /// stiffness; `res` its residual, `self.rhs` its right-hand side): the KKT matrix, shifted
    /// where the reduced tangent is not convex when `check_convexity` asks (then `energy_mode`
    /// tells whether the step is a descent step of the energy), solved with regularization.
    fn dense_newton_step(
        &mut self,
        model: &Model,
        state: &State,
        ws: &Workspace,
        res: &Residual,
        check_convexity: &mut bool,
        energy_mode: &mut bool,
    ) -> Option<DVector<f64>> {
        let n = model.dof_count;
        self.assemble_kkt(model, state, ws);
        // where the reduced tangent is indefinite or singular (hanging masses, slack cables,
        // a structure tilted past a maximum of its energy), shift it by mu M: the step then
        // goes down the potential energy instead of towards the nearest stationary point
        // not while a contact slips (`equilibrate_mixed` says why): Newton's own step
        let correction = if *check_convexity && self.slipping.is_empty() {
            let tangent = self.kkt.view((0, 0), (n, n)).into_owned();
            let residual_force = self.rhs.rows(0, n).into_owned();
            convexity_correction(model, &tangent, &ws.constraint_jacobian, &self.mass, res, &residual_force)
        } else {
            None
        };
        *check_convexity = false;
        if let Some((correction, descent)) = correction {
            *check_convexity = true;
            let mut top = self.kkt.view_mut((0, 0), (n, n));
            top += &correction;
            *energy_mode = descent;
        }
        solve_regularized(&self.kkt, &self.rhs, n)
    }

    /// The report of a converged equilibrium: `res` its residual, stability from the tangents
    /// last evaluated into `ws` (on a sparse solver, from `ws`'s kinematics and cable states).
    pub(crate) fn report(
        &mut self,
        model: &Model,
        state: &State,
        ws: &mut Workspace,
        res: &Residual,
        iterations: usize,
    ) -> EquilibriumReport {
        let modes = match &mut self.sparse {
            Some(kkt) => sparse_stability(kkt, model, state, ws),
            None => {
                let members: Vec<usize> =
                    self.stiff.iter().copied().filter(|&c| !model.cables[c].tension_only).collect();
                dense_stability(model, state, ws, &members)
            }
        };
        EquilibriumReport {
            iterations,
            residual: res.force,
            force_scale: res.force_scale,
            constraint_residual: res.constraint,
            min_stiffness_eigenvalue: modes.min_eigenvalue,
            stable: modes.negative == 0 && modes.zero <= modes.rigid,
            negative_modes: modes.negative,
            zero_modes: modes.zero,
            rigid_modes: modes.rigid,
            potential_energy: ws.energies.elastic + ws.energies.gravitational,
        }
    }
}

/// Sticks every contact of `state` unstretched where it stands (`initial_anchors`) and
/// evaluates `ws` there.
fn stick_where_it_stands(model: &Model, state: &mut State, ws: &mut Workspace) {
    state.contact_anchors = crate::forces::contact::initial_anchors(model, &state.poses);
    evaluate(model, state, ws, Tangents::None);
}

/// The sparse displacement form's first Levenberg-Marquardt shift, 1/s^2: the curvature of the
/// structure's own scale, `(|g| + F / m_max) / L` (the dense convexity shift's floor,
/// `convexity_correction`), with `F` and `L` the residual's force and length scales.
fn sparse_shift_base(model: &Model, res: &Residual) -> f64 {
    let m_max = model.bodies.iter().map(|b| b.mass).fold(0.0, f64::max).max(1e-300);
    (model.gravity.norm() + res.force_scale / m_max) / res.length_scale
}

/// Shifts below this fraction of the base return to plain Newton steps.
pub const SPARSE_SHIFT_OFF: f64 = 1e-4;

/// The largest shift, as a multiple of the base: a step this shifted is a gradient step of the
/// size the structure's own forces move it in `1e-3 / sqrt(base)` s.
pub const SPARSE_SHIFT_MAX: f64 = 1e6;

/// The sparse shift after a step with shift `shift` that was a `success` (taken whole, and it
/// lowered its merit) or not: a failed plain step starts shifting at `base`, a failed shifted
/// step shifts ten times more (up to `SPARSE_SHIFT_MAX` times the base), a successful shifted
/// step ten times less (and none below `SPARSE_SHIFT_OFF` of the base).
fn next_sparse_shift(shift: f64, success: bool, base: f64) -> f64 {
    match (shift > 0.0, success) {
        (false, true) => 0.0,
        (false, false) => base,
        (true, false) => (10.0 * shift).min(SPARSE_SHIFT_MAX * base),
        (true, true) if shift / 10.0 < SPARSE_SHIFT_OFF * base => 0.0,
        (true, true) => shift / 10.0,
    }
}

/// Adds `shift` times every body's mass matrix (`BodyModel::mass_matrix`, in its local
/// coordinates) to the coordinate block of the sparse `kkt`.
fn add_mass_shift(kkt: &mut KktSystem, model: &Model, shift: f64) {
    for (b, body) in model.bodies.iter().enumerate() {
        if body.dof_count > 0 {
            kkt.add_body_block(BodyId(b), BodyId(b), &body.mass_matrix(), shift);
        }
    }
}
