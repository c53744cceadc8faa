//! `tensegrity check SCENE`: validates a scene and prints counts of its bodies, coordinates,
//! constraints, cables, pulleys and actuators, its grounds and contact spheres, and its colliding
//! strut pairs.

use std::path::Path;

use tensegrity::report;

use crate::output::*;

/// Runs `check` on the scene file `scene`.
pub fn run(scene: &Path) -> Result<(), String> {
    let model = load(scene)?;
    let s = report::summary(&model);
    say!("{}: valid scene '{}'", scene.display(), s.name);
    say!(
        "bodies: {} ({} node, {} bar, {} rigid, {} fixed)",
        s.bodies.iter().sum::<usize>(),
        s.bodies[0],
        s.bodies[1],
        s.bodies[2],
        s.bodies[3]
    );
    say!("coordinates: {}", s.coordinates);
    say!("constraints: {}", s.constraints);
    say!("cables: {} ({} sliding)", s.cables, s.sliding_cables);
    let rollers = model.joints.iter().filter(|j| j.kind == tensegrity::model::JointKind::Roller).count();
    let sliders = model.joints.iter().filter(|j| j.kind == tensegrity::model::JointKind::Slider).count();
    if rollers + sliders > 0 {
        say!(
            "supports: {} (free along a line), {} (free in a plane)",
            counted(rollers, "roller"),
            counted(sliders, "slider")
        );
    }
    // a hinge's or planar joint's axis rows are their own JointModel: count the point rows
    let of_kind = |kind| model.joints.iter().filter(|j| j.kind == kind && j.alignment.is_none()).count();
    let hinges = of_kind(tensegrity::model::JointKind::Hinge);
    let planars = of_kind(tensegrity::model::JointKind::Planar);
    if hinges + planars > 0 {
        say!(
            "axes: {} (turn about one axis), {} (slide on a plane, turn about its normal)",
            counted(hinges, "hinge"),
            counted(planars, "planar joint")
        );
    }
    let damped = model.joints.iter().filter(|j| j.damping > 0.0).count();
    if damped > 0 {
        say!("joint damping: {} (rotational, against the bodies' relative spin)", counted(damped, "joint"));
    }
    if model.rayleigh != Default::default() {
        say!(
            "damping: Rayleigh alpha {} 1/s (on every body's mass), beta {} s (on each cable's and member's EA/L0)",
            model.rayleigh.alpha,
            model.rayleigh.beta
        );
    }
    if s.members > 0 {
        say!(
            "members: {} (elastic: push and pull; in the cable lists, negative tension is compression)",
            s.members
        );
        if !model.mass_couplings.is_empty() {
            say!(
                "consistent mass: {} members (the uniform bar's mass matrix, coupling their end nodes)",
                model.mass_couplings.len()
            );
        }
        let buckling: Vec<String> = model
            .cables
            .iter()
            .zip(&model.cable_names)
            .filter(|(c, _)| c.buckling_load.is_finite())
            .map(|(c, name)| format!("{name} at {:.6} N", c.buckling_load))
            .collect();
        if !buckling.is_empty() {
            say!("buckling: {} (past it, the elastica's post-buckling law)", buckling.join(", "));
        }
    }
    say!("pulleys: {}", s.pulleys);
    if !model.pulley_friction.is_empty() {
        let with: Vec<String> = model
            .pulley_friction
            .iter()
            .map(|f| {
                let mus: Vec<String> = f.mu.iter().map(|m| format!("{m}")).collect();
                format!("{} (mu {})", model.cable_names[f.cable.0], mus.join(", "))
            })
            .collect();
        say!("pulley friction: {} (capstan stick and slip; dense Newton systems)", with.join("; "));
    }
    say!("actuators: {} (schedule: {})", s.actuators, counted(s.ramps, "ramp"));
    for w in &model.winches {
        let gear = if w.back_drivable { "back-drivable" } else { "self-locking" };
        say!(
            "winch: {} (drum {} m, stall {:.6} N, no-load {:.6} m/s, rotor {} kg m^2, {gear})",
            model.actuator_names[w.actuator.0],
            w.drum_radius,
            w.stall_tension,
            w.no_load_speed,
            w.rotor_inertia
        );
    }
    let dt = model.physics_dt.unwrap_or(tensegrity::sim::DEFAULT_PHYSICS_DT);
    let delayed: Vec<String> = model
        .actuators
        .iter()
        .zip(&model.actuator_names)
        .filter(|(a, _)| !a.command_delay.is_zero())
        .map(|(a, name)| format!("{name} {}", delay_text(a.command_delay, dt)))
        .collect();
    if !delayed.is_empty() {
        say!("command delay: {}", delayed.join(", "));
    }
    for d in &model.randomized {
        say!(
            "randomized: {} of {} drawn {:.6} ({:.9} -> {:.9})",
            d.parameter.name(),
            d.element,
            d.drawn,
            d.written,
            d.value
        );
    }
    if !model.sensors.channels.is_empty() {
        let channels: Vec<String> = model
            .sensors
            .channels
            .iter()
            .map(|(kind, c)| {
                let rate =
                    if c.period > 0.0 { format!("{} Hz", 1.0 / c.period) } else { "every step".into() };
                format!(
                    "{} (sigma {}, bias {}, resolution {}, delay {}, {rate}, dropout {})",
                    kind.name(),
                    c.sigma,
                    c.bias,
                    c.resolution,
                    delay_text(c.delay, dt),
                    c.dropout
                )
            })
            .collect();
        say!("sensors: {} (seed {}; truth on ~/ground_truth/...)", channels.join("; "), model.sensors.seed);
    }
    if s.planar {
        say!("planar: yes (xy plane)");
    }
    if s.grounds > 0 {
        let grounds: Vec<String> = model
            .grounds
            .iter()
            .map(|g| {
                let m = &g.material;
                let friction = match &m.stick {
                    None => format!("stiction speed {:.1e} m/s", m.stiction_speed),
                    Some(stick) => format!(
                        "stick-slip friction: k_t {:.3e} N/m, c_t {}",
                        stick.stiffness,
                        stick.damping.map_or("critical per body".to_string(), |c| format!("{c} N s/m"))
                    ),
                };
                format!(
                    "{} (normal [{:.3}, {:.3}, {:.3}], mu {}, stiffness {:.3e} N/m, dissipation {} s/m, {friction})",
                    g.name, g.normal.x, g.normal.y, g.normal.z, m.friction, m.stiffness, m.dissipation
                )
            })
            .collect();
        say!("grounds: {}", grounds.join("; "));
        say!("contact spheres: {}", s.contact_spheres);
    }
    if !model.strut_pairs.is_empty() {
        let m = &model.strut_material;
        let pairs: Vec<String> =
            model.contact_labels().skip(model.ground_pairs()).map(|(a, b)| format!("{a}-{b}")).collect();
        say!(
            "strut collisions: {} ({}) (mu {}, stiffness {:.3e} N/m, dissipation {} s/m, stiction speed {:.1e} m/s)",
            counted(pairs.len(), "pair"),
            pairs.join(", "),
            m.friction,
            m.stiffness,
            m.dissipation,
            m.stiction_speed
        );
    }
    if let Some(note) = report::unheld_bodies_note(&model) {
        say!("warning: {note} (dynamics lets them drift or fall)");
    }
    for w in model.delay_warnings(dt) {
        say!("warning: {w}");
    }
    Ok(())
}

/// A delay as `check` lists it: `0`, or as given with its whole steps at `dt` (s) beside it.
fn delay_text(delay: tensegrity::model::Delay, dt: f64) -> String {
    use tensegrity::model::Delay;
    let steps = delay.steps(dt);
    match delay {
        _ if delay.is_zero() => "0".into(),
        Delay::Steps(_) => {
            format!("{delay} ({} s at {dt} s)", tensegrity::error::readable_number(steps as f64 * dt))
        }
        Delay::Seconds(_) => format!("{delay} ({steps} step{} of {dt} s)", if steps == 1 { "" } else { "s" }),
    }
}
