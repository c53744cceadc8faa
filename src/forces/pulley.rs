//! Friction at a clustered cable's pulleys: takes a friction cable's route kinematics, the rest
//! lengths of its segments at the last accepted step and its current total rest length, gives
//! which pulleys stick and which slip, each segment's tension and rest length, the generalized
//! force `Q = -sum_k T_k g_k`, its consistent tangents `K = -dQ/dq` and `C = -dQ/dv`, and the
//! energy friction dissipates when a step is accepted (`commit`).
//!
//! Segment `k` runs from route point `k` to `k + 1` (`k = 0 .. m-1`); pulley `i` is route point
//! `i + 1`, between segments `i` and `i + 1`. With `l_k`, `e_k` and `g_k = dl_k/dq` the
//! segment's length, direction and length gradient, and `s_k` its rest length (its material):
//! - **law of a segment**: `T_k = max(0, (EA (l_k - s_k) + c L0 rho l_k) / s_k)` while
//!   `l_k > s_k` (else 0), with `rho = Ldot_ch / L_ch` the stretch rate of the chain of segments
//!   the segment slips with (below; the segment alone while its pulleys stick): the cable's
//!   damper `c` acts on the stretching of the material, not on cable running through a pulley,
//!   and with every pulley slipping freely the segments add up to the frictionless element
//!   `T = (EA/L0)(L - L0) + c Ldot` exactly. Inverted: `s_k = n_k / (EA + T_k)` with
//!   `n_k = l_k (EA + c L0 rho)`.
//! - **capstan bound** at pulley `i`, wrap angle `theta_i = atan2(|e_i x e_(i+1)|, e_i . e_(i+1))`
//!   (the angle the cable turns through): `T_high <= T_low exp(mu_i theta_i)`. A pulley sticks
//!   (no material crosses it since the last accepted step) while its ratio is inside the bound,
//!   and slips at the bound, material moving toward the higher tension.
//! - **return map** (rate independent, like plasticity): from the accepted rest lengths (the
//!   actuator's change of `L0` wound into the fed segment), pulleys that stick split the cable
//!   into chains of segments joined by slipping pulleys. In a chain `T_k = r_k T_a` (`r_k` the
//!   product of the factors `exp(-+mu theta)` of the slipping pulleys before `k`) and its
//!   material is fixed, `sum_k n_k / (EA + r_k T_a) = S`: one monotone equation for `T_a`
//!   (Newton, bracketed). An active set settles which pulleys slip: a sticking pulley past its
//!   bound starts to slip; a slipping one whose material would flow against its slip sticks.
//!   A chain whose material reaches its length is slack (all its tensions 0).
//! - **tangent**: with `D_j = EA + r_j T_a`, `W = sum_j s_j r_j / D_j`, `Lambda_D = sum_j l_j /
//!   D_j`, `dn_j = (EA + c L0 rho) dl_j + c L0 l_j drho`, `drho = (dLdot_ch - rho dL_ch) / L_ch`:
//!   `dT_a = (1/W) [sum_j dn_j / D_j + T_a sum_i d_i mu_i w_i dtheta_i]`
//!   (`w_i = sum_(j > i) s_j r_j / D_j`, `d_i = +1` when the cable slips toward the route's start
//!   at pulley `i`, `-1` toward its end), and `dT_k = r_k dT_a - T_a sum_(i < k) d_i mu_i r_k
//!   dtheta_i`; `K = sum_k [T_k dg_k/dq + g_k (dT_k/dq)^T]`, `C = sum_k g_k (dT_k/dv)^T`. Not
//!   symmetric while a pulley slips (friction is not conservative). At `theta = 0` or `pi` the
//!   wrap angle has no gradient (a cone point); it is taken as zero there (`WRAP_SINE_FLOOR`).
//!   Next to a vanishing segment the wrap angle fades out (`WRAP_FADE`), gradient included.
//! - **dissipation**: the elastic energy `V = sum_k EA (l_k - s_k)^2 / (2 s_k)` changes by
//!   `-phi_k ds_k` with `phi_k = T_el,k (l_k + s_k) / (2 s_k)`, so material `xi_i` crossing pulley
//!   `i` (into segment `i`) dissipates `(phi_i - phi_(i+1)) xi_i`, which is
//!   `(T_high - T_low)` times the slip to first order in the strain.

use nalgebra::{DVector, Vector3, Vector6};

