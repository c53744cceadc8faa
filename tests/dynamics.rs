//! Invariants of the dynamic integrators:
//! - with no damping and no actuation total energy is conserved, and its drift shrinks with the
//!   step at the integrator's order (2 for generalized-alpha, 1 for symplectic Euler);
//! - with actuation and damping, actuator work minus damping loss equals the energy change;
//! - generalized-alpha converges at order 2 (within 0.2) on a smooth deployment;
//! - a free rigid body spinning about a non-principal axis keeps its angular momentum;
//! - very slow dynamic deployment approaches the quasi-static path, fast deployment overshoots it;
//! - the explicit integrator's stability limit is real and enforced;
//! - a run started at the static equilibrium stays at rest (and resets there), one started from
//!   the scene's sketch swings;
//! - generalized-alpha keeps a 1 ms step with cables up to EA/L = 1e9 N/m, and a run whose stiff
//!   cable snaps taut and slack within a step never holds more energy than it was given.

mod common;

use common::*;
use nalgebra::{DVector, Vector3};
use tensegrity::evaluate::Workspace;
use tensegrity::scene::generate::{prism, PrismParams};
use tensegrity::sim::{SimSettings, Simulator, StepError};
use tensegrity::solve::deploy::deploy_quasi_static;
use tensegrity::solve::dynamics::{stability_limit, Integrator};
use tensegrity::{Model, State};

/// prism3 without damping or schedule, released with its ring `shortening` short: it oscillates.
fn oscillating_prism(shortening: f64) -> Model {
    let mut model =
        model_of(&prism(&PrismParams { damping_ratio: 0.0, deploy_shortening: 0.0, ..Default::default() }));
    let ring = model.cable_id("ring").unwrap().0;
    model.initial_rest_lengths[ring] *= 1.0 - shortening;
    model
}

fn ga(rho_inf: f64, dt: f64) -> SimSettings {
    SimSettings { dt, integrator: Integrator::GeneralizedAlpha { rho_inf }, ..Default::default() }
}

/// Largest |E(t) - E(0)| over `duration` seconds.
fn energy_drift(model: &Model, settings: SimSettings, duration: f64) -> f64 {
    let mut sim = Simulator::new(model.clone(), settings).unwrap();
    let e0 = sim.energy().total();
    let steps = (duration / settings.dt).round() as usize;
    let mut worst: f64 = 0.0;
    for _ in 0..steps {
        sim.step().unwrap();
        worst = worst.max((sim.energy().total() - e0).abs());
    }
    worst
}

#[test]
fn energy_is_conserved_and_its_drift_shrinks_at_the_integrators_order() {
    let model = oscillating_prism(0.02);
    let e_scale = Simulator::new(model.clone(), ga(1.0, 1e-3)).unwrap().energy().elastic;
    let drifts: Vec<f64> =
        [2e-3, 1e-3, 5e-4].iter().map(|&dt| energy_drift(&model, ga(1.0, dt), 0.2)).collect();
    assert!(drifts[2] < 5e-3 * e_scale, "generalized-alpha drift {drifts:?} J of {e_scale} J");
    for w in drifts.windows(2) {
        let order = (w[0] / w[1]).log2();
        assert!((order - 2.0).abs() < 0.3, "generalized-alpha energy drift order {order} ({drifts:?})");
    }
    let limit = stability_limit(&model, &State::initial(&model));
    let dts = [limit / 8.0, limit / 16.0, limit / 32.0];
    let euler = |dt| SimSettings { dt, integrator: Integrator::SymplecticEuler, ..Default::default() };
    let drifts: Vec<f64> = dts.iter().map(|&dt| energy_drift(&model, euler(dt), 0.2)).collect();
    for w in drifts.windows(2) {
        let order = (w[0] / w[1]).log2();
        assert!((order - 1.0).abs() < 0.3, "symplectic Euler energy drift order {order} ({drifts:?})");
    }
}

#[test]
fn actuator_work_and_damping_loss_balance_the_energy_change() {
    // the bundled prism3: damped cables, ring shortened 10 % over 1 s
    let model = bundled("prism3.toml");
    let mut sim = Simulator::new(model, ga(1.0, 5e-4)).unwrap();
    while sim.state().time < 1.5 {
        sim.step().unwrap();
    }
    let e = *sim.energy();
    assert!(e.actuator_work > 1.0 && e.damping_loss > 0.0, "{e:?}");
    let unexplained = e.numerical_loss().abs();
    assert!(
        unexplained <= 1e-3 * e.actuator_work,
        "energy balance off by {unexplained} J of {} J work ({e:?})",
        e.actuator_work
    );
}

