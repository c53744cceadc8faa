//! Form finding: takes a model at its initial geometry and, per cable, a given rest length, a
//! target tension (prestress) or nothing; gives the rest lengths that make the initial geometry an
//! equilibrium.
//!
//! With `g_c = dL_c/dq`, gravity `Q_g` and joint Jacobian `Phi_q`, equilibrium is
//! `Q_g - sum_c T_c g_c - Phi_q^T lambda = 0`. Cables with a given rest length have known tensions;
//! the others (`U`) and the reactions are unknowns of the linear system `A x = b`,
//! `A = [-g_U, -Phi_q^T]`. Among its solutions we take the one closest (least squares) to the
//! targets (a prestress `T*`, or a force density `q*` meaning `T* = q* L`). The result is refused
//! when the geometry admits no equilibrium, when a target cannot be met, when a cable would have to
//! push, or when some tension is left undetermined. An elastic member (`CableModel::tension_only`
//! false) is an unknown like a cable whose force may be negative (compression, down to `-EA`).
//! Rest lengths then follow from the tension law: `L0 = EA L / (EA + T)`.
//!
//! Small systems (`n + p <= DENSE_FORM_FINDING_MAX`) are solved with a dense SVD (rank decisions
//! at `1e-10` of the largest singular value). Large ones never form a dense matrix: `A` is kept
//! column by column and each constrained least-squares problem is a sparse saddle-point system,
//! factored as faer's sparse `LDL^T` after regularization (`-eps` on the multiplier blocks, which
//! makes it quasi-definite, so any fill-reducing ordering is stable and redundant equilibrium
//! equations do not make it singular), then refined against the unregularized system. With `E`
//! selecting the target columns:
//! - `[I A^T E^T; A 0 0; E 0 0] (x, mu, nu) = (0, b, t)` gives the smallest solution that meets
//!   equilibrium and every target exactly (when they are compatible);
//! - the same matrix with right-hand side `(c, 0, 0)` gives `d = P c`, the projection of a fixed
//!   pseudo-random `c` on the null space of `[A; E]`: a tension is undetermined exactly when some
//!   null direction moves it, which shows as `d_j != 0` (generically in `c`);
//! - when the first solve misses equilibrium or a target, `[W A^T; A 0] (x, mu) = (W t, b)` with
//!   `W = 1` on targets and 0 elsewhere (factored with `1e-3` in place of the zeros) gives the
//!   equilibrium nearest to the targets, whose residual and target misfit the error reports.
//!
//! Cost: one symbolic and numeric sparse `LDL^T` of size `p + n + targets`, whose fill grows
//! linearly with the structure for the bundled families (prisms of 100 and 999 struts in
//! `tests/formfind.rs`; `check` on the 999-strut clustered prism takes about 0.05 s, form finding
//! and the joints' rank test together, docs/scene-format.md).

use nalgebra::{DMatrix, DVector};

use crate::evaluate::{evaluate_forces, Workspace};
use crate::forces::cable::{length_gradient_entries, route_geometry, tension, CableScratch, DISENGAGED};
use crate::model::{CableId, Model};
use crate::solve::linear::{SparseLdlt, ThinSvd};
use crate::state::State;

/// How a cable's rest length is specified in the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RestLengthSpec {
    /// Given rest length, m.
    Given(f64),
    /// Target tension at the initial geometry, N.
    Prestress(f64),
    /// Target force density `T / L` at the initial geometry, N/m.
    ForceDensity(f64),
    /// To be determined by equilibrium.
    Free,
    /// The initial length: unstressed at the initial geometry (a member's default).
    Unstressed,
}

/// Which linear algebra form finding uses (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FormFindingMethod {
    /// Dense SVD up to `DENSE_FORM_FINDING_MAX`, sparse above.
    #[default]
    Auto,
    /// Dense SVD whatever the size (cubic cost).
    Dense,
    /// Sparse regularized saddle-point solves whatever the size.
    Sparse,
}

/// Largest `n + p` (coordinates plus unknown tensions and reactions) that
/// `FormFindingMethod::Auto` solves with the dense SVD.
pub const DENSE_FORM_FINDING_MAX: usize = 400;

/// A form-finding refusal: what to blame and why.
pub type FormFindingError = (Blame, String);

