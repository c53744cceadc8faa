//! Strut-strut collision (`forces::collision`, `[collisions]`): the closest points of two axes,
//! the element's tangents against finite differences, two bars thrown at each other (an elastic
//! bounce reverses their speeds, momentum is kept, dissipation only takes energy), a rod dropped
//! across another, a throw fast enough to pass through in one step (resolved by retrying, or
//! reported when the contact is too soft to stop it), and the scene errors a careless user meets.

mod common;

use common::{fd_damping, fd_stiffness, model_from_toml, rel_err};
use nalgebra::{DVector, Vector3};
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::forces::collision::closest_points;
use tensegrity::sim::{SimSettings, Simulator, StepError};
use tensegrity::State;

const G: f64 = 9.81;

/// Two bars of 1 kg and 1 m: `upper` along x at height `z`, `lower` along y at the origin, both
/// free, with `extra` appended (gravity, `[collisions]` lines).
/// (The bars have capsules of `radius` only when `extra` declares `[collisions]`.)
fn crossed_bars(z: f64, radius: f64, extra: &str) -> tensegrity::Model {
    let capsule =
        if extra.contains("[collisions]") { format!("contact_radius = {radius}") } else { String::new() };
    model_from_toml(&format!(
        "[[bodies]]\nname = \"upper\"\nkind = \"bar\"\nmass = 1.0\nends = [[-0.5, 0.0, {z}], [0.5, 0.0, {z}]]\n\
         {capsule}\n[[bodies]]\nname = \"lower\"\nkind = \"bar\"\nmass = 1.0\n\
         ends = [[0.0, -0.5, 0.0], [0.0, 0.5, 0.0]]\n{capsule}\n{extra}\n"
    ))
}

#[test]
fn closest_points_of_crossed_touching_and_parallel_axes() {
    let v = Vector3::new;
    // crossed at 90 degrees, 0.3 apart: both interior, the first above
    let cp = closest_points(&v(-1.0, 0.0, 0.3), &v(1.0, 0.0, 0.3), &v(0.0, -1.0, 0.0), &v(0.0, 1.0, 0.0));
    assert!((cp.s - 0.5).abs() < 1e-15 && (cp.t - 0.5).abs() < 1e-15);
    assert!((cp.w - v(0.0, 0.0, 0.3)).norm() < 1e-15);
    assert!(cp.s_free && cp.t_free);
    // an end against the other's middle: t clamped at 1
    let cp = closest_points(&v(-1.0, 0.0, 0.0), &v(1.0, 0.0, 0.0), &v(0.2, 0.0, -1.0), &v(0.2, 0.0, -0.1));
    assert_eq!(cp.t, 1.0);
    assert!((cp.s - 0.6).abs() < 1e-15 && cp.s_free && !cp.t_free);
    assert!((cp.w - v(0.0, 0.0, 0.1)).norm() < 1e-15);
    // parallel and overlapping on [0.5, 1] of the first: the middle of the overlap
    let cp = closest_points(&v(0.0, 0.0, 0.0), &v(1.0, 0.0, 0.0), &v(0.5, 0.2, 0.0), &v(1.5, 0.2, 0.0));
    assert!((cp.s - 0.75).abs() < 1e-15 && (cp.t - 0.25).abs() < 1e-15, "{cp:?}");
    assert!((cp.w.norm() - 0.2).abs() < 1e-15);
    // parallel and apart along their line: the nearest ends
    let cp = closest_points(&v(0.0, 0.0, 0.0), &v(1.0, 0.0, 0.0), &v(2.0, 0.0, 0.0), &v(3.0, 0.0, 0.0));
    assert_eq!((cp.s, cp.t), (1.0, 0.0));
}

