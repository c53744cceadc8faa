//! Invariant: a member with a bending stiffness `EI` (or a buckling load `P`) buckles at the
//! Euler load `P = pi^2 EI / L0^2` and follows the elastica's initial post-buckling path.
//! - The law's force is the derivative of its energy, its tangent the derivative of its force,
//!   both continuous at the buckling load; the structure's stiffness matrix with a buckled
//!   member matches finite differences.
//! - Against the exact elastica (pinned-pinned, inextensible; `K(k)`, `E(k)` by the AGM) the
//!   post-buckling force is within 5e-4 of it up to a bow shortening of 4 % of the length.
//! - Statics of a column on a roller under weights around `P`: the shortening is `W L0 / EA`
//!   below `P` and bends to the post-buckling stiffness above; the knee sits at `pi^2 EI / L0^2`.
//! - A weight released onto the column buckles it and swings, the energy account closing.
//! - Careless members are refused naming the field.

mod common;

use common::*;
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::forces::cable::{elastic_energy, elastic_force, is_buckled, tangent_axial_stiffness};
use tensegrity::model::CableModel;
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::Integrator;
use tensegrity::solve::statics::StaticSolver;
use tensegrity::State;

const EA: f64 = 1e6;
const L0: f64 = 2.0;
const EI: f64 = 500.0;

fn euler_load() -> f64 {
    std::f64::consts::PI.powi(2) * EI / (L0 * L0)
}

fn member(p: f64) -> CableModel {
    CableModel {
        route_start: 0,
        route_len: 2,
        axial_stiffness: EA,
        damping: 0.0,
        tension_only: false,
        buckling_load: p,
        friction: None,
        winch: None,
    }
}

/// `K(k)` and `E(k)`, the complete elliptic integrals of modulus `k`, by the AGM.
fn elliptic(k: f64) -> (f64, f64) {
    let (mut a, mut b) = (1.0, (1.0 - k * k).sqrt());
    let (mut sum, mut power) = (0.5 * k * k, 1.0);
    for _ in 0..40 {
        let c = 0.5 * (a - b);
        (a, b) = (0.5 * (a + b), (a * b).sqrt());
        power *= 2.0;
        sum += 0.5 * power * c * c;
    }
    let big_k = std::f64::consts::PI / (2.0 * a);
    (big_k, big_k * (1.0 - sum))
}

#[test]
fn the_law_is_consistent_and_follows_the_elastica() {
    let p = euler_load();
    let m = member(p);
    let s_cr = p * L0 / EA;
    // force = dV/dL, tangent = dT/dL, on both branches and across the knee
    let h = 1e-7;
    for s in [0.2 * s_cr, 0.9 * s_cr, 1.5 * s_cr, 10.0 * s_cr, 0.05 * L0] {
        let l = L0 - s;
        let dv = (elastic_energy(&m, L0, l + h) - elastic_energy(&m, L0, l - h)) / (2.0 * h);
        let t = elastic_force(&m, L0, l);
        assert!((dv - t).abs() < 1e-6 * t.abs(), "dV/dL {dv} against T {t} at s = {s}");
        let dt = (elastic_force(&m, L0, l + h) - elastic_force(&m, L0, l - h)) / (2.0 * h);
        let k = tangent_axial_stiffness(&m, L0, l) / L0;
        assert!((dt - k).abs() < 1e-6 * k, "dT/dL {dt} against {k} at s = {s}");
        assert_eq!(is_buckled(&m, L0, l), s > s_cr);
        if s > s_cr {
            // what an actuator works against: dV/dL0 at a fixed length
            let dv0 = (elastic_energy(&m, L0 + h, l) - elastic_energy(&m, L0 - h, l)) / (2.0 * h);
            let analytic = tensegrity::forces::cable::buckled_energy_rest_derivative(&m, L0, l);
            assert!(
                (dv0 - analytic).abs() < 1e-6 * analytic.abs(),
                "dV/dL0 {dv0} against {analytic} at s = {s}"
            );
        }
    }
    let below = elastic_force(&m, L0, L0 - s_cr * (1.0 - 1e-12));
    let above = elastic_force(&m, L0, L0 - s_cr * (1.0 + 1e-12));
    assert!((below + p).abs() < 1e-6 && (above + p).abs() < 1e-6, "continuous at -P: {below}, {above}");
    // without a buckling load, the linear law at any compression
    let plain = member(f64::INFINITY);
    let l = L0 - 0.1;
    assert_eq!(elastic_force(&plain, L0, l), EA / L0 * (l - L0));
    // the elastica: P/P_cr = 4 K(k)^2 / pi^2 at a bow shortening delta/L = 2 (1 - E/K)
    let inextensible = CableModel { axial_stiffness: 1e15, ..member(p) };
    for k in [0.02, 0.05, 0.1, 0.15, 0.2] {
        let (big_k, big_e) = elliptic(k);
        let exact = p * 4.0 * big_k * big_k / std::f64::consts::PI.powi(2);
        let delta = L0 * 2.0 * (1.0 - big_e / big_k);
        let ours = -elastic_force(&inextensible, L0, L0 - exact * L0 / 1e15 - delta);
        let err = (ours - exact).abs() / exact;
        assert!(
            err < 5e-4,
            "k = {k}: bow shortening {:.4} L: {ours} N against the elastica's {exact} N",
            delta / L0
        );
    }
}