use crate::assembly::TangentSink;
use crate::forces::cable::{add_segment_geometric_stiffness, route_geometry, CableResponse, CableScratch};
use crate::kinematics::{force_jacobian_derivative, velocity_derivative, PointKinematics};
use crate::model::{BodyKind, CableModel, Model, PointId, Pose, PulleyFriction};

/// Below this `sin(theta)` the wrap angle's gradient is taken as zero: `theta` is at one of its
/// cone points (0 or pi), where it has no derivative.
pub const WRAP_SINE_FLOOR: f64 = 1e-9;

/// A pulley next to a segment shorter than this fraction of its two segments' length has its
/// wrap angle faded out, `theta_eff = theta min(1, l_min / (WRAP_FADE (l_a + l_b)))`: the angle
/// to a segment about to vanish (a load pulled into its pulley) turns by `1/l` per metre of
/// motion and flips between 0 and pi, which no step could follow; a real pulley's radius
/// ends the wrap there too.
pub const WRAP_FADE: f64 = 1e-3;

/// `min(1, l_min / (WRAP_FADE (l_a + l_b)))` (`WRAP_FADE`), 0 for two empty segments.
fn wrap_fade(la: f64, lb: f64) -> f64 {
    let total = la + lb;
    if total > 0.0 {
        (la.min(lb) / (WRAP_FADE * total)).min(1.0)
    } else {
        0.0
    }
}

/// What a pulley with friction does at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PulleyState {
    /// No material crosses it: the tension ratio is inside the capstan bound.
    #[default]
    Stick,
    /// The cable slips toward the route's start (the segment before the pulley is the high side:
    /// `T_before = T_after exp(mu theta)`).
    SlipTowardStart,
    /// The cable slips toward the route's end (`T_after = T_before exp(mu theta)`).
    SlipTowardEnd,
    /// A frictionless pulley (`mu = 0`) on a cable whose other pulleys have friction: the cable
    /// runs through it freely.
    Free,
    /// Both segments are slack: no tension to hold.
    Slack,
}

impl PulleyState {
    /// `d_i`: +1 slipping toward the start, -1 toward the end, 0 otherwise.
    fn slip_sign(self) -> f64 {
        match self {
            PulleyState::SlipTowardStart => 1.0,
            PulleyState::SlipTowardEnd => -1.0,
            _ => 0.0,
        }
    }
    /// True when the segments on both sides belong to one chain (one tension, scaled).
    fn joins(self) -> bool {
        matches!(self, PulleyState::SlipTowardStart | PulleyState::SlipTowardEnd | PulleyState::Free)
    }
    /// The state as a number (recordings pack states as numbers): 0 stick, 1 slip toward the
    /// start, 2 toward the end, 3 free, 4 slack.
    pub fn code(self) -> f64 {
        match self {
            PulleyState::Stick => 0.0,
            PulleyState::SlipTowardStart => 1.0,
            PulleyState::SlipTowardEnd => 2.0,
            PulleyState::Free => 3.0,
            PulleyState::Slack => 4.0,
        }
    }
    /// The state of `code` (`PulleyState::code`; anything else: stick).
    pub fn from_code(code: f64) -> Self {
        match code as u8 {
            1 => PulleyState::SlipTowardStart,
            2 => PulleyState::SlipTowardEnd,
            3 => PulleyState::Free,
            4 => PulleyState::Slack,
            _ => PulleyState::Stick,
        }
    }
    /// Name in outputs: `stick`, `slip+` (toward the start), `slip-` (toward the end), `free`, `slack`.
    pub fn as_str(self) -> &'static str {
        match self {
            PulleyState::Stick => "stick",
            PulleyState::SlipTowardStart => "slip-start",
            PulleyState::SlipTowardEnd => "slip-end",
            PulleyState::Free => "free",
            PulleyState::Slack => "slack",
        }
    }
}

