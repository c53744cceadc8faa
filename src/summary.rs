//! Whole-command results as data: takes a model, gives its static equilibrium with everything
//! `tensegrity statics --json` prints (`statics`, `StaticsSummary`) and its modes as
//! `tensegrity modes --json` prints them (`modes`, `ModeSummary`). The command line and the
//! Python library both call these, so their numbers are the same to the bit.

use serde::Serialize;

use crate::evaluate::{evaluate, Tangents, Workspace};
use crate::model::Model;
use crate::report;
use crate::solve::modes::Mode;
use crate::solve::statics::{EquilibriumReport, StaticSolver};
use crate::state::State;

/// Why a structure whose joints hold every coordinate has no reduced stiffness to report.
pub const NO_FREE_MOTION: &str = "no free motion: the joints hold every coordinate";

/// Everything `tensegrity statics --json` prints (docs/cli.md, "JSON"): the solve (iterations,
/// stop reason, residuals, N), stability, the potential energy (J), how far the equilibrium lies
/// from the scene's pose (m), and each body, named point, cable, contact and joint.
#[derive(Debug, Clone, Serialize)]
pub struct StaticsSummary {
    /// Scene name.
    pub scene: String,
    /// Newton iterations.
    pub iterations: usize,
    /// The solver's stop reason, in words.
    pub stop_reason: &'static str,
    /// Final residual, N.
    pub residual_n: f64,
    /// Residual after each iteration, N.
    pub residual_history_n: Vec<f64>,
    /// The force scale the tolerance is relative to, N.
    pub force_scale_n: f64,
    /// Whether the equilibrium is stable.
    pub stable: bool,
    /// Modes of negative reduced stiffness.
    pub negative_stiffness_modes: usize,
    /// Modes of zero reduced stiffness (besides rigid-body motions).
    pub zero_stiffness_modes: usize,
    /// The smallest reduced stiffness eigenvalue; left out where there is no free motion
    /// (`not_computed` says why).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_stiffness_eigenvalue: Option<f64>,
    /// The quantities left out of this report, each with the reason.
    #[serde(skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub not_computed: std::collections::BTreeMap<&'static str, &'static str>,
    /// Elastic plus gravitational potential energy, J.
    pub potential_energy_j: f64,
    /// The largest distance of a named point from where the scene sketched it, m.
    pub largest_move_from_scene_m: f64,
    /// Body poses.
    pub bodies: Vec<report::BodyReport>,
    /// Every named point's position, m.
    pub points: Vec<(String, [f64; 3])>,
    /// Every cable and member.
    pub cables: Vec<report::CableReport>,
    /// Every contact pair (scenes with grounds or colliding struts).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub contacts: Vec<report::ContactReport>,
    /// Every joint's reaction.
    pub joints: Vec<report::JointReport>,
}

/// A solved equilibrium: the state, its evaluation, the solver's report and the summary.
pub struct StaticsSolution {
    /// The equilibrium state.
    pub state: State,
    /// Its evaluation (forces, no tangents).
    pub ws: Workspace,
    /// The solver's report.
    pub report: EquilibriumReport,
    /// The largest move from the scene's pose, m, and the point that moved so.
    pub largest_move: (f64, String),
    /// What `statics --json` prints.
    pub summary: StaticsSummary,
}

/// Why no equilibrium was found.
#[derive(Debug, Clone, PartialEq)]
pub struct NoEquilibrium {
    /// Newton iterations taken.
    pub iterations: usize,
    /// The last residual, N.
    pub residual: f64,
    /// The solver's stop reason, in words.
    pub stop_words: String,
    /// Residual after each iteration, N.
    pub history: Vec<f64>,
}

