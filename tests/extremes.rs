//! Invariant: at the extremes the engine either stays stable and finite or refuses with a clear
//! error, and never lets a NaN into the state: cable stiffness up to EA/L0 = 1e9 N/m at
//! dt = 1e-3 s (generalized-alpha), a mass bouncing on a cable through thousands of slack/taut
//! switches without gaining energy, mass ratios of 1e6, and steps from 1e-6 s to 1e-1 s. The
//! first two hold at the default Newton tolerance, at 1e-6 and at the loosest one allowed
//! (`NEWTON_TOLERANCE_RANGE`; more of the looser tolerance in tests/newton_tolerance.rs).

mod common;

use common::*;
use std::path::PathBuf;
use tensegrity::scene::generate::{atwood, AtwoodParams};
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::{Integrator, DEFAULT_NEWTON_TOLERANCE, NEWTON_TOLERANCE_RANGE};

fn ga(rho_inf: f64, dt: f64) -> SimSettings {
    SimSettings { dt, integrator: Integrator::GeneralizedAlpha { rho_inf }, ..Default::default() }
}

/// The Newton tolerances the slack/taut extremes run at: the default, the one the benchmarks
/// trade for speed, the loosest.
const NEWTON_TOLERANCES: [f64; 3] = [DEFAULT_NEWTON_TOLERANCE, 1e-6, NEWTON_TOLERANCE_RANGE.1];

/// `ga` with Newton stopped at `newton` of the forces.
fn ga_newton(rho_inf: f64, dt: f64, newton: f64) -> SimSettings {
    let mut s = ga(rho_inf, dt);
    s.newton.tolerance = newton;
    s
}

#[test]
fn nearly_rigid_cables_stay_stable_at_a_millisecond_step() {
    for (k, newton) in [1e2, 1e5, 1e7, 1e9].into_iter().flat_map(|k| NEWTON_TOLERANCES.map(|n| (k, n))) {
        let model = model_of(&atwood(&AtwoodParams { stiffness: k, ..Default::default() }));
        let mut sim = Simulator::new(model, ga_newton(0.8, 1e-3, newton)).unwrap();
        let t_star = 2.0 * 2.0 * 1.0 * 9.81 / 3.0;
        let mut peak: f64 = 0.0;
        // 0.5 s: the light mass rises 0.41 m, still below its pulley (it would reach it at 0.78 s)
        for _ in 0..500 {
            let stats = sim.step().unwrap_or_else(|e| panic!("k = {k}, newton {newton}: {e}"));
            assert!(stats.residual.is_finite());
            assert!(sim.state().is_finite(), "k = {k}, newton {newton}");
            peak = peak.max(sim.workspace().cables[0].tension);
        }
        // the tension never exceeds twice its static value (the exact peak of T*(1 - cos))
        assert!(peak <= 2.0 * t_star * 1.01, "k = {k}, newton {newton}: peak tension {peak} N");
    }
}

#[test]
fn mass_bouncing_on_a_cable_switches_thousands_of_times_without_gaining_energy() {
    // a 1 kg node hanging from a fixed point on a 1 m cable, dropped from 1 mm above where the
    // cable tightens; no damping, rho_inf = 1 (no numerical dissipation)
    let text = r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "anchor"
kind = "fixed"
[[bodies]]
name = "m"
kind = "node"
mass = 1.0
position = [0.0, 0.0, -0.999]
[[cables]]
name = "bungee"
route = ["anchor", "m"]
ea = 1e4
rest_length = 1.0
"#;
    for newton in NEWTON_TOLERANCES {
        let model = model_from_toml(text);
        let mut sim = Simulator::new(model, ga_newton(1.0, 5e-4, newton)).unwrap();
        let e0 = sim.energy().total();
        let mut switches = 0;
        let mut slack = sim.workspace().cables[0].slack;
        let mut worst_gain: f64 = 0.0;
        while switches < 2000 {
            sim.step().unwrap();
            assert!(sim.state().is_finite());
            let now = sim.workspace().cables[0].slack;
            if now != slack {
                switches += 1;
                slack = now;
            }
            worst_gain = worst_gain.max(sim.energy().total() - e0);
            assert!(sim.state().time < 200.0, "newton {newton}: only {switches} switches");
        }
        // energy scale: the drop's potential energy m g h = 9.81e-3 J
        assert!(
            worst_gain <= 0.05 * 9.81e-3,
            "newton {newton}: energy gained {worst_gain} J over {switches} switches"
        );
    }
}

#[test]
fn mass_ratio_of_a_million_runs_finite() {
    let model = model_of(&atwood(&AtwoodParams { m1: 1e3, m2: 1e-3, ..Default::default() }));
    let mut sim = Simulator::new(model, ga(0.8, 1e-3)).unwrap();
    for _ in 0..500 {
        sim.step().unwrap();
        assert!(sim.state().is_finite());
    }
    // the heavy mass falls almost freely; the light one is yanked up
    let z_heavy = sim.state().poses[1].position.z;
    assert!(z_heavy < -1.0 - 0.9 * 0.5 * 9.81 * 0.25);
}

#[test]
fn steps_from_a_microsecond_to_a_tenth_of_a_second_work_or_fail_cleanly() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes/prism3.toml");
    let model = tensegrity::scene::load(&path).unwrap();
    for dt in [1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1] {
        let mut sim = Simulator::new(model.clone(), ga(0.8, dt)).unwrap();
        let steps = ((0.05 / dt).ceil() as usize).clamp(5, 2000);
        for _ in 0..steps {
            match sim.step() {
                Ok(stats) => assert!(stats.residual.is_finite()),
                Err(e) => {
                    // a clear error, and the state stays at the last good step
                    assert!(!e.to_string().is_empty());
                    break;
                }
            }
            assert!(sim.state().is_finite(), "dt = {dt}");
        }
    }
    // at dt = 0.1 s the implicit method must actually work through the whole deployment
    let mut sim = Simulator::new(model, ga(0.8, 0.1)).unwrap();
    for _ in 0..20 {
        sim.step().unwrap();
    }
    assert!(sim.workspace().cables.iter().all(|c| c.tension.is_finite() && c.tension > 0.0));
}