#[test]
fn collision_tangents_match_finite_differences() {
    // two bars in general position pressed into each other by half a radius: crossing (both
    // closest points interior) and one's end against the other's side (one clamped); slipping
    // fast, slipping at about the regularization speed, or stuck
    let cases = [
        ("crossing", [[-0.5, 0.05, 0.02], [0.5, 0.1, -0.03]], [[0.07, -0.5, 0.3], [-0.04, 0.45, 0.25]]),
        ("end on side", [[-0.5, 0.05, 0.02], [0.5, 0.1, -0.03]], [[0.2, -0.1, 0.9], [0.1, 0.05, 0.1]]),
    ];
    for (geometry, first, second) in cases {
        let text = format!(
            "[[bodies]]\nname = \"s1\"\nkind = \"bar\"\nmass = 1.0\nends = {first:?}\ncontact_radius = 0.02\n\
             [[bodies]]\nname = \"s2\"\nkind = \"bar\"\nmass = 0.7\nends = {second:?}\ncontact_radius = 0.03\n\
             [collisions]\nmu = 0.7\nstiffness = 2e4\ndissipation = 0.8\nstiction_speed = 0.05\n"
        );
        let model = model_from_toml(&text);
        let mut state = State::initial(&model);
        let mut ws = Workspace::new(&model);
        evaluate(&model, &state, &mut ws, Tangents::None);
        // move the second bar along the normal until the capsules overlap by 0.025 m
        let c = ws.contacts[0];
        state.poses[1].position += c.normal * (c.gap + 0.025);
        for (label, scale) in [("fast slip", 1.0), ("slip near v_s", 0.04), ("stuck", 0.0)] {
            state.velocities =
                DVector::from_fn(model.dof_count, |i, _| scale * (0.3 + 0.37 * i as f64).sin());
            evaluate(&model, &state, &mut ws, Tangents::StiffnessAndDamping);
            let c = ws.contacts[0];
            assert!(c.normal_force > 0.0 && (c.gap + 0.025).abs() < 1e-12, "{geometry}: {c:?}");
            let k_err = rel_err(&ws.stiffness, &fd_stiffness(&model, &state, 1e-7), 1.0);
            let c_err = rel_err(&ws.damping, &fd_damping(&model, &state, 1e-7), 1.0);
            println!("{geometry}, {label}: K {k_err:.1e}, C {c_err:.1e}");
            assert!(k_err < 1e-6, "{geometry}, {label}: K differs from finite differences by {k_err:e}");
            assert!(c_err < 1e-6, "{geometry}, {label}: C differs from finite differences by {c_err:e}");
        }
    }
}

/// Sets both bars of `crossed_bars` moving toward each other at `speed` m/s each.
fn thrown(model: &tensegrity::Model, speed: f64) -> State {
    let mut state = State::initial(model);
    // a bar's first three coordinates are its centre's world velocity
    let (upper, lower) = (model.bodies[0].dof_offset, model.bodies[1].dof_offset);
    state.velocities[upper + 2] = -speed;
    state.velocities[lower + 2] = speed;
    state
}

#[test]
fn bars_thrown_at_each_other_bounce_back_keeping_momentum_and_never_gaining_energy() {
    for (dissipation, rebound_range) in [(0.0, (0.999, 1.001)), (1.0, (0.2, 0.9))] {
        let model = crossed_bars(
            0.1,
            0.01,
            &format!("[collisions]\nstiffness = 1e5\ndissipation = {dissipation}\nmu = 0.3"),
        );
        let state = thrown(&model, 1.0);
        let settings = SimSettings { dt: 1e-5, ..Default::default() };
        let mut sim = Simulator::from_state(model.clone(), state, settings).unwrap();
        let (mut touched, mut largest_rise) = (false, 0.0f64);
        let mut lowest = sim.energy().total();
        while sim.state().time < 0.15 {
            sim.step().unwrap();
            touched |= sim.workspace().contacts[0].in_contact();
            let mechanical = {
                let e = sim.workspace().energies;
                e.kinetic + e.elastic + e.gravitational
            };
            largest_rise = largest_rise.max(mechanical - lowest);
            lowest = lowest.min(mechanical);
            assert!(sim.workspace().strut_closest[0].side >= 0.0, "the upper bar went through");
        }
        assert!(touched, "the bars never met");
        let v = &sim.state().velocities;
        let (up, low) = (v[model.bodies[0].dof_offset + 2], v[model.bodies[1].dof_offset + 2]);
        let rebound = up;
        println!("dissipation {dissipation}: rebound {rebound:.6} m/s, momentum {:.1e}", up + low);
        assert!((up + low).abs() < 1e-9, "momentum {} kg m/s", up + low);
        assert!(
            rebound > rebound_range.0 && rebound < rebound_range.1,
            "dissipation {dissipation}: rebound {rebound} m/s"
        );
        // no more than the integrator's error at the impact (of the 1 J the bars carry)
        assert!(
            largest_rise < 1e-5,
            "dissipation {dissipation}: the mechanical energy rose by {largest_rise} J"
        );
        let unexplained = sim.energy().numerical_loss().abs();
        assert!(unexplained < 1e-4, "{unexplained} J unexplained by the contact loss");
    }
}