/// Body positions and velocities after `duration` of the bundled prism3 deployment.
fn prism_state_at(dt: f64, duration: f64) -> DVector<f64> {
    let mut sim = Simulator::new(bundled("prism3.toml"), ga(0.8, dt)).unwrap();
    for _ in 0..(duration / dt).round() as usize {
        sim.step().unwrap();
    }
    let s = sim.state();
    let mut out: Vec<f64> =
        s.poses.iter().flat_map(|p| p.position.iter().copied().collect::<Vec<_>>()).collect();
    out.extend(s.velocities.iter());
    DVector::from_vec(out)
}

#[test]
fn generalized_alpha_converges_at_second_order() {
    let dts = [4e-3, 2e-3, 1e-3, 5e-4];
    let sol: Vec<DVector<f64>> = dts.iter().map(|&dt| prism_state_at(dt, 0.4)).collect();
    let diffs: Vec<f64> = sol.windows(2).map(|w| (&w[0] - &w[1]).amax()).collect();
    let orders: Vec<f64> = diffs.windows(2).map(|w| (w[0] / w[1]).log2()).collect();
    for p in &orders {
        assert!((p - 2.0).abs() <= 0.2, "observed orders {orders:?} (differences {diffs:?})");
    }
}

#[test]
fn free_rigid_body_keeps_its_angular_momentum() {
    let text = r#"
[[bodies]]
name = "top"
kind = "rigid"
mass = 1.0
position = [0.0, 0.0, 0.0]
rotation = [0.3, 0.2, 0.1]
inertia = [0.2, 0.25, 0.3, 0.01, 0.0, 0.02]
"#;
    let model = model_from_toml(text);
    let mut state = State::initial(&model);
    state.velocities.copy_from_slice(&[0.0, 0.0, 0.0, 3.0, 1.0, 2.0]);
    let momentum = |s: &State| {
        let w = Vector3::new(s.velocities[3], s.velocities[4], s.velocities[5]);
        s.poses[0].rotation * (model.bodies[0].inertia * w)
    };
    let h0 = momentum(&state);
    let mut sim = Simulator::from_state(model.clone(), state, ga(0.9, 1e-3)).unwrap();
    let mut worst: f64 = 0.0;
    for _ in 0..3000 {
        sim.step().unwrap();
        worst = worst.max((momentum(sim.state()) - h0).norm() / h0.norm());
    }
    assert!(worst < 1e-3, "angular momentum drifted by {worst} (relative)");
}

/// Peak side-string tension of prism3's dynamic deployment with the ramp taking `duration` s.
fn dynamic_peak(duration: f64) -> f64 {
    let mut model = bundled("prism3.toml");
    model.schedule.ramps[0].duration = duration;
    let mut sim = Simulator::new(model, ga(0.8, 1e-3)).unwrap();
    let side = sim.model().cable_id("side0").unwrap().0;
    let mut peak: f64 = 0.0;
    while sim.state().time < duration + 0.5 {
        sim.step().unwrap();
        peak = peak.max(sim.workspace().cables[side].tension);
    }
    peak
}

#[test]
fn slow_deployment_approaches_quasi_static_and_fast_deployment_overshoots() {
    let model = bundled("prism3.toml");
    let side = model.cable_id("side0").unwrap().0;
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    let mut qs_peak: f64 = 0.0;
    deploy_quasi_static(&model, &mut state, &mut ws, |_, _, w| qs_peak = qs_peak.max(w.cables[side].tension))
        .unwrap();
    let deviations: Vec<f64> =
        [0.02, 0.2, 2.0, 8.0].iter().map(|&d| (dynamic_peak(d) - qs_peak) / qs_peak).collect();
    assert!(deviations[0] > 0.01, "fast deployment must overshoot: deviations {deviations:?}");
    assert!(
        deviations.windows(2).all(|w| w[1] < w[0]),
        "deviation must shrink as the ramp slows: {deviations:?}"
    );
    assert!(deviations[3].abs() < 0.01, "slow deployment within 1 % of quasi-static: {deviations:?}");
}

