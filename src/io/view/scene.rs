//! A scene for the viewer: takes a model, gives the frame of its static equilibrium at the
//! initial rest lengths (`equilibrium`) and frames of its vibration modes animated over it
//! (`mode_frames`).

use crate::evaluate::{evaluate_forces, Workspace};
use crate::model::Model;
use crate::solve::statics::StaticSolver;
use crate::state::{retract, State};

use super::{Frame, ViewGeometry};

/// The equilibrium of `model` at its initial rest lengths and its frame, or why there is none
/// (the solver's stop reason and residual).
pub fn equilibrium(model: &Model, geometry: &ViewGeometry) -> Result<(State, Frame), String> {
    let mut state = State::initial(model);
    let mut ws = Workspace::new(model);
    let mut solver = StaticSolver::new(model);
    solver.equilibrate(model, &mut state, &mut ws, &model.solver).map_err(|(it, res)| {
        format!(
            "no equilibrium found: residual {res:.3e} N after {it} Newton iterations ({})",
            solver.stop_words(model)
        )
    })?;
    evaluate_forces(model, &state, &mut ws);
    let frame = Frame::of_state(model, geometry, &state, &ws);
    Ok((state, frame))
}

/// Frames of the vibrating modes `first..first + count` (lowest first, zero-frequency modes
/// skipped) about the equilibrium `state`, each over one cycle of `frames_per_cycle` frames, its
/// farthest point moving by a tenth of the structure's size. A frame's time runs over the modes
/// one after the other, each cycle stretched to 2 s; its tensions are those of the displaced
/// state. Also a line per mode drawn (`mode 1: 2.5 Hz, 0-2 s`). Empty when nothing vibrates.
pub fn mode_frames(
    model: &Model,
    geometry: &ViewGeometry,
    state: &State,
    count: usize,
    frames_per_cycle: usize,
) -> (Vec<Frame>, Vec<String>) {
    let Some(modes) = crate::solve::modes::natural_modes(model, state) else {
        return (Vec::new(), Vec::new());
    };
    let rest = geometry.vertices(model, &state.poses);
    let size = crate::solve::statics::body_size(model).max(
        rest.iter()
            .flat_map(|a| {
                rest.iter().map(move |b| (nalgebra::Vector3::from(*a) - nalgebra::Vector3::from(*b)).norm())
            })
            .fold(0.0, f64::max),
    );
    let reach_of = |poses: &[crate::model::Pose]| {
        geometry
            .vertices(model, poses)
            .iter()
            .zip(&rest)
            .map(|(a, b)| (nalgebra::Vector3::from(*a) - nalgebra::Vector3::from(*b)).norm())
            .fold(0.0, f64::max)
    };
    let mut ws = Workspace::new(model);
    let mut out = Vec::new();
    let mut labels = Vec::new();
    let n = frames_per_cycle.max(4);
    for (k, mode) in modes.iter().filter(|m| !m.zero && m.omega_squared > 0.0).take(count).enumerate() {
        labels.push(format!(
            "mode {}: {:.4} Hz, shown at {}-{} s",
            k + 1,
            mode.frequency_hz,
            2 * k,
            2 * k + 2
        ));
        let mut unit = state.poses.clone();
        retract(model, &mut unit, &mode.shape, 1e-6);
        let amplitude = 0.1 * size / (reach_of(&unit) / 1e-6).max(1e-300);
        for i in 0..n {
            let phase = std::f64::consts::TAU * i as f64 / n as f64;
            let mut moved = state.clone();
            retract(model, &mut moved.poses, &mode.shape, amplitude * phase.sin());
            moved.time = 2.0 * (k as f64 + i as f64 / n as f64);
            evaluate_forces(model, &moved, &mut ws);
            out.push(Frame::of_state(model, geometry, &moved, &ws));
        }
    }
    (out, labels)
}
