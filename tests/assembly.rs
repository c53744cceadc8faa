//! Invariant: the block-scattered Newton matrix (dense and sparse `KktSystem`, clustered cables
//! bordered on the sparse path) equals the reference assembly from the dense tangents
//! `M + (gamma' C + K + H_lambda)/beta'` with `Phi_q` to 1e-12 relative once the border unknowns
//! are eliminated, and its Newton step equals the dense one to round-off — on every bundled scene,
//! on towers of all three side-string families, and on random scenes with long routes, every
//! body kind, joints, slack and taut cables, velocities and multipliers.

mod common;

use std::path::{Path, PathBuf};

use nalgebra::{DMatrix, DVector, Matrix6};
use proptest::prelude::*;
use tensegrity::assembly::DenseTangents;
use tensegrity::constraints::add_multiplier_hessian;
use tensegrity::evaluate::{evaluate, evaluate_forces, Tangents, Workspace};
use tensegrity::model::Model;
use tensegrity::scene::{BodyKindSpec, BodySpec, CableSpec, JointKindSpec, JointSpec, PointSpec, SceneSpec};
use tensegrity::solve::dynamics::{
    add_gyroscopic_damping, assemble_newton_matrix, mass_matrix, AlphaCoefficients,
};
use tensegrity::solve::linear::{KktSystem, LinearBackend};
use tensegrity::state::{retract, State};
use tensegrity::study::TowerFamily;

/// `(beta', gamma')` of generalized-alpha at `h`, rho_inf 0.8.
fn coefficients(h: f64) -> (f64, f64) {
    let c = AlphaCoefficients::new(0.8);
    ((1.0 - c.alpha_m) / (h * h * c.beta * (1.0 - c.alpha_f)), c.gamma / (h * c.beta))
}

/// The reference: dense `K`, `C`, `Phi_q` from `evaluate::evaluate`, combined entry by entry.
fn reference_matrix(model: &Model, state: &State, beta_p: f64, gamma_p: f64) -> DMatrix<f64> {
    let (n, nc) = (model.dof_count, model.constraint_count);
    let mut ws = Workspace::new(model);
    evaluate(model, state, &mut ws, Tangents::StiffnessAndDamping);
    let mut h = DMatrix::zeros(n, n);
    add_multiplier_hessian(model, &state.poses, &state.multipliers, &mut h);
    let mut stiffness = ws.stiffness.clone();
    let mut damping = ws.damping.clone();
    add_gyroscopic_damping(
        model,
        &state.velocities,
        &mut DenseTangents { model, stiffness: &mut stiffness, damping: Some(&mut damping) },
    );
    let mut a = DMatrix::zeros(n + nc, n + nc);
    let top = mass_matrix(model) + (damping * gamma_p + stiffness + h) / beta_p;
    a.view_mut((0, 0), (n, n)).copy_from(&top);
    a.view_mut((n, 0), (nc, n)).copy_from(&ws.constraint_jacobian);
    a.view_mut((0, n), (n, nc)).copy_from(&ws.constraint_jacobian.transpose());
    a
}

/// The Newton matrix as `KktSystem` assembles it, bordered unknowns eliminated (Schur
/// complement), and the system itself (assembled, not yet factored).
fn assembled(
    model: &Model,
    state: &State,
    backend: LinearBackend,
    beta_p: f64,
    gamma_p: f64,
) -> (DMatrix<f64>, KktSystem) {
    let mut ws = Workspace::for_forces(model);
    evaluate_forces(model, state, &mut ws);
    let mass: Vec<Matrix6<f64>> = model.bodies.iter().map(|b| b.mass_matrix()).collect();
    let mut kkt = KktSystem::new(model, backend);
    assemble_newton_matrix(model, state, &mut ws, &mass, &mut kkt, beta_p, gamma_p);
    let full = kkt.to_dense();
    let m = model.dof_count + model.constraint_count;
    let b = kkt.size() - m;
    if b == 0 {
        return (full, kkt);
    }
    let a11 = full.view((0, 0), (m, m)).into_owned();
    let a12 = full.view((0, m), (m, b)).into_owned();
    let a21 = full.view((m, 0), (b, m)).into_owned();
    let a22 = full.view((m, m), (b, b)).into_owned();
    let inv = a22.try_inverse().expect("border block is diagonal and nonzero");
    (a11 - a12 * inv * a21, kkt)
}