/// Everything the return map found for the friction cables at the last evaluation, plus its
/// scratch; allocated once per model (`FrictionWork::new`), so evaluation never allocates.
#[derive(Debug, Clone, Default)]
pub struct FrictionWork {
    /// Per friction segment (`PulleyFriction::segment_offset`): tension `T_k`, N.
    pub tensions: Vec<f64>,
    /// Per friction segment: rest length `s_k` the return map gives, m (what `commit` keeps).
    pub rest_lengths: Vec<f64>,
    /// Per friction segment: length `l_k`, m.
    pub lengths: Vec<f64>,
    /// Per friction segment: length rate `ldot_k`, m/s.
    rates: Vec<f64>,
    /// Per friction segment: `r_k`, its tension over its chain's first segment's.
    ratio: Vec<f64>,
    /// Per friction pulley (`PulleyFriction::pulley_offset`): what it does.
    pub states: Vec<PulleyState>,
    /// Per friction pulley: wrap angle `theta_i`, rad.
    pub wrap_angles: Vec<f64>,
    /// Per friction pulley: material that crossed it since the last accepted step, m (positive:
    /// into the segment before it, the cable moving toward the route's start).
    pub flows: Vec<f64>,
    /// Per friction pulley: the last accepted step's flow over its duration, m/s (0 in statics).
    pub slip_speeds: Vec<f64>,
    /// Scratch, per segment of the longest friction route: the accepted rest lengths with the
    /// actuator's change, and `n_k` (module docs).
    history: Vec<f64>,
    numerators: Vec<f64>,
    /// Scratch, per segment: `g_k` and `h_k = dldot_k/dq` at the segment's two points.
    seg_grad: Vec<[Vector6<f64>; 2]>,
    seg_rate_grad: Vec<[Vector6<f64>; 2]>,
    /// Scratch, per pulley: `dtheta_i/dq` at its three points.
    wrap_grad: Vec<[Vector6<f64>; 3]>,
    /// Scratch, per route point: the vectors of the tangent's outer products.
    left: Vec<Vector6<f64>>,
    right: Vec<Vector6<f64>>,
    right_rate: Vec<Vector6<f64>>,
}

impl FrictionWork {
    /// Sized for `model`'s friction cables (empty without).
    pub fn new(model: &Model) -> Self {
        let segments = model.initial_segment_rest_lengths.len();
        let pulleys: usize = model.pulley_friction.iter().map(|f| f.mu.len()).sum();
        let longest = model.pulley_friction.iter().map(|f| f.mu.len() + 2).max().unwrap_or(0);
        Self {
            tensions: vec![0.0; segments],
            rest_lengths: model.initial_segment_rest_lengths.clone(),
            lengths: vec![0.0; segments],
            rates: vec![0.0; segments],
            ratio: vec![1.0; segments],
            states: vec![PulleyState::Stick; pulleys],
            wrap_angles: vec![0.0; pulleys],
            flows: vec![0.0; pulleys],
            slip_speeds: vec![0.0; pulleys],
            history: vec![0.0; longest],
            numerators: vec![0.0; longest],
            seg_grad: vec![[Vector6::zeros(); 2]; longest],
            seg_rate_grad: vec![[Vector6::zeros(); 2]; longest],
            wrap_grad: vec![[Vector6::zeros(); 3]; longest],
            left: vec![Vector6::zeros(); longest],
            right: vec![Vector6::zeros(); longest],
            right_rate: vec![Vector6::zeros(); longest],
        }
    }

    /// Pulley `i` of friction cable `f` at the last evaluation (no allocation).
    pub fn pulley(&self, f: &PulleyFriction, i: usize) -> PulleyNumbers {
        let (j, k) = (f.pulley_offset + i, f.segment_offset + i);
        let (before, after) = (self.tensions[k], self.tensions[k + 1]);
        PulleyNumbers {
            state: self.states[j],
            wrap_angle: self.wrap_angles[j],
            tension_before: before,
            tension_after: after,
            tension_ratio: tension_ratio(before, after),
            // (0.0 - x: no negative zero in the outputs)
            slip_speed: 0.0 - self.slip_speeds[j],
        }
    }
}

/// One pulley's numbers at the last evaluation, in the outputs' conventions (`FrictionWork::
/// pulley`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PulleyNumbers {
    /// What it does.
    pub state: PulleyState,
    /// Wrap angle, rad.
    pub wrap_angle: f64,
    /// Tension of the segment before it (toward the route's first anchor), N.
    pub tension_before: f64,
    /// Tension of the segment after it, N.
    pub tension_after: f64,
    /// `tension_ratio(tension_before, tension_after)`.
    pub tension_ratio: f64,
    /// Slip speed over the last accepted step, m/s, positive toward the route's last anchor
    /// (0 after a static solve).
    pub slip_speed: f64,
}

/// Tension after a pulley over tension before it: 0 when the side before is slack (the ratio
/// the outputs publish).
pub fn tension_ratio(before: f64, after: f64) -> f64 {
    if before > 0.0 {
        after / before
    } else {
        0.0
    }
}

