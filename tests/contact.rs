//! Ground contact (`forces::contact`): the element's tangents against finite differences, closed
//! forms (a weight's rest penetration, a block sliding down an incline, sticking within the creep
//! bound), statics of a structure resting on the ground, bounces with and without dissipation and
//! the energy account, explicit stability limits that see the contact stiffness, and the scene
//! errors a careless user meets.

mod common;

use common::{fd_damping, fd_stiffness, model_from_toml, rel_err};
use nalgebra::{DVector, Vector3};
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::sim::{SimSettings, Simulator, StepError};
use tensegrity::solve::dynamics::{explicit_stability_limit, Integrator};
use tensegrity::solve::statics::StaticSolver;
use tensegrity::State;

const G: f64 = 9.81;

/// A node of `mass` kg at height `z` m on a ground tilted by `tilt` rad about x, with `ground`
/// the ground table's extra lines.
fn block_on_incline(mass: f64, tilt: f64, z: f64, ground: &str) -> tensegrity::Model {
    model_from_toml(&format!(
        "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"block\"\nkind = \"node\"\nmass = {mass}\n\
         position = [0.0, 0.0, {z}]\ncontact_radius = 0.0\n[[grounds]]\nnormal = [0.0, {ny}, {nz}]\n{ground}\n",
        ny = -tilt.sin(),
        nz = tilt.cos()
    ))
}

#[test]
fn contact_tangents_match_finite_differences() {
    // a rigid body with three contact spheres, a bar with its capsule and a node, on a tilted
    // ground with friction and dissipation; every sphere pressed in, slipping fast, slipping at
    // about the regularization speed, or stuck
    let model = three_bodies_on_a_tilted_ground("stiction_speed = 0.05");
    // lower each body along the normal until its lowest sphere presses in by half its radius
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::None);
    let ground = &model.grounds[0];
    for b in 0..model.bodies.len() {
        let lowest = model
            .contact_spheres
            .iter()
            .zip(&ws.contacts)
            .filter(|(s, _)| model.points[s.point.0].body.0 == b)
            .map(|(s, c)| c.gap + 0.5 * s.radius)
            .fold(f64::INFINITY, f64::min);
        state.poses[b].position -= ground.normal * lowest;
    }
    for (label, scale) in [("fast slip", 1.0), ("slip near v_s", 0.04), ("stuck", 0.0)] {
        state.velocities = DVector::from_fn(model.dof_count, |i, _| scale * (0.3 + 0.17 * i as f64).sin());
        evaluate(&model, &state, &mut ws, Tangents::StiffnessAndDamping);
        let touching = ws.contacts.iter().filter(|c| c.normal_force > 0.0).count();
        assert!(touching >= 3, "{label}: only {touching} contacts press in");
        let k_err = rel_err(&ws.stiffness, &fd_stiffness(&model, &state, 1e-7), 1.0);
        let c_err = rel_err(&ws.damping, &fd_damping(&model, &state, 1e-7), 1.0);
        assert!(k_err < 1e-6, "{label}: K differs from finite differences by {k_err:e}");
        assert!(c_err < 1e-6, "{label}: C differs from finite differences by {c_err:e}");
    }
}

#[test]
fn a_weight_rests_at_its_closed_form_penetration_and_the_ground_never_pulls() {
    // 2 kg on k = 1e4 N/m: delta = m g / k = 1.962 mm
    let model = block_on_incline(2.0, 0.0, 0.01, "stiffness = 1e4");
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    let report = StaticSolver::new(&model).equilibrate(&model, &mut state, &mut ws, &model.solver).unwrap();
    let z = state.poses[0].position.z;
    assert!((z + 2.0 * G / 1e4).abs() < 1e-12, "rest height {z} m");
    assert!(report.stable, "{}", report.stability_words());
    assert!((ws.contacts[0].normal_force - 2.0 * G).abs() < 1e-9);
    // lifted above the ground, the sphere feels nothing; pressed in and pulled out fast, nothing
    let mut lifted = State::initial(&model);
    lifted.poses[0].position.z = 0.001;
    evaluate(&model, &lifted, &mut ws, Tangents::Stiffness);
    assert_eq!(ws.contacts[0].normal_force, 0.0);
    assert_eq!(ws.stiffness.amax(), 0.0);
    lifted.poses[0].position.z = -0.001;
    lifted.velocities[2] = 5.0; // leaving at 5 m/s > 1 / dissipation
    evaluate(&model, &lifted, &mut ws, Tangents::Stiffness);
    assert_eq!(ws.contacts[0].normal_force, 0.0, "the ground pulled");
    assert!(ws.force[2] < 0.0, "only gravity acts");
}

#[test]
fn a_prism_resting_on_the_ground_carries_its_weight_on_its_bar_ends() {
    let mut spec = common::free_prism_spec();
    for b in &mut spec.bodies {
        b.contact_radius = Some(0.01);
    }
    spec.grounds.push(tensegrity::scene::GroundSpec {
        point: Some([0.0, 0.0, -0.01]),
        stiffness: Some(1e5),
        ..Default::default()
    });
    // form-found without weight, then stood on the ground
    let mut model = common::model_of(&spec);
    model.gravity = Vector3::new(0.0, 0.0, -G);
    let weight: f64 = model.bodies.iter().map(|b| b.mass).sum::<f64>() * G;
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    let report = StaticSolver::new(&model)
        .equilibrate(&model, &mut state, &mut ws, &model.solver)
        .unwrap_or_else(|e| panic!("no equilibrium: {e:?}"));
    let carried: f64 = ws.contacts.iter().map(|c| c.normal_force).sum();
    assert!((carried - weight).abs() < 1e-8 * weight, "ground carries {carried} N of {weight} N");
    let touching = ws.contacts.iter().filter(|c| c.normal_force > 0.0).count();
    assert_eq!(touching, 3, "the three lower ends stand, the upper ones are free");
    // free to slide and turn on a frictionless statics ground: 3 rigid-body modes, nothing else
    assert!(report.stable, "{}", report.stability_words());
    assert_eq!(report.rigid_modes, 3, "{}", report.stability_words());
}

