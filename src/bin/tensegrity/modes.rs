//! `tensegrity modes SCENE`: natural frequencies and mode shapes at the equilibrium (a table,
//! JSON, and optionally drawings of the shapes).

use std::path::{Path, PathBuf};

use tensegrity::report::Num;
use tensegrity::solve::statics::EquilibriumReport;
use tensegrity::summary::ModesFailure;
use tensegrity::Model;

use crate::output::*;

/// Runs `modes` on `scene`: `count` modes, as JSON when `json`, drawn to `plot` when given;
/// `progress` shows the Newton iterations of a long solve and is finished before any output.
pub fn run(
    scene: &Path,
    json: bool,
    count: usize,
    plot: Option<PathBuf>,
    progress: crate::output::Progress,
) -> Result<(), String> {
    let model = load_for_statics(scene)?;
    crate::output::refuse_nothing_to_move(&model, scene)?;
    let solved = tensegrity::summary::modes(&model);
    progress.finish();
    let (state, r, modes) = solved.map_err(|f| match f {
        ModesFailure::NoEquilibrium(f) => format!(
            "{}: no equilibrium found: residual {:.3e} N after {} Newton iterations ({})",
            scene.display(),
            f.residual,
            f.iterations,
            f.stop_words
        ),
        ModesFailure::SingularMass => {
            format!("{}: the mass matrix is singular on the joints' null space", scene.display())
        }
    })?;
    emit(&format_modes(&model, &r, &modes, count, json)?);
    if let Some(base) = plot {
        let panels = tensegrity::plot::mode_panels(&model, &state, &modes, count.min(6));
        if panels.is_empty() {
            return Err(format!("{}: no vibrating mode to draw", scene.display()));
        }
        let title = format!(
            "{}: mode shapes over the equilibrium (grey), exaggerated: farthest point moved {} m",
            model.name,
            tensegrity::error::readable_number((panels[0].largest_displacement * 1e4).round() / 1e4)
        );
        tensegrity::plot::write_structure_panels(&title, &panels, &base)?;
        say!(
            "mode shapes drawn to {} and {}",
            base.with_extension("png").display(),
            base.with_extension("svg").display()
        );
    }
    Ok(())
}

/// The `modes` output: a table (or JSON) of the zero-frequency modes and the lowest `count`
/// others, each with its largest kinetic-energy shares and the cables it stretches.
fn format_modes(
    model: &Model,
    r: &EquilibriumReport,
    modes: &[tensegrity::solve::modes::Mode],
    count: usize,
    json: bool,
) -> Result<String, String> {
    use std::fmt::Write as _;
    let zero: Vec<usize> = (0..modes.len()).filter(|&i| modes[i].zero).collect();
    let listed = tensegrity::summary::listed_modes(modes, count);
    if json {
        let out = tensegrity::summary::mode_summaries(model, modes, count);
        return serde_json::to_string_pretty(&out).map(|s| s + "\n").map_err(|e| e.to_string());
    }
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: {} at the equilibrium ({}); {} zero-frequency",
        model.name,
        counted(modes.len(), "mode"),
        r.stability_words(),
        zero.len()
    );
    if modes.is_empty() {
        let _ = writeln!(out, "no free motion: the joints hold every coordinate, so nothing vibrates");
        return Ok(out);
    }
    let _ = writeln!(
        out,
        "\n{:>4} {:>14} {:>12}  {:<40} cables stretched, m per unit amplitude",
        "mode", "frequency Hz", "period s", "kinetic energy"
    );
    for &i in &listed {
        let m = &modes[i];
        let mut shares: Vec<(usize, f64)> = m.kinetic_share.iter().copied().enumerate().collect();
        shares.sort_by(|a, b| b.1.total_cmp(&a.1));
        let ke: Vec<String> = shares
            .iter()
            .take(3)
            .filter(|(_, f)| *f >= 0.005)
            .map(|(b, f)| format!("{} {:.0}%", model.bodies[*b].name, 100.0 * f))
            .collect();
        let top = m.segment_change.iter().copied().fold(0.0, f64::max).max(1e-300);
        let mut cables: Vec<(usize, f64)> =
            (0..m.cable_stretch.len()).map(|c| (c, m.segment_change[c])).collect();
        cables.sort_by(|a, b| b.1.total_cmp(&a.1));
        let stretched: Vec<String> = cables
            .iter()
            .take(3)
            .filter(|(_, s)| *s >= 1e-3 * top)
            .map(|&(c, seg)| {
                let total = m.cable_stretch[c];
                let total = format!("{:+.3}", Num(total));
                if seg > 2.0 * m.cable_stretch[c].abs() + 1e-9 * top {
                    format!("{} {total} (slides: segments {seg:.3})", model.cable_names[c])
                } else {
                    format!("{} {total}", model.cable_names[c])
                }
            })
            .collect();
        let (freq, period) = if m.zero {
            ("0 (zero)".to_string(), "-".to_string())
        } else if m.omega_squared < 0.0 {
            ("unstable".to_string(), "-".to_string())
        } else {
            (format!("{:.4}", m.frequency_hz), format!("{:.4}", 1.0 / m.frequency_hz))
        };
        let _ = writeln!(
            out,
            "{:>4} {:>14} {:>12}  {:<40} {}",
            i + 1,
            freq,
            period,
            ke.join(", "),
            stretched.join(", ")
        );
    }
    Ok(out)
}
