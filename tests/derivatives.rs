//! Invariant: every analytic derivative the solvers use equals its finite-difference twin taken
//! along the same group retraction — cable length gradient `g`, generalized force, tangent
//! stiffness `K = -dQ/dq` (elastic, geometric and damping parts), damping matrix `C = -dQ/dv`,
//! joint Jacobian `Phi_q` and multiplier Hessian — for every body kind, arbitrary rotations, and
//! classical and sliding cables with 1 to 5 pulleys, and elastic members (`tension_only = false`)
//! in tension and in compression.

mod common;

use common::*;
use nalgebra::{DMatrix, DVector};
use proptest::prelude::*;
use tensegrity::constraints::add_multiplier_hessian;
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::scene::{BodyKindSpec, BodySpec, CableSpec, JointKindSpec, JointSpec, PointSpec, SceneSpec};
use tensegrity::state::State;

/// A scene with one body of each kind; `route` indexes into its point pool.
fn scene(p: &Params, route: &[usize], planar: bool) -> SceneSpec {
    let z = |v: [f64; 3]| if planar { [v[0], v[1], 0.0] } else { v };
    let zr = |v: [f64; 3]| if planar { [0.0, 0.0, v[2]] } else { v };
    let mut g = BodySpec::new("g", BodyKindSpec::Fixed);
    g.position = Some(z(p.pos[0]));
    g.rotation = Some(zr(p.rot[0]));
    g.points.insert("p".into(), PointSpec::Local(p.local[0]));
    let mut n = BodySpec::new("n", BodyKindSpec::Node);
    n.mass = Some(1.5);
    n.position = Some(z(p.pos[1]));
    let mut b = BodySpec::new("b", BodyKindSpec::Bar);
    b.mass = Some(2.0);
    let (c, d) = (z(p.pos[2]), p.local[1]);
    let d = if planar { [d[0], d[1] + 0.5, 0.0] } else { [d[0], d[1], d[2] + 0.5] };
    b.ends = Some([[c[0] - d[0], c[1] - d[1], c[2] - d[2]], [c[0] + d[0], c[1] + d[1], c[2] + d[2]]]);
    b.points.insert("m".into(), PointSpec::Along(0.3));
    let mut r = BodySpec::new("r", BodyKindSpec::Rigid);
    r.mass = Some(3.0);
    r.position = Some(z(p.pos[3]));
    r.rotation = Some(zr(p.rot[1]));
    r.inertia = Some(vec![0.3, 0.4, 0.5, 0.01, -0.02, 0.03]);
    r.points.insert("p".into(), PointSpec::Local(p.local[2]));
    r.points.insert("q".into(), PointSpec::Local(p.local[3]));
    let pool = ["g.p", "n", "b.a", "b.b", "b.m", "r.p", "r.q"];
    let mut names: Vec<String> = route.iter().map(|&i| pool[i % pool.len()].to_string()).collect();
    names.dedup();
    if names.len() < 2 {
        names = vec!["n".into(), "r.p".into()];
    }
    let cable = CableSpec {
        name: "c".into(),
        route: names,
        ea: 1e3,
        damping: Some(p.damping),
        damping_ratio: None,
        rest_length: Some(0.5),
        prestress: None,
        force_density: None,
        tension_only: true,
        pulley_friction: None,
        winch_end: None,
    };
    SceneSpec { planar, bodies: vec![g, n, b, r], cables: vec![cable], ..Default::default() }
}

#[derive(Debug, Clone)]
struct Params {
    pos: [[f64; 3]; 4],
    rot: [[f64; 3]; 2],
    local: [[f64; 3]; 4],
    damping: f64,
    vel: Vec<f64>,
}

fn v3() -> impl Strategy<Value = [f64; 3]> {
    [-2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64]
}

fn params() -> impl Strategy<Value = Params> {
    (
        [v3(), v3(), v3(), v3()],
        [v3(), v3()],
        [v3(), v3(), v3(), v3()],
        prop_oneof![Just(0.0), 0.1..20.0f64],
        proptest::collection::vec(-1.0..1.0f64, 14),
    )
        .prop_map(|(pos, rot, local, damping, vel)| Params { pos, rot, local, damping, vel })
}

fn check(p: &Params, route: &[usize], planar: bool) -> Result<(), TestCaseError> {
    check_element(p, route, planar, None)
}