/// Runs `model` for `seconds` with generalized-alpha at `dt`.
fn run(model: &tensegrity::Model, dt: f64, seconds: f64) -> Simulator {
    let mut sim = Simulator::new(model.clone(), SimSettings { dt, ..Default::default() }).unwrap();
    while sim.state().time < seconds - 1e-9 {
        sim.step().unwrap_or_else(|e| panic!("{e}"));
    }
    sim
}

/// A 1 kg block on a 30 degree incline at mu 0.3 (`law`: the ground's friction lines), started at
/// its normal equilibrium (no bounce): its acceleration down the slope from its speeds at 0.5 s
/// and 1 s (dt 0.5 ms), the closed form `g (sin 30 - 0.3 cos 30)`, and the run to 1 s.
fn slide_down_30_degrees(law: &str) -> (f64, f64, Simulator) {
    let tilt = 30f64.to_radians();
    let depth = G * tilt.cos() / 1e6;
    let model =
        block_on_incline(1.0, tilt, -depth / tilt.cos(), &format!("mu = 0.3\nstiffness = 1e6\n{law}"));
    let slope = Vector3::new(0.0, -tilt.cos(), -tilt.sin()); // downhill
    let v1 = run(&model, 5e-4, 0.5).state().velocities.fixed_rows::<3>(0).dot(&slope);
    let sim = run(&model, 5e-4, 1.0);
    let v2 = sim.state().velocities.fixed_rows::<3>(0).dot(&slope);
    ((v2 - v1) / 0.5, G * (tilt.sin() - 0.3 * tilt.cos()), sim)
}

#[test]
fn a_block_slides_down_a_steep_incline_at_the_coulomb_acceleration() {
    // 30 degrees, mu 0.3: a = g (sin 30 - 0.3 cos 30) = 2.356 m/s^2 along the slope
    let (a, expected, sim2) = slide_down_30_degrees("stiction_speed = 1e-4");
    println!(
        "slide: a = {a:.6} m/s^2, closed form {expected:.6} ({:.1e} relative)",
        (a - expected) / expected
    );
    assert!((a - expected).abs() < 1e-4 * expected, "a = {a} m/s^2, closed form {expected}");
    // energy: the friction's booked loss closes the account
    let e = sim2.energy();
    assert!(e.damping_loss > 0.0);
    assert!(e.numerical_loss().abs() < 1e-3 * e.damping_loss, "unexplained {} J", e.numerical_loss());
}

#[test]
fn a_cylinder_rolls_down_an_incline_without_slipping() {
    // a solid cylinder (radius 0.1 m, length 0.4 m, 1 kg; spheres of its radius at its end
    // faces' centres) across the fall line of a 30 degree incline, mu 0.5 > tan 30 / 3: it rolls
    // at a = g sin 30 / (1 + I / (m R^2)) = g sin 30 / 1.5 = 3.27 m/s^2, where sliding
    // would be g (sin 30 - mu cos 30) = 0.657 m/s^2
    let tilt = 30f64.to_radians();
    let (r, len, k) = (0.1, 0.4, 1e6);
    let depth = G * tilt.cos() / (2.0 * k);
    let n = Vector3::new(0.0, -tilt.sin(), tilt.cos());
    let centre = n * (r - depth);
    let (axial, transverse) = (0.5 * r * r, (3.0 * r * r + len * len) / 12.0);
    let model = model_from_toml(&format!(
        "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"roller\"\nkind = \"rigid\"\nmass = 1.0\n\
         position = [{}, {}, {}]\ninertia = [{axial}, {transverse}, {transverse}]\n\
         points = {{ left = [{h}, 0.0, 0.0], right = [-{h}, 0.0, 0.0] }}\ncontact_radius = {r}\n\
         contact_points = [\"left\", \"right\"]\n[[grounds]]\nnormal = [0.0, {}, {}]\nmu = 0.5\nstiffness = {k}\n",
        centre.x,
        centre.y,
        centre.z,
        n.y,
        n.z,
        h = len / 2.0
    ));
    let downhill = Vector3::new(0.0, -tilt.cos(), -tilt.sin());
    let speed = |t: f64| {
        let sim = run(&model, 5e-4, t);
        let v = sim.state().velocities.fixed_rows::<3>(0).dot(&downhill);
        let slip = sim.workspace().contacts[0].slip.norm();
        (v, slip)
    };
    let ((v1, _), (v2, slip)) = (speed(0.5), speed(1.0));
    let a = (v2 - v1) / 0.5;
    let expected = G * tilt.sin() / 1.5;
    println!("roll: a = {a:.6} m/s^2, closed form {expected:.6}; contact slip {slip:.1e} m/s at {v2:.3} m/s");
    assert!((a - expected).abs() < 1e-4 * expected, "a = {a} m/s^2, closed form {expected}");
    assert!(slip < 1e-4, "the contact point slips at {slip} m/s");
}

#[test]
fn a_block_on_an_incline_within_its_friction_cone_stays_put() {
    // 30 degrees, mu 0.6 > tan 30: at the default regularization speed of 1e-5 m/s the block creeps at
    // v_s r / sqrt(1 - r^2) = 3.5e-5 m/s (r = tan 30 / 0.6 = 0.962): less than 1e-4 m in 2 s
    let tilt = 30f64.to_radians();
    let depth = G * tilt.cos() / 1e6;
    let model =
        block_on_incline(1.0, tilt, -depth / tilt.cos(), "mu = 0.6\nstiffness = 1e6\nstiction_speed = 1e-5");
    let sim = run(&model, 1e-3, 2.0);
    let drift = (sim.state().poses[0].position - State::initial(&model).poses[0].position).norm();
    println!("stick on 30 degrees at mu 0.6: drift {drift:.2e} m in 2 s");
    assert!(drift < 1e-4, "drifted {drift} m in 2 s");
}

