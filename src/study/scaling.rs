//! Step time against structure size: towers of stacked prisms (three families), dense against
//! sparse, with the growth exponent of the step time (table and plot).

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use crate::model::Model;
use crate::plot::{self, Chart, Series};
use crate::sim::{SimSettings, Simulator};

use super::{create, run_dynamic};

/// Side strings of a scaling-benchmark tower (`crate::scene::generate::TowerParams`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TowerFamily {
    /// Helical clustered side cables through every stage (each couples a bar of every stage).
    Helical,
    /// One clustered cable per stage through its side strings (MuJoCo's peer towers).
    PerStage,
    /// Classical two-point side strings.
    Classical,
}

impl TowerFamily {
    /// Name used in tables.
    pub fn name(self) -> &'static str {
        match self {
            TowerFamily::Helical => "helical clustered",
            TowerFamily::PerStage => "clustered per stage",
            TowerFamily::Classical => "classical",
        }
    }

    /// The tower of `stages` stages of this family: the helical tower deploys by its side
    /// cables, the others by their clustered top ring.
    pub fn model(self, stages: usize) -> Result<Model, String> {
        use crate::scene::generate::{tower, TowerParams};
        let spec = tower(&TowerParams {
            stages,
            cluster_sides: self == TowerFamily::Helical,
            cluster_per_stage: self == TowerFamily::PerStage,
            cluster_top_ring: self != TowerFamily::Helical,
            ..Default::default()
        });
        crate::scene::build_model(&spec, &format!("<{} tower {stages}>", self.name()), None)
            .map_err(|e| e.to_string())
    }
}

/// One row of the scaling benchmark.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalingRow {
    /// Which side strings.
    pub family: TowerFamily,
    /// Tower stages.
    pub stages: usize,
    /// Generalized coordinates.
    pub coordinates: usize,
    /// Constraint rows.
    pub constraints: usize,
    /// Unknowns of the sparse Newton system (coordinates, constraint rows, bordered cables).
    pub sparse_size: usize,
    /// Structural nonzeros of the sparse Newton matrix.
    pub nonzeros: usize,
    /// Median wall time per step with the dense LU, s (`None`: not run, too large).
    pub dense_step: Option<f64>,
    /// Median wall time per step with the sparse backend (`LDL^T` of the symmetric part, LU when that does not contract), s.
    pub sparse_step: f64,
    /// Newton iterations per step (sparse run).
    pub newton_per_step: f64,
    /// Factorizations per step (sparse run).
    pub factorizations_per_step: f64,
}

/// Largest system the scaling benchmark also times with the dense LU.
pub const SCALING_DENSE_MAX_SIZE: usize = 800;

/// Median wall time per step (s), Newton iterations and factorizations per step of `steps`
/// generalized-alpha steps of `model` (dt 1 ms).
pub fn median_step_time(
    model: &Model,
    linear: crate::solve::linear::LinearBackend,
    steps: usize,
) -> Result<(f64, f64, f64), String> {
    let settings = SimSettings { dt: 1e-3, linear, ..Default::default() };
    let mut times = Vec::with_capacity(steps);
    let mut factorizations = 0;
    let totals = run_dynamic(model, settings, steps as f64 * 1e-3, |_, stats| {
        times.push(stats.wall_time.as_secs_f64());
        factorizations += stats.factorizations;
        Ok(())
    })?;
    times.sort_by(f64::total_cmp);
    let per = |k: usize| k as f64 / totals.steps.max(1) as f64;
    Ok((times[times.len() / 2], per(totals.newton_iterations), per(factorizations)))
}

/// Step-time statistics of one run (`step_times`).
#[derive(Debug, Clone, PartialEq)]
pub struct StepTimes {
    /// Median wall time per step, s.
    pub median: f64,
    /// Mean wall time per step, s.
    pub mean: f64,
    /// Largest wall time of one step, s.
    pub max: f64,
    /// Newton iterations per step.
    pub newton_per_step: f64,
    /// Newton-matrix factorizations per step.
    pub factorizations_per_step: f64,
    /// The linear-solver backend `Auto` chose.
    pub backend: crate::solve::linear::LinearBackend,
    /// Unknowns of the Newton system (coordinates, joint rows, bordered cables).
    pub unknowns: usize,
    /// Stored entries of the Newton matrix (`unknowns^2` when dense).
    pub nonzeros: usize,
    /// Stored entries of the sparse symmetric factor `L`, when the backend has one.
    pub factor_entries: Option<usize>,
}

