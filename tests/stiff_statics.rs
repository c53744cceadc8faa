//! Invariant: `statics` costs about the same at every cable stiffness. Mechanisms held by cables
//! (a bar pinned at one end with its tip held over a pulley by a counterweight; a point mass hung
//! on a cable from a hook; a point mass riding on a sliding cable between two hooks), with EA
//! from 1e2 to 1e9 N, from starts around the circle where the geometry allows (cables just taut,
//! slack with the mass inside the cable's reach, or overstretched), each converge in at most
//! `BUDGET` Newton iterations, to the equilibrium a continuation in EA reaches from the soft one
//! (each stiffer solve started from the softer solution). The prestressed bundled structures
//! (prism, T-bar) with their cables stiffened to 1e9 N come back from disturbed starts too.

mod common;

use nalgebra::{DVector, Vector3};
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::scene::generate::{prism, tbar, PrismParams, TbarParams};
use tensegrity::solve::statics::StaticSolver;
use tensegrity::state::retract;
use tensegrity::{Model, State};

/// Most Newton iterations any case may take (docs/accuracy.md gives the measured worst).
const BUDGET: usize = 30;
const STIFFNESSES: [f64; 8] = [1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9];

/// Solves from `state`; the iterations and every named point's position, or why not.
fn solve(model: &Model, state: &mut State) -> Result<(usize, Vec<Vector3<f64>>), String> {
    let mut ws = Workspace::new(model);
    let r = StaticSolver::new(model)
        .equilibrate(model, state, &mut ws, &model.solver)
        .map_err(|(it, res)| format!("no equilibrium: residual {res:.3e} N after {it} iterations"))?;
    if !r.stable {
        return Err(format!("{} after {} iterations", r.stability_words(), r.iterations));
    }
    evaluate(model, state, &mut ws, Tangents::None);
    Ok((r.iterations, ws.points.iter().map(|p| p.position).collect()))
}

/// Checks one mechanism (`scene(ea, start)` gives its scene text) over every stiffness and start:
/// the iteration budget, and the equilibrium against a continuation in EA from the softest.
/// Prints and returns the worst iteration count at each stiffness.
fn sweep(what: &str, starts: &[f64], scene: impl Fn(f64, f64) -> String) -> [usize; 8] {
    let mut worst = [0; 8];
    for &start in starts {
        let mut continued: Option<State> = None;
        for (e, ea) in STIFFNESSES.into_iter().enumerate() {
            let case = format!("{what}, EA {ea:e} N, start {start}");
            let model =
                tensegrity::scene::from_toml(&scene(ea, start), &case).unwrap_or_else(|e| panic!("{e}"));
            let mut state = State::initial(&model);
            let (iterations, points) = solve(&model, &mut state).unwrap_or_else(|e| panic!("{case}: {e}"));
            assert!(iterations <= BUDGET, "{case}: {iterations} Newton iterations");
            worst[e] = worst[e].max(iterations);
            // the continuation: this stiffness from the softer one's equilibrium
            let mut from_softer = match &continued {
                Some(softer) => State { rest_lengths: state.rest_lengths.clone(), ..softer.clone() },
                None => State::initial(&model),
            };
            let (_, along) =
                solve(&model, &mut from_softer).unwrap_or_else(|e| panic!("{case}, continued: {e}"));
            for (p, (a, b)) in points.iter().zip(&along).enumerate() {
                assert!((a - b).norm() < 1e-8, "{case}: point {p} at {a:?}, the continuation's at {b:?}");
            }
            continued = Some(from_softer);
        }
    }
    println!("{what}: worst Newton iterations at EA 1e2..1e9 N: {worst:?}");
    worst
}

#[test]
fn a_bar_held_over_a_pulley_by_a_counterweight_costs_the_same_at_every_stiffness() {
    // bar pinned at the origin (length 1 m, 2 kg), its tip tied to a 2 m rope over a pulley at
    // (1, 0, 0) down to a 0.6 kg weight; started at `deg` from hanging, the rope just taut
    sweep("bar over a pulley", &[0.0, 10.0, 30.0, 45.0, 60.0, 90.0, 120.0, 150.0, 170.0], |ea, deg| {
        let (bx, bz) = (deg.to_radians().sin(), -deg.to_radians().cos());
        let weight_z = -(2.0 - (1.0 - bx).hypot(bz));
        format!(
            "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"ground\"\nkind = \"fixed\"\npoints = {{ pulley = [1.0, 0.0, 0.0] }}\n[[bodies]]\nname = \"arm\"\nkind = \"bar\"\nmass = 2.0\nends = [[0.0, 0.0, 0.0], [{bx}, 0.0, {bz}]]\n[[bodies]]\nname = \"weight\"\nkind = \"node\"\nmass = 0.6\nposition = [1.0, 0.0, {weight_z}]\n[[joints]]\nkind = \"pin\"\na = \"arm.a\"\n[[cables]]\nname = \"rope\"\nroute = [\"arm.b\", \"ground.pulley\", \"weight\"]\nea = {ea}\nrest_length = 2.0\n"
        )
    });
}

