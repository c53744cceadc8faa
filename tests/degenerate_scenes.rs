//! Legal but degenerate models never panic, never print null and never hang: a scene whose bodies
//! are all fixed (nothing to move) is refused by what moves it with the input error status and
//! solved by `statics`; a fully constrained beam has no modes and no reduced stiffness, and says
//! so instead of printing `inf` or `null`; robots and loose bars on the ground by the hundred,
//! with contact, solve `statics` on the sparse path in a handful of Newton iterations (the cases
//! `benches/mutate_scenes.py` and the first hour of a new user found).

use std::path::{Path, PathBuf};
use std::process::Command;

use tensegrity::evaluate::Workspace;
use tensegrity::scene::generate::{self, SixbarParams};
use tensegrity::sim::{SimSettings, Simulator, StepError};
use tensegrity::solve::modes::natural_modes;
use tensegrity::solve::statics::StaticSolver;
use tensegrity::State;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn tensegrity(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_tensegrity")).args(args).current_dir(root()).output().expect("runs")
}

/// The bundled Atwood machine with every body fixed (masses and the like removed), written to a
/// scratch file.
fn all_fixed_scene(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(root().join("config/scenes/atwood.toml")).unwrap();
    let mut out = String::new();
    for line in text.lines() {
        if line.starts_with("kind = ") {
            out.push_str("kind = \"fixed\"\n");
        } else if !line.starts_with("mass = ") {
            out.push_str(line);
            out.push('\n');
        }
    }
    let path = dir.join("all_fixed.toml");
    std::fs::write(&path, out).unwrap();
    path
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("tensegrity-degenerate-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn a_scene_with_nothing_to_move_is_refused_by_what_moves_it_and_solved_by_statics() {
    let dir = scratch("fixed");
    let scene = all_fixed_scene(&dir);
    let model = tensegrity::scene::load(&scene).unwrap();
    assert_eq!(model.dof_count, 0);

    // the library: a typed error, no panic
    let err = Simulator::new(model.clone(), SimSettings::default()).unwrap_err();
    assert_eq!(err, StepError::NothingToMove);
    assert!(err.to_string().contains("nothing to move"), "{err}");
    let state = State::initial(&model);
    assert_eq!(natural_modes(&model, &state).map(|m| m.len()), Some(0));
    let mut s = State::initial(&model);
    let report = StaticSolver::new(&model)
        .equilibrate(&model, &mut s, &mut Workspace::new(&model), &model.solver)
        .expect("a fixed structure is its own equilibrium");
    assert_eq!(report.iterations, 0);

    // the command line: the input error status and a sentence that says what to do
    let path = scene.to_str().unwrap();
    let csv = dir.join("run.csv");
    for args in [
        vec!["deploy", path, "--dynamic", "--duration", "0.05", "--out", csv.to_str().unwrap()],
        vec!["modes", path],
        vec!["study", path, "--out", dir.join("study").to_str().unwrap()],
        vec!["bench", "steps", path, "--steps", "5"],
    ] {
        let out = tensegrity(&args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(3), "{args:?}: {stderr}");
        assert!(stderr.contains("nothing to move") && !stderr.contains("panicked"), "{args:?}: {stderr}");
    }
    for args in [vec!["statics", path], vec!["statics", path, "--json"], vec!["check", path]] {
        let out = tensegrity(&args);
        assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_fully_constrained_structure_has_no_modes_and_no_null_in_its_json() {
    let beam = "config/examples/beam.toml";
    let json = tensegrity(&["statics", beam, "--json"]);
    assert!(json.status.success());
    let text = String::from_utf8(json.stdout).unwrap();
    assert!(!text.contains("null"), "{text}");
    let value: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert!(value.get("min_stiffness_eigenvalue").is_none());
    assert_eq!(
        value["not_computed"]["min_stiffness_eigenvalue"],
        "no free motion: the joints hold every coordinate"
    );
    // prism3 has the number and no `not_computed`
    let prism: serde_json::Value =
        serde_json::from_slice(&tensegrity(&["statics", "config/scenes/prism3.toml", "--json"]).stdout)
            .unwrap();
    assert!(prism["min_stiffness_eigenvalue"].as_f64().unwrap() > 0.0);
    assert!(prism.get("not_computed").is_none());

    let text = String::from_utf8(tensegrity(&["statics", beam]).stdout).unwrap();
    assert!(!text.contains("inf"), "{text}");
    assert!(text.contains("no free motion"), "{text}");

    let modes = tensegrity(&["modes", beam]);
    assert!(modes.status.success(), "{}", String::from_utf8_lossy(&modes.stderr));
    assert!(String::from_utf8_lossy(&modes.stdout).contains("nothing vibrates"));
    assert_eq!(String::from_utf8(tensegrity(&["modes", beam, "--json"]).stdout).unwrap().trim(), "[]");
}

#[test]
fn elastic_members_are_listed_as_members() {
    let text = String::from_utf8(tensegrity(&["statics", "config/scenes/prism3_nodal.toml"]).stdout).unwrap();
    assert!(text.contains("cable/member"), "{text}");
    let text = String::from_utf8(tensegrity(&["statics", "config/scenes/prism3.toml"]).stdout).unwrap();
    assert!(!text.contains("cable/member"), "{text}");
}

/// Newton iterations of `statics` on `model` from its pose, or the failure.
fn statics_iterations(model: &tensegrity::Model) -> usize {
    let mut state = State::initial(model);
    let mut solver = StaticSolver::new(model);
    let report = solver
        .equilibrate(model, &mut state, &mut Workspace::new(model), &model.solver)
        .unwrap_or_else(|(it, res)| panic!("{}: no equilibrium: {res:.3e} N after {it}", model.name));
    assert!(solver.is_sparse(), "{} is solved on the sparse path", model.name);
    report.iterations
}

#[test]
fn fifty_robots_on_one_ground_solve_statics_on_the_sparse_path() {
    for robots in [50, 100] {
        let spec = generate::sixbar(&SixbarParams { robots, ..Default::default() });
        let model = tensegrity::scene::build_model(&spec, "<fleet>", None).unwrap();
        assert_eq!(model.bodies.len(), 6 * robots);
        assert_eq!(model.contact_spheres.len(), 12 * robots);
        let iterations = statics_iterations(&model);
        assert!(iterations <= 12, "{robots} robots: {iterations} Newton iterations");
    }
}

#[test]
fn a_thousand_loose_bars_beside_the_robot_solve_statics_in_a_handful_of_iterations() {
    let mut spec = generate::sixbar(&SixbarParams::default());
    let bar = spec.bodies[0].clone();
    for k in 0..996 {
        let (x, y) = (3.0 + (k % 32) as f64 * 1.2, (k / 32) as f64 * 0.3);
        spec.bodies.push(tensegrity::scene::BodySpec {
            name: format!("loose{k}"),
            ends: Some([[x, y, 0.02], [x + 1.0, y, 0.02]]),
            ..bar.clone()
        });
    }
    let model = tensegrity::scene::build_model(&spec, "<loose bars>", None).unwrap();
    assert_eq!(model.dof_count, 5010);
    let iterations = statics_iterations(&model);
    assert!(iterations <= 12, "{iterations} Newton iterations");
}
