//! Invariant: `statics` finds the stable equilibrium from the rough starts a newcomer sketches, not
//! only from starts next to it. The three pendulums of the statics issue (a bar pinned at one end,
//! a rigid body on a ball joint, a point mass on an elastic cable from a hook), started at every
//! tilt from 1 to 179 degrees, converge to hanging straight down, stable, in a bounded number of
//! Newton iterations; started hanging, they take no iteration at all; and a bar held by a
//! counterweight over a pulley settles at the closed-form angle from any start. This holds because the joint
//! reactions start at their least-squares values and the tangent is made positive definite on the
//! joints' null space where it is not (so a step goes down the energy, away from the inverted
//! equilibrium).

use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::solve::statics::{EquilibriumReport, StaticSolver};
use tensegrity::{Model, State};

fn solve(text: &str, what: &str) -> (Model, State, Workspace, EquilibriumReport) {
    let model = tensegrity::scene::from_toml(text, what).unwrap_or_else(|e| panic!("{e}"));
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    let r = StaticSolver::new(&model)
        .equilibrate(&model, &mut state, &mut ws, &model.solver)
        .unwrap_or_else(|e| panic!("{what}: no equilibrium: {e:?}"));
    evaluate(&model, &state, &mut ws, Tangents::None);
    (model, state, ws, r)
}

fn tilted(deg: f64, length: f64) -> (f64, f64) {
    let a = deg.to_radians();
    (length * a.sin(), -length * a.cos())
}

fn point(model: &Model, ws: &Workspace, name: &str) -> nalgebra::Vector3<f64> {
    ws.points[model.points.iter().position(|p| p.name == name).unwrap()].position
}