/// What a form-finding refusal blames: the scene field a user changes to fix it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Blame {
    /// The geometry as a whole (no single element).
    Geometry,
    /// No tensions hold the sketched geometry in equilibrium: the targets (prestress, force
    /// density) asked for tensions it cannot have.
    Equilibrium,
    /// A cable or member (index into `Model::cables`).
    Cable(usize),
    /// A ground (index into `Model::grounds`) and its field (`mu`, `normal`).
    Ground(usize, &'static str),
}

/// The reason `find_rest_lengths` gives for an element whose ends coincide at the initial
/// geometry (a fault of its route, not of its target).
pub const ZERO_LENGTH: &str = "zero length at the initial geometry: its ends coincide";

/// What form finding found, and what it cost.
#[derive(Debug, Clone, PartialEq)]
pub struct FormFound {
    /// Rest length of every cable, m.
    pub rest_lengths: Vec<f64>,
    /// Unknowns `p` (tensions of cables without a given rest length, then joint reactions).
    pub unknowns: usize,
    /// True when the dense SVD was used.
    pub dense: bool,
    /// Entries of the sparse `LDL^T` factor (0 on the dense path or with no unknowns).
    pub factor_entries: usize,
    /// The reaction of every contact that carries the structure at its sketched pose (a sphere
    /// within `TOUCHING_GAP` of a ground), in `Model::contact_labels` order. Empty without
    /// grounds, when no rest length was to be found, and when the cables and joints hold the
    /// structure without the ground (tried first: such a scene keeps the rest lengths it had
    /// before grounds took reactions).
    pub reactions: Vec<ContactReaction>,
    /// True when the structure stands on a ground but has no equilibrium with its weight at the
    /// sketched pose (a prestress-stable mechanism, as a prism, whose weight works along its
    /// mechanism): the rest lengths then give the cables' self-stress at the sketched pose
    /// without the weight and without the grounds, and statics settles the structure onto its
    /// contacts, which carry the weight, a little way from the sketch. `reactions` is empty.
    pub settles_under_weight: bool,
}

/// What one ground contact carries in a form-found equilibrium.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactReaction {
    /// The contact pair (`Model::contact_labels`).
    pub pair: usize,
    /// Normal force, N (>= 0 in an accepted result).
    pub normal: f64,
    /// Magnitude of the tangential (friction) force, N: zero on grounds without stick-slip
    /// friction, which hold nothing sideways at rest; at most `mu normal` in an accepted result.
    pub friction: f64,
}

/// Two unit tangents `[t, n x t]` of a ground with unit normal `n`.
fn ground_tangents(n: &nalgebra::Vector3<f64>) -> [nalgebra::Vector3<f64>; 2] {
    let helper = if n.x.abs() < 0.9 { nalgebra::Vector3::x() } else { nalgebra::Vector3::y() };
    let t = (helper - n * n.dot(&helper)).normalize();
    [t, n.cross(&t)]
}

/// Column `c` of the lever's part of a contact point's Jacobian: `d(R lever_b)/dq_c` for the
/// world-fixed lever `lever` (the sphere's lowest point from its centre), `R ((B_r e_c) x b)`,
/// `b = R^T lever`: the lowest point's velocity is the centre's plus `omega x lever`.
fn lever_column(
    model: &Model,
    poses: &[crate::model::Pose],
    p: &crate::kinematics::PointKinematics,
    lever: &nalgebra::Vector3<f64>,
    c: usize,
) -> nalgebra::Vector3<f64> {
    let body = &model.bodies[p.body.0];
    let b_r = body.basis.column(c).fixed_rows::<3>(3).into_owned();
    let rot = poses[p.body.0].rotation;
    let local = rot.inverse() * lever;
    rot * b_r.cross(&local)
}

/// Rest lengths (m) for every cable, or `(cable index if one is to blame, reason)`.
pub fn find_rest_lengths(model: &Model, specs: &[RestLengthSpec]) -> Result<Vec<f64>, FormFindingError> {
    find_rest_lengths_with(model, specs, FormFindingMethod::Auto).map(|f| f.rest_lengths)
}

