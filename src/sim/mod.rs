//! The simulator: owns a `Model`, its `State`, the integrator memory and the workspace; takes a
//! step size and an integrator, gives fixed-size steps (`step`) with step statistics and a running
//! energy account. A step whose Newton iteration fails, or that produces a non-finite number, is
//! rejected and retried in halves down to `min_dt`; below that a typed `StepError` comes out and the
//! state is left at the last good step. No NaN or infinity ever enters the state. The explicit
//! integrator is refused at start-up when the step exceeds its stability limit (checked at the
//! initial state; tension changes during a run move the limit, so keep a margin).
//!
//! The parts, one file each: `settings` (how it steps, what a step cost, why one failed),
//! `simulator` (construction, commands, reset), `substep` (the sub-step loop), `step_size` (its step-size
//! control), `guards` (the checks that accept, retry or fail a sub-step: contact events,
//! pass-throughs, energy gain, divergence), `memory` (the prepare/commit hooks of elements with
//! memory: winches, pulley friction) and `energy` (the energy account).

mod energy;
mod guards;
mod memory;
mod settings;
mod simulator;
mod step_size;
mod substep;

pub use energy::EnergyAccount;
pub use guards::{CONTACT_EVENT_DEPTH, DIVERGENCE_FACTOR, IMPLICIT_GAIN_FACTOR};
pub use settings::{
    checked_dt, checked_newton, DynamicOptions, SimSettings, StepError, StepStats, DEFAULT_PHYSICS_DT,
};
pub use simulator::Simulator;
pub use step_size::{
    smallest_controlled_step, EXPLICIT_ERROR_STEP, EXPLICIT_STEP_CAP, GROWTH_THRESHOLD,
    INITIAL_STEP_FRACTION, MIN_CONTROLLED_STEP, TIGHT_CONTROLLED_TOLERANCE,
};