fn relative_difference(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    (a - b).amax() / a.amax().max(1e-300)
}

/// Checks assembly and Newton step of `model` at `state` on both backends.
fn check_state(model: &Model, state: &State, what: &str) {
    let (beta_p, gamma_p) = coefficients(1e-3);
    let reference = reference_matrix(model, state, beta_p, gamma_p);
    let m = reference.nrows();
    let rhs = DVector::from_fn(m, |i, _| ((i * 7919) % 13) as f64 - 6.0);
    let x_ref = reference.clone().lu().solve(&rhs);
    for backend in [LinearBackend::Dense, LinearBackend::Sparse] {
        let (eliminated, mut kkt) = assembled(model, state, backend, beta_p, gamma_p);
        let d = relative_difference(&reference, &eliminated);
        assert!(
            d < 1e-12,
            "{what}, {backend:?}: assembled matrix differs from the reference by {d:.2e} (relative)"
        );
        let Some(x_ref) = &x_ref else { continue };
        let mut x = DVector::zeros(kkt.size());
        x.rows_mut(0, m).copy_from(&rhs);
        assert!(kkt.solve(&mut x), "{what}, {backend:?}: solve failed");
        let scale = x_ref.amax().max(1e-300);
        let e = (x.rows(0, m) - x_ref).amax() / scale;
        // condition numbers of KKT matrices reach 1e6 here; the solutions agree to round-off
        assert!(e < 1e-8, "{what}, {backend:?}: Newton step differs by {e:.2e} (relative)");
    }
}