#[test]
fn a_block_on_a_gentle_incline_sticks_within_the_creep_bound() {
    // 20 degrees, mu 0.6: r = tan 20 / 0.6 = 0.607, creep v_s r / sqrt(1 - r^2) = 0.764 v_s
    let tilt = 20f64.to_radians();
    let v_s = 1e-3;
    // started pressed in by its normal load m g cos(tilt) / k, so that it does not bounce
    let depth = G * tilt.cos() / 1e6;
    let ground = format!("mu = 0.6\nstiffness = 1e6\nstiction_speed = {v_s}");
    let model = block_on_incline(1.0, tilt, -depth / tilt.cos(), &ground);
    let sim = run(&model, 1e-3, 1.0);
    let r = tilt.tan() / 0.6;
    let creep = v_s * r / (1.0 - r * r).sqrt();
    let speed = sim.state().velocities.fixed_rows::<3>(0).norm();
    println!("creep on 20 degrees at mu 0.6: {speed:.4e} m/s, bound {creep:.4e}");
    assert!((speed - creep).abs() < 1e-3 * creep, "creeps at {speed} m/s, bound {creep}");
    assert!((sim.workspace().contacts[0].slip.norm() - creep).abs() < 1e-3 * creep);
}

#[test]
fn a_dropped_ball_bounces_back_without_dissipation_and_loses_its_energy_with_it() {
    // from 0.1 m: impact at sqrt(2 g h) = 1.4007 m/s
    for (dissipation, restitution_range) in [(0.0, (0.99, 1.002)), (0.5, (0.3, 0.9))] {
        let text = format!("stiffness = 1e5\ndissipation = {dissipation}\nmu = 0.0");
        let model = block_on_incline(0.1, 0.0, 0.1, &text);
        let mut sim = Simulator::new(model, SimSettings { dt: 1e-4, ..Default::default() }).unwrap();
        let (mut top, mut left) = (0.0f64, false);
        let (mut lowest_total, mut largest_rise) = (sim.energy().total(), 0.0f64);
        while sim.state().time < 0.5 {
            sim.step().unwrap();
            let total = sim.energy().total();
            largest_rise = largest_rise.max(total - lowest_total);
            lowest_total = lowest_total.min(total);
            let z = sim.state().poses[0].position.z;
            left |= sim.workspace().contacts[0].normal_force > 0.0;
            if left && z > 0.0 {
                top = top.max(z);
            }
        }
        let restitution = (top / 0.1).sqrt();
        let unexplained = sim.energy().numerical_loss();
        println!(
            "bounce, dissipation {dissipation} s/m: restitution {restitution:.4}, unexplained energy {unexplained:.1e} J, largest rise of the total energy {largest_rise:.1e} J"
        );
        assert!(
            restitution > restitution_range.0 && restitution < restitution_range.1,
            "dissipation {dissipation}: restitution {restitution}"
        );
        if dissipation > 0.0 {
            // no more than the integrator's error at the impacts (GA at 0.1 ms: 2e-4 of it)
            assert!(largest_rise < 1e-3 * 0.1 * G * 0.1, "the total energy rose by {largest_rise} J");
        }
        let e = sim.energy();
        let unexplained = e.numerical_loss().abs();
        assert!(unexplained < 2e-3 * 0.1 * G * 0.1, "dissipation {dissipation}: {unexplained} J unexplained");
    }
}

#[test]
fn explicit_steps_are_limited_by_the_contact_stiffness_before_the_first_touch() {
    // 1 kg above a ground of 1e6 N/m and no friction: omega = 1000 rad/s, symplectic Euler's
    // limit 2 / omega (2 ms), though nothing touches yet
    let model = block_on_incline(1.0, 0.0, 0.5, "stiffness = 1e6\ndissipation = 0.0\nmu = 0.0");
    let limit = explicit_stability_limit(&model, &State::initial(&model), Integrator::SymplecticEuler);
    assert!((limit - 2e-3).abs() < 1e-9, "limit {limit} s");
    let settings = SimSettings { dt: 0.01, integrator: Integrator::SymplecticEuler, ..Default::default() };
    let err = Simulator::new(model, settings).unwrap_err();
    assert!(matches!(err, StepError::UnstableExplicitStep { .. }));
    // the message says the contact sets it (without it a free block has no limit)
    assert!(err.to_string().contains("set by the contacts' normal stiffness"), "{err}");
}

#[test]
fn contact_mistakes_are_named() {
    let base = "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"b\"\nkind = \"node\"\nmass = 1.0\nposition = [0.0, 0.0, 0.5]\n";
    let cases = [
        ("[[grounds]]\n", "grounds[0]", "nothing would touch"),
        ("contact_radius = 0.01\n", "bodies[0].contact_radius", "no [[grounds]]"),
        ("contact_radius = -0.01\n[[grounds]]\n", "bodies[0].contact_radius", ">= 0"),
        ("contact_radius = 0.0\n[[grounds]]\npoint = [0.0, 0.0, 1.0]\n", "grounds[0]", "inside ground"),
        ("contact_radius = 0.0\n[[grounds]]\nnormal = [0.0, 0.0, 0.0]\n", "grounds[0].normal", "zero"),
        ("contact_radius = 0.0\n[[grounds]]\nmu = -1\n", "grounds[0].mu", ">= 0"),
        ("contact_radius = 0.0\n[[grounds]]\nstiffness = nan\n", "grounds[0].stiffness", "finite"),
        ("contact_radius = 0.0\n[[grounds]]\nfriction = 0.5\n", "grounds[0]", "unknown field"),
        ("contact_points = [\"x\"]\n[[grounds]]\n", "bodies[0].contact_points", "contact_radius"),
        (
            "contact_radius = 0.0\n[[grounds]]\nstick_damping = 5.0\n",
            "grounds[0].stick_damping",
            "needs stick_stiffness",
        ),
        (
            "contact_radius = 0.0\n[[grounds]]\nstick_stiffness = 0.0\n",
            "grounds[0].stick_stiffness",
            "positive",
        ),
        (
            "contact_radius = 0.0\n[[grounds]]\nstick_stiffness = nan\n",
            "grounds[0].stick_stiffness",
            "finite",
        ),
        (
            "contact_radius = 0.0\n[[grounds]]\nstick_stiffness = \"stiff\"\n",
            "grounds[0].stick_stiffness",
            "invalid type",
        ),
        (
            "contact_radius = 0.0\n[[grounds]]\nstick_stiffness = 1e4\nstick_damping = -3.0\n",
            "grounds[0].stick_damping",
            ">= 0",
        ),
    ];
    for (extra, field, words) in cases {
        let text = format!("{base}{extra}");
        let err = tensegrity::scene::from_toml(&text, "careless.toml").expect_err(extra);
        let message = err.to_string();
        assert!(message.contains("careless.toml"), "{message}");
        assert!(err.field.starts_with(field), "{extra}: field {} in {message}", err.field);
        assert!(message.contains(words), "{extra}: {message}");
    }
    // a rigid body must name its contact points, and a fixed body cannot have any
    let rigid = "[[bodies]]\nname = \"r\"\nkind = \"rigid\"\nmass = 1.0\nposition = [0.0, 0.0, 1.0]\ninertia = [1.0, 1.0, 1.0]\ncontact_radius = 0.1\n[[grounds]]\n";
    let err = tensegrity::scene::from_toml(rigid, "r.toml").unwrap_err();
    assert_eq!(err.field, "bodies[0].contact_points", "{err}");
    let fixed = "[[bodies]]\nname = \"f\"\nkind = \"fixed\"\ncontact_radius = 0.1\n[[grounds]]\n";
    let err = tensegrity::scene::from_toml(fixed, "f.toml").unwrap_err();
    assert!(err.to_string().contains("[[grounds]]"), "{err}");
}