/// `find_rest_lengths` with a chosen method. `specs` has one entry per cable.
pub fn find_rest_lengths_with(
    model: &Model,
    specs: &[RestLengthSpec],
    method: FormFindingMethod,
) -> Result<FormFound, FormFindingError> {
    let mut state = State::initial(model);
    state.rest_lengths.iter_mut().for_each(|l| *l = DISENGAGED);
    let mut ws = Workspace::for_forces(model);
    evaluate_forces(model, &state, &mut ws);
    let lengths: Vec<f64> = ws.cables.iter().map(|c| c.length).collect();
    for (c, l) in lengths.iter().enumerate() {
        if *l <= 1e-12 {
            return Err((Blame::Cable(c), ZERO_LENGTH.into()));
        }
    }
    let resolved: Vec<RestLengthSpec> = specs
        .iter()
        .zip(&lengths)
        .map(|(s, l)| if *s == RestLengthSpec::Unstressed { RestLengthSpec::Given(*l) } else { *s })
        .collect();
    let specs = &resolved[..];
    let unknown: Vec<usize> =
        (0..specs.len()).filter(|&c| !matches!(specs[c], RestLengthSpec::Given(_))).collect();
    if unknown.is_empty() {
        let rest_lengths = specs
            .iter()
            .map(|s| if let RestLengthSpec::Given(l) = s { *l } else { unreachable!() })
            .collect();
        return Ok(FormFound {
            rest_lengths,
            unknowns: 0,
            dense: true,
            factor_entries: 0,
            reactions: Vec::new(),
            settles_under_weight: false,
        });
    }

    let contacts = touching_contacts(model, &state, &ws, &lengths);
    let grounded = !contacts.is_empty() && model.gravity.norm() > 0.0;
    if !contacts.is_empty() {
        // a structure that its cables and joints hold without the ground's help keeps the
        // rest lengths it had before grounds took reactions (all of them zero)
        let (none, poses) = (Vec::new(), &state.poses[..]);
        let sys = EquilibriumSystem::assemble(
            model,
            specs,
            &ws.force,
            &ws,
            &lengths,
            unknown.clone(),
            (none, poses),
        );
        if let Ok(found) = solve_system(model, specs, &sys, &lengths, method) {
            return Ok(found);
        }
    }
    let sys = EquilibriumSystem::assemble(
        model,
        specs,
        &ws.force,
        &ws,
        &lengths,
        unknown.clone(),
        (contacts, &state.poses),
    );
    let exact = solve_system(model, specs, &sys, &lengths, method);
    if !grounded || !matches!(exact, Err((Blame::Equilibrium, _))) {
        return exact;
    }
    // a prestress-stable structure standing on a ground (a prism: its twist mechanism moves its
    // weight) has no equilibrium with its weight at the sketched pose: the cables' self-stress is
    // found without the weight and without the ground, and statics then settles the structure
    // onto its contacts, which carry the weight (`FormFound::settles_under_weight`)
    let mut weightless = model.clone();
    weightless.gravity = nalgebra::Vector3::zeros();
    weightless.grounds.clear();
    let mut free = Workspace::for_forces(&weightless);
    evaluate_forces(&weightless, &state, &mut free);
    let sys = EquilibriumSystem::assemble(
        &weightless,
        specs,
        &free.force,
        &free,
        &lengths,
        unknown,
        (Vec::new(), &state.poses),
    );
    match solve_system(&weightless, specs, &sys, &lengths, method) {
        Ok(found) => Ok(FormFound { settles_under_weight: true, ..found }),
        Err(_) => exact,
    }
}

/// Solves `sys` (the module docs) and turns its tensions into rest lengths, refusing targets it
/// misses, cables that would push, members beyond their EA and reactions outside the grounds'
/// cones.
fn solve_system(
    model: &Model,
    specs: &[RestLengthSpec],
    sys: &EquilibriumSystem,
    lengths: &[f64],
    method: FormFindingMethod,
) -> Result<FormFound, FormFindingError> {
    let dense = match method {
        FormFindingMethod::Auto => sys.n + sys.columns.len() <= DENSE_FORM_FINDING_MAX,
        FormFindingMethod::Dense => true,
        FormFindingMethod::Sparse => false,
    };
    let (x, factor_entries) = if dense { (solve_dense(model, sys)?, 0) } else { solve_sparse(model, sys)? };

    for (col, t) in &sys.targets {
        if (x[*col] - t).abs() > 1e-6 * sys.scale {
            return Err((Blame::Cable(sys.unknown[*col]), format!("prestress target {t} N is not compatible with equilibrium at this geometry (nearest equilibrium has {:.6} N){}", x[*col], sys.sideways_hint)));
        }
    }
    sys.check_reactions(model, &x)?;
    let mut out = vec![0.0; specs.len()];
    for (c, spec) in specs.iter().enumerate() {
        if let RestLengthSpec::Given(l) = spec {
            out[c] = *l;
        }
    }
    for (col, &c) in sys.unknown.iter().enumerate() {
        let t = x[col];
        let ea = model.cables[c].axial_stiffness;
        if !model.cables[c].tension_only {
            // a member: any force whose rest length stays positive and finite
            if ea + t <= 0.0 || t.is_nan() {
                return Err((
                    Blame::Cable(c),
                    format!("equilibrium needs a compression of {:.6} N in this member, at least its EA {ea} N: no rest length gives it", -t),
                ));
            }
            out[c] = ea * lengths[c] / (ea + t);
            continue;
        }
        if t < -1e-9 * sys.scale {
            return Err((
                Blame::Cable(c),
                format!("equilibrium needs this cable to push (T = {t:.6} N); a cable can only pull"),
            ));
        }
        out[c] = ea * lengths[c] / (ea + t.max(0.0));
    }
    let reactions = sys.reactions_of(&x);
    Ok(FormFound {
        rest_lengths: out,
        unknowns: sys.columns.len(),
        dense,
        factor_entries,
        reactions,
        settles_under_weight: false,
    })
}

