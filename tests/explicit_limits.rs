//! Invariant: no explicit run diverges without a refusal or a stop. The stability limit counts
//! every cable as taut (`EA / L0`), also one that starts just taut at zero tension (the bundled
//! atwood scene; a mass hung at its cable's rest length), so a step above it is refused before
//! the run; a run that starts below the limit and diverges anyway, because its structure
//! stiffens (a winch hauling a hanging mass in to a twentieth of its cable), is stopped with
//! `StepError::Diverged` at its last good state, and no non-finite or blown-up number is ever
//! handed out.

mod common;

use tensegrity::sim::{SimSettings, Simulator, StepError};
use tensegrity::solve::dynamics::{explicit_stability_limit, Integrator};
use tensegrity::State;

const EXPLICIT: [Integrator; 3] = [Integrator::SymplecticEuler, Integrator::Rk4, Integrator::DormandPrince];

fn settings(integrator: Integrator, dt: f64) -> SimSettings {
    SimSettings { dt, integrator, ..Default::default() }
}

#[test]
fn the_atwood_rope_starting_at_zero_tension_limits_the_explicit_step() {
    let model = common::bundled("atwood");
    // omega = sqrt(k (1/m1 + 1/m2)) = 38.7298 rad/s: symplectic Euler's limit 2 / omega
    let limit = explicit_stability_limit(&model, &State::initial(&model), Integrator::SymplecticEuler);
    assert!((limit - 2.0 / 38.7298).abs() < 1e-4, "limit {limit} s");
    for integrator in EXPLICIT {
        match Simulator::new(model.clone(), settings(integrator, 0.1)) {
            Err(StepError::UnstableExplicitStep { .. }) => {}
            other => panic!("{}: dt 0.1 s was not refused: {:?}", integrator.name(), other.map(|_| ())),
        }
        // below the limit the run is stable: 5 s of it, the rope going slack and taut, keep the
        // energy error below the energy a 1 m drop of the heavier mass releases
        let dt = 0.5 * explicit_stability_limit(&model, &State::initial(&model), integrator);
        let mut sim = Simulator::new(model.clone(), settings(integrator, dt)).unwrap();
        let scale = 2.0 * 9.81 * 1.0;
        while sim.state().time < 5.0 {
            sim.step().unwrap_or_else(|e| panic!("{}: {e}", integrator.name()));
        }
        let drift = sim.energy().numerical_loss().abs();
        assert!(drift < scale, "{}: energy error {drift} J at dt {dt} s", integrator.name());
    }
}

