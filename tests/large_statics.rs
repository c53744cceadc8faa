//! Statics on the sparse KKT system (`StaticSolver` from `SPARSE_STATICS_MIN` coordinates): the
//! same equilibria, stability verdicts and smallest eigenvalues as the dense path on structures
//! small enough for both (stable, unstable, with rigid-body modes, clustered, with gravity), the
//! sparse path chosen by size, and large structures solved from disturbed starts without any
//! dense `n x n` or `nc x n` matrix in the workspace.

mod common;

use common::{free_prism, model_from_toml, model_of};
use nalgebra::DVector;
use tensegrity::evaluate::{evaluate_forces, Workspace};
use tensegrity::scene::generate::{prism, tower, PrismParams, TowerParams};
use tensegrity::solve::statics::{EquilibriumReport, StaticSolver, SPARSE_STATICS_MIN};
use tensegrity::state::retract;
use tensegrity::{Model, State};

/// `state` moved by a deterministic pattern: translations up to `h` m, rotations up to `h` rad.
fn disturbed(model: &Model, state: &State, h: f64) -> State {
    let mut s = state.clone();
    let dq = DVector::from_iterator(
        model.dof_count,
        (0..model.dof_count).map(|i| h * ((i as f64 * 0.754_877_666).fract() - 0.5)),
    );
    retract(model, &mut s.poses, &dq, 1.0);
    s.multipliers.fill(0.0);
    s
}

fn solve(model: &Model, start: &State, sparse: bool) -> (State, EquilibriumReport, StaticSolver, Workspace) {
    let mut solver = StaticSolver::new(model).with_sparse_kkt(model, sparse);
    let mut state = start.clone();
    let mut ws = Workspace::for_forces(model);
    let report = solver
        .equilibrate(model, &mut state, &mut ws, &model.solver)
        .unwrap_or_else(|e| panic!("{} (sparse {sparse}): no equilibrium: {e:?}", model.name));
    (state, report, solver, ws)
}

/// Largest distance between the same point of `model` in two states, m (a bar's spin about its
/// own axis is no coordinate, so poses are compared through their points).
fn largest_point_difference(model: &Model, a: &State, b: &State) -> f64 {
    let (mut wa, mut wb) = (Workspace::for_forces(model), Workspace::for_forces(model));
    evaluate_forces(model, a, &mut wa);
    evaluate_forces(model, b, &mut wb);
    wa.points.iter().zip(&wb.points).map(|(p, q)| (p.position - q.position).norm()).fold(0.0, f64::max)
}

/// Both paths from the same start: the same equilibrium and the same verdict.
fn agree(model: &Model, start: &State) -> (EquilibriumReport, EquilibriumReport) {
    let (dense_state, dense, _, _) = solve(model, start, false);
    let (sparse_state, sparse, solver, _) = solve(model, start, true);
    let name = &model.name;
    assert!(solver.is_sparse(), "{name}: the sparse path was not taken");
    let moved = largest_point_difference(model, &dense_state, &sparse_state);
    assert!(moved <= 1e-8, "{name}: equilibria differ by {moved:e}\n{dense:?}\n{sparse:?}");
    assert_eq!(
        (dense.negative_modes, dense.zero_modes, dense.rigid_modes, dense.stable),
        (sparse.negative_modes, sparse.zero_modes, sparse.rigid_modes, sparse.stable),
        "{name}: dense {dense:?}, sparse {sparse:?}"
    );
    let (a, b) = (dense.min_stiffness_eigenvalue, sparse.min_stiffness_eigenvalue);
    if dense.zero_modes > 0 {
        // a zero mode's eigenvalue is round-off in both
        let zero = 1e-6 * dense.force_scale;
        assert!(a.abs() <= zero && b.abs() <= zero, "{name}: smallest eigenvalue {a} dense, {b} sparse");
    } else {
        assert!((a - b).abs() <= 1e-6 * a.abs(), "{name}: smallest eigenvalue {a} dense, {b} sparse");
    }
    (dense, sparse)
}

