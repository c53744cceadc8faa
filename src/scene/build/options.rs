//! The scene's options: takes `[sensors]`, `[randomize]`, `[damping]` and `[solver]`, gives the
//! sensor model, the randomization, Rayleigh damping and solver settings.

use super::context::{delay, in_range, Ctx};
use crate::error::SceneError;
use crate::model::{Model, SolverSettings};
use crate::scene::spec::{self, limits, SceneSpec};

/// Checks `[sensors]` and gives the sensor model: each channel's noise, bias and resolution
/// (`>= 0`, bias of either sign), delay, rate (> 0) and dropout (`[0, 1)`); an orientation takes
/// no bias or resolution.
pub(super) fn build_sensors(spec: &SceneSpec, cx: &Ctx) -> Result<crate::sensors::SensorModel, SceneError> {
    use crate::sensors::{ChannelModel, SensorKind, SensorModel};
    let Some(s) = &spec.sensors else {
        return Ok(SensorModel::default());
    };
    let declared =
        [&s.tension, &s.length, &s.rest_length, &s.position, &s.orientation, &s.gyro, &s.accelerometer];
    let mut channels = Vec::new();
    for (kind, c) in SensorKind::ALL.into_iter().zip(declared) {
        let Some(c) = c else { continue };
        let table = format!("sensors.{}", kind.name());
        let e = |field: &str, r: String| cx.top(&format!("{table}.{field}"), r);
        let value = |x: f64, field: &str| in_range(x, limits::SENSOR_VALUE, "").map_err(|r| e(field, r));
        let sigma = value(c.sigma, "sigma")?;
        let resolution = value(c.resolution, "resolution")?;
        let bias = if c.bias.is_finite() && c.bias.abs() <= limits::SENSOR_VALUE.1 {
            c.bias
        } else {
            return Err(e("bias", format!("must be finite, within +-1e12, got {}", c.bias)));
        };
        if kind == SensorKind::Orientation && (bias != 0.0 || resolution != 0.0) {
            return Err(e(
                "bias",
                "an orientation sensor has noise (sigma, rad) but no bias or resolution".into(),
            ));
        }
        let delay = delay(c.delay_s, c.delay, "delay", e)?;
        let period = match c.rate {
            Some(r) => 1.0 / in_range(r, limits::SENSOR_RATE, "Hz").map_err(|r| e("rate", r))?,
            None => 0.0,
        };
        if !(c.dropout >= 0.0 && c.dropout < 1.0) {
            return Err(e("dropout", format!("must be in [0, 1), got {}", c.dropout)));
        }
        channels.push((kind, ChannelModel { sigma, bias, resolution, delay, period, dropout: c.dropout }));
    }
    Ok(SensorModel { seed: s.seed, channels })
}

