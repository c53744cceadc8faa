//! Continuation of the quasi-static path past limit points: takes a model, an equilibrium on the
//! deployment path and a schedule time that load stepping could not reach from it; gives the
//! points of the path traced by pseudo-arc-length continuation (Keller 1977) through the limit
//! point and along the unstable branch, and the equilibrium where the path comes back to that
//! time on a stable branch: where the structure lands after snapping through.
//!
//! Unknowns `x = (q, lambda, t)`: the configuration (local increments in the chart of the last
//! accepted point, `crate::state::retract`), the joint reactions and the schedule time (the
//! actuation parameter; rest lengths follow the schedule). Equations: the equilibrium
//! `r(q, lambda, t) = [Q - Phi_q^T lambda; -Phi] = 0` of `crate::solve::statics`, and the
//! pseudo-arc-length condition `tau^T W (x - x_k) = ds` with the unit tangent `tau` at the last
//! point `x_k` in the weighted norm `W`: a translation counts per `ARC_LENGTH_FRACTION` of the
//! structure's length scale, a rotation per `ARC_ROTATION` rad, time per load step (so one unit
//! of arc length is about one load step, or a twentieth of the structure's size); reactions are
//! not weighted. Newton's matrix is bordered,
//!
//! ```text
//! [ A          -r_t      M R ] [dq; dlambda]   [ r  ]
//! [ tau_q^T W   tau_t w_t  0 ] [dt         ] = [ -a ]
//! [ (M R)^T      0         0 ] [mu         ]   [ 0  ]
//! ```
//!
//! with `A` the statics KKT matrix (`StaticSolver::assemble_kkt`), `r_t = dr/dt`
//! (`statics::load_rate`), `a` the arc condition's residual, and `R` the structure's free
//! rigid-body motions (`stability::rigid_body_motions`, none when anything holds it), whose
//! mass-weighted amplitude is held at zero. The bordered matrix stays regular at a simple limit
//! point, where `A` is singular; that is what lets the path turn. The tangent at a new point
//! solves the same matrix with right-hand side `(0, 1, 0)` and the previous tangent in the arc
//! row, so its orientation follows the path. A limit point is where the tangent's time
//! component changes sign from increasing to decreasing: the stiffness loses definiteness there.
//!
//! The arc step grows by 1.5 after a corrector that needed at most 3 iterations and halves after
//! one that failed; each point is an equilibrium by the same residual test as `equilibrate`. A
//! step that passes the first limit point is retaken in eighths until the two points around the
//! limit are at most `1e-3` apart; the limit's time is then the maximum of the cubic Hermite
//! interpolant of `t(s)` between them.

use nalgebra::{DMatrix, DVector};

use crate::evaluate::{evaluate, Tangents, Workspace};
use crate::model::Model;
use crate::solve::stability::rigid_body_motions;
use crate::solve::statics::{load_rate, residual_of, EquilibriumReport, StaticSolver};
use crate::state::{retract, State};

/// Largest number of points one continuation traces before it gives up.
pub const MAX_ARC_POINTS: usize = 2000;
/// A translation of this fraction of the structure's length scale counts as one unit of arc
/// length.
pub const ARC_LENGTH_FRACTION: f64 = 0.05;
/// A rotation of this many radians counts as one unit of arc length.
pub const ARC_ROTATION: f64 = 0.05;
const MAX_CORRECTOR_ITERATIONS: usize = 12;
const FIRST_ARC_STEP: f64 = 0.5;
const MAX_ARC_STEP: f64 = 2.0;
const MIN_ARC_STEP: f64 = 1e-7;
/// A limit point is located between two points at most this far apart (arc length).
const LIMIT_BRACKET: f64 = 1e-3;

/// A point of the path traced by arc length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArcPoint {
    /// Schedule time of the point, s.
    pub time: f64,
    /// The equilibrium there (residual, stability).
    pub report: EquilibriumReport,
    /// `dt/ds` of the unit tangent: positive while the path advances in time, negative on a
    /// branch that runs back (between two limit points).
    pub tangent_time: f64,
}

/// How a continuation ended.
#[derive(Debug, Clone)]
pub enum ArcOutcome {
    /// The path reached the target time on a stable branch; the state holds that equilibrium.
    Landed {
        /// The landing's equilibrium report.
        report: EquilibriumReport,
        /// Schedule time of the first limit point passed on the way (None: the path never
        /// turned back, there was no snap).
        limit_time: Option<f64>,
        /// Points traced (not counting the landing).
        points: usize,
    },
    /// The path did not come back to the target time on a stable branch (it left the schedule,
    /// or the continuation could not go on); the state is unchanged.
    NoReturn {
        /// The first limit point passed (time, equilibrium there), if any.
        limit: Option<(f64, State)>,
        /// Points traced.
        points: usize,
        /// Why it stopped.
        reason: &'static str,
    },
}