#[test]
fn the_six_bar_robot_stands_on_a_face_and_its_winch_rolls_it_onto_the_next() {
    let model = common::bundled("sixbar");
    let weight: f64 = model.bodies.iter().map(|b| b.mass).sum::<f64>() * G;
    let mut sim =
        Simulator::at_equilibrium(model.clone(), SimSettings { dt: 1e-3, ..Default::default() }).unwrap();
    // at rest on the closed bottom triangle: each of its three ends carries a third of the weight
    let face = |sim: &Simulator| -> Vec<String> {
        let names = tensegrity::report::contact_reports(sim.model(), sim.workspace());
        let mut on: Vec<String> = names.into_iter().filter(|c| c.in_contact).map(|c| c.point).collect();
        on.sort();
        on
    };
    assert_eq!(face(&sim), ["x0.b", "y0.b", "z0.b"]);
    // statics holds the feet where the scene stands them (settled on the normal springs, moved
    // back rigidly onto the anchors, held): they carry the weight, a third each (the robot is
    // symmetric about its vertical axis), and stick, their friction inside their cones and
    // their lowest points within the stick springs' stretch of where the scene puts them
    let sketch = State::initial(&model);
    let mut ws0 = Workspace::new(&model);
    evaluate(&model, &sketch, &mut ws0, Tangents::None);
    for (k, c) in sim.workspace().contacts.iter().enumerate().filter(|(_, c)| c.in_contact()) {
        let moved = c.position - ws0.contacts[k].position;
        let in_plane = (moved.x.powi(2) + moved.y.powi(2)).sqrt();
        assert!(in_plane < 0.8 * c.normal_force / 2e4 + 1e-9, "foot {k} moved {in_plane} m sideways");
        assert!(c.friction.norm() > 0.1, "foot {k} holds {} N", c.friction.norm());
    }
    let carried: f64 = sim.workspace().contacts.iter().map(|c| c.normal_force).sum();
    assert!((carried - weight).abs() < 1e-9 * weight, "{carried} N of {weight} N");
    for c in sim.workspace().contacts.iter().filter(|c| c.in_contact()) {
        assert!(
            (c.normal_force - weight / 3.0).abs() < 1e-4 * weight,
            "{} N of {}",
            c.normal_force,
            weight / 3.0
        );
        assert_eq!(c.friction_state, tensegrity::forces::contact::FrictionState::Stuck);
        assert!(c.friction.norm() < 0.5 * 0.8 * c.normal_force, "friction {} N", c.friction.norm());
    }
    // the winch hauls a bottom edge in: the robot tips over and comes to rest on the next face,
    // with hardly a sub-step retried (5000 steps through its impacts and stick-slip switches)
    // and the energy account closed
    let mut rejected = 0;
    while sim.state().time < 5.0 - 1e-9 {
        rejected += sim.step().unwrap_or_else(|e| panic!("{e}")).rejected;
    }
    assert_eq!(face(&sim), ["x0.b", "y0.a", "z1.b"]);
    assert!(rejected <= 3, "{rejected} sub-steps rejected");
    let e = sim.energy();
    assert!(e.kinetic < 1e-3, "still moving: {} J", e.kinetic);
    let lost = e.damping_loss + e.friction_loss;
    assert!(e.numerical_loss().abs() < 2e-3 * lost, "unexplained {} J of {lost} J lost", e.numerical_loss());
}

