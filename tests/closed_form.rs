//! Invariant: statics reproduces closed-form equilibria to tight tolerances.
//! - Elastic Atwood machine with equal masses m at rest: tension `m g`, stretch `m g L0 / EA`.
//! - Regular n-prism (n = 3, 4, 5) on pinned supports, started away from its equilibrium: Newton
//!   returns to the prism geometry with force densities `q_bar = -q_side`,
//!   `q_ring = q_side / (2 sin(pi/n))` (docs/architecture.md), to 1e-9 relative, and clustering the top
//!   ring into one sliding cable leaves that equilibrium unchanged.

mod common;

use common::*;
use nalgebra::DVector;
use std::f64::consts::PI;
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::scene::generate::{atwood, prism, prism_twist, AtwoodParams, PrismParams};
use tensegrity::solve::statics::StaticSolver;
use tensegrity::state::{retract, State};

#[test]
fn equal_mass_atwood_machine_hangs_at_tension_m_g() {
    for (m, k) in [(1.0, 1000.0), (5.0, 1e2), (0.3, 1e6)] {
        let model = model_of(&atwood(&AtwoodParams { m1: m, m2: m, stiffness: k, ..Default::default() }));
        let mut state = State::initial(&model);
        let mut ws = Workspace::new(&model);
        let r = StaticSolver::new(&model)
            .equilibrate(&model, &mut state, &mut ws, &model.solver)
            .unwrap_or_else(|e| panic!("m = {m}, k = {k}: {e:?}"));
        evaluate(&model, &state, &mut ws, Tangents::None);
        let c = ws.cables[0];
        let g = 9.81;
        let ea = model.cables[0].axial_stiffness;
        assert!((c.tension - m * g).abs() <= 1e-9 * m * g, "tension {} vs {}", c.tension, m * g);
        let stretch = c.length - c.rest_length;
        let expected = m * g * c.rest_length / ea;
        assert!((stretch - expected).abs() <= 1e-9 * expected, "stretch {stretch} vs {expected}");
        // the masses' sliding mode is neutral: not reported as stable
        assert!(!r.stable);
    }
}

fn check_prism(n: usize, cluster: bool) {
    let (radius, height) = (0.8 + 0.1 * n as f64, 1.0 + 0.2 * n as f64);
    let params = PrismParams {
        n,
        radius,
        height,
        cluster_top_ring: cluster,
        deploy_shortening: 0.0,
        ..Default::default()
    };
    let model = model_of(&prism(&params));
    let mut state = State::initial(&model);
    // disturb every body (twist, tilt), then let Newton find the equilibrium again
    let dq = DVector::from_fn(model.dof_count, |i, _| 0.03 * ((i as f64 * 1.7).sin()));
    retract(&model, &mut state.poses, &dq, 1.0);
    let mut ws = Workspace::new(&model);
    let r = StaticSolver::new(&model)
        .equilibrate(&model, &mut state, &mut ws, &model.solver)
        .expect("equilibrium");
    assert!(r.stable, "prism n={n} cluster={cluster} must be prestress-stable");
    evaluate(&model, &state, &mut ws, Tangents::None);

    // geometry: top node i back at angle 2 pi i/n + alpha, height h
    let alpha = prism_twist(n);
    for i in 0..n {
        let top = ws.points[model.point_id(&format!("bar0_{i}.b")).unwrap().0].position;
        let ang = 2.0 * PI * i as f64 / n as f64 + alpha;
        let expected = nalgebra::Vector3::new(radius * ang.cos(), radius * ang.sin(), height);
        assert!((top - expected).norm() < 1e-9 * radius, "top node {i}: {top} vs {expected}");
    }
    // force densities
    let side = ws.cables[model.cable_id("side0").unwrap().0];
    let q_side = side.tension / side.length;
    let q_ring_expected = q_side / (2.0 * (PI / n as f64).sin());
    let ring_density: Vec<f64> = if cluster {
        let c = model.cable_id("ring").unwrap().0;
        // one tension along the whole loop; every segment has the ring-string length
        let seg = ws.cable_segments(&model, c);
        seg.iter().map(|l| ws.cables[c].tension / l).collect()
    } else {
        (0..n)
            .map(|i| {
                let c = ws.cables[model.cable_id(&format!("ring{i}")).unwrap().0];
                c.tension / c.length
            })
            .collect()
    };
    for q in ring_density {
        assert!(
            (q - q_ring_expected).abs() <= 1e-9 * q_ring_expected,
            "n={n}: q_ring {q} vs {q_ring_expected}"
        );
    }
    for i in 0..n {
        let s = ws.cables[model.cable_id(&format!("side{i}")).unwrap().0];
        assert!((s.tension / s.length - q_side).abs() <= 1e-9 * q_side);
    }
    // bar force density: the bar is a two-force member, so the cable forces on its top end add up
    // to the bar force along its axis; q_bar = -|F_top| / l_bar
    for i in 0..n {
        let top = model.point_id(&format!("bar0_{i}.b")).unwrap();
        let a = ws.points[model.point_id(&format!("bar0_{i}.a")).unwrap().0].position;
        let b = ws.points[top.0].position;
        let f = cable_force_on_point(&model, &ws, top);
        assert!(
            f.cross(&(b - a)).norm() <= 1e-9 * f.norm() * (b - a).norm(),
            "bar {i} is not a two-force member"
        );
        let q_bar = -f.norm() / (b - a).norm();
        assert!((q_bar + q_side).abs() <= 1e-9 * q_side, "n={n}: q_bar {q_bar} vs {}", -q_side);
    }
}

