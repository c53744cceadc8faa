//! Invariant: an elastic member (`[[members]]`, or a cable with `tension_only = false`) is the
//! cable law without the clamp at zero: it pushes when compressed and never goes slack, its mass
//! is lumped half on each end, and the nodal (finite-element) models it makes match closed forms
//! and their rigid-strut twins.
//! - A bar hanging under its own weight, as a chain of members between nodes, has the closed-form
//!   displacement `u(X) = (rho g / EA)(L X - X^2 / 2)` at its nodes (exact for lumped loads).
//! - A two-bar truss under an apex load carries `N = -P / (2 sin theta)` in each bar, and its apex
//!   sits where the exact (geometrically nonlinear) balance puts it.
//! - A member pressed shorter pushes back and reports no slack: a mass launched along it moves as
//!   the linear oscillator's closed form, where a cable lets it coast; the energy balance holds.
//! - A free-free chain of `n` members has its first axial frequency at the lumped-mass chain's
//!   closed form `2 sqrt(k / m_e) sin(pi / 2n)`, converging at order 2 to the continuum's
//!   `(1 / 2L) sqrt(EA / (m / L))` (within 1e-4 at 128 elements).
//! - The nodal prism (struts as members, form-found like the rigid one) starts in the same
//!   equilibrium as the rigid-strut prism, its members carry the rigid struts' compression, and
//!   after a cable is shortened its equilibrium converges to the rigid prism's at order 1 in
//!   `1 / EA`; its dynamics converge to those of rigid bars of the same mass distribution.
//! - Careless scenes are refused, naming the field: a pushing cable with pulleys, a member's
//!   mass lumped on a bar, a compression beyond EA.

mod common;

use common::*;
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::scene::generate::{prism, PrismParams};
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::Integrator;
use tensegrity::solve::modes::natural_modes;
use tensegrity::solve::statics::StaticSolver;
use tensegrity::{Model, State};

fn equilibrium(model: &Model, mut state: State) -> State {
    let mut ws = Workspace::new(model);
    StaticSolver::new(model).equilibrate(model, &mut state, &mut ws, &model.solver).expect("equilibrium");
    state
}

fn position(model: &Model, state: &State, point: &str) -> nalgebra::Vector3<f64> {
    let mut ws = Workspace::new(model);
    evaluate(model, state, &mut ws, Tangents::None);
    ws.points[model.point_id(point).unwrap_or_else(|| panic!("no point {point}")).0].position
}

/// A vertical chain of `n` members of total mass `mass` and length `length`, top node pinned at
/// the origin, hanging along -z (gravity 9.81).
fn hanging_chain(n: usize, mass: f64, length: f64, ea: f64) -> String {
    let h = length / n as f64;
    let mut text = String::from("gravity = [0.0, 0.0, -9.81]\n");
    for k in 0..=n {
        text += &format!(
            "[[bodies]]\nname = \"n{k}\"\nkind = \"node\"\nposition = [0.0, 0.0, {}]\n",
            -(k as f64) * h
        );
    }
    text += "[[joints]]\nkind = \"pin\"\na = \"n0\"\n";
    for k in 0..n {
        text += &format!(
            "[[members]]\nname = \"m{k}\"\nends = [\"n{k}\", \"n{}\"]\nea = {ea:e}\nmass = {:e}\n",
            k + 1,
            mass / n as f64
        );
    }
    text
}

#[test]
fn a_bar_under_its_own_weight_has_the_closed_form_displacement_at_its_nodes() {
    let (n, mass, length, ea) = (10, 5.0, 2.0, 1e4);
    let model = model_from_toml(&hanging_chain(n, mass, length, ea));
    // nodes take their mass from the members: half a member at each end, a whole one inside
    assert!((model.bodies[n].mass - 0.25).abs() < 1e-15 && (model.bodies[3].mass - 0.5).abs() < 1e-15);
    let state = equilibrium(&model, State::initial(&model));
    let (rho, g) = (mass / length, 9.81);
    for k in 0..=n {
        let x = k as f64 * length / n as f64;
        let u = rho * g / ea * (length * x - x * x / 2.0);
        let z = position(&model, &state, &format!("n{k}")).z;
        assert!((z + x + u).abs() < 1e-12 * length, "node {k}: z {z} against {}", -(x + u));
    }
    // every member in tension, the top one carrying the whole weight below its top node
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::None);
    let top = ws.cables[0].tension;
    assert!((top - (mass - 0.5 * mass / n as f64) * g).abs() < 1e-9 * top, "top member {top} N");
}