/// The equilibrium of `model` at its initial rest lengths (`tensegrity statics`).
///
/// Precondition: every body is held (`report::unheld_bodies_note` is None); a structure that
/// floats has no equilibrium and the solve ends with `NoEquilibrium`.
pub fn statics(model: &Model) -> Result<StaticsSolution, NoEquilibrium> {
    let mut state = State::initial(model);
    let mut ws = Workspace::for_forces(model);
    evaluate(model, &state, &mut ws, Tangents::None);
    let reference = report::all_pulley_coordinates(model, &state, &ws);
    let mut solver = StaticSolver::new(model);
    let r =
        solver.equilibrate(model, &mut state, &mut ws, &model.solver).map_err(|(iterations, residual)| {
            NoEquilibrium {
                iterations,
                residual,
                stop_words: solver.stop_words(model),
                history: solver.residual_history().to_vec(),
            }
        })?;
    evaluate(model, &state, &mut ws, Tangents::None);
    let cables = report::cable_reports(model, &state, &ws, &reference);
    // how far the equilibrium lies from the pose the scene sketched, and where
    let sketched = State::initial(model);
    let largest_move = model
        .points
        .iter()
        .map(|p| {
            let at = |s: &State| s.poses[p.body.0].transform_point(&p.local);
            ((at(&state) - at(&sketched)).norm(), p.name.as_str())
        })
        .fold((0.0, ""), |a, b| if b.0 > a.0 { b } else { a });
    let summary = StaticsSummary {
        scene: model.name.clone(),
        iterations: r.iterations,
        stop_reason: solver.stop_reason().words(),
        residual_n: r.residual,
        residual_history_n: solver.residual_history().to_vec(),
        force_scale_n: r.force_scale,
        stable: r.stable,
        negative_stiffness_modes: r.negative_modes,
        zero_stiffness_modes: r.zero_modes,
        min_stiffness_eigenvalue: r
            .min_stiffness_eigenvalue
            .is_finite()
            .then_some(r.min_stiffness_eigenvalue),
        not_computed: if r.min_stiffness_eigenvalue.is_finite() {
            Default::default()
        } else {
            [("min_stiffness_eigenvalue", NO_FREE_MOTION)].into()
        },
        potential_energy_j: r.potential_energy,
        largest_move_from_scene_m: largest_move.0,
        bodies: report::body_reports(model, &state),
        points: report::point_positions(model, &ws),
        cables,
        contacts: report::contact_reports(model, &ws),
        joints: report::joint_reports(model, &state),
    };
    let largest_move = (largest_move.0, largest_move.1.to_string());
    Ok(StaticsSolution { state, ws, report: r, largest_move, summary })
}

/// One mode as `tensegrity modes --json` prints it.
#[derive(Debug, Clone, Serialize)]
pub struct ModeSummary {
    /// 1-based, in the order of all modes (zero-frequency ones included).
    pub index: usize,
    /// Frequency, Hz (0 for zero and unstable modes).
    pub frequency_hz: f64,
    /// `omega^2`, 1/s^2.
    pub omega_squared: f64,
    /// A zero-frequency mode (rigid-body motion, mechanism, sliding).
    pub zero_frequency: bool,
    /// Each body's share of the mode's kinetic energy.
    pub kinetic_share: Vec<(String, f64)>,
    /// Each cable's length change per unit modal amplitude, m.
    pub cable_stretch_m: Vec<(String, f64)>,
    /// Each cable's largest segment-length change per unit modal amplitude, m.
    pub largest_segment_change_m: Vec<(String, f64)>,
}

/// The modes `tensegrity modes` lists: every zero-frequency one, then the lowest `count` others.
pub fn listed_modes(modes: &[Mode], count: usize) -> Vec<usize> {
    let zero = (0..modes.len()).filter(|&i| modes[i].zero);
    zero.chain((0..modes.len()).filter(|&i| !modes[i].zero).take(count)).collect()
}

/// The summaries of `listed_modes(modes, count)`.
pub fn mode_summaries(model: &Model, modes: &[Mode], count: usize) -> Vec<ModeSummary> {
    let named =
        |v: &[f64], names: &mut dyn Iterator<Item = String>| names.zip(v.iter().copied()).collect::<Vec<_>>();
    listed_modes(modes, count)
        .iter()
        .map(|&i| {
            let m = &modes[i];
            ModeSummary {
                index: i + 1,
                frequency_hz: m.frequency_hz,
                omega_squared: m.omega_squared,
                zero_frequency: m.zero,
                kinetic_share: named(&m.kinetic_share, &mut model.bodies.iter().map(|b| b.name.clone())),
                cable_stretch_m: named(&m.cable_stretch, &mut model.cable_names.iter().cloned()),
                largest_segment_change_m: named(&m.segment_change, &mut model.cable_names.iter().cloned()),
            }
        })
        .collect()
}

/// Why `modes` found none.
#[derive(Debug, Clone, PartialEq)]
pub enum ModesFailure {
    /// No equilibrium to vibrate about.
    NoEquilibrium(NoEquilibrium),
    /// The mass matrix on the joints' null space is singular (a massless free coordinate).
    SingularMass,
}

/// The equilibrium of `model` (`tensegrity modes`' own solve) and its natural modes.
///
/// Precondition: as `statics`, and some coordinate is free (`model.dof_count > 0`).
pub fn modes(model: &Model) -> Result<(State, EquilibriumReport, Vec<Mode>), ModesFailure> {
    let mut state = State::initial(model);
    let mut ws = Workspace::new(model);
    let mut solver = StaticSolver::new(model);
    let r =
        solver.equilibrate(model, &mut state, &mut ws, &model.solver).map_err(|(iterations, residual)| {
            ModesFailure::NoEquilibrium(NoEquilibrium {
                iterations,
                residual,
                stop_words: solver.stop_words(model),
                history: solver.residual_history().to_vec(),
            })
        })?;
    let modes = crate::solve::modes::natural_modes(model, &state).ok_or(ModesFailure::SingularMass)?;
    Ok((state, r, modes))
}