/// Quasi-static deployment with stiff cables: a winch hauls in the bar-over-a-pulley mechanism's
/// rope from 2.0 to 1.6 m in 20 load steps (the bar swings up from 30 degrees, the weight rises)
/// at every EA from 1e2 to 1e9 N: no load step is cut, none takes more than `BUDGET` iterations.
#[test]
fn quasi_static_deployment_cuts_no_load_step_at_any_stiffness() {
    use tensegrity::solve::deploy::deploy_quasi_static;
    let mut worst = [0; 8];
    for (e, ea) in STIFFNESSES.into_iter().enumerate() {
        let (bx, bz) = (30f64.to_radians().sin(), -30f64.to_radians().cos());
        let weight_z = -(2.0 - (1.0 - bx).hypot(bz));
        let text = format!(
            "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"ground\"\nkind = \"fixed\"\npoints = {{ pulley = [1.0, 0.0, 0.0] }}\n[[bodies]]\nname = \"arm\"\nkind = \"bar\"\nmass = 2.0\nends = [[0.0, 0.0, 0.0], [{bx}, 0.0, {bz}]]\n[[bodies]]\nname = \"weight\"\nkind = \"node\"\nmass = 0.6\nposition = [1.0, 0.0, {weight_z}]\n[[joints]]\nkind = \"pin\"\na = \"arm.a\"\n[[cables]]\nname = \"rope\"\nroute = [\"arm.b\", \"ground.pulley\", \"weight\"]\nea = {ea}\nrest_length = 2.0\n[[actuators]]\nname = \"winch\"\ncable = \"rope\"\nmin_rest_length = 1.0\nmax_rest_length = 2.0\nmax_rate = 1.0\n[deployment]\nsteps = 20\n[[deployment.ramps]]\nactuator = \"winch\"\nstart = 0.0\nduration = 1.0\nrest_length = 1.6\n"
        );
        let case = format!("winch on the bar over a pulley, EA {ea:e} N");
        let model = tensegrity::scene::from_toml(&text, &case).unwrap_or_else(|e| panic!("{e}"));
        let mut state = State::initial(&model);
        let mut ws = Workspace::new(&model);
        let path = deploy_quasi_static(&model, &mut state, &mut ws, |_, _, _| {})
            .unwrap_or_else(|e| panic!("{case}: {e}"));
        assert!(path.snaps.is_empty(), "{case}: {:?}", path.snaps);
        let rows: Vec<_> = path.output_steps().collect();
        assert_eq!(rows.len(), 21, "{case}");
        for row in rows {
            assert_eq!(row.cuts, 0, "{case}: load step {} was cut", row.index);
            assert!(row.report.iterations <= BUDGET, "{case}: load step {}: {:?}", row.index, row.report);
            assert!(row.report.stable, "{case}: load step {}: {:?}", row.index, row.report);
            worst[e] = worst[e].max(row.report.iterations);
        }
    }
    println!(
        "winch on the bar over a pulley: worst Newton iterations per load step at EA 1e2..1e9 N: {worst:?}"
    );
}

#[test]
fn a_mass_hung_on_a_cable_costs_the_same_at_every_stiffness_slack_or_overstretched() {
    // a 1 kg point mass on a 1 m cable from a hook, started at `r` m from the hook at 40 degrees
    // from the vertical: inside the cable's reach (slack), at it, or beyond it (overstretched)
    sweep("mass on a cable", &[0.3, 0.9, 1.0, 1.1, 1.5], |ea, r| {
        let (x, z) = (r * 40f64.to_radians().sin(), -r * 40f64.to_radians().cos());
        format!(
            "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"ground\"\nkind = \"fixed\"\npoints = {{ hook = [0.0, 0.0, 0.0] }}\n[[bodies]]\nname = \"bob\"\nkind = \"node\"\nmass = 1.0\nposition = [{x}, 0.0, {z}]\n[[cables]]\nname = \"cable\"\nroute = [\"ground.hook\", \"bob\"]\nea = {ea}\nrest_length = 1.0\n"
        )
    });
}

