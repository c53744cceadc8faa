//! Invariant: the nodal (finite-element) T-bar, four half-bars as elastic members meeting at one
//! hub node, converges to its rigid twin, the pin-jointed T-bar (`generate tbar --hinged-hub`),
//! as the members' EA grows.
//! - The generator makes one hub node: five nodes, four members, one pin (the bundled
//!   `tbar_nodal.toml` is its output, `tests/cli.rs`).
//! - Both start in the same form-found equilibrium, stable, with the same rest lengths; the
//!   members carry the rigid half-bars' axial forces (the hub joints' reactions along them).
//! - With the sliding upper cable over the mast top the hinged hub is a mechanism (a
//!   negative-stiffness mode), which is why the hinged and nodal T-bars split the upper strings.
//! - After the lower winch hauls in 10 %, the nodal equilibrium converges to the rigid one at
//!   order 1 in `1 / EA`, as do the dynamics with the consistent mass matrix (a uniform half-bar's
//!   inertia) after the left lower string is released 3 % short.
//! - Quasi-static deployment of the bundled nodal T-bar stays within its members' elastic
//!   shortening of the rigid twin's at every load step.

mod common;

use common::*;
use nalgebra::Vector3;
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::scene::generate::{tbar, TbarParams};
use tensegrity::scene::{BodyKindSpec, MassMatrixSpec};
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::statics::{EquilibriumReport, StaticSolver};
use tensegrity::{Model, State};

/// The points compared: the hub, the mast top and the two cross-bar tips (rigid names; the nodal
/// form's are the same with `_` for `.`).
const POINTS: [&str; 4] = ["mast_lower.b", "mast_upper.b", "cross_left.b", "cross_right.b"];

fn hinged() -> Model {
    model_of(&tbar(&TbarParams { hinged_hub: true, ..Default::default() }))
}

fn nodal(ea: f64, mass_matrix: MassMatrixSpec) -> Model {
    model_of(&tbar(&TbarParams {
        nodal_strut_ea: Some(ea),
        nodal_mass_matrix: mass_matrix,
        ..Default::default()
    }))
}

/// The compared points of `model` at `state`, in `POINTS` order.
fn points(model: &Model, state: &State) -> Vec<Vector3<f64>> {
    let mut ws = Workspace::new(model);
    evaluate(model, state, &mut ws, Tangents::None);
    let nodal = model.cables.iter().any(|c| !c.tension_only);
    POINTS
        .iter()
        .map(|p| {
            let name = if nodal { p.replace('.', "_") } else { p.to_string() };
            ws.points[model.point_id(&name).unwrap_or_else(|| panic!("no point {name}")).0].position
        })
        .collect()
}

fn largest_gap(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).norm()).fold(0.0, f64::max)
}

fn equilibrium(model: &Model, mut state: State) -> (State, EquilibriumReport) {
    let mut ws = Workspace::new(model);
    let report =
        StaticSolver::new(model).equilibrate(model, &mut state, &mut ws, &model.solver).expect("equilibrium");
    (state, report)
}

/// `state` with `cable`'s rest length times `factor`.
fn shortened(model: &Model, cable: &str, factor: f64) -> State {
    let mut state = State::initial(model);
    let c = model.cable_names.iter().position(|n| n == cable).unwrap();
    state.rest_lengths[c] *= factor;
    state
}

fn assert_first_order_in_stiffness(errors: &[f64], slack: f64) {
    for w in errors.windows(2) {
        let order = (w[0] / w[1]).log10();
        assert!((order - 1.0).abs() < slack, "observed order {order} in 1/EA from {errors:?}");
    }
}

#[test]
fn the_nodal_tbar_has_one_hub_node() {
    let spec = tbar(&TbarParams { nodal_strut_ea: Some(1e7), ..Default::default() });
    let nodes: Vec<_> =
        spec.bodies.iter().filter(|b| b.kind == BodyKindSpec::Node).map(|b| b.name.as_str()).collect();
    assert_eq!(nodes, ["mast_lower_a", "mast_lower_b", "mast_upper_b", "cross_left_b", "cross_right_b"]);
    assert_eq!(spec.joints.len(), 1, "the hub's ball joints are gone, the foot's pin stays");
    let hub_members = spec.members.iter().filter(|m| m.ends.contains(&"mast_lower_b".to_string())).count();
    assert_eq!(hub_members, 4);
    let model = model_of(&spec);
    assert_eq!((model.dof_count, model.constraint_count), (10, 2));
    // the rigid twin: four bars, a pin and three ball joints, 2 + 3 * 2 rows in the plane
    let rigid = hinged();
    assert_eq!((rigid.dof_count, rigid.constraint_count), (12, 8));
}

