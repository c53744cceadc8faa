//! Invariant: a structure held by nothing (in orbit, in a drop test) is solved like any other and
//! reported stable, with its free rigid-body motions counted apart from its stiffness: a free
//! 3-strut prism has 6 rigid-body modes, a free planar cross 3, a pinned prism none, a body hanging
//! from a ball joint 1 (its spin about the vertical). Its quasi-static deployment takes a few
//! Newton iterations per load step, and a start moved as a whole and disturbed comes back to the
//! same self-stress.

mod common;

use nalgebra::DVector;
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::scene::generate::{prism, PrismParams};
use tensegrity::solve::deploy::deploy_quasi_static;
use tensegrity::solve::statics::{EquilibriumReport, StaticSolver};
use tensegrity::state::retract;
use tensegrity::{Model, State};

use common::free_prism;

fn solve(model: &Model, state: &mut State) -> EquilibriumReport {
    let mut ws = Workspace::new(model);
    StaticSolver::new(model).equilibrate(model, state, &mut ws, &model.solver).expect("equilibrium")
}

fn example(name: &str) -> Model {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config").join(name);
    tensegrity::scene::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn free_structures_are_stable_with_their_rigid_body_modes_counted() {
    let model = free_prism();
    let r = solve(&model, &mut State::initial(&model));
    assert!(r.stable, "{}", r.stability_words());
    assert_eq!((r.rigid_modes, r.zero_modes, r.negative_modes), (6, 6, 0));
    assert_eq!(r.stability_words(), "stable (6 rigid-body modes)");

    let cross = example("examples/planar_cross.toml");
    let r = solve(&cross, &mut State::initial(&cross));
    assert_eq!(r.stability_words(), "stable (3 rigid-body modes)");

    let pinned = example("scenes/prism3.toml");
    let r = solve(&pinned, &mut State::initial(&pinned));
    assert_eq!((r.stability_words().as_str(), r.rigid_modes), ("stable", 0));
}

#[test]
fn a_free_prism_moved_as_a_whole_and_disturbed_comes_back_to_its_self_stress() {
    let model = free_prism();
    let mut eq = State::initial(&model);
    solve(&model, &mut eq);
    let mut ws = Workspace::new(&model);
    evaluate(&model, &eq, &mut ws, Tangents::None);
    let tensions: Vec<f64> = ws.cables.iter().map(|c| c.tension).collect();
    for k in 0..20 {
        let mut state = eq.clone();
        let dq = DVector::from_fn(model.dof_count, |i, _| 0.15 * ((i * 7 + k * 13) as f64).sin());
        retract(&model, &mut state.poses, &dq, 1.0);
        let r = solve(&model, &mut state);
        assert!(r.stable && r.iterations <= 30, "case {k}: {r:?}");
        evaluate(&model, &state, &mut ws, Tangents::None);
        for (c, t) in ws.cables.iter().zip(&tensions) {
            assert!(
                (c.tension - t).abs() <= 1e-7 * t.abs().max(1.0),
                "case {k}: tension {} vs {t}",
                c.tension
            );
        }
    }
}

#[test]
fn a_free_prism_deploys_in_a_few_newton_iterations_per_load_step() {
    let model = free_prism();
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    let path = deploy_quasi_static(&model, &mut state, &mut ws, |_, _, _| {}).expect("deployment");
    let iterations: usize = path.steps.iter().map(|p| p.report.iterations).sum();
    let per_step = iterations as f64 / (path.steps.len() - 1) as f64;
    assert!(per_step <= 4.0, "{per_step} Newton iterations per load step");
    assert!(path.snaps.is_empty() && path.output_steps().count() == path.steps.len(), "plain load steps");
    assert!(path.steps.iter().all(|p| p.report.stable && p.report.rigid_modes == 6));
}

#[test]
fn a_body_on_a_ball_joint_has_one_rigid_body_mode_its_spin() {
    let text = "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"ground\"\nkind = \"fixed\"\npoints = { hook = [0.0, 0.0, 0.0] }\n[[bodies]]\nname = \"bob\"\nkind = \"rigid\"\nmass = 2.0\nposition = [0.3, 0.0, -0.7]\ninertia = [0.02, 0.03, 0.04]\npoints = { top = [-0.3, 0.0, 0.7] }\n[[joints]]\nkind = \"ball\"\na = \"bob.top\"\nb = \"ground.hook\"\n";
    let model = tensegrity::scene::from_toml(text, "bob").unwrap();
    let r = solve(&model, &mut State::initial(&model));
    assert_eq!(r.stability_words(), "stable (1 rigid-body mode)");
}

#[test]
fn rigid_alignment_removes_any_rotation_and_translation() {
    let start: Vec<nalgebra::Vector3<f64>> = (0..7)
        .map(|i| nalgebra::Vector3::new((i as f64).sin(), (2.0 * i as f64).cos(), 0.3 * i as f64))
        .collect();
    let turn = nalgebra::Rotation3::from_scaled_axis(nalgebra::Vector3::new(0.4, -1.1, 2.0));
    let moved: Vec<_> = start.iter().map(|p| turn * p + nalgebra::Vector3::new(5.0, -2.0, 0.7)).collect();
    let aligned = tensegrity::study::rigidly_aligned(&moved, &start);
    for (a, s) in aligned.iter().zip(&start) {
        assert!((a - s).norm() < 1e-12, "{a:?} vs {s:?}");
    }
}

#[test]
fn a_free_prism_deployment_study_compares_shapes_and_converges_as_actuation_slows() {
    let model = free_prism();
    assert!(model.is_free_floating());
    let out = std::env::temp_dir().join(format!("tensegrity-free-study-{}", std::process::id()));
    let settings = tensegrity::sim::SimSettings::default();
    let r =
        tensegrity::study::deployment_study(&model, &[0.2, 1.0, 5.0], None, settings, 0.5, 0, &out).unwrap();
    assert!(r.rigid_motion_removed && r.markdown().contains("optimal rigid alignment"));
    let dev: Vec<f64> =
        r.rows.iter().map(|row| row.displacement_deviation.abs().max(row.tension_deviation.abs())).collect();
    assert!(dev[0] > dev[1] && dev[1] > dev[2], "deviations shrink as actuation slows: {dev:?}");
    assert!(dev[2] < 1e-3, "a 5 s actuation is quasi-static: {dev:?}");
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn the_work_precision_bench_compares_a_free_structures_shapes_and_says_so() {
    let model = free_prism();
    let out = std::env::temp_dir().join(format!("tensegrity-free-wp-{}", std::process::id()));
    let ga = tensegrity::solve::dynamics::Integrator::GeneralizedAlpha { rho_inf: 0.8 };
    use tensegrity::study::{RunConfig, WorkPrecisionSettings};
    let settings = |duration| WorkPrecisionSettings {
        reference_dt: 1e-4,
        reference_integrator: tensegrity::solve::dynamics::Integrator::DormandPrince,
        duration,
        sample: 0.01,
        repeats: 1,
        jobs: 0,
    };
    let runs = [RunConfig::fixed(ga, 4e-3), RunConfig::fixed(ga, 2e-3), RunConfig::fixed(ga, 1e-3)];
    let rows = tensegrity::study::work_precision(&model, &runs, settings(0.3), &out).unwrap();
    assert!(rows.windows(2).all(|w| w[1].error < w[0].error), "errors fall with the step: {rows:?}");
    let md = std::fs::read_to_string(out.join("work_precision.md")).unwrap();
    assert!(md.contains("after the optimal rigid alignment"), "{md}");
    // a held structure's table makes no such claim
    let pinned = tensegrity::scene::build_model(&prism(&PrismParams::default()), "<prism>", None).unwrap();
    tensegrity::study::work_precision(&pinned, &[RunConfig::fixed(ga, 2e-3)], settings(0.05), &out).unwrap();
    assert!(!std::fs::read_to_string(out.join("work_precision.md")).unwrap().contains("alignment"));
    std::fs::remove_dir_all(&out).ok();
}