/// A planar column: a fixed base at the origin, a node of `mass` kg at (0, L0) held on a
/// vertical roller, joined by a member of EA and EI; gravity -y.
fn column(mass: f64, extra: &str) -> String {
    format!(
        r#"
planar = true
gravity = [0.0, -9.81, 0.0]
[[bodies]]
name = "base"
kind = "fixed"
[[bodies]]
name = "top"
kind = "node"
mass = {mass}
position = [0.0, {L0}, 0.0]
[[joints]]
kind = "roller"
a = "top"
direction = [0.0, 1.0, 0.0]
[[members]]
name = "column"
ends = ["base", "top"]
ea = {EA}
bending_stiffness = {EI}
{extra}
"#
    )
}

/// The column's shortening at equilibrium under a weight `w` (N).
fn shortening(w: f64) -> f64 {
    let model = model_from_toml(&column(w / 9.81, ""));
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    let report = StaticSolver::new(&model)
        .equilibrate(&model, &mut state, &mut ws, &model.solver)
        .expect("equilibrium");
    assert_eq!(report.negative_modes, 0, "{}", report.stability_words());
    L0 - state.poses[1].position.y
}

#[test]
fn a_column_buckles_at_the_euler_load() {
    let p = euler_load();
    let model = model_from_toml(&column(1.0, ""));
    assert!((model.cables[0].buckling_load - p).abs() < 1e-12 * p, "P = pi^2 EI / L0^2");
    let k_b = 1.0 / (L0 / EA + 2.0 * L0 / p);
    for f in [0.3, 0.8, 0.99] {
        let s = shortening(f * p);
        let want = f * p * L0 / EA;
        assert!((s - want).abs() < 1e-9 * want, "below P: {s} against {want}");
    }
    // (the post-buckling stiffness is about P / (2 L0): 1 % over P bows the column 2 % of L0)
    for f in [1.001, 1.005, 1.01] {
        let s = shortening(f * p);
        let want = p * L0 / EA + (f - 1.0) * p / k_b;
        assert!((s - want).abs() < 1e-9 * want, "above P: {s} against {want}");
    }
    // the knee: where the two branches' lines meet, found from the equilibria alone
    let (w1, w2, w3, w4) = (0.5 * p, 0.9 * p, 1.002 * p, 1.01 * p);
    let (s1, s2, s3, s4) = (shortening(w1), shortening(w2), shortening(w3), shortening(w4));
    let (a1, a2) = ((s2 - s1) / (w2 - w1), (s4 - s3) / (w4 - w3));
    let knee = (s3 - s1 + a1 * w1 - a2 * w3) / (a1 - a2);
    assert!((knee - p).abs() < 1e-6 * p, "buckles at {knee} N, Euler's {p} N");
    // statics says so
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_tensegrity"))
        .args(["statics", concat!(env!("CARGO_MANIFEST_DIR"), "/config/examples/column.toml"), "--json"])
        .output()
        .unwrap();
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("statics --json");
    let column = &json["cables"][0];
    assert_eq!(column["buckled"], serde_json::Value::Bool(true), "{column}");
}