/// The contacts that carry a structure at its sketched pose: every sphere whose surface lies
/// within `TOUCHING_GAP` of the largest cable length from a ground (or presses into it), as
/// `(contact pair k, its generalized force at the sketched pose)`. Form finding takes their normal
/// reactions as unknowns in place of those forces.
fn touching_contacts(
    model: &Model,
    state: &State,
    ws: &Workspace,
    lengths: &[f64],
) -> Vec<(usize, DVector<f64>)> {
    let reach = lengths.iter().copied().fold(1e-3, f64::max);
    let mut out = Vec::new();
    for (k, sphere, ground) in model.contact_pair_list() {
        if ws.contacts[k].gap > TOUCHING_GAP * reach {
            continue;
        }
        let mut force = DVector::zeros(model.dof_count);
        let kin = &ws.points[sphere.point.0];
        let anchor = state.contact_anchors.get(k);
        let (poses, v) = (&state.poses, &state.velocities);
        crate::forces::contact::add_contact_force(model, poses, v, ground, sphere, kin, anchor, &mut force);
        out.push((k, force));
    }
    out
}

/// A contact sphere whose surface lies within this fraction of the structure's largest cable
/// length from a ground touches it, for form finding (`touching_contacts`).
pub const TOUCHING_GAP: f64 = 1e-6;

/// The equilibrium equations `A x = b` of form finding, `A` (n x p) kept column by column:
/// columns `0..nu` are `-g_c` of the cables without a given rest length, then `-Phi_q^T` of the
/// joints, then `J_k^T n_k` of each touching contact (`touching_contacts`: the generalized force
/// of a unit normal reaction through the sphere's centre, `N_k >= 0`).
struct EquilibriumSystem {
    /// Rows: generalized coordinates.
    n: usize,
    /// `(row, value)` per column, rows sorted and unique.
    columns: Vec<Vec<(usize, f64)>>,
    /// Right-hand side: `-Q_g` plus the forces of cables with given rest lengths, N.
    b: DVector<f64>,
    /// The cable of each of the first `nu` columns.
    unknown: Vec<usize>,
    /// `(column, target tension N)`.
    targets: Vec<(usize, f64)>,
    /// Force scale for the tolerances, N.
    scale: f64,
    /// `; a ground without stick_stiffness ...` when a touching contact's ground has friction
    /// that holds nothing at rest (the regularized law), else empty: the refusals' hint.
    sideways_hint: &'static str,
    /// The contact pair of each reaction column (the last `reactions.len()` columns) and its
    /// direction: 0 the ground's normal, 1 and 2 its tangents (`ground_tangents`).
    reactions: Vec<(usize, usize)>,
}