/// Buffers and scales of one continuation.
struct Tracer<'a> {
    model: &'a Model,
    solver: &'a mut StaticSolver,
    /// Weights of the coordinates in the arc-length norm (per unit of arc length).
    weights: DVector<f64>,
    /// Weight of time.
    time_weight: f64,
    rhs: DVector<f64>,
    rates: Vec<f64>,
    r_t: DVector<f64>,
}

impl Tracer<'_> {
    /// The weighted norm of a direction `(dq, dlambda, dt)`.
    fn norm(&self, x: &DVector<f64>) -> f64 {
        let n = self.model.dof_count;
        let nc = self.model.constraint_count;
        let mut sum = (x[n + nc] * self.time_weight).powi(2);
        for i in 0..n {
            sum += (x[i] * self.weights[i]).powi(2);
        }
        sum.sqrt()
    }

    /// The bordered matrix at `state` (evaluated into `ws` with its stiffness), with the arc row
    /// `tau^T W` and the rigid-motion rows `(M R)^T`.
    fn bordered(
        &mut self,
        state: &State,
        ws: &mut Workspace,
        tau: &DVector<f64>,
        rigid: &DMatrix<f64>,
    ) -> DMatrix<f64> {
        let model = self.model;
        let n = model.dof_count;
        let nc = model.constraint_count;
        let kr = rigid.ncols();
        let size = n + nc + 1 + kr;
        self.solver.assemble_kkt(model, state, ws);
        model.scheduled_rest_rates(state.time, &mut self.rates);
        load_rate(model, state, ws, &self.rates, &mut self.r_t);
        let mut b = DMatrix::zeros(size, size);
        b.view_mut((0, 0), (n + nc, n + nc)).copy_from(self.solver.kkt());
        for i in 0..n {
            b[(i, n + nc)] = -self.r_t[i];
            b[(n + nc, i)] = self.weights[i] * self.weights[i] * tau[i];
        }
        b[(n + nc, n + nc)] = self.time_weight * self.time_weight * tau[n + nc];
        if kr > 0 {
            let mr = self.solver.mass(model) * rigid;
            b.view_mut((0, n + nc + 1), (n, kr)).copy_from(&mr);
            b.view_mut((n + nc + 1, 0), (kr, n)).copy_from(&mr.transpose());
        }
        b
    }

    /// The unit tangent at the equilibrium `state` (evaluated into `ws` with its stiffness),
    /// oriented along `previous` (or towards increasing time at the first point).
    fn tangent(
        &mut self,
        state: &State,
        ws: &mut Workspace,
        previous: Option<&DVector<f64>>,
        rigid: &DMatrix<f64>,
    ) -> Option<DVector<f64>> {
        let n = self.model.dof_count;
        let nc = self.model.constraint_count;
        let mut start = DVector::zeros(n + nc + 1);
        start[n + nc] = 1.0;
        let orient = previous.unwrap_or(&start);
        let b = self.bordered(state, ws, orient, rigid);
        let mut rhs = DVector::zeros(b.nrows());
        rhs[n + nc] = 1.0;
        let x = b.lu().solve(&rhs)?;
        let tau = x.rows(0, n + nc + 1).into_owned();
        let norm = self.norm(&tau);
        (norm.is_finite() && norm > 0.0).then(|| tau / norm)
    }

    /// Newton's corrector from `base` along `tau` by arc length `ds`: the equilibrium, the
    /// increment from `base` it lies at, and the iterations it took.
    fn correct(
        &mut self,
        base: &State,
        ws: &mut Workspace,
        tau: &DVector<f64>,
        ds: f64,
        rigid: &DMatrix<f64>,
    ) -> Option<(State, DVector<f64>, usize)> {
        let model = self.model;
        let settings = model.solver;
        let n = model.dof_count;
        let nc = model.constraint_count;
        let mut x = tau * ds; // (dq from base, dlambda from base, dt from base)
        let mut trial = base.clone();
        for iteration in 0..=MAX_CORRECTOR_ITERATIONS {
            trial.poses.copy_from_slice(&base.poses);
            retract(model, &mut trial.poses, &x.rows(0, n).into_owned(), 1.0);
            trial.multipliers = &base.multipliers + x.rows(n, nc);
            trial.time = base.time + x[n + nc];
            model.scheduled_rest_lengths(trial.time, &mut trial.rest_lengths);
            if trial.rest_lengths.iter().any(|l| !(l.is_finite() && *l > 0.0)) {
                return None;
            }
            evaluate(model, &trial, ws, Tangents::Stiffness);
            let res = residual_of(model, &trial, ws, &mut self.rhs, self.solver.size());
            if !(res.force.is_finite() && res.constraint.is_finite()) {
                return None;
            }
            let mut arc = -ds;
            for i in 0..n {
                arc += self.weights[i] * self.weights[i] * tau[i] * x[i];
            }
            arc += self.time_weight * self.time_weight * tau[n + nc] * x[n + nc];
            if res.converged(&settings) && arc.abs() <= 0.25 * ds {
                return Some((trial, x, iteration));
            }
            if iteration == MAX_CORRECTOR_ITERATIONS {
                break;
            }
            let b = self.bordered(&trial, ws, tau, rigid);
            let mut rhs = DVector::zeros(b.nrows());
            rhs.rows_mut(0, n + nc).copy_from(&self.rhs);
            rhs[n + nc] = -arc;
            let dx = b.lu().solve(&rhs)?;
            if !dx.iter().all(|v| v.is_finite()) {
                return None;
            }
            // a Newton update larger than four arc steps is cut back to that
            let mut step = dx.rows(0, n + nc + 1).into_owned();
            let size = self.norm(&step);
            let cap = 4.0 * ds.max(FIRST_ARC_STEP);
            if size > cap {
                step *= cap / size;
            }
            x += step;
        }
        None
    }
}

