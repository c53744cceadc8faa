//! Invariant: a member with `mass_matrix = "consistent"` carries the uniform bar element's
//! consistent mass matrix `(m/6) [[2 I, I], [I, 2 I]]` on its end nodes, everywhere the mass
//! matrix enters (implicit and explicit integrators, dense and sparse systems, kinetic energy,
//! Rayleigh damping, natural modes), and leaves weight and momentum as lumped mass has them.
//! - The assembled mass matrix is the sum of the element matrices, and the kinetic energy is
//!   `v^T M v / 2` with it.
//! - A free-free chain's first axial frequency equals the consistent chain's closed form
//!   `sqrt(6 k / m_e (1 - cos t) / (2 + cos t))`, `t = pi / n`, and converges at order 2 from
//!   above to `(1 / 2L) sqrt(EA / (m / L))` (within 1e-4 when refined).
//! - A spinning member turns at the uniform bar's rate (inertia `m L^2 / 12`) under every
//!   integrator and linear backend, and keeps its energy.
//! - The nodal prism with consistent mass converges to the rigid-strut prism itself (bars of
//!   inertia `m l^2 / 12`) as strut EA grows, where lumped mass converges to bars of `m l^2 / 4`.
//! - Rayleigh's `alpha M` with the coupled mass matrix closes the energy account.
//! - A consistent mass matrix without a mass, or an unknown kind, is refused naming the field.

mod common;

use common::*;
use nalgebra::{DMatrix, DVector};
use tensegrity::evaluate::{evaluate, kinetic_energy, Tangents, Workspace};
use tensegrity::scene::generate::{prism, PrismParams};
use tensegrity::scene::MassMatrixSpec;
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::{mass_matrix, Integrator};
use tensegrity::solve::linear::LinearBackend;
use tensegrity::solve::modes::natural_modes;
use tensegrity::{Model, State};

#[test]
fn the_mass_matrix_is_the_sum_of_the_element_matrices_and_weighs_the_kinetic_energy() {
    let (n, mass) = (3, 1.2);
    let model = member_chain(n, mass, 1.5, 1e4, "consistent");
    let m = mass_matrix(&model);
    // planar nodes: two coordinates each
    let mut expected = DMatrix::zeros(2 * (n + 1), 2 * (n + 1));
    let me = mass / n as f64;
    for k in 0..n {
        for (r, c, w) in [(k, k, 2.0), (k + 1, k + 1, 2.0), (k, k + 1, 1.0), (k + 1, k, 1.0)] {
            for d in 0..2 {
                expected[(2 * r + d, 2 * c + d)] += w * me / 6.0;
            }
        }
    }
    assert!((&m - &expected).amax() < 1e-15, "{m} against {expected}");
    // its rows sum to the lumped masses: the weight is the lumped one
    for (k, body) in model.bodies.iter().enumerate() {
        let row: f64 = (0..m.ncols()).map(|c| m[(2 * k, c)]).sum();
        assert!((row - body.mass).abs() < 1e-15, "node {k}: row sum {row}, lumped {}", body.mass);
    }
    let v = DVector::from_fn(m.nrows(), |i, _| ((i * 7 + 3) % 5) as f64 - 2.0);
    let exact = 0.5 * v.dot(&(&m * &v));
    assert!((kinetic_energy(&model, &v) - exact).abs() < 1e-14 * exact);
    // lumped: diagonal, and the same matrix without a coupling
    let lumped = mass_matrix(&member_chain(n, mass, 1.5, 1e4, "lumped"));
    assert_eq!(lumped, DMatrix::from_diagonal(&lumped.diagonal()));
}

#[test]
fn the_first_axial_mode_of_a_consistent_chain_converges_at_order_two_from_above() {
    let (mass, length, ea): (f64, f64, f64) = (3.0, 2.0, 2e5);
    let continuum = (1.0 / (2.0 * length)) * (ea / (mass / length)).sqrt();
    let mut errors = Vec::new();
    for n in [8usize, 16, 32, 64, 128] {
        let model = member_chain(n, mass, length, ea, "consistent");
        let modes = natural_modes(&model, &State::initial(&model)).expect("modes");
        let first = modes.iter().find(|m| !m.zero).expect("an axial mode");
        let (k, m_e, t) = (ea / (length / n as f64), mass / n as f64, std::f64::consts::PI / n as f64);
        let discrete =
            (6.0 * k / m_e * (1.0 - t.cos()) / (2.0 + t.cos())).sqrt() / (2.0 * std::f64::consts::PI);
        assert!(
            (first.frequency_hz - discrete).abs() < 1e-9 * discrete,
            "n {n}: {} Hz against the consistent chain's {discrete}",
            first.frequency_hz
        );
        errors.push((first.frequency_hz - continuum) / continuum);
    }
    for w in errors.windows(2) {
        let order = (w[0] / w[1]).log2();
        assert!((order - 2.0).abs() < 0.01, "observed order {order} from errors {errors:?}");
    }
    // consistent mass errs high, lumped low, both by about (pi / n)^2 / 24
    assert!(errors[4] > 0.0 && errors[4] < 1e-4, "128 elements: relative error {}", errors[4]);
}