#[test]
fn a_rod_dropped_across_another_bounces_and_comes_to_rest_on_it() {
    // the lower rod is pinned at its middle (free to rock); the upper falls 0.1 m across it
    let model = model_from_toml(
        "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"upper\"\nkind = \"bar\"\nmass = 1.0\n\
         ends = [[-0.5, 0.0, 0.12], [0.5, 0.0, 0.12]]\ncontact_radius = 0.01\n[[bodies]]\nname = \"lower\"\n\
         kind = \"bar\"\nmass = 1.0\nends = [[0.0, -0.5, 0.0], [0.0, 0.5, 0.0]]\npoints = { mid = 0.5 }\n\
         contact_radius = 0.01\n[[joints]]\nkind = \"pin\"\na = \"lower.mid\"\n\
         [collisions]\nstiffness = 1e5\ndissipation = 2.0\nmu = 0.5\n",
    );
    let mut sim = Simulator::new(model.clone(), SimSettings { dt: 1e-4, ..Default::default() }).unwrap();
    let (mut bounced, mut touched, mut largest_rise) = (false, false, 0.0f64);
    let mut lowest = sim.energy().total();
    while sim.state().time < 1.5 {
        sim.step().unwrap();
        let c = sim.workspace().contacts[0];
        touched |= c.in_contact();
        bounced |= touched && sim.state().velocities[2] > 0.05;
        let e = sim.workspace().energies;
        let mechanical = e.kinetic + e.elastic + e.gravitational;
        largest_rise = largest_rise.max(mechanical - lowest);
        lowest = lowest.min(mechanical);
    }
    let c = sim.workspace().contacts[0];
    println!("rest: normal force {:.6} N, gap {:.3e} m, rise {largest_rise:.1e} J", c.normal_force, c.gap);
    assert!(bounced, "the rod never bounced");
    // no more than the integrator's error at the impacts (of the m g h = 1.2 J it falls)
    assert!(largest_rise < 1e-5, "the mechanical energy rose by {largest_rise} J");
    // at rest across the other: it carries the rod's weight, pressed in by m g / k
    assert!((c.normal_force - G).abs() < 1e-3 * G, "normal force {} N", c.normal_force);
    assert!((c.gap + G / 1e5).abs() < 1e-6, "gap {} m", c.gap);
    assert!(sim.state().poses[0].position.z > 0.0, "it fell through");
    let unexplained = sim.energy().numerical_loss().abs();
    assert!(unexplained < 1e-3 * G * 0.1, "{unexplained} J unexplained");
}

#[test]
fn a_throw_that_would_pass_through_in_one_step_is_retried_or_reported() {
    // 0.5 m/s each, 2 cm apart at first, capsule radii 5 mm: at a 50 ms step the bars would swap
    // sides within one step (5 cm of closing) without a contact force ever seen
    let start = |extra: &str| {
        let model = crossed_bars(0.02, 0.005, extra);
        let state = thrown(&model, 0.5);
        (model, state)
    };
    let settings = SimSettings { dt: 0.05, ..Default::default() };
    // without [collisions]: they pass through each other, as they would today
    let (model, state) = start("");
    let mut sim = Simulator::from_state(model, state, settings).unwrap();
    sim.step().unwrap();
    assert!(sim.state().poses[0].position.z < sim.state().poses[1].position.z, "no collision was declared");
    // with them, stiff enough to stop the bars: the step is retried in halves and they bounce
    let (model, state) = start("[collisions]\nstiffness = 1e6\ndissipation = 0.0\nmu = 0.0");
    let mut sim = Simulator::from_state(model, state, settings).unwrap();
    let mut pass_throughs = 0;
    while sim.state().time < 0.2 {
        pass_throughs += sim.step().unwrap().pass_throughs;
        assert!(sim.state().poses[0].position.z > sim.state().poses[1].position.z, "passed through");
    }
    println!("50 ms steps: {pass_throughs} sub-steps retried for passing through");
    assert!(pass_throughs > 0);
    assert!(sim.state().velocities[2] > 0.0, "the upper bar did not bounce back");
    // too soft to stop them (k delta^2 / 2 < m v^2 / 2 at delta = 2 r): reported, naming both
    let (model, state) = start("[collisions]\nstiffness = 10.0\ndissipation = 0.0\nmu = 0.0");
    let mut sim =
        Simulator::from_state(model, state, SimSettings { dt: 1e-3, ..Default::default() }).unwrap();
    let err = loop {
        match sim.step() {
            Ok(_) if sim.state().time < 1.0 => continue,
            Ok(_) => panic!("a soft contact stopped the bars"),
            Err(e) => break e,
        }
    };
    assert!(matches!(err, StepError::PassThrough { .. }), "{err}");
    let message = err.to_string();
    assert!(message.contains("'upper'") && message.contains("'lower'"), "{message}");
    assert!(sim.state().is_finite());
}

