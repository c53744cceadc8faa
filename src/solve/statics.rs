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

use nalgebra::{DMatrix, DVector, SymmetricEigen};

use crate::assembly::DenseTangents;
use crate::constraints::{add_multiplier_hessian, add_multiplier_hessian_to};
use crate::evaluate::{add_workspace_tangents, evaluate, evaluate_forces, Tangents, Workspace};
use crate::model::{CableId, Model, Pose, SolverSettings};
use crate::solve::linear::{KktSystem, LinearBackend};
use crate::state::{retract, State};

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

/// The free rigid-body motions of the whole structure at the evaluated configuration
/// (`ws.points`, `state.poses`), as columns of generalized velocities (local coordinates): among
/// the world motions `v(r) = t + w x (r - c)` (3 translations and 3 rotations about the centroid
/// `c` of the moving points; in a planar scene `t` in the plane and `w` about z), those that leave
/// every anchor still (`v(F) = 0` for each fixed point a cable segment or joint ties the structure
/// to: only then are lengths to it kept at every order, not just the first), and that move some
/// body. 6 columns for a structure held by nothing, 3 in a planar scene, fewer
/// with partial supports. Linear in the scene size (6 x 6 Gram matrices).
pub fn rigid_body_motions(model: &Model, state: &State, ws: &Workspace) -> DMatrix<f64> {
    use nalgebra::{Matrix6, Vector3};
    let n = model.dof_count;
    let moving = |p: usize| model.bodies[model.points[p].body.0].dof_count > 0;
    let moving_points: Vec<usize> = (0..model.points.len()).filter(|&p| moving(p)).collect();
    if moving_points.is_empty() {
        return DMatrix::zeros(n, 0);
    }
    let c = moving_points.iter().map(|&p| ws.points[p].position).sum::<Vector3<f64>>()
        / moving_points.len() as f64;
    let generators: Vec<(Vector3<f64>, Vector3<f64>)> = if model.planar {
        vec![
            (Vector3::x(), Vector3::zeros()),
            (Vector3::y(), Vector3::zeros()),
            (Vector3::zeros(), Vector3::z()),
        ]
    } else {
        (0..6)
            .map(|k| {
                if k < 3 {
                    (Vector3::ith(k, 1.0), Vector3::zeros())
                } else {
                    (Vector3::zeros(), Vector3::ith(k - 3, 1.0))
                }
            })
            .collect()
    };
    // Gram matrix of the generators' velocities at the anchors (must vanish)
    let g = generators.len();
    let mut broken = Matrix6::<f64>::zeros();
    let add = |m: &mut Matrix6<f64>, row: &[f64]| {
        for i in 0..g {
            for j in 0..g {
                m[(i, j)] += row[i] * row[j];
            }
        }
    };
    // a rigid motion of the moving bodies keeps every length between them; it keeps a length to a
    // fixed point at every order only if that point would not move (it lies on the motion's axis)
    let mut anchors: Vec<Vector3<f64>> = Vec::new();
    for cable in 0..model.cables.len() {
        let route = model.route(crate::model::CableId(cable));
        for k in 1..route.len() {
            let (a, b) = (route[k - 1].0, route[k].0);
            if moving(a) != moving(b) {
                anchors.push(ws.points[if moving(a) { b } else { a }].position);
            }
        }
    }
    let mut row = [0.0; 6];
    for anchor in &anchors {
        for axis in 0..3 {
            for (i, (t, w)) in generators.iter().enumerate() {
                row[i] = (t + w.cross(&(anchor - c)))[axis];
            }
            add(&mut broken, &row[..g]);
        }
    }
    // a joint to the ground holds its point along its held directions only (a roller, a slider)
    for joint in &model.joints {
        let anchor = match joint.target {
            crate::model::JointTarget::World(x) => x,
            crate::model::JointTarget::Point(q) if !moving(q.0) => ws.points[q.0].position,
            crate::model::JointTarget::Point(_) => continue,
        };
        // an axis held to the ground turns with no rigid motion but about itself
        let held = joint
            .alignment
            .map(|al| crate::constraints::alignment_directions(model, &state.poses, joint, &al));
        for r in 0..joint.rows {
            for (i, (t, w)) in generators.iter().enumerate() {
                row[i] = match &held {
                    None => joint.project(&(t + w.cross(&(anchor - c))))[r],
                    Some(d) => (d * w)[r],
                };
            }
            add(&mut broken, &row[..g]);
        }
    }
    // each generator as generalized velocities: per body `(dx_world, dtheta_body)` through the
    // body's orthonormal basis columns (a spin that moves no point still turns a rigid body)
    let mut local = DMatrix::zeros(n, g);
    for (i, (t, w)) in generators.iter().enumerate() {
        for (b, body) in model.bodies.iter().enumerate() {
            let pose = &state.poses[b];
            let dx = t + w.cross(&(pose.position - c));
            let dtheta = pose.rotation.inverse() * w;
            let motion = nalgebra::Vector6::new(dx.x, dx.y, dx.z, dtheta.x, dtheta.y, dtheta.z);
            for k in 0..body.dof_count {
                local[(body.dof_offset + k, i)] = body.basis.column(k).dot(&motion);
            }
        }
    }
    let gram = local.transpose() * &local;
    let mut moved = Matrix6::<f64>::zeros();
    moved.view_mut((0, 0), (g, g)).copy_from(&gram);
    // free combinations: the null space of `broken`, restricted to those that move something
    let broken = broken.view((0, 0), (g, g)).into_owned();
    let moved = moved.view((0, 0), (g, g)).into_owned();
    let scale = moved.amax().max(1e-300);
    let eig = SymmetricEigen::new(broken);
    let free: Vec<DVector<f64>> = (0..g)
        .filter(|&i| eig.eigenvalues[i] <= 1e-10 * scale)
        .map(|i| eig.eigenvectors.column(i).into_owned())
        .collect();
    if free.is_empty() {
        return DMatrix::zeros(n, 0);
    }
    let basis = DMatrix::from_columns(&free);
    let effect = SymmetricEigen::new(basis.transpose() * moved * &basis);
    let combos: Vec<DVector<f64>> = (0..free.len())
        .filter(|&i| effect.eigenvalues[i] > 1e-10 * scale)
        .map(|i| &basis * effect.eigenvectors.column(i))
        .collect();
    if combos.is_empty() {
        // free combinations that move nothing: a node on the line through its anchors spinning
        // about that line
        return DMatrix::zeros(n, 0);
    }
    DMatrix::from_columns(&combos.iter().map(|a| &local * a).collect::<Vec<_>>())
}

/// What the reduced tangent stiffness's eigenvalues say.
struct Modes {
    min_eigenvalue: f64,
    negative: usize,
    zero: usize,
    /// Free rigid-body motions (`rigid_body_motions`) that also have zero stiffness.
    rigid: usize,
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
}