/// Two massless members from supports at `(-a, 0)` and `(a, 0)` to an apex at `(0, h)` carrying
/// a point mass (planar, gravity -y).
fn two_bar_truss(a: f64, h: f64, ea: f64, load_mass: f64) -> Model {
    model_from_toml(&format!(
        r#"
planar = true
gravity = [0.0, -9.81, 0.0]
[[bodies]]
name = "ground"
kind = "fixed"
points = {{ left = [-{a}, 0.0, 0.0], right = [{a}, 0.0, 0.0] }}
[[bodies]]
name = "apex"
kind = "node"
mass = {load_mass}
position = [0.0, {h}, 0.0]
[[members]]
name = "left"
ends = ["ground.left", "apex"]
ea = {ea:e}
[[members]]
name = "right"
ends = ["apex", "ground.right"]
ea = {ea:e}
"#
    ))
}

#[test]
fn a_two_bar_truss_carries_the_textbook_forces_and_sits_at_the_exact_balance() {
    let (a, h, load_mass) = (1.5, 2.0, 10.0);
    let p = load_mass * 9.81;
    for ea in [1e4, 1e6, 1e9] {
        let model = two_bar_truss(a, h, ea, load_mass);
        let state = equilibrium(&model, State::initial(&model));
        let y = position(&model, &state, "apex").y;
        // exact balance: 2 N y / L = -P with N = EA (L - L0) / L0, L = sqrt(a^2 + y^2)
        let l0 = (a * a + h * h).sqrt();
        let balance = |y: f64| {
            let l = (a * a + y * y).sqrt();
            2.0 * ea * (l - l0) / l0 * y / l + p
        };
        let (mut lo, mut hi) = (0.5 * h, h);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if balance(mid) > 0.0 {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        assert!((y - lo).abs() < 1e-10 * h, "EA {ea}: apex at {y}, exact {lo}");
        // textbook (small deflection): N = -P / (2 sin theta), deflection P L / (2 EA sin^2)
        let sin = h / l0;
        let mut ws = Workspace::new(&model);
        evaluate(&model, &state, &mut ws, Tangents::None);
        let n = -p / (2.0 * sin);
        let delta = p * l0 / (2.0 * ea * sin * sin);
        let strain = delta / l0;
        for c in &ws.cables {
            assert!(c.tension < 0.0 && !c.slack, "a strut in compression pushes: {c:?}");
            assert!((c.tension - n).abs() < 3.0 * strain * n.abs() + 1e-9, "EA {ea}: N {} vs {n}", c.tension);
        }
        assert!(((h - y) - delta).abs() < 3.0 * strain * delta, "EA {ea}: deflection {} vs {delta}", h - y);
    }
}

#[test]
fn a_compressed_member_pushes_back_and_keeps_the_energy_balance() {
    // a node on a member from a support, launched toward it: along the member's line the member
    // is a linear spring, x(t) = L0 - (v0 / w) sin(w t), w = sqrt(EA / (L0 m)), pushing
    // (T < 0) through the first half period; a tension-only cable goes slack and lets it coast
    let text = |tension_only: bool| {
        format!(
            r#"
[[bodies]]
name = "ground"
kind = "fixed"
[[bodies]]
name = "mass"
kind = "node"
mass = 2.0
position = [1.0, 0.0, 0.0]
[[cables]]
name = "strut"
route = ["ground", "mass"]
ea = 1e3
rest_length = 1.0
tension_only = {tension_only}
"#
        )
    };
    let (v0, w): (f64, f64) = (0.5, (1e3f64 / 2.0).sqrt());
    for tension_only in [false, true] {
        let model = model_from_toml(&text(tension_only));
        let mut state = State::initial(&model);
        state.velocities[0] = -v0; // toward the support
        let settings = SimSettings {
            dt: 1e-4,
            integrator: Integrator::GeneralizedAlpha { rho_inf: 1.0 },
            ..Default::default()
        };
        let mut sim = Simulator::from_state(model, state, settings).unwrap();
        let e0 = sim.energy().total();
        let (mut least, mut most) = (0.0f64, 0.0f64);
        let mut largest_error = 0.0f64;
        for k in 1..=3000 {
            sim.step().unwrap();
            let c = sim.workspace().cables[0];
            (least, most) = (least.min(c.tension), most.max(c.tension));
            assert!(tension_only || !c.slack, "a member never goes slack");
            let t = k as f64 * 1e-4;
            let x = sim.state().poses[1].position.x;
            let exact = if tension_only { 1.0 - v0 * t } else { 1.0 - v0 / w * (w * t).sin() };
            assert!((x - exact).abs() < 1e-6, "t {t}: x {x} against {exact}");
            largest_error = largest_error.max((sim.energy().total() - e0).abs() / e0);
        }
        if tension_only {
            assert_eq!((least, most), (0.0, 0.0), "a cable shorter than its rest length carries nothing");
        } else {
            // the peak push and pull: EA / L0 times the amplitude v0 / w
            let peak = 1e3 * v0 / w;
            assert!(
                (least + peak).abs() < 1e-4 * peak && (most - peak).abs() < 1e-4 * peak,
                "{least} {most} vs {peak}"
            );
        }
        assert!(largest_error < 1e-6, "energy balance off by {largest_error:e} of the total");
    }
}

#[test]
fn the_first_axial_mode_of_a_free_free_member_converges_at_order_two() {
    let (mass, length, ea): (f64, f64, f64) = (3.0, 2.0, 2e5);
    let continuum = (1.0 / (2.0 * length)) * (ea / (mass / length)).sqrt();
    let mut errors = Vec::new();
    for n in [8usize, 16, 32, 64, 128] {
        let model = member_chain(n, mass, length, ea, "lumped");
        let state = State::initial(&model);
        let modes = natural_modes(&model, &state).expect("modes");
        let first = modes.iter().find(|m| !m.zero).expect("an axial mode");
        let (k, m_e) = (ea / (length / n as f64), mass / n as f64);
        let discrete = 2.0 * (k / m_e).sqrt() * (std::f64::consts::PI / (2.0 * n as f64)).sin()
            / (2.0 * std::f64::consts::PI);
        assert!(
            (first.frequency_hz - discrete).abs() < 1e-9 * discrete,
            "n {n}: {} Hz against the lumped chain's {discrete}",
            first.frequency_hz
        );
        errors.push((continuum - first.frequency_hz) / continuum);
    }
    for w in errors.windows(2) {
        let order = (w[0] / w[1]).log2();
        assert!((order - 2.0).abs() < 0.01, "observed order {order} from errors {errors:?}");
    }
    assert!(errors[4] > 0.0 && errors[4] < 1e-4, "128 elements: relative error {}", errors[4]);
}

/// The generated 3-prism in nodal form, struts of axial stiffness `ea` (N).
fn nodal_prism(ea: f64) -> Model {
    model_of(&prism(&PrismParams { nodal_strut_ea: Some(ea), ..Default::default() }))
}

/// `errors` at EA growing tenfold each: every pair falls by a factor 10 (order 1 in 1/EA) within
/// `slack` of the order.
fn assert_first_order_in_stiffness(errors: &[f64], slack: f64) {
    for w in errors.windows(2) {
        let order = (w[0] / w[1]).log10();
        assert!((order - 1.0).abs() < slack, "observed order {order} in 1/EA from {errors:?}");
    }
}

#[test]
fn the_nodal_prism_starts_in_the_rigid_prisms_equilibrium_with_its_struts_compression() {
    let rigid = model_of(&prism(&PrismParams::default()));
    let nodal = nodal_prism(1e6);
    assert!(nodal.cables.iter().filter(|c| !c.tension_only).count() == 3);
    let mut ws = Workspace::new(&nodal);
    let state = State::initial(&nodal);
    evaluate(&nodal, &state, &mut ws, Tangents::None);
    // the form-found start is an equilibrium: the free top nodes feel no force
    for i in 0..3 {
        let top = &nodal.bodies[nodal.body_id(&format!("bar0_{i}_b")).unwrap().0];
        let f = ws.force.rows(top.dof_offset, top.dof_count).amax();
        assert!(f < 1e-9 * 100.0, "top node {i}: residual {f} N");
    }
    // cables: the same rest lengths; struts: the rigid bars' axial force, as compression
    for (c, name) in rigid.cable_names.iter().enumerate() {
        let k = nodal.cable_names.iter().position(|n| n == name).unwrap();
        let (a, b) = (rigid.initial_rest_lengths[c], nodal.initial_rest_lengths[k]);
        assert!((a - b).abs() < 1e-12, "{name}: {a} vs {b}");
    }
    let struts: Vec<f64> = (0..nodal.cables.len())
        .filter(|&c| !nodal.cables[c].tension_only)
        .map(|c| ws.cables[c].tension)
        .collect();
    assert!(struts.iter().all(|t| *t < -100.0), "struts in compression: {struts:?}");
    assert!(struts.iter().all(|t| (t - struts[0]).abs() < 1e-9 * t.abs()), "symmetric: {struts:?}");
}

#[test]
fn the_nodal_prisms_equilibrium_converges_to_the_rigid_prisms_as_strut_ea_grows() {
    // shorten one side cable by 3 % and solve; compare the top ends
    let shortened = |model: &Model| {
        let mut state = State::initial(model);
        let c = model.cable_names.iter().position(|n| n == "side0").unwrap();
        state.rest_lengths[c] *= 0.97;
        equilibrium(model, state)
    };
    let rigid = model_of(&prism(&PrismParams::default()));
    let reference = shortened(&rigid);
    let tops: Vec<_> = (0..3).map(|i| position(&rigid, &reference, &format!("bar0_{i}.b"))).collect();
    let mut errors = Vec::new();
    for ea in [1e6, 1e7, 1e8, 1e9] {
        let nodal = nodal_prism(ea);
        let state = shortened(&nodal);
        let error = (0..3)
            .map(|i| (position(&nodal, &state, &format!("bar0_{i}_b")) - tops[i]).norm())
            .fold(0.0, f64::max);
        errors.push(error);
    }
    assert_first_order_in_stiffness(&errors, 0.1);
    assert!(errors[3] < 2e-6, "EA 1e9: {} m", errors[3]);
}

#[test]
fn the_nodal_prisms_dynamics_converge_to_rigid_bars_of_the_same_mass_distribution() {
    // lumped mass puts half a strut's mass at each end: a rigid bar of mass m with transverse
    // inertia m l^2 / 4 (instead of a uniform bar's m l^2 / 12) has the same kinetic energy
    let mut spec = prism(&PrismParams::default());
    for b in &mut spec.bodies {
        let [a, c] = b.ends.unwrap();
        let l2: f64 = (0..3).map(|k| (c[k] - a[k]).powi(2)).sum();
        b.inertia = Some(vec![b.mass.unwrap() * l2 / 4.0]);
    }
    let rigid = model_of(&spec);
    let run = |model: Model, top: &str| {
        let settings = SimSettings { dt: 2e-3, tolerance: Some(1e-9), ..Default::default() };
        let mut state = State::initial(&model);
        let c = model.cable_names.iter().position(|n| n == "side0").unwrap();
        state.rest_lengths[c] *= 0.97; // released out of balance
        let mut sim = Simulator::from_state(model, state, settings).unwrap();
        for _ in 0..100 {
            sim.step().unwrap();
        }
        let model = sim.model().clone();
        (0..3).map(|i| position(&model, sim.state(), &format!("bar0_{i}{top}"))).collect::<Vec<_>>()
    };
    let reference = run(rigid, ".b");
    let mut errors = Vec::new();
    for ea in [1e6, 1e7, 1e8] {
        let tops = run(nodal_prism(ea), "_b");
        errors.push((0..3).map(|i| (tops[i] - reference[i]).norm()).fold(0.0, f64::max));
    }
    assert_first_order_in_stiffness(&errors, 0.15);
    assert!(errors[2] < 5e-5, "EA 1e8: {} m after 0.2 s", errors[2]);
}

#[test]
fn careless_member_scenes_are_refused_naming_the_field() {
    let base = r#"
[[bodies]]
name = "ground"
kind = "fixed"
points = { a = [0.0, 0.0, 0.0], b = [2.0, 0.0, 0.0] }
[[bodies]]
name = "bar"
kind = "bar"
mass = 1.0
ends = [[0.0, 0.0, 1.0], [2.0, 0.0, 1.0]]
[[bodies]]
name = "n"
kind = "node"
mass = 1.0
position = [1.0, 0.0, 2.0]
"#;
    let cases = [
        (
            "[[cables]]\nname = \"c\"\nroute = [\"ground.a\", \"bar.a\", \"ground.b\"]\nea = 1e3\nrest_length = 1.0\ntension_only = false\n",
            "cables[0].tension_only",
            "pulleys",
        ),
        ("[[members]]\nname = \"m\"\nends = [\"bar.a\", \"n\"]\nea = 1e3\nmass = 1.0\n", "members[0].mass", "on the bar 'bar'"),
        ("[[members]]\nname = \"m\"\nends = [\"ground.a\", \"n\"]\nea = 1e3\nforce = -2e3\n", "members[0].force", "at least EA"),
        ("[[members]]\nname = \"m\"\nends = [\"ground.a\", \"nowhere\"]\nea = 1e3\n", "members[0].ends", "unknown body"),
        (
            "[[members]]\nname = \"m\"\nends = [\"ground.a\", \"n\"]\nea = 1e3\nrest_length = 1.0\nform_find = true\n",
            "members[0].form_find",
            "form_find",
        ),
        ("[[members]]\nname = \"m\"\nends = [\"ground.a\", \"n\"]\nea = -1.0\n", "members[0].ea", "EA"),
        ("[[members]]\nname = \"m\"\nends = [\"ground.a\"]\nea = 1.0\n", "members", ""),
        // a member whose ends coincide is a fault of its ends, not of its force
        ("[[members]]\nname = \"m\"\nends = [\"n\", \"n\"]\nea = 1e3\n", "members[0].ends", ""),
        (
            "[[bodies]]\nname = \"o\"\nkind = \"node\"\nmass = 1.0\nposition = [1.0, 0.0, 2.0]\n[[members]]\nname = \"m\"\nends = [\"n\", \"o\"]\nea = 1e3\n",
            "members[0].ends",
            "zero length at the initial geometry",
        ),
        // two collinear members form-found against each other: their common force is free
        (
            "[[bodies]]\nname = \"m\"\nkind = \"node\"\nmass = 1.0\nposition = [1.0, 0.0, 0.0]\n[[members]]\nname = \"left\"\nends = [\"ground.a\", \"m\"]\nea = 1e3\nform_find = true\n[[members]]\nname = \"right\"\nends = [\"m\", \"ground.b\"]\nea = 1e3\nform_find = true\n",
            "members",
            "cannot determine the forces of",
        ),
    ];
    for (extra, field, reason) in cases {
        let text = format!("{base}\n{extra}");
        let err = tensegrity::scene::from_toml(&text, "careless.toml").expect_err(extra);
        let shown = err.to_string();
        assert!(shown.contains("careless.toml") && shown.contains(field), "{extra}: {shown}");
        assert!(shown.contains(reason), "{extra}: {shown}");
    }
}

#[test]
fn the_bundled_nodal_prism_deploys_like_the_rigid_one_within_its_struts_shortening() {
    // quasi-static deployment of both bundled prisms: at every load step the nodal prism's top
    // ends lie within twice its struts' elastic shortening |N| L / EA of the rigid prism's
    let tops = |model: &Model, suffix: &str| {
        let mut state = State::initial(model);
        let mut ws = Workspace::new(model);
        let mut rows = Vec::new();
        tensegrity::solve::deploy::deploy_quasi_static(model, &mut state, &mut ws, |_, _, w| {
            let ends: Vec<_> = (0..3)
                .map(|i| w.points[model.point_id(&format!("bar0_{i}{suffix}")).unwrap().0].position)
                .collect();
            let shortening = (0..model.cables.len())
                .filter(|&c| !model.cables[c].tension_only)
                .map(|c| -w.cables[c].tension * w.cables[c].rest_length / model.cables[c].axial_stiffness)
                .fold(0.0, f64::max);
            rows.push((ends, shortening));
        })
        .unwrap_or_else(|e| panic!("{e}"));
        rows
    };
    let rigid = tops(&bundled("prism3.toml"), ".b");
    let nodal = tops(&bundled("prism3_nodal.toml"), "_b");
    assert_eq!(rigid.len(), nodal.len());
    let (mut worst, mut largest_shortening) = (0.0f64, 0.0f64);
    for ((r, _), (n, shortening)) in rigid.iter().zip(&nodal) {
        let gap = (0..3).map(|i| (r[i] - n[i]).norm()).fold(0.0, f64::max);
        assert!(gap <= 2.0 * shortening + 1e-9, "gap {gap} m against a strut shortening of {shortening} m");
        (worst, largest_shortening) = (worst.max(gap), largest_shortening.max(*shortening));
    }
    println!("nodal against rigid prism3: largest gap {worst:.3e} m, largest strut shortening {largest_shortening:.3e} m");
    assert!(largest_shortening > 1e-4, "the deployment loads the struts");
}