#[test]
fn the_six_bar_robot_tips_over_an_edge_where_its_weight_passes_the_edge_as_the_ground_tilts() {
    // stiff cables, mu = 1, no winch motion; the ground stays level and gravity turns instead
    // (the same physics), slowly: 0.1 degree every 0.15 s from 19 degrees on, toward the
    // outward normal of one bottom edge. The closed form is this structure's own: the
    // equal-tension six-bar is not a regular icosahedron (whose face-edge angle arctan(1 /
    // phi^2) = 20.905 degrees the run prints beside it), and its feet are spheres of 2 cm
    let mut spec = tensegrity::scene::generate::sixbar(&tensegrity::scene::generate::SixbarParams {
        ea: 1e6,
        mu: 1.0,
        ..Default::default()
    });
    spec.deployment = None;
    spec.grounds[0].normal = Some([0.0, 0.0, 1.0]);
    let mut model = common::model_of(&spec);
    let settings = SimSettings { dt: 1e-3, ..Default::default() };
    let sim = Simulator::at_equilibrium(model.clone(), settings).unwrap();
    let (mut state, ws) = (sim.state().clone(), sim.workspace());
    let feet: Vec<(usize, Vector3<f64>)> = ws
        .contacts
        .iter()
        .enumerate()
        .filter(|(_, c)| c.in_contact())
        .map(|(k, c)| (k, c.position))
        .collect();
    assert_eq!(feet.len(), 3);
    // the closed form for this structure as it stands: the weight's line passes the edge (the
    // line of two contact points) when tan(theta) = (horizontal distance of the centre of mass
    // from the edge) / (its height)
    let mass: f64 = model.bodies.iter().map(|b| b.mass).sum();
    let com =
        model.bodies.iter().zip(&state.poses).map(|(b, p)| p.position * b.mass).sum::<Vector3<f64>>() / mass;
    let (p, q, far) = (feet[0].1, feet[1].1, feet[2].0);
    let edge = (q - p).normalize();
    let to_com = com - p;
    let across = to_com - edge * edge.dot(&to_com);
    let outward = Vector3::new(-across.x, -across.y, 0.0).normalize();
    let closed_form = (across.xy().norm() / across.z).atan().to_degrees();
    let regular = (1.0 / (1.618033988749895f64).powi(2)).atan().to_degrees();
    let mut tilt = 0.0f64;
    let tipped = loop {
        tilt += if tilt < 19.0 { 1.0 } else { 0.1 };
        assert!(tilt < 25.0, "still standing at {tilt} degrees");
        let t = tilt.to_radians();
        model.gravity = (Vector3::z() * -t.cos() + outward * t.sin()) * G;
        let start = state.time;
        let mut sim = Simulator::from_state(model.clone(), state, settings).unwrap();
        while sim.state().time < start + 0.15 - 1e-9 {
            sim.step().unwrap_or_else(|e| panic!("{tilt} degrees: {e}"));
        }
        state = sim.state().clone();
        if !sim.workspace().contacts[far].in_contact() {
            // the far foot lifted: the robot goes over the edge and lands on the next face
            // (slowly at first: a bar does not spin about its axis, so its end sphere slips a
            // little as the robot turns about the edge, and friction holds that back)
            let landed = |sim: &Simulator| {
                let down = sim.workspace().contacts.iter().filter(|c| c.in_contact()).count();
                down >= 3 && sim.workspace().contacts[far].gap > 0.05
            };
            while !landed(&sim) {
                assert!(sim.state().time < start + 6.0, "{tilt} degrees: did not land on the next face");
                sim.step().unwrap();
            }
            break tilt;
        }
    };
    println!(
        "six-bar tips at {tipped:.1} degrees of tilt; closed form for its shape {closed_form:.3}, \
         regular icosahedron's face-edge angle {regular:.3}"
    );
    assert!((tipped - closed_form).abs() < 0.5, "tipped at {tipped}, closed form {closed_form}");
}

#[test]
fn error_controlled_generalized_alpha_resolves_the_impacts_a_long_fixed_step_misses() {
    // 0.1 kg dropped 0.2 m onto 1e5 N/m (contact lasts about 3 ms) and bouncing for 0.6 s, output
    // every 10 ms: against a 1e-7 s reference (3.4e-8 m from a 1e-6 s run, 4.9e-10 m from a 1e-8 s
    // one), the fixed 10 ms step is 0.13 m off; under error control (sub-steps retried to end
    // close to each touchdown and lift-off, sim::CONTACT_EVENT_DEPTH) the impacts are resolved
    // within the tolerance from 1e-3 to 1e-9 m (measured 0.42, 0.81, 0.81, 0.13, 0.07, 0.06 and
    // 0.22 times the tolerance; 0.20 at 1e-9 m with 1 ms outputs). At 1e-9 m the smallest
    // sub-step error control takes used to be 1e-7 s (sim::MIN_CONTROLLED_STEP of the 10 ms
    // interval), which bound through each impact (357 times the tolerance); it now shrinks with
    // tolerances below 1e-8 m (sim::smallest_controlled_step).
    let model = block_on_incline(0.1, 0.0, 0.2, "stiffness = 1e5\ndissipation = 0.5\nmu = 0.0");
    let heights = |dt: f64, tolerance: Option<f64>, every: usize, integrator: Integrator| {
        let settings = SimSettings { dt, tolerance, integrator, ..Default::default() };
        let mut sim = Simulator::new(model.clone(), settings).unwrap();
        let mut z = vec![];
        let mut k = 0;
        while sim.state().time < 0.6 - 1e-9 {
            sim.step().unwrap_or_else(|e| panic!("{e}"));
            k += 1;
            if k % every == 0 {
                z.push(sim.state().poses[0].position.z);
            }
        }
        z
    };
    let ga = SimSettings::default().integrator;
    let reference = heights(1e-7, None, 100_000, ga);
    let error = |z: Vec<f64>| z.iter().zip(&reference).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    let fixed = error(heights(1e-2, None, 1, ga));
    assert!(fixed > 0.05, "the fixed 10 ms step is only {fixed} m off: the test shows nothing");
    for (tol, interval) in [
        (1e-3, 1e-2),
        (1e-4, 1e-2),
        (1e-5, 1e-2),
        (1e-6, 1e-2),
        (1e-7, 1e-2),
        (1e-8, 1e-2),
        (1e-9, 1e-2),
        (1e-9, 1e-3),
    ] {
        let every = (1e-2_f64 / interval).round() as usize;
        let e = error(heights(interval, Some(tol), every, ga));
        println!("impacts under error control: tolerance {tol:e} m, outputs every {interval} s, error {e:.2e} m ({:.2} x; fixed 10 ms step: {fixed:.2e} m)", e / tol);
        assert!(e < 3.0 * tol, "tolerance {tol} m: error {e} m");
    }
    // Dormand-Prince's estimate measures positions and lets an impact's rebound velocity go
    // wrong (43 mm off at 1 mm): it is refused a tolerance in a scene with contacts
    let settings = SimSettings {
        dt: 1e-2,
        tolerance: Some(1e-3),
        integrator: Integrator::DormandPrince,
        ..Default::default()
    };
    assert!(matches!(Simulator::new(model.clone(), settings), Err(StepError::ToleranceWithContact { .. })));
}

#[test]
fn rviz_markers_show_the_contact_points_and_their_forces() {
    use tensegrity::io::msg::MarkerArray;
    let model = common::bundled("sixbar");
    let sim = Simulator::at_equilibrium(model.clone(), SimSettings::default()).unwrap();
    let markers = MarkerArray::from_state(&model, sim.state(), sim.workspace(), "world").markers;
    let find = |ns: &str| markers.iter().find(|m| m.ns == ns).unwrap_or_else(|| panic!("no {ns} marker"));
    let (points, forces) = (find("contacts"), find("contact_forces"));
    assert_eq!(points.points.len(), 3, "the three ends it stands on");
    assert_eq!(forces.points.len(), 6, "a line per contact");
    for pair in forces.points.chunks(2) {
        // standing still on a level floor: mostly up (the feet's friction is within half their
        // cones), the largest a fifth of the robot's size
        let (up, side) = (pair[1].z - pair[0].z, (pair[1].x - pair[0].x).hypot(pair[1].y - pair[0].y));
        assert!(up > 0.1 && side < 0.4 * up, "up {up}, sideways {side}");
    }
    // a scene without grounds draws none
    let prism = common::bundled("prism3");
    let state = State::initial(&prism);
    let mut ws = Workspace::new(&prism);
    evaluate(&prism, &state, &mut ws, Tangents::None);
    let plain = MarkerArray::from_state(&prism, &state, &ws, "world").markers;
    assert!(plain.iter().all(|m| !m.ns.starts_with("contact")));
}

