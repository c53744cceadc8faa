//! The learning task, defined once: takes a model's sizes and a task's choices (the actuators an
//! action drives, rate or rest-length targets, their limits, the observed fields, the default
//! reward's target tensions), gives the action mapping (`LearningTask::values`), the observation
//! layout and the observation of a state (`LearningTask::observe`), and the default reward
//! (`LearningTask::tension_reward`). The Python extension runs it in process and hands the same
//! definition to the Gymnasium environment for a node stepped over shared memory, so both
//! backends give the same bits.

use crate::evaluate::Workspace;
use crate::model::{Model, Pose};
use crate::sensors::{reading, SensorKind};
use crate::state::State;

/// What an observed field has one entry per.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Element {
    /// One per cable (`Model::cables`).
    Cable,
    /// One per actuator (`Model::actuators`).
    Actuator,
    /// One per body (`Model::bodies`).
    Body,
}

impl Element {
    /// Its name: `cable`, `actuator`, `body`.
    pub fn name(self) -> &'static str {
        match self {
            Element::Cable => "cable",
            Element::Actuator => "actuator",
            Element::Body => "body",
        }
    }
}

/// An array of the state an observation may take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObservationField {
    /// Each cable's tension, N.
    CableTension,
    /// Each cable's length, m.
    CableLength,
    /// Each cable's rest length, m.
    CableRestLength,
    /// Each actuator's cable's rest length, m.
    ActuatorRestLength,
    /// Each actuator's cable's rest-length rate over the last step, m/s.
    ActuatorRate,
    /// Each body's centre of mass (x, y, z), m.
    BodyPosition,
    /// Each body's orientation as a unit quaternion in ROS order (x, y, z, w).
    BodyOrientation,
}

impl ObservationField {
    /// Every field, in the order the reference lists them.
    pub const ALL: [Self; 7] = [
        Self::CableTension,
        Self::CableLength,
        Self::CableRestLength,
        Self::ActuatorRestLength,
        Self::ActuatorRate,
        Self::BodyPosition,
        Self::BodyOrientation,
    ];

    /// Its name (`cable_tension`, ...), the `State` attribute of the Python kit that holds it.
    pub fn name(self) -> &'static str {
        match self {
            Self::CableTension => "cable_tension",
            Self::CableLength => "cable_length",
            Self::CableRestLength => "cable_rest_length",
            Self::ActuatorRestLength => "actuator_rest_length",
            Self::ActuatorRate => "actuator_rate",
            Self::BodyPosition => "body_position",
            Self::BodyOrientation => "body_orientation",
        }
    }

    /// The field named `name`, if there is one.
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.name() == name)
    }

    /// What it has one entry per.
    pub fn element(self) -> Element {
        match self {
            Self::CableTension | Self::CableLength | Self::CableRestLength => Element::Cable,
            Self::ActuatorRestLength | Self::ActuatorRate => Element::Actuator,
            Self::BodyPosition | Self::BodyOrientation => Element::Body,
        }
    }

    /// Numbers per entry: 3 for a position, 4 for an orientation, else 1.
    pub fn width(self) -> usize {
        match self {
            Self::BodyPosition => 3,
            Self::BodyOrientation => 4,
            _ => 1,
        }
    }

    /// The sensor channel that reports this field instead when observations are measured, if any
    /// (a rest length set by the controller and a rate have none).
    pub fn sensor(self) -> Option<SensorKind> {
        Some(match self {
            Self::CableTension => SensorKind::Tension,
            Self::CableLength => SensorKind::Length,
            Self::ActuatorRestLength => SensorKind::RestLength,
            Self::BodyPosition => SensorKind::Position,
            Self::BodyOrientation => SensorKind::Orientation,
            Self::CableRestLength | Self::ActuatorRate => return None,
        })
    }

    /// Entries of this field in a model of `sizes`.
    pub fn count(self, sizes: &TaskSizes) -> usize {
        match self.element() {
            Element::Cable => sizes.cables,
            Element::Actuator => sizes.actuators,
            Element::Body => sizes.bodies,
        }
    }

    /// Appends this field of the state `state` (evaluated into `ws`, rest-length rates `rates`
    /// per cable, m/s) to `out`; with `measured` (the sensors' readings,
    /// `crate::sensors::Sensors::measured`, non-empty) what its sensor channel reports where the
    /// model declares one. Orientations go in ROS order (x, y, z, w) either way.
    pub fn append(
        self,
        model: &Model,
        state: &State,
        ws: &Workspace,
        rates: &[f64],
        measured: Option<&[f64]>,
        out: &mut Vec<f64>,
    ) {
        let sensed = self.sensor().zip(measured).and_then(|(k, m)| reading(model, m, k));
        if let Some(values) = sensed {
            if self == Self::BodyOrientation {
                for q in values.chunks_exact(4) {
                    out.extend_from_slice(&xyzw_of_wxyz(q));
                }
            } else {
                out.extend_from_slice(values);
            }
            return;
        }
        match self {
            Self::CableTension => out.extend(ws.cables.iter().map(|c| c.tension)),
            Self::CableLength => out.extend(ws.cables.iter().map(|c| c.length)),
            Self::CableRestLength => out.extend(ws.cables.iter().map(|c| c.rest_length)),
            Self::ActuatorRestLength => {
                out.extend(model.actuators.iter().map(|a| state.rest_lengths[a.cable.0]))
            }
            Self::ActuatorRate => out.extend(model.actuators.iter().map(|a| rates[a.cable.0])),
            Self::BodyPosition => {
                for p in &state.poses {
                    out.extend_from_slice(&[p.position.x, p.position.y, p.position.z]);
                }
            }
            Self::BodyOrientation => {
                for p in &state.poses {
                    out.extend_from_slice(&quaternion_xyzw(p));
                }
            }
        }
    }
}

