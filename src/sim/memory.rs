//! The prepare/commit hooks of force elements with memory: before a sub-step the winches'
//! controllers set their drives; after an accepted one the pulleys' return map and the winches'
//! drums become the state, and their works go into the energy account; the stick-slip
//! contacts' anchors follow the accepted step. Out of line: a scene without winches, pulley
//! friction or stick-slip friction never runs them.

use crate::model::Model;
use crate::sim::simulator::Simulator;

impl Simulator {
    /// After an accepted sub-step of `h` (s): the pulleys' return map at the accepted state
    /// becomes the state (`crate::forces::pulley::commit`), and friction's loss is booked. Out
    /// of line: scenes without friction never run it.
    #[cold]
    #[inline(never)]
    pub(super) fn commit_pulley_friction(&mut self, h: f64) {
        self.energy.friction_loss += crate::forces::pulley::commit(
            &self.model,
            &mut self.ws.friction,
            &mut self.state.segment_rest_lengths,
            h,
        );
    }

    /// After an accepted sub-step: the stick-slip contacts' anchors follow what the step ended
    /// with (`crate::forces::contact::commit_anchors`), and the spring energy the slipping ones
    /// gave up is booked as friction's loss (and leaves the workspace's elastic energy and
    /// contact power, which now describe the committed anchors). Out of line: scenes without stick-slip friction
    /// never run it.
    #[cold]
    #[inline(never)]
    pub(super) fn commit_contact_anchors(&mut self) {
        let (removed, power) = crate::forces::contact::commit_anchors(
            &self.model,
            &self.state.poses,
            &self.ws.points,
            &self.ws.contacts,
            &mut self.state.contact_anchors,
        );
        self.energy.friction_loss += removed;
        self.ws.energies.elastic -= removed;
        self.ws.contact_loss_power += power;
    }

    /// Before a sub-step of `h` (s): each winch's controller sets its drive for the sub-step
    /// (`crate::forces::winch::prepare`, from its command in `Control`), and the work factor
    /// `dV/dL0` of its cable now is kept for `commit_winches`. Out of line: scenes without
    /// winches never run it.
    #[cold]
    #[inline(never)]
    pub(super) fn prepare_winches(&mut self, h: f64) {
        for (w, winch) in self.model.winches.iter().enumerate() {
            let c = winch.cable.0;
            let s = &mut self.state.winches[w];
            let command =
                self.control.winch_command(&self.model, winch.actuator, self.state.time, h, s.reference);
            crate::forces::winch::prepare(&self.model, winch, s, command, self.state.rest_lengths[c], h);
            self.winch_rest_force[w] = rest_force(&self.model, &self.ws.cables[c], c);
        }
    }

    /// After an accepted sub-step of `h` (s): each winch's cable takes the rest length its motor
    /// reached (`crate::forces::winch::commit`), and the motors' work, friction and rotor energy
    /// and the work the drums did on their cables (trapezoidal, into `actuator_work`) are
    /// booked.
    #[cold]
    #[inline(never)]
    pub(super) fn commit_winches(&mut self, h: f64) {
        let mut kinetic = 0.0;
        for (w, winch) in self.model.winches.iter().enumerate() {
            let c = winch.cable.0;
            let (l0_start, l0_end) = (self.state.rest_lengths[c], self.ws.cables[c].rest_length);
            let work = crate::forces::winch::commit(winch, &mut self.state.winches[w], l0_start, l0_end);
            self.energy.motor_work += work.motor;
            self.energy.winch_friction_loss += work.friction;
            let rate = (l0_end - l0_start) / h;
            let end = rest_force(&self.model, &self.ws.cables[c], c);
            self.energy.actuator_work -= 0.5 * h * (self.winch_rest_force[w] + end) * rate;
            self.state.rest_lengths[c] = l0_end;
            kinetic += crate::forces::winch::rotor_energy(winch, self.state.winches[w].speed);
        }
        self.energy.winch_kinetic = kinetic;
    }
}

/// `-dV/dL0` of cable `c` (N) at its response `r`, at a fixed length: `T_el (L + L0) / (2 L0)`
/// while taut, 0 slack: the force an actuator moving its rest length works against
/// (`crate::forces::cable::elastic_energy_rest_derivative`).
fn rest_force(model: &Model, r: &crate::forces::cable::CableResponse, c: usize) -> f64 {
    if r.slack {
        return 0.0;
    }
    -crate::forces::cable::elastic_energy_rest_derivative(&model.cables[c], r.rest_length, r.length)
}