/// The rest lengths each friction cable's segments hold at t = 0 (`Model::
/// initial_segment_rest_lengths`): rest length `rest_lengths[c]` shared in proportion to the
/// segment lengths at `kin` (uniform strain, as a frictionless cable holds it).
pub fn shared_rest_lengths(model: &Model, kin: &[PointKinematics], rest_lengths: &[f64]) -> Vec<f64> {
    let mut out = Vec::new();
    for f in &model.pulley_friction {
        let route = model.route(f.cable);
        let lengths: Vec<f64> =
            route.windows(2).map(|w| (kin[w[1].0].position - kin[w[0].0].position).norm()).collect();
        let total: f64 = lengths.iter().sum();
        let l0 = rest_lengths[f.cable.0];
        let m = lengths.len() as f64;
        out.extend(lengths.iter().map(|l| if total > 0.0 { l0 * l / total } else { l0 / m }));
    }
    out
}

/// Tension of one chain's first segment, N: the `T_a >= 0` with
/// `sum_j n_j / (EA + r_j T_a) = total_rest` (module docs), 0 when the chain is slack (its
/// material reaches its length `total_length`, or only a pushing damper would hold it).
fn chain_tension(ea: f64, numerators: &[f64], ratio: &[f64], total_rest: f64, total_length: f64) -> f64 {
    if total_rest >= total_length {
        return 0.0;
    }
    let residual = |t: f64| -> (f64, f64) {
        let mut f = -total_rest;
        let mut df = 0.0;
        for (n, r) in numerators.iter().zip(ratio) {
            let d = ea + r * t;
            f += n / d;
            df -= n * r / (d * d);
        }
        (f, df)
    };
    let (f0, _) = residual(0.0);
    if f0 <= 0.0 {
        return 0.0;
    }
    if ratio.iter().all(|r| *r == 1.0) {
        // one tension along the chain: `sum n / (EA + T) = S`, in closed form
        return (numerators.iter().sum::<f64>() / total_rest - ea).max(0.0);
    }
    // Newton from below, kept inside a bracket [lo, hi] with f(lo) > 0 > f(hi)
    let (mut lo, mut hi) = (0.0, f64::INFINITY);
    let mut t = 0.0;
    for _ in 0..200 {
        let (f, df) = residual(t);
        if f > 0.0 {
            lo = t;
        } else {
            hi = t;
        }
        if f.abs() <= 1e-15 * total_rest {
            return t;
        }
        let mut next = if df < 0.0 { t - f / df } else { f64::NAN };
        if !(next > lo && next < hi) {
            next = if hi.is_finite() { 0.5 * (lo + hi) } else { 2.0 * lo.max(ea * 1e-12) };
        }
        if (next - t).abs() <= 1e-15 * t.abs().max(1e-300) {
            return next;
        }
        t = next;
    }
    t
}