/// A free member of mass `m` and length `l` along x in the xy plane (no gravity), its ends
/// moving at -v and +v along y: it spins about its middle at `omega = 2 v / l`.
fn spinning_member(kind: &str) -> (Model, State) {
    let model = model_from_toml(&format!(
        r#"
gravity = [0.0, 0.0, 0.0]
[[bodies]]
name = "a"
kind = "node"
position = [-0.5, 0.0, 0.0]
[[bodies]]
name = "b"
kind = "node"
position = [0.5, 0.0, 0.0]
[[members]]
name = "strut"
ends = ["a", "b"]
ea = 1e9
mass = 3.0
mass_matrix = "{kind}"
"#
    ));
    let mut state = State::initial(&model);
    state.velocities[1] = -0.5;
    state.velocities[4] = 0.5;
    (model, state)
}

#[test]
fn a_spinning_member_turns_with_the_uniform_bars_inertia_under_every_integrator() {
    let (m, l, v) = (3.0, 1.0, 0.5);
    let omega = 2.0 * v / l;
    let (model, state) = spinning_member("consistent");
    // T = I omega^2 / 2 with I = m l^2 / 12 (lumped: m v^2, three times more)
    let uniform = 0.5 * (m * l * l / 12.0) * omega * omega;
    assert!((kinetic_energy(&model, &state.velocities) - uniform).abs() < 1e-15);
    let (lumped, lumped_state) = spinning_member("lumped");
    assert!((kinetic_energy(&lumped, &lumped_state.velocities) - 3.0 * uniform).abs() < 1e-15);
    let duration = 0.5;
    let cases = [
        (Integrator::GeneralizedAlpha { rho_inf: 1.0 }, LinearBackend::Dense, 1e-4),
        (Integrator::GeneralizedAlpha { rho_inf: 1.0 }, LinearBackend::Sparse, 1e-4),
        (Integrator::Rk4, LinearBackend::Dense, 1e-6),
        (Integrator::Rk4, LinearBackend::Sparse, 1e-6),
        (Integrator::SymplecticEuler, LinearBackend::Dense, 1e-6),
    ];
    for (integrator, linear, dt) in cases {
        let settings = SimSettings { dt, integrator, linear, ..Default::default() };
        let mut sim = Simulator::from_state(model.clone(), state.clone(), settings).unwrap();
        let steps = (duration / dt).round() as usize;
        for _ in 0..steps {
            sim.step().unwrap();
        }
        let s = sim.state();
        let axis = s.poses[1].position - s.poses[0].position;
        let angle = axis.y.atan2(axis.x);
        // the member turns at omega; centrifugal stretch (m omega^2 l / 12 over EA / l) is 2.5e-10
        let tolerance = if integrator == Integrator::SymplecticEuler { 1e-6 } else { 1e-8 };
        assert!(
            (angle - omega * duration).abs() < tolerance,
            "{integrator:?} {linear:?}: turned {angle} rad, the uniform bar {}",
            omega * duration
        );
        let drift = (sim.energy().total() - uniform).abs() / uniform;
        assert!(drift < 1e-6, "{integrator:?} {linear:?}: energy drift {drift:e}");
        // the middle stays put: momentum is the lumped one, zero
        let middle = (s.poses[0].position + s.poses[1].position) / 2.0;
        assert!(middle.norm() < 1e-12, "{integrator:?} {linear:?}: middle moved to {middle}");
    }
}

/// Positions of the three top ends after a side string is shortened by 3 % and released for
/// 0.2 s (generalized-alpha under error control).
fn released_prism_tops(model: Model, top: &str) -> Vec<nalgebra::Vector3<f64>> {
    let settings = SimSettings { dt: 2e-3, tolerance: Some(1e-9), ..Default::default() };
    let mut state = State::initial(&model);
    let c = model.cable_names.iter().position(|n| n == "side0").unwrap();
    state.rest_lengths[c] *= 0.97;
    let mut sim = Simulator::from_state(model, state, settings).unwrap();
    for _ in 0..100 {
        sim.step().unwrap();
    }
    let model = sim.model().clone();
    let mut ws = Workspace::new(&model);
    evaluate(&model, sim.state(), &mut ws, Tangents::None);
    (0..3).map(|i| ws.points[model.point_id(&format!("bar0_{i}{top}")).unwrap().0].position).collect()
}