/// The finite-difference scene: a rigid body on three spheres, a bar and a node over a tilted
/// ground (mu 0.7, k 2e4 N/m, dissipation 0.8 s/m) whose table ends with `extra` (its friction
/// law).
fn three_bodies_on_a_tilted_ground(extra: &str) -> tensegrity::Model {
    model_from_toml(&format!(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "box"
kind = "rigid"
mass = 2.0
position = [0.0, 0.0, 1.0]
rotation = [0.1, -0.2, 0.3]
inertia = [0.02, 0.03, 0.04]
points = {{ p = [0.1, 0.05, -0.1], q = [-0.1, 0.05, -0.12], r = [0.0, -0.1, -0.09] }}
contact_radius = 0.02
contact_points = ["p", "q", "r"]
[[bodies]]
name = "bar"
kind = "bar"
mass = 1.0
ends = [[1.0, 0.0, 1.0], [1.3, 0.4, 1.01]]
contact_radius = 0.01
[[bodies]]
name = "bob"
kind = "node"
mass = 0.5
position = [-1.0, 0.0, 1.0]
contact_radius = 0.01
[[grounds]]
normal = [0.05, -0.1, 1.0]
mu = 0.7
stiffness = 2e4
dissipation = 0.8
{extra}
"#
    ))
}

#[test]
fn stick_slip_contact_tangents_match_finite_differences() {
    // every sphere pressed in by half its radius, its anchor set there, then the bodies moved
    // and turned a little (stuck: the springs pull within the cone) or far (slipping), so that
    // the held material points are no longer the lowest ones and the levers' terms count
    for stick in ["stick_stiffness = 3e3\nstick_damping = 40.0", "stick_stiffness = 5e2"] {
        let model = three_bodies_on_a_tilted_ground(stick);
        let mut state = State::initial(&model);
        let mut ws = Workspace::new(&model);
        evaluate(&model, &state, &mut ws, Tangents::None);
        let ground = &model.grounds[0];
        for b in 0..model.bodies.len() {
            let lowest = model
                .contact_spheres
                .iter()
                .zip(&ws.contacts)
                .filter(|(s, _)| model.points[s.point.0].body.0 == b)
                .map(|(s, c)| c.gap + 0.5 * s.radius)
                .fold(f64::INFINITY, f64::min);
            state.poses[b].position -= ground.normal * lowest;
        }
        let anchors = tensegrity::forces::contact::initial_anchors(&model, &state.poses);
        assert_eq!(anchors.len(), model.ground_pairs());
        // slipping: the anchors 2 m away along the ground, each in its own direction
        let across = ground.normal.cross(&Vector3::x()).normalize();
        let along = ground.normal.cross(&across);
        for (label, reach, speed, slipping) in [
            ("stuck", 1e-4, 1e-3, false),
            ("slipping", 2e-2, 1.0, true),
            ("at rest, slipping", 2e-2, 0.0, true),
        ] {
            let mut moved = state.clone();
            moved.contact_anchors = anchors.clone();
            if slipping {
                for (k, a) in moved.contact_anchors.iter_mut().enumerate() {
                    let angle = 1.3 * k as f64;
                    a.anchor += (across * angle.cos() + along * angle.sin()) * 2.0;
                }
            }
            let dq = DVector::from_fn(model.dof_count, |i, _| reach * (0.7 + 0.31 * i as f64).cos());
            tensegrity::state::retract(&model, &mut moved.poses, &dq, 1.0);
            moved.velocities =
                DVector::from_fn(model.dof_count, |i, _| speed * (0.3 + 0.17 * i as f64).sin());
            evaluate(&model, &moved, &mut ws, Tangents::StiffnessAndDamping);
            let pressed: Vec<_> = ws.contacts.iter().filter(|c| c.normal_force > 0.0).collect();
            assert!(pressed.len() >= 3, "{stick} {label}: only {} contacts press in", pressed.len());
            for c in &pressed {
                let cone = 0.7 * c.normal_force;
                let at_cone = (c.friction.norm() - cone).abs() < 1e-9 * cone;
                assert_eq!(
                    at_cone,
                    slipping,
                    "{stick} {label}: |F_t| {} against mu F_n {cone}",
                    c.friction.norm()
                );
                assert!(
                    c.friction.dot(&ground.normal).abs() < 1e-12 * cone.max(1.0),
                    "friction along the normal"
                );
            }
            let k_err = rel_err(&ws.stiffness, &fd_stiffness(&model, &moved, 1e-7), 1.0);
            let c_err = rel_err(&ws.damping, &fd_damping(&model, &moved, 1e-7), 1.0);
            assert!(k_err < 1e-6, "{stick} {label}: K differs from finite differences by {k_err:e}");
            assert!(c_err < 1e-6, "{stick} {label}: C differs from finite differences by {c_err:e}");
        }
    }
}

