//! `tensegrity study SCENE`: the quasi-static path and dynamic deployments at several actuation
//! times, or with `--friction` the quasi-static deployment at several pulley-friction
//! coefficients (CSVs, a summary table, plots).

use std::path::PathBuf;

use tensegrity::study;

use crate::output::*;

/// The options of `study` (see `Command::Study`).
pub struct StudyArgs {
    /// Scene file.
    pub scene: PathBuf,
    /// `--ramp-times`.
    pub ramp_times: Option<Vec<f64>>,
    /// `--point`.
    pub point: Option<String>,
    /// `--friction`.
    pub friction: Option<Vec<f64>>,
    /// `--settle`.
    pub settle: f64,
    /// The integrator options.
    pub dynamics: DynamicArgs,
    /// `--jobs`.
    pub jobs: usize,
    /// `--out`.
    pub out: PathBuf,
}

/// Runs `study`.
pub fn run(args: StudyArgs) -> Result<(), String> {
    let StudyArgs { scene, ramp_times, point, friction, settle, dynamics, jobs, out } = args;
    let model = crate::output::load_moving(&scene)?;
    if let Some(mus) = friction {
        let result = study::friction_study(&model, &mus, point.as_deref(), &out)?;
        emit(&result.markdown());
        say!("written to {}", out.display());
        return Ok(());
    }
    let ramp_times = match ramp_times {
        Some(t) => t,
        None => study::default_ramp_times(&model)?,
    };
    let result = study::deployment_study(
        &model,
        &ramp_times,
        point.as_deref(),
        dynamics.settings(&model)?,
        settle,
        jobs,
        &out,
    )?;
    emit(&result.markdown());
    say!("written to {}", out.display());
    Ok(())
}
