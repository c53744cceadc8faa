//! `tensegrity statics SCENE`: the equilibrium at the initial rest lengths (tables or JSON).

use std::path::Path;

use serde::Serialize;
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::report;
use tensegrity::report::Num;
use tensegrity::solve::statics::{EquilibriumReport, StaticSolver};
use tensegrity::{Model, State};

use crate::output::*;

#[derive(Serialize)]
struct StaticsJson {
    scene: String,
    iterations: usize,
    stop_reason: &'static str,
    residual_n: f64,
    residual_history_n: Vec<f64>,
    force_scale_n: f64,
    stable: bool,
    negative_stiffness_modes: usize,
    zero_stiffness_modes: usize,
    /// Left out where it does not exist (no free motion): `not_computed` says why.
    #[serde(skip_serializing_if = "Option::is_none")]
    min_stiffness_eigenvalue: Option<f64>,
    /// The quantities left out of this report, each with the reason (docs/cli.md, "JSON").
    #[serde(skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    not_computed: std::collections::BTreeMap<&'static str, &'static str>,
    potential_energy_j: f64,
    largest_move_from_scene_m: f64,
    bodies: Vec<report::BodyReport>,
    points: Vec<(String, [f64; 3])>,
    cables: Vec<report::CableReport>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    contacts: Vec<report::ContactReport>,
    joints: Vec<report::JointReport>,
}

/// Why a structure whose joints hold every coordinate has no reduced stiffness to report.
const NO_FREE_MOTION: &str = "no free motion: the joints hold every coordinate";

/// Runs `statics` on `scene`, as JSON when `json`.
/// `progress` shows the Newton iterations of a long solve and is finished before any output.
pub fn run(scene: &Path, json: bool, progress: crate::output::Progress) -> Result<(), String> {
    let model = load_for_statics(scene)?;
    let mut state = State::initial(&model);
    let mut ws = Workspace::for_forces(&model);
    evaluate(&model, &state, &mut ws, Tangents::None);
    let reference = report::all_pulley_coordinates(&model, &state, &ws);
    let mut solver = StaticSolver::new(&model);
    let r = solver.equilibrate(&model, &mut state, &mut ws, &model.solver);
    progress.finish();
    let r = r.map_err(|(it, res)| {
        format!(
            "{}: no equilibrium found: residual {res:.3e} N after {} ({}; residual by iteration {})",
            scene.display(),
            counted(it, "Newton iteration"),
            solver.stop_words(&model),
            history_words(solver.residual_history())
        )
    })?;
    evaluate(&model, &state, &mut ws, Tangents::None);
    let cables = report::cable_reports(&model, &state, &ws, &reference);
    // how far the equilibrium lies from the pose the scene sketched, and where
    let sketched = State::initial(&model);
    let largest_move = model
        .points
        .iter()
        .map(|p| {
            let at = |s: &State| s.poses[p.body.0].transform_point(&p.local);
            ((at(&state) - at(&sketched)).norm(), p.name.as_str())
        })
        .fold((0.0, ""), |a, b| if b.0 > a.0 { b } else { a });
    if json {
        let out = StaticsJson {
            scene: model.name.clone(),
            iterations: r.iterations,
            stop_reason: solver.stop_reason().words(),
            residual_n: r.residual,
            residual_history_n: solver.residual_history().to_vec(),
            force_scale_n: r.force_scale,
            stable: r.stable,
            negative_stiffness_modes: r.negative_modes,
            zero_stiffness_modes: r.zero_modes,
            min_stiffness_eigenvalue: r
                .min_stiffness_eigenvalue
                .is_finite()
                .then_some(r.min_stiffness_eigenvalue),
            not_computed: if r.min_stiffness_eigenvalue.is_finite() {
                Default::default()
            } else {
                [("min_stiffness_eigenvalue", NO_FREE_MOTION)].into()
            },
            potential_energy_j: r.potential_energy,
            largest_move_from_scene_m: largest_move.0,
            bodies: report::body_reports(&model, &state),
            points: report::point_positions(&model, &ws),
            cables,
            contacts: report::contact_reports(&model, &ws),
            joints: report::joint_reports(&model, &state),
        };
        emit(&(serde_json::to_string_pretty(&out).map_err(|e| e.to_string())? + "\n"));
    } else {
        emit(&format_statics(&model, &state, &ws, &r, &cables, largest_move));
    }
    Ok(())
}