#[test]
fn with_stick_slip_friction_a_block_within_its_cone_holds_still_and_one_beyond_slides_at_coulombs_rate() {
    // 30 degrees, k_t 1e4 N/m. mu 0.6 > tan 30: the block settles (slipping a little at first:
    // the load is 96 % of the cone) on its spring, stretched by m g sin(30) / k_t = 0.49 mm, and
    // then does not move at all (the regularized law creeps,
    // `a_block_on_an_incline_within_its_friction_cone_stays_put`); friction m g sin(30), normal
    // m g cos(30)
    let tilt = 30f64.to_radians();
    let depth = G * tilt.cos() / 1e6;
    let stuck =
        block_on_incline(1.0, tilt, -depth / tilt.cos(), "mu = 0.6\nstiffness = 1e6\nstick_stiffness = 1e4");
    let sim = run(&stuck, 1e-3, 2.0);
    let at_2 = sim.state().poses[0].position;
    let sim = run(&stuck, 1e-3, 3.0);
    let moved = (sim.state().poses[0].position - at_2).norm();
    let c = &sim.workspace().contacts[0];
    let deflection = c.stick_extension.norm();
    println!(
        "stick-slip on 30 degrees at mu 0.6: deflection {deflection:.4e} m (m g sin / k_t = {:.4e}), moved {moved:.1e} m in the third second",
        G * tilt.sin() / 1e4
    );
    assert!(moved < 1e-12, "moved {moved} m in the third second");
    assert!(
        (deflection - G * tilt.sin() / 1e4).abs() < 1e-3 * G * tilt.sin() / 1e4,
        "deflection {deflection} m"
    );
    assert!((c.friction.norm() - G * tilt.sin()).abs() < 1e-9 * G, "friction {} N", c.friction.norm());
    assert!((c.normal_force - G * tilt.cos()).abs() < 1e-6 * G, "normal {} N", c.normal_force);
    assert!(c.friction.norm() < 0.6 * c.normal_force, "inside the cone");

    // mu 0.3 < tan 30: a = g (sin 30 - 0.3 cos 30) = 2.356 m/s^2 down the slope, and the
    // energy account closes (the slip's loss booked as the friction's power and, where the
    // anchors follow the slip, as the spring energy they give up)
    let (a, expected, sim2) = slide_down_30_degrees("stick_stiffness = 1e4");
    println!("stick-slip slide: a = {a:.6} m/s^2, closed form {expected:.6}");
    assert!((a - expected).abs() < 1e-6 * expected, "a = {a} m/s^2, closed form {expected}");
    let e = sim2.energy();
    let lost = e.damping_loss + e.friction_loss;
    println!("stick-slip slide: {lost:.6} J lost, {:.2e} J unexplained", e.numerical_loss());
    assert!(e.numerical_loss().abs() < 1e-3 * lost, "unexplained {} J of {lost} J lost", e.numerical_loss());
}

#[test]
fn with_stick_slip_friction_statics_finds_the_block_resting_on_an_incline() {
    // the anchors hold the contact where it stands: an equilibrium with friction m g sin(theta)
    // and normal m g cos(theta), where frictionless statics has none
    let tilt = 20f64.to_radians();
    let model = block_on_incline(2.0, tilt, 0.0, "mu = 0.8\nstiffness = 1e5\nstick_stiffness = 5e3");
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    StaticSolver::new(&model).equilibrate(&model, &mut state, &mut ws, &model.solver).unwrap();
    let c = &ws.contacts[0];
    assert!((c.friction.norm() - 2.0 * G * tilt.sin()).abs() < 1e-9 * G, "friction {} N", c.friction.norm());
    assert!((c.normal_force - 2.0 * G * tilt.cos()).abs() < 1e-9 * G, "normal {} N", c.normal_force);
    let deflection = c.stick_extension.norm();
    assert!((deflection - 2.0 * G * tilt.sin() / 5e3).abs() < 1e-9, "spring deflected by {deflection} m");
}

#[test]
fn statics_on_an_incline_steeper_than_the_friction_angle_stops_because_the_contact_slips() {
    // 1 kg on 30 degrees: tan(30) = 0.577. With mu 0.6 the contact sticks, with friction
    // m g sin(theta) inside its cone mu m g cos(theta); with mu 0.55 (and a careless 0.0) no
    // equilibrium exists and the solve says that the contact slips, naming it
    use tensegrity::forces::contact::FrictionState;
    use tensegrity::solve::statics::StopReason;
    let tilt = 30f64.to_radians();
    for (mu, holds) in [(0.6, true), (0.55, false), (0.3, false)] {
        let model = block_on_incline(
            1.0,
            tilt,
            0.0,
            &format!("name = \"slope\"\nmu = {mu}\nstiffness = 1e5\nstick_stiffness = 5e3"),
        );
        let mut state = State::initial(&model);
        let before = state.clone();
        let mut ws = Workspace::new(&model);
        let mut solver = StaticSolver::new(&model);
        let result = solver.equilibrate(&model, &mut state, &mut ws, &model.solver);
        if holds {
            result.unwrap();
            let c = &ws.contacts[0];
            assert_eq!(c.friction_state, FrictionState::Stuck, "mu {mu}");
            assert!(
                (c.friction.norm() - G * tilt.sin()).abs() < 1e-9 * G,
                "mu {mu}: friction {}",
                c.friction.norm()
            );
            assert!(c.friction.norm() < mu * c.normal_force);
            let reports = tensegrity::report::contact_reports(&model, &ws);
            assert_eq!((reports[0].friction_state, reports[0].at_limit), ("stick", false));
            assert!((reports[0].friction_limit_n - mu * G * tilt.cos()).abs() < 1e-9 * G);
        } else {
            assert!(result.is_err(), "mu {mu}: an equilibrium on a slope steeper than atan(mu)");
            assert_eq!(solver.stop_reason(), StopReason::ContactSlips, "mu {mu}");
            assert_eq!(solver.slipping_contact_labels(&model), ["block@slope"], "mu {mu}");
            let words = solver.stop_words(&model);
            assert!(words.starts_with("contact slips: block@slope"), "mu {mu}: {words}");
            assert_eq!(state, before, "mu {mu}: a failed solve leaves the state as it found it");
        }
    }
    // a frictionless slope, and one without stick_stiffness (no friction in statics): the
    // words say why
    let model = block_on_incline(1.0, tilt, 0.0, "mu = 0.0\nstiffness = 1e5\nstick_stiffness = 5e3");
    let mut solver = StaticSolver::new(&model);
    let mut state = State::initial(&model);
    assert!(solver.equilibrate(&model, &mut state, &mut Workspace::new(&model), &model.solver).is_err());
    assert!(
        solver.stop_words(&model).contains("frictionless ground (mu = 0)"),
        "{}",
        solver.stop_words(&model)
    );
    let model = block_on_incline(1.0, tilt, 0.0, "mu = 0.8\nstiffness = 1e5");
    let mut solver = StaticSolver::new(&model);
    let mut state = State::initial(&model);
    assert!(solver.equilibrate(&model, &mut state, &mut Workspace::new(&model), &model.solver).is_err());
    assert_ne!(solver.stop_reason(), StopReason::ContactSlips);
    assert!(
        solver.stop_words(&model).contains("give a ground stick_stiffness"),
        "{}",
        solver.stop_words(&model)
    );
}