impl EquilibriumSystem {
    /// `known`: the generalized force at the sketched pose of everything but the unknowns (the
    /// forces of the cables with given rest lengths are added here), N.
    fn assemble(
        model: &Model,
        specs: &[RestLengthSpec],
        known: &DVector<f64>,
        ws: &Workspace,
        lengths: &[f64],
        unknown: Vec<usize>,
        (contacts, poses): (Vec<(usize, DVector<f64>)>, &[crate::model::Pose]),
    ) -> Self {
        let n = model.dof_count;
        let max_route = model.cables.iter().map(|c| c.route_len).max().unwrap_or(2);
        let mut scratch = CableScratch::new(max_route);
        let mut b = -known;
        // the touching contacts' forces at the sketched pose are replaced by their reactions
        for (_, force) in &contacts {
            b += force;
        }
        let mut columns = Vec::with_capacity(unknown.len() + model.constraint_count);
        let mut entries = Vec::new();
        for (c, spec) in specs.iter().enumerate() {
            let route = model.route(CableId(c));
            route_geometry(route, &ws.points, &mut scratch);
            entries.clear();
            length_gradient_entries(model, route, &ws.points, &scratch, &mut entries);
            if let RestLengthSpec::Given(l0) = spec {
                let cable = &model.cables[c];
                let t = tension(cable, *l0, lengths[c], 0.0);
                for &(r, g) in &entries {
                    b[r] += t * g;
                }
            } else {
                columns.push(merged(entries.iter().map(|&(r, g)| (r, -g))));
            }
        }
        for joint in &model.joints {
            for r in 0..joint.rows {
                let column = crate::constraints::joint_points(joint).flat_map(|(pid, sign)| {
                    let p = &ws.points[pid.0];
                    let body = &model.bodies[p.body.0];
                    let jacobian = crate::constraints::side_jacobian(model, &ws.poses, joint, p);
                    (0..body.dof_count).map(move |k| (body.dof_offset + k, -sign * jacobian[(r, k)]))
                });
                columns.push(merged(column));
            }
        }
        let pairs: Vec<_> = model.contact_pair_list().collect();
        let mut reactions = Vec::new();
        let sideways_hint = if contacts.iter().any(|(k, _)| {
            let m = &pairs[*k].2.material;
            m.friction > 0.0 && m.stick.is_none()
        }) {
            "; the ground it stands on holds nothing sideways at rest (its friction is regularized): give the ground stick_stiffness"
        } else {
            ""
        };
        for (k, _) in &contacts {
            let (_, sphere, ground) = pairs[*k];
            let p = &ws.points[sphere.point.0];
            let body = &model.bodies[p.body.0];
            let [tangent, binormal] = ground_tangents(&ground.normal);
            // the normal reaction through the centre; where the ground's friction holds at rest
            // (stick-slip), two tangential ones at the lowest point (the sphere's lever)
            let holds = ground.material.friction > 0.0 && ground.material.stick.is_some();
            let directions = if holds { 3 } else { 1 };
            for (d, direction) in [ground.normal, tangent, binormal].iter().enumerate().take(directions) {
                let lever = -ground.normal * sphere.radius;
                let column = (0..body.dof_count).map(|c| {
                    let mut along = p.jacobian.column(c).into_owned();
                    if d > 0 {
                        along += lever_column(model, poses, p, &lever, c);
                    }
                    (body.dof_offset + c, direction.dot(&along))
                });
                columns.push(merged(column));
                reactions.push((*k, d));
            }
        }
        let targets: Vec<(usize, f64)> = unknown
            .iter()
            .enumerate()
            .filter_map(|(col, &c)| match specs[c] {
                RestLengthSpec::Prestress(t) => Some((col, t)),
                RestLengthSpec::ForceDensity(q) => Some((col, q * lengths[c])),
                _ => None,
            })
            .collect();
        let scale = targets.iter().map(|t| t.1.abs()).fold(b.amax(), f64::max).max(1e-12);
        Self { n, columns, b, unknown, targets, scale, sideways_hint, reactions }
    }

    /// Refuses `x` when it needs a ground to pull (a normal reaction below zero) or more
    /// friction than the cone holds (`|F_t| > mu N`).
    fn check_reactions(&self, model: &Model, x: &DVector<f64>) -> Result<(), FormFindingError> {
        let labels: Vec<(&str, &str)> = model.contact_labels().collect();
        let mu: Vec<f64> = model.contact_friction_coefficients().collect();
        for r in self.reactions_of(x) {
            let (point, ground) = labels[r.pair];
            // pair k = sphere * grounds + ground
            let g = r.pair % model.grounds.len();
            if r.normal < -1e-9 * self.scale {
                return Err((Blame::Ground(g, "normal"), format!("equilibrium at the sketched pose needs the ground `{ground}` to pull {point} down with {:.6} N; a ground only pushes: move the structure, or change its prestress", -r.normal)));
            }
            let limit = mu[r.pair] * r.normal.max(0.0);
            if r.friction > limit + 1e-9 * self.scale {
                return Err((Blame::Ground(g, "mu"), format!("equilibrium at the sketched pose needs {:.6} N of friction at {point} on `{ground}`, beyond its cone mu N = {limit:.6} N: raise the ground's mu, or move the structure", r.friction)));
            }
        }
        Ok(())
    }