#[test]
fn collision_mistakes_are_named() {
    let bar = |name: &str, y: f64, radius: &str| {
        format!(
            "[[bodies]]\nname = \"{name}\"\nkind = \"bar\"\nmass = 1.0\nends = [[0.0, {y}, 0.0], [1.0, {y}, 0.0]]\n{radius}\n"
        )
    };
    let two =
        format!("{}{}", bar("s1", 0.0, "contact_radius = 0.01"), bar("s2", 0.5, "contact_radius = 0.01"));
    let node = "[[bodies]]\nname = \"n\"\nkind = \"node\"\nmass = 1.0\nposition = [0.0, 2.0, 0.0]\n";
    let cases = [
        (format!("{two}[collisions]\npairs = \"some\"\n"), "collisions.pairs", "neither"),
        (format!("{two}[collisions]\npairs = []\n"), "collisions.pairs", "empty"),
        (format!("{two}[collisions]\npairs = [[\"s1\", \"s3\"]]\n"), "collisions.pairs", "no body called 's3'"),
        (format!("{two}[collisions]\npairs = [[\"s1\", \"s1\"]]\n"), "collisions.pairs", "twice"),
        (
            format!("{two}[collisions]\npairs = [[\"s1\", \"s2\"], [\"s2\", \"s1\"]]\n"),
            "collisions.pairs",
            "listed twice",
        ),
        (format!("{two}{node}[collisions]\npairs = [[\"s1\", \"n\"]]\n"), "collisions.pairs", "only bars"),
        (
            format!("{}{}[collisions]\npairs = [[\"s1\", \"s2\"]]\n", bar("s1", 0.0, "contact_radius = 0.01"), bar("s2", 0.5, "")),
            "collisions.pairs",
            "no contact_radius",
        ),
        (format!("{}[collisions]\n", bar("s1", 0.0, "contact_radius = 0.01")), "collisions.pairs", "no pair"),
        (format!("{two}[collisions]\nmu = -0.1\n"), "collisions.mu", ">= 0"),
        (format!("{two}[collisions]\nstiffness = nan\n"), "collisions.stiffness", "finite"),
        (format!("{two}[collisions]\nfriction = 0.3\n"), "", "unknown field"),
        (
            format!("{}{}[collisions]\n", bar("s1", 0.0, "contact_radius = 0.01"), bar("s2", 0.002, "contact_radius = 0.01")),
            "collisions.pairs",
            "into each other",
        ),
        (
            format!("{two}[[bodies]]\nname = \"n\"\nkind = \"node\"\nmass = 1.0\nposition = [0.0, 2.0, 0.0]\ncontact_radius = 0.01\n[collisions]\n"),
            "bodies[2].contact_radius",
            "no [[grounds]]",
        ),
    ];
    for (text, field, words) in cases {
        let err = tensegrity::scene::from_toml(&text, "careless.toml").expect_err(&text);
        let message = err.to_string();
        assert!(message.contains("careless.toml"), "{message}");
        assert!(err.field.starts_with(field), "{text}: field {} in {message}", err.field);
        assert!(message.contains(words), "{text}: {message}");
    }
    // joined bars are left out of "all"; a ball joint at touching ends is no collision
    let joined = format!(
        "{}{}[[joints]]\nkind = \"ball\"\na = \"s1.b\"\nb = \"s2.a\"\n[[bodies]]\nname = \"s3\"\nkind = \"bar\"\nmass = 1.0\n\
         ends = [[0.0, 2.0, 0.0], [1.0, 2.0, 0.0]]\ncontact_radius = 0.01\n[collisions]\n",
        bar("s1", 0.0, "contact_radius = 0.01"),
        "[[bodies]]\nname = \"s2\"\nkind = \"bar\"\nmass = 1.0\nends = [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0]]\ncontact_radius = 0.01\n",
    );
    let model = tensegrity::scene::from_toml(&joined, "joined.toml").unwrap();
    let names: Vec<_> = model.contact_labels().collect();
    assert_eq!(names, [("s1", "s3"), ("s2", "s3")]);
    // and named as a pair, refused
    let listed = joined.replace("[collisions]\n", "[collisions]\npairs = [[\"s2\", \"s1\"]]\n");
    let err = tensegrity::scene::from_toml(&listed, "joined.toml").unwrap_err();
    assert_eq!(err.field, "collisions.pairs", "{err}");
    assert!(err.to_string().contains("joined by a joint"), "{err}");
}