/// The largest time on the path between two points that bracket a limit point: the maximum of
/// the cubic Hermite interpolant of `t(s)` over the chord length `h` (weighted norm), with
/// values `t0`, `t1` and slopes `dt/ds` `s0 > 0 >= s1` at its ends. Exact to `O(h^4)`; falls back
/// to the larger end value where the cubic has no interior maximum.
fn limit_time(t0: f64, s0: f64, t1: f64, s1: f64, h: f64) -> f64 {
    let ends = t0.max(t1);
    if !(h.is_finite() && h > 0.0) {
        return ends;
    }
    // t(u) on u in [0, 1] with t'(u) = h dt/ds: Hermite basis
    let (m0, m1) = (h * s0, h * s1);
    let at = |u: f64| {
        let (u2, u3) = (u * u, u * u * u);
        (2.0 * u3 - 3.0 * u2 + 1.0) * t0
            + (u3 - 2.0 * u2 + u) * m0
            + (-2.0 * u3 + 3.0 * u2) * t1
            + (u3 - u2) * m1
    };
    // t'(u) = a u^2 + b u + c
    let a = 6.0 * t0 + 3.0 * m0 - 6.0 * t1 + 3.0 * m1;
    let b = -6.0 * t0 - 4.0 * m0 + 6.0 * t1 - 2.0 * m1;
    let c = m0;
    let mut best = ends;
    let mut consider = |u: f64| {
        if (0.0..=1.0).contains(&u) {
            best = best.max(at(u));
        }
    };
    if a.abs() < 1e-14 * (b.abs() + c.abs()) {
        if b != 0.0 {
            consider(-c / b);
        }
    } else {
        let disc = b * b - 4.0 * a * c;
        if disc >= 0.0 {
            let r = disc.sqrt();
            consider((-b + r) / (2.0 * a));
            consider((-b - r) / (2.0 * a));
        }
    }
    best
}