#[test]
fn a_mass_riding_on_a_sliding_cable_costs_the_same_at_every_stiffness() {
    // a 1 kg point mass rides on a 3 m cable between hooks 2 m apart (a pulley on the mass),
    // started off to one side at `x` m from the middle, at the cable's length or short of it
    sweep("mass on a sliding cable", &[-0.8, -0.4, 0.0, 0.5, 0.9], |ea, x| {
        format!(
            "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"ground\"\nkind = \"fixed\"\npoints = {{ left = [-1.0, 0.0, 0.0], right = [1.0, 0.0, 0.0] }}\n[[bodies]]\nname = \"bob\"\nkind = \"node\"\nmass = 1.0\nposition = [{x}, 0.0, -1.0]\n[[cables]]\nname = \"cable\"\nroute = [\"ground.left\", \"bob\", \"ground.right\"]\nea = {ea}\nrest_length = 3.0\n"
        )
    });
}

/// How far the body of `a` farthest from its place in `b` is from it, m.
fn farthest_body(a: &State, b: &State) -> f64 {
    a.poses.iter().zip(&b.poses).map(|(p, q)| (p.position - q.position).norm()).fold(0.0, f64::max)
}

/// A prestressed structure with cables of axial stiffness `ea`, from its form-found start moved
/// by rotations and translations of every body of up to 0.02, 0.05 and 0.1 (m, rad): back to its
/// form-found geometry (the equilibrium it started in) within 1e-9 m. Returns the worst
/// iteration count.
fn prestressed_comes_back(model: &Model, what: &str) -> usize {
    let start = State::initial(model);
    let mut worst = 0;
    for k in 0..4 {
        let mut state = start.clone();
        let size = [0.02, 0.05, 0.1, 0.02][k];
        let dq = DVector::from_fn(model.dof_count, |i, _| size * ((i * 7 + k * 13) as f64).sin());
        retract(model, &mut state.poses, &dq, 1.0);
        let (iterations, _) = solve(model, &mut state).unwrap_or_else(|e| panic!("{what}, case {k}: {e}"));
        let off = farthest_body(&state, &start);
        assert!(off < 1e-9, "{what}, case {k}: {off} m off the form-found geometry");
        worst = worst.max(iterations);
    }
    worst
}

/// The prism and the T-bar with their cables at EA 1e2 to 1e9 N: the displacement form below
/// `statics::PRESTRESSED_STIFF_RATIO`, the bilateral mixed form above it
/// (`statics::prestressed_stiff_cables`). The worst iteration count stays flat from 1e5 N
/// (measured: prism 4, 6, 12, 16, 15, 16, 17, 16; T-bar 4, 6, 14, 11, 4, 4, 4, 4); the
/// displacement form alone took the prism to 19, 22, 25 and 29 from 1e6 to 1e9 N, the T-bar to
/// 10, 8, 8, 8.
#[test]
fn prestressed_structures_with_stiff_cables_come_back_from_disturbed_starts() {
    let (mut prisms, mut tbars) = (Vec::new(), Vec::new());
    for ea in STIFFNESSES {
        let spec = prism(&PrismParams { ea, cluster_top_ring: true, ..Default::default() });
        let model = tensegrity::scene::build_model(&spec, "<prism>", None).unwrap();
        prisms.push(prestressed_comes_back(&model, &format!("prism, EA {ea:e} N")));
        let spec = tbar(&TbarParams { ea, ..Default::default() });
        let model = tensegrity::scene::build_model(&spec, "<tbar>", None).unwrap();
        tbars.push(prestressed_comes_back(&model, &format!("T-bar, EA {ea:e} N")));
    }
    println!("worst Newton iterations at EA 1e2..1e9 N: prism {prisms:?}, T-bar {tbars:?}");
    let worst = prisms.iter().chain(&tbars).copied().max().unwrap_or(0);
    assert!(worst <= 20, "{worst} Newton iterations");
    // no growth with EA: the stiffest four within two iterations of the 1e5 N case
    for counts in [&prisms, &tbars] {
        assert!(counts[4..].iter().all(|&c| c <= counts[3] + 2), "{counts:?}");
    }
}