/// Evaluates one friction cable at the kinematics `kin`: its pulleys' wrap angles, the return
/// map from the accepted segment rest lengths `accepted` (this cable's slice of
/// `State::segment_rest_lengths`, m) at total rest length `rest_length` (m; what it gained since
/// goes into `PulleyFriction::fed_segment`), and adds `-sum_k T_k g_k` into `force`. Fills this
/// cable's entries of `work`; leaves the route geometry in `scratch`. The response's `tension`
/// is the fed segment's (what the winch pulls against); `slack` means every segment is.
#[allow(clippy::too_many_arguments)]
pub fn add_friction_cable_force(
    model: &Model,
    route: &[PointId],
    cable: &CableModel,
    friction: &PulleyFriction,
    rest_length: f64,
    accepted: &[f64],
    kin: &[PointKinematics],
    scratch: &mut CableScratch,
    work: &mut FrictionWork,
    force: &mut DVector<f64>,
) -> CableResponse {
    let m = route.len() - 1;
    let (so, po) = (friction.segment_offset, friction.pulley_offset);
    let (length, length_rate) = route_geometry(route, kin, scratch);
    for k in 0..m {
        let e = scratch.segment_direction(k + 1);
        work.lengths[so + k] = scratch.segment_lengths[k];
        work.rates[so + k] = e.dot(&(kin[route[k + 1].0].velocity - kin[route[k].0].velocity));
    }
    for i in 0..m - 1 {
        let (a, b) = (scratch.segment_direction(i + 1), scratch.segment_direction(i + 2));
        let fade = wrap_fade(work.lengths[so + i], work.lengths[so + i + 1]);
        work.wrap_angles[po + i] = fade * a.cross(&b).norm().atan2(a.dot(&b));
    }
    // the accepted material, with what the actuator wound in or out since on the fed segment
    let history = &mut work.history[..m];
    history.copy_from_slice(accepted);
    history[friction.fed_segment] += rest_length - accepted.iter().sum::<f64>();
    let (ea, c) = (cable.axial_stiffness, cable.damping);
    for (i, mu) in friction.mu.iter().enumerate() {
        work.states[po + i] = if *mu == 0.0 { PulleyState::Free } else { PulleyState::Stick };
    }
    let tolerance = 1e-13 * rest_length;
    for _ in 0..4 * m + 8 {
        solve_chains(friction, (ea, c * rest_length), work, m);
        // flows: the material that crossed pulley i into segments 0..=i
        let mut flow = 0.0;
        for i in 0..m - 1 {
            flow += work.rest_lengths[so + i] - work.history[i];
            work.flows[po + i] = flow;
        }
        let mut changed = false;
        for (i, mu) in friction.mu.iter().enumerate() {
            let (before, after) = (work.tensions[so + i], work.tensions[so + i + 1]);
            if before == 0.0 && after == 0.0 {
                continue; // a slack chain holds nothing: leave it as it is
            }
            let bound = (mu * work.wrap_angles[po + i]).exp() * (1.0 + 1e-12);
            let state = &mut work.states[po + i];
            let next = match *state {
                PulleyState::Stick if before > after * bound => PulleyState::SlipTowardStart,
                PulleyState::Stick if after > before * bound => PulleyState::SlipTowardEnd,
                PulleyState::SlipTowardStart if work.flows[po + i] < -tolerance => PulleyState::Stick,
                PulleyState::SlipTowardEnd if work.flows[po + i] > tolerance => PulleyState::Stick,
                s => s,
            };
            if next != *state {
                *state = next;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let mut energy = 0.0;
    for k in 0..m {
        let t = work.tensions[so + k];
        let (l, s) = (work.lengths[so + k], work.rest_lengths[so + k]);
        if l > s {
            energy += 0.5 * ea / s * (l - s) * (l - s);
        }
        if t != 0.0 {
            let e = scratch.segment_direction(k + 1);
            let (p0, p1) = (&kin[route[k].0], &kin[route[k + 1].0]);
            crate::assembly::add_vector(model, p1.body, &(p1.jacobian.transpose() * e), -t, force);
            crate::assembly::add_vector(model, p0.body, &(p0.jacobian.transpose() * e), t, force);
        }
    }
    for i in 0..m - 1 {
        if work.tensions[so + i] == 0.0 && work.tensions[so + i + 1] == 0.0 {
            work.states[po + i] = PulleyState::Slack;
        }
    }
    let tensions = &work.tensions[so..so + m];
    CableResponse {
        length,
        length_rate,
        rest_length,
        tension: tensions[friction.fed_segment],
        slack: tensions.iter().all(|t| *t == 0.0),
        energy,
    }
}

/// Splits the cable into chains at its sticking pulleys and solves each (module docs): fills
/// `tensions`, `rest_lengths` and `ratio` of its `m` segments. `(ea, c_l0)`: EA (N) and
/// `c L0` (N s).
fn solve_chains(friction: &PulleyFriction, (ea, c_l0): (f64, f64), work: &mut FrictionWork, m: usize) {
    let (so, po) = (friction.segment_offset, friction.pulley_offset);
    let mut a = 0;
    while a < m {
        // the chain a..=b and its ratios
        let mut b = a;
        work.ratio[so + a] = 1.0;
        while b + 1 < m && work.states[po + b].joins() {
            let factor = (-work.states[po + b].slip_sign() * friction.mu[b] * work.wrap_angles[po + b]).exp();
            work.ratio[so + b + 1] = work.ratio[so + b] * factor;
            b += 1;
        }
        let total_rest: f64 = work.history[a..=b].iter().sum();
        let total_length: f64 = work.lengths[so + a..=so + b].iter().sum();
        let rho = stretch_rate(&work.lengths[so + a..=so + b], &work.rates[so + a..=so + b]);
        for k in a..=b {
            work.numerators[k] = work.lengths[so + k] * (ea + c_l0 * rho);
        }
        let t = chain_tension(
            ea,
            &work.numerators[a..=b],
            &work.ratio[so + a..=so + b],
            total_rest,
            total_length,
        );
        for k in a..=b {
            if t > 0.0 {
                let r = work.ratio[so + k];
                work.tensions[so + k] = r * t;
                work.rest_lengths[so + k] = work.numerators[k] / (ea + r * t);
            } else {
                // slack: the material shared at uniform strain
                work.tensions[so + k] = 0.0;
                work.rest_lengths[so + k] = if total_length > 0.0 {
                    total_rest * work.lengths[so + k] / total_length
                } else {
                    total_rest / (b - a + 1) as f64
                };
            }
        }
        a = b + 1;
    }
}

/// `rho = sum ldot / sum l` of a chain's segment lengths and rates (1/s; 0 for a chain of no
/// length).
fn stretch_rate(lengths: &[f64], rates: &[f64]) -> f64 {
    let total: f64 = lengths.iter().sum();
    if total > 0.0 {
        rates.iter().sum::<f64>() / total
    } else {
        0.0
    }
}

/// Adds one friction cable's `K` and `C` (module docs) into `sink`, for the return map that
/// `add_friction_cable_force` left in `work` at the same state.
#[allow(clippy::too_many_arguments)]
pub fn add_friction_cable_tangents<S: TangentSink + ?Sized>(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    route: &[PointId],
    cable: &CableModel,
    friction: &PulleyFriction,
    rest_length: f64,
    kin: &[PointKinematics],
    scratch: &mut CableScratch,
    work: &mut FrictionWork,
    sink: &mut S,
) {
    let m = route.len() - 1;
    let (so, po) = (friction.segment_offset, friction.pulley_offset);
    if work.tensions[so..so + m].iter().all(|t| *t == 0.0) {
        return;
    }
    route_geometry(route, kin, scratch);
    let (ea, c) = (cable.axial_stiffness, cable.damping);
    let body_of = |i: usize| kin[route[i].0].body;
    // geometric terms: T_k G_k^T P_k G_k per segment, d(J_i^T f_i)/dq per point with the
    // net force direction f_i = T_(i-1) e_(i-1) - T_i e_i
    for k in 0..m {
        let t = work.tensions[so + k];
        if t != 0.0 {
            add_segment_geometric_stiffness(route, k + 1, kin, scratch, t, sink);
        }
    }
    for i in 0..=m {
        if model.bodies[body_of(i).0].kind == BodyKind::Node {
            continue;
        }
        let mut f = Vector3::zeros();
        if i > 0 {
            f += scratch.segment_direction(i) * work.tensions[so + i - 1];
        }
        if i < m {
            f -= scratch.segment_direction(i + 1) * work.tensions[so + i];
        }
        let d2 = force_jacobian_derivative(model, poses, route[i], &f);
        sink.stiffness(body_of(i), body_of(i), &d2, 1.0);
    }
    // g_k, h_k per segment and dtheta_i per pulley, at their points
    for k in 0..m {
        let e = scratch.segment_direction(k + 1);
        let (p0, p1) = (&kin[route[k].0], &kin[route[k + 1].0]);
        work.seg_grad[k] = [-(p0.jacobian.transpose() * e), p1.jacobian.transpose() * e];
        if c > 0.0 {
            let l = work.lengths[so + k];
            let dv = p1.velocity - p0.velocity;
            let w = if l > crate::forces::cable::SEGMENT_LENGTH_FLOOR {
                (dv - e * e.dot(&dv)) / l
            } else {
                Vector3::zeros()
            };
            let d0 = velocity_derivative(model, poses, v, route[k]);
            let d1 = velocity_derivative(model, poses, v, route[k + 1]);
            work.seg_rate_grad[k] = [
                -(d0.transpose() * e) - p0.jacobian.transpose() * w,
                d1.transpose() * e + p1.jacobian.transpose() * w,
            ];
        }
    }
    for i in 0..m - 1 {
        work.wrap_grad[i] = [Vector6::zeros(); 3];
        if work.states[po + i].slip_sign() == 0.0 {
            continue;
        }
        let (a, b) = (scratch.segment_direction(i + 1), scratch.segment_direction(i + 2));
        let sin = a.cross(&b).norm();
        let (la, lb) = (work.lengths[so + i], work.lengths[so + i + 1]);
        let fade = wrap_fade(la, lb);
        if fade > 0.0 && sin >= WRAP_SINE_FLOOR {
            // theta_eff = fade theta; dtheta = -(1/sin) dcos,
            // dcos = (P_a b) . (dr_(i+1) - dr_i) + (P_b a) . (dr_(i+2) - dr_(i+1))
            let pa_b = (b - a * a.dot(&b)) / la;
            let pb_a = (a - b * a.dot(&b)) / lb;
            let (q0, q1, q2) = (&kin[route[i].0], &kin[route[i + 1].0], &kin[route[i + 2].0]);
            let scale = fade / sin;
            work.wrap_grad[i] = [
                q0.jacobian.transpose() * (pa_b * scale),
                q1.jacobian.transpose() * ((pb_a - pa_b) * scale),
                q2.jacobian.transpose() * (-pb_a * scale),
            ];
        }
        if fade < 1.0 && la + lb > 0.0 {
            // + theta dfade: fade = l_min / (WRAP_FADE S), S = l_a + l_b
            let theta = sin.atan2(a.dot(&b));
            let total = la + lb;
            let common = -la.min(lb) / (WRAP_FADE * total * total);
            let own = 1.0 / (WRAP_FADE * total);
            let (ca, cb) = if la <= lb { (own + common, common) } else { (common, own + common) };
            let (ga, gb) = (work.seg_grad[i], work.seg_grad[i + 1]);
            work.wrap_grad[i][0] += ga[0] * (theta * ca);
            work.wrap_grad[i][1] += ga[1] * (theta * ca) + gb[0] * (theta * cb);
            work.wrap_grad[i][2] += gb[1] * (theta * cb);
        }
    }
    // per chain: K += U a^T - sum_i d_i mu_i T_a V_i dtheta_i^T, C += U b^T
    let mut a = 0;
    while a < m {
        let mut b = a;
        while b + 1 < m && work.states[po + b].joins() {
            b += 1;
        }
        let t_a = work.tensions[so + a];
        if t_a > 0.0 {
            add_chain_tangents(route, kin, friction, (ea, c * rest_length), (a, b), work, sink);
        }
        a = b + 1;
    }
}

/// The axial and damping terms of chain `a..=b` (module docs). `(ea, c_l0)`: EA (N) and
/// `c L0` (N s).
#[allow(clippy::too_many_arguments)]
fn add_chain_tangents<S: TangentSink + ?Sized>(
    route: &[PointId],
    kin: &[PointKinematics],
    friction: &PulleyFriction,
    (ea, c_l0): (f64, f64),
    (a, b): (usize, usize),
    work: &mut FrictionWork,
    sink: &mut S,
) {
    let (so, po) = (friction.segment_offset, friction.pulley_offset);
    let t_a = work.tensions[so + a];
    let denominator = |j: usize| ea + work.ratio[so + j] * t_a;
    let w_total: f64 = (a..=b).map(|j| work.rest_lengths[so + j] * work.ratio[so + j] / denominator(j)).sum();
    let chain_length: f64 = work.lengths[so + a..=so + b].iter().sum();
    let rho = stretch_rate(&work.lengths[so + a..=so + b], &work.rates[so + a..=so + b]);
    let lambda_d: f64 = (a..=b).map(|j| work.lengths[so + j] / denominator(j)).sum();
    // c L0 Lambda_D / (L_ch W): the weight of drho's terms
    let rate_weight = if chain_length > 0.0 { c_l0 * lambda_d / (chain_length * w_total) } else { 0.0 };
    let n = route.len();
    let (left, right, right_rate) = (&mut work.left[..n], &mut work.right[..n], &mut work.right_rate[..n]);
    left.fill(Vector6::zeros());
    right.fill(Vector6::zeros());
    right_rate.fill(Vector6::zeros());
    // U = sum_k r_k g_k;
    // a = (1/W) [sum_j (EA + c L0 rho) g_j / D_j + (c L0 Lambda_D / L_ch) sum_j (h_j - rho g_j)
    //            + T_a sum_i d_i mu_i w_i dtheta_i];
    // b = (c L0 Lambda_D / (L_ch W)) sum_j g_j
    for j in a..=b {
        let (r, d) = (work.ratio[so + j], denominator(j));
        for side in 0..2 {
            let g = work.seg_grad[j][side];
            left[j + side] += g * r;
            right[j + side] += g * ((ea + c_l0 * rho) / (d * w_total));
            if c_l0 > 0.0 {
                right[j + side] += (work.seg_rate_grad[j][side] - g * rho) * rate_weight;
                right_rate[j + side] += g * rate_weight;
            }
        }
    }
    let mut w_after = 0.0; // w_i = sum_(j > i) s_j r_j / D_j, built from the chain's end
    for i in (a..b).rev() {
        let j = i + 1;
        w_after += work.rest_lengths[so + j] * work.ratio[so + j] / denominator(j);
        let sign = work.states[po + i].slip_sign();
        if sign == 0.0 {
            continue;
        }
        let scale = t_a * sign * friction.mu[i] * w_after / w_total;
        for p in 0..3 {
            right[i + p] += work.wrap_grad[i][p] * scale;
        }
    }
    add_outer(route, kin, left, right, 1.0, sink, false);
    if c_l0 > 0.0 {
        add_outer(route, kin, left, right_rate, 1.0, sink, true);
    }
    // -sum_i d_i mu_i T_a V_i dtheta_i^T with V_i = sum_(k > i) r_k g_k
    for i in a..b {
        let sign = work.states[po + i].slip_sign();
        if sign == 0.0 {
            continue;
        }
        let suffix = &mut work.left[..n];
        suffix.fill(Vector6::zeros());
        for k in i + 1..=b {
            for side in 0..2 {
                suffix[k + side] += work.seg_grad[k][side] * work.ratio[so + k];
            }
        }
        let wrap = &mut work.right[..n];
        wrap.fill(Vector6::zeros());
        wrap[i..i + 3].copy_from_slice(&work.wrap_grad[i]);
        add_outer(route, kin, &work.left[..n], &work.right[..n], -sign * friction.mu[i] * t_a, sink, false);
    }
}

/// `K += scale * sum_(p, q) u_p w_q^T` (or `C` when `damping`) over the route points' bodies.
fn add_outer<S: TangentSink + ?Sized>(
    route: &[PointId],
    kin: &[PointKinematics],
    u: &[Vector6<f64>],
    w: &[Vector6<f64>],
    scale: f64,
    sink: &mut S,
    damping: bool,
) {
    for (p, up) in u.iter().enumerate() {
        if *up == Vector6::zeros() {
            continue;
        }
        for (q, wq) in w.iter().enumerate() {
            if *wq == Vector6::zeros() {
                continue;
            }
            let blk = up * wq.transpose();
            let (bp, bq) = (kin[route[p].0].body, kin[route[q].0].body);
            if damping {
                sink.damping(bp, bq, &blk, scale);
            } else {
                sink.stiffness(bp, bq, &blk, scale);
            }
        }
    }
}

/// Power flows of friction cable `f` at the last evaluation (W): the actuator's power into it
/// at rest-length rate `rest_rate` (m/s), `-phi_fed L0dot` on the fed segment (module docs), and
/// the power its dampers dissipate, `sum_k (T_k - T_el,k) ldot_k`. Friction's loss is booked
/// per accepted step by `commit`.
pub fn powers(model: &Model, work: &FrictionWork, f: &PulleyFriction, rest_rate: f64) -> (f64, f64) {
    let ea = model.cables[f.cable.0].axial_stiffness;
    let m = f.mu.len() + 1;
    let mut loss = 0.0;
    let mut actuator = 0.0;
    for k in 0..m {
        let j = f.segment_offset + k;
        let (l, s) = (work.lengths[j], work.rest_lengths[j]);
        if l <= s || work.tensions[j] == 0.0 {
            continue;
        }
        let t_el = ea * (l - s) / s;
        loss += (work.tensions[j] - t_el) * work.rates[j];
        if k == f.fed_segment {
            actuator -= t_el * (l + s) / (2.0 * s) * rest_rate;
        }
    }
    (actuator, loss)
}

/// After an accepted step of duration `h` (s; 0 for a static solve): the return map of the
/// last evaluation (`work`, at the step's end) becomes the state's `segment_rest_lengths`, the
/// slip speeds are the flows over `h`, and the energy friction dissipated over the step is
/// returned, J: `sum_i (phi_i - phi_(i+1)) xi_i` (module docs).
pub fn commit(model: &Model, work: &mut FrictionWork, segment_rest_lengths: &mut [f64], h: f64) -> f64 {
    let mut loss = 0.0;
    for f in &model.pulley_friction {
        let ea = model.cables[f.cable.0].axial_stiffness;
        let phi = |k: usize| {
            let (l, s) = (work.lengths[f.segment_offset + k], work.rest_lengths[f.segment_offset + k]);
            if l > s {
                ea * (l - s) / s * (l + s) / (2.0 * s)
            } else {
                0.0
            }
        };
        for i in 0..f.mu.len() {
            let flow = work.flows[f.pulley_offset + i];
            loss += (phi(i) - phi(i + 1)) * flow;
            work.slip_speeds[f.pulley_offset + i] = if h > 0.0 { flow / h } else { 0.0 };
        }
    }
    segment_rest_lengths.copy_from_slice(&work.rest_lengths);
    loss
}