#[test]
fn the_nodal_prism_with_consistent_mass_converges_to_the_rigid_prism_itself() {
    let reference = released_prism_tops(model_of(&prism(&PrismParams::default())), ".b");
    let nodal = |ea: f64, mass_matrix: MassMatrixSpec| {
        model_of(&prism(&PrismParams {
            nodal_strut_ea: Some(ea),
            nodal_mass_matrix: mass_matrix,
            ..Default::default()
        }))
    };
    let mut errors = Vec::new();
    for ea in [1e6, 1e7, 1e8] {
        let tops = released_prism_tops(nodal(ea, MassMatrixSpec::Consistent), "_b");
        errors.push((0..3).map(|i| (tops[i] - reference[i]).norm()).fold(0.0, f64::max));
    }
    println!(
        "consistent mass, EA 1e6..1e8: {:?} m",
        errors.iter().map(|e| format!("{e:.2e}")).collect::<Vec<_>>()
    );
    for w in errors.windows(2) {
        let order = (w[0] / w[1]).log10();
        assert!((order - 1.0).abs() < 0.15, "observed order {order} in 1/EA from {errors:?}");
    }
    assert!(errors[2] < 5e-5, "EA 1e8: {} m from the rigid prism after 0.2 s", errors[2]);
    // lumped mass misses the same rigid prism by the inertia it puts at the ends
    let tops = released_prism_tops(nodal(1e8, MassMatrixSpec::Lumped), "_b");
    let lumped = (0..3).map(|i| (tops[i] - reference[i]).norm()).fold(0.0, f64::max);
    println!("lumped mass, EA 1e8: {lumped:.3e} m");
    assert!(lumped > 10.0 * errors[2], "lumped {lumped} m against consistent {} m", errors[2]);
}

#[test]
fn rayleigh_damping_on_the_coupled_mass_matrix_closes_the_energy_account() {
    let mut text = String::from(
        "gravity = [0.0, -9.81, 0.0]\n[damping]\nalpha = 0.8\n[[bodies]]\nname = \"ground\"\nkind = \"fixed\"\n",
    );
    for k in 1..=4 {
        text += &format!(
            "[[bodies]]\nname = \"n{k}\"\nkind = \"node\"\nposition = [{}, {}, 0.0]\n",
            0.4 * k as f64,
            -0.1 * k as f64
        );
    }
    for k in 0..4 {
        let a = if k == 0 { "ground".to_string() } else { format!("n{k}") };
        text += &format!(
            "[[members]]\nname = \"m{k}\"\nends = [\"{a}\", \"n{}\"]\nea = 5e3\nmass = 0.3\nmass_matrix = \"consistent\"\n",
            k + 1
        );
    }
    // a pinned chain of members swinging down (a flexible pendulum)
    let model = model_from_toml(&text);
    let settings = SimSettings { dt: 1e-4, ..Default::default() };
    let mut sim = Simulator::from_state(model.clone(), State::initial(&model), settings).unwrap();
    for _ in 0..3000 {
        sim.step().unwrap();
    }
    let e = *sim.energy();
    assert!(e.damping_loss > 0.1 * e.kinetic, "alpha dissipated {} J", e.damping_loss);
    let scale = e.damping_loss.max(e.kinetic);
    assert!(e.numerical_loss().abs() < 1e-3 * scale, "unexplained {} J of {scale} J", e.numerical_loss());
}

#[test]
fn careless_consistent_mass_is_refused_naming_the_field() {
    let scene = |member_extra: &str| {
        format!(
            r#"
[[bodies]]
name = "a"
kind = "node"
mass = 1.0
position = [0.0, 0.0, 0.0]
[[bodies]]
name = "b"
kind = "node"
mass = 1.0
position = [1.0, 0.0, 0.0]
[[members]]
name = "strut"
ends = ["a", "b"]
ea = 1e4
{member_extra}
"#
        )
    };
    for (extra, field) in [
        ("mass_matrix = \"consistent\"", "members[0].mass_matrix"),
        ("mass = 1.0\nmass_matrix = \"diagonal\"", "mass_matrix"),
    ] {
        let err =
            tensegrity::scene::from_toml(&scene(extra), "careless.toml").expect_err("refused").to_string();
        assert!(err.contains("careless.toml") && err.contains(field), "{extra}: {err}");
    }
}