/// The nodal prism (struts as elastic members of EA 1e4 to 1e10 N between point masses, cables
/// as bundled) from its form-found start moved by up to 0.02, 0.05 and 0.1 m: its stiff members'
/// forces are unknowns of the mixed form (they never go slack, so the prism keeps its
/// self-stress), and every solve comes back to the form-found geometry within a count that does
/// not grow with EA. The displacement form took 10 to 62 iterations from EA 1e4 to 1e9 N and
/// failed from 1e10 N. (From 1e11 N the solves converge as well, in 7 to 15 iterations, but the
/// stability test's relative tolerance, 1e-9 of the largest eigenvalue, calls the prism's
/// softest modes zero.)
#[test]
fn a_nodal_prism_with_stiff_members_comes_back_at_every_member_stiffness() {
    let mut worst_by_ea = Vec::new();
    for ea in [1e4, 1e6, 1e8, 1e9, 1e10, 1e11, 1e12] {
        let mut spec = prism(&PrismParams::default());
        tensegrity::scene::generate::nodal_struts(&mut spec, ea, Default::default());
        let model = tensegrity::scene::build_model(&spec, "<nodal prism>", None).unwrap();
        let start = State::initial(&model);
        let mut worst = 0;
        for (k, size) in [0.02, 0.05, 0.1].into_iter().enumerate() {
            let mut state = start.clone();
            let dq = DVector::from_fn(model.dof_count, |i, _| size * ((i * 7 + k * 13 + 1) as f64).sin());
            retract(&model, &mut state.poses, &dq, 1.0);
            let (iterations, _) =
                solve(&model, &mut state).unwrap_or_else(|e| panic!("EA {ea:e}, {size} m: {e}"));
            let off = farthest_body(&state, &start);
            assert!(off < 1e-9, "EA {ea:e}, {size} m: {off} m off the form-found geometry");
            worst = worst.max(iterations);
        }
        assert!(worst <= 16, "EA {ea:e}: {worst} Newton iterations");
        worst_by_ea.push(worst);
    }
    println!("nodal prism: worst Newton iterations at member EA 1e4, 1e6, 1e8, 1e9, 1e10, 1e11, 1e12 N: {worst_by_ea:?}");
}

/// Invariant: a solve says why it stopped and how its residual went, and its cap ends a solve that
/// stagnates, not one that converges. A converged solve has one residual per iteration and the
/// final one; a solve that reaches its cap while the residual still falls goes on and converges;
/// one that cannot converge (the atwood machine's unequal masses have no static equilibrium)
/// stops at its cap and says it stagnated or diverged, never that it converged.
#[test]
fn a_solve_reports_why_it_stopped_and_its_residual_history() {
    use tensegrity::solve::statics::StopReason;
    let text = |max: usize| {
        format!(
        "gravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"ground\"\nkind = \"fixed\"\npoints = {{ pulley = [1.0, 0.0, 0.0] }}\n[[bodies]]\nname = \"arm\"\nkind = \"bar\"\nmass = 2.0\nends = [[0.0, 0.0, 0.0], [0.7071067811865476, 0.0, -0.7071067811865476]]\n[[bodies]]\nname = \"weight\"\nkind = \"node\"\nmass = 0.6\nposition = [1.0, 0.0, -1.2346331352698203]\n[[joints]]\nkind = \"pin\"\na = \"arm.a\"\n[[cables]]\nname = \"rope\"\nroute = [\"arm.b\", \"ground.pulley\", \"weight\"]\nea = 1e6\nrest_length = 2.0\n[solver]\nmax_iterations = {max}\n"
    )
    };
    let model = tensegrity::scene::from_toml(&text(60), "bar").unwrap();
    let mut solver = StaticSolver::new(&model);
    let mut ws = Workspace::new(&model);
    let r = solver.equilibrate(&model, &mut State::initial(&model), &mut ws, &model.solver).unwrap();
    let h = solver.residual_history();
    assert_eq!((solver.stop_reason(), h.len()), (StopReason::Converged, r.iterations + 1), "{h:?}");
    assert!(h[h.len() - 1] < 1e-6 * h[0], "{h:?}");

    // capped at 2 while the residual still falls: the solve goes on (to 4 times the cap) and converges
    let model = tensegrity::scene::from_toml(&text(2), "bar, capped").unwrap();
    let r = solver.equilibrate(&model, &mut State::initial(&model), &mut ws, &model.solver).unwrap();
    assert!(r.iterations > 2 && r.iterations <= 8, "{r:?}");
    assert_eq!(solver.stop_reason(), StopReason::Converged);

    let atwood = common::bundled("atwood");
    let mut solver = StaticSolver::new(&atwood);
    let mut ws = Workspace::new(&atwood);
    let e = solver.equilibrate(&atwood, &mut State::initial(&atwood), &mut ws, &atwood.solver).unwrap_err();
    assert_eq!(e.0, atwood.solver.max_iterations, "a stagnating solve stops at its cap");
    assert!(
        matches!(solver.stop_reason(), StopReason::Stagnated | StopReason::Diverged | StopReason::Singular),
        "{:?}: {:?}",
        solver.stop_reason(),
        solver.residual_history()
    );
}