/// A moved, spinning, loaded copy of the initial state: every body displaced and rotated a
/// little, velocities and multipliers set, so that every term of the matrix is nonzero.
fn disturbed(model: &Model, seed: u64) -> State {
    let mut state = State::initial(model);
    let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let mut next = || {
        x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((x >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    let dq = DVector::from_fn(model.dof_count, |_, _| 0.01 * next());
    retract(model, &mut state.poses, &dq, 1.0);
    for v in state.velocities.iter_mut() {
        *v = 0.5 * next();
    }
    for l in state.multipliers.iter_mut() {
        *l = 50.0 * next();
    }
    state
}

fn scenes() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("config");
    let mut out = Vec::new();
    for dir in ["scenes", "examples"] {
        for e in std::fs::read_dir(root.join(dir)).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "toml") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

#[test]
fn every_bundled_scene_assembles_the_reference_matrix_on_both_backends() {
    for path in scenes() {
        let model = tensegrity::scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let what = path.file_name().unwrap().to_string_lossy().to_string();
        check_state(&model, &State::initial(&model), &format!("{what} (initial)"));
        check_state(&model, &disturbed(&model, 7), &format!("{what} (disturbed)"));
    }
}

#[test]
fn towers_of_every_family_assemble_the_reference_matrix_and_border_their_clustered_cables() {
    for family in [TowerFamily::Classical, TowerFamily::PerStage, TowerFamily::Helical] {
        for stages in [2, 5] {
            let model = family.model(stages).unwrap();
            let sparse = KktSystem::new(&model, LinearBackend::Sparse);
            let long_routes = (0..model.cables.len())
                .filter(|&c| {
                    let mut bodies: Vec<usize> = model
                        .route(tensegrity::model::CableId(c))
                        .iter()
                        .map(|p| model.points[p.0].body.0)
                        .filter(|&b| model.bodies[b].dof_count > 0)
                        .collect();
                    bodies.sort();
                    bodies.dedup();
                    bodies.len() >= tensegrity::solve::linear::BORDER_MIN_BODIES
                })
                .count();
            assert_eq!(sparse.bordered_cables(), long_routes, "{family:?} {stages}");
            assert!(long_routes > 0 || family == TowerFamily::Classical && stages < 2);
            check_state(&model, &disturbed(&model, stages as u64), &format!("{family:?} tower of {stages}"));
        }
    }
}

#[test]
fn the_symmetric_factors_solve_the_symmetric_part_to_round_off() {
    // the sparse LDL^T's own substitution (`SymmetricFactor::solve`) against a dense LU of
    // `(A + A^T) / 2`, on towers whose factors have supernodes of many widths, with borders
    for (family, stages) in
        [(TowerFamily::PerStage, 6), (TowerFamily::Helical, 5), (TowerFamily::Classical, 3)]
    {
        let model = family.model(stages).unwrap();
        let state = disturbed(&model, 7);
        let (beta_p, gamma_p) = coefficients(1e-3);
        let mut ws = Workspace::for_forces(&model);
        evaluate_forces(&model, &state, &mut ws);
        let mass: Vec<Matrix6<f64>> = model.bodies.iter().map(|b| b.mass_matrix()).collect();
        let mut kkt = KktSystem::new(&model, LinearBackend::Sparse);
        assemble_newton_matrix(&model, &state, &mut ws, &mass, &mut kkt, beta_p, gamma_p);
        let full = kkt.to_dense();
        let symmetric = (&full + full.transpose()) * 0.5;
        assert!(kkt.factor_symmetric(), "{family:?}");
        for seed in 0..3 {
            let b = DVector::from_fn(kkt.size(), |i, _| ((i * 7 + seed * 13) as f64 * 0.37).sin());
            let mut x = b.clone();
            assert!(kkt.solve_factored(&mut x), "{family:?}");
            let expected = symmetric.clone().lu().solve(&b).expect("regular");
            let error = (&x - &expected).amax() / expected.amax();
            assert!(error < 1e-9, "{family:?} {stages}: relative difference {error:e}");
            let residual = (&symmetric * &x - &b).amax() / (symmetric.amax() * x.amax());
            assert!(residual < 1e-13, "{family:?} {stages}: residual {residual:e}");
        }
    }
}

#[test]
fn the_sparse_pattern_stays_linear_in_the_number_of_stages() {
    // nonzeros per stage must not grow with the tower: clustered cables add a border, not a
    // dense block
    for family in [TowerFamily::Classical, TowerFamily::PerStage, TowerFamily::Helical] {
        let nnz = |s| KktSystem::new(&family.model(s).unwrap(), LinearBackend::Sparse).nonzeros() as f64;
        let (small, large) = (nnz(8) / 8.0, nnz(32) / 32.0);
        assert!(
            large < 1.15 * small,
            "{family:?}: {small:.0} nonzeros per stage at 8 stages, {large:.0} at 32"
        );
    }
}

/// A random scene: `kinds.len()` bodies in a row (0 node, 1 bar, 2 rigid), two world pins,
/// and cables whose routes run through the listed points (long routes cross many
/// bodies and are bordered on the sparse path); `rest` are the rest lengths (m; short ones are
/// taut, long ones slack).
fn random_scene(kinds: &[u8], routes: &[Vec<usize>], rest: &[f64], damping: &[f64]) -> SceneSpec {
    let mut bodies = Vec::new();
    let mut pool = Vec::new();
    for (i, k) in kinds.iter().enumerate() {
        let x = i as f64 * 0.7;
        let y = if i % 2 == 0 { 0.0 } else { 0.4 };
        let mut b = match k % 3 {
            0 => {
                let mut b = BodySpec::new(&format!("b{i}"), BodyKindSpec::Node);
                b.position = Some([x, y, 0.1 * i as f64]);
                pool.push(format!("b{i}"));
                b
            }
            1 => {
                let mut b = BodySpec::new(&format!("b{i}"), BodyKindSpec::Bar);
                b.ends = Some([[x, y, 0.0], [x + 0.1, y - 0.2, 1.0]]);
                b.points.insert("m".into(), PointSpec::Along(0.4));
                pool.extend([format!("b{i}.a"), format!("b{i}.b"), format!("b{i}.m")]);
                b
            }
            _ => {
                let mut b = BodySpec::new(&format!("b{i}"), BodyKindSpec::Rigid);
                b.position = Some([x, y, 0.5]);
                b.rotation = Some([0.1 * i as f64, -0.2, 0.3]);
                b.inertia = Some(vec![0.3, 0.4, 0.5, 0.01, -0.02, 0.03]);
                b.points.insert("p".into(), PointSpec::Local([0.2, 0.1, -0.3]));
                b.points.insert("q".into(), PointSpec::Local([-0.1, 0.3, 0.2]));
                pool.extend([format!("b{i}.p"), format!("b{i}.q")]);
                b
            }
        };
        b.mass = Some(1.0 + i as f64);
        bodies.push(b);
    }
    let mut cables = Vec::new();
    for (c, route) in routes.iter().enumerate() {
        let mut names: Vec<String> = route.iter().map(|&i| pool[i % pool.len()].clone()).collect();
        names.dedup();
        if names.len() < 2 || names.first() == names.last() && names.len() == 2 {
            continue;
        }
        cables.push(CableSpec {
            name: format!("c{c}"),
            route: names,
            ea: 1e4,
            damping: Some(damping[c % damping.len()]),
            damping_ratio: None,
            rest_length: Some(rest[c % rest.len()]),
            prestress: None,
            force_density: None,
            tension_only: true,
            pulley_friction: None,
            winch_end: None,
        });
    }
    let mut joints = vec![JointSpec {
        kind: JointKindSpec::Pin,
        a: pool[0].clone(),
        b: None,
        at: None,
        direction: None,
        normal: None,
        axis: None,
        damping: None,
    }];
    if kinds.len() > 2 {
        joints.push(JointSpec {
            kind: JointKindSpec::Pin,
            a: pool[pool.len() - 1].clone(),
            b: None,
            at: None,
            direction: None,
            normal: None,
            axis: None,
            damping: None,
        });
    }
    SceneSpec { bodies, cables, joints, ..Default::default() }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]
    #[test]
    fn random_scenes_assemble_the_reference_matrix(
        kinds in proptest::collection::vec(0u8..3, 3..7),
        routes in proptest::collection::vec(proptest::collection::vec(0usize..40, 2..9), 1..5),
        rest in proptest::collection::vec(0.3..3.0f64, 1..4),
        damping in proptest::collection::vec(prop_oneof![Just(0.0), 0.1..30.0f64], 1..3),
        seed in 0u64..1000,
    ) {
        let spec = random_scene(&kinds, &routes, &rest, &damping);
        prop_assume!(!spec.cables.is_empty());
        let model = match tensegrity::scene::build_model(&spec, "<random>", None) {
            Ok(m) => m,
            Err(e) => { eprintln!("{e}"); return Err(TestCaseError::reject("scene refused")); }
        };
        check_state(&model, &disturbed(&model, seed), "random scene");
    }
}

#[test]
fn a_reused_factorization_gives_the_same_trajectory_as_full_newton() {
    use tensegrity::sim::{SimSettings, Simulator};
    use tensegrity::solve::dynamics::NewtonSettings;
    let model = TowerFamily::PerStage.model(4).unwrap();
    let run = |reuse: bool| {
        let settings = SimSettings {
            dt: 1e-3,
            newton: NewtonSettings { reuse_factorization: reuse, ..Default::default() },
            ..Default::default()
        };
        let mut sim = Simulator::new(model.clone(), settings).unwrap();
        let mut factorizations = 0;
        for _ in 0..300 {
            factorizations += sim.step().unwrap().factorizations;
        }
        (sim.state().clone(), factorizations)
    };
    let (full, f_full) = run(false);
    let (reused, f_reused) = run(true);
    assert!(f_reused * 10 < f_full, "{f_reused} factorizations with reuse, {f_full} without");
    let worst = full
        .poses
        .iter()
        .zip(&reused.poses)
        .map(|(a, b)| (a.position - b.position).norm())
        .fold(0.0, f64::max);
    // both converge to the same residual tolerance (1e-9 of the force scale) every step
    assert!(worst < 1e-8, "positions differ by {worst:.2e} m after 0.3 s");
}

/// The sparse backend's modified Newton factors the symmetric part of the Newton matrix by
/// `LDL^T` and turns to the exact LU when that does not contract; the converged steps must be
/// the ones the exact LU gives (same residual test), also where the matrix is far from
/// symmetric: damped cables sliding through a deploying helical tower, rigid bodies spinning fast
/// (gyroscopic damping), and a large step where stiffness rivals inertia. Symplectic Euler's
/// matrix is symmetric, so its `LDL^T` steps equal the LU's to round-off.
#[test]
fn the_symmetric_factorization_gives_the_exact_factorizations_trajectories() {
    use tensegrity::sim::{SimSettings, Simulator};
    use tensegrity::solve::dynamics::{Integrator, NewtonSettings};
    let spinning = {
        let spec = random_scene(
            &[2, 2, 1, 2, 0, 2],
            &[vec![0, 3, 5, 7], vec![1, 4, 9], vec![2, 6, 8, 10, 11]],
            &[0.6, 0.9],
            &[5.0, 0.0],
        );
        tensegrity::scene::build_model(&spec, "<spinning>", None).unwrap()
    };
    let mut spin_start = State::initial(&spinning);
    for (i, v) in spin_start.velocities.iter_mut().enumerate() {
        *v = if i % 6 >= 3 { 30.0 * ((i as f64) * 0.7).sin() } else { 0.2 * (i as f64).cos() };
    }
    let cases: Vec<(&str, Model, State, SimSettings, usize)> = vec![
        (
            "helical tower",
            TowerFamily::Helical.model(4).unwrap(),
            State::initial(&TowerFamily::Helical.model(4).unwrap()),
            SimSettings { dt: 1e-3, ..Default::default() },
            300,
        ),
        (
            "spinning rigid bodies",
            spinning.clone(),
            spin_start,
            SimSettings { dt: 1e-3, ..Default::default() },
            200,
        ),
        (
            "large steps",
            TowerFamily::PerStage.model(4).unwrap(),
            State::initial(&TowerFamily::PerStage.model(4).unwrap()),
            SimSettings { dt: 2e-2, ..Default::default() },
            50,
        ),
        (
            "symplectic Euler",
            TowerFamily::Helical.model(4).unwrap(),
            State::initial(&TowerFamily::Helical.model(4).unwrap()),
            SimSettings { dt: 1e-4, integrator: Integrator::SymplecticEuler, ..Default::default() },
            300,
        ),
    ];
    for (what, model, start, settings, steps) in cases {
        let run = |linear| {
            // converged far below the default tolerance, so that the comparison sees the
            // factorizations and not two different points within the tolerance (the spinning
            // bodies amplify differences: dense and sparse LU end 2e-11 m apart)
            let newton = NewtonSettings { tolerance: 1e-13, max_iterations: 40, ..Default::default() };
            let mut sim = Simulator::from_state(
                model.clone(),
                start.clone(),
                SimSettings { linear, newton, ..settings },
            )
            .unwrap();
            assert_eq!(sim.linear_backend(), linear);
            for _ in 0..steps {
                sim.step().unwrap_or_else(|e| panic!("{what}: {e}"));
            }
            sim
        };
        let (symmetric, exact) = (run(LinearBackend::Sparse), run(LinearBackend::SparseLu));
        let dense = run(LinearBackend::Dense);
        eprintln!(
            "{what}: dense vs LU {:e}",
            dense
                .state()
                .poses
                .iter()
                .zip(&exact.state().poses)
                .map(|(a, b)| (a.position - b.position).norm())
                .fold(0.0, f64::max)
        );
        assert!(symmetric.newton_system().symmetric_factor_entries().is_some(), "{what}");
        assert!(exact.newton_system().symmetric_factor_entries().is_none(), "{what}");
        let worst = symmetric
            .state()
            .poses
            .iter()
            .zip(&exact.state().poses)
            .map(|(a, b)| (a.position - b.position).norm())
            .fold(0.0, f64::max);
        let bound = if settings.integrator == Integrator::SymplecticEuler { 1e-12 } else { 1e-8 };
        assert!(worst < bound, "{what}: positions differ by {worst:.2e} m");
    }
}
