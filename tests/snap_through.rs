//! Invariant: the quasi-static deployment follows a path through its limit point instead of
//! stopping there, and matches the closed-form equilibrium curve on every branch. The scene
//! (`config/examples/snap_lever.toml`) is a von Mises-type snap-through with one degree of
//! freedom: a lever of length 1 m pinned at the origin, angle `theta` from horizontal, tip
//! `p = (cos theta, sin theta)`; a spring cable from the tip to `(-1, 0)` (EA 1000 N, rest length
//! `|p - (-1, 0)|` at 30 degrees, so it pushes the lever away from horizontal while within 30
//! degrees of it); a soft cable up to `(0, 3)` (EA 5 N, rest 0.6 m) and the winch's soft cable
//! down to `(0, -3)` (EA 5 N), whose rest length goes from 0.7 m to 0.53 m.
//!
//! Closed form. A cable from the tip to anchor `x` with tension `T` has moment `T (p x e)_z`
//! about the pin, `e = (x - p)/|x - p|`. Equilibrium of moments gives the winch tension at any
//! angle, `T_d = -(M_spring + M_up) / m_d` with `m_d` the down cable's moment per newton, and its
//! rest length from `T_d = EA (L_d - L0_d) / L0_d`: `L0_d(theta) = L_d / (1 + T_d / EA)`. Along
//! the path the winch's rest length falls while the lever comes down; the minimum of
//! `L0_d(theta)` near 16 degrees is the limit point (load control cannot go further on that
//! branch), the branch between it and the maximum near -15 degrees is unstable (there
//! `dL0_d/dtheta < 0`), and past the maximum the far branch is stable again.

mod common;

use tensegrity::evaluate::Workspace;
use tensegrity::solve::deploy::{deploy_quasi_static, PathKind, QuasiStaticPath};
use tensegrity::{Model, State};

const SPRING_EA: f64 = 1000.0;
const SOFT_EA: f64 = 5.0;
const UP_REST: f64 = 0.6;

fn spring_rest() -> f64 {
    (2.0 + 2.0 * 30f64.to_radians().cos()).sqrt()
}

/// Moment about the pin of a cable from the tip at angle `theta` to `anchor`, per newton of
/// tension, and the cable's length.
fn arm(theta: f64, anchor: (f64, f64)) -> (f64, f64) {
    let (px, py) = (theta.cos(), theta.sin());
    let (dx, dy) = (anchor.0 - px, anchor.1 - py);
    let l = (dx * dx + dy * dy).sqrt();
    ((px * dy - py * dx) / l, l)
}

fn tension(ea: f64, rest: f64, length: f64) -> f64 {
    (ea / rest * (length - rest)).max(0.0)
}

/// The winch's rest length at which the lever rests at `theta` (closed form, module docs).
fn winch_rest_length(theta: f64) -> f64 {
    let (m_s, l_s) = arm(theta, (-1.0, 0.0));
    let (m_u, l_u) = arm(theta, (0.0, 3.0));
    let (m_d, l_d) = arm(theta, (0.0, -3.0));
    let moment = tension(SPRING_EA, spring_rest(), l_s) * m_s + tension(SOFT_EA, UP_REST, l_u) * m_u;
    let t_d = -moment / m_d;
    l_d / (1.0 + t_d / SOFT_EA)
}

/// `theta` in `[lo, hi]` where `f` is smallest (golden section; `f` unimodal there).
fn argmin(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    while hi - lo > 1e-13 {
        let (a, b) = (hi - g * (hi - lo), lo + g * (hi - lo));
        if f(a) < f(b) {
            hi = b;
        } else {
            lo = a;
        }
    }
    0.5 * (lo + hi)
}

/// `theta` in `[lo, hi]` where `f` crosses zero (bisection).
fn root(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    assert!(f(lo) * f(hi) <= 0.0, "bracket");
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if f(lo) * f(mid) <= 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    0.5 * (lo + hi)
}

struct Row {
    kind: PathKind,
    time: f64,
    theta: f64,
    winch: f64,
    stable: bool,
}

fn lever(winch_start: Option<f64>) -> Model {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut text = std::fs::read_to_string(root.join("config/examples/snap_lever.toml")).unwrap();
    if let Some(start) = winch_start {
        text = text.replace("rest_length = 0.7\n", &format!("rest_length = {start}\n"));
    }
    let model = common::model_from_toml(&text);
    // the closed form's parameters are the scene's
    let down = model.cable_id("down").unwrap().0;
    assert_eq!(model.cables[down].axial_stiffness, SOFT_EA);
    assert_eq!(model.cables[model.cable_id("spring").unwrap().0].axial_stiffness, SPRING_EA);
    assert!((model.initial_rest_lengths[model.cable_id("spring").unwrap().0] - spring_rest()).abs() < 1e-15);
    model
}

fn deploy(model: &Model) -> (QuasiStaticPath, Vec<Row>) {
    let tip = model.point_id("lever.b").unwrap().0;
    let winch = model.cable_id("down").unwrap().0;
    let mut state = State::initial(model);
    let mut ws = Workspace::new(model);
    let mut rows = Vec::new();
    let path = deploy_quasi_static(model, &mut state, &mut ws, |step, st, w| {
        let p = w.points[tip].position;
        assert!((p.norm() - 1.0).abs() < 1e-10, "the tip stays on the circle: {}", p.norm());
        rows.push(Row {
            kind: step.kind,
            time: step.time,
            theta: p.y.atan2(p.x),
            winch: st.rest_lengths[winch],
            stable: step.report.stable,
        });
    })
    .unwrap_or_else(|e| panic!("{e}"));
    (path, rows)
}

