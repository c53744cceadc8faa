//! Quasi-static deployment: takes a model with a deployment schedule and a state at its start,
//! gives the path of equilibria along the schedule (`QuasiStaticPath`) by load stepping (a
//! path-tangent predictor and a Newton corrector, `crate::solve::statics`, with step cutting),
//! continued past limit points by pseudo-arc-length continuation (`crate::solve::continuation`)
//! with the snap-throughs reported.

use nalgebra::DVector;

use crate::error::SolveError;
use crate::evaluate::{evaluate, Tangents, Workspace};
use crate::model::{Model, Pose};
use crate::solve::statics::{residual_of, EquilibriumReport, StaticSolver};
use crate::state::{retract, State};

/// What a row of the quasi-static path is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PathKind {
    /// The equilibrium at an output step's schedule time, reached by load stepping.
    Load,
    /// A point traced by arc-length continuation on the way to an output step (its time is
    /// wherever the path passes; between two limit points the path runs back in time and the
    /// equilibrium is unstable).
    ArcLength,
    /// The equilibrium at an output step's time reached after a snap-through (`SnapThrough`).
    SnapThrough,
}

impl PathKind {
    /// Lower-case name for tables: `load`, `arc`, `snap`.
    pub fn as_str(self) -> &'static str {
        match self {
            PathKind::Load => "load",
            PathKind::ArcLength => "arc",
            PathKind::SnapThrough => "snap",
        }
    }
}

/// One row of a quasi-static deployment path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathStep {
    /// Index of the output step (0 = initial equilibrium) this row reaches or is on the way to.
    pub index: usize,
    /// Schedule time, s (the actuation parameter).
    pub time: f64,
    /// The equilibrium solve that ended at this row.
    pub report: EquilibriumReport,
    /// Number of times a load step was halved on the way to this row.
    pub cuts: usize,
    /// How the row was reached.
    pub kind: PathKind,
    /// False once the path's stick-slip contacts could not be held from load step to load step
    /// (`StaticSolver::equilibrate_holding` found no equilibrium with them sticking and
    /// slipping, even in the smallest load step; `StaticSolver::release_contacts`):
    /// from then on each equilibrium is solved as a structure set down, its contacts stuck
    /// where the normal springs alone put it, so the path slides where held feet would stick.
    /// True without stick-slip grounds.
    pub contacts_held: bool,
}

/// A snap-through on the path: past a limit point (the largest load the branch carries, where
/// its stiffness loses definiteness) no equilibrium is near, and the structure jumps to another
/// stable equilibrium at the same load.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SnapThrough {
    /// Schedule time of the limit point, s: the largest time the branch reaches before the
    /// path turns back.
    pub limit_time: f64,
    /// Row (in `QuasiStaticPath::steps`) of the last load step before the limit point.
    pub from_row: usize,
    /// Row of the equilibrium the structure lands on.
    pub landing_row: usize,
    /// Largest displacement of any point between those two equilibria, m.
    pub jump: f64,
    /// Points the arc-length continuation traced between them.
    pub traced_points: usize,
    /// True when the traced path itself came back to the landing's time on a stable branch;
    /// false when it did not (a branch that ends, e.g. where a cable goes slack) and the landing
    /// was found by descending the energy from the limit point.
    pub followed_path: bool,
}

/// A quasi-static deployment path: every row in the order it was found, and the snap-throughs.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct QuasiStaticPath {
    /// Rows: the initial equilibrium, every output step (`Load` or `SnapThrough`) and the
    /// arc-length points between them.
    pub steps: Vec<PathStep>,
    /// Snap-throughs, in path order.
    pub snaps: Vec<SnapThrough>,
}

impl QuasiStaticPath {
    /// The rows at output steps (initial equilibrium, then one per load step), without the
    /// arc-length points between them.
    pub fn output_steps(&self) -> impl Iterator<Item = &PathStep> {
        self.steps.iter().filter(|s| s.kind != PathKind::ArcLength)
    }
}

/// Largest distance any attachment point moves between two sets of poses, m.
pub fn largest_point_distance(model: &Model, a: &[Pose], b: &[Pose]) -> f64 {
    model
        .points
        .iter()
        .map(|p| {
            let (pa, pb) = (&a[p.body.0], &b[p.body.0]);
            (pa.transform_point(&p.local) - pb.transform_point(&p.local)).norm()
        })
        .fold(0.0, f64::max)
}