/// A pose's orientation in ROS order (x, y, z, w): the order of the shared-memory payloads,
/// the ROS messages and observations.
pub fn quaternion_xyzw(pose: &Pose) -> [f64; 4] {
    let q = pose.rotation.quaternion();
    [q.i, q.j, q.k, q.w]
}

/// A quaternion given (w, x, y, z), as an orientation sensor reports it, in ROS order (x, y,
/// z, w).
///
/// Precondition: `q.len() == 4`.
pub fn xyzw_of_wxyz(q: &[f64]) -> [f64; 4] {
    [q[1], q[2], q[3], q[0]]
}

/// The sizes a task is checked against: how many cables, actuators and bodies the model has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TaskSizes {
    /// Cables (and members).
    pub cables: usize,
    /// Actuators.
    pub actuators: usize,
    /// Bodies.
    pub bodies: usize,
}

impl TaskSizes {
    /// The sizes of `model`.
    pub fn of(model: &Model) -> Self {
        Self { cables: model.cables.len(), actuators: model.actuators.len(), bodies: model.bodies.len() }
    }
}

/// A learning task's constant description: which actuators an action drives and how, what is
/// observed, and the default reward's targets.
#[derive(Debug, Clone, PartialEq)]
pub struct LearningTask {
    /// The actuators (indices into `Model::actuators`) an action drives, one value each.
    pub actuators: Vec<usize>,
    /// True: each value is a rest-length rate (m/s); false: a rest-length target (m).
    pub rate: bool,
    /// Each value's limits in SI units (low, high).
    pub bounds: Vec<(f64, f64)>,
    /// Values in [-1, 1], mapped linearly onto `bounds`; else clipped to them.
    pub normalize: bool,
    /// The observed fields, concatenated in this order.
    pub fields: Vec<ObservationField>,
    /// Observe what the sensors report where the scene declares them.
    pub measured: bool,
    /// (cable index, target tension N > 0) of the default reward.
    pub targets: Vec<(usize, f64)>,
}