#[test]
fn the_path_follows_the_closed_form_curve_through_its_limit_point_and_snaps_through() {
    let model = lever(None);
    let (path, rows) = deploy(&model);

    // every row, on every branch, lies on the closed-form curve
    for r in &rows {
        let expected = winch_rest_length(r.theta);
        assert!(
            (r.winch - expected).abs() < 1e-9,
            "{:?} at t = {}: theta {} deg, rest length {} against the closed form {expected}",
            r.kind,
            r.time,
            r.theta.to_degrees(),
            r.winch
        );
    }

    // the limit point: the smallest rest length the upper branch holds
    let theta_limit = argmin(winch_rest_length, 0.05, 0.5);
    let rest_limit = winch_rest_length(theta_limit);
    let t_limit = (0.7 - rest_limit) / (0.7 - 0.53);
    assert_eq!(path.snaps.len(), 1, "one snap-through");
    let snap = path.snaps[0];
    assert!(
        (snap.limit_time - t_limit).abs() < 1e-7,
        "limit point at t = {} against the closed form {t_limit} ({} degrees)",
        snap.limit_time,
        theta_limit.to_degrees()
    );
    assert!(snap.followed_path, "the traced path comes back to the load on the far branch");

    // the unstable branch was traced: rows on both sides of horizontal, between the two limits,
    // flagged unstable exactly where the closed-form curve falls (dL0/dtheta < 0)
    let theta_upper = argmin(|t| -winch_rest_length(t), -0.5, -0.05);
    let arc: Vec<&Row> = rows.iter().filter(|r| r.kind == PathKind::ArcLength).collect();
    assert!(
        arc.iter().any(|r| r.theta > 0.1 && !r.stable) && arc.iter().any(|r| r.theta < -0.1 && !r.stable)
    );
    assert!(arc.iter().any(|r| r.theta < theta_upper - 0.1 && r.stable), "the far branch was reached");
    for r in &rows {
        let near_a_kink = [theta_limit, theta_upper, 30f64.to_radians(), -30f64.to_radians()]
            .iter()
            .any(|k| (r.theta - k).abs() < 2e-3);
        if near_a_kink {
            continue;
        }
        let h = 1e-6;
        let slope = (winch_rest_length(r.theta + h) - winch_rest_length(r.theta - h)) / (2.0 * h);
        assert_eq!(r.stable, slope > 0.0, "stability at {} degrees (slope {slope})", r.theta.to_degrees());
    }

    // the landing: the far-branch equilibrium at the same winch length (closed form)
    let landing = &rows[snap.landing_row];
    assert_eq!(landing.kind, PathKind::SnapThrough);
    let theta_far = root(|t| winch_rest_length(t) - landing.winch, -1.5, theta_upper);
    assert!(
        (landing.theta - theta_far).abs() < 1e-9,
        "landed at {} degrees, closed form {}",
        landing.theta.to_degrees(),
        theta_far.to_degrees()
    );
    assert!(snap.jump > 1.0, "the tip moves {} m", snap.jump);
    // the output steps are the schedule's, in order
    let outputs: Vec<&Row> = rows.iter().filter(|r| r.kind != PathKind::ArcLength).collect();
    assert_eq!(outputs.len(), model.schedule.steps + 1);
    assert!(outputs.windows(2).all(|w| w[1].time > w[0].time));
    assert!(outputs.iter().all(|r| r.stable));
}

#[test]
fn a_branch_that_ends_inside_the_schedule_lands_by_descending_the_energy() {
    // starting the winch at 0.62 m puts the unstable branch's far end (0.676 m) outside the
    // schedule: the traced path leaves it, and the landing comes from the limit point downhill
    let model = lever(Some(0.62));
    let (path, rows) = deploy(&model);
    assert_eq!(path.snaps.len(), 1);
    let snap = path.snaps[0];
    assert!(!snap.followed_path);
    let theta_limit = argmin(winch_rest_length, 0.05, 0.5);
    let t_limit = (0.62 - winch_rest_length(theta_limit)) / (0.62 - 0.53);
    assert!((snap.limit_time - t_limit).abs() < 1e-7, "{} against {t_limit}", snap.limit_time);
    let landing = &rows[snap.landing_row];
    let theta_upper = argmin(|t| -winch_rest_length(t), -0.5, -0.05);
    let theta_far = root(|t| winch_rest_length(t) - landing.winch, -1.5, theta_upper);
    assert!((landing.theta - theta_far).abs() < 1e-9);
    assert!(landing.stable);
}

#[test]
fn deploy_reports_the_limit_point_and_the_jump() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = common::scratch("snap_through_cli");
    let csv = dir.join("path.csv");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_tensegrity"))
        .args(["deploy", "config/examples/snap_lever.toml", "--quasi-static", "--out"])
        .arg(&csv)
        .current_dir(root)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("snap-through: limit point at t = 0.94973"), "{text}");
    assert!(text.contains("path traced through the unstable branch"), "{text}");
    let csv = std::fs::read_to_string(csv).unwrap();
    let kinds: Vec<&str> = csv.lines().skip(1).map(|l| l.split(',').nth(2).unwrap()).collect();
    assert_eq!(kinds.iter().filter(|k| **k == "snap").count(), 1);
    assert!(kinds.iter().filter(|k| **k == "arc").count() > 10);
    assert_eq!(kinds.iter().filter(|k| **k != "arc").count(), 21);
}