#[test]
fn explicit_step_above_the_stability_limit_is_refused_and_really_unstable() {
    // small oscillations: the limit is a property of the linearized system (large ones raise the
    // tensions, and with them omega_max, during the run)
    let model = oscillating_prism(2e-4);
    let limit = stability_limit(&model, &State::initial(&model));
    let euler = |dt| SimSettings { dt, integrator: Integrator::SymplecticEuler, ..Default::default() };
    match Simulator::new(model.clone(), euler(1.1 * limit)) {
        Err(StepError::UnstableExplicitStep { limit: l, .. }) => assert!((l - limit).abs() < 1e-12 * limit),
        other => panic!("expected a refusal, got {:?}", other.map(|_| ())),
    }
    // below the limit the energy stays bounded over many periods
    let e0 = Simulator::new(model.clone(), euler(0.9 * limit)).unwrap().energy().total();
    let short = energy_drift(&model, euler(0.95 * limit), 200.0 * limit);
    let long = energy_drift(&model, euler(0.95 * limit), 4000.0 * limit);
    assert!(
        long < 1.5 * short && long < 0.2 * e0.abs(),
        "bounded below the limit: drift {short} J then {long} J of {e0} J"
    );
    // and above it, integrating anyway (through the low-level API) blows up
    let mut dynamics =
        tensegrity::solve::dynamics::Dynamics::new(&model, tensegrity::solve::linear::LinearBackend::Auto);
    let mut state = State::initial(&model);
    assert!(dynamics.initialize(&model, &mut state));
    let rest = state.rest_lengths.clone();
    let mut grew = false;
    for _ in 0..20000 {
        match dynamics.step(
            &model,
            Integrator::SymplecticEuler,
            &Default::default(),
            &mut state,
            &rest,
            &rest,
            1.1 * limit,
            None,
        ) {
            Ok(_) if state.velocities.amax() < 1e6 => {}
            _ => {
                grew = true;
                break;
            }
        }
    }
    assert!(grew, "symplectic Euler above its limit should diverge");
}

#[test]
fn sparse_and_dense_factorizations_give_the_same_motion() {
    use tensegrity::solve::linear::LinearBackend;
    let model = bundled("tower.toml");
    let run = |linear| {
        let mut sim = Simulator::new(model.clone(), SimSettings { linear, ..ga(0.8, 2e-3) }).unwrap();
        assert_eq!(sim.linear_backend(), linear);
        for _ in 0..150 {
            sim.step().unwrap();
        }
        sim.state().clone()
    };
    let (dense, sparse) = (run(LinearBackend::Dense), run(LinearBackend::Sparse));
    for (a, b) in dense.poses.iter().zip(&sparse.poses) {
        assert!((a.position - b.position).norm() < 1e-9, "{} vs {}", a.position, b.position);
    }
    assert!((&dense.velocities - &sparse.velocities).amax() < 1e-7);
    // symplectic Euler: the dense backend projects through the joints' Schur complement, the
    // sparse one factors the whole symmetric matrix by LDL^T, and LU is the reference
    let euler = |linear| {
        let settings =
            SimSettings { dt: 2e-4, integrator: Integrator::SymplecticEuler, linear, ..Default::default() };
        let mut sim = Simulator::new(model.clone(), settings).unwrap();
        for _ in 0..1000 {
            sim.step().unwrap();
        }
        sim.state().clone()
    };
    let reference = euler(LinearBackend::SparseLu);
    for other in [euler(LinearBackend::Dense), euler(LinearBackend::Sparse)] {
        for (a, b) in reference.poses.iter().zip(&other.poses) {
            assert!((a.position - b.position).norm() < 1e-12, "{} vs {}", a.position, b.position);
        }
        assert!((&reference.multipliers - &other.multipliers).amax() < 1e-8 * reference.multipliers.amax());
    }
}

#[test]
fn long_runs_stay_on_the_constraint_manifold() {
    // the tower's 27 joint equations over 4 s of deployment and settling: generalized-alpha solves
    // them at position level (gap at round-off), symplectic Euler projects velocities and corrects
    // the O(h^2) gap every step, so its gap stays small and does not grow
    let model = bundled("tower.toml");
    for (settings, bound) in [
        (ga(0.8, 2e-3), 1e-11),
        (SimSettings { dt: 5e-4, integrator: Integrator::SymplecticEuler, ..Default::default() }, 1e-7),
    ] {
        let mut sim = Simulator::new(model.clone(), settings).unwrap();
        let (mut early, mut late): (f64, f64) = (0.0, 0.0);
        while sim.state().time < 4.0 {
            sim.step().unwrap();
            let gap = sim.workspace().constraint.amax();
            if sim.state().time < 2.0 {
                early = early.max(gap);
            } else {
                late = late.max(gap);
            }
        }
        assert!(early.max(late) < bound, "{:?}: joint gap {early} then {late} m", settings.integrator);
        assert!(
            late <= 2.0 * early.max(1e-15),
            "{:?}: joint gap grew from {early} to {late} m",
            settings.integrator
        );
    }
}