fn format_statics(
    model: &Model,
    state: &State,
    ws: &Workspace,
    r: &EquilibriumReport,
    cables: &[report::CableReport],
    (moved, moved_point): (f64, &str),
) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: equilibrium after {}, residual {:.3e} N ({:.1e} of {:.4} N), {} ({})",
        model.name,
        counted(r.iterations, "Newton iteration"),
        r.residual,
        r.residual / r.force_scale,
        r.force_scale,
        r.stability_words(),
        if r.min_stiffness_eigenvalue.is_finite() {
            format!("min reduced stiffness eigenvalue {:.4e}", r.min_stiffness_eigenvalue)
        } else {
            NO_FREE_MOTION.to_string()
        }
    );
    let _ = writeln!(
        out,
        "potential energy {:.6} J (elastic + gravitational); largest move from the scene's pose {:.6} m{}",
        Num(r.potential_energy),
        Num(moved),
        if moved > 0.0 { format!(" ({moved_point})") } else { String::new() }
    );
    let _ = writeln!(
        out,
        "\n{:<14} {:>12} {:>12} {:>12} {:>12} {:>12}  slack",
        if model.cables.iter().any(|c| !c.tension_only) { "cable/member" } else { "cable" },
        "tension N",
        "length m",
        "rest m",
        "strain",
        "pulleys"
    );
    for c in cables {
        let _ = writeln!(
            out,
            "{:<14} {:>12.6} {:>12.6} {:>12.6} {:>12.4e} {:>12}  {}",
            c.name,
            Num(c.tension),
            c.length,
            c.rest_length,
            c.strain,
            c.segment_lengths.len() - 1,
            if c.slack {
                "yes"
            } else if c.buckled {
                "no, buckled"
            } else {
                "no"
            }
        );
    }
    // sliding cables: where the cable runs and how far it has passed through each pulley
    // (a cable with pulley friction has its own table below)
    let sliding: Vec<&report::CableReport> =
        cables.iter().filter(|c| c.segment_lengths.len() > 1 && c.pulleys.is_empty()).collect();
    if !sliding.is_empty() {
        let _ =
            writeln!(out, "\n{:<14} {:>8}  {:>12} {:>12}", "sliding cable", "segment", "length m", "slip m");
        const SHOWN: usize = 12;
        for c in sliding {
            let m = c.segment_lengths.len();
            for (k, l) in c.segment_lengths.iter().enumerate().take(SHOWN) {
                // slip is at the pulley that ends segment k (the last segment ends at the anchor)
                let slip = c.pulley_slip.get(k).map_or("-".to_string(), |s| format!("{:.6}", Num(*s)));
                let name = if k == 0 { c.name.as_str() } else { "" };
                let _ = writeln!(out, "{:<14} {:>8} {:>12.6} {:>12}", name, k + 1, l, slip);
            }
            if m > SHOWN {
                let _ = writeln!(
                    out,
                    "{:<14} {:>8}  ({} more segments: --json lists them all)",
                    "",
                    "...",
                    m - SHOWN
                );
            }
        }
    }
    // pulleys with friction: which stick, which slip, and the tensions on their two sides
    let with_friction: Vec<&report::CableReport> = cables.iter().filter(|c| !c.pulleys.is_empty()).collect();
    if !with_friction.is_empty() {
        let _ = writeln!(
            out,
            "\n{:<14} {:<16} {:>6} {:<10} {:>10} {:>12} {:>12} {:>10}",
            "cable", "pulley", "mu", "state", "wrap deg", "T before N", "T after N", "slip m"
        );
        for c in with_friction {
            for (i, p) in c.pulleys.iter().enumerate() {
                let name = if i == 0 { c.name.as_str() } else { "" };
                let _ = writeln!(
                    out,
                    "{:<14} {:<16} {:>6.3} {:<10} {:>10.3} {:>12.6} {:>12.6} {:>10.6}",
                    name,
                    p.point,
                    p.mu,
                    if p.at_limit && p.state == "stick" { "at limit" } else { p.state },
                    p.wrap_angle_rad.to_degrees(),
                    Num(p.tension_before_n),
                    Num(p.tension_after_n),
                    Num(p.slip_m)
                );
            }
        }
    }
    let _ =
        writeln!(out, "\n{:<14} {:>12} {:>12} {:>12}   quaternion (w x y z)", "body", "x m", "y m", "z m");
    for b in report::body_reports(model, state) {
        let (p, q) = (b.position, b.orientation);
        let _ = writeln!(
            out,
            "{:<14} {:>12.6} {:>12.6} {:>12.6}   {:.6} {:.6} {:.6} {:.6}",
            b.name,
            Num(p[0]),
            Num(p[1]),
            Num(p[2]),
            Num(q[0]),
            Num(q[1]),
            Num(q[2]),
            Num(q[3])
        );
    }
    let _ = writeln!(out, "\n{:<20} {:>12} {:>12} {:>12}", "point", "x m", "y m", "z m");
    for (name, p) in report::point_positions(model, ws) {
        let _ = writeln!(out, "{:<20} {:>12.6} {:>12.6} {:>12.6}", name, Num(p[0]), Num(p[1]), Num(p[2]));
    }
    let joints = report::joint_reports(model, state);
    if !joints.is_empty() {
        // moments only where a joint holds an axis (hinge, planar)
        let axes = model.joints.iter().any(|j| j.alignment.is_some());
        let _ = write!(
            out,
            "\n{:<8} {:<20} {:<20} {:>12} {:>12} {:>12}",
            "joint", "point", "on", "Fx N", "Fy N", "Fz N"
        );
        if axes {
            let _ = write!(out, " {:>12} {:>12} {:>12}", "Mx N m", "My N m", "Mz N m");
        }
        let _ = writeln!(out);
        for j in joints {
            let on = if j.other.is_empty() { "(ground)" } else { j.other.as_str() };
            let f = j.force_n;
            let _ = write!(
                out,
                "{:<8} {:<20} {:<20} {:>12.6} {:>12.6} {:>12.6}",
                j.kind,
                j.point,
                on,
                Num(f[0]),
                Num(f[1]),
                Num(f[2])
            );
            if axes {
                let m = j.moment_nm;
                let _ = write!(out, " {:>12.6} {:>12.6} {:>12.6}", Num(m[0]), Num(m[1]), Num(m[2]));
            }
            let _ = writeln!(out);
        }
    }
    let contacts = report::contact_reports(model, ws);
    if !contacts.is_empty() {
        let _ = writeln!(
            out,
            "\n{:<20} {:<10} {:>12} {:>14} {:>12} {:>12}  friction",
            "contact", "with", "gap m", "normal force N", "friction N", "mu Fn N"
        );
        for c in contacts {
            let friction = c.friction_n.iter().map(|f| f * f).sum::<f64>().sqrt();
            let _ = writeln!(
                out,
                "{:<20} {:<10} {:>12.3e} {:>14.6} {:>12.6} {:>12.6}  {}",
                c.point,
                c.ground,
                c.gap_m,
                Num(c.normal_force_n),
                Num(friction),
                Num(c.friction_limit_n),
                if c.at_limit { "at limit" } else { c.friction_state }
            );
        }
    }
    out
}

/// A residual history as a person reads it: at most the first 5 and the last 5 values, `1.2e3`
/// form, N.
fn history_words(history: &[f64]) -> String {
    let words = |h: &[f64]| h.iter().map(|x| format!("{x:.1e}")).collect::<Vec<_>>().join(", ");
    if history.len() <= 10 {
        format!("[{}] N", words(history))
    } else {
        format!("[{}, ..., {}] N", words(&history[..5]), words(&history[history.len() - 5..]))
    }
}