/// Times `steps` steps of `model` with `settings` after 10 untimed warm-up steps.
pub fn step_times(model: &Model, settings: SimSettings, steps: usize) -> Result<StepTimes, String> {
    let mut sim = Simulator::new(model.clone(), settings).map_err(|e| e.to_string())?;
    for _ in 0..10 {
        sim.step().map_err(|e| e.to_string())?;
    }
    let mut times = Vec::with_capacity(steps);
    let (mut newton, mut factorizations) = (0, 0);
    for k in 0..steps {
        let s = sim.step().map_err(|e| e.to_string())?;
        times.push(s.wall_time.as_secs_f64());
        // outside the timed step; every 256 steps
        if k % 256 == 255 {
            let total = Some(steps as u64);
            crate::progress::report(crate::progress::Report {
                unit: "steps",
                done: k as u64 + 1,
                total,
                residual_n: None,
            });
        }
        newton += s.newton_iterations;
        factorizations += s.factorizations;
    }
    let mean = times.iter().sum::<f64>() / steps as f64;
    times.sort_by(f64::total_cmp);
    Ok(StepTimes {
        median: times[steps / 2],
        mean,
        max: times[steps - 1],
        newton_per_step: newton as f64 / steps as f64,
        factorizations_per_step: factorizations as f64 / steps as f64,
        backend: sim.linear_backend(),
        unknowns: sim.newton_system().size(),
        nonzeros: sim.newton_system().nonzeros(),
        factor_entries: sim.newton_system().symmetric_factor_entries(),
    })
}

/// Least-squares slope of `log y` against `log x`: the exponent `p` of `y ~ x^p`.
pub fn growth_exponent(points: &[(f64, f64)]) -> f64 {
    let logs: Vec<(f64, f64)> = points.iter().map(|(x, y)| (x.ln(), y.ln())).collect();
    let k = logs.len() as f64;
    let (mx, my) = (logs.iter().map(|p| p.0).sum::<f64>() / k, logs.iter().map(|p| p.1).sum::<f64>() / k);
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
    sxy / sxx
}