    /// The reactions of the touching contacts in `x`, one per contact.
    fn reactions_of(&self, x: &DVector<f64>) -> Vec<ContactReaction> {
        let first = self.columns.len() - self.reactions.len();
        let mut out: Vec<ContactReaction> = Vec::new();
        let mut tangential = [0.0; 2];
        for (i, &(pair, direction)) in self.reactions.iter().enumerate() {
            let value = x[first + i];
            if direction == 0 {
                out.push(ContactReaction { pair, normal: value, friction: 0.0 });
                tangential = [0.0; 2];
            } else {
                tangential[direction - 1] = value;
                if let Some(last) = out.last_mut() {
                    last.friction = (tangential[0] * tangential[0] + tangential[1] * tangential[1]).sqrt();
                }
            }
        }
        out
    }

    /// `|A x - b|_inf`, N.
    fn residual(&self, x: &DVector<f64>) -> f64 {
        let mut r = -&self.b;
        for (j, column) in self.columns.iter().enumerate() {
            for &(i, a) in column {
                r[i] += a * x[j];
            }
        }
        r.amax()
    }

    /// Refuses `x` when it misses equilibrium.
    fn check_equilibrium(&self, x: &DVector<f64>) -> Result<(), FormFindingError> {
        let residual = self.residual(x);
        if residual > 1e-8 * self.scale {
            return Err((Blame::Equilibrium, format!("the initial geometry is not an equilibrium for any cable tensions (or member forces) (force residual {residual:.3e} N); move the bodies or give rest lengths{}", self.sideways_hint)));
        }
        Ok(())
    }

    /// The refusal for tensions (columns `< nu` among `open`) that equilibrium leaves free.
    fn undetermined(&self, model: &Model, open: impl Iterator<Item = usize>) -> Result<(), FormFindingError> {
        let elements: Vec<usize> =
            open.filter(|&col| col < self.unknown.len()).map(|col| self.unknown[col]).collect();
        let names: Vec<&str> = elements.iter().map(|&c| model.cable_names[c].as_str()).collect();
        if names.is_empty() {
            return Ok(());
        }
        // members (and cables that may push) take a force of either sign
        let push = elements.iter().any(|&c| !model.cables[c].tension_only);
        let listed = if names.len() > 6 {
            format!("{} and {} more", names[..5].join(", "), names.len() - 5)
        } else {
            names.join(", ")
        };
        if push {
            return Err((Blame::Geometry, format!("form finding cannot determine the forces of {listed}: give one of them a rest_length, or a force ([[members]]) or prestress ([[cables]])")));
        }
        Err((Blame::Geometry, format!("form finding cannot determine the tensions of cables {listed}: give one of them a prestress or a rest_length")))
    }
}

/// Sums repeated rows and sorts them.
fn merged(entries: impl Iterator<Item = (usize, f64)>) -> Vec<(usize, f64)> {
    let mut v: Vec<(usize, f64)> = entries.collect();
    v.sort_unstable_by_key(|e| e.0);
    let mut out: Vec<(usize, f64)> = Vec::with_capacity(v.len());
    for (r, a) in v {
        match out.last_mut() {
            Some(last) if last.0 == r => last.1 += a,
            _ => out.push((r, a)),
        }
    }
    out.retain(|e| e.1 != 0.0);
    out
}