#[test]
fn both_start_in_the_same_stable_equilibrium_and_the_members_carry_the_half_bars_forces() {
    let rigid = hinged();
    let (rigid_state, rigid_report) = equilibrium(&rigid, State::initial(&rigid));
    assert!(rigid_report.stable, "{}", rigid_report.stability_words());
    for mass_matrix in [MassMatrixSpec::Lumped, MassMatrixSpec::Consistent] {
        let model = nodal(1e7, mass_matrix);
        let (state, report) = equilibrium(&model, State::initial(&model));
        assert!(report.stable, "{}", report.stability_words());
        assert_eq!(report.iterations, 0, "the form-found start is the equilibrium");
        for (c, name) in rigid.cable_names.iter().enumerate() {
            let k = model.cable_names.iter().position(|n| n == name).unwrap();
            let (a, b) = (rigid.initial_rest_lengths[c], model.initial_rest_lengths[k]);
            assert!((a - b).abs() < 1e-12, "{name}: rest length {a} against {b}");
        }
        assert!(largest_gap(&points(&rigid, &rigid_state), &points(&model, &state)) < 1e-12);
    }
    // a member's compression is the rigid half-bar's axial load: the hub joints' reactions on the
    // outer bars along their axes (tip forces balance them with the weights), checked through the
    // upper mast: its member carries the guys' and upper strings' downward pull at the top plus
    // half its own weight, as the bar's axis sees it
    let model = nodal(1e7, MassMatrixSpec::Consistent);
    let mut ws = Workspace::new(&model);
    evaluate(&model, &State::initial(&model), &mut ws, Tangents::None);
    let tension = |name: &str| ws.cables[model.cable_names.iter().position(|n| n == name).unwrap()].tension;
    let (guy, upper) = (tension("guy_left"), tension("upper_left"));
    let (guy_sin, upper_sin) = (2.0 / 2.5, 1.0 / (1.0f64 + 0.36).sqrt());
    let top_load = 2.0 * guy * guy_sin + 2.0 * upper * upper_sin + 0.25 * 9.81;
    let member = -tension("mast_upper");
    assert!((member - top_load).abs() < 1e-6 * top_load, "upper mast member {member} N against {top_load} N");
}

#[test]
fn a_sliding_upper_cable_leaves_the_hinged_hub_a_mechanism() {
    let mut spec = tbar(&TbarParams { hinged_hub: true, deploy_shortening: 0.0, ..Default::default() });
    spec.cables.retain(|c| !c.name.starts_with("upper"));
    let mut upper = spec_from_toml(
        "[[cables]]\nname = \"upper\"\nroute = [\"cross_left.b\", \"mast_upper.b\", \"cross_right.b\"]\nea = 2e4\n",
    )
    .cables
    .remove(0);
    upper.damping_ratio = Some(0.05);
    spec.cables.insert(0, upper);
    let model = model_of(&spec);
    let (_, report) = equilibrium(&model, State::initial(&model));
    assert!(report.negative_modes == 1 && !report.stable, "{}", report.stability_words());
    let (_, split) = equilibrium(&hinged(), State::initial(&hinged()));
    assert!(split.stable && split.min_stiffness_eigenvalue > 1e3, "{}", split.stability_words());
}