impl LearningTask {
    /// The task, checked against a model of `sizes`: at least one actuator, each an index of
    /// the model with finite limits `low[k] <= high[k]`; at least one field, each a name of
    /// `ObservationField`; at least one target, each a cable index with a finite tension > 0 N.
    /// Else the reason.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        sizes: &TaskSizes,
        actuators: Vec<usize>,
        rate: bool,
        low: &[f64],
        high: &[f64],
        normalize: bool,
        fields: &[String],
        measured: bool,
        targets: Vec<(usize, f64)>,
    ) -> Result<Self, String> {
        if actuators.is_empty() || actuators.len() != low.len() || actuators.len() != high.len() {
            return Err(format!(
                "{} actuators, {} lows and {} highs: one each, at least one",
                actuators.len(),
                low.len(),
                high.len()
            ));
        }
        if let Some(a) = actuators.iter().find(|a| **a >= sizes.actuators) {
            return Err(format!("actuator index {a} of {}", sizes.actuators));
        }
        if low.iter().zip(high).any(|(l, h)| !(l.is_finite() && h.is_finite() && l <= h)) {
            return Err("every bound finite and low <= high".into());
        }
        let fields = fields
            .iter()
            .map(|f| {
                ObservationField::parse(f).ok_or_else(|| {
                    let names: Vec<&str> = ObservationField::ALL.iter().map(|f| f.name()).collect();
                    format!("unknown field {f:?} (fields: {})", names.join(", "))
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        if fields.is_empty() {
            return Err("observe at least one field".into());
        }
        if let Some((c, t)) = targets.iter().find(|(c, t)| *c >= sizes.cables || !(t.is_finite() && *t > 0.0))
        {
            return Err(format!("target ({c}, {t}): a cable index of {} and a tension > 0", sizes.cables));
        }
        if targets.is_empty() {
            return Err("at least one target tension".into());
        }
        Ok(Self {
            actuators,
            rate,
            bounds: low.iter().copied().zip(high.iter().copied()).collect(),
            normalize,
            fields,
            measured,
            targets,
        })
    }

    /// The SI value of action value `x` for actuator slot `k`: with `normalize`,
    /// `low + (clamp(x, -1, 1) + 1) (high - low) / 2`; else `x` clipped to `[low, high]`.
    pub fn value(&self, k: usize, x: f64) -> f64 {
        let (low, high) = self.bounds[k];
        if self.normalize {
            low + 0.5 * (x.clamp(-1.0, 1.0) + 1.0) * (high - low)
        } else {
            x.max(low).min(high)
        }
    }

    /// `Ok` when `action` has one finite value per actuator, else the reason.
    pub fn check_action(&self, action: &[f64]) -> Result<(), String> {
        if action.len() != self.actuators.len() {
            return Err(format!(
                "the action has {} values for {} actuators",
                action.len(),
                self.actuators.len()
            ));
        }
        if action.iter().any(|x| !x.is_finite()) {
            return Err(format!("the action is not finite: {action:?}"));
        }
        Ok(())
    }

    /// Checks `action` (`check_action`) and maps it in place onto the actuators' rates (m/s) or
    /// rest lengths (m) (`value`). Else the reason, and `action` unchanged.
    pub fn map_action(&self, action: &mut [f64]) -> Result<(), String> {
        self.check_action(action)?;
        for (k, x) in action.iter_mut().enumerate() {
            *x = self.value(k, *x);
        }
        Ok(())
    }

    /// The default reward, `tension(c)` giving cable `c`'s tension (N): minus the mean of
    /// `|T - T*| / T*` over the targets.
    pub fn tension_reward(&self, tension: impl Fn(usize) -> f64) -> f64 {
        let sum: f64 = self.targets.iter().map(|&(c, t)| (tension(c) - t).abs() / t).sum();
        -sum / self.targets.len() as f64
    }

    /// Where each observed field sits in an observation of a model of `sizes`: (field, entries,
    /// numbers per entry), in order.
    pub fn layout(&self, sizes: &TaskSizes) -> Vec<(ObservationField, usize, usize)> {
        self.fields.iter().map(|&f| (f, f.count(sizes), f.width())).collect()
    }

    /// The observation's length in a model of `sizes`.
    pub fn observation_size(&self, sizes: &TaskSizes) -> usize {
        self.layout(sizes).iter().map(|(_, n, w)| n * w).sum()
    }

    /// Appends the observation of `state` (evaluated into `ws`, rest-length rates `rates` per
    /// cable; `measured` the sensors' readings, used when the task observes them) to `out`.
    pub fn observe(
        &self,
        model: &Model,
        state: &State,
        ws: &Workspace,
        rates: &[f64],
        measured: &[f64],
        out: &mut Vec<f64>,
    ) {
        let measured = (self.measured && !measured.is_empty()).then_some(measured);
        for f in &self.fields {
            f.append(model, state, ws, rates, measured, out);
        }
    }
}