#[test]
fn a_run_started_at_equilibrium_stays_at_rest_where_one_from_the_sketch_swings() {
    // the README's scene: a pole and a box slung over a pulley, sketched away from equilibrium;
    // no actuation, so only the start differs
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/examples/readme.toml");
    let mut model = tensegrity::scene::load(&path).unwrap();
    model.schedule.ramps.clear();
    let settings = SimSettings { dt: 1e-3, ..Default::default() };
    let drift = |mut sim: Simulator| {
        let start = sim.state().poses.clone();
        let tensions = |s: &Simulator| s.workspace().cables.iter().map(|c| c.tension).collect::<Vec<f64>>();
        let first = tensions(&sim);
        let mut worst = 0.0f64;
        for _ in 0..200 {
            sim.step().unwrap();
            let moved = sim
                .state()
                .poses
                .iter()
                .zip(&start)
                .map(|(a, b)| (a.position - b.position).amax().max(a.rotation.angle_to(&b.rotation)))
                .fold(0.0, f64::max);
            worst = worst.max(moved);
        }
        let change = tensions(&sim).iter().zip(&first).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        (worst, change, sim)
    };
    let (still, tension_change, sim) = drift(Simulator::at_equilibrium(model.clone(), settings).unwrap());
    assert!(still < 1e-6, "from equilibrium the poses moved {still:.3e}");
    assert!(tension_change < 1e-3, "from equilibrium a tension changed {tension_change:.3e} N");
    assert!(sim.state().velocities.amax() < 1e-5);
    let (swing, _, _) = drift(Simulator::new(model.clone(), settings).unwrap());
    assert!(swing > 1e-2, "from the sketch the structure swings ({swing:.3e})");
    // reset comes back to the equilibrium, and `start` picks by its flag
    let mut sim = Simulator::start(model.clone(), settings, true).unwrap();
    let at_rest = sim.state().poses.clone();
    sim.step().unwrap();
    sim.reset();
    assert_eq!(sim.state().poses, at_rest);
}

/// The README's scene with both cables' EA set to `ea` (N), damping ratios kept.
fn readme_scene_with_ea(ea: f64) -> Model {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/examples/readme.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let text =
        text.replace("ea = 1000.0", &format!("ea = {ea:e}")).replace("ea = 500.0", &format!("ea = {ea:e}"));
    tensegrity::scene::from_toml(&text, "<readme, stiff>").unwrap()
}

#[test]
fn generalized_alpha_keeps_its_step_with_stiff_cables_and_its_energy_when_they_snap() {
    // from the equilibrium, the winch hauling the sling in over 1 s: a step of 1 ms whatever the
    // cables' stiffness (EA/L up to 1e9 N/m), no step rejected because a cable is stiff
    for ea in [1e3, 1e6, 1e9] {
        let model = readme_scene_with_ea(ea);
        let settings = SimSettings { dt: 1e-3, ..Default::default() };
        let mut sim = Simulator::at_equilibrium(model, settings).unwrap();
        let (mut newton, mut rejected) = (0, 0);
        for _ in 0..1000 {
            let s = sim.step().unwrap_or_else(|e| panic!("EA {ea:e}: {e}"));
            newton += s.newton_iterations;
            rejected += s.rejected;
        }
        assert!(rejected <= 2, "EA {ea:e}: {rejected} rejected attempts");
        assert!(newton <= 3000, "EA {ea:e}: {newton} Newton iterations in 1000 steps");
    }
    // from the sketch, the tail cable stretched 0.11 m at EA 1e7 (2.7e6 N): the weight snaps it
    // taut and slack faster than the step resolves, which pumped energy into the run until the
    // tensions passed 1e10 N and Newton failed; now such a sub-step is undone and retried in
    // halves, and the run holds no more than it started with and the winch gave it
    let model = readme_scene_with_ea(1e7);
    let settings = SimSettings { dt: 1e-3, ..Default::default() };
    let mut sim = Simulator::new(model, settings).unwrap();
    let start = sim.energy().total();
    // the guard's allowance: once the kinetic and elastic energy of the start, plus the weight's
    // release over the structure (3.5 kg over a few metres: under 100 J)
    let allowance = sim.energy().kinetic + sim.energy().elastic + 100.0;
    let start_tension = sim.workspace().cables.iter().map(|c| c.tension).fold(0.0, f64::max);
    let mut rejected = 0;
    for _ in 0..500 {
        rejected += sim.step().unwrap().rejected;
        let e = sim.energy();
        let gained = e.total() - start - e.actuator_work.abs();
        assert!(gained <= allowance + e.actuator_work.abs(), "gained {gained:e} J, allowed {allowance:e} J");
        let tension = sim.workspace().cables.iter().map(|c| c.tension).fold(0.0, f64::max);
        assert!(
            tension.is_finite() && tension < 10.0 * start_tension,
            "{tension:e} N from {start_tension:e} N"
        );
    }
    assert!(rejected > 0, "the guard had snapping to undo");
}