/// A predicted first-order step may move points by at most this fraction of the length scale.
pub const PREDICTOR_CAP: f64 = 0.05;
/// A load step whose Newton correction moves a point farther than its prediction did, and
/// farther than this fraction of the length scale, jumped to another branch.
pub const JUMP_FRACTION: f64 = 0.01;
/// Halvings of a failing load step before continuation takes over.
pub const CUTS_BEFORE_CONTINUATION: usize = 2;

/// Follows the deployment schedule: `model.schedule.steps` output steps over its duration, each
/// reached from the previous equilibrium by load stepping with a first-order predictor (the
/// path tangent `StaticSolver::path_tangent`, capped at `PREDICTOR_CAP` of the length scale)
/// and the Newton corrector of `StaticSolver::equilibrate_holding` (stick-slip contacts held
/// from step to step). A step that fails is halved (up to `settings.max_step_cuts` times); where
/// contacts are held and even the smallest step fails, the path gives up holding them
/// (`StaticSolver::release_contacts`) and the step is tried again from its full size. Past a limit point load stepping either fails or lands on
/// another branch (a correction larger than its prediction and than `JUMP_FRACTION` of the
/// length scale); then pseudo-arc-length continuation
/// (`crate::solve::continuation`) traces the path through the limit point and back to the step's
/// time on a stable branch, and the jump is reported as a `SnapThrough`; where the traced branch
/// does not come back, the landing is found by descending the energy from the limit point.
/// Calls `on_step` at every row (initial equilibrium, arc-length points, output steps) with the
/// state and the evaluated workspace.
pub fn deploy_quasi_static(
    model: &Model,
    state: &mut State,
    ws: &mut Workspace,
    mut on_step: impl FnMut(&PathStep, &State, &Workspace),
) -> Result<QuasiStaticPath, SolveError> {
    let settings = model.solver;
    let n = model.dof_count;
    let nc = model.constraint_count;
    let mut solver = StaticSolver::new(model);
    let mut path = QuasiStaticPath::default();
    let fail = |time, load_step, (iterations, residual): (usize, f64), cuts, solver: &StaticSolver| {
        SolveError::NoEquilibrium {
            time,
            load_step,
            residual,
            iterations,
            cuts,
            slipping: solver.slipping_contact_labels(model),
        }
    };
    model.scheduled_rest_lengths(state.time, &mut state.rest_lengths);
    let report =
        solver.equilibrate(model, state, ws, &settings).map_err(|e| fail(state.time, 0, e, 0, &solver))?;
    evaluate(model, state, ws, Tangents::None);
    let first =
        PathStep { index: 0, time: state.time, report, cuts: 0, kind: PathKind::Load, contacts_held: true };
    on_step(&first, state, ws);
    path.steps.push(first);

    let t0 = state.time;
    let t_end = model.schedule.end_time().max(t0);
    let steps = model.schedule.steps.max(1);
    let load_step = (t_end - t0) / steps as f64;
    let mut rhs = DVector::zeros(n + nc);
    let mut tangent = solver.path_tangent(model, state, ws);
    let holds_contacts = !state.contact_anchors.is_empty();
    for s in 1..=steps {
        let target = t0 + (t_end - t0) * s as f64 / steps as f64;
        let mut h = target - state.time;
        let mut cuts = 0;
        let mut failures = 0;
        let mut tried_continuation = false;
        let mut last_error = (0, f64::NAN);
        let (report, kind) = loop {
            let t_try = (state.time + h).min(target);
            let dt = t_try - state.time;
            evaluate(model, state, ws, Tangents::None);
            let length_scale = residual_of(model, state, ws, &mut rhs, solver.size()).length_scale;
            // first-order predictor along the path tangent, capped
            let mut trial = state.clone();
            model.scheduled_rest_lengths(t_try, &mut trial.rest_lengths);
            let mut predicted_move = 0.0;
            if let Some(z) = tangent.as_ref().filter(|z| z.iter().all(|v| v.is_finite())) {
                let dq = z.rows(0, n) * dt;
                retract(model, &mut trial.poses, &dq, 1.0);
                let moved = largest_point_distance(model, &state.poses, &trial.poses);
                let scale = if moved > PREDICTOR_CAP * length_scale {
                    PREDICTOR_CAP * length_scale / moved
                } else {
                    1.0
                };
                if scale < 1.0 {
                    trial.poses.copy_from_slice(&state.poses);
                    retract(model, &mut trial.poses, &dq, scale);
                }
                trial.multipliers += z.rows(n, nc) * (dt * scale);
                predicted_move = moved * scale;
            }
            let predicted = trial.poses.clone();
            let jumped = match solver.equilibrate_holding(model, &mut trial, ws, &settings) {
                Ok(r) => {
                    let correction = largest_point_distance(model, &predicted, &trial.poses);
                    if correction <= predicted_move.max(JUMP_FRACTION * length_scale) {
                        trial.time = t_try;
                        *state = trial;
                        tangent = solver.path_tangent(model, state, ws);
                        if t_try >= target {
                            break (r, PathKind::Load);
                        }
                        continue;
                    }
                    true
                }
                Err(e) => {
                    last_error = e;
                    false
                }
            };
            if !jumped {
                failures += 1;
            }
            if !tried_continuation && (jumped || failures > CUTS_BEFORE_CONTINUATION) {
                tried_continuation = true;
                let before = state.clone();
                let from_row = path.steps.len() - 1;
                let mut traced = 0;
                let held = !solver.holding_failed;
                let outcome = crate::solve::continuation::continue_past_limit_points(
                    model,
                    &mut solver,
                    state,
                    ws,
                    target,
                    load_step,
                    (t0, t_end),
                    |point, st, w| {
                        let row = PathStep {
                            index: s,
                            time: point.time,
                            report: point.report,
                            cuts,
                            kind: PathKind::ArcLength,
                            contacts_held: held,
                        };
                        on_step(&row, st, w);
                        path.steps.push(row);
                        traced += 1;
                    },
                );
                use crate::solve::continuation::ArcOutcome;
                let landed = match outcome {
                    ArcOutcome::Landed { report, limit_time, .. } => Some((report, limit_time, true)),
                    ArcOutcome::NoReturn { limit: Some((limit_time, at_limit)), .. } => {
                        // the branch ends: descend the energy from the limit point at the target
                        let mut trial = at_limit;
                        trial.multipliers.fill(0.0);
                        model.scheduled_rest_lengths(target, &mut trial.rest_lengths);
                        match solver.equilibrate_holding(model, &mut trial, ws, &settings) {
                            Ok(r) if r.stable || r.negative_modes == 0 => {
                                *state = trial;
                                Some((r, Some(limit_time), false))
                            }
                            _ => None,
                        }
                    }
                    ArcOutcome::NoReturn { limit: None, .. } => None,
                };
                if let Some((report, limit_time, followed_path)) = landed {
                    state.time = target;
                    tangent = solver.path_tangent(model, state, ws);
                    match limit_time {
                        Some(limit_time) => {
                            path.snaps.push(SnapThrough {
                                limit_time,
                                from_row,
                                landing_row: path.steps.len(),
                                jump: largest_point_distance(model, &before.poses, &state.poses),
                                traced_points: traced,
                                followed_path,
                            });
                            break (report, PathKind::SnapThrough);
                        }
                        None => break (report, PathKind::Load),
                    }
                }
            }
            cuts += 1;
            if cuts > settings.max_step_cuts && holds_contacts && solver.contacts_held() {
                // no held equilibrium even in the smallest load step: the rest of the path is
                // solved as structures set down, this step again from its full size
                solver.release_contacts();
                (h, cuts, failures, tried_continuation) = (target - state.time, 0, 0, false);
                continue;
            }
            if cuts > settings.max_step_cuts {
                return Err(fail(t_try, s, last_error, cuts - 1, &solver));
            }
            h *= 0.5;
        };
        evaluate(model, state, ws, Tangents::None);
        let row = PathStep {
            index: s,
            time: state.time,
            report,
            cuts,
            kind,
            contacts_held: !solver.holding_failed,
        };
        on_step(&row, state, ws);
        path.steps.push(row);
        let total = Some(steps as u64);
        crate::progress::report(crate::progress::Report {
            unit: "load steps",
            done: s as u64,
            total,
            residual_n: None,
        });
    }
    Ok(path)
}
