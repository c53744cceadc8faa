//! `tensegrity statics SCENE`: the equilibrium at the initial rest lengths (tables or JSON).

use std::path::Path;

use tensegrity::evaluate::Workspace;
use tensegrity::report;
use tensegrity::report::Num;
use tensegrity::solve::statics::EquilibriumReport;
use tensegrity::summary::NO_FREE_MOTION;
use tensegrity::{Model, State};

use crate::output::*;

/// Runs `statics` on `scene`, as JSON when `json`.
/// `progress` shows the Newton iterations of a long solve and is finished before any output.
pub fn run(scene: &Path, json: bool, progress: crate::output::Progress) -> Result<(), String> {
    let model = load_for_statics(scene)?;
    let solved = tensegrity::summary::statics(&model);
    progress.finish();
    let solved = solved.map_err(|f| {
        format!(
            "{}: no equilibrium found: residual {:.3e} N after {} ({}; residual by iteration {})",
            scene.display(),
            f.residual,
            counted(f.iterations, "Newton iteration"),
            f.stop_words,
            history_words(&f.history)
        )
    })?;
    if json {
        emit(&(serde_json::to_string_pretty(&solved.summary).map_err(|e| e.to_string())? + "\n"));
    } else {
        let (moved, point) = &solved.largest_move;
        emit(&format_statics(
            &model,
            &solved.state,
            &solved.ws,
            &solved.report,
            &solved.summary.cables,
            (*moved, point.as_str()),
        ));
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