/// `check` for a cable, or with `member = Some(r)` for a two-point member (`tension_only =
/// false`) whose rest length is `r` times its initial length (compressed when `r > 1`).
fn check_element(
    p: &Params,
    route: &[usize],
    planar: bool,
    member: Option<f64>,
) -> Result<(), TestCaseError> {
    let mut spec = scene(p, route, planar);
    if let Some(ratio) = member {
        prop_assume!(spec.cables[0].route.len() == 2);
        let length = {
            let model = model_of(&spec);
            let mut ws = Workspace::new(&model);
            evaluate(&model, &State::initial(&model), &mut ws, Tangents::None);
            ws.cables[0].length
        };
        prop_assume!(length > 0.05);
        spec.cables[0].tension_only = false;
        spec.cables[0].rest_length = Some(length * ratio);
    }
    let model = model_of(&spec);
    let mut state = State::initial(&model);
    for (j, v) in state.velocities.iter_mut().enumerate() {
        *v = p.vel[j];
    }
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::StiffnessAndDamping);
    let cable = ws.cables[0];
    prop_assume!(cable.tension > 1.0 || (member.is_some() && cable.tension.abs() > 1.0));
    prop_assert!(!(member.is_some() && cable.slack), "a member is never slack");
    prop_assume!(ws.segment_lengths.iter().all(|l| *l > 0.05));
    let h = 1e-6;

    // g = dL/dq and Ldot = g^T v
    let mut g_fd = DVector::zeros(model.dof_count);
    for j in 0..model.dof_count {
        let mut w = Workspace::new(&model);
        evaluate(&model, &perturbed(&model, &state, j, h), &mut w, Tangents::None);
        let lp = w.cables[0].length;
        evaluate(&model, &perturbed(&model, &state, j, -h), &mut w, Tangents::None);
        g_fd[j] = (lp - w.cables[0].length) / (2.0 * h);
    }
    // Q = -T g
    let g = -&ws.force / cable.tension;
    prop_assert!((&g - &g_fd).amax() < 1e-7, "gradient: {g} vs {g_fd}");
    prop_assert!((g.dot(&state.velocities) - cable.length_rate).abs() < 1e-9);

    let k_fd = fd_stiffness(&model, &state, 1e-5);
    let ek = rel_err(&ws.stiffness, &k_fd, cable.tension.abs());
    prop_assert!(
        ek < 1e-6,
        "stiffness rel err {ek} damping {} T {} v {:?}\nK-K_fd = {:.3e}",
        p.damping,
        cable.tension,
        state.velocities.as_slice(),
        &ws.stiffness - &k_fd
    );
    // Q is affine in v while the cable stays taut, so a large step is exact
    let c_fd = fd_damping(&model, &state, 1e-3);
    prop_assert!(
        (&ws.damping - &c_fd).amax() < 1e-6 * c_fd.amax().max(1.0),
        "damping C = {} C_fd = {c_fd}",
        ws.damping
    );
    // symmetric part of the elastic K equals the FD Hessian of the energy when undamped
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

    #[test]
    fn sliding_cable_derivatives_match_finite_differences(p in params(), route in proptest::collection::vec(0usize..7, 2..=6)) {
        check(&p, &route, false)?;
    }

    #[test]
    fn member_derivatives_match_finite_differences_in_tension_and_compression(p in params(), ends in [0usize..7, 0usize..7], ratio in 0.6..1.4f64, planar in proptest::bool::ANY) {
        check_element(&p, &ends, planar, Some(ratio))?;
    }

    #[test]
    fn planar_sliding_cable_derivatives_match_finite_differences(p in params(), route in proptest::collection::vec(0usize..7, 2..=6)) {
        check(&p, &route, true)?;
    }

    #[test]
    fn joint_jacobian_and_multiplier_hessian_match_finite_differences(p in params(), lam in [-5.0..5.0f64, -5.0..5.0f64, -5.0..5.0f64]) {
        let mut spec = scene(&p, &[1, 5], false);
        // join the bar's end b to the rigid body's point p where they are: move the rigid body
        let model0 = model_of(&spec);
        let st0 = State::initial(&model0);
        let mut ws0 = Workspace::new(&model0);
        evaluate(&model0, &st0, &mut ws0, Tangents::None);
        let pb = ws0.points[model0.point_id("b.b").unwrap().0].position;
        let pr = ws0.points[model0.point_id("r.p").unwrap().0].position;
        let shift = pb - pr;
        let rp = spec.bodies[3].position.unwrap();
        spec.bodies[3].position = Some([rp[0] + shift.x, rp[1] + shift.y, rp[2] + shift.z]);
        spec.joints = vec![
            JointSpec { kind: JointKindSpec::Ball, a: "b.b".into(), b: Some("r.p".into()), at: None, direction: None, normal: None, axis: None, damping: None },
            JointSpec { kind: JointKindSpec::Pin, a: "n".into(), b: None, at: None, direction: None, normal: None, axis: None, damping: None },
        ];
        let model = model_of(&spec);
        let state = State::initial(&model);
        let lambda = DVector::from_vec(vec![lam[0], lam[1], lam[2], lam[2], lam[0], lam[1]]);
        let mut ws = Workspace::new(&model);
        evaluate(&model, &state, &mut ws, Tangents::None);
        let h = 1e-6;
        let n = model.dof_count;
        let mut jac_fd = DMatrix::zeros(model.constraint_count, n);
        let mut hess_fd = DMatrix::zeros(n, n);
        let phi_at = |s: &State| { let mut w = Workspace::new(&model); evaluate(&model, s, &mut w, Tangents::None); (w.constraint.clone(), w.constraint_jacobian.transpose() * &lambda) };
        for j in 0..n {
            let (fp, tp) = phi_at(&perturbed(&model, &state, j, h));
            let (fm, tm) = phi_at(&perturbed(&model, &state, j, -h));
            jac_fd.set_column(j, &((fp - fm) / (2.0 * h)));
            hess_fd.set_column(j, &((tp - tm) / (2.0 * h)));
        }
        prop_assert!((&ws.constraint_jacobian - &jac_fd).amax() < 1e-7);
        let mut hess = DMatrix::zeros(n, n);
        add_multiplier_hessian(&model, &state.poses, &lambda, &mut hess);
        prop_assert!((&hess - &hess_fd).amax() < 1e-6 * hess_fd.amax().max(1.0), "H = {hess}\nH_fd = {hess_fd}");
    }
}