/// Sum of the cable forces acting at point `pid` (N), from the route geometry: an anchor or pulley
/// at route index j receives `T (e_(j+1) - e_j)`.
fn cable_force_on_point(
    model: &tensegrity::Model,
    ws: &Workspace,
    pid: tensegrity::model::PointId,
) -> nalgebra::Vector3<f64> {
    let mut f = nalgebra::Vector3::zeros();
    for c in 0..model.cables.len() {
        let route = model.route(tensegrity::model::CableId(c));
        let pos = |j: usize| ws.points[route[j].0].position;
        for j in 0..route.len() {
            if route[j] != pid {
                continue;
            }
            if j + 1 < route.len() {
                f += ws.cables[c].tension * (pos(j + 1) - pos(j)).normalize();
            }
            if j > 0 {
                f += ws.cables[c].tension * (pos(j - 1) - pos(j)).normalize();
            }
        }
    }
    f
}

#[test]
fn prism_self_stress_matches_closed_form() {
    for n in [3, 4, 5] {
        check_prism(n, false);
    }
}

#[test]
fn clustering_the_top_ring_keeps_the_prism_equilibrium() {
    for n in [3, 4, 5] {
        check_prism(n, true);
    }
}

#[test]
fn force_density_targets_give_the_same_prism_as_tension_targets() {
    // the 4-prism specified by force densities only: q_side on the sides, nothing on the rings
    let spec =
        prism(&PrismParams { n: 4, cluster_top_ring: false, deploy_shortening: 0.0, ..Default::default() });
    let mut by_density = spec.clone();
    let q_side = 100.0 / 1.7;
    for c in by_density.cables.iter_mut() {
        if c.name.starts_with("side") {
            c.prestress = None;
            c.force_density = Some(q_side);
        }
    }
    let model = model_of(&by_density);
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    StaticSolver::new(&model).equilibrate(&model, &mut state, &mut ws, &model.solver).unwrap();
    evaluate(&model, &state, &mut ws, Tangents::None);
    let q_ring = q_side / (2.0 * (PI / 4.0).sin());
    for (c, name) in model.cable_names.iter().enumerate() {
        let q = ws.cables[c].tension / ws.cables[c].length;
        let expected = if name.starts_with("side") { q_side } else { q_ring };
        assert!((q - expected).abs() <= 1e-9 * expected, "{name}: {q} vs {expected}");
    }
}