/// Scaling benchmark: towers of 3-strut prisms with `stages` stages in the three
/// `TowerFamily`s, `steps` generalized-alpha steps each with the sparse backend and (up to
/// `SCALING_DENSE_MAX_SIZE` unknowns) the dense LU; writes `scaling.csv`, `scaling.md` (with the
/// fitted growth exponent of the sparse step time over the runs with 8 or more stages) and
/// `scaling.{png,svg}`.
pub fn scaling(stages: &[usize], steps: usize, out_dir: &Path) -> Result<Vec<ScalingRow>, String> {
    use crate::solve::linear::{KktSystem, LinearBackend};
    std::fs::create_dir_all(out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;
    let mut rows = Vec::new();
    // towers with nothing to deploy stand still: their steps time nothing comparable
    let mut still = Vec::new();
    for family in [TowerFamily::Classical, TowerFamily::PerStage, TowerFamily::Helical] {
        for &s in stages {
            let model = family.model(s)?;
            if model.actuators.is_empty() {
                still.push(format!("{} at {s} stage{}", family.name(), if s == 1 { "" } else { "s" }));
                continue;
            }
            let kkt = KktSystem::new(&model, LinearBackend::Sparse);
            let (sparse_step, newton_per_step, factorizations_per_step) =
                median_step_time(&model, LinearBackend::Sparse, steps)?;
            let size = model.dof_count + model.constraint_count;
            let dense_step = if size <= SCALING_DENSE_MAX_SIZE {
                Some(median_step_time(&model, LinearBackend::Dense, steps)?.0)
            } else {
                None
            };
            rows.push(ScalingRow {
                family,
                stages: s,
                coordinates: model.dof_count,
                constraints: model.constraint_count,
                sparse_size: kkt.size(),
                nonzeros: kkt.nonzeros(),
                dense_step,
                sparse_step,
                newton_per_step,
                factorizations_per_step,
            });
        }
    }
    let mut csv = create(&out_dir.join("scaling.csv"))?;
    let _ = writeln!(
        csv,
        "side_strings,stages,coordinates,constraints,sparse_unknowns,sparse_nonzeros,newton_per_step,factorizations_per_step,dense_step_us,sparse_step_us"
    );
    let mut md = format!(
        "Towers of 3-strut prisms, generalized-alpha (rho_inf 0.8) at dt = 1 ms, median wall time per step over {steps} steps.\n\n| side strings | stages | coordinates | constraints | sparse unknowns | sparse nonzeros | Newton / step | factorizations / step | dense LU µs/step | sparse µs/step |\n| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n"
    );
    for r in &rows {
        let dense = r.dense_step.map(|d| format!("{:.1}", 1e6 * d)).unwrap_or_else(|| "-".into());
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{:.3},{:.3},{},{:.2}",
            r.family.name(),
            r.stages,
            r.coordinates,
            r.constraints,
            r.sparse_size,
            r.nonzeros,
            r.newton_per_step,
            r.factorizations_per_step,
            r.dense_step.map(|d| format!("{:.2}", 1e6 * d)).unwrap_or_default(),
            1e6 * r.sparse_step
        );
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {:.2} | {:.2} | {dense} | {:.1} |",
            r.family.name(),
            r.stages,
            r.coordinates,
            r.constraints,
            r.sparse_size,
            r.nonzeros,
            r.newton_per_step,
            r.factorizations_per_step,
            1e6 * r.sparse_step
        );
    }
    md.push('\n');
    let mut series = Vec::new();
    for family in [TowerFamily::Classical, TowerFamily::PerStage, TowerFamily::Helical] {
        let points: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.family == family)
            .map(|r| (r.stages as f64, 1e6 * r.sparse_step))
            .collect();
        let fit: Vec<(f64, f64)> = points.iter().copied().filter(|p| p.0 >= 8.0).collect();
        if fit.len() >= 2 {
            let _ = writeln!(
                md,
                "{}: sparse step time ~ stages^{:.2} (fitted over {} runs with 8+ stages)  ",
                family.name(),
                growth_exponent(&fit),
                fit.len()
            );
        }
        series.push(Series::new(format!("{} (sparse)", family.name()), points, true));
        if family == TowerFamily::Helical {
            // the helical tower's cost beside the per-stage one's, at each size both ran
            let per_stage = |s: usize| {
                rows.iter()
                    .find(|r| r.family == TowerFamily::PerStage && r.stages == s)
                    .map(|r| r.sparse_step)
            };
            let ratios: Vec<String> = rows
                .iter()
                .filter(|r| r.family == family && r.stages >= 8)
                .filter_map(|r| {
                    per_stage(r.stages).map(|p| format!("{:.2} at {}", r.sparse_step / p, r.stages))
                })
                .collect();
            if !ratios.is_empty() {
                let _ = writeln!(md, "helical / per-stage step time: {} stages  ", ratios.join(", "));
            }
        }
        let dense: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.family == family)
            .filter_map(|r| r.dense_step.map(|d| (r.stages as f64, 1e6 * d)))
            .collect();
        if !dense.is_empty() {
            series.push(Series::new(format!("{} (dense LU)", family.name()), dense, true));
        }
    }
    csv.flush().map_err(|e| e.to_string())?;
    if !still.is_empty() {
        let _ = writeln!(
            md,
            "\nLeft out, as they have no actuator and stand still: {} (a helical tower's side \
             cables run through the stages; with one stage each is a plain two-point cable, so \
             nothing is clustered to deploy).",
            still.join(", ")
        );
    }
    std::fs::write(out_dir.join("scaling.md"), &md).map_err(|e| e.to_string())?;
    plot::write(
        &Chart {
            title: "generalized-alpha step time vs tower size".into(),
            x_label: "stages".into(),
            y_label: "median wall time per step (µs)".into(),
            log_x: true,
            log_y: true,
            series,
            reference: None,
            ordered: false,
        },
        &out_dir.join("scaling"),
    )?;
    Ok(rows)
}
