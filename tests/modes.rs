//! Invariant: `natural_modes` gives the small free oscillations about an equilibrium. The
//! equal-mass elastic Atwood machine has its stretch mode at `sqrt(k (1/m1 + 1/m2))`, its four
//! pendulum modes at `sqrt(T / (m l))`, and one zero-frequency sliding mode in which the cable's
//! segments change while its length does not; a free prism has 6 zero-frequency modes; the
//! period of the bundled prism's lowest mode matches an undamped dynamic run started along it; and
//! a point mass between two taut collinear cables (whose equilibrium solve used to panic: its
//! spin about the cable line moves nothing) has its axial and string frequencies.

use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::scene::generate::{atwood, AtwoodParams};
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::{mass_matrix, Integrator};
use tensegrity::solve::modes::natural_modes;
use tensegrity::solve::statics::StaticSolver;
use tensegrity::{Model, State};

mod common;
use common::knot_between_cables;

fn equilibrium(model: &Model) -> State {
    let mut state = State::initial(model);
    let mut ws = Workspace::new(model);
    StaticSolver::new(model).equilibrate(model, &mut state, &mut ws, &model.solver).expect("equilibrium");
    state
}

#[test]
fn the_atwood_machine_has_its_closed_form_frequencies_and_a_sliding_zero_mode() {
    for (m, k) in [(1.0, 1000.0), (5.0, 1e2), (0.3, 1e6)] {
        let spec = atwood(&AtwoodParams { m1: m, m2: m, stiffness: k, ..Default::default() });
        let model = tensegrity::scene::build_model(&spec, "<atwood>", None).unwrap();
        let state = equilibrium(&model);
        let modes = natural_modes(&model, &state).expect("modes");
        let two_pi = 2.0 * std::f64::consts::PI;
        let stretch = (k * (1.0 / m + 1.0 / m)).sqrt() / two_pi;
        let top = modes.last().unwrap();
        assert!((top.frequency_hz - stretch).abs() <= 1e-6 * stretch, "{} Hz vs {stretch}", top.frequency_hz);
        assert!(top.cable_stretch[0].abs() > 0.1, "the stretch mode stretches the rope");
        // pendulums: each mass on its segment, T = m g
        let mut ws = Workspace::new(&model);
        evaluate(&model, &state, &mut ws, Tangents::None);
        let segment = ws.cables[0].length - 0.2; // the 0.2 m between the two pulleys
        let pendulum = (9.81 / (segment / 2.0)).sqrt() / two_pi;
        let pendulums: Vec<f64> =
            modes.iter().filter(|md| !md.zero).map(|md| md.frequency_hz).take(4).collect();
        for f in &pendulums {
            assert!((f - pendulum).abs() <= 1e-6 * pendulum, "pendulum {f} Hz vs {pendulum}");
        }
        let zero: Vec<_> = modes.iter().filter(|md| md.zero).collect();
        assert_eq!(zero.len(), 1, "one sliding mode");
        assert!(zero[0].cable_stretch[0].abs() < 1e-6 && zero[0].segment_change[0] > 0.1, "it slides");
    }
}

#[test]
fn the_prisms_lowest_mode_has_the_period_of_an_undamped_dynamic_run() {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes/prism3.toml");
    let mut model = tensegrity::scene::load(&path).unwrap();
    for c in &mut model.cables {
        c.damping = 0.0;
    }
    model.schedule.ramps.clear(); // no actuation: a free oscillation
    let mut state = equilibrium(&model);
    let modes = natural_modes(&model, &state).unwrap();
    let lowest = modes.iter().find(|m| !m.zero).unwrap();
    let period = 1.0 / lowest.frequency_hz;
    // start at the equilibrium with a small velocity along the mode and watch its coordinate
    let amplitude = 1e-4;
    state.velocities = &lowest.shape * amplitude;
    let dt = period / 400.0;
    let settings =
        SimSettings { dt, integrator: Integrator::GeneralizedAlpha { rho_inf: 1.0 }, ..Default::default() };
    let mut sim = Simulator::from_state(model.clone(), state, settings).unwrap();
    let m = mass_matrix(&model);
    let modal = |s: &Simulator| (lowest.shape.transpose() * &m * &s.state().velocities)[(0, 0)];
    let (mut crossings, mut previous) = (Vec::new(), modal(&sim));
    while crossings.len() < 5 {
        let t0 = sim.state().time;
        sim.step().unwrap();
        let now = modal(&sim);
        if previous > 0.0 && now <= 0.0 || previous < 0.0 && now >= 0.0 {
            crossings.push(t0 + dt * previous / (previous - now));
        }
        previous = now;
        assert!(sim.state().time < 10.0 * period, "no oscillation");
    }
    let measured = (crossings[4] - crossings[0]) / 2.0;
    println!("lowest mode: dynamic period {measured:.6} s, modal {period:.6} s");
    assert!((measured - period).abs() <= 1e-3 * period, "dynamic period {measured} s, modal {period} s");
}

