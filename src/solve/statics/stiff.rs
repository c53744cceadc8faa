//! Stiff cables in the mixed form: takes a model, gives which cables have their tensions as
//! unknowns (`stiff_sets`), the tension unknowns' state (`StiffCables`), the mixed residual, and
//! the least-squares tensions and projections the mixed Newton iteration starts from.

use nalgebra::DVector;

use crate::evaluate::{evaluate, Tangents, Workspace};
use crate::model::Model;
use crate::solve::statics::kkt::{fit_multipliers, SPARSE_STATICS_MIN};
use crate::state::State;

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
pub(crate) fn stiff_sets(model: &Model, ws: &mut Workspace, size: f64) -> (Vec<usize>, Vec<usize>) {
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
            // the mixed form is dense: from SPARSE_STATICS_MIN coordinates the displacement form
            // on the sparse KKT system solves it (its cost grows with the structure, not its cube)
            let kind =
                if cable.tension_only { !prestressed && small } else { members && mixed_member(cable) };
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

/// A stiff cable's tension after a step `dt` from `t` (N): at least `TENSION_FLOOR` of `t`, so
/// that one step from a badly strained start (where the linearized balance asks for a tension
/// far below zero) cannot drop a prestress whole; a cable goes slack only when it is shorter than
/// its rest length (`equilibrate_mixed`'s active set).
pub(crate) fn next_tension(t: f64, dt: f64) -> f64 {
    (t + dt).max(TENSION_FLOOR * t).max(0.0)
}

/// The least fraction of its tension a stiff cable keeps over one Newton step (`next_tension`).
pub(crate) const TENSION_FLOOR: f64 = 0.1;

/// The stiff cables of a mixed iteration: their tensions as unknowns and what the current
/// iterate's evaluation found for them.
pub(crate) struct StiffCables {
    /// Model cable indices.
    pub(crate) ids: Vec<usize>,
    /// Tension unknowns `T`, N (0 while inactive).
    pub(crate) tension: Vec<f64>,
    /// Compliances `c = L0 / EA`, m/N.
    pub(crate) compliance: Vec<f64>,
    /// True for a member: its force takes either sign and it never goes slack (always active).
    pub(crate) push: Vec<bool>,
    /// True while a cable is taut in the iteration (its length equation is imposed).
    pub(crate) active: Vec<bool>,
    /// Lengths `L` at the last evaluation, m.
    pub(crate) length: Vec<f64>,
    /// Length gradients `g = dL/dq` at the last evaluation.
    pub(crate) gradient: Vec<DVector<f64>>,
}

impl StiffCables {
    /// The length equation's residual of stiff cable `i`, m: `L - L0 - c T` while active,
    /// else the stretch of a cable that carries no tension (`max(0, L - L0)`).
    pub(crate) fn length_residual(&self, i: usize, rest_length: f64) -> f64 {
        if self.active[i] {
            self.length[i] - rest_length - self.compliance[i] * self.tension[i]
        } else {
            (self.length[i] - rest_length).max(0.0)
        }
    }
    /// Element `i`'s force after a step `dt` from `t` (N): a cable's by `next_tension` (kept
    /// above a floor, never below zero), a member's `t + dt` of either sign.
    pub(crate) fn next_tension(&self, i: usize, t: f64, dt: f64) -> f64 {
        if self.push[i] {
            t + dt
        } else {
            next_tension(t, dt)
        }
    }
    pub(crate) fn active_ids(&self) -> Vec<usize> {
        (0..self.ids.len()).filter(|&i| self.active[i]).collect()
    }
}

/// What a mixed evaluation's residual measures (see `StaticSolver::mixed_residual`).
pub(crate) struct MixedResidual {
    /// `|Q - sum T g - Phi_q^T lambda|_inf`, N.
    pub(crate) force: f64,
    /// `|Phi|_inf`, m.
    pub(crate) constraint: f64,
    /// Largest length residual of the stiff cables, m.
    pub(crate) cable: f64,
}

impl MixedResidual {
    pub(crate) fn merit(&self, f_scale: f64, l_scale: f64) -> f64 {
        (self.force / f_scale).powi(2) + (self.constraint / l_scale).powi(2) + (self.cable / l_scale).powi(2)
    }
}