#[test]
fn a_quasi_static_deployment_that_starts_on_an_incline_steeper_than_its_friction_angle_names_the_slipping_contact(
) {
    // a careless user deploys a block set on 30 degrees at mu 0.3: there is no equilibrium to
    // start from, and the error says which contact slips (a held block pays out along the slope
    // instead: each tether length has its equilibrium)
    let tilt = 30f64.to_radians();
    let model = block_on_incline(
        1.0,
        tilt,
        0.0,
        "name = \"slope\"\nmu = 0.3\nstiffness = 1e5\nstick_stiffness = 5e3",
    );
    let mut state = State::initial(&model);
    let before = state.clone();
    let mut ws = Workspace::new(&model);
    let err = tensegrity::solve::deploy::deploy_quasi_static(&model, &mut state, &mut ws, |_, _, _| {})
        .expect_err("no equilibrium on a slope steeper than atan(mu)");
    match &err {
        tensegrity::SolveError::NoEquilibrium { slipping, load_step, .. } => {
            assert_eq!((slipping.as_slice(), *load_step), (&["block@slope".to_string()][..], 0))
        }
        other => panic!("expected NoEquilibrium, got {other:?}"),
    }
    let words = err.to_string();
    assert!(
        words.contains("; contact slips: block@slope (no equilibrium holds it inside its friction cone)"),
        "{words}"
    );
    assert_eq!(state, before, "a failed deployment leaves the state as it found it");
}

#[test]
fn a_quasi_static_haul_drags_a_stuck_foot_only_once_the_pull_reaches_the_friction_limit() {
    // a 1 kg block on a level ground (mu 0.5, k_t 2e3 N/m), hauled toward a wall 1 m away by a
    // horizontal cable (EA 1000 N) whose rest length goes from 1 m to 0.9 m in 40 load steps.
    // Stuck, the cable and the contact's spring share the haul: T = k_t x with
    // T = EA (1 - x - L0) / L0; once T reaches mu m g = 4.905 N the foot slips and the pull stays
    // there: x = 1 - L0 (1 + mu m g / EA). The anchors carry the slip from load step to load step.
    let (mu, k_t, ea, m) = (0.5, 2e3, 1000.0, 1.0);
    let k_n = 1e6;
    let depth = m * G / k_n;
    let model = model_from_toml(&format!(
        "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"wall\"\nkind = \"fixed\"\npoints = {{ hook = [1.0, 0.0, {z}] }}\n\
         [[bodies]]\nname = \"block\"\nkind = \"node\"\nmass = {m}\nposition = [0.0, 0.0, {z}]\ncontact_radius = 0.0\n\
         [[cables]]\nname = \"haul\"\nroute = [\"block\", \"wall.hook\"]\nea = {ea}\nrest_length = 1.0\n\
         [[actuators]]\nname = \"winch\"\ncable = \"haul\"\nmin_rest_length = 0.5\nmax_rest_length = 1.5\nmax_rate = 1.0\n\
         [deployment]\nsteps = 40\n[[deployment.ramps]]\nactuator = \"winch\"\nstart = 0.0\nduration = 1.0\nrest_length = 0.9\n\
         [[grounds]]\nmu = {mu}\nstiffness = {k_n}\nstick_stiffness = {k_t}\n",
        z = -depth
    ));
    let limit = mu * m * G;
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    let mut rows = Vec::new();
    tensegrity::solve::deploy::deploy_quasi_static(&model, &mut state, &mut ws, |step, s, w| {
        rows.push((
            step.time,
            s.rest_lengths[0],
            s.poses[1].position.x,
            w.cables[0].tension,
            w.contacts[0].friction.x,
            tensegrity::report::contact_reports(&model, w).remove(0),
        ));
    })
    .unwrap();
    let mut slipped = false;
    for (t, l0, x, tension, friction, report) in &rows {
        let (t, l0, x, tension, friction) = (*t, *l0, *x, *tension, *friction);
        // the stuck branch: k_t x = EA (1 - x - L0) / L0
        let stuck_x = ea * (1.0 - l0) / (k_t * l0 + ea);
        let (want_x, want_t) = if k_t * stuck_x <= limit && !slipped {
            (stuck_x, k_t * stuck_x)
        } else {
            slipped = true;
            (1.0 - l0 * (1.0 + limit / ea), limit)
        };
        assert!((x - want_x).abs() < 1e-9, "t = {t}: foot at {x} m, closed form {want_x} m");
        assert!((tension - want_t).abs() < 1e-7 * limit, "t = {t}: pull {tension} N, closed form {want_t} N");
        assert!((friction + tension).abs() < 1e-7 * limit, "t = {t}: friction {friction} N against the pull");
        // stuck inside the cone until the foot slips; from then on each equilibrium sits on
        // the cone's edge
        if slipped {
            assert!(report.at_limit, "t = {t}: {} at {friction} N", report.friction_state);
        } else {
            assert_eq!((report.friction_state, report.at_limit), ("stick", false), "t = {t}");
        }
    }
    assert!(slipped, "the haul never reached the friction limit");
    assert!(rows.last().unwrap().5.at_limit, "the hauled foot ends at its friction limit");
    // then the haul eases off (the cable goes slack): the foot comes back by its spring's
    // stretch only, mu m g / k_t, and stays where it slipped to (the anchor moved with it)
    let x_end = rows.last().unwrap().2;
    let mut eased = state.clone();
    eased.rest_lengths[0] = 0.95;
    tensegrity::solve::statics::StaticSolver::new(&model)
        .equilibrate_holding(&model, &mut eased, &mut ws, &model.solver)
        .unwrap();
    let pull = (ea * (1.0 - eased.poses[1].position.x - 0.95) / 0.95).max(0.0); // slack here
    let back = x_end - eased.poses[1].position.x;
    assert!(
        (back - (limit - pull) / k_t).abs() < 1e-9,
        "eased off, the foot came back {back} m: only its spring's"
    );
}