#[test]
fn sparse_and_dense_statics_agree_on_structures_small_enough_for_both() {
    let mut checked = 0;
    for (n, cluster) in [(3, false), (5, true), (12, true)] {
        let model = model_of(&prism(&PrismParams { n, cluster_top_ring: cluster, ..Default::default() }));
        let eq = State::initial(&model);
        let (_, sparse) = agree(&model, &disturbed(&model, &eq, 0.02));
        assert!(sparse.stable, "{}: {sparse:?}", model.name);
        checked += 1;
    }
    for cluster_sides in [false, true] {
        let model = model_of(&tower(&TowerParams { n: 3, stages: 3, cluster_sides, ..Default::default() }));
        let eq = State::initial(&model);
        agree(&model, &disturbed(&model, &eq, 0.01));
        checked += 1;
    }
    // held by nothing: six rigid-body modes, stable otherwise
    let model = free_prism();
    let (_, sparse) = agree(&model, &State::initial(&model));
    assert_eq!((sparse.rigid_modes, sparse.zero_modes, sparse.stable), (6, 6, true), "{sparse:?}");
    checked += 1;
    assert_eq!(checked, 6);
}

/// A bar pinned at its foot under gravity: standing up it is a maximum of the energy (two
/// negative-stiffness modes), hanging down a minimum. A tilt `theta` moves the centre of mass
/// by `L theta / 2` and costs `-+ m g L theta^2 / 4`; over the unit coordinate vector
/// `(L/2, 1) / sqrt(1 + L^2/4)` that is the eigenvalue `-+ (m g L / 2) / (1 + L^2 / 4)`.
#[test]
fn sparse_stability_tells_an_inverted_pendulum_from_a_hanging_one() {
    for (tip_z, negative) in [(1.0, 2), (-1.0, 0)] {
        let model = model_from_toml(&format!(
            r#"
name = "pendulum"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "bar"
kind = "bar"
mass = 2.0
ends = [[0.0, 0.0, 0.0], [0.0, 0.0, {tip_z}]]
[[joints]]
kind = "pin"
a = "bar.a"
"#
        ));
        let (dense, sparse) = agree(&model, &State::initial(&model));
        assert_eq!(sparse.negative_modes, negative, "{sparse:?}");
        // m = 2 kg, L = 1 m: (m g L / 2) / (1 + L^2 / 4) = 9.81 / 1.25, signed
        let expected = if negative > 0 { -9.81 / 1.25 } else { 9.81 / 1.25 };
        for r in [dense, sparse] {
            assert!((r.min_stiffness_eigenvalue - expected).abs() <= 1e-9, "{r:?}");
        }
    }
}

/// Above `SPARSE_STATICS_MIN` coordinates the solver is sparse by itself; a 400-strut clustered
/// prism disturbed from its equilibrium comes back to it, its stability judged, with no dense
/// matrix of the structure's size formed in the workspace.
#[test]
fn a_400_strut_prism_comes_back_to_its_equilibrium_on_the_sparse_path() {
    let model = model_of(&prism(&PrismParams { n: 400, cluster_top_ring: true, ..Default::default() }));
    assert!(model.dof_count >= SPARSE_STATICS_MIN);
    let eq = State::initial(&model);
    let mut solver = StaticSolver::new(&model);
    assert!(solver.is_sparse());
    let mut state = disturbed(&model, &eq, 1e-3);
    let mut ws = Workspace::for_forces(&model);
    let report = solver.equilibrate(&model, &mut state, &mut ws, &model.solver).expect("equilibrium");
    let moved = largest_point_difference(&model, &eq, &state);
    assert!(moved <= 1e-7, "ended {moved:e} from the form-found equilibrium: {report:?}");
    assert!(report.iterations <= 30, "{report:?}");
    assert!(report.stable && report.negative_modes == 0 && report.zero_modes == 0, "{report:?}");
    assert!(report.min_stiffness_eigenvalue > 0.0, "{report:?}");
    assert_eq!(
        (ws.stiffness.len(), ws.damping.len(), ws.constraint_jacobian.len()),
        (0, 0, 0),
        "a dense matrix of the structure's size was formed"
    );
}