impl StopReason {
    /// The reason in words (`converged`, `iteration limit`, `stagnated`, `diverged`, `singular`).
    pub fn words(self) -> &'static str {
        match self {
            StopReason::Converged => "converged",
            StopReason::IterationLimit => "iteration limit",
            StopReason::Stagnated => "stagnated",
            StopReason::Diverged => "diverged",
            StopReason::Singular => "singular",
        }
    }

    /// `IterationLimit` or `Stagnated` for a solve that reached its cap with the residuals
    /// `history` (one per iteration, N).
    fn at_cap(history: &[f64]) -> Self {
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

/// What `StaticSolver::start_iteration` found.
enum Start {
    /// Go on with this residual.
    Go(Residual),
    /// Converged: the report.
    Converged(EquilibriumReport),
    /// Stop without an equilibrium (`StaticSolver::stop_reason` says why).
    Stop,
}

/// Buffers for the Newton iteration, sized once per model.
#[derive(Debug, Clone)]
pub struct StaticSolver {
    /// The dense KKT matrix (`assemble_kkt`), sized on first use.
    kkt: DMatrix<f64>,
    /// The sparse KKT system of a model of at least `SPARSE_STATICS_MIN` coordinates: its
    /// stability test (`sparse_stability`), and its Newton steps when `sparse_newton`.
    sparse: Option<KktSystem>,
    /// Newton steps on `sparse` (a model without stiff cables, solved in the displacement form).
    sparse_newton: bool,
    rhs: DVector<f64>,
    dq: DVector<f64>,
    trial_poses: Vec<Pose>,
    best_poses: Vec<Pose>,
    /// Mass matrix in local coordinates (constant), the metric of the convexity shift.
    mass: DMatrix<f64>,
    /// `body_size(model)`, m.
    size: f64,
    /// The force residual at the start of each iteration of the last solve, N.
    history: Vec<f64>,
    /// Why the last solve stopped.
    stop: StopReason,
    /// The model's stiff cables (`stiff_cables`), whose tensions `equilibrate` solves for.
    stiff: Vec<usize>,
    /// The stiff cables of a structure held by prestress (`prestressed_stiff_cables`), which
    /// `equilibrate` first solves for as if they could push.
    prestressed: Vec<usize>,
}

pub(crate) struct Residual {
    pub(crate) force: f64,
    pub(crate) constraint: f64,
    pub(crate) force_scale: f64,
    pub(crate) length_scale: f64,
    /// Round-off floor of the force residual: positions carry a relative error of about machine
    /// epsilon, so a cable's force is only known to `~eps EA L / L0`.
    pub(crate) force_floor: f64,
}

impl Residual {
    /// True when this residual passes the convergence test of `StaticSolver::equilibrate`.
    pub(crate) fn converged(&self, settings: &SolverSettings) -> bool {
        self.force <= (settings.tolerance * self.force_scale).max(self.force_floor)
            && self.force <= ROUND_OFF_CEILING * self.force_scale
            && self.constraint <= settings.tolerance * self.length_scale
    }

    fn merit(&self, f_scale: f64, l_scale: f64) -> f64 {
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
    let force_floor = model
        .cables
        .iter()
        .zip(&ws.cables)
        .map(|(m, c)| 16.0 * f64::EPSILON * m.axial_stiffness * c.length / c.rest_length)
        .fold(0.0, f64::max);
    Residual {
        force_floor,
        force: r.amax(),
        constraint: ws.constraint.amax(),
        force_scale: weight.max(tension).max(1e-12),
        length_scale: length.max(size),
    }
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
    fn start_iteration(
        &mut self,
        model: &Model,
        state: &State,
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
        if !res.force.is_finite() || !res.constraint.is_finite() {
            self.stop = StopReason::Diverged;
            return Start::Stop;
        }
        *best = best.min(res.force);
        if res.converged(settings) {
            self.stop = StopReason::Converged;
            return Start::Converged(self.report(model, state, ws, &res, iterations));
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
    pub fn equilibrate(
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
        loop {
            let res = match self.start_iteration(model, state, ws, settings, iterations, &mut best) {
                Start::Go(res) => res,
                Start::Converged(report) => {
                    commit_friction(model, state, ws);
                    return Ok(report);
                }
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
            let step = match self.sparse.as_mut().filter(|_| self.sparse_newton && !dense_check) {
                Some(kkt) => {
                    assemble_sparse(kkt, model, state, ws);
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
            let energy0 = energy_merit(ws);
            let merit0 = res.merit(res.force_scale, res.length_scale);
            let base_multipliers = state.multipliers.clone();
            self.best_poses.copy_from_slice(&state.poses);
            let mut alpha = limit;
            let mut best_trial = (f64::INFINITY, alpha);
            for _ in 0..12 {
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
                let trial = if energy_mode { energy_merit(ws) } else { residual_merit };
                std::mem::swap(&mut state.poses, &mut self.trial_poses);
                if trial.is_finite() && trial < best_trial.0 {
                    best_trial = (trial, alpha);
                }
                // a Newton step on a positive-definite tangent is a descent step of the energy too:
                // far from the solution the energy tells progress better than the residual (a
                // cable swung about its anchor stretches on the tangent line), near it the
                // residual does (the energy's decrease drowns in round-off)
                let decreased = if energy_mode {
                    trial < energy0
                } else {
                    trial <= (1.0 - 1e-4 * alpha) * merit0 || energy_merit(ws) < energy0
                };
                if trial.is_finite() && decreased {
                    break;
                }
                alpha *= 0.5;
            }
            if !best_trial.0.is_finite() {
                self.stop = StopReason::Diverged;
                break;
            }
            let alpha = best_trial.1;
            check_convexity |= alpha < limit.min(1.0);
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
        let correction = if *check_convexity {
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

/// The symmetric reduced tangent stiffness's smallest eigenvalue and its counts of negative and
/// zero eigenvalues (relative to the largest, `1e-9`), from the dense tangent last evaluated into
/// `ws`: the reduced tangent `Z^T K_sym Z` over an orthonormal null-space basis `Z` of `Phi_q`,
/// all its eigenvalues (`sparse_stability` counts them without forming `Z`).
///
/// The stiff members `stiff_members` (the mixed form's, `stiff_cables`) are judged in their
/// inextensible limit: `Z` also spans only motions that keep their lengths, on which their
/// material stiffness `(EA/L0) g g^T` vanishes, so the tolerance scales with the structure's own
/// stiffness and not with theirs (a strut of EA 1e12 N would otherwise make every mode below
/// 1e-9 of its `EA/L0` count as zero). Along their lengths they only add stiffness.
fn dense_stability(model: &Model, state: &State, ws: &Workspace, stiff_members: &[usize]) -> Modes {
    let n = model.dof_count;
    if n == 0 {
        return Modes { min_eigenvalue: 0.0, negative: 0, zero: 0, rigid: 0 };
    }
    let mut k = ws.stiffness.clone();
    if model.constraint_count > 0 {
        add_multiplier_hessian(model, &state.poses, &state.multipliers, &mut k);
    }
    let k_sym = (&k + k.transpose()) * 0.5;
    let held = if stiff_members.is_empty() {
        None
    } else {
        let nc = model.constraint_count;
        let mut j = DMatrix::zeros(nc + stiff_members.len(), n);
        if nc > 0 {
            j.view_mut((0, 0), (nc, n)).copy_from(&ws.constraint_jacobian);
        }
        let mut scratch = crate::forces::cable::CableScratch::new(2);
        for (k, &c) in stiff_members.iter().enumerate() {
            let route = model.route(CableId(c));
            crate::forces::cable::route_geometry(route, &ws.points, &mut scratch);
            let mut g = DVector::zeros(n);
            crate::forces::cable::add_length_gradient(model, route, &ws.points, &scratch, 1.0, &mut g);
            j.view_mut((nc + k, 0), (1, n)).copy_from(&g.transpose());
        }
        Some(j)
    };
    let Some(z) = crate::constraints::null_space(held.as_ref().unwrap_or(&ws.constraint_jacobian), n) else {
        return Modes { min_eigenvalue: f64::INFINITY, negative: 0, zero: 0, rigid: 0 };
    };
    let reduced = z.transpose() * &k_sym * z;
    let eig = SymmetricEigen::new(reduced).eigenvalues;
    let tol = 1e-9 * eig.amax().max(1e-300);
    // the free rigid motions, orthonormalized, and how many of them cost no energy
    let motions = rigid_body_motions(model, state, ws);
    let rigid = if motions.ncols() == 0 {
        0
    } else {
        let q = motions.qr().q();
        let on_rigid = SymmetricEigen::new(q.transpose() * &k_sym * &q).eigenvalues;
        on_rigid.iter().filter(|e| e.abs() <= tol).count()
    };
    Modes {
        min_eigenvalue: eig.min(),
        negative: eig.iter().filter(|e| **e < -tol).count(),
        zero: eig.iter().filter(|e| e.abs() <= tol).count(),
        rigid,
    }
}

/// A cable is stiff, and `StaticSolver::equilibrate` carries its tension as an unknown, when its
/// material stiffness `EA / L0` exceeds this many times the structure's own stiffness scale
/// `F_ref / L_scale` (`F_ref` the largest body weight or cable tension, N, the weight alone when
/// the start is out of equilibrium; `L_scale` the longest cable or body, m), both taken in the
/// scene's initial state: its stretch under the structure's
/// loads is then below a thousandth of the structure's size, and a Newton step that moves its
/// ends along an arc would stretch it by far more than that (see `equilibrate_mixed`).
pub const STIFF_CABLE_RATIO: f64 = 1e1;

/// A cable of a structure held by prestress is solved for in the bilateral mixed form
/// (`prestressed_stiff_cables`) when its `EA / L0` exceeds this many times the structure's
/// stiffness scale (`STIFF_CABLE_RATIO`'s `F_ref / L_scale`). Below it the displacement form
/// converges in as few iterations or fewer: the prism (100 N of prestress, cables about 1 m) from
/// 0.02 disturbances took at most 4, 10 and 12 Newton iterations at EA 1e3, 1e4 and 1e5 N in the
/// displacement form and 13, 16 and 14 in the mixed one; at 1e6 N, 18 against 13, growing to 28
/// at 1e9 N against 11 (`tests/stiff_statics.rs`).
pub const PRESTRESSED_STIFF_RATIO: f64 = 1e4;

/// Largest residual, relative to the largest tension, of a start that counts as an equilibrium
/// held by prestress (`stiff_cables`).
pub const PRESTRESSED_START: f64 = 1e-6;

/// The cables `equilibrate` treats as stiff (`STIFF_CABLE_RATIO`), in model order: a property of
/// the model, judged in its initial state (`State::initial`), so that every solve of a scene (a
/// deployment's load steps, a disturbed start) takes the same formulation. A structure without
/// weight, or one that starts in equilibrium (residual below `PRESTRESSED_START` of its largest
/// tension) with more tension than its heaviest body weighs, is held by its prestress (a
/// form-found tensegrity, a lever between springs) and has none: from a badly disturbed start the mixed iteration can lose a self-stress (every
/// cable slack is an equilibrium of a free structure too), where the displacement form comes back
/// to it (`tests/free_structures.rs`, `tests/perturbed_starts.rs`). A sketch drawn with its
/// cables overstretched is not in equilibrium and keeps its stiff cables. `size` is
/// `body_size(model)`; `ws` (a `Workspace::for_forces` will do) is overwritten.
///
/// Stiff elastic members (`CableModel::tension_only` false, without a buckling law) join the set
/// in scenes small enough for the mixed form's dense steps (`SPARSE_STATICS_MIN`), prestressed or
/// not: a member cannot go slack, so no self-stress is lost through it, and its force takes
/// either sign.
pub fn stiff_cables(model: &Model, ws: &mut Workspace, size: f64) -> Vec<usize> {
    stiff_sets(model, ws, size).0
}

/// The stiff tension-only cables (`STIFF_CABLE_RATIO`, as in `stiff_cables`) of a structure held
/// by its prestress, in scenes small enough for the mixed form's dense steps
/// (`SPARSE_STATICS_MIN`): `equilibrate` first solves for their tensions as if they could push
/// (the mixed form, bilateral), which cannot lose the self-stress through a cable going slack in
/// the iteration, and keeps the equilibrium found when every one of them pulls there; else it
/// solves in the displacement form from the same start. The displacement form alone measures a
/// stiff cable's misfit as `EA/L0` times its stretch, which a step along the arc of a
/// prestress-stabilized motion makes to second order: its iterations grew with EA (the prism from
/// a 0.02 disturbance: 3 at 1e2 N, 28 at 1e9 N). Empty where `stiff_cables` is not.
pub fn prestressed_stiff_cables(model: &Model, ws: &mut Workspace, size: f64) -> Vec<usize> {
    stiff_sets(model, ws, size).1
}

/// (`stiff_cables`, `prestressed_stiff_cables`).
fn stiff_sets(model: &Model, ws: &mut Workspace, size: f64) -> (Vec<usize>, Vec<usize>) {
    if model.cables.is_empty() {
        return (Vec::new(), Vec::new());
    }
    let weight = model.bodies.iter().map(|b| b.mass * model.gravity.norm()).fold(0.0, f64::max);
    let mixed_member = |c: &crate::model::CableModel| !c.tension_only && c.buckling_load == f64::INFINITY;
    let small = model.dof_count < SPARSE_STATICS_MIN;
    let members = small && model.cables.iter().any(mixed_member);
    let mut initial = State::initial(model);
    evaluate(model, &initial, ws, Tangents::None);
    fit_multipliers(model, &mut initial.multipliers, ws);
    let tension = ws.cables.iter().map(|c| c.tension.abs()).fold(0.0, f64::max);
    let mut residual = ws.force.clone_owned();
    if model.constraint_count > 0 {
        residual -= ws.constraint_jacobian.transpose() * &initial.multipliers;
    }
    let balanced = residual.amax() <= PRESTRESSED_START * tension.max(weight);
    let prestressed = weight == 0.0 || (tension > weight && balanced);
    // the tensions of a sketch out of equilibrium say nothing of the loads: the weights do
    let force = if balanced || weight == 0.0 { weight.max(tension) } else { weight };
    let length = ws.cables.iter().map(|c| c.length).fold(0.0, f64::max).max(size);
    let reference = force.max(1e-12) / length;
    let stiff = |c: usize| {
        let cable = &model.cables[c];
        // a cable with pulley friction has a tension per segment, not one unknown
        cable.friction.is_none()
            && cable.axial_stiffness / initial.rest_lengths[c] > STIFF_CABLE_RATIO * reference
    };
    let mixed: Vec<usize> = (0..model.cables.len())
        .filter(|&c| {
            let cable = &model.cables[c];
            let kind = if cable.tension_only { !prestressed } else { members && mixed_member(cable) };
            kind && stiff(c)
        })
        .collect();
    let bilateral = if prestressed && mixed.is_empty() && small {
        let very_stiff = |c: usize| {
            model.cables[c].axial_stiffness / initial.rest_lengths[c] > PRESTRESSED_STIFF_RATIO * reference
        };
        (0..model.cables.len())
            .filter(|&c| model.cables[c].tension_only && stiff(c) && very_stiff(c))
            .collect()
    } else {
        Vec::new()
    };
    (mixed, bilateral)
}

/// At an equilibrium found: the pulleys' return map (`crate::forces::pulley`) becomes the
/// state's segment rest lengths, so the next solve (a deployment's next load step) starts from
/// the material where this one left it.
fn commit_friction(model: &Model, state: &mut State, ws: &mut Workspace) {
    if !model.pulley_friction.is_empty() {
        crate::forces::pulley::commit(model, &mut ws.friction, &mut state.segment_rest_lengths, 0.0);
    }
}

/// A stiff cable's tension after a step `dt` from `t` (N): at least `TENSION_FLOOR` of `t`, so
/// that one step from a badly strained start (where the linearized balance asks for a tension
/// far below zero) cannot drop a prestress whole; a cable goes slack only when it is shorter than
/// its rest length (`equilibrate_mixed`'s active set).
fn next_tension(t: f64, dt: f64) -> f64 {
    (t + dt).max(TENSION_FLOOR * t).max(0.0)
}

/// The least fraction of its tension a stiff cable keeps over one Newton step (`next_tension`).
const TENSION_FLOOR: f64 = 0.1;

/// The stiff cables of a mixed iteration: their tensions as unknowns and what the current
/// iterate's evaluation found for them.
struct StiffCables {
    /// Model cable indices.
    ids: Vec<usize>,
    /// Tension unknowns `T`, N (0 while inactive).
    tension: Vec<f64>,
    /// Compliances `c = L0 / EA`, m/N.
    compliance: Vec<f64>,
    /// True for a member: its force takes either sign and it never goes slack (always active).
    push: Vec<bool>,
    /// True while a cable is taut in the iteration (its length equation is imposed).
    active: Vec<bool>,
    /// Lengths `L` at the last evaluation, m.
    length: Vec<f64>,
    /// Length gradients `g = dL/dq` at the last evaluation.
    gradient: Vec<DVector<f64>>,
}

impl StiffCables {
    /// The length equation's residual of stiff cable `i`, m: `L - L0 - c T` while active,
    /// else the stretch of a cable that carries no tension (`max(0, L - L0)`).
    fn length_residual(&self, i: usize, rest_length: f64) -> f64 {
        if self.active[i] {
            self.length[i] - rest_length - self.compliance[i] * self.tension[i]
        } else {
            (self.length[i] - rest_length).max(0.0)
        }
    }
    /// Element `i`'s force after a step `dt` from `t` (N): a cable's by `next_tension` (kept
    /// above a floor, never below zero), a member's `t + dt` of either sign.
    fn next_tension(&self, i: usize, t: f64, dt: f64) -> f64 {
        if self.push[i] {
            t + dt
        } else {
            next_tension(t, dt)
        }
    }
    fn active_ids(&self) -> Vec<usize> {
        (0..self.ids.len()).filter(|&i| self.active[i]).collect()
    }
}

/// What a mixed evaluation's residual measures (see `StaticSolver::mixed_residual`).
struct MixedResidual {
    /// `|Q - sum T g - Phi_q^T lambda|_inf`, N.
    force: f64,
    /// `|Phi|_inf`, m.
    constraint: f64,
    /// Largest length residual of the stiff cables, m.
    cable: f64,
}

impl MixedResidual {
    fn merit(&self, f_scale: f64, l_scale: f64) -> f64 {
        (self.force / f_scale).powi(2) + (self.constraint / l_scale).powi(2) + (self.cable / l_scale).powi(2)
    }
}

impl StaticSolver {
    /// Evaluates `work` (the state with the stiff cables made slack, `slack_rest_lengths`) and
    /// adds the stiff cables' forces `-T g` and, with `tangents`, their geometric stiffness
    /// `T sum_k G_k^T P_k G_k + T sum_i d(J_i^T n_i)/dq` (no material term: their stretch is
    /// the length equation's) for the tension unknowns of `stiff`; records their lengths and
    /// gradients.
    fn mixed_evaluate(
        model: &Model,
        work: &State,
        ws: &mut Workspace,
        stiff: &mut StiffCables,
        tangents: bool,
    ) {
        evaluate(model, work, ws, if tangents { Tangents::Stiffness } else { Tangents::None });
        let Workspace { points, scratch, stiffness, force, .. } = ws;
        for (i, &c) in stiff.ids.iter().enumerate() {
            let route = model.route(CableId(c));
            let (length, _) = crate::forces::cable::route_geometry(route, points, scratch);
            stiff.length[i] = length;
            stiff.gradient[i].fill(0.0);
            crate::forces::cable::add_length_gradient(
                model,
                route,
                points,
                scratch,
                1.0,
                &mut stiff.gradient[i],
            );
            let t = stiff.tension[i];
            if !stiff.active[i] || (t <= 0.0 && !stiff.push[i]) {
                continue;
            }
            force.axpy(-t, &stiff.gradient[i], 1.0);
            if tangents {
                let mut sink = DenseTangents { model, stiffness: &mut *stiffness, damping: None };
                crate::forces::cable::add_cable_tangents(
                    model,
                    &work.poses,
                    &work.velocities,
                    CableId(c),
                    route,
                    0.0,
                    0.0,
                    1.0,
                    t,
                    points,
                    scratch,
                    &mut sink,
                );
            }
        }
    }

    /// The residual of a mixed evaluation (`mixed_evaluate` just ran): force balance with the
    /// tension unknowns, joints, and the stiff cables' length equations (`rest` the true rest
    /// lengths). Fills `rhs` (`[r; -Phi; -h_active]`) when given.
    fn mixed_residual(
        model: &Model,
        state: &State,
        ws: &Workspace,
        stiff: &StiffCables,
        rest: &[f64],
        rhs: Option<&mut DVector<f64>>,
    ) -> MixedResidual {
        let n = model.dof_count;
        let nc = model.constraint_count;
        let mut r = ws.force.clone_owned();
        if nc > 0 {
            r -= ws.constraint_jacobian.transpose() * &state.multipliers;
        }
        let cable = (0..stiff.ids.len())
            .map(|i| stiff.length_residual(i, rest[stiff.ids[i]]).abs())
            .fold(0.0, f64::max);
        if let Some(rhs) = rhs {
            rhs.rows_mut(0, n).copy_from(&r);
            if nc > 0 {
                rhs.rows_mut(n, nc).copy_from(&(-&ws.constraint));
            }
            for (k, i) in stiff.active_ids().into_iter().enumerate() {
                rhs[n + nc + k] = -stiff.length_residual(i, rest[stiff.ids[i]]);
            }
        }
        MixedResidual { force: r.amax(), constraint: ws.constraint.amax(), cable }
    }

    /// `equilibrate` with the tensions of the stiff cables `ids` as unknowns (a mixed, or
    /// perturbed-Lagrangian, formulation): Newton on
    /// `[Q - sum_s T_s g_s - Phi_q^T lambda; Phi; L_s - L0_s - c_s T_s] = 0` (`c = L0/EA`) for
    /// every taut stiff cable `s`, whose matrix
    /// `[[K' + H_lambda, Phi_q^T, G], [Phi_q, 0, 0], [G^T, 0, -diag(c)]]` stays well conditioned
    /// as `c -> 0` (`K'` the tangent of the other cables and gravity plus the stiff cables'
    /// geometric stiffness at `T`, `G` their length gradients). Its residual measures a stiff
    /// cable's misfit as a length, where the displacement form measures `EA/L0` times it as a
    /// force: a step that swings a bar about its pin stretches a cable tied to it to second
    /// order, which the displacement form's line search sees as a force `EA/L0` times that
    /// stretch and refuses, so its iteration count grew with EA until the cap (1e6 N on a bar
    /// held over a pulley); here the tension follows the step linearly. A cable whose tension
    /// falls to zero while its length is below its rest length goes slack (its equation is
    /// dropped), and a slack one is taken up again as soon as it is stretched. Convergence is
    /// tested on the displacement form's residual, as in `equilibrate`.
    fn equilibrate_mixed(
        &mut self,
        model: &Model,
        state: &mut State,
        ws: &mut Workspace,
        settings: &SolverSettings,
        ids: Vec<usize>,
        bilateral: bool,
    ) -> Result<EquilibriumReport, (usize, f64)> {
        let n = model.dof_count;
        let nc = model.constraint_count;
        state.velocities.fill(0.0);
        let start_poses = state.poses.clone();
        let start_multipliers = state.multipliers.clone();
        let rest = state.rest_lengths.clone();
        let fresh = state.multipliers.iter().all(|l| *l == 0.0);
        // the work state: the stiff cables made slack, their forces added from the unknowns
        let mut work = state.clone();
        for &c in &ids {
            work.rest_lengths[c] = crate::forces::cable::DISENGAGED;
        }
        evaluate(model, state, ws, Tangents::None);
        let m = ids.len();
        let mut stiff = StiffCables {
            tension: ids.iter().map(|&c| ws.cables[c].tension).collect(),
            compliance: ids.iter().map(|&c| rest[c] / model.cables[c].axial_stiffness).collect(),
            push: ids.iter().map(|&c| bilateral || !model.cables[c].tension_only).collect(),
            active: ids
                .iter()
                .map(|&c| bilateral || ws.cables[c].tension > 0.0 || !model.cables[c].tension_only)
                .collect(),
            length: vec![0.0; m],
            gradient: vec![DVector::zeros(n); m],
            ids,
        };
        if fresh {
            work.poses.copy_from_slice(&state.poses);
            Self::mixed_evaluate(model, &work, ws, &mut stiff, false);
            least_squares_tensions(model, &mut work, ws, &mut stiff, &rest);
            state.multipliers.copy_from(&work.multipliers);
        }
        let mut best = f64::INFINITY;
        let mut iterations = 0;
        let mut check_convexity = true;
        let mut previous_merit = f64::INFINITY;
        loop {
            // converged in the displacement form, as `equilibrate` tests it
            let res = match self.start_iteration(model, state, ws, settings, iterations, &mut best) {
                Start::Go(res) => res,
                Start::Converged(report) => {
                    commit_friction(model, state, ws);
                    return Ok(report);
                }
                Start::Stop => break,
            };
            iterations += 1;

            // the active set: taut where the cable carries tension or is stretched
            work.poses.copy_from_slice(&state.poses);
            work.multipliers.copy_from(&state.multipliers);
            Self::mixed_evaluate(model, &work, ws, &mut stiff, false);
            for i in 0..m {
                // taut while it carries tension or is stretched (a member always)
                stiff.active[i] =
                    stiff.push[i] || stiff.tension[i] > 0.0 || stiff.length[i] > rest[stiff.ids[i]];
                if !stiff.active[i] {
                    stiff.tension[i] = 0.0;
                }
            }
            Self::mixed_evaluate(model, &work, ws, &mut stiff, true);
            let active = stiff.active_ids();
            let ma = active.len();
            let size = n + nc + ma;
            let mut rhs = DVector::zeros(size);
            let mres = Self::mixed_residual(model, &work, ws, &stiff, &rest, Some(&mut rhs));
            let f_scale = model
                .bodies
                .iter()
                .map(|b| b.mass * model.gravity.norm())
                .chain(ws.cables.iter().map(|c| c.tension.abs()))
                .chain(stiff.tension.iter().map(|t| t.abs()))
                .fold(1e-12, f64::max);
            let l_scale = res.length_scale;

            // [[K' + H, Phi_q^T, G], [Phi_q, 0, 0], [G^T, 0, -c]]
            let mut kkt = DMatrix::zeros(size, size);
            kkt.view_mut((0, 0), (n, n)).copy_from(&ws.stiffness);
            if nc > 0 {
                let mut h = DMatrix::zeros(n, n);
                add_multiplier_hessian(model, &work.poses, &work.multipliers, &mut h);
                let mut top = kkt.view_mut((0, 0), (n, n));
                top += &h;
                kkt.view_mut((0, n), (n, nc)).copy_from(&ws.constraint_jacobian.transpose());
                kkt.view_mut((n, 0), (nc, n)).copy_from(&ws.constraint_jacobian);
            }
            let mut jacobian = DMatrix::zeros(nc + ma, n);
            if nc > 0 {
                jacobian.view_mut((0, 0), (nc, n)).copy_from(&ws.constraint_jacobian);
            }
            for (k, &i) in active.iter().enumerate() {
                let g = &stiff.gradient[i];
                kkt.view_mut((0, n + nc + k), (n, 1)).copy_from(g);
                kkt.view_mut((n + nc + k, 0), (1, n)).copy_from(&g.transpose());
                kkt[(n + nc + k, n + nc + k)] = -stiff.compliance[i];
                jacobian.view_mut((nc + k, 0), (1, n)).copy_from(&g.transpose());
            }
            // saddle-free on the null space of the joints and the stiff cables' lengths
            let tangent = kkt.view((0, 0), (n, n)).into_owned();
            let residual_force = rhs.rows(0, n).into_owned();
            let merit_now = mres.merit(f_scale, l_scale);
            check_convexity |= merit_now > 0.25 * previous_merit;
            previous_merit = merit_now;
            let mut energy_mode = false;
            let checked = check_convexity;
            check_convexity = false;
            if checked {
                let scales = Residual { force_scale: f_scale, length_scale: l_scale, ..res };
                if let Some((correction, descent)) =
                    convexity_correction(model, &tangent, &jacobian, &self.mass, &scales, &residual_force)
                {
                    check_convexity = true;
                    let mut top = kkt.view_mut((0, 0), (n, n));
                    top += &correction;
                    energy_mode = descent;
                }
            }
            let Some(step) = solve_regularized(&kkt, &rhs, n) else {
                self.stop = StopReason::Singular;
                break;
            };
            self.dq.copy_from(&step.rows(0, n));
            let limit = self.step_limit(model, l_scale);
            let dlambda = step.rows(n, nc).into_owned();
            let mut dt = vec![0.0; m];
            for (k, &i) in active.iter().enumerate() {
                dt[i] = step[n + nc + k];
            }

            // line search, as in `equilibrate`, on the mixed residual or the energy
            let penalty = 10.0
                * ((&state.multipliers + &dlambda).amax()
                    + (0..m).map(|i| (stiff.tension[i] + dt[i]).abs()).fold(0.0, f64::max)
                    + f_scale);
            let energy_of = |ws: &Workspace, stiff: &StiffCables, cable: f64| {
                let stiff_energy: f64 = (0..m)
                    .filter(|&i| stiff.active[i])
                    .map(|i| 0.5 * stiff.compliance[i] * stiff.tension[i].powi(2))
                    .sum();
                ws.energies.elastic
                    + ws.energies.gravitational
                    + stiff_energy
                    + penalty * (ws.constraint.amax() + cable)
            };
            let energy0 = energy_of(ws, &stiff, mres.cable);
            let merit0 = merit_now;
            let base_multipliers = state.multipliers.clone();
            let base_tension = stiff.tension.clone();
            let mut alpha = limit;
            let mut best_trial = (f64::INFINITY, alpha);
            for _ in 0..12 {
                work.poses.copy_from_slice(&state.poses);
                retract(model, &mut work.poses, &self.dq, alpha);
                work.multipliers = &base_multipliers + &dlambda * alpha;
                for i in 0..m {
                    stiff.tension[i] = stiff.next_tension(i, base_tension[i], alpha * dt[i]);
                }
                if energy_mode {
                    Self::mixed_evaluate(model, &work, ws, &mut stiff, false);
                    project_onto_mixed(model, &mut work, ws, &mut stiff, &rest, l_scale);
                }
                Self::mixed_evaluate(model, &work, ws, &mut stiff, false);
                let trial_res = Self::mixed_residual(model, &work, ws, &stiff, &rest, None);
                let residual_merit = trial_res.merit(f_scale, l_scale);
                let trial_energy = energy_of(ws, &stiff, trial_res.cable);
                let trial = if energy_mode { trial_energy } else { residual_merit };
                if trial.is_finite() && trial < best_trial.0 {
                    best_trial = (trial, alpha);
                }
                let decreased = if energy_mode {
                    trial < energy0
                } else {
                    trial <= (1.0 - 1e-4 * alpha) * merit0 || trial_energy < energy0
                };
                if trial.is_finite() && decreased {
                    break;
                }
                alpha *= 0.5;
            }
            if !best_trial.0.is_finite() {
                stiff.tension.copy_from_slice(&base_tension);
                self.stop = StopReason::Diverged;
                break;
            }
            let alpha = best_trial.1;
            check_convexity |= alpha < limit.min(1.0);
            retract(model, &mut state.poses, &self.dq, alpha);
            state.multipliers = &base_multipliers + &dlambda * alpha;
            for i in 0..m {
                stiff.tension[i] = stiff.next_tension(i, base_tension[i], alpha * dt[i]);
            }
            if energy_mode {
                // a descent step moves the poses, not towards the reactions: take them afresh
                work.poses.copy_from_slice(&state.poses);
                work.multipliers.copy_from(&state.multipliers);
                Self::mixed_evaluate(model, &work, ws, &mut stiff, false);
                project_onto_mixed(model, &mut work, ws, &mut stiff, &rest, l_scale);
                fit_multipliers(model, &mut work.multipliers, ws);
                state.poses.copy_from_slice(&work.poses);
                state.multipliers.copy_from(&work.multipliers);
            }
        }
        state.poses.copy_from_slice(&start_poses);
        state.multipliers.copy_from(&start_multipliers);
        Err((iterations, best))
    }

    /// The largest fraction of the Newton step `self.dq` that moves no body by more than 0.5 rad
    /// or `STEP_CAP` length scales.
    fn step_limit(&self, model: &Model, length_scale: f64) -> f64 {
        let mut limit: f64 = 1.0;
        for b in &model.bodies {
            for c in 0..b.dof_count {
                let col = b.basis.column(c);
                let x = self.dq[b.dof_offset + c].abs();
                let cap = if col.fixed_rows::<3>(3).norm() > 0.0 { 0.5 } else { STEP_CAP * length_scale };
                if x > cap {
                    limit = limit.min(cap / x);
                }
            }
        }
        limit
    }
}

/// The joint reactions and stiff-cable tensions that best balance the other forces, the tensions
/// kept near their current values along any self-stress the forces do not decide:
/// `[lambda; T] = argmin |Q_other - Phi_q^T lambda - G T|^2 + eps |T - T_now|^2` over the joints
/// and the stiff cables that are stretched or just taut (`L >= L0`, `rest` the true rest
/// lengths), tensions clamped at zero, `eps` a 1e-8 part of the largest diagonal entry. `ws` and
/// `stiff` come from `mixed_evaluate` at `work` (`Q_other` is its force with the stiff cables'
/// tensions added back). A fresh start's tensions so balance the loads instead of following an
/// overstretched sketch (1e5 N for a 1 kg mass on a cable of EA 1e6 N drawn 10 % too long).
/// Left unchanged when the system is singular.
fn least_squares_tensions(
    model: &Model,
    work: &mut State,
    ws: &Workspace,
    stiff: &mut StiffCables,
    rest: &[f64],
) {
    let n = model.dof_count;
    let nc = model.constraint_count;
    let mut q = ws.force.clone_owned();
    for i in 0..stiff.ids.len() {
        if stiff.active[i] && (stiff.tension[i] > 0.0 || stiff.push[i]) {
            q.axpy(stiff.tension[i], &stiff.gradient[i], 1.0);
        }
    }
    let taut: Vec<usize> =
        (0..stiff.ids.len()).filter(|&i| stiff.push[i] || stiff.length[i] >= rest[stiff.ids[i]]).collect();
    let rows = nc + taut.len();
    if rows == 0 {
        return;
    }
    let mut j = DMatrix::zeros(rows, n);
    if nc > 0 {
        j.view_mut((0, 0), (nc, n)).copy_from(&ws.constraint_jacobian);
    }
    for (k, &i) in taut.iter().enumerate() {
        j.view_mut((nc + k, 0), (1, n)).copy_from(&stiff.gradient[i].transpose());
    }
    let mut normal = &j * j.transpose();
    let mut rhs = &j * &q;
    let eps = 1e-8 * (0..rows).map(|r| normal[(r, r)]).fold(0.0, f64::max);
    for (k, &i) in taut.iter().enumerate() {
        normal[(nc + k, nc + k)] += eps;
        rhs[nc + k] += eps * stiff.tension[i];
    }
    let Some(y) = normal.lu().solve(&rhs) else { return };
    if !y.iter().all(|x| x.is_finite()) {
        return;
    }
    if nc > 0 {
        work.multipliers.copy_from(&y.rows(0, nc));
    }
    for (k, &i) in taut.iter().enumerate() {
        stiff.tension[i] = if stiff.push[i] { y[nc + k] } else { y[nc + k].max(0.0) };
        stiff.active[i] = true;
    }
}

/// Moves `work`'s poses onto `Phi = 0` and the active stiff cables' `L = L0 + c T` (tensions
/// held) by Gauss-Newton steps of the smallest correction, like `project_onto_joints`; leaves
/// `ws` and `stiff` evaluated at the result (no tangents).
fn project_onto_mixed(
    model: &Model,
    work: &mut State,
    ws: &mut Workspace,
    stiff: &mut StiffCables,
    rest: &[f64],
    length_scale: f64,
) {
    let n = model.dof_count;
    let nc = model.constraint_count;
    for _ in 0..8 {
        StaticSolver::mixed_evaluate(model, work, ws, stiff, false);
        let active = stiff.active_ids();
        let rows = nc + active.len();
        if rows == 0 {
            return;
        }
        let mut j = DMatrix::zeros(rows, n);
        let mut phi = DVector::zeros(rows);
        if nc > 0 {
            j.view_mut((0, 0), (nc, n)).copy_from(&ws.constraint_jacobian);
            phi.rows_mut(0, nc).copy_from(&ws.constraint);
        }
        for (k, &i) in active.iter().enumerate() {
            j.view_mut((nc + k, 0), (1, n)).copy_from(&stiff.gradient[i].transpose());
            phi[nc + k] = stiff.length_residual(i, rest[stiff.ids[i]]);
        }
        if phi.amax() <= 1e-12 * length_scale {
            return;
        }
        let Some(y) = (&j * j.transpose()).lu().solve(&phi) else { return };
        let dq = -(j.transpose() * y);
        if !dq.iter().all(|x| x.is_finite()) {
            return;
        }
        retract(model, &mut work.poses, &dq, 1.0);
    }
    StaticSolver::mixed_evaluate(model, work, ws, stiff, false);
}

/// The joint reactions that best balance the current forces: `lambda = argmin |Q - Phi_q^T lambda|`,
/// i.e. `(Phi_q Phi_q^T) lambda = Phi_q Q`. Exact at an equilibrium; elsewhere it gives the joints'
/// geometric stiffness `H_lambda` its right sign and size from the first iteration on (a hanging
/// pendulum started with `lambda = 0` has no stiffness at all). Left unchanged when `Phi_q` is
/// rank deficient.
fn least_squares_multipliers(model: &Model, state: &mut State, ws: &mut Workspace) {
    if model.constraint_count == 0 {
        return;
    }
    evaluate(model, state, ws, Tangents::None);
    fit_multipliers(model, &mut state.multipliers, ws);
}

/// `least_squares_multipliers` on the sparse `kkt`: the reactions from the symmetric
/// quasi-definite system `[[I, Phi_q^T], [Phi_q, 0]] [x; lambda] = [Q; 0]`, whose solution has
/// `Phi_q Phi_q^T lambda = Phi_q Q` (its exact sparse `LDL^T`, no dense `nc x nc` matrix).
fn sparse_least_squares_multipliers(
    kkt: &mut KktSystem,
    model: &Model,
    state: &mut State,
    ws: &mut Workspace,
) {
    let (n, nc) = (model.dof_count, model.constraint_count);
    if nc == 0 {
        return;
    }
    evaluate_forces(model, state, ws);
    kkt.clear();
    kkt.add_to_coordinate_diagonal(1.0);
    kkt.add_joints(model, &state.poses, &ws.points);
    let mut x = DVector::zeros(kkt.size());
    x.rows_mut(0, n).copy_from(&ws.force);
    if kkt.factor_symmetric() && kkt.solve_factored(&mut x) {
        state.multipliers.copy_from(&x.rows(n, nc));
    }
}

/// `multipliers = argmin |Q - Phi_q^T lambda|` for the force `Q` and joint Jacobian evaluated
/// into `ws` (the displacement form's, or a mixed evaluation's with the stiff cables' tensions
/// held: those are not fitted, since a prestressed structure's self-stress is not decided by its
/// loads and a fit would drop it). Left unchanged without joints or when `Phi_q` is rank
/// deficient.
fn fit_multipliers(model: &Model, multipliers: &mut DVector<f64>, ws: &Workspace) {
    if model.constraint_count == 0 {
        return;
    }
    let j = &ws.constraint_jacobian;
    if let Some(lambda) = (j * j.transpose()).lu().solve(&(j * &ws.force)) {
        if lambda.iter().all(|x| x.is_finite()) {
            *multipliers = lambda;
        }
    }
}

/// Moves the poses back onto the joints' manifold `Phi(q) = 0` by Gauss-Newton steps
/// `dq = -Phi_q^T (Phi_q Phi_q^T)^-1 Phi` (the smallest correction), until `|Phi|_inf` is below
/// `1e-12 length_scale` or after 8 steps. Leaves the workspace evaluated (no tangents).
fn project_onto_joints(model: &Model, state: &mut State, ws: &mut Workspace, length_scale: f64) {
    if model.constraint_count == 0 {
        return;
    }
    for _ in 0..8 {
        evaluate(model, state, ws, Tangents::None);
        if ws.constraint.amax() <= 1e-12 * length_scale {
            return;
        }
        let j = &ws.constraint_jacobian;
        let Some(y) = (j * j.transpose()).lu().solve(&ws.constraint) else { return };
        let dq = -(j.transpose() * y);
        if !dq.iter().all(|x| x.is_finite()) {
            return;
        }
        retract(model, &mut state.poses, &dq, 1.0);
    }
    evaluate(model, state, ws, Tangents::None);
}

/// Largest translation of a body per Newton iteration, as a fraction of the length scale.
pub const STEP_CAP: f64 = 1.0;

/// Largest system (coordinates) for which the reduced tangent's definiteness is checked each
/// iteration (a dense eigenproblem); larger systems take plain Newton steps.
pub const MAX_CONVEXITY_CHECK: usize = 600;

/// Smallest system (coordinates) that `StaticSolver` solves on the sparse KKT system: its
/// stability test by shifted sparse factorizations (`sparse_stability`) instead of a dense
/// eigenproblem, and, without stiff cables, plain Newton steps (no convexity check) by a
/// sparse LU instead of a dense one. `tensegrity bench scaling` put the dynamics' crossover
/// between 100 and 200 unknowns; the dense statics path's eigenproblems cost more per unknown.
pub const SPARSE_STATICS_MIN: usize = 200;

/// A positive-definite modification of the tangent on the null space of `jacobian` (the joints'
/// `Phi_q`, with the stiff cables' length gradients in the mixed iteration: "saddle-free"
/// Newton). With `Z` spanning the null space of `jacobian`, `Z^T M Z = L L^T` and the mass-normalized
/// reduced tangent `S = L^-1 Z^T A Z L^-T = V diag(e) V^T` (`A` the symmetric part of `tangent`),
/// each eigenvalue at or below `1e-8 max|e|` (negative: heading for a maximum or saddle; zero: a
/// neutral or slack direction) becomes `max(|e|, delta)`, `delta = max(1e-2 max|e|, 1e-3 (|g| +
/// F_scale / m_max) / L_scale)` (1/s^2); the others are kept, so Newton stays quadratic where the
/// tangent is fine. Returns the correction `M Z L^-T V diag(e' - e) V^T L^-1 Z^T M` to add to the
/// tangent, and whether the residual has a significant part along the modified directions (then
/// the step is a descent step of the energy, and the line search measures the energy). `None`
/// when nothing needs modifying or the system is too large to check.
fn convexity_correction(
    model: &Model,
    tangent: &DMatrix<f64>,
    jacobian: &DMatrix<f64>,
    mass: &DMatrix<f64>,
    res: &Residual,
    residual: &DVector<f64>,
) -> Option<(DMatrix<f64>, bool)> {
    let n = model.dof_count;
    if n == 0 || n > MAX_CONVEXITY_CHECK {
        return None;
    }
    let z = crate::constraints::null_space(jacobian, n)?;
    let a = (tangent + tangent.transpose()) * 0.5;
    let chol = (z.transpose() * mass * &z).cholesky()?;
    let l_inv = chol.l().try_inverse()?;
    let s = &l_inv * (z.transpose() * a * &z) * l_inv.transpose();
    let eig = SymmetricEigen::new((&s + s.transpose()) * 0.5);
    let e_max = eig.eigenvalues.amax();
    let m_max = model.bodies.iter().map(|b| b.mass).fold(0.0, f64::max).max(1e-300);
    let floor = (model.gravity.norm() + res.force_scale / m_max) / res.length_scale;
    let delta = (1e-2 * e_max).max(1e-3 * floor);
    let modified: Vec<usize> =
        (0..eig.eigenvalues.len()).filter(|&i| eig.eigenvalues[i] <= 1e-8 * e_max).collect();
    if modified.is_empty() {
        return None;
    }
    // residual in the mass-normalized eigenbasis
    let c = eig.eigenvectors.transpose() * (&l_inv * (z.transpose() * residual));
    let along: f64 = modified.iter().map(|&i| c[i] * c[i]).sum();
    let descent = along > 1e-12 * c.norm_squared().max(1e-300) && along.sqrt() > 1e-14 * res.force_scale;
    let mut d = DVector::zeros(eig.eigenvalues.len());
    for &i in &modified {
        let e = eig.eigenvalues[i];
        d[i] = e.abs().max(delta) - e;
    }
    let v = &eig.eigenvectors;
    let ds = v * DMatrix::from_diagonal(&d) * v.transpose();
    let b = mass * &z * l_inv.transpose();
    Some((&b * ds * b.transpose(), descent))
}

/// Assembles the statics KKT matrix `[[K + H_lambda, Phi_q^T], [Phi_q, 0]]` into the sparse
/// `kkt` at `state` (clustered cables bordered, `crate::solve::linear`), from the point
/// kinematics, cable and contact responses last evaluated into `ws` (no dense tangent needed).
fn assemble_sparse(kkt: &mut KktSystem, model: &Model, state: &State, ws: &mut Workspace) {
    kkt.clear();
    kkt.add_joints(model, &state.poses, &ws.points);
    let mut sink = kkt.tangents(1.0, 0.0);
    add_workspace_tangents(model, state, ws, &mut sink);
    if model.constraint_count > 0 {
        add_multiplier_hessian_to(model, &state.poses, &state.multipliers, 1.0, &mut sink);
    }
}

/// `solve_regularized` on the sparse `kkt` (assembled by `assemble_sparse`): its exact sparse LU,
/// with the Levenberg term `mu I` on the coordinates grown from `1e-14` of the Gershgorin bound
/// (`KktSystem::coordinate_bound`) while the factorization fails or the solution is not finite
/// or misses the equations by more than `1e-6` of the right-hand side.
/// `rhs` has the `n + nc` rows of the unknowns `[dq; dlambda]`; so has the answer.
fn solve_sparse(kkt: &mut KktSystem, rhs: &DVector<f64>) -> Option<DVector<f64>> {
    let rows = rhs.len();
    let scale = kkt.coordinate_bound()?.max(1e-12);
    let mut mu = 1e-14 * scale;
    let mut added = 0.0;
    let (mut x, mut b, mut check) =
        (DVector::zeros(kkt.size()), DVector::zeros(kkt.size()), DVector::zeros(kkt.size()));
    for _ in 0..8 {
        kkt.add_to_coordinate_diagonal(mu - added);
        added = mu;
        b.fill(0.0);
        b.rows_mut(0, rows).copy_from(rhs);
        x.copy_from(&b);
        if kkt.factor() && kkt.solve_factored(&mut x) {
            kkt.multiply(&x, &mut check);
            if (&check - &b).amax() <= 1e-6 * b.amax().max(1e-300) {
                return Some(x.rows(0, rows).into_owned());
            }
        }
        mu *= 1000.0;
    }
    None
}

/// `dense_stability` without forming the null space or any dense matrix: the inertia of
/// the sparse statics KKT matrix shifted by `sigma` (`KktSystem::symmetric_inertia`) counts the
/// reduced tangent's eigenvalues below `sigma`. With `B` the Gershgorin bound of the tangent
/// (`KktSystem::coordinate_bound`, which bounds every reduced eigenvalue) and `tol = 1e-9 B`
/// (the dense test's `1e-9` of the largest eigenvalue, with the bound in its place): negative
/// modes are those below `-tol`, zero modes those in `[-tol, tol]`. The smallest eigenvalue is
/// bracketed by bisection on the counts (geometric where the bracket has one sign) to 1e-3 and
/// then found by inverse iteration from the bracket's lower end (to 1e-12). Rigid-body modes are
/// counted on the 6 x 6 (at most) tangent over `rigid_body_motions`. Every factorization is a
/// sparse `LDL^T` of the same pattern, so the cost grows with the structure. Falls back to the
/// dense test when a shift hits a zero pivot.
fn sparse_stability(kkt: &mut KktSystem, model: &Model, state: &State, ws: &mut Workspace) -> Modes {
    let n = model.dof_count;
    if n == 0 {
        return Modes { min_eigenvalue: 0.0, negative: 0, zero: 0, rigid: 0 };
    }
    assemble_sparse(kkt, model, state, ws);
    let offset = model.constraint_count + kkt.bordered_cables();
    let bound = kkt.coordinate_bound().unwrap_or(0.0).max(1e-300);
    let tol = 1e-9 * bound;
    // eigenvalues of the reduced tangent below `shift`; a shift on an eigenvalue of a leading
    // block (a zero pivot) is moved by a part in 1e6 of the bracket scale
    let below = |kkt: &mut KktSystem, shift: f64| -> Option<usize> {
        for k in 0..4 {
            let nudged = shift + k as f64 * 1e-6 * tol;
            if let Some(i) = kkt.symmetric_inertia(nudged) {
                return Some(i.negative.saturating_sub(offset));
            }
        }
        None
    };
    let counts = below(kkt, -tol).zip(below(kkt, tol)).zip(below(kkt, 2.0 * bound + tol));
    let Some(((negative, not_positive), reduced)) = counts else {
        return dense_stability_fallback(model, state, ws);
    };
    let zero = not_positive - negative;
    if reduced == 0 {
        // every coordinate is held by a joint
        return Modes { min_eigenvalue: f64::INFINITY, negative: 0, zero: 0, rigid: 0 };
    }
    // bracket the smallest eigenvalue: nothing below `lo`, something below `hi`
    let (mut lo, mut hi) = if negative > 0 {
        (-2.0 * bound - tol, -tol)
    } else if zero > 0 {
        (-tol, tol)
    } else {
        (tol, 2.0 * bound + tol)
    };
    for _ in 0..80 {
        if hi - lo <= 1e-3 * lo.abs().max(hi.abs()) {
            break;
        }
        let mid = if lo > 0.0 {
            (lo * hi).sqrt()
        } else if hi < 0.0 {
            -(lo * hi).sqrt()
        } else {
            0.5 * (lo + hi)
        };
        match below(kkt, mid) {
            Some(0) => lo = mid,
            Some(_) => hi = mid,
            None => break,
        }
    }
    // inverse iteration with the shift `lo`, below every eigenvalue: converges to the smallest
    let mut min_eigenvalue = 0.5 * (lo + hi);
    if kkt.symmetric_inertia(lo).is_some() {
        let mut x = DVector::zeros(kkt.size());
        let mut v: DVector<f64> = DVector::from_iterator(
            n,
            (0..n).map(|i| 1.0 + 0.5 * ((i as f64 * 0.618_033_988_7).fract() - 0.5)),
        );
        v /= v.norm();
        for _ in 0..30 {
            x.fill(0.0);
            x.rows_mut(0, n).copy_from(&v);
            if !kkt.solve_factored(&mut x) {
                break;
            }
            let y = x.rows(0, n).into_owned();
            let (theta, norm) = (v.dot(&y), y.norm());
            if !(norm > 0.0 && theta.is_finite()) {
                break;
            }
            let estimate = lo + 1.0 / theta;
            let settled = (estimate - min_eigenvalue).abs() <= 1e-12 * estimate.abs().max(tol);
            min_eigenvalue = estimate;
            v = y / norm;
            if settled {
                break;
            }
        }
        min_eigenvalue = min_eigenvalue.clamp(lo, hi);
    }
    // the free rigid motions, orthonormalized, and how many of them cost no energy
    let motions = rigid_body_motions(model, state, ws);
    let rigid = if motions.ncols() == 0 {
        0
    } else {
        let q = motions.qr().q();
        let g = q.ncols();
        let mut on_rigid = DMatrix::zeros(g, g);
        for i in 0..g {
            for j in 0..=i {
                let (a, b) = (q.column(i), q.column(j));
                let v = kkt.coordinate_form(a.as_slice(), b.as_slice()).unwrap_or(0.0);
                on_rigid[(i, j)] = v;
                on_rigid[(j, i)] = v;
            }
        }
        SymmetricEigen::new(on_rigid).eigenvalues.iter().filter(|e| e.abs() <= tol).count()
    };
    Modes { min_eigenvalue, negative, zero, rigid }
}

/// The dense stability test for a sparse solver whose shifted factorizations failed: evaluates
/// the dense tangent at `state` first.
fn dense_stability_fallback(model: &Model, state: &State, ws: &mut Workspace) -> Modes {
    evaluate(model, state, ws, Tangents::Stiffness);
    dense_stability(model, state, ws, &[])
}

/// Solves the KKT system with a Levenberg term `mu I` on the coordinate block, starting from
/// `mu = 1e-14 max|K_ii|` (negligible for a regular system, but it turns an exactly neutral
/// direction, such as an equal-mass Atwood machine's sliding mode, into a zero step instead of a
/// round-off one) and growing it while the LU fails or gives non-finite values.
fn solve_regularized(kkt: &DMatrix<f64>, rhs: &DVector<f64>, n: usize) -> Option<DVector<f64>> {
    let diag = (0..n).map(|i| kkt[(i, i)].abs()).fold(0.0, f64::max).max(1e-12);
    let mut mu = 1e-14 * diag;
    for _ in 0..8 {
        let mut a = kkt.clone();
        for i in 0..n {
            a[(i, i)] += mu;
        }
        if let Some(x) = a.clone().lu().solve(rhs) {
            if x.iter().all(|v| v.is_finite()) && (&a * &x - rhs).amax() <= 1e-6 * rhs.amax().max(1e-300) {
                return Some(x);
            }
        }
        mu *= 1000.0;
    }
    None
}