/// Checks `[randomize]` against `model` (built as written) and gives the declarations: a known
/// parameter, elements that have it (a cable for `ea`, `damping`, `rest_length` and
/// `pulley_friction`, a body with mass for `mass`; every such one by default), a distribution with
/// its fields, factors that stay positive and rest lengths that stay above zero within six
/// standard deviations, and no `rest_length` on a cable with pulley friction.
pub(super) fn build_randomization(
    r: &spec::RandomizeSpec,
    model: &Model,
    cx: &Ctx,
) -> Result<crate::randomize::Randomization, SceneError> {
    use crate::randomize::{DrawDistribution, Parameter, RandomParameter};
    let mut parameters = Vec::new();
    for (i, p) in r.parameters.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("randomize.parameters", i, field, reason);
        let parameter = Parameter::parse(&p.parameter).ok_or_else(|| {
            e(
                "parameter",
                format!("'{}' is not ea, damping, mass, rest_length or pulley_friction", p.parameter),
            )
        })?;
        let finite = |x: Option<f64>, field: &str| match x {
            Some(x) if x.is_finite() => Ok(x),
            Some(x) => Err(e(field, format!("must be finite, got {x}"))),
            None => Err(e(field, format!("a {} distribution needs {field}", p.distribution))),
        };
        let distribution = match p.distribution.as_str() {
            "uniform" => {
                let (low, high) = (finite(p.low, "low")?, finite(p.high, "high")?);
                if high <= low {
                    return Err(e("high", format!("must be above low ({low}), got {high}")));
                }
                DrawDistribution::Uniform { low, high }
            }
            "normal" | "lognormal" => {
                let (mean, sigma) = (finite(p.mean, "mean")?, finite(p.sigma, "sigma")?);
                if sigma <= 0.0 {
                    return Err(e("sigma", format!("must be positive, got {sigma}")));
                }
                if p.distribution == "normal" {
                    DrawDistribution::Normal { mean, sigma }
                } else {
                    DrawDistribution::LogNormal { mean, sigma }
                }
            }
            other => {
                return Err(e("distribution", format!("'{other}' is not uniform, normal or lognormal")));
            }
        };
        let names: Vec<&String> = if parameter == Parameter::Mass {
            model.bodies.iter().map(|b| &b.name).collect()
        } else {
            model.cable_names.iter().collect()
        };
        let has = |k: usize| match parameter {
            Parameter::Mass => model.bodies[k].mass > 0.0 && model.bodies[k].dof_count > 0,
            Parameter::PulleyFriction => model.cables[k].friction.is_some(),
            _ => true,
        };
        let elements: Vec<usize> = match &p.elements {
            None => (0..names.len()).filter(|&k| has(k)).collect(),
            Some(list) => {
                let mut out = Vec::new();
                for name in list {
                    let k = names.iter().position(|n| *n == name).ok_or_else(|| {
                        let what = if parameter == Parameter::Mass { "body" } else { "cable" };
                        e("elements", format!("unknown {what} '{name}'"))
                    })?;
                    if !has(k) {
                        let why = match parameter {
                            Parameter::Mass => "has no mass that moves",
                            _ => "has no pulley friction",
                        };
                        return Err(e("elements", format!("'{name}' {why}")));
                    }
                    out.push(k);
                }
                out
            }
        };
        let low = distribution.practical_minimum();
        if parameter.is_factor() && low <= 0.0 && !matches!(distribution, DrawDistribution::LogNormal { .. })
        {
            return Err(e(
                "distribution",
                format!("a factor on {} must stay positive: the draws reach {low}", parameter.name()),
            ));
        }
        if parameter == Parameter::RestLength {
            for &k in &elements {
                if model.cables[k].friction.is_some() {
                    return Err(e(
                        "elements",
                        format!("'{}' has pulley friction: its rest length is shared by segments", names[k]),
                    ));
                }
                let l0 = model.initial_rest_lengths[k];
                if l0 + low <= limits::LENGTH.0 {
                    return Err(e(
                        "distribution",
                        format!("'{}': its rest length {l0} m would reach {} m", names[k], l0 + low),
                    ));
                }
            }
        }
        parameters.push(RandomParameter { parameter, elements, distribution });
    }
    Ok(crate::randomize::Randomization { seed: r.seed, parameters })
}

/// The `[damping]` coefficients, checked.
pub(super) fn build_rayleigh(
    spec: &SceneSpec,
    cx: &Ctx,
) -> Result<crate::model::RayleighDamping, SceneError> {
    let Some(d) = &spec.damping else { return Ok(Default::default()) };
    let alpha = match d.alpha {
        Some(a) => in_range(a, limits::RAYLEIGH_ALPHA, "1/s").map_err(|r| cx.top("damping.alpha", r))?,
        None => 0.0,
    };
    let beta = match d.beta {
        Some(b) => in_range(b, limits::RAYLEIGH_BETA, "s").map_err(|r| cx.top("damping.beta", r))?,
        None => 0.0,
    };
    Ok(crate::model::RayleighDamping { alpha, beta })
}

/// The `[solver]` settings, checked.
pub(super) fn build_solver(spec: &SceneSpec, cx: &Ctx) -> Result<SolverSettings, SceneError> {
    let mut solver = SolverSettings::default();
    if let Some(s) = &spec.solver {
        if let Some(t) = s.tolerance {
            if !(t.is_finite() && t > 0.0 && t < 1.0) {
                return Err(cx.top("solver", format!("tolerance must be in (0, 1), got {t}")));
            }
            solver.tolerance = t;
        }
        if let Some(n) = s.max_iterations {
            if n == 0 || n > limits::MAX_SOLVER_ITERATIONS {
                return Err(cx.top(
                    "solver",
                    format!("max_iterations must be in [1, {}], got {n}", limits::MAX_SOLVER_ITERATIONS),
                ));
            }
            solver.max_iterations = n;
        }
    }

    Ok(solver)
}