#[test]
fn a_buckled_members_stiffness_matches_finite_differences() {
    // a 3-D bar propped by a buckling member from the ground, compressed past P by its weight
    let model = model_from_toml(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "ground"
kind = "fixed"
points = { foot = [0.3, 0.1, 0.0] }
[[bodies]]
name = "bar"
kind = "bar"
mass = 2.0
ends = [[0.0, 0.0, 1.0], [1.2, 0.4, 1.1]]
[[members]]
name = "prop"
ends = ["ground.foot", "bar.a"]
ea = 1e4
rest_length = 1.2
buckling_load = 50.0
damping = 3.0
"#,
    );
    let mut state = State::initial(&model);
    state.velocities = nalgebra::DVector::from_fn(model.dof_count, |i, _| 0.1 * (i as f64 + 1.0).sin());
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::StiffnessAndDamping);
    let c = &ws.cables[0];
    assert!(
        is_buckled(&model.cables[0], c.rest_length, c.length),
        "the test member is buckled: {}",
        c.tension
    );
    let fd = fd_stiffness(&model, &state, 1e-6);
    let err = rel_err(&ws.stiffness, &fd, 1e-6);
    assert!(err < 1e-6, "K against finite differences: {err}");
    let fd = fd_damping(&model, &state, 1e-6);
    assert!(rel_err(&ws.damping, &fd, 1e-6) < 1e-6);
}

#[test]
fn a_weight_dropped_on_a_column_buckles_it_and_the_energy_account_closes() {
    let p = euler_load();
    // 1.005 P of weight on the unstressed column: it buckles on the way down and swings back up
    let model = model_from_toml(&column(1.005 * p / 9.81, ""));
    let settings = SimSettings { dt: 1e-4, integrator: Integrator::Rk4, ..Default::default() };
    let mut sim = Simulator::new(model, settings).unwrap();
    let mut deepest: f64 = 0.0;
    let mut buckled = 0;
    // the buckled column's swing (k_b ~ P / (2 L0) against 126 kg) takes about 4 s
    let mut returned = false;
    for _ in 0..60000 {
        sim.step().unwrap();
        returned |= deepest > 0.01 && sim.state().poses[1].position.y > L0 - 0.1 * deepest;
        let y = sim.state().poses[1].position.y;
        deepest = deepest.max(L0 - y);
        let c = &sim.workspace().cables[0];
        if is_buckled(&sim.model().cables[0], c.rest_length, c.length) {
            buckled += 1;
        }
    }
    assert!(buckled > 1000 && deepest > 2.0 * p * L0 / EA, "it buckled: {buckled} steps, {deepest} m deep");
    assert!(returned, "it swung back up");
    let account = sim.energy();
    let scale = 1.005 * p * deepest;
    assert!(
        account.numerical_loss().abs() < 1e-6 * scale,
        "the account closes: {} J unexplained of {scale} J",
        account.numerical_loss()
    );
}

#[test]
fn careless_buckling_members_are_refused_naming_the_field() {
    let both = column(1.0, "buckling_load = 100.0");
    let err = tensegrity::scene::from_toml(&both, "col.toml").expect_err("EI and P").to_string();
    assert!(err.contains("members[0].buckling_load") && err.contains("not both"), "{err}");
    let negative = column(1.0, "").replace("bending_stiffness = 500", "bending_stiffness = -5");
    let err = tensegrity::scene::from_toml(&negative, "col.toml").expect_err("negative EI").to_string();
    assert!(err.contains("members[0].bending_stiffness"), "{err}");
    // a member form-found into a compression past its buckling load
    let pushed = column(200.0, "force = -1962.0");
    let err = tensegrity::scene::from_toml(&pushed, "col.toml").expect_err("starts buckled").to_string();
    assert!(err.contains("members[0].force") && err.contains("past its buckling load"), "{err}");
}