#[test]
fn parallel_and_meeting_axes_give_finite_forces_and_a_parallel_drop_lands() {
    // a rod dropped parallel onto another pinned at its middle (the closest points are not
    // unique: the middle of the overlap carries the force)
    let model = model_from_toml(
        "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"upper\"\nkind = \"bar\"\nmass = 1.0\n\
         ends = [[-0.3, 0.0, 0.05], [0.5, 0.0, 0.05]]\ncontact_radius = 0.01\n[[bodies]]\nname = \"lower\"\n\
         kind = \"bar\"\nmass = 1.0\nends = [[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0]]\npoints = { mid = 0.5 }\n\
         contact_radius = 0.01\n[[joints]]\nkind = \"pin\"\na = \"lower.mid\"\n\
         [collisions]\nstiffness = 1e5\ndissipation = 2.0\nmu = 0.5\n",
    );
    let mut sim = Simulator::new(model, SimSettings { dt: 1e-4, ..Default::default() }).unwrap();
    let (mut touched, mut lowest) = (false, f64::INFINITY);
    while sim.state().time < 0.5 {
        sim.step().unwrap_or_else(|e| panic!("{e}"));
        assert!(sim.state().is_finite());
        touched |= sim.workspace().contacts[0].in_contact();
        lowest = lowest.min(sim.workspace().contacts[0].gap);
    }
    assert!(touched, "the rod never landed");
    assert!(lowest > -0.01, "pressed {lowest} m in: it went through");
    // axes that meet exactly (a careless start the penalty must survive): a finite, unit normal
    // and finite forces, no tangent to divide by zero with
    for second in ["[[0.0, -0.5, 0.0], [0.0, 0.5, 0.0]]", "[[0.2, 0.0, 0.0], [0.8, 0.0, 0.0]]"] {
        let text = |z: f64| {
            format!(
                "[[bodies]]\nname = \"s1\"\nkind = \"bar\"\nmass = 1.0\nends = [[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0]]\n\
                 contact_radius = 0.01\n[[bodies]]\nname = \"s2\"\nkind = \"bar\"\nmass = 1.0\nends = {}\n\
                 contact_radius = 0.01\n[collisions]\npairs = [[\"s1\", \"s2\"]]\n",
                second.replace("0.0]", &format!("{z:.1}]"))
            )
        };
        // check refuses such a start (the capsules are inside each other)
        let err = tensegrity::scene::from_toml(&text(0.0), "meet.toml").unwrap_err();
        assert!(err.to_string().contains("into each other"), "{err}");
        // built apart and moved onto the first in code, as a user editing a model might
        let mut model = model_from_toml(&text(3.0));
        model.bodies[1].initial_pose.position.z = 0.0;
        let state = State::initial(&model);
        let mut ws = Workspace::new(&model);
        evaluate(&model, &state, &mut ws, Tangents::StiffnessAndDamping);
        let c = ws.contacts[0];
        assert!((c.normal.norm() - 1.0).abs() < 1e-12 && c.normal_force > 0.0, "{second}: {c:?}");
        assert!(ws.force.iter().all(|f| f.is_finite()) && ws.stiffness.iter().all(|k| k.is_finite()));
    }
}

#[test]
fn explicit_steps_are_limited_by_the_collision_stiffness_before_the_bars_meet() {
    use tensegrity::solve::dynamics::{explicit_stability_limit, Integrator};
    let apart = |extra: &str| crossed_bars(0.5, 0.01, extra);
    let free = apart("");
    let stiff = apart("[collisions]\nstiffness = 1e6\ndissipation = 0.0\nmu = 0.0");
    let euler = Integrator::SymplecticEuler;
    let without = explicit_stability_limit(&free, &State::initial(&free), euler);
    let with = explicit_stability_limit(&stiff, &State::initial(&stiff), euler);
    // two 1 kg bars on a 1e6 N/m contact: omega = sqrt(2 k / m) at most 1414 rad/s, bounded
    // from above (every end counted) so the limit is below 2 / 1414 s
    assert!(with < 2.0 / (2e6f64).sqrt(), "limit {with} s");
    assert!(without > 10.0 * with, "without collisions {without} s, with {with} s");
}
