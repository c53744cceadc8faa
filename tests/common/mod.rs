//! Shared helpers for the integration tests: bundled scenes, scene construction from specs and
//! TOML (and a knot between two cables), finite differences along the group retraction, scratch
//! directories; and, in submodules, what the node and recording tests share (bags, the network
//! namespace, DDS peers and their roles, a running node, the Python interpreter).
#![allow(dead_code)]

pub mod bags;
pub mod cleanup;
pub mod cpu;
pub mod netns;
#[cfg(feature = "ros2")]
pub mod peer;
pub mod python;
#[cfg(feature = "ros2")]
pub mod roles;
pub mod running_node;

use nalgebra::{DMatrix, DVector};
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::model::Model;
use tensegrity::scene::{build_model, SceneSpec};
use tensegrity::state::{retract, State};

/// The bundled scene `name` (`prism3` or `prism3.toml`: `tensegrity::scene::bundled`), panicking
/// with the scene error.
pub fn bundled(name: &str) -> Model {
    tensegrity::scene::bundled(name).unwrap_or_else(|e| panic!("{e}"))
}

/// The user's documentation as one text: README.md, then every page of docs/ (in name order).
pub fn user_docs() -> String {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut pages: Vec<_> = std::fs::read_dir(root.join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .collect();
    pages.sort();
    let mut text = std::fs::read_to_string(root.join("README.md")).unwrap();
    for page in pages {
        text += "\n";
        text += &std::fs::read_to_string(page).unwrap();
    }
    text
}

/// Builds a model from a spec, panicking with the scene error.
pub fn model_of(spec: &SceneSpec) -> Model {
    build_model(spec, "<test>", None).unwrap_or_else(|e| panic!("{e}"))
}

/// Model from TOML text.
pub fn model_from_toml(text: &str) -> Model {
    tensegrity::scene::from_toml(text, "<test>").unwrap_or_else(|e| panic!("{e}"))
}

/// `state` moved by `h` along local coordinate `j`.
pub fn perturbed(model: &Model, state: &State, j: usize, h: f64) -> State {
    let mut s = state.clone();
    let mut dq = DVector::zeros(model.dof_count);
    dq[j] = 1.0;
    retract(model, &mut s.poses, &dq, h);
    s
}

/// Generalized force at `state`.
pub fn force_at(model: &Model, state: &State) -> DVector<f64> {
    let mut ws = Workspace::new(model);
    evaluate(model, state, &mut ws, Tangents::None);
    ws.force.clone()
}

/// `-dQ/dq` by central differences along the retraction.
pub fn fd_stiffness(model: &Model, state: &State, h: f64) -> DMatrix<f64> {
    let n = model.dof_count;
    let mut k = DMatrix::zeros(n, n);
    for j in 0..n {
        let qp = force_at(model, &perturbed(model, state, j, h));
        let qm = force_at(model, &perturbed(model, state, j, -h));
        k.set_column(j, &(-(qp - qm) / (2.0 * h)));
    }
    k
}

/// `-dQ/dv` by central differences.
pub fn fd_damping(model: &Model, state: &State, h: f64) -> DMatrix<f64> {
    let n = model.dof_count;
    let mut c = DMatrix::zeros(n, n);
    for j in 0..n {
        let mut sp = state.clone();
        sp.velocities[j] += h;
        let mut sm = state.clone();
        sm.velocities[j] -= h;
        c.set_column(j, &(-(force_at(model, &sp) - force_at(model, &sm)) / (2.0 * h)));
    }
    c
}

/// Max-norm of `a - b` relative to the max-norm of `b` (floored at `floor`).
pub fn rel_err(a: &DMatrix<f64>, b: &DMatrix<f64>, floor: f64) -> f64 {
    (a - b).amax() / b.amax().max(floor)
}

/// Parses a spec from TOML text (for tests that edit a scene before building it).
pub fn spec_from_toml(text: &str) -> SceneSpec {
    tensegrity::scene::parse(text, "<test>").unwrap_or_else(|e| panic!("{e}"))
}

/// A point mass `mass` (kg) at the origin between two collinear cables `west` and `east` from
/// anchors at x = -`half_span` and +`half_span` (m), both of axial stiffness `ea` (N), gravity
/// `(0, 0, gravity_z)`; `west` and `east` are each cable's rest-length line (`rest_length = ...`,
/// `prestress = ...` or empty).
pub fn knot_between_cables(
    half_span: f64,
    mass: f64,
    ea: f64,
    gravity_z: f64,
    west: &str,
    east: &str,
) -> Model {
    model_from_toml(&format!(
        r#"
name = "knot"
gravity = [0.0, 0.0, {gravity_z}]
[[bodies]]
name = "ground"
kind = "fixed"
points = {{ left = [{neg}, 0.0, 0.0], right = [{half_span}, 0.0, 0.0] }}
[[bodies]]
name = "knot"
kind = "node"
mass = {mass}
position = [0.0, 0.0, 0.0]
[[cables]]
name = "west"
route = ["ground.left", "knot"]
ea = {ea}
{west}
[[cables]]
name = "east"
route = ["knot", "ground.right"]
ea = {ea}
{east}
"#,
        neg = -half_span
    ))
}

/// An empty-or-new directory under the system temporary directory for one test's files.
/// The hanging load of `config/examples/sensors.toml` without its `[sensors]`: a 10 kg node on a
/// 1 m rope (EA 1e5 N) from a fixed hook, the rope's actuator `winch`. Tests append their own
/// tables.
pub fn hanging_load() -> String {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/examples/sensors.toml"))
        .unwrap();
    let end = text.find("\n[sensors]").expect("sensors.toml declares [sensors]");
    text[..=end].to_string()
}

pub fn scratch(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("tensegrity-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    cleanup::remove_at_exit(&d);
    d
}

/// The bundled prism's spec without its pins and with a bottom ring: held by nothing.
pub fn free_prism_spec() -> SceneSpec {
    let mut spec = tensegrity::scene::generate::prism(&tensegrity::scene::generate::PrismParams::default());
    spec.name = "free prism".into();
    spec.joints.clear();
    let template = spec.cables[0].clone();
    for i in 0..3 {
        spec.cables.push(tensegrity::scene::CableSpec {
            name: format!("bottom{i}"),
            route: vec![format!("bar0_{i}.a"), format!("bar0_{}.a", (i + 1) % 3)],
            prestress: None,
            rest_length: None,
            force_density: None,
            tension_only: true,
            pulley_friction: None,
            winch_end: None,
            ..template.clone()
        });
    }
    spec
}

/// The bundled prism without its pins and with a bottom ring: held by nothing.
pub fn free_prism() -> Model {
    build_model(&free_prism_spec(), "<free prism>", None).unwrap_or_else(|e| panic!("{e}"))
}
