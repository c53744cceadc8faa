//! The energy account: takes the workspace's energies and the works booked per sub-step, gives
//! the balance `total - initial = actuator work - losses` and what it does not explain.

/// Energies and cumulative works, J. With no numerical dissipation,
/// `total() - initial_total = actuator_work - damping_loss` up to the integrator's error.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EnergyAccount {
    /// Kinetic energy `v^T M v / 2`.
    pub kinetic: f64,
    /// Elastic energy of taut cables.
    pub elastic: f64,
    /// Gravitational potential.
    pub gravitational: f64,
    /// Work done by the actuators on the cables since the start (trapezoidal in time).
    pub actuator_work: f64,
    /// Energy dissipated since the start (trapezoidal in time) by the cable and member dampers
    /// (Rayleigh's `beta` included), the contacts, the joints' rotational damping and Rayleigh's
    /// mass-proportional `alpha`.
    pub damping_loss: f64,
    /// Energy dissipated since the start by friction at the pulleys, and by stick-slip contacts
    /// where their anchors follow a slip, booked per accepted step
    /// (`crate::forces::pulley::commit`, `crate::forces::contact::commit_anchors`).
    pub friction_loss: f64,
    /// Work of the winch motors' line forces since the start, `sum h F_m v`
    /// (`crate::forces::winch`); 0 without winches.
    pub motor_work: f64,
    /// Energy lost in the winch drums' viscous friction since the start.
    pub winch_friction_loss: f64,
    /// Kinetic energy of the winch rotors now, `sum J omega^2 / 2`. Outside `total()`: the
    /// motors' balance is `motor_work - winch_friction_loss - winch_kinetic ~ ` the work the
    /// drums do on their cables (part of `actuator_work`).
    pub winch_kinetic: f64,
    /// Total energy at the start.
    pub initial_total: f64,
}

impl EnergyAccount {
    /// Kinetic + elastic + gravitational.
    pub fn total(&self) -> f64 {
        self.kinetic + self.elastic + self.gravitational
    }
    /// Energy the balance does not explain: `initial + work - loss - total` (the integrator's
    /// numerical dissipation plus its error).
    pub fn numerical_loss(&self) -> f64 {
        self.initial_total + self.actuator_work - self.damping_loss - self.friction_loss - self.total()
    }
}
