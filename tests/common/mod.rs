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
use tensegrity::evaluate::{evaluate, evaluate_forces, Tangents, Workspace};
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

/// `state` moved along the local increments `dq` by `scale` (velocities kept).
pub fn moved(model: &Model, state: &State, dq: &DVector<f64>, scale: f64) -> State {
    let mut s = state.clone();
    retract(model, &mut s.poses, dq, scale);
    s
}

/// A fixed pseudo-random vector of length `n` (entries in [-1, 1]).
pub fn wiggle(n: usize, seed: u64) -> DVector<f64> {
    let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    DVector::from_fn(n, |_, _| {
        x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((x >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    })
}

/// Checks the joints' rows at `state` against central differences (step 1e-6): `Phi_q` against
/// `Phi` (1e-8), the reactions `Phi_q^T lambda` of pseudo-random multipliers against `Phi_q`
/// itself, and their derivative `d(Phi_q^T lambda)/dq` (1e-6 relative); and that the rates are
/// `Phi_q v`. Returns the central difference of the rates along the velocities at fixed `v`
/// (the acceleration bias each joint kind's own function should give).
pub fn check_joint_rows_by_finite_differences(model: &Model, state: &State) -> DVector<f64> {
    let mut ws = Workspace::new(model);
    evaluate(model, state, &mut ws, Tangents::None);
    let phi_q = ws.constraint_jacobian.clone();
    let (n, h) = (model.dof_count, 1e-6);
    let lambda = wiggle(model.constraint_count, 3) * 10.0;
    let reactions = |s: &State| {
        let mut w = Workspace::new(model);
        evaluate_forces(model, s, &mut w);
        let mut out = DVector::zeros(n);
        tensegrity::constraints::add_reaction_force(model, &s.poses, &w.points, &lambda, 1.0, &mut out);
        out
    };
    let mut hessian = DMatrix::zeros(n, n);
    tensegrity::constraints::add_multiplier_hessian(model, &state.poses, &lambda, &mut hessian);
    assert!((reactions(state) - phi_q.transpose() * &lambda).amax() < 1e-12, "reactions are Phi_q^T lambda");
    for j in 0..n {
        let e = DVector::from_fn(n, |i, _| if i == j { 1.0 } else { 0.0 });
        let (sp, sm) = (moved(model, state, &e, h), moved(model, state, &e, -h));
        let (mut wp, mut wm) = (Workspace::new(model), Workspace::new(model));
        evaluate(model, &sp, &mut wp, Tangents::None);
        evaluate(model, &sm, &mut wm, Tangents::None);
        let fd = (&wp.constraint - &wm.constraint) / (2.0 * h);
        let err = (&fd - phi_q.column(j)).amax();
        assert!(err < 1e-8, "Phi_q column {j}: {err}");
        let fd = (reactions(&sp) - reactions(&sm)) / (2.0 * h);
        let err = (&fd - hessian.column(j)).amax();
        assert!(err < 1e-6 * (1.0 + fd.amax()), "d(Phi_q^T lambda)/dq column {j}: {err}");
    }
    let rates_at = |s: &State| {
        let mut w = Workspace::new(model);
        evaluate_forces(model, s, &mut w);
        let mut r = DVector::zeros(model.constraint_count);
        tensegrity::constraints::evaluate_rates(model, &s.poses, &s.velocities, &w.points, &mut r);
        r
    };
    assert!((rates_at(state) - &phi_q * &state.velocities).amax() < 1e-12, "the rates are Phi_q v");
    (rates_at(&moved(model, state, &state.velocities, h))
        - rates_at(&moved(model, state, &state.velocities, -h)))
        / (2.0 * h)
}

/// A free chain along x of `n` members between `n + 1` nodes (planar), total mass `mass` (kg)
/// carried as `mass_matrix` says (`"lumped"` or `"consistent"`), length `length` (m), member
/// stiffness `ea` (N); the nodes take their mass from the members only.
pub fn member_chain(n: usize, mass: f64, length: f64, ea: f64, mass_matrix: &str) -> Model {
    let h = length / n as f64;
    let mut text = String::from("planar = true\n");
    for k in 0..=n {
        text += &format!(
            "[[bodies]]\nname = \"n{k}\"\nkind = \"node\"\nposition = [{}, 0.0, 0.0]\n",
            k as f64 * h
        );
    }
    for k in 0..n {
        text += &format!(
            "[[members]]\nname = \"m{k}\"\nends = [\"n{k}\", \"n{}\"]\nea = {ea:e}\nmass = {:e}\nmass_matrix = \"{mass_matrix}\"\n",
            k + 1,
            mass / n as f64
        );
    }
    model_from_toml(&text)
}
