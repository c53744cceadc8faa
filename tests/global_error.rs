//! Invariant: global error control (`study::globally_controlled`, `deploy --dynamic --global-error`)
//! delivers the tolerance asked for on a run through unstable equilibria, where local error
//! control cannot.
//! - A bar pinned at its foot, released 0.01 rad off upright, swings over the top through the
//!   unstable upright position for 3 s: local control at 1e-5 and 1e-6 m delivers 50-130 times
//!   the tolerance against an RK4 reference (1e-5 s); global control at most the tolerance, and
//!   its estimate is within a factor 3 of the error it delivers.
//! - Where local control already meets the tolerance (a hanging, damped pendulum) it costs two
//!   runs and returns the finer one.
//! - Careless input: a tolerance that is not positive is refused; `--global-error` without
//!   `--tol` is refused by `deploy`.

mod common;

use common::*;
use tensegrity::sim::SimSettings;
use tensegrity::solve::dynamics::Integrator;
use tensegrity::study::{self, PointSamples, RunTotals};
use tensegrity::Model;

const FALLING_BAR: &str = r#"
planar = true
gravity = [0.0, -9.81, 0.0]
[[bodies]]
name = "bar"
kind = "bar"
mass = 1.0
ends = [[0.0, 0.0, 0.0], [0.01, 1.0, 0.0]]
[[joints]]
kind = "pin"
a = "bar.a"
"#;

/// Every point of `model` every 0.01 s for `duration` s, with `settings`.
fn samples(model: &Model, settings: SimSettings, duration: f64) -> Result<(PointSamples, RunTotals), String> {
    study::sampled_positions(model, settings, duration, 0.01)
}

fn controlled(tolerance: f64) -> SimSettings {
    SimSettings {
        dt: 0.01,
        integrator: Integrator::GeneralizedAlpha { rho_inf: 0.8 },
        tolerance: Some(tolerance),
        ..Default::default()
    }
}

#[test]
fn global_control_delivers_its_tolerance_through_unstable_equilibria_where_local_control_cannot() {
    let model = model_from_toml(FALLING_BAR);
    let duration = 3.0;
    let reference_settings = SimSettings { dt: 1e-5, integrator: Integrator::Rk4, ..Default::default() };
    let (reference, _) = samples(&model, reference_settings, duration).unwrap();
    assert_eq!(reference.len(), 300);
    // it passes the upright position again: the tip goes below the foot and comes back up
    let tip_heights: Vec<f64> = reference.iter().map(|s| s[2].y).collect();
    assert!(tip_heights.iter().any(|&y| y < -0.9) && tip_heights.iter().skip(100).any(|&y| y > 0.9));
    for tolerance in [1e-5, 1e-6] {
        let (local, _) = samples(&model, controlled(tolerance), duration).unwrap();
        let local_error = study::largest_distance(&local, &reference, false);
        let global =
            study::globally_controlled(tolerance, false, |t| samples(&model, controlled(t), duration))
                .unwrap();
        let global_error = study::largest_distance(&global.samples, &reference, false);
        println!(
            "tolerance {tolerance:e} m: local {:.1} x, global {:.2} x (local tolerance {:e} m, {} runs, estimate {:.3e} m, error {global_error:.3e} m)",
            local_error / tolerance,
            global_error / tolerance,
            global.tolerance,
            global.runs,
            global.estimate
        );
        assert!(local_error > 30.0 * tolerance, "local control: {local_error:e} m at {tolerance:e} m");
        assert!(global_error <= tolerance, "global control: {global_error:e} m at {tolerance:e} m");
        assert!(global.estimate <= tolerance && global.runs >= 3, "{global:?}");
        let ratio = global.estimate / global_error;
        assert!(
            (1.0 / 3.0..=3.0).contains(&ratio),
            "estimate {} m against {global_error} m",
            global.estimate
        );
    }
}

#[test]
fn where_local_control_suffices_global_control_costs_two_runs() {
    // a damped pendulum hanging 0.3 rad from its equilibrium: a stable motion
    let model = model_from_toml(
        r#"
planar = true
gravity = [0.0, -9.81, 0.0]
[damping]
alpha = 0.5
[[bodies]]
name = "bar"
kind = "bar"
mass = 1.0
ends = [[0.0, 0.0, 0.0], [0.3, -0.95, 0.0]]
[[joints]]
kind = "pin"
a = "bar.a"
"#,
    );
    let mut tolerances = Vec::new();
    let global = study::globally_controlled(1e-5, false, |t| {
        tolerances.push(t);
        samples(&model, controlled(t), 2.0)
    })
    .unwrap();
    assert_eq!(global.runs, 2);
    assert_eq!(tolerances.len(), 2);
    assert!((global.tolerance - 1e-6).abs() < 1e-20 && global.estimate <= 1e-5, "{global:?}");
}

#[test]
fn careless_global_tolerances_are_refused() {
    for bad in [0.0, -1e-6, f64::NAN, f64::INFINITY] {
        let err =
            study::globally_controlled(bad, false, |_| Ok((Vec::new(), RunTotals::default()))).unwrap_err();
        assert!(err.contains("positive"), "{bad}: {err}");
    }
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_tensegrity"))
        .args(["deploy", "--dynamic", "config/scenes/atwood.toml", "--global-error", "--out", "-"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(said.contains("--global-error needs --tol"), "{said}");
}