#[test]
fn a_bar_pinned_at_one_end_hangs_straight_down_from_every_tilt() {
    for deg in (0..180).step_by(2).map(|d| d as f64).chain([1.0, 179.0]) {
        let (x, z) = tilted(deg, 1.0);
        let text = format!(
            "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"rod\"\nkind = \"bar\"\nmass = 1.0\nends = [[0.0, 0.0, 0.0], [{x}, 0.0, {z}]]\n[[joints]]\nkind = \"pin\"\na = \"rod.a\"\n"
        );
        let (model, _, ws, r) = solve(&text, &format!("bar at {deg} degrees"));
        let b = point(&model, &ws, "rod.b");
        assert!(
            (b - nalgebra::Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-9,
            "{deg} degrees: free end at {b:?}"
        );
        assert!(r.stable, "{deg} degrees: {r:?}");
        let budget = if deg == 0.0 { 0 } else { 15 };
        assert!(r.iterations <= budget, "{deg} degrees: {} iterations", r.iterations);
    }
}

#[test]
fn a_rigid_body_on_a_ball_joint_hangs_below_it_from_every_tilt() {
    for deg in (0..180).step_by(7).map(|d| d as f64).chain([179.0]) {
        let (x, z) = tilted(deg, 0.8);
        let text = format!(
            "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"ground\"\nkind = \"fixed\"\npoints = {{ hook = [0.0, 0.0, 0.0] }}\n[[bodies]]\nname = \"bob\"\nkind = \"rigid\"\nmass = 2.0\nposition = [{x}, 0.0, {z}]\ninertia = [0.02, 0.03, 0.04]\npoints = {{ top = [{}, 0.0, {}] }}\n[[joints]]\nkind = \"ball\"\na = \"bob.top\"\nb = \"ground.hook\"\n",
            -x, -z
        );
        let (model, state, _, r) = solve(&text, &format!("ball joint at {deg} degrees"));
        let com = state.poses[model.bodies.iter().position(|b| b.name == "bob").unwrap()].position;
        assert!(
            (com - nalgebra::Vector3::new(0.0, 0.0, -0.8)).norm() < 1e-9,
            "{deg} degrees: centre of mass at {com:?}"
        );
        // the spin about the vertical through the joint is neutral (zero stiffness), nothing is
        // negative: a minimum, not a saddle
        assert!(r.min_stiffness_eigenvalue > -1e-9, "{deg} degrees: {r:?}");
        let budget = if deg == 0.0 { 0 } else { 15 };
        assert!(r.iterations <= budget, "{deg} degrees: {} iterations", r.iterations);
    }
}

#[test]
fn a_point_mass_on_a_cable_hangs_below_the_hook_from_every_tilt() {
    let (ea, l0, m, g) = (1000.0, 0.99, 1.0, 9.81);
    for deg in (0..180).step_by(7).map(|d| d as f64).chain([179.0]) {
        let (x, z) = tilted(deg, 1.0);
        let text = format!(
            "gravity = [0.0, 0.0, -{g}]\n[[bodies]]\nname = \"ground\"\nkind = \"fixed\"\npoints = {{ hook = [0.0, 0.0, 0.0] }}\n[[bodies]]\nname = \"m\"\nkind = \"node\"\nmass = {m}\nposition = [{x}, 0.0, {z}]\n[[cables]]\nname = \"string\"\nroute = [\"ground.hook\", \"m\"]\nea = {ea}\nrest_length = {l0}\n"
        );
        let (model, state, ws, r) = solve(&text, &format!("mass at {deg} degrees"));
        // closed form: T = m g, length L0 (1 + m g / EA), straight below the hook
        let hanging = l0 * (1.0 + m * g / ea);
        let p = state.poses[model.bodies.iter().position(|b| b.name == "m").unwrap()].position;
        assert!(
            (p - nalgebra::Vector3::new(0.0, 0.0, -hanging)).norm() < 1e-9,
            "{deg} degrees: mass at {p:?}"
        );
        assert!(
            (ws.cables[0].tension - m * g).abs() < 1e-9,
            "{deg} degrees: tension {}",
            ws.cables[0].tension
        );
        assert!(r.stable, "{deg} degrees: {r:?}");
        assert!(r.iterations <= 30, "{deg} degrees: {} iterations", r.iterations);
    }
}

/// A bar hanging from a pin, its tip pulled sideways by a counterweight whose cable runs over a
/// pulley level with the pin at distance `a`. The counterweight hangs freely, so the tension is
/// exactly `m_c g` whatever EA, and the torque balance about the pin gives the angle `phi` from the
/// vertical: `(m_b / 2) sin(phi) d(phi) = m_c a cos(phi)` with `d^2 = l^2 + a^2 - 2 a l sin(phi)`
/// the tip-to-pulley distance (solved here by bisection).
#[test]
fn a_counterweight_over_a_pulley_holds_the_bar_at_the_closed_form_angle() {
    let (l, a, mb, mc, rope) = (1.0f64, 1.0f64, 2.0f64, 0.6f64, 2.0f64);
    let d = |p: f64| (l * l + a * a - 2.0 * a * l * p.sin()).sqrt();
    let balance = |p: f64| mb / 2.0 * p.sin() * d(p) - mc * a * p.cos();
    let (mut lo, mut hi) = (0.0, std::f64::consts::FRAC_PI_2);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if balance(lo) * balance(mid) <= 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let phi = lo;
    for ea in [1e3, 1e6] {
        for start_deg in [0.0, 10.0, 30.0, 50.0, 80.0] {
            let p0 = f64::to_radians(start_deg);
            let (bx, bz) = (l * p0.sin(), -l * p0.cos());
            let weight_z = -(rope - (a - bx).hypot(bz));
            let text = format!(
                "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"ground\"\nkind = \"fixed\"\npoints = {{ pulley = [{a}, 0.0, 0.0] }}\n[[bodies]]\nname = \"arm\"\nkind = \"bar\"\nmass = {mb}\nends = [[0.0, 0.0, 0.0], [{bx}, 0.0, {bz}]]\n[[bodies]]\nname = \"weight\"\nkind = \"node\"\nmass = {mc}\nposition = [{a}, 0.0, {weight_z}]\n[[joints]]\nkind = \"pin\"\na = \"arm.a\"\n[[cables]]\nname = \"rope\"\nroute = [\"arm.b\", \"ground.pulley\", \"weight\"]\nea = {ea}\nrest_length = {rope}\n"
            );
            let what = format!("EA {ea:e}, start {start_deg} degrees");
            let (model, _, ws, r) = solve(&text, &what);
            let b = point(&model, &ws, "arm.b");
            let angle = b.x.atan2(-b.z);
            assert!(
                (angle - phi).abs() < 1e-8,
                "{what}: {} degrees, closed form {}",
                angle.to_degrees(),
                phi.to_degrees()
            );
            assert!(
                (ws.cables[0].tension - mc * 9.81).abs() < 1e-8 * mc * 9.81,
                "{what}: tension {}",
                ws.cables[0].tension
            );
            assert!(r.stable && r.iterations <= 40, "{what}: {r:?}");
        }
    }
}