/// A 1 kg mass hung from a hook on a cable of EA 1000 N, rest length 1 m, placed at exactly the
/// rest length (just taut, zero tension); with a winch that hauls it in to `haul_to` m over 2 s.
fn hung_mass(haul_to: f64) -> tensegrity::Model {
    let text = format!(
        "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"ground\"\nkind = \"fixed\"\npoints = {{ hook = [0.0, 0.0, 0.0] }}\n[[bodies]]\nname = \"bob\"\nkind = \"node\"\nmass = 1.0\nposition = [0.0, 0.0, -1.0]\n[[cables]]\nname = \"cable\"\nroute = [\"ground.hook\", \"bob\"]\nea = 1000.0\nrest_length = 1.0\n[[actuators]]\nname = \"winch\"\ncable = \"cable\"\nmin_rest_length = 0.01\nmax_rest_length = 2.0\nmax_rate = 1.0\n[deployment]\nsteps = 10\n[[deployment.ramps]]\nactuator = \"winch\"\nstart = 0.0\nduration = 2.0\nrest_length = {haul_to}\n"
    );
    tensegrity::scene::from_toml(&text, "hung mass").unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn a_mass_hung_just_taut_limits_the_explicit_step() {
    let model = hung_mass(1.0);
    // omega = sqrt(EA / L0 / m) = 31.62 rad/s, though the cable starts at zero tension
    let limit = explicit_stability_limit(&model, &State::initial(&model), Integrator::SymplecticEuler);
    assert!((limit - 2.0 / 1000f64.sqrt()).abs() < 1e-6, "limit {limit} s");
    for integrator in EXPLICIT {
        assert!(
            matches!(
                Simulator::new(model.clone(), settings(integrator, 0.1)),
                Err(StepError::UnstableExplicitStep { .. })
            ),
            "{}: dt 0.1 s not refused",
            integrator.name()
        );
    }
}

#[test]
fn an_explicit_run_that_stiffens_past_its_limit_is_stopped_at_its_last_good_state() {
    // hauled in to a twentieth of its length, the cable is twenty times stiffer: the limits fall
    // by 4.5 (the Runge-Kutta methods' reach further along the imaginary axis than the
    // half-disk they are computed from, so they need that much)
    let model = hung_mass(0.05);
    for integrator in EXPLICIT {
        let dt = 0.9 * explicit_stability_limit(&model, &State::initial(&model), integrator);
        let mut sim = Simulator::new(model.clone(), settings(integrator, dt)).unwrap();
        let mut stopped = None;
        while sim.state().time < 3.0 {
            match sim.step() {
                Ok(_) => {
                    assert!(
                        sim.state().is_finite(),
                        "{}: a non-finite state was accepted",
                        integrator.name()
                    );
                }
                Err(e) => {
                    stopped = Some(e);
                    break;
                }
            }
        }
        let Some(StepError::Diverged { time, gain, scale, .. }) = stopped else {
            panic!("{}: the run was not stopped: {stopped:?} at t = {}", integrator.name(), sim.state().time)
        };
        assert!(
            gain > 10.0 * scale && time > 0.1,
            "{}: gain {gain} J, scale {scale} J at {time} s",
            integrator.name()
        );
        // the state is the last good one: finite, at the time the error names, its energy sane
        assert!(sim.state().is_finite() && sim.state().time == time);
        assert!(sim.energy().numerical_loss().abs() <= 10.0 * scale, "{}", integrator.name());
    }
}

/// `|R(z)|` of an explicit Runge-Kutta tableau applied to `y' = lambda y`, `z = h lambda`,
/// computed from its stages: `k_i = z (1 + sum_j a_ij k_j)`, `R = 1 + sum_i b_i k_i`.
fn amplification(tableau: &tensegrity::solve::dynamics::explicit::Tableau, z: nalgebra::Complex<f64>) -> f64 {
    let one = nalgebra::Complex::new(1.0, 0.0);
    let mut k: Vec<nalgebra::Complex<f64>> = Vec::new();
    for row in tableau.a.iter() {
        let sum = row.iter().zip(&k).fold(one, |s, (a, kj)| s + kj * *a);
        k.push(z * sum);
    }
    (one + tableau.b.iter().zip(&k).fold(nalgebra::Complex::new(0.0, 0.0), |s, (b, ki)| s + ki * *b)).norm()
}

#[test]
fn the_exact_stability_region_limits_an_undamped_oscillator_where_its_tableau_says() {
    // the hung mass with its cable counted taut: one undamped mode, eigenvalues +-i omega
    let model = hung_mass(1.0);
    let omega = 1000f64.sqrt();
    let state = State::initial(&model);
    use tensegrity::solve::dynamics::{explicit, stability_region_limit};
    // RK4 reaches 2 sqrt(2) on the imaginary axis, where its half-disk stops at 2.615
    let rk4 = stability_region_limit(&model, &state, Integrator::Rk4);
    assert!((rk4 * omega - 8f64.sqrt()).abs() < 1e-9, "RK4: h omega = {}", rk4 * omega);
    for (integrator, tableau) in
        [(Integrator::Rk4, &explicit::RK4), (Integrator::DormandPrince, &explicit::DOPRI5)]
    {
        let h = stability_region_limit(&model, &state, integrator);
        let at = |scale: f64| amplification(tableau, nalgebra::Complex::new(0.0, scale * h * omega));
        assert!((at(1.0) - 1.0).abs() < 1e-9, "{}: |R| {} at the limit", integrator.name(), at(1.0));
        assert!(at(0.99) < 1.0 && at(1.01) > 1.0, "{}: the limit is the region's edge", integrator.name());
    }
    // on the imaginary axis RK4's region reaches past its half-disk (2.828 against 2.615);
    // Dormand-Prince's leaves it at about 0.99, where its half-disk ends too
    assert!(rk4 > 1.05 * explicit_stability_limit(&model, &state, Integrator::Rk4));
    let dopri = stability_region_limit(&model, &state, Integrator::DormandPrince) * omega;
    assert!((0.95..1.0).contains(&dopri), "Dormand-Prince: h omega = {dopri}");
    // other integrators have no region to stay in
    assert_eq!(stability_region_limit(&model, &state, Integrator::SymplecticEuler), f64::INFINITY);
}