#[test]
fn a_free_prism_has_six_zero_frequency_modes() {
    let model = common::free_prism();
    let modes = natural_modes(&model, &equilibrium(&model)).unwrap();
    assert_eq!(modes.iter().filter(|m| m.zero).count(), 6);
    assert!(modes.iter().all(|m| m.zero || m.frequency_hz > 0.5));
}

#[test]
fn a_mass_between_two_taut_cables_has_its_axial_and_string_frequencies() {
    // a knot of mass m between two collinear cables of length l, tension T, axial stiffness EA:
    // along the cables k = 2 EA / L0 (each cable's dT/dL), across them the string stiffness 2 T / l
    for (m, ea, t, l) in [(1.0f64, 1000.0f64, 50.0f64, 1.0f64), (0.2, 5e4, 300.0, 0.7), (3.0, 1e6, 10.0, 2.5)]
    {
        let l0 = ea * l / (ea + t);
        let model =
            knot_between_cables(l, m, ea, 0.0, &format!("prestress = {t}"), &format!("rest_length = {l0}"));
        let state = equilibrium(&model);
        let modes = natural_modes(&model, &state).expect("modes");
        assert_eq!(modes.len(), 3);
        let two_pi = 2.0 * std::f64::consts::PI;
        let across = (2.0 * t / (m * l)).sqrt() / two_pi;
        let along = (2.0 * ea / (l0 * m)).sqrt() / two_pi;
        for (mode, f) in modes.iter().zip([across, across, along]) {
            assert!(!mode.zero);
            assert!((mode.frequency_hz - f).abs() <= 1e-8 * f, "{} Hz vs {f} Hz", mode.frequency_hz);
        }
        // the axial mode stretches one cable and shortens the other by the same amount
        let axial = &modes[2];
        assert!(
            (axial.cable_stretch[0] + axial.cable_stretch[1]).abs() < 1e-9 * axial.cable_stretch[0].abs()
        );
    }
}

/// The mode-shape drawing shows each vibrating mode at the same visible amplitude (a tenth of the
/// structure's size at its farthest point) over the equilibrium, and `tensegrity modes --plot`
/// writes it as PNG and SVG with the frequencies in the panel titles.
#[test]
fn mode_shapes_are_drawn_at_a_tenth_of_the_structures_size() {
    use tensegrity::plot::{mode_panels, MODE_DRAWING_AMPLITUDE};
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let model = tensegrity::scene::load(&root.join("config/scenes/prism3.toml")).unwrap();
    let state = equilibrium(&model);
    let modes = natural_modes(&model, &state).unwrap();
    let panels = mode_panels(&model, &state, &modes, 4);
    assert_eq!(panels.len(), 4);
    // bars drawn thick, cables thin, the same segments in both configurations
    let struts = panels[0].reference.iter().filter(|s| s.strut).count();
    assert_eq!(struts, 3, "three bars");
    assert_eq!(panels[0].reference.len(), panels[0].displaced.len());
    // the clustered ring's pulleys drawn, axes named in metres, the exaggeration known
    use tensegrity::plot::Mark;
    let pulleys = panels[0].reference_marks.iter().filter(|m| matches!(m, Mark::Pulley(_))).count();
    assert_eq!(pulleys, model.route(tensegrity::model::CableId(3)).len() - 2, "the ring's pulleys");
    assert!(panels[0].axes.0.ends_with("(m)") && panels[0].axes.1.ends_with("(m)"));
    assert!(panels[0].largest_displacement > 0.0);
    let ends = |p: &tensegrity::plot::StructurePanel| -> Vec<(f64, f64)> {
        p.displaced.iter().flat_map(|s| [s.from, s.to]).collect()
    };
    let rest: Vec<(f64, f64)> = panels[0].reference.iter().flat_map(|s| [s.from, s.to]).collect();
    let span = rest
        .iter()
        .flat_map(|a| rest.iter().map(move |b| ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt()))
        .fold(0.0, f64::max);
    for (panel, mode) in panels.iter().zip(modes.iter().filter(|m| !m.zero)) {
        assert!(panel.title.contains(&format!("{:.4} Hz", mode.frequency_hz)), "{}", panel.title);
        let moved = ends(panel)
            .iter()
            .zip(&rest)
            .map(|(a, b)| ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt())
            .fold(0.0, f64::max);
        // projected displacements are at most the 3-D ones, and visible
        assert!(
            moved > 0.02 * span && moved <= 1.01 * MODE_DRAWING_AMPLITUDE * span * 2.0,
            "{moved} of {span}"
        );
    }
    let dir = common::scratch("modes_plot");
    let base = dir.join("modes");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_tensegrity"))
        .args(["modes", "config/scenes/prism3.toml", "--count", "3", "--plot"])
        .arg(&base)
        .current_dir(root)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let svg = std::fs::read_to_string(base.with_extension("svg")).unwrap();
    assert!(svg.contains("mode 1: 1.1603 Hz") && svg.contains("mode 3:"), "panel titles");
    assert!(svg.contains("farthest point moved") && svg.contains("(m)"), "exaggeration and axes in metres");
    assert!(std::fs::metadata(base.with_extension("png")).unwrap().len() > 1000);
}