/// The dense SVD path: minimum-norm solution, then the targets fitted in the null space.
fn solve_dense(model: &Model, sys: &EquilibriumSystem) -> Result<DVector<f64>, FormFindingError> {
    let (n, p) = (sys.n, sys.columns.len());
    let rows = n.max(p);
    let mut a = DMatrix::zeros(rows, p);
    for (j, column) in sys.columns.iter().enumerate() {
        for &(i, v) in column {
            a[(i, j)] = v;
        }
    }
    let mut b = DVector::zeros(rows);
    b.rows_mut(0, n).copy_from(&sys.b);

    let failed = || {
        (
            Blame::Geometry,
            "form finding failed: the singular value decomposition did not converge".to_string(),
        )
    };
    let svd = ThinSvd::new(&a).ok_or_else(failed)?;
    let tol = 1e-10 * svd.s.max().max(1e-300);
    let mut x = svd.solve(&b, tol);
    sys.check_equilibrium(&x)?;
    let null: Vec<DVector<f64>> =
        (0..p).filter(|&i| svd.s[i] <= tol).map(|i| svd.v.column(i).into_owned()).collect();
    if null.is_empty() {
        return Ok(x);
    }
    let nb = DMatrix::from_columns(&null);
    let mut sn = DMatrix::zeros(sys.targets.len().max(null.len()), null.len());
    let mut rhs = DVector::zeros(sn.nrows());
    for (r, (col, t)) in sys.targets.iter().enumerate() {
        sn.row_mut(r).copy_from(&nb.row(*col));
        rhs[r] = t - x[*col];
    }
    let svd2 = ThinSvd::new(&sn).ok_or_else(failed)?;
    let tol2 = 1e-10 * svd2.s.max().max(1.0);
    x += &nb * svd2.solve(&rhs, tol2);
    // directions that the targets leave open must not change any tension
    let mut open = vec![false; p];
    for i in 0..null.len() {
        if svd2.s[i] > tol2 {
            continue;
        }
        let dir = &nb * svd2.v.column(i);
        (0..p).filter(|&col| dir[col].abs() > 1e-8).for_each(|col| open[col] = true);
    }
    sys.undetermined(model, (0..p).filter(|&col| open[col]))?;
    Ok(x)
}

/// Regularization of the multiplier blocks of the exact-target system, relative to the largest
/// entry of `A` (the ratio to its unit weights bounds the growth in the `LDL^T`).
const KKT_REGULARIZATION: f64 = 1e-12;
/// The nearest-equilibrium fit: weight of the columns without a target in the factored matrix
/// (the fit itself gives them none; refinement removes the bias) ...
const UNTARGETED_WEIGHT: f64 = 1e-3;
/// ... and its multiplier regularization, both relative to the largest entry of `A`.
const FIT_REGULARIZATION: f64 = 1e-9;
/// Refinement steps against the unregularized systems (each stops early at round-off, or once a
/// step no longer shrinks the residual by a tenth: what is left then lies along redundant
/// equations, which do not move `x`).
const EXACT_REFINEMENT_STEPS: usize = 12;
const FIT_REFINEMENT_STEPS: usize = 400;
/// `|d_j|` above which a tension is moved by a null direction (`c_j` has magnitude 0.5..1.5).
const OPEN_DIRECTION_TOLERANCE: f64 = 1e-6;

/// The saddle-point matrix `K0 = [W A^T E^T; A 0 0; E 0 0]` (no `E` rows unless `hard_targets`),
/// with the factors of `K0 + diag(R, -eps, -eps)` that precondition its refinement.
struct SaddlePoint<'a> {
    sys: &'a EquilibriumSystem,
    weights: Vec<f64>,
    hard_targets: bool,
    max_steps: usize,
    lu: SparseLdlt,
}

impl<'a> SaddlePoint<'a> {
    fn size(sys: &EquilibriumSystem, hard_targets: bool) -> usize {
        sys.columns.len() + sys.n + if hard_targets { sys.targets.len() } else { 0 }
    }

    /// `weights` is `W`, `extra` is `R` (both per column of `A`, `W + R > 0`).
    fn factor(
        sys: &'a EquilibriumSystem,
        weights: Vec<f64>,
        extra: &[f64],
        hard_targets: bool,
        eps: f64,
        max_steps: usize,
    ) -> Result<Self, FormFindingError> {
        let (n, p) = (sys.n, sys.columns.len());
        let size = Self::size(sys, hard_targets);
        let mut upper = Vec::new();
        for (j, column) in sys.columns.iter().enumerate() {
            upper.push((j, j, weights[j] + extra[j]));
            upper.extend(column.iter().map(|&(i, a)| (j, p + i, a)));
        }
        upper.extend((p..size).map(|i| (i, i, -eps)));
        if hard_targets {
            upper.extend(sys.targets.iter().enumerate().map(|(k, &(j, _))| (j, p + n + k, 1.0)));
        }
        let signs: Vec<i8> = (0..size).map(|i| if i < p { 1 } else { -1 }).collect();
        let lu = SparseLdlt::factor(size, &upper, &signs, eps)
            .map_err(|e| (Blame::Geometry, format!("form finding failed: {e}")))?;
        Ok(Self { sys, weights, hard_targets, max_steps, lu })
    }
    /// The unregularized product `K0 z`.
    fn apply(&self, z: &[f64], out: &mut [f64]) {
        let (n, p) = (self.sys.n, self.sys.columns.len());
        out.fill(0.0);
        for (j, column) in self.sys.columns.iter().enumerate() {
            out[j] += self.weights[j] * z[j];
            for &(i, a) in column {
                out[j] += a * z[p + i];
                out[p + i] += a * z[j];
            }
        }
        if self.hard_targets {
            for (k, &(j, _)) in self.sys.targets.iter().enumerate() {
                out[j] += z[p + n + k];
                out[p + n + k] += z[j];
            }
        }
    }