#[test]
fn the_nodal_equilibrium_converges_to_the_hinged_ones_at_order_one_in_stiffness() {
    // the schedule's end: the lower winch has hauled in 10 %
    let rigid = hinged();
    let (state, _) = equilibrium(&rigid, shortened(&rigid, "lower_left", 0.9));
    let reference = points(&rigid, &state);
    assert!(reference[2].y < 0.95 && reference[0].x > 0.01, "the cross bar tilts: {reference:?}");
    let mut errors = Vec::new();
    for ea in [1e6, 1e7, 1e8, 1e9] {
        let model = nodal(ea, MassMatrixSpec::Lumped);
        let (state, report) = equilibrium(&model, shortened(&model, "lower_left", 0.9));
        assert!(report.stable, "EA {ea:e}: {}", report.stability_words());
        errors.push(largest_gap(&points(&model, &state), &reference));
    }
    println!("statics, EA 1e6..1e9: {:?} m", errors.iter().map(|e| format!("{e:.2e}")).collect::<Vec<_>>());
    assert_first_order_in_stiffness(&errors, 0.05);
    assert!(errors[3] < 2e-6, "EA 1e9: {} m", errors[3]);
}

/// The compared points after `model` is released with its left lower string 3 % short and run
/// 0.2 s (generalized-alpha under error control).
fn released(model: Model) -> Vec<Vector3<f64>> {
    let settings = SimSettings { dt: 2e-3, tolerance: Some(1e-9), ..Default::default() };
    let state = shortened(&model, "lower_left", 0.97);
    let mut sim = Simulator::from_state(model, state, settings).unwrap();
    for _ in 0..100 {
        sim.step().unwrap();
    }
    let model = sim.model().clone();
    points(&model, sim.state())
}

#[test]
fn the_nodal_dynamics_with_consistent_mass_converge_to_the_hinged_tbars() {
    let reference = released(hinged());
    let start = points(&hinged(), &State::initial(&hinged()));
    assert!(largest_gap(&reference, &start) > 1e-2, "the release moves the structure");
    let mut errors = Vec::new();
    for ea in [1e6, 1e7, 1e8] {
        errors.push(largest_gap(&released(nodal(ea, MassMatrixSpec::Consistent)), &reference));
    }
    println!("dynamics, EA 1e6..1e8: {:?} m", errors.iter().map(|e| format!("{e:.2e}")).collect::<Vec<_>>());
    assert_first_order_in_stiffness(&errors, 0.1);
    assert!(errors[2] < 1e-5, "EA 1e8: {} m from the hinged T-bar after 0.2 s", errors[2]);
    // lumped mass gives each half-bar m l^2 / 4 about its middle, not m l^2 / 12: it misses
    let lumped = largest_gap(&released(nodal(1e8, MassMatrixSpec::Lumped)), &reference);
    println!("dynamics, lumped mass at EA 1e8: {lumped:.2e} m");
    assert!(lumped > 10.0 * errors[2], "lumped {lumped} m against consistent {} m", errors[2]);
}

#[test]
fn the_bundled_nodal_tbar_deploys_like_its_rigid_twin_within_its_members_shortening() {
    let path = |model: &Model| {
        let mut state = State::initial(model);
        let mut ws = Workspace::new(model);
        let mut rows = Vec::new();
        tensegrity::solve::deploy::deploy_quasi_static(model, &mut state, &mut ws, |_, s, w| {
            let shortening = (0..model.cables.len())
                .filter(|&c| !model.cables[c].tension_only)
                .map(|c| -w.cables[c].tension * w.cables[c].rest_length / model.cables[c].axial_stiffness)
                .fold(0.0, f64::max);
            rows.push((points(model, s), shortening));
        })
        .unwrap_or_else(|e| panic!("{e}"));
        rows
    };
    let rigid = path(&hinged());
    let nodal = path(&bundled("tbar_nodal.toml"));
    assert_eq!(rigid.len(), nodal.len());
    let (mut worst, mut largest_shortening) = (0.0f64, 0.0f64);
    for ((r, _), (n, shortening)) in rigid.iter().zip(&nodal) {
        let gap = largest_gap(r, n);
        worst = worst.max(gap);
        // the hub sits two members from the foot, the tips three: a few shortenings at most
        assert!(gap <= 4.0 * shortening + 1e-9, "gap {gap} m against a member shortening of {shortening} m");
        largest_shortening = largest_shortening.max(*shortening);
    }
    println!("nodal against hinged T-bar: largest gap {worst:.3e} m, largest member shortening {largest_shortening:.3e} m");
    assert!(largest_shortening > 1e-5, "the deployment loads the members: {largest_shortening} m");
}