/// Traces the equilibrium path from `state` (an equilibrium on it, at `state.time < target`)
/// by pseudo-arc-length continuation until it reaches `target` on a stable branch, staying
/// within the schedule times `[t_min, t_max]`. `time_scale` (s) is the time that counts as one
/// unit of arc length (a load step). Calls `on_point` at every traced point with the state and
/// the workspace evaluated there. On `Landed` the state holds the equilibrium at `target`;
/// otherwise it is unchanged.
#[allow(clippy::too_many_arguments)]
pub fn continue_past_limit_points(
    model: &Model,
    solver: &mut StaticSolver,
    state: &mut State,
    ws: &mut Workspace,
    target: f64,
    time_scale: f64,
    (t_min, t_max): (f64, f64),
    mut on_point: impl FnMut(&ArcPoint, &State, &Workspace),
) -> ArcOutcome {
    let n = model.dof_count;
    let nc = model.constraint_count;
    let settings = model.solver;
    let mut rhs = DVector::zeros(n + nc);
    evaluate(model, state, ws, Tangents::Stiffness);
    let length_scale = residual_of(model, state, ws, &mut rhs, solver.size()).length_scale;
    let mut weights = DVector::zeros(n);
    for body in &model.bodies {
        for c in 0..body.dof_count {
            let rotation = body.basis.column(c).fixed_rows::<3>(3).norm() > 0.0;
            weights[body.dof_offset + c] =
                if rotation { 1.0 / ARC_ROTATION } else { 1.0 / (ARC_LENGTH_FRACTION * length_scale) };
        }
    }
    let mut tracer = Tracer {
        model,
        solver,
        weights,
        time_weight: 1.0 / time_scale.max(1e-300),
        rhs,
        rates: vec![0.0; model.cables.len()],
        r_t: DVector::zeros(n + nc),
    };
    let no_return =
        |limit: Option<(f64, State)>, points, reason| ArcOutcome::NoReturn { limit, points, reason };

    let mut base = state.clone();
    let mut rigid = rigid_body_motions(model, &base, ws);
    let Some(mut tau) = tracer.tangent(&base, ws, None, &rigid) else {
        return no_return(None, 0, "the path's tangent could not be computed at its start");
    };
    let mut ds = FIRST_ARC_STEP;
    let mut limit: Option<(f64, State)> = None;
    let mut approaching = false;
    let mut points = 0;
    while points < MAX_ARC_POINTS {
        let Some((next, step, iterations)) = tracer.correct(&base, ws, &tau, ds, &rigid) else {
            ds *= 0.5;
            if ds < MIN_ARC_STEP {
                return no_return(limit, points, "the arc-length corrector did not converge");
            }
            continue;
        };
        // `correct` left `ws` evaluated at `next` with its stiffness
        let res = residual_of(model, &next, ws, &mut tracer.rhs, tracer.solver.size());
        let report = tracer.solver.report(model, &next, ws, &res, iterations);
        rigid = rigid_body_motions(model, &next, ws);
        let Some(next_tau) = tracer.tangent(&next, ws, Some(&tau), &rigid) else {
            return no_return(limit, points, "the path's tangent could not be computed");
        };
        let (t_old, t_new) = (tau[n + nc], next_tau[n + nc]);
        if limit.is_none() && t_old > 0.0 && t_new <= 0.0 && ds > LIMIT_BRACKET {
            // bracket the limit point again with shorter steps, so that it is located to O(h^4)
            ds = (ds / 8.0).max(LIMIT_BRACKET);
            approaching = true;
            continue;
        }
        points += 1;
        if limit.is_none() && t_old > 0.0 && t_new <= 0.0 {
            let mut chord = step.rows(0, n + nc + 1).into_owned();
            chord.rows_mut(n, nc).fill(0.0);
            let peak = limit_time(base.time, t_old, next.time, t_new, tracer.norm(&chord));
            let nearest = if next.time >= base.time { next.clone() } else { base.clone() };
            limit = Some((peak, nearest));
        }
        evaluate(model, &next, ws, Tangents::None);
        on_point(&ArcPoint { time: next.time, report, tangent_time: t_new }, &next, ws);
        if base.time < target && next.time >= target && report.stable {
            // land exactly on the target time from the point interpolated between the two
            let f = (target - base.time) / (next.time - base.time);
            let mut landing = base.clone();
            retract(model, &mut landing.poses, &step.rows(0, n).into_owned(), f);
            landing.multipliers = &base.multipliers + (&next.multipliers - &base.multipliers) * f;
            landing.time = target;
            model.scheduled_rest_lengths(target, &mut landing.rest_lengths);
            if let Ok(report) = tracer.solver.equilibrate_holding(model, &mut landing, ws, &settings) {
                if report.stable {
                    *state = landing;
                    return ArcOutcome::Landed { report, limit_time: limit.map(|l| l.0), points };
                }
            }
        }
        if next.time < t_min || next.time > t_max {
            return no_return(limit, points, "the path left the schedule's time span");
        }
        base = next;
        tau = next_tau;
        if limit.is_some() {
            approaching = false;
        }
        ds = if iterations <= 3 && !approaching { (1.5 * ds).min(MAX_ARC_STEP) } else { ds };
    }
    no_return(limit, points, "the path did not come back within the largest number of points")
}