    /// Solves `K0 z = rhs` through the regularized factors with iterative refinement; returns
    /// the `x` part.
    fn solve(&mut self, rhs: &[f64]) -> DVector<f64> {
        let size = rhs.len();
        let mut z = rhs.to_vec();
        self.lu.solve_in_place(&mut z);
        let mut r = vec![0.0; size];
        let floor = 1e-15 * rhs.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
        let mut previous = f64::INFINITY;
        for _ in 0..self.max_steps {
            self.apply(&z, &mut r);
            let mut worst = 0.0f64;
            for (ri, bi) in r.iter_mut().zip(rhs) {
                *ri = bi - *ri;
                worst = worst.max(ri.abs());
            }
            if worst <= floor || worst > 0.9 * previous {
                break;
            }
            previous = worst;
            self.lu.solve_in_place(&mut r);
            z.iter_mut().zip(&r).for_each(|(zi, di)| *zi += di);
        }
        DVector::from_column_slice(&z[..self.sys.columns.len()])
    }
}

/// The sparse path (module documentation): exact targets, determinacy, nearest equilibrium.
/// Returns the solution and the entries of the (first) factor.
fn solve_sparse(model: &Model, sys: &EquilibriumSystem) -> Result<(DVector<f64>, usize), FormFindingError> {
    let (n, p) = (sys.n, sys.columns.len());
    let a_max = sys.columns.iter().flatten().fold(0.0f64, |m, e| m.max(e.1.abs())).max(1e-300);
    let eps = KKT_REGULARIZATION * a_max;
    let mut hard =
        SaddlePoint::factor(sys, vec![a_max; p], &vec![0.0; p], true, eps, EXACT_REFINEMENT_STEPS)?;
    let size = SaddlePoint::size(sys, true);

    let mut rhs = vec![0.0; size];
    rhs[p..p + n].copy_from_slice(sys.b.as_slice());
    for (k, &(_, t)) in sys.targets.iter().enumerate() {
        rhs[p + n + k] = t;
    }
    let mut x = hard.solve(&rhs);
    let meets = |x: &DVector<f64>| {
        sys.residual(x) <= 1e-8 * sys.scale
            && sys.targets.iter().all(|&(j, t)| (x[j] - t).abs() <= 1e-6 * sys.scale)
    };
    if !meets(&x) {
        let mut targeted = vec![false; p];
        sys.targets.iter().for_each(|&(j, _)| targeted[j] = true);
        let weights: Vec<f64> = targeted.iter().map(|&t| if t { a_max } else { 0.0 }).collect();
        let extra: Vec<f64> =
            targeted.iter().map(|&t| if t { 0.0 } else { UNTARGETED_WEIGHT * a_max }).collect();
        let mut soft = SaddlePoint::factor(
            sys,
            weights.clone(),
            &extra,
            false,
            FIT_REGULARIZATION * a_max,
            FIT_REFINEMENT_STEPS,
        )?;
        let mut rhs = vec![0.0; SaddlePoint::size(sys, false)];
        for &(j, t) in &sys.targets {
            rhs[j] = weights[j] * t;
        }
        rhs[p..p + n].copy_from_slice(sys.b.as_slice());
        x = soft.solve(&rhs);
    }
    sys.check_equilibrium(&x)?;

    // determinacy: d = P c on the null space of [A; E]
    let mut rhs = vec![0.0; size];
    let mut seed: u64 = 0x9e37_79b9_7f4a_7c15;
    for v in rhs.iter_mut().take(p) {
        seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        let u = (seed >> 11) as f64 / (1u64 << 53) as f64;
        *v = if (seed >> 40) & 1 == 0 { 0.5 + u } else { -0.5 - u } * a_max;
    }
    let d = hard.solve(&rhs);
    sys.undetermined(model, (0..p).filter(|&j| d[j].abs() > OPEN_DIRECTION_TOLERANCE))?;
    Ok((x, hard.lu.factor_entries()))
}
